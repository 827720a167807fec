"""Mirrored instances: a node whose world matrix has a negative determinant (scale (-1, 1, 1), a
symmetric model's other half) is drawn, shaded and shadowed like the same geometry built without
a mirror.

A mirror reverses every triangle's winding, so a pass that culls back faces must swap which
winding is in front. Each mirrored scene here is compared with its *baked* twin: the same world
triangles with identity matrices and outward winding, which the renderer has always drawn right.
"""

from __future__ import annotations

import numpy as np
import pytest

from shadowmap.renderer import RenderParams, Scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.scene import Instance, Primitive, scene_from_meshes, world_bounds

pytestmark = pytest.mark.gl

CAMERA = {"eye": [0.0, 4.5, 7.5], "target": [0.0, 0.6, 0.0]}
SIZE = {"width": 320, "height": 240}
LIGHTS = {
    "directional": {"type": "directional", "direction": [0.25, -1.0, -0.45]},
    "spot": {"type": "spot", "position": [0.4, 5.5, 2.5], "target": [0, 0, 0],
             "outer_cone_deg": 50},
    # Wider than 120 degrees: rendered into cube faces like a point light.
    "wide_spot": {"type": "spot", "position": [0.4, 3.0, 1.5], "direction": [0, -1, 0],
                  "outer_cone_deg": 75},
    "point": {"type": "point", "position": [0.4, 3.5, 1.8]},
}
ENCODINGS = ["depth", "rgba8", "rgb8", "rg8", "r8"]


def _mirror(axis: int) -> np.ndarray:
    m = np.eye(4)
    m[axis, axis] = -1.0
    return m


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[[0, 0, 2, 2], [0, 2, 0, 2]] = [c, s, -s, c]
    return m


def _move(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _caster():
    """A tilted box lifted off the ground, so that its mirror image is a different shape."""
    import trimesh

    box = trimesh.creation.box(extents=(0.7, 1.0, 0.5))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.5, [0, 0, 1]))
    box.apply_translation((0.5, 1.1, 0.2))
    return box


def _with_instances(matrices: list[np.ndarray], name: str) -> Scene:
    """A ground plane and one caster primitive placed by each of ``matrices``."""
    scene = scene_from_meshes([T._plane(9.0), _caster()], ["ground", "caster"])
    local = scene.primitives[1].local_bounds.astype(np.float64)
    scene.instances[1:] = [
        Instance(1, m, name=f"caster_{k}", bounds=world_bounds(local, m))
        for k, m in enumerate(matrices)
    ]
    # The content key covers positions, not node matrices: keep the upload caches apart.
    scene.key = f"{scene.key}:{name}"
    return scene


def _baked(scene: Scene) -> Scene:
    """The same world triangles, each instance its own primitive with an identity matrix and
    outward (counter-clockwise) winding: what the mirrored scene must look like."""
    prims, insts = [], []
    for k, inst in enumerate(scene.instances):
        prim = scene.primitives[inst.primitive]
        m = inst.matrix
        pos = prim.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        nrm = prim.normals.astype(np.float64) @ np.linalg.inv(m[:3, :3])  # inverse transpose
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        idx = prim.indices[:, ::-1] if np.linalg.det(m[:3, :3]) < 0 else prim.indices
        prims.append(Primitive(pos.astype(np.float32), nrm.astype(np.float32),
                               np.ascontiguousarray(idx), prim.material, prim.uv, prim.colors,
                               prim.name))
        insts.append(Instance(k, np.eye(4), inst.cast_shadow, inst.receive_shadow, inst.name,
                              np.stack([pos.min(axis=0), pos.max(axis=0)])))
    return Scene(prims, insts, key=f"{scene.key}:baked")


def single_mirror() -> Scene:
    """One caster and its mirror image across x = 0 (scale (-1, 1, 1))."""
    return _with_instances([np.eye(4), _move(-0.3) @ _mirror(0)], "single")


