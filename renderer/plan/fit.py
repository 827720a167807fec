"""Shadow frusta, one way per kind of light, each in two pure steps.

``reach_*`` finds the light's region over what the camera sees of the receivers (their boxes
clipped to the view frustum, :class:`~.context.Seen`): which boxes lie inside it, how near each
is to the light, how deep the seen receivers go. The plan then chooses the casters from that
(:func:`~.culling.select_casters`, the same for every kind), and ``fit_*`` tightens the region to
those casters and sizes the map: an orthographic box for directional lights, as in the
packed-depth blog; an off-axis perspective frustum for spot lights; six cube faces for point
lights and very wide spots. Either step may instead return a :class:`Skip` with its reason.

A new kind of fit (cascades, say) is a :class:`ShadowMethod` beside these: a reach step (perhaps
an existing one) and a fit step; :func:`choose_method` picks it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from .. import encodings
from .context import AUTO_TEXEL_PIXELS, Toward
from .geometry import (
    CUBE_FACE_PLANES,
    CUBE_FACES,
    boxes_in_frustum,
    clip_boxes,
    column_max,
    column_min,
    corner_max,
    corner_min,
    cube_face_views,
    face_meets_cone,
    frustum,
    frustum_planes,
    ortho,
    perspective,
    pose_from_direction,
    pyramid_planes,
    row_norm,
    slice_max,
    transform_boxes,
    transform_points,
)

if TYPE_CHECKING:  # the lights import this package's geometry: types only, no import cycle
    from ..lights import Light
    from .context import PlanContext

# Spot lights wider than this (half-angle) are shadowed with cube faces: a single perspective map
# would spend most of its texels near the frustum's edges.
MAX_SPOT_HALF_ANGLE = math.radians(60.0)

#: Slack around an orthographic map's depth range, as a share of it (:func:`ortho_depth_range`).
DEPTH_SLACK = 1e-3
#: The narrowest window an orthographic map is fitted to, relative to its distance from the
#: scene's centre: 8 steps of float32 (2**-20), the precision the GPU transforms the
#: origin-relative positions with. Casters narrower than that for where they lie (a part a
#: millionth of the scene's size at its far end) would be drawn into texels and depths that are
#: rounding noise: such a light gets no pass (``"below_precision"``), with a warning.
MIN_RELATIVE_EXTENT = 2.0**-20

#: The nearest a perspective or cube map's near plane comes to the light, as a share of its far
#: plane: its casters' nearest points set it, down to this. The maps store linear depth, so a
#: near plane close to the light takes no precision from the rest of the range (what a deep
#: range costs is its quantisation bias, :data:`DEPTH_STEP_WARN_TEXELS`); this floor is about
#: where float32 light-view depths of positions that far away stop resolving the distance to
#: the light (2**-22). A caster wholly nearer the light than that is clipped from the map, with
#: a warning.
MIN_MAP_NEAR_SHARE = 2.0**-22

#: A 16-bit depth texture is used (``shadows.depth_bits: "auto"``) when one of its steps, a
#: 65535th of the map's depth range, is at most this many of the map's texels nearest the light
#: (the unit of the constant bias): the default quantisation bias of 1.5 steps then adds under a
#: fifth of a texel to the bias. Half the bytes per texel make every lookup cheaper on a software
#: rasterizer, where the map's reads go through the CPU's caches (bench/results/floor.md).
DEPTH16_MAX_STEP_TEXELS = 0.125
#: The step of a 16-bit UNORM depth texture, in units of the stored depth t in [0, 1].
DEPTH16_STEP = 1.0 / 65535.0
#: The plan warns of a map whose quantisation bias (``bias.quantisation_steps`` of its depth
#: steps over its depth range) is over this many of its texels where its receivers are (the
#: depth its size is chosen for): more than the default bias reaches on the steepest receivers
#: (0.5 + 0.25 x 10 texels), so shadows of casters that near to what they fall on are lost (a
#: point light a few units from its casters with receivers 1e7 units away in one map: 0.9
#: units, about 200 texels).
DEPTH_STEP_WARN_TEXELS = 4.0


@dataclass(frozen=True)
class Skip:
    """No light pass, for ``reason`` ("no_visible_receiver", "no_caster_in_frustum", ...)."""

    reason: str


@dataclass(frozen=True)
class Subject:
    """The light being fitted and what it must cover.

    Attributes
    ----------
    light : Light
    position : ndarray, shape (3,)
        The light's position relative to the origin.
    receivers : ndarray, shape (R,), int
        Receivers that matter (R >= 1): those the camera sees (:meth:`PlanContext.receivers`).
    """

    light: Light
    position: np.ndarray
    receivers: np.ndarray


def toward_light(s: Subject) -> Toward:
    """Where the subject's light is, for the angle it meets the receivers' faces at."""
    if s.light.type == "directional":
        d = -np.asarray(s.light.direction, np.float64)
        return Toward(d / np.linalg.norm(d), positional=False)
    return Toward(np.asarray(s.position, np.float64), positional=True)


@dataclass(frozen=True, kw_only=True)
class Reach:
    """A light's region over its receivers, before casters are chosen.

    Attributes
    ----------
    in_frustum : ndarray, shape (N,), bool
        Boxes that may lie inside the region (conservative).
    depth_min : ndarray, shape (N,)
        Nearest light depth of each box (0 where a box reaches behind the light).
    far : float
        Deepest receiver depth that matters: boxes wholly beyond it shadow nothing seen.
    skipped : mapping of str to int
        Work the reach itself left out (e.g. cube faces), reported with the casters' counts.
    """

    in_frustum: np.ndarray
    depth_min: np.ndarray
    far: float
    skipped: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Fit:
    """A fitted shadow map (see :class:`~.plan.LightShadow` for the fields)."""

    kind: str
    view: np.ndarray
    proj: np.ndarray
    near: float
    far: float
    map_size: int
    texel: tuple[float, float]
    faces: list[int] = field(default_factory=list)
    face_views: list[np.ndarray] = field(default_factory=list)
    needed: float = 0.0  # texels per side 'auto' would want, before max_map_size
    texel_depth: float = 0.0  # perspective and cube: the light depth its size is chosen for
    near_clipped: int = 0  # casters wholly ahead of the light but nearer than ``near``


def depth_step(encoding: str, depth_bits: int) -> float:
    """One step of a map's stored depth t (the unit of the quantisation bias and of the polygon
    offset): the encoding's (:data:`~shadowmap.renderer.encodings.STEP`, a 32-bit float depth
    texture's for ``"depth"``), or a 16-bit depth texture's 1/65535."""
    if encoding == "depth" and depth_bits == 16:
        return DEPTH16_STEP
    return encodings.STEP[encoding]


def texel_at(depth: float, texel: tuple[float, float]) -> float:
    """A map's texel at light depth ``depth``, in world units (see :attr:`Fit.texel`); at its
    near plane, its smallest."""
    return texel[0] + texel[1] * max(depth, 0.0)


def depth16_is_enough(near: float, far: float, texel: tuple[float, float]) -> bool:
    """Whether a map's depth range fits 16 bits (:data:`DEPTH16_MAX_STEP_TEXELS`).

    Parameters
    ----------
    near, far : float
        The stored depth's range (world units along the light's axis; Chebyshev distance for
        cube maps).
    texel : (float, float)
        A texel's world size at light depth d is ``texel[0] + texel[1] * d``
        (:attr:`Fit.texel`): the same everywhere in an orthographic map, smallest at ``near``
        in a perspective or cube one.
    """
    finest = texel_at(near, texel)
    step = (far - near) * DEPTH16_STEP
    return bool(finest > 0 and step <= DEPTH16_MAX_STEP_TEXELS * finest)


R = TypeVar("R", bound=Reach)


@dataclass(frozen=True)
class ShadowMethod(Generic[R]):
    """One way of shadowing a light: its reach, then its fit to the chosen casters.

    Attributes
    ----------
    reach : callable (ctx, subject) -> Reach or Skip
    fit : callable (ctx, subject, reach, fit_mask) -> Fit or Skip
        ``fit_mask`` (N,) bool marks the casters that can shadow a receiver (at least one).
    """

    reach: Callable[[PlanContext, Subject], R | Skip]
    fit: Callable[[PlanContext, Subject, R, np.ndarray], Fit | Skip]


# --------------------------------------------------------------------------------------------
# Directional: an orthographic box along the light
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class DirectionalReach(Reach):
    """Attributes: ``view`` (4, 4) world to light; ``lo``, ``hi`` (N, 3) light-view box bounds;
    ``window`` (x0, y0, x1, y1), the lateral extent of the seen receivers."""

    view: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    window: tuple[float, float, float, float]


def reach_directional(ctx: PlanContext, s: Subject) -> DirectionalReach:
    """The light-view column over what the camera sees of the receivers: their boxes clipped to
    the camera frustum (:class:`~.context.Seen`), laterally and in depth."""
    view = np.linalg.inv(pose_from_direction(np.zeros(3), s.light.direction))
    lo, hi = transform_boxes(view, ctx.bounds)  # (N, 3) light-view box bounds
    # A directional shadow falls straight along the light: a receiver point is shadowed only by
    # casters over it laterally and nearer the light. The window holds every seen receiver point.
    seen = _seen_light_points(ctx, view)
    whole = ctx.seen.whole
    r_lo = np.minimum(column_min(lo[whole], np.inf), column_min(seen, np.inf))
    r_hi = np.maximum(column_max(hi[whole], -np.inf), column_max(seen, -np.inf))
    x0, y0 = r_lo[:2]
    x1, y1 = r_hi[:2]
    far = float(-r_lo[2])  # the deepest seen receiver point (light depth is -z)
    in_frustum = (hi[:, 0] >= x0) & (lo[:, 0] <= x1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1)
    return DirectionalReach(in_frustum=in_frustum, depth_min=-hi[:, 2], far=far, view=view,
                            lo=lo, hi=hi, window=(x0, y0, x1, y1))


def _seen_light_points(ctx: PlanContext, view: np.ndarray) -> np.ndarray:
    """The vertices of the receivers' clipped parts (:attr:`Seen.points`) in light view, (M, 3)."""
    return transform_points(view, ctx.seen.points)


