"""Resolving lights: from request parameters or the file's ``KHR_lights_punctual`` to world vectors.

The light frusta themselves (which depend on what the camera sees) are fitted in
:mod:`renderer.plan`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .camera import orthonormalize_pose
from .errors import RequestError
from .params import DirectionalLight, LightParams
from .plan.instances import scene_box  # Scene.bounds, read once per scene
from .scene import Scene

DEFAULT_DIRECTION = np.array([-0.5, -1.0, 0.2])


@dataclass(frozen=True)
class Light:
    """A resolved light in world space.

    Attributes
    ----------
    type : {"directional", "spot", "point"}
    position : ndarray, shape (3,), float64
        Spot and point lights; for a directional light a point on its axis (unused).
    direction : ndarray, shape (3,), float64
        Unit vector the light travels along (directional, spot); ``[0, 0, -1]`` for point lights.
    color : ndarray, shape (3,)
    intensity : float
    inner_cone, outer_cone : float
        Spot half-angles in radians.
    range : float or None
        Spot/point cut-off distance (glTF's smooth window); None means unlimited.
    cast_shadows : bool
    """

    type: str
    position: np.ndarray
    direction: np.ndarray
    color: np.ndarray
    intensity: float = 1.0
    inner_cone: float = 0.0
    outer_cone: float = math.pi / 6
    range: float | None = None
    cast_shadows: bool = True

    def __post_init__(self) -> None:
        # Read-only float64 copies: a resolved light is shared by a repeated request's cached
        # preparation and by the results handed out (RenderResult.lights).
        for name in ("position", "direction", "color"):
            a = np.array(getattr(self, name), np.float64)
            a.flags.writeable = False
            object.__setattr__(self, name, a)


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n <= 1e-300:
        raise RequestError(f"{what} has zero length")
    return v / n


def resolve_light(p: LightParams, scene: Scene, index: int = 0) -> Light:
    """Resolve one light of a request.

    Raises
    ------
    RequestError
        Missing or degenerate pose data (zero-length direction, position equal to target, a
        spot light without position, a singular pose matrix).
    """
    what = f"light {index}"
    position: np.ndarray | None
    if p.pose is not None:
        pose = orthonormalize_pose(np.array(p.pose), what)
        position, direction = pose[:3, 3], -pose[:3, 2]
    else:
        position = None if p.position is None else np.array(p.position, np.float64)
        # A point light has neither (each light type has exactly its own fields).
        target = getattr(p, "target", None)
        given = getattr(p, "direction", None)
        if target is not None:
            if position is None:
                raise RequestError(f"{what}: target needs a position")
            direction = _unit(np.array(target) - position,
                              f"{what} direction (position to target)")
        elif given is not None:
            direction = _unit(np.array(given), f"{what} direction")
        elif p.type == "point":
            direction = np.array([0.0, 0.0, -1.0])
        elif p.type == "directional" and position is not None:
            # A directional light given only a position shines from there toward the scene.
            lo, hi = scene_box(scene)
            direction = _unit((lo + hi) / 2 - position, f"{what} direction (position to centre)")
        elif p.type == "directional":
            direction = DEFAULT_DIRECTION / np.linalg.norm(DEFAULT_DIRECTION)
        else:
            raise RequestError(f"{what}: a spot light needs a direction, a target or a pose")
        if position is None:
            if p.type != "directional":
                raise RequestError(f"{what}: a {p.type} light needs a position or a pose")
            lo, hi = scene_box(scene)
            position = (lo + hi) / 2
    return Light(
        type=p.type,
        position=position,
        direction=direction,
        color=np.array(p.color, np.float64),
        intensity=p.intensity,
        inner_cone=math.radians(getattr(p, "inner_cone_deg", 0.0)),
        outer_cone=math.radians(getattr(p, "outer_cone_deg", 30.0)),
        range=getattr(p, "range", None),
        cast_shadows=p.cast_shadows,
    )


def resolve_lights(params: list[LightParams] | None, scene: Scene) -> list[Light]:
    """The request's lights; else the file's lights; else one default directional light."""
    if params is not None:
        return [resolve_light(p, scene, i) for i, p in enumerate(params)]
    if scene.lights:
        out = []
        for sl in scene.lights:
            t = sl.type if sl.type in ("directional", "spot", "point") else "directional"
            out.append(
                Light(
                    type=t,
                    position=sl.pose[:3, 3].copy(),
                    direction=-sl.pose[:3, 2].copy(),
                    color=np.array(sl.color, np.float64),
                    # glTF intensities are photometric; map them to a unit-ish scale.
                    intensity=float(min(sl.intensity, 1e6)) if t == "directional" else 1.0,
                    inner_cone=min(sl.inner_cone, sl.outer_cone * 0.999),
                    outer_cone=min(max(sl.outer_cone, 1e-3), math.radians(89.5)),
                    range=sl.range,
                )
            )
        return out
    return [resolve_light(_DEFAULT_LIGHT, scene)]


#: The light of a request that names none and a file that has none (models are not changed).
_DEFAULT_LIGHT = DirectionalLight()
