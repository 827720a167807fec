"""The glTF container: binary (GLB) or JSON, the ``asset`` check, and the bytes of buffers and
buffer views.

The kind of file is decided by its content (a GLB starts with the magic ``glTF``; anything else
must be glTF JSON); a file name or suffix is only a hint for messages. Buffers are read lazily,
so a scene refused by a cheap check (a limit, an unsupported extension) never decodes its data.

Bytes come from three places only: the GLB ``BIN`` chunk, ``data:`` URIs, and the caller's
resolver (a mapping of relative names, see :class:`~shadowmap.renderer.scene.MappingResolver`).
No path or URL named inside a file is ever opened.
"""

from __future__ import annotations

import base64
import binascii
import gc
import json
import re
import reprlib
import struct
from dataclasses import dataclass
from typing import Any, Protocol
from urllib.parse import unquote_to_bytes

from ..errors import SceneError, UnsupportedExtension, UnsupportedVersion
from ..scene import safe_uri

GLB_MAGIC = b"glTF"
JSON_CHUNK = 0x4E4F534A
BIN_CHUNK = 0x004E4942
#: The newest glTF version this loader implements (``asset.minVersion`` must not exceed it).
SUPPORTED_VERSION = (2, 0)

_VERSION = re.compile(r"^(\d+)\.(\d+)$")


class Resolver(Protocol):
    """Where external files come from: relative name -> bytes, ``SceneError`` when unsafe or
    missing (:class:`~shadowmap.renderer.scene.MappingResolver`)."""

    def get(self, name: str) -> bytes: ...


@dataclass
class Document:
    """A parsed glTF container.

    Attributes
    ----------
    json : dict
        The glTF JSON document.
    binary : bytes or None
        The GLB ``BIN`` chunk (``None`` for JSON files and for GLBs without one).
    container : {"glb", "gltf"}
        What the content turned out to be.
    """

    json: dict[str, Any]
    binary: bytes | None
    container: str


def read_container(data: bytes, hint: str | None = None) -> Document:
    """Split a ``.glb`` or parse a ``.gltf``, deciding which by the content.

    Parameters
    ----------
    data : bytes
        The whole file.
    hint : str, optional
        ``"glb"``, ``"gltf"`` or a file suffix: used only to word errors.

    Raises
    ------
    SceneError
        Truncated or corrupt GLB header or chunks; JSON that cannot be parsed (or nests absurdly
        deep); a document that is not a JSON object or lacks a valid glTF 2 ``asset``.
    """
    if not data:
        raise SceneError("the scene file is empty")
    if data[:4] == GLB_MAGIC:
        raw, binary = _split_glb(data)
        container = "glb"
    else:
        raw, binary, container = data, None, "gltf"
    hint_type = (hint or "").lower().lstrip(".")
    try:
        doc = parse_json(raw)
    except SceneError as exc:
        if container == "gltf" and hint_type == "glb":
            raise SceneError("not a binary glTF: the file does not start with the magic 'glTF', "
                             f"and it is not glTF JSON either ({exc})") from None
        if container == "gltf" and hint_type not in ("", "gltf"):
            raise SceneError(f"unsupported scene type {hint!r}: the file is neither binary glTF "
                             f"nor glTF JSON ({exc})") from None
        raise
    check_asset(doc)
    return Document(doc, binary, container)


