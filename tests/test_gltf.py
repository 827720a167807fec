"""The project's glTF reader (``shadowmap.renderer.gltf``): container, accessors, primitives,
materials, nodes, instancing, skins, morph targets, extensions, limits, and the model corpus.

Most tests build their own small file with :func:`gltf_files.make_glb`; the corpus tests load
every model in the models folder and compare with trimesh's loader where trimesh is right (no
skins, Draco, meshopt or instancing). Only the last test needs GL.
"""

from __future__ import annotations

import io
import json
import math
import struct
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from conftest import models_dir
from gltf_files import make_glb, split_glb, transcode_textures
from shadowmap.renderer import (
    LimitError,
    Limits,
    RenderParams,
    SceneError,
    UnsupportedExtension,
    load_scene,
)
from shadowmap.renderer.gltf.extensions import IGNORED, SUPPORTED
from shadowmap.renderer.scene import MappingResolver, Sampler, Scene

FLOAT, UBYTE, BYTE, USHORT, SHORT, UINT = 5126, 5121, 5120, 5123, 5122, 5125
DOUBLE = 5130  # KHR_accessor_float64
DTYPES = {FLOAT: "<f4", UBYTE: "<u1", BYTE: "<i1", USHORT: "<u2", SHORT: "<i2", UINT: "<u4",
          DOUBLE: "<f8"}
KINDS = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)


class Gltf:
    """A glTF document under construction, with buffer 0 as the GLB's binary chunk."""

    def __init__(self) -> None:
        self.doc: dict = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 0}],
                          "bufferViews": [], "accessors": [], "meshes": [], "nodes": [],
                          "scenes": [{"nodes": []}], "scene": 0}
        self.blob = bytearray()

    def view(self, data: bytes, stride: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        v = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        self.blob += data
        self.doc["bufferViews"].append(v)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, values=None, ctype: int = FLOAT, kind: str | None = None,
                 view: int | None = None, **fields) -> int:
        acc: dict = {"componentType": ctype}
        if values is not None:
            arr = np.asarray(values, DTYPES[ctype])
            n = arr.shape[1] if arr.ndim == 2 else (16 if arr.ndim == 3 else 1)
            if view is None:
                data = arr.transpose(0, 2, 1).tobytes() if arr.ndim == 3 else arr.tobytes()
                view = self.view(data)
            acc.update(count=len(arr), type=kind or KINDS[n])
        elif kind:
            acc["type"] = kind
        if view is not None:
            acc["bufferView"] = view
        acc.update(fields)
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, *primitives: dict, **fields) -> int:
        self.doc["meshes"].append({"primitives": list(primitives), **fields})
        return len(self.doc["meshes"]) - 1

    def node(self, root: bool = True, **fields) -> int:
        self.doc["nodes"].append(fields)
        i = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(i)
        return i

    def triangle(self, positions=TRI, **prim) -> int:
        """A mesh of one primitive with POSITION ``positions`` (and ``prim`` fields)."""
        attrs = prim.pop("attributes", {})
        return self.mesh({"attributes": {"POSITION": self.accessor(positions), **attrs}, **prim})

    def glb(self) -> bytes:
        self.doc["buffers"][0]["byteLength"] = max(len(self.blob), 1)
        return make_glb(self.doc, bytes(self.blob) or b"\0\0\0\0")

    def load(self, **kw) -> Scene:
        return load_scene(self.glb(), **kw)


def one_triangle() -> Gltf:
    g = Gltf()
    g.node(mesh=g.triangle())
    return g


def png(rgba: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(rgba, np.uint8), "RGBA").save(buf, "PNG")
    return buf.getvalue()


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header declares ``width x height`` pixels (its pixel data is a stub)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0"))
            + chunk(b"IEND", b""))


# ------------------------------------------------------------------------------------------------
# Container
# ------------------------------------------------------------------------------------------------


def test_file_type_is_decided_by_content(tmp_path):
    g = one_triangle()
    g.doc["buffers"][0] = {"byteLength": 36, "uri": "data:application/octet-stream;base64,"
                           + __import__("base64").b64encode(TRI.tobytes()).decode()}
    text = json.dumps(g.doc).encode()
    named_glb = tmp_path / "scene.glb"
    named_glb.write_bytes(text)
    assert load_scene(named_glb).triangle_count == 1
    assert load_scene(text, file_type="glb").triangle_count == 1
    named_gltf = tmp_path / "binary.gltf"
    named_gltf.write_bytes(one_triangle().glb())
    assert load_scene(named_gltf).triangle_count == 1


def _glb_with(header_len: int | None = None, version: int = 2, chunk_type: int = 0x4E4F534A,
              chunk_len: int | None = None, tail: bytes = b"") -> bytes:
    js = json.dumps({"asset": {"version": "2.0"}}).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js) if chunk_len is None else chunk_len, chunk_type) + js + tail
    total = 12 + len(body)
    return b"glTF" + struct.pack("<II", version, total if header_len is None else header_len) + body


@pytest.mark.parametrize("data, message", [
    (b"glTF\x02\x00", "truncated binary glTF"),
    (_glb_with(version=1), "version 1 is not supported"),
    (_glb_with(header_len=10_000), "truncated binary glTF: header says 10000"),
    (_glb_with(header_len=16), "corrupt binary glTF"),
    (_glb_with(chunk_type=0x004E4942), "first chunk is not a complete JSON chunk"),
    (_glb_with(chunk_len=4000), "first chunk is not a complete JSON chunk"),
    (_glb_with(tail=struct.pack("<II", 400, 0x004E4942) + b"\0" * 8), "past the file's end"),
])
def test_glb_header_and_chunks_are_validated(data, message):
    with pytest.raises(SceneError, match=message):
        load_scene(data)


def test_unknown_glb_chunks_are_skipped():
    g = one_triangle()
    doc, blob = split_glb(g.glb())
    glb = make_glb(doc, blob)
    extra = struct.pack("<II", 4, 0x12345678) + b"abcd"
    body = glb[12:] + extra
    glb = b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body
    assert load_scene(glb).triangle_count == 1


@pytest.mark.parametrize("data, message", [
    (b"{not json", "JSON cannot be parsed"),
    (b"[1, 2]", "not an object"),
    (b'{"asset": {"version": "2.0"}, "x": ' + b"[" * 200_000 + b"]" * 200_000 + b"}",
     "nests too deep"),
    (b"\xff\xfe\x00", "JSON cannot be parsed"),
])
def test_json_errors_are_scene_errors(data, message):
    with pytest.raises(SceneError, match=message):
        load_scene(data)


@pytest.mark.parametrize("asset, message", [
    ("2.0", "'asset' is not an object"),
    ({}, "asset.version"),
    ({"version": 2}, "asset.version"),
    ({"version": "3.0"}, "asset.version"),
    ({"version": "1.0"}, "asset.version"),
    ({"version": "2.0", "minVersion": "2.1"}, "asset.minVersion"),
    ({"version": "2.0", "minVersion": "two"}, "asset.minVersion"),
])
def test_asset_is_checked(asset, message):
    g = one_triangle()
    g.doc["asset"] = asset
    with pytest.raises(SceneError, match=message):
        g.load()


@pytest.mark.parametrize("asset, field", [
    ({"version": "3.0"}, "asset.version"),
    ({"version": "1.0"}, "asset.version"),
    ({"version": "2.0", "minVersion": "2.1"}, "asset.minVersion"),
])
def test_unsupported_versions_name_the_field(asset, field):
    from shadowmap.renderer import UnsupportedVersion

    g = one_triangle()
    g.doc["asset"] = asset
    with pytest.raises(UnsupportedVersion) as info:
        g.load()
    assert info.value.field == field


def test_newer_minor_versions_load():
    g = one_triangle()
    g.doc["asset"] = {"version": "2.7", "minVersion": "2.0"}
    assert g.load().triangle_count == 1


# ------------------------------------------------------------------------------------------------
# Accessors
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("ctype, normalized, raw, expected", [
    (UBYTE, True, [[0, 0, 0], [255, 0, 0], [0, 255, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]]),
    (BYTE, True, [[-128, 0, 0], [127, 0, 0], [0, 127, 0]], [[-1, 0, 0], [1, 0, 0], [0, 1, 0]]),
    (USHORT, True, [[0, 0, 0], [65535, 0, 0], [0, 65535, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]]),
    (SHORT, True, [[-32768, 0, 0], [32767, 0, 0], [0, 32767, 0]],
     [[-1, 0, 0], [1, 0, 0], [0, 1, 0]]),
    (USHORT, False, [[0, 0, 0], [1000, 0, 0], [0, 2, 0]], [[0, 0, 0], [1000, 0, 0], [0, 2, 0]]),
    (BYTE, False, [[-5, 0, 0], [7, 0, 0], [0, 3, 0]], [[-5, 0, 0], [7, 0, 0], [0, 3, 0]]),
])
def test_quantized_positions(ctype, normalized, raw, expected):
    """KHR_mesh_quantization: 8/16-bit positions, each element padded to 4 bytes."""
    g = Gltf()
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    arr = np.asarray(raw, DTYPES[ctype])
    itemsize = arr.dtype.itemsize
    stride = 4 * math.ceil(3 * itemsize / 4)
    padded = np.zeros((3, stride // itemsize), arr.dtype)
    padded[:, :3] = arr
    view = g.view(padded.tobytes(), stride=stride)
    pos = g.accessor(ctype=ctype, kind="VEC3", view=view, count=3,
                     **({"normalized": True} if normalized else {}))
    g.node(mesh=g.mesh({"attributes": {"POSITION": pos}}))
    scene = g.load()
    np.testing.assert_allclose(scene.primitives[0].positions, expected, atol=1e-6)
    assert not scene.warnings


def test_quantized_normals_and_texcoords():
    g = Gltf()
    nrm = np.array([[0, 0, 127, 0]] * 3, np.int8)  # padded VEC3 bytes, normalized
    n_view = g.view(nrm.tobytes(), stride=4)
    n_acc = g.accessor(ctype=BYTE, kind="VEC3", view=n_view, count=3, normalized=True)
    uv = g.accessor(np.array([[0, 0], [65535, 0], [0, 65535]]), ctype=USHORT, normalized=True)
    g.doc["images"] = [{"bufferView": g.view(png(np.full((2, 2, 4), 255))),
                        "mimeType": "image/png"}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.node(mesh=g.triangle(attributes={"NORMAL": n_acc, "TEXCOORD_0": uv}, material=0))
    prim = g.load().primitives[0]
    np.testing.assert_allclose(prim.normals, [[0, 0, 1]] * 3, atol=1e-6)
    np.testing.assert_allclose(prim.uv, [[0, 1], [1, 1], [0, 0]], atol=1e-6)


def test_interleaved_view_with_view_and_accessor_offsets():
    g = Gltf()
    g.view(b"\xee" * 8)  # something before, so the view's byteOffset is not 0
    uv = np.array([[0.25, 0.5], [0.75, 0.5], [0.25, 1.0]], np.float32)
    inter = np.concatenate([np.zeros((3, 1), np.float32), TRI, uv], axis=1)  # 4 pad bytes first
    view = g.view(inter.tobytes(), stride=24)
    pos = g.accessor(ctype=FLOAT, kind="VEC3", view=view, count=3, byteOffset=4)
    tex = g.accessor(ctype=FLOAT, kind="VEC2", view=view, count=3, byteOffset=16)
    g.doc["images"] = [{"bufferView": g.view(png(np.full((2, 2, 4), 255)))}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.node(mesh=g.mesh({"attributes": {"POSITION": pos, "TEXCOORD_0": tex}, "material": 0}))
    prim = g.load().primitives[0]
    np.testing.assert_array_equal(prim.positions, TRI)
    np.testing.assert_allclose(prim.uv, np.c_[uv[:, 0], 1 - uv[:, 1]])


def test_every_index_component_type():
    for ctype in (UBYTE, USHORT, UINT):
        g = Gltf()
        idx = g.accessor(np.array([0, 2, 1, 0, 1, 2]), ctype=ctype)
        g.node(mesh=g.triangle(indices=idx))
        prim = g.load().primitives[0]
        np.testing.assert_array_equal(prim.indices, [[0, 2, 1], [0, 1, 2]])
        assert prim.indices.dtype == np.uint32


@pytest.mark.parametrize("with_view", [True, False])
def test_sparse_accessors(with_view):
    g = Gltf()
    base = np.array([[0, 0, 0], [5, 5, 5], [9, 9, 9]], np.float32)
    sparse = {"count": 2,
              "indices": {"bufferView": g.view(np.array([1, 2], np.uint16).tobytes()),
                          "componentType": USHORT},
              "values": {"bufferView": g.view(TRI[1:].tobytes())}}
    if with_view:
        pos = g.accessor(base, sparse=sparse)
    else:
        pos = g.accessor(None, kind="VEC3", count=3, sparse=sparse)
    g.node(mesh=g.mesh({"attributes": {"POSITION": pos}}))
    np.testing.assert_array_equal(g.load().primitives[0].positions, TRI)


def test_sparse_index_out_of_range():
    g = Gltf()
    sparse = {"count": 1, "indices": {"bufferView": g.view(np.array([7], np.uint32).tobytes()),
                                      "componentType": UINT},
              "values": {"bufferView": g.view(TRI[:1].tobytes())}}
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(TRI, sparse=sparse)}}))
    with pytest.raises(SceneError, match="accessor 0 sparse: index 7"):
        g.load()


