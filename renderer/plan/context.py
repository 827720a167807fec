"""The per-request arrays every light fit reads: instance boxes, flags, planes, the camera's view.

Built once per request and read-only afterwards (its arrays are locked against writes), so a fit
cannot change what the next light sees. What depends only on the scene (boxes, flags, planes, and
the boxes relative to the upload's origin) comes from :func:`.instances.scene_arrays`, read once
per scene; only the camera's view test and what it sees of the receivers (:class:`Seen`) are
computed per request, over all instances at once.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .culling import view_planes
from .geometry import aabbs_against_frustum, clip_boxes, row_norm, texel_stretch
from .instances import Planes, SceneArrays, scene_arrays

if TYPE_CHECKING:  # the camera imports this package: types only, no import cycle
    from ..camera import Camera
    from ..params import RenderParams
    from ..scene import Scene

MIN_AUTO_MAP = 256
# With map_size "auto", one texel covers at most this many camera pixels on the visible receivers:
# half a pixel, so that an edge is sampled at least twice per pixel.
AUTO_TEXEL_PIXELS = 0.5
# A flat face lit at a grazing angle stretches each texel across it (geometry.texel_stretch):
# 'auto' then wants its texel no longer than one camera pixel along the stretch (the half pixel
# above is the target where nothing stretches), up to this many times finer than for the nearest
# receiver: one power of two, as the next would cost four times the light pass again.
MAX_TEXEL_STRETCH = 2.0
# Receivers whose faces are weighed for the stretch: the nearest ones that could need it.
MAX_STRETCH_RECEIVERS = 256


@dataclass(frozen=True)
class Toward:
    """Where a light is, seen from the receivers: ``vector`` is the unit direction toward a
    directional light (``positional`` False) or a positional light's origin-relative position."""

    vector: np.ndarray
    positional: bool

    def at(self, points: np.ndarray) -> np.ndarray:
        """Unit directions toward the light from ``points`` (M, 3); zero at the light itself."""
        if not self.positional:
            return np.broadcast_to(self.vector, points.shape)
        d = self.vector - points
        length = row_norm(d)[:, None]
        return np.divide(d, length, out=np.zeros_like(d), where=length > 0)


@dataclass(frozen=True)
class SizeRead:
    """One :meth:`PlanContext.map_size_and_need` call of a scene-fit light's plan: its arguments
    and the size it gave, which another view must get again to share the plan
    (:meth:`.plan.SceneFitPlan.refit`). ``stretch``: the any-view stretch the call found, where
    no camera changes it (see :meth:`PlanContext._distance_and_stretch`), else None."""

    world: float
    receivers: np.ndarray
    cube: bool
    toward: Toward | None
    size: int
    stretch: float | None


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _pow2_at_least(x: float, lo: int, hi: int) -> int:
    """The smallest power of two >= ``x``, within [lo, hi] (lo for non-finite ``x``)."""
    if not np.isfinite(x) or x <= lo:
        return lo
    return int(min(hi, 2 ** math.ceil(math.log2(x))))


#: The outputs a shadow shows in: the colour, the visibility, and the light's own depth map.
SHADOW_OUTPUTS = frozenset({"color", "visibility", "light_depth"})
#: The outputs the camera pass draws for.
CAMERA_OUTPUTS = frozenset({"color", "visibility", "depth"})


def camera_mode(params: RenderParams) -> str:
    """What the camera pass draws for the request's outputs: ``"shaded"`` (the colour asked:
    lights, shadows, materials), ``"visibility"`` (visibility without colour: the shadow lookups
    alone, no shading and no blended surfaces, which write no visibility), ``"depth"`` (only the
    depth among the camera's outputs: no lookups either, no blended surfaces, which write no
    depth) or ``"none"`` (only the light's depth maps: no camera pass). The alpha cut-out
    discards in each. Without ``optimize`` it always shades."""
    asked = CAMERA_OUTPUTS.intersection(params.outputs)
    if not params.optimize or "color" in asked:
        return "shaded"
    if "visibility" in asked:
        return "visibility"
    return "depth" if asked else "none"


