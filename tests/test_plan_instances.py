"""The plan over many instances without GL: its batched steps give what one instance at a time
gives, and what depends only on the scene is read once per scene."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest
import trimesh

from shadowmap.renderer import RenderParams
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import culling, instances, make_plan
from shadowmap.renderer.plan.context import PlanContext
from shadowmap.renderer.plan.geometry import (
    SLICE_ROWS,
    aabbs_in_frustum,
    box_corners,
    boxes_in_frustum,
    column_max,
    column_min,
    corner_max,
    corner_min,
    frustum_planes,
    look_at,
    perspective,
    points_product,
    row_norm,
    slice_max,
    slice_min,
    slice_sum,
)
from shadowmap.renderer.scene import Instance, Scene, scene_from_meshes, world_bounds


def mixed_scene(seed: int, n: int = 80) -> Scene:
    """Quads, boxes and spheres placed by rotations, mirrors, shears, non-uniform and singular
    matrices, some on integer positions (planes through box corners), with random flags."""
    rng = np.random.default_rng(seed)
    quad = trimesh.Trimesh([[-.5, 0, -.5], [.5, 0, -.5], [.5, 0, .5], [-.5, 0, .5]],
                           [[0, 2, 1], [0, 3, 2]], process=False)
    base = scene_from_meshes([quad, trimesh.creation.box(extents=(.4, .4, .4)),
                              trimesh.creation.icosphere(1)])
    out = []
    for _ in range(n):
        p = int(rng.integers(0, 3))
        m = np.eye(4)
        kind = int(rng.integers(0, 5))
        if kind == 0:
            m = trimesh.transformations.random_rotation_matrix(rng.random(3))
        elif kind == 1:
            m[:3, :3] = np.diag(rng.uniform(-2, 2, 3))
        elif kind == 2:
            m[:3, :3] = rng.normal(size=(3, 3))
        elif kind == 3 and rng.random() < 0.3:
            m[:3, :3] = np.diag([1.0, 0.0, 1.0])
        m[:3, 3] = rng.uniform(-3, 3, 3)
        if rng.random() < 0.2:
            m[:3, 3] = np.round(m[:3, 3])
        out.append(Instance(p, m, cast_shadow=bool(rng.random() < 0.85),
                            receive_shadow=bool(rng.random() < 0.85),
                            bounds=world_bounds(base.primitives[p].local_bounds.astype(np.float64),
                                                m)))
    scene = Scene(base.primitives, out)
    return scene.with_ground() if seed % 2 else scene


def context(scene: Scene, origin=None) -> PlanContext:
    params = RenderParams()
    camera = resolve_camera(params.camera, scene, params.width, params.height)
    lo, hi = scene.bounds
    return PlanContext.build(scene, camera, (lo + hi) / 2 if origin is None else origin, params)


# -- one instance at a time, as the plan did it before it was batched ---------------------------


def planes_one_by_one(scene: Scene, origin: np.ndarray) -> list:
    out: list = []
    for inst in scene.instances:
        plane = instances.primitive_plane(scene.primitives[inst.primitive])
        if plane is None:
            out.append(None)
            continue
        n, c = plane
        m = inst.matrix
        n_w = np.linalg.solve(m[:3, :3].T, n) if abs(np.linalg.det(m[:3, :3])) > 0 else None
        if n_w is None or not np.all(np.isfinite(n_w)) or np.linalg.norm(n_w) == 0:
            out.append(None)
            continue
        out.append((n_w / np.linalg.norm(n_w), m[:3, :3] @ c + m[:3, 3] - origin))
    return out


def shadowless_one_by_one(ctx: PlanContext, light, position, receivers) -> np.ndarray:
    out = np.zeros(len(ctx.cast), bool)
    tol = 1e-9 * max(float(np.max(ctx.bounds[:, 1] - ctx.bounds[:, 0])), 1e-300)
    for i in np.flatnonzero(ctx.planes.flat & ctx.cast):
        n, p0 = ctx.planes.normal[i], ctx.planes.point[i]
        if light.type == "directional":
            facing = -float(np.dot(n, light.direction))
            if abs(facing) <= 1e-12:
                out[i] = True
                continue
        else:
            facing = float(np.dot(n, position - p0))
            if abs(facing) <= tol:
                continue
        others = receivers[receivers != i]
        if len(others) == 0:
            out[i] = True
            continue
        d = (ctx.corners[others] - p0) @ (n * np.sign(facing))
        out[i] = bool(np.all(d >= -tol))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_instance_planes_equal_one_instance_at_a_time(seed):
    scene = mixed_scene(seed)
    ctx = context(scene)
    expected = planes_one_by_one(scene, ctx.origin)
    assert [p is not None for p in expected] == ctx.planes.flat.tolist()
    assert ctx.planes.flat.any() and not ctx.planes.flat.all()
    for i, plane in enumerate(expected):
        if plane is not None:
            # To a few ulps, not bit for bit: a batched solve and a single one may take
            # different LAPACK kernels (OpenBLAS picks them per processor).
            np.testing.assert_allclose(ctx.planes.normal[i], plane[0], rtol=0, atol=1e-14)
            scale = max(float(np.abs(plane[1]).max()), 1.0)
            np.testing.assert_allclose(ctx.planes.point[i], plane[1], rtol=0, atol=1e-14 * scale)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_patch_normals_equal_one_instance_at_a_time(seed):
    # Every instance's flat patches (a box's six sides, a quad's one, none for a sphere) through
    # its own inverse transpose, in the order primitive_patches gives them; none for a singular
    # matrix.
    scene = mixed_scene(seed)
    arrays = instances.scene_arrays(scene)
    idx = np.arange(len(scene.instances))[::-1].copy()  # any order, as the plan asks
    owner, normal = arrays.patch_normals(idx)
    for k, i in enumerate(idx.tolist()):
        inst = scene.instances[i]
        local = instances.primitive_patches(scene.primitives[inst.primitive])
        a = inst.matrix[:3, :3]
        want = (np.zeros((0, 3)) if len(local) == 0 or abs(np.linalg.det(a)) == 0
                else np.linalg.inv(a).T @ local.T)
        if len(want):
            want = (want / np.linalg.norm(want, axis=0)).T
        np.testing.assert_allclose(normal[owner == k], want, atol=1e-12)
    assert len(owner) == sum(
        0 if abs(np.linalg.det(inst.matrix[:3, :3])) == 0
        else len(instances.primitive_patches(scene.primitives[inst.primitive]))
        for inst in scene.instances)


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("block", [8, 1 << 22])
def test_shadowless_planes_equal_one_plane_at_a_time(seed, block, monkeypatch):
    # A small block forces the exact step through several blocks of directions.
    monkeypatch.setattr(culling, "_BLOCK_ELEMENTS", block)
    rng = np.random.default_rng(100 + seed)
    scene = mixed_scene(seed, n=int(rng.integers(5, 200)))
    ctx = context(scene)
    n = len(ctx.cast)
    specs = [{"direction": [0, -1, 0]}, {"direction": [1, 0, 0]}]
    for _ in range(6):  # eight lights: the most a request may have
        kind = rng.integers(0, 3)
        if kind == 0:
            specs.append({"direction": rng.normal(size=3).tolist()})
        elif kind == 1:
            specs.append({"type": "point", "position": (rng.normal(size=3) * 3).tolist()})
        else:
            specs.append({"type": "spot", "position": (rng.normal(size=3) * 3).tolist(),
                          "direction": rng.normal(size=3).tolist()})
    lights = resolve_lights(RenderParams(lights=specs).lights, scene)
    receiver_sets = [np.flatnonzero(ctx.receive), np.array([], int), rng.choice(n, 1),
                     np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))]
    for light in lights:
        for receivers in receiver_sets:
            position = light.position - ctx.origin
            np.testing.assert_array_equal(
                culling.shadowless_planes(ctx, light, position, receivers),
                shadowless_one_by_one(ctx, light, position, receivers))


def test_many_flat_casters_in_few_orientations():
    """Floor tiles and wall panels: thousands of planes, two normals, decided in bulk."""
    tile = trimesh.Trimesh([[-.5, 0, -.5], [.5, 0, -.5], [.5, 0, .5], [-.5, 0, .5]],
                           [[0, 2, 1], [0, 3, 2]], process=False)
    base = scene_from_meshes([tile, trimesh.creation.box(extents=(.3, .3, .3))])
    insts = []
    for i in range(60):
        for j in range(60):
            m = np.eye(4)
            m[:3, 3] = (i, 0.0, j)
            if (i + j) % 7 == 0:  # a few upright panels
                m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
                m[1, 3] = 0.5
            insts.append(Instance(0, m, bounds=world_bounds(
                base.primitives[0].local_bounds.astype(np.float64), m)))
    for k in range(20):
        m = np.eye(4)
        m[:3, 3] = (3 * k % 60, 0.16, 7 * k % 60)  # clear of the tiles in float32 too
        insts.append(Instance(1, m, bounds=world_bounds(
            base.primitives[1].local_bounds.astype(np.float64), m)))
    scene = Scene(base.primitives, insts)
    ctx = context(scene)
    for spec in ({"direction": [-0.3, -1, -0.2]}, {"type": "point", "position": [30, 8, 30]}):
        light = resolve_lights(RenderParams(lights=[spec]).lights, scene)[0]
        receivers = ctx.receivers()
        position = light.position - ctx.origin
        got = culling.shadowless_planes(ctx, light, position, receivers)
        np.testing.assert_array_equal(got, shadowless_one_by_one(ctx, light, position, receivers))
        assert 0 < got.sum() < len(insts) - 20


# -- geometry ------------------------------------------------------------------------------------


def test_aabbs_in_frustum_equals_the_corner_test():
    rng = np.random.default_rng(0)
    for trial in range(300):
        scale = 10 ** rng.uniform(-4, 5)
        offset = rng.normal(size=3) * scale * rng.choice([0, 1, 100])
        lo = rng.normal(size=(200, 3)) * scale + offset
        size = np.abs(rng.normal(size=(200, 3))) * scale * rng.choice([0, 0.01, 1], size=(200, 1))
        bounds = np.stack([lo, lo + size], 1)
        pose = look_at(offset + rng.normal(size=3) * scale * 3, offset + rng.normal(size=3) * scale)
        planes = frustum_planes(perspective(rng.uniform(0.2, 2.5), rng.uniform(0.5, 2),
                                            scale * 1e-3, scale * 10) @ np.linalg.inv(pose))
        if trial % 3 == 0:  # boxes exactly touching planes: the corner test decides those
            planes = np.array([[1.0, 0, 0, -1.0], [0, -1.0, 0, 2.0], [0, 0, 1, 0.5],
                               [0.6, 0.8, 0, 0.0]])
            bounds[:100, 1, 0] = 1.0
            bounds[100:, 0, 1] = 2.0
            bounds[:50, :, 2] = -0.5
            bounds.sort(axis=1)
        frustum = rng.normal(size=(8, 3)) * scale + offset if trial % 2 else None
        np.testing.assert_array_equal(aabbs_in_frustum(bounds, planes, frustum),
                                      boxes_in_frustum(box_corners(bounds), planes, frustum))


@pytest.mark.parametrize("shape", [(0, 8, 3), (5, 3), (7, 8, 3), (300, 8, 3), (4, 2, 8, 3)])
def test_points_product_gives_numpys_stacked_product(shape: tuple[int, ...]):
    rng = np.random.default_rng(len(shape) * 100 + shape[0])
    p = rng.normal(size=shape) * 1e3
    m = rng.normal(size=(3, 4))
    for b in (m, m[:, 2]):
        out = points_product(p, b)
        assert out.shape == (p @ b).shape
        np.testing.assert_array_equal(out, p @ b)
    strided = p[..., ::-1]  # not contiguous: copied, the same values
    np.testing.assert_array_equal(points_product(strided, m), strided @ m)


@pytest.mark.parametrize("rows", [0, 1, 50, SLICE_ROWS - 1, SLICE_ROWS, 3 * SLICE_ROWS + 5])
def test_short_axis_reductions_give_numpys_values(rows: int):
    """Below SLICE_ROWS numpy's own reduction, from it one slice or column at a time: the same
    values either way, NaN and signed zeros included."""
    rng = np.random.default_rng(rows)
    a = rng.normal(size=(rows, 8, 3))
    if rows > 3:
        a[1, 2, 0], a[2, :, 1], a[3, 0, :] = np.nan, -0.0, np.inf
    np.testing.assert_array_equal(corner_min(a), a.min(axis=1))
    np.testing.assert_array_equal(corner_max(a), a.max(axis=1))
    np.testing.assert_array_equal(slice_min(a, 2), a.min(axis=2))
    np.testing.assert_array_equal(slice_max(a, -1), a.max(axis=-1))
    flags = a > 0
    np.testing.assert_array_equal(slice_max(flags, 1), flags.any(axis=1))
    points = a[:, 0]  # (N, 3)
    np.testing.assert_array_equal(slice_sum(points, 1), points.sum(axis=1))
    np.testing.assert_array_equal(row_norm(points), np.linalg.norm(points, axis=1))
    np.testing.assert_array_equal(column_min(points, np.inf), points.min(axis=0, initial=np.inf))
    np.testing.assert_array_equal(column_max(points, -np.inf),
                                  points.max(axis=0, initial=-np.inf))
    ints = rng.integers(-9, 9, size=(rows, 4))
    assert column_min(ints, 99).dtype == ints.dtype
    np.testing.assert_array_equal(column_min(ints, 99), ints.min(axis=0, initial=99))
    if rows:
        np.testing.assert_array_equal(column_max(ints), ints.max(axis=0))
    else:
        with pytest.raises(ValueError):  # no initial value: an empty column has no maximum
            column_max(ints)


# -- the per-scene cache -----------------------------------------------------------------------


def test_scene_arrays_are_read_once_and_shared_read_only():
    scene = T.many_small_objects(50)
    first = instances.scene_arrays(scene)
    assert instances.scene_arrays(scene) is first
    a, b = context(scene), context(scene)
    assert a.bounds is b.bounds and a.corners is b.corners and a.cast is first.cast
    for arr in (first.bounds, first.cast, first.receive, first.primitive, first.planes.normal,
                a.planes.point, a.bounds, a.corners):
        with pytest.raises(ValueError):
            arr[...] = 0
    # Another origin: new relative arrays from the same scene arrays.
    c = context(scene, np.zeros(3))
    assert c.bounds is not a.bounds and instances.scene_arrays(scene) is first
    np.testing.assert_array_equal(c.bounds, first.bounds)


def test_scene_arrays_follow_a_new_instance_list_and_leave_with_the_scene():
    scene = T.caster_on_ground()
    first = instances.scene_arrays(scene)
    scene.instances = scene.instances[:2]
    second = instances.scene_arrays(scene)
    assert second is not first and len(second.cast) == 2
    scene.instances.append(scene.instances[0])  # the same list, longer
    third = instances.scene_arrays(scene)
    assert third is not second and len(third.cast) == 3
    del third
    gone = weakref.ref(second)
    del scene, first, second
    gc.collect()
    assert gone() is None


def test_plans_of_a_cached_scene_equal_those_of_a_fresh_one():
    build = T.pebbles_on_a_plain
    params = RenderParams(camera={"eye": [0, 3, 6], "target": [0, 0, 0]},
                          lights=[{"direction": [0.3, -0.5, 1.0]},
                                  {"type": "point", "position": [0, 2, 0]}])

    def plan(scene):
        camera = resolve_camera(params.camera, scene, params.width, params.height)
        lo, hi = scene.bounds
        return make_plan(scene, camera, resolve_lights(params.lights, scene), (lo + hi) / 2,
                         params).to_dict()

    scene = build()
    assert plan(scene) == plan(scene) == plan(build())


def test_scene_box_is_the_scene_bounds():
    for scene in (T.caster_on_ground(), T.many_small_objects(30).with_ground(), mixed_scene(3)):
        box = instances.scene_box(scene)
        np.testing.assert_array_equal(box, scene.bounds)
        assert box.dtype == scene.bounds.dtype and instances.scene_box(scene) is box
