"""Cascaded shadow maps: the plan's splits and fits (no GL), then rendered large scenes against
the ray-traced reference, per band of camera distance, at the origin and far from it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shadowmap.renderer import RenderParams
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import make_plan
from shadowmap.renderer.plan.cascades import (
    cascade_count,
    practical_splits,
    slices,
)


def _plan(scene, camera, light, **shadows):
    params = RenderParams(camera=camera, lights=[light], shadows=shadows)
    cam = resolve_camera(params.camera, scene, params.width, params.height)
    lo, hi = scene.bounds
    return make_plan(scene, cam, resolve_lights(params.lights, scene), (lo + hi) / 2, params)


def _moved(large: T.LargeScene, offset: float) -> tuple:
    """The scene and its camera moved by ``offset`` along x and z (float64 node matrices)."""
    shift = np.array([offset, 0.0, offset])
    scene = T.transformed(large.scene, offset=tuple(shift))
    camera = {k: (np.asarray(v) + shift).tolist() for k, v in large.camera.items()}
    return scene, camera


# --------------------------------------------------------------------------------------------
# The plan (pure)
# --------------------------------------------------------------------------------------------


def test_practical_splits_blend_logarithmic_and_uniform():
    assert np.allclose(practical_splits(1.0, 1000.0, 3, 1.0), [1, 10, 100, 1000])
    assert np.allclose(practical_splits(1.0, 1000.0, 3, 0.0), [1, 334, 667, 1000])
    half = practical_splits(1.0, 1000.0, 3, 0.5)
    assert np.allclose(half, (np.array([1, 10, 100, 1000]) + [1, 334, 667, 1000]) / 2)
    d = practical_splits(0.3, 5e4, 4, 0.8)
    assert d[0] == 0.3 and d[-1] == 5e4 and np.all(np.diff(d) > 0)


def test_slices_overlap_by_the_blend_band():
    parts = slices(2.0, 200.0, 3, 0.8, 0.1)
    assert [p.near for p in parts[1:]] == [p.far for p in parts[:-1]]
    for prev, cur in zip(parts, parts[1:], strict=False):
        assert prev.blend == pytest.approx(0.1 * (prev.far - prev.near))
        assert cur.reach_near == pytest.approx(cur.near - prev.blend)
    assert parts[0].reach_near == 2.0 and parts[-1].blend == 0.0


def test_cascade_count_follows_the_depth_ratio():
    assert cascade_count(1.0, 7.0, 4) == 2  # at least two once cascades are needed
    assert cascade_count(1.0, 100.0, 4) == 3  # 8^2 < 100 <= 8^3
    assert cascade_count(1.0, 1e6, 4) == 4
    assert cascade_count(1.0, 1e6, 3) == 3


def test_a_compact_scene_keeps_exactly_one_map():
    """A model on a table: 'auto' plans the very map that ``cascades: 1`` does."""
    scene = T.caster_on_ground()
    camera = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}
    sun = {"direction": [-0.5, -1, -0.3]}
    auto = _plan(scene, camera, sun).lights[0]
    one = _plan(scene, camera, sun, cascades=1).lights[0]
    assert not auto.cascades and auto.maps == (auto,)
    assert auto.map_size == one.map_size and np.array_equal(auto.proj, one.proj)
    assert "cascades" not in auto.to_dict()


def test_a_low_view_to_the_horizon_is_cascaded():
    large = T.terrain_to_horizon()
    plan = _plan(large.scene, large.camera, large.light)
    lp = plan.lights[0]
    k = len(lp.cascades)
    assert 2 <= k <= 4 and plan.map_lights == list(lp.cascades)
    sizes = {c.map_size for c in lp.cascades}
    assert len(sizes) == 1 and sizes.pop() <= 4096 // 2  # layers of one array texture
    splits = [c.split for c in lp.cascades]
    assert all(a[1] == b[0] for a, b in zip(splits, splits[1:], strict=False))
    assert splits[0][0] < 5 and splits[-1][1] > 300  # from the nearest seen box to the far ones
    # Each cascade is fitted to its own slice: nearer ones are smaller (finer texels).
    texels = [c.texel[0] for c in lp.cascades]
    assert texels == sorted(texels) and texels[0] < texels[-1] / 4
    report = lp.to_dict()
    assert len(report["cascades"]) == k and report["shadow_map"] == "ortho"
    assert all(c["texel_pixels"] > 0 for c in report["cascades"])


def test_the_request_can_force_the_count():
    large = T.terrain_to_horizon()
    assert len(_plan(large.scene, large.camera, large.light, cascades=3).lights[0].cascades) == 3
    assert not _plan(large.scene, large.camera, large.light, cascades=1).lights[0].cascades
    two = _plan(large.scene, large.camera, large.light, max_cascades=2).lights[0]
    assert len(two.cascades) == 2
    fixed = _plan(large.scene, large.camera, large.light, map_size=512).lights[0]
    assert {c.map_size for c in fixed.cascades} == {512}


def test_a_caster_wider_than_the_map_counts_only_over_it():
    """The 10,000-unit plane (one mesh with the box) casts too, but only its part over each
    map's window matters: the stored depth range follows that part, not the plane's far
    corners (which lie thousands of units nearer the light)."""
    large = T.small_caster_on_huge_plane()
    for lp in (_plan(large.scene, large.camera, large.light).lights[0],
               _plan(large.scene, large.camera, large.light, cascades=1).lights[0]):
        for m in lp.maps:
            assert m.far - m.near < 200, (m.near, m.far)  # the whole plane: over 3,000


def _orbit_camera(angle: float) -> dict:
    eye = [30.0 * math.sin(angle), 3.0, 30.0 * math.cos(angle)]
    return {"eye": eye, "target": [0.0, 1.0, 0.0], "znear": 0.5, "zfar": 400.0}


def test_stable_cascades_keep_one_texel_grid_along_an_orbit():
    """In stable mode each cascade's texel size stays the same as the camera orbits, and its
    window starts on whole texels of a grid fixed in light space: a static caster's shadow
    is drawn from the same texels in every frame."""
    large = T.terrain_to_horizon()
    frames = [_plan(large.scene, _orbit_camera(a), large.light, stable_cascades=True,
                    cascades=3).lights[0] for a in (0.0, 0.013, 0.05)]
    for k in range(3):
        texels = [f.cascades[k].texel[0] for f in frames]
        assert texels[0] == texels[1] == texels[2]
        for f in frames:
            c = f.cascades[k]
            # ortho(): x0 = -(m[0, 3] + 1) / m[0, 0], in light-view units
            x0 = -(c.proj[0, 3] + 1) / c.proj[0, 0]
            y0 = -(c.proj[1, 3] + 1) / c.proj[1, 1]
            for v in (x0, y0):
                assert abs(v / texels[0] - round(v / texels[0])) < 1e-6


# --------------------------------------------------------------------------------------------
# Rendered against the reference
# --------------------------------------------------------------------------------------------

LARGE = ["terrain_to_horizon", "small_caster_on_huge_plane", "city_grid"]


@pytest.mark.gl
@pytest.mark.parametrize("name", LARGE)
def test_every_distance_band_matches_the_reference(renderer, name):
    large = getattr(T, name)()
    m = T.measure(renderer, large.scene,
                  RenderParams(lights=[large.light], camera=large.camera))
    bands = T.band_metrics(m.result.visibility, m.reference, large.bands)
    assert [b.iou >= 0.95 for b in bands] == [True] * len(bands), [b.iou for b in bands]
    assert m.result.plan["lights"][0]["cascades"]
    assert bands[0].pixels > 10_000  # the near band is really there


@pytest.mark.gl
def test_cascades_sharpen_what_one_map_blurs(renderer):
    """The small box's shadow on the 10,000-unit plane: one map over what the camera sees of the
    plane gets it roughly; cascades get its edges closer to the truth."""
    large = T.small_caster_on_huge_plane()
    one = T.measure(renderer, large.scene, RenderParams(
        lights=[large.light], camera=large.camera, shadows={"cascades": 1}))
    auto = T.measure(renderer, large.scene, RenderParams(
        lights=[large.light], camera=large.camera))
    assert auto.result.plan["lights"][0]["cascades"]
    assert auto.metrics[0].iou >= max(0.95, one.metrics[0].iou)
    assert auto.metrics[0].edge_distance_px < one.metrics[0].edge_distance_px


@pytest.mark.gl
@pytest.mark.parametrize("offset", [1e6, 1e7])
def test_far_from_the_origin_changes_no_cascaded_shadow(renderer, offset):
    large = T.terrain_to_horizon()
    here = T.measure(renderer, large.scene, RenderParams(lights=[large.light],
                                                         camera=large.camera))
    scene, camera = _moved(large, offset)
    there = T.measure(renderer, scene, RenderParams(lights=[large.light], camera=camera))
    assert abs(here.metrics[0].iou - there.metrics[0].iou) <= 0.005
    assert len(there.result.plan["lights"][0]["cascades"]) == len(
        here.result.plan["lights"][0]["cascades"])


@pytest.mark.gl
@pytest.mark.parametrize("offset", [1e6, 1e7])
@pytest.mark.parametrize("kind", ["spot", "point"])
def test_far_from_the_origin_changes_no_spot_or_point_shadow(renderer, offset, kind):
    """Every light-space matrix is composed relative to the scene's origin in float64."""
    large = T.small_caster_on_huge_plane()
    light = ({"type": "spot", "position": [-2.0, 4.0, -1.5], "target": [0.0, 0.0, 0.0],
              "outer_cone_deg": 35} if kind == "spot"
             else {"type": "point", "position": [-1.5, 3.0, -1.0]})
    here = T.measure(renderer, large.scene, RenderParams(lights=[light], camera=large.camera))
    scene, camera = _moved(large, offset)
    moved = dict(light)
    moved.update({k: (np.asarray(light[k]) + [offset, 0.0, offset]).tolist()
                  for k in ("position", "target") if k in light})
    there = T.measure(renderer, scene, RenderParams(lights=[moved], camera=camera))
    assert here.metrics[0].iou >= 0.95
    assert abs(here.metrics[0].iou - there.metrics[0].iou) <= 0.005


