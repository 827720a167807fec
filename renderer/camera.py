"""Resolving the viewing camera of a request into matrices.

A request may give a pose, an eye/target pair, or nothing (use the file's camera, else frame the
scene). Degenerate input is fixed where a meaning exists (an up vector parallel to the view
direction is replaced) and refused where it does not (eye at the target, singular pose).
The matrix helpers themselves (``perspective``, ``look_at``, ``pose_from_direction``) are in
:mod:`renderer.plan.geometry`.
"""

from __future__ import annotations

import math
import threading
import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import RequestError, SceneError
from .params import CameraParams
from .plan.geometry import look_at, ortho, perspective, row_norm
from .plan.instances import primitive_edge, scene_arrays, scene_box  # Scene.bounds, once per scene
from .scene import Scene, instance_arrays

#: The automatic near plane's distance, as a share of the far plane's, where no geometry is nearer
#: (a camera inside the scene's bounding sphere).
NEAR_SHARE = 1e-4
#: The nearest the automatic near plane comes, as a share of the far plane's distance: geometry
#: nearer than :data:`NEAR_SHARE` pulls the near plane in to it, down to this. The camera pass
#: draws with reversed depth into a float depth buffer (``camera_pass.REVERSED_Z``), whose
#: precision is relative at every distance, so a deep range costs no precision far away; past it
#: the geometry nearer than the near plane is clipped, with a warning (:func:`near_clip_warning`).
MIN_NEAR_SHARE = 1e-7
#: Where the automatic near plane stands in front of the nearest geometry, as a share of its
#: distance (its box's nearest point, not its surface).
NEAR_MARGIN = 0.5


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class Camera:
    """A resolved camera: perspective, or orthographic when ``ymag`` is set.

    Attributes
    ----------
    pose : ndarray, shape (4, 4), float64
        Camera-to-world, orthonormal rotation; the camera looks down its local −Z, +Y up.
    yfov : float
        Vertical field of view in radians (perspective; unused when ``ymag`` is set).
    width, height : int
        Image size in pixels; row 0 of every output is the top of the picture.
    znear, zfar : float
        Clip distances, fitted to the scene unless the request fixed them.
    ymag : float or None
        Orthographic: half the view's height in scene units (the width follows the image's
        aspect). None: perspective.
    """

    pose: np.ndarray
    yfov: float
    width: int
    height: int
    znear: float
    zfar: float
    ymag: float | None = None

    @property
    def orthographic(self) -> bool:
        return self.ymag is not None

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        """The view direction (unit, world), shape (3,)."""
        return -self.pose[:3, 2]

    def pixel_size(self, distance: np.ndarray | float) -> np.ndarray:
        """World size of a pixel at ``distance`` along the view axis (same shape, float64):
        growing with it in perspective, the same everywhere in an orthographic view."""
        d = np.asarray(distance, np.float64)
        if self.ymag is not None:
            return np.full_like(d, 2.0 * self.ymag / self.height)
        return d * (2.0 * math.tan(self.yfov / 2) / self.height)

    def view_from(self, origin: np.ndarray) -> np.ndarray:
        """Origin-relative world to camera, shape (4, 4): the pose is made relative to
        ``origin`` before it is inverted. Inverting the world pose first and adding the origin
        back cancels float64 steps of the eye's size (a camera 3e-6 from a part 1.8e8 units
        out: 3e-8, 1 % of the depth)."""
        pose = np.array(self.pose, np.float64)
        pose[:3, 3] -= origin
        return np.linalg.inv(pose)

    # Computed once per camera (a repeated request's camera is the same object) and read-only:
    # the camera is immutable, so is this.
    @cached_property
    def projection(self) -> np.ndarray:
        """OpenGL projection (perspective or orthographic), shape (4, 4), read-only."""
        if self.ymag is not None:
            x = self.ymag * self.width / self.height
            return _read_only(ortho(-x, x, -self.ymag, self.ymag, self.znear, self.zfar))
        return _read_only(perspective(self.yfov, self.width / self.height, self.znear,
                                      self.zfar))

    def view_projection(self, origin: np.ndarray) -> np.ndarray:
        """``projection @ view_from(origin)``, shape (4, 4), read-only: computed once per
        camera and origin (a plan's view test, its shadow region and the camera pass all use
        it)."""
        key = np.asarray(origin, np.float64).tobytes()
        vp = self._view_projections.get(key)
        if vp is None:
            vp = self._view_projections[key] = _read_only(self.projection
                                                          @ self.view_from(origin))
        return vp

    @cached_property
    def _view_projections(self) -> dict[bytes, np.ndarray]:
        return {}

    def _half_extents(self, z: float) -> tuple[float, float]:
        """Half width and half height of the view at distance ``z``."""
        h = self.ymag if self.ymag is not None else z * math.tan(self.yfov / 2)
        return h * self.width / self.height, h

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through every pixel centre: from the eye (perspective), or from
        the pixel's place on the plane through the eye, all along the view axis
        (orthographic).

        Returns
        -------
        origins : ndarray, shape (H*W, 3)
        directions : ndarray, shape (H*W, 3)
            Unit vectors, row-major from the top-left pixel.
        """
        hx, hy = self._half_extents(1.0)
        xs = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * hx
        ys = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * hy
        gx, gy = np.meshgrid(xs, ys)
        r = self.pose[:3, :3]
        if self.ymag is not None:
            local = np.stack([gx, gy, np.zeros_like(gx)], axis=-1).reshape(-1, 3)
            origins = local @ r.T + self.position
            return origins, np.broadcast_to(-r[:, 2], origins.shape).copy()
        d = np.stack([gx, gy, -np.ones_like(gx)], axis=-1).reshape(-1, 3)
        d = d @ r.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.position, d.shape).copy(), d

    def frustum_corners(self, origin: np.ndarray | None = None) -> np.ndarray:
        """Corners of the view volume (a frustum, or a box when orthographic), shape (8, 3): in
        world space, or relative to ``origin`` (subtracted from the eye before the corners are
        placed: near corners a fraction of a float64 step of the eye's world coordinates from
        it keep their precision)."""
        pts = []
        for z in (self.znear, self.zfar):
            hx, hy = self._half_extents(z)
            for sx in (-1, 1):
                for sy in (-1, 1):
                    pts.append((sx * hx, sy * hy, -z))
        p = np.array(pts)
        eye = self.pose[:3, 3] if origin is None else self.pose[:3, 3] - origin
        return p @ self.pose[:3, :3].T + eye


def orthonormalize_pose(matrix: np.ndarray, what: str) -> np.ndarray:
    """Turn a user pose into a rigid one (rotation + translation).

    Scale and shear are removed with the polar decomposition (the nearest rotation); a mirrored
    or singular matrix has no orientation and is refused.
    """
    m = np.asarray(matrix, np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise RequestError(f"{what} pose must be a finite 4x4 matrix")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise RequestError(f"{what} pose must have a last row of [0, 0, 0, 1]")
    r = m[:3, :3]
    u, s, vt = np.linalg.svd(r)
    if s[-1] <= 1e-9 * max(s[0], 1e-300) or np.linalg.det(r) <= 0:
        raise RequestError(f"{what} pose is singular or mirrored: it has no orientation")
    out = np.eye(4)
    out[:3, :3] = u @ vt
    out[:3, 3] = m[:3, 3]
    return out


def nearest_box_distances(scene: Scene, eye: np.ndarray) -> np.ndarray:
    """Distance from ``eye`` to each instance's box (N,), float64: 0 for a box holding it."""
    bounds = scene_arrays(scene).bounds  # (N, 2, 3)
    return row_norm(np.maximum(np.maximum(bounds[:, 0] - eye, eye - bounds[:, 1]), 0.0))