def fit_directional(ctx: PlanContext, s: Subject, reach: DirectionalReach,
                    fit: np.ndarray) -> Fit | Skip:
    """An orthographic box: the window narrowed to the casters' lateral extent, from the nearest
    caster to the deepest seen receiver point under the window (:func:`_column_far`), padded by
    the filter margin."""
    x0, y0, x1, y1 = reach.window
    # A directional shadow falls straight along the light: only where casters are, laterally.
    x0, y0 = np.maximum([x0, y0], column_min(reach.lo[fit, :2]))
    x1, y1 = np.minimum([x1, y1], column_max(reach.hi[fit, :2]))
    if x1 <= x0 or y1 <= y0:
        return Skip("no_caster_in_frustum")
    near = _caster_near(ctx, reach, fit, (x0, x1, y0, y1))
    extent = max(x1 - x0, y1 - y0, 1e-300)
    if extent < MIN_RELATIVE_EXTENT * max(abs(x0), abs(x1), abs(y0), abs(y1), abs(near)):
        return Skip("below_precision")
    size, needed = ctx.map_size_and_need(extent, s.receivers, toward=toward_light(s))
    pad = ctx.margin(extent, size)
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    # Only the receivers under the (padded) window can be shadowed: a lookup anywhere else
    # finds its point outside the map and lit.
    far = min(reach.far, _column_far(ctx, reach, s.receivers, (x0, x1, y0, y1)))
    # The deepest receiver point is the window's exact bound (no box beyond it any more):
    # filter taps read the margin past it in depth too.
    far += pad
    near, far = ortho_depth_range(near, far)
    return Fit(kind="ortho", view=reach.view, proj=ortho(x0, x1, y0, y1, near, far), near=near,
               far=far, map_size=size, texel=(max(x1 - x0, y1 - y0) / size, 0.0), needed=needed)


