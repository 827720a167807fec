"""GL resources owned explicitly: uploaded scenes and framebuffers.

Meshes are uploaded as one vertex array each (interleaved vertex attributes, an instance buffer
of model matrices, uint32 indices) and base-colour images as mipmapped RGBA8 textures. Every
object here belongs to the :class:`~shadowmap.renderer.gl.context.GLContext` current when it
was made, is used from that context's thread only, and is freed by its ``release()`` (safe to
call twice).
"""

from __future__ import annotations

import ctypes
import itertools
import sys
from collections import OrderedDict
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from OpenGL import GL

from ..errors import RenderError
from ..plan.instances import scene_box
from ..scene import Material, Sampler, Scene, instance_arrays

# --------------------------------------------------------------------------------------------
# Vertex arrays and textures
# --------------------------------------------------------------------------------------------

_FLOAT = 4  # bytes


class VertexArray:
    """A vertex array object with its buffers: interleaved float32 attributes at locations
    0, 1, ... in the order given, an instance buffer of model matrices at the next four
    locations (one ``vec4`` column each, divisor 1), and uint32 triangle indices.

    Parameters
    ----------
    attributes : sequence of ndarray, each shape (N, k)
        Per-vertex attributes (positions first); ``None`` entries are left out.
    poses : ndarray, shape (K, 4, 4)
        Model matrices, one per instance.
    indices : ndarray, shape (F, 3)
    """

    def __init__(self, attributes: Sequence[np.ndarray | None], poses: np.ndarray,
                 indices: np.ndarray) -> None:
        columns = [np.asarray(a, np.float32) for a in attributes if a is not None]
        vertices = np.ascontiguousarray(np.hstack(columns), dtype=np.float32)
        self.vao = int(GL.glGenVertexArrays(1))
        self.buffers: list[int] = []
        #: bytes of its buffers on the GPU (vertices, model matrices, indices)
        self.nbytes = 0
        GL.glBindVertexArray(self.vao)
        try:
            self._buffer(GL.GL_ARRAY_BUFFER, vertices)
            stride = vertices.shape[1] * _FLOAT
            offset = 0
            for loc, a in enumerate(columns):
                GL.glVertexAttribPointer(loc, a.shape[1], GL.GL_FLOAT, GL.GL_FALSE, stride,
                                         ctypes.c_void_p(offset))
                GL.glEnableVertexAttribArray(loc)
                offset += a.shape[1] * _FLOAT
            #: the first of the four model-matrix locations
            self.loc_model = len(columns)
            # Column-major, as GLSL reads a mat4 attribute.
            self.instances = len(poses)
            self.model_buffer = self._buffer(
                GL.GL_ARRAY_BUFFER, np.ascontiguousarray(np.transpose(poses, (0, 2, 1)),
                                                         np.float32))
            for i in range(4):
                loc = self.loc_model + i
                GL.glEnableVertexAttribArray(loc)
                GL.glVertexAttribPointer(loc, 4, GL.GL_FLOAT, GL.GL_FALSE, 16 * _FLOAT,
                                         ctypes.c_void_p(4 * _FLOAT * i))
                GL.glVertexAttribDivisor(loc, 1)
            self._buffer(GL.GL_ELEMENT_ARRAY_BUFFER, np.ascontiguousarray(indices, np.uint32))
        except BaseException:
            GL.glBindVertexArray(0)
            self.release()
            raise
        GL.glBindVertexArray(0)

    def _buffer(self, target: int, data: np.ndarray) -> int:
        buf = int(GL.glGenBuffers(1))
        self.buffers.append(buf)
        GL.glBindBuffer(target, buf)
        GL.glBufferData(target, data.nbytes, data, GL.GL_STATIC_DRAW)
        self.nbytes += data.nbytes
        return buf

    def write_poses(self, poses: np.ndarray) -> None:
        """Replace the model matrices (as many as the buffer holds), e.g. for a new origin.

        Parameters
        ----------
        poses : ndarray, shape (K, 4, 4)
        """
        data = np.ascontiguousarray(np.transpose(poses, (0, 2, 1)), np.float32)
        if len(data) != self.instances:
            raise ValueError(f"{len(data)} model matrices for a buffer of {self.instances}")
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.model_buffer)
        GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)

    def read_poses(self) -> np.ndarray:
        """The model matrices as the GPU holds them (read back, for checks).

        Returns
        -------
        ndarray, shape (K, 4, 4), float32
        """
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.model_buffer)
        raw = GL.glGetBufferSubData(GL.GL_ARRAY_BUFFER, 0, self.instances * 16 * _FLOAT)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
        cols = np.frombuffer(bytes(raw), np.float32).reshape(self.instances, 4, 4)
        return np.ascontiguousarray(np.transpose(cols, (0, 2, 1)))

    def bind(self) -> None:
        GL.glBindVertexArray(self.vao)

    @staticmethod
    def unbind() -> None:
        GL.glBindVertexArray(0)

    def release(self) -> None:
        """Delete the vertex array and its buffers. Safe to call twice."""
        if self.vao:
            GL.glDeleteVertexArrays(1, [self.vao])
            self.vao = 0
        if self.buffers:
            GL.glDeleteBuffers(len(self.buffers), self.buffers)
            self.buffers = []