@pytest.mark.gl
@pytest.mark.parametrize("encoding", ["rgba8", "rgb8", "rg8", "r8", "depth"])
@pytest.mark.parametrize("filtering", [{}, {"filter": "hard"}, {"pcf_kernel": 3}])
def test_every_encoding_and_filter_works_with_cascades(renderer, encoding, filtering):
    large = T.terrain_to_horizon()
    m = T.measure(renderer, large.scene, RenderParams(
        lights=[large.light], camera=large.camera, shadows={"encoding": encoding, **filtering}))
    assert m.result.plan["lights"][0]["cascades"]
    assert m.metrics[0].iou >= 0.95, m.metrics[0]


@pytest.mark.gl
@pytest.mark.parametrize("encoding", ["rgba8", "depth"])
def test_normal_offset_works_with_cascades(renderer, encoding):
    large = T.terrain_to_horizon()
    shadows = {"encoding": encoding, "bias": {"normal_offset": 1.0}}
    m = T.measure(renderer, large.scene, RenderParams(
        lights=[large.light], camera=large.camera, shadows=shadows))
    assert m.metrics[0].iou >= 0.95, m.metrics[0]


@pytest.mark.gl
def test_light_depth_shows_every_cascade_and_the_tint_marks_them(renderer):
    large = T.terrain_to_horizon()
    base = {"lights": [large.light], "camera": large.camera,
            "outputs": ["color", "light_depth", "visibility"]}
    plain = renderer.render(large.scene, base)
    ld = plain.light_depth[0]
    k = len(plain.plan["lights"][0]["cascades"])
    size = plain.plan["lights"][0]["cascades"][0]["map_size"]
    assert ld.kind == "cascades" and ld.depth.shape == (k, size, size)
    assert ld.image.shape == (size, k * size) and len(ld.ranges) == k
    for layer in ld.depth:  # every layer has its casters (the boxes) drawn into it
        assert np.isfinite(layer).sum() > 1000
    tinted = renderer.render(large.scene, {**base, "shadows": {"debug_cascades": True}})
    assert np.array_equal(tinted.visibility, plain.visibility, equal_nan=True)
    diff = np.abs(tinted.color.astype(int) - plain.color.astype(int)).sum(axis=2) > 0
    assert diff.mean() > 0.3  # receivers are tinted
    # Near pixels (bottom rows) and far ones (just below the horizon) read different cascades.
    assert not np.array_equal(tinted.color[-5, 320], tinted.color[200, 320])


