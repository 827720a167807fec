"""The render plan without GL: fits are pure and deterministic, skips give their reasons, and the
geometry helpers match hand-computed matrices."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from shadowmap.renderer import RenderParams, RequestError
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import LightShadow, RenderPlan, geometry, make_plan
from shadowmap.renderer.plan.context import PlanContext, Toward
from shadowmap.renderer.plan.culling import shadowless_planes, view_planes
from shadowmap.renderer.plan.fit import (
    CUBE,
    DEPTH16_MAX_STEP_TEXELS,
    DEPTH16_STEP,
    DIRECTIONAL,
    MAX_SPOT_HALF_ANGLE,
    SPOT,
    Subject,
    caster_cone,
    choose_method,
    depth16_is_enough,
    seen_cone,
)
from shadowmap.renderer.plan.geometry import (
    CUBE_FACES,
    box_corners,
    boxes_in_frustum,
    clip_boxes,
    cross3,
    cube_face_views,
    face_meets_cone,
    frustum,
    frustum_planes,
    look_at,
    ortho,
    perspective,
    pose_from_direction,
    pyramid_planes,
    transform_points,
)
from shadowmap.renderer.plan.plan import depth_bits
from shadowmap.renderer.scene import Instance, Scene, scene_from_meshes, world_bounds

CAMERA = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}
SUN = {"direction": [-0.5, -1, -0.3]}
SPOT_40 = {"type": "spot", "position": [-2.5, 4.0, 1.5], "target": [0, 0, 0], "outer_cone_deg": 40}
WIDE_SPOT = {"type": "spot", "position": [0.5, 2.5, 0.5], "direction": [0, -1, 0],
             "outer_cone_deg": 89.5}
POINT = {"type": "point", "position": [0.0, 2.0, 0.0]}
#: A point light so far that everything seen lies in a narrow cone from it.
FAR_POINT = {"type": "point", "position": [-60.0, 80.0, 40.0]}
#: A low point light beside the casters of T.ground_only_receives: the ground it lights spreads
#: over 90 degrees from it, the casters lie within 25.
BESIDE = {"type": "point", "position": [-2.5, 1.8, 0.0]}
AWAY = {"type": "spot", "position": [0, 3, 0], "direction": [0, 1, 0], "outer_cone_deg": 30}
ROOM_CAMERA = {"eye": [3.0, 3.5, 3.0], "target": [-2, -1, -2], "yfov_deg": 45}


def inputs(scene, camera=CAMERA, lights=None, **fields):
    """(scene, camera, lights, origin, params) as the renderer resolves them."""
    params = RenderParams(camera=camera, lights=lights, **fields)
    cam = resolve_camera(params.camera, scene, params.width, params.height)
    lo, hi = scene.bounds
    return scene, cam, resolve_lights(params.lights, scene), (lo + hi) / 2, params


def plan(scene, camera=CAMERA, lights=None, **fields) -> RenderPlan:
    return make_plan(*inputs(scene, camera, lights, **fields))


def light(scene, light_params, camera=CAMERA, **fields) -> LightShadow:
    return plan(scene, camera, [light_params], **fields).lights[0]


def assert_same(a, b, path="value"):
    """Exact equality through dataclasses, dicts, sequences and arrays."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype, path
        np.testing.assert_array_equal(a, b, err_msg=path)
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            assert_same(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{i}]")
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def snapshot(scene, camera, lights, origin, params) -> dict:
    """Copies of everything the planner reads."""
    return {
        "matrices": [i.matrix.copy() for i in scene.instances],
        "bounds": [i.bounds.copy() for i in scene.instances],
        "flags": [(i.cast_shadow, i.receive_shadow) for i in scene.instances],
        "positions": [p.positions.copy() for p in scene.primitives],
        # No cache or other attribute is written into the scene's objects.
        "primitive_attrs": [sorted(vars(p)) for p in scene.primitives],
        "instance_attrs": [sorted(vars(i)) for i in scene.instances],
        "camera": dataclasses.asdict(camera),
        "lights": [dataclasses.asdict(lt) for lt in lights],
        "origin": origin.copy(),
        "params": params.model_dump(),
    }


SCENES = {
    "caster_on_ground": (T.caster_on_ground, CAMERA, [SUN, SPOT_40, WIDE_SPOT, POINT]),
    "room": (T.room, ROOM_CAMERA, [POINT, SUN, {**SPOT_40, "position": [0.0, 2.0, 0.0]}]),
    "many_small_objects": (lambda: T.many_small_objects(50), CAMERA, [SUN, SPOT_40]),
}


# -- purity -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("optimize", [True, False])
def test_fits_are_deterministic_and_leave_inputs_unchanged(name, optimize):
    build, camera, lights = SCENES[name]
    args = inputs(build(), camera, lights, optimize=optimize)
    before = snapshot(*args)
    first = make_plan(*args)
    second = make_plan(*args)
    assert_same(first, second)
    assert_same(snapshot(*args), before)
    # Freshly built inputs give the same plan as reused ones (nothing is cached in the inputs).
    assert_same(make_plan(*inputs(build(), camera, lights, optimize=optimize)), first)
    assert all(lp.kind is not None for lp in first.lights), first.to_dict()


def test_each_light_is_planned_on_its_own():
    scene = T.caster_on_ground()
    together = plan(scene, lights=[SUN, SPOT_40, POINT, AWAY]).lights
    for i, lt in enumerate([SUN, SPOT_40, POINT, AWAY]):
        alone = light(scene, lt)
        assert_same(dataclasses.replace(alone, index=i), together[i])


def test_plan_results_and_shared_arrays_are_read_only():
    lp = light(T.caster_on_ground(), SUN)
    with pytest.raises(dataclasses.FrozenInstanceError):
        lp.map_size = 1  # type: ignore[misc]
    ctx = PlanContext.build(*inputs(T.caster_on_ground())[:2], np.zeros(3), RenderParams())
    for a in (ctx.bounds, ctx.corners, ctx.cast, ctx.receive, ctx.in_view, ctx.frustum_corners):
        with pytest.raises(ValueError):
            a[...] = 0


# -- skips ------------------------------------------------------------------------------------


def test_light_with_cast_shadows_false_has_no_pass():
    lp = light(T.caster_on_ground(), {**SUN, "cast_shadows": False})
    assert lp.kind is None and lp.reason == "cast_shadows_false"
    assert lp.to_dict() == {"type": "directional", "shadow_map": None,
                            "skipped_pass": "cast_shadows_false"}
    assert lp.casters == [] and lp.map_size == 0