class Texture2D:
    """A mipmapped RGBA8 texture of an image; with ``alpha``, also its alpha channel alone at
    full resolution (:attr:`alpha_id`). Its own filters and wrapping are GL's defaults, which a
    :func:`sampler_object` bound with it replaces (one image may be sampled by several glTF
    samplers).

    The light pass tests cut-out casters against that R8 copy: one channel and no mipmaps, so a
    software rasterizer's sampler converts a quarter of the data per texel, and the bilinear
    level-0 value is the RGBA texture's own alpha at the same point (same texels, filter and
    wrapping), so the map is the same.

    Parameters
    ----------
    image : ndarray, shape (H, W, 4), uint8
        Rows top to bottom, as stored in the file; uploaded bottom row first, so that texture
        coordinate v = 0 is the image's bottom row (the convention of ``Primitive.uv``).
    alpha : bool
        Upload the alpha copy as well (:meth:`add_alpha` adds it later).
    """

    def __init__(self, image: np.ndarray, alpha: bool = False) -> None:
        data = _bottom_up(image)
        h, w = data.shape[:2]
        self.id = _texture(data, GL.GL_RGBA8, GL.GL_RGBA, mipmaps=True)
        self.alpha_id = 0
        #: bytes on the GPU, the mip chain (and the alpha copy) included
        self.nbytes = data.nbytes * 4 // 3
        if alpha:
            self.add_alpha(image)

    def add_alpha(self, image: np.ndarray) -> None:
        """Upload the alpha copy of ``image`` (the image this texture was made from), once."""
        if self.alpha_id:
            return
        a = np.ascontiguousarray(_bottom_up(image)[..., 3])
        self.alpha_id = _texture(a, GL.GL_R8, GL.GL_RED, mipmaps=False)
        self.nbytes += a.nbytes

    def bind(self) -> None:
        """Bind to ``GL_TEXTURE_2D`` of the active texture unit."""
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.id)

    def bind_alpha(self) -> None:
        """Bind the alpha copy to ``GL_TEXTURE_2D`` of the active texture unit."""
        if not self.alpha_id:
            raise RenderError("the texture has no alpha copy (Texture2D.add_alpha)")
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.alpha_id)

    def release(self) -> None:
        """Delete the textures. Safe to call twice."""
        ids = [t for t in (self.id, self.alpha_id) if t]
        if ids:
            GL.glDeleteTextures(ids)
        self.id = self.alpha_id = 0


def _bottom_up(image: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(image[::-1], dtype=np.uint8)


def _texture(data: np.ndarray, internal: int, fmt: int, mipmaps: bool) -> int:
    """A repeated, bilinear (trilinear with ``mipmaps``) 2D texture of ``data``, (H, W) or
    (H, W, C) bytes, row 0 first."""
    h, w = data.shape[:2]
    tex = int(GL.glGenTextures(1))
    GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, internal, w, h, 0, fmt, GL.GL_UNSIGNED_BYTE, data)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
    if mipmaps:
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D)
    else:
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, 0)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER,
                       GL.GL_LINEAR_MIPMAP_LINEAR if mipmaps else GL.GL_LINEAR)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, GL.GL_REPEAT)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    return tex


def sampler_object(sampler: Sampler) -> int:
    """A GL sampler object with a glTF sampler's filters and wrap modes (glTF's values are GL's
    enums). Bound to a texture unit (``glBindSampler``), it replaces the parameters of whatever
    texture is bound there."""
    sid = int(GL.glGenSamplers(1))
    GL.glSamplerParameteri(sid, GL.GL_TEXTURE_MAG_FILTER, sampler.mag_filter)
    GL.glSamplerParameteri(sid, GL.GL_TEXTURE_MIN_FILTER, sampler.min_filter)
    GL.glSamplerParameteri(sid, GL.GL_TEXTURE_WRAP_S, sampler.wrap_s)
    GL.glSamplerParameteri(sid, GL.GL_TEXTURE_WRAP_T, sampler.wrap_t)
    return sid


# --------------------------------------------------------------------------------------------
# Scene upload
# --------------------------------------------------------------------------------------------


