"""What the camera sees and which casters can matter to a light.

View culling of instance boxes, the planes of flat instances, and the caster selection shared by
every light fit: casters inside the light's region over the visible receivers, not beyond them,
and not a plane that faces every receiver from its lit side. Pure functions; positions are
relative to the scene's origin.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .geometry import boxes_in_frustum, frustum_planes

if TYPE_CHECKING:  # the camera and lights import this package: types only, no import cycle
    from ..camera import Camera
    from ..lights import Light
    from ..scene import Primitive, Scene
    from .context import PlanContext

# (unit normal, point) of a flat primitive, or None; keyed by the primitive so that repeated
# renders of a cached scene do not redo the SVD, without writing into the scene's objects.
_PLANES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def boxes_in_view(corners: np.ndarray, camera: Camera, origin: np.ndarray) -> np.ndarray:
    """Which boxes the camera may see (conservative).

    Parameters
    ----------
    corners : ndarray, shape (N, 8, 3)
        Instance box corners, relative to ``origin``.
    camera : Camera
    origin : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (N,), bool
    """
    pose = camera.pose.copy()
    pose[:3, 3] -= origin
    view_proj = camera.projection @ np.linalg.inv(pose)
    return boxes_in_frustum(corners, frustum_planes(view_proj), camera.frustum_corners() - origin)


def primitive_plane(prim: Primitive) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane of a flat primitive in its local frame.

    Returns
    -------
    (normal, point) : ndarray, shape (3,) each, or None
        Unit normal and the vertices' centre when every vertex lies on one plane; None otherwise
        (fewer than three vertices, a single point, or a curved or folded mesh).
    """
    try:
        return _PLANES[prim]
    except KeyError:
        pass
    p = prim.positions.astype(np.float64)
    centre = p.mean(axis=0)
    extent = float(np.max(p.max(axis=0) - p.min(axis=0)))
    result = None
    if len(p) >= 3 and extent > 0:
        _, sv, vt = np.linalg.svd(p - centre, full_matrices=False)
        if sv[-1] <= 1e-7 * max(sv[0], 1e-300) * np.sqrt(len(p)) or np.max(
            np.abs((p - centre) @ vt[-1])
        ) <= 1e-7 * extent:
            result = (vt[-1], centre)
    _PLANES[prim] = result
    return result


def instance_planes(scene: Scene, origin: np.ndarray) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Per instance: (unit normal, point) in origin-relative world space if flat, else None.

    Normals are carried by the inverse transpose, so a non-uniformly scaled plane keeps a true
    normal; a singular node matrix leaves the instance without a plane.
    """
    out: list[tuple[np.ndarray, np.ndarray] | None] = []
    for inst in scene.instances:
        plane = primitive_plane(scene.primitives[inst.primitive])
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


def shadowless_planes(ctx: PlanContext, light: Light, position: np.ndarray,
                      receivers: np.ndarray) -> np.ndarray:
    """Planar casters that cannot shadow any visible receiver of this light.

    A flat caster (a ground plane, a wall) separates space in two: it can shadow only what lies
    on its far side from the light. When every visible receiver but itself is on the light's
    side (or it is edge-on to a directional light), it casts onto nothing the camera sees and is
    left out of the fit and, with ``optimize``, of the light pass.

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
    out = np.zeros(len(ctx.planes), bool)
    tol = 1e-9 * max(float(np.max(ctx.bounds[:, 1] - ctx.bounds[:, 0])), 1e-300)
    for i, plane in enumerate(ctx.planes):
        if plane is None or not ctx.cast[i]:
            continue
        n, p0 = plane
        if light.type == "directional":
            facing = -float(np.dot(n, light.direction))
            if abs(facing) <= 1e-12:
                out[i] = True  # edge-on: it projects to a line
                continue
        else:
            facing = float(np.dot(n, position - p0))
            if abs(facing) <= tol:
                continue  # the light sits in the plane
        side = np.sign(facing)
        others = receivers[receivers != i]
        if len(others) == 0:
            out[i] = True
            continue
        d = (ctx.corners[others] - p0) @ (n * side)  # (R, 8): >= 0 on the light's side
        out[i] = bool(np.all(d >= -tol))
    return out


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
        casters=[int(i) for i in np.flatnonzero(drawn)],
        fit=fit,
        skipped={k: v for k, v in skipped.items() if v},
    )