def _auto_near(scene: Scene, eye: np.ndarray, sphere_near: float, zfar: float) -> float:
    """The automatic near plane: the scene's bounding sphere's near side, at least
    :data:`NEAR_SHARE` of the far plane; nearer, in front of the nearest instance box that does
    not hold the eye (down to :data:`MIN_NEAR_SHARE`), so that a camera close to a part of a
    large scene still sees it."""
    znear = max(sphere_near, zfar * NEAR_SHARE, 1e-30)
    if sphere_near >= zfar * NEAR_SHARE:
        return znear  # the eye outside the sphere: nothing lies nearer than its near side
    d = nearest_box_distances(scene, eye)
    d = d[d > 0.0]  # a box around the eye (a room) says nothing of where its surfaces lie
    if len(d) and float(d.min()) < znear:
        znear = max(sphere_near, float(d.min()) * NEAR_MARGIN, zfar * MIN_NEAR_SHARE, 1e-30)
    return znear


BoxesAhead = tuple[np.ndarray, np.ndarray]


def boxes_ahead(camera: Camera, scene: Scene) -> BoxesAhead:
    """Each instance box's distance from the eye (N,), and whether it lies ahead of the camera
    and does not hold the eye (N,) bool (a box around the eye says nothing of where its
    surfaces lie). :func:`near_clip_warning` and :func:`view_origin` both read them: a caller
    of both works them out once and hands them to each."""
    eye = camera.position
    d = nearest_box_distances(scene, eye)
    bounds = scene_arrays(scene).bounds
    centre = (bounds[:, 0] + bounds[:, 1]) / 2
    return d, ((centre - eye) @ -camera.pose[:3, 2] > 0.0) & (d > 0.0)