def _split_glb(data: bytes) -> tuple[bytes, bytes | None]:
    """The JSON chunk and the first BIN chunk of a GLB, with every length checked."""
    if len(data) < 12:
        raise SceneError(f"truncated binary glTF: {len(data)} bytes is shorter than its "
                         "12-byte header")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise SceneError(f"binary glTF version {version} is not supported (only 2)")
    if length > len(data):
        raise SceneError(f"truncated binary glTF: header says {length} bytes, got {len(data)}")
    if length < 20:
        raise SceneError(f"corrupt binary glTF: header length {length} leaves no room for the "
                         "JSON chunk")
    chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
    if chunk_type != JSON_CHUNK or 20 + chunk_len > length:
        raise SceneError("corrupt binary glTF: the first chunk is not a complete JSON chunk")
    # The JSON chunk is padded with spaces; some writers pad with NULs, which JSON refuses.
    raw = data[20:20 + chunk_len].rstrip(b"\0")
    binary: bytes | None = None
    pos = 20 + chunk_len
    # Later chunks: the first BIN chunk is the binary buffer; unknown chunk types are skipped, as
    # the GLB specification asks.
    while pos + 8 <= length:
        clen, ctype = struct.unpack_from("<II", data, pos)
        if pos + 8 + clen > length:
            raise SceneError(f"corrupt binary glTF: the chunk at byte {pos} says {clen} bytes, "
                             f"past the file's end ({length} bytes)")
        if ctype == BIN_CHUNK and binary is None:
            binary = data[pos + 8:pos + 8 + clen]
        elif ctype == JSON_CHUNK:
            raise SceneError("corrupt binary glTF: a second JSON chunk")
        pos += 8 + clen
    # Fewer than 8 bytes left over is padding at worst: ignored.
    return raw, binary


def parse_json(raw: bytes) -> dict[str, Any]:
    """The glTF JSON object of ``raw`` (UTF-8, a byte-order mark tolerated).

    Raises
    ------
    SceneError
        Not UTF-8, not JSON, nested too deep for the parser, or not a JSON object.
    """
    # The cyclic garbage collector is paused while parsing: JSON builds no cycles, and its
    # generation-0 passes over every new list and dict cost a third of the parse of a file of
    # many small objects (100,000 nodes).
    collecting = gc.isenabled()
    gc.disable()
    try:
        doc = json.loads(raw.decode("utf-8-sig"), parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        # ValueError: JSONDecodeError, and integers longer than Python converts (4,300 digits).
        raise SceneError(f"the glTF JSON cannot be parsed: {exc}") from None
    except RecursionError:
        # e.g. a million nested '[': the C parser gives up with RecursionError.
        raise SceneError("the glTF JSON cannot be parsed: it nests too deep") from None
    finally:
        if collecting:
            gc.enable()
    if not isinstance(doc, dict):
        raise SceneError("not a glTF 2.0 file: the JSON is not an object")
    if _SURROGATE_ESCAPE.search(raw):
        _check_strings(doc)
    return doc


def _no_constant(name: str) -> Any:
    # Python's json reads NaN and Infinity, which JSON (and so glTF) does not have.
    raise SceneError(f"the glTF JSON cannot be parsed: {name} is not a JSON value")


#: A \uD800-\uDFFF escape: the only way a JSON text can spell a lone UTF-16 surrogate, which
#: no UTF-8 text (a warning, a JSON response) can carry.
_SURROGATE_ESCAPE = re.compile(rb"\\u[dD][89a-fA-F][0-9a-fA-F]{2}")


def _check_strings(doc: dict[str, Any]) -> None:
    """Refuse a document holding a string or key that is not valid Unicode (a lone surrogate).

    Iterative, so that a document nested as deep as the parser allows costs no recursion.
    """
    stack: list[Any] = [doc]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, str):
            try:
                item.encode("utf-8")
            except UnicodeEncodeError:
                raise SceneError("the glTF JSON cannot be parsed: a string holds a lone UTF-16 "
                                 f"surrogate ({item[:40]!r})") from None


