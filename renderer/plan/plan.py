"""The render plan: what must run for this scene and request, decided before any GL work.

For every light the plan fits a shadow frustum to the casters that matter and the receivers the
camera sees (an orthographic box for directional lights, as in the packed-depth blog; an off-axis
perspective frustum for spot lights; six cube faces for point lights and very wide spots), picks
the map size, and lists the casters to draw. With ``optimize`` it also records what it leaves out
and why: objects outside the view, non-casters, casters outside a light's frustum or behind every
receiver, whole light passes and cube faces that reach nothing visible.

All positions here are relative to the scene's origin (see :class:`renderer.gpu.GpuScene`).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera, perspective, pose_from_direction
from ..lights import Light
from ..params import RenderParams
from ..scene import Scene

# Spot lights wider than this (half-angle) are shadowed with cube faces: a single perspective map
# would spend most of its texels near the frustum's edges.
MAX_SPOT_HALF_ANGLE = math.radians(60.0)
MIN_AUTO_MAP = 256
# With map_size "auto", one texel covers at most this many camera pixels on the visible receivers:
# half a pixel, so that an edge is sampled at least twice per pixel.
AUTO_TEXEL_PIXELS = 0.5

# GL cube-map faces: (forward, up) in the order +X, -X, +Y, -Y, +Z, -Z.
CUBE_FACES = (
    ((1, 0, 0), (0, -1, 0)),
    ((-1, 0, 0), (0, -1, 0)),
    ((0, 1, 0), (0, 0, 1)),
    ((0, -1, 0), (0, 0, -1)),
    ((0, 0, 1), (0, -1, 0)),
    ((0, 0, -1), (0, -1, 0)),
)


@dataclass
class LightPlan:
    """How one light is shadowed.

    Attributes
    ----------
    kind : {"ortho", "perspective", "cube"} or None
        None: no light pass (see ``reason``); the light still shades, with visibility 1.
    view : ndarray, shape (4, 4)
        World (origin-relative) to light view (2D maps).
    proj : ndarray, shape (4, 4)
    near, far : float
        Range of the linear depth stored in the map.
    size : int
        Map texels per side.
    texel : tuple of float
        World size of a texel at light depth d is ``texel[0] + texel[1] * d``.
    casters : list of int
        Scene instance indices drawn into the map.
    faces : list of int
        Cube faces rendered (cube maps only).
    face_views : list of ndarray
        View matrix of each of the 6 faces (cube maps only).
    """

    index: int
    light: Light
    position: np.ndarray
    kind: str | None = None
    reason: str | None = None
    view: np.ndarray = field(default_factory=lambda: np.eye(4))
    proj: np.ndarray = field(default_factory=lambda: np.eye(4))
    near: float = 0.0
    far: float = 1.0
    size: int = 0
    texel: tuple[float, float] = (0.0, 0.0)
    casters: list[int] = field(default_factory=list)
    faces: list[int] = field(default_factory=list)
    face_views: list[np.ndarray] = field(default_factory=list)
    skipped: Counter = field(default_factory=Counter)

    def to_dict(self) -> dict:
        d: dict = {"type": self.light.type, "shadow_map": self.kind}
        if self.kind is None:
            d["skipped_pass"] = self.reason
            return d
        d.update(
            map_size=self.size,
            casters=len(self.casters),
            skipped=dict(self.skipped),
            near=self.near,
            far=self.far,
        )
        if self.kind == "cube":
            d["faces"] = self.faces
        return d


@dataclass
class RenderPlan:
    """Everything decided before GL work; ``to_dict`` is the report given to users."""

    camera: Camera
    origin: np.ndarray
    visible: list[int]
    culled: int
    lights: list[LightPlan]
    outputs: list[str]
    optimize: bool

    @property
    def map_lights(self) -> list[LightPlan]:
        return [lp for lp in self.lights if lp.kind is not None]

    def to_dict(self) -> dict:
        return {
            "optimize": self.optimize,
            "camera_pass": {"drawn": len(self.visible), "skipped": {"outside_view": self.culled}},
            "lights": [lp.to_dict() for lp in self.lights],
            "light_passes": len(self.map_lights),
            "outputs": self.outputs,
        }


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """Corners of axis-aligned boxes: (2, 3) -> (8, 3), or (N, 2, 3) -> (N, 8, 3)."""
    b = np.asarray(bounds, np.float64)
    idx = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])
    if b.ndim == 2:
        return b[idx, [0, 1, 2]]
    return b[:, idx, [0, 1, 2]]


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def frustum_planes(view_proj: np.ndarray) -> np.ndarray:
    """Six planes (a, b, c, d), inside where a x + b y + c z + d >= 0 (Gribb-Hartmann)."""
    m = view_proj
    planes = np.array([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]])
    norms = np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
    return planes / np.maximum(norms, 1e-300)


def boxes_in_frustum(corners: np.ndarray, planes: np.ndarray,
                     frustum_corners: np.ndarray | None = None) -> np.ndarray:
    """Conservative test of boxes (N, 8, 3) against planes (P, 4): False only when surely outside.

    With the frustum's own corners (8, 3), boxes that lie wholly beyond the frustum along a world
    axis are rejected too (the plane test alone keeps large boxes near the frustum's corners).
    """
    d = corners @ planes[:, :3].T + planes[:, 3]  # (N, 8, P)
    inside = ~np.any(np.all(d < 0, axis=1), axis=1)
    if frustum_corners is not None:
        lo, hi = corners.min(axis=1), corners.max(axis=1)  # (N, 3)
        f_lo, f_hi = frustum_corners.min(axis=0), frustum_corners.max(axis=0)
        inside &= np.all((hi >= f_lo) & (lo <= f_hi), axis=1)
    return inside


def ortho(left, right, bottom, top, near, far) -> np.ndarray:
    m = np.eye(4)
    m[0, 0] = 2 / (right - left)
    m[1, 1] = 2 / (top - bottom)
    m[2, 2] = -2 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    return m


def frustum(left, right, bottom, top, near, far) -> np.ndarray:
    """Off-axis perspective projection (glFrustum) with extents given at the near plane."""
    m = np.zeros((4, 4))
    m[0, 0] = 2 * near / (right - left)
    m[1, 1] = 2 * near / (top - bottom)
    m[0, 2] = (right + left) / (right - left)
    m[1, 2] = (top + bottom) / (top - bottom)
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2 * far * near / (far - near)
    m[3, 2] = -1
    return m


def _pow2_at_least(x: float, lo: int, hi: int) -> int:
    if not np.isfinite(x) or x <= lo:
        return lo
    return int(min(hi, 2 ** math.ceil(math.log2(x))))


# --------------------------------------------------------------------------------------------
# Planning
# --------------------------------------------------------------------------------------------


class _Ctx:
    """Per-request arrays shared by the light planners."""

    def __init__(self, scene: Scene, camera: Camera, origin: np.ndarray, params: RenderParams):
        self.scene = scene
        self.camera = camera
        self.params = params
        self.optimize = params.optimize
        b = np.stack([inst.bounds for inst in scene.instances]) - origin  # (N, 2, 3)
        self.bounds = b
        self.corners = box_corners(b)  # (N, 8, 3)
        self.cast = np.array([inst.cast_shadow for inst in scene.instances])
        self.planes = _instance_planes(scene, origin)
        self.receive = np.array([inst.receive_shadow for inst in scene.instances])
        cam_pose = camera.pose.copy()
        cam_pose[:3, 3] -= origin
        self.cam_view = np.linalg.inv(cam_pose)
        self.cam_pos = cam_pose[:3, 3]
        vp = camera.projection @ self.cam_view
        fc = camera.frustum_corners() - origin
        self.frustum_corners = fc
        self.in_view = boxes_in_frustum(self.corners, frustum_planes(vp), fc)
        # World size of one camera pixel at unit distance, for automatic map sizes.
        self.pixel_per_distance = 2 * math.tan(camera.yfov / 2) / camera.height * AUTO_TEXEL_PIXELS
        shadow = params.shadows
        self.max_size = shadow.max_map_size
        self.margin_texels = (shadow.pcf_kernel // 2 if shadow.filter == "pcf" else 0) + 2

    def receivers(self) -> np.ndarray:
        """Receivers the camera sees; without ``optimize``, all receivers when it sees none
        (the map then exists but changes nothing on screen)."""
        rec = np.flatnonzero(self.in_view & self.receive)
        if len(rec) == 0 and not self.optimize:
            rec = np.flatnonzero(self.receive)
        return rec

    def map_size(self, needed: float, cube: bool = False) -> int:
        """The request's map size, or for 'auto' the power of two giving ``needed`` texels."""
        size = self.params.shadows.map_size
        if size == "auto":
            top = max(self.max_size // 2, MIN_AUTO_MAP) if cube else self.max_size
            return _pow2_at_least(needed, MIN_AUTO_MAP, top)
        return int(size)

    def receiver_distance(self, rec: np.ndarray) -> float:
        """A representative camera distance of the visible receivers (their box centre)."""
        c = self.bounds[rec].mean(axis=1)
        d = np.linalg.norm(c - self.cam_pos, axis=1)
        return float(max(np.min(d), self.camera.znear))


def _primitive_plane(prim) -> tuple[np.ndarray, np.ndarray] | None:
    """(unit normal, point) when every vertex of the primitive lies on one plane, else None."""
    cached = getattr(prim, "_plane_cache", False)
    if cached is not False:
        return cached
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
    prim._plane_cache = result
    return result


def _instance_planes(scene: Scene, origin: np.ndarray) -> list:
    """Per instance: (unit normal, point) in origin-relative world space if planar, else None."""
    out = []
    for inst in scene.instances:
        plane = _primitive_plane(scene.primitives[inst.primitive])
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


def _shadowless_planes(ctx: _Ctx, lp: LightPlan, rec: np.ndarray) -> np.ndarray:
    """Planar casters that cannot shadow any visible receiver of this light.

    A flat caster (a ground plane, a wall) separates space in two: it can shadow only what lies
    on its far side from the light. When every visible receiver but itself is on the light's
    side (or it is edge-on to a directional light), it casts onto nothing the camera sees and is
    left out of the fit and, with ``optimize``, of the light pass.
    """
    out = np.zeros(len(ctx.planes), bool)
    tol = 1e-9 * max(float(np.max(ctx.bounds[:, 1] - ctx.bounds[:, 0])), 1e-300)
    for i, plane in enumerate(ctx.planes):
        if plane is None or not ctx.cast[i]:
            continue
        n, p0 = plane
        if lp.light.type == "directional":
            facing = -float(np.dot(n, lp.light.direction))
            if abs(facing) <= 1e-12:
                out[i] = True  # edge-on: it projects to a line
                continue
        else:
            facing = float(np.dot(n, lp.position - p0))
            if abs(facing) <= tol:
                continue  # the light sits in the plane
        side = np.sign(facing)
        others = rec[rec != i]
        if len(others) == 0:
            out[i] = True
            continue
        d = (ctx.corners[others] - p0) @ (n * side)  # (R, 8): >= 0 on the light's side
        out[i] = bool(np.all(d >= -tol))
    return out


def make_plan(
    scene: Scene,
    camera: Camera,
    lights: list[Light],
    origin: np.ndarray,
    params: RenderParams,
) -> RenderPlan:
    """Decide the passes, frusta, map sizes and draw lists of one render.

    Limits are checked before planning (:mod:`~shadowmap.renderer.limits`).
    """
    ctx = _Ctx(scene, camera, origin, params)
    n = len(scene.instances)
    if params.optimize:
        visible = [int(i) for i in np.flatnonzero(ctx.in_view)]
    else:
        visible = list(range(n))
    plans = []
    for i, light in enumerate(lights):
        lp = LightPlan(index=i, light=light, position=light.position - origin)
        if not light.cast_shadows:
            lp.reason = "cast_shadows_false"
        elif not ctx.cast.any():
            lp.reason = "no_caster"
        elif light.type == "directional":
            _plan_directional(ctx, lp)
        elif light.type == "spot" and light.outer_cone <= MAX_SPOT_HALF_ANGLE:
            _plan_spot(ctx, lp)
        else:
            _plan_cube(ctx, lp)
        plans.append(lp)
    return RenderPlan(
        camera=camera,
        origin=origin,
        visible=visible,
        culled=n - len(visible),
        lights=plans,
        outputs=list(params.outputs),
        optimize=params.optimize,
    )


def _select_casters(ctx: _Ctx, lp: LightPlan, in_frustum: np.ndarray, depth_min: np.ndarray,
                    far: float, shadowless: np.ndarray) -> np.ndarray:
    """Casters that can shadow a receiver, counting the others by reason; returns their indices.

    Without ``optimize`` every caster is drawn; the frustum is fitted the same way either way, so
    the maps agree where it matters (what is skipped rasterises nothing, lies beyond the far
    plane, or is a plane that only its own lit side sees).
    """
    relevant = ctx.cast & in_frustum & (depth_min <= far) & ~shadowless
    if ctx.optimize:
        lp.skipped["non_caster"] = int((~ctx.cast).sum())
        lp.skipped["outside_frustum"] = int((ctx.cast & ~in_frustum).sum())
        lp.skipped["behind_receivers"] = int((ctx.cast & in_frustum & (depth_min > far)).sum())
        lp.skipped["plane_facing_receivers"] = int(
            (ctx.cast & in_frustum & (depth_min <= far) & shadowless).sum())
        lp.skipped = Counter({k: v for k, v in lp.skipped.items() if v})
        return np.flatnonzero(relevant)
    lp.skipped["non_caster"] = int((~ctx.cast).sum())
    lp.skipped = Counter({k: v for k, v in lp.skipped.items() if v})
    return np.flatnonzero(ctx.cast)


def _casters_and_fit(ctx: _Ctx, lp: LightPlan, rec: np.ndarray, in_frustum: np.ndarray,
                     depth_min: np.ndarray, far: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(casters to draw, casters the frustum is fitted to); None, with the reason recorded,
    when nothing can cast onto a visible receiver."""
    shadowless = _shadowless_planes(ctx, lp, rec)
    casters = _select_casters(ctx, lp, in_frustum, depth_min, far, shadowless)
    fit = ctx.cast & in_frustum & (depth_min <= far) & ~shadowless
    if not fit.any():
        lp.reason = "no_caster_in_frustum"
        return None
    return casters, fit


def _plan_directional(ctx: _Ctx, lp: LightPlan) -> None:
    rec = ctx.receivers()
    if len(rec) == 0:
        lp.reason = "no_visible_receiver"
        return
    pose = pose_from_direction(np.zeros(3), lp.light.direction)
    view = np.linalg.inv(pose)
    lc = transform_points(view, ctx.corners)  # (N, 8, 3) light view
    lo = lc.min(axis=1)
    hi = lc.max(axis=1)
    # Lateral region: the visible receivers, clipped to what the camera frustum can show.
    r_lo, r_hi = lo[rec].min(axis=0), hi[rec].max(axis=0)
    f = transform_points(view, ctx.frustum_corners)
    x0, y0 = np.maximum(r_lo[:2], f.min(axis=0)[:2])
    x1, y1 = np.minimum(r_hi[:2], f.max(axis=0)[:2])
    if x1 <= x0 or y1 <= y0:
        x0, y0 = r_lo[:2]
        x1, y1 = r_hi[:2]
    # Receiver depth range (light depth is -z), no deeper than the camera can see.
    rec_far = float(min(-r_lo[2], -f.min(axis=0)[2]))
    in_frustum = (hi[:, 0] >= x0) & (lo[:, 0] <= x1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1)
    depth_min = -hi[:, 2]
    chosen = _casters_and_fit(ctx, lp, rec, in_frustum, depth_min, rec_far)
    if chosen is None:
        return
    casters, fit = chosen
    # A directional shadow falls straight along the light: only where casters are, laterally.
    x0, y0 = np.maximum([x0, y0], lo[fit, :2].min(axis=0))
    x1, y1 = np.minimum([x1, y1], hi[fit, :2].max(axis=0))
    if x1 <= x0 or y1 <= y0:
        lp.reason = "no_caster_in_frustum"
        return
    near = float(depth_min[fit].min())
    far = rec_far
    extent = max(x1 - x0, y1 - y0, 1e-300)
    # Auto size: one texel no larger than a camera pixel at the receivers' distance.
    pixel = ctx.pixel_per_distance * ctx.receiver_distance(rec)
    size = ctx.map_size(extent / max(pixel, 1e-300))
    # Margin: PCF taps and the normal offset may read a few texels beyond the receivers.
    pad = extent / size * ctx.margin_texels
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    span = max(far - near, 1e-300)
    near, far = near - span * 1e-3, far + span * 1e-3
    lp.kind = "ortho"
    lp.view, lp.proj = view, ortho(x0, x1, y0, y1, near, far)
    lp.near, lp.far, lp.size = near, far, size
    lp.texel = (max(x1 - x0, y1 - y0) / size, 0.0)
    lp.casters = [int(i) for i in casters]


def _plan_spot(ctx: _Ctx, lp: LightPlan) -> None:
    rec = ctx.receivers()
    if len(rec) == 0:
        lp.reason = "no_visible_receiver"
        return
    pose = pose_from_direction(lp.position, lp.light.direction)
    view = np.linalg.inv(pose)
    lc = transform_points(view, ctx.corners)
    depth = -lc[..., 2]  # (N, 8)
    tan_cone = math.tan(lp.light.outer_cone)
    # Receivers inside the cone's bounding pyramid: fit the frustum to their angular extent.
    rc = lc[rec].reshape(-1, 3)
    front = -rc[:, 2] > 0
    rec_far = float(depth[rec].max())
    if rec_far <= 0:
        lp.reason = "no_visible_receiver"
        return
    if front.all():
        ang = rc[:, :2] / (-rc[:, 2:3])
        a_lo = np.maximum(ang.min(axis=0), -tan_cone)
        a_hi = np.minimum(ang.max(axis=0), tan_cone)
    else:  # a receiver straddles the light's plane: cover the whole cone
        a_lo = np.array([-tan_cone, -tan_cone])
        a_hi = np.array([tan_cone, tan_cone])
    if np.any(a_hi <= a_lo):
        lp.reason = "no_visible_receiver"
        return
    # Casters inside the fitted pyramid (conservative: boxes against its four side planes).
    planes = _pyramid_planes(a_lo, a_hi)
    in_frustum = boxes_in_frustum(lc, planes)
    depth_min = np.where(
        np.all(depth > 0, axis=1), depth.min(axis=1), 0.0
    )
    chosen = _casters_and_fit(ctx, lp, rec, in_frustum, depth_min, rec_far)
    if chosen is None:
        return
    casters, fit = chosen
    # Shadows lie within the casters' angular extent, when all of them are in front of the light.
    cc = lc[fit].reshape(-1, 3)
    if np.all(-cc[:, 2] > 0):
        ang = cc[:, :2] / (-cc[:, 2:3])
        a_lo = np.maximum(a_lo, ang.min(axis=0))
        a_hi = np.minimum(a_hi, ang.max(axis=0))
        if np.any(a_hi <= a_lo):
            lp.reason = "no_caster_in_frustum"
            return
    far = rec_far * 1.001
    near = float(max(depth_min[fit].min() * 0.999, far * 1e-5))
    extent = float(max(a_hi[0] - a_lo[0], a_hi[1] - a_lo[1]))
    pixel = ctx.pixel_per_distance * ctx.receiver_distance(rec)
    d_light = float(np.median(depth[rec].mean(axis=1).clip(min=near)))
    size = ctx.map_size(extent * d_light / max(pixel, 1e-300))
    pad = extent / size * ctx.margin_texels
    a_lo, a_hi = a_lo - pad, a_hi + pad
    lp.kind = "perspective"
    lp.view = view
    lp.proj = frustum(a_lo[0] * near, a_hi[0] * near, a_lo[1] * near, a_hi[1] * near, near, far)
    lp.near, lp.far, lp.size = near, far, size
    lp.texel = (0.0, float(max(a_hi - a_lo)) / size)
    lp.casters = [int(i) for i in casters]


def _pyramid_planes(a_lo: np.ndarray, a_hi: np.ndarray) -> np.ndarray:
    """Planes of the pyramid x/(-z) in [a_lo.x, a_hi.x], y/(-z) in [a_lo.y, a_hi.y], z <= 0."""
    return np.array(
        [
            [1.0, 0.0, a_lo[0], 0.0],  # x >= a_lo.x * (-z)
            [-1.0, 0.0, -a_hi[0], 0.0],
            [0.0, 1.0, a_lo[1], 0.0],
            [0.0, -1.0, -a_hi[1], 0.0],
            [0.0, 0.0, -1.0, 0.0],  # in front of the light
        ]
    )


def _plan_cube(ctx: _Ctx, lp: LightPlan) -> None:
    rec = ctx.receivers()
    if len(rec) == 0:
        lp.reason = "no_visible_receiver"
        return
    rel = ctx.corners - lp.position  # (N, 8, 3)
    cheb = np.abs(rel).max(axis=2)
    # Chebyshev distance from the light to each box (0 when the light is inside it).
    gap = np.maximum(np.maximum(ctx.bounds[:, 0] - lp.position, lp.position - ctx.bounds[:, 1]), 0)
    near_dist = gap.max(axis=1)
    rec_far = float(cheb[rec].max()) * 1.001
    face_views = []
    used_faces = []
    caster_mask = np.zeros(len(ctx.corners), bool)
    cone_cos = math.cos(lp.light.outer_cone) if lp.light.type == "spot" else -1.0
    for f, (fwd, up) in enumerate(CUBE_FACES):
        pose = np.eye(4)
        z = -np.array(fwd, np.float64)
        y = np.array(up, np.float64)
        x = np.cross(y, z)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, lp.position
        view = np.linalg.inv(pose)
        face_views.append(view)
        lc = transform_points(view, ctx.corners)
        planes = _pyramid_planes(np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
        inside = boxes_in_frustum(lc, planes)
        if lp.light.type == "spot" and not _face_meets_cone(np.array(fwd, float), lp.light, cone_cos):
            continue
        if ctx.optimize and not (inside & ctx.in_view & ctx.receive).any():
            lp.skipped["faces_without_receivers"] += 1
            continue
        used_faces.append(f)
        caster_mask |= inside
    if not used_faces:
        lp.reason = "no_visible_receiver"
        return
    chosen = _casters_and_fit(ctx, lp, rec, caster_mask, near_dist, rec_far)
    if chosen is None:
        return
    casters, fit = chosen
    far = rec_far
    near = float(max(near_dist[fit].min() * 0.999, far * 1e-5))
    pixel = ctx.pixel_per_distance * ctx.receiver_distance(rec)
    d_light = float(np.median(cheb[rec].mean(axis=1).clip(min=near)))
    # Six faces: an automatic size stops one power of two below the 2D maximum.
    size = ctx.map_size(2 * d_light / max(pixel, 1e-300), cube=True)
    lp.kind = "cube"
    lp.face_views = face_views
    lp.faces = used_faces
    lp.proj = perspective(math.pi / 2, 1.0, near, far)
    lp.near, lp.far, lp.size = near, far, size
    lp.texel = (0.0, 2.0 / size)
    lp.casters = [int(i) for i in casters]


def _face_meets_cone(forward: np.ndarray, light: Light, cone_cos: float) -> bool:
    """Whether a 90-degree cube face overlaps a spot cone (angle between axes < cone + 54.7°)."""
    face_half_diag = math.acos(1 / math.sqrt(3))
    angle = math.acos(float(np.clip(np.dot(forward, light.direction), -1, 1)))
    return angle < math.acos(max(min(cone_cos, 1.0), -1.0)) + face_half_diag
