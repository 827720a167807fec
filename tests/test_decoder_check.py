"""``bench/decoder_vs_blender.py``: its comparison of two decoders' triangles, the files it
builds, and its handling of the other decoder's process, with a stand-in for Blender (bpy is
not installed here: the check itself is run by hand)."""

from __future__ import annotations

import json
import struct
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from shadowmap.renderer import load_scene

ROOT = Path(__file__).resolve().parents[1]
# The container's test stage holds the tests and the installed package, not bench/.
pytestmark = pytest.mark.skipif(not (ROOT / "bench").is_dir(),
                                reason="no bench/ beside the tests (the container)")


@pytest.fixture(scope="module")
def check():
    sys.path.insert(0, str(ROOT))
    try:
        from bench import decoder_vs_blender
    finally:
        sys.path.remove(str(ROOT))
    return decoder_vs_blender


TRIS = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [1, 1, 1]],
                 [[2, 0, 0], [3, 0, 0], [2, 0, 1]]], np.float64)


def test_the_same_triangles_in_any_order_are_the_same(check):
    # Another triangle order, each triangle's corners turned, one duplicated, one degenerate.
    other = np.concatenate([TRIS[::-1][:, [1, 2, 0]], TRIS[:1], [[[5, 5, 5]] * 3]])
    got = check.compare(TRIS, other)
    assert got["verdict"] == "same" and got["distance"] == 0.0
    assert (got["ours"], got["blender"], got["drawn_ours"], got["drawn_blender"]) == (3, 5, 3, 3)


def test_a_moved_corner_is_measured_as_a_share_of_the_diagonal(check):
    other = TRIS.copy()
    other[1, 2] += [0, 0, 0.03]
    got = check.compare(TRIS, other)
    diagonal = np.linalg.norm(np.ptp(np.concatenate([TRIS, other]).reshape(-1, 3), axis=0))
    assert got["verdict"] == "differs"
    assert got["distance"] == pytest.approx(0.03 / diagonal)
    # A missing triangle is as far as its nearest neighbour; nothing against something: inf.
    assert check.compare(TRIS, TRIS[:2])["verdict"] == "differs"
    assert check.farthest(TRIS, TRIS[:0]) == np.inf
    assert check.compare(TRIS, TRIS * np.nan)["verdict"] == "not finite"


def test_built_files_load_and_only_the_shearing_one_is_warned(check):
    for name, make in check.BUILT.items():
        scene = load_scene(make())
        assert scene.instances, name
        if name == "sheared_matrix.glb":
            (w,) = scene.warnings
            assert "shears" in w
        else:
            assert scene.warnings == [], (name, scene.warnings)


def test_animations_are_taken_out_and_nothing_else(check):
    data = (Path(check.C.models_dir()) / "Fox.glb").read_bytes()  # skinned and animated
    assert b'"animations"' in data
    stripped = check.without_animations(data)
    doc = json.loads(stripped[20:20 + struct.unpack_from("<I", stripped, 12)[0]])
    assert "animations" not in doc and doc["skins"]
    a, b = load_scene(data), load_scene(stripped)
    for pa, pb in zip(a.primitives, b.primitives, strict=True):
        np.testing.assert_array_equal(pa.positions, pb.positions)
    assert check.without_animations(b"not glTF") == b"not glTF"


