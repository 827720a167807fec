"""The glTF extension decoders: KHR_draco_mesh_compression and EXT_meshopt_compression (no GL).

The boxes are real files (``BoxDraco.gltf``, ``BoxMeshopt.glb`` from gltfpack); the meshopt
filter cases are streams written here by hand, from the extension's bitstream spec and the filter
encoders' formulas, so the library's filters are checked against the spec and not against
themselves.
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from conftest import models_dir
from gltf_files import split_glb
from shadowmap.renderer.errors import SceneError
from shadowmap.renderer.gltf.extensions import draco, meshopt

# --- helpers: the files ----------------------------------------------------------------------


def _draco_box() -> tuple[dict, bytes, dict]:
    """BoxDraco.gltf: the document, its bufferView's bytes and the primitive."""
    models = models_dir()
    doc = json.loads((models / "BoxDraco.gltf").read_text())
    primitive = doc["meshes"][0]["primitives"][0]
    ext = primitive["extensions"]["KHR_draco_mesh_compression"]
    view = doc["bufferViews"][ext["bufferView"]]
    blob = (models / doc["buffers"][view["buffer"]]["uri"]).read_bytes()
    start = view.get("byteOffset", 0)
    return doc, blob[start:start + view["byteLength"]], primitive


def _meshopt_box() -> tuple[dict, list[bytes]]:
    """BoxMeshopt.glb: the document and each bufferView decoded with its extension's fields."""
    doc, blob = split_glb((models_dir() / "BoxMeshopt.glb").read_bytes())
    views = []
    for view in doc["bufferViews"]:
        ext = view["extensions"]["EXT_meshopt_compression"]
        assert ext["buffer"] == 0  # the GLB binary chunk
        start = ext.get("byteOffset", 0)
        source = blob[start:start + ext["byteLength"]]
        views.append(meshopt.decode_buffer_view(
            source, ext["count"], ext["byteStride"], ext["mode"], ext.get("filter")
        ))
    return doc, views


def _meshopt_source(index: int) -> tuple[bytes, dict]:
    doc, blob = split_glb((models_dir() / "BoxMeshopt.glb").read_bytes())
    ext = doc["bufferViews"][index]["extensions"]["EXT_meshopt_compression"]
    start = ext.get("byteOffset", 0)
    return blob[start:start + ext["byteLength"]], ext


def _check_faces(positions: np.ndarray, normals: np.ndarray, indices: np.ndarray) -> None:
    """Twelve triangles, indices in range, each one's vertex normals along its face normal."""
    assert indices.shape == (36,)
    assert int(indices.min()) >= 0 and int(indices.max()) < len(positions)
    tri = positions[indices.reshape(-1, 3)].astype(np.float64)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    for k in range(3):
        along = np.einsum("ij,ij->i", face, normals[indices.reshape(-1, 3)[:, k]])
        np.testing.assert_allclose(np.abs(along), 1.0, atol=1e-3)


# --- KHR_draco_mesh_compression --------------------------------------------------------------


def test_draco_box_decodes_to_the_accessors_box() -> None:
    doc, data, primitive = _draco_box()
    attributes = primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"]
    out = draco.decode_primitive(data, attributes)
    assert set(out) == {"POSITION", "NORMAL", "indices"}

    positions, normals, indices = out["POSITION"], out["NORMAL"], out["indices"]
    accessors = doc["accessors"]
    pos_acc = accessors[primitive["attributes"]["POSITION"]]
    assert positions.dtype == np.float32 and positions.shape == (pos_acc["count"], 3) == (24, 3)
    assert normals.dtype == np.float32 and normals.shape == (24, 3)
    assert indices.dtype == np.uint32
    assert len(indices) == accessors[primitive["indices"]]["count"] == 36

    # Dequantized: the real corners (±0.5), spanning exactly the accessor's min/max, not the
    # stream's quantized integers.
    lo, hi = np.array(pos_acc["min"]), np.array(pos_acc["max"])
    assert np.all(positions >= lo - 1e-6) and np.all(positions <= hi + 1e-6)
    np.testing.assert_allclose(positions.min(axis=0), lo, atol=1e-6)
    np.testing.assert_allclose(positions.max(axis=0), hi, atol=1e-6)
    assert len(np.unique(positions, axis=0)) == 8

    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-3)
    nrm_acc = accessors[primitive["attributes"]["NORMAL"]]
    assert np.all(normals >= np.array(nrm_acc["min"]) - 1e-3)
    assert np.all(normals <= np.array(nrm_acc["max"]) + 1e-3)
    assert int(indices.max()) == accessors[primitive["indices"]]["max"][0]
    _check_faces(positions, normals, indices)


