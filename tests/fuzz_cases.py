"""A deterministic generator of malformed scenes, archives, params and HTTP requests.

:func:`generate` returns a few hundred :class:`Case` objects, the same ones for the same seed:
mutations of the real files in the models folder (``../shared/models``) and of documents built
with :mod:`gltf_files`: truncations, wrong lengths and chunk types in GLB headers, flipped bytes,
wrong JSON types at every field of a small file, huge counts, offsets and strides, wrong
component types, NaN and infinity in JSON and in buffers, negative and out-of-range indices,
node cycles, deep nesting, the denial-of-service shapes of issue 12 (deep chains, wide trees,
repeated primitives, huge instance and triangle counts, aliased accessors), URIs that try to
leave the upload (a sentinel file beside it, a localhost port the test listens on), zip bombs and
zips with ``..`` or absolute names, bad params JSON, and malformed HTTP requests.

``tests/test_fuzz.py`` runs them against the library and against a real server. Each case says
what is acceptable (:attr:`Case.expect`): ``"error"`` (refused: a ``ShadowMapError`` from the
library, a 4xx from the service), ``"ok"`` (a render: the controls that show the harness can
tell), or ``"either"`` (refused or rendered, never anything else).
"""

from __future__ import annotations

import base64
import io
import json
import random
import struct
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gltf_files import BIN_CHUNK, JSON_CHUNK, make_glb, split_glb

#: Small renders: every case that renders costs tens of milliseconds on llvmpipe.
SMALL: dict[str, Any] = {"width": 64, "height": 48}
SMALL_JSON = json.dumps(SMALL)
#: Models mutated (small enough to repack hundreds of times).
GLB_MODELS = ("cube.glb", "TwoCubes.glb", "BoxTextured.glb", "BoxMeshopt.glb", "Duck.glb")
#: JSON models and the files they refer to.
GLTF_MODELS = {"TestScene.gltf": ("TestScene.bin",), "BoxDraco.gltf": ("0.bin",),
               "Animation_Skin_01.gltf": ("Animation_Skin_01.bin",)}
#: Values of the wrong type (or range) put where a field was.
WRONG_VALUES: tuple[Any, ...] = (None, True, "x", -1, 2**31, 2**64, 1e308, -0.5, [], {},
                                 [1, 2, 3], {"a": 1}, "\u0000", [None], 0)


@dataclass(frozen=True)
class Outside:
    """What lies outside an upload, for the cases that try to reach it.

    Attributes
    ----------
    sentinel : Path
        A regular file beside the upload (the server's working directory): never to be read.
    port : int
        A localhost port on which the test listens: never to be connected to.
    """

    sentinel: Path
    port: int

    def uris(self) -> list[str]:
        """URIs naming the sentinel or the port, in every way a file might spell them."""
        s = self.sentinel
        return [str(s), f"file://{s}", f"file:{s}", f"../{s.name}",
                f"../../{s.parent.name}/{s.name}",
                f"sub/../../{s.name}", f"%2e%2e/{s.name}", f"..\\{s.name}",
                f"http://127.0.0.1:{self.port}/{s.name}", f"//127.0.0.1:{self.port}/{s.name}",
                f"https://localhost:{self.port}/x.bin", f"ftp://127.0.0.1:{self.port}/x",
                f"C:/{s.name}", f"\\\\127.0.0.1\\share\\{s.name}"]


@dataclass(frozen=True)
class Case:
    """One fuzz input.

    Attributes
    ----------
    name : str
        Unique, says what was done.
    kind : {"glb", "gltf", "zip", "params", "http"}
    scene : bytes or None
        The uploaded scene file; None: params only (the service's demo scene, the library's
        :attr:`base`).
    filename : str
        The name it is uploaded under.
    params : str or None
        The params JSON text.
    expect : {"error", "ok", "either"}
    resources : dict or None
        For the library: the external files a ``.gltf`` (or a zip's ``.gltf``) refers to; None
        for zip cases that only the service can unpack.
    http : dict or None
        For ``kind == "http"``: ``method``, ``headers``, ``content`` and ``query`` of a raw
        request to ``/render``.
    outside : bool
        The case names the sentinel or the port: a refusal must name the URI.
    """

    name: str
    kind: str
    scene: bytes | None
    filename: str = "scene.glb"
    params: str | None = SMALL_JSON
    expect: str = "either"
    resources: dict[str, bytes] | None = None
    http: dict[str, Any] | None = None
    outside: bool = False
    base: str = field(default="cube.glb")


# ------------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------------


def _glb_parts(glb: bytes) -> tuple[int, bytes, bytes]:
    """(json chunk length, json chunk bytes, the rest after the JSON chunk)."""
    n = struct.unpack_from("<I", glb, 12)[0]
    return n, glb[20:20 + n], glb[20 + n:]


def _with_header(glb: bytes, version: int | None = None, length: int | None = None) -> bytes:
    v, n = struct.unpack_from("<II", glb, 4)
    return b"glTF" + struct.pack("<II", v if version is None else version,
                                 n if length is None else length) + glb[12:]


