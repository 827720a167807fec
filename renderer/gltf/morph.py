"""Morph targets at their default weights: ``mesh.weights``, overridden by ``node.weights``.

``base + sum_i w_i * target_i`` for POSITION and NORMAL (targets are accessors, so sparse
targets are substituted like any other). Tangents and other attributes are not used by the
renderer.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import SceneError
from .accessors import Accessors, check_type
from .extensions import mesh_quantization


def default_weights(mesh: dict[str, Any], node: dict[str, Any] | None) -> tuple[float, ...]:
    """The weights a node draws its mesh with: ``node.weights``, else ``mesh.weights``, else
    none (all zero).

    Non-numeric or non-finite entries count as 0.
    """
    for source in (node, mesh):
        if isinstance(source, dict) and isinstance(source.get("weights"), list):
            return tuple(float(w) if isinstance(w, int | float) and not isinstance(w, bool)
                         and math.isfinite(w) else 0.0 for w in source["weights"])
    return ()


def apply_targets(base: np.ndarray, primitive: dict[str, Any], semantic: str,
                  weights: tuple[float, ...], accessors: Accessors, what: str,
                  warnings: list[str]) -> np.ndarray:
    """``base`` plus the weighted displacements of the primitive's targets for ``semantic``.

    Parameters
    ----------
    base : ndarray, shape (N, 3), float64
        The attribute (all N vertices of its accessor).
    primitive : dict
        The primitive's JSON (its ``targets``).
    semantic : {"POSITION", "NORMAL"}
    weights : tuple of float
        One per target (missing ones are 0).

    Returns
    -------
    ndarray, shape (N, 3), float64
        A new array when any target applies, else ``base``.
    """
    targets = primitive.get("targets", [])
    if not isinstance(targets, list):
        raise SceneError(f"{what}: 'targets' is not an array")
    out = base
    for i, target in enumerate(targets):
        w = weights[i] if i < len(weights) else 0.0
        if w == 0.0 or not isinstance(target, dict) or semantic not in target:
            continue
        idx = target[semantic]
        tw = f"{what} target {i} {semantic}"
        if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < len(accessors):
            raise SceneError(f"{tw}: {idx!r} is not an accessor index")
        info = accessors.info(idx)
        reason = check_type(info, {"VEC3"}, mesh_quantization.TARGET, tw)
        if reason:
            raise SceneError(reason)
        if info.count != len(base):
            warnings.append(f"{tw} has {info.count} elements for {len(base)} vertices: "
                            "the target is left out")
            continue
        out = out + w * accessors.read_float(idx)
    return out
