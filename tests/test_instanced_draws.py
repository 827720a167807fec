"""Drawing many instances: culled instances leave scattered slots, drawn as runs in one
multi-draw per winding; per-instance flags reach the shader; the per-scene arrays the upload and
the passes read equal what the scene's instances say."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maps import assert_same_but_silhouettes
from shadowmap.renderer import RenderParams, Scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.scene import Instance, Primitive, instance_arrays, world_bounds

pytestmark = pytest.mark.gl

PITCH = 1.5
LIGHT = {"type": "directional", "direction": [-0.45, -1.0, -0.3]}
ALL = ["color", "visibility", "depth", "light_depth"]


def _box_primitive(name: str) -> Primitive:
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    mesh = trimesh.creation.box(extents=(0.6, 1.0, 0.6))
    mesh.apply_translation((0.0, 0.5, 0.0))
    return scene_from_meshes([mesh], [name]).primitives[0]


def field(n: int, seed: int = 11) -> Scene:
    """``n`` boxes on a grid over a ground plane: two primitives interleaved in scene order,
    turned and stretched at random, every third one mirrored (so its slot is far from its
    neighbours' in the instance buffer)."""
    rng = np.random.default_rng(seed)
    ground = T.caster_on_ground().primitives[0]
    prims = [ground, _box_primitive("a"), _box_primitive("b")]
    side = math.ceil(math.sqrt(n))
    scale = side * PITCH / 6.0  # the test ground plane is 6 wide
    ground_matrix = np.diag([scale, 1.0, scale, 1.0])
    instances = [Instance(0, ground_matrix, cast_shadow=False, name="ground",
                          bounds=world_bounds(prims[0].local_bounds.astype(np.float64),
                                              ground_matrix))]
    for k in range(n):
        yaw = rng.uniform(0, 2 * math.pi)
        c, s = math.cos(yaw), math.sin(yaw)
        m = np.array([[c, 0, s, 0], [0, rng.uniform(1.0, 1.6), 0, 0], [-s, 0, c, 0],
                      [0, 0, 0, 1.0]])
        if k % 3 == 2:
            m = m @ np.diag([-1.0, 1.0, 1.0, 1.0])
        m[0, 3] = (k % side - (side - 1) / 2) * PITCH
        m[2, 3] = (k // side - (side - 1) / 2) * PITCH
        p = 1 + k % 2
        instances.append(Instance(p, m, name=f"box_{k}",
                                  bounds=world_bounds(prims[p].local_bounds.astype(np.float64),
                                                      m)))
    return Scene(prims, instances, key=f"test-field:{n}:{seed}")


@pytest.fixture(scope="module")
def boxes() -> Scene:
    return field(1600)


def corner(n: int) -> dict:
    """Looking down at one corner of the field: a few hundred boxes in view, in short rows."""
    c = -math.ceil(math.sqrt(n)) * PITCH / 2
    return {"eye": [c + 14, 22.0, c + 4], "target": [c + 14, 0.0, c + 16]}


def _spy_multi_draws(monkeypatch) -> list[int]:
    """Record the number of commands of every glMultiDrawElementsIndirect."""
    from shadowmap.renderer.gl import resources

    seen: list[int] = []
    draw = resources.IndirectBuffer.draw

    def spy(self, commands):
        seen.append(len(commands))
        return draw(self, commands)

    monkeypatch.setattr(resources.IndirectBuffer, "draw", spy)
    return seen


def test_culled_instances_render_like_the_unculled_frame(renderer, boxes, monkeypatch):
    params = {"width": 320, "height": 240, "camera": corner(1600), "lights": [LIGHT],
              "outputs": ALL}
    seen = _spy_multi_draws(monkeypatch)
    on = renderer.render(boxes, RenderParams(optimize=True, **params))
    assert seen and max(seen) > 10  # scattered slots: many runs in one multi-draw
    drawn = on.plan["camera_pass"]["drawn"]
    assert 100 < drawn < 1000 and on.plan["camera_pass"]["skipped"]["outside_view"] > 600
    off = renderer.render(boxes, RenderParams(optimize=False, **params))
    assert off.plan["camera_pass"]["drawn"] == len(boxes.instances)
    # The generic variant of optimize=False may round a colour differently by one.
    assert np.max(np.abs(on.color.astype(int) - off.color.astype(int))) <= 1
    np.testing.assert_array_equal(on.visibility, off.visibility)
    np.testing.assert_array_equal(on.depth, off.depth)
    assert (on.visibility == 0).sum() > 1000  # shadows to compare
    # The closed boxes' far faces are left out with optimize: the maps agree but at silhouettes.
    for a, b in zip(on.light_depth, off.light_depth, strict=True):
        assert_same_but_silhouettes(a.depth, b.depth)


def test_one_call_per_run_draws_the_same_frame(renderer, boxes):
    """The multi-draw and the fallback for contexts without it (one call per run) agree."""
    params = RenderParams(width=320, height=240, camera=corner(1600), lights=[LIGHT],
                          outputs=ALL)
    multi = renderer.render(boxes, params)
    gpu, kept, _ = renderer._upload(boxes)
    assert kept
    saved = [gp.indirect for gp in gpu.primitives]
    assert all(ind is not None for ind in saved)  # GL 4.3 or newer: see init_egl_context
    try:
        for gp in gpu.primitives:
            gp.indirect = None
        single = renderer.render(boxes, params)
    finally:
        for gp, ind in zip(gpu.primitives, saved, strict=True):
            gp.indirect = ind
    for k in ("color", "visibility", "depth"):
        np.testing.assert_array_equal(getattr(multi, k), getattr(single, k))


def test_upload_slots_follow_primitives_and_windings(renderer, boxes):
    from shadowmap.renderer.gl.resources import GpuScene

    renderer.context.make_current()
    gpu = GpuScene.upload(boxes)
    try:
        assert [gp.primitive for gp in gpu.primitives] == [0, 1, 2]
        arrays = instance_arrays(boxes)
        for g, gp in enumerate(gpu.primitives):
            ids = gp.instances
            assert np.all(arrays.primitive[ids] == gp.primitive)
            dets = np.linalg.det(arrays.matrices[ids, :3, :3])
            assert np.all(dets[:gp.mirrored_from] > 0) and np.all(dets[gp.mirrored_from:] < 0)
            # Scene order within each winding.
            assert np.all(np.diff(ids[:gp.mirrored_from]) > 0)
            assert np.all(np.diff(ids[gp.mirrored_from:]) > 0)
            np.testing.assert_array_equal(gpu.prim_of[ids], g)
            np.testing.assert_array_equal(gpu.slot[ids], np.arange(len(ids)))
            assert gpu.slot_of[int(ids[-1])] == (g, len(ids) - 1)
        # Groups keep the order in which the instances first reach them.
        groups = gpu.groups([5, 2, 7, 0, 4])
        assert [(p, flag) for p, flag, _ in groups] == [(1, False), (2, False), (0, False)]
        assert groups[0][2].tolist() == [gpu.slot[5], gpu.slot[7]]
        runs = gpu.runs([5, 7, 2, 4, 9])
        assert [p for p, _, _ in runs] == [1, 2, 1]
    finally:
        gpu.release()


def test_poses_are_exactly_the_shifted_matrices(renderer, boxes):
    """``M - origin`` in the translation is bit for bit ``T(-origin) @ M`` of affine matrices."""
    from shadowmap.renderer.gl.resources import GpuScene

    renderer.context.make_current()
    gpu = GpuScene.upload(boxes)
    try:
        shift = np.eye(4)
        shift[:3, 3] = -gpu.origin
        for gp in gpu.primitives:
            expected = np.stack([shift @ boxes.instances[i].matrix for i in gp.instances])
            assert np.array_equal(gp.mesh.read_poses(), expected.astype(np.float32))
    finally:
        gpu.release()


def test_a_new_origin_rewrites_every_instance_buffer(renderer, boxes):
    """``set_origin`` writes ``T(-origin) @ M`` again into every primitive's instance buffer,
    computed in float64: far from the scene's centre the float32 matrices keep the small
    offsets that the ones relative to the centre rounded away. The same origin writes
    nothing."""
    from shadowmap.renderer.gl.resources import GpuScene

    renderer.context.make_current()
    gpu = GpuScene.upload(boxes)
    try:
        centre = gpu.origin.copy()
        far = np.array([1e7 + 0.25, -3e6 + 0.125, 0.5])
        gpu.set_origin(far)
        assert np.array_equal(gpu.origin, far) and not gpu.origin.flags.writeable
        for gp in gpu.primitives:
            shift = np.eye(4)
            shift[:3, 3] = -far
            expected = np.stack([shift @ boxes.instances[i].matrix for i in gp.instances])
            assert np.array_equal(gp.mesh.read_poses(), expected.astype(np.float32))
        before = [gp.mesh.read_poses() for gp in gpu.primitives]
        gpu.set_origin(far.copy())
        assert all(np.array_equal(gp.mesh.read_poses(), b)
                   for gp, b in zip(gpu.primitives, before, strict=True))
        gpu.set_origin(centre)
        shift = np.eye(4)
        shift[:3, 3] = -centre
        gp = gpu.primitives[0]
        expected = np.stack([shift @ boxes.instances[i].matrix for i in gp.instances])
        assert np.array_equal(gp.mesh.read_poses(), expected.astype(np.float32))
    finally:
        gpu.release()


def _flagged(split: bool) -> Scene:
    """A board overhead shading a row of boxes of one primitive whose receive flags alternate;
    with ``split``, the non-receivers are a second primitive (the same data): drawn apart."""
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    base = scene_from_meshes([T._plane(8.0), trimesh.creation.box(extents=(3.0, 0.1, 3.0)),
                              trimesh.creation.box(extents=(0.5, 0.5, 0.5))],
                             ["ground", "board", "box"])
    prims = list(base.primitives)
    box = prims[2]
    prims.append(Primitive(box.positions, box.normals, box.indices, box.material, name="box2"))
    board = np.eye(4)
    board[1, 3] = 2.5
    insts = [base.instances[0],
             Instance(1, board, bounds=world_bounds(prims[1].local_bounds.astype(float), board))]
    local = box.local_bounds.astype(np.float64)
    for k in range(6):
        m = np.eye(4)
        m[:3, 3] = (-1.5 + 0.6 * k, 0.25, 0.2 * (k % 2))
        receive = k % 3 != 1
        p = 3 if split and not receive else 2
        insts.append(Instance(p, m, receive_shadow=receive, name=f"box_{k}",
                              bounds=world_bounds(local, m)))
    return Scene(prims, insts, key=f"flags:{split}")


def test_receive_shadow_is_each_instances_own(renderer):
    params = RenderParams(width=240, height=180, lights=[{"direction": [0.0, -1.0, -0.1]}],
                          camera={"eye": [0.0, 3.5, 4.5], "target": [0.0, 0.3, 0.0]},
                          outputs=["color", "visibility"])
    one = renderer.render(_flagged(False), params)
    apart = renderer.render(_flagged(True), params)
    np.testing.assert_array_equal(one.visibility, apart.visibility)
    np.testing.assert_array_equal(one.color, apart.color)
    vis = one.visibility[..., 0]
    # Both kinds are seen under the board: shadowed receivers, lit non-receivers.
    assert (vis == 0).sum() > 500 and (vis == 1).sum() > 500


# --------------------------------------------------------------------------------------------
# Per-scene arrays and the grounded-scene cache
# --------------------------------------------------------------------------------------------


def test_scene_arrays_equal_the_instances(boxes):
    arrays = instance_arrays(boxes)
    assert arrays is instance_arrays(boxes)
    np.testing.assert_array_equal(arrays.matrices, np.stack([i.matrix for i in boxes.instances]))
    np.testing.assert_array_equal(arrays.bounds, np.stack([i.bounds for i in boxes.instances]))
    b = np.stack([i.bounds for i in boxes.instances])
    np.testing.assert_array_equal(boxes.bounds, [b[:, 0].min(axis=0), b[:, 1].max(axis=0)])
    assert boxes.triangle_count == sum(len(boxes.primitives[i.primitive].indices)
                                       for i in boxes.instances)
    assert not arrays.matrices.flags.writeable
    boxes.bounds[0, 0] = 1e9  # a copy: the cached box is not changed
    assert boxes.bounds[0, 0] != 1e9


def test_scene_arrays_follow_new_or_longer_lists():
    scene = T.many_small_objects(20)
    before = scene.triangle_count
    one = scene.primitives[scene.instances[1].primitive]
    scene.instances.append(scene.instances[1])  # the same list, longer
    assert scene.triangle_count == before + len(one.indices)
    scene.instances = scene.instances[:3]
    assert len(instance_arrays(scene)) == 3
    np.testing.assert_array_equal(
        scene.bounds, [np.min([i.bounds[0] for i in scene.instances], axis=0),
                       np.max([i.bounds[1] for i in scene.instances], axis=0)])


def test_grounded_scene_extends_its_source_arrays(boxes):
    grounded = boxes.with_ground()
    arrays = instance_arrays(grounded)
    assert len(arrays) == len(boxes.instances) + 1
    np.testing.assert_array_equal(arrays.matrices,
                                  np.stack([i.matrix for i in grounded.instances]))
    np.testing.assert_array_equal(arrays.receive,
                                  [i.receive_shadow for i in grounded.instances])
    np.testing.assert_array_equal(arrays.primitive, [i.primitive for i in grounded.instances])
    assert grounded.triangle_count == boxes.triangle_count + 2


def test_renderer_reuses_the_grounded_scene(renderer):
    scene = T.caster_on_ground()
    first = renderer._with_ground(scene)
    assert renderer._with_ground(scene) is first
    scene.instances = list(scene.instances)  # a new list: the scene may have changed
    again = renderer._with_ground(scene)
    assert again is not first and renderer._with_ground(scene) is again
    result = renderer.render(scene, RenderParams(width=64, height=48, ground=True))
    assert result.color is not None


@pytest.mark.gl
def test_an_upload_counts_the_bytes_its_buffers_hold(renderer):
    """The upload cache's budget sees every buffer: vertices, indices and the instance
    matrices (64 bytes an instance), read back from GL's own buffer sizes."""
    from OpenGL import GL

    from shadowmap.renderer.gl.resources import GpuScene

    boxes = T.many_small_objects(50)
    gpu = GpuScene.upload(boxes)
    try:
        held = 0
        for gp in gpu.primitives:
            for buf in gp.mesh.buffers:
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, buf)
                held += int(GL.glGetBufferParameteriv(GL.GL_ARRAY_BUFFER, GL.GL_BUFFER_SIZE))
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
        assert held >= 64 * len(boxes.instances)
        assert gpu.nbytes == held  # untextured: buffers only
    finally:
        gpu.release()
