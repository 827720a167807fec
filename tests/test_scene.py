"""Loading glTF: every model, external resources, and clear errors for bad or unsafe files."""

from __future__ import annotations

import base64
import json
import os
from pathlib import PurePosixPath

import numpy as np
import pytest
import trimesh

from shadowmap.renderer import LimitError, Limits, SceneError, load_scene
from shadowmap.renderer.scene import MappingResolver

MODELS = ["AlphaBlendModeTest.glb", "BoxTextured.glb", "CesiumMilkTruck.glb", "Duck.glb",
          "cube.glb"]


@pytest.mark.parametrize("name", MODELS)
def test_every_binary_model_loads(models, name):
    scene = load_scene(models / name)
    assert scene.triangle_count > 0
    lo, hi = scene.bounds
    assert np.all(hi > lo)
    for prim in scene.primitives:
        assert prim.normals.shape == prim.positions.shape
        np.testing.assert_allclose(np.linalg.norm(prim.normals, axis=1), 1.0, atol=1e-3)


def test_sources_are_paths_or_bytes(models):
    """A path (str or os.PathLike) or anything holding bytes loads; other values, a NUL in a
    path, and trimesh geometry that is not a mesh or scene are SceneErrors, not crashes."""
    path = models / "Duck.glb"
    data = path.read_bytes()
    key = load_scene(data).key
    for source in (str(path), PurePosixPath(path), bytearray(data), memoryview(data),
                   np.frombuffer(data, np.uint8)):
        assert load_scene(source).key == key, type(source)
    for source, text in ((None, "NoneType"), (10**12, "int"), (1.5, "float"),
                         (trimesh.PointCloud(np.zeros((3, 3))), "PointCloud")):
        with pytest.raises(SceneError, match=f"cannot load a scene from a value of type {text}: "
                           "give a path, a .glb or .gltf file's bytes"):
            load_scene(source)
    with pytest.raises(SceneError, match="embedded null byte"):
        load_scene(str(path) + "\0")
    with pytest.raises(SceneError, match="Is a directory"):
        load_scene(models)


def test_files_that_are_no_regular_files_are_refused_before_reading(models, tmp_path):
    """A FIFO would block the read until something writes to it, a device such as /dev/zero
    would never end it: each is a SceneError at once, for the scene and for a file a .gltf
    names; a file over ``max_request_bytes`` is a LimitError before it is read."""
    os.mkfifo(tmp_path / "pipe.glb")
    (tmp_path / "zero.glb").symlink_to("/dev/zero")
    for name, kind in (("pipe.glb", "a FIFO"), ("zero.glb", "a device")):
        with pytest.raises(SceneError, match=f"{name} is {kind}, not a regular file"):
            load_scene(tmp_path / name)
    os.mkfifo(tmp_path / "buf.bin")
    (tmp_path / "res.gltf").write_text(json.dumps(
        {"asset": {"version": "2.0"}, "buffers": [{"uri": "buf.bin", "byteLength": 4}]}))
    with pytest.raises(SceneError, match=r"buffer 0 \(buf.bin beside res.gltf\) is a FIFO"):
        load_scene(tmp_path / "res.gltf")
    duck = models / "Duck.glb"
    size = duck.stat().st_size
    with pytest.raises(LimitError, match=f"holds {size} bytes, over the {size - 1}") as info:
        load_scene(duck, limits=Limits(max_request_bytes=size - 1))
    assert info.value.limit == "max_request_bytes"
    assert load_scene(duck, limits=Limits(max_request_bytes=10 * size)).triangle_count > 0


def test_a_scenes_content_cannot_change_in_place(models):
    """A renderer keeps what it read of a scene (its upload, instance arrays and plans): an
    array changed in place drew the old content, unsaid. The arrays of a loaded or built scene
    are read-only and its primitives and materials frozen, so such a change raises instead."""
    import dataclasses

    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes, scene_from_trimesh

    box = trimesh.creation.box()
    for scene in (load_scene(models / "Duck.glb"), load_scene(models / "Duck.glb").with_ground(),
                  scene_from_trimesh(trimesh.Scene([box])), scene_from_meshes([box])):
        prim, inst = scene.primitives[0], scene.instances[-1]
        for array in (prim.positions, prim.normals, prim.indices, prim.material.base_color,
                      inst.matrix, inst.bounds):
            with pytest.raises(ValueError, match="read-only"):
                array[0] = 1
        with pytest.raises(dataclasses.FrozenInstanceError):
            prim.positions = prim.positions * 2  # type: ignore[misc]
    assert box.vertices.flags.writeable  # trimesh's own arrays are left as they were


def test_node_transforms_are_applied(models):
    # Duck's mesh is in centimetres under a node scaled by 0.01.
    duck = load_scene(models / "Duck.glb")
    assert np.max(duck.bounds[1] - duck.bounds[0]) < 3.0
    assert np.max(duck.primitives[0].local_bounds[1] - duck.primitives[0].local_bounds[0]) > 100