def test_accessor_past_its_view_names_the_accessor():
    g = Gltf()
    g.node(mesh=g.triangle())
    g.doc["accessors"][0]["count"] = 4
    with pytest.raises(SceneError, match="accessor 0 reads past the end of bufferView 0"):
        g.load()
    g = Gltf()
    g.node(mesh=g.triangle())
    g.doc["accessors"][0]["byteOffset"] = 4
    with pytest.raises(SceneError, match="accessor 0 reads past the end"):
        g.load()


def test_view_past_its_buffer_names_the_accessor():
    g = Gltf()
    g.node(mesh=g.triangle())
    glb = g.glb()
    doc, blob = split_glb(glb)
    doc["bufferViews"][0]["byteOffset"] = 8
    with pytest.raises(SceneError, match="accessor 0: bufferView 0 reaches past the end of"):
        load_scene(make_glb(doc, blob[:36]))


@pytest.mark.parametrize("kind, ctype", [("VEC2", FLOAT), ("SCALAR", FLOAT), ("VEC3", UINT),
                                          ("VEC4", FLOAT)])
def test_position_of_the_wrong_type_is_refused(kind, ctype):
    g = Gltf()
    values = np.zeros((3, {"VEC2": 2, "SCALAR": 1, "VEC3": 3, "VEC4": 4}[kind]))
    if kind == "SCALAR":
        values = values[:, 0]
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(values, ctype=ctype)}}))
    with pytest.raises(SceneError, match="mesh 0 primitive 0 POSITION is accessor 0"):
        g.load()


@pytest.mark.parametrize("ctype, normalized, message", [
    (UBYTE, 1, "normalized must be true or false, not 1"),
    (UBYTE, "yes", "normalized must be true or false, not 'yes'"),
    (FLOAT, True, "normalized must be false for FLOAT"),
])
def test_accessor_normalized_flag_is_checked(ctype, normalized, message):
    g = Gltf()
    values = np.zeros((3, 3))
    g.node(mesh=g.triangle(attributes={"COLOR_0": g.accessor(values, ctype=ctype,
                                                             normalized=normalized)}))
    with pytest.raises(SceneError, match=f"accessor 0: {message}"):
        g.load()


def test_external_buffers_come_only_from_resources():
    g = one_triangle()
    doc, blob = split_glb(g.glb())
    doc["buffers"][0]["uri"] = "geometry/tri.bin"
    text = json.dumps(doc).encode()
    scene = load_scene(text, resources={"geometry/tri.bin": blob})
    assert scene.triangle_count == 1
    with pytest.raises(SceneError, match="not provided"):
        load_scene(text)
    doc["buffers"][0]["uri"] = "../tri.bin"
    with pytest.raises(SceneError, match="outside"):
        load_scene(json.dumps(doc).encode(), resources={"tri.bin": blob})


def _gltf_on_disk(tmp_path: Path, uri: str = "geometry/tri%20a.bin",
                  image: str | None = None) -> tuple[Path, bytes]:
    """A one-triangle ``.gltf`` in ``tmp_path`` whose buffer is the file ``uri`` names."""
    g = one_triangle()
    doc, blob = split_glb(g.glb())
    doc["buffers"][0]["uri"] = uri
    if image is not None:
        doc["images"] = [{"uri": image}]
        doc["textures"] = [{"source": 0}]
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
    path = tmp_path / "scene.gltf"
    path.write_text(json.dumps(doc))
    return path, blob


def test_gltf_path_reads_the_files_it_names_from_its_folder(tmp_path):
    from shadowmap.renderer.scene import gltf_resources

    path, blob = _gltf_on_disk(tmp_path)
    (tmp_path / "geometry").mkdir()
    (tmp_path / "geometry" / "tri a.bin").write_bytes(blob)  # percent-escaped in the URI
    (tmp_path / "unrelated.bin").write_bytes(b"\0" * 4096)  # not named: never read
    assert gltf_resources(path, path.read_bytes()) == {"geometry/tri a.bin": blob}
    assert load_scene(path).triangle_count == 1
    # Only what the file names counts against the byte bound, checked before reading.
    assert load_scene(path, limits=Limits(max_request_bytes=len(blob) + 1024)).triangle_count == 1
    with pytest.raises(LimitError, match="exceed") as info:
        gltf_resources(path, path.read_bytes(), max_bytes=len(blob) - 1)
    assert info.value.limit == "max_request_bytes"
    # Given resources win over the folder.
    with pytest.raises(SceneError, match="not provided"):
        load_scene(path, resources={"other.bin": blob})
    # A GLB named .gltf has no external files to read.
    glb = tmp_path / "binary.gltf"
    glb.write_bytes(one_triangle().glb())
    assert gltf_resources(glb, glb.read_bytes()) == {}


def test_gltf_path_missing_files_are_the_loaders_to_report(tmp_path):
    path, blob = _gltf_on_disk(tmp_path, uri="tri.bin", image="textures/missing.png")
    with pytest.raises(SceneError, match="refers to 'tri.bin', which is not in "):
        load_scene(path)  # a buffer is required
    (tmp_path / "tri.bin").write_bytes(blob)
    scene = load_scene(path)  # a missing image drops the texture, with a warning
    assert scene.triangle_count == 1
    assert any("missing.png" in w for w in scene.warnings), scene.warnings
    path, _ = _gltf_on_disk(tmp_path, uri="../outside.bin")
    with pytest.raises(SceneError, match="outside"):
        load_scene(path)


def test_meshopt_views_are_decoded_through_the_extension_module(monkeypatch):
    """The decoder gets the extension's own bytes and fields; its output is the view's data
    when the fallback buffer holds nothing."""
    from shadowmap.renderer.gltf.extensions import meshopt

    calls = []

    def fake(source, count, byte_stride, mode, filter):
        calls.append((bytes(source), count, byte_stride, mode, filter))
        return TRI.tobytes()

    monkeypatch.setattr(meshopt, "decode_buffer_view", fake)
    compressed = b"HEAD" + b"packed!!" + b"tail"
    doc = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["EXT_meshopt_compression"],
        "extensionsRequired": ["EXT_meshopt_compression"],
        "buffers": [{"byteLength": len(compressed)},
                    {"byteLength": 36, "extensions": {"EXT_meshopt_compression":
                                                      {"fallback": True}}}],
        "bufferViews": [{"buffer": 1, "byteOffset": 0, "byteLength": 36, "byteStride": 12,
                         "extensions": {"EXT_meshopt_compression": {
                             "buffer": 0, "byteOffset": 4, "byteLength": 8, "byteStride": 12,
                             "count": 3, "mode": "ATTRIBUTES", "filter": "NONE"}}}],
        "accessors": [{"bufferView": 0, "componentType": FLOAT, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0,
    }
    scene = load_scene(make_glb(doc, compressed))
    assert calls == [(b"packed!!", 3, 12, "ATTRIBUTES", "NONE")]
    np.testing.assert_array_equal(scene.primitives[0].positions, TRI)


# ------------------------------------------------------------------------------------------------
# Primitives
# ------------------------------------------------------------------------------------------------


def _face_normals(prim) -> np.ndarray:
    t = prim.positions[prim.indices].astype(np.float64)
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


def test_strips_keep_their_winding():
    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float32)
    for indexed in (False, True):
        g = Gltf()
        prim = {"mode": 5}
        if indexed:
            prim["indices"] = g.accessor(np.arange(6), ctype=USHORT)
        g.node(mesh=g.triangle(quad, **prim))
        p = g.load().primitives[0]
        np.testing.assert_array_equal(p.indices, [[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]])
        assert np.all(_face_normals(p)[:, 2] > 0)


def test_fans_keep_their_winding():
    fan = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [-1, 1, 0]], np.float32)
    g = Gltf()
    g.node(mesh=g.triangle(fan, mode=6))
    p = g.load().primitives[0]
    assert len(p.indices) == 3
    assert np.all(_face_normals(p)[:, 2] > 0)


def test_points_and_lines_are_left_out_with_a_warning():
    g = Gltf()
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(TRI)}, "mode": 1},
                       {"attributes": {"POSITION": g.accessor(TRI)}}, name="wire"))
    scene = g.load()
    assert scene.triangle_count == 1
    (w,) = scene.warnings
    assert "mesh 0 ('wire') primitive 0" in w and "LINES" in w


