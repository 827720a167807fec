"""Stiff and extreme cases, each checked against the ray-traced reference or an exact
expectation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shadowmap.renderer import RenderParams, RequestError, SceneError
from shadowmap.renderer import testing as T
from shadowmap.renderer.scene import scene_from_meshes

pytestmark = pytest.mark.gl

CAMERA = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}


def iou(renderer, scene, **params):
    m = T.measure(renderer, scene, RenderParams(**params))
    return m.metrics[0], m.result


@pytest.fixture(scope="module")
def scene():
    return T.caster_on_ground()


# -- light far away ------------------------------------------------------------------------


@pytest.mark.parametrize("distance", [40.0, 100 * 6.0, 1000 * 6.0, 1e5, 1e7, 5e10])
def test_far_spot_light(renderer, scene, distance):
    """The WebGL guide's LIGHT_Y = 40, then 100x and 1000x the scene's size (6 units), then up
    to 5e10 units, the cone always just holding the scene. From 1e5 out the cone (3e-3 degrees
    there) lit nothing: its cos rounded to 1 in float32. The falloff is now taken in 1 - cos
    from the angle off the axis, measured from a point of the axis near the scene."""
    direction = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    position = -direction * distance
    cone = math.degrees(math.atan(5.0 / distance)) * 1.2
    m, result = iou(renderer, scene, camera=CAMERA, lights=[
        {"type": "spot", "position": position.tolist(), "target": [0, 0, 0],
         "outer_cone_deg": cone}])
    assert result.plan["lights"][0]["shadow_map"] == "perspective"
    assert m.iou >= 0.95, m


@pytest.mark.parametrize("distance", [1e3, 1e5, 1e7, 1e9, 5e10])
def test_far_point_light(renderer, scene, distance):
    """A point light far from the scene gets a frustum around its casters. Its depths were
    read as w - near from w, the distance along its axis, which float32 keeps to 0.008 units
    at 1e5 (IoU 0.53 there, 0.34 at 1e7); and its near and far planes stood a thousandth of
    the distance beyond the scene's depth, 5e7 units at 5e10 (IoU 0.03). Both are gone: the
    stored depth is an affine function of the position with its constant worked out in
    float64, and the planes stand a thousandth of the scene's depth range out."""
    direction = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    m, result = iou(renderer, scene, camera=CAMERA, lights=[
        {"type": "point", "position": (-direction * distance).tolist()}])
    lp = result.plan["lights"][0]
    assert lp["shadow_map"] == "perspective"
    assert lp["far"] - lp["near"] < 20.0  # the scene's depth and a little, at any distance
    assert m.iou >= 0.95, m


@pytest.mark.parametrize("distance", [40.0, 600.0, 6000.0])
def test_far_directional_light_given_by_position(renderer, scene, distance):
    position = (np.array([-0.3, 1.0, -0.2]) / np.linalg.norm([-0.3, 1.0, -0.2]) * distance).tolist()
    m, _ = iou(renderer, scene, camera=CAMERA,
               lights=[{"type": "directional", "position": position, "target": [0, 0, 0]}])
    assert m.iou >= 0.95, m


# -- grazing light ---------------------------------------------------------------------------


@pytest.mark.parametrize("elevation", [10.0, 5.0, 2.0])
def test_grazing_light_has_no_acne(renderer, elevation):
    e = math.radians(elevation)
    direction = [0.3 * math.cos(e), -math.sin(e), math.cos(e)]
    m, _ = iou(renderer, T.grazing_plane(), camera={"eye": [0, 6, 12], "target": [0, 0, 0]},
               lights=[{"type": "directional", "direction": direction}])
    assert m.false_shadow_pct <= 0.1, m
    assert m.pixels > 50_000