def _with_chunk(glb: bytes, json_len: int | None = None, json_type: int | None = None,
                bin_len: int | None = None, bin_type: int | None = None) -> bytes:
    out = bytearray(glb)
    n, _, rest = _glb_parts(glb)
    if json_len is not None:
        struct.pack_into("<I", out, 12, json_len % 2**32)
    if json_type is not None:
        struct.pack_into("<I", out, 16, json_type)
    if len(rest) >= 8:
        if bin_len is not None:
            struct.pack_into("<I", out, 20 + n, bin_len % 2**32)
        if bin_type is not None:
            struct.pack_into("<I", out, 24 + n, bin_type)
    return bytes(out)


def _raw_glb(json_bytes: bytes, blob: bytes = b"") -> bytes:
    """A GLB around JSON bytes as given (not re-serialised), padded with spaces."""
    js = json_bytes + b" " * (-len(json_bytes) % 4)
    body = struct.pack("<II", len(js), JSON_CHUNK) + js
    if blob:
        blob += b"\0" * (-len(blob) % 4)
        body += struct.pack("<II", len(blob), BIN_CHUNK) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def _paths(doc: Any, limit_list: int = 6) -> list[tuple[Any, ...]]:
    """Every path to a value in ``doc`` (lists sampled to their first ``limit_list`` items),
    walked iteratively."""
    out: list[tuple[Any, ...]] = []
    stack: list[tuple[tuple[Any, ...], Any]] = [((), doc)]
    while stack:
        path, value = stack.pop()
        if path:
            out.append(path)
        if isinstance(value, dict):
            stack.extend((path + (k,), v) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((path + (i,), v) for i, v in enumerate(value[:limit_list]))
    return sorted(out, key=lambda p: [str(x) for x in p])


def _set(doc: Any, path: tuple[Any, ...], value: Any) -> None:
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


def _copy(doc: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(doc))


def _nested(depth: int, open_: str = "[", close: str = "]") -> str:
    return open_ * depth + close * depth


def _zip(entries: dict[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in entries.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=compression)
    return buf.getvalue()


def _zip_bomb(size: int) -> bytes:
    """A zip of one ``.gltf`` and ``size`` zero bytes, deflated (about 1000:1)."""
    buf = io.BytesIO()
    # ZipInfo entries (dated 1980) rather than names (dated now): the same bytes every run.
    info = zipfile.ZipInfo("zeros.bin")
    info.compress_type = zipfile.ZIP_DEFLATED
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(zipfile.ZipInfo("scene.gltf"), json.dumps(_triangle_doc(uri="zeros.bin")))
        with zf.open(info, "w", force_zip64=True) as f:
            chunk = b"\0" * 2**20
            for _ in range(size // len(chunk)):
                f.write(chunk)
    return buf.getvalue()


def _understate(data: bytes, entry: str, size: int) -> bytes:
    """Rewrite the declared uncompressed size of ``entry`` (local and central headers)."""
    out = bytearray(data)
    name = entry.encode()
    for magic, name_len_at, size_at, name_at in ((b"PK\x03\x04", 26, 22, 30),
                                                 (b"PK\x01\x02", 28, 24, 46)):
        pos = 0
        while (pos := out.find(magic, pos)) >= 0:
            n = int.from_bytes(out[pos + name_len_at:pos + name_len_at + 2], "little")
            if out[pos + name_at:pos + name_at + n] == name:
                out[pos + size_at:pos + size_at + 4] = size.to_bytes(4, "little")
            pos += 4
    return bytes(out)


TRI = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)


def _triangle_doc(uri: str | None = None, **extra: Any) -> dict[str, Any]:
    """One triangle; its buffer is ``uri``, else a data: URI."""
    data = uri or "data:application/octet-stream;base64," + base64.b64encode(TRI).decode()
    doc: dict[str, Any] = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(TRI), "uri": data}],
        "bufferViews": [{"buffer": 0, "byteLength": len(TRI)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    doc.update(extra)
    return doc


def _triangle_glb(**extra: Any) -> tuple[dict[str, Any], bytes]:
    doc = _triangle_doc(**extra)
    doc["buffers"] = [{"byteLength": len(TRI)}]
    return doc, TRI


# ------------------------------------------------------------------------------------------------
# Case families
# ------------------------------------------------------------------------------------------------


class _Gen:
    def __init__(self, models: Path, outside: Outside, seed: int) -> None:
        self.models = models
        self.outside = outside
        self.rng = random.Random(seed)
        self.cases: list[Case] = []
        self.glbs = {name: (models / name).read_bytes() for name in GLB_MODELS}
        self.gltfs = {name: ((models / name).read_bytes(),
                             {r: (models / r).read_bytes() for r in res})
                      for name, res in GLTF_MODELS.items()}

    def add(self, name: str, kind: str, scene: bytes | None, **kw: Any) -> None:
        self.cases.append(Case(name, kind, scene, **kw))

    def glb_doc(self, name: str, edit: Callable[[dict[str, Any]], Any], expect: str = "either",
                blob_edit: Callable[[bytearray, dict[str, Any]], Any] | None = None,
                **kw: Any) -> None:
        """A case from model ``name`` with its JSON (and binary chunk) edited."""
        doc, blob = split_glb(self.glbs[name])
        edit(doc)
        b = bytearray(blob)
        if blob_edit is not None:
            blob_edit(b, doc)
        self.add(kw.pop("label"), "glb", make_glb(doc, bytes(b)), expect=expect, **kw)

    # -- controls --------------------------------------------------------------------------

    def controls(self) -> None:
        for name, data in self.glbs.items():
            self.add(f"control {name}", "glb", data, filename=name, expect="ok")
        for name, (data, res) in self.gltfs.items():
            self.add(f"control {name} zip", "zip", _zip({name: data, **res}), filename="s.zip",
                     expect="ok", resources=dict(res), base=name)
        self.add("control embedded .gltf", "gltf", json.dumps(_triangle_doc()).encode(),
                 filename="t.gltf", expect="ok")
        self.add("control params only", "params", None, params=SMALL_JSON, expect="ok")

    # -- the GLB container -----------------------------------------------------------------

    def container(self) -> None:
        # Every header and chunk mutation on two models; truncations and flipped bytes on the
        # others.
        for name in ("TwoCubes.glb", "Duck.glb", "BoxTextured.glb"):
            glb = self.glbs[name]
            for cut in sorted({self.rng.randrange(1, len(glb)) for _ in range(3)}):
                self.add(f"{name} truncated to {cut} bytes", "glb", glb[:cut], expect="error")
            for k in range(2):
                b = bytearray(glb)
                pos = self.rng.randrange(20, len(glb))
                b[pos] = self.rng.randrange(256)
                self.add(f"{name} byte {pos} flipped #{k}", "glb", bytes(b))
        for name in ("cube.glb", "BoxMeshopt.glb"):
            glb = self.glbs[name]
            n, _, rest = _glb_parts(glb)
            cuts = {0, 1, 3, 4, 8, 11, 12, 16, 19, 20, 21, 20 + n // 2, 20 + n, 20 + n + 4,
                    len(glb) - 1}
            cuts |= {self.rng.randrange(1, len(glb)) for _ in range(3)}
            for cut in sorted(cuts):
                self.add(f"{name} truncated to {cut} bytes", "glb", glb[:cut], expect="error")
            for version in (0, 1, 3, 2**32 - 1):
                self.add(f"{name} GLB version {version}", "glb", _with_header(glb, version=version),
                         expect="error")
            for length in (0, 11, 12, 19, 20, len(glb) + 1, 2**32 - 1, 20 + n):
                self.add(f"{name} GLB length {length}", "glb", _with_header(glb, length=length),
                         expect="error")
            for jl in (0, 1, n - 1, n + 1, n + 8, 2**31, 2**32 - 1):
                self.add(f"{name} JSON chunk length {jl}", "glb", _with_chunk(glb, json_len=jl))
            for jt in (BIN_CHUNK, 0, 0x12345678):
                self.add(f"{name} JSON chunk type {jt:#x}", "glb", _with_chunk(glb, json_type=jt),
                         expect="error")
            if len(rest) >= 8:
                bl = struct.unpack_from("<I", rest, 0)[0]
                for new in (0, 1, bl - 4, bl + 4, 2**32 - 1):
                    self.add(f"{name} BIN chunk length {new}", "glb", _with_chunk(glb, bin_len=new))
                for bt in (JSON_CHUNK, 0, 0x12345678):
                    self.add(f"{name} BIN chunk type {bt:#x}", "glb", _with_chunk(glb, bin_type=bt),
                             expect="error")
            self.add(f"{name} trailing garbage", "glb", glb + b"\xff" * 7)
            self.add(f"{name} extra unknown chunk", "glb", _with_header(
                glb + struct.pack("<II", 4, 0x41424344) + b"abcd", length=len(glb) + 12))
            for k in range(3):
                b = bytearray(glb)
                for _ in range(1 + k):
                    pos = self.rng.randrange(20, 20 + n)
                    b[pos] = self.rng.randrange(256)
                self.add(f"{name} JSON bytes flipped #{k}", "glb", bytes(b))
            if len(rest) > 8:
                b = bytearray(glb)
                for _ in range(16):
                    b[self.rng.randrange(28 + n, len(glb))] = self.rng.randrange(256)
                self.add(f"{name} BIN bytes flipped", "glb", bytes(b))
        self.add("magic only", "glb", b"glTF", expect="error")
        self.add("magic and junk", "glb", b"glTF" + bytes(self.rng.randrange(256)
                                                         for _ in range(64)), expect="error")
        self.add("empty file", "glb", b"", expect="error")
        self.add("not a scene", "glb", b"\x89PNG\r\n\x1a\n" + b"\0" * 40, expect="error")

    # -- wrong JSON types at every field ---------------------------------------------------

    def wrong_types(self) -> None:
        # Every path of the smallest model, each with a wrong value (cycling the pool); then
        # a random sample of the paths of the others.
        doc, _ = split_glb(self.glbs["cube.glb"])
        for k, path in enumerate(_paths(doc)):
            value = WRONG_VALUES[k % len(WRONG_VALUES)]
            self.glb_doc("cube.glb", lambda d, p=path, v=value: _set(d, p, v),
                         label=f"cube.glb {'/'.join(map(str, path))} = {value!r}")
        for name in ("TwoCubes.glb", "BoxTextured.glb", "BoxMeshopt.glb"):
            doc, _ = split_glb(self.glbs[name])
            paths = _paths(doc)
            for path in self.rng.sample(paths, min(8, len(paths))):
                value = self.rng.choice(WRONG_VALUES)
                # "sampled": the top-level cases below may draw the same path and value.
                self.glb_doc(name, lambda d, p=path, v=value: _set(d, p, v),
                             label=f"{name} sampled {'/'.join(map(str, path))} = {value!r}")
        for key in ("asset", "scene", "scenes", "nodes", "meshes", "accessors", "bufferViews",
                    "buffers", "materials", "textures", "images", "samplers", "cameras", "skins",
                    "animations", "extensions", "extensionsUsed", "extensionsRequired",
                    "extras"):
            for value in ("x", {}):
                expect = "error" if key in ("asset", "nodes", "meshes", "accessors",
                                            "bufferViews", "buffers") and value != {} else "either"
                self.glb_doc("BoxTextured.glb", lambda d, k=key, v=value: d.__setitem__(k, v),
                             label=f"BoxTextured.glb {key} = {value!r}", expect=expect)

    # -- sizes, types, indices, numbers ----------------------------------------------------

    def numbers(self) -> None:
        def acc(key: str, value: Any, which: int = -1) -> Callable[[dict[str, Any]], None]:
            def edit(d: dict[str, Any]) -> None:
                prim = d["meshes"][0]["primitives"][0]
                index = prim["attributes"]["POSITION"] if which < 0 else prim.get("indices", 0)
                d["accessors"][index][key] = value
            return edit

        for name in ("cube.glb",):
            for value in (0, -1, 2**31 - 1, 10**12, 2**64, 7):
                self.glb_doc(name, acc("count", value), label=f"{name} POSITION count {value}")
                self.glb_doc(name, acc("count", value, 0), label=f"{name} indices count {value}")
            for value in (2**40, -4, 3, 2**31 + 1):
                self.glb_doc(name, acc("byteOffset", value), label=f"{name} byteOffset {value}")
            for value in (5124, 5130, 0, 5121, 5126.5, "5126"):
                self.glb_doc(name, acc("componentType", value),
                             label=f"{name} POSITION componentType {value!r}")
                self.glb_doc(name, acc("componentType", value, 0),
                             label=f"{name} indices componentType {value!r}")
            for value in ("VEC2", "SCALAR", "MAT4", "VEC5", "vec3"):
                self.glb_doc(name, acc("type", value), label=f"{name} POSITION type {value}",
                             expect="error")
            for key, value in (("byteStride", 1), ("byteStride", 3), ("byteStride", 2**31),
                               ("byteStride", 0), ("byteLength", 2**40), ("byteLength", 0),
                               ("byteOffset", 2**40), ("buffer", 9), ("buffer", -1)):
                self.glb_doc(name, lambda d, k=key, v=value: [
                    bv.__setitem__(k, v) for bv in d["bufferViews"]],
                    label=f"{name} every bufferView {key} = {value}")
            for value in (2**40, 0, 1, -1):
                self.glb_doc(name, lambda d, v=value: d["buffers"][0].__setitem__("byteLength", v),
                             label=f"{name} buffer byteLength {value}")
            for key, value in (("mesh", 99), ("mesh", -1), ("children", [99]),
                               ("children", [-1]), ("camera", 5), ("skin", 3),
                               ("matrix", [float("nan")] * 16), ("translation", [1e400, 0, 0]),
                               ("rotation", [0, 0, 0, 0]), ("scale", [0, 0, 0]),
                               ("matrix", [0] * 16), ("weights", ["x"])):
                self.glb_doc(name, lambda d, k=key, v=value: [n.__setitem__(k, v)
                                                              for n in d["nodes"]],
                             label=f"{name} every node {key} = {value!r}")
            for value in (5, -1, "0", None):
                self.glb_doc(name, lambda d, v=value: d.__setitem__("scene", v),
                             label=f"{name} scene = {value!r}")
            self.glb_doc(name, lambda d: d["scenes"][0].__setitem__("nodes", [0, 0, 0]),
                         label=f"{name} scene lists a node 3 times")
            self.glb_doc(name, lambda d: d["meshes"][0]["primitives"][0].__setitem__("material",
                                                                                     42),
                         label=f"{name} material 42")
            for mode in (0, 1, 3, 5, 6, 7, -1, "4"):
                self.glb_doc(name, lambda d, m=mode: d["meshes"][0]["primitives"][0].__setitem__(
                    "mode", m), label=f"{name} mode {mode!r}")

            # Data: NaN and infinite positions, out-of-range and restart indices.
            def floats(b: bytearray, d: dict[str, Any], value: float) -> None:
                prim = d["meshes"][0]["primitives"][0]
                a = d["accessors"][prim["attributes"]["POSITION"]]
                v = d["bufferViews"][a["bufferView"]]
                struct.pack_into("<f", b, v.get("byteOffset", 0) + a.get("byteOffset", 0), value)

            def index(b: bytearray, d: dict[str, Any], value: int) -> None:
                prim = d["meshes"][0]["primitives"][0]
                a = d["accessors"][prim["indices"]]
                v = d["bufferViews"][a["bufferView"]]
                fmt = {5121: "<B", 5123: "<H", 5125: "<I"}[a["componentType"]]
                struct.pack_into(fmt, b, v.get("byteOffset", 0) + a.get("byteOffset", 0),
                                 value % (256 ** struct.calcsize(fmt)))

            for value in (float("nan"), float("inf"), -float("inf"), 3e38):
                self.glb_doc(name, lambda d: None, label=f"{name} a position is {value}",
                             blob_edit=lambda b, d, v=value: floats(b, d, v))
            for value in (-1, 2**16 - 1, 2**32 - 1, 9999):
                self.glb_doc(name, lambda d: None, label=f"{name} an index is {value}",
                             blob_edit=lambda b, d, v=value: index(b, d, v))

    # -- graphs, nesting, JSON text --------------------------------------------------------

    def graphs(self) -> None:
        name = "TwoCubes.glb"

        def cycle(d: dict[str, Any]) -> None:
            n = len(d["nodes"])
            d["nodes"] += [{"children": [n + 1]}, {"children": [n], "mesh": 0}]

        self.glb_doc(name, cycle, label="node cycle of two", expect="error")
        self.glb_doc(name, lambda d: d["nodes"][0].__setitem__("children", [0]),
                     label="node is its own child", expect="error")
        self.glb_doc(name, lambda d: d["nodes"].append({"children": [0, 1]}),
                     label="two parents")
        self.glb_doc(name, lambda d: d["nodes"].append({"children": [0] * 100_000}),
                     label="100,000 child links", expect="error")
        self.glb_doc(name, lambda d: d["scenes"][0].__setitem__("nodes", [0] * 100_000),
                     label="scene lists 100,000 nodes", expect="error")

    def nesting(self) -> None:
        deep = _nested(100_000)
        # In the GLB JSON chunk, in extras, in a .gltf, as the whole document, in params.
        doc, blob = split_glb(self.glbs["cube.glb"])
        js = json.dumps(doc)
        self.add("GLB: 100k-deep array in extras", "glb",
                 _raw_glb(js[:-1].encode() + b', "extras": ' + deep.encode() + b"}", blob),
                 expect="error")
        self.add("GLB: 100k-deep objects in node extras", "glb", _raw_glb(
            js.replace('"name": "world"', '"extras": ' + '{"a":' * 100_000 + "0"
                       + "}" * 100_000, 1).encode(), blob), expect="error")
        self.add("GLB: the document is 100k-deep", "glb", _raw_glb(deep.encode()),
                 expect="error")
        text = json.dumps(_triangle_doc())
        self.add(".gltf: 100k-deep extras", "gltf",
                 (text[:-1] + ', "extras": ' + deep + "}").encode(), filename="t.gltf",
                 expect="error")
        self.add(".gltf: 100k-deep asset.extras", "gltf", text.replace(
            '"version": "2.0"', '"version": "2.0", "extras": ' + deep).encode(),
            filename="t.gltf", expect="error")
        # As deep as Python's parser allows: parsed, and nothing after it may recurse on it.
        for depth in (200, 900):
            self.add(f".gltf: {depth}-deep extras (parses)", "gltf",
                     (text[:-1] + ', "extras": ' + _nested(depth) + "}").encode(),
                     filename="t.gltf")
            self.add(f".gltf: {depth}-deep node extras (parses)", "gltf", json.dumps(
                _triangle_doc(nodes=[{"mesh": 0, "extras": {}}])).replace(
                '"extras": {}', '"extras": ' + _nested(depth, '{"k":', "}").replace(
                    '{"k":}', '{"k":0}')).encode(), filename="t.gltf")

    def json_text(self) -> None:
        text = json.dumps(_triangle_doc())
        for label, bad in (
                ("NaN literal", text.replace('"count": 3', '"count": NaN')),
                ("Infinity literal", text.replace('"count": 3', '"count": Infinity')),
                ("1e400", text.replace('"count": 3', '"count": 1e400')),
                ("5000-digit integer", text.replace('"count": 3', '"count": 1' + "0" * 5000)),
                ("lone surrogate in a name", text.replace('{"mesh": 0}',
                                                          '{"mesh": 0, "name": "\\ud800"}')),
                ("surrogate pair in a name", text.replace('{"mesh": 0}',
                                                          '{"mesh": 0, "name": "\\ud83d\\ude00"}')),
                ("trailing comma", text[:-1] + ",}"),
                ("two documents", text + text),
                ("truncated", text[: len(text) // 2]),
                ("BOM", "\ufeff" + text),
                ("megabyte name", text.replace('{"mesh": 0}',
                                               '{"mesh": 0, "name": "' + "n" * 2**20 + '"}')),
                ("a JSON array", "[" + text + "]"),
                ("a JSON string", json.dumps(text)),
                ("null", "null")):
            self.add(f".gltf: {label}", "gltf", bad.encode("utf-8", "surrogatepass"),
                     filename="t.gltf")
        self.add(".gltf: invalid UTF-8", "gltf", text.encode()[:-2] + b"\xff\xfe}",
                 filename="t.gltf", expect="error")
        self.add(".gltf: UTF-16", "gltf", text.encode("utf-16"), filename="t.gltf",
                 expect="error")

    # -- the denial-of-service shapes of issue 12 ------------------------------------------

    def dos(self) -> None:
        doc, blob = _triangle_glb()
        chain = _copy(doc)
        chain["nodes"] = [{"children": [i + 1]} for i in range(99_999)] + [{"mesh": 0}]
        chain["scenes"] = [{"nodes": [0]}]
        self.add("DoS: 100,000-deep node chain", "glb", make_glb(chain, blob), expect="error")
        deep = _copy(doc)
        deep["nodes"] = [{"children": [i + 1]} for i in range(1999)] + [{"mesh": 0}]
        deep["scenes"] = [{"nodes": [0]}]
        self.add("DoS: 2,000-deep node chain", "glb", make_glb(deep, blob), expect="error")
        tree = _copy(doc)
        n = 65_535
        tree["nodes"] = [{"mesh": 0, "children": [c for c in (2 * i + 1, 2 * i + 2) if c < n]}
                         for i in range(n)]
        tree["scenes"] = [{"nodes": [0]}]
        self.add("DoS: 65,535-node tree", "glb", make_glb(tree, blob), expect="error")
        prims = _copy(doc)
        prims["meshes"][0]["primitives"] *= 20_000
        self.add("DoS: one primitive listed 20,000 times", "glb", make_glb(prims, blob),
                 expect="error")
        tris = _copy(doc)
        tris["accessors"][0]["count"] = 30_000_000
        self.add("DoS: 10 M triangles declared", "glb", make_glb(tris, blob), expect="error")
        inst = _copy(doc)
        inst["accessors"].append({"componentType": 5126, "count": 10**9, "type": "VEC3"})
        inst["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
        inst["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {
            "attributes": {"TRANSLATION": 1}}}
        self.add("DoS: 10^9 instances", "glb", make_glb(inst, blob), expect="error")
        alias = _copy(doc)
        big = b"\0" * (2**20 * 3)  # 1 M zero vertices
        alias["buffers"] = [{"byteLength": len(big)}]
        alias["bufferViews"] = [{"buffer": 0, "byteLength": len(big)}]
        alias["accessors"] = [{"bufferView": 0, "componentType": 5126, "count": 2**18,
                               "type": "VEC3"} for _ in range(600)]
        alias["accessors"].append({"bufferView": 0, "componentType": 5125, "count": 3,
                                   "type": "SCALAR"})
        alias["meshes"] = [{"primitives": [{"attributes": {"POSITION": i}, "indices": 600}
                                           for i in range(600)]}]
        self.add("DoS: 600 accessors over one 3 MiB view", "glb", make_glb(alias, big),
                 expect="error")
        skin = _copy(doc)
        skin["skins"] = [{"joints": [0] * 40_000}]
        skin["nodes"][0]["skin"] = 0
        self.add("DoS: a skin listing 40,000 joints", "glb", make_glb(skin, blob),
                 expect="error")
        sparse = _copy(doc)
        sparse["accessors"][0] = {"componentType": 5126, "count": 2**27, "type": "VEC3",
                                  "sparse": {"count": 1, "indices": {"bufferView": 0,
                                                                     "componentType": 5125},
                                             "values": {"bufferView": 0}}}
        self.add("DoS: a 2^27-vertex sparse accessor with no data", "glb",
                 make_glb(sparse, blob), expect="error")

    # -- URIs that try to leave the upload -------------------------------------------------

    def uris(self) -> None:
        for uri in self.outside.uris():
            doc = _triangle_doc(uri=uri)
            self.add(f".gltf: buffer uri {uri}", "gltf", json.dumps(doc).encode(),
                     filename="t.gltf", expect="error", outside=True, resources={})
            tex = _triangle_doc()
            tex["images"] = [{"uri": uri}]
            tex["textures"] = [{"source": 0}]
            tex["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
            tex["meshes"][0]["primitives"][0]["material"] = 0
            self.add(f".gltf: image uri {uri}", "gltf", json.dumps(tex).encode(),
                     filename="t.gltf", expect="error", outside=True, resources={})
        for uri in ("data:", "data:;base64,@@@@", "data:application/octet-stream;base64,AAAA",
                    "data:,%ZZ", 7, None, ["a"], "", "nothere.bin", "sub/nothere.bin"):
            doc = _triangle_doc()
            doc["buffers"][0]["uri"] = uri
            self.add(f".gltf: buffer uri {uri!r}", "gltf", json.dumps(doc).encode(),
                     filename="t.gltf", expect="error", resources={})

    # -- zip archives ----------------------------------------------------------------------

    def zips(self) -> None:
        gltf, res = self.gltfs["TestScene.gltf"]
        binary = res["TestScene.bin"]
        good = {"TestScene.gltf": gltf, "TestScene.bin": binary}
        moved = json.loads(gltf)
        moved["buffers"][0]["uri"] = "../TestScene.bin"
        for label, entries in (
                ("entry named ../", {"TestScene.gltf": gltf, "../TestScene.bin": binary}),
                ("absolute entry name", {"TestScene.gltf": gltf, "/tmp/TestScene.bin": binary}),
                ("entry sub/../../", {"TestScene.gltf": gltf, "sub/../../TestScene.bin": binary}),
                ("backslash entry ..\\", {"TestScene.gltf": gltf, "..\\TestScene.bin": binary}),
                ("drive-letter entry", {"TestScene.gltf": gltf, "C:/TestScene.bin": binary}),
                ("gltf refers to ../", {"TestScene.gltf": json.dumps(moved).encode(),
                                        "TestScene.bin": binary}),
                ("no scene file", {"TestScene.bin": binary}),
                ("two scene files", {**good, "b.gltf": gltf}),
                ("missing buffer", {"TestScene.gltf": gltf}),
                ("empty archive", {}),
                ("scene in a folder, buffer outside", {"a/TestScene.gltf": gltf,
                                                       "TestScene.bin": binary}),
        ):
            names = {k: v for k, v in entries.items() if not k.endswith(".gltf")}
            self.add(f"zip: {label}", "zip", _zip(entries), filename="s.zip", expect="error",
                     resources=names if "entry" in label else None)
        self.add("zip: stored, not deflated", "zip", _zip(good, zipfile.ZIP_STORED),
                 filename="s.zip", expect="ok", resources={"TestScene.bin": binary})
        self.add("zip: nested zip", "zip", _zip({"inner.zip": _zip(good)}), filename="s.zip",
                 expect="error")
        self.add("zip: bomb (64 MiB of zeros)", "zip", _zip_bomb(64 * 2**20), filename="s.zip",
                 expect="error")
        small = _zip({"scene.gltf": json.dumps(_triangle_doc(uri="zeros.bin")).encode(),
                      "zeros.bin": b"\0" * (32 * 2**20)})
        self.add("zip: sizes understated", "zip", _understate(small, "zeros.bin", 36),
                 filename="s.zip", expect="error")
        self.add("zip: 2,000 entries", "zip", _zip({f"f{i}.bin": b"" for i in range(2000)}
                                                   | {"t.gltf": json.dumps(_triangle_doc())
                                                      .encode()}), filename="s.zip",
                 expect="error")
        data = _zip(good)
        self.add("zip: truncated", "zip", data[: len(data) // 2], filename="s.zip",
                 expect="error")
        # The central directory's CRC and flags are the ones zipfile reads.
        b = bytearray(data)
        pos = b.find(b"PK\x01\x02")
        b[pos + 16:pos + 20] = b"\0\0\0\0"
        self.add("zip: bad CRC", "zip", bytes(b), filename="s.zip", expect="error")
        b = bytearray(data)
        b[pos + 8] |= 1
        self.add("zip: encrypted flag", "zip", bytes(b), filename="s.zip", expect="error")
        self.add("zip: not a zip", "zip", b"this is not a zip" * 10, filename="s.zip",
                 expect="error")
        info = zipfile.ZipInfo("TestScene.bin")
        info.external_attr = (0o120777 << 16)  # a symlink entry
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as zf:
            zf.writestr(zipfile.ZipInfo("TestScene.gltf"), gltf)
            zf.writestr(info, str(self.outside.sentinel))
        self.add("zip: symlink entry to the sentinel", "zip", buf.getvalue(), filename="s.zip",
                 expect="error", outside=True)

    # -- params ----------------------------------------------------------------------------

    def params(self) -> None:
        for label, text in (
                ("empty", ""), ("not JSON", "{"), ("array", "[]"), ("null", "null"),
                ("number", "1"), ("string", '"x"'), ("trailing brace", "{}}"),
                ("NaN", '{"width": NaN}'), ("1e400", '{"width": 1e400}'),
                ("5000 digits", '{"width": 1' + "0" * 5000 + "}"),
                ("100k-deep arrays", _nested(100_000)),
                ("100k-deep camera", '{"camera":' * 100_000 + "{}" + "}" * 100_000),
                ("lone surrogate", '{"outputs": ["\\ud800"]}'),
                ("unknown field", '{"widht": 10}'),
                ("a megabyte of spaces", " " * 2**20 + "{}")):
            self.add(f"params: {label}", "params", None, params=text,
                     expect="either" if label in ("empty", "a megabyte of spaces") else "error")
        fields: dict[str, tuple[Any, ...]] = {
            "width": (0, -1, 16385, 10**20, "64", 1.5, None),
            "height": (0, 2**31, [48]),
            "camera": ("front", [], {"pose": [[1] * 4] * 4}, {"eye": [0, 0, 0]},
                       {"eye": [1, 1, 1], "target": [1, 1, 1]}, {"yfov_deg": 0},
                       {"yfov_deg": 180}, {"znear": 2, "zfar": 1}, {"pose": [[0] * 4] * 4},
                       {"eye": [1e308, 0, 0], "target": [0, 0, 0]}, {"ymag": 1},
                       {"projection": "fisheye"}, {"projection": "orthographic", "ymag": 0},
                       {"projection": "orthographic", "ymag": 1e-9},
                       {"projection": "orthographic", "ymag": 1e20},
                       {"projection": "orthographic", "eye": [0, 1e-12, 0],
                        "target": [0, 0, 0]}),
            "lights": ("sun", [{}] * 9, [{"type": "laser"}], [{"direction": [0, 0, 0]}],
                       [{"type": "spot", "position": [0, 1, 0]}],
                       [{"type": "point"}], [{"color": [-1, 0, 0]}], [{"intensity": -1}],
                       [{"type": "spot", "position": [0, 2, 0], "target": [0, 0, 0],
                         "inner_cone_deg": 40, "outer_cone_deg": 30}], [None]),
            "shadows": ({"map_size": 3}, {"map_size": 17}, {"map_size": 2**40},
                        {"map_size": 32768}, {"pcf_kernel": 2}, {"pcf_kernel": 99},
                        {"encoding": "r16"}, {"filter": "soft"}, {"bias": {"constant": -1}},
                        {"max_map_size": 8}, "none"),
            "outputs": ([], ["nope"], "color", [None]),
            "background": ([2, 0, 0, 1], [0, 0, 0]),
            "ambient": ([-1, 0, 0],),
            "reference": ("yes",),
        }
        # Pydantic's lax mode takes "64" for 64 and "yes" for true: those may render.
        lax = ("64", "yes")
        for key, values in fields.items():
            for value in values:
                expect = "either" if key in ("camera", "lights") or value in lax else "error"
                self.add(f"params: {key} = {value!r}"[:120], "params", None,
                         params=json.dumps({**SMALL, key: value}), expect=expect)
        point = [{"type": "point", "position": [2 * i - 7, 3, 1]} for i in range(8)]
        self.add("params DoS: 8 point lights with 4096^2 cube maps", "params", None,
                 params=json.dumps({**SMALL, "lights": point, "shadows": {"map_size": 4096}}),
                 expect="error")
        self.add("params DoS: 4096^2 with 8 lights and every output", "params", None,
                 params=json.dumps({"width": 4096, "height": 4096, "lights": point,
                                    "outputs": ["color", "visibility", "depth", "light_depth"],
                                    "shadows": {"map_size": 4096}}), expect="error")

    # -- malformed HTTP requests (service only) --------------------------------------------

    def http(self) -> None:
        glb = self.glbs["cube.glb"]
        for label, req, expect in (
                ("unknown content type", {"headers": {"Content-Type": "text/x-nothing"},
                                          "content": b"hello"}, "error"),
                ("multipart without boundary", {"headers": {"Content-Type":
                                                            "multipart/form-data"},
                                                "content": b"--x\r\n\r\n"}, "error"),
                ("multipart with the wrong boundary",
                 {"headers": {"Content-Type": "multipart/form-data; boundary=abc"},
                  "content": b"--xyz\r\nContent-Disposition: form-data; name=\"scene\"\r\n\r\n"
                             b"data\r\n--xyz--\r\n"}, "either"),
                ("multipart garbage", {"headers": {"Content-Type":
                                                   "multipart/form-data; boundary=b"},
                                       "content": bytes(range(256)) * 4}, "either"),
                ("glb body declared as JSON params", {"headers": {"Content-Type":
                                                                  "application/json"},
                                                      "content": glb}, "error"),
                ("gltf media type with a GLB", {"headers": {"Content-Type": "model/gltf+json"},
                                                "content": glb}, "either"),
                ("glb media type, empty body", {"headers": {"Content-Type":
                                                            "model/gltf-binary"},
                                                "content": b""}, "either"),
                ("params in the query, not JSON", {"headers": {"Content-Type":
                                                               "model/gltf-binary"},
                                                   "content": glb, "query": {"params": "{"}},
                 "error"),
                ("params in query and body", {"headers": {"Content-Type": "application/json"},
                                              "content": SMALL_JSON.encode(),
                                              "query": {"params": SMALL_JSON}}, "error"),
                ("GET /render", {"method": "GET"}, "error"),
                ("PUT /render", {"method": "PUT", "content": glb}, "error"),
                ("Accept: nothing we make", {"headers": {"Accept": "application/x-nothing",
                                                         "Content-Type": "model/gltf-binary"},
                                             "content": glb}, "either"),
        ):
            self.add(f"http: {label}", "http", None, http=req, params=None, expect=expect)
        # Raw bytes on a socket, for what an HTTP client library will not send.
        head = b"POST /render HTTP/1.1\r\nHost: x\r\nContent-Type: model/gltf-binary\r\n"
        for label, raw in (
                ("Content-Length not a number", head + b"Content-Length: oops\r\n\r\n" + glb),
                ("negative Content-Length", head + b"Content-Length: -5\r\n\r\n" + glb),
                ("Content-Length over the body", head + b"Content-Length: 99999\r\n\r\n" + glb),
                ("Content-Length over the limit", head + b"Content-Length: 99999999999\r\n\r\n"),
                ("chunked garbage", head + b"Transfer-Encoding: chunked\r\n\r\nzz\r\n"),
                ("two Content-Lengths", head + b"Content-Length: 4\r\nContent-Length: 5\r\n"
                                              b"\r\nglTF"),
                ("not HTTP", b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + b"\0" * 64)):
            self.add(f"http raw: {label}", "http", None, http={"raw": raw}, params=None)
        for label, parts in (
                ("unknown form part", [("nope", ("a.bin", b"x"))]),
                ("scene part twice", [("scene", ("a.glb", glb)), ("scene", ("b.glb", glb))]),
                ("params part twice", [("params", (None, SMALL_JSON.encode())),
                                       ("params", (None, SMALL_JSON.encode()))]),
                ("scene with an unknown suffix", [("scene", ("a.obj", glb))]),
                ("scene without a file name", [("scene", (None, glb))]),
                ("params part is a file", [("scene", ("a.glb", glb)),
                                           ("params", ("p.json", b"{"))])):
            self.add(f"http: {label}", "http", None, http={"files": parts}, params=None)

    def run(self) -> list[Case]:
        for family in (self.controls, self.container, self.wrong_types, self.numbers,
                       self.graphs, self.nesting, self.json_text, self.dos, self.uris,
                       self.zips, self.params, self.http):
            family()
        names = [c.name for c in self.cases]
        assert len(names) == len(set(names)), "fuzz case names must be unique"
        return self.cases


def generate(models: Path, outside: Outside, seed: int = 12) -> list[Case]:
    """Every fuzz case, in a fixed order; the same list for the same ``seed`` and models.

    Parameters
    ----------
    models : Path
        The models folder (``conftest.models_dir()``).
    outside : Outside
        The sentinel file and the listening port the URI cases name.
    seed : int
    """
    return _Gen(models, outside, seed).run()
