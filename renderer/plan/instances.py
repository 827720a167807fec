"""A scene's instances as arrays: what every plan of the scene reads, built once per scene.

The plan works on arrays over all instances (boxes, flags, the planes of flat instances), never
on one :class:`~shadowmap.renderer.scene.Instance` at a time. Reading them out of the scene's
objects is the only step that visits each instance in Python, so it is done once per scene and
kept, keyed by the :class:`~shadowmap.renderer.scene.Scene` object in a weak mapping (nothing is
written into the scene; the entry goes when the scene does). A repeated request on the same scene
(a cached parse, the service's scene cache, a benchmark's repeats) reuses them; so does a request
with the same origin, for the origin-relative boxes and corners.

A cached entry is reused while the scene holds the same ``instances`` and ``primitives`` lists
with the same lengths. Changing an instance in place (its matrix, bounds or flags) after the scene
was planned is not seen, as for the upload cache, which keeps a scene's matrices on the GPU by
its key: build a new :class:`Scene` for changed content.

Planarity is a property of the primitive: it is decided once per primitive (an SVD of its
vertices, cached per primitive in the same way) and carried to every instance of it at once, with
one batched solve for the normals (the inverse transpose of each node matrix). So are a
primitive's large flat patches (:func:`primitive_patches`: the orientations that hold a good share
of its area), whose angle to a light decides how finely the 'auto' map size must sample them.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass, field
from operator import attrgetter
from typing import TYPE_CHECKING

import numpy as np

from .geometry import box_corners, column_max, column_min, corner_max, slice_max

if TYPE_CHECKING:  # the scene module is the planner's input: types only
    from ..scene import Instance, Primitive, Scene

# (unit normal, point) of a flat primitive, or None; keyed by the primitive so that repeated
# renders of a cached scene do not redo the SVD, without writing into the scene's objects.
_PLANES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# (normals, shares) of a primitive's large flat patches (:func:`primitive_patches`), same way.
_PATCHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# +1, -1 or 0 per primitive (:func:`primitive_closure`), same way.
_CLOSURE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# The longest triangle edge per primitive (:func:`primitive_edge`), same way.
_EDGE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# SceneArrays by scene, same reasoning. One lock for both maps: the service may plan on more than
# one thread, and a weak mapping is not safe to grow from two at once.
_SCENES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()
# Origins kept per scene: the renderer plans relative to its upload's origin, which is the same
# for every request on a scene; a few more cover callers that pass their own.
_MAX_ORIGINS = 4
#: An instance whose world box float64 resolves to fewer steps across than this (its largest
#: side over the step of its largest coordinate) is placed from its matrix relative to each
#: origin (:meth:`SceneArrays.relative`).
MIN_BOX_STEPS = 2.0**20


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a``, made read-only: these arrays are shared by every request on the scene."""
    a.flags.writeable = False
    return a