def test_scene_without_casters_has_no_pass():
    scene = T.caster_on_ground()
    scene.instances[:] = [dataclasses.replace(inst, cast_shadow=False)
                          for inst in scene.instances]
    p = plan(scene, lights=[SUN, SPOT_40, POINT])
    assert [lp.reason for lp in p.lights] == ["no_caster"] * 3
    assert p.map_lights == [] and p.to_dict()["light_passes"] == 0


@pytest.mark.parametrize("optimize", [True, False])
def test_spot_pointing_away_reaches_no_visible_receiver(optimize):
    lp = light(T.caster_on_ground(), AWAY, optimize=optimize)
    assert lp.to_dict() == {"type": "spot", "shadow_map": None,
                            "skipped_pass": "no_visible_receiver"}


def test_spot_over_bare_ground_has_no_caster_in_frustum():
    # The narrow cone sees only the ground, which faces the light: it casts onto nothing seen.
    narrow = {"type": "spot", "position": [2.5, 3, 2.5], "direction": [0, -1, 0],
              "outer_cone_deg": 10}
    assert light(T.caster_on_ground(), narrow).reason == "no_caster_in_frustum"


# -- the camera pass's order ------------------------------------------------------------------


def _boxes_at(xz: list[tuple[float, float]]) -> Scene:
    """Unit boxes centred at (x, 0.5, z), listed in the order given."""
    import trimesh

    meshes = [trimesh.creation.box(extents=(1, 1, 1)) for _ in xz]
    for m, (x, z) in zip(meshes, xz, strict=True):
        m.apply_translation((x, 0.5, z))
    return scene_from_meshes(meshes)


def test_visible_instances_are_drawn_nearest_first():
    # Listed far, near, middle from an eye on the +x axis: drawn near, middle, far, so that
    # nothing is shaded before what hides it.
    scene = _boxes_at([(-6.0, 0.0), (4.0, 0.0), (0.0, 0.0)])
    camera = {"eye": [20.0, 0.5, 0.0], "target": [0.0, 0.5, 0.0]}
    p = plan(scene, camera, [SUN])
    assert p.visible == [1, 2, 0]
    assert p.to_dict()["camera_pass"]["order"] == "near_first"
    # An orthographic view orders by depth along its axis: a box off to the side (12.2 from
    # the eye, 10 deep) comes before one 11 from it on the axis (11 deep).
    side = _boxes_at([(9.0, 0.0), (10.0, 7.0)])
    assert plan(side, {**camera, "yfov_deg": 90.0}, [SUN]).visible == [0, 1]
    ortho_view = {**camera, "projection": "orthographic", "ymag": 12.0}
    assert plan(side, ortho_view, [SUN]).visible == [1, 0]
    # Equal distances keep the file's order.
    twins = _boxes_at([(0.0, 0.0), (0.0, 0.0), (5.0, 0.0), (5.0, 0.0)])
    assert plan(twins, camera, [SUN]).visible == [2, 3, 0, 1]
    # Without optimize: every instance, in the file's order.
    off = plan(scene, camera, [SUN], optimize=False)
    assert off.visible == [0, 1, 2] and off.to_dict()["camera_pass"]["order"] == "file"


# -- what the fits leave out ------------------------------------------------------------------


def test_casters_far_outside_the_view_are_counted_not_drawn():
    scene = T.many_small_objects(200)
    p = plan(scene, lights=[SUN])
    assert p.to_dict()["camera_pass"]["skipped"] == {"outside_view": 200}
    d = p.lights[0].to_dict()
    assert d["casters"] == 1 and p.lights[0].casters == [1]
    assert d["skipped"] == {"outside_frustum": 200, "plane_facing_receivers": 1}
    off = plan(scene, lights=[SUN], optimize=False).lights[0]
    assert len(off.casters) == 202 and off.skipped == {}
    # The frustum is fitted the same way either way.
    assert_same((off.view, off.proj, off.map_size), (p.lights[0].view, p.lights[0].proj,
                                                     p.lights[0].map_size))


def test_non_casters_are_counted():
    lp = light(T.ground_only_receives(), SUN)
    assert lp.skipped == {"non_caster": 1} and lp.casters == [1, 2]


def test_point_light_in_a_room_leaves_out_faces_without_receivers():
    every = light(T.room(), POINT, ROOM_CAMERA, optimize=False)
    assert every.faces == [0, 1, 2, 3, 4, 5] and every.to_dict()["faces"] == every.faces
    seen = light(T.room(), POINT, ROOM_CAMERA)
    assert 0 < len(seen.faces) < 6
    assert seen.skipped["faces_without_receivers"] == 6 - len(seen.faces)
    assert list(seen.skipped)[0] == "faces_without_receivers"
    assert_same(seen.face_views, every.face_views)


# -- kinds and sizes --------------------------------------------------------------------------


@pytest.mark.parametrize("light_params, kind, method", [
    (SUN, "ortho", DIRECTIONAL),
    (SPOT_40, "perspective", SPOT),
    (WIDE_SPOT, "cube", CUBE),
    (POINT, "cube", CUBE),
    (FAR_POINT, "perspective", SPOT),
])
def test_each_light_kind_gets_its_fit(light_params, kind, method):
    args = inputs(T.caster_on_ground(), lights=[light_params])
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    light = args[2][0]
    chosen, subject = choose_method(ctx, Subject(light, light.position - ctx.origin,
                                                 ctx.receivers()))
    assert chosen is method
    # The light is planned with its own type; a point light fitted by a frustum only borrows a
    # spot's cone, and around the seen receivers.
    assert (subject.light is light) == (light.type == "spot" or kind != "perspective")
    lp = make_plan(*args).lights[0]
    assert lp.kind == kind and lp.reason is None
    assert set(lp.to_dict()) == {"type", "shadow_map", "map_size", "casters", "skipped", "near",
                                 "far", "depth_bits", "one_sided"} | (
                                     {"faces"} if kind == "cube" else set())
    assert lp.depth_bits in (16, 32)
    assert 0 < lp.near < lp.far or kind == "ortho"
    assert lp.map_size >= 256 and lp.map_size & (lp.map_size - 1) == 0


