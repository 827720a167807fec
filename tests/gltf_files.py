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


def transcode_textures(glb: bytes, extension: str, encode: Callable[[bytes], bytes],
                       keep_fallback: bool = False) -> bytes:
    """``glb`` with every texture's image re-encoded and named by ``extension``
    (``EXT_texture_webp`` or ``EXT_texture_avif``), as gltf-transform's ``webp`` and ``avif``
    commands write it: the new images appended to the binary chunk, each texture's
    ``extensions[extension].source`` pointing at its new image and, unless ``keep_fallback``,
    no plain ``source`` and the extension required."""
    doc, blob = split_glb(glb)
    blob = bytearray(blob)
    mime = {"EXT_texture_webp": "image/webp", "EXT_texture_avif": "image/avif"}[extension]
    made: dict[int, int] = {}
    for texture in doc.get("textures", []):
        old = texture["source"]
        if old not in made:
            view = doc["bufferViews"][doc["images"][old]["bufferView"]]
            start = view.get("byteOffset", 0)
            data = encode(bytes(blob[start:start + view["byteLength"]]))
            blob += b"\0" * (-len(blob) % 4)
            doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob),
                                       "byteLength": len(data)})
            blob += data
            doc["images"].append({"bufferView": len(doc["bufferViews"]) - 1, "mimeType": mime})
            made[old] = len(doc["images"]) - 1
        texture.setdefault("extensions", {})[extension] = {"source": made[old]}
        if not keep_fallback:
            del texture["source"]
    doc["buffers"][0]["byteLength"] = len(blob)
    doc["extensionsUsed"] = sorted({*doc.get("extensionsUsed", []), extension})
    if not keep_fallback:
        doc["extensionsRequired"] = sorted({*doc.get("extensionsRequired", []), extension})
    return make_glb(doc, bytes(blob))
