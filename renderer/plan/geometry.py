"""Matrices and box geometry shared by the camera, the planner and the passes.

Everything here is a pure function of its arguments (numpy in, new numpy out), in the OpenGL
conventions: right-handed view spaces looking down −Z, clip space [-1, 1] on every axis, column
vectors (``p' = M @ p``). Nothing here knows about scenes, requests or GL.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import RequestError

#: A surface faces a light when the cosine between its normal and the direction to the light
#: exceeds this (89.94 degrees): the ray-traced reference compares shadows there, the camera
#: pass's receiver plane follows every such surface (``PLANE_SLOPE_MAX``, its tangent, in
#: :mod:`..shader_constants`), and the 'auto' map size weighs the faces lit at least this much.
FACING_COS = 1e-3

# GL cube-map faces: (forward, up) in the order +X, -X, +Y, -Y, +Z, -Z.
CUBE_FACES = (
    ((1, 0, 0), (0, -1, 0)),
    ((-1, 0, 0), (0, -1, 0)),
    ((0, 1, 0), (0, 0, 1)),
    ((0, -1, 0), (0, 0, -1)),
    ((0, 0, 1), (0, -1, 0)),
    ((0, 0, -1), (0, -1, 0)),
)
# Half of the angle between a 90-degree cube face's axis and its corner directions (54.7°).
CUBE_FACE_HALF_DIAGONAL = math.acos(1 / math.sqrt(3))

# --------------------------------------------------------------------------------------------
# Projections and poses
# --------------------------------------------------------------------------------------------


def perspective(yfov: float, aspect: float, znear: float, zfar: float) -> np.ndarray:
    """OpenGL perspective projection (gluPerspective).

    Parameters
    ----------
    yfov : float
        Vertical field of view in radians.
    aspect : float
        Width over height.
    znear, zfar : float
        Positive clip distances.

    Returns
    -------
    ndarray, shape (4, 4), float64
    """
    f = 1.0 / math.tan(yfov / 2)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (zfar + znear) / (znear - zfar)
    m[2, 3] = 2 * zfar * znear / (znear - zfar)
    m[3, 2] = -1.0
    return m


def ortho(left: float, right: float, bottom: float, top: float, near: float,
          far: float) -> np.ndarray:
    """Orthographic projection (glOrtho) of the view-space box [left, right] x [bottom, top] x
    [-far, -near].

    Returns
    -------
    ndarray, shape (4, 4), float64
    """
    m = np.eye(4)
    m[0, 0] = 2 / (right - left)
    m[1, 1] = 2 / (top - bottom)
    m[2, 2] = -2 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    return m


def frustum(left: float, right: float, bottom: float, top: float, near: float,
            far: float) -> np.ndarray:
    """Off-axis perspective projection (glFrustum) with extents given at the near plane.

    Returns
    -------
    ndarray, shape (4, 4), float64
    """
    m = np.zeros((4, 4))
    m[0, 0] = 2 * near / (right - left)
    m[1, 1] = 2 * near / (top - bottom)
    m[0, 2] = (right + left) / (right - left)
    m[1, 2] = (top + bottom) / (top - bottom)
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2 * far * near / (far - near)
    m[3, 2] = -1
    return m


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Pose at ``eye`` looking at ``target`` (−Z toward it).

    An ``up`` parallel to the view direction is replaced by the world axis least aligned with it,
    so a light straight above its target still gets a valid frame.

    Parameters
    ----------
    eye, target : ndarray, shape (3,)
    up : ndarray, shape (3,), optional
        Defaults to +Y.

    Returns
    -------
    ndarray, shape (4, 4), float64
        Camera-to-world.

    Raises
    ------
    RequestError
        When ``eye`` and ``target`` coincide (no direction exists).
    """
    eye = np.asarray(eye, np.float64)
    forward = np.asarray(target, np.float64) - eye
    return pose_from_direction(eye, forward, up)