def test_point_light_beside_its_casters_gets_one_frustum_around_them():
    args = inputs(T.ground_only_receives(), lights=[BESIDE])
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    lt = args[2][0]
    position = lt.position - ctx.origin
    seen = seen_cone(ctx, position)
    assert seen is not None and seen[1] > MAX_SPOT_HALF_ANGLE  # the seen ground: no frustum
    cone = caster_cone(ctx, position)
    assert cone is not None
    axis, half = cone
    assert half < math.radians(25)
    # Every caster's bounding sphere lies inside the cone and one touches its edge.
    boxes = ctx.bounds[ctx.cast]
    delta = boxes.mean(axis=1) - position
    dist = np.linalg.norm(delta, axis=1)
    radius = np.linalg.norm(boxes[:, 1] - boxes[:, 0], axis=1) / 2
    reach = np.arccos(np.clip(delta @ axis / dist, -1, 1)) + np.arcsin(radius / dist)
    assert np.all(reach <= half + 1e-12) and math.isclose(reach.max(), half, rel_tol=1e-12)
    # Part of the seen ground lies behind the light's plane across that axis: the lookups
    # there must read "lit", not a folded image of the map (tests/test_render.py renders it).
    ground = ctx.bounds[~ctx.cast][0]
    corners = np.array([[x, ground[0, 1], z] for x in ground[:, 0] for z in ground[:, 2]])
    assert np.any((corners - position) @ axis < 0)

    method, subject = choose_method(ctx, Subject(lt, position, ctx.receivers()))
    assert method is SPOT and subject.light.type == "spot"
    np.testing.assert_allclose(subject.light.direction, axis, rtol=0, atol=1e-15)
    assert subject.light.outer_cone == half
    lp = make_plan(*args).lights[0]
    assert lp.kind == "perspective" and lp.light is lt and lp.reason is None
    assert lp.casters == [1, 2]
    # The same light with the ground casting too stands inside the ground's box: no cone holds
    # every caster, and the seen ground spreads too wide: cube faces.
    args = inputs(T.caster_on_ground(), lights=[BESIDE])
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    assert caster_cone(ctx, args[2][0].position - ctx.origin) is None
    assert make_plan(*args).lights[0].kind == "cube"


def test_fixed_map_size_is_used_as_given():
    for lt in (SUN, SPOT_40, POINT):
        assert light(T.caster_on_ground(), lt, shadows={"map_size": 1024}).map_size == 1024


def test_flat_patches_of_a_primitive():
    import trimesh

    from shadowmap.renderer.plan.instances import primitive_patches

    def patches(mesh):
        return primitive_patches(scene_from_meshes([mesh], ["m"]).primitives[0])

    box = patches(trimesh.creation.box((1.0, 2.0, 3.0)))
    assert len(box) == 6
    np.testing.assert_allclose(np.sort(np.abs(box).max(axis=1)), np.ones(6), atol=1e-12)
    assert len(patches(trimesh.creation.icosphere(3))) == 0  # curved: 1,280 orientations
    quad = patches(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]],
                                   [[0, 2, 1], [0, 3, 2]], process=False))
    np.testing.assert_allclose(np.abs(quad), [[0.0, 1.0, 0.0]], atol=1e-12)


def test_texel_stretch_on_a_flat_face():
    up = np.array([[0.0, 1.0, 0.0]])
    down = np.array([[0.0, -1.0, 0.0]])
    # Square to the light and to the view: a texel looks as wide as it is long.
    assert geometry.texel_stretch(up, up, down) == pytest.approx([1.0])
    # Lit at 10 degrees from its plane and seen straight on: 1 / sin 10 degrees, either side.
    th = math.radians(10)
    low = np.array([[math.cos(th), math.sin(th), 0.0]])
    assert geometry.texel_stretch(up, low, down) == pytest.approx([1 / math.sin(th)])
    assert geometry.texel_stretch(-up, low, down) == pytest.approx([1 / math.sin(th)])
    # Seen along the stretch, edge-on: it is foreshortened away.
    assert geometry.texel_stretch(up, low, np.array([[1.0, 0.0, 0.0]])) == pytest.approx([1.0])
    # The side the camera sees is not lit, or lit at less than FACING_COS: no stretch counts.
    assert geometry.texel_stretch(up, -low, down) == [0.0]
    edge = np.array([[1.0, geometry.FACING_COS / 2, 0.0]])
    assert geometry.texel_stretch(up, edge / np.linalg.norm(edge), down) == [0.0]


@pytest.mark.parametrize("elevation, ratio", [(80.0, 1), (30.0, 1), (10.0, 2), (2.0, 2)])
def test_auto_map_size_grows_one_power_of_two_for_grazing_flat_faces(elevation, ratio):
    # The ground is a flat patch; lit at 10 degrees a texel spans 5.8 times its width on it, one
    # camera pixel at the most then wants a texel a fifth as long, held to half the size.
    scene, camera, lights, origin, params = inputs(T.caster_on_ground(), lights=[SUN])
    ctx = PlanContext.build(scene, camera, origin, params)
    ground = [i for i, inst in enumerate(scene.instances) if inst.name == "ground"]
    receivers = np.array(ground)
    e = math.radians(elevation)
    toward = Toward(np.array([math.cos(e), math.sin(e), 0.0]), positional=False)
    # A side that wants 600 texels at the nearest receiver's distance: 1024 unstretched.
    world = 600 * ctx.pixel_per_distance * ctx.receiver_distance(receivers)
    plain = ctx.map_size_for(world, receivers)
    assert plain == 1024
    assert ctx.map_size_for(world, receivers, toward=toward) == plain * ratio
    # A curved receiver has no flat patch: its size stays as it was.
    import trimesh

    ball = scene_from_meshes([trimesh.creation.icosphere(3)], ["ball"])
    b_scene, b_camera, _, b_origin, b_params = inputs(ball, lights=[SUN])
    b_ctx = PlanContext.build(b_scene, b_camera, b_origin, b_params)
    world = 600 * b_ctx.pixel_per_distance * b_ctx.receiver_distance(np.array([0]))
    assert b_ctx.map_size_for(world, np.array([0]), toward=toward) == 1024


