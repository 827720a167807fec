"""The node graph: local and world matrices of every node, computed once and vectorised.

The graph is walked iteratively, level by level from the parentless nodes, so depth costs no
recursion and every node is visited once; each level's world matrices are one batched matrix
product. A node listed as the child of two parents, or a cycle, is a ``SceneError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import SceneError
from .extensions import node_visibility
from .reader import brief, get_index, get_list

#: ``NodeGraph.camera`` of a node whose camera index is out of range.
INVALID = -2
#: Longest node name kept (longer ones are cut).
MAX_NAME = 120


def trs_matrices(t: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``T @ R @ S`` for many translation/rotation/scale triples at once.

    Parameters
    ----------
    t : ndarray, shape (K, 3)
    r : ndarray, shape (K, 4)
        Quaternions (x, y, z, w), used as given (glTF requires unit quaternions).
    s : ndarray, shape (K, 3)

    Returns
    -------
    ndarray, shape (K, 4, 4), float64
    """
    t, r, s = (np.asarray(a, np.float64) for a in (t, r, s))
    x, y, z, w = r.T
    m = np.zeros((len(t), 4, 4))
    rot = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], 1)
    m[:, :3, :3] = rot * s[:, None, :]  # R @ diag(s): scales the columns
    m[:, :3, 3] = t
    m[:, 3, 3] = 1.0
    return m


@dataclass
class NodeGraph:
    """Every node of a document with its place in the graph.

    Attributes
    ----------
    nodes : list of dict
        The nodes' JSON.
    local, world : ndarray, shape (N, 4, 4), float64
        Node-to-parent and node-to-world matrices (world may hold non-finite values; users
        refuse them where it matters).
    parent : ndarray, shape (N,), int64
        -1 for root nodes.
    order : ndarray, shape (N,), int64
        Nodes in breadth-first order from the roots (parents before children).
    in_scene : ndarray, shape (N,), bool
        The node belongs to the scene drawn (the default scene, or all roots when none is set).
    visible : ndarray, shape (N,), bool
        Neither the node nor a node above it says ``visible: false`` (KHR_node_visibility):
        its mesh and light are drawn.
    """

    nodes: list[dict[str, Any]]
    local: np.ndarray
    world: np.ndarray
    parent: np.ndarray
    order: np.ndarray
    in_scene: np.ndarray
    visible: np.ndarray
    #: What each node references, -1 for nothing: ``mesh``, ``skin``, ``camera`` (validated
    #: indices; :data:`INVALID` for a camera index that is not one), read in the same single
    #: pass over the nodes as the transforms.
    mesh: np.ndarray
    skin: np.ndarray
    camera: np.ndarray
    #: ``extras.castShadow`` / ``extras.receiveShadow`` of each node: 1, 0, or -1 when unset.
    cast: np.ndarray
    receive: np.ndarray
    #: The node needs per-node work beyond its world matrix: morph weights or an extension
    #: (EXT_mesh_gpu_instancing, KHR_lights_punctual).
    special: np.ndarray
    names: list[str]
    #: What was repaired or is drawn against the glTF rules in the graph of the drawn scene (a
    #: non-affine or shearing node matrix, a rotation that is not a unit quaternion).
    warnings: list[str]


#: How far from 1 a rotation quaternion's length may be before its normalization is worth a
#: warning: float rounding is not, nor the steps of a rotation stored as normalized bytes (at
#: most about 0.008 from 1).
ROTATION_SLACK = 0.02

#: How far from 0 the cosine between two axes of a node matrix may be before the matrix is said
#: to shear (about 0.06 degrees from square): float32 rounding of a composed TRS is far below.
SHEAR_SLACK = 1e-3