@dataclass(eq=False)
class GpuPrimitive:
    """One uploaded primitive with all its instances in one instance buffer.

    Instances whose model matrix mirrors (negative determinant, e.g. a node scaled by
    (-1, 1, 1)) sit at the end of the buffer, from slot :attr:`mirrored_from`: a mirror reverses
    the winding of every triangle, so their front faces are clockwise on screen and
    :meth:`draw` switches ``glFrontFace`` for them. Both kinds share one vertex buffer.

    Attributes
    ----------
    mesh : VertexArray
    instances : ndarray, shape (K,), intp
        Indices into :attr:`Scene.instances`, in instance-buffer order (read-only).
    texture : Texture2D or None
        The base-colour texture (shared by the primitives of one image).
    sampler : int
        The GL sampler object of the material's :class:`~shadowmap.renderer.scene.Sampler`
        (shared by the primitives of one sampler), bound with :attr:`texture`; 0 without one.
    loc_uv, loc_color, loc_model : int
        Attribute locations of the interleaved layout (positions 0, normals 1, then texture
        coordinates and colours when present, then the 4 columns of the model matrix).
    has_color : bool
        The primitive has per-vertex colours (at ``loc_color``).
    count : int
        Indices per instance.
    mirrored_from : int
        First slot of the mirrored instances; ``len(instances)`` when there are none.
    primitive : int
        Index into :attr:`Scene.primitives`.
    material : Material
        The primitive's material (the same for every instance).
    indirect : IndirectBuffer or None
        Where :meth:`draw` writes the commands of a multi-draw; None where the context has no
        ``glMultiDrawElementsIndirect`` (GL 4.3): one call per run of slots instead.
    """

    mesh: VertexArray
    instances: np.ndarray
    texture: Texture2D | None
    loc_uv: int
    loc_color: int
    loc_model: int
    has_color: bool
    count: int
    mirrored_from: int
    primitive: int
    material: Material
    indirect: IndirectBuffer | None = None
    sampler: int = 0

    def bind_texture(self, unit: int = 0, alpha: bool = False) -> None:
        """Make ``unit`` the active texture unit and bind the texture (with ``alpha``, its
        alpha copy) and its sampler object to it. A pass that binds one takes it off again with
        ``glBindSampler(unit, 0)``: it would override every texture later bound to the unit."""
        assert self.texture is not None
        GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
        if alpha:
            self.texture.bind_alpha()
        else:
            self.texture.bind()
        GL.glBindSampler(unit, self.sampler)

    @property
    def mirrored(self) -> int:
        """Number of mirrored instances (the last ones in the buffer)."""
        return len(self.instances) - self.mirrored_from

    def draw(self, slots: npt.ArrayLike | None = None, *, ordered: bool = False) -> None:
        """Draw all instances, or only the given slots (positions in :attr:`instances`).

        Slots are drawn in increasing order, or with ``ordered`` in the order given (blended
        instances back to front). Each run of consecutive slots is one instanced draw, and the
        runs of one winding are one ``glMultiDrawElementsIndirect``: GL draws its commands, and
        the instances of each, in order, so the frame is the one that one call per run draws.

        Mirrored instances are drawn with clockwise front faces, so that back-face culling, where
        the caller enables it, removes the same faces as for their unmirrored counterparts.
        """
        self.mesh.bind()
        n = len(self.instances)
        if slots is None and not self.mirrored:
            GL.glDrawElementsInstanced(GL.GL_TRIANGLES, self.count, GL.GL_UNSIGNED_INT, None, n)
        else:
            if slots is None:
                s = np.arange(n)
            else:
                s = np.asarray(slots, dtype=np.intp).reshape(-1)
                s = s if ordered else np.sort(s)
            runs = _slot_runs(s, self.mirrored_from)
            for start, length, mirrored in runs:
                if mirrored:
                    GL.glFrontFace(GL.GL_CW)
                self._draw_runs(start, length)
                if mirrored:
                    GL.glFrontFace(GL.GL_CCW)  # GL's default, which every other draw assumes
        self.mesh.unbind()

    def _draw_runs(self, start: np.ndarray, length: np.ndarray) -> None:
        """Draw the runs ``start[i] .. start[i] + length[i]`` of slots, in that order."""
        if len(start) == 1 or self.indirect is None:
            for first, n in zip(start.tolist(), length.tolist(), strict=True):
                GL.glDrawElementsInstancedBaseInstance(
                    GL.GL_TRIANGLES, self.count, GL.GL_UNSIGNED_INT, None, n, first
                )
            return
        # DrawElementsIndirectCommand: count, instanceCount, firstIndex, baseVertex, baseInstance
        commands = np.zeros((len(start), 5), np.uint32)
        commands[:, 0] = self.count
        commands[:, 1] = length
        commands[:, 4] = start
        self.indirect.draw(commands)

    def release(self) -> None:
        """Free the vertex array and the texture (shared textures are freed once: their
        ``release`` is safe to call twice)."""
        self.mesh.release()
        if self.texture is not None:
            self.texture.release()