def nested_mirrors() -> Scene:
    """Casters under chains of node matrices with one, two and three mirrors (determinant
    negative, positive, negative), a mirror with non-uniform scale, and mirrored instances before
    unmirrored ones in scene order."""
    chains = [
        _move(-2.6, 0, -0.6) @ _mirror(0),                                   # one: det < 0
        _move(-1.2, 0, 0.4) @ _mirror(0) @ _rot_y(0.7) @ _mirror(2),          # two: det > 0
        _move(0.0, 0, -0.8),                                                 # none
        _move(1.3, 0, 0.5) @ _mirror(2) @ _rot_y(-0.4) @ _mirror(0) @ _mirror(2),  # three
        _move(2.6, 0, -0.4) @ np.diag([1.0, 0.8, -1.3, 1.0]),               # scaled mirror
    ]
    return _with_instances(chains, "nested")


@pytest.fixture(scope="module")
def scenes() -> dict[str, tuple[Scene, Scene]]:
    out = {}
    for build in (single_mirror, nested_mirrors):
        scene = build()
        out[build.__name__] = (scene, _baked(scene))
    return out


def _compare(renderer, scenes, which: str, **params):
    mirrored, baked = scenes[which]
    p = RenderParams(camera=CAMERA, **SIZE, **params)
    a = T.measure(renderer, baked, p)
    b = T.measure(renderer, mirrored, p)
    for ma, mb in zip(a.metrics, b.metrics, strict=True):
        assert ma.iou >= 0.95, ma
        assert mb.iou >= 0.95, mb
        assert abs(ma.iou - mb.iou) <= 0.01, (ma, mb)
    return a, b


def test_mirrored_scenes_really_mirror():
    dets = [np.linalg.det(i.matrix[:3, :3]) for i in nested_mirrors().instances[1:]]
    assert [d < 0 for d in dets] == [True, False, False, True, True]


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("light", ["directional", "spot", "wide_spot", "point"])
def test_nested_mirrors_every_light_and_encoding(renderer, scenes, light, encoding):
    _, b = _compare(renderer, scenes, "nested_mirrors", lights=[LIGHTS[light]],
                    shadows={"encoding": encoding})
    kind = {"directional": "ortho", "spot": "perspective"}.get(light, "cube")
    assert b.result.plan["lights"][0]["shadow_map"] == kind


@pytest.mark.parametrize("light", ["directional", "spot", "point"])
@pytest.mark.parametrize("shadows", [
    {"filter": "hard"},
    {"filter": "hard", "encoding": "rgba8"},
    {"filter": "pcf", "pcf_kernel": 3},
    {"filter": "pcf", "pcf_kernel": 3, "encoding": "r8"},
    {"bias": {"normal_offset": 1.5, "slope": 2.0, "slope_max": 5.0}},
    {"bias": {"normal_offset": 1.0, "polygon_offset": [1.0, 2.0]}, "encoding": "rg8"},
], ids=["hard", "hard-rgba8", "pcf3", "pcf3-r8", "normal-offset-slope", "offsets-rg8"])
def test_mirrors_with_every_filter_and_bias(renderer, scenes, light, shadows):
    _compare(renderer, scenes, "nested_mirrors", lights=[LIGHTS[light]], shadows=shadows)


@pytest.mark.parametrize("light", ["directional", "spot", "point"])
def test_single_mirror_is_shaded_like_its_baked_twin(renderer, scenes, light):
    a, b = _compare(renderer, scenes, "single_mirror", lights=[LIGHTS[light]],
                    outputs=["color", "visibility", "depth"])
    # The same surfaces are drawn (no inside faces) and lit from the same side: the colour and
    # the depth agree up to float rounding at edges.
    diff = np.abs(a.result.color.astype(int) - b.result.color.astype(int)).max(axis=2)
    assert np.mean(diff > 2) < 0.002
    da, db = a.result.depth, b.result.depth
    both = np.isfinite(da) & np.isfinite(db)
    assert np.mean(np.isfinite(da) != np.isfinite(db)) < 0.002
    np.testing.assert_allclose(da[both], db[both], rtol=1e-4)


