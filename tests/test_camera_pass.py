"""The camera pass's per-map factors of the receiver plane: small exact cases, no GL.

The lookups of ``shaders/chunks/shadow_{2d,cube,csm}.glsl`` take their plane's factors from
Python (quotients worked out once per frame, not on every pixel); these cases check them against
planes whose tangent and depth steps are known.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from shadowmap.renderer.lights import Light
from shadowmap.renderer.passes.camera_pass import (
    cascade_plane_factors,
    cube_plane_factors,
    map2d_plane_factors,
)
from shadowmap.renderer.plan import LightShadow
from shadowmap.renderer.plan.geometry import frustum, ortho


def _light() -> Light:
    return Light(type="directional", position=np.zeros(3), direction=np.array([0.0, 0.0, -1.0]),
                 color=np.ones(3), intensity=1.0)


def _ortho_map(width: float, height: float, near: float, far: float, size: int) -> LightShadow:
    """An orthographic map ``width`` x ``height`` world units across, texel along its larger
    side (the plan's convention)."""
    return LightShadow(index=0, light=_light(), position=np.zeros(3), kind="ortho",
                       proj=ortho(-width / 2, width / 2, -height / 2, height / 2, near, far),
                       near=near, far=far, map_size=size,
                       texel=(max(width, height) / size, 0.0))


@pytest.mark.parametrize(("width", "height"), [(8.0, 8.0), (8.0, 2.0), (3.0, 12.0)])
def test_a_45_degree_plane_has_tangent_one_along_both_axes_of_an_ortho_map(width, height):
    near, far, size = 1.0, 21.0, 512
    span = far - near
    plan = _ortho_map(width, height, near, far, size)
    (kx, ky, sx, sy), (texel_t, quant, span_out) = map2d_plane_factors(plan, 0.01, 1.5)
    # Depth rising one world unit per world unit along x: t (depth / span) changes by
    # width / span per unit of u (u in [0, 1] across the width); the same along y.
    a, b = width / span, height / span
    assert a * kx == pytest.approx(1.0)
    assert b * ky == pytest.approx(1.0)
    # One texel along x is texel * ax world units (ax <= 1 on the shorter side): on that plane
    # the stored depth changes by as much, over the span.
    texel = max(width, height) / size
    assert sx == pytest.approx(width / size / span)
    assert sy == pytest.approx(height / size / span)
    assert texel_t == pytest.approx(texel / span)
    assert quant == pytest.approx(1.5 * 0.01)
    assert span_out == pytest.approx(span)


@pytest.mark.parametrize("u", [0.5, 0.75, 0.2])
def test_a_45_degree_plane_through_a_spot_maps_axis(u):
    """The plane w = w0 + x (w the depth along the axis, x across it) seen by a 60-degree spot:
    in map coordinates w = e / (1 - a u) with a = 2 h / (1 + h), h = tan(30 degrees). Its
    tangent, the depth change between neighbouring texels' rays over a texel's world size there,
    is w / w0 (1 on the axis)."""
    near, far, size, w0 = 0.5, 40.5, 1024, 10.0
    h = math.tan(math.radians(30.0))
    plan = LightShadow(index=0, light=_light(), position=np.zeros(3), kind="perspective",
                       proj=frustum(-h * near, h * near, -h * near, h * near, near, far),
                       near=near, far=far, map_size=size, texel=(0.0, 2 * h / size))
    (kx, ky, sx, sy), (texel_t, _, span) = map2d_plane_factors(plan, 0.0, 0.0)
    a = 2 * h / (1 + h)
    w = w0 / (1 + h - 2 * h * u)
    # The shader: tangent = a kx w / (w - (a, b) . c.xy), c.xy = uv w (before the divide).
    assert a * kx * w / (w - a * u * w) == pytest.approx(w / w0)
    assert kx == ky
    # Per unit of w: a texel is 2 h w / size world units, over the span in stored depth.
    assert texel_t == pytest.approx(2 * h / size / 40.0)
    assert sx == sy == pytest.approx(texel_t)
    assert span == pytest.approx(40.0)


def test_a_cube_maps_texel_grows_with_face_depth():
    plan = LightShadow(index=0, light=_light(), position=np.zeros(3), kind="cube", near=0.1,
                       far=10.1, map_size=256)
    inv_span, per_depth, texel_t_per_depth, quant = cube_plane_factors(plan, 1e-4, 2.0)
    # A 90-degree face 2 d wide at depth d, over 256 texels.
    assert per_depth * 3.0 == pytest.approx(2 * 3.0 / 256)
    assert texel_t_per_depth * 3.0 == pytest.approx(2 * 3.0 / 256 / 10.0)
    assert inv_span == pytest.approx(0.1)
    assert quant == pytest.approx(2e-4)


def test_a_cascades_factors_match_an_ortho_maps():
    plan = _ortho_map(8.0, 2.0, 1.0, 21.0, 512)
    sx, sy, texel_t, quant = cascade_plane_factors(plan, 0.01, 1.5)
    (_, _, sx2, sy2), (texel_t2, quant2, _) = map2d_plane_factors(plan, 0.01, 1.5)
    assert (sx, sy, texel_t, quant) == pytest.approx((sx2, sy2, texel_t2, quant2))


def test_a_degenerate_map_gives_finite_factors():
    plan = dataclasses.replace(_ortho_map(8.0, 8.0, 5.0, 6.0, 512), far=5.0, texel=(0.0, 0.0))
    plane, depth = map2d_plane_factors(plan, 0.01, 1.5)
    assert np.isfinite(plane).all() and np.isfinite(depth).all()
    assert np.isfinite(cube_plane_factors(plan, 0.01, 1.5)).all()


@pytest.mark.parametrize("orthographic", [False, True])
@pytest.mark.parametrize("reversed_z", [False, True])
@pytest.mark.parametrize("near, far", [(0.1, 100.0), (1e-3, 1e7), (3.3, 3.4)])
def test_linear_depth_is_the_plain_formula(orthographic, reversed_z, near, far):
    """The in-place linearisation gives, bit for bit, the plain formulas of each depth mode."""
    from types import SimpleNamespace

    from shadowmap.renderer.passes.camera_pass import linear_depth

    window = np.random.default_rng(7).random((48, 64)).astype(np.float32)
    window[:4] = 0.0
    window[4:8] = 1.0
    d = window.astype(np.float64)
    n, f = near, far
    if orthographic:
        z = n + ((1.0 - d) if reversed_z else d) * (f - n)
        nothing = d <= 0.0 if reversed_z else d >= 1.0
    elif reversed_z:
        z = n * f / (d * (f - n) + n)
        nothing = d <= 0.0
    else:
        z = 2 * n * f / ((f + n) - (2 * d - 1) * (f - n))
        nothing = d >= 1.0
    plain = np.where(nothing, np.nan, z).astype(np.float32)
    camera = SimpleNamespace(znear=near, zfar=far, orthographic=orthographic)
    got = linear_depth(window, camera, reversed_z)  # type: ignore[arg-type]
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, plain)
    assert np.isnan(got[:4]).all() != np.isnan(got[4:8]).all()  # one end is "nothing"