@pytest.mark.parametrize("elevation", [0.3, 0.15])
@pytest.mark.parametrize("kind", ["directional", "spot", "point"])
def test_ground_lit_at_a_fraction_of_a_degree(renderer, kind, elevation):
    # A receiver plane at tan 190 and 380 to the light: past where a clamp on it (once at 100)
    # tilted the plane every texel is compared against and striped the ground with shadow,
    # still inside what faces the light (FACING_COS). The spot and point lights stand 200 units
    # away: the point light's map is one frustum around the scene, not a cube face that would
    # give the scene a few dozen of its texels (IoU 0.0 to 0.4 with one).
    e = math.radians(elevation)
    direction = np.array([0.3 * math.cos(e), -math.sin(e), math.cos(e)])
    direction /= np.linalg.norm(direction)
    far = (-direction * 200.0).tolist()
    light = {
        "directional": {"type": "directional", "direction": direction.tolist()},
        "spot": {"type": "spot", "position": far, "target": [0, 0, 0], "outer_cone_deg": 5},
        "point": {"type": "point", "position": far},
    }[kind]
    m, result = iou(renderer, T.grazing_plane(), camera={"eye": [0, 6, 12], "target": [0, 0, 0]},
                    lights=[light])
    assert result.plan["lights"][0]["shadow_map"] == ("ortho" if kind == "directional"
                                                      else "perspective")
    assert m.pixels > 50_000
    assert m.false_shadow_pct <= 0.02, m
    assert m.iou >= 0.99, m


@pytest.mark.parametrize("elevation", [30.0, 5.0])
def test_small_casters_on_a_vast_ground_plane(renderer, elevation):
    # The plane reaches the horizon; it casts nothing onto what stands on it, so the map is fitted
    # to the pebbles, not to the plain.
    e = math.radians(elevation)
    m, result = iou(renderer, T.pebbles_on_a_plain(),
                    camera={"eye": [0, 3, 6], "target": [0, 0, 0]},
                    lights=[{"direction": [0.3 * math.cos(e), -math.sin(e), math.cos(e)]}])
    assert result.plan["lights"][0]["skipped"] == {"plane_facing_receivers": 1}
    assert m.iou >= 0.95, m
    assert m.false_shadow_pct <= 0.2, m


# -- scale and distance from the origin --------------------------------------------------------


@pytest.mark.parametrize("scale, offset",
                         [(1e-3, 0.0), (1e3, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e5)])
def test_same_iou_at_any_scale_and_offset(renderer, scene, scale, offset):
    light = {"type": "spot", "position": [-3.0, 6.0, 2.0], "target": [0, 0, 0],
             "outer_cone_deg": 45}

    def params(s, o):
        off = np.array([o, o, o])
        move = lambda p: (np.asarray(p) * s + off).tolist()  # noqa: E731
        return {
            "camera": {"eye": move(CAMERA["eye"]), "target": move(CAMERA["target"])},
            "lights": [{**light, "position": move(light["position"]),
                        "target": move(light["target"])},
                       {"type": "directional", "direction": [-0.5, -1.0, -0.3]}],
        }

    for a, b in T.moved_metrics(renderer, scene, params, scale, offset):
        assert a.iou >= 0.95
        assert abs(a.iou - b.iou) <= 0.01, (a, b)


# -- stiff frusta ----------------------------------------------------------------------------


def test_spot_near_far_ratio_of_1e5(renderer):
    # A caster right in front of the light and receivers 1e5 times further away.
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    tiny = trimesh.creation.box(extents=(2e-5, 2e-5, 2e-5))
    tiny.apply_translation((0, 10 - 1e-4 - 1e-5, 0))
    big = trimesh.creation.box(extents=(1, 1, 1))
    big.apply_translation((0, 1.0, 0))
    ground = trimesh.creation.box(extents=(6, 0.01, 6))
    scene = scene_from_meshes([ground, big, tiny])
    m, result = iou(renderer, scene, camera=CAMERA, lights=[
        {"type": "spot", "position": [0, 10, 0], "direction": [0, -1, 0], "outer_cone_deg": 20}])
    lp = result.plan["lights"][0]
    assert lp["far"] / lp["near"] > 1e4
    assert m.iou >= 0.95, m


