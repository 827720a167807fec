"""Admission control: what a glTF document asks of the loader, counted from its JSON alone.

:func:`admit` runs after the JSON is parsed and before anything else reads it (the node graph,
the extensions, any buffer), so that a small file asking for a lot of work is refused in
milliseconds: a 100,000-deep node chain, a 65,535-node tree, one mesh listing a primitive
20,000 times, accessors whose counts add up to more triangles or decoded bytes than the limits
allow. It also refuses, wherever they are in the document, buffer and image URIs that could
leave the upload (:func:`~shadowmap.renderer.scene.safe_uri`).

The walk is tolerant: what it cannot count (a malformed node, an index out of range) it leaves
for the loader, which refuses it with a :class:`~shadowmap.renderer.errors.SceneError` naming
the field; what it counts is what the loader would do with a valid document, so nothing that
passes here costs more than the limits allow. Each node, mesh and accessor is looked at a
bounded number of times, and nothing recurses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypeGuard

from ..errors import SceneError
from ..limits import Limits, check_count, check_decoded_bytes
from ..scene import safe_uri
from .extensions import gpu_instancing
from .primitives import TRIANGLES, triangle_count
from .reader import extension, is_data_uri

#: Elements per accessor type; decoded accessors become float64 arrays (``read_float``).
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_DECODED_BYTES = 8


@dataclass(frozen=True)
class DocumentCounts:
    """What a document asks the loader to build, from its JSON alone.

    Attributes
    ----------
    nodes : int
        Nodes in the file.
    depth : int
        Levels of the node hierarchy (0 without nodes).
    instances : int
        Drawn instances: the scene's nodes with a mesh, an ``EXT_mesh_gpu_instancing`` node
        counting its instances (a skinned one counts once, as the loader draws it).
    primitives : int
        Primitives drawn, summed over every use of a mesh.
    triangles : int
        Triangles the accessors' counts imply, counting every instance.
    decoded_bytes : int
        Bytes the drawn primitives' distinct accessors (attributes, indices, morph targets,
        instance transforms) decode to, as float64.
    """

    nodes: int
    depth: int
    instances: int
    primitives: int
    triangles: int
    decoded_bytes: int


def _is_index(value: Any, length: int) -> TypeGuard[int]:
    """Whether ``value`` is an index into ``length`` items (an int, not a bool)."""
    return type(value) is int and 0 <= value < length


def _list(doc: dict[str, Any], key: str) -> list[Any]:
    value = doc.get(key, [])
    return value if isinstance(value, list) else []


def check_uris(doc: dict[str, Any]) -> None:
    """Refuse any buffer or image URI that could leave the upload, used or not.

    Raises
    ------
    SceneError
        As :func:`~shadowmap.renderer.scene.safe_uri`, naming the buffer or image.
    """
    for key, kind in (("buffers", "buffer"), ("images", "image")):
        for i, spec in enumerate(_list(doc, key)):
            if isinstance(spec, dict) and "uri" in spec:
                uri = spec["uri"]
                if isinstance(uri, str) and not is_data_uri(uri):
                    safe_uri(uri, f"{kind} {i}")


class _Counter:
    """One pass over the JSON that counts what :class:`DocumentCounts` holds."""

    def __init__(self, doc: dict[str, Any]) -> None:
        self.doc = doc
        self.nodes = _list(doc, "nodes")
        self.meshes = _list(doc, "meshes")
        self.accessors = _list(doc, "accessors")
        self._mesh_triangles: dict[int, int] = {}

    def accessor_count(self, index: Any) -> int:
        """The declared count of an accessor, 0 when there is no such valid accessor (the
        loader refuses it when it is read)."""
        if not _is_index(index, len(self.accessors)):
            return 0
        spec = self.accessors[index]
        count = spec.get("count") if isinstance(spec, dict) else None
        return count if type(count) is int and count > 0 else 0

    def accessor_bytes(self, index: int) -> int:
        """Bytes accessor ``index`` decodes to (an unknown type counted as the largest)."""
        count = self.accessor_count(index)
        kind = self.accessors[index].get("type") if count else None
        components = _COMPONENTS.get(kind, 16) if isinstance(kind, str) else 16
        return count * components * _DECODED_BYTES

    def hierarchy(self, limits: Limits | None) -> tuple[list[bool], int]:
        """Which nodes the drawn scene holds, and the hierarchy's depth.

        Both as the loader's graph computes them: level by level from the parentless nodes.
        The walk stops at the first level over ``max_depth``.
        """
        n = len(self.nodes)
        children: list[list[int]] = [[] for _ in range(n)]
        has_parent = [False] * n
        links = 0
        for i, node in enumerate(self.nodes):
            kids = node.get("children") if isinstance(node, dict) else None
            if not isinstance(kids, list):
                continue
            # A forest has fewer child links than nodes: more means a node with two parents
            # or a child that is not a node, which the loader refuses anyway. Checked before
            # the list is read, so that millions of entries cost nothing.
            links += len(kids)
            if links > n:
                raise SceneError("malformed glTF: the nodes list more children than there are "
                                 "nodes, so some node has two parents or a child is not a node "
                                 "(the node graph must be a forest)")
            for c in kids:
                if _is_index(c, n) and not has_parent[c]:
                    has_parent[c] = True
                    children[i].append(c)
        listed = [False] * n
        scenes = _list(self.doc, "scenes")
        index = self.doc.get("scene")
        if _is_index(index, len(scenes)) and isinstance(scenes[index], dict):
            roots = scenes[index].get("nodes", [])
            if isinstance(roots, list):
                if len(roots) > n:
                    raise SceneError(f"malformed glTF: scene {index} lists {len(roots)} nodes, "
                                     f"more than the file's {n}")
                for r in roots:
                    if _is_index(r, n):
                        listed[r] = True
        else:
            listed = [not p for p in has_parent]
        in_scene = [False] * n
        level = [i for i in range(n) if not has_parent[i]]
        for i in level:
            in_scene[i] = listed[i]
        depth = 0
        while level:
            depth += 1
            if limits is not None:
                # Refused at the first level over the limit: the rest is not walked.
                check_count("max_depth", depth, limits, at_least=True)
            nxt: list[int] = []
            for p in level:
                for c in children[p]:
                    in_scene[c] = in_scene[p] or listed[c]
                    nxt.append(c)
            level = nxt
        return in_scene, depth

    def mesh_triangles(self, m: int) -> int:
        """Triangles one use of mesh ``m`` declares (indices, else POSITION counts)."""
        cached = self._mesh_triangles.get(m)
        if cached is not None:
            return cached
        total = 0
        for prim in self.primitives_of(m):
            if not isinstance(prim, dict):
                continue
            mode = prim.get("mode", TRIANGLES)
            if type(mode) is not int:
                continue
            attrs = prim.get("attributes")
            acc = prim.get("indices")
            if acc is None and isinstance(attrs, dict):
                acc = attrs.get("POSITION")
            total += triangle_count(mode, self.accessor_count(acc))
        self._mesh_triangles[m] = total
        return total

    def primitives_of(self, m: int) -> list[Any]:
        spec = self.meshes[m]
        prims = spec.get("primitives") if isinstance(spec, dict) else None
        return prims if isinstance(prims, list) else []

    def mesh_accessors(self, m: int, into: set[int]) -> None:
        """Add the accessors the primitives of mesh ``m`` read to ``into``."""
        for prim in self.primitives_of(m):
            if not isinstance(prim, dict):
                continue
            sources: list[Any] = [prim.get("attributes"), *_list(prim, "targets")]
            for attrs in sources:
                if isinstance(attrs, dict):
                    into.update(a for a in attrs.values() if _is_index(a, len(self.accessors)))
            if _is_index(prim.get("indices"), len(self.accessors)):
                into.add(prim["indices"])

    def skin(self, node: dict[str, Any]) -> tuple[int, int, int | None]:
        """(skin index, its joint count, its inverseBindMatrices accessor) of a skinned mesh
        node; (-1, 0, None) for any other."""
        skins = _list(self.doc, "skins")
        s = node.get("skin")
        if not _is_index(s, len(skins)) or not isinstance(skins[s], dict):
            return -1, 0, None
        joints = skins[s].get("joints")
        ibm = skins[s].get("inverseBindMatrices")
        return (s, len(joints) if isinstance(joints, list) else 0,
                ibm if _is_index(ibm, len(self.accessors)) else None)

    def instance_count(self, node: dict[str, Any]) -> tuple[int, list[int]]:
        """Instances one mesh node draws, and the accessors of its instance transforms."""
        ext = extension(node, gpu_instancing.EXTENSION)
        if ext is None or "skin" in node:
            return 1, []  # a skinned node's instances are drawn once (see the loader)
        attrs = ext.get("attributes")
        if not isinstance(attrs, dict):
            return 1, []
        used = [a for a in attrs.values() if _is_index(a, len(self.accessors))]
        count = max((self.accessor_count(a) for a in used), default=0)
        return (count or 1), used


def admit(doc: dict[str, Any], limits: Limits | None) -> DocumentCounts:
    """Count what ``doc`` asks for and refuse it when over a limit, before any other work.

    Order, cheapest first: the URIs; the node count (a length); the hierarchy's depth (stopped
    at ``max_depth``); instances and primitives (lengths, per drawn node); triangles and decoded
    bytes (per distinct mesh and accessor, at most ``max_primitives`` primitives read).

    Parameters
    ----------
    doc : dict
        The parsed glTF JSON.
    limits : Limits or None
        None counts without refusing (the URIs are still checked).

    Returns
    -------
    DocumentCounts

    Raises
    ------
    LimitError
        ``max_nodes``, ``max_depth``, ``max_instances``, ``max_primitives``, ``max_triangles``
        or ``max_request_bytes`` (the decoded accessors).
    SceneError
        An unsafe URI; more child links than nodes; a scene listing more nodes than exist.
    """
    check_uris(doc)
    c = _Counter(doc)
    n = len(c.nodes)
    if limits is not None:
        check_count("max_nodes", n, limits, where="the file")
    in_scene, depth = c.hierarchy(limits)
    drawn: list[tuple[int, int, list[int]]] = []  # (mesh, instances, accessors of the node)
    instances = primitives = 0
    skins: dict[int, int] = {}  # the drawn skins' joint counts
    for i in range(n):
        node = c.nodes[i]
        if not in_scene[i] or not isinstance(node, dict):
            continue
        m = node.get("mesh")
        if not _is_index(m, len(c.meshes)):
            continue
        k, used = c.instance_count(node)
        s, joints, ibm = c.skin(node)
        if s >= 0:
            skins[s] = joints
            used = used + ([ibm] if ibm is not None else [])
        instances += k
        primitives += len(c.primitives_of(m))
        drawn.append((m, k, used))
    if limits is not None:
        check_count("max_instances", instances, limits)
        check_count("max_primitives", primitives, limits)
        # Joints are nodes, and each skin's joint matrices are computed from its list: the drawn
        # skins together may list as many joints as the file may hold nodes.
        check_count("max_nodes", sum(skins.values()), limits, noun="joints in its drawn skins")
    triangles = sum(k * c.mesh_triangles(m) for m, k, _ in drawn)
    if limits is not None:
        check_count("max_triangles", triangles, limits,
                    noun="triangles (as its accessors declare, counting every instance)")
    accessors: set[int] = set()
    for m in {m for m, _, _ in drawn}:
        c.mesh_accessors(m, accessors)
    for _, _, used in drawn:
        accessors.update(used)
    decoded = sum(c.accessor_bytes(a) for a in accessors)
    if limits is not None:
        check_decoded_bytes(decoded, limits)
    return DocumentCounts(n, depth, instances, primitives, triangles, decoded)
