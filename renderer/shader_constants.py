"""Numbers the GLSL code shares with Python, written once, here, and handed to every program.

The program builder (:mod:`shadowmap.renderer.gl.programs`) puts :func:`shader_constants` into
every stage as ``#define`` lines right after ``#version``. The GLSL files use these names and never
spell out the values, nor guard them with ``#ifndef``: a program built without them fails to
compile instead of silently using numbers that have drifted from Python's.

- ``ENC_DEPTH``, ``ENC_R8``, ... : the depth encodings' ids (:data:`.encodings.ENCODING_ID`),
  which the ``ENCODING`` define takes. (Each map's depth step, the unit of the quantisation bias
  and of the polygon offset, is a uniform: a depth texture's depends on the bits its plan chose.)
- ``LIGHT_DIRECTIONAL``, ``LIGHT_SPOT``, ``LIGHT_POINT``: the light type ids of
  :data:`LIGHT_TYPES`, the values of the camera pass's ``LIGHT_TYPES`` list.
- ``MAX_LIGHTS``: lights one camera pass shades (:data:`.limits.MAX_LIGHTS`).
- ``MAX_CASCADES``: cascades of one directional light (:data:`.limits.MAX_CASCADES`).
- ``PLANE_SLOPE_MAX``: the steepest receiver plane (tan of its angle to the light) the shadow
  lookups follow: that of a surface at :data:`.plan.geometry.FACING_COS` to the light, the most
  grazing one that still counts as lit.
- ``FOR_EACH_SLOT(X)``: expands to ``X(0) X(1) ... X(MAX_LIGHTS - 1)``; the shadow chunks build
  their per-map dispatch from it, so that every sampler array is indexed by a constant (dynamic
  indexing of sampler arrays is where drivers differ).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from . import encodings
from .limits import MAX_CASCADES, MAX_LIGHTS
from .plan.geometry import FACING_COS

#: Light type -> the id the camera pass's ``LIGHT_TYPES`` define lists per light.
LIGHT_TYPES: dict[str, int] = {"directional": 0, "spot": 1, "point": 2}


def _float_literal(value: float) -> str:
    """A GLSL float literal that reads back as exactly ``float32(value)``.

    Nine significant digits identify every float32, so the compiler's parse of the literal is the
    same number a constant expression such as ``1.0 / 255.0`` folds to.
    """
    f = np.float32(value)
    if not np.isfinite(f):
        raise ValueError(f"{value!r} has no GLSL float literal")
    text = f"{float(f):.9g}"
    return text if any(c in text for c in ".e") else text + ".0"


@lru_cache(maxsize=1)
def shader_constants() -> tuple[tuple[str, str], ...]:
    """The constants as ``(name, value)`` pairs, in the order they are defined.

    Returns
    -------
    tuple of (str, str)
        ``name`` is a macro name (with its parameter list for function-like macros, e.g.
        ``"FOR_EACH_SLOT(X)"``); ``#define {name} {value}`` is the line a stage gets.
    """
    out: list[tuple[str, str]] = []
    for name, ident in sorted(encodings.ENCODING_ID.items(), key=lambda kv: kv[1]):
        out.append((f"ENC_{name.upper()}", str(ident)))
    for name, ident in sorted(LIGHT_TYPES.items(), key=lambda kv: kv[1]):
        out.append((f"LIGHT_{name.upper()}", str(ident)))
    out.append(("MAX_LIGHTS", str(MAX_LIGHTS)))
    out.append(("MAX_CASCADES", str(MAX_CASCADES)))
    out.append(("PLANE_SLOPE_MAX", _float_literal(math.sqrt(1.0 - FACING_COS**2) / FACING_COS)))
    out.append(("FOR_EACH_SLOT(X)", " ".join(f"X({k})" for k in range(MAX_LIGHTS))))
    return tuple(out)