def test_spot_cone_of_179_degrees(renderer, scene):
    m, result = iou(renderer, scene, camera=CAMERA, lights=[
        {"type": "spot", "position": [0.5, 2.5, 0.5], "direction": [0, -1, 0],
         "outer_cone_deg": 89.5}])
    assert result.plan["lights"][0]["shadow_map"] == "cube"
    assert m.iou >= 0.95, m


def test_point_light_inside_a_room_uses_all_six_faces(renderer):
    room = T.room()
    params = dict(camera={"eye": [3.0, 3.5, 3.0], "target": [-2, -1, -2], "yfov_deg": 45},
                  lights=[{"type": "point", "position": [0.0, 2.0, 0.0]}], optimize=False)
    m, result = iou(renderer, room, **params)
    assert result.plan["lights"][0]["faces"] == [0, 1, 2, 3, 4, 5]
    assert m.iou >= 0.95, m
    # With the plan, faces that show no visible receiver are left out; the answer is the same.
    m2, result2 = iou(renderer, room, **{**params, "optimize": True})
    assert len(result2.plan["lights"][0]["faces"]) < 6
    assert m2.iou >= 0.95 and abs(m2.iou - m.iou) < 1e-9


# -- degenerate poses --------------------------------------------------------------------------


def test_light_straight_down_parallel_to_up(renderer, scene):
    m, _ = iou(renderer, scene, camera=CAMERA,
               lights=[{"type": "directional", "direction": [0, -1, 0]}])
    assert m.iou >= 0.95, m


def test_camera_looking_straight_down(renderer, scene):
    m, _ = iou(renderer, scene, camera={"eye": [0, 8, 0], "target": [0, 0, 0]},
               lights=[{"type": "directional", "direction": [-0.4, -1, 0.2]}])
    assert m.iou >= 0.95, m


