"""Where shadows can fall on screen (renderer/plan/shadow_region.py): exact sweeps of small boxes,
screen rectangles, a randomized check that no shadowed point is ever left out, and renders that
draw the rest of the frame without lookups yet match the frame drawn with lookups everywhere."""

from __future__ import annotations

import json

import numpy as np
import pytest

from shadowmap.renderer import RenderParams
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import geometry
from shadowmap.renderer.plan import shadow_region as SR
from shadowmap.renderer.plan.shadow_region import (
    _swept_directional,
    _swept_positional,
    screen_rects,
    union_per_receiver,
)
from shadowmap.renderer.reference import trace_reference
from test_plan_pure import plan

INF = np.inf
UNIT = (np.array([-0.5, 1.0, -0.5]), np.array([0.5, 2.0, 0.5]))  # a unit box, 1 above y = 0
GROUND = (np.array([-10.0, -0.1, -10.0]), np.array([10.0, 0.0, 10.0]))


def _sweep_dir(box, receiver, u):
    lo, hi = _swept_directional(box[0], box[1], receiver[0], receiver[1],
                                np.asarray(u, float) / np.linalg.norm(u))
    return lo, hi


def test_straight_down_the_shadow_is_the_footprint():
    lo, hi = _sweep_dir(UNIT, GROUND, [0, -1, 0])
    np.testing.assert_allclose(lo, [-0.5, -0.1, -0.5])
    np.testing.assert_allclose(hi, [0.5, 0.0, 0.5])


def test_slanted_light_moves_the_footprint_by_height_times_slope():
    # Travelling 1 sideways per 1 down: the box at heights 1..2 lands 1..2.1 further along x.
    lo, hi = _sweep_dir(UNIT, GROUND, [1, -1, 0])
    np.testing.assert_allclose(lo, [0.5, -0.1, -0.5])
    np.testing.assert_allclose(hi, [2.6, 0.0, 0.5])


def test_light_travelling_away_from_the_receiver_shadows_nothing():
    lo, hi = _sweep_dir(UNIT, GROUND, [0, 1, 0])
    assert np.any(lo > hi)


def test_the_caster_is_inside_its_own_shadow_volume():
    lo, hi = _sweep_dir(UNIT, UNIT, [0.3, -1, 0.2])
    np.testing.assert_allclose(lo, UNIT[0])
    np.testing.assert_allclose(hi, UNIT[1])


def test_a_light_parallel_to_an_axis_keeps_the_box_on_that_axis():
    # Travelling along -x: the receiver slab below the box (y < 1) is never reached.
    lo, hi = _sweep_dir(UNIT, GROUND, [-1, 0, 0])
    assert np.any(lo > hi)
    wall = (np.array([-5.0, 0.0, -3.0]), np.array([-4.9, 3.0, 3.0]))
    lo, hi = _sweep_dir(UNIT, wall, [-1, 0, 0])
    np.testing.assert_allclose(lo, [-5.0, 1.0, -0.5])
    np.testing.assert_allclose(hi, [-4.9, 2.0, 0.5])


def test_point_light_scales_the_box_onto_the_ground():
    # Light 4 above the ground: the box's top (2 below the light) reaches the slab's underside
    # (4.1 below it) scaled by 4.1 / 2.
    light = np.array([0.0, 4.0, 0.0])
    lo, hi = _swept_positional(UNIT[0], UNIT[1], GROUND[0], GROUND[1], light)
    np.testing.assert_allclose(lo, [-1.025, -0.1, -1.025])
    np.testing.assert_allclose(hi, [1.025, 0.0, 1.025])


def test_point_light_inside_the_caster_reaches_every_receiver():
    lo, hi = _swept_positional(UNIT[0], UNIT[1], GROUND[0], GROUND[1], np.array([0, 1.5, 0]))
    np.testing.assert_allclose(lo, GROUND[0])
    np.testing.assert_allclose(hi, GROUND[1])


def test_point_light_between_caster_and_receiver_shadows_nothing():
    # The box above the light, the ground below: the shadow goes up.
    lo, hi = _swept_positional(UNIT[0], UNIT[1], GROUND[0], GROUND[1], np.array([0, 0.5, 0]))
    assert np.any(lo > hi)


def _view_proj(eye, target, yfov=60.0, w=640, h=480):
    view = np.linalg.inv(geometry.look_at(np.asarray(eye, float), np.asarray(target, float)))
    return geometry.perspective(np.radians(yfov), w / h, 0.1, 100.0) @ view