def test_directional_fit_is_along_the_light_with_its_texel_size():
    scene, camera, lights, origin, params = inputs(T.caster_on_ground(), lights=[SUN])
    lp = make_plan(scene, camera, lights, origin, params).lights[0]
    direction = np.array(SUN["direction"]) / np.linalg.norm(SUN["direction"])
    np.testing.assert_allclose(lp.view[:3, :3] @ direction, [0, 0, -1], atol=1e-12)
    width, height = 2 / lp.proj[0, 0], 2 / lp.proj[1, 1]
    assert lp.texel == pytest.approx((max(width, height) / lp.map_size, 0.0))
    # Every caster's box lies within the map's depth range.
    for i in lp.casters:
        corners = transform_points(lp.view, box_corners(scene.instances[i].bounds - origin))
        assert np.all(-corners[:, 2] >= lp.near)


# -- geometry ---------------------------------------------------------------------------------


def test_ortho_matches_glortho():
    np.testing.assert_array_equal(ortho(-1, 1, -1, 1, 1, 3),
                                  [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, -2], [0, 0, 0, 1]])
    np.testing.assert_allclose(ortho(0, 4, -2, 0, 0.5, 10.5),
                               [[0.5, 0, 0, -1], [0, 1, 0, 1], [0, 0, -0.2, -1.1], [0, 0, 0, 1]])


def test_frustum_matches_glfrustum():
    np.testing.assert_array_equal(frustum(-1, 1, -1, 1, 1, 3),
                                  [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -2, -3], [0, 0, -1, 0]])
    np.testing.assert_array_equal(frustum(0, 2, 0, 1, 1, 5),
                                  [[1, 0, 1, 0], [0, 2, 1, 0], [0, 0, -1.5, -2.5], [0, 0, -1, 0]])
    # Symmetric, it is gluPerspective; near and far map to -1 and +1.
    np.testing.assert_allclose(perspective(math.pi / 2, 1.0, 1, 3), frustum(-1, 1, -1, 1, 1, 3))
    clip = frustum(0, 2, 0, 1, 1, 5) @ np.array([[0, 0, -1, 1], [0, 0, -5, 1]]).T
    np.testing.assert_allclose(clip[2] / clip[3], [-1, 1])


def test_look_at_poses():
    np.testing.assert_array_equal(look_at(np.array([0, 0, 5.0]), np.zeros(3)),
                                  [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]])
    # Straight down, +Y up is parallel to the view: +X (least aligned) stands in for it.
    pose = look_at(np.array([0, 5.0, 0]), np.zeros(3))
    np.testing.assert_array_equal(pose, [[0, 1, 0, 0], [0, 0, 1, 5], [1, 0, 0, 0], [0, 0, 0, 1]])
    pose = pose_from_direction(np.array([1.0, 2, 3]), np.array([1.0, 0, -1]))
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(-pose[:3, 2], np.array([1, 0, -1]) / math.sqrt(2))
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(RequestError):
        look_at(np.ones(3), np.ones(3))


def test_cross3_is_numpy_cross_bit_for_bit():
    # The poses of every plan use it: any difference would move maps and the pictures.
    rng = np.random.default_rng(7)
    for scale in (1e-30, 1e-6, 1.0, 1e6, 1e30):
        for _ in range(500):
            a, b = rng.normal(size=3) * scale, rng.normal(size=3) * scale
            assert np.array_equal(cross3(a, b), np.cross(a, b))
    with np.errstate(invalid="ignore"):
        a, b = np.array([1.0, np.inf, 0.0]), np.array([0.0, 1.0, np.nan])
        assert np.array_equal(cross3(a, b), np.cross(a, b), equal_nan=True)
    assert cross3([1, 0, 0], [0, 1, 0]).tolist() == [0.0, 0.0, 1.0]  # lists and ints too


def test_box_corners_and_transform():
    c = box_corners(np.array([[0.0, 0, 0], [1, 2, 3]]))
    assert c.shape == (8, 3)
    np.testing.assert_array_equal(c[[0, 5, 7]], [[0, 0, 0], [1, 0, 3], [1, 2, 3]])
    assert box_corners(np.zeros((4, 2, 3))).shape == (4, 8, 3)
    m = np.eye(4)
    m[:3, 3] = (1, 2, 3)
    np.testing.assert_array_equal(transform_points(m, c)[0], [1, 2, 3])


def test_frustum_planes_of_an_ortho_box():
    planes = frustum_planes(ortho(-1, 1, -1, 1, 1, 3))
    np.testing.assert_array_equal(planes, [[1, 0, 0, 1], [-1, 0, 0, 1], [0, 1, 0, 1],
                                           [0, -1, 0, 1], [0, 0, -1, -1], [0, 0, 1, 3]])


def test_boxes_in_frustum():
    # The pyramid |x|, |y| <= -z, -3 <= z <= -1.
    planes = frustum_planes(frustum(-1, 1, -1, 1, 1, 3))
    boxes = np.array([
        [[-0.5, -0.5, -2], [0.5, 0.5, -1.5]],  # inside
        [[-0.5, -0.5, -5], [0.5, 0.5, -4]],  # beyond the far plane
        [[0.5, -0.1, -1.5], [2.0, 0.1, -1.2]],  # across the right plane
        [[3.05, -0.1, -4], [4, 0.1, -2.95]],  # beyond the far right edge, past no single plane
    ])
    corners = box_corners(boxes)
    np.testing.assert_array_equal(boxes_in_frustum(corners, planes), [True, False, True, True])
    near_far = np.array([[sx * z, sy * z, -z] for z in (1, 3) for sx in (-1, 1) for sy in (-1, 1)])
    np.testing.assert_array_equal(boxes_in_frustum(corners, planes, near_far),
                                  [True, False, True, False])


def test_pyramid_planes():
    planes = pyramid_planes(np.array([-0.5, -1.0]), np.array([0.5, 0.0]))
    points = np.array([[0, -0.5, -1], [0.4, -0.9, -1], [0.6, -0.5, -1], [0, 0.1, -1], [0, -0.5, 1]])
    inside = np.all(points @ planes[:, :3].T + planes[:, 3] >= 0, axis=1)
    np.testing.assert_array_equal(inside, [True, True, False, False, False])


def test_cube_faces_look_along_their_axes():
    position = np.array([1.0, -2.0, 3.0])
    views = cube_face_views(position)
    assert len(views) == 6
    for view, (forward, up) in zip(views, CUBE_FACES, strict=True):
        np.testing.assert_allclose(transform_points(view, position + forward), [0, 0, -1],
                                   atol=1e-15)
        np.testing.assert_allclose(transform_points(view, position + np.array(up)), [0, 1, 0],
                                   atol=1e-15)