@pytest.mark.parametrize("request_", [
    {"lights": [{"type": "spot", "position": [1, 2, 3], "target": [1, 2, 3]}]},
    {"lights": [{"type": "directional", "direction": [0, 0, 0]}]},
    {"camera": {"eye": [1, 1, 1], "target": [1, 1, 1]}},
    {"camera": {"pose": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]]}},
    {"lights": [{"pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]}]},  # mirrored
    {"lights": [{"type": "spot", "direction": [0, -1, 0]}]},  # a spot needs a position
])
def test_meaningless_poses_are_clear_errors(renderer, scene, request_):
    with pytest.raises(RequestError):
        renderer.render(scene, request_)


def test_scaled_and_sheared_poses_are_made_rigid(renderer, scene):
    pose = np.array(T_look := [[2, 0.3, 0, 4], [0, 2, 0, 4], [0, 0, 2, 6], [0, 0, 0, 1]], float)
    del T_look
    from shadowmap.renderer.camera import orthonormalize_pose

    rigid = orthonormalize_pose(pose, "camera")
    np.testing.assert_allclose(rigid[:3, :3] @ rigid[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rigid[:3, 3], pose[:3, 3])
    # A light pose with scale shines the same way as its rigid version.
    light_pose = np.eye(4)
    light_pose[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]) * 3.0  # -Z -> -Y, scaled
    a, _ = iou(renderer, scene, camera=CAMERA, lights=[{"pose": light_pose.tolist()}])
    b, _ = iou(renderer, scene, camera=CAMERA, lights=[{"direction": [0, -1, 0]}])
    assert a.iou >= 0.95 and abs(a.iou - b.iou) < 1e-9


# -- degenerate geometry ----------------------------------------------------------------------


def test_degenerate_triangles_and_a_lone_triangle(renderer):
    m, _ = iou(renderer, T.degenerate_geometry(), camera=CAMERA,
               lights=[{"direction": [-0.4, -1, -0.3]}])
    assert m.iou >= 0.95, m


def test_a_scene_at_one_point_or_too_small_to_frame_is_a_scene_error(renderer):
    """Every vertex at one point has nothing to draw, with any camera; the automatic camera
    cannot frame a scene 1e-9 across a million units out, as float64 cannot place an eye near
    it. Both are the scene's fault,
    not the request's (a RequestError would be a 422 for a request that asked nothing odd)."""
    import trimesh

    point = trimesh.Trimesh(vertices=[[0.5, 0.5, 0.5]] * 3, faces=[[0, 1, 2]], process=False)
    for ground in (False, True):
        with pytest.raises(SceneError, match="lies at one point"):
            renderer.render(scene_from_meshes([point], ["point"]),
                            {"width": 64, "height": 48, "ground": ground, "camera": CAMERA})
    tiny = T.transformed(T.caster_on_ground(), 1e-10, (1e6, 0.0, 0.0))
    with pytest.raises(SceneError, match="spans 9.33e-10 units at 1e[+]06 units from the origin: "
                                         "too small there for the automatic camera"):
        renderer.render(tiny, {"width": 64, "height": 48})
    # The same scene nearer the origin is framed.
    near = T.transformed(T.caster_on_ground(), 1e-10, (1.0, 0.0, 0.0))
    assert renderer.render(near, {"width": 64, "height": 48}).color.shape == (48, 64, 3)


def test_two_sided_thin_sheets_cast_from_both_sides(renderer):
    for direction in ([-0.4, -1, -0.3], [0.5, -1, 0.6]):
        m, _ = iou(renderer, T.thin_sheets(), camera=CAMERA, lights=[{"direction": direction}])
        assert m.iou >= 0.95, m


def test_contact_shadow_without_gap_or_leak(renderer, scene):
    # The post stands on the ground: its shadow must start at its foot.
    m, _ = iou(renderer, scene, camera={"eye": [3.5, 1.5, 3.0], "target": [1.6, 0.3, 0.8]},
               lights=[{"direction": [-0.6, -0.5, -0.4]}])
    assert m.iou >= 0.95, m
    assert m.missed_shadow_pct < 2.0


def test_coplanar_caster_and_receiver_has_no_acne(renderer):
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    ground = trimesh.Trimesh([[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]],
                             [[0, 2, 1], [0, 3, 2]])
    decal = trimesh.Trimesh([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]],
                            [[0, 2, 1], [0, 3, 2]])
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    box.apply_translation((1.5, 0.25, 1.5))
    m, _ = iou(renderer, scene_from_meshes([ground, decal, box]), camera=CAMERA,
               lights=[{"direction": [-0.5, -1, -0.2]}])
    assert m.false_shadow_pct <= 0.1, m
    assert m.iou >= 0.95, m


@pytest.mark.parametrize("far_end", [1e4, 5e10])
def test_a_caster_narrower_than_float32_resolves_where_it_lies_gets_a_warning(renderer, far_end):
    """A unit box over the far end of a plane ``2 * far_end`` long: 1e4 units from the scene's
    centre the box is 1e-4 of its distance and casts its shadow; 5e10 units out float32 holds
    nothing finer than about 4e3 units there, so its map would be rounding noise (the depth
    range once rounded to one number and the projection divided by zero, unsaid). The light
    then shines unshadowed, with a warning, and nothing overflows on the way."""
    import warnings as w

    from shadowmap.renderer.scene import scene_from_meshes as meshes

    plane = T._plane(1.0)
    plane.vertices *= [2 * far_end, 1.0, 4.0]
    scene = meshes([plane, T._box((1, 1, 1), (far_end - 1.0, 1.0, 0.0))], ["plane", "box"])
    params = {"width": 160, "height": 120, "outputs": ["color", "visibility"],
              "lights": [{"direction": [-0.2, -1.0, -0.1]}]}
    if far_end < 1e6:  # near the box; the automatic camera frames the whole plane
        params["camera"] = {"eye": [far_end + 2.0, 4.0, 5.0], "target": [far_end - 1, 0.5, 0]}
    with w.catch_warnings():
        w.simplefilter("error", RuntimeWarning)
        result = renderer.render(scene, params)
    light = result.plan["lights"][0]
    if far_end < 1e6:
        assert light["shadow_map"] == "ortho" and not result.warnings
        assert (result.visibility[..., 0] < 0.5).mean() > 0.01  # the box's shadow
    else:
        assert light["shadow_map"] is None and light["skipped_pass"] == "below_precision"
        assert any("narrower than the GPU's float32" in m for m in result.warnings)