def check_asset(doc: dict[str, Any]) -> None:
    """Refuse anything but glTF 2.x that needs at most version 2.0.

    Raises
    ------
    SceneError
        ``asset`` missing or not an object; ``asset.version`` missing, malformed or with a major
        version other than 2; ``asset.minVersion`` malformed or newer than 2.0.
    """
    if "asset" not in doc:
        raise SceneError("not a glTF 2.0 file: the JSON has no 'asset'")
    asset = doc["asset"]
    if not isinstance(asset, dict):
        raise SceneError("not a glTF 2.0 file: 'asset' is not an object")
    version = asset.get("version")
    match = _VERSION.match(version) if isinstance(version, str) else None
    if match is None:
        raise SceneError(f"asset.version {brief(version)} is not a version like '2.0'")
    if int(match.group(1)) != 2:
        raise UnsupportedVersion("asset.version", f"asset.version: glTF version {version!r} is "
                                 "not supported (only 2.x)")
    if "minVersion" in asset:
        min_version = asset["minVersion"]
        m = _VERSION.match(min_version) if isinstance(min_version, str) else None
        if m is None:
            raise SceneError(f"asset.minVersion {brief(min_version)} is not a version like "
                             "'2.0'")
        if (int(m.group(1)), int(m.group(2))) > SUPPORTED_VERSION:
            raise UnsupportedVersion("asset.minVersion", f"asset.minVersion {min_version!r}: the "
                                     "file needs a newer glTF loader than this one (2.0)")


def decode_data_uri(uri: str, what: str) -> bytes:
    """The bytes of a ``data:[<mediatype>][;base64],<data>`` URI.

    Raises
    ------
    SceneError
        No comma, or invalid base64.
    """
    head, sep, payload = uri[5:].partition(",")
    if not sep:
        raise SceneError(f"{what}: malformed data: URI (no ',')")
    if head.lower().endswith(";base64"):
        try:
            return base64.b64decode(payload, validate=False)
        except (binascii.Error, ValueError) as exc:
            raise SceneError(f"{what}: the base64 data: URI cannot be decoded: {exc}") from None
    return unquote_to_bytes(payload)


def load_uri(uri: Any, resolver: Resolver, what: str) -> bytes:
    """Bytes named by a glTF ``uri``: a ``data:`` URI, else a name looked up in ``resolver``.

    Raises
    ------
    SceneError
        Not a string; a name that could leave the upload
        (:func:`~shadowmap.renderer.scene.safe_uri`, checked here whatever the resolver does);
        a malformed ``data:`` URI; whatever the resolver raises.
    """
    if not isinstance(uri, str):
        raise SceneError(f"{what}: 'uri' is not a string")
    if is_data_uri(uri):
        return decode_data_uri(uri, what)
    return resolver.get(safe_uri(uri, what))


def is_data_uri(uri: str) -> bool:
    """Whether ``uri`` is a ``data:`` URI (decoded in place, never looked up)."""
    return uri[:5].lower() == "data:"


#: How :func:`brief` shows values: a few levels and items of each, so that neither a wide nor
#: a deeply nested value costs more than a few hundred characters (or any recursion) to show.
_BRIEF = reprlib.Repr()  # (keyword arguments only from Python 3.12)
_BRIEF.maxlevel = 3
_BRIEF.maxtuple = _BRIEF.maxlist = _BRIEF.maxdict = _BRIEF.maxset = 4
_BRIEF.maxstring = _BRIEF.maxlong = _BRIEF.maxother = 40


def brief(value: Any, limit: int = 60) -> str:
    """A short ``repr`` of a value from a file, for messages: a warning or an error must not
    carry a megabyte of the file."""
    text = _BRIEF.repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


#: An object's default repr (``<_io.BytesIO object at 0x7f...>``), as a decoder's message may
#: quote its input: the address changes from run to run.
_OBJECT_REPR = re.compile(r"<([\w.]+) object at 0x[0-9a-fA-F]+>")


def exception_text(exc: BaseException) -> str:
    """``Type: message`` of a decoder's exception, for a warning: the same from run to run
    (object addresses left out) and short (:func:`brief`'s limit of a few lines)."""
    text = _OBJECT_REPR.sub(r"<\1>", f"{type(exc).__name__}: {exc}")
    return text if len(text) <= 200 else text[:197] + "..."


def get_list(doc: dict[str, Any], key: str) -> list[Any]:
    """A top-level array of the document (empty when absent), refused when not an array."""
    value = doc.get(key, [])
    if not isinstance(value, list):
        raise SceneError(f"malformed glTF: '{key}' is not an array")
    return value