def pose_from_direction(
    position: np.ndarray, forward: np.ndarray, up: np.ndarray | None = None
) -> np.ndarray:
    """Pose at ``position`` whose −Z points along ``forward``.

    Parameters
    ----------
    position, forward : ndarray, shape (3,)
    up : ndarray, shape (3,), optional
        Defaults to +Y; replaced by the world axis least aligned with ``forward`` when parallel.

    Returns
    -------
    ndarray, shape (4, 4), float64
        Camera-to-world, orthonormal rotation.

    Raises
    ------
    RequestError
        When ``forward`` has (next to) zero length relative to the position's magnitude.
    """
    forward = np.asarray(forward, np.float64)
    n = np.linalg.norm(forward)
    scale = max(1.0, float(np.max(np.abs(position))))
    if not np.isfinite(n) or n <= 1e-12 * scale:
        raise RequestError("the view direction has zero length (position equals target?)")
    z = -forward / n
    up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, np.float64)
    un = np.linalg.norm(up)
    if un == 0.0 and up.any():
        # Components below about 1e-160 square to zero: the direction is still there.
        up = up / np.abs(up).max()
        un = np.linalg.norm(up)
    if un <= 0 or abs(np.dot(up / un, z)) > 0.999:
        up = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = cross3(up, z)
    x /= np.linalg.norm(x)
    y = cross3(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, position
    return pose


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, bit for bit (the same products and differences, in the
    same order), without its general case's overhead: a plan builds several poses per request,
    and ``np.cross`` spends tens of microseconds a call on array handling.

    Parameters
    ----------
    a, b : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3,), float64
    """
    a0, a1, a2 = np.asarray(a, np.float64).tolist()
    b0, b1, b2 = np.asarray(b, np.float64).tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


# --------------------------------------------------------------------------------------------
# Boxes, points and planes
# --------------------------------------------------------------------------------------------


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """Corners of axis-aligned boxes.

    Parameters
    ----------
    bounds : ndarray, shape (2, 3) or (N, 2, 3)
        Min and max corner of each box.

    Returns
    -------
    ndarray, shape (8, 3) or (N, 8, 3), float64
        Corner ``i`` takes x from bit 2 of ``i``, y from bit 1, z from bit 0 (0 min, 1 max).
    """
    b = np.asarray(bounds, np.float64)
    if b.ndim == 2:
        return b[_CORNER_BITS, _AXES]
    # Fancy indexing lays the result out axis by axis; in row order every later product and
    # reduction over the corners runs several times faster.
    return np.ascontiguousarray(b[:, _CORNER_BITS, _AXES])


# Corner i of a box: (min or max) per axis from the bits of i (box_corners), built once.
_CORNER_BITS = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], np.intp)
_CORNER_BITS.flags.writeable = False
_AXES = np.arange(3)
_AXES.flags.writeable = False


# --------------------------------------------------------------------------------------------
# Reductions over a short axis
# --------------------------------------------------------------------------------------------
#
# numpy reduces an axis of a few elements (a point's 3 coordinates, a box's 8 corners) row by
# row: at thousands of rows that costs many times what one elementwise operation per element of
# the short axis costs (the plan's stage at 10,000 instances: bench/ab_commits.py --scenes
# boxes_10k against the code before these). The functions below give the values numpy's
# reduction gives: a least or greatest value rounds nothing, and numpy adds fewer than 8 terms
# in order.

#: Rows from which the functions below reduce one slice or column at a time; with fewer, one
#: numpy call costs less than one per slice (a few microseconds each).
SLICE_ROWS = 128


def _by_slices(a: np.ndarray, axis: int, ufunc: np.ufunc) -> np.ndarray:
    """``ufunc.reduce(a, axis)``, as one elementwise ``ufunc`` per slice along ``axis`` once
    there are :data:`SLICE_ROWS` results or more."""
    n = a.shape[axis]
    if n < 2 or a.size < SLICE_ROWS * n:
        return ufunc.reduce(a, axis=axis)
    head = (slice(None),) * (axis % a.ndim)  # a[head + (k,)]: slice k (np.moveaxis costs more)
    out = ufunc(a[head + (0,)], a[head + (1,)])
    for k in range(2, n):
        ufunc(out, a[head + (k,)], out=out)
    return out


def slice_min(a: np.ndarray, axis: int) -> np.ndarray:
    """``a.min(axis=axis)`` over a short axis (see :data:`SLICE_ROWS`)."""
    return _by_slices(a, axis, np.minimum)


def slice_max(a: np.ndarray, axis: int) -> np.ndarray:
    """``a.max(axis=axis)`` over a short axis."""
    return _by_slices(a, axis, np.maximum)


def slice_sum(a: np.ndarray, axis: int) -> np.ndarray:
    """``a.sum(axis=axis)`` of floats over an axis of fewer than 8 elements, added in order as
    numpy adds them (up to the sign of a zero sum)."""
    if a.shape[axis] >= 8:  # numpy adds 8 or more pairwise: another rounding
        return a.sum(axis=axis)
    return _by_slices(a, axis, np.add)


def row_norm(a: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(a, axis=1)`` of (N, K) floats (K < 8), shape (N,)."""
    return np.sqrt(slice_sum(a * a, 1))


