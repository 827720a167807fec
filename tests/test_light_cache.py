"""``shadows.fit: "scene"`` and the light-map cache: one light pass for every view of a scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shadowmap.renderer import Renderer, RenderParams, RequestError
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.demo import demo_glb
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import make_plan
from shadowmap.renderer.scene import load_scene


def orbit(k: int, n: int = 8, fit: str = "scene", radius: float = 4.0, **shadows) -> dict:
    a = 2 * math.pi * k / n
    return {
        "width": 160, "height": 120,
        "camera": {"eye": [radius * math.cos(a), 2.5, radius * math.sin(a)],
                   "target": [0.0, 0.5, 0.0]},
        "shadows": {"fit": fit, **shadows},
        "outputs": ["color", "visibility"],
    }


@pytest.fixture(scope="module")
def demo():
    return load_scene(demo_glb())


def plan_of(scene, params: dict):
    p = RenderParams.model_validate(params)
    cam = resolve_camera(p.camera, scene, p.width, p.height)
    lights = resolve_lights(p.lights, scene)
    lo, hi = scene.bounds
    return make_plan(scene, cam, lights, (lo + hi) / 2, p)


# -- the plan (no GL) ----------------------------------------------------------------------------


def test_scene_fit_does_not_depend_on_the_camera(demo):
    plans = [plan_of(demo, orbit(k)) for k in range(4)]
    first = plans[0].lights[0]
    assert first.kind == "ortho"
    for p in plans[1:]:
        lp = p.lights[0]
        assert np.array_equal(lp.view, first.view) and np.array_equal(lp.proj, first.proj)
        assert (lp.near, lp.far, lp.casters) == (first.near, first.far, first.casters)
    assert all(p.to_dict()["fit"] == "scene" for p in plans)


def test_scene_fit_lights_are_planned_once_for_every_view(demo):
    # Views of an orbit that want the same 'auto' map size: the directional light is planned by
    # the first and taken from the memo by the others, and every plan equals the one made
    # without it.
    from shadowmap.renderer.cache import BoundedCache

    memo: BoundedCache = BoundedCache(8)
    for k in range(4):
        p = RenderParams.model_validate(orbit(k))
        cam = resolve_camera(p.camera, demo, p.width, p.height)
        lights = resolve_lights(p.lights, demo)
        lo, hi = demo.bounds
        with_memo = make_plan(demo, cam, lights, (lo + hi) / 2, p, memo)
        fresh = make_plan(demo, cam, lights, (lo + hi) / 2, p)
        assert with_memo.to_dict() == fresh.to_dict()
        a, b = with_memo.lights[0], fresh.lights[0]
        assert np.array_equal(a.proj, b.proj) and a.casters == b.casters
    assert (memo.misses, memo.hits) == (1, 3)
    # A camera four times as far wants a smaller 'auto' map: planned again, not taken from the memo.
    far = RenderParams.model_validate(orbit(0, radius=16.0))
    cam = resolve_camera(far.camera, demo, far.width, far.height)
    far_lights = resolve_lights(far.lights, demo)
    lp = make_plan(demo, cam, far_lights, (lo + hi) / 2, far, memo).lights[0]
    fresh_far = make_plan(demo, cam, far_lights, (lo + hi) / 2, far).lights[0]
    assert lp.map_size == fresh_far.map_size < with_memo.lights[0].map_size
    assert np.array_equal(lp.proj, fresh_far.proj)
    # A view fit never reads the memo.
    counts = (memo.misses, memo.hits)
    view = RenderParams.model_validate(orbit(1, fit="view"))
    cam = resolve_camera(view.camera, demo, view.width, view.height)
    make_plan(demo, cam, resolve_lights(view.lights, demo), (lo + hi) / 2, view, memo)
    assert (memo.misses, memo.hits) == counts


@pytest.mark.parametrize("make", [T.caster_on_ground, lambda: T.many_small_objects(60)])
def test_scene_fit_views_take_their_shadow_regions_pairs_from_the_memo(make):
    # Views that see different receivers: each takes its visible receivers' swept pairs from the
    # ones the memo made over every receiver, and plans the region a fresh plan gives, box for
    # box; the pairs are made once.
    from shadowmap.renderer.cache import BoundedCache

    scene = make()
    lo, hi = scene.bounds
    centre, size = (lo + hi) / 2, float(np.max(hi - lo))
    memo: BoundedCache = BoundedCache(8)
    shown = set()
    for k in range(6):
        a = 2 * math.pi * k / 6
        eye = centre + size * np.array([0.9 * math.cos(a), 0.35 + 0.1 * k, 0.9 * math.sin(a)])
        p = RenderParams.model_validate({
            "width": 640, "height": 480, "shadows": {"fit": "scene", "map_size": 1024},
            "camera": {"eye": eye.tolist(), "target": (centre + [0.1 * k, 0, 0]).tolist(),
                       "yfov_deg": 30.0 + 8 * k}})
        cam = resolve_camera(p.camera, scene, p.width, p.height)
        lights = resolve_lights(p.lights, scene)
        with_memo = make_plan(scene, cam, lights, centre, p, memo)
        fresh = make_plan(scene, cam, lights, centre, p)
        a_region, b_region = with_memo.shadow_region, fresh.shadow_region
        assert a_region is not None and b_region is not None
        assert with_memo.to_dict() == fresh.to_dict()
        assert np.array_equal(a_region.classes, b_region.classes)
        assert (a_region.rects, a_region.counts, a_region.share) == (
            b_region.rects, b_region.counts, b_region.share)
        shown.add(tuple(with_memo.visible))
    assert len(shown) > 1 and (memo.misses, memo.hits) == (1, 5)
    (kept,) = memo.values()
    (pairs,) = kept._pairs.values()
    assert pairs is not None and len(pairs.boxes) > 0


def test_a_scene_fit_plan_keeps_no_more_pairs_than_its_bound(monkeypatch):
    # Past MAX_KEPT_PAIRS (caster, receiver) pairs the kept plan holds none, and each view
    # sweeps its own: the region is the same.
    from shadowmap.renderer.cache import BoundedCache
    from shadowmap.renderer.plan import shadow_region

    monkeypatch.setattr(shadow_region, "MAX_KEPT_PAIRS", 100)
    scene = T.many_small_objects(60)
    lo, hi = scene.bounds
    centre = (lo + hi) / 2
    memo: BoundedCache = BoundedCache(8)
    for yfov in (40.0, 50.0):
        p = RenderParams.model_validate({"width": 640, "height": 480, "camera": {
            "eye": (centre + [40.0, 30.0, 40.0]).tolist(), "target": centre.tolist(),
            "yfov_deg": yfov}, "shadows": {"fit": "scene", "map_size": 1024}})
        cam = resolve_camera(p.camera, scene, p.width, p.height)
        lights = resolve_lights(p.lights, scene)
        with_memo = make_plan(scene, cam, lights, centre, p, memo)
        fresh = make_plan(scene, cam, lights, centre, p)
        assert with_memo.shadow_region is not None
        assert with_memo.to_dict() == fresh.to_dict()
        assert np.array_equal(with_memo.shadow_region.classes, fresh.shadow_region.classes)
    (kept,) = memo.values()
    assert list(kept._pairs.values()) == [None]


def test_view_fit_follows_the_camera(demo):
    a, b = (plan_of(demo, orbit(k, fit="view")).lights[0] for k in (0, 2))
    assert not np.array_equal(a.proj, b.proj)


SPOT = {"type": "spot", "position": [-2.5, 4.0, 1.5], "target": [0, 0, 0], "outer_cone_deg": 40}


def _orbit_fits(scene, light: dict | None = None, n: int = 8) -> list:
    return [plan_of(scene, {**orbit(k, n, fit="view"),
                            **({"lights": [light]} if light else {})}).lights[0]
            for k in range(n)]


def _alike(a, b) -> bool:
    return bool(np.array_equal(a.view, b.view) and np.array_equal(a.proj, b.proj)
                and (a.near, a.far, a.casters) == (b.near, b.far, b.casters))


def test_view_fits_end_at_the_deepest_receiver_under_the_map():
    # A box on a wide ground, seen from around: every view sees the ground under the box's
    # shadow, and further ground beyond it at other depths. The map's depth range ends at the
    # deepest receiver point under the map (a lookup elsewhere finds the point lit), so the
    # views fit the light alike for each 'auto' size and draw the same map.
    scene = T.caster_on_ground()
    fits = _orbit_fits(scene)
    by_size: dict[int, list] = {}
    for lp in fits:
        assert lp.kind == "ortho"
        by_size.setdefault(lp.map_size, []).append(lp)
    assert max(len(v) for v in by_size.values()) >= 4
    for group in by_size.values():
        assert all(_alike(group[0], lp) for lp in group[1:])
    # Shallower than the deepest receiver point a view sees: what the map left out is no
    # receiver it could shadow.
    p = RenderParams.model_validate(orbit(0, fit="view"))
    cam = resolve_camera(p.camera, scene, p.width, p.height)
    lo, hi = scene.bounds
    from shadowmap.renderer.plan.context import PlanContext
    from shadowmap.renderer.plan.geometry import transform_points

    ctx = PlanContext.build(scene, cam, (lo + hi) / 2, p)
    seen = np.concatenate([ctx.corners[ctx.seen.whole].reshape(-1, 3), ctx.seen.points])
    assert fits[0].far < float(np.max(-transform_points(fits[0].view, seen)[:, 2]))
    # A spot light's perspective map likewise, where two views see all of its pyramid.
    spots = _orbit_fits(scene, SPOT)
    assert all(lp.kind == "perspective" for lp in spots)
    assert any(_alike(a, b) for i, a in enumerate(spots) for b in spots[i + 1:])


def test_scene_fit_covers_receivers_the_camera_does_not_see(demo):
    # A camera close to the floor, looking at one corner: the view fit covers that corner only,
    # the scene fit the whole floor.
    params = {"width": 160, "height": 120,
              "camera": {"eye": [2.5, 0.4, 2.5], "target": [3.5, 0.0, 3.5]}}
    view = plan_of(demo, {**params, "shadows": {"fit": "view", "cascades": 1}}).lights[0]
    scene = plan_of(demo, {**params, "shadows": {"fit": "scene"}}).lights[0]
    assert scene.kind == "ortho" and view.kind == "ortho"

    def window_area(lp) -> float:
        # Orthographic: x, y scale of the projection are 2 / width, 2 / height.
        return 4.0 / (lp.proj[0, 0] * lp.proj[1, 1])

    assert window_area(scene) > 2 * window_area(view)
    assert not scene.cascades


def test_scene_fit_has_no_cascades():
    from shadowmap.renderer.render import _as_params

    with pytest.raises(RequestError, match="cascades"):
        _as_params({"shadows": {"fit": "scene", "cascades": 2}})
    assert RenderParams.model_validate({"shadows": {"fit": "scene", "cascades": 1}})


# -- the cache (GL) -----------------------------------------------------------------------------


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a, b, equal_nan=True))


@pytest.mark.gl
def test_views_share_one_light_pass_and_match_fresh_renders(renderer, demo):
    with Renderer(map_cache_bytes=0) as fresh:
        renderer.context.make_current()
        reports = []
        for k in range(4):
            got = renderer.render(demo, orbit(k, n=4))
            reports.append(got.plan["lights"][0]["light_pass"])
            fresh.context.make_current()
            want = fresh.render(demo, orbit(k, n=4))
            renderer.context.make_current()
            assert want.plan["lights"][0]["light_pass"] == "drawn"
            assert _same(got.color, want.color)
            assert _same(got.visibility, want.visibility)
    assert reports[1:] == ["cached"] * 3
    assert got.plan["light_passes_cached"] == 1


@pytest.mark.gl
def test_views_with_alike_view_fits_share_the_map_and_match_fresh_renders(renderer):
    # The default fit: views around a box on a wide ground that fit the light alike (above)
    # draw its map once per 'auto' size, and every view equals a render with no map cache.
    scene = T.caster_on_ground()
    reports = []
    with Renderer(map_cache_bytes=0) as fresh:
        for k in range(8):
            renderer.context.make_current()
            got = renderer.render(scene, orbit(k, fit="view"))
            reports.append(got.plan["lights"][0]["light_pass"])
            fresh.context.make_current()
            want = fresh.render(scene, orbit(k, fit="view"))
            assert want.plan["lights"][0]["light_pass"] == "drawn"
            assert _same(got.color, want.color)
            assert _same(got.visibility, want.visibility)
        renderer.context.make_current()
    sizes = {lp.map_size for lp in _orbit_fits(scene)}
    assert len(sizes) <= 3 and reports.count("cached") >= 8 - len(sizes)


@pytest.mark.gl
def test_a_changed_light_or_setting_draws_again(renderer, demo):
    base = orbit(0)
    renderer.render(demo, base)
    again = renderer.render(demo, orbit(1))
    assert again.plan["lights"][0]["light_pass"] == "cached"
    moved = {**orbit(1), "lights": [{"type": "directional", "direction": [-0.3, -1.0, -0.5]}]}
    assert renderer.render(demo, moved).plan["lights"][0]["light_pass"] == "drawn"
    # The filter is how the camera pass reads a map, not what the map holds.
    hard = orbit(1, filter="hard")
    assert renderer.render(demo, hard).plan["lights"][0]["light_pass"] == "cached"
    packed = orbit(1, encoding="rgba8")
    assert renderer.render(demo, packed).plan["lights"][0]["light_pass"] == "drawn"
    assert renderer.render(demo, orbit(2, encoding="rgba8")).plan["lights"][0][
        "light_pass"] == "cached"


@pytest.mark.gl
def test_a_repeated_view_fit_request_is_cached(renderer, demo):
    params = orbit(3, fit="view")
    first = renderer.render(demo, params)
    second = renderer.render(demo, params)
    assert second.plan["lights"][0]["light_pass"] == "cached"
    assert _same(first.color, second.color)


@pytest.mark.gl
def test_maps_over_the_cache_bound_are_not_cached(demo):
    # A 256² depth map is 256 KiB: a 64 KiB bound keeps none of them.
    with Renderer(map_cache_bytes=64 * 2**10) as r:
        for k in range(2):
            res = r.render(demo, orbit(k, map_size=256))
            assert res.plan["lights"][0]["light_pass"] == "drawn"
        assert len(r.light_pass.cache) == 0


@pytest.mark.gl
def test_evicted_maps_are_reused_not_leaked(demo):
    # Room for one 256² map of 32-bit depths: every new fit evicts the last, whose framebuffer
    # the next draw takes from the pool.
    with Renderer(map_cache_bytes=300 * 2**10) as r:
        for k in range(6):
            r.render(demo, orbit(k, fit="view", map_size=256, cascades=1, depth_bits=32))
        held = sum(len(v) for v in r.light_pass.pool.values()) + len(r.light_pass.cache)
        assert len(r.light_pass.cache) == 1
        assert held <= 2


@pytest.mark.gl
def test_a_repeated_request_plans_nothing(renderer, demo):
    params = orbit(5, fit="view", map_size=512)
    first = renderer.render(demo, params)
    second = renderer.render(demo, params)
    assert second.plan["plan_cache"] == "hit"
    for key in ("camera_pass", "light_passes", "fit", "outputs"):
        assert second.plan[key] == first.plan[key]
    assert second.plan["lights"][0]["light_pass"] == "cached"
    assert second.plan["shader_variants"]["light_pass"] == []  # no light-pass draw at all
    other = renderer.render(demo, {**params, "specular": 0.5})
    assert other.plan["plan_cache"] == "miss"  # any change of the request plans again
    assert _same(first.color, second.color)


@pytest.mark.gl
def test_a_request_model_changed_in_place_is_prepared_again(renderer, demo):
    """A repeated request reuses its validated camera, lights and plan key; the same model
    changed in place is a new request."""
    params = RenderParams.model_validate(orbit(2, fit="view", map_size=256))
    first = renderer.render(demo, params)
    assert renderer.render(demo, params).plan["plan_cache"] == "hit"
    params.camera.eye = [3.0, 2.0, 1.0]  # in place: the same object, another request
    moved = renderer.render(demo, params)
    assert moved.plan["camera"]["eye"] == pytest.approx([3.0, 2.0, 1.0])
    assert not _same(moved.color, first.color)
    fresh = renderer.render(load_scene(demo_glb()), params)
    assert _same(moved.color, fresh.color)
    # The caller's lists in the result are their own.
    moved.plan["camera"]["eye"].append(0.0)
    assert len(renderer.render(demo, params).plan["camera"]["eye"]) == 3


@pytest.mark.gl
def test_requests_differing_in_their_camera_alone_share_their_checks(demo):
    """A new camera on the same request resolves its camera and plans anew, and takes the rest
    of its preparation (limits, ground, memory estimate, the copy of the request, its lights)
    from the first such request: the same pictures, plans and warnings as a renderer that
    keeps nothing."""
    views = [orbit(k, fit="view", map_size=256, max_map_size=128) for k in (1, 2, 3)]
    with Renderer() as r, Renderer(cache_entries=0) as bare:
        kept = [r.render(demo, v) for v in views]
        assert len(r.request_bases) == 1  # one base for the three cameras
        assert len(r.requests) == 3
        assert all(k.plan["plan_cache"] == "miss" for k in kept)
        for v, k in zip(views, kept, strict=True):
            fresh = bare.render(demo, v)
            assert _same(k.color, fresh.color)
            assert k.warnings == fresh.warnings
            assert k.plan["camera"] == fresh.plan["camera"]
            assert k.plan["lights"][0]["map_size"] == fresh.plan["lights"][0]["map_size"]
        # Anything else changed is another base.
        other = r.render(demo, {**views[0], "specular": 0.5})
        assert len(r.request_bases) == 2
        assert other.plan["plan_cache"] == "miss"
        assert not bare.request_bases  # a renderer that keeps nothing keeps no base either
