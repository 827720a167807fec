"""``KHR_texture_transform``: offset, rotation, scale and texCoord override of a texture.

Applied to the primitive's UVs at load (the renderer samples one base-colour texture with the
primitive's own UVs), so a transformed texture moves its alpha cut-outs, and with them the
shadows they cast.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...errors import SceneError

EXTENSION = "KHR_texture_transform"


def _pair(ext: dict[str, Any], key: str, default: tuple[float, float], what: str
          ) -> tuple[float, float]:
    value = ext.get(key, default)
    if (not isinstance(value, list | tuple) or len(value) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            or not all(math.isfinite(v) for v in value)):
        raise SceneError(f"{what}: {EXTENSION} '{key}' must be two finite numbers")
    return float(value[0]), float(value[1])


def uv_matrix(ext: dict[str, Any], what: str) -> np.ndarray:
    """The transform as a 3x3 matrix on (u, v, 1) in glTF's UV convention.

    ``T(offset) @ R(rotation) @ S(scale)``, with the extension's rotation matrix
    ``[[cos, sin], [-sin, cos]]`` (a counter-clockwise rotation of the image).

    Returns
    -------
    ndarray, shape (3, 3), float64
    """
    ox, oy = _pair(ext, "offset", (0.0, 0.0), what)
    sx, sy = _pair(ext, "scale", (1.0, 1.0), what)
    rot = ext.get("rotation", 0.0)
    if isinstance(rot, bool) or not isinstance(rot, int | float) or not math.isfinite(rot):
        raise SceneError(f"{what}: {EXTENSION} 'rotation' must be a finite number")
    c, s = math.cos(rot), math.sin(rot)
    translation = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1]], np.float64)
    rotation = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], np.float64)
    scale = np.diag([sx, sy, 1.0])
    out: np.ndarray = translation @ rotation @ scale
    return out


def tex_coord(ext: dict[str, Any], default: int, what: str) -> int:
    """The texCoord set the transform asks for (its ``texCoord`` overrides the textureInfo's)."""
    value = ext.get("texCoord", default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SceneError(f"{what}: {EXTENSION} 'texCoord' must be an integer >= 0")
    return value


def apply(uv: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Transformed UVs.

    Parameters
    ----------
    uv : ndarray, shape (N, 2)
        glTF convention (v down the image).
    matrix : ndarray, shape (3, 3)

    Returns
    -------
    ndarray, shape (N, 2), float64
    """
    uv = np.asarray(uv, np.float64)
    out: np.ndarray = uv @ matrix[:2, :2].T + matrix[:2, 2]
    return out