def test_file_camera_is_read_with_its_node_transform(models):
    duck = load_scene(models / "Duck.glb")
    (cam,) = duck.cameras
    assert cam.yfov > 0 and np.allclose(cam.pose[3], [0, 0, 0, 1])
    # The camera looks at the duck: its -Z axis points toward the scene's centre.
    to_centre = duck.bounds.mean(axis=0) - cam.pose[:3, 3]
    assert np.dot(-cam.pose[:3, 2], to_centre / np.linalg.norm(to_centre)) > 0.8


def test_gltf_with_external_buffer_needs_the_buffer(models):
    data = (models / "TestScene.gltf").read_bytes()
    scene = load_scene(data, resources={"TestScene.bin": (models / "TestScene.bin").read_bytes()})
    assert len(scene.instances) > 1
    with pytest.raises(SceneError, match="not provided"):
        load_scene(data)


def _gltf_with_uri(uri: str) -> bytes:
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": uri, "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    return json.dumps(doc).encode()


def test_embedded_data_uri_gltf_loads():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    uri = "data:application/octet-stream;base64," + base64.b64encode(tri).decode()
    scene = load_scene(_gltf_with_uri(uri))
    assert scene.triangle_count == 1


@pytest.mark.parametrize("uri", ["../secret.bin", "/etc/passwd", "file:///etc/passwd",
                                 "http://example.com/a.bin", "sub/../../x.bin", "C:/x.bin"])
def test_unsafe_uris_are_refused(uri):
    with pytest.raises(SceneError, match="refusing|outside|not provided"):
        load_scene(_gltf_with_uri(uri), resources={"x.bin": b"\0" * 36})


def test_resolver_never_reads_the_filesystem(tmp_path):
    (tmp_path / "a.bin").write_bytes(b"1234")
    resolver = MappingResolver({"a.bin": b"abcd"})
    assert resolver.get("a.bin") == b"abcd"
    with pytest.raises(SceneError):
        resolver.get(str(tmp_path / "a.bin"))


@pytest.mark.parametrize(
    "data, message",
    [
        (b"", "empty"),
        (b"glTF\x02\x00\x00\x00\xff\xff\xff\x00", "binary glTF|truncated|corrupt"),
        (b"NOTGLTF" + b"\0" * 40, "JSON"),
        (b'{"asset": {"version": "1.0"}}', "version"),
        (b'{"nodes": []}', "asset"),
        (b'{"asset": {"version": "2.0"}}', "no triangles"),
    ],
)
def test_bad_files_raise_scene_error(data, message):
    with pytest.raises(SceneError, match=message):
        load_scene(data)


def test_truncated_binary_gltf(models):
    data = (models / "Duck.glb").read_bytes()
    for cut in (12, 100, len(data) // 2):
        with pytest.raises(SceneError):
            load_scene(data[:cut], file_type="glb")


def test_triangle_limit(models):
    with pytest.raises(LimitError) as info:
        load_scene(models / "Duck.glb", limits=Limits(max_triangles=100))
    assert info.value.limit == "max_triangles"


def test_khr_lights_punctual_are_read():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    doc = json.loads(_gltf_with_uri("data:application/octet-stream;base64,"
                                    + base64.b64encode(tri).decode()))
    doc["extensionsUsed"] = ["KHR_lights_punctual"]
    doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "spot", "intensity": 2.0, "spot": {"outerConeAngle": 0.5}}]}}
    doc["nodes"].append({"translation": [0, 5, 0], "rotation": [-0.7071068, 0, 0, 0.7071068],
                         "extensions": {"KHR_lights_punctual": {"light": 0}}})
    doc["scenes"][0]["nodes"].append(1)
    scene = load_scene(json.dumps(doc).encode())
    (light,) = scene.lights
    assert light.type == "spot" and light.outer_cone == 0.5
    np.testing.assert_allclose(light.pose[:3, 3], [0, 5, 0])
    np.testing.assert_allclose(-light.pose[:3, 2], [0, -1, 0], atol=1e-6)  # looks down


@pytest.mark.gl
def test_vertex_colours_reach_the_picture(renderer):
    import trimesh

    from shadowmap.renderer import RenderParams

    box = trimesh.creation.box(extents=(1, 1, 1))
    box.unmerge_vertices()
    box.visual = trimesh.visual.ColorVisuals(
        box, vertex_colors=np.tile([255, 0, 0, 255], (len(box.vertices), 1)))
    scene = trimesh.Scene(box)
    loaded = load_scene(scene.export(file_type="glb"))
    prim = loaded.primitives[0]
    assert prim.colors is not None and np.allclose(prim.colors[:, :3], [1, 0, 0], atol=0.01)
    r = renderer.render(loaded, RenderParams(lights=[{"direction": [-0.3, -1, -0.5]}],
                                             ambient=[0.5] * 3, background=[0, 0, 0, 1],
                                             width=64, height=48))
    covered = r.color.sum(axis=2) > 0
    red, green = r.color[..., 0][covered].astype(int), r.color[..., 1][covered].astype(int)
    assert covered.mean() > 0.1 and np.all(red > green + 50)