def shown_receivers(arrays: SceneArrays, params: RenderParams) -> np.ndarray:
    """The receivers whose shadows the request shows (N,) bool: every receiving instance, but
    for those of unlit materials (``KHR_materials_unlit``, whose colour shows no shadow) when no
    ``visibility`` output asks for their shadows and no ``light_depth`` output for the maps
    themselves (fitted as they would be with ``visibility``). Maps are fitted to these alone."""
    if not arrays.unlit.any() or {"visibility", "light_depth"}.intersection(params.outputs):
        return arrays.receive
    return _frozen(arrays.receive & ~arrays.unlit)


def _visible_receivers(in_view: np.ndarray, receive: np.ndarray, optimize: bool) -> np.ndarray:
    """Indices of the receivers the camera may see; without ``optimize``, all receivers when it
    sees none."""
    rec = np.flatnonzero(in_view & receive)
    if len(rec) == 0 and not optimize:
        rec = np.flatnonzero(receive)
    return rec


class Seen:
    """What the camera can see of its receivers: the parts of their boxes inside its frustum.

    A shadow map need cover only these parts: every receiver point drawn by the camera pass lies
    in one. Their extent along any direction (a light's lateral window, its deepest receiver) and
    the extremes of a point's slopes or Chebyshev distance from a light are reached at the boxes
    of ``whole`` or at ``points`` (:func:`.geometry.clip_boxes`).

    Made by :meth:`clip`, the parts are clipped when first read: only a light fitted to the view
    reads them, so a request whose lights cast no shadow, or whose maps cover every receiver
    (``shadows.fit: "scene"``), never clips.

    Attributes
    ----------
    whole : ndarray, shape (W,), int
        Receivers whose whole box lies inside the frustum; when the camera sees no part of any
        receiver (its view test is conservative), every receiver that matters, as a fallback.
    points : ndarray, shape (M, 3)
        The vertices of the other receivers' boxes clipped to the frustum (origin-relative).
    """

    __slots__ = ("_clip_args", "_parts")

    def __init__(self, whole: np.ndarray, points: np.ndarray) -> None:
        self._parts: tuple[np.ndarray, np.ndarray] | None = (whole, points)
        self._clip_args: tuple[np.ndarray, ...] | None = None

    @classmethod
    def clip(cls, bounds: np.ndarray, receivers: np.ndarray, whole: np.ndarray,
             planes: np.ndarray, frustum_corners: np.ndarray) -> Seen:
        """The receivers' boxes clipped to the view frustum (``planes``, ``frustum_corners``);
        ``whole`` (N,) marks the boxes wholly inside it. The arguments are read-only; the clip
        runs on the first read of :attr:`whole` or :attr:`points`."""
        seen = cls.__new__(cls)
        seen._parts = None
        seen._clip_args = (bounds, receivers, whole, planes, frustum_corners)
        return seen

    def _get(self) -> tuple[np.ndarray, np.ndarray]:
        if self._parts is None:
            assert self._clip_args is not None
            self._parts = _clip_seen(*self._clip_args)
            self._clip_args = None
        return self._parts

    @property
    def whole(self) -> np.ndarray:
        return self._get()[0]

    @property
    def points(self) -> np.ndarray:
        return self._get()[1]


