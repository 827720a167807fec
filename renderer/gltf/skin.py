"""Skins applied at load, in the pose the file's nodes store (no animation is played).

A viewer draws a skinned vertex at ``sum_k w_k * (jointWorld_k @ inverseBindMatrix_k) @ v``;
the skinned mesh node's own transform is ignored (glTF 2.0 3.7.3.3). Normals use the
inverse-transpose of the blended matrix. The result is in world space, so the instance that
draws it has the identity matrix.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import SceneError
from .accessors import FLOAT_ONLY, Accessors, check_type
from .nodes import NodeGraph
from .reader import get_index

#: Vertices blended per step: bounds the (chunk, 3, 4) temporaries.
CHUNK = 1 << 16


@dataclass
class SkinResult:
    """Skinned positions and normals, and what could not be skinned as the file asks.

    Attributes
    ----------
    positions : ndarray, shape (N, 3), float64
        World space.
    normals : ndarray or None, shape (N, 3), float64
        Unit length (None when no normals were given).
    unweighted : int
        Vertices whose weights sum to zero (drawn with the mesh node's world matrix).
    bad_joints : int
        Influences naming a joint the skin does not have (their weight is dropped).
    """

    positions: np.ndarray
    normals: np.ndarray | None
    unweighted: int
    bad_joints: int


def joint_matrices(doc: dict[str, Any], skin: int, graph: NodeGraph,
                   accessors: Accessors) -> np.ndarray:
    """``jointWorld @ inverseBindMatrix`` for every joint of skin ``skin``.

    Returns
    -------
    ndarray, shape (J, 4, 4), float64

    Raises
    ------
    SceneError
        No joints, joint indices out of range, an inverseBindMatrices accessor that is not MAT4
        float or has fewer matrices than joints, non-finite joint matrices.
    """
    what = f"skin {skin}"
    spec = doc["skins"][skin]
    if not isinstance(spec, dict):
        raise SceneError(f"malformed glTF: {what} is not an object")
    joints = spec.get("joints")
    n = len(graph.nodes)
    if (not isinstance(joints, list) or not joints
            or not all(isinstance(j, int) and not isinstance(j, bool) and 0 <= j < n
                       for j in joints)):
        raise SceneError(f"{what}: 'joints' must be a non-empty array of node indices")
    joint_idx = np.asarray(joints, np.int64)
    ibm_index = get_index(spec, "inverseBindMatrices", len(accessors), what)
    if ibm_index is None:
        ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
    else:
        reason = check_type(accessors.info(ibm_index), {"MAT4"}, FLOAT_ONLY,
                            f"{what} inverseBindMatrices")
        if reason:
            raise SceneError(reason)
        ibm = accessors.read_float(ibm_index)
        if len(ibm) < len(joints):
            raise SceneError(f"{what}: inverseBindMatrices has {len(ibm)} matrices for "
                             f"{len(joints)} joints")
        ibm = ibm[: len(joints)]
    mats: np.ndarray = graph.world[joint_idx] @ ibm
    if not np.all(np.isfinite(mats)):
        raise SceneError(f"{what}: a joint has a non-finite transform")
    return mats


def joint_warnings(doc: dict[str, Any], skin: int, graph: NodeGraph) -> list[str]:
    """What a skin's joint list breaks of the glTF rules, though it is drawn as its matrices
    say: a node listed twice as a joint, and joints with no common root. Viewers that build one
    bone per node in one skeleton (Blender's importer) draw such a skin another way.

    Call after :func:`joint_matrices`, which checks the list itself.
    """
    joints = np.asarray(doc["skins"][skin]["joints"], np.int64)
    out = []
    nodes, counts = np.unique(joints, return_counts=True)
    twice = nodes[counts > 1]
    if len(twice):
        named = ", ".join(repr(graph.names[i]) for i in twice[:3].tolist())
        more = f" and {len(twice) - 3} more" if len(twice) > 3 else ""
        out.append(f"skin {skin} lists node {named}{more} more than once as a joint (glTF "
                   "requires each joint once): each entry is drawn with its own inverse bind "
                   "matrix")
    # Each joint's topmost ancestor: one walk up per level of the deepest joint.
    root = joints.copy()
    up = graph.parent[root]
    while (up >= 0).any():
        root = np.where(up >= 0, up, root)
        up = graph.parent[root]
    trees = np.unique(root)
    if len(trees) > 1:
        first = [int(joints[root == t][0]) for t in trees[:2].tolist()]
        out.append(f"skin {skin}: its joints have no common root (glTF requires one): nodes "
                   f"{graph.names[first[0]]!r} and {graph.names[first[1]]!r} lie in different "
                   "trees; each joint is drawn where its own tree places it")
    return out


def _cofactor(m: np.ndarray) -> np.ndarray:
    """``det(m) * inv(m).T`` for (K, 3, 3) matrices, defined for singular ones too.

    Rows are the cross products of the rows: (r1 x r2, r2 x r0, r0 x r1).
    """
    r0, r1, r2 = m[:, 0], m[:, 1], m[:, 2]
    return np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=1)


def apply_skin(positions: np.ndarray, normals: np.ndarray | None, joints: list[np.ndarray],
               weights: list[np.ndarray], mats: np.ndarray, fallback: np.ndarray) -> SkinResult:
    """Blend joint matrices per vertex and transform positions and normals.

    Parameters
    ----------
    positions : ndarray, shape (N, 3)
        After morph targets, in the mesh's frame.
    normals : ndarray or None, shape (N, 3)
    joints : list of ndarray, each shape (N, 4), integer
        ``JOINTS_0``, ``JOINTS_1``, ...
    weights : list of ndarray, each shape (N, 4), float
        ``WEIGHTS_n`` of the same sets; normalized here to sum to one.
    mats : ndarray, shape (J, 4, 4)
        From :func:`joint_matrices`.
    fallback : ndarray, shape (4, 4)
        Used for vertices whose weights sum to zero: the mesh node's world matrix.

    Returns
    -------
    SkinResult
    """
    n = len(positions)
    jj = np.concatenate([np.asarray(j, np.int64) for j in joints], axis=1)  # (N, 4S)
    ww = np.concatenate([np.asarray(w, np.float64) for w in weights], axis=1)
    ww = np.where(np.isfinite(ww) & (ww > 0), ww, 0.0)
    bad = (jj < 0) | (jj >= len(mats))
    bad_count = int(np.count_nonzero(bad & (ww > 0)))
    ww[bad] = 0.0
    jj[bad] = 0
    total = ww.sum(axis=1)
    zero = total <= 0
    ww[~zero] /= total[~zero, None]
    m34 = mats[:, :3, :]
    out_p = np.empty((n, 3))
    out_n = None if normals is None else np.empty((n, 3))
    for start in range(0, n, CHUNK):
        sl = slice(start, min(start + CHUNK, n))
        w, j = ww[sl], jj[sl]
        blend = np.zeros((len(w), 3, 4))
        for k in range(w.shape[1]):
            blend += w[:, k, None, None] * m34[j[:, k]]
        blend[zero[sl]] = fallback[:3, :]
        p = positions[sl]
        out_p[sl] = np.einsum("nij,nj->ni", blend[:, :, :3], p) + blend[:, :, 3]
        if normals is not None and out_n is not None:
            lin = blend[:, :, :3]
            cof = _cofactor(lin)
            det = np.einsum("ni,ni->n", lin[:, 0], cof[:, 0])
            nn = np.einsum("nij,nj->ni", cof, normals[sl]) * np.sign(det)[:, None]
            out_n[sl] = nn
    if out_n is not None:
        length = np.linalg.norm(out_n, axis=1, keepdims=True)
        ok = length[:, 0] > 1e-30
        out_n[ok] /= length[ok]
        out_n[~ok] = np.nan  # the loader replaces these with computed normals
    return SkinResult(out_p, out_n, int(np.count_nonzero(zero)), bad_count)