def test_screen_rect_of_a_centred_box_is_centred():
    vp = _view_proj([0, 0, 5], [0, 0, 0])
    (x0, y0, x1, y1), = screen_rects(np.array([[[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]]), vp, 640,
                                     480)
    assert x0 + x1 == 640 and y0 + y1 == 480
    # The near face (z = 0.5, 4.5 away) spans 1 / (2 * 4.5 * tan 30°) of the frame's height.
    half = 480 / 2 / (4.5 * np.tan(np.radians(30)))
    assert abs((y1 - y0) - 2 * (0.5 * half + SR.PAD_PIXELS)) <= 2


def test_screen_rect_of_a_box_through_the_camera_is_finite_and_behind_is_empty():
    vp = _view_proj([0, 0, 5], [0, 0, 0])
    through = np.array([[[-0.5, -0.5, 0.0], [0.5, 0.5, 10.0]]])
    assert tuple(screen_rects(through, vp, 640, 480)[0]) == (0, 0, 640, 480)
    behind = np.array([[[-0.5, -0.5, 6.0], [0.5, 0.5, 7.0]]])
    x0, _, x1, _ = screen_rects(behind, vp, 640, 480)[0]
    assert x1 <= x0
    # A floor reaching under the camera: cut at the near plane, it still fills the lower half.
    floor = np.array([[[-50.0, -1.0, -50.0], [50.0, -1.0, 50.0]]])
    x0, y0, x1, y1 = screen_rects(floor, vp, 640, 480)[0]
    assert (x0, y0, x1) == (0, 0, 640) and 235 <= y1 <= 250


def test_union_per_receiver_skips_empty_rects_and_spreads_shared_ones():
    rects = np.array([[10, 20, 30, 40], [5, 25, 12, 50], [0, 0, 0, 0], [1, 1, 1, 9],
                      [50, 60, 70, 80]])
    which = np.array([0, 0, 2, 2, 1])
    np.testing.assert_array_equal(union_per_receiver(rects, which, 3),
                                  [[5, 20, 30, 50], [50, 60, 70, 80], [0, 0, 0, 0]])
    # A rectangle given to every receiver (-1) joins each one's own.
    shared = np.concatenate([rects, [[40, 0, 60, 10]]])
    np.testing.assert_array_equal(union_per_receiver(shared, np.append(which, -1), 3),
                                  [[5, 0, 60, 50], [40, 0, 70, 80], [40, 0, 60, 10]])
    assert union_per_receiver(rects[:0], which[:0], 2).tolist() == [[0] * 4] * 2


def _segment_hits_box(p, q, lo, hi):
    """Exact slab test: does the segment p -> q meet the box?"""
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - p) / d
        t1 = (hi - p) / d
    near = np.where(d == 0, np.where((p >= lo) & (p <= hi), -INF, INF), np.minimum(t0, t1))
    far = np.where(d == 0, np.where((p >= lo) & (p <= hi), INF, -INF), np.maximum(t0, t1))
    a, b = max(near.max(), 0.0), min(far.min(), 1.0)
    return a <= b


@pytest.mark.parametrize("kind", ["directional", "point"])
def test_no_shadowed_point_is_left_out(kind):
    """Random boxes and lights: every receiver point whose segment to the light meets a caster
    box lies in the swept box of that caster and receiver."""
    rng = np.random.default_rng(11)
    misses = checked = 0
    for _ in range(60):
        c = rng.uniform(-3, 3, (4, 3))
        casters = np.stack([c, c + rng.uniform(0.05, 2, (4, 3))], axis=1)
        r = rng.uniform(-4, 4, (3, 3))
        receivers = np.stack([r, r + rng.uniform(0.0, 4, (3, 3))], axis=1)
        if kind == "directional":
            u = rng.normal(size=3)
            u /= np.linalg.norm(u)
            lo, hi = _swept_directional(casters[:, None, 0], casters[:, None, 1],
                                        receivers[None, :, 0], receivers[None, :, 1], u)
        else:
            light = rng.uniform(-6, 6, 3)
            lo, hi = _swept_positional(casters[:, None, 0], casters[:, None, 1],
                                       receivers[None, :, 0], receivers[None, :, 1], light)
        for j in range(len(receivers)):
            pts = rng.uniform(receivers[j, 0], receivers[j, 1], (40, 3))
            for p in pts:
                target = p - 100.0 * u if kind == "directional" else light
                for i in range(len(casters)):
                    if _segment_hits_box(p, target, casters[i, 0], casters[i, 1]):
                        checked += 1
                        inside = np.all(p >= lo[i, j] - 1e-9) and np.all(p <= hi[i, j] + 1e-9)
                        misses += not inside
    assert checked > 300
    assert misses == 0