def _box_at_the_far_end(far_end: float):
    """A unit box over the far end of a plane ``2 * far_end`` long, and a camera 5 units from it
    (the scene's centre ``far_end`` away)."""
    from shadowmap.renderer.scene import scene_from_meshes as meshes

    plane = T._plane(1.0)
    plane.vertices *= [2 * far_end, 1.0, 4.0]
    scene = meshes([plane, T._box((1, 1, 1), (far_end - 1.0, 1.0, 0.0))], ["plane", "box"])
    camera = {"eye": [far_end + 2.0, 4.0, 5.0], "target": [far_end - 1.0, 0.5, 0.0]}
    return scene, camera


def test_a_camera_close_to_a_part_of_a_large_scene_sees_it(renderer):
    """The automatic near plane followed the scene's bounding sphere, at least 1e-4 of the far
    plane: 8 units here, and the box 5 units from the camera was clipped away, unsaid. It now
    comes in front of the nearest box (the depth buffer is reversed float: deep ranges cost no
    precision)."""
    scene, camera = _box_at_the_far_end(4e4)
    result = renderer.render(scene, {"width": 160, "height": 120, "camera": camera,
                                     "outputs": ["color", "depth"],
                                     "lights": [{"direction": [-0.2, -1.0, -0.1]}]})
    assert not any("near plane" in w for w in result.warnings), result.warnings
    assert np.nanmin(result.depth) < 6.0  # the box's nearest face, drawn
    assert result.plan["camera"]["znear"] < 5.0


@pytest.mark.parametrize(("far_end", "says"), [
    (1e6, "'plane' (5.39 units away, 0.0372 units a pixel there) is drawn from float32 values up "
          "to 2e+06 units"),
    (1e9, "the automatic near plane at 202 units"),
])
def test_what_a_close_camera_in_a_vast_scene_cannot_show_is_said(renderer, far_end, says):
    """The view is drawn from a point beside the eye, but the plane under the box is two
    triangles 2e6 units long: what the GPU interpolates over them steps by 0.24 units, coarser
    than the view's pixels there, and that is said. 1e9 units out the depth range from the
    camera to the far end is 4e8 times the box's distance, past what the near plane follows
    (1e-7 of the far plane): the box is clipped, and that is said too."""
    scene, camera = _box_at_the_far_end(far_end)
    result = renderer.render(scene, {"width": 160, "height": 120, "camera": camera,
                                     "lights": [{"direction": [-0.2, -1.0, -0.1]}]})
    assert any(says in w for w in result.warnings), result.warnings


@pytest.mark.parametrize("far", [1e5, 1e7, 1e9])
def test_a_close_view_of_a_far_part_of_a_vast_scene_is_drawn_from_its_eye(renderer, far):
    """A camera 3 units from a part 1e5 units from the scene's other part (a vast scene: the
    centre lies half-way). Drawn relative to the scene's centre, float32 positions there step
    by 0.006 units, more than half a pixel: edges and shadows came out jagged (shadow IoU 0.68
    against the same part drawn alone, with a warning), and at 1e7 the shadow was left out.
    The view is now drawn relative to a point beside its eye: the same picture as the part
    alone at its own origin."""
    params = {"width": 320, "height": 240, "outputs": ["color", "visibility"],
              "lights": [{"direction": [-0.3, -1.0, -0.2]}]}
    alone = renderer.render(T.part_far_out(0.0, origin_box=False),
                            dict(params, camera={"eye": [2, 3, 3], "target": [0, 0.5, 0]}))
    # Past 1e7 the depth from the eye to the far box needs the request's own near plane.
    depth = {"znear": 0.5, "zfar": 3 * far} if far > 1e7 else {}
    far_out = renderer.render(T.part_far_out(far), dict(params, camera={
        "eye": [far + 2, 3, 3], "target": [far, 0.5, 0], **depth}))
    assert far_out.warnings == []
    camera = far_out.plan["camera"]
    assert camera["origin_at"] == "eye"
    # A grid point beside the eye, far nearer to it than the scene's centre (far / 2 away).
    assert np.linalg.norm(np.subtract(camera["origin"], [far + 2, 3, 3])) < 0.02 * far
    shade, shade_alone = far_out.visibility[..., 0] < 0.5, alone.visibility[..., 0] < 0.5
    assert (shade & shade_alone).sum() / (shade | shade_alone).sum() > 0.99
    differ = np.abs(far_out.color.astype(int) - alone.color.astype(int)).max(axis=-1) > 8
    assert differ.mean() < 1e-3