def test_a_flattening_matrix_is_found_and_given_depth_back(check):
    b = check.Builder()
    mesh = b.quad()
    flat = np.diag([1.0, 0.0, 2.0, 1.0])
    thin = np.diag([1e-30, 1.0, 1.0, 1.0])
    b.node(mesh=mesh, matrix=flat.T.ravel().tolist())
    b.node(mesh=mesh, matrix=thin.T.ravel().tolist())
    b.node(mesh=mesh, matrix=np.diag([1e-3, 1.0, 1.0, 1.0]).T.ravel().tolist())
    data = b.glb()
    assert check.flattening_matrices(data) == [0, 1]
    again = check.unflattened(data, [0, 1])
    doc = json.loads(again[20:20 + struct.unpack_from("<I", again, 12)[0]])
    m0 = np.asarray(doc["nodes"][0]["matrix"]).reshape(4, 4)
    m1 = np.asarray(doc["nodes"][1]["matrix"]).reshape(4, 4)
    # The zero axis takes the direction of z x x (keeping the handedness), at 1e-3 of 2.
    np.testing.assert_allclose(m0[:3, :3], np.diag([1.0, 2e-3, 2.0]))
    np.testing.assert_allclose(m1[:3, :3], np.diag([1e-3, 1.0, 1.0]))
    assert check.flattening_matrices(again) == []
    assert len(load_scene(again).instances) == 3


def test_the_other_decoder_dying_on_a_file_costs_that_file_only(check, tmp_path):
    """A stand-in for Blender's Python: it decodes with this project's loader and dies (exit 3)
    on a file whose asset names the generator "die"."""
    fake = tmp_path / "fake_blender.py"
    fake.write_text(textwrap.dedent(f"""
        import json, sys
        import numpy as np
        sys.path.insert(0, {str(ROOT)!r})
        from bench.decoder_vs_blender import world_triangles
        for source, target in json.load(open(sys.argv[2])):
            data = open(source, "rb").read()
            if b'"generator": "die"' in data:
                sys.exit(3)
            np.save(target, world_triangles(data)[0])
            open(target + ".views.json", "w").write("[]")
    """))
    python = tmp_path / "python"
    python.write_text(f"#!/bin/sh\nexec {sys.executable} {fake} \"$@\"\n")
    python.chmod(0o755)

    def built(generator: str) -> bytes:
        b = check.Builder()
        b.doc["asset"]["generator"] = generator
        b.node(mesh=b.quad())
        return b.glb()

    files = [("a", built("ok")), ("b", built("die")), ("c", built("ok"))]
    rows = check.compare_files(str(python), files, "built", tmp_path / "work")
    assert [r["verdict"] for r in rows] == ["same", "Blender refuses", "same"]
    assert rows[1]["blender_error"] == "Blender exited with code 3"


def test_an_interpreter_without_blender_is_refused_with_the_reason(check, tmp_path):
    with pytest.raises(SystemExit, match="does not import bpy: ModuleNotFoundError"):
        check.blender_version(sys.executable)
    with pytest.raises(SystemExit, match="No such file"):
        check.blender_version(str(tmp_path / "missing"))


def test_cameras_and_lights_are_matched_by_kind_and_compared(check):
    scene = load_scene(check.cameras_and_lights())
    ours = check.scene_views(scene)
    assert sorted(v["kind"] for v in ours) == ["camera", "camera", "directional", "point",
                                               "spot"]
    spot = next(v for v in ours if v["kind"] == "spot")
    assert spot["angle"] == pytest.approx(0.5)
    theirs = list(reversed(ours))  # another order: matched by kind and place
    got = check.compare_views(ours, theirs, 10.0)
    assert got["views_verdict"] == "same" and got["view_position"] == 0.0
    turned = [dict(v) for v in theirs]
    pose = np.array(turned[0]["pose"], np.float64)
    c, s = np.cos(np.radians(0.01)), np.sin(np.radians(0.01))
    pose[:3, :3] = pose[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    turned[0]["pose"] = pose
    got = check.compare_views(ours, turned, 10.0)
    assert got["views_verdict"] == "differs" and got["view_degrees"] == pytest.approx(0.01)
    wider = [dict(v, angle=0.51) if v["kind"] == "spot" else v for v in theirs]
    assert check.compare_views(ours, wider, 10.0)["view_angle"] == pytest.approx(
        np.degrees(0.01))
    assert check.compare_views(ours, theirs[1:], 10.0)["views_verdict"] == "differs (kinds)"
