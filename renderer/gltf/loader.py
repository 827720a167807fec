"""A glTF document to the renderer's scene parts: primitives, instances, cameras, lights, and
warnings for everything dropped or approximated.

Order of work, cheapest first, so a scene refused by a check decodes nothing: the container and
``asset``; the admission check from the JSON alone (:mod:`.admission`: URIs, node count,
hierarchy depth, instances, primitives, declared triangles and decoded bytes against the limits);
``extensionsRequired``; the node graph; then the data each drawn mesh needs, each mesh decoded
once per distinct (skin, morph weights) use, and instances built per mesh in vectorised steps.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import SceneError, UnsupportedExtension
from ..limits import MAX_COORDINATE, Limits
from ..scene import (
    FLOAT32_MAX,
    Instance,
    Material,
    Primitive,
    SceneCamera,
    SceneLight,
    _vertex_normals,
    world_bounds_many,
)
from . import morph, skin
from .accessors import DOUBLE, UNSIGNED_BYTE, UNSIGNED_INT, UNSIGNED_SHORT, Accessors, check_type
from .admission import admit
from .extensions import (
    check_extensions,
    gpu_instancing,
    lights_punctual,
    mesh_quantization,
    primitive_restart,
    uses,
)
from .extensions import texture_transform as tt
from .materials import Materials, MaterialUse, clamp_colour
from .nodes import INVALID, NodeGraph, build_graph
from .primitives import MODE_NAMES, RESTART, TRIANGLES, triangulate
from .reader import Buffers, Document, Resolver, brief, extension, get_index, get_list

DRACO = "KHR_draco_mesh_compression"
INSTANCING = gpu_instancing.EXTENSION
#: Texture coordinates beyond this are moved towards 0 by whole repeats: float32 keeps
#: 2**-13 of a repeat at 1024 (a quarter texel of a 2048-texel image), less beyond.
_UV_SHIFT_FROM = 1024.0
_INDEX_COMPONENTS = frozenset({(UNSIGNED_BYTE, False), (UNSIGNED_SHORT, False),
                               (UNSIGNED_INT, False)})

#: (mesh, skin or -1, morph weights, node for skinned uses or -1): one decoded mesh.
_UseKey = tuple[int, int, tuple[float, ...], int]


@dataclass
class LoadedGltf:
    """What :func:`load_gltf` returns: the parts of a :class:`~shadowmap.renderer.scene.Scene`.

    Attributes
    ----------
    primitives, instances, cameras, lights
        As in ``Scene``.
    warnings : list of str
        Everything dropped or approximated, each once, in the order met.
    arrays : dict of str to ndarray
        The instances as arrays (``primitive``, ``matrices``, ``bounds``, ``receive``, as in
        :class:`~shadowmap.renderer.scene.InstanceArrays`), which the loader builds anyway.
    """

    primitives: list[Primitive]
    instances: list[Instance]
    cameras: list[SceneCamera] = field(default_factory=list)
    lights: list[SceneLight] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def load_gltf(document: Document, resolver: Resolver,
              limits: Limits | None = None) -> LoadedGltf:
    """Decode a parsed glTF container into scene parts.

    Parameters
    ----------
    document : Document
        From :func:`~shadowmap.renderer.gltf.reader.read_container`.
    resolver : Resolver
        External buffers and images by relative name.
    limits : Limits, optional
        Refuse, from the JSON alone and before anything else, a document over a limit
        (:func:`~shadowmap.renderer.gltf.admission.admit`: nodes, depth, instances, primitives,
        triangles, decoded bytes); hold decoded textures to ``max_texture_pixels``.

    Raises
    ------
    UnsupportedExtension
        A required extension is not implemented (or its decoder is not installed).
    LimitError
        A limit of ``limits``.
    SceneError
        Malformed, inconsistent or unsafe content; nothing drawable.
    """
    admit(document.json, limits)
    return _Loader(document, resolver, limits).load()


#: A node matrix's axis shorter than this share of its longest counts as lost (a zero scale).
LOST_AXIS = 1e-12


def _orthonormal_pose(m: np.ndarray) -> tuple[np.ndarray, bool, bool]:
    """A camera's or light's pose from its node's world matrix: position, and a rotation whose
    -Z is the way the node's -Z axis points and whose +Y is the node's +Y made perpendicular
    to it; (pose, whether the matrix mirrors, whether it has no orientation left).

    glTF has a camera look, and a light shine, along its node's -Z axis as the world matrix
    carries it. Under a non-uniform scale and a turn (a scaled parent, a turned child) that
    matrix shears, and its nearest rotation (the polar decomposition) points elsewhere: 27
    degrees off for a turn of 45 under a scale of 3. A mirroring matrix (a negative scale)
    keeps its -Z and +Y here, so its picture is drawn unmirrored; posed by the mirror itself, a
    camera's frustum would wind every face the other way and cull it.

    A zero scale (glTF allows it, often to hide a node) loses an axis: a lost -Z is the cross
    product of the other two, a lost +Y comes from the +X axis. With two or three lost there is
    no orientation to read.
    """
    pose = np.eye(4)
    pose[:3, 3] = m[:3, 3]
    axes = np.array(m[:3, :3].T, np.float64)  # rows: the node's x, y and z axes in the world
    length = np.linalg.norm(axes, axis=1)
    kept = length > LOST_AXIS * length.max()
    if kept.sum() < 2:
        return pose, False, True
    axes[kept] /= length[kept, None]
    x, y, z = axes
    mirrored = bool(kept.all() and np.linalg.det(m[:3, :3]) < 0)
    if not kept[2]:
        z = np.cross(x, y)
        z /= np.linalg.norm(z)
    right = np.cross(y, z) if kept[1] else x - (x @ z) * z  # +X: +Y x +Z
    size = np.linalg.norm(right)
    if not size > LOST_AXIS:  # +Y along -Z: the +X axis stands in for it
        right = x - (x @ z) * z
        size = np.linalg.norm(right)
        if not size > LOST_AXIS:
            return pose, mirrored, True
    right /= size
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(z, right), z
    return pose, mirrored, False


def _faceless(node: str, what: str) -> str:
    return (f"node {node!r} has a transform that keeps at most one axis (zero scales): the "
            f"way its {what} faces cannot be read; left out")


def _flag(extras: Any, key: str) -> int:
    if isinstance(extras, dict) and isinstance(extras.get(key), bool):
        return int(extras[key])
    return -1


def _as_float(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, np.float64)


@dataclass
class _Record:
    """Instances of one primitive: the nodes drawing it, their matrices, and for
    EXT_mesh_gpu_instancing the instance number of each (None otherwise)."""

    nodes: np.ndarray  # (K,) int64
    primitive: int
    matrices: np.ndarray  # (K, 4, 4) float64
    sub: np.ndarray | None  # (K,) int64


class _Loader:
    def __init__(self, document: Document, resolver: Resolver,
                 limits: Limits | None = None) -> None:
        self.doc = document.json
        self.warnings: list[str] = check_extensions(self.doc)
        required = self.doc.get("extensionsRequired", [])
        self.required = ({r for r in required if isinstance(r, str)}
                         if isinstance(required, list) else set())
        self.graph: NodeGraph = build_graph(self.doc)
        self.warnings += self.graph.warnings
        self.restarts = uses(self.doc, primitive_restart.EXTENSION)
        self.meshes = get_list(self.doc, "meshes")
        self.skins = get_list(self.doc, "skins")
        self.buffers = Buffers(document, resolver)
        self.accessors = Accessors(self.buffers)
        self.materials = Materials(self.buffers, resolver, self.warnings,
                                   None if limits is None else limits.max_texture_pixels)
        self._joint_matrices: dict[int, np.ndarray] = {}
        self.primitives: list[Primitive] = []
        self._uses: dict[_UseKey, list[int | None]] = {}
        self._left_out: list[str] = []
        self.arrays: dict[str, np.ndarray] = {}
        # Primitives stored relative to their box centre (float64 positions,
        # KHR_accessor_float64): the centre, which their instances' matrices take on.
        self._centres: dict[int, np.ndarray] = {}

    def _mesh_spec(self, m: int) -> dict[str, Any]:
        spec = self.meshes[m]
        if not isinstance(spec, dict) or not isinstance(spec.get("primitives"), list):
            raise SceneError(f"malformed glTF: mesh {m} has no 'primitives' array")
        return spec

    # -- loading ---------------------------------------------------------------------------

    def load(self) -> LoadedGltf:
        instances = self._instances()
        if not instances:
            detail = "; ".join(self._left_out[:5]) or "no mesh node in the scene"
            more = f" (and {len(self._left_out) - 5} more)" if len(self._left_out) > 5 else ""
            raise SceneError(f"the scene has no triangles to render (left out: {detail}{more})")
        cameras, lights = self._cameras_and_lights()
        warnings = list(dict.fromkeys(self.warnings + self.buffers.warnings))
        return LoadedGltf(self.primitives, instances, cameras, lights, warnings, self.arrays)

    def _instances(self) -> list[Instance]:
        g = self.graph
        nodes = np.flatnonzero(g.in_scene & g.visible & (g.mesh >= 0))
        mesh_cast = np.full(len(self.meshes), -1, np.int8)
        mesh_receive = np.full(len(self.meshes), -1, np.int8)
        for m in np.unique(g.mesh[nodes]):
            extras = self._mesh_spec(int(m)).get("extras")
            mesh_cast[m] = _flag(extras, "castShadow")
            mesh_receive[m] = _flag(extras, "receiveShadow")
        # Records of (node, primitive, matrices (K, 4, 4)), grouped so that the many nodes that
        # draw one mesh plainly share one decode and one vectorised bounds computation.
        records: list[_Record] = []
        plain = nodes[(g.skin[nodes] < 0) & ~g.special[nodes]]
        plain = plain[np.argsort(g.mesh[plain], kind="stable")]
        meshes, starts = np.unique(g.mesh[plain], return_index=True)
        groups = np.split(plain, starts[1:]) if len(plain) else []
        for m, group in zip(meshes.tolist(), groups, strict=True):
            prims = self._mesh_use((m, -1, self._weights(m, None), -1))
            self._check_finite(group)
            for p in prims:
                if p is not None:
                    records.append(_Record(group, p, g.world[group], None))
        for i in nodes[(g.skin[nodes] >= 0) | g.special[nodes]]:
            records.extend(self._special_node(int(i)))
        if not records:
            return []
        cast = np.where(g.cast >= 0, g.cast, mesh_cast[np.maximum(g.mesh, 0)]) != 0
        receive = np.where(g.receive >= 0, g.receive, mesh_receive[np.maximum(g.mesh, 0)]) != 0
        # Every record's instances as parallel arrays, in file order (node, instance,
        # primitive), then one Instance object each: the objects are built by map() over the
        # arrays' rows, with nothing but their construction left in Python per instance.
        node = np.concatenate([r.nodes for r in records])
        sub = np.concatenate([r.sub if r.sub is not None else np.zeros(len(r.nodes), np.int64)
                              for r in records])
        prim = np.concatenate([np.full(len(r.nodes), r.primitive, np.intp) for r in records])
        with np.errstate(over="ignore", invalid="ignore"):  # refused just below
            placed = [self._placed(r) for r in records]
            matrices = np.concatenate(placed)
            bounds = np.concatenate([
                world_bounds_many(self.primitives[r.primitive].local_bounds.astype(np.float64),
                                  mats) for r, mats in zip(records, placed, strict=True)])
        if not np.isfinite(bounds).all():
            raise SceneError("the scene's transforms and positions overflow: an instance "
                             "reaches past 1e308 units")
        order = np.lexsort((prim, sub, node))
        node, sub, prim = node[order], sub[order], prim[order]
        matrices, bounds = matrices[order], bounds[order]
        names = [g.names[i] for i in node.tolist()]
        numbered = np.zeros(len(node), bool)
        start = 0
        for r in records:  # EXT_mesh_gpu_instancing instances are named "<node>#<instance>"
            numbered[start:start + len(r.nodes)] = r.sub is not None
            start += len(r.nodes)
        numbered = numbered[order]
        for k in np.flatnonzero(numbered).tolist():
            names[k] = f"{names[k]}#{int(sub[k])}"
        # Read-only, so that the Instance objects' matrices and bounds, views of their rows, are
        # born read-only (a change in place would go unseen by a renderer's caches) and the
        # scene's arrays can be these same ones.
        matrices.setflags(write=False)
        bounds.setflags(write=False)
        self.arrays = {"primitive": prim, "matrices": matrices, "bounds": bounds,
                       "receive": receive[node]}
        return list(map(Instance, prim.tolist(), matrices, cast[node].tolist(),
                        receive[node].tolist(), names, bounds))

    def _check_finite(self, nodes: np.ndarray) -> None:
        bad = ~np.all(np.isfinite(self.graph.world[nodes]), axis=(1, 2))
        if bad.any():
            i = int(nodes[bad][0])
            raise SceneError(f"node {self.graph.names[i]!r} has a non-finite transform")

    def _weights(self, m: int, node: dict[str, Any] | None) -> tuple[float, ...]:
        w = morph.default_weights(self._mesh_spec(m), node)
        return w if any(w) else ()

    def _special_node(self, i: int) -> list[_Record]:
        """Records for a skinned, morph-weighted or instanced node."""
        g = self.graph
        node = g.nodes[i]
        m = int(g.mesh[i])
        s = int(g.skin[i])
        weights = self._weights(m, node)
        one = np.array([i], np.int64)
        ext = extension(node, INSTANCING)
        if s >= 0:
            if ext is not None:
                self.warnings.append(f"node {g.names[i]!r} is skinned: its {INSTANCING} "
                                     "instances are drawn once")
            self._check_finite(one)
            prims = self._mesh_use((m, s, weights, i))
            # Skinned vertices are in world space already.
            return [_Record(one, p, np.eye(4)[None], None) for p in prims if p is not None]
        self._check_finite(one)
        prims = self._mesh_use((m, -1, weights, -1))
        local = None
        if ext is not None:
            local = gpu_instancing.instance_matrices(ext, self.accessors,
                                                     f"node {g.names[i]!r}", self.warnings)
        if local is None:
            return [_Record(one, p, g.world[one], None) for p in prims if p is not None]
        mats = g.world[i] @ local
        bad = ~np.all(np.isfinite(mats), axis=(1, 2))
        if bad.any():
            raise SceneError(f"node {g.names[i]!r}: {INSTANCING} instance "
                             f"{int(np.flatnonzero(bad)[0])} has a non-finite transform")
        k = len(mats)
        return [_Record(np.full(k, i, np.int64), p, mats, np.arange(k))
                for p in prims if p is not None]

    def _placed(self, r: _Record) -> np.ndarray:
        """The record's instance matrices, shape (K, 4, 4), with its primitive's centre moved
        in when the primitive is stored relative to it (float64 positions)."""
        centre = self._centres.get(r.primitive)
        if centre is None:
            return r.matrices
        move = np.eye(4)
        move[:3, 3] = centre
        return r.matrices @ move

    # -- meshes ----------------------------------------------------------------------------

    def _mesh_use(self, key: _UseKey) -> list[int | None]:
        """Primitive indices (None where dropped) of one use of a mesh, decoded once."""
        cached = self._uses.get(key)
        if cached is not None:
            return cached
        m, s, weights, node = key
        spec = self._mesh_spec(m)
        name = spec.get("name") if isinstance(spec.get("name"), str) else ""
        out: list[int | None] = []
        for p, prim in enumerate(spec["primitives"]):
            what = f"mesh {m} ({brief(name)}) primitive {p}" if name else f"mesh {m} primitive {p}"
            made = self._primitive(m, p, prim, s, weights, node, what)
            if made is None:
                out.append(None)
                continue
            built, centre = made
            built = dataclasses.replace(built, name=(name or f"mesh_{m}") + (f"_{p}" if p else ""))
            if centre is not None:
                self._centres[len(self.primitives)] = centre
            out.append(len(self.primitives))
            self.primitives.append(built)
        self._uses[key] = out
        return out

    def _drop(self, what: str, reason: str) -> None:
        message = f"{what}: {reason}"
        self.warnings.append(message)
        self._left_out.append(message)

    def _primitive(self, m: int, p: int, prim: Any, s: int, weights: tuple[float, ...],
                   node: int, what: str) -> tuple[Primitive, np.ndarray | None] | None:
        """The primitive, and the centre its positions are stored relative to (float64
        positions) or None; None when it is left out."""
        if not isinstance(prim, dict):
            raise SceneError(f"malformed glTF: {what} is not an object")
        mode = prim.get("mode", TRIANGLES)
        if isinstance(mode, bool) or not isinstance(mode, int) or mode not in (4, 5, 6):
            if isinstance(mode, int) and mode in MODE_NAMES:
                self._drop(what, f"mode {mode} ({MODE_NAMES[mode]}) is left out: only "
                           "triangles are drawn")
            else:
                self._drop(what, f"unknown mode {brief(mode)}: left out")
            return None
        attrs = prim.get("attributes")
        if not isinstance(attrs, dict):
            raise SceneError(f"{what}: 'attributes' is not an object")
        draco_ext = extension(prim, DRACO)
        decoded = self._draco(draco_ext, attrs, what) if draco_ext is not None else {}

        # POSITION: refused when of the wrong type (it is the one attribute that must be right).
        if "POSITION" not in attrs and "POSITION" not in decoded:
            self._drop(what, "no POSITION attribute: left out")
            return None
        double = False
        if "POSITION" in decoded:
            positions = _as_float(decoded["POSITION"])
        else:
            pos_index = self._accessor_index(attrs, "POSITION", what)
            pos_info = self.accessors.info(pos_index)
            reason = check_type(pos_info, {"VEC3"}, mesh_quantization.POSITION,
                                f"{what} POSITION")
            if reason:
                raise SceneError(reason)
            positions = self.accessors.read_float(pos_index)
            double = pos_info.component_type == DOUBLE
        n = len(positions)

        # Indices, checked, then one triangle list.
        if decoded:
            indices = np.asarray(decoded["indices"], np.int64).reshape(-1)
            restart = None
            mode = TRIANGLES  # Draco streams decode to triangle lists
        elif "indices" in prim:
            idx = get_index(prim, "indices", len(self.accessors), what, required=True)
            assert idx is not None
            info = self.accessors.info(idx)
            reason = check_type(info, {"SCALAR"}, _INDEX_COMPONENTS, f"{what} indices")
            if reason:
                self._drop(what, f"{reason}: left out")
                return None
            indices = self.accessors.read(idx).astype(np.int64)
            restart = RESTART[info.component_type]
        else:
            indices, restart = np.arange(n, dtype=np.int64), None
        # Restart values cut strips and fans where the file declares KHR_mesh_primitive_restart;
        # anywhere else glTF forbids them.
        cuts = restart if restart is not None and mode != TRIANGLES and self.restarts else None
        if len(indices):
            top = int(indices.max())
            if top == restart and cuts is not None:
                drawn = indices[indices != restart]
                top = int(drawn.max()) if len(drawn) else -1
            elif restart is not None and top == restart:
                self._drop(what, f"its indices hold the primitive-restart value {restart}: "
                           "left out")
                return None
            if top >= n:
                self._drop(what, f"index {top} is out of range for {n} vertices: left out")
                return None
        if mode == TRIANGLES and len(indices) % 3:
            self.warnings.append(f"{what}: {len(indices)} indices is not a multiple of 3; the "
                                 "last partial triangle is left out")
        faces = triangulate(indices, mode, cuts)
        if len(faces) == 0:
            self._drop(what, "no triangles: left out")
            return None

        # Keep only the vertices the triangles use (a view may serve many primitives).
        used = np.unique(faces)
        if len(used) < n:
            remap = np.full(n, -1, np.int64)
            remap[used] = np.arange(len(used))
            faces = remap[faces]
            sel: np.ndarray | None = used
        else:
            sel = None

        def take(a: np.ndarray) -> np.ndarray:
            return a if sel is None else a[sel]

        normals = self._attribute(attrs, decoded, "NORMAL", {"VEC3"}, mesh_quantization.NORMAL,
                                  n, what)
        if weights:
            positions = morph.apply_targets(positions, prim, "POSITION", weights,
                                            self.accessors, what, self.warnings)
            if normals is not None:
                normals = morph.apply_targets(normals, prim, "NORMAL", weights, self.accessors,
                                              what, self.warnings)
        positions = take(positions)
        normals = None if normals is None else take(normals)
        if s >= 0:
            positions, normals = self._skin(s, node, attrs, decoded, positions, normals, n, take,
                                            what)
        if not np.all(np.isfinite(positions)):
            raise SceneError(f"mesh {m} ({what}) has NaN or infinite vertex positions")

        normals = self._normals(positions, faces, normals, what)
        use = self.materials.get(get_index(prim, "material", len(self.materials.specs), what))
        material, uv = self._uv(use, attrs, decoded, n, take, what)
        colors = self._colors(attrs, decoded, n, take, what)
        centre = None
        if double and len(positions):
            # float64 positions keep their precision: float32 offsets from the box centre, the
            # centre in the instances' float64 matrices (_instance_matrices).
            centre = (positions.min(axis=0) + positions.max(axis=0)) / 2
            positions = positions - centre
        built = Primitive(
            positions=positions.astype(np.float32),
            normals=normals,
            indices=faces.astype(np.uint32),
            material=material,
            uv=uv,
            colors=colors,
        )
        return built, centre

    def _accessor_index(self, attrs: dict[str, Any], semantic: str, what: str) -> int:
        idx = get_index(attrs, semantic, len(self.accessors), f"{what} attribute", required=True)
        assert idx is not None
        return idx

    def _attribute(self, attrs: dict[str, Any], decoded: dict[str, np.ndarray], semantic: str,
                   types: set[str], components: frozenset[tuple[int, bool]], n: int,
                   what: str) -> np.ndarray | None:
        """An optional vertex attribute as float64 (all ``n`` vertices), or None with a
        warning when it cannot be used."""
        if semantic in decoded:
            return _as_float(decoded[semantic])
        if semantic not in attrs:
            return None
        idx = self._accessor_index(attrs, semantic, what)
        info = self.accessors.info(idx)
        reason = check_type(info, types, components, f"{what} {semantic}")
        if reason:
            self.warnings.append(f"{reason}: the attribute is ignored")
            return None
        if info.count != n:
            self.warnings.append(f"{what} {semantic} has {info.count} elements for {n} "
                                 "vertices: the attribute is ignored")
            return None
        return self.accessors.read_float(idx)

    def _normals(self, positions: np.ndarray, faces: np.ndarray,
                 normals: np.ndarray | None, what: str) -> np.ndarray:
        """Unit normals: the file's (renormalized; quantized ones are not unit), computed
        area-weighted ones where the file has none or a vertex's is zero or not finite."""
        computed = None
        if normals is not None:
            with np.errstate(over="ignore", invalid="ignore"):
                length = np.linalg.norm(normals, axis=1, keepdims=True)
            ok = np.isfinite(length[:, 0]) & (length[:, 0] > 1e-12)
            out = np.where(ok[:, None], normals / np.where(ok[:, None], length, 1.0), 0.0)
            if not ok.all():
                computed = _vertex_normals(positions, faces)
                out[~ok] = computed[~ok]
                self.warnings.append(f"{what}: {int((~ok).sum())} normals are zero or not "
                                     "finite; computed from the faces")
            return out.astype(np.float32)
        return _vertex_normals(positions, faces)

    def _skin(self, s: int, node: int, attrs: dict[str, Any], decoded: dict[str, np.ndarray],
              positions: np.ndarray, normals: np.ndarray | None, n: int, take: Any,
              what: str) -> tuple[np.ndarray, np.ndarray | None]:
        # Once per skin, not per primitive: a skin's list may hold thousands of joints.
        mats = self._joint_matrices.get(s)
        if mats is None:
            mats = self._joint_matrices[s] = skin.joint_matrices(self.doc, s, self.graph,
                                                                 self.accessors)
            self.warnings += skin.joint_warnings(self.doc, s, self.graph)
        joints: list[np.ndarray] = []
        weights: list[np.ndarray] = []
        k = 0
        while f"JOINTS_{k}" in attrs or f"JOINTS_{k}" in decoded:
            j = self._attribute(attrs, decoded, f"JOINTS_{k}", {"VEC4"},
                                mesh_quantization.JOINTS, n, what)
            w = self._attribute(attrs, decoded, f"WEIGHTS_{k}", {"VEC4"},
                                mesh_quantization.WEIGHTS, n, what)
            if j is None or w is None:
                break
            joints.append(take(j).astype(np.int64))
            weights.append(take(w))
            k += 1
        if not joints:
            self.warnings.append(f"{what} is skinned (skin {s}) but has no usable JOINTS_0/"
                                 "WEIGHTS_0: drawn with its node's transform")
            joints = [np.zeros((len(positions), 4), np.int64)]
            weights = [np.zeros((len(positions), 4))]
        result = skin.apply_skin(positions, normals, joints, weights, mats,
                                 self.graph.world[node])
        if result.unweighted:
            self.warnings.append(f"{what}: {result.unweighted} vertices have zero skin weights: "
                                 "drawn with their node's transform")
        if result.bad_joints:
            self.warnings.append(f"{what}: {result.bad_joints} skin influences name joints "
                                 f"skin {s} does not have: they are left out")
        return result.positions, result.normals

    def _uv(self, use: MaterialUse, attrs: dict[str, Any], decoded: dict[str, np.ndarray],
            n: int, take: Any, what: str) -> tuple[Material, np.ndarray | None]:
        """The material and, when it is textured, the UVs in the renderer's convention."""
        if use.material.texture is None:
            return use.material, None
        semantic = f"TEXCOORD_{use.tex_coord}"
        raw = self._attribute(attrs, decoded, semantic, {"VEC2"}, mesh_quantization.TEXCOORD,
                              n, what)
        if raw is None:
            self.warnings.append(f"{what}: its {use.name} has a base colour texture but the "
                                 f"primitive has no usable {semantic}: drawn without the "
                                 "texture")
            return use.untextured, None
        uv = take(raw)
        if use.uv_transform is not None:
            uv = tt.apply(uv, use.uv_transform)
        uv = np.asarray(uv, np.float64)
        with np.errstate(invalid="ignore"):
            # Past float32's range a coordinate has no fraction left even in float64.
            finite = (np.abs(uv) <= FLOAT32_MAX).all(axis=1)
        if not finite.all():
            self.warnings.append(f"{what}: {int((~finite).sum())} texture coordinates "
                                 f"({semantic}) are not finite in float32; drawn as (0, 0)")
            uv = np.where(finite[:, None], uv, 0.0)
        if len(uv) and np.abs(uv).max() > _UV_SHIFT_FROM:
            # Far from 0, float32 keeps few bits of a repeat. A repeated (or mirrored) texture
            # has a period of 2 units, so moving the primitive's coordinates by an even integer
            # towards 0 samples the same texels; a clamped axis is left as it is (its far
            # coordinates read the edge texels). What then still spans too far is said.
            periodic = np.asarray(use.material.sampler.periodic)
            uv = uv - np.where(periodic, 2.0 * np.floor(uv.min(axis=0) / 2.0), 0.0)
            span = float(uv[:, periodic].max(initial=0.0))
            if span > _UV_SHIFT_FROM:
                uv = np.minimum(uv, FLOAT32_MAX)  # a span past float32's range: its edge
                # float32's step at the span; from 2**24 on, whole repeats at best.
                kept = (f"to {float(np.spacing(np.float32(span))):.2g} of a repeat"
                        if span < 2.0**24 else "no fraction of a repeat")
                self.warnings.append(
                    f"{what}: its texture coordinates ({semantic}) span {span:.3g} repeats: "
                    f"float32 keeps {kept}")
        # Primitive.uv is in OpenGL's convention (v = 1 - glTF v): the renderer and the
        # reference sample the image, stored top row first, at row (1 - v) * height.
        out = np.empty_like(uv, dtype=np.float32)
        out[:, 0] = uv[:, 0]
        out[:, 1] = 1.0 - uv[:, 1]
        return use.material, out

    def _colors(self, attrs: dict[str, Any], decoded: dict[str, np.ndarray], n: int, take: Any,
                what: str) -> np.ndarray | None:
        raw = self._attribute(attrs, decoded, "COLOR_0", {"VEC3", "VEC4"},
                              mesh_quantization.COLOR, n, what)
        if raw is None:
            return None
        c = take(raw)
        if c.shape[1] == 3:
            c = np.concatenate([c, np.ones((len(c), 1))], axis=1)
        finite = np.isfinite(c)
        if not finite.all():
            self.warnings.append(f"{what}: {int((~finite).any(axis=1).sum())} vertex colours "
                                 "(COLOR_0) are not finite; drawn white")
            c = np.where(finite, c, 1.0)
        # A float COLOR_0 may hold anything: clamped to glTF's range, and said.
        clamped, outside = clamp_colour(c)
        if outside:
            self.warnings.append(f"{what}: vertex colours (COLOR_0) outside [0, 1] "
                                 f"(from {c.min():.3g} to {c.max():.3g}); clamped")
        c = clamped
        if np.allclose(c, 1.0):
            return None  # all-white vertex colours change nothing: leave the path out
        return c.astype(np.float32)

    # -- Draco -----------------------------------------------------------------------------

    def _draco(self, ext: dict[str, Any], attrs: dict[str, Any],
               what: str) -> dict[str, np.ndarray]:
        """The decoded arrays of a Draco primitive (empty: use the accessors)."""
        view = get_index(ext, "bufferView", len(self.buffers.views), f"{what} {DRACO}",
                         required=True)
        assert view is not None
        mapping = ext.get("attributes", {})
        if not isinstance(mapping, dict) or not all(
                isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool)
                for k, v in mapping.items()):
            raise SceneError(f"{what}: {DRACO} 'attributes' must map semantics to integer ids")
        try:
            from .extensions.draco import decode_primitive
        except ImportError as exc:
            plain = all(isinstance(attrs.get(sem), int) and 0 <= attrs[sem] < len(self.accessors)
                        and isinstance(self.accessors.specs[attrs[sem]], dict)
                        and "bufferView" in self.accessors.specs[attrs[sem]] for sem in mapping)
            if plain and DRACO not in self.required:
                self.warnings.append(f"{what}: no Draco decoder ({exc}); its uncompressed "
                                     "fallback accessors are used")
                return {}
            raise UnsupportedExtension(
                [DRACO], f"{what} is Draco-compressed and the Draco decoder is not available "
                f"({exc})") from None
        data = self.buffers.view(view)
        try:
            out = decode_primitive(data, dict(mapping))
        except SceneError as exc:
            raise SceneError(f"{what}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a decoder fed untrusted bytes may raise anything
            raise SceneError(f"{what}: the Draco data cannot be decoded: "
                             f"{type(exc).__name__}: {exc}") from None
        if "indices" not in out or "POSITION" not in out:
            raise SceneError(f"{what}: the Draco stream has no indices or no POSITION")
        n = len(out["POSITION"])
        for key, arr in out.items():
            if key != "indices" and (arr.ndim != 2 or len(arr) != n):
                raise SceneError(f"{what}: Draco attribute {key} has shape {arr.shape} for {n} "
                                 "points")
        if out["POSITION"].shape[1] != 3:
            raise SceneError(f"{what}: Draco POSITION is not 3-component")
        return {k: v for k, v in out.items() if k == "indices" or k in mapping}

    # -- cameras and lights ----------------------------------------------------------------

    def _cameras_and_lights(self) -> tuple[list[SceneCamera], list[SceneLight]]:
        g = self.graph
        cams = get_list(self.doc, "cameras")
        lights = lights_punctual.document_lights(self.doc)
        cameras: list[SceneCamera] = []
        out_lights: list[SceneLight] = []
        candidates = np.flatnonzero(g.in_scene & ((g.camera != -1) | g.special))
        box = self.arrays["bounds"]
        # The upload is placed at the centre of the scene's box: a camera or positioned light
        # float32 cannot place relative to it is left out (a request's is refused).
        centre = (box[:, 0].min(axis=0) + box[:, 1].max(axis=0)) / 2
        for i in candidates.tolist():
            node = g.nodes[i]
            # A hidden node's light does not shine; its camera is still one (KHR_node_visibility).
            has_light = lights_punctual.names_extension(node) and bool(g.visible[i])
            if g.camera[i] == INVALID:
                self.warnings.append(f"node {g.names[i]!r}: camera {brief(node.get('camera'))} "
                                     "does not exist: left out")
            if g.camera[i] < 0 and not has_light:
                continue
            pose, mirrored, faceless = (
                _orthonormal_pose(g.world[i]) if np.all(np.isfinite(g.world[i]))
                else (None, False, False))
            if pose is None or not np.all(np.isfinite(pose)):
                self.warnings.append(f"node {g.names[i]!r} has a non-finite transform: its "
                                     "camera or light is left out")
                continue
            with np.errstate(over="ignore", invalid="ignore"):
                reach = float(np.max(np.abs(pose[:3, 3] - centre)))
            far = (f"node {g.names[i]!r} is {reach:.3g} units from the scene's centre, more "
                   "than float32 coordinates hold: its ")  # + what is left out
            if g.camera[i] >= 0:
                cam = self._camera(cams[int(g.camera[i])], pose, int(g.camera[i]),
                                   g.world[i])
                if cam is not None and faceless:
                    self.warnings.append(_faceless(g.names[i], "camera"))
                    cam = None
                if cam is not None and mirrored:
                    # A light's cone is the same mirrored: only a camera's picture changes.
                    self.warnings.append(f"node {g.names[i]!r}: its camera's transform mirrors "
                                         "(a negative scale): drawn unmirrored, looking along "
                                         "the node's -Z")
                if cam is not None and not reach <= MAX_COORDINATE:
                    self.warnings.append(far + "camera is left out")
                elif cam is not None:
                    cameras.append(cam)
            if has_light:
                light = lights_punctual.node_light(node, lights, pose, self.warnings,
                                                   f"node {g.names[i]!r}")
                # A transform that keeps at most one axis (zero scales): the way a spot or a
                # sun faces cannot be read from it; a point light needs only its position.
                if light is not None and faceless and light.type != "point":
                    self.warnings.append(_faceless(g.names[i], f"{light.type} light"))
                    light = None
                # A directional light has no position that matters.
                if (light is not None and light.type != "directional"
                        and not reach <= MAX_COORDINATE):
                    self.warnings.append(far + f"{light.type} light is left out")
                elif light is not None:
                    out_lights.append(light)
        return cameras, out_lights

    def _camera(self, cam: Any, pose: np.ndarray, index: int,
                world: np.ndarray) -> SceneCamera | None:
        if not isinstance(cam, dict):
            self.warnings.append(f"camera {index} is not an object: left out")
            return None
        kind = cam.get("type")
        if kind not in ("perspective", "orthographic"):
            self.warnings.append(f"camera {index}: type {brief(kind)} is neither 'perspective' "
                                 "nor 'orthographic': left out")
            return None
        p = cam.get(kind)
        if not isinstance(p, dict):
            self.warnings.append(f"camera {index} ({kind}) has no '{kind}' object: left out")
            return None

        def num(key: str) -> float | None:
            v = p.get(key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                return None
            return float(v)

        yfov = ymag = aspect = None
        scale = 1.0  # of an orthographic camera's lengths
        if kind == "perspective":
            yfov = num("yfov")
            if yfov is None or not 0 < yfov < math.pi:
                self.warnings.append(f"camera {index} has no valid yfov (radians, between 0 "
                                     f"and pi): {brief(p.get('yfov'))}: left out")
                return None
            aspect = num("aspectRatio")
            if aspect is not None and aspect <= 0:
                aspect = None
        else:
            # The picture's width follows the request's aspect, as a perspective camera's
            # aspectRatio does: xmag is only checked.
            ymag, xmag = num("ymag"), num("xmag")
            if ymag is None or ymag == 0 or not abs(ymag) <= MAX_COORDINATE:
                self.warnings.append(f"camera {index} has no valid ymag (half the view's "
                                     f"height, non-zero): {brief(p.get('ymag'))}: left out")
                return None
            if xmag is None or xmag == 0:
                self.warnings.append(f"camera {index}: xmag {brief(p.get('xmag'))} is not a "
                                     "non-zero number: the width follows the image's aspect")
            else:
                if xmag < 0 or ymag < 0:
                    # Negative magnifications (the specification advises against them) would
                    # mirror the picture: it is drawn unmirrored.
                    self.warnings.append(f"camera {index}: negative xmag or ymag (a mirrored "
                                         "picture): drawn unmirrored")
                aspect = abs(xmag / ymag)
            # An orthographic view's size is a length: the node's scale applies to it (a
            # camera under a scaled root, common in converted files, as viewers draw it).
            with np.errstate(over="ignore", invalid="ignore"):
                scale = float(abs(np.linalg.det(world[:3, :3]))) ** (1.0 / 3.0)
            scale = 1.0 if abs(scale - 1.0) < 1e-6 else scale  # rounding of a rotation
            ymag = abs(ymag) * scale
            if not 1e-30 < ymag <= MAX_COORDINATE:  # NaN included
                self.warnings.append(f"camera {index}: its node's scale makes its ymag "
                                     f"{ymag:.3g} units, too small or large to draw: left out")
                return None
        znear, zfar = num("znear"), num("zfar")
        if scale != 1.0:  # lengths along the view axis, in the node's units
            znear = None if znear is None else znear * scale
            zfar = None if zfar is None else zfar * scale
        # Each is optional: one that cannot be used is fitted to the scene instead.
        if znear is not None and (znear < 0 or (znear == 0 and kind == "perspective")):
            self.warnings.append(f"camera {index}: znear {znear} is not positive: fitted to the "
                                 "scene instead")
            znear = None
        if zfar is not None and (zfar <= 0 or (znear is not None and zfar <= znear)):
            self.warnings.append(f"camera {index}: zfar {zfar} is not beyond znear: fitted to "
                                 "the scene instead")
            zfar = None
        return SceneCamera(pose, yfov, znear, zfar, aspect, ymag)