def ortho_depth_range(near: float, far: float) -> tuple[float, float]:
    """An orthographic map's depth range: ``near`` and ``far`` moved apart by
    :data:`DEPTH_SLACK` of their span, so that the nearest caster and the deepest receiver are
    not clipped, and by at least 2**-40 of their magnitude, so that the two stay apart (a range
    flat in depth far from the scene's centre would otherwise round to one number, and its
    projection divide by zero)."""
    slack = max((far - near) * DEPTH_SLACK, max(abs(near), abs(far)) * 2.0**-40, 1e-300)
    return near - slack, far + slack


def _caster_near(ctx: PlanContext, reach: DirectionalReach, fit: np.ndarray,
                 window: tuple[float, float, float, float]) -> float:
    """The nearest light depth of the casters' parts over the window (x0, x1, y0, y1).

    A caster wider than the window (a ground and a box in one mesh, a terrain) matters only
    over the window, and its box's nearest corner elsewhere can lie far nearer the light: its
    box is clipped to the window's column first, so the stored depth range (and with it the
    precision of the 8-bit encodings) follows what is drawn into the map.
    """
    x0, x1, y0, y1 = window
    idx = np.flatnonzero(fit)
    lo, hi = reach.lo[idx], reach.hi[idx]
    wide = (lo[:, 0] < x0) | (hi[:, 0] > x1) | (lo[:, 1] < y0) | (hi[:, 1] > y1)
    near = float(reach.depth_min[idx[~wide]].min(initial=np.inf))
    if wide.any():
        depth = _column_depths(ctx, reach, idx[wide], window)
        if len(depth):
            near = min(near, float(depth.min()))
    return near if np.isfinite(near) else float(reach.depth_min[fit].min())


