"""``EXT_mesh_gpu_instancing``: one instance of a node's mesh per TRANSLATION/ROTATION/SCALE
entry, each composed with the node's world matrix (the matrices built in one vectorised step).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import SceneError
from ..accessors import FLOAT_ONLY, NORMALIZED_INTS, PLAIN_INTS, Accessors, check_type
from ..nodes import trs_matrices, unit_quaternions

EXTENSION = "EXT_mesh_gpu_instancing"
_TYPES = {"TRANSLATION": "VEC3", "ROTATION": "VEC4", "SCALE": "VEC3"}


def _accessor(ext: dict[str, Any], key: str, accessors: Accessors, what: str) -> int | None:
    attrs = ext.get("attributes", {})
    if not isinstance(attrs, dict):
        raise SceneError(f"{what}: {EXTENSION} 'attributes' is not an object")
    idx = attrs.get(key)
    if idx is None:
        return None
    if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < len(accessors):
        raise SceneError(f"{what}: {EXTENSION} {key} = {idx!r} is not an accessor index")
    return idx


def instance_count(ext: dict[str, Any], accessors: Accessors, what: str) -> int:
    """Instances the extension asks for, from the accessors' declared counts (no data read);
    0 when it names no attribute (then the node is drawn once, as without the extension)."""
    counts = {accessors.count(i) for key in _TYPES
              if (i := _accessor(ext, key, accessors, what)) is not None}
    if len(counts) > 1:
        raise SceneError(f"{what}: {EXTENSION} attributes have different counts {sorted(counts)}")
    return counts.pop() if counts else 0


def instance_matrices(ext: dict[str, Any], accessors: Accessors, what: str,
                      warnings: list[str]) -> np.ndarray | None:
    """The per-instance local matrices (instance-to-node), rotations made unit quaternions
    (:func:`~..nodes.unit_quaternions`; those that were far from it are counted in
    ``warnings``).

    Returns
    -------
    ndarray, shape (K, 4, 4), float64, or None when the extension names no attribute.

    Raises
    ------
    SceneError
        Bad accessor indices or types, counts that differ.
    """
    k = instance_count(ext, accessors, what)
    if k == 0:
        return None
    arrays: dict[str, np.ndarray] = {}
    for key, kind in _TYPES.items():
        idx = _accessor(ext, key, accessors, what)
        if idx is None:
            continue
        # Rotations may be normalized bytes/shorts; translations and scales floats or, with
        # KHR_mesh_quantization, normalized or plain integers.
        comps = FLOAT_ONLY | NORMALIZED_INTS
        if key != "ROTATION":
            comps = comps | PLAIN_INTS
        reason = check_type(accessors.info(idx), {kind}, comps, f"{what} {EXTENSION} {key}")
        if reason:
            raise SceneError(reason)
        arrays[key] = accessors.read_float(idx)
    t = arrays.get("TRANSLATION", np.zeros((k, 3)))
    r, _, off = unit_quaternions(arrays.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (k, 1))))
    if off.any():
        warnings.append(f"{what}: {int(off.sum())} {EXTENSION} rotations are not unit "
                        "quaternions: normalized (a zero one is no rotation)")
    s = arrays.get("SCALE", np.ones((k, 3)))
    return trs_matrices(t, r, s)