def _slot_runs(slots: np.ndarray, boundary: int) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Runs of consecutive slots, in the order given, cut at ``boundary``, as the list of
    (starts, lengths, mirrored) of each stretch of runs on one side of it."""
    if not len(slots):
        return []
    side = slots >= boundary
    cut = np.flatnonzero((np.diff(slots) != 1) | (side[1:] != side[:-1])) + 1
    first = np.concatenate([[0], cut])
    lengths = np.diff(np.concatenate([first, [len(slots)]]))
    return _group_sides(slots[first], lengths, side[first])


def _group_sides(start: np.ndarray, length: np.ndarray,
                 side: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Consecutive runs on the same side of the boundary, together."""
    cut = np.flatnonzero(side[1:] != side[:-1]) + 1
    bounds = np.concatenate([[0], cut, [len(start)]]).tolist()
    return [(start[a:b], length[a:b], bool(side[a])) for a, b in itertools.pairwise(bounds)]


class IndirectBuffer:
    """A small ``GL_DRAW_INDIRECT_BUFFER`` refilled for each multi-draw (orphaned each time:
    GL keeps the commands of a draw already issued)."""

    def __init__(self) -> None:
        self.buffer = 0

    def draw(self, commands: np.ndarray) -> None:
        """``glMultiDrawElementsIndirect`` of triangles with uint32 indices, one command a row
        of ``commands`` (uint32, shape (n, 5)), for the vertex array bound now."""
        if not self.buffer:
            self.buffer = int(GL.glGenBuffers(1))
        data = np.ascontiguousarray(commands, dtype=np.uint32)
        GL.glBindBuffer(GL.GL_DRAW_INDIRECT_BUFFER, self.buffer)
        GL.glBufferData(GL.GL_DRAW_INDIRECT_BUFFER, data.nbytes, data, GL.GL_STREAM_DRAW)
        GL.glMultiDrawElementsIndirect(GL.GL_TRIANGLES, GL.GL_UNSIGNED_INT, None, len(data), 0)
        GL.glBindBuffer(GL.GL_DRAW_INDIRECT_BUFFER, 0)

    def release(self) -> None:
        if self.buffer:
            GL.glDeleteBuffers(1, [self.buffer])
            self.buffer = 0


def _has_multi_draw_indirect() -> bool:
    """Whether the current context has ``glMultiDrawElementsIndirect`` (core in GL 4.3)."""
    major = int(GL.glGetIntegerv(GL.GL_MAJOR_VERSION))
    minor = int(GL.glGetIntegerv(GL.GL_MINOR_VERSION))
    return (major, minor) >= (4, 3) and bool(GL.glMultiDrawElementsIndirect)


class SlotMap(Mapping[int, tuple[int, int]]):
    """Scene instance index -> (GPU primitive index, slot in its instance buffer), read from
    :attr:`GpuScene.prim_of` and :attr:`GpuScene.slot` (kept for callers of one instance)."""

    def __init__(self, prim_of: np.ndarray, slot: np.ndarray) -> None:
        self._prim_of, self._slot = prim_of, slot

    def __getitem__(self, index: int) -> tuple[int, int]:
        if not 0 <= index < len(self._slot):
            raise KeyError(index)
        return int(self._prim_of[index]), int(self._slot[index])

    def __len__(self) -> int:
        return len(self._slot)

    def __iter__(self) -> Iterator[int]:
        return iter(range(len(self._slot)))


#: Instance sets up to this size are memoised by :meth:`GpuScene.groups`, this many per upload.
_GROUPS_MEMO_MAX = 4096
_GROUPS_MEMO_ENTRIES = 32