def _draco_stream() -> tuple[bytes, dict[str, int], dict[str, np.ndarray]]:
    """A quantized Draco tetrahedron with every glTF attribute kind, and what went in."""
    dracopy = pytest.importorskip("DracoPy")
    rng = np.random.default_rng(7)
    points = rng.uniform(-3.0, 5.0, size=(4, 3)).astype(np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.uint32)
    normals = rng.normal(size=(4, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.25, 0.75]])
    colors = np.array([[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 0], [10, 20, 30, 40]],
                      np.uint8)
    joints = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [300, 1, 0, 0], [9, 8, 7, 6]], np.uint16)
    weights = np.array([[1, 0, 0, 0], [0.5, 0.5, 0, 0], [0.25] * 4, [0.7, 0.2, 0.1, 0]],
                       np.float32)
    data = dracopy.encode(
        points, faces, quantization_bits=10, preserve_order=True, colors=colors, tex_coord=uv,
        normals=normals, generic_attributes={10: joints, 11: weights},
    )
    decoded = dracopy.decode(data)
    ids = {
        "POSITION": decoded.get_attribute_by_type(0)["unique_id"],
        "NORMAL": decoded.get_attribute_by_type(1)["unique_id"],
        "COLOR_0": decoded.get_attribute_by_type(2)["unique_id"],
        "TEXCOORD_0": decoded.get_attribute_by_type(3)["unique_id"],
        "JOINTS_0": 10,
        "WEIGHTS_0": 11,
    }
    inputs = {"POSITION": points, "NORMAL": normals, "COLOR_0": colors, "TEXCOORD_0": uv,
              "JOINTS_0": joints, "WEIGHTS_0": weights, "indices": faces.reshape(-1)}
    return data, ids, inputs


def test_draco_attributes_are_dequantized_and_typed() -> None:
    data, ids, inputs = _draco_stream()
    out = draco.decode_primitive(data, ids)
    assert set(out) == set(ids) | {"indices"}

    # 10-bit positions: back as the real values, within one quantization step of the input.
    points = inputs["POSITION"]
    step = float((points.max(axis=0) - points.min(axis=0)).max()) / (2**10 - 1)
    assert out["POSITION"].dtype == np.float32 and out["POSITION"].shape == (4, 3)
    np.testing.assert_allclose(out["POSITION"], points, atol=step)
    assert np.abs(out["POSITION"]).max() > 2.0  # not integers in [0, 1023], not [0, 1]

    assert out["NORMAL"].dtype == np.float32
    np.testing.assert_allclose(out["NORMAL"], inputs["NORMAL"], atol=1e-2)
    assert out["TEXCOORD_0"].dtype == np.float32 and out["TEXCOORD_0"].shape == (4, 2)
    np.testing.assert_allclose(out["TEXCOORD_0"], inputs["TEXCOORD_0"], atol=1e-3)  # not flipped
    assert out["COLOR_0"].dtype == np.float32 and out["COLOR_0"].shape == (4, 4)
    np.testing.assert_allclose(out["COLOR_0"], inputs["COLOR_0"] / 255.0, atol=1e-6)
    assert out["JOINTS_0"].dtype == np.uint16
    np.testing.assert_array_equal(out["JOINTS_0"], inputs["JOINTS_0"])
    assert out["WEIGHTS_0"].dtype == np.float32
    np.testing.assert_allclose(out["WEIGHTS_0"], inputs["WEIGHTS_0"], atol=1e-3)
    assert out["indices"].dtype == np.uint32
    np.testing.assert_array_equal(out["indices"], inputs["indices"])
    assert all(a.flags.c_contiguous for a in out.values())


