"""GL resources owned explicitly: uploaded scenes and framebuffers.

Meshes and textures are uploaded with pyrender's ``Primitive`` and ``Texture``. Every object here
belongs to the :class:`~shadowmap.renderer.gl.context.GLContext` current when it was made, is used
from that context's thread only, and is freed by its ``release()`` (safe to call twice).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pyrender
from OpenGL import GL

from ..errors import RenderError
from ..scene import Scene

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
    mesh : pyrender.Primitive
    instances : list of int
        Indices into :attr:`Scene.instances`, in instance-buffer order.
    texture : pyrender.Texture or None
    loc_uv, loc_color, loc_model : int
        Attribute locations of pyrender's interleaved layout (positions 0, normals 1, then
        texture coordinates and colours when present, then the 4 columns of the model matrix).
    count : int
        Indices per instance.
    mirrored_from : int
        First slot of the mirrored instances; ``len(instances)`` when there are none.
    """

    mesh: pyrender.Primitive
    instances: list[int]
    texture: pyrender.Texture | None
    loc_uv: int
    loc_color: int
    loc_model: int
    count: int
    mirrored_from: int

    @property
    def mirrored(self) -> int:
        """Number of mirrored instances (the last ones in the buffer)."""
        return len(self.instances) - self.mirrored_from

    def draw(self, slots: list[int] | None = None) -> None:
        """Draw all instances, or only the given slots (positions in :attr:`instances`).

        Mirrored instances are drawn with clockwise front faces, so that back-face culling, where
        the caller enables it, removes the same faces as for their unmirrored counterparts.
        """
        self.mesh._bind()
        if slots is None and not self.mirrored:
            GL.glDrawElementsInstanced(
                GL.GL_TRIANGLES, self.count, GL.GL_UNSIGNED_INT, None, len(self.instances)
            )
        else:
            runs = [(0, len(self.instances))] if slots is None else _runs(slots)
            for start, n, mirrored in _split_runs(runs, self.mirrored_from):
                if mirrored:
                    GL.glFrontFace(GL.GL_CW)
                GL.glDrawElementsInstancedBaseInstance(
                    GL.GL_TRIANGLES, self.count, GL.GL_UNSIGNED_INT, None, n, start
                )
                if mirrored:
                    GL.glFrontFace(GL.GL_CCW)  # GL's default, which every other draw assumes
        self.mesh._unbind()

    def release(self) -> None:
        self.mesh.delete()
        if self.texture is not None and self.texture._in_context():
            self.texture.delete()


def _split_runs(runs: list[tuple[int, int]], boundary: int) -> list[tuple[int, int, bool]]:
    """Runs of slots cut at ``boundary``: (start, length, slots from ``boundary`` on)."""
    out: list[tuple[int, int, bool]] = []
    for start, n in runs:
        end = start + n
        if start < boundary < end:
            out += [(start, boundary - start, False), (boundary, end - boundary, True)]
        else:
            out.append((start, n, start >= boundary))
    return out