def near_clip_warning(camera: Camera, scene: Scene, params: CameraParams | None,
                      ahead: BoxesAhead | None = None) -> str:
    """A warning when the automatic near plane clips geometry in front of the camera: an
    instance box (not one around the eye) that lies wholly nearer than it, ahead of the eye.
    Empty when the request gave ``znear``. ``ahead``: :func:`boxes_ahead`, when the caller has
    it."""
    if params is not None and params.znear is not None:
        return ""
    d, front = boxes_ahead(camera, scene) if ahead is None else ahead
    clipped = front & (d < camera.znear)
    if not clipped.any():
        return ""
    return (f"camera: the automatic near plane at {camera.znear:.3g} units (it comes no nearer "
            f"than {MIN_NEAR_SHARE:g} of the far plane, at {camera.zfar:.3g}) clips "
            f"{int(clipped.sum())} instance(s) wholly nearer than it (the nearest "
            f"{float(d[clipped].min()):.3g} units away): the scene is too deep from this camera "
            "for one depth range; give camera.znear and camera.zfar")


#: Positions the GPU gets are float32, relative to the render's origin: at distance M from it they
#: step by about M * 2**-23, and a view transform of such a position errs by a few steps. A view
#: whose nearest pixels are finer than 4 such steps (2**-21 of M) shows them.
VIEW_PRECISION = 2.0**-21
#: Share of the precision budget of the nearest pixels the eye's origin may stand off the eye:
#: it is snapped to a grid this fine, so that nearby views share an origin (and an upload's
#: matrices, plans and light maps).
ORIGIN_SNAP_SHARE = 1.0 / 16


@dataclass(frozen=True)
class ViewOrigin:
    """Where a view's GPU coordinates start (:func:`view_origin`).

    Attributes
    ----------
    origin : ndarray, shape (3,), float64
    at : str
        ``"scene_centre"`` (where the upload is placed) or ``"eye"`` (a grid point beside it).
    warning : str
        Empty, or what float32 still cannot resolve from that origin.
    """

    origin: np.ndarray
    at: str
    warning: str = ""


# (local, own) of :func:`_own_reach` by scene, weakly: nothing is written into the scene.
_OWN: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_OWN_LOCK = threading.Lock()


