"""trimesh objects as scenes: what pyrender users hold goes straight into the renderer."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shadowmap import RenderParams, SceneError, scene_from_meshes, scene_from_trimesh
from shadowmap.renderer.scene import is_trimesh

LIGHT = {"type": "directional", "direction": [-0.3, -1.0, -0.2]}
CAMERA = {"eye": [0.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}


def _shelf() -> trimesh.Scene:
    """Two nodes drawing one box geometry, a third box drawn once, over a ground that casts no
    shadow (``castShadow`` in the geometry's glTF extras, where trimesh keeps a file's)."""
    scene = trimesh.Scene()
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    scene.add_geometry(box, node_name="left", geom_name="box",
                       transform=trimesh.transformations.translation_matrix([-1.5, 0.5, 0]))
    scene.graph.update(frame_to="right", frame_from=scene.graph.base_frame, geometry="box",
                       matrix=trimesh.transformations.translation_matrix([1.5, 0.5, 0]))
    tall = trimesh.creation.box((0.4, 2.0, 0.4))
    scene.add_geometry(tall, node_name="post", geom_name="post",
                       transform=trimesh.transformations.translation_matrix([0, 1.0, 1.5]))
    ground = trimesh.creation.box((10.0, 0.1, 10.0))
    ground.apply_translation([0, -0.05, 0])
    ground.metadata["extras"] = {"castShadow": False}
    scene.add_geometry(ground, node_name="ground", geom_name="ground")
    return scene


def test_a_trimesh_scene_keeps_its_graph():
    s = scene_from_trimesh(_shelf())
    names = [i.name for i in s.instances]
    assert sorted(names) == ["ground", "left", "post", "right"]
    assert len(s.primitives) == 3  # the box twice by two nodes is one primitive
    by = {i.name: i for i in s.instances}
    assert by["left"].primitive == by["right"].primitive != by["post"].primitive
    assert np.allclose(by["right"].matrix[:3, 3], [1.5, 0.5, 0])
    assert np.allclose(by["right"].bounds, [[1.0, 0.0, -0.5], [2.0, 1.0, 0.5]])
    assert not by["ground"].cast_shadow and by["ground"].receive_shadow
    assert by["post"].cast_shadow
    assert np.allclose(s.bounds, [[-5, -0.1, -5], [5, 2.0, 5]])


def test_keys_follow_content():
    """The key (which the upload cache uses) changes with a colour or a transform, not with a
    new but equal object."""
    a, b = scene_from_trimesh(_shelf()), scene_from_trimesh(_shelf())
    assert a.key == b.key and a.key.startswith("built:")
    moved = _shelf()
    moved.graph.update(frame_to="post", matrix=trimesh.transformations.translation_matrix(
        [0, 1.0, 1.6]))
    assert scene_from_trimesh(moved).key != a.key
    red = _shelf()
    red.geometry["post"].visual.face_colors = [255, 0, 0, 255]
    assert scene_from_trimesh(red).key != a.key


def test_keys_follow_every_part_of_a_material():
    """Texels of one count and bytes in another shape, the sampler and unlit are content too."""
    import dataclasses

    from shadowmap.renderer.scene import Sampler, _built_key

    base = scene_from_trimesh(_shelf())
    prim = base.primitives[0]
    texels = np.arange(64, dtype=np.uint8).reshape(4, 4, 4)

    def key(**material) -> str:
        changed = dataclasses.replace(prim, material=dataclasses.replace(prim.material,
                                                                         **material))
        return _built_key([changed, *base.primitives[1:]], base.instances)

    keys = [key(texture=texels), key(texture=texels.reshape(2, 8, 4)),
            key(texture=texels, sampler=Sampler(wrap_s=33071)), key(unlit=True), key()]
    assert len(set(keys)) == len(keys)


def test_refusals_and_warnings():
    empty = trimesh.Scene()
    with pytest.raises(SceneError, match="no triangles"):
        scene_from_trimesh(empty)
    with_points = _shelf()
    with_points.add_geometry(trimesh.PointCloud(np.zeros((3, 3))), node_name="dots")
    s = scene_from_trimesh(with_points)
    assert any("dots" in w and "PointCloud" in w for w in s.warnings)
    bad = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], faces=[[0, 1, 2]],
                          process=False)
    with pytest.raises(SceneError, match="NaN"):
        scene_from_trimesh(bad)
    # Past float32's range the GPU's positions would be infinite (and the scene's box NaN).
    huge = trimesh.Trimesh(vertices=[[0, 0, 0], [1e39, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]],
                           process=False)
    with pytest.raises(SceneError, match=r"beyond float32's range \(1e\+39; at most 3.4e\+38\)"):
        scene_from_trimesh(huge)
    with pytest.raises(SceneError, match="not a trimesh"):
        scene_from_trimesh("box.glb")
    box = trimesh.creation.box()
    for meshes, names, text in (([trimesh.PointCloud(np.zeros((3, 3)))], None,
                                 "mesh 0 is a PointCloud, not a trimesh.Trimesh"),
                                ([box, box], ["a"], "1 names for 2 meshes"),
                                ("box", None, "must be a list of trimesh.Trimesh, not a str")):
        with pytest.raises(SceneError, match=text):
            scene_from_meshes(meshes, names)
    assert scene_from_meshes((box,), ["b"]).instances[0].name == "b"
    assert is_trimesh(trimesh.creation.box()) and not is_trimesh(b"glTF")


@pytest.mark.gl
def test_renders_a_trimesh_scene_against_the_reference(renderer):
    """``Renderer.render`` takes the trimesh scene itself, and its shadows match the ray-traced
    reference of the same geometry; a bare ``Trimesh`` renders too."""
    from shadowmap.renderer import testing as T

    shelf = _shelf()
    direct = renderer.render(shelf, {"lights": [LIGHT], "camera": CAMERA,
                                     "outputs": ["visibility"]})
    m = T.measure(renderer, scene_from_trimesh(shelf),
                  RenderParams(lights=[LIGHT], camera=CAMERA))
    assert m.metrics[0].iou >= 0.97 and m.metrics[0].pixels > 100_000
    assert np.array_equal(np.nan_to_num(direct.visibility, nan=-1),
                          np.nan_to_num(m.result.visibility, nan=-1))
    assert direct.plan["lights"][0]["casters"] == 3  # the ground casts nothing
    one = renderer.render(trimesh.creation.icosphere(), {"width": 64, "height": 48})
    assert one.color.shape == (48, 64, 3)


@pytest.mark.parametrize("limit, value, text", [
    ("max_primitives", 5, "has 6 geometries, over the limit of 5"),
    ("max_instances", 8, "has 9 nodes drawing geometry, over the limit of 8"),
    ("max_triangles", 100, "draws 108 triangles, over the limit of 100"),
])
def test_a_trimesh_scene_over_a_count_is_refused_before_conversion(renderer, limit, value, text,
                                                                  monkeypatch):
    """The counts come from the graph: no mesh is converted (that loop is the expensive part;
    the service's limits used to be checked only after it, and only for triangles)."""
    from shadowmap.renderer import LimitError, Limits
    from shadowmap.renderer import scene as scene_module

    scene = trimesh.Scene()
    box = trimesh.creation.box()  # 12 triangles
    for i in range(6):
        scene.add_geometry(box.copy(), geom_name=f"g{i}", node_name=f"n{i}")
    for i in range(3):  # three more nodes drawing g0: 9 nodes, 108 triangles
        scene.graph.update(frame_to=f"again{i}", frame_from=scene.graph.base_frame,
                           geometry="g0")
    assert len(scene.geometry) == 6 and len(scene.graph.nodes_geometry) == 9
    converted = []
    monkeypatch.setattr(scene_module, "_primitive_from_trimesh",
                        lambda *a: converted.append(a) or pytest.fail("a mesh was converted"))
    with pytest.raises(LimitError, match=text) as info:
        scene_from_trimesh(scene, Limits(**{limit: value}))
    assert info.value.limit == limit and not converted