def origin_poses(matrices: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Model matrices relative to ``origin``: ``T(-origin) @ M`` in float64, so that float32 on
    the GPU keeps its precision near the origin, wherever the scene lies.

    Parameters
    ----------
    matrices : ndarray, shape (K, 4, 4)
    origin : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (K, 4, 4), float64 (a new array)
    """
    out = np.array(matrices, np.float64)
    if np.all(out[:, 3] == (0.0, 0.0, 0.0, 1.0)):
        # Affine: only the translation changes, by exactly the subtraction the product computes
        # (the other terms add zeros).
        out[:, :3, 3] -= origin
        return out
    shift = np.eye(4)
    shift[:3, 3] = -np.asarray(origin, np.float64)
    return np.matmul(shift, out)


@dataclass(eq=False)
class GpuScene:
    """A scene uploaded to one context, positioned relative to ``origin``.

    Model matrices are uploaded as ``T(-origin) @ M`` computed in float64, so float32 on the GPU
    keeps its precision for a scene far from the world origin.

    GPU primitives follow the order in which the scene's instances first name each primitive;
    each one's instance buffer holds its unmirrored instances in scene order, then its mirrored
    ones in scene order.

    Attributes
    ----------
    origin : ndarray, shape (3,), float64
    primitives : list of GpuPrimitive
    prim_of, slot : ndarray, shape (N,), intp
        Per scene instance: its GPU primitive (index into :attr:`primitives`) and its slot in
        that primitive's instance buffer (read-only).
    blended : ndarray, shape (len(primitives),), bool
        GPU primitives whose material blends (``alpha_mode == "BLEND"``).
    nbytes : int
        What the upload holds on the GPU: every vertex, instance-matrix and index buffer, and
        each texture once with its mipmaps (the upload cache's budget counts this).
    samplers : dict of Sampler to int
        The GL sampler objects of its textured materials, one per glTF sampler.
    """

    scene: Scene
    origin: np.ndarray
    primitives: list[GpuPrimitive] = field(default_factory=list)
    prim_of: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))
    slot: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))
    blended: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    nbytes: int = 0
    indirect: IndirectBuffer | None = None
    samplers: dict[Sampler, int] = field(default_factory=dict)
    # groups() of recent calls, by (instances, split, classes): a repeated request asks for the
    # same.
    _groups: OrderedDict[tuple[bytes, int, int], tuple[np.ndarray | None, list]] = field(
        default_factory=OrderedDict, repr=False)

    @property
    def slot_of(self) -> SlotMap:
        """Scene instance index -> (GPU primitive index, slot in its instance buffer)."""
        return SlotMap(self.prim_of, self.slot)

    @classmethod
    def upload(cls, scene: Scene) -> GpuScene:
        arrays = instance_arrays(scene)
        # Scene.bounds, from the plan's per-scene arrays, which this scene's plan reads anyway.
        lo, hi = scene_box(scene)
        origin = (lo + hi) / 2
        gs = cls(scene=scene, origin=origin)
        matrices = arrays.matrices
        n = len(matrices)
        # GPU primitives in the order the instances first name them, as (scene primitive, GPU
        # index of each instance).
        used, first, prim_of = np.unique(arrays.primitive, return_index=True, return_inverse=True)
        by_first = np.argsort(first, kind="stable")
        rank = np.empty(len(used), np.intp)
        rank[by_first] = np.arange(len(used))
        prim_of = rank[prim_of.reshape(-1)]
        # Mirrored instances after the others (a stable partition: without any, the buffer is
        # in scene order as before), so that each kind is one run of slots with one winding.
        mirrored = np.linalg.det(matrices[:, :3, :3]) < 0
        order = np.lexsort((mirrored, prim_of))  # stable: scene order within each kind
        counts = np.bincount(prim_of, minlength=len(used))
        unmirrored = np.bincount(prim_of[~mirrored], minlength=len(used))
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        slot = np.empty(n, np.intp)
        slot[order] = np.arange(n) - np.repeat(starts, counts)
        for a in (prim_of, slot, order):
            a.flags.writeable = False
        gs.prim_of, gs.slot = prim_of, slot
        gs.blended = np.array([scene.primitives[p].material.alpha_mode == "BLEND"
                               for p in used[by_first].tolist()], bool)
        if _has_multi_draw_indirect():
            gs.indirect = IndirectBuffer()
        textures: dict[int, Texture2D] = {}
        try:
            for g, pidx in enumerate(used[by_first].tolist()):
                prim = scene.primitives[pidx]
                inst_ids = order[starts[g]:starts[g] + counts[g]]
                poses = origin_poses(matrices[inst_ids], origin)
                has_uv = prim.uv is not None
                has_color = prim.colors is not None
                mesh = VertexArray((prim.positions, prim.normals, prim.uv, prim.colors),
                                   poses, prim.indices)
                tex = None
                sid = 0
                if prim.material.texture is not None:
                    sid = gs.samplers.get(prim.material.sampler, 0)
                    if not sid:
                        sid = gs.samplers[prim.material.sampler] = sampler_object(
                            prim.material.sampler)
                    key = id(prim.material.texture)
                    # Cut-out casters are tested against the texture's alpha copy.
                    alpha = prim.material.shadow_cutoff is not None
                    tex = textures.get(key)
                    if tex is None:
                        tex = textures[key] = Texture2D(prim.material.texture, alpha)
                        gs.nbytes += tex.nbytes
                    elif alpha and not tex.alpha_id:
                        before = tex.nbytes
                        tex.add_alpha(prim.material.texture)
                        gs.nbytes += tex.nbytes - before
                gp = GpuPrimitive(
                    mesh=mesh,
                    instances=inst_ids,
                    texture=tex,
                    loc_uv=2,
                    loc_color=2 + has_uv,
                    loc_model=mesh.loc_model,
                    has_color=has_color,
                    count=int(prim.indices.size),
                    mirrored_from=int(unmirrored[g]),
                    primitive=pidx,
                    material=prim.material,
                    indirect=gs.indirect,
                    sampler=sid,
                )
                gs.primitives.append(gp)
                gs.nbytes += mesh.nbytes  # what its buffers hold, instance matrices included
        except Exception:
            gs.release()
            for t in textures.values():
                t.release()
            raise
        return gs

    def set_origin(self, origin: np.ndarray) -> None:
        """Place the upload relative to ``origin`` (shape (3,), float64): every instance
        buffer's model matrices are written again as ``T(-origin) @ M``. A view that looks
        closely at a part of a vast scene far from its centre is drawn relative to a point near
        its eye (:func:`renderer.camera.view_origin`), where float32 keeps the precision its
        pixels need. Nothing is written when the origin is the current one."""
        origin = np.asarray(origin, np.float64)
        if np.array_equal(origin, self.origin):
            return
        matrices = instance_arrays(self.scene).matrices
        for gp in self.primitives:
            gp.mesh.write_poses(origin_poses(matrices[gp.instances], origin))
        self.origin = origin.copy()
        self.origin.flags.writeable = False

    def groups(self, instances: npt.ArrayLike, split: np.ndarray | None = None,
               classes: int = 2) -> list[tuple[int, int, np.ndarray]]:
        """Scene instances sorted out by GPU primitive, for one draw each.

        Parameters
        ----------
        instances : array of int
            Scene instance indices.
        split : ndarray, shape (N,), bool or int, optional
            A per-scene-instance flag, or class in ``[0, classes)``, that also separates groups
            (e.g. ``receive_shadow``).
        classes : int
            How many values ``split`` takes.

        Returns
        -------
        list of (GPU primitive index, flag, slots)
            In the order in which ``instances`` first reach each group; ``slots`` (intp) in the
            order of ``instances``. ``flag`` is the group's ``split`` value (0 without it).
        """
        inst = np.asarray(instances, dtype=np.intp).reshape(-1)
        # Small sets are memoised (their key is the indices' bytes): for them the grouping's
        # fixed cost is the whole cost, and frames repeat their sets.
        memo = (inst.tobytes(), id(split), classes) if len(inst) <= _GROUPS_MEMO_MAX else None
        if memo is not None:
            hit = self._groups.get(memo)
            if hit is not None and hit[0] is split:
                self._groups.move_to_end(memo)
                return hit[1]
        out = self._grouped(inst, split, classes)
        if memo is not None:
            self._groups[memo] = (split, out)
            while len(self._groups) > _GROUPS_MEMO_ENTRIES:
                self._groups.popitem(last=False)
        return out

    def _grouped(self, instances: np.ndarray, split: np.ndarray | None, classes: int
                 ) -> list[tuple[int, int, np.ndarray]]:
        inst, key = self._group_keys(instances, split, classes)
        if not len(inst):
            return []
        order = np.argsort(key, kind="stable")
        k = key[order]
        cut = np.flatnonzero(k[1:] != k[:-1]) + 1
        bounds = np.concatenate([[0], cut, [len(k)]])
        heads = bounds[:-1]
        # A stable sort puts each group's first instance at its head.
        by_first = np.argsort(order[heads])
        slots = self.slot[inst[order]]
        slots.flags.writeable = False  # shared by the memo's callers
        return [(int(k[a]) // classes, int(k[a]) % classes, slots[a:b])
                for a, b in zip(heads[by_first].tolist(), bounds[1:][by_first].tolist(),
                                strict=True)]

    def _group_keys(self, instances: npt.ArrayLike, split: np.ndarray | None, classes: int = 2
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Scene instance indices as an array, and each one's group key: its GPU primitive
        times ``classes``, plus its ``split`` value."""
        inst = np.asarray(instances, dtype=np.intp).reshape(-1)
        key = self.prim_of[inst] * classes
        if split is not None:
            key = key + split[inst].astype(np.intp)
        return inst, key

    def runs(self, instances: npt.ArrayLike, split: np.ndarray | None = None
             ) -> list[tuple[int, int, np.ndarray]]:
        """Like :meth:`groups`, but keeping the order of ``instances``: one group for each
        stretch of consecutive instances of one GPU primitive (and flag)."""
        inst, key = self._group_keys(instances, split)
        if not len(inst):
            return []
        cut = np.flatnonzero(key[1:] != key[:-1]) + 1
        bounds = np.concatenate([[0], cut, [len(key)]]).tolist()
        slots = self.slot[inst]
        return [(int(key[a]) // 2, int(key[a]) % 2, slots[a:b])
                for a, b in itertools.pairwise(bounds)]

    def release(self) -> None:
        for gp in self.primitives:
            gp.release()
        self.primitives.clear()
        if self.indirect is not None:
            self.indirect.release()
        if self.samplers:
            GL.glDeleteSamplers(len(self.samplers), list(self.samplers.values()))
            self.samplers.clear()


# --------------------------------------------------------------------------------------------
# Render targets
# --------------------------------------------------------------------------------------------


#: Bytes per texel of the internal formats framebuffers use.
_TEXEL_BYTES = {GL.GL_RGBA8: 4, GL.GL_RGBA32F: 16, GL.GL_RG32F: 8, GL.GL_R32F: 4,
                GL.GL_DEPTH_COMPONENT32F: 4,
                GL.GL_DEPTH_COMPONENT24: 4, GL.GL_DEPTH_COMPONENT16: 2}


class Framebuffer:
    """An FBO with owned attachments.

    Parameters
    ----------
    width, height : int
    colors : list of (internal format, format, type)
        One colour attachment each, as 2D textures (or cube faces when ``cube`` is true).
    depth : (internal format, is_texture) or None
    cube : bool
        Attachments are a cube map's six faces, stored as the six layers of 2D array textures
        in GL's face order (+X, -X, +Y, -Y, +Z, -Z); :meth:`bind_face` selects the face to
        render. The camera pass picks the face itself (``cube_face`` in
        ``chunks/shadow_lookup.glsl``), and an array read costs much less than a cube-map read
        on llvmpipe.
    layers : int
        Attachments are 2D array textures of this many layers (cascades); :meth:`bind_layer`
        selects the layer to render. 0: plain 2D textures.
    """

    def __init__(self, width: int, height: int, colors: Sequence[tuple[int, int, int]],
                 depth: tuple[int, bool] | None, cube: bool = False,
                 layers: int = 0) -> None:
        if cube:
            layers = 6
        self.width, self.height, self.cube, self.layers = width, height, cube, layers
        # What the attachments hold (caches bound their size by it).
        texels = width * height * max(layers, 1)
        self.nbytes = texels * (sum(_TEXEL_BYTES.get(c[0], 16) for c in colors)
                                + (_TEXEL_BYTES.get(depth[0], 4) if depth is not None else 0))
        self.fbo = GL.glGenFramebuffers(1)
        self.color_textures: list[int] = []
        self.depth_texture = 0
        self.depth_renderbuffer = 0
        target = GL.GL_TEXTURE_2D_ARRAY if layers else GL.GL_TEXTURE_2D
        self.target = target

        def storage(internal: int, fmt: int, typ: int) -> None:
            if layers:
                GL.glTexImage3D(target, 0, internal, width, height, layers, 0, fmt, typ, None)
            else:
                GL.glTexImage2D(target, 0, internal, width, height, 0, fmt, typ, None)

        try:
            for internal, fmt, typ in colors:
                tex = GL.glGenTextures(1)
                self.color_textures.append(tex)
                GL.glBindTexture(target, tex)
                storage(internal, fmt, typ)
                _sampling(target)
            if depth is not None:
                internal, as_texture = depth
                if as_texture:
                    self.depth_texture = GL.glGenTextures(1)
                    GL.glBindTexture(target, self.depth_texture)
                    storage(internal, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
                    # Read as plain depths, nearest: the camera pass compares every texel
                    # against the receiver's plane at that texel (chunks/shadow_lookup.glsl).
                    _sampling(target)
                else:
                    self.depth_renderbuffer = GL.glGenRenderbuffers(1)
                    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self.depth_renderbuffer)
                    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, internal, width, height)
            GL.glBindTexture(target, 0)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
            if self.depth_renderbuffer:
                GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT,
                                             GL.GL_RENDERBUFFER, self.depth_renderbuffer)
            if layers:
                self.bind_layer(0)
            else:
                self._attach(GL.GL_TEXTURE_2D)
            GL.glDrawBuffers(len(colors), [GL.GL_COLOR_ATTACHMENT0 + i for i in range(len(colors))]
                             if colors else [GL.GL_NONE])
            if not colors:
                GL.glReadBuffer(GL.GL_NONE)
            status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
            if status != GL.GL_FRAMEBUFFER_COMPLETE:
                raise RenderError(
                    f"framebuffer {width}x{height} incomplete (status 0x{status:04x})"
                )
        except Exception:
            self.release()
            raise

    def _attach(self, target: int) -> None:
        for i, tex in enumerate(self.color_textures):
            GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0 + i, target, tex,
                                      0)
        if self.depth_texture:
            GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, target,
                                      self.depth_texture, 0)

    def bind(self) -> None:
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glViewport(0, 0, self.width, self.height)

    def bind_face(self, face: int) -> None:
        """Render into (and read from) one face of a cube map (0 to 5: +X, -X, +Y, -Y, +Z, -Z)."""
        self.bind_layer(face)

    def bind_layer(self, layer: int) -> None:
        """Render into (and read from) one layer of the array attachments."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        for i, tex in enumerate(self.color_textures):
            GL.glFramebufferTextureLayer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0 + i, tex, 0,
                                         layer)
        if self.depth_texture:
            GL.glFramebufferTextureLayer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT,
                                         self.depth_texture, 0, layer)
        GL.glViewport(0, 0, self.width, self.height)

    def read_color(self, index: int, fmt: int, typ: int, channels: int,
                   dtype: npt.DTypeLike, buffers: ReadbackBuffers | None = None) -> np.ndarray:
        """Read one colour attachment; returns (H, W, channels), row 0 at the top.

        The result is a row-flipped view (negative row stride) of the array GL wrote into: GL's
        row 0 is the bottom, and a contiguous top-down copy would cost several times the read
        itself (the PNG writer takes the rows as they are). That array comes from ``buffers``
        when given (see :class:`ReadbackBuffers`), else it is a new one.
        """
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0 + index)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        # Into our own array: PyOpenGL's own return value is one more copy, as bytes.
        shape = (self.height, self.width, channels)
        arr = buffers.take(shape, dtype) if buffers is not None else np.empty(shape, dtype)
        GL.glReadPixels(0, 0, self.width, self.height, fmt, typ, arr)
        return arr[::-1]

    def read_depth(self, buffers: ReadbackBuffers | None = None) -> np.ndarray:
        """Read the depth attachment as float32 (H, W), row 0 at the top (a flipped view, as
        :meth:`read_color`)."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        shape = (self.height, self.width)
        arr = (buffers.take(shape, np.float32) if buffers is not None
               else np.empty(shape, np.float32))
        GL.glReadPixels(0, 0, self.width, self.height, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, arr)
        return arr[::-1]

    def release(self) -> None:
        if self.color_textures:
            GL.glDeleteTextures(self.color_textures)
            self.color_textures = []
        if self.depth_texture:
            GL.glDeleteTextures([self.depth_texture])
            self.depth_texture = 0
        if self.depth_renderbuffer:
            GL.glDeleteRenderbuffers(1, [self.depth_renderbuffer])
            self.depth_renderbuffer = 0
        if self.fbo:
            GL.glDeleteFramebuffers(1, [self.fbo])
            self.fbo = 0