def _column_depths(ctx: PlanContext, reach: DirectionalReach, boxes: np.ndarray,
                   window: tuple[float, float, float, float]) -> np.ndarray:
    """Light depths (M,) of the vertices of the parts of ``boxes`` (indices) inside the light's
    column over the window (x0, x1, y0, y1), at any depth (:func:`.geometry.clip_boxes`)."""
    x0, x1, y0, y1 = window
    z0 = float(reach.depth_min[boxes].min())
    z1 = float(np.max(-reach.lo[boxes, 2]))
    z1 += 1.0 + abs(z1)  # the column's depth: past every box
    z0 -= 1.0 + abs(z0)
    column = np.array([[x, y, -z] for z in (z0, z1) for x in (x0, x1) for y in (y0, y1)])
    return _depths_inside(ctx, reach.view, ortho(x0, x1, y0, y1, z0, z1), column, boxes)


def _depths_inside(ctx: PlanContext, view: np.ndarray, proj: np.ndarray, corners: np.ndarray,
                   boxes: np.ndarray) -> np.ndarray:
    """Light depths (M,) of the vertices of the parts of ``boxes`` (indices) inside the light's
    frustum ``proj``, whose corners in light view are ``corners`` (8, 3; numbered as
    :func:`.geometry.clip_boxes` expects)."""
    world = np.linalg.inv(view)
    hull = corners @ world[:3, :3].T + world[:3, 3]
    scale = float(np.max(np.abs(hull)))
    pts = clip_boxes(ctx.bounds[boxes], frustum_planes(proj @ view), hull, 1e-9 * scale)
    return -(pts @ view[2, :3] + view[2, 3])


def _column_far(ctx: PlanContext, reach: DirectionalReach, receivers: np.ndarray,
                window: tuple[float, float, float, float]) -> float:
    """The deepest light depth of the receivers' boxes over the window's column (x0, x1, y0, y1),
    inf where none reaches it.

    Only receiver points under the map can be shadowed, and a lookup there must find its depth
    inside the map's range: this bounds the map's far end as well as the deepest seen point
    anywhere does (:attr:`Reach.far`), and the two together bound it tighter than either. It
    does not move with the camera while the column's receivers are all in its view, so views
    around a scene often fit a light alike and share its map (the light-map cache).
    """
    x0, x1, y0, y1 = window
    # Columns gathered first: comparisons on contiguous rows (a column of an (N, 3) array is
    # strided, and slower to compare at 10,000 instances than the gather).
    lx, ly, lz = (reach.lo[:, k][receivers] for k in range(3))
    hx, hy = (reach.hi[:, k][receivers] for k in range(2))
    over = (hx >= x0) & (lx <= x1) & (hy >= y0) & (ly <= y1)
    inside = over & (lx >= x0) & (hx <= x1) & (ly >= y0) & (hy <= y1)
    deepest = -lz  # each box's deepest point (its light-view box's far side)
    far = float(np.max(deepest[inside], initial=-np.inf))
    # Only a box reaching deeper than those can move the bound: clip just those.
    straddling = receivers[over & ~inside & (deepest > far)]
    if len(straddling):
        depth = _column_depths(ctx, reach, straddling, window)
        far = max(far, float(np.max(depth, initial=-np.inf)))
    return far if np.isfinite(far) else np.inf


# --------------------------------------------------------------------------------------------
# Spot: an off-axis perspective frustum inside the cone
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SpotReach(Reach):
    """Attributes: ``view`` (4, 4) world to light; ``lc`` (N, 8, 3) box corners in light view;
    ``depth`` (N, 8) their light depth; ``a_lo``, ``a_hi`` (2,) slope bounds (x/-z, y/-z) of the
    receivers inside the cone."""

    view: np.ndarray
    lc: np.ndarray
    depth: np.ndarray
    a_lo: np.ndarray
    a_hi: np.ndarray