def test_face_meets_cone():
    cone_cos = math.cos(math.radians(10))
    axis = np.array([1.0, 0, 0])
    meets = [face_meets_cone(np.array(f, float), axis, cone_cos) for f, _ in CUBE_FACES]
    assert meets == [True, False, False, False, False, False]
    # A 40-degree cone reaches the four neighbouring faces (90 < 40 + 54.7).
    meets = [face_meets_cone(np.array(f, float), axis, math.cos(math.radians(40)))
             for f, _ in CUBE_FACES]
    assert meets == [True, False, True, True, True, True]


# -- what the maps cover ----------------------------------------------------------------------


def box_field(side: int = 60, pitch: float = 1.5) -> Scene:
    """``side`` x ``side`` boxes 0.6 wide and 1.0-1.6 tall on a grid centred on the origin, one
    primitive, over a ground plane that casts nothing (bench/instancing.py in small)."""
    import trimesh

    box = trimesh.creation.box(extents=(0.6, 1.0, 0.6))
    box.apply_translation((0, 0.5, 0))
    base = scene_from_meshes([box])
    local = base.primitives[0].local_bounds.astype(np.float64)
    rng = np.random.default_rng(5)
    out = []
    for k in range(side * side):
        m = np.diag([1.0, rng.uniform(1.0, 1.6), 1.0, 1.0])
        m[[0, 2], 3] = (np.array([k % side, k // side]) - (side - 1) / 2) * pitch
        out.append(Instance(0, m, bounds=world_bounds(local, m)))
    return Scene(base.primitives, out).with_ground()


def field_corner(side: int = 60, pitch: float = 1.5) -> dict:
    """Looking down at one corner of :func:`box_field` from 30 units up, as the benchmark does."""
    c = -side * pitch / 2
    return {"eye": [c + 20, 30.0, c + 5], "target": [c + 20, 0.0, c + 22]}


def seen_samples(ctx: PlanContext, per_box: int = 48, seed: int = 0) -> np.ndarray:
    """Points (M, 3) of the seen receivers' boxes inside the camera frustum: random ones (more in
    the largest box, a ground), and the boxes' corners."""
    rng = np.random.default_rng(seed)
    b = ctx.bounds[ctx.receivers()]
    u = rng.random((len(b), per_box, 3))
    inner = b[:, 0, None] + u * (b[:, 1] - b[:, 0])[:, None]
    big = b[np.argmax(np.max(b[:, 1] - b[:, 0], axis=1))]
    extra = big[0] + rng.random((20000, 3)) * (big[1] - big[0])
    pts = np.concatenate([inner.reshape(-1, 3), extra, box_corners(b).reshape(-1, 3)])
    planes = view_planes(ctx.camera, ctx.origin)
    return pts[np.all(pts @ planes[:, :3].T + planes[:, 3] >= 0, axis=1)]


def seen_support(ctx: PlanContext, d: np.ndarray) -> float:
    """max d . x over the seen receivers' parts (their boxes inside the camera frustum), by
    linear programming for the boxes that cross the frustum."""
    planes = view_planes(ctx.camera, ctx.origin)
    best = -np.inf
    for i in ctx.receivers():
        corners = box_corners(ctx.bounds[i])
        if np.all(corners @ planes[:, :3].T + planes[:, 3] >= 0):
            best = max(best, float((corners @ d).max()))
        else:
            best = max(best, _part_support(ctx.bounds[i], planes, d))
    return best


def ray_hits(bounds: np.ndarray, origins: np.ndarray, dirs: np.ndarray,
             t_max: float, exits: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """(P, N) bool: whether the ray ``origins + t dirs``, 0 <= t <= t_max, meets each box; with
    ``exits`` also the (P, N) ray parameter where it leaves each box (its end nearest the
    light)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1 / dirs[:, None, :]  # (P, 1, 3)
        t0 = (bounds[None, :, 0] - origins[:, None]) * inv
        t1 = (bounds[None, :, 1] - origins[:, None]) * inv
    # A ray parallel to a slab: inside it for every t, or never.
    par = dirs[:, None, :] == 0
    inside = (origins[:, None] >= bounds[None, :, 0]) & (origins[:, None] <= bounds[None, :, 1])
    lo = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1)).max(axis=2)
    hi = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1)).min(axis=2)
    hit = (lo <= hi) & (hi >= 0) & (lo <= t_max)
    return (hit, np.minimum(hi, t_max)) if exits else hit


def small_field() -> Scene:
    return box_field(40)


COVERAGE_CASES = {
    "field corner, sun": (small_field, field_corner(40), {"direction": [-0.45, -1.0, -0.3]}),
    # Long shadows into the view from boxes outside it.
    "field corner, low sun": (small_field, field_corner(40), {"direction": [1.0, -0.25, 0.6]}),
    "field corner, spot": (small_field, field_corner(40),
                           {"type": "spot", "position": [-15.0, 12.0, -25.0],
                            "target": [-15, 0, -11], "outer_cone_deg": 45}),
    "field corner, point": (small_field, field_corner(40),
                            {"type": "point", "position": [-18.0, 6.0, -15.0]}),
    "caster on ground, sun": (T.caster_on_ground, CAMERA, SUN),
    "caster on ground, spot": (T.caster_on_ground, CAMERA, SPOT_40),
    "caster on ground, wide spot": (T.caster_on_ground, CAMERA, WIDE_SPOT),
    "room, point": (T.room, ROOM_CAMERA, POINT),
    "room, sun": (T.room, ROOM_CAMERA, SUN),
    "plain to the horizon, sun": (T.pebbles_on_a_plain, {"eye": [0, 3, 6], "target": [0, 0, 0]},
                                  {"direction": [0.3, -0.5, 1.0]}),
}


@pytest.mark.parametrize("name", list(COVERAGE_CASES))
def test_maps_cover_every_seen_receiver_point_and_its_casters(name):
    # The map is fitted to what the camera sees of the receivers: every receiver point inside
    # the view frustum must lie in the map (laterally and before its far plane), and every
    # caster on its way to the light must be drawn and inside the map's depth range, whether
    # the camera sees that caster or not.
    build, camera, light_params = COVERAGE_CASES[name]
    args = inputs(build(), camera, [light_params])
    lp = make_plan(*args).lights[0]
    assert lp.kind is not None, lp.to_dict()
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    lt = args[2][0]

    def lit(p: np.ndarray) -> np.ndarray:  # what the light reaches (a spot: its cone)
        if lt.type != "spot":
            return np.ones(len(p), bool)
        rel = p - lp.position
        return rel @ lt.direction >= np.cos(lt.outer_cone) * np.linalg.norm(rel, axis=1)

    pts = seen_samples(ctx)
    pts = pts[lit(pts)]
    assert len(pts) > 100
    # Casters on the way from a seen receiver point to the light.
    cast = ctx.cast & ~shadowless_planes(ctx, lt, lp.position, ctx.receivers())
    idx = np.flatnonzero(cast)
    sample = pts[np.random.default_rng(1).permutation(len(pts))[:1500]]
    if lt.type == "directional":
        hits = ray_hits(ctx.bounds[idx], sample, np.broadcast_to(-lt.direction, sample.shape),
                        np.inf)
    else:
        hits = ray_hits(ctx.bounds[idx], sample, lp.position - sample, 1.0)
    needed = idx[hits.any(axis=0)]
    sample = sample[hits.any(axis=1)]  # points a caster may shadow: they must lie in the map
    assert len(needed) > 0 and len(sample) > 10
    assert set(needed.tolist()) <= set(lp.casters), sorted(set(needed.tolist()) - set(lp.casters))
    if "low sun" in name:
        assert not ctx.in_view[needed].all()  # some of them out of the camera's sight
    if lp.kind == "cube":
        rel = pts - lp.position
        cheb = np.abs(rel).max(axis=1)
        assert np.all(cheb <= lp.far), (cheb.max(), lp.far)
        axis = np.argmax(np.abs(rel), axis=1)
        face = 2 * axis + (rel[np.arange(len(rel)), axis] < 0)
        assert set(face.tolist()) <= set(lp.faces)
    else:
        # A lookup reads the map only inside its window (elsewhere the point is lit): there,
        # every seen receiver point lies before the far end.
        view_pts = transform_points(lp.view, pts)
        clip = np.c_[view_pts, np.ones(len(pts))] @ lp.proj.T
        under = (clip[:, 3] > 0) & np.all(np.abs(clip[:, :2]) <= clip[:, 3:], axis=1)
        assert under.sum() > 10
        depth = -view_pts[under, 2]
        assert np.all(depth <= lp.far), (depth.max(), lp.far)
        clip = np.c_[transform_points(lp.view, sample), np.ones(len(sample))] @ lp.proj.T
        ndc = clip[:, :2] / clip[:, 3:]
        assert np.all(np.abs(ndc) <= 1), np.abs(ndc).max()
    if lp.kind == "ortho":
        # Where each ray from a shadowable point toward the light leaves each caster it meets
        # (the caster's surface nearest the light along that ray) lies inside the depth range;
        # a caster's box corners elsewhere, outside the map's window, need not.
        d = np.broadcast_to(-lt.direction, sample.shape)
        met, t_exit = ray_hits(ctx.bounds[needed], sample, d, np.inf, exits=True)
        far_pts = sample[:, None, :] + t_exit[..., None] * d[:, None, :]
        depth = -transform_points(lp.view, far_pts[met])[:, 2]
        assert len(depth) and np.all(depth >= lp.near), (depth.min(), lp.near)


def test_directional_map_covers_only_the_seen_part_of_a_large_field():
    # 3,600 boxes, about 600 in view: the map spans what the camera sees of the field and the
    # ground (the boxes and the ground clipped to the view frustum), not the field, and draws
    # the casters over that part only.
    scene = box_field()
    args = inputs(scene, field_corner(), [{"direction": [-0.45, -1.0, -0.3]}])
    lp = make_plan(*args).lights[0]
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    axes = lp.view[:3, :3]  # light view x, y, z as world directions
    x0, x1 = -seen_support(ctx, -axes[0]), seen_support(ctx, axes[0])
    y0, y1 = -seen_support(ctx, -axes[1]), seen_support(ctx, axes[1])
    deepest = seen_support(ctx, -axes[2])
    left, right = (-1 - lp.proj[0, 3]) / lp.proj[0, 0], (1 - lp.proj[0, 3]) / lp.proj[0, 0]
    bottom, top = (-1 - lp.proj[1, 3]) / lp.proj[1, 1], (1 - lp.proj[1, 3]) / lp.proj[1, 1]
    # The window is the seen part's extent, narrowed to the casters', plus the filter margin.
    pad = lp.texel[0] * ctx.margin_texels * (1 + 1e-9)
    assert x0 - pad <= left and right <= x1 + pad and y0 - pad <= bottom and top <= y1 + pad
    assert deepest <= lp.far <= deepest + pad + 2e-3 * (lp.far - lp.near)
    assert (x1 - x0) * (y1 - y0) < 0.5 * (scene.bounds[1, 0] - scene.bounds[0, 0]) ** 2
    assert len(lp.casters) < 0.4 * len(scene.instances)
    assert lp.skipped["outside_frustum"] == len(scene.instances) - 1 - len(lp.casters)


def _part_support(box: np.ndarray, planes: np.ndarray, d: np.ndarray) -> float:
    """max d . x over box ∩ {planes >= 0}, by linear programming (-inf when empty)."""
    from scipy.optimize import linprog

    r = linprog(-d, A_ub=-planes[:, :3], b_ub=planes[:, 3], bounds=list(zip(*box, strict=True)),
                method="highs")
    return -r.fun if r.status == 0 else -np.inf


def _random_frustum(rng) -> tuple[np.ndarray, np.ndarray]:
    pose = look_at(rng.uniform(-5, 5, 3), rng.uniform(-2, 2, 3))
    vp = perspective(math.radians(rng.uniform(20, 90)), rng.uniform(0.5, 2),
                     rng.uniform(0.1, 2), rng.uniform(5, 20)) @ np.linalg.inv(pose)
    inv = np.linalg.inv(vp)
    ndc = np.array([[sx, sy, z, 1.0] for z in (-1, 1) for sx in (-1, 1) for sy in (-1, 1)])
    h = ndc @ inv.T
    return frustum_planes(vp), h[:, :3] / h[:, 3:]


def test_clip_boxes_gives_the_extent_of_each_part_exactly():
    rng = np.random.default_rng(2)
    dirs = np.concatenate([np.eye(3), -np.eye(3), rng.normal(size=(3, 3))])
    for trial in range(12):
        planes, hull = _random_frustum(rng)
        c, half = rng.uniform(-6, 6, (6, 3)), rng.uniform(0, 3, (6, 3))
        if trial % 3 == 0:
            half[:, 1] = 0  # flat boxes (a ground plane)
        boxes = np.stack([c - half, c + half], axis=1)
        for box in boxes:
            pts = clip_boxes(box[None], planes, hull, 1e-9)
            for d in dirs:
                want = _part_support(box, planes, d)
                got = float((pts @ d).max()) if len(pts) else -np.inf
                assert got == pytest.approx(want, abs=1e-7) or want == got == -np.inf


def test_clip_boxes_past_the_cap_is_larger_never_smaller(monkeypatch):
    rng = np.random.default_rng(4)
    planes, hull = _random_frustum(rng)
    c = rng.uniform(-4, 4, (40, 3))
    boxes = np.stack([c - 0.5, c + 0.5], axis=1)
    exact = clip_boxes(boxes, planes, hull, 1e-9)
    monkeypatch.setattr(geometry, "MAX_CLIPPED_BOXES", 5)
    capped = clip_boxes(boxes, planes, hull, 1e-9)
    assert np.all(capped.min(axis=0) <= exact.min(axis=0) + 1e-12)
    assert np.all(capped.max(axis=0) >= exact.max(axis=0) - 1e-12)


def test_sixteen_bits_when_a_step_is_at_most_an_eighth_of_the_nearest_texel():
    texel = 1 / 1024  # world units, orthographic: the same everywhere
    edge = DEPTH16_MAX_STEP_TEXELS * texel / DEPTH16_STEP  # the deepest range 16 bits allow
    assert depth16_is_enough(-1.0, -1.0 + edge * 0.999, (texel, 0.0))
    assert not depth16_is_enough(-1.0, -1.0 + edge * 1.001, (texel, 0.0))
    # Perspective and cube maps: a texel grows with depth, so the one at ``near`` decides.
    per_unit = 1 / 2048
    far = 1.0 + DEPTH16_MAX_STEP_TEXELS * per_unit * 1.0 / DEPTH16_STEP
    assert depth16_is_enough(1.0, far * 0.999, (0.0, per_unit))
    assert not depth16_is_enough(0.5, far, (0.0, per_unit))  # a nearer caster: finer texels
    assert not depth16_is_enough(0.0, 1.0, (0.0, per_unit))  # a texel of no size


def test_depth_bits_follow_the_setting_the_encoding_and_the_fit():
    scene = T.caster_on_ground()
    assert light(scene, SUN).depth_bits == 16  # a box on a ground: a shallow range
    assert light(scene, SUN, shadows={"depth_bits": 32}).depth_bits == 32
    assert light(scene, SUN, shadows={"depth_bits": 16}).to_dict()["depth_bits"] == 16
    for enc in ("rg8", "rgba8"):  # colour packings: no depth texture to size
        lp = light(scene, SUN, shadows={"encoding": enc})
        assert lp.depth_bits == 0 and "depth_bits" not in lp.to_dict()
    no_pass = light(scene, {**SUN, "cast_shadows": False})
    assert no_pass.depth_bits == 0 and "depth_bits" not in no_pass.to_dict()
    # A caster a hundredth of a unit from a spot light, receivers 100 units away: 16 bits
    # would step by 200 texels of the nearest ones.
    deep = dataclasses.replace(light(scene, SPOT_40), near=0.01, far=100.0)
    assert depth_bits(RenderParams().shadows, deep) == 32
    cascaded = light(scene, SUN, shadows={"cascades": 2})
    assert len(cascaded.cascades) == 2 and cascaded.depth_bits == (
        16 if all(depth16_is_enough(c.near, c.far, c.texel) for c in cascaded.cascades) else 32)


# -- the far end of a view-fitted map: the deepest receiver point under it ----------------------


def _deepest_by_lp(ctx: PlanContext, boxes: np.ndarray, planes: np.ndarray,
                   view: np.ndarray) -> float:
    """max light depth over the parts of ``boxes`` inside ``planes`` (world), by linear
    programming box by box (-inf when none reaches inside)."""
    return max((_part_support(ctx.bounds[i], planes, -view[2, :3]) - view[2, 3] for i in boxes),
               default=-np.inf)


def _world_planes(view: np.ndarray, rows: list[np.ndarray]) -> np.ndarray:
    """Planes (P, 4) in world space from rows (4,) over light-view (x, y, z, 1)."""
    return np.array([r @ view for r in rows])


@pytest.mark.parametrize("kind", ["directional", "spot"])
def test_far_bound_is_the_deepest_receiver_point_under_the_map(kind):
    # A field of boxes over a ground (more than the spot's PYRAMID_FIRST receivers, so that its
    # deepest-first pass is taken): the bound equals the deepest point of the receivers' boxes
    # under a window (a pyramid for the spot) that covers part of the field, as linear
    # programming finds it box by box, to rounding.
    from shadowmap.renderer.plan.fit import (
        PYRAMID_FIRST,
        _column_far,
        _pyramid_far,
        reach_directional,
        reach_spot,
    )

    scene = box_field(18)
    light = SUN if kind == "directional" else {"type": "spot", "position": [4.0, 14.0, 6.0],
                                               "target": [0, 0, 0], "outer_cone_deg": 60}
    camera = {"eye": [0.0, 35.0, 25.0], "target": [0.0, 0.0, 0.0]}
    args = inputs(scene, camera, [light])
    ctx = PlanContext.build(args[0], args[1], args[3], args[4])
    lt = args[2][0]
    position = (np.zeros(3) if lt.type == "directional"
                else np.asarray(lt.position, np.float64) - ctx.origin)
    s = Subject(lt, position, ctx.receivers())
    assert len(s.receivers) > PYRAMID_FIRST
    if kind == "directional":
        reach = reach_directional(ctx, s)
        v = reach.view
        x0, y0, x1, y1 = reach.window
        window = (x0 + 0.3 * (x1 - x0), x0 + 0.6 * (x1 - x0), y0 + 0.2 * (y1 - y0),
                  y0 + 0.7 * (y1 - y0))
        got = _column_far(ctx, reach, s.receivers, window)
        e = np.eye(4)
        planes = _world_planes(v, [e[0] - window[0] * e[3], window[1] * e[3] - e[0],
                                   e[1] - window[2] * e[3], window[3] * e[3] - e[1]])
    else:
        reach = reach_spot(ctx, s)
        v = reach.view
        a_lo = reach.a_lo + 0.3 * (reach.a_hi - reach.a_lo)
        a_hi = reach.a_lo + 0.7 * (reach.a_hi - reach.a_lo)
        near = 0.5 * float(reach.depth_min[s.receivers].max())
        got = _pyramid_far(ctx, reach, s.receivers, a_lo, a_hi, near)
        e = np.eye(4)
        # x >= a_lo.x d and x <= a_hi.x d with d = -z; d >= near.
        planes = _world_planes(v, [e[0] + a_lo[0] * e[2], -e[0] - a_hi[0] * e[2],
                                   e[1] + a_lo[1] * e[2], -e[1] - a_hi[1] * e[2],
                                   -e[2] - near * e[3]])
    planes = planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
    want = _deepest_by_lp(ctx, s.receivers, planes, v)
    assert np.isfinite(want)
    scale = float(np.max(np.abs(ctx.bounds)))
    assert want - 1e-7 * scale <= got <= want + 1e-7 * scale, (got, want)
    # Tighter than the deepest seen point anywhere, which a map's range ended at before.
    assert got < reach.far


def test_an_ortho_depth_range_stays_open_at_any_magnitude():
    from shadowmap.renderer.plan.fit import DEPTH_SLACK, ortho_depth_range

    # The usual case: the slack is a share of the span.
    assert ortho_depth_range(2.0, 12.0) == pytest.approx((2.0 - 10 * DEPTH_SLACK,
                                                          12.0 + 10 * DEPTH_SLACK))
    # Flat in depth, far out: the two ends no longer round to one number.
    for d in (-3.17e16, 4.3e9, 1e-300, 0.0):
        near, far = ortho_depth_range(d, d)
        assert far > near and np.isfinite(2.0 / (far - near))


# -- the view's origin ---------------------------------------------------------------------


def _two_parts(far: float, baked: bool = False) -> Scene:
    """A unit box at the origin and one ``far`` along X: placed by its matrix, or with its
    vertices there (``baked``, a mesh far from its own origin)."""
    near_box, far_box = T._box((1, 1, 1), (0, 0.5, 0)), T._box((1, 1, 1), (0, 0.5, 0))
    m = np.eye(4)
    if baked:
        far_box.apply_translation((far, 0, 0))
    else:
        m[0, 3] = far
    built = scene_from_meshes([near_box, far_box])
    matrices = [np.eye(4), m]
    instances = [Instance(i.primitive, mm, True, True, i.name,
                          world_bounds(built.primitives[i.primitive].local_bounds
                                       .astype(np.float64), mm))
                 for i, mm in zip(built.instances, matrices, strict=True)]
    return Scene(built.primitives, instances, key=f"two_parts:{far}:{baked}")


def _origin_of(scene: Scene, eye, target):
    from shadowmap.renderer.camera import view_origin
    from shadowmap.renderer.params import CameraParams

    cam = resolve_camera(CameraParams(eye=eye, target=target), scene, 320, 240)
    lo, hi = scene.bounds
    return view_origin(cam, scene, (lo + hi) / 2)


def test_a_view_stays_at_the_scene_centre_while_float32_resolves_its_pixels():
    scene = _two_parts(1e3)
    placed = _origin_of(scene, [1e3 + 2, 3, 3], [1e3, 0.5, 0])
    assert placed.at == "scene_centre" and placed.warning == ""
    np.testing.assert_array_equal(placed.origin, [500.0, 0.5, 0.0])


def test_a_close_view_far_from_the_centre_moves_to_a_grid_point_beside_its_eye():
    """1e6 units out the nearest pixels (0.01 units) are finer than float32 steps there; the
    origin moves beside the eye, snapped to a grid so that nearby views share it."""
    scene = _two_parts(1e6)
    a = _origin_of(scene, [1e6 + 2, 3, 3], [1e6, 0.5, 0])
    b = _origin_of(scene, [1e6 + 2.001, 3.001, 3], [1e6, 0.5, 0])
    assert a.at == b.at == "eye" and a.warning == b.warning == ""
    np.testing.assert_array_equal(a.origin, b.origin)
    assert np.linalg.norm(a.origin - [1e6 + 2, 3, 3]) < 1e3
    # The grid: a power of two within 1/16 of what the nearest pixels (0.0096 units, the far
    # box 2.6 units away) allow, 2**10 here.
    np.testing.assert_array_equal(a.origin, np.round(np.array([1e6 + 2, 3, 3]) / 1024) * 1024)


def test_a_mesh_far_from_its_own_origin_keeps_its_warning():
    """The same box with its vertices 1e6 units out: the file's float32 coordinates are that
    coarse, and no origin gives the precision back."""
    placed = _origin_of(_two_parts(1e6, baked=True), [1e6 + 2, 3, 3], [1e6, 0.5, 0])
    assert placed.at == "eye"
    assert "its triangles or its own coordinates span 1e+06 units" in placed.warning


def test_the_longest_edge_of_a_primitive():
    from shadowmap.renderer.plan.instances import primitive_edge

    prim = scene_from_meshes([T._plane(4.0)]).primitives[0]
    assert primitive_edge(prim) == pytest.approx(4.0 * math.sqrt(2.0))
    assert primitive_edge(prim) == primitive_edge(prim)  # cached


@pytest.mark.parametrize(("lights", "shadows", "clips"), [
    ([SUN], {}, 1),  # fitted to the view: what the camera sees of the receivers is read
    ([SUN], {"fit": "scene"}, 0),  # a map over every receiver reads none of it
    ([{**SUN, "cast_shadows": False}], {}, 0),  # no shadow: nothing to fit
    ([POINT, SPOT_40], {}, 1),  # clipped once however many lights read it
])
def test_the_receivers_are_clipped_to_the_view_only_for_a_fit_that_reads_them(
        monkeypatch, lights, shadows, clips):
    from shadowmap.renderer.plan import context

    calls = []
    clip = context._clip_seen
    monkeypatch.setattr(context, "_clip_seen", lambda *a: calls.append(1) or clip(*a))
    p = plan(T.caster_on_ground(), lights=lights, shadows=shadows)
    assert len(calls) == clips
    assert any(lp.kind is not None for lp in p.lights) == (lights[0].get("cast_shadows", True))