def _runs(slots: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs of sorted slots as (start, length)."""
    out: list[tuple[int, int]] = []
    for s in sorted(slots):
        if out and out[-1][0] + out[-1][1] == s:
            out[-1] = (out[-1][0], out[-1][1] + 1)
        else:
            out.append((s, 1))
    return out


@dataclass(eq=False)
class GpuScene:
    """A scene uploaded to one context, positioned relative to ``origin``.

    Model matrices are uploaded as ``T(-origin) @ M`` computed in float64, so float32 on the GPU
    keeps its precision for a scene far from the world origin.

    Attributes
    ----------
    origin : ndarray, shape (3,), float64
    primitives : list of GpuPrimitive
    slot_of : dict of int to (int, int)
        Scene instance index -> (GPU primitive index, slot in its instance buffer).
    """

    scene: Scene
    origin: np.ndarray
    primitives: list[GpuPrimitive] = field(default_factory=list)
    slot_of: dict[int, tuple[int, int]] = field(default_factory=dict)
    nbytes: int = 0

    @classmethod
    def upload(cls, scene: Scene) -> GpuScene:
        lo, hi = scene.bounds
        origin = (lo + hi) / 2
        gs = cls(scene=scene, origin=origin)
        shift = np.eye(4)
        shift[:3, 3] = -origin
        by_prim: dict[int, list[int]] = {}
        for idx, inst in enumerate(scene.instances):
            by_prim.setdefault(inst.primitive, []).append(idx)
        # Mirrored instances after the others (a stable partition: without any, the buffer is
        # in scene order as before), so that each kind is one run of slots with one winding.
        dets = np.linalg.det(np.stack([inst.matrix[:3, :3] for inst in scene.instances]))
        mirrored = {int(i) for i in np.flatnonzero(dets < 0)}
        if mirrored:
            by_prim = {p: [i for i in ids if i not in mirrored] + [i for i in ids if i in mirrored]
                       for p, ids in by_prim.items()}
        textures: dict[int, pyrender.Texture] = {}
        try:
            for pidx, inst_ids in by_prim.items():
                prim = scene.primitives[pidx]
                poses = np.stack([shift @ scene.instances[i].matrix for i in inst_ids])
                mesh = pyrender.Primitive(
                    positions=prim.positions,
                    normals=prim.normals,
                    texcoord_0=prim.uv,
                    color_0=prim.colors,
                    indices=prim.indices,
                    poses=poses,
                )
                mesh._add_to_context()
                tex = None
                if prim.material.texture is not None:
                    key = id(prim.material.texture)
                    tex = textures.get(key)
                    if tex is None:
                        tex = pyrender.Texture(
                            source=prim.material.texture,
                            source_channels="RGBA",
                            sampler=pyrender.Sampler(
                                wrapS=GL.GL_REPEAT, wrapT=GL.GL_REPEAT
                            ),
                        )
                        tex._add_to_context()
                        textures[key] = tex
                        gs.nbytes += prim.material.texture.nbytes * 4 // 3
                has_uv = prim.uv is not None
                has_color = prim.colors is not None
                gp = GpuPrimitive(
                    mesh=mesh,
                    instances=inst_ids,
                    texture=tex,
                    loc_uv=2,
                    loc_color=2 + has_uv,
                    loc_model=2 + has_uv + has_color,
                    count=int(prim.indices.size),
                    mirrored_from=sum(1 for i in inst_ids if i not in mirrored),
                )
                for slot, i in enumerate(inst_ids):
                    gs.slot_of[i] = (len(gs.primitives), slot)
                gs.primitives.append(gp)
                gs.nbytes += prim.positions.nbytes * (2 + has_uv + has_color) + prim.indices.nbytes
        except Exception:
            gs.release()
            for t in textures.values():
                if t._in_context():
                    t.delete()
            raise
        return gs

    def release(self) -> None:
        for gp in self.primitives:
            gp.release()
        self.primitives.clear()


# --------------------------------------------------------------------------------------------
# Render targets
# --------------------------------------------------------------------------------------------


class Framebuffer:
    """An FBO with owned attachments.

    Parameters
    ----------
    width, height : int
    colors : list of (internal format, format, type)
        One colour attachment each, as 2D textures (or cube faces when ``cube`` is true).
    depth : (internal format, is_texture) or None
    cube : bool
        Attachments are cube maps; :meth:`bind_face` selects the face to render.
    """

    def __init__(self, width: int, height: int, colors: Sequence[tuple[int, int, int]],
                 depth: tuple[int, bool] | None, cube: bool = False, depth_compare: bool = False,
                 linear: bool = False) -> None:
        self.width, self.height, self.cube = width, height, cube
        self.fbo = GL.glGenFramebuffers(1)
        self.color_textures: list[int] = []
        self.depth_texture = 0
        self.depth_renderbuffer = 0
        target = GL.GL_TEXTURE_CUBE_MAP if cube else GL.GL_TEXTURE_2D
        faces = [GL.GL_TEXTURE_CUBE_MAP_POSITIVE_X + i for i in range(6)] if cube else [target]
        try:
            for internal, fmt, typ in colors:
                tex = GL.glGenTextures(1)
                self.color_textures.append(tex)
                GL.glBindTexture(target, tex)
                for f in faces:
                    GL.glTexImage2D(f, 0, internal, width, height, 0, fmt, typ, None)
                _sampling(target, linear=False)
            if depth is not None:
                internal, as_texture = depth
                if as_texture:
                    self.depth_texture = GL.glGenTextures(1)
                    GL.glBindTexture(target, self.depth_texture)
                    for f in faces:
                        GL.glTexImage2D(f, 0, internal, width, height, 0,
                                        GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, None)
                    _sampling(target, linear=linear)
                    if depth_compare:
                        GL.glTexParameteri(target, GL.GL_TEXTURE_COMPARE_MODE,
                                           GL.GL_COMPARE_REF_TO_TEXTURE)
                        GL.glTexParameteri(target, GL.GL_TEXTURE_COMPARE_FUNC, GL.GL_LEQUAL)
                else:
                    self.depth_renderbuffer = GL.glGenRenderbuffers(1)
                    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self.depth_renderbuffer)
                    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, internal, width, height)
            GL.glBindTexture(target, 0)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
            if self.depth_renderbuffer:
                GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT,
                                             GL.GL_RENDERBUFFER, self.depth_renderbuffer)
            if not cube:
                self._attach(GL.GL_TEXTURE_2D)
            else:
                self.bind_face(0)
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
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        self._attach(GL.GL_TEXTURE_CUBE_MAP_POSITIVE_X + face)
        GL.glViewport(0, 0, self.width, self.height)

    def read_color(self, index: int, fmt: int, typ: int, channels: int,
                   dtype: npt.DTypeLike) -> np.ndarray:
        """Read one colour attachment; returns (H, W, channels), row 0 at the top."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0 + index)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        data = GL.glReadPixels(0, 0, self.width, self.height, fmt, typ)
        arr = np.frombuffer(data, dtype=dtype).reshape(self.height, self.width, channels)
        return arr[::-1]

    def read_depth(self) -> np.ndarray:
        """Read the depth attachment as float32 (H, W), row 0 at the top."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        data = GL.glReadPixels(0, 0, self.width, self.height, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
        return np.frombuffer(data, dtype=np.float32).reshape(self.height, self.width)[::-1]

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


def _sampling(target: int, linear: bool) -> None:
    f = GL.GL_LINEAR if linear else GL.GL_NEAREST
    GL.glTexParameteri(target, GL.GL_TEXTURE_MIN_FILTER, f)
    GL.glTexParameteri(target, GL.GL_TEXTURE_MAG_FILTER, f)
    GL.glTexParameteri(target, GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE)
    GL.glTexParameteri(target, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)
    if target == GL.GL_TEXTURE_CUBE_MAP:
        GL.glTexParameteri(target, GL.GL_TEXTURE_WRAP_R, GL.GL_CLAMP_TO_EDGE)