@pytest.mark.gl
def test_stable_cascades_draw_a_static_caster_from_the_same_texels(renderer):
    """Two frames of an orbit in stable mode: the nearest cascade's maps agree texel for texel
    (in world depth) once shifted by the whole number of texels their windows moved."""
    large = T.terrain_to_horizon()
    frames = []
    for a in (0.0, 0.013):
        camera = _orbit_camera(a)
        shadows = {"stable_cascades": True, "cascades": 3}
        r = renderer.render(large.scene, {"lights": [large.light], "camera": camera,
                                          "outputs": ["light_depth"], "shadows": shadows})
        ld = r.light_depth[0]
        near, far = ld.ranges[0]
        c = _plan(large.scene, camera, large.light, **shadows).lights[0].cascades[0]
        corner = (-(c.proj[0, 3] + 1) / c.proj[0, 0], -(c.proj[1, 3] + 1) / c.proj[1, 1])
        frames.append((near + ld.depth[0] * (far - near), np.array(corner), c.texel[0]))
    (d0, c0, t0), (d1, c1, t1) = frames
    assert t0 == t1
    moved = (c1 - c0) / t0
    assert np.allclose(moved, np.round(moved), atol=1e-6) and np.any(np.round(moved) != 0)
    dx, dy = np.round(moved).astype(int)
    # Column j of frame 1 is column j + dx of frame 0; rows run top (+Y) down.
    assert _mismatch(d0, d1, -dy, dx) < 1e-4 * float(np.nanmax(d0) - np.nanmin(d0))