def test_draco_errors_name_the_extension(monkeypatch: pytest.MonkeyPatch) -> None:
    dracopy = pytest.importorskip("DracoPy")
    _, data, primitive = _draco_box()
    attributes = primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"]

    with pytest.raises(SceneError, match="KHR_draco_mesh_compression.*id 7"):
        draco.decode_primitive(data, {**attributes, "TEXCOORD_0": 7})
    with pytest.raises(SceneError, match="KHR_draco_mesh_compression.*TEXCOORD_0.*3 comp"):
        draco.decode_primitive(data, {"TEXCOORD_0": attributes["NORMAL"]})
    for corrupt in (b"", b"not draco at all", data[: len(data) // 2], b"DRACO" + bytes(64)):
        with pytest.raises(SceneError, match="KHR_draco_mesh_compression"):
            draco.decode_primitive(corrupt, attributes)

    cloud = dracopy.encode(np.eye(3, dtype=np.float32))
    with pytest.raises(SceneError, match="KHR_draco_mesh_compression.*point cloud"):
        draco.decode_primitive(cloud, {"POSITION": 0})

    monkeypatch.setitem(sys.modules, "DracoPy", None)  # import fails as if not installed
    with pytest.raises(SceneError, match="KHR_draco_mesh_compression.*DracoPy"):
        draco.decode_primitive(data, attributes)


def test_draco_flipped_bytes_never_escape_as_raw_errors() -> None:
    _, data, primitive = _draco_box()
    attributes = primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"]
    rng = np.random.default_rng(3)
    for _ in range(200):
        damaged = bytearray(data)
        for at in rng.integers(0, len(data), size=3):
            damaged[at] = int(rng.integers(0, 256))
        try:
            out = draco.decode_primitive(bytes(damaged), attributes)
        except SceneError:
            continue
        assert int(out["indices"].max(initial=0)) < max(len(out["POSITION"]), 1)


# --- EXT_meshopt_compression: the box --------------------------------------------------------


def _node_matrix(node: dict) -> np.ndarray:
    """A node's local matrix from its TRS (no rotation in the test file)."""
    assert "rotation" not in node and "matrix" not in node
    m = np.diag(np.append(np.array(node.get("scale", [1, 1, 1]), np.float64), 1.0))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def test_meshopt_box_decodes_to_a_unit_box() -> None:
    doc, views = _meshopt_box()
    for view, data in zip(doc["bufferViews"], views, strict=True):
        assert len(data) == view["byteLength"]

    primitive = doc["meshes"][0]["primitives"][0]
    accessors = doc["accessors"]

    # NORMAL: VEC3 normalized BYTE in 4-byte elements (KHR_mesh_quantization).
    nrm = accessors[primitive["attributes"]["NORMAL"]]
    assert nrm["componentType"] == 5120 and nrm["normalized"]
    stride = doc["bufferViews"][nrm["bufferView"]]["byteStride"]
    raw = np.frombuffer(views[nrm["bufferView"]], np.int8).reshape(-1, stride)[:, :3]
    normals = np.maximum(raw / 127.0, -1.0)
    assert normals.shape == (24, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-3)

    # POSITION: VEC3 UNSIGNED_SHORT, not normalized, in 8-byte elements; the node's scale and
    # translation turn the integers back into metres.
    pos = accessors[primitive["attributes"]["POSITION"]]
    assert pos["componentType"] == 5123 and not pos.get("normalized", False)
    stride = doc["bufferViews"][pos["bufferView"]]["byteStride"]
    quantized = np.frombuffer(views[pos["bufferView"]], "<u2").reshape(-1, stride // 2)[:, :3]
    assert quantized.shape == (24, 3)
    np.testing.assert_array_equal(quantized.min(axis=0), pos["min"])
    np.testing.assert_array_equal(quantized.max(axis=0), pos["max"])
    node = next(n for n in doc["nodes"] if n.get("mesh") == 0)
    world = (_node_matrix(node) @ np.c_[quantized, np.ones(24)].T).T[:, :3]
    np.testing.assert_allclose(world.min(axis=0), -0.5, atol=1e-4)
    np.testing.assert_allclose(world.max(axis=0), 0.5, atol=1e-4)
    assert len(np.unique(quantized, axis=0)) == 8

    # Indices: UNSIGNED_SHORT triangle list.
    idx = accessors[primitive["indices"]]
    assert idx["componentType"] == 5123
    indices = np.frombuffer(views[idx["bufferView"]], "<u2")
    _check_faces(world, normals, indices)


def test_meshopt_triangles_decode_to_either_index_size() -> None:
    source, ext = _meshopt_source(2)
    short = np.frombuffer(meshopt.decode_buffer_view(source, ext["count"], 2, "TRIANGLES", None),
                          "<u2")
    wide = np.frombuffer(meshopt.decode_buffer_view(source, ext["count"], 4, "TRIANGLES", "NONE"),
                         "<u4")
    np.testing.assert_array_equal(short, wide)


# --- EXT_meshopt_compression: streams written by hand ----------------------------------------


def _attribute_stream(rows: np.ndarray) -> bytes:
    """Mode 0 (attributes), bitstream version 0, every byte delta stored as a literal (bits 3).

    ``rows`` is (count, stride) uint8. The baseline element (the tail) is all zeros.
    """
    count, stride = rows.shape
    out = bytearray([0xA0])
    block_size = min((8192 // stride) & ~15, 256)
    previous = np.zeros(stride, np.uint8)
    for start in range(0, count, block_size):
        block = rows[start:start + block_size]
        groups = -(-len(block) // 16)
        deltas = np.zeros((groups * 16, stride), np.uint8)
        step = (block.astype(np.int16) - np.vstack([previous, block[:-1]])).astype(np.uint8)
        deltas[: len(block)] = np.where(step & 0x80, ~(step << 1), step << 1)  # zigzag
        for k in range(stride):
            out += b"\xff" * (-(-groups // 4))  # header: 2 bits (= 3, literal) per group
            out += deltas[:, k].tobytes()
        previous = block[-1]
    out += bytes(max(32, stride))  # tail: padding, then the (zero) baseline element
    return bytes(out)


def _leb128(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _index_sequence(indices: list[int]) -> bytes:
    """Mode 2 (indices): deltas from baseline 0, zigzag, LEB128; 4 tail bytes."""
    out, last = bytearray([0xD1]), 0
    for index in indices:
        delta, last = index - last, index
        zig = (delta << 1) if delta >= 0 else ((~delta) << 1) | 1
        out += _leb128(zig << 1)
    return bytes(out + bytes(4))


def _snorm(value: float, bits: int) -> int:
    """meshopt_quantizeSnorm: a value in [-1, 1] as a signed ``bits``-bit integer."""
    scale = (1 << (bits - 1)) - 1
    value = min(max(value, -1.0), 1.0)
    return int(value * scale + (0.5 if value >= 0 else -0.5))


def _oct_encode(v: np.ndarray, bits: int, w: int) -> list[int]:
    """The octahedral filter's encoder: x, y, 1.0 as K-bit integers, then w as is."""
    x, y, z = (float(c) for c in v[:3])
    n = abs(x) + abs(y) + abs(z)
    x, y = x / n, y / n
    u = x if z >= 0 else (1 - abs(y)) * (1.0 if x >= 0 else -1.0)
    t = y if z >= 0 else (1 - abs(x)) * (1.0 if y >= 0 else -1.0)
    return [_snorm(u, bits), _snorm(t, bits), _snorm(1.0, bits), w]


def _oct_decode_spec(raw: list[int], one_max: int) -> list[int]:
    """The spec's reference octahedral decoder, in Python floats."""
    one = float(raw[2])
    x, y = raw[0] / one, raw[1] / one
    z = 1.0 - abs(x) - abs(y)
    t = min(z, 0.0)
    x -= math.copysign(t, x)
    y -= math.copysign(t, y)
    length = math.sqrt(x * x + y * y + z * z)
    return [round(x / length * one_max), round(y / length * one_max),
            round(z / length * one_max), raw[3]]


def _quat_encode(q: np.ndarray, bits: int) -> list[int]:
    """The quaternion filter's encoder: the three smaller components scaled by sqrt(2)."""
    big = int(np.argmax(np.abs(q)))
    sign = -1.0 if q[big] < 0 else 1.0
    rest = [_snorm(float(q[(big + k) % 4]) * math.sqrt(2.0) * sign, bits) for k in (1, 2, 3)]
    return [*rest, (_snorm(1.0, bits) & ~3) | big]


def _quat_decode_spec(raw: list[int]) -> list[int]:
    """The spec's reference quaternion decoder, in Python floats."""
    one = float(raw[3] | 3)
    x, y, z = (raw[k] / one / math.sqrt(2.0) for k in range(3))
    w = math.sqrt(max(0.0, 1.0 - x * x - y * y - z * z))
    out = [0] * 4
    big = raw[3] & 3
    for k, value in zip((1, 2, 3, 0), (x, y, z, w), strict=True):
        out[(big + k) % 4] = round(value * 32767.0)
    return out


def _exp_word(mantissa: int, exponent: int) -> int:
    return ((exponent & 0xFF) << 24) | (mantissa & 0xFFFFFF)


def _exp_encode(value: float, bits: int) -> int:
    """The exponential filter's encoder: a ``bits``-bit mantissa and its own exponent."""
    exponent = min(max(math.frexp(value)[1] - (bits - 1), -100), 100) if value else 0
    return _exp_word(round(value / 2.0**exponent), exponent)


def test_meshopt_attributes_without_filter_are_the_bytes() -> None:
    rng = np.random.default_rng(11)
    for count, stride in ((1, 4), (17, 12), (300, 8), (40, 256)):
        rows = rng.integers(0, 256, size=(count, stride), dtype=np.uint8)
        source = _attribute_stream(rows)
        for name in (None, "NONE"):
            assert meshopt.decode_buffer_view(source, count, stride, "ATTRIBUTES", name) == (
                rows.tobytes())


def test_meshopt_indices_mode() -> None:
    indices = [0, 1, 2, 2, 1, 3, 70000, 5, 4, 4]
    source = _index_sequence(indices)
    wide = meshopt.decode_buffer_view(source, len(indices), 4, "INDICES", None)
    assert list(np.frombuffer(wide, "<u4")) == indices
    small = [i for i in indices if i < 65536]
    short = meshopt.decode_buffer_view(_index_sequence(small), len(small), 2, "INDICES", "NONE")
    assert list(np.frombuffer(short, "<u2")) == small


def test_meshopt_octahedral_filter() -> None:
    # Exact cases, 8-bit components (stride 4), K = 8: the axes, w passed through.
    axes = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    raw = [_oct_encode(np.array(a, float), 8, w) for a, w in zip(axes, (0, 1, -1, 127, -128, 5),
                                                               strict=True)]
    assert raw[0] == [0, 0, 127, 0] and raw[1] == [127, 127, 127, 1]
    rows = np.array(raw, np.int8).view(np.uint8)
    out = meshopt.decode_buffer_view(_attribute_stream(rows), len(raw), 4, "ATTRIBUTES",
                                     "OCTAHEDRAL")
    got = np.frombuffer(out, np.int8).reshape(-1, 4)
    expected = [[127 * c for c in a] + [w] for a, w in zip(axes, (0, 1, -1, 127, -128, 5),
                                                           strict=True)]
    np.testing.assert_array_equal(got, expected)

    # Random unit vectors: 8-bit storage with K = 6 (top bits = sign), 16-bit with K = 12.
    rng = np.random.default_rng(5)
    vectors = rng.normal(size=(40, 3))
    vectors /= np.linalg.norm(vectors, axis=1, keepdims=True)
    for stride, dtype, bits, one_max in ((4, np.int8, 6, 127), (8, np.int16, 12, 32767)):
        raw = [_oct_encode(v, bits, int(i)) for i, v in enumerate(vectors)]
        rows = np.array(raw, dtype).view(np.uint8).reshape(len(raw), stride)
        out = meshopt.decode_buffer_view(_attribute_stream(rows), len(raw), stride, "ATTRIBUTES",
                                         "OCTAHEDRAL")
        got = np.frombuffer(out, dtype).reshape(-1, 4).astype(np.int64)
        spec = np.array([_oct_decode_spec(r, one_max) for r in raw])
        assert np.abs(got - spec).max() <= 1  # the spec allows one unit in the last place
        np.testing.assert_array_equal(got[:, 3], np.arange(40))
        decoded = got[:, :3] / one_max
        np.testing.assert_allclose(np.linalg.norm(decoded, axis=1), 1.0, atol=2.5 / 127)
        assert np.abs(decoded - vectors).max() < 4.0 / ((1 << (bits - 1)) - 1)


def test_meshopt_quaternion_filter() -> None:
    # Exact: the identity, and 180 degrees about x (its largest component is x).
    raw = [_quat_encode(np.array([0.0, 0.0, 0.0, 1.0]), 16),
           _quat_encode(np.array([1.0, 0.0, 0.0, 0.0]), 16)]
    assert raw[0] == [0, 0, 0, 32767] and raw[1] == [0, 0, 0, 32764]
    rows = np.array(raw, np.int16).view(np.uint8).reshape(2, 8)
    out = meshopt.decode_buffer_view(_attribute_stream(rows), 2, 8, "ATTRIBUTES", "QUATERNION")
    np.testing.assert_array_equal(np.frombuffer(out, "<i2").reshape(-1, 4),
                                  [[0, 0, 0, 32767], [32767, 0, 0, 0]])

    rng = np.random.default_rng(9)
    quats = rng.normal(size=(33, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    for bits in (16, 12, 8):
        raw = [_quat_encode(q, bits) for q in quats]
        rows = np.array(raw, np.int16).view(np.uint8).reshape(len(raw), 8)
        out = meshopt.decode_buffer_view(_attribute_stream(rows), len(raw), 8, "ATTRIBUTES",
                                         "QUATERNION")
        got = np.frombuffer(out, "<i2").reshape(-1, 4).astype(np.int64)
        spec = np.array([_quat_decode_spec(r) for r in raw])
        assert np.abs(got - spec).max() <= 1
        decoded = got / 32767.0
        sign = np.sign(np.einsum("ij,ij->i", decoded, quats))[:, None]  # double cover
        assert np.abs(decoded * sign - quats).max() < 3.0 / ((1 << (bits - 1)) - 1)


def test_meshopt_exponential_filter() -> None:
    # Exact words: 2^e * m, including the ends of the valid exponent range.
    cases = [(3, -1, 1.5), (-3, -3, -0.375), (1, 10, 1024.0), (0, 0, 0.0), (1, -100, 2.0**-100),
             (-(1 << 23), 0, -(2.0**23)), ((1 << 23) - 1, 100, ((1 << 23) - 1) * 2.0**100),
             (5, 0, 5.0)]
    words = np.array([_exp_word(m, e) for m, e, _ in cases], "<u4")
    rows = words.view(np.uint8).reshape(-1, 8)  # two floats per element (stride 8)
    out = meshopt.decode_buffer_view(_attribute_stream(rows), len(rows), 8, "ATTRIBUTES",
                                     "EXPONENTIAL")
    np.testing.assert_array_equal(np.frombuffer(out, "<f4"),
                                  np.array([v for _, _, v in cases], np.float32))

    # Encoded from real values with 23 and 10-bit mantissas (stride 12: VEC3).
    values = np.array([[0.1, -2.5e5, 3.14159], [1e-20, 7.0, -0.001], [123.456, 0.0, 1.0]])
    for bits in (23, 10):
        words = np.array([[_exp_encode(float(v), bits) for v in row] for row in values], "<u4")
        out = meshopt.decode_buffer_view(_attribute_stream(words.view(np.uint8)), 3, 12,
                                         "ATTRIBUTES", "EXPONENTIAL")
        got = np.frombuffer(out, "<f4").reshape(3, 3)
        np.testing.assert_allclose(got, values, rtol=2.0 ** -(bits - 1), atol=0)


# --- EXT_meshopt_compression: errors ---------------------------------------------------------


def test_meshopt_corrupt_data_is_a_scene_error() -> None:
    attributes, ext = _meshopt_source(1)
    triangles, _ = _meshopt_source(2)
    cases = [
        (attributes[:-5], ext["count"], 8, "ATTRIBUTES", None),  # truncated
        (b"\x00" + attributes[1:], ext["count"], 8, "ATTRIBUTES", None),  # bad header
        (attributes + b"\x00", ext["count"], 8, "ATTRIBUTES", None),  # trailing byte
        (b"", 24, 8, "ATTRIBUTES", None),
        (triangles[:10], 36, 2, "TRIANGLES", None),
        (b"\x00" + triangles[1:], 36, 2, "TRIANGLES", None),
        (triangles, 36, 2, "INDICES", None),  # the wrong codec
        (_index_sequence([1, 2, 3])[:-3], 3, 4, "INDICES", None),
    ]
    for source, count, stride, mode, name in cases:
        with pytest.raises(SceneError, match="EXT_meshopt_compression"):
            meshopt.decode_buffer_view(source, count, stride, mode, name)


@pytest.mark.parametrize(
    ("count", "stride", "mode", "name", "message"),
    [
        (24, 6, "ATTRIBUTES", None, "multiple of 4"),
        (24, 260, "ATTRIBUTES", None, "multiple of 4"),
        (24, 12, "ATTRIBUTES", "OCTAHEDRAL", "OCTAHEDRAL needs byteStride 4 or 8"),
        (24, 4, "ATTRIBUTES", "QUATERNION", "QUATERNION needs byteStride 8"),
        (24, 8, "ATTRIBUTES", "COLOR", "unknown filter"),
        (35, 2, "TRIANGLES", None, "divisible by 3"),
        (36, 1, "TRIANGLES", None, "byteStride 2 or 4"),
        (36, 2, "TRIANGLES", "EXPONENTIAL", "cannot have filter"),
        (36, 2, "STRIPS", None, "unknown mode"),
        (-1, 4, "ATTRIBUTES", None, "non-negative"),
        (10**12, 8, "ATTRIBUTES", None, "cannot hold"),  # refused before any allocation
        (3 * 10**9, 4, "TRIANGLES", None, "cannot hold"),
        (10**9, 4, "INDICES", None, "cannot hold"),
    ],
)
def test_meshopt_bad_parameters(count: int, stride: int, mode: str, name: str | None,
                                message: str) -> None:
    source, _ = _meshopt_source(1)
    with pytest.raises(SceneError, match=f"EXT_meshopt_compression.*{message}"):
        meshopt.decode_buffer_view(source, count, stride, mode, name)


def test_meshopt_without_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    source, ext = _meshopt_source(0)
    monkeypatch.setitem(sys.modules, "meshopt", None)
    with pytest.raises(SceneError, match="EXT_meshopt_compression.*meshopt package"):
        meshopt.decode_buffer_view(source, ext["count"], 4, "ATTRIBUTES", None)


def test_meshopt_zero_count_is_empty() -> None:
    assert meshopt.decode_buffer_view(b"", 0, 4, "ATTRIBUTES", None) == b""
