"""``KHR_lights_punctual``: directional, point and spot lights placed by nodes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...scene import SceneLight
from ..reader import extension

EXTENSION = "KHR_lights_punctual"
_TYPES = ("directional", "point", "spot")


def _number(value: Any, default: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return default
    return float(value)


def document_lights(doc: dict[str, Any]) -> list[Any]:
    """The document's light definitions (empty when the extension is absent or malformed)."""
    ext = extension(doc, EXTENSION)
    lights = ext.get("lights", []) if ext else []
    return lights if isinstance(lights, list) else []


def node_light(node: dict[str, Any], lights: list[Any], pose: np.ndarray,
               warnings: list[str], what: str) -> SceneLight | None:
    """The light a node places, with its (scale-free) world pose, or None.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
        The node's world matrix without scale; the light looks down its −Z.
    """
    ref = extension(node, EXTENSION)
    if ref is None or "light" not in ref:
        return None
    li = ref["light"]
    if isinstance(li, bool) or not isinstance(li, int) or not 0 <= li < len(lights):
        warnings.append(f"{what}: {EXTENSION} light {li!r} does not exist: left out")
        return None
    spec = lights[li]
    kind = spec.get("type") if isinstance(spec, dict) else None
    if kind not in _TYPES:
        warnings.append(f"{what}: light {li} has unknown type {kind!r}: left out")
        return None
    assert isinstance(spec, dict)
    spot = spec.get("spot", {})
    spot = spot if isinstance(spot, dict) else {}
    color = spec.get("color", (1.0, 1.0, 1.0))
    if (not isinstance(color, list | tuple) or len(color) != 3
            or not all(isinstance(c, int | float) and not isinstance(c, bool) for c in color)):
        color = (1.0, 1.0, 1.0)
    rng = _number(spec.get("range"), -1.0)
    return SceneLight(
        type=kind,
        pose=pose,
        color=(float(color[0]), float(color[1]), float(color[2])),
        intensity=_number(spec.get("intensity"), 1.0),
        range=rng if rng > 0 else None,
        inner_cone=_number(spot.get("innerConeAngle"), 0.0),
        outer_cone=_number(spot.get("outerConeAngle"), math.pi / 4),
    )