def test_nothing_drawable_says_what_was_left_out():
    g = Gltf()
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(TRI)}, "mode": 0}))
    with pytest.raises(SceneError, match="no triangles to render.*primitive 0.*POINTS"):
        g.load()


def test_indices_out_of_range_drop_the_primitive():
    g = Gltf()
    bad = {"attributes": {"POSITION": g.accessor(TRI)},
           "indices": g.accessor(np.array([0, 1, 5]), ctype=USHORT)}
    g.node(mesh=g.mesh(bad, {"attributes": {"POSITION": g.accessor(TRI)}}))
    scene = g.load()
    assert len(scene.primitives) == 1
    assert any("mesh 0 primitive 0" in w and "out of range" in w for w in scene.warnings)


def test_primitive_restart_value_drops_the_primitive():
    g = Gltf()
    pos = np.zeros((256, 3), np.float32)
    pos[:3] = TRI
    bad = {"attributes": {"POSITION": g.accessor(pos)},
           "indices": g.accessor(np.array([0, 1, 2, 0, 1, 255]), ctype=UBYTE)}
    g.node(mesh=g.mesh(bad, {"attributes": {"POSITION": g.accessor(TRI)}}))
    scene = g.load()
    assert len(scene.primitives) == 1
    assert any("mesh 0 primitive 0" in w and "primitive-restart" in w for w in scene.warnings)


@pytest.mark.parametrize("mode", [5, 6])
def test_primitive_restart_cuts_strips_and_fans_where_declared(mode):
    """KHR_mesh_primitive_restart: a strip or fan holding restart values draws the same
    triangles as its pieces drawn as primitives of their own (each piece's strip alternation
    and fan centre starting again); without the declaration the primitive is dropped, and a
    triangle list may never hold the value."""
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(9, 3)).astype(np.float32)
    pieces = [np.array([0, 1, 2, 3, 4]), np.array([5, 6, 7, 8])]
    joined = np.concatenate([pieces[0], [0xFFFF], pieces[1], [0xFFFF]])

    def scene(declare: bool, *index_lists: np.ndarray, prim_mode: int = mode) -> Scene:
        g = Gltf()
        p = g.accessor(pos)
        g.node(mesh=g.mesh(*[{"attributes": {"POSITION": p}, "mode": prim_mode,
                              "indices": g.accessor(ix, ctype=USHORT)} for ix in index_lists]))
        if declare:
            g.doc["extensionsUsed"] = ["KHR_mesh_primitive_restart"]
        return g.load()

    def world_triangles(sc: Scene) -> np.ndarray:
        tris = np.concatenate([p.positions[p.indices] for p in sc.primitives])
        return _sorted_rows(tris)

    cut = scene(True, joined)
    assert cut.warnings == []
    np.testing.assert_array_equal(world_triangles(cut), world_triangles(scene(False, *pieces)))
    assert cut.triangle_count == 3 + 2
    with pytest.raises(SceneError, match="primitive-restart value 65535"):
        scene(False, joined)
    listed = scene(True, np.array([0, 1, 2, 0xFFFF, 3, 4]), np.array([5, 6, 7]), prim_mode=4)
    assert listed.triangle_count == 1
    assert any("primitive-restart value 65535" in w for w in listed.warnings)


def test_float64_positions_keep_their_precision_far_out():
    """KHR_accessor_float64: a millimetre triangle 6,378,137 m out (float32's step there is
    0.5 m) in float64 positions lands where the file puts it, to float64's precision: stored as
    float32 offsets from its centre, the centre in the instance's matrix. The same accessor in a
    file that does not declare the extension is refused, naming it."""
    far = np.array([6378137.0, 1234.5, -4321.25])
    tri = far + np.array([[0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0]])
    g = Gltf()
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(tri, ctype=DOUBLE)}}))
    g.node(mesh=g.mesh({"attributes": {"POSITION": g.accessor(tri, ctype=DOUBLE),
                                       "NORMAL": g.accessor(np.tile([0.0, 0, 1], (3, 1)),
                                                            ctype=DOUBLE)}}),
           translation=[-6378137.0, 0, 0])
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_accessor_float64"]
    scene = g.load()
    assert scene.warnings == []
    first, moved = scene.instances
    got = scene.world_triangles(first, far).reshape(3, 3) + far
    np.testing.assert_allclose(got, tri, rtol=0, atol=1e-9)
    np.testing.assert_allclose(scene.world_triangles(moved).reshape(3, 3),
                               tri - [6378137.0, 0, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(scene.primitives[1].normals, np.tile([0, 0, 1], (3, 1)))
    np.testing.assert_allclose(scene.bounds, [tri.min(axis=0) - [6378137.0, 0, 0],
                                              tri.max(axis=0)], rtol=0, atol=1e-9)
    del g.doc["extensionsUsed"], g.doc["extensionsRequired"]
    with pytest.raises(SceneError, match="componentType 5130 .DOUBLE. needs "
                                         "KHR_accessor_float64"):
        g.load()


def test_primitive_without_position_is_skipped():
    g = Gltf()
    g.node(mesh=g.mesh({"attributes": {"NORMAL": g.accessor(TRI)}},
                       {"attributes": {"POSITION": g.accessor(TRI)}}))
    scene = g.load()
    assert len(scene.primitives) == 1
    assert any("primitive 0" in w and "POSITION" in w for w in scene.warnings)


def test_only_referenced_vertices_are_kept():
    g = Gltf()
    pos = np.concatenate([TRI, np.full((5, 3), np.nan, np.float32)])  # unused, even NaN
    g.node(mesh=g.triangle(pos, indices=g.accessor(np.array([0, 1, 2]), ctype=USHORT)))
    prim = g.load().primitives[0]
    np.testing.assert_array_equal(prim.positions, TRI)


def test_normals_are_the_files_or_area_weighted():
    g = Gltf()
    nrm = g.accessor(np.array([[0, 0, 2], [0, 0, 1], [0, 0, 0]], np.float32))
    g.node(mesh=g.triangle(attributes={"NORMAL": nrm}))
    g.node(mesh=g.triangle())
    scene = g.load()
    with_normals, computed = scene.primitives
    np.testing.assert_allclose(with_normals.normals, [[0, 0, 1]] * 3)  # zero one filled in
    np.testing.assert_allclose(computed.normals, [[0, 0, 1]] * 3)
    assert scene.warnings == ["mesh 0 primitive 0: 1 normals are zero or not finite; computed "
                              "from the faces"]


def test_vertex_colours_only_when_not_all_white():
    g = Gltf()
    g.node(mesh=g.triangle(attributes={"COLOR_0": g.accessor(np.ones((3, 3)))}))
    g.node(mesh=g.triangle(attributes={"COLOR_0": g.accessor(
        np.array([[255, 0, 0, 255]] * 3), ctype=UBYTE, normalized=True)}))
    white, red = g.load().primitives
    assert white.colors is None
    np.testing.assert_allclose(red.colors, [[1, 0, 0, 1]] * 3)


def test_vertex_colours_outside_their_range_are_clamped_with_a_warning():
    g = Gltf()
    g.node(mesh=g.triangle(attributes={"COLOR_0": g.accessor(
        np.array([[2, 0.5, -1], [0.5, 0.5, 0.5], [1, 1, 1]], np.float32))}), name="hot")
    g.node(mesh=g.triangle(attributes={"COLOR_0": g.accessor(
        np.array([[np.nan, 0, 0, 1], [0, 1, 0, 1], [0, 0, np.inf, 1]], np.float32))}))
    scene = g.load()
    hot, holes = scene.primitives
    np.testing.assert_array_equal(hot.colors, [[1, 0.5, 0, 1], [0.5, 0.5, 0.5, 1], [1, 1, 1, 1]])
    np.testing.assert_array_equal(holes.colors, [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])
    assert len(scene.warnings) == 2, scene.warnings
    assert "outside [0, 1] (from -1 to 2); clamped" in scene.warnings[0]
    assert "2 vertex colours (COLOR_0) are not finite; drawn white" in scene.warnings[1]


def test_draco_primitives_use_the_decoder_interface(monkeypatch):
    from shadowmap.renderer.gltf.extensions import draco

    calls = []

    def fake(data, attributes):
        calls.append((bytes(data), dict(attributes)))
        return {"POSITION": TRI.copy(), "indices": np.array([0, 2, 1], np.uint32)}

    monkeypatch.setattr(draco, "decode_primitive", fake)
    g = Gltf()
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    stream = g.view(b"DRACOxxx")
    pos = g.accessor(None, kind="VEC3", count=3)
    colors = g.accessor(np.array([[1, 0, 0, 1]] * 3, np.float32))  # not compressed
    g.node(mesh=g.mesh({"attributes": {"POSITION": pos, "COLOR_0": colors},
                        "indices": g.accessor(None, ctype=USHORT, kind="SCALAR", count=3),
                        "extensions": {"KHR_draco_mesh_compression": {
                            "bufferView": stream, "attributes": {"POSITION": 0}}}}))
    prim = g.load().primitives[0]
    assert calls == [(b"DRACOxxx", {"POSITION": 0})]
    np.testing.assert_array_equal(prim.positions, TRI)
    np.testing.assert_array_equal(prim.indices, [[0, 2, 1]])
    np.testing.assert_allclose(prim.colors, [[1, 0, 0, 1]] * 3)


# ------------------------------------------------------------------------------------------------
# Materials
# ------------------------------------------------------------------------------------------------


def _textured(material: dict, uv0=None, uv1=None, image: bytes | None = None,
              image_spec: dict | None = None) -> Gltf:
    g = Gltf()
    rgba = np.zeros((2, 4, 4), np.uint8)
    rgba[0] = 255  # top row opaque white, bottom row transparent
    g.doc["images"] = [image_spec or {"bufferView": g.view(image or png(rgba)),
                                      "mimeType": "image/png", "name": "cutout"}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["materials"] = [{"name": "leaf", **material}]
    attrs = {}
    if uv0 is not None:
        attrs["TEXCOORD_0"] = g.accessor(np.asarray(uv0, np.float32))
    if uv1 is not None:
        attrs["TEXCOORD_1"] = g.accessor(np.asarray(uv1, np.float32))
    g.node(mesh=g.triangle(attributes=attrs, material=0))
    return g


UV0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
UV1 = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])


def test_base_colour_texture_and_its_texcoord_set():
    g = _textured({"pbrMetallicRoughness": {"baseColorFactor": [1, 0.5, 0.25, 1],
                                            "baseColorTexture": {"index": 0, "texCoord": 1}},
                   "alphaMode": "MASK", "doubleSided": True}, UV0, UV1)
    prim = g.load().primitives[0]
    mat = prim.material
    np.testing.assert_allclose(mat.base_color, [1, 0.5, 0.25, 1])
    assert mat.texture.shape == (2, 4, 4) and mat.texture.dtype == np.uint8
    assert mat.texture[0, 0, 3] == 255 and mat.texture[1, 0, 3] == 0  # rows top to bottom
    assert mat.alpha_mode == "MASK" and mat.alpha_cutoff == 0.5 and mat.double_sided
    # OpenGL convention: v = 1 - glTF v.
    np.testing.assert_allclose(prim.uv, np.c_[UV1[:, 0], 1 - UV1[:, 1]], atol=1e-7)


def test_texture_transform_is_applied_to_the_uvs():
    tt = {"offset": [0.5, -0.25], "rotation": math.pi / 2, "scale": [2.0, 3.0]}
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {
        "index": 0, "texCoord": 1, "extensions": {"KHR_texture_transform": tt}}}}, UV0, UV1)
    g.doc["extensionsUsed"] = ["KHR_texture_transform"]
    scene = g.load()
    assert not scene.warnings
    # T(offset) R(rotation) S(scale) on (u, v, 1), the extension's rotation [[c, s], [-s, c]].
    su, sv = UV1[:, 0] * 2.0, UV1[:, 1] * 3.0
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    u, v = c * su + s * sv + 0.5, -s * su + c * sv - 0.25
    np.testing.assert_allclose(scene.primitives[0].uv, np.c_[u, 1 - v], atol=1e-6)