def reach_spot(ctx: PlanContext, s: Subject) -> SpotReach | Skip:
    """The pyramid from the light over what the camera sees of the receivers inside its cone; a
    skip when all of it is behind the light or outside the cone."""
    view = np.linalg.inv(pose_from_direction(s.position, s.light.direction))
    lc = transform_points(view, ctx.corners)
    depth = -lc[..., 2]  # (N, 8)
    tan_cone = math.tan(s.light.outer_cone)
    # What the camera sees of the receivers (:class:`~.context.Seen`): a receiver point is
    # shadowed only by casters on its ray from the light, so the frustum holds their slopes and
    # depths, reached at these points.
    rc = np.concatenate([lc[ctx.seen.whole].reshape(-1, 3), _seen_light_points(ctx, view)])
    far = float(-rc[:, 2].min())
    if far <= 0:
        return Skip("no_visible_receiver")  # every seen receiver point is behind the light
    # Receivers inside the cone's bounding pyramid: fit the frustum to their angular extent.
    if np.all(-rc[:, 2] > 0):
        ang = rc[:, :2] / (-rc[:, 2:3])
        a_lo = np.maximum(column_min(ang), -tan_cone)
        a_hi = np.minimum(column_max(ang), tan_cone)
    else:  # a receiver straddles the light's plane: cover the whole cone
        a_lo = np.array([-tan_cone, -tan_cone])
        a_hi = np.array([tan_cone, tan_cone])
    if np.any(a_hi <= a_lo):
        return Skip("no_visible_receiver")
    # Casters inside the fitted pyramid (conservative: boxes against its four side planes).
    in_frustum = boxes_in_frustum(lc, pyramid_planes(a_lo, a_hi))
    nearest = corner_min(depth)
    depth_min = np.where(nearest > 0, nearest, 0.0)  # 0 where a corner is behind the light
    return SpotReach(in_frustum=in_frustum, depth_min=depth_min, far=far, view=view, lc=lc,
                     depth=depth, a_lo=a_lo, a_hi=a_hi)


def fit_spot(ctx: PlanContext, s: Subject, reach: SpotReach, fit: np.ndarray) -> Fit | Skip:
    """An off-axis frustum: the pyramid narrowed to the casters' slopes, from the nearest caster
    to the deepest seen receiver inside the pyramid (:func:`_pyramid_far`), padded by the filter
    margin."""
    a_lo, a_hi = reach.a_lo, reach.a_hi
    # Shadows lie within the casters' angular extent, when all of them are in front of the light.
    cc = reach.lc[fit].reshape(-1, 3)
    if np.all(-cc[:, 2] > 0):
        ang = cc[:, :2] / (-cc[:, 2:3])
        a_lo = np.maximum(a_lo, column_min(ang))
        a_hi = np.minimum(a_hi, column_max(ang))
        if np.any(a_hi <= a_lo):
            return Skip("no_caster_in_frustum")
    caster_near = float(reach.depth_min[fit].min() * 0.999)
    near = max(caster_near, reach.far * 1.001 * MIN_MAP_NEAR_SHARE)
    extent = float(max(a_hi[0] - a_lo[0], a_hi[1] - a_lo[1]))
    # Slopes become world sizes at a typical receiver's light depth.
    d_light = float(np.median(reach.depth[s.receivers].mean(axis=1).clip(min=near)))
    size = ctx.map_size_for(extent * d_light, s.receivers, toward=toward_light(s))
    pad = ctx.margin(extent, size)
    a_lo, a_hi = a_lo - pad, a_hi + pad
    far0 = min(reach.far, _pyramid_far(ctx, reach, s.receivers, a_lo, a_hi, near))
    near, far = _map_depth_range(float(reach.depth_min[fit].min()), far0)
    if not far > near:
        return Skip("below_precision")  # see _map_depth_range
    proj = frustum(a_lo[0] * near, a_hi[0] * near, a_lo[1] * near, a_hi[1] * near, near, far)
    # What the most demanding seen receiver point wants: one texel spans extent / size * its
    # light depth and a pixel pixel_per_distance * its camera distance, and receivers over
    # orders of magnitude in distance want far more than the typical one the size is for.
    pts = np.concatenate([ctx.corners[ctx.seen.whole].reshape(-1, 3), ctx.seen.points])
    d_l = -(pts @ reach.view[2, :3] + reach.view[2, 3])
    d_c = ctx.view_distance(np.maximum(np.linalg.norm(pts - ctx.cam_pos, axis=1),
                                       ctx.camera.znear))
    ok = d_l > 0
    ratio = float(np.max(d_l[ok] / d_c[ok])) if ok.any() else 0.0
    # (at one camera pixel per texel: the half pixel 'auto' aims at is a target, not a need)
    needed = extent * ratio / (ctx.pixel_per_distance / AUTO_TEXEL_PIXELS)
    return Fit(kind="perspective", view=reach.view, proj=proj, near=near, far=far, map_size=size,
               texel=(0.0, float(max(a_hi - a_lo)) / size), needed=needed, texel_depth=d_light,
               near_clipped=_near_clipped(reach.depth_min[fit], near))