def get_index(obj: dict[str, Any], key: str, length: int, what: str,
              required: bool = False) -> int | None:
    """``obj[key]`` as an index into an array of ``length`` items; SceneError when invalid."""
    if key not in obj:
        if required:
            raise SceneError(f"{what}: '{key}' is missing")
        return None
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < length:
        raise SceneError(f"{what}: '{key}' = {brief(value)} is not a valid index "
                         f"(0..{length - 1})")
    return value


def get_int(obj: dict[str, Any], key: str, what: str, default: int | None = None,
            minimum: int = 0) -> int:
    """``obj[key]`` as an integer >= ``minimum``; SceneError when invalid or missing."""
    if key not in obj:
        if default is None:
            raise SceneError(f"{what}: '{key}' is missing")
        return default
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise SceneError(f"{what}: '{key}' = {brief(value)} is not an integer >= {minimum}")
    return value


def extension(obj: Any, name: str) -> dict[str, Any] | None:
    """``obj.extensions[name]`` when it is an object, else None."""
    if not isinstance(obj, dict):
        return None
    exts = obj.get("extensions")
    if not isinstance(exts, dict):
        return None
    ext = exts.get(name)
    return ext if isinstance(ext, dict) else None


class Buffers:
    """The bytes of a document's buffers and buffer views, read on first use and kept.

    Parameters
    ----------
    document : Document
    resolver : Resolver
        External files by the relative name the document uses.
    """

    def __init__(self, document: Document, resolver: Resolver) -> None:
        self.doc = document.json
        self._binary = document.binary
        self._container = document.container
        self._resolver = resolver
        self.buffers = get_list(self.doc, "buffers")
        self.views = get_list(self.doc, "bufferViews")
        self._buffer_cache: dict[int, bytes | None] = {}
        #: Messages about data dropped or approximated while reading (collected by the loader).
        self.warnings: list[str] = []
        self._view_cache: dict[int, bytes] = {}

    # -- buffers ---------------------------------------------------------------------------

    def buffer(self, index: int) -> bytes | None:
        """Bytes of buffer ``index``; None for a buffer that holds no data (an
        ``EXT_meshopt_compression`` fallback buffer without ``uri``).

        Raises
        ------
        SceneError
            Unsafe or missing URI, a buffer without data that nothing can fill, or fewer bytes
            than its ``byteLength``.
        """
        if index in self._buffer_cache:
            return self._buffer_cache[index]
        what = f"buffer {index}"
        spec = self.buffers[index]
        if not isinstance(spec, dict):
            raise SceneError(f"malformed glTF: {what} is not an object")
        length = get_int(spec, "byteLength", what, minimum=1)
        data: bytes | None
        if "uri" in spec:
            data = load_uri(spec["uri"], self._resolver, what)
        elif index == 0 and self._container == "glb" and self._binary is not None:
            data = self._binary
        elif extension(spec, "EXT_meshopt_compression") is not None:
            data = None  # filled by the views that decode into it
        elif index == 0 and self._container == "glb":
            raise SceneError(f"{what} has no uri and the binary glTF has no BIN chunk")
        else:
            raise SceneError(f"{what} has no uri: its data is missing")
        if data is not None and len(data) < length:
            raise SceneError(f"{what} holds {len(data)} bytes, fewer than its byteLength "
                             f"{length}")
        self._buffer_cache[index] = data
        return data

    # -- views -----------------------------------------------------------------------------

    def view_spec(self, index: int, what: str) -> dict[str, Any]:
        """The JSON of buffer view ``index`` (SceneError when not an object)."""
        if not 0 <= index < len(self.views) or not isinstance(self.views[index], dict):
            raise SceneError(f"{what}: bufferView {index} does not exist")
        spec: dict[str, Any] = self.views[index]
        return spec

    def view(self, index: int) -> bytes:
        """The bytes buffer view ``index`` holds (``byteLength`` of them), decoding
        ``EXT_meshopt_compression`` when the view has it.

        Raises
        ------
        SceneError
            The view reaches past its buffer, or its compressed data cannot be decoded.
        """
        cached = self._view_cache.get(index)
        if cached is not None:
            return cached
        what = f"bufferView {index}"
        spec = self.view_spec(index, what)
        buf = get_index(spec, "buffer", len(self.buffers), what, required=True)
        assert buf is not None
        offset = get_int(spec, "byteOffset", what, default=0)
        length = get_int(spec, "byteLength", what, minimum=1)
        meshopt = extension(spec, "EXT_meshopt_compression")
        if meshopt is not None:
            data = self._meshopt_view(index, spec, meshopt, buf, offset, length)
        else:
            raw = self.buffer(buf)
            if raw is None:
                raise SceneError(f"{what} reads buffer {buf}, which holds no data")
            if offset + length > len(raw):
                raise SceneError(f"{what} reaches past the end of buffer {buf}: bytes {offset}.."
                                 f"{offset + length} of {len(raw)}")
            data = raw[offset:offset + length]
        self._view_cache[index] = data
        return data

    def _meshopt_view(self, index: int, spec: dict[str, Any], ext: dict[str, Any], buf: int,
                      offset: int, length: int) -> bytes:
        """Decode an ``EXT_meshopt_compression`` view.

        The compressed bytes are the extension's own ``buffer``/``byteOffset``/``byteLength``;
        the decoder (``extensions/meshopt.py``) returns ``count * byteStride`` bytes, which are
        what the view holds. The view's own buffer is the fallback: when it has data and no
        decoder is installed, that uncompressed copy is used instead.
        """
        what = f"bufferView {index} (EXT_meshopt_compression)"
        src_buf = get_index(ext, "buffer", len(self.buffers), what, required=True)
        assert src_buf is not None
        src_offset = get_int(ext, "byteOffset", what, default=0)
        src_length = get_int(ext, "byteLength", what, minimum=1)
        count = get_int(ext, "count", what, minimum=1)
        stride = get_int(ext, "byteStride", what, minimum=1)
        mode = ext.get("mode")
        if not isinstance(mode, str) or mode not in ("ATTRIBUTES", "TRIANGLES", "INDICES"):
            raise SceneError(f"{what}: unknown mode {brief(mode)}")
        filt = ext.get("filter", "NONE")
        if not isinstance(filt, str) or filt not in ("NONE", "OCTAHEDRAL", "QUATERNION",
                                                     "EXPONENTIAL"):
            raise SceneError(f"{what}: unknown filter {brief(filt)}")
        src = self.buffer(src_buf)
        if src is None:
            raise SceneError(f"{what}: its compressed data is in buffer {src_buf}, which holds "
                             "no data")
        if src_offset + src_length > len(src):
            raise SceneError(f"{what}: the compressed bytes {src_offset}..{src_offset + src_length}"
                             f" reach past the end of buffer {src_buf} ({len(src)} bytes)")
        fallback = self.buffer(buf)
        if count * stride < length:
            raise SceneError(f"{what}: count {count} x byteStride {stride} is less than the "
                             f"view's byteLength {length}")
        try:
            from .extensions.meshopt import decode_buffer_view
        except ImportError as exc:
            if fallback is not None and offset + length <= len(fallback):
                self.warnings.append(f"{what}: no meshopt decoder ({exc}); the uncompressed "
                                     "fallback data is used")
                return fallback[offset:offset + length]
            raise UnsupportedExtension(
                ["EXT_meshopt_compression"],
                f"{what}: the meshopt decoder is not available ({exc}), and the file has no "
                "uncompressed fallback") from None
        try:
            data = decode_buffer_view(src[src_offset:src_offset + src_length], count, stride,
                                      mode, filt)
        except SceneError:
            raise
        except Exception as exc:  # noqa: BLE001 - a decoder fed untrusted bytes may raise anything
            raise SceneError(f"{what}: the compressed data cannot be decoded: "
                             f"{type(exc).__name__}: {exc}") from None
        data = bytes(data)
        if len(data) != count * stride:
            raise SceneError(f"{what}: the decoder returned {len(data)} bytes, expected "
                             f"{count * stride}")
        return data[:length]
