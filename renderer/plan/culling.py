"""What the camera sees and which casters can matter to a light.

View culling of instance boxes, and the caster selection shared by every light fit: casters inside
the light's region over the visible receivers, not beyond them, and not a plane that faces every
receiver from its lit side. Pure functions over arrays of all instances (the planes of flat
instances come from :mod:`.instances`); positions are relative to the scene's origin.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .geometry import column_max, column_min, frustum_planes, thin_matmul

if TYPE_CHECKING:  # the camera and lights import this package: types only, no import cycle
    from ..camera import Camera
    from ..lights import Light
    from .context import PlanContext


def view_planes(camera: Camera, origin: np.ndarray) -> np.ndarray:
    """The camera frustum's six unit-normal planes (:func:`.geometry.frustum_planes`), relative
    to ``origin``, shape (6, 4)."""
    return frustum_planes(camera.view_projection(origin))


def near_first(ctx: PlanContext, instances: np.ndarray) -> np.ndarray:
    """``instances`` in the order the camera pass draws them: nearest box centre first.

    A surface drawn before what hides it is shaded and then overwritten; drawn after, the depth
    test drops its fragments before the fragment shader runs (a software rasterizer skips every
    block of pixels that none passes). Near first leaves the least to overwrite, and a ground or
    a wall, whose centre lies behind what stands on it, comes after it.

    Parameters
    ----------
    ctx : PlanContext
    instances : ndarray, shape (V,), intp
        Scene instance indices.

    Returns
    -------
    ndarray, shape (V,), intp
        The same indices, by the distance of their box centre from the eye (orthographic: its
        depth along the view axis), ties in the order given.
    """
    rel = ctx.centres[instances] - ctx.cam_pos
    if ctx.flat_distance is None:
        key = np.einsum("ij,ij->i", rel, rel)
    else:
        key = rel @ np.asarray(ctx.camera.forward, np.float64)
    return instances[np.argsort(key, kind="stable")]


# Directions whose most extreme receivers are tried first as witnesses that a plane has a
# receiver behind it (the 26 neighbours of a grid cell): one such receiver settles the test, and
# a large receiver (a ground, a wall) is extreme along some of them.
_WITNESS_DIRECTIONS = np.array(
    [(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if x or y or z],
    np.float64,
)
_WITNESS_DIRECTIONS.flags.writeable = False
# Directions per block of the exact test: the (receivers, block) array stays near 4M floats.
_BLOCK_ELEMENTS = 1 << 22


def _support_min(lo: np.ndarray, hi: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """The least ``corner . d`` over the corners of each box, for each direction.

    Parameters
    ----------
    lo, hi : ndarray, shape (R, 3)
        Box min and max corners.
    dirs : ndarray, shape (D, 3)

    Returns
    -------
    ndarray, shape (R, D)
        Per axis the lesser of ``lo * d`` and ``hi * d``: the corner nearest along ``-d``.
    """
    return thin_matmul(np.concatenate([lo, hi], axis=1),
                       np.concatenate([np.maximum(dirs, 0), np.minimum(dirs, 0)], axis=1).T)


def shadowless_planes(ctx: PlanContext, light: Light, position: np.ndarray,
                      receivers: np.ndarray) -> np.ndarray:
    """Planar casters that cannot shadow any visible receiver of this light.

    A flat caster (a ground plane, a wall) separates space in two: it can shadow only what lies
    on its far side from the light. When every visible receiver but itself is on the light's
    side (or it is edge-on to a directional light), it casts onto nothing the camera sees and is
    left out of the fit and, with ``optimize``, of the light pass.

    All flat casters are tested at once (:func:`_on_light_side`); no step visits one instance at a
    time.

    Parameters
    ----------
    ctx : PlanContext
    light : Light
    position : ndarray, shape (3,)
        The light's position relative to the origin (unused for directional lights).
    receivers : ndarray, shape (R,), int
        Indices of the receivers that matter.

    Returns
    -------
    ndarray, shape (N,), bool
    """
    out = np.zeros(len(ctx.cast), bool)
    idx = np.flatnonzero(ctx.planes.flat & ctx.cast)
    if len(idx) == 0:
        return out
    normal, p0 = ctx.planes.normal[idx], ctx.planes.point[idx]
    tol = 1e-9 * max(ctx.extent, 1e-300)
    # Row sums of products: the same rounding as one 3-vector dot product per plane.
    if light.type == "directional":
        facing = -(normal * light.direction).sum(axis=1)
        edge_on = np.abs(facing) <= 1e-12
        out[idx[edge_on]] = True  # edge-on: it projects to a line
        live = ~edge_on
    else:
        facing = (normal * (position - p0)).sum(axis=1)
        live = np.abs(facing) > tol  # otherwise the light sits in the plane
    idx, normal, p0, facing = idx[live], normal[live], p0[live], facing[live]
    if len(idx):
        # Normals turned toward the light: a receiver corner c is on the light's side of plane
        # k when (c - p0[k]) . toward[k] >= -tol.
        toward = normal * np.sign(facing)[:, None]
        out[idx] = _on_light_side(ctx.bounds, idx, toward, p0, receivers, tol)
    return out


def _on_light_side(bounds: np.ndarray, idx: np.ndarray, toward: np.ndarray, p0: np.ndarray,
                   receivers: np.ndarray, tol: float) -> np.ndarray:
    """Whether every receiver box other than the plane's own lies on the light's side of it.

    A box's nearest corner along ``-toward`` decides for the whole box (:func:`_support_min`).
    Three steps, each exact: planes with the receivers' common bounding box on their light side
    hold; planes with one of a few extreme receivers (:data:`_WITNESS_DIRECTIONS`) behind them
    fail; the rest are tested against every receiver, once per distinct normal, in blocks. The
    work is O(K + D R) for K planes with D distinct normals among the undecided and R receivers.

    Parameters
    ----------
    bounds : ndarray, shape (N, 2, 3)
        Every instance's box.
    idx : ndarray, shape (K,), int
        The planes' instance indices (a plane's own box is not tested against it).
    toward : ndarray, shape (K, 3)
        Unit normals turned toward the light.
    p0 : ndarray, shape (K, 3)
        A point of each plane.
    receivers : ndarray, shape (R,), int
    tol : float

    Returns
    -------
    ndarray, shape (K,), bool
    """
    k = len(idx)
    if len(receivers) == 0:
        return np.ones(k, bool)
    offset = (p0 * toward).sum(axis=1)  # (K,): p0 . toward
    lo, hi = bounds[receivers, 0], bounds[receivers, 1]  # (R, 3)
    # 1. Nothing is behind a plane whose light side holds the box around every receiver.
    common = _support_min(column_min(lo)[None], column_max(hi)[None], toward)[0]
    result = common - offset >= -tol
    undecided = ~result
    # 2. A receiver (not the plane itself) behind the plane decides against it.
    if undecided.any():
        s = _support_min(lo, hi, _WITNESS_DIRECTIONS)  # (R, 26)
        two = np.argpartition(s, 1, axis=0)[:2] if len(receivers) > 1 else np.zeros((1, 26), int)
        w = np.unique(two)  # positions in ``receivers``
        u = np.flatnonzero(undecided)
        sw = _support_min(lo[w], hi[w], toward[u])  # (W, U)
        sw[receivers[w][:, None] == idx[u][None, :]] = np.inf
        undecided[u[np.any(sw - offset[u] < -tol, axis=0)]] = False  # result stays False
    # 3. The rest against every receiver: per distinct normal, the nearest receiver box and
    # the nearest other than the first (a plane whose own box is the nearest takes the second).
    u = np.flatnonzero(undecided)
    if len(u):
        dirs, group = np.unique(toward[u], axis=0, return_inverse=True)
        group = group.reshape(-1)
        nearest = np.empty(len(dirs))
        second = np.empty(len(dirs))
        owner = np.empty(len(dirs), np.intp)
        step = max(1, _BLOCK_ELEMENTS // len(receivers))
        for b in range(0, len(dirs), step):  # blocks of directions, not instances
            s = _support_min(lo, hi, dirs[b:b + step])  # (R, B)
            cols = np.arange(s.shape[1])
            first = np.argmin(s, axis=0)
            nearest[b:b + step] = s[first, cols]
            owner[b:b + step] = receivers[first]
            s[first, cols] = np.inf
            second[b:b + step] = s.min(axis=0)
        others = np.where(owner[group] == idx[u], second[group], nearest[group])
        result[u] = others - offset[u] >= -tol
    return result


@dataclass(frozen=True)
class Selection:
    """The casters of one light pass.

    Attributes
    ----------
    casters : list of int
        Instance indices drawn into the map.
    fit : ndarray, shape (N,), bool
        Casters the light's frustum is fitted to (those that can shadow a visible receiver).
    skipped : dict of str to int
        Casters left out, by reason; only non-zero counts.
    """

    casters: list[int]
    fit: np.ndarray
    skipped: dict[str, int]


def select_casters(ctx: PlanContext, light: Light, position: np.ndarray, receivers: np.ndarray,
                   in_frustum: np.ndarray, depth_min: np.ndarray, far: float) -> Selection:
    """Casters that can shadow a visible receiver, counting the others by reason.

    Without ``optimize`` every caster is drawn; the frustum is fitted the same way either way, so
    the maps agree where it matters (what is skipped rasterises nothing, lies beyond the far
    plane, or is a plane that only its own lit side sees).

    Parameters
    ----------
    ctx : PlanContext
    light : Light
    position : ndarray, shape (3,)
        Origin-relative light position.
    receivers : ndarray, shape (R,), int
    in_frustum : ndarray, shape (N,), bool
        Boxes inside the light's region over the receivers.
    depth_min : ndarray, shape (N,)
        Nearest light depth of each box.
    far : float
        Deepest receiver depth: boxes wholly beyond it cast onto nothing that is seen.
    """
    shadowless = shadowless_planes(ctx, light, position, receivers)
    before = depth_min <= far
    fit = ctx.cast & in_frustum & before & ~shadowless
    skipped = {"non_caster": int((~ctx.cast).sum())}
    if ctx.optimize:
        skipped["outside_frustum"] = int((ctx.cast & ~in_frustum).sum())
        skipped["behind_receivers"] = int((ctx.cast & in_frustum & (depth_min > far)).sum())
        skipped["plane_facing_receivers"] = int((ctx.cast & in_frustum & before & shadowless).sum())
        drawn = fit
    else:
        drawn = ctx.cast
    return Selection(
        casters=np.flatnonzero(drawn).tolist(),  # Python ints, without a loop here
        fit=fit,
        skipped={k: v for k, v in skipped.items() if v},
    )