def test_texture_transform_texcoord_overrides_the_texture_info():
    tt = {"texCoord": 0, "offset": [0.25, 0.0]}
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {
        "index": 0, "texCoord": 1, "extensions": {"KHR_texture_transform": tt}}}}, UV0, UV1)
    uv = g.load().primitives[0].uv
    np.testing.assert_allclose(uv, np.c_[UV0[:, 0] + 0.25, 1 - UV0[:, 1]], atol=1e-7)


def test_specular_glossiness_diffuse_is_the_fallback_base_colour():
    g = Gltf()
    g.doc["extensionsUsed"] = ["KHR_materials_pbrSpecularGlossiness"]
    g.doc["materials"] = [
        {"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.2, 0.4,
                                                                              0.6, 1]}}},
        {"pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]},
         "extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0, 1, 0, 1]}}},
    ]
    g.node(mesh=g.triangle(material=0))
    g.node(mesh=g.triangle(material=1))
    scene = g.load()
    sg, mr = scene.primitives
    np.testing.assert_allclose(sg.material.base_color, [0.2, 0.4, 0.6, 1], atol=1e-7)
    np.testing.assert_allclose(mr.material.base_color, [1, 0, 0, 1])
    assert not scene.warnings


def test_alpha_cutoff_is_read_exactly():
    g = Gltf()
    g.doc["materials"] = [{"alphaMode": "MASK", "alphaCutoff": 0},
                          {"alphaMode": "MASK"},
                          {"alphaMode": "MASK", "alphaCutoff": 1.5, "name": "gone"}]
    for m in range(3):
        g.node(mesh=g.triangle(material=m))
    scene = g.load()
    assert [p.material.alpha_cutoff for p in scene.primitives] == [0.0, 0.5, 1.5]
    (w,) = scene.warnings
    assert "material 2 ('gone')" in w and "fully cut out" in w


@pytest.mark.parametrize("case, image, spec, reason", [
    # PIL names the file object it read: the warning leaves out its address, which changes
    # from run to run.
    ("undecodable", b"this is not a png", None,
     r"cannot be decoded \(UnidentifiedImageError: cannot identify image file <_io.BytesIO>\);"),
    ("bomb", png_header_only(9000, 9000), None, "over the limit"),
    ("missing uri", None, {"uri": "leaf.png"}, "not provided"),
])
def test_unusable_textures_are_dropped_with_a_warning(case, image, spec, reason):
    g = _textured({"pbrMetallicRoughness": {"baseColorFactor": [0, 1, 0, 1],
                                            "baseColorTexture": {"index": 0}}}, UV0,
                  image=image, image_spec=spec)
    scene = g.load()
    prim = scene.primitives[0]
    assert prim.material.texture is None and prim.uv is None
    np.testing.assert_allclose(prim.material.base_color, [0, 1, 0, 1])
    (w,) = scene.warnings
    assert w.startswith("image 0") and "material 0 ('leaf')" in w, w
    assert __import__("re").search(reason, w), w


@pytest.mark.parametrize("uri", ["../../etc/secret.png", "/etc/passwd", "file:///etc/passwd",
                                 "http://127.0.0.1:9/leaf.png", "sub/../../leaf.png", "C:/leaf.png",
                                 "%2e%2e/leaf.png", "..\\leaf.png"])
def test_unsafe_image_uris_are_refused_like_buffer_uris(uri):
    """An image URI that could leave the upload refuses the scene (as a buffer's does), even
    when the file it names was provided: it is never a texture that is merely dropped."""
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}, UV0,
                  image_spec={"uri": uri})
    with pytest.raises(SceneError, match="image 0: refusing URI"):
        g.load(resources={"leaf.png": png(np.full((2, 2, 4), 255, np.uint8))})
    g.doc["materials"] = []  # not even used: still refused, before any work
    g.doc["meshes"][0]["primitives"][0].pop("material")
    with pytest.raises(SceneError, match="image 0: refusing URI"):
        g.load()


def test_base_colour_factor_outside_its_range_is_clamped_with_a_warning():
    g = Gltf()
    # -1e308 is finite here but not in float32, where it would turn into -inf.
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [2, 0.5, -1e308, 1]},
                           "name": "hot"}]
    g.node(mesh=g.triangle(material=0))
    scene = g.load()
    np.testing.assert_array_equal(scene.primitives[0].material.base_color, [1, 0.5, 0, 1])
    (w,) = scene.warnings
    assert "material 0 ('hot')" in w and "outside [0, 1]; clamped" in w, w


def test_uvs_far_from_zero_move_by_whole_repeats_and_non_finite_ones_are_said():
    """Texture coordinates a million repeats out keep no fraction in float32: moved towards 0
    by an even number of repeats (the same texels under REPEAT and MIRRORED_REPEAT)."""
    far = np.array([[1e6 + 0.25, 0.0], [1e6 + 0.5, 0.0], [1e6 + 0.75, 1.0]])
    prim = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
                     far).load().primitives[0]
    np.testing.assert_array_equal(prim.uv, [[0.25, 1.0], [0.5, 1.0], [0.75, 0.0]])
    wide = np.array([[0.0, 0.0], [5000.0, 0.0], [0.0, 1.0]])
    scene = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
                      wide).load()
    np.testing.assert_array_equal(scene.primitives[0].uv, [[0, 1], [5000, 1], [0, 0]])
    (w,) = scene.warnings
    assert "span 5e+03 repeats" in w, w
    holes = np.array([[np.nan, 0.0], [1.0, 0.0], [0.0, 1.0]])
    scene = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
                      holes).load()
    np.testing.assert_array_equal(scene.primitives[0].uv, [[0, 1], [1, 1], [0, 0]])
    (w,) = scene.warnings
    assert "1 texture coordinates (TEXCOORD_0) are not finite in float32" in w, w
    # Finite in float64, past float32's range: no fraction left either.
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "extensions": {
        "KHR_texture_transform": {"scale": [1e39, 1.0]}}}}}, UV0)
    g.doc["extensionsUsed"] = ["KHR_texture_transform"]
    scene = g.load()
    np.testing.assert_array_equal(scene.primitives[0].uv, [[0, 1], [0, 1], [0, 0]])
    (w,) = scene.warnings
    assert "1 texture coordinates (TEXCOORD_0) are not finite in float32" in w, w


def _with_sampler(sampler, uv=UV0) -> Gltf:
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}, uv)
    if sampler is not None:
        g.doc["samplers"] = [sampler]
        g.doc["textures"][0]["sampler"] = 0
    return g


def test_the_texture_sampler_is_read_with_glTF_defaults():
    mat = _with_sampler({"magFilter": 9728, "minFilter": 9986, "wrapS": 33071,
                         "wrapT": 33648}).load().primitives[0].material
    assert mat.sampler == Sampler(9728, 9986, 33071, 33648)
    assert _with_sampler({}).load().primitives[0].material.sampler == Sampler()
    assert _with_sampler(None).load().primitives[0].material.sampler == Sampler()
    assert Sampler().wrap_s == Sampler().wrap_t == 10497  # glTF's default wrap: REPEAT


@pytest.mark.parametrize("sampler, said", [
    ({"wrapS": 12345}, "sampler 0 wrapS 12345 is not a glTF value; REPEAT is used"),
    ({"magFilter": 9986}, "magFilter 9986 is not a glTF value; LINEAR is used"),
    ({"minFilter": "LINEAR"}, "minFilter 'LINEAR' is not a glTF value"),
    ({"wrapT": 33071.0}, "wrapT 33071.0 is not a glTF value"),
    ({"wrapS": True}, "wrapS True is not a glTF value"),
])
def test_a_sampler_value_glTF_does_not_define_is_replaced_with_a_warning(sampler, said):
    scene = _with_sampler({"wrapT": 33071, **sampler}).load()
    (w,) = scene.warnings
    assert said in w and "material 0 ('leaf')" in w, w
    assert scene.primitives[0].material.sampler.wrap_t == (
        33071 if "wrapT" not in sampler else 10497)


def test_a_missing_sampler_is_said_and_the_defaults_used():
    g = _with_sampler(None)
    g.doc["textures"][0]["sampler"] = 3
    scene = g.load()
    (w,) = scene.warnings
    assert "sampler 3 does not exist" in w, w
    assert scene.primitives[0].material.sampler == Sampler()


def test_a_clamped_axis_keeps_its_far_coordinates():
    """Moving a coordinate by an even number of repeats samples the same texels under REPEAT
    and MIRRORED_REPEAT only: a clamped axis keeps its own (all of them read its edge)."""
    far = np.array([[1e6 + 0.25, 1e6 + 0.25], [1e6 + 0.5, 1e6 + 0.25], [1e6 + 0.75, 1e6 + 1]])
    prim = _with_sampler({"wrapS": 33071, "wrapT": 33648}, far).load().primitives[0]
    np.testing.assert_array_equal(prim.uv[:, 0], np.float32(far[:, 0]))
    np.testing.assert_array_equal(prim.uv[:, 1], 1 - np.array([0.25, 0.25, 1.0], np.float32))


def _reencode(fmt: str, **options) -> Callable[[bytes], bytes]:
    from PIL import Image

    def encode(data: bytes) -> bytes:
        out = io.BytesIO()
        with Image.open(io.BytesIO(data)) as im:
            im.convert("RGBA").save(out, fmt, **options)
        return out.getvalue()
    return encode


def _textures(scene: Scene) -> list[np.ndarray]:
    return [p.material.texture for p in scene.primitives if p.material.texture is not None]