def corner_min(a: np.ndarray) -> np.ndarray:
    """The least value over axis 1 (a box's corners), e.g. (N, 8, 3) -> (N, 3)."""
    return slice_min(a, 1)


def corner_max(a: np.ndarray) -> np.ndarray:
    """The greatest value over axis 1 (a box's corners); see :func:`corner_min`."""
    return slice_max(a, 1)


def column_min(a: np.ndarray, initial: float | None = None) -> np.ndarray:
    """``a.min(axis=0)`` (with ``initial``, if given) of (N, K) ``a`` with few columns, shape
    (K,): one column at a time from :data:`SLICE_ROWS` rows."""
    return _by_columns(a, np.minimum, initial)


def column_max(a: np.ndarray, initial: float | None = None) -> np.ndarray:
    """``a.max(axis=0)`` of (N, K) ``a``; see :func:`column_min`."""
    return _by_columns(a, np.maximum, initial)


def _by_columns(a: np.ndarray, ufunc: np.ufunc, initial: float | None) -> np.ndarray:
    # A reduction's ``initial=None`` starts from the first element, as if none were given.
    if len(a) < SLICE_ROWS:
        return ufunc.reduce(a, axis=0, initial=initial)
    return np.array([ufunc.reduce(a[:, k], initial=initial) for k in range(a.shape[1])],
                    a.dtype)


def points_product(p: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``p @ b`` for points ``p`` (..., 3) and ``b`` (3,) or (3, P): shape (...) or (..., P).

    One (M, 3) product over all the points instead of numpy's one per leading index (per box of
    N x 8 corners): the same values, several times faster at thousands of boxes.
    """
    if p.ndim <= 2:
        return p @ b
    return (p.reshape(-1, p.shape[-1]) @ b).reshape(p.shape[:-1] + b.shape[1:])


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply an affine matrix (4, 4) to points (..., 3); the last row of ``m`` is ignored."""
    return points_product(p, m[:3, :3].T) + m[:3, 3]