def shear_degrees(linear: np.ndarray) -> np.ndarray:
    """How far from square the axes of each matrix meet: the largest of ``|90 - angle|`` over
    its three pairs of columns, in degrees; 0 where a column is zero or not finite (a zero
    scale decomposes; a non-finite matrix is refused where it is drawn).

    Parameters
    ----------
    linear : ndarray, shape (N, 3, 3)

    Returns
    -------
    ndarray, shape (N,)
    """
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # Each axis scaled by its largest component first: squares of components past 1e154
        # would overflow, and the cosines come out NaN, hiding the shear.
        big = np.abs(linear).max(axis=1, keepdims=True)
        linear = linear / np.where(big > 0.0, big, 1.0)
        gram = np.einsum("nki,nkj->nij", linear, linear)
        d = np.sqrt(np.einsum("nii->ni", gram))
        cos = [gram[:, i, j] / (d[:, i] * d[:, j]) for i, j in ((0, 1), (0, 2), (1, 2))]
        worst = np.max(np.abs(np.stack(cos, axis=1)), axis=1, initial=0.0)
    worst = np.where(np.isfinite(worst), np.minimum(worst, 1.0), 0.0)
    return np.degrees(np.arcsin(worst))


def unit_quaternions(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """glTF rotations as unit quaternions.

    Another length would scale and shear what they turn; a zero one turns nothing (the
    identity is used); a non-finite one is kept, to be refused where it is drawn. A length
    whose squares leave float64's range (components past about 1e154, or all below about
    1e-154) is taken from the components scaled by the largest first: divided by an overflowed
    length of infinity, such a rotation would silently become none at all.

    Parameters
    ----------
    r : ndarray, shape (N, 4)
        XYZW.

    Returns
    -------
    unit : ndarray, shape (N, 4), float64
    length : ndarray, shape (N,)
        The given lengths.
    off : ndarray, shape (N,), bool
        Finite rotations whose length was past :data:`ROTATION_SLACK` from 1 (zero included).
    """
    r = np.asarray(r, np.float64)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        finite = np.isfinite(r).all(axis=1)
        length = np.linalg.norm(r, axis=1)
        unit = np.where((finite & (length > 0.0))[:, None],
                        r / np.where(length > 0.0, length, 1.0)[:, None],
                        np.where(finite[:, None], (0.0, 0.0, 0.0, 1.0), r))
        big = np.abs(r).max(axis=1, initial=0.0)
        redo = np.flatnonzero(finite & (big > 0.0) & ~(np.isfinite(length) & (length > 0.0)))
        if len(redo):
            scaled = r[redo] / big[redo, None]
            n = np.linalg.norm(scaled, axis=1)  # in [1, 2]
            unit[redo] = scaled / n[:, None]
            length[redo] = big[redo] * n  # infinite past float64's range: still said
    return unit, length, finite & (np.abs(length - 1.0) > ROTATION_SLACK)


_VECTORS = {"matrix": 16, "translation": 3, "rotation": 4, "scale": 3}
_REFS = ("mesh", "skin", "camera")
_COLLECTED = (*_VECTORS, *_REFS, "children", "extras", "name", "weights", "extensions")


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _vectors(key: str, rows: list[int], values: list[Any]) -> np.ndarray:
    """The ``key`` arrays of the nodes ``rows`` as one (len(rows), n) float64 array."""
    n = _VECTORS[key]
    try:
        arr = np.array(values)
    except ValueError:  # ragged
        arr = np.zeros(0)
    # Numbers only (a list holding strings, objects or only booleans has another dtype kind).
    if arr.shape == (len(values), n) and arr.dtype.kind in "iuf":
        return arr.astype(np.float64)
    for i, v in zip(rows, values, strict=True):  # find the culprit for the message
        if (not isinstance(v, list) or len(v) != n
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)):
            raise SceneError(f"node {i}: '{key}' must be an array of {n} numbers")
    raise SceneError(f"malformed glTF: node '{key}' arrays")  # pragma: no cover