@pytest.mark.parametrize("extension, fmt, options, tolerance", [
    # The encoders' fastest efforts (the files decode the same way; the default efforts cost
    # the test 15-20 s per format).
    ("EXT_texture_webp", "WEBP", {"lossless": True, "exact": True, "method": 0, "quality": 0}, 0),
    ("EXT_texture_avif", "AVIF", {"quality": 90, "speed": 10}, 8),
])
def test_webp_and_avif_textures_load_as_gltf_transform_writes_them(models, extension, fmt,
                                                                  options, tolerance):
    """A model whose textures are re-encoded and named only by the extension (required, no
    fallback source: gltf-transform's webp and avif commands) loads the same textures: equal
    for lossless WebP, within AVIF's rounding. The cut-out model, where they shape shadows."""
    glb = (models / "AlphaBlendModeTest.glb").read_bytes()
    original = load_scene(glb)
    moved = load_scene(transcode_textures(glb, extension, _reencode(fmt, **options)))
    assert moved.warnings == original.warnings == []
    ours, theirs = _textures(moved), _textures(original)
    assert len(ours) == len(theirs) == 9
    for a, b in zip(ours, theirs, strict=True):
        assert a.shape == b.shape
        assert np.abs(a.astype(int) - b.astype(int)).mean() <= tolerance
        if tolerance == 0:
            np.testing.assert_array_equal(a, b)


def test_texture_extension_image_first_then_its_fallback_source():
    def rgba(value: int) -> bytes:
        return png(np.full((2, 2, 4), value, np.uint8))

    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}, UV0,
                  image=rgba(10))  # image 0, the plain source
    webp = _reencode("WEBP", lossless=True)(rgba(200))
    g.doc["images"].append({"bufferView": g.view(webp), "mimeType": "image/webp"})
    g.doc["textures"][0]["extensions"] = {"EXT_texture_webp": {"source": 1}}
    g.doc["extensionsUsed"] = ["EXT_texture_webp"]
    scene = g.load()
    assert scene.warnings == []
    assert _textures(scene)[0][0, 0, 0] == 200  # the extension's image
    # An extension image that does not decode: the fallback, with a warning naming both.
    g.doc["images"][1]["bufferView"] = g.view(b"RIFF not a webp")
    scene = g.load()
    assert _textures(scene)[0][0, 0, 0] == 10
    (w,) = scene.warnings
    assert w.startswith("image 1 (EXT_texture_webp) of material 0 ('leaf'): cannot be decoded")
    assert w.endswith("image 0 ('cutout') is used instead"), w
    # Neither decodes: dropped, both named.
    g.doc["images"][0] = {"bufferView": g.view(b"not a png either"), "mimeType": "image/png"}
    scene = g.load()
    assert _textures(scene) == []
    (w,) = scene.warnings
    assert "image 1 (EXT_texture_webp)" in w and "image 0 of material 0" in w
    assert w.endswith("the texture is dropped and the base colour factor is used"), w


def test_ktx2_textures_stay_refused_when_required():
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}, UV0)
    g.doc["textures"][0] = {"extensions": {"KHR_texture_basisu": {"source": 0}}}
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_texture_basisu"]
    with pytest.raises(UnsupportedExtension, match="KHR_texture_basisu"):
        g.load()


def test_texture_without_its_uv_set_draws_untextured():
    g = _textured({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "texCoord": 1}}},
                  UV0)
    scene = g.load()
    assert scene.primitives[0].material.texture is None
    assert any("TEXCOORD_1" in w for w in scene.warnings)


# ------------------------------------------------------------------------------------------------
# Nodes and instancing
# ------------------------------------------------------------------------------------------------


def test_node_cycles_and_two_parents_are_refused():
    g = Gltf()
    mesh = g.triangle()
    g.node(mesh=mesh, children=[1])
    g.node(root=False, children=[0])
    with pytest.raises(SceneError, match="cycle"):
        g.load()
    g = Gltf()
    mesh = g.triangle()
    g.node(children=[2])
    g.node(children=[2])
    g.node(root=False, mesh=mesh)
    with pytest.raises(SceneError, match="node 2 has two parents"):
        g.load()
    g = Gltf()
    g.node(mesh=g.triangle(), children=[0])
    with pytest.raises(SceneError, match="cycle|two parents"):
        g.load()


def test_deep_hierarchies_need_no_recursion():
    g = Gltf()
    mesh = g.triangle()
    depth = 20_000
    g.doc["nodes"] = [{"translation": [0, 0.001, 0], "children": [i + 1]} for i in range(depth)]
    g.doc["nodes"].append({"mesh": mesh})
    g.doc["scenes"][0]["nodes"] = [0]
    scene = g.load()
    np.testing.assert_allclose(scene.instances[0].matrix[:3, 3], [0, depth * 0.001, 0],
                               rtol=1e-9)


def test_default_scene_or_every_root():
    g = Gltf()
    mesh = g.triangle()
    g.node(mesh=mesh)
    g.node(root=False, mesh=mesh, translation=[5, 0, 0])
    g.doc["scenes"].append({"nodes": [1]})
    assert len(g.load().instances) == 1
    g.doc["scene"] = 1
    np.testing.assert_allclose(g.load().instances[0].matrix[:3, 3], [5, 0, 0])
    del g.doc["scene"]  # no default scene: every root node
    assert len(g.load().instances) == 2


def test_matrix_and_trs_and_non_finite_transforms():
    g = Gltf()
    mesh = g.triangle()
    m = np.eye(4)
    m[:3, 3] = [1, 2, 3]
    g.node(mesh=mesh, matrix=m.T.ravel().tolist())  # glTF matrices are column-major
    g.node(mesh=mesh, translation=[0, 0, 1], rotation=[0, 0, math.sin(math.pi / 4),
                                                       math.cos(math.pi / 4)], scale=[2, 2, 2])
    a, b = g.load().instances
    np.testing.assert_allclose(a.matrix, m)
    np.testing.assert_allclose(b.matrix[:3, :3], [[0, -2, 0], [2, 0, 0], [0, 0, 2]], atol=1e-12)
    np.testing.assert_allclose(b.bounds, [[-2, 0, 1], [0, 2, 1]], atol=1e-12)
    g = Gltf()
    mesh = g.triangle()
    g.node(translation=[1e308, 0, 0], children=[1])
    g.node(root=False, mesh=mesh, translation=[1e308, 0, 0])
    with pytest.raises(SceneError, match="non-finite transform"):
        g.load()


def test_a_non_affine_node_matrix_is_drawn_affine_with_a_warning():
    """A projective bottom row would divide the drawn positions by w while bounds, culling and
    the reference treat the node as affine: it is reset to (0, 0, 0, 1) and said; rounding noise
    is reset without a word."""
    g = Gltf()
    mesh = g.triangle()
    m = np.eye(4)
    m[:3, 3] = [1, 2, 3]
    m[3] = [0.5, 0, 0, 1]
    g.node(matrix=m.T.ravel().tolist(), children=[1], name="lens")
    g.node(root=False, mesh=mesh, translation=[0, 0, 1])
    noisy = np.eye(4)
    noisy[3] = [1e-9, 0, 0, 1 + 1e-9]
    g.node(mesh=mesh, matrix=noisy.T.ravel().tolist())
    far = np.eye(4)
    far[3, 0] = 1e308
    g.node(root=False, mesh=mesh, matrix=far.T.ravel().tolist())  # not drawn: no warning
    scene = g.load()
    child, plain = scene.instances
    expected = np.eye(4)
    expected[:3, 3] = [1, 2, 4]
    np.testing.assert_array_equal(child.matrix, expected)
    np.testing.assert_array_equal(plain.matrix, np.eye(4))
    np.testing.assert_allclose(child.bounds, [[1, 2, 4], [2, 3, 4]])
    (w,) = scene.warnings
    assert "node 'lens'" in w and "not affine" in w and "[0.5, 0.0, 0.0, 1.0]" in w, w


def test_a_shearing_node_matrix_is_drawn_as_written_with_a_warning():
    """glTF requires node matrices that decompose into TRS. A shearing one is drawn as its
    numbers say (normals by the cofactor, so still perpendicular to the sheared faces), and
    said, since viewers that decompose it draw another shape; a zero scale, a mirror, float32
    rounding of a rotation and shear composed from TRS parents are all fine."""
    g = Gltf()
    mesh = g.triangle(TRI * 2)
    shear = np.eye(4)
    shear[0, 1] = 0.5  # x += 0.5 y: the y axis leans 26.6 degrees off square
    g.node(mesh=mesh, matrix=shear.T.ravel().tolist(), name="leaning")
    turn = np.eye(4, dtype=np.float32)
    c, s = np.float32(math.cos(0.3)), np.float32(math.sin(0.3))
    turn[:2, :2] = [[c, -s], [s, c]]
    flat = np.diag([1.0, 0.0, -2.0, 1.0])  # a zero scale and a mirror: both decompose
    g.node(mesh=mesh, matrix=(turn @ flat).T.ravel().tolist(), name="flat")
    g.node(scale=[1, 3, 1], children=[3])  # non-uniform parent, turned child: TRS each
    g.node(root=False, mesh=mesh, rotation=[0, 0, math.sin(0.4), math.cos(0.4)])
    vast = np.eye(4)
    vast[:3, 0] = [1e308, 1e308, 0]  # its squares overflow: the 45 degrees must still show
    g.node(matrix=vast.T.ravel().tolist(), name="vast")
    scene = g.load()
    leaning = scene.instances[0]
    np.testing.assert_array_equal(leaning.matrix, shear)
    # The box around the sheared local box, which holds the sheared triangle.
    np.testing.assert_allclose(leaning.bounds, [[0, 0, 0], [3, 2, 0]])
    w, far = scene.warnings
    assert "node 'leaning'" in w and "shears" in w and "26.6 degrees from perpendicular" in w, w
    assert "node 'vast'" in far and "45 degrees from perpendicular" in far, far
    # Drawn as written: the world triangles are the sheared ones.
    np.testing.assert_allclose(scene.world_triangles(leaning)[0],
                               [[0, 0, 0], [2, 0, 0], [1, 2, 0]])