def _clip_seen(bounds: np.ndarray, receivers: np.ndarray, whole: np.ndarray, planes: np.ndarray,
               frustum_corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Seen.clip`'s work: (whole, points)."""
    inside = whole[receivers]
    boxes = bounds[receivers[~inside]]
    # Rounding tolerance: a part may come out larger by a billionth of the view's span.
    scale = max(float(np.max(np.abs(frustum_corners))),
                float(np.max(np.abs(boxes), initial=0.0)))
    points = clip_boxes(boxes, planes, frustum_corners, 1e-9 * scale)
    if not inside.any() and len(points) == 0:
        inside = np.ones(len(receivers), bool)
    return _frozen(receivers[inside]), _frozen(points)


@dataclass(frozen=True)
class PlanContext:
    """What one request's light fits share; positions relative to ``origin``.

    Attributes
    ----------
    camera : Camera
    params : RenderParams
    origin : ndarray, shape (3,)
    bounds : ndarray, shape (N, 2, 3)
        Instance boxes (min, max corner).
    corners : ndarray, shape (N, 8, 3)
    centres : ndarray, shape (N, 3)
        Box centres.
    cast, receive : ndarray, shape (N,), bool
        The instances' cast and receive flags.
    planes : Planes
        The flat instances' unit normals and points (origin-relative).
    extent : float
        The largest side of any instance box.
    in_view : ndarray, shape (N,), bool
        Boxes the camera may see.
    seen : Seen
        What the camera sees of the receivers of :meth:`receivers`.
    cam_pos : ndarray, shape (3,)
    frustum_corners : ndarray, shape (8, 3)
        The camera's view frustum.
    pixel_per_distance : float
        World size of one camera pixel at unit distance, times :data:`AUTO_TEXEL_PIXELS`: a
        pixel at camera distance d is ``pixel_per_distance * view_distance(d)`` wide.
    max_size : int
        Largest map side allowed.
    margin_texels : int
        Texels a map reaches beyond the receivers: PCF taps and the normal offset read there.
    texel_distance : float or None
        The camera distance at which automatic map sizes give their texel size; None: the
        nearest receiver box's centre (:meth:`receiver_distance`). A cascade's context sets its
        slice's near distance.
    """

    camera: Camera
    params: RenderParams
    origin: np.ndarray
    bounds: np.ndarray
    corners: np.ndarray
    centres: np.ndarray
    cast: np.ndarray
    receive: np.ndarray
    planes: Planes
    extent: float
    in_view: np.ndarray
    seen: Seen
    cam_pos: np.ndarray
    frustum_corners: np.ndarray
    pixel_per_distance: float
    max_size: int
    margin_texels: int
    texel_distance: float | None = None
    #: An orthographic camera's pixels are the same size at every distance: the distances that
    #: size texels all count as this one (:meth:`view_distance`). None: perspective.
    flat_distance: float | None = None
    #: Where given, every :meth:`map_size_for` call appends its :class:`SizeRead`: what a
    #: scene-fit light's plan read of the camera (see :func:`.plan.scene_fit_key`).
    sizes_read: list[SizeRead] | None = None
    #: The scene's instance arrays, for the faces of the receivers (:meth:`receiver_distance`).
    arrays: SceneArrays | None = None
    #: Weigh the receivers' faces as any view could see them, not as this camera does (a map
    #: shared by every view: ``shadows.fit: "scene"``).
    any_view: bool = False

    @classmethod
    def build(cls, scene: Scene, camera: Camera, origin: np.ndarray,
              params: RenderParams) -> PlanContext:
        """The context of one request (reads its inputs, changes none of them)."""
        origin = np.array(origin, np.float64)
        arrays = scene_arrays(scene)  # shared by every request on this scene: read-only
        rel = arrays.relative(origin)
        shadow = params.shadows
        planes = view_planes(camera, origin)
        frustum_corners = _frozen(camera.frustum_corners(origin))
        in_view, whole = aabbs_against_frustum(rel.bounds, planes, frustum_corners)
        flat = camera.zfar if camera.orthographic else None
        receive = shown_receivers(arrays, params)
        receivers = _visible_receivers(in_view, receive, params.optimize)
        return cls(
            camera=camera,
            params=params,
            origin=_frozen(origin),
            bounds=rel.bounds,
            corners=rel.corners,
            centres=rel.centres,
            cast=arrays.cast,
            receive=receive,
            planes=rel.planes,
            extent=rel.extent,
            in_view=_frozen(in_view),
            seen=Seen.clip(rel.bounds, receivers, whole, planes, frustum_corners),
            cam_pos=_frozen(camera.pose[:3, 3] - origin),
            frustum_corners=frustum_corners,
            pixel_per_distance=float(camera.pixel_size(flat or 1.0)) / (flat or 1.0)
            * AUTO_TEXEL_PIXELS,
            flat_distance=flat,
            max_size=shadow.max_map_size,
            margin_texels=(shadow.pcf_kernel // 2 if shadow.filter == "pcf" else 0) + 2,
            arrays=arrays,
        )

    def scene_fit(self) -> PlanContext:
        """This context for maps that cover every receiver (``shadows.fit: "scene"``).

        The light fits then read no part of the camera's view: every receiver counts as seen,
        whole, so a light's map depends on the scene and the light alone (its 'auto' size still
        follows the camera's resolution, :meth:`map_size_for`) and one light pass serves every
        view. The camera pass keeps the view test of this context.
        """
        receivers = np.flatnonzero(self.receive)
        return dataclasses.replace(
            self,
            in_view=_frozen(np.ones(len(self.receive), bool)),
            seen=Seen(whole=_frozen(receivers), points=_frozen(np.zeros((0, 3)))),
            any_view=True,
        )

    @property
    def optimize(self) -> bool:
        return self.params.optimize

    def receivers(self) -> np.ndarray:
        """Indices (R,) of the receivers the camera sees.

        Without ``optimize``, all receivers when it sees none (the map then exists but changes
        nothing on screen).
        """
        return _visible_receivers(self.in_view, self.receive, self.optimize)

    def map_size(self, needed: float, cube: bool = False) -> int:
        """The request's map size, or for 'auto' the power of two giving ``needed`` texels.

        Six cube faces cost six maps: an automatic cube size stops one power of two below the
        2D maximum.
        """
        size = self.params.shadows.map_size
        if size == "auto":
            top = max(self.max_size // 2, MIN_AUTO_MAP) if cube else self.max_size
            return _pow2_at_least(needed, MIN_AUTO_MAP, top)
        return int(size)

    def map_size_for(self, world: float, receivers: np.ndarray, cube: bool = False,
                     toward: Toward | None = None) -> int:
        """Map size for a map side spanning ``world`` units at the receivers' distance.

        With 'auto', one texel is no larger than :data:`AUTO_TEXEL_PIXELS` camera pixels there,
        and (given where the light is) no longer than one pixel across the grazing-lit flat
        faces of the receivers (:meth:`receiver_distance`).
        """
        return self.map_size_and_need(world, receivers, cube, toward)[0]

    def map_size_and_need(self, world: float, receivers: np.ndarray, cube: bool = False,
                          toward: Toward | None = None, stretch: float | None = None
                          ) -> tuple[int, float]:
        """:meth:`map_size_for`, and the texels per side the same receivers want at one camera
        pixel per texel (what 'auto' would give them but for ``max_map_size``: the plan warns
        when that is over the limit, :func:`~.plan._resolution_warning`). ``stretch``: see
        :meth:`_distance_and_stretch`."""
        distance, stretch = self._distance_and_stretch(receivers, toward, stretch)
        pixel = self.pixel_per_distance * distance
        wanted = world / max(pixel, 1e-300)
        size = self.map_size(wanted, cube)
        if self.sizes_read is not None:
            self.sizes_read.append(SizeRead(world, receivers, cube, toward, size, stretch))
        return size, wanted * AUTO_TEXEL_PIXELS

    def margin(self, extent: float, size: int) -> float:
        """Padding of a map side ``extent`` wide, in the same unit: PCF taps and the normal offset
        may read a few texels beyond the receivers."""
        return extent / size * self.margin_texels

    def view_distance(self, d: np.ndarray | float) -> np.ndarray:
        """Camera distances ``d`` as the texel sizes see them (same shape, float64): themselves
        in perspective, :attr:`flat_distance` each in an orthographic view (its pixels are the
        same size at every distance)."""
        d = np.asarray(d, np.float64)
        if self.flat_distance is None:
            return d
        return np.full_like(d, self.flat_distance)

    def receiver_distance(self, receivers: np.ndarray, toward: Toward | None = None) -> float:
        """A representative camera distance of the receivers: the nearest box centre, or nearer
        where a light ``toward`` stretches its texels over their flat faces.

        A receiver at distance d whose flat patch (:func:`.instances.primitive_patches`) shows
        a texel k times longer than wide (:func:`.geometry.texel_stretch`) wants the texel size
        of distance d / (k x AUTO_TEXEL_PIXELS), capped at :data:`MAX_TEXEL_STRETCH` times
        finer than d; only the :data:`MAX_STRETCH_RECEIVERS` nearest receivers that could ask
        for more than the nearest one are weighed (vectorised, a few per primitive). With
        :attr:`any_view`, the nearest distance over the largest k of the (nearest
        :data:`MAX_STRETCH_RECEIVERS`) receivers, k the most any view could see (1 / cos of the
        light's angle to the face).
        """
        return self._distance_and_stretch(receivers, toward, None)[0]

    def _distance_and_stretch(self, receivers: np.ndarray, toward: Toward | None,
                              stretch: float | None) -> tuple[float, float | None]:
        """:meth:`receiver_distance`, and the any-view stretch it divided by where that does not
        depend on the camera (else None).

        With :attr:`any_view` and at most :data:`MAX_STRETCH_RECEIVERS` receivers, the nearest
        distance is divided by a stretch that no camera changes: ``stretch``, where given, is
        that divisor as an earlier view of the same receivers and light found it
        (:class:`SizeRead`), and is not worked out again."""
        if self.texel_distance is not None:
            return float(self.view_distance(self.texel_distance)), None
        d = self.view_distance(row_norm(self.centres[receivers] - self.cam_pos))
        near = float(max(np.min(d), self.camera.znear))
        if toward is None or self.arrays is None:
            return near, None
        receivers = np.asarray(receivers)
        if self.any_view:
            # A map every view shares weighs every receiver the same, as any view could see it:
            # its size then follows the camera only by the nearest distance, as without faces.
            if len(d) <= MAX_STRETCH_RECEIVERS:
                if stretch is None:
                    stretch = self._any_view_stretch(receivers, toward)
                return near / stretch, stretch
            nearest = np.argpartition(d, MAX_STRETCH_RECEIVERS - 1)[:MAX_STRETCH_RECEIVERS]
            return near / self._any_view_stretch(receivers[nearest], toward), None
        cand = np.flatnonzero(d < near * MAX_TEXEL_STRETCH)
        if len(cand) > MAX_STRETCH_RECEIVERS:
            cand = cand[np.argpartition(d[cand], MAX_STRETCH_RECEIVERS - 1)
                        [:MAX_STRETCH_RECEIVERS]]
        idx = receivers[cand]
        owner, normal = self.arrays.patch_normals(idx)
        if len(owner) == 0:
            return near, None
        centre = self.centres[idx][owner]
        # The direction pixels look along: from the eye, or the view axis (orthographic).
        view = (centre - self.cam_pos if self.flat_distance is None
                else np.broadcast_to(self.camera.forward, centre.shape))
        length = row_norm(view)
        ok = length > 0
        if not ok.any():
            return near, None
        view = view[ok] / length[ok, None]
        k = texel_stretch(normal[ok], toward.at(centre[ok]), view)
        k = np.clip(k * AUTO_TEXEL_PIXELS, 1.0, MAX_TEXEL_STRETCH)
        dist = np.maximum(d[cand][owner][ok], self.camera.znear) / k
        return float(min(near, dist.min())), None

    def _any_view_stretch(self, idx: np.ndarray, toward: Toward) -> float:
        """The most any view sees a texel stretched on the flat faces of instances ``idx`` (K,),
        as a divisor of their nearest distance: 1 / cos of the light's angle to a face, times
        :data:`AUTO_TEXEL_PIXELS`, held to [1, :data:`MAX_TEXEL_STRETCH`]; 1 without faces."""
        assert self.arrays is not None
        owner, normal = self.arrays.patch_normals(idx)
        if len(owner) == 0:
            return 1.0
        k = texel_stretch(normal, toward.at(self.centres[idx][owner]), None)
        return float(np.clip(k.max() * AUTO_TEXEL_PIXELS, 1.0, MAX_TEXEL_STRETCH))