@pytest.mark.parametrize("out", [0.0, 1.83e6, 1.83e8])
def test_a_tiny_model_far_out_is_seen_and_shadowed_as_the_reference_sees_it(renderer, models,
                                                                            out):
    """The Duck scaled to 1e-6 units (its file's camera with it) and moved 1.83e8 units up:
    float64 world coordinates there step by 3e-8, a twentieth of it. The camera's view was
    made relative to the render's origin after inverting its world pose, which cancelled
    steps of the eye's size (depth off by 0.9 %, 193 pixels seen differently, shadow IoU
    0.70); it is now inverted from the origin-relative pose, and the reference places each
    part relative to its frame before rounding to float64: the two agree exactly on what each
    pixel sees, and on the shadow as at the origin."""
    from conftest import load_model

    duck = T.transformed(load_model(models, "Duck.glb"), 5.05e-7, (0.0, out, 0.47))
    m = T.measure(renderer, duck, RenderParams.model_validate({
        "width": 160, "height": 120, "outputs": ["visibility", "depth"],
        "lights": [{"direction": [0.2, -1.0, 0.1]}], "shadows": {"fit": "scene"}}))
    seen, truth = np.isfinite(m.result.depth), np.isfinite(m.reference.depth)
    assert seen.sum() > 3000 and (seen != truth).sum() <= 2
    both = seen & truth
    rel = np.abs(m.result.depth[both] - m.reference.depth[both]) / m.reference.depth[both]
    assert np.median(rel) < 1e-4
    assert m.metrics[0].iou >= 0.96, m.metrics[0]
    assert m.result.warnings == []


def test_a_part_narrower_than_a_float64_step_of_its_place_is_fitted_from_its_matrix(renderer,
                                                                                     models):
    """The Duck scaled to 7e-7 units and moved 9.15e9 units out, where float64 world
    coordinates step by 1.9e-6: its world box is 0 wide along x. The point light's map was
    fitted to that box and missed the Duck (shadow IoU 0 against the reference, unsaid); boxes
    that coarse are now placed from the instance's matrix relative to the render's origin
    (plan.instances.SceneArrays.coarse), and the shadow is the one at 9.15e6 units."""
    from conftest import load_model
    from shadowmap.renderer.plan.instances import scene_arrays

    def shadow(out: float):
        duck = T.transformed(load_model(models, "Duck.glb", ground=False), 4.363e-7,
                             (out, 0.0, -1.64))
        lo, hi = duck.bounds
        centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
        light = {"type": "point",
                 "position": (centre - np.array([0.523, -0.614, 0.591]) * size * 3630).tolist()}
        m = T.measure(renderer, duck, RenderParams.model_validate({
            "width": 64, "height": 48, "lights": [light], "shadows": {"fit": "scene"}}))
        return duck, m

    duck, far = shadow(9.15e9)
    assert duck.bounds[1, 0] - duck.bounds[0, 0] == 0.0  # what float64 keeps of its width
    assert len(scene_arrays(duck).coarse) == 1
    _, near = shadow(9.15e6)
    assert far.metrics[0].iou >= near.metrics[0].iou - 0.05 and far.metrics[0].iou > 0.8
    assert far.result.warnings == []