def test_rotations_are_normalized_quaternions():
    """A rotation of another length would scale and shear the node: normalized (a zero one is
    no rotation), said past rounding; a matrix's node has no rotation to check."""
    g = Gltf()
    mesh = g.triangle()
    g.node(mesh=mesh, rotation=[0, 0, 2 * math.sin(math.pi / 4), 2 * math.cos(math.pi / 4)],
           name="double")
    g.node(mesh=mesh, rotation=[0, 0, 0, 0], name="zero")
    g.node(mesh=mesh, rotation=[0, 0, 0, 1.0000001])  # rounding: no word
    g.node(mesh=mesh, rotation=[0, 0, 0, 3], matrix=np.eye(4).ravel().tolist())
    # Squares past float64's range: the length is found without them (a plain norm would be
    # infinite, and the rotation divided by it none at all).
    g.node(mesh=mesh, rotation=[0, 1e308, 1e-300, 0], name="huge")
    g.node(mesh=mesh, rotation=[0, 0, 1e-200, 0], name="tiny")
    scene = g.load()
    double, zero, rounded, matrix, huge, tiny = (i.matrix for i in scene.instances)
    np.testing.assert_allclose(double[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    for m in (zero, rounded, matrix):
        np.testing.assert_allclose(m, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(huge[:3, :3], np.diag([-1, 1, -1]), atol=1e-12)  # 180 deg, y
    np.testing.assert_allclose(tiny[:3, :3], np.diag([-1, -1, 1]), atol=1e-12)  # 180 deg, z
    assert scene.warnings == ["node 'double': its rotation has length 2, not 1; normalized",
                              "node 'zero': its rotation has length 0, not 1; no rotation is "
                              "used",
                              "node 'huge': its rotation has length 1e+308, not 1; normalized",
                              "node 'tiny': its rotation has length 1e-200, not 1; normalized"]


def test_fifty_thousand_instances_load_quickly():
    g = Gltf()
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    idx = g.accessor(np.array([0, 1, 2, 1, 3, 2, 4, 6, 5, 5, 6, 7], np.uint16), ctype=USHORT)
    mesh = g.triangle(box, indices=idx)
    n = 50_000
    g.doc["nodes"] = [{"mesh": mesh, "translation": [2 * i, 0, 0]} for i in range(n)]
    g.doc["scenes"][0]["nodes"] = list(range(n))
    data = g.glb()
    t = time.perf_counter()
    scene = load_scene(data)
    seconds = time.perf_counter() - t
    assert len(scene.primitives) == 1 and len(scene.instances) == n
    np.testing.assert_allclose(scene.instances[12345].bounds, [[24690, 0, 0], [24691, 1, 1]])
    np.testing.assert_allclose(scene.bounds, [[0, 0, 0], [2 * n - 1, 1, 1]])
    assert seconds < 15, seconds


def test_gpu_instancing_makes_one_instance_per_entry():
    from scipy.spatial.transform import Rotation

    g = Gltf()
    g.doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    t = np.array([[0, 0, 0], [3, 0, 0], [0, 0, 3]], np.float32)
    r = Rotation.from_euler("xyz", [[0, 0, 0], [0, 90, 0], [30, 0, 45]], degrees=True)
    s = np.array([[1, 1, 1], [2, 2, 2], [1, 0.5, 3]], np.float32)
    ext = {"attributes": {"TRANSLATION": g.accessor(t),
                          "ROTATION": g.accessor(r.as_quat().astype(np.float32)),
                          "SCALE": g.accessor(s)}}
    g.node(mesh=g.triangle(), translation=[0, 10, 0], extensions={"EXT_mesh_gpu_instancing": ext})
    scene = g.load()
    assert len(scene.instances) == 3 and len(scene.primitives) == 1 and not scene.warnings
    node = np.eye(4)
    node[1, 3] = 10
    for k, inst in enumerate(scene.instances):
        local = np.eye(4)
        local[:3, :3] = r[k].as_matrix() @ np.diag(s[k])
        local[:3, 3] = t[k]
        np.testing.assert_allclose(inst.matrix, node @ local, atol=1e-6)
        # Bounds: the local box's 8 corners under the instance matrix.
        box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 0)])
        w = box @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
        np.testing.assert_allclose(inst.bounds, [w.min(0), w.max(0)], atol=1e-6)


def test_gpu_instancing_rotations_are_made_unit_quaternions():
    """Rotations stored as normalized bytes are a step from unit length: normalized without a
    word; a doubled one and a zero one are counted in a warning."""
    g = Gltf()
    g.doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    quarter = [0, 0, 90, 90]  # a quarter turn about z, as normalized bytes: length 1.0021
    bytes_ = g.accessor(np.array([quarter, [0, 0, 0, 127]], np.int8), ctype=BYTE,
                        normalized=True)
    floats = g.accessor(np.array([[0, 0, 0, 2], [0, 0, 0, 0]], np.float32))
    g.node(mesh=g.triangle(), name="bytes",
           extensions={"EXT_mesh_gpu_instancing": {"attributes": {"ROTATION": bytes_}}})
    g.node(mesh=g.triangle(), name="floats",
           extensions={"EXT_mesh_gpu_instancing": {"attributes": {"ROTATION": floats}}})
    scene = g.load()
    for inst in scene.instances:
        rot = inst.matrix[:3, :3]
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(scene.instances[0].matrix[:3, :3],
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert scene.warnings == ["node 'floats': 2 EXT_mesh_gpu_instancing rotations are not unit "
                              "quaternions: normalized (a zero one is no rotation)"]


def test_instancing_counts_towards_the_triangle_precheck():
    g = Gltf()
    ext = {"attributes": {"TRANSLATION": g.accessor(np.zeros((1000, 3)))}}
    g.node(mesh=g.triangle(), extensions={"EXT_mesh_gpu_instancing": ext})
    with pytest.raises(LimitError) as info:
        g.load(limits=Limits(max_triangles=999))
    assert info.value.limit == "max_triangles"
    assert g.load(limits=Limits(max_triangles=1000)).triangle_count == 1000


def test_cast_and_receive_shadow_extras_on_node_or_mesh():
    g = Gltf()
    mesh = g.triangle(extras=None)
    g.doc["meshes"][mesh]["extras"] = {"castShadow": False}
    g.node(mesh=mesh)
    g.node(mesh=mesh, extras={"castShadow": True, "receiveShadow": False})
    a, b = g.load().instances
    assert (a.cast_shadow, a.receive_shadow) == (False, True)
    assert (b.cast_shadow, b.receive_shadow) == (True, False)


def test_cameras_and_lights_with_their_node_transforms():
    g = one_triangle()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}},
                        {"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1,
                                                                  "znear": 0, "zfar": 1}}]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point", "range": 4}]}}
    g.node(children=[2], translation=[0, 0, 5], scale=[3, 3, 3])
    g.node(root=False, camera=0, extensions={"KHR_lights_punctual": {"light": 0}})
    g.node(camera=1)
    g.node(camera=9)  # no such camera: costs the camera, not the scene
    scene = g.load()
    cam, ortho = scene.cameras
    np.testing.assert_allclose(cam.pose, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]])
    assert cam.yfov == 0.8 and cam.znear == 0.1 and cam.zfar is None and cam.ymag is None
    assert ortho.yfov is None and ortho.ymag == 1 and ortho.aspect == 1
    assert (ortho.znear, ortho.zfar) == (0, 1)
    (light,) = scene.lights
    assert light.type == "point" and light.range == 4
    np.testing.assert_allclose(light.pose[:3, 3], [0, 0, 5])
    assert not any("orthographic" in w for w in scene.warnings)
    assert any("camera 9 does not exist" in w for w in scene.warnings)


def test_a_mirrored_camera_looks_along_its_nodes_minus_z_unmirrored():
    """A negative scale on a camera's node (valid glTF) used to give a mirrored pose: its
    frustum's faces wound the other way and were culled, and the picture came out empty
    without a word. The pose is a rotation looking along the node's -Z with its +Y up, and the
    mirror is said; a light under a mirror keeps its direction and needs no word."""
    g = one_triangle()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "directional"}]}}
    g.node(camera=0, translation=[0.3, 0.3, 4], scale=[-1, 1, 1], name="mirror")
    g.node(translation=[0, 0, 2], scale=[1, -2, 1], rotation=[math.sin(0.3), 0, 0, math.cos(0.3)],
           extensions={"KHR_lights_punctual": {"light": 0}})
    scene = g.load()
    (cam,) = scene.cameras
    np.testing.assert_allclose(cam.pose, [[1, 0, 0, 0.3], [0, 1, 0, 0.3], [0, 0, 1, 4],
                                          [0, 0, 0, 1]], atol=1e-12)
    (light,) = scene.lights
    assert np.linalg.det(light.pose[:3, :3]) == pytest.approx(1.0)
    # It shines along its node's -Z: the turned z axis, whatever the y axis's sign.
    np.testing.assert_allclose(light.pose[:3, 2], [0, -math.sin(0.6), math.cos(0.6)],
                               atol=1e-12)
    (w,) = scene.warnings
    assert "node 'mirror': its camera's transform mirrors" in w, w


def test_cameras_and_lights_face_along_their_nodes_minus_z_under_a_shearing_parent():
    """A turned child under a non-uniformly scaled parent (valid glTF): its world matrix
    shears. glTF has the camera look and the light shine along the node's -Z axis as that
    matrix carries it; the nearest rotation (polar decomposition) would point 27 degrees away
    for this turn of 45 under a scale of 3."""
    g = one_triangle()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "spot"}]}}
    turn = [math.sin(math.pi / 8), 0, 0, math.cos(math.pi / 8)]  # 45 degrees about x
    g.node(children=[2, 3], scale=[1, 3, 1], translation=[0, 0, 5])
    g.node(root=False, camera=0, rotation=turn)
    g.node(root=False, rotation=turn, extensions={"KHR_lights_punctual": {"light": 0}})
    scene = g.load()
    axis = np.array([0, -3, 1]) / math.sqrt(10)  # diag(1, 3, 1) @ (0, -sin 45, cos 45)
    for pose in (scene.cameras[0].pose, scene.lights[0].pose):
        np.testing.assert_allclose(pose[:3, 2], axis, atol=1e-12)
        np.testing.assert_allclose(pose[:3, 0], [1, 0, 0], atol=1e-12)
        np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    assert scene.warnings == []


def test_zero_scales_keep_an_orientation_while_two_axes_are_left():
    """A zero scale (glTF allows it, often to hide a node) loses an axis. With one lost, the
    two left fix the way a camera or light faces, as a rotation (the lost axis's sign, free in
    the decomposition, is the one that makes it proper). With two lost it cannot be read: a
    camera, a spot or a sun is left out and said; a point light needs only its position."""
    g = one_triangle()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "spot"},
                                                              {"type": "point"}]}}
    turn = [math.sin(0.2), 0, 0, math.cos(0.2)]  # 0.4 rad about x
    g.node(children=[3, 4], scale=[1, 1, 0], rotation=turn)  # z lost
    g.node(children=[5, 6], scale=[0, 1, 0], name="thin")  # x and z lost
    for k, extra in enumerate([{"camera": 0},
                               {"extensions": {"KHR_lights_punctual": {"light": 0}}},
                               {"camera": 0},
                               {"extensions": {"KHR_lights_punctual": {"light": 1}}}]):
        g.node(root=False, name=f"n{k}", translation=[0, 0, 4], **extra)
    scene = g.load()
    c, s = math.cos(0.4), math.sin(0.4)
    expected = [[1, 0, 0], [0, c, -s], [0, s, c]]
    (cam,) = scene.cameras
    np.testing.assert_allclose(cam.pose[:3, :3], expected, atol=1e-12)
    np.testing.assert_allclose(cam.pose[:3, 3], [0, 0, 0], atol=1e-12)  # z scaled away
    spot, point = scene.lights
    assert (spot.type, point.type) == ("spot", "point")
    np.testing.assert_allclose(spot.pose[:3, :3], expected, atol=1e-12)
    assert scene.warnings == [
        "node 'n2' has a transform that keeps at most one axis (zero scales): the way its "
        "camera faces cannot be read; left out"]


