"""Matrices and box geometry shared by the camera, the planner and the passes.

Everything here is a pure function of its arguments (numpy in, new numpy out), in the OpenGL
conventions: right-handed view spaces looking down −Z, clip space [-1, 1] on every axis, column
vectors (``p' = M @ p``). Nothing here knows about scenes, requests or GL.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import RequestError

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
    if un <= 0 or abs(np.dot(up / un, z)) > 0.999:
        up = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, position
    return pose


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
    idx = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])
    if b.ndim == 2:
        return b[idx, [0, 1, 2]]
    return b[:, idx, [0, 1, 2]]


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply an affine matrix (4, 4) to points (..., 3); the last row of ``m`` is ignored."""
    return p @ m[:3, :3].T + m[:3, 3]


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
    d = corners @ planes[:, :3].T + planes[:, 3]  # (N, 8, P)
    inside = ~np.any(np.all(d < 0, axis=1), axis=1)
    if frustum_corners is not None:
        lo, hi = corners.min(axis=1), corners.max(axis=1)  # (N, 3)
        f_lo, f_hi = frustum_corners.min(axis=0), frustum_corners.max(axis=0)
        inside &= np.all((hi >= f_lo) & (lo <= f_hi), axis=1)
    return inside


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
    x = np.cross(y, z)
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