VAST_VARIANTS = {
    "directional": ([{"direction": [-0.3, -1.0, -0.2]}], {}),
    "directional, 3 cascades": ([{"direction": [-0.3, -1.0, -0.2]}], {"cascades": 3}),
    "directional, fit scene": ([{"direction": [-0.3, -1.0, -0.2]}], {"fit": "scene"}),
    "spot": ([{"type": "spot", "position": [1, 6, 2], "direction": [-0.1, -1, -0.3],
               "outer_cone_deg": 40}], {}),
    "point": ([{"type": "point", "position": [1, 4, 2]}], {}),
    "point, fit scene": ([{"type": "point", "position": [1, 4, 2]}], {"fit": "scene"}),
}


@pytest.mark.parametrize("far", [1e5, 1e7])
def test_a_vast_scene_shadows_a_close_view_as_its_part_alone_or_says_why_not(renderer, far):
    """The close view of :func:`test_a_close_view_of_a_far_part_of_a_vast_scene_is_drawn_\
    from_its_eye` under every kind of light and fit: the shadow matches the part drawn alone,
    or the result says why not. One map over every receiver (``fit: "scene"``) cannot serve
    both parts: a directional map 1e5 units wide has texels of 24 units, and a point light's
    cube map from 2.5 to 1e7 units has a quantisation bias of 0.9 units (shadow IoU 0 and 0.59
    against the part alone); both were unsaid. Fitted to the view, every light matches."""
    params = {"width": 320, "height": 240, "outputs": ["visibility"]}
    said = {}
    for name, (lights, shadows) in VAST_VARIANTS.items():
        moved = [dict(light, **({"position": [light["position"][0] + far,
                                              *light["position"][1:]]}
                                if "position" in light else {})) for light in lights]
        alone = renderer.render(T.part_far_out(0.0, origin_box=False), dict(
            params, lights=lights, shadows=shadows,
            camera={"eye": [2, 3, 3], "target": [0, 0.5, 0]}))
        far_out = renderer.render(T.part_far_out(far), dict(
            params, lights=moved, shadows=shadows,
            camera={"eye": [far + 2, 3, 3], "target": [far, 0.5, 0]}))
        a, b = alone.visibility[..., 0] < 0.5, far_out.visibility[..., 0] < 0.5
        match = (a & b).sum() / max((a | b).sum(), 1) > 0.99
        assert alone.warnings == [], (name, alone.warnings)
        assert match or far_out.warnings, (name, "a different shadow, unsaid")
        if "fit" not in shadows:
            assert match and far_out.warnings == [], (name, far_out.warnings)
        said[name] = " ".join(far_out.warnings)
    assert "would need" in said["directional, fit scene"]
    assert 'fit "view"' in said["directional, fit scene"]
    if far >= 1e7:
        assert "quantisation bias" in said["point, fit scene"]


@pytest.mark.parametrize("kind", ["spot", "point"])
def test_a_caster_almost_touching_a_spot_or_point_light_casts(renderer, kind):
    """A 4e-6 box 1e-5 below a light 2 units over the ground: its shadow is a wide disc. The
    map's near plane stopped at 1e-5 of its far plane (2e-5 units here) and clipped the box,
    unsaid (IoU 0). It now follows the casters down to 2**-22 of the far plane (maps store
    linear depth); a box nearer than that is clipped with a warning."""
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    def scene(gap: float, size: float):
        tiny = trimesh.creation.box(extents=(size,) * 3)
        tiny.apply_translation((0, 2.0 - gap - size / 2, 0))
        ground = trimesh.creation.box(extents=(6, 0.01, 6))
        return scene_from_meshes([ground, tiny])

    light = {"type": kind, "position": [0, 2, 0]}
    if kind == "spot":
        light.update(direction=[0, -1, 0], outer_cone_deg=30)
    m, result = iou(renderer, scene(1e-5, 4e-6), camera=CAMERA, lights=[light])
    assert m.iou >= 0.9, m
    assert result.warnings == []
    clipped = renderer.render(scene(1e-7, 4e-8), {"camera": CAMERA, "lights": [light],
                                                  "width": 64, "height": 48})
    assert any("begin nearer to the" in w for w in clipped.warnings), clipped.warnings