@pytest.fixture(scope="module")
def loaded() -> tuple[Scene, Scene]:
    """A binary glTF whose nodes mirror the caster (scale -1 on x; three nested mirrors), loaded
    as a user's file would be, and its baked twin."""
    import trimesh

    from shadowmap.renderer import load_scene

    tm = trimesh.Scene()
    tm.add_geometry(T._plane(9.0), node_name="ground")
    caster = _caster()
    three = _move(1.3, 0, 0.5) @ _mirror(2) @ _rot_y(-0.4) @ _mirror(0) @ _mirror(2)
    for k, m in enumerate([np.eye(4), _move(-0.3) @ _mirror(0), three]):
        tm.add_geometry(caster, geom_name="caster", node_name=f"caster_{k}", transform=m)
    scene = load_scene(tm.export(file_type="glb"), file_type="glb")
    assert sum(np.linalg.det(i.matrix[:3, :3]) < 0 for i in scene.instances) == 2
    return scene, _baked(scene)


@pytest.mark.parametrize("light", ["directional", "spot", "point"])
def test_mirrored_nodes_of_a_gltf_file(renderer, loaded, light):
    _compare(renderer, {"file": loaded}, "file", lights=[LIGHTS[light]])


def test_two_lights_of_different_kinds(renderer, scenes):
    _compare(renderer, scenes, "nested_mirrors", lights=[LIGHTS["spot"], LIGHTS["point"]])


def test_reference_traces_mirrored_instances_like_their_baked_twin(renderer, scenes):
    from shadowmap.renderer.camera import resolve_camera
    from shadowmap.renderer.lights import resolve_lights
    from shadowmap.renderer.params import light_params
    from shadowmap.renderer.reference import trace_reference

    mirrored, baked = scenes["nested_mirrors"]
    params = [light_params(LIGHTS[k]) for k in ("directional", "spot", "point")]
    camera = resolve_camera(RenderParams(camera=CAMERA).camera, baked, 320, 240)
    a = trace_reference(baked, camera, resolve_lights(params, baked))
    b = trace_reference(mirrored, camera, resolve_lights(params, mirrored))
    # The shadow rays see the same triangles whatever their winding; only float rounding of the
    # transformed vertices may move an edge pixel.
    assert np.mean(a.valid != b.valid) < 0.001
    both = a.valid & b.valid
    assert np.mean(a.visibility[both] != b.visibility[both]) < 0.001
    assert (a.visibility[both] == 0).sum() > 1000  # there are shadows to compare


def test_upload_keeps_each_winding_in_one_run(renderer, scenes):
    from OpenGL import GL

    from shadowmap.renderer.gl.resources import GpuScene

    mirrored, _ = scenes["nested_mirrors"]
    renderer.context.make_current()
    gpu = GpuScene.upload(mirrored)
    try:
        gp = gpu.primitives[gpu.slot_of[1][0]]
        # Scene order has mirrored casters first; the buffer puts the unmirrored ones first.
        assert gp.mirrored == 3 and gp.mirrored_from == 2
        assert gp.instances.tolist() == [2, 3, 1, 4, 5]
        for slot, inst in enumerate(gp.instances):
            assert gpu.slot_of[inst][1] == slot
        ground = gpu.primitives[gpu.slot_of[0][0]]
        assert ground.mirrored == 0
    finally:
        gpu.release()
    assert GL.glGetIntegerv(GL.GL_FRONT_FACE) == GL.GL_CCW


def test_front_face_is_restored_after_a_frame(renderer, scenes):
    from OpenGL import GL

    mirrored, _ = scenes["single_mirror"]
    renderer.render(mirrored, RenderParams(camera=CAMERA, **SIZE, lights=[LIGHTS["spot"]]))
    assert GL.glGetIntegerv(GL.GL_FRONT_FACE) == GL.GL_CCW