def primitive_plane(prim: Primitive) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane of a flat primitive in its local frame.

    Returns
    -------
    (normal, point) : ndarray, shape (3,) each, or None
        Unit normal and the vertices' centre when every vertex lies on one plane; None otherwise
        (fewer than three vertices, a single point, or a curved or folded mesh).
    """
    with _LOCK:
        if prim in _PLANES:
            return _PLANES[prim]
    p = prim.positions.astype(np.float64)
    centre = p.mean(axis=0)
    extent = float(np.max(p.max(axis=0) - p.min(axis=0)))
    result = None
    if len(p) >= 3 and extent > 0:
        _, sv, vt = np.linalg.svd(p - centre, full_matrices=False)
        if sv[-1] <= 1e-7 * max(sv[0], 1e-300) * np.sqrt(len(p)) or np.max(
            np.abs((p - centre) @ vt[-1])
        ) <= 1e-7 * extent:
            result = (_frozen(vt[-1]), _frozen(centre))
    with _LOCK:
        _PLANES[prim] = result
    return result


def primitive_closure(prim: Primitive) -> int:
    """Whether a primitive's triangles close a surface, and which way they wind around it.

    Vertices at bitwise equal positions (after ``-0.0`` becomes ``0.0``) are one vertex: a
    glTF mesh splits its vertices along UV seams and normal creases, and those copies project
    to the same window coordinates, so the rasterizer sees the surface closed across them.
    Triangles with a repeated vertex are left out (they cover no texel).

    The surface is closed when every directed edge occurs once and its reverse once: each edge
    joins two triangles wound opposite ways along it. Then a ray from outside first enters it
    through a face turned toward the ray's origin (outward winding), so a light outside the
    surface sees only those faces first; the faces turned away lie behind them and change no
    texel of a depth map (:func:`.plan.one_sided_casters`).

    Returns
    -------
    int
        +1: closed, counter-clockwise seen from outside (positive signed volume); -1: closed,
        wound the other way (a negative one); 0: open, not consistently wound, or empty.
        Cached per primitive.
    """
    with _LOCK:
        if prim in _CLOSURE:
            return int(_CLOSURE[prim])
    result = 0
    p = np.ascontiguousarray(prim.positions, np.float32) + np.float32(0.0)  # -0.0 -> 0.0
    f = np.asarray(prim.indices, np.intp).reshape(-1, 3)
    if len(f) and len(p):
        # Weld by the positions' bits: sorted by (x, y) as one 64-bit key, then z.
        xy = np.ascontiguousarray(p[:, :2]).view(np.uint64).reshape(-1)
        z = p[:, 2].view(np.uint32)
        order = np.lexsort((z, xy))
        new = np.ones(len(p), bool)
        new[1:] = (xy[order[1:]] != xy[order[:-1]]) | (z[order[1:]] != z[order[:-1]])
        weld = np.empty(len(p), np.int64)
        weld[order] = np.cumsum(new) - 1
        w = weld[f]  # (F, 3) welded vertex ids
        w = w[(w[:, 0] != w[:, 1]) & (w[:, 1] != w[:, 2]) & (w[:, 2] != w[:, 0])]
        if len(w):
            n = int(weld.max()) + 1
            a, b = w, np.roll(w, -1, axis=1)
            # Each edge once, as (undirected key, direction) in one sorted array: closed and
            # consistently wound when the keys come in pairs, one each way, and no key thrice.
            key = ((np.minimum(a, b) * n + np.maximum(a, b)) << 1 | (a > b)).reshape(-1)
            key.sort()
            even, odd = key[0::2], key[1::2]
            if (len(key) % 2 == 0 and np.array_equal(even >> 1, odd >> 1)
                    and not (even & 1).any() and (odd & 1).all()
                    and not np.any(even[1:] >> 1 == odd[:-1] >> 1)):
                # Signed volume (times 6) about the vertices' centre, its sign the winding's:
                # the divergence theorem with x alone, sum of x-centroid * x-normal * area.
                q = p[order[new]].astype(np.float64)
                q -= q.mean(axis=0)
                v0, v1, v2 = q[w[:, 0]], q[w[:, 1]], q[w[:, 2]]
                e1, e2 = v1 - v0, v2 - v0
                nx = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
                volume = float(np.dot(nx, v0[:, 0] + v1[:, 0] + v2[:, 0]))
                result = -1 if volume < 0 else 1
    with _LOCK:
        _CLOSURE[prim] = result
    return result


def primitive_edge(prim: Primitive) -> float:
    """The longest edge of any of the primitive's triangles, in its local units (0 without
    triangles). Cached per primitive.

    A varying the GPU interpolates over a triangle is as precise as the triangle's vertices'
    float32 coordinates: a plane of two triangles 1e6 units long carries their error into the
    pixels beside the eye (:func:`renderer.camera.view_origin`).
    """
    with _LOCK:
        if prim in _EDGE:
            return float(_EDGE[prim])
    f = np.asarray(prim.indices, np.intp).reshape(-1, 3)
    result = 0.0
    if len(f):
        v = np.asarray(prim.positions, np.float64)[f]  # (F, 3, 3)
        d = v - np.roll(v, -1, axis=1)
        result = float(np.sqrt(np.max(np.einsum("fij,fij->fi", d, d))))
    with _LOCK:
        _EDGE[prim] = result
    return result


#: A flat patch holds at least this share of its primitive's area.
PATCH_MIN_SHARE = 0.05
#: Face normals within about 1 degree count as one orientation (normals rounded to 1/64).
_PATCH_GRID = 64.0


def primitive_patches(prim: Primitive) -> np.ndarray:
    """The orientations of a primitive's large flat patches, in its local frame.

    Faces are grouped by their normal (rounded to :data:`_PATCH_GRID` steps per axis); a group
    holding at least :data:`PATCH_MIN_SHARE` of the area is a patch, however many separate
    faces it spans (a box's sides, a pedestal's rim). A curved mesh spreads its area over many
    orientations and has none.

    Returns
    -------
    ndarray, shape (P, 3), float64
        Area-weighted unit normals, at most ``1 / PATCH_MIN_SHARE`` of them; (0, 3) for none.
    """
    with _LOCK:
        if prim in _PATCHES:
            return _PATCHES[prim]
    p = prim.positions.astype(np.float64)
    f = prim.indices.astype(np.intp)
    out = np.zeros((0, 3))
    if len(f) and len(p):
        n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])  # (F, 3), |n| = 2 area
        area = np.sqrt((n * n).sum(axis=1))
        ok = np.isfinite(area) & (area > 0)
        n, area = n[ok], area[ok]
        total = float(area.sum())
        if len(n) and total > 0:
            key = np.round(n / area[:, None] * _PATCH_GRID).astype(np.int64)
            _, group = np.unique(key, axis=0, return_inverse=True)
            group = group.ravel()
            share = np.bincount(group, area) / total
            summed = np.stack([np.bincount(group, n[:, k]) for k in range(3)], axis=1)
            big = share >= PATCH_MIN_SHARE
            length = np.sqrt((summed[big] ** 2).sum(axis=1))
            out = summed[big][length > 0] / length[length > 0, None]
    out = _frozen(out)
    with _LOCK:
        _PATCHES[prim] = out
    return out


@dataclass(frozen=True)
class Planes:
    """The planes of the flat instances (those of a flat primitive with an invertible matrix).

    Attributes
    ----------
    flat : ndarray, shape (N,), bool
    normal : ndarray, shape (N, 3)
        Unit normal in world space (carried by the inverse transpose, so that a non-uniformly
        scaled plane keeps a true normal); zero where not flat.
    point : ndarray, shape (N, 3)
        A point of the plane (the primitive's vertex centre, placed); zero where not flat.
        World space in :class:`SceneArrays`, origin-relative in a plan's context.
    """

    flat: np.ndarray
    normal: np.ndarray
    point: np.ndarray


def instance_planes(primitives: list[Primitive], instances: list[Instance],
                    prim_of: np.ndarray) -> Planes:
    """The world planes of the flat instances, batched per primitive.

    Parameters
    ----------
    primitives : list of Primitive
    instances : list of Instance
        Only the matrices of instances of flat primitives are read.
    prim_of : ndarray, shape (N,), int
        Each instance's primitive.

    Returns
    -------
    Planes
        A singular node matrix (or one whose normal comes out non-finite or zero) leaves its
        instance without a plane.
    """
    n = len(prim_of)
    flat = np.zeros(n, bool)
    normal = np.zeros((n, 3))
    point = np.zeros((n, 3))
    for p in np.unique(prim_of).tolist():  # once per primitive, not per instance
        plane = primitive_plane(primitives[p])
        if plane is None:
            continue
        nrm, centre = plane
        idx = np.flatnonzero(prim_of == p)
        matrices = map(attrgetter("matrix"), map(instances.__getitem__, idx.tolist()))
        m = np.concatenate(list(matrices)).reshape(-1, 4, 4)  # (K, 4, 4)
        a = m[:, :3, :3]
        # Only invertible matrices are solved (a batched solve fails on any singular one); the
        # determinant is taken from the same LU factorisation the solve uses.
        ok = np.abs(np.linalg.det(a)) > 0
        n_w = np.full((len(idx), 3), np.nan)
        if ok.any():
            rhs = np.broadcast_to(nrm, (int(ok.sum()), 3))[..., None]
            n_w[ok] = np.linalg.solve(a[ok].transpose(0, 2, 1), rhs)[..., 0]
        # Norms summed in the order of a 3-vector's dot product, as for one instance at a time.
        length = np.sqrt((n_w * n_w).sum(axis=1))
        good = ok & np.all(np.isfinite(n_w), axis=1) & (length != 0)
        sel = idx[good]
        flat[sel] = True
        normal[sel] = n_w[good] / length[good, None]
        point[sel] = np.matmul(a[good], centre[:, None])[..., 0] + m[good, :3, 3]
    return Planes(_frozen(flat), _frozen(normal), _frozen(point))


@dataclass(frozen=True)
class RelativeArrays:
    """A scene's boxes relative to one origin.

    Attributes
    ----------
    bounds : ndarray, shape (N, 2, 3)
    corners : ndarray, shape (N, 8, 3)
    centres : ndarray, shape (N, 3)
        Box centres, ``bounds.mean(axis=1)`` (the same values).
    planes : Planes
        With origin-relative points.
    extent : float
        The largest side of any box (the scale of the plane tests' tolerance).
    """

    bounds: np.ndarray
    corners: np.ndarray
    centres: np.ndarray
    planes: Planes
    extent: float


@dataclass(frozen=True, eq=False)
class SceneArrays:
    """What the plan reads of a scene's instances, as read-only arrays.

    Attributes
    ----------
    bounds : ndarray, shape (N, 2, 3)
        World boxes (min, max corner), as in :attr:`Instance.bounds`.
    cast, receive : ndarray, shape (N,), bool
        The instances' cast and receive flags.
    primitive : ndarray, shape (N,), int
        Each instance's primitive.
    unlit : ndarray, shape (N,), bool
        Whether its material is unlit (``KHR_materials_unlit``).
    planes : Planes
        World planes of the flat instances.
    box : ndarray, shape (2, 3)
        The box around every instance: :attr:`Scene.bounds`, the same values.
    coarse : ndarray, shape (C,), int
        The instances whose world box float64 resolves to fewer than
        :data:`MIN_BOX_STEPS` steps across (a part 1e-6 across, 1e10 units out): their
        origin-relative boxes and plane points are placed from their matrices
        (:meth:`relative`), not from the world values.
    """

    bounds: np.ndarray
    cast: np.ndarray
    receive: np.ndarray
    primitive: np.ndarray
    unlit: np.ndarray
    planes: Planes
    box: np.ndarray
    coarse: np.ndarray
    # What the entry was read from (checked on reuse), and its origin-relative arrays by origin.
    _source: tuple = field(repr=False)
    _relative: dict = field(default_factory=dict, repr=False)
    _patches: dict = field(default_factory=dict, repr=False)
    _closure: dict = field(default_factory=dict, repr=False)

    @classmethod
    def read(cls, scene: Scene) -> SceneArrays:
        """Read the arrays out of the scene's instances (one pass over each attribute)."""
        insts = scene.instances
        n = len(insts)
        # attrgetter maps keep the per-instance work inside C loops; concatenating the (2, 3)
        # boxes along their first axis copies the same values as np.stack, at half the cost.
        boxes = list(map(attrgetter("bounds"), insts))
        bounds = np.concatenate(boxes).reshape(n, 2, 3) if n else np.zeros((0, 2, 3))
        cast = np.fromiter(map(attrgetter("cast_shadow"), insts), bool, n)
        receive = np.fromiter(map(attrgetter("receive_shadow"), insts), bool, n)
        prim = np.fromiter(map(attrgetter("primitive"), insts), np.intp, n)
        planes = instance_planes(scene.primitives, insts, prim)
        unlit = np.fromiter((p.material.unlit for p in scene.primitives), bool,
                            len(scene.primitives))[prim]
        box = np.stack([column_min(bounds[:, 0]), column_max(bounds[:, 1])])
        step = np.spacing(corner_max(slice_max(np.abs(bounds), 2))) if n else np.zeros(0)
        coarse = np.flatnonzero(step * MIN_BOX_STEPS > corner_max(bounds[:, 1] - bounds[:, 0]))
        return cls(bounds=_frozen(bounds), cast=_frozen(cast), receive=_frozen(receive),
                   primitive=_frozen(prim), unlit=_frozen(unlit), planes=planes,
                   box=_frozen(box),
                   coarse=_frozen(coarse), _source=_source(scene))

    def patches(self) -> tuple[np.ndarray, np.ndarray]:
        """World unit normals of every instance's flat patches (:func:`primitive_patches`),
        computed on first use with one batched solve per primitive and kept.

        Returns
        -------
        start : ndarray, shape (N + 1,), int
            Instance i's patches are rows ``start[i]:start[i + 1]`` of ``normal``.
        normal : ndarray, shape (M, 3)
            Unit normals; an instance with a singular matrix has none.
        """
        with _LOCK:
            hit = self._patches.get("all")
        if hit is not None:
            return hit
        instances, primitives = self._source[0], self._source[2]
        n = len(self.primitive)
        counts = np.zeros(n, np.intp)
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for prim in np.unique(self.primitive).tolist():
            local = primitive_patches(primitives[prim])
            if len(local) == 0:
                continue
            at = np.flatnonzero(self.primitive == prim)
            matrices = map(attrgetter("matrix"), map(instances.__getitem__, at.tolist()))
            a = np.concatenate(list(matrices)).reshape(-1, 4, 4)[:, :3, :3]
            ok = np.abs(np.linalg.det(a)) > 0
            n_w = np.full((len(at), len(local), 3), np.nan)
            if ok.any():
                # Normals go through the inverse transpose: n_w = A^-T n, every patch at once.
                rhs = np.broadcast_to(local.T, (int(ok.sum()), 3, len(local)))
                n_w[ok] = np.linalg.solve(a[ok].transpose(0, 2, 1), rhs).transpose(0, 2, 1)
            length = np.sqrt((n_w * n_w).sum(axis=2))
            good = np.isfinite(length) & (length > 0)  # (K, P)
            counts[at] = good.sum(axis=1)
            parts.append((at, n_w / np.where(good, length, 1.0)[..., None], good))
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        normal = np.zeros((int(start[-1]), 3))
        for at, n_w, good in parts:
            # Instance at[j]'s good patches fill rows start[at[j]]:start[at[j] + 1], in order.
            rows = start[at][:, None] + np.cumsum(good, axis=1) - 1
            normal[rows[good]] = n_w[good]
        out = (_frozen(start), _frozen(np.ascontiguousarray(normal, np.float64)))
        with _LOCK:
            self._patches["all"] = out
        return out

    def closure(self) -> np.ndarray:
        """Per instance, how its light-pass draw may leave out faces: the winding of its
        primitive's closed surface (:func:`primitive_closure`), +1 or -1, or 0 where every face
        is drawn (an open surface, or a material whose shadow is cut out by its texture's alpha:
        a face turned toward the light may have holes that the faces behind fill). Computed on
        first use, once per primitive, and kept.

        Returns
        -------
        ndarray, shape (N,), int8
        """
        with _LOCK:
            hit = self._closure.get("all")
        if hit is not None:
            return hit
        primitives = self._source[2]
        per_prim = np.zeros(len(primitives), np.int8)
        for p in np.unique(self.primitive).tolist():
            prim = primitives[p]
            if not prim.material.shadow_texture_cut:
                per_prim[p] = primitive_closure(prim)
        out = _frozen(per_prim[self.primitive])
        with _LOCK:
            self._closure["all"] = out
        return out

    def patch_normals(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The flat patches of instances ``idx`` (:meth:`patches`).

        Parameters
        ----------
        idx : ndarray, shape (K,), int

        Returns
        -------
        owner : ndarray, shape (M,), int
            Position in ``idx`` of each patch's instance.
        normal : ndarray, shape (M, 3)
        """
        start, normal = self.patches()
        first = start[idx]
        count = start[idx + 1] - first
        total = int(count.sum())
        if total == 0:
            return np.zeros(0, np.intp), np.zeros((0, 3))
        owner = np.repeat(np.arange(len(idx)), count)
        rows = np.arange(total) + np.repeat(first - (np.cumsum(count) - count), count)
        return owner, normal[rows]

    def relative(self, origin: np.ndarray) -> RelativeArrays:
        """Boxes, corners and plane points relative to ``origin`` (cached per origin).

        Parameters
        ----------
        origin : ndarray, shape (3,), float64
        """
        key = origin.tobytes()
        with _LOCK:
            hit = self._relative.get(key)
        if hit is not None:
            return hit
        bounds = self.bounds - origin
        points = self.planes.point - origin
        if len(self.coarse):
            self._place_coarse(origin, bounds, points)
        rel = RelativeArrays(
            bounds=_frozen(bounds),
            corners=_frozen(box_corners(bounds)),
            # The mean of two values, computed as ``mean`` does: their sum, halved.
            centres=_frozen((bounds[:, 0] + bounds[:, 1]) / 2),
            planes=Planes(self.planes.flat, self.planes.normal, _frozen(points)),
            extent=float(np.max(bounds[:, 1] - bounds[:, 0])),
        )
        with _LOCK:
            if len(self._relative) >= _MAX_ORIGINS:
                self._relative.pop(next(iter(self._relative)))
            self._relative[key] = rel
        return rel


    def _place_coarse(self, origin: np.ndarray, bounds: np.ndarray, points: np.ndarray) -> None:
        """The :attr:`coarse` instances' boxes and plane points relative to ``origin``, written
        into ``bounds`` (N, 2, 3) and ``points`` (N, 3): their local boxes and planes placed by
        their matrices with the origin taken off the translation first, so that they keep the
        precision float64 has beside the origin."""
        from ..scene import world_bounds_many  # the scene module is the planner's input

        instances, primitives = self._source[0], self._source[2]
        for p in np.unique(self.primitive[self.coarse]).tolist():
            idx = self.coarse[self.primitive[self.coarse] == p]
            mats = np.stack([instances[k].matrix for k in idx.tolist()]).astype(np.float64)
            mats[:, :3, 3] -= origin
            local = primitives[p].local_bounds.astype(np.float64)
            bounds[idx] = world_bounds_many(local, mats)
            flat = idx[self.planes.flat[idx]]
            plane = primitive_plane(primitives[p]) if len(flat) else None
            if plane is not None:
                m = mats[self.planes.flat[idx]]
                points[flat] = np.matmul(m[:, :3, :3], plane[1][:, None])[..., 0] + m[:, :3, 3]


def _source(scene: Scene) -> tuple:
    """What a cached entry must still match: the scene's lists, by identity, and their lengths."""
    return (scene.instances, len(scene.instances), scene.primitives, len(scene.primitives))


def _same_source(a: tuple, b: tuple) -> bool:
    """Whether two :func:`_source` tuples name the same lists at the same lengths."""
    return a[0] is b[0] and a[1] == b[1] and a[2] is b[2] and a[3] == b[3]


def scene_arrays(scene: Scene) -> SceneArrays:
    """The scene's instance arrays, read once per scene and reused while it holds the same
    instance and primitive lists (see the module's notes)."""
    with _LOCK:
        hit = _SCENES.get(scene)
    if hit is not None and _same_source(hit._source, _source(scene)):
        return hit
    arrays = SceneArrays.read(scene)
    with _LOCK:
        _SCENES[scene] = arrays
    return arrays


def scene_box(scene: Scene) -> np.ndarray:
    """The box around every instance of the scene, shape (2, 3), read-only.

    The values of :attr:`Scene.bounds`, from :func:`scene_arrays`: resolving a request's camera
    and lights needs it several times, and the property reads every instance each time.
    """
    return scene_arrays(scene).box