def build_graph(doc: dict[str, Any]) -> NodeGraph:
    """Local and world matrices of every node, and which nodes the drawn scene holds.

    The drawn scene is ``scenes[scene]``; when ``scene`` is absent, every root node is drawn.
    The nodes are walked once in Python, collecting each field's values; the fields are then
    checked and turned into arrays field by field.

    Raises
    ------
    SceneError
        Malformed nodes, matrices or TRS; a child index out of range; a node with two parents;
        a cycle; an invalid ``scene`` or scene node index.
    """
    nodes = get_list(doc, "nodes")
    n = len(nodes)
    collected: dict[str, tuple[list[int], list[Any]]] = {k: ([], []) for k in _COLLECTED}
    # The one Python pass over the nodes.
    for i, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise SceneError(f"malformed glTF: node {i} is not an object")
        for key, value in node.items():
            slot = collected.get(key)
            if slot is not None:
                slot[0].append(i)
                slot[1].append(value)

    def field(key: str) -> tuple[list[int], list[Any]]:
        return collected[key]

    t = np.zeros((n, 3))
    r = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    s = np.ones((n, 3))
    for key, arr in (("translation", t), ("rotation", r), ("scale", s)):
        rows, values = field(key)
        if rows:
            arr[rows] = _vectors(key, rows, values)
    m_rows, m_values = field("matrix")
    matrix = _vectors("matrix", m_rows, m_values) if m_rows else np.zeros((0, 16))

    lengths = {"mesh": len(get_list(doc, "meshes")), "skin": len(get_list(doc, "skins")),
               "camera": len(get_list(doc, "cameras"))}
    refs = {key: np.full(n, -1, np.int64) for key in _REFS}
    for key in _REFS:
        rows, values = field(key)
        ok = [_is_int(v) and 0 <= v < lengths[key] for v in values]
        if not all(ok):
            bad = ok.index(False)
            if key != "camera":
                raise SceneError(f"node {rows[bad]}: '{key}' = {brief(values[bad])} is not a valid "
                                 f"index (0..{lengths[key] - 1})")
        good = [v if k else INVALID for v, k in zip(values, ok, strict=True)]
        # A bad camera reference costs the camera (INVALID), not the scene.
        refs[key][rows] = good

    names = [f"node_{i}" for i in range(n)]
    for i, name in zip(*field("name"), strict=True):
        if isinstance(name, str) and name:
            # Cut: names go into every message about their node, and a file must not turn
            # one long name into megabytes of warnings.
            names[i] = name if len(name) <= MAX_NAME else name[:MAX_NAME - 3] + "..."
    cast = np.full(n, -1, np.int8)
    receive = np.full(n, -1, np.int8)
    for i, extras in zip(*field("extras"), strict=True):
        if isinstance(extras, dict):
            for key, flags in (("castShadow", cast), ("receiveShadow", receive)):
                if isinstance(extras.get(key), bool):
                    flags[i] = extras[key]
    special = np.zeros(n, bool)
    special[field("weights")[0]] = True
    special[[i for i, e in zip(*field("extensions"), strict=True)
             if e and not node_visibility.only_extension(e)]] = True
    hides = np.zeros(n, bool)
    visibility_warnings: dict[int, list[str]] = {}
    for i in field("extensions")[0]:
        hides[i] = node_visibility.hides(nodes[i], visibility_warnings.setdefault(i, []),
                                         f"node {names[i]!r}")

    parent = np.full(n, -1, np.int64)
    children: list[list[int]] = [[] for _ in range(n)]
    for i, kids in zip(*field("children"), strict=True):
        if not isinstance(kids, list):
            raise SceneError(f"node {i}: 'children' is not an array")
        for c in kids:
            if not _is_int(c) or not 0 <= c < n:
                raise SceneError(f"node {i}: child {brief(c)} is not a valid node index")
            if parent[c] != -1:
                raise SceneError(f"node {c} has two parents (nodes {parent[c]} and {i}): the "
                                 "node graph must be a forest")
            parent[c] = i
        children[i] = kids
    r, length, off_unit = unit_quaternions(r)
    with np.errstate(over="ignore", invalid="ignore"):  # huge TRS: refused where drawn
        local = trs_matrices(t, r, s)
    # glTF matrices are column-major: the 16 numbers are the columns. A matrix wins over TRS.
    given = matrix.reshape(-1, 4, 4).transpose(0, 2, 1)
    # A node matrix must be an affine TRS. A projective bottom row would divide the drawn
    # positions by w while bounds, culling and the reference treat the matrix as affine: the
    # row is reset to (0, 0, 0, 1) (exporters' rounding noise silently, anything else warned).
    with np.errstate(invalid="ignore"):
        projective = np.abs(given[:, 3] - (0.0, 0.0, 0.0, 1.0)).max(axis=1, initial=0.0) > 1e-6
    projective |= ~np.isfinite(given[:, 3]).all(axis=1)
    given[:, 3] = (0.0, 0.0, 0.0, 1.0)
    # Nor may it shear: glTF requires a node matrix to decompose into translation, rotation
    # and scale. One that shears is drawn as written, and said: viewers that decompose it into
    # TRS (Blender's importer, three.js) draw another shape.
    shear = shear_degrees(given[:, :3, :3])
    sheared = shear > np.degrees(np.arcsin(SHEAR_SLACK))
    local[m_rows] = given

    # The scene drawn, and its listed nodes.
    listed = np.zeros(n, bool)
    scenes = get_list(doc, "scenes")
    scene_index = get_index(doc, "scene", len(scenes), "the file's default 'scene'")
    if scene_index is not None:
        scene = scenes[scene_index]
        if not isinstance(scene, dict):
            raise SceneError(f"malformed glTF: scene {scene_index} is not an object")
        roots = scene.get("nodes", [])
        if not isinstance(roots, list):
            raise SceneError(f"scene {scene_index}: 'nodes' is not an array")
        for x in roots:
            if isinstance(x, bool) or not isinstance(x, int) or not 0 <= x < n:
                raise SceneError(f"scene {scene_index}: node {brief(x)} is not a valid node "
                                 "index")
            listed[x] = True
    else:
        listed[parent == -1] = True

    # Level by level from the roots: each level's world matrices in one batched product.
    world = np.empty_like(local)
    in_scene = np.zeros(n, bool)
    visible = ~hides
    level = np.flatnonzero(parent == -1)
    world[level] = local[level]
    in_scene[level] = listed[level]
    order = [level]
    seen = len(level)
    while len(level):
        nxt = np.fromiter((c for p in level for c in children[p]), np.int64)
        if len(nxt):
            with np.errstate(over="ignore", invalid="ignore"):  # refused where drawn
                world[nxt] = world[parent[nxt]] @ local[nxt]
            in_scene[nxt] = in_scene[parent[nxt]] | listed[nxt]
            visible[nxt] &= visible[parent[nxt]]
            order.append(nxt)
            seen += len(nxt)
        level = nxt
    if seen < n:
        # With one parent per node, the nodes never reached from a root lie on a cycle.
        reached = np.zeros(n, bool)
        reached[np.concatenate(order)] = True
        first = int(np.flatnonzero(~reached)[0])
        raise SceneError(f"the node graph has a cycle (through node {first})")
    warnings = [f"node {names[i]!r}: its matrix is not affine (bottom row "
                f"{brief(m_values[k][3::4])}, not [0, 0, 0, 1]); drawn with [0, 0, 0, 1]"
                for k, i in enumerate(m_rows) if projective[k] and in_scene[i]]
    warnings += [f"node {names[i]!r}: its matrix shears (two of its axes are {shear[k]:.3g} "
                 "degrees from perpendicular), which glTF does not allow (a node matrix must "
                 "decompose into translation, rotation and scale); drawn as written, where a "
                 "viewer that decomposes it draws another shape"
                 for k, i in enumerate(m_rows) if sheared[k] and in_scene[i]]
    with_matrix = np.zeros(n, bool)
    with_matrix[m_rows] = True  # a matrix wins over TRS: its rotation is not used
    warnings += [f"node {names[i]!r}: its rotation has length {length[i]:.3g}, not 1; "
                 + ("normalized" if length[i] > 0 else "no rotation is used")
                 for i in np.flatnonzero(off_unit & in_scene & ~with_matrix).tolist()]
    warnings += [w for i, ws in visibility_warnings.items() if in_scene[i] for w in ws]
    return NodeGraph(nodes, local, world, parent, np.concatenate(order), in_scene, visible,
                     refs["mesh"], refs["skin"], refs["camera"], cast, receive, special, names,
                     warnings)
