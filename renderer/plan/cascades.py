"""Cascaded shadow maps for directional lights: how many maps, where the view is split, and one
fitted map per slice.

One orthographic map over everything the camera sees is exact for a model on a table, but a
camera near the ground looking toward the horizon sees receivers from a metre to kilometres
away, and one map gives the near ones texels of many pixels. Cascades split the view's depth
range into slices (the practical split scheme: a blend of logarithmic and uniform splits) and
give each slice its own map, fitted as the single map is (:mod:`.fit`: to the casters that
matter and the receivers the camera sees, here inside the slice), sized for the slice's nearest
distance. The camera pass picks the map per pixel by its view depth and blends across a band at
each seam.

The count is decided here: one map (exactly today's fit and cost) while it gives at most
:data:`CASCADE_TEXEL_PIXELS` camera pixels per texel at the nearest seen receiver, else the
fewest cascades, up to ``max_cascades``, whose maps all do within the map-size limit. Stable
mode fits each slice's bounding sphere instead and snaps the window to whole texels, so a static
shadow does not move as the camera does.

Every function here is pure: no GL, no change to its inputs.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .context import AUTO_TEXEL_PIXELS, MIN_AUTO_MAP, PlanContext, Seen, _visible_receivers
from .culling import select_casters, view_planes
from .fit import (
    DirectionalReach,
    Fit,
    Skip,
    Subject,
    fit_directional,
    ortho_depth_range,
    reach_directional,
)
from .geometry import aabbs_against_frustum, ortho

if TYPE_CHECKING:
    from ..lights import Light

#: One map is kept while one of its texels covers at most this many camera pixels at the
#: nearest receiver point the camera sees; automatic cascade sizes aim at it too.
CASCADE_TEXEL_PIXELS = 1.0
#: 'auto' gives one cascade per this factor of camera distance over the seen receivers.
CASCADE_DEPTH_RATIO = 8.0


@dataclass(frozen=True)
class Slice:
    """One cascade's part of the view.

    Attributes
    ----------
    near, far : float
        Camera distances (along the view axis) the cascade is chosen for.
    reach_near : float
        Where its map starts: ``near`` less the previous cascade's blend band.
    blend : float
        Width of the band before ``far`` where its shadow fades into the next cascade's (0 for
        the last).
    """

    near: float
    far: float
    reach_near: float
    blend: float


@dataclass(frozen=True)
class CascadeFit:
    """A slice and its fitted map, with the casters drawn into it."""

    slice: Slice
    fit: Fit
    casters: list[int]
    skipped: dict[str, int]
    needed: int  # the map size for one texel per CASCADE_TEXEL_PIXELS pixels at the near end
    texel_pixels: float  # camera pixels one texel covers at the near end


def seen_depth_range(ctx: PlanContext) -> tuple[float, float]:
    """Nearest and farthest camera distance (along the view axis) of the receiver points the
    camera sees, within its near and far planes."""
    cam = ctx.camera
    forward = -cam.pose[:3, 2]
    boxes = ctx.bounds[ctx.seen.whole]
    points = ctx.seen.points
    if not len(boxes) and not len(points):
        return cam.znear, cam.zfar
    # A whole box's distance range along the axis from its centre and half-size (the extremes
    # of its eight corners), the clipped parts' from their vertices.
    c = (boxes[:, 0] + boxes[:, 1]) * 0.5 - ctx.cam_pos
    h = (boxes[:, 1] - boxes[:, 0]) * 0.5
    zc, zh = c @ forward, h @ np.abs(forward)
    zp = (points - ctx.cam_pos) @ forward
    lo = min(float((zc - zh).min(initial=np.inf)), float(zp.min(initial=np.inf)))
    hi = max(float((zc + zh).max(initial=-np.inf)), float(zp.max(initial=-np.inf)))
    return float(np.clip(lo, cam.znear, cam.zfar)), float(np.clip(hi, cam.znear, cam.zfar))


def practical_splits(near: float, far: float, count: int, blend: float) -> np.ndarray:
    """The practical split scheme: ``count + 1`` distances from ``near`` to ``far``, each a
    blend (weight ``blend`` on the logarithmic one) of the logarithmic and uniform splits.

    Returns
    -------
    ndarray, shape (count + 1,)
    """
    i = np.arange(count + 1) / count
    log = near * (far / near) ** i
    uni = near + (far - near) * i
    d = blend * log + (1.0 - blend) * uni
    d[0], d[-1] = near, far
    return d


def slices(near: float, far: float, count: int, split: float, band: float) -> list[Slice]:
    """The cascades' slices of ``[near, far]``, each reaching back over the previous one's blend
    band so that both maps cover the band."""
    d = practical_splits(near, far, count, split)
    out = []
    prev_blend = 0.0
    for k in range(count):
        blend = band * (d[k + 1] - d[k]) if k < count - 1 else 0.0
        out.append(Slice(float(d[k]), float(d[k + 1]), float(d[k] - prev_blend), float(blend)))
        prev_blend = blend
    return out


def slice_context(ctx: PlanContext, sl: Slice) -> PlanContext:
    """The plan context of one slice: the camera frustum cut to ``[sl.reach_near, sl.far]``
    (what it sees of the receivers, clipped to that), with map sizes chosen for pixels at
    ``sl.reach_near``."""
    cam = dataclasses.replace(ctx.camera, znear=max(sl.reach_near, ctx.camera.znear),
                              zfar=sl.far)
    planes = view_planes(cam, ctx.origin)
    corners = cam.frustum_corners(ctx.origin)
    in_view, whole = aabbs_against_frustum(ctx.bounds, planes, corners)
    receivers = _visible_receivers(in_view, ctx.receive, True)
    seen = Seen.clip(ctx.bounds, receivers, whole, planes, corners)
    return dataclasses.replace(ctx, in_view=in_view, seen=seen, frustum_corners=corners,
                               texel_distance=cam.znear)


def _stable_fit(ctx: PlanContext, reach: DirectionalReach, fit_mask: np.ndarray,
                size: int) -> Fit:
    """A window over the slice's bounding sphere, its corner on whole texels of a grid fixed in
    light space: the same texel grid for every camera pose with the same slice."""
    radius = _sphere_radius(ctx)
    corners = ctx.frustum_corners
    texel = 2 * radius / size
    c = (reach.view @ np.append(corners.mean(axis=0), 1.0))[:2]
    x0, y0 = np.floor((c - radius) / texel) * texel
    x1, y1 = x0 + 2 * radius, y0 + 2 * radius
    near = float(reach.depth_min[fit_mask].min())
    far = reach.far + texel * ctx.margin_texels
    near, far = ortho_depth_range(near, far)
    return Fit(kind="ortho", view=reach.view, proj=ortho(x0, x1, y0, y1, near, far), near=near,
               far=far, map_size=size, texel=(texel, 0.0))


def _sphere_radius(ctx: PlanContext) -> float:
    """Radius of the slice frustum's bounding sphere (about its corners' centre), rounded up to
    a 64th of an octave so that rounding in the corners cannot change it between frames."""
    corners = ctx.frustum_corners
    radius = float(np.linalg.norm(corners - corners.mean(axis=0), axis=1).max())
    return float(2.0 ** (math.ceil(math.log2(max(radius, 1e-300)) * 64) / 64))


def _pow2(x: float) -> int:
    return 1 << max(0, math.ceil(math.log2(max(x, 1.0))))


def _pixel(ctx: PlanContext, distance: float) -> float:
    """World size of :data:`CASCADE_TEXEL_PIXELS` camera pixels at ``distance``."""
    return (ctx.pixel_per_distance / AUTO_TEXEL_PIXELS * CASCADE_TEXEL_PIXELS
            * float(ctx.view_distance(distance)))


def fit_slice(ctx: PlanContext, light: Light, position: np.ndarray, sl: Slice,
              size: int | None) -> CascadeFit | Skip:
    """One cascade: the directional fit of :mod:`.fit` inside the slice (or the stable fit),
    with maps of ``size`` texels (None: the size 'auto' gives the slice alone)."""
    sc = slice_context(ctx, sl)
    receivers = sc.receivers()
    if len(receivers) == 0:
        return Skip("no_visible_receiver")
    if size is not None:
        shadows = sc.params.shadows.model_copy(update={"map_size": size})
        sc = dataclasses.replace(sc, params=sc.params.model_copy(update={"shadows": shadows}))
    s = Subject(light, position, receivers)
    reach = reach_directional(sc, s)
    chosen = select_casters(sc, light, position, receivers, reach.in_frustum, reach.depth_min,
                            reach.far)
    if not chosen.fit.any():
        return Skip("no_caster_in_frustum")
    if ctx.params.shadows.stable_cascades:
        extent = 2 * _sphere_radius(sc)
        fit = _stable_fit(sc, reach, chosen.fit, size or _pow2(extent / _pixel(sc, sl.reach_near)))
    else:
        fitted = fit_directional(sc, s, reach, chosen.fit)
        if isinstance(fitted, Skip):
            return fitted
        fit = fitted
        extent = fit.texel[0] * fit.map_size
    skipped = {k: v for k, v in {**reach.skipped, **chosen.skipped}.items() if v}
    pixel = max(_pixel(sc, sl.reach_near) / CASCADE_TEXEL_PIXELS, 1e-300)
    return CascadeFit(sl, fit, chosen.casters, skipped,
                      _pow2(extent * CASCADE_TEXEL_PIXELS / pixel), fit.texel[0] / pixel)


def single_map_is_enough(ctx: PlanContext, fit: Fit, near: float, size_limit: int) -> bool:
    """Whether one map over the whole view gives at most :data:`CASCADE_TEXEL_PIXELS` camera
    pixels per texel at the nearest seen receiver distance ``near``, within ``size_limit``."""
    extent = fit.texel[0] * fit.map_size
    return extent / max(_pixel(ctx, near), 1e-300) <= size_limit


def cascade_count(near: float, far: float, most: int) -> int:
    """Cascades for receivers seen from ``near`` to ``far``: one per factor of
    :data:`CASCADE_DEPTH_RATIO` in distance, from 2 to ``most``."""
    wanted = math.ceil(math.log(max(far / near, 1.0)) / math.log(CASCADE_DEPTH_RATIO))
    return int(min(max(wanted, 2), most))


def plan_cascades(ctx: PlanContext, light: Light, position: np.ndarray,
                  single: Fit) -> list[CascadeFit]:
    """The cascades of one directional light whose single map is ``single``.

    Returns
    -------
    list of CascadeFit
        Empty when one map is kept; else two or more, near to far (slices without a visible
        receiver or caster are left out), all with maps of one size (the layers of one array
        texture): for ``map_size`` 'auto' the largest any cascade needs for one texel per
        :data:`CASCADE_TEXEL_PIXELS` pixels at its near end, at most half of ``max_map_size``
        (so that the cascades together cost about what one map of the largest size does).
    """
    shadows = ctx.params.shadows
    explicit: int | None = shadows.map_size if isinstance(shadows.map_size, int) else None
    near, far = seen_depth_range(ctx)
    requested = shadows.cascades
    if far <= near * (1 + 1e-9):
        return []
    if requested == "auto":
        if single_map_is_enough(ctx, single, near, explicit or ctx.max_size):
            return []
        count = cascade_count(near, far, shadows.max_cascades)
    elif requested <= 1:
        return []
    else:
        count = requested
    parts = slices(near, far, count, shadows.cascade_split, shadows.cascade_blend)
    if explicit is not None:
        size = explicit
    else:
        # Pose-independent in stable mode (the sphere, not the fit): sized from a first fit.
        first = [f for sl in parts
                 if isinstance(f := fit_slice(ctx, light, position, sl, None), CascadeFit)]
        if not first:
            return []
        top = max(ctx.max_size // 2, MIN_AUTO_MAP)
        size = int(min(max(max(f.needed for f in first), MIN_AUTO_MAP), top))
        if all(f.fit.map_size == size for f in first) and not shadows.stable_cascades:
            return first if len(first) > 1 else []
    fits = [f for sl in parts
            if isinstance(f := fit_slice(ctx, light, position, sl, size), CascadeFit)]
    return fits if len(fits) > 1 else []