#: Bytes of read-back arrays a camera pass keeps for its next frames
#: (:class:`ReadbackBuffers`): a 1920x1080 frame's colour, visibility and depth, twice over.
READBACK_KEEP_BYTES = 96 * 2**20


def _references(kept: list[np.ndarray], i: int) -> int:
    """References to ``kept[i]``, counted the same way for :data:`_REFERENCES_WHEN_FREE`."""
    return sys.getrefcount(kept[i])


#: What :func:`_references` says of an array only its list holds (the interpreter's own
#: references during the call included, whatever they are in this version of Python).
_REFERENCES_WHEN_FREE = _references([np.empty(0)], 0)


class ReadbackBuffers:
    """Arrays that ``glReadPixels`` writes frames into, each used again once nothing else holds
    it.

    A new array of a frame's size may be memory the process has not touched since the
    allocator last gave such a block back to the system, and then the first write to each of
    its pages is a page fault: whether it is depends on what else the process allocated and
    freed. In a service worker it was, at 1920x1080: about 1,000 faults per request, and the
    read-back took 1.5 times as long (``bench/page_faults.py``). An array here is taken again
    only when no result, view or copy refers to it any more (its reference count says so), so a
    frame a caller still holds is never overwritten; two per shape serve a loop that keeps the
    previous frame while it renders the next. The other arrays of a render (the depth's and
    the encoders' steps) are the C allocator's to keep: see
    :func:`shadowmap.renderer.allocator.keep_freed_memory`.

    Parameters
    ----------
    per_shape : int
        Arrays kept per (shape, dtype); a take that finds all of them held makes a new one and
        lets the oldest go.
    max_bytes : int
        Most bytes kept in all: a new array that would take the total past it is handed out
        and not kept (a 4096x4096 frame's visibility is 256 MiB a target, which a long-lived
        process should not hold between renders).
    """

    def __init__(self, per_shape: int = 2, max_bytes: int = READBACK_KEEP_BYTES) -> None:
        self.per_shape = per_shape
        self.max_bytes = max_bytes
        self._arrays: dict[tuple[tuple[int, ...], np.dtype], list[np.ndarray]] = {}

    def take(self, shape: tuple[int, ...], dtype: npt.DTypeLike) -> np.ndarray:
        """An array of this shape and dtype that nothing outside this object refers to."""
        kept = self._arrays.setdefault((shape, np.dtype(dtype)), [])
        for i in range(len(kept)):
            if _references(kept, i) == _REFERENCES_WHEN_FREE:
                return kept[i]
        arr = np.empty(shape, dtype)
        if self.per_shape <= 0:
            return arr
        if len(kept) >= self.per_shape:
            del kept[0]
        if self.nbytes + arr.nbytes <= self.max_bytes:
            kept.append(arr)
        return arr

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays kept."""
        return sum(a.nbytes for kept in self._arrays.values() for a in kept)

    def clear(self) -> None:
        """Let every array go (those still held elsewhere live on there)."""
        self._arrays.clear()


def _sampling(target: int) -> None:
    f = GL.GL_NEAREST
    GL.glTexParameteri(target, GL.GL_TEXTURE_MIN_FILTER, f)
    GL.glTexParameteri(target, GL.GL_TEXTURE_MAG_FILTER, f)
    GL.glTexParameteri(target, GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE)
    GL.glTexParameteri(target, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)