# ---------------------------------------------------------------------------------------------
# The plan


def test_plan_reports_the_region_and_its_rectangles():
    p = plan(T.caster_on_ground())
    region = p.shadow_region
    assert region is not None and region.rect is not None and 0 < region.share < 0.5
    report = p.to_dict()["camera_pass"]["shadow_region"]
    assert report["rect"] == list(region.rect) and report["rects"] == [list(r) for r in
                                                                       region.rects]
    # All three receive; the ground shows outside its shadows' rectangle, the box and the post
    # (which shadow themselves) inside theirs.
    assert report["instances"] == {"lookup": 3, "plain": 0, "split": 1}
    x, y, w, h = region.rect
    for bx, by, bw, bh in region.rects:  # every rectangle lies in the region's
        assert x <= bx and y <= by and bx + bw <= x + w and by + bh <= y + h
    # Ground, box, post: each its own rectangle (numbered in drawing order), the ground split
    # around its own.
    lookup = region.classes[[0, 1, 2]] - SR.LOOKUP
    assert (lookup >= 0).all() and sorted(lookup // 2) == [0, 1, 2]
    assert (lookup % 2).tolist() == [1, 0, 0]


def test_without_optimize_there_is_no_region():
    p = plan(T.caster_on_ground(), optimize=False)
    assert p.shadow_region is None
    assert "shadow_region" not in p.to_dict()["camera_pass"]


def test_without_a_map_no_region_is_planned(monkeypatch):
    """Lights that cast no shadow leave no lookup to draw around: the region is not computed."""
    calls = []
    real = SR.plan_region

    def spy(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    import shadowmap.renderer.plan.plan as plan_module

    monkeypatch.setattr(plan_module, "plan_region", spy)
    unlit = plan(T.caster_on_ground(), lights=[{"direction": [-0.5, -1, -0.3],
                                                 "cast_shadows": False}])
    assert not unlit.map_lights and unlit.shadow_region is None and not calls
    assert "shadow_region" not in unlit.to_dict()["camera_pass"]
    lit = plan(T.caster_on_ground(), lights=[{"direction": [-0.5, -1, -0.3]}])
    assert lit.shadow_region is not None and calls == [1]


def test_a_shadow_off_screen_skips_the_light_pass_unless_its_picture_is_asked_for():
    # The camera looks down at a corner of the ground, away from the casters and their shadows;
    # a map over every receiver (fit "scene") has casters, and nothing of their shadows shows.
    away = {"eye": [2.6, 1.0, -2.6], "target": [2.7, 0.0, -2.7]}
    scene = T.caster_on_ground()
    assert plan(scene, camera=away).lights[0].reason == "no_caster_in_frustum"  # fit "view"
    skipped = plan(scene, camera=away, shadows={"fit": "scene"})
    assert [lp.reason for lp in skipped.lights] == ["no_shadow_in_view"]
    assert skipped.map_lights == [] and skipped.shadow_region.rects == ()
    kept = plan(scene, camera=away, shadows={"fit": "scene"}, outputs=["color", "light_depth"])
    assert kept.lights[0].kind == "ortho"
    assert kept.shadow_region.rect is None and kept.shadow_region.rects == ()
    assert set(kept.shadow_region.classes[kept.visible].tolist()) == {SR.UNREACHED}


# ---------------------------------------------------------------------------------------------
# Rendering: the frame drawn around the region is the frame drawn with lookups everywhere


def _both(renderer, scene, params: dict):
    """The same request rendered with the region and with lookups on every receiver."""
    p = RenderParams.model_validate({**params, "outputs": ["color", "visibility", "depth"]})
    renderer.plans.clear()
    split = renderer.render(scene, p)
    old = SR.MAX_SPLIT_SHARE
    SR.MAX_SPLIT_SHARE = -1.0  # every rectangle becomes the frame: lookups everywhere
    try:
        renderer.plans.clear()
        whole = renderer.render(scene, p)
    finally:
        SR.MAX_SPLIT_SHARE = old
        renderer.plans.clear()
    return split, whole


CASES = {
    "sun": {"lights": [{"direction": [-0.5, -1, -0.3]}]},
    "spot": {"lights": [{"type": "spot", "position": [-2.5, 4, 1.5], "target": [0, 0, 0],
                         "outer_cone_deg": 40}]},
    "point": {"lights": [{"type": "point", "position": [0.5, 2.5, 0.5]}]},
    "two_lights_pcf5": {"lights": [{"direction": [-0.5, -1, -0.3]},
                                   {"type": "point", "position": [-1, 3, 1]}],
                        "shadows": {"pcf_kernel": 5}},
}


@pytest.mark.gl
@pytest.mark.parametrize("case", list(CASES))
def test_split_frame_matches_lookups_everywhere(renderer, case):
    scene = T.caster_on_ground()
    params = {"width": 400, "height": 300, **CASES[case]}
    split, whole = _both(renderer, scene, params)
    region = split.plan["camera_pass"]["shadow_region"]
    assert region["share"] < 0.85 and region["instances"]["split"] >= 1, region
    assert region["split"] and region["saved_share"] >= SR.MIN_SAVED_SHARE, region
    np.testing.assert_array_equal(split.depth, whole.depth)  # NaN where both are empty
    vs, vw = split.visibility, whole.visibility
    assert (vw < 0.5).sum() > 100  # there are shadows, and they are the same
    same = np.isclose(vs, vw, atol=1e-6, equal_nan=True)  # (H, W, lights)
    assert same.mean() > 0.99
    # Where they differ, the frame drawn around the region reads exactly 1, and the ray-traced
    # reference agrees: no caster reaches there (the lookup's partial shadow was false).
    p = RenderParams.model_validate(params)
    camera = resolve_camera(p.camera, scene, p.width, p.height)
    ref = trace_reference(scene, camera, resolve_lights(p.lights, scene))
    assert np.all(vs[~same] == 1.0)
    # (NaN: the reference's ray through the pixel centre missed a silhouette the raster hit.)
    assert np.all(np.nan_to_num(ref.visibility, nan=1.0)[~same] == 1.0)
    everywhere = same.all(axis=2)
    np.testing.assert_array_equal(split.color[everywhere], whole.color[everywhere])


@pytest.mark.gl
def test_split_frame_is_as_accurate_as_lookups_everywhere(renderer, models):
    from conftest import load_model

    scene = load_model(models, "Duck.glb")
    lo, hi = scene.bounds
    c = ((lo + hi) / 2).tolist()
    for light in ({"direction": [-0.5, -1, 0.2]},
                  {"type": "point", "position": [c[0] + 30, c[1] + 120, c[2] + 40]}):
        p = RenderParams.model_validate({"lights": [light]})
        renderer.plans.clear()
        split = T.measure(renderer, scene, p).metrics[0]
        old = SR.MAX_SPLIT_SHARE
        SR.MAX_SPLIT_SHARE = -1.0
        try:
            renderer.plans.clear()
            whole = T.measure(renderer, scene, p).metrics[0]
        finally:
            SR.MAX_SPLIT_SHARE = old
            renderer.plans.clear()
        assert split.missed_shadow_pct <= whole.missed_shadow_pct, json.dumps(light)
        assert split.iou >= whole.iou - 1e-9, (split.iou, whole.iou)


def test_too_little_saved_draws_lookups_on_every_receiver():
    # Two receivers on a 640x480 frame: one shows 100x100 pixels, 90x100 of them in its shadow
    # rectangle; the other's shadow covers its 50x50 pixels. 1,000 pixels would be saved.
    visible = np.array([0, 1])
    receive = np.array([True, True])
    on_screen = np.array([[100, 100, 200, 200], [300, 300, 350, 350]])
    rects = np.array([[110, 100, 200, 200], [300, 300, 350, 350]])
    region = SR.divide(rects, visible, receive, on_screen, 640, 480)
    assert region.classes.tolist() == [SR.LOOKUP + 1, SR.LOOKUP + 2]
    assert region.saved_share == pytest.approx(1000 / (640 * 480))
    assert not region.split and region.to_dict()["split"] is False
    # A receiver no shadow reaches, 300x300 pixels, drawn without lookups: that is enough.
    region = SR.divide(np.concatenate([rects, [[0, 0, 0, 0]]]), np.array([0, 1, 2]),
                       np.array([True, True, True]),
                       np.concatenate([on_screen, [[0, 0, 300, 300]]]), 640, 480)
    assert region.classes[2] == SR.UNREACHED
    assert region.saved_share == pytest.approx(91_000 / (640 * 480)) and region.split


def test_small_frames_draw_lookups_on_every_receiver():
    # The region costs about a millisecond of Python; the lookups of a small frame less.
    small = plan(T.caster_on_ground(), width=96, height=72)
    assert small.shadow_region is None and small.map_lights
    assert plan(T.caster_on_ground(), width=400, height=300).shadow_region is not None