def _mismatch(a: np.ndarray, b: np.ndarray, dy: int, dx: int) -> float:
    """Mean difference of ``b[i, j]`` and ``a[i + dy, j + dx]`` where both are drawn."""
    h, w = a.shape
    ia = slice(max(dy, 0), h + min(dy, 0))
    ja = slice(max(dx, 0), w + min(dx, 0))
    ib = slice(max(-dy, 0), h + min(-dy, 0))
    jb = slice(max(-dx, 0), w + min(-dx, 0))
    pa, pb = a[ia, ja], b[ib, jb]
    both = np.isfinite(pa) & np.isfinite(pb)
    assert both.sum() > 200  # the casters drawn in both frames
    return float(np.abs(pa[both] - pb[both]).mean())


SPOT_OVER_TERRAIN = {"type": "spot", "position": [0.0, 30.0, 10.0], "target": [0, 0, -100],
                     "outer_cone_deg": 50}


def test_a_spot_light_says_when_its_map_is_too_coarse_for_near_receivers():
    """Receivers from 4 to 500 units: the nearest ones want about 4096 texels per side; with
    1024 at most the plan says so (and how much coarser), with 4096 it does not."""
    large = T.terrain_to_horizon()
    fine = _plan(large.scene, large.camera, SPOT_OVER_TERRAIN)
    assert fine.lights[0].kind == "perspective" and not fine.warnings
    assert 1024 < fine.lights[0].needed <= 4096
    coarse = _plan(large.scene, large.camera, SPOT_OVER_TERRAIN, max_map_size=1024)
    assert coarse.lights[0].map_size == 1024
    (w,) = coarse.warnings
    assert "would need 4096x4096" in w and "max_map_size 1024" in w and w.startswith("light 0")
    compact = _plan(T.caster_on_ground(), {"eye": [4.0, 4.0, 6.0], "target": [0, 0.5, 0]},
                    {"type": "spot", "position": [-2.5, 4, 1.5], "target": [0, 0, 0]},
                    max_map_size=1024)
    assert not compact.warnings


@pytest.mark.parametrize("light, shadows, limit", [
    ({"direction": [-0.3, -1.0, -0.2]}, {"cascades": 1}, "max_map_size 1024"),
    ({"direction": [-0.3, -1.0, -0.2]}, {"fit": "scene"}, "max_map_size 1024"),
    ({"type": "point", "position": [0.0, 10.0, -20.0]}, {}, "(512 per cube face)"),
])
def test_every_map_says_when_it_is_too_coarse_for_near_receivers(light, shadows, limit):
    """A single directional map (no cascades, or one map for the scene) and a point light's
    cube over receivers from 4 to 500 units are capped like a spot's map, and say so: what the
    nearest receivers want (whatever the limit), the limit (a cube face's half of it) and how
    much coarser it leaves them. Cascades, fitted to the view, serve them unsaid."""
    large = T.terrain_to_horizon()
    coarse = _plan(large.scene, large.camera, light, max_map_size=1024, **shadows)
    (w,) = coarse.warnings
    lp = coarse.lights[0]
    assert lp.kind == ("cube" if "type" in light else "ortho")
    assert w.startswith("light 0") and "would need" in w and limit in w, w
    assert f"up to {lp.needed / lp.map_size:.1f}x coarser" in w
    assert ('fit "view"' in w) == (shadows.get("fit") == "scene")
    finer = _plan(large.scene, large.camera, light, max_map_size=4096, **shadows)
    assert finer.lights[0].needed == pytest.approx(lp.needed)
    assert finer.lights[0].map_size == 4 * lp.map_size
    if "cascades" in shadows:
        assert not _plan(large.scene, large.camera, light, max_map_size=1024).warnings


@pytest.mark.gl
def test_the_plans_warnings_reach_the_result(renderer):
    large = T.terrain_to_horizon()
    r = renderer.render(large.scene, {"lights": [SPOT_OVER_TERRAIN], "camera": large.camera,
                                      "shadows": {"max_map_size": 1024}})
    assert any("would need 4096x4096" in w for w in r.warnings)


@pytest.mark.gl
def test_several_cascaded_lights_beside_other_maps(renderer):
    """Two cascaded suns, a spot map and a point light's cube map in one camera pass: each
    light reads its own maps."""
    large = T.terrain_to_horizon()
    lights = [large.light, {"type": "directional", "direction": [-0.5, -0.6, 0.3]},
              SPOT_OVER_TERRAIN, {"type": "point", "position": [2.0, 3.0, -6.0]}]
    m = T.measure(renderer, large.scene, RenderParams(lights=lights, camera=large.camera))
    plan = m.result.plan["lights"]
    assert [bool(lp.get("cascades")) for lp in plan] == [True, True, False, False]
    assert [lp["shadow_map"] for lp in plan[2:]] == ["perspective", "cube"]
    assert [x.iou >= 0.95 for x in m.metrics] == [True] * 4, [x.iou for x in m.metrics]