def _pyramid_far(ctx: PlanContext, reach: SpotReach, receivers: np.ndarray, a_lo: np.ndarray,
                 a_hi: np.ndarray, near: float) -> float:
    """The deepest light depth of the receivers' boxes inside the pyramid of slopes
    [a_lo, a_hi] past ``near``, inf where none reaches it (the spot's :func:`_column_far`).

    The deepest boxes are weighed first (:data:`PYRAMID_FIRST` of them): once one of those lies
    in the pyramid, a box no deeper cannot move the bound, and at thousands of instances the
    rest are never tested.
    """
    deepest = corner_max(reach.depth[receivers])
    far = -np.inf
    rest = np.arange(len(receivers))
    if len(rest) > PYRAMID_FIRST:
        first = np.argpartition(-deepest, PYRAMID_FIRST - 1)[:PYRAMID_FIRST]
        far = _pyramid_far_of(ctx, reach, receivers[first], deepest[first], a_lo, a_hi, near,
                              far)
        rest = np.delete(rest, first)
    rest = rest[deepest[rest] > far]
    if len(rest):
        far = _pyramid_far_of(ctx, reach, receivers[rest], deepest[rest], a_lo, a_hi, near, far)
    return far if np.isfinite(far) else np.inf


#: Receivers :func:`_pyramid_far` weighs before the others.
PYRAMID_FIRST = 256


def _pyramid_far_of(ctx: PlanContext, reach: SpotReach, boxes: np.ndarray, deepest: np.ndarray,
                    a_lo: np.ndarray, a_hi: np.ndarray, near: float, far: float) -> float:
    """``far`` raised to the deepest point of ``boxes`` (indices; ``deepest`` (B,) their deepest
    corners) inside the pyramid (:func:`_pyramid_far`)."""
    depth = reach.depth[boxes]  # (B, 8)
    # Each corner against the pyramid's sides and its near end, as products (no division):
    # x >= a_lo.x d, x <= a_hi.x d, the same for y, and d > near. A box is outside when every
    # corner lies beyond one of these planes, inside when every corner lies within all.
    sides = []
    for axis in (0, 1):
        v = reach.lc[boxes, :, axis]
        sides += [v >= a_lo[axis] * depth, v <= a_hi[axis] * depth]
    sides.append(depth > near)
    out = np.zeros(len(boxes), bool)
    inside = np.ones(len(boxes), bool)
    for ok in sides:
        out |= ~ok.any(axis=1)
        inside &= ok.all(axis=1)
    far = max(far, float(np.max(deepest[inside], initial=-np.inf)))
    # Only a box reaching deeper than those can move the bound: clip just those.
    straddling = boxes[~out & ~inside & (deepest > far)]
    if len(straddling):
        z0 = near
        z1 = float(reach.depth[straddling].max())
        z1 += 1.0 + abs(z1)  # past every box
        corners = np.array([[x * z, y * z, -z] for z in (z0, z1)
                            for x in (a_lo[0], a_hi[0]) for y in (a_lo[1], a_hi[1])])
        proj = frustum(a_lo[0] * z0, a_hi[0] * z0, a_lo[1] * z0, a_hi[1] * z0, z0, z1)
        depth = _depths_inside(ctx, reach.view, proj, corners, straddling)
        far = max(far, float(np.max(depth, initial=-np.inf)))
    return far


# --------------------------------------------------------------------------------------------
# Cube: six 90-degree faces (point lights, wide spots)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class CubeReach(Reach):
    """Attributes: ``face_views`` the six face view matrices (4, 4); ``faces`` the faces to
    render; ``cheb`` (N, 8) Chebyshev distance of every box corner from the light."""

    face_views: list[np.ndarray]
    faces: list[int]
    cheb: np.ndarray