def _own_reach(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Per instance (N,) each, float64: the reach of its local coordinates (its box's farthest
    corner from the instance's own origin), and a first bound of what its float32 values span
    (the larger of that and its box's diagonal, which bounds its longest triangle edge). Kept
    per scene: they do not depend on the view."""
    with _OWN_LOCK:
        hit = _OWN.get(scene)
    if hit is not None:
        return hit
    arrays = instance_arrays(scene)
    bounds = arrays.bounds
    local = np.linalg.norm(np.max(np.abs(bounds - arrays.matrices[:, None, :3, 3]), axis=1),
                           axis=1)
    own = np.maximum(np.linalg.norm(bounds[:, 1] - bounds[:, 0], axis=1), local)
    out = (_read_only(local), _read_only(own))
    with _OWN_LOCK:
        _OWN[scene] = out
    return out


def view_origin(camera: Camera, scene: Scene, centre: np.ndarray,
                ahead: BoxesAhead | None = None) -> ViewOrigin:
    """The origin of a view's GPU coordinates: the scene's centre unless this camera looks so
    closely at geometry so far from it that a pixel there is finer than float32 places positions
    (jagged edges, noisy shading and shadows); then a point beside the eye, where the view's
    nearest pixels need the precision (``GpuScene.set_origin`` writes the instance matrices
    relative to it, in float64).

    Each instance box ahead of the eye (not one around it) is checked at its nearest distance
    ``near`` (at least the near plane): its pixels there are :meth:`Camera.pixel_size` wide,
    and the float32 values drawn there reach ``|eye - origin| + near + own`` from the origin,
    where ``own`` is the larger of the instance's longest triangle edge (a varying is
    interpolated from the triangle's vertices) and the reach of its local coordinates (a mesh
    far from its own origin). Shortfalls from the eye's origin are said in the warning.
    ``ahead``: :func:`boxes_ahead`, when the caller has it.
    """
    d, front = boxes_ahead(camera, scene) if ahead is None else ahead
    idx = np.flatnonzero(front)
    if not len(idx):
        return ViewOrigin(centre, "scene_centre")
    near = np.maximum(d[idx], camera.znear)
    pixel = camera.pixel_size(near)
    local_all, own_all = _own_reach(scene)
    local, own = local_all[idx], own_all[idx]
    eye = camera.position

    def short(origin: np.ndarray) -> np.ndarray:
        reach = float(np.linalg.norm(eye - origin)) + near + own
        return pixel < reach * VIEW_PRECISION

    coarse = short(centre)
    if not coarse.any():
        return ViewOrigin(centre, "scene_centre")
    arrays = instance_arrays(scene)
    used, inverse = np.unique(arrays.primitive[idx[coarse]], return_inverse=True)
    edges = np.array([primitive_edge(scene.primitives[p]) for p in used.tolist()])
    stretch = np.linalg.norm(arrays.matrices[idx[coarse], :3, :3], ord=2, axis=(1, 2))
    own[coarse] = np.maximum(edges[inverse.reshape(-1)] * stretch, local[coarse])
    if not short(centre).any():
        return ViewOrigin(centre, "scene_centre")
    budget = float(pixel.min()) / VIEW_PRECISION * ORIGIN_SNAP_SHARE
    q = 2.0 ** math.floor(math.log2(budget))
    origin = np.round(eye / q) * q
    still = short(origin)
    if not still.any():
        return ViewOrigin(origin, "eye")
    reach = float(np.linalg.norm(eye - origin)) + near + own
    worst = int(np.argmax(np.where(still, reach * VIEW_PRECISION / pixel, 0.0)))
    inst = scene.instances[int(idx[worst])]
    name = repr(inst.name) if inst.name else f"instance {int(idx[worst])}"
    return ViewOrigin(origin, "eye", (
        f"camera: {name} ({near[worst]:.3g} units away, {pixel[worst]:.3g} units a pixel there) "
        f"is drawn from float32 values up to {reach[worst]:.3g} units from the view's origin "
        f"(its triangles or its own coordinates span {own[worst]:.3g} units), where the GPU's "
        f"float32 positions step by about {reach[worst] * 2.0**-23:.3g} units: edges and "
        "shading there show those steps; view it from further away, or split it into smaller "
        "parts"))


def resolve_camera(params: CameraParams | None, scene: Scene, width: int, height: int) -> Camera:
    """Resolve the request's camera against a scene.

    Order: the request's pose or eye/target; else the file's first camera (with its projection
    unless the request names one); else an automatic framing that looks at the scene's centre
    from the front, above and to the side, far enough for the bounding sphere to fit the
    vertical and horizontal field of view. An orthographic camera without ``ymag`` shows the
    whole bounding sphere.
    """
    params = params or CameraParams()
    lo, hi = scene_box(scene) if scene.focus is None else scene.focus
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-30)
    yfov = math.radians(params.yfov_deg)
    ymag = params.ymag
    orthographic = params.projection == "orthographic"
    if params.pose is not None:
        pose = orthonormalize_pose(np.array(params.pose), "camera")
    elif params.eye is not None:
        pose = look_at(np.array(params.eye), np.array(params.target), np.array(params.up))
    elif scene.cameras:
        cam = scene.cameras[0]
        pose = cam.pose
        if params.projection is None:  # the file's projection
            orthographic = cam.ymag is not None
            ymag = cam.ymag
            yfov = cam.yfov if cam.yfov is not None else yfov
    else:
        aspect = width / height
        half = min(yfov, 2 * math.atan(math.tan(yfov / 2) * aspect)) / 2
        dist = radius / math.sin(half) * 1.05
        direction = np.array([0.6, 0.55, 1.0])
        direction /= np.linalg.norm(direction)
        try:
            pose = look_at(centre + direction * dist, centre)
        except RequestError:
            # The scene, not the request: too small for float64 to place a camera near it.
            raise SceneError(
                f"the scene spans {2 * radius:.3g} units at {float(np.max(np.abs(centre))):.3g} "
                "units from the origin: too small there for the automatic camera to frame; "
                "give the camera's pose, or eye and target") from None
    if orthographic and ymag is None:
        ymag = _ortho_fit(pose, centre, radius, width / height)
    # Near/far follow the scene: the tightest range containing its bounding sphere, so depth
    # precision does not depend on the scene's scale or distance from the origin.
    lo, hi = scene_box(scene)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-30)
    dist_c = float(np.linalg.norm(centre - pose[:3, 3]))
    zfar = params.zfar or (dist_c + radius) * 1.01
    if params.zfar is None and params.znear is not None and zfar <= params.znear:
        # A near plane beyond the scene: the fitted far plane follows it (nothing is drawn,
        # which is what such a camera sees).
        zfar = params.znear * 2.0
    znear = params.znear or _auto_near(scene, pose[:3, 3], dist_c - radius, zfar)
    if params.znear is None and znear >= zfar:
        # A far plane before the scene: likewise.
        znear = zfar * 1e-4
    if znear >= zfar:  # both given: CameraParams refuses this already
        raise RequestError("camera znear must be smaller than zfar")
    return Camera(pose, yfov, width, height, znear, zfar, ymag if orthographic else None)


#: Margin of the automatic orthographic framing around the scene's bounding sphere.
ORTHO_FIT_MARGIN = 1.05


def _ortho_fit(pose: np.ndarray, centre: np.ndarray, radius: float, aspect: float) -> float:
    """The ``ymag`` of an orthographic camera at ``pose`` that shows the whole sphere
    (``centre``, ``radius``): its centre's offset across the view plus the radius, in both
    directions (the width is ``aspect`` times the height)."""
    x, y = (centre - pose[:3, 3]) @ pose[:3, :2]
    return max(abs(float(y)) + radius, (abs(float(x)) + radius) / aspect) * ORTHO_FIT_MARGIN
