"""``KHR_lights_punctual``: directional, point and spot lights placed by nodes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...scene import SceneLight
from ..reader import brief, extension

EXTENSION = "KHR_lights_punctual"
_TYPES = ("directional", "point", "spot")


def _number(spec: dict[str, Any], key: str, default: float, low: float, high: float,
            warnings: list[str], what: str, instead: str = "") -> float:
    """``spec[key]`` as a finite number in [low, high]; the default, with a warning (ending in
    ``instead``, else the default), when it is something else (a string, a boolean, NaN, out
    of range)."""
    if key not in spec:
        return default
    value = spec[key]
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not math.isfinite(value) or not low <= value <= high):
        warnings.append(f"{what}: {key} {brief(value)} is not a number from {low:g} to {high:g}"
                        f": {instead or f'{default:g} is used'}")
        return default
    return float(value)


def _color(spec: dict[str, Any], warnings: list[str], what: str) -> tuple[float, float, float]:
    value = spec.get("color", [1.0, 1.0, 1.0])
    if (isinstance(value, list) and len(value) == 3
            and all(isinstance(c, int | float) and not isinstance(c, bool) for c in value)
            and all(math.isfinite(c) and c >= 0 for c in value)):
        return float(value[0]), float(value[1]), float(value[2])
    warnings.append(f"{what}: color {brief(value)} is not 3 finite numbers >= 0: white is used")
    return 1.0, 1.0, 1.0


def document_lights(doc: dict[str, Any]) -> list[Any]:
    """The document's light definitions (empty when the extension is absent or malformed)."""
    ext = extension(doc, EXTENSION)
    lights = ext.get("lights", []) if ext else []
    return lights if isinstance(lights, list) else []


def names_extension(node: dict[str, Any]) -> bool:
    """The node's ``extensions`` hold this one's key, well formed or not (a malformed light
    reference is warned about by :func:`node_light`, not passed over)."""
    exts = node.get("extensions")
    return isinstance(exts, dict) and EXTENSION in exts


def node_light(node: dict[str, Any], lights: list[Any], pose: np.ndarray,
               warnings: list[str], what: str) -> SceneLight | None:
    """The light a node places, with its (scale-free) world pose, or None.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
        The node's world matrix without scale; the light looks down its −Z.
    """
    if not names_extension(node):
        return None
    ref = extension(node, EXTENSION)
    if ref is None or "light" not in ref:
        warnings.append(f"{what}: its {EXTENSION} {brief(node['extensions'][EXTENSION])} names "
                        "no light: left out")
        return None
    li = ref["light"]
    if isinstance(li, bool) or not isinstance(li, int) or not 0 <= li < len(lights):
        warnings.append(f"{what}: {EXTENSION} light {brief(li)} does not exist: left out")
        return None
    spec = lights[li]
    kind = spec.get("type") if isinstance(spec, dict) else None
    if kind not in _TYPES:
        warnings.append(f"{what}: light {li} has unknown type {brief(kind)}: left out")
        return None
    assert isinstance(spec, dict)
    what = f"{what}: light {li}"
    spot = spec.get("spot", {})
    if not isinstance(spot, dict):
        warnings.append(f"{what}: spot {brief(spot)} is not an object: the default cone is used")
        spot = {}
    # glTF: intensity >= 0, range > 0, 0 <= innerConeAngle < outerConeAngle <= pi/2.
    rng = _number(spec, "range", math.inf, 0.0, math.inf, warnings, what, "no range is used")
    inner = _number(spot, "innerConeAngle", 0.0, 0.0, math.pi / 2, warnings, f"{what} spot")
    outer = _number(spot, "outerConeAngle", math.pi / 4, 0.0, math.pi / 2, warnings,
                    f"{what} spot")
    return SceneLight(
        type=kind,
        pose=pose,
        color=_color(spec, warnings, what),
        intensity=_number(spec, "intensity", 1.0, 0.0, math.inf, warnings, what),
        range=rng if 0 < rng < math.inf else None,
        inner_cone=inner,
        outer_cone=outer,
    )
