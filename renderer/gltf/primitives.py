"""Primitive topology: triangle lists, strips and fans to one triangle list, with index checks.

Points and lines (modes 0-3) are not drawn by a triangle renderer; the loader leaves them out
with a warning. Indices are checked against the vertex count and against the primitive-restart
value of their component type (which glTF forbids in index data, and GL would treat as a cut).
"""

from __future__ import annotations

import numpy as np

TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES",
              5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}
#: Primitive-restart value by index component type (all bits set).
RESTART = {5121: 0xFF, 5123: 0xFFFF, 5125: 0xFFFFFFFF}


def triangle_count(mode: int, count: int) -> int:
    """Triangles a primitive of ``count`` indices (or vertices) makes; 0 for points and lines."""
    if mode == TRIANGLES:
        return count // 3
    if mode in (TRIANGLE_STRIP, TRIANGLE_FAN):
        return max(count - 2, 0)
    return 0


def triangulate(indices: np.ndarray, mode: int, restart: int | None = None) -> np.ndarray:
    """One triangle list from a list, strip or fan, keeping glTF's winding.

    Strips alternate (glTF 2.0 3.7.2.1: triangle i is (v_i, v_{i+1+i%2}, v_{i+2-i%2}), so every
    triangle keeps the first one's orientation); fans are (v_{i+1}, v_{i+2}, v_0). A trailing
    partial triangle of a list is dropped.

    Parameters
    ----------
    indices : ndarray, shape (K,), integer
    mode : {4, 5, 6}
    restart : int, optional
        For a strip or a fan: the primitive-restart value (KHR_mesh_primitive_restart), which
        ends one strip or fan and starts the next; each is triangulated as if alone (a strip's
        alternation and a fan's centre start again).

    Returns
    -------
    ndarray, shape (F, 3), int64
    """
    idx = np.asarray(indices, np.int64)
    if mode == TRIANGLES:
        f = len(idx) // 3
        return idx[: f * 3].reshape(f, 3)
    if mode not in (TRIANGLE_STRIP, TRIANGLE_FAN):
        raise ValueError(f"mode {mode} is not a triangle mode")
    f = max(len(idx) - 2, 0)
    i = np.arange(f)
    cut = idx == restart if restart is not None else np.zeros(len(idx), bool)
    # Each index's segment (restarts counted before it) and the segment's first position.
    segment = np.cumsum(cut)
    first = np.concatenate([[0], np.flatnonzero(cut) + 1])[segment]
    # A triangle's three positions lie in one segment when no restart is among them.
    if mode == TRIANGLE_STRIP:
        whole = ~(cut[i] | cut[i + 1] | cut[i + 2])
        odd = (i - first[i]) % 2
        return np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)[whole]
    # Fan: the triangle at i is (v_{i+1}, v_{i+2}, v_first) of the segment holding i + 1, when
    # i + 1 is not the segment's first (the centre) and i + 2 still belongs to it.
    j = i + 1
    keep = ~(cut[j] | cut[j + 1]) & (j > first[j])
    return np.stack([idx[j], idx[j + 1], idx[first[j]]], axis=1)[keep]
