"""The light pass: render each light's shadow map.

One FBO per map, from a small pool reused across renders. Colour encodings render the packed depth
into an RGBA8 texture with a float depth renderbuffer for the depth test; the ``depth`` encoding
renders into a depth texture of the plan's ``depth_bits`` (``GL_DEPTH_COMPONENT16`` or
``GL_DEPTH_COMPONENT32F``), which the camera pass reads as plain depths (``textureGather``) to
compare each texel on its own (``shaders/chunks/shadow_lookup.glsl``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from OpenGL import GL

from .. import encodings
from ..cache import BoundedCache, parts_key
from ..gl.programs import ProgramCache
from ..gl.resources import Framebuffer, GpuScene
from ..params import ShadowParams
from ..plan import LightShadow
from ..plan.fit import depth_step

#: Internal format of a depth-encoded map by its plan's ``depth_bits``.
DEPTH_FORMATS = {16: GL.GL_DEPTH_COMPONENT16, 32: GL.GL_DEPTH_COMPONENT32F}


@dataclass(eq=False)
class ShadowMap:
    """A rendered map: ``texture`` is the texture to sample (colour or depth), ``target`` its
    type; ``cached``: drawn by an earlier render (:class:`LightPass`'s map cache)."""

    plan: LightShadow
    fbo: Framebuffer
    encoding: str
    cached: bool = False

    @property
    def texture(self) -> int:
        return self.fbo.depth_texture if self.encoding == "depth" else self.fbo.color_textures[0]

    @property
    def target(self) -> int:
        return self.fbo.target

    @property
    def step(self) -> float:
        """One step of the stored depth t (the unit of the quantisation bias and of the polygon
        offset): the encoding's, or a 16-bit depth texture's 1/65535."""
        return depth_step(self.encoding, self.plan.depth_bits)

    def read_depth(self) -> np.ndarray:
        """Decoded linear depth, NaN where nothing was drawn.

        Returns
        -------
        ndarray, shape (S, S), (6, S, S) or (K, S, S) for K cascades, float32
            Row 0 is the top of the light's view (+Y of the light).
        """
        h, w = self.fbo.height, self.fbo.width
        if self.plan.cascades:
            out = np.empty((len(self.plan.cascades), h, w), np.float32)
            for k in range(len(out)):
                self.fbo.bind_layer(k)
                self._read_into(out[k])
            return out
        if self.plan.kind != "cube":
            out = np.empty((h, w), np.float32)
            self._read_into(out)
            return out
        out = np.empty((6, h, w), np.float32)  # each face straight into its place
        for face in range(6):
            if face not in self.plan.faces:
                out[face] = np.nan
                continue
            self.fbo.bind_face(face)
            self._read_into(out[face])
        return out

    def _read_into(self, out: np.ndarray) -> None:
        """The bound face or layer, decoded into ``out`` (H, W), float32."""
        if self.encoding == "depth":
            # float32 as read: the threshold is the float32 nearest above 1 - 1e-6, so the
            # comparison is the float64 one.
            copy_marking_empty(self.fbo.read_depth(), out, _EMPTY_FLOAT32)
            return
        rgba = self.fbo.read_color(0, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, 4, np.uint8)
        t = encodings.decode(rgba, self.encoding)
        out[...] = np.where(t >= _EMPTY, np.nan, t)


def copy_marking_empty(src: np.ndarray, out: np.ndarray, threshold: np.float32) -> None:
    """``out[...] = src``, NaN where ``src >= threshold``, a block of rows at a time
    (:data:`~shadowmap.renderer.encodings.ROW_BLOCK`: the block stays in the CPU's caches
    between the two passes, where a whole map, 64 MiB at 4096², would go to memory and back).

    Parameters
    ----------
    src : ndarray, shape (H, W), float32
        Any strides (the read-back's bottom-up rows as a flipped view).
    out : ndarray, shape (H, W), float32
    """
    nan = np.float32(np.nan)
    step = encodings.ROW_BLOCK
    for r in range(0, src.shape[0], step):
        block, dst = src[r:r + step], out[r:r + step]
        np.copyto(dst, block)
        np.copyto(dst, nan, where=block >= threshold)


#: Stored depth from which a texel counts as empty (the cleared far plane, 1).
_EMPTY = 1.0 - 1e-6
#: The smallest float32 at or above it: a float32 depth compares against it as against _EMPTY.
_EMPTY_FLOAT32 = np.float32(_EMPTY)
if float(_EMPTY_FLOAT32) < _EMPTY:  # compared in float64
    _EMPTY_FLOAT32 = np.nextafter(_EMPTY_FLOAT32, np.float32(2.0))


def map_key(scene_key: str, origin: np.ndarray, lp: LightShadow, shadows: ShadowParams) -> str:
    """What a light's map holds, as one content key ("" when the scene has no key).

    A map is a function of the scene's geometry (its key, and the upload's origin the matrices
    are relative to), the map's fit (views, projections, depth range, size, faces, casters and
    the faces they leave out) and the settings the light pass reads (encoding, polygon
    offset) — not of the camera, nor of the filter the camera pass reads it with: two renders
    whose plans fit a light alike draw the same texels.
    """
    if not scene_key:
        return ""
    parts: list[bytes] = [scene_key.encode(), np.asarray(origin, np.float64).tobytes(),
                          repr((shadows.encoding, shadows.bias.polygon_offset,
                                lp.kind, len(lp.cascades), lp.depth_bits)).encode()]
    for m in lp.maps:
        parts += [m.view.tobytes(), m.proj.tobytes(), *(v.tobytes() for v in m.face_views),
                  repr((m.near, m.far, m.map_size, list(m.faces))).encode(),
                  np.asarray(m.casters, np.int64).tobytes(),
                  # Faces left out change a few silhouette texels by rounding: kept apart.
                  np.asarray(m.one_sided, np.int8).tobytes()]
    return parts_key(parts)


def near_origin(lp: LightShadow, view: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """The view, projection and depth range a map's casters are drawn with: for a perspective
    map the light's view moved along its axis to the near plane, and the projection moved back
    (their product unchanged, composed in float64).

    The view depth of a caster then is its distance past the near plane, small where the light
    is far from the scene (a point light 1e5 units out, its casters between 1e5 and 1e5 + 6): in
    float32 a depth of 1e5 steps by 0.008, a hundred steps of a 16-bit map over a span of 6,
    and the stored depth (w - near) / span was rounding noise. Orthographic and cube maps keep
    theirs (their views are centred on the scene or the light's position nearby).

    Returns
    -------
    view, proj : ndarray, shape (4, 4), float64
    depth_range : (float, float)
        The near and far depths in that view (the stored depth is linear between them).
    """
    if lp.kind != "perspective":
        return view, lp.proj, (lp.near, lp.far)
    move = np.eye(4)
    move[2, 3] = lp.near  # view-space z + near: -z is the depth past the near plane
    back = np.eye(4)
    back[2, 3] = -lp.near
    return move @ view, lp.proj @ back, (0.0, lp.far - lp.near)


class LightPass:
    """Renders shadow maps; owns a pool of framebuffers keyed by (kind, size, encoding, layers,
    depth bits)
    and a cache of drawn maps by :func:`map_key`.

    Parameters
    ----------
    programs : ProgramCache
    pool_size : int
        Framebuffers kept for reuse by later renders.
    cache_bytes : int
        Upper bound of the attachments held by cached maps; 0 disables the map cache. A render
        whose plan fits a light as an earlier render did (``shadows.fit: "scene"`` over one
        scene, or the same request again) samples that map instead of drawing it.
    cache_entries : int
        Most maps cached.
    """

    def __init__(self, programs: ProgramCache, pool_size: int = 8, *,
                 cache_bytes: int = 192 * 2**20, cache_entries: int = 16) -> None:
        self.programs = programs
        self.pool: dict[tuple, list[Framebuffer]] = {}
        self.pool_size = pool_size
        self.variants: set[tuple] = set()  # defines of the programs drawn with, per frame
        self._taken: set[int] = set()  # framebuffers the current frame draws or samples
        # map_key() by light plan (see _map_key); the plan is held, so its id stays its own.
        self._keys: dict[int, tuple[LightShadow, tuple, str]] = {}
        # Per map plan with one-sided casters, by id: (plan, scene instances, the face classes
        # by scene instance). The same array for a repeated plan lets GpuScene.groups() reuse
        # its grouping. (No upload is held here: a cache must not keep a scene alive.)
        self._sides: dict[int, tuple[LightShadow, int, np.ndarray]] = {}
        # An evicted map's framebuffer goes back to the pool: the next map of its shape reuses it.
        self.cache: BoundedCache[tuple[tuple, Framebuffer]] = BoundedCache(
            cache_entries, cache_bytes, size=lambda e: e[1].nbytes, on_evict=self._unkeep)

    def _map_key(self, scene_key: str, origin: np.ndarray, lp: LightShadow,
                 shadows: ShadowParams) -> str:
        """:func:`map_key`, once per light plan: a plan is immutable, and a repeated request's
        plan is the same object (the renderer's plan cache), so its maps' keys are too."""
        settings = (scene_key, np.asarray(origin, np.float64).tobytes(), shadows.encoding,
                    tuple(shadows.bias.polygon_offset))
        hit = self._keys.get(id(lp))
        if hit is not None and hit[0] is lp and hit[1] == settings:
            return hit[2]
        key = map_key(scene_key, origin, lp, shadows)
        self._keys[id(lp)] = (lp, settings, key)
        while len(self._keys) > 4 * max(self.cache.max_entries, 1):
            self._keys.pop(next(iter(self._keys)))
        return key

    def _unkeep(self, entry: tuple[tuple, Framebuffer]) -> None:
        pool_key, fb = entry
        self.pool.setdefault(pool_key, []).append(fb)
        self._trim(self._taken)

    def _framebuffer(self, key: tuple, taken: set[int]) -> Framebuffer:
        kind, size, encoding, layers, bits = key
        for fb in self.pool.get(key, []):
            if id(fb) not in taken:
                return fb
        cube = kind == "cube"
        if encoding == "depth":
            fb = Framebuffer(size, size, [], (DEPTH_FORMATS[bits], True), cube=cube,
                             layers=layers)
        elif layers:
            # Each layer needs its own depth test: a layered depth texture, not a renderbuffer.
            fb = Framebuffer(size, size, [(GL.GL_RGBA8, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)],
                             (GL.GL_DEPTH_COMPONENT32F, True), layers=layers)
        else:
            fb = Framebuffer(size, size, [(GL.GL_RGBA8, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)],
                             (GL.GL_DEPTH_COMPONENT32F, False), cube=cube)
        self.pool.setdefault(key, []).append(fb)
        self._trim(taken | {id(fb)})
        return fb

    def _trim(self, keep: set[int]) -> None:
        """Release the oldest framebuffers until the pool holds ``pool_size``, never one in
        ``keep`` (the maps this frame has drawn, or is about to draw, and will sample): a frame
        with more maps than ``pool_size`` grows the pool until a later frame needs fewer."""
        total = sum(len(v) for v in self.pool.values())
        for key in list(self.pool):
            fbs = self.pool[key]
            for fb in list(fbs):
                if total <= self.pool_size:
                    return
                if id(fb) in keep:
                    continue
                fbs.remove(fb)
                fb.release()
                total -= 1
            if not fbs:
                del self.pool[key]

    def render(self, gpu: GpuScene, plans: list[LightShadow], shadows: ShadowParams,
               scene_key: str = "") -> list[ShadowMap]:
        """Render the maps of every light that has one; lights without a plan get no map.

        A map whose :func:`map_key` is cached is sampled as it is (``ShadowMap.cached``); the
        others are drawn and then cached. ``scene_key``: the scene's content key ("" caches
        nothing).
        """
        maps = []
        self.variants = set()
        taken = self._taken = set()
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDisable(GL.GL_BLEND)
        # Both faces cast (thin and open geometry must not leak), but where the plan leaves the
        # far side of a closed caster out (LightShadow.one_sided; _draw_casters culls it).
        GL.glDisable(GL.GL_CULL_FACE)
        for lp in plans:
            if lp.kind is None:
                continue
            layers = len(lp.cascades)
            size = lp.cascades[0].map_size if layers else lp.map_size
            key = self._map_key(scene_key, gpu.origin, lp, shadows) if self.cache.enabled else ""
            hit = self.cache.get(key) if key else None
            if hit is not None:
                taken.add(id(hit[1]))
                maps.append(ShadowMap(lp, hit[1], shadows.encoding, cached=True))
                continue
            pool_key = (lp.kind, size, shadows.encoding, layers, lp.depth_bits)
            fb = self._framebuffer(pool_key, taken)
            taken.add(id(fb))
            # (target, plan, view): every cube face, every cascade's layer, or the one map.
            targets: list[tuple[tuple[str, int] | None, LightShadow, np.ndarray]]
            if layers:
                targets = [(("layer", k), c, c.view) for k, c in enumerate(lp.cascades)]
            elif lp.kind == "cube":
                targets = [(("face", f), lp, lp.face_views[f]) for f in lp.faces]
            else:
                targets = [(None, lp, lp.view)]
            groups = self._groups(gpu, lp)  # once per light, for every face
            step = ShadowMap(lp, fb, shadows.encoding).step
            for where, part, view in targets:
                if where is None:
                    fb.bind()
                elif where[0] == "face":
                    fb.bind_face(where[1])
                else:
                    fb.bind_layer(where[1])
                GL.glClearColor(1.0, 1.0, 1.0, 1.0)
                GL.glClearDepth(1.0)
                GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
                if part is not lp:  # a cascade draws its own casters
                    self._draw_casters(gpu, self._groups(gpu, part), part, view, shadows,
                                       step)
                else:
                    self._draw_casters(gpu, groups, part, view, shadows, step)
            maps.append(ShadowMap(lp, fb, shadows.encoding))
            if key and self.cache.put(key, (pool_key, fb)):
                self.pool[pool_key].remove(fb)  # the cache owns it now
                if not self.pool[pool_key]:
                    del self.pool[pool_key]
        self._trim(taken)
        return maps

    def _groups(self, gpu: GpuScene, m: LightShadow) -> list[tuple[int, int, np.ndarray]]:
        """The casters of map ``m`` by GPU primitive and by the faces they leave out: (GPU
        primitive, class, slots), class 0 drawing every face, 1 leaving out GL's back faces, 2
        its front faces (``m.one_sided``)."""
        if not m.one_sided.size:
            return gpu.groups(m.casters)
        n = len(gpu.prim_of)
        hit = self._sides.get(id(m))
        if hit is None or hit[0] is not m or hit[1] != n:
            classes = np.zeros(n, np.intp)
            classes[np.asarray(m.casters, np.intp)] = np.choose(m.one_sided + 1, (2, 0, 1))
            hit = self._sides[id(m)] = (m, n, classes)
            while len(self._sides) > 4 * max(self.cache.max_entries, 1):
                self._sides.pop(next(iter(self._sides)))
        return gpu.groups(m.casters, hit[2], classes=3)

    def _draw_casters(self, gpu: GpuScene, groups: list[tuple[int, int, np.ndarray]],
                      lp: LightShadow, view: np.ndarray, shadows: ShadowParams,
                      step: float) -> None:
        """Draw the casters, one draw per GPU primitive (:meth:`GpuScene.groups`); ``step``:
        one step of the map's stored depth (:attr:`ShadowMap.step`), the polygon offset's
        unit."""
        perspective = lp.kind != "ortho"
        shifted = near_origin(lp, view)
        po_factor, po_units = shadows.bias.polygon_offset
        polygon_offset = bool(po_factor or po_units)
        culled = 0
        for p, faces, slots in groups:
            if faces != culled:  # see _groups(): which faces this group leaves out
                if faces:
                    GL.glEnable(GL.GL_CULL_FACE)
                    GL.glCullFace(GL.GL_BACK if faces == 1 else GL.GL_FRONT)
                else:
                    GL.glDisable(GL.GL_CULL_FACE)
                culled = faces
            gp = gpu.primitives[p]
            mat = gp.material
            cutoff = mat.shadow_cutoff
            if cutoff is not None and gp.texture is None and mat.base_color[3] < cutoff:
                continue  # wholly transparent for shadows
            alpha_test = mat.shadow_texture_cut
            texture = gp.texture if alpha_test else None
            defines = {
                "ENCODING": encodings.ENCODING_ID[shadows.encoding],
                "ALPHA_TEST": alpha_test,
                "LOC_UV": gp.loc_uv,
                "LOC_MODEL": gp.loc_model,
                "WRITE_DEPTH": perspective or (polygon_offset and shadows.encoding == "depth"),
                "POLYGON_OFFSET": polygon_offset,
            }
            self.variants.add(tuple(sorted(defines.items())))
            prog = self.programs.get("light_pass.vert", "light_pass.frag", defines)
            prog.use()
            prog.set("u_light_view", shifted[0])
            prog.set("u_light_proj", shifted[1])
            if shadows.encoding != "depth" or defines["WRITE_DEPTH"]:
                # (an orthographic depth-texture map stores the window depth as it is)
                prog.set("u_depth_range", shifted[2])
            if polygon_offset:
                prog.set("u_polygon_offset", (po_factor, po_units * step))
            if texture is not None and cutoff is not None:
                gp.bind_texture(0, alpha=True)
                prog.set("u_alpha_texture", 0)
                prog.set("u_base_alpha", float(mat.base_color[3]))
                prog.set("u_alpha_cutoff", cutoff)
            gp.draw(None if len(slots) == len(gp.instances) else slots)
        if culled:
            GL.glDisable(GL.GL_CULL_FACE)
        GL.glBindSampler(0, 0)  # what a cut-out bound (GpuPrimitive.bind_texture)

    def release(self) -> None:
        self.cache.clear()  # back into the pool, released below
        for fbs in self.pool.values():
            for fb in fbs:
                fb.release()
        self.pool.clear()