def reach_cube(ctx: PlanContext, s: Subject) -> CubeReach | Skip:
    """The faces that meet the cone (spots) and, with ``optimize``, show a visible receiver; a
    skip when none does."""
    light, position = s.light, s.position
    cheb = slice_max(np.abs(ctx.corners - position), 2)  # (N, 8)
    # Chebyshev distance from the light to each box (0 when the light is inside it): a box's
    # depth on the face that sees it is at least that.
    gap = np.maximum(np.maximum(ctx.bounds[:, 0] - position, position - ctx.bounds[:, 1]), 0)
    depth_min = corner_max(gap)
    # The farthest seen receiver point (:class:`~.context.Seen`; Chebyshev distance is convex,
    # so a clipped part's farthest point is one of its vertices).
    seen = np.abs(ctx.seen.points - position).max(axis=1, initial=0.0)
    far = max(float(cheb[ctx.seen.whole].max(initial=0.0)), float(seen.max(initial=0.0))) * 1.001
    face_views = cube_face_views(position)
    cone_cos = math.cos(light.outer_cone) if light.type == "spot" else -1.0
    faces: list[int] = []
    without_receivers = 0
    in_frustum = np.zeros(len(ctx.corners), bool)
    for f, view in enumerate(face_views):
        forward = np.array(CUBE_FACES[f][0], float)
        if light.type == "spot" and not face_meets_cone(forward, light.direction, cone_cos):
            continue  # outside the cone: never lit, not worth a count
        inside = boxes_in_frustum(transform_points(view, ctx.corners), CUBE_FACE_PLANES)
        if ctx.optimize and not (inside & ctx.in_view & ctx.receive).any():
            without_receivers += 1
            continue
        faces.append(f)
        in_frustum |= inside
    if not faces:
        return Skip("no_visible_receiver")
    skipped = {"faces_without_receivers": without_receivers} if without_receivers else {}
    return CubeReach(in_frustum=in_frustum, depth_min=depth_min, far=far, skipped=skipped,
                     face_views=face_views, faces=faces, cheb=cheb)


def _map_depth_range(caster_near: float, receiver_far: float) -> tuple[float, float]:
    """A perspective or cube map's near and far planes around its nearest caster and deepest
    receiver: each moved out by a thousandth of the range between them, or nearer by a
    thousandth of the caster's distance where that is less (a caster close to the light), the
    near plane no nearer than :data:`MIN_MAP_NEAR_SHARE` of the far one.

    The margin is a share of the depth range, not of the distance: a light 5e10 units from a
    scene 6 units deep moved its near plane 5e7 units in front of the casters at 0.999 of their
    distance, and the map's depth range, 5e7 units, left float32 a step of 3 units for a scene 6
    deep (IoU 0 against the reference).

    A range that comes out empty (far not beyond near) is float64's rounding: a box on a ground
    1.2e-6 units wide, lit from 1e10 units away, where float64's steps are 1.9e-6, has its
    nearest caster and deepest receiver at one depth. The fits then give the light no pass
    (``"below_precision"``, with a warning); dividing by the range raised ZeroDivisionError.
    """
    margin = 1e-3 * max(receiver_far - caster_near, 0.0)
    far = receiver_far + margin
    near = caster_near - min(margin, 1e-3 * caster_near)
    return max(near, far * MIN_MAP_NEAR_SHARE), far


def _near_clipped(depth_min: np.ndarray, near: float) -> int:
    """How many casters (their boxes' nearest depth from the light, ``depth_min``) lie wholly
    ahead of the light yet begin nearer than the map's near plane: what the floor
    :data:`MIN_MAP_NEAR_SHARE` clips. A box around the light (depth 0) is not counted: its
    surfaces may lie anywhere in it."""
    return int(np.count_nonzero((depth_min > 0.0) & (depth_min < near)))


def fit_cube(ctx: PlanContext, s: Subject, reach: CubeReach, fit: np.ndarray) -> Fit | Skip:
    """Six 90-degree faces from the nearest caster to the farthest receiver (Chebyshev depth,
    the depth along the face axis)."""
    near, far = _map_depth_range(float(reach.depth_min[fit].min()), reach.far)
    if not far > near:
        return Skip("below_precision")  # see _map_depth_range
    d_light = float(np.median(reach.cheb[s.receivers].mean(axis=1).clip(min=near)))
    # A face spans two units at unit depth.
    size, needed = ctx.map_size_and_need(2 * d_light, s.receivers, cube=True,
                                         toward=toward_light(s))
    return Fit(kind="cube", view=np.eye(4), proj=perspective(math.pi / 2, 1.0, near, far),
               near=near, far=far, map_size=size, texel=(0.0, 2.0 / size), faces=list(reach.faces),
               needed=needed, texel_depth=d_light,
               near_clipped=_near_clipped(reach.depth_min[fit], near),
               face_views=list(reach.face_views))