def transform_boxes(m: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned bounds, after an affine matrix (4, 4), of boxes (N, 2, 3) (min, max).

    The same box as the least and greatest of the eight transformed corners
    (``corner_min(transform_points(m, box_corners(bounds)))``), from the centre and half-size
    instead: ``R c + t`` and ``|R| h``, an eighth of the products (the corners' extremes along
    each new axis are reached at the corner whose signs follow that row of ``R``).

    Returns
    -------
    lo, hi : ndarray, shape (N, 3)
    """
    c = (bounds[:, 0] + bounds[:, 1]) * 0.5
    h = (bounds[:, 1] - bounds[:, 0]) * 0.5
    rot = m[:3, :3]
    centre = c @ rot.T + m[:3, 3]
    half = h @ np.abs(rot).T
    return centre - half, centre + half


def frustum_planes(view_proj: np.ndarray) -> np.ndarray:
    """Clip planes of a view-projection matrix (Gribb-Hartmann).

    Parameters
    ----------
    view_proj : ndarray, shape (4, 4)

    Returns
    -------
    ndarray, shape (6, 4)
        Unit-normal planes (a, b, c, d) in the order left, right, bottom, top, near, far; a point
        is inside where ``a x + b y + c z + d >= 0``.
    """
    m = view_proj
    planes = np.array(
        [m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]]
    )
    norms = np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
    return planes / np.maximum(norms, 1e-300)


def boxes_in_frustum(corners: np.ndarray, planes: np.ndarray,
                     frustum_corners: np.ndarray | None = None) -> np.ndarray:
    """Conservative test of boxes against a convex region: False only when surely outside.

    Parameters
    ----------
    corners : ndarray, shape (N, 8, 3)
        Box corners (:func:`box_corners`), in the planes' space.
    planes : ndarray, shape (P, 4)
        Inside where ``a x + b y + c z + d >= 0``.
    frustum_corners : ndarray, shape (8, 3), optional
        The region's own corners: boxes that lie wholly beyond them along a world axis are
        rejected too (the plane test alone keeps large boxes near the region's corners).

    Returns
    -------
    ndarray, shape (N,), bool
    """
    d = points_product(corners, planes[:, :3].T) + planes[:, 3]  # (N, 8, P)
    # Outside a plane when every corner is: when the corner nearest the inside still is.
    inside = ~np.any(corner_max(d) < 0, axis=1)
    if frustum_corners is not None:
        lo, hi = corner_min(corners), corner_max(corners)  # (N, 3)
        f_lo, f_hi = frustum_corners.min(axis=0), frustum_corners.max(axis=0)
        inside &= np.all((hi >= f_lo) & (lo <= f_hi), axis=1)
    return inside


# Rows per block of :func:`thin_matmul`: a block's product is too small for BLAS to spread over
# threads.
_THIN_ROWS = 4096


def thin_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for many rows and few columns, in blocks of rows.

    A product such as (50000, 6) x (6, 6) is split across BLAS threads, whose start-up and
    synchronisation cost more than the product itself, ten times more on a busy 2-core machine;
    blocks of :data:`_THIN_ROWS` rows each run on the calling thread.

    Parameters
    ----------
    a : ndarray, shape (M, K)
    b : ndarray, shape (K, P)

    Returns
    -------
    ndarray, shape (M, P)
    """
    out = np.empty((a.shape[0], b.shape[1]), np.result_type(a, b))
    for start in range(0, a.shape[0], _THIN_ROWS):  # blocks of rows, not one per row
        np.matmul(a[start:start + _THIN_ROWS], b, out=out[start:start + _THIN_ROWS])
    return out


# Bound on the rounding of the filtered box test below, in units of the terms' magnitude: a few
# ulps per product and sum (the corner test rounds too), with a wide margin.
_AABB_FILTER_ULPS = 64 * float(np.finfo(np.float64).eps)


def aabbs_in_frustum(bounds: np.ndarray, planes: np.ndarray,
                     frustum_corners: np.ndarray | None = None) -> np.ndarray:
    """:func:`boxes_in_frustum` for axis-aligned boxes: the same result, far fewer operations.

    A box is outside a plane when its corner farthest along the plane's normal is. That corner
    takes per axis the box's min or max by the sign of the normal, O(N P) work instead of the
    O(8 N P) of testing every corner. Where its distance lies within a rounding bound of zero (a
    box touching the plane, to ~1e-14 of the scene's size) the box is tested corner by corner as
    in :func:`boxes_in_frustum`, so that the answer is the corner test's in every case.

    Parameters
    ----------
    bounds : ndarray, shape (N, 2, 3)
        Min and max corner of each box, in the planes' space.
    planes : ndarray, shape (P, 4)
    frustum_corners : ndarray, shape (8, 3), optional

    Returns
    -------
    ndarray, shape (N,), bool
        Equal to ``boxes_in_frustum(box_corners(bounds), planes, frustum_corners)``.
    """
    return aabbs_against_frustum(bounds, planes, frustum_corners)[0]


def aabbs_against_frustum(bounds: np.ndarray, planes: np.ndarray,
                          frustum_corners: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`aabbs_in_frustum`, and which boxes lie wholly inside every plane.

    Returns
    -------
    inside : ndarray, shape (N,), bool
        The result of :func:`aabbs_in_frustum`.
    whole : ndarray, shape (N,), bool
        Boxes whose nearest corner to each plane is on its inside (by the rounded distance: a
        box touching a plane from inside may be left out; see :func:`clip_boxes`).
    """
    lo, hi = bounds[:, 0], bounds[:, 1]  # (N, 3)
    n, w = planes[:, :3], planes[:, 3]  # (P, 3), (P,)
    size = np.abs(n)
    p = len(planes)
    # The farthest and the nearest corner's distance, (N, 2P): per axis the max or min corner by
    # the sign of the normal, from the rows (min, max) of the boxes as they lie in memory.
    pos, neg = np.maximum(n, 0).T, np.minimum(n, 0).T  # (3, P)
    m = np.empty((6, 2 * p))  # [[neg, pos], [pos, neg]]: np.block is slow on small arrays
    m[:3, :p], m[:3, p:], m[3:, :p], m[3:, p:] = neg, pos, pos, neg
    d = thin_matmul(np.ascontiguousarray(bounds, np.float64).reshape(-1, 6), m)
    d += np.concatenate([w, w])
    far = d[:, :p]
    whole = corner_min(d[:, p:]) >= 0
    # One rounding bound per plane, from the largest coordinate of any box. Reductions over the
    # few planes go column by column (corner_min, corner_max): numpy reduces a short last axis
    # several times slower.
    bound = _AABB_FILTER_ULPS * (float(np.max(np.abs(bounds), initial=0.0)) * size.sum(axis=1)
                                 + np.abs(w))
    outside = corner_max(far < -bound)  # beyond a plane by more than the rounding bound
    unsure = np.flatnonzero(corner_max(np.abs(far) <= bound) & ~outside)
    if len(unsure):  # the corner test itself, on the few boxes that touch a plane
        c = box_corners(bounds[unsure]) @ planes[:, :3].T + planes[:, 3]  # (U, 8, P)
        outside[unsure] = np.any(corner_max(c) < 0, axis=1)
    inside = ~outside
    if frustum_corners is not None:
        # The corners' bounding box is the box itself: its min and max corner.
        f_lo, f_hi = frustum_corners.min(axis=0), frustum_corners.max(axis=0)
        inside &= corner_min((hi >= f_lo) & (lo <= f_hi))
    return inside, whole & inside


# The 12 edges of a hexahedron whose 8 corners are numbered by three bits, one per direction
# (:func:`box_corners`, :meth:`Camera.frustum_corners`): corners that differ in one bit.
HEX_EDGES = np.array([(i, i | b) for b in (4, 2, 1) for i in range(8) if not i & b], np.intp)
HEX_EDGES.flags.writeable = False
# Boxes that :func:`clip_boxes` clips one by one (the largest first); the others are clipped
# together, as their common bounding box.
MAX_CLIPPED_BOXES = 4096


def clip_boxes(bounds: np.ndarray, planes: np.ndarray, hull: np.ndarray,
               tol: float) -> np.ndarray:
    """The parts of boxes inside a convex hexahedron (a view frustum), as points.

    The part of a box inside the hull is the convex polytope ``box ∩ hull``; its extent along any
    direction, and the extreme of any convex or linear-fractional function over it, is reached
    at one of its vertices. Those are among the box corners inside the hull, the hull corners
    inside the box, and the crossings of each one's edges with the other's faces; all are found
    at once, O(R) work for R boxes. A box wholly outside gives no point, one wholly inside its
    own corners (callers pass on those boxes whole: :func:`aabbs_against_frustum`).

    Parameters
    ----------
    bounds : ndarray, shape (R, 2, 3)
        Min and max corner of each box.
    planes : ndarray, shape (P, 4)
        The hull's unit-normal planes, inside where ``a x + b y + c z + d >= 0``
        (:func:`frustum_planes`).
    hull : ndarray, shape (8, 3)
        The hull's corners, numbered as :data:`HEX_EDGES` expects.
    tol : float
        Distance within which a point counts as inside a plane or a box (rounding): the parts
        come out at most this much larger, never smaller.

    Returns
    -------
    ndarray, shape (M, 3)
        The vertices of the boxes' parts inside the hull, all boxes together. Past
        :data:`MAX_CLIPPED_BOXES` boxes, the smaller ones are clipped together as their common
        bounding box (a larger part, never a smaller one).
    """
    if len(bounds) > MAX_CLIPPED_BOXES:
        size = corner_max(bounds[:, 1] - bounds[:, 0])
        order = np.argsort(-size, kind="stable")
        own, rest = order[:MAX_CLIPPED_BOXES], order[MAX_CLIPPED_BOXES:]
        common = np.stack([column_min(bounds[rest, 0]), column_max(bounds[rest, 1])])
        bounds = np.concatenate([bounds[own], common[None]])
    return _clip_straddling(bounds, planes, hull, tol)


def _clip_straddling(boxes: np.ndarray, planes: np.ndarray, hull: np.ndarray,
                     tol: float) -> np.ndarray:
    """The vertices (M, 3) of ``box ∩ hull`` for boxes (S, 2, 3), every box on its own (see
    :func:`clip_boxes`)."""
    if len(boxes) == 0:
        return np.zeros((0, 3))
    n, w = planes[:, :3], planes[:, 3]
    lo, hi = boxes[:, 0], boxes[:, 1]  # (S, 3)
    corners = box_corners(boxes)  # (S, 8, 3)
    d = corners @ n.T + w  # (S, 8, P)
    out = [corners[np.all(d >= -tol, axis=2)]]
    # Hull corners inside each box.
    inside = np.all((hull >= lo[:, None] - tol) & (hull <= hi[:, None] + tol), axis=2)  # (S, 8)
    out.append(hull[np.nonzero(inside)[1]])
    e0, e1 = HEX_EDGES[:, 0], HEX_EDGES[:, 1]
    # Box edges crossing a hull plane (endpoints strictly on either side), inside the others.
    d0, d1 = d[:, e0], d[:, e1]  # (S, 12, P)
    s, e, k = np.nonzero(((d0 < 0) & (d1 > 0)) | ((d0 > 0) & (d1 < 0)))
    t = d0[s, e, k] / (d0[s, e, k] - d1[s, e, k])
    a = corners[s, e0[e]]
    p = a + t[:, None] * (corners[s, e1[e]] - a)
    out.append(p[np.all(p @ n.T + w >= -tol, axis=1)])
    # Hull edges crossing a box face (a plane x_j = lo_j or hi_j), inside the box's other sides:
    # only the (box, edge) pairs whose bounding boxes meet.
    q0, q1 = hull[e0], hull[e1]  # (12, 3)
    q_lo, q_hi = np.minimum(q0, q1), np.maximum(q0, q1)
    meet = np.all((q_lo <= hi[:, None] + tol) & (q_hi >= lo[:, None] - tol), axis=2)  # (S, 12)
    s, e = np.nonzero(meet)
    face = boxes[s].transpose(0, 2, 1)  # (K, 3, 2): per axis, the lo and hi face
    a, dq = q0[e], q1[e] - q0[e]  # (K, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (face - a[:, :, None]) / dq[:, :, None]  # (K, 3, 2)
    # A division by 0 (an edge parallel to the face) gives inf or nan: no crossing.
    i, j, side = np.nonzero((t >= 0) & (t <= 1))
    p = a[i] + t[i, j, side][:, None] * dq[i]
    p[np.arange(len(p)), j] = face[i, j, side]  # on the face exactly
    out.append(p[np.all((p >= lo[s[i]] - tol) & (p <= hi[s[i]] + tol), axis=1)])
    return np.concatenate(out)


def pyramid_planes(a_lo: np.ndarray, a_hi: np.ndarray) -> np.ndarray:
    """Planes of the pyramid with its apex at the view origin, opening toward −Z.

    Parameters
    ----------
    a_lo, a_hi : ndarray, shape (2,)
        Bounds of the slopes ``x / -z`` and ``y / -z``.

    Returns
    -------
    ndarray, shape (5, 4)
        Four side planes and the apex plane ``z <= 0``, inside where ``a x + b y + c z + d >= 0``
        (not unit length: only signs are compared).
    """
    return np.array(
        [
            [1.0, 0.0, a_lo[0], 0.0],  # x >= a_lo.x * (-z)
            [-1.0, 0.0, -a_hi[0], 0.0],
            [0.0, 1.0, a_lo[1], 0.0],
            [0.0, -1.0, -a_hi[1], 0.0],
            [0.0, 0.0, -1.0, 0.0],  # in front of the light
        ]
    )


# The 90-degree pyramid of one cube face, in that face's view space.
CUBE_FACE_PLANES = pyramid_planes(np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
CUBE_FACE_PLANES.flags.writeable = False  # shared by every call


# --------------------------------------------------------------------------------------------
# Cube maps
# --------------------------------------------------------------------------------------------


def cube_face_view(position: np.ndarray, face: int) -> np.ndarray:
    """World-to-face view matrix of one GL cube-map face seen from ``position``.

    Parameters
    ----------
    position : ndarray, shape (3,)
    face : int
        0..5 in the order of :data:`CUBE_FACES` (+X, -X, +Y, -Y, +Z, -Z).

    Returns
    -------
    ndarray, shape (4, 4), float64
    """
    fwd, up = CUBE_FACES[face]
    pose = np.eye(4)
    z = -np.array(fwd, np.float64)
    y = np.array(up, np.float64)
    x = cross3(y, z)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, position
    return np.linalg.inv(pose)


def cube_face_views(position: np.ndarray) -> list[np.ndarray]:
    """The six face view matrices (4, 4) of a cube map at ``position``, in GL face order."""
    return [cube_face_view(position, f) for f in range(len(CUBE_FACES))]


def face_meets_cone(forward: np.ndarray, direction: np.ndarray, cone_cos: float) -> bool:
    """Whether a 90-degree cube face overlaps a cone (angle between axes < cone + 54.7°).

    Parameters
    ----------
    forward : ndarray, shape (3,)
        Unit axis of the face.
    direction : ndarray, shape (3,)
        Unit axis of the cone.
    cone_cos : float
        Cosine of the cone's half-angle.
    """
    angle = math.acos(float(np.clip(np.dot(forward, direction), -1, 1)))
    return angle < math.acos(max(min(cone_cos, 1.0), -1.0)) + CUBE_FACE_HALF_DIAGONAL


def texel_stretch(normal: np.ndarray, to_light: np.ndarray,
                  view: np.ndarray | None) -> np.ndarray:
    """How many times its own width a shadow-map texel spans on screen along its longest side,
    on flat faces: the texel's square across the light's rays, cast along them onto the face
    and seen from the camera (locally orthographic).

    The image of a vector ``w`` across the light ``l`` is ``P_v (w - l (n.w) / (n.l))`` (the
    face point it shades, then its part across the view ``v``); the stretch is the largest
    singular value of that map on the plane across ``l``. With ``c = n.l``, ``a = v.l`` and
    ``e = n.v``, its squared singular values add up to
    ``F = 1 + a^2 + 2a (e - ca) / c + (1 - c^2)(1 - a^2) / c^2`` and multiply to
    ``(e / c)^2`` (the ratio of the texel's area on screen to its own), so the largest is
    ``sqrt((F + sqrt(F^2 - 4 (e / c)^2)) / 2)``. A face square to the light and to the view
    gives 1, and a face lit at angle θ from its plane up to 1 / sin θ.

    Parameters
    ----------
    normal : ndarray, shape (M, 3)
        Unit face normals (either side).
    to_light : ndarray, shape (M, 3)
        Unit directions from the faces toward the light.
    view : ndarray, shape (M, 3), or None
        Unit directions from the camera to the faces; None for the most any view can see,
        1 / c (seen square on along the stretch).

    Returns
    -------
    ndarray, shape (M,)
        0 for a face whose side the camera sees is not lit (c at most :data:`FACING_COS`):
        its lookups decide nothing.
    """
    c = slice_sum(normal * to_light, 1)
    if view is None:
        c = np.abs(c)
        lit = c > FACING_COS
        return np.where(lit, 1.0 / np.where(lit, c, 1.0), 0.0)
    e = slice_sum(normal * view, 1)
    # The side the camera sees: its normal points back at the camera (e < 0).
    flip = np.where(e > 0, -1.0, 1.0)
    c, e = c * flip, e * flip
    lit = c > FACING_COS
    c = np.where(lit, c, 1.0)
    a = slice_sum(view * to_light, 1)
    f = 1.0 + a * a + 2.0 * a * (e - c * a) / c + (1.0 - c * c) * (1.0 - a * a) / (c * c)
    p = e / c
    big = (f + np.sqrt(np.maximum(f * f - 4.0 * p * p, 0.0))) / 2.0
    return np.where(lit, np.sqrt(np.maximum(big, 0.0)), 0.0)
