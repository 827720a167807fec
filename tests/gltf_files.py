"""Building and patching binary glTF files for tests (one helper instead of one per test file)."""

from __future__ import annotations

import json
import struct
from collections.abc import Callable

JSON_CHUNK = 0x4E4F534A
BIN_CHUNK = 0x004E4942


def make_glb(doc: dict, blob: bytes = b"") -> bytes:
    """A .glb from a glTF JSON document and an optional binary chunk (both padded to 4 bytes)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), JSON_CHUNK) + js
    if blob:
        blob += b"\0" * (-len(blob) % 4)
        body += struct.pack("<II", len(blob), BIN_CHUNK) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def split_glb(glb: bytes) -> tuple[dict, bytes]:
    """The JSON document and the binary chunk (empty when absent) of a .glb."""
    length = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20:20 + length])
    rest = glb[20 + length:]
    blob = b""
    if len(rest) >= 8:
        blob_len, kind = struct.unpack_from("<II", rest, 0)
        if kind == BIN_CHUNK:
            blob = rest[8:8 + blob_len]
    return doc, blob


def patch_glb(glb: bytes, edit: Callable[[dict], None]) -> bytes:
    """The same .glb with its JSON changed in place by ``edit(doc)``."""
    doc, blob = split_glb(glb)
    edit(doc)
    return make_glb(doc, blob)
