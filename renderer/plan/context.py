"""The per-request arrays every light fit reads: instance boxes, flags, planes, the camera's view.

Built once per request and read-only afterwards (its arrays are locked against writes), so a fit
cannot change what the next light sees. What depends only on the scene (boxes, flags, planes, and
the boxes relative to the upload's origin) comes from :func:`.instances.scene_arrays`, read once
per scene; only the camera's view test is computed per request, over all instances at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .culling import boxes_in_view
from .instances import Planes, scene_arrays

if TYPE_CHECKING:  # the camera imports this package: types only, no import cycle
    from ..camera import Camera
    from ..params import RenderParams
    from ..scene import Scene

MIN_AUTO_MAP = 256
# With map_size "auto", one texel covers at most this many camera pixels on the visible receivers:
# half a pixel, so that an edge is sampled at least twice per pixel.
AUTO_TEXEL_PIXELS = 0.5


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _pow2_at_least(x: float, lo: int, hi: int) -> int:
    """The smallest power of two >= ``x``, within [lo, hi] (lo for non-finite ``x``)."""
    if not np.isfinite(x) or x <= lo:
        return lo
    return int(min(hi, 2 ** math.ceil(math.log2(x))))


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
    cam_pos : ndarray, shape (3,)
    frustum_corners : ndarray, shape (8, 3)
        The camera's view frustum.
    pixel_per_distance : float
        World size of one camera pixel at unit distance, times :data:`AUTO_TEXEL_PIXELS`.
    max_size : int
        Largest map side allowed.
    margin_texels : int
        Texels a map reaches beyond the receivers: PCF taps and the normal offset read there.
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
    cam_pos: np.ndarray
    frustum_corners: np.ndarray
    pixel_per_distance: float
    max_size: int
    margin_texels: int

    @classmethod
    def build(cls, scene: Scene, camera: Camera, origin: np.ndarray,
              params: RenderParams) -> PlanContext:
        """The context of one request (reads its inputs, changes none of them)."""
        origin = np.array(origin, np.float64)
        arrays = scene_arrays(scene)  # shared by every request on this scene: read-only
        rel = arrays.relative(origin)
        shadow = params.shadows
        return cls(
            camera=camera,
            params=params,
            origin=_frozen(origin),
            bounds=rel.bounds,
            corners=rel.corners,
            centres=rel.centres,
            cast=arrays.cast,
            receive=arrays.receive,
            planes=rel.planes,
            extent=rel.extent,
            in_view=_frozen(boxes_in_view(rel.bounds, camera, origin)),
            cam_pos=_frozen(camera.pose[:3, 3] - origin),
            frustum_corners=_frozen(camera.frustum_corners() - origin),
            pixel_per_distance=2 * math.tan(camera.yfov / 2) / camera.height * AUTO_TEXEL_PIXELS,
            max_size=shadow.max_map_size,
            margin_texels=(shadow.pcf_kernel // 2 if shadow.filter == "pcf" else 0) + 2,
        )

    @property
    def optimize(self) -> bool:
        return self.params.optimize

    def receivers(self) -> np.ndarray:
        """Indices (R,) of the receivers the camera sees.

        Without ``optimize``, all receivers when it sees none (the map then exists but changes
        nothing on screen).
        """
        rec = np.flatnonzero(self.in_view & self.receive)
        if len(rec) == 0 and not self.optimize:
            rec = np.flatnonzero(self.receive)
        return rec

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

    def map_size_for(self, world: float, receivers: np.ndarray, cube: bool = False) -> int:
        """Map size for a map side spanning ``world`` units at the receivers' distance.

        With 'auto', one texel is no larger than :data:`AUTO_TEXEL_PIXELS` camera pixels there.
        """
        pixel = self.pixel_per_distance * self.receiver_distance(receivers)
        return self.map_size(world / max(pixel, 1e-300), cube)

    def margin(self, extent: float, size: int) -> float:
        """Padding of a map side ``extent`` wide, in the same unit: PCF taps and the normal offset
        may read a few texels beyond the receivers."""
        return extent / size * self.margin_texels

    def receiver_distance(self, receivers: np.ndarray) -> float:
        """A representative camera distance of the receivers: the nearest box centre."""
        d = np.linalg.norm(self.centres[receivers] - self.cam_pos, axis=1)
        return float(max(np.min(d), self.camera.znear))