@pytest.mark.gl
def test_a_mirrored_camera_draws_the_scene(renderer):
    def camera_under(scale):
        g = one_triangle()
        g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
        g.node(camera=0, translation=[0.3, 0.3, 4], scale=scale)
        return g.load()

    plain = renderer.render(camera_under([1, 1, 1]), {"width": 64, "height": 48})
    mirrored = renderer.render(camera_under([-1, 1, 1]), {"width": 64, "height": 48})
    assert (plain.color != 255).any()
    np.testing.assert_array_equal(mirrored.color, plain.color)  # the same view, unmirrored
    assert any("mirrors" in w for w in mirrored.warnings)


@pytest.mark.parametrize("camera, said", [
    ({"type": "image/png", "perspective": {"yfov": 0.8}}, "type 'image/png' is neither"),
    ({"type": "perspective"}, "has no 'perspective' object"),
    ([0.8], "is not an object"),
])
def test_a_camera_that_cannot_be_read_is_left_out_with_a_warning(camera, said):
    g = one_triangle()
    g.doc["cameras"] = [camera]
    g.node(camera=0)
    scene = g.load()
    assert scene.cameras == []
    (w,) = scene.warnings
    assert w.startswith("camera 0") and said in w and w.endswith("left out"), w


def test_node_visibility_hides_subtrees_but_not_cameras():
    """KHR_node_visibility: ``visible: false`` hides the node and everything below it, even a
    child that says ``true``: no mesh, no light; its camera stays. The plain nodes around it
    are drawn as before."""
    def vis(value):
        return {"KHR_node_visibility": {"visible": value}}

    g = Gltf()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
    g.doc["extensionsUsed"] = ["KHR_node_visibility", "KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point"}]}}
    tri = g.triangle()
    g.node(mesh=tri, name="shown")                                          # 0
    g.node(mesh=tri, children=[2, 3], extensions=vis(False), name="hidden")  # 1
    g.node(root=False, mesh=tri, extensions=vis(True), name="under")        # 2
    g.node(root=False, camera=0,
           extensions={**vis(True), "KHR_lights_punctual": {"light": 0}})   # 3
    g.node(mesh=tri, translation=[0, 0, 1], extensions=vis(True))           # 4
    scene = g.load()
    assert scene.warnings == []
    assert sorted(inst.name for inst in scene.instances) == ["node_4", "shown"]
    assert len(scene.cameras) == 1 and scene.lights == []
    # Everything hidden: nothing to draw, said as such.
    g.doc["nodes"][0]["extensions"] = vis(False)
    g.doc["nodes"][4]["extensions"] = vis(False)
    with pytest.raises(SceneError, match="no triangles to render"):
        g.load()
    # Not a boolean: drawn, with a warning.
    g.doc["nodes"][0]["extensions"] = vis("no")
    scene = g.load()
    assert [inst.name for inst in scene.instances] == ["shown"]
    assert scene.warnings == ["node 'shown': KHR_node_visibility visible 'no' is not a boolean: "
                              "the node is drawn"]


def test_a_light_reference_without_a_light_is_said():
    g = one_triangle()
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point"}]}}
    g.node(extensions={"KHR_lights_punctual": {}}, name="empty")
    g.node(extensions={"KHR_lights_punctual": 0}, name="number")
    scene = g.load()
    assert scene.lights == []
    assert scene.warnings == [
        "node 'empty': its KHR_lights_punctual {} names no light: left out",
        "node 'number': its KHR_lights_punctual 0 names no light: left out"]


def test_cameras_and_lights_float32_cannot_place_are_left_out_with_a_warning():
    """A camera 1e30 units out would overflow the camera's near and far planes (and a point
    light the shaders' distances): left out, said; a directional light's position is moot."""
    g = one_triangle()
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point"},
                                                              {"type": "directional"}]}}
    g.node(translation=[0, 1e30, 0], camera=0, name="far {x}",  # no format string
           extensions={"KHR_lights_punctual": {"light": 0}})
    g.node(translation=[0, 1e30, 0], extensions={"KHR_lights_punctual": {"light": 1}})
    g.node(translation=[0, 0, 1e17], camera=0, extensions={"KHR_lights_punctual": {"light": 0}})
    scene = g.load()
    (cam,) = scene.cameras
    assert cam.pose[2, 3] == 1e17
    assert [lt.type for lt in scene.lights] == ["directional", "point"]
    assert scene.warnings == [
        f"node 'far {{x}}' is 1e+30 units from the scene's centre, more than float32 coordinates "
        f"hold: its {what} is left out" for what in ("camera", "point light")]


# ------------------------------------------------------------------------------------------------
# Skins and morph targets
# ------------------------------------------------------------------------------------------------


def _skin_01():
    models = models_dir()
    doc = json.loads((models / "Animation_Skin_01.gltf").read_text())
    blob = (models / "Animation_Skin_01.bin").read_bytes()
    scene = load_scene(models / "Animation_Skin_01.gltf",
                       resources={"Animation_Skin_01.bin": blob})
    return doc, blob, scene


def _raw(doc: dict, blob: bytes, accessor: int, dtype: str, width: int) -> np.ndarray:
    acc = doc["accessors"][accessor]
    view = doc["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(blob, dtype, acc["count"] * width, start).reshape(acc["count"], width)


def test_skin_in_the_stored_pose_matches_a_hand_computation():
    """Animation_Skin_01: joint nodes store a pose unlike the bind pose."""
    from scipy.spatial.transform import Rotation

    doc, blob, scene = _skin_01()
    assert not scene.warnings
    (prim,) = scene.primitives
    (inst,) = scene.instances
    np.testing.assert_array_equal(inst.matrix, np.eye(4))  # positions are world-space
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    raw = _raw(doc, blob, attrs["POSITION"], "<f4", 3).astype(np.float64)
    weights = _raw(doc, blob, attrs["WEIGHTS_0"], "<f4", 4).astype(np.float64)
    joints = _raw(doc, blob, attrs["JOINTS_0"], "<u2", 4)
    ibm = _raw(doc, blob, doc["skins"][0]["inverseBindMatrices"], "<f4", 16)
    ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major in the file

    def local(node):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(node.get("rotation", [0, 0, 0, 1])).as_matrix()
        m[:3, 3] = node.get("translation", [0, 0, 0])
        return m

    j0 = local(doc["nodes"][1])
    j1 = j0 @ local(doc["nodes"][2])
    jm = [j0 @ ibm[0], j1 @ ibm[1]]
    expected = []
    for v, w, j in zip(raw, weights, joints, strict=True):
        m = sum(wk * jm[jk] for wk, jk in zip(w, j, strict=True) if wk)
        expected.append((m @ np.r_[v, 1])[:3])
    expected = np.array(expected)
    # Every file vertex is kept, in order (the indices use them all).
    np.testing.assert_allclose(prim.positions, expected, atol=1e-6)
    assert np.abs(prim.positions - raw).max() > 0.05  # skinning moved them
    tri = prim.positions[prim.indices].astype(np.float64)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.linalg.norm(fn, axis=1) > 1e-6)


def test_skinned_normals_use_the_inverse_transpose():
    g = Gltf()
    nrm = np.tile(np.array([1, 1, 0], np.float32) / np.sqrt(2), (3, 1))
    joints = g.accessor(np.array([[0, 1, 0, 0]] * 3), ctype=UBYTE)
    weights = g.accessor(np.array([[1, 0, 0, 0], [0.5, 0.5, 0, 0], [2, 0, 0, 0]], np.float32))
    mesh = g.triangle(attributes={"NORMAL": g.accessor(nrm), "JOINTS_0": joints,
                                  "WEIGHTS_0": weights})
    g.doc["skins"] = [{"joints": [1, 2]}]  # no inverseBindMatrices: identity
    g.node(mesh=mesh, skin=0, translation=[100, 0, 0])  # ignored, per the spec
    g.node(scale=[2, 1, 1])
    g.node(translation=[0, 1, 0])
    scene = g.load()
    prim = scene.primitives[0]
    np.testing.assert_array_equal(scene.instances[0].matrix, np.eye(4))
    # v0: joint 0 (scale x2); v1: half each; v2: weight 2 normalized to 1, joint 0.
    np.testing.assert_allclose(prim.positions, [[0, 0, 0], [1.5, 0.5, 0], [0, 1, 0]], atol=1e-6)
    n0 = np.array([0.5, 1, 0]) / np.linalg.norm([0.5, 1, 0])
    np.testing.assert_allclose(prim.normals[0], n0, atol=1e-6)
    np.testing.assert_allclose(prim.normals[2], n0, atol=1e-6)


def test_a_joint_listed_twice_and_joints_without_a_common_root_are_said():
    """glTF requires each joint once and a common root for a skin's joints. Such a skin is
    drawn as its matrices say (each entry with its own inverse bind matrix, each joint where
    its tree puts it), and said: viewers that build one bone per node in one skeleton draw it
    otherwise."""
    def skinned(joints: list[int], roots: list[int]) -> Scene:
        g = Gltf()
        mesh = g.triangle(attributes={
            "JOINTS_0": g.accessor(np.array([[0, 0, 0, 0], [1, 0, 0, 0],
                                             [len(joints) - 1, 0, 0, 0]]), ctype=UBYTE),
            "WEIGHTS_0": g.accessor(np.tile(np.array([1, 0, 0, 0], np.float32), (3, 1)))})
        ibm = np.tile(np.eye(4, dtype=np.float32), (len(joints), 1, 1))
        ibm[-1, :3, 3] = [0, 0, -1]  # the last entry's own bind
        g.doc["skins"] = [{"joints": joints, "inverseBindMatrices": g.accessor(ibm)}]
        g.node(mesh=mesh, skin=0)
        g.node(root=1 in roots, name="hip", translation=[1, 0, 0],
               children=[] if 2 in roots else [2])
        g.node(root=2 in roots, name="knee", translation=[0, 1, 0])
        return g.load()

    twice = skinned([1, 2, 2], roots=[1])
    (w,) = twice.warnings
    assert "skin 0 lists node 'knee' more than once as a joint" in w, w
    # Each entry with its own inverse bind matrix: v2 is the knee's, moved by its own bind.
    np.testing.assert_allclose(twice.primitives[0].positions,
                               TRI + [[1, 0, 0], [1, 1, 0], [1, 1, -1]], atol=1e-6)
    apart = skinned([1, 2], roots=[1, 2])
    assert any("its joints have no common root" in w and "'hip' and 'knee'" in w
               for w in apart.warnings), apart.warnings
    ok = skinned([1, 2], roots=[1])
    assert not ok.warnings
    np.testing.assert_allclose(ok.primitives[0].positions,
                               TRI + [[1, 0, 0], [1, 1, -1], [1, 1, -1]], atol=1e-6)