# --------------------------------------------------------------------------------------------

DIRECTIONAL: ShadowMethod[DirectionalReach] = ShadowMethod(reach_directional, fit_directional)
SPOT: ShadowMethod[SpotReach] = ShadowMethod(reach_spot, fit_spot)
CUBE: ShadowMethod[CubeReach] = ShadowMethod(reach_cube, fit_cube)


def _cone(centres: np.ndarray, radius: np.ndarray,
          position: np.ndarray) -> tuple[np.ndarray, float] | None:
    """A cone from ``position`` holding every sphere (``centres`` (K, 3), ``radius`` (K,)): its
    unit axis (3,) and half-angle in radians, or None for no sphere or one holding ``position``.

    The axis is the mean of the directions to the centres; the half-angle is the widest
    centre's angle from it plus that sphere's own angular radius.
    """
    if len(centres) == 0:
        return None
    delta = centres - position
    dist = row_norm(delta)
    if not np.all(dist > radius):
        return None
    u = delta / dist[:, None]
    mean = u.mean(axis=0)
    length = float(np.sqrt(mean @ mean))
    if not length > 0:
        return None
    axis = mean / length
    angle = np.arccos(np.clip(u @ axis, -1.0, 1.0)) + np.arcsin(radius / dist)
    return axis, float(angle.max())


def _box_radius(ctx: PlanContext, boxes: np.ndarray) -> np.ndarray:
    return row_norm((ctx.bounds[boxes, 1] - ctx.bounds[boxes, 0]) / 2)


def seen_cone(ctx: PlanContext, position: np.ndarray) -> tuple[np.ndarray, float] | None:
    """A cone from ``position`` holding every receiver part the camera sees (:func:`_cone`),
    or None where the light lies inside one of them.

    Each seen box counts as the sphere around it and each vertex of a clipped part as a point,
    so the cost is one row per box.
    """
    whole = ctx.seen.whole
    centres = np.concatenate([ctx.centres[whole], ctx.seen.points])
    radius = np.concatenate([_box_radius(ctx, whole), np.zeros(len(ctx.seen.points))])
    return _cone(centres, radius, position)


def caster_cone(ctx: PlanContext, position: np.ndarray) -> tuple[np.ndarray, float] | None:
    """A cone from ``position`` holding every caster's box (as its sphere, :func:`_cone`), or
    None where the light lies inside one of them. A shadow ray that meets a caster lies in it,
    so a receiver outside it is lit."""
    casters = np.flatnonzero(ctx.cast)
    return _cone(ctx.centres[casters], _box_radius(ctx, casters), position)


def choose_method(ctx: PlanContext, s: Subject) -> tuple[ShadowMethod, Subject]:
    """How a light is shadowed: directional lights with a box, spots up to
    :data:`MAX_SPOT_HALF_ANGLE` with a frustum, point lights and wider spots with a cube --
    unless a cone from the light that narrow holds everything the camera sees of the receivers
    (a far light: :func:`seen_cone`) or every caster (a light beside or above its casters:
    :func:`caster_cone`; a receiver outside it is lit, since its ray to the light meets no
    caster): then one frustum around the narrower cone, in place of up to six cube faces that
    would spread their texels over all the light reaches.

    Returns the method and the subject it fits: for a frustum around a cone, the light as a
    spot along that cone (which only bounds the map; shading uses the light itself).
    """
    light = s.light
    if light.type == "directional":
        return DIRECTIONAL, s
    if light.type == "spot" and light.outer_cone <= MAX_SPOT_HALF_ANGLE:
        return SPOT, s
    cones = [c for c in (seen_cone(ctx, s.position), caster_cone(ctx, s.position))
             if c is not None]
    cone = min(cones, key=lambda c: c[1]) if cones else None
    if cone is not None and cone[1] <= MAX_SPOT_HALF_ANGLE:
        axis, half_angle = cone
        if light.type == "spot":
            half_angle = min(half_angle, light.outer_cone)
        narrowed = dataclasses.replace(light, type="spot", direction=axis,
                                       outer_cone=half_angle)
        return SPOT, dataclasses.replace(s, light=narrowed)
    return CUBE, s