@pytest.mark.parametrize("name", ["CesiumMan.glb", "Fox.glb"])
def test_real_figures_load_without_warnings(models, name):
    scene = load_scene(models / name)
    assert scene.warnings == []
    lo, hi = scene.bounds
    assert np.all(np.isfinite(scene.bounds)) and 0.5 < np.max(hi - lo) < 10
    if name == "Fox.glb":
        # The fox's stored pose is its bind pose: skinned, its vertices are the file's bind
        # positions (the accessor's min/max), not those positions under the node's 0.0254 scale.
        doc, _ = split_glb((models / name).read_bytes())
        acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
        fox = next(i for i in scene.instances if i.name == "fox1")
        np.testing.assert_allclose(fox.bounds, [acc["min"], acc["max"]], atol=1e-3)


def test_morph_targets_at_their_default_weights():
    g = Gltf()
    up = g.accessor(np.tile(np.array([0, 0, 1], np.float32), (3, 1)))
    sparse = {"count": 1, "indices": {"bufferView": g.view(np.array([2], np.uint8).tobytes()),
                                      "componentType": UBYTE},
              "values": {"bufferView": g.view(np.array([[1, 0, 0]], np.float32).tobytes())}}
    side = g.accessor(None, kind="VEC3", count=3, sparse=sparse)
    dn = g.accessor(np.tile(np.array([1, 0, -1], np.float32), (3, 1)))
    nrm = g.accessor(np.tile(np.array([0, 0, 1], np.float32), (3, 1)))
    mesh = g.triangle(attributes={"NORMAL": nrm},
                      targets=[{"POSITION": up, "NORMAL": dn}, {"POSITION": side}],
                      )
    g.doc["meshes"][mesh]["weights"] = [0.5, 1.0]
    g.node(mesh=mesh)
    g.node(mesh=mesh, weights=[1.0, 0.0])
    a, b = g.load().primitives
    np.testing.assert_allclose(a.positions, TRI + [[0, 0, 0.5], [0, 0, 0.5], [1, 0, 0.5]])
    np.testing.assert_allclose(b.positions, TRI + [0, 0, 1])
    np.testing.assert_allclose(b.normals, [[1, 0, 0]] * 3, atol=1e-7)
    np.testing.assert_allclose(a.normals, [[1, 0, 1] / np.sqrt(2)] * 3, atol=1e-6)


# ------------------------------------------------------------------------------------------------
# Extensions and limits
# ------------------------------------------------------------------------------------------------


def test_supported_extensions_are_listed():
    for name in ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization",
                 "KHR_texture_transform", "EXT_mesh_gpu_instancing", "KHR_lights_punctual",
                 "KHR_materials_pbrSpecularGlossiness", "KHR_materials_emissive_strength"):
        assert name in SUPPORTED and SUPPORTED[name]
    # Extensions whose absence would change shadows are not "ignorable".
    for name in ("KHR_materials_transmission", "KHR_materials_volume", "KHR_texture_basisu"):
        assert name not in SUPPORTED and name not in IGNORED


def test_unsupported_required_extensions_are_refused():
    import shadowmap

    g = one_triangle()
    g.doc["extensionsUsed"] = ["KHR_texture_transform", "EXT_future", "KHR_materials_transmission"]
    g.doc["extensionsRequired"] = ["EXT_future", "KHR_texture_transform",
                                   "KHR_materials_transmission"]
    with pytest.raises(UnsupportedExtension) as info:
        g.load()
    assert info.value.extensions == ["EXT_future", "KHR_materials_transmission"]
    assert "EXT_future" in str(info.value) and "KHR_materials_transmission" in str(info.value)
    assert isinstance(info.value, SceneError)
    assert shadowmap.UnsupportedExtension is UnsupportedExtension


def test_unknown_optional_extensions_are_ignored_with_a_warning():
    g = one_triangle()
    g.doc["extensionsUsed"] = ["EXT_future", "KHR_materials_emissive_strength"]
    scene = g.load()
    assert scene.warnings == ["ignored optional extension EXT_future"]
    assert scene.with_ground().warnings == scene.warnings


def test_triangle_limit_is_checked_before_any_data_is_read():
    """The declared counts are over the limit: refused as a limit even though the buffer the
    accessors read is missing (so nothing was decoded)."""
    g = one_triangle()
    doc, _ = split_glb(g.glb())
    doc["accessors"].append({"bufferView": 0, "componentType": UINT, "count": 3_000_000,
                             "type": "SCALAR"})
    doc["meshes"][0]["primitives"][0]["indices"] = 1
    doc["buffers"][0]["uri"] = "missing.bin"
    text = json.dumps(doc).encode()
    with pytest.raises(LimitError) as info:
        load_scene(text, limits=Limits(max_triangles=10_000))
    assert info.value.limit == "max_triangles" and "1000000 triangles" in str(info.value)
    with pytest.raises(SceneError, match="not provided"):
        load_scene(text)


def test_malformed_documents_stay_scene_errors():
    for edit in (lambda d: d.update(nodes=5), lambda d: d.update(meshes=[{"primitives": 3}]),
                 lambda d: d["accessors"][0].update(count="many"),
                 lambda d: d["accessors"][0].update(componentType=5124),
                 lambda d: d["nodes"][0].update(mesh=7),
                 lambda d: d["nodes"][0].update(translation=[1, 2]),
                 lambda d: d["meshes"][0]["primitives"][0].update(attributes=[])):
        g = one_triangle()
        doc, blob = split_glb(g.glb())
        edit(doc)
        with pytest.raises(SceneError):
            load_scene(make_glb(doc, blob))


# ------------------------------------------------------------------------------------------------
# The model corpus
# ------------------------------------------------------------------------------------------------

CORPUS = sorted(p.name for p in models_dir().iterdir() if p.suffix in (".glb", ".gltf"))
#: Files trimesh's loader reads right (no skin, Draco, meshopt or instancing): the oracle.
TRIMESH_AGREES = ["AlphaBlendModeTest.glb", "BoxTextured.glb", "CesiumMan.glb",
                  "CesiumMilkTruck.glb", "Duck.glb", "TestScene.gltf", "TwoCubes.glb", "cube.glb"]
#: Independent expectations for the others: triangles and world bounds.
EXPECTED = {
    "BoxDraco.gltf": (12, [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]),
    "BoxMeshopt.glb": (12, [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]),
    "Animation_Skin_01.gltf": (4, None),
    "Fox.glb": (None, None),
}


def _resources(models: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in models.iterdir() if p.suffix == ".bin"}


@pytest.mark.parametrize("name", CORPUS)
def test_every_model_loads(models, name):
    scene = load_scene(models / name, resources=_resources(models))
    assert scene.triangle_count > 0
    assert np.all(np.isfinite(scene.bounds)) and np.all(scene.bounds[1] > scene.bounds[0])
    for prim in scene.primitives:
        assert prim.normals.shape == prim.positions.shape
        np.testing.assert_allclose(np.linalg.norm(prim.normals, axis=1), 1.0, atol=1e-3)
        assert prim.indices.max() < len(prim.positions)
        assert (prim.uv is None) == (prim.material.texture is None)
    if name in EXPECTED:
        triangles, bounds = EXPECTED[name]
        if triangles is not None:
            assert scene.triangle_count == triangles
        if bounds is not None:
            np.testing.assert_allclose(scene.bounds, bounds, atol=1e-3)
    extra = ["ignored optional extension KHR_materials_common"] if name == "TestScene.gltf" else []
    assert scene.warnings == extra


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    a = np.round(a.reshape(len(a), -1), 4) + 0.0  # + 0.0: -0.0 sorts as 0.0
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("name", TRIMESH_AGREES)
def test_geometry_matches_trimesh(models, name):
    import trimesh

    res = _resources(models)
    scene = load_scene(models / name, resources=res)
    tm = trimesh.load(str(models / name), force="scene", process=False,
                      resolver=MappingResolver(res))
    theirs, mats, boxes = [], [], []
    for node in tm.graph.nodes_geometry:
        matrix, geom = tm.graph[node]
        mesh = tm.geometry[geom]
        v = np.asarray(mesh.vertices) @ matrix[:3, :3].T + matrix[:3, 3]
        theirs.append(v[mesh.faces])
        mats.append(np.asarray(matrix))
        corners = trimesh.bounds.corners(mesh.bounds) @ matrix[:3, :3].T + matrix[:3, 3]
        boxes.append([corners.min(axis=0), corners.max(axis=0)])
        # Same vertices in the same order (where every vertex is used): same attributes.
        ours = [p for p in scene.primitives if len(p.positions) == len(mesh.vertices)
                and np.allclose(p.positions, mesh.vertices, atol=1e-6)]
        assert ours, (name, geom)
        p = ours[0]
        np.testing.assert_array_equal(p.indices, mesh.faces)
        uv = getattr(mesh.visual, "uv", None)
        if p.uv is not None:
            np.testing.assert_allclose(p.uv, uv, atol=1e-6)  # trimesh flips v too
    ours_tri = np.concatenate([scene.world_triangles(i) for i in scene.instances])
    theirs_tri = np.concatenate(theirs)
    assert ours_tri.shape == theirs_tri.shape
    np.testing.assert_allclose(_sorted_rows(ours_tri), _sorted_rows(theirs_tri), atol=2e-4)
    np.testing.assert_allclose(_sorted_rows(np.stack([i.matrix for i in scene.instances])),
                               _sorted_rows(np.stack(mats)), atol=1e-4)
    # Instances are bounded by their local box's corners under the instance matrix.
    np.testing.assert_allclose(scene.bounds, [np.min(boxes, axis=0)[0], np.max(boxes, axis=0)[1]],
                               atol=1e-4)


# ------------------------------------------------------------------------------------------------
# End to end (GL)
# ------------------------------------------------------------------------------------------------


@pytest.mark.gl
@pytest.mark.parametrize("name", ["BoxTextured.glb", "CesiumMilkTruck.glb",
                                  "Animation_Skin_01.gltf"])
def test_loaded_models_cast_the_reference_shadows(renderer, models, name):
    from shadowmap.renderer import testing as T

    scene = load_scene(models / name, resources=_resources(models)).with_ground()
    params = RenderParams(lights=[{"type": "directional", "direction": [-0.5, -1.0, 0.2]}])
    m = T.measure(renderer, scene, params).metrics[0]
    assert m.pixels > 10_000
    assert m.iou >= 0.97, (name, m)


def test_readme_lists_every_supported_extension():
    path = Path(__file__).resolve().parents[1] / "README.md"
    if not path.is_file():
        pytest.skip("no README.md beside the tests (the container holds only the tests)")
    readme = path.read_text()
    section = readme.split("### glTF support", 1)[1].split("\n## ", 1)[0]
    for name in SUPPORTED:
        short = "_" + name.split("_materials_")[1] if "_materials_" in name else name
        assert f"`{name}`" in section or f"`{short}`" in section, name
