"""The camera pass: shade the visible objects, comparing against each light's shadow map.

Writes the colour image, and only when asked for, the per-light visibility (float targets) and
the camera depth. Opaque and alpha-masked objects are drawn first; blended objects after them,
back to front, without writing depth or visibility.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from OpenGL import GL

from .. import encodings
from ..camera import Camera
from ..errors import RenderError
from ..gl.programs import Program, ProgramCache
from ..gl.resources import Framebuffer, GpuPrimitive, GpuScene, ReadbackBuffers
from ..limits import MAX_CASCADES, visibility_target_channels
from ..params import RenderParams
from ..plan import LightShadow, RenderPlan
from ..plan import shadow_region as SR
from ..plan.context import CAMERA_OUTPUTS
from ..scene import Material, instance_arrays
from ..shader_constants import LIGHT_TYPES
from .light_pass import ShadowMap

# Attribute slots that no VAO enables: reading them yields the constant set with glVertexAttrib,
# which is how the generic variant feeds white colours and (0, 0) UVs to primitives without them.
SPARE_UV, SPARE_COLOR = 14, 15
# Light clip space [-1, 1] -> texture space [0, 1] on x, y and z (the documents' bias matrix).
BIAS = np.array([[0.5, 0, 0, 0.5], [0, 0.5, 0, 0.5], [0, 0, 0.5, 0.5], [0, 0, 0, 1.0]])
# The camera's clip space -> reversed depth: z_ndc' = (1 - z_ndc) / 2, the near plane at window
# depth 1 and the far plane at 0 (with glClipControl's zero-to-one depth range). A float depth
# buffer holds most of its values near 0, so the depth test keeps about the same relative
# precision at every distance; with depth growing towards the far plane it had the precision of
# a 24-bit integer there, and surfaces a few centimetres apart 350 units away, seen through a
# near plane 1e-4 of the far one (a camera inside a wide ground's bounds), drew each other.
# x, y and w are unchanged: every pixel is covered by the same surfaces as with the standard
# projection (the shadow region's rectangles are projected with it).
REVERSED_Z = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, -0.5, 0.5], [0, 0, 0, 1.0]])


@dataclass
class CameraOutputs:
    """Read-back images; each None unless requested.

    color : (H, W, 3|4) uint8; visibility : (H, W, L) float32; depth : (H, W) float32.
    """

    color: np.ndarray | None = None
    visibility: np.ndarray | None = None
    depth: np.ndarray | None = None


#: Visibility target formats by channels, (internal format, read-back format): see
#: :func:`~shadowmap.renderer.limits.visibility_target_channels`. The shader writes a vec4 per
#: target; a narrower target keeps its first channels.
_VIS_FORMATS = {1: (GL.GL_R32F, GL.GL_RED), 2: (GL.GL_RG32F, GL.GL_RG),
                4: (GL.GL_RGBA32F, GL.GL_RGBA)}


def linear_depth(window: np.ndarray, camera: Camera, reversed_z: bool) -> np.ndarray:
    """Camera depth (distance along the view axis) of each pixel from its window depth.

    Worked in float64 in one array, in place, then float32; NaN where nothing was drawn (the
    depth still the cleared value: 0 with reversed depth, 1 without). At 640x480 this takes
    half the time of the plain formulas with a new array per step, for the same bits.

    Parameters
    ----------
    window : ndarray, shape (H, W), float32
        The depth buffer as read.
    camera : Camera
    reversed_z : bool
        Whether the frame was drawn with reversed depth (``CameraPass.reversed_z``).

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    n, f = camera.znear, camera.zfar
    z = window.astype(np.float64)
    if camera.orthographic:  # window depth linear in z: (z - n) / (f - n), or 1 - that
        if reversed_z:
            np.subtract(1.0, z, out=z)
        z *= f - n
        z += n
    elif reversed_z:  # window depth n (f - z) / ((f - n) z): 1 at z = n, 0 at f
        z *= f - n
        z += n
        np.divide(n * f, z, out=z)
    else:  # z = 2 n f / ((f + n) - (2 d - 1) (f - n))
        z *= 2
        z -= 1
        z *= f - n
        np.subtract(f + n, z, out=z)
        np.divide(2 * n * f, z, out=z)
    out = z.astype(np.float32)
    # The window depth's distance from the cleared value, divided by itself: exactly 1 where
    # something was drawn and NaN (0 / 0) where nothing was, one multiplication that leaves the
    # depth's bits as they are (a masked assignment over a large background costs as much as
    # the whole linearisation).
    gap = window if reversed_z else np.subtract(np.float32(1.0), window)
    with np.errstate(invalid="ignore"):
        out *= gap / gap
    return out


class CameraPass:
    """Owns the camera framebuffer (re-created when the size or outputs change)."""

    def __init__(self, programs: ProgramCache) -> None:
        self.programs = programs
        self.fbo: Framebuffer | None = None
        self._fbo_key: tuple | None = None
        # The arrays frames are read back into, used again once the caller lets a result go.
        self.readback = ReadbackBuffers()
        self._white = 0
        self.variants: set[tuple] = set()  # defines of the programs drawn with, per frame
        # The last frame's state, by (plan, request, maps' plans, visibility targets): a
        # repeated request (the same plan and request objects) reuses it and its defines.
        self._frame: tuple[RenderPlan, RenderParams, tuple, _FrameState] | None = None
        # glClipControl, None where the context has none; looked up once a context is current.
        self._clip_control: Callable[[int, int], None] | None | _Unresolved = _UNRESOLVED

    @property
    def reversed_z(self) -> bool:
        """Whether the camera pass draws with reversed depth (:data:`REVERSED_Z`): where the
        context has ``glClipControl`` (GL 4.5, or ``ARB_clip_control``); the standard depth
        range otherwise."""
        if isinstance(self._clip_control, _Unresolved):
            self._clip_control = _clip_control()
        return self._clip_control is not None

    def _framebuffer(self, width: int, height: int, vis_layout: tuple[int, ...]) -> Framebuffer:
        key = (width, height, vis_layout)
        if self._fbo_key != key:
            if self.fbo is not None:
                self.fbo.release()
                self.fbo = None
            self.readback.clear()  # sized for the old frame
            colors = [(GL.GL_RGBA8, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)]
            colors += [(_VIS_FORMATS[c][0], _VIS_FORMATS[c][1], GL.GL_FLOAT) for c in vis_layout]
            self.fbo = Framebuffer(width, height, colors, (GL.GL_DEPTH_COMPONENT32F, True))
            self._fbo_key = key
        assert self.fbo is not None
        return self.fbo

    def _white_texture(self) -> int:
        if not self._white:
            self._white = GL.glGenTextures(1)
            GL.glBindTexture(GL.GL_TEXTURE_2D, self._white)
            GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA8, 1, 1, 0, GL.GL_RGBA,
                            GL.GL_UNSIGNED_BYTE, np.full(4, 255, np.uint8))
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_NEAREST)
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_NEAREST)
        return self._white

    def render(self, gpu: GpuScene, plan: RenderPlan, maps: list[ShadowMap],
               params: RenderParams) -> None:
        """Draw the frame into the camera framebuffer (read it back with :meth:`read`); nothing
        where no output asks for the camera's picture (``plan.camera_mode`` ``"none"``)."""
        self.variants = set()
        if plan.camera_mode == "none":
            return
        if plan.camera_mode == "depth":
            maps = []  # drawn for a light_depth output, if any: no lookup here reads them
        cam = plan.camera
        n_lights = len(plan.lights)
        want_vis = "visibility" in params.outputs and n_lights > 0
        vis_layout = tuple(visibility_target_channels(n_lights)) if want_vis else ()
        vis_targets = len(vis_layout)
        fb = self._framebuffer(cam.width, cam.height, vis_layout)
        fb.bind()
        bg = np.asarray(params.background, np.float32)
        GL.glClearBufferfv(GL.GL_COLOR, 0, bg)
        for i in range(vis_targets):
            GL.glClearBufferfv(GL.GL_COLOR, 1 + i, np.full(4, np.nan, np.float32))
        reversed_z = self.reversed_z  # resolves self._clip_control
        GL.glClearBufferfv(GL.GL_DEPTH, 0, np.full(1, 0.0 if reversed_z else 1.0, np.float32))
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_GREATER if reversed_z else GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDisable(GL.GL_BLEND)
        clip_control = self._clip_control
        if callable(clip_control):
            clip_control(GL.GL_LOWER_LEFT, GL.GL_ZERO_TO_ONE)
        no_color = plan.camera_mode != "shaded"
        if no_color:  # the colour is not read: not written either
            GL.glColorMaski(0, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE)
        try:
            self._draw(gpu, plan, maps, params, vis_targets)
        finally:  # the light pass and everything else draw with GL's default depth range
            GL.glBindSampler(0, 0)  # the last textured draw's (GpuPrimitive.bind_texture)
            if callable(clip_control):
                clip_control(GL.GL_LOWER_LEFT, GL.GL_NEGATIVE_ONE_TO_ONE)
            if no_color:
                GL.glColorMaski(0, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)

    def _draw(self, gpu: GpuScene, plan: RenderPlan, maps: list[ShadowMap],
              params: RenderParams, vis_targets: int) -> None:
        cam = plan.camera
        frame = self._frame_state(plan, maps, params, vis_targets)
        units = self._bind_maps(maps)
        arrays = instance_arrays(gpu.scene)
        # Instances of one primitive with different receive flags are drawn apart (the flag is
        # a uniform); without maps it changes nothing.
        receive = arrays.receive if frame.maps else None
        visible = np.asarray(plan.visible, dtype=np.intp).reshape(-1)
        blended = visible[gpu.blended[gpu.prim_of[visible]]]  # the material is the primitive's
        if len(blended):
            # Back to front by box centre (a stable sort on the negated distance, as the sort
            # of one instance at a time did).
            eye = cam.position
            distance = np.linalg.norm(arrays.bounds[blended].mean(axis=1) - eye, axis=1)
            blended = blended[np.argsort(-distance, kind="stable")]
        region = plan.shadow_region
        opaque = self._opaque(gpu, visible)
        if frame.no_color:  # blended surfaces write no depth or visibility: nothing is output
            blended = blended[:0]
        if not frame.maps or region is None or not region.split:
            self._draw_groups(gpu, gpu.groups(opaque, receive), frame, units)
            self._draw_blended(gpu, gpu.runs(blended, receive), frame, units, vis_targets)
            return
        # Each receiver is drawn with the shadow lookups only inside the rectangle its shadows
        # can reach, and, where it shows outside it too, whole again right after without them:
        # the depth test (GL_GREATER, or GL_LESS) keeps the pixels already drawn, the same
        # surface at the same depth (every variant declares gl_Position invariant), and fills in
        # the rest. Everything else is drawn once, without lookups (plan.shadow_region). The
        # groups keep the order of a frame drawn without the region, so equal depths resolve as
        # they would there.
        plain = frame.without_maps()
        for p, cls, slots in gpu.groups(opaque, region.classes, SR.classes_count()):
            group = [(p, 1, slots)]
            if cls < SR.LOOKUP:
                self._draw_groups(gpu, group, plain, [])
                continue
            rect = region.rects[(cls - SR.LOOKUP) // 2]
            self._draw_groups(gpu, group, frame, units,
                              scissors=[] if region.whole(rect) else [rect])
            if (cls - SR.LOOKUP) % 2:
                self._draw_groups(gpu, group, plain, [])
        # Blended surfaces write no depth: they are drawn in each part of the frame, back to
        # front, with lookups inside the region's bounding rectangle and without outside it.
        inside = [] if region.rect is None or region.whole(region.rect) else [region.rect]
        if region.rect is not None and len(blended):
            self._draw_blended(gpu, gpu.runs(blended, receive), frame, units, vis_targets,
                               inside)
        if (region.rect is None or inside) and len(blended):
            self._draw_blended(gpu, gpu.runs(blended), plain, [], vis_targets,
                               region.outside(region.rect))

    @staticmethod
    def _opaque(gpu: GpuScene, instances: np.ndarray) -> np.ndarray:
        """The instances whose material is not blended."""
        return instances[~gpu.blended[gpu.prim_of[instances]]]

    def _draw_blended(self, gpu: GpuScene, runs: list[tuple[int, int, np.ndarray]],
                      frame: _FrameState, units: list[int], vis_targets: int,
                      scissors: Sequence[tuple[int, int, int, int]] = ()) -> None:
        """Blended runs in the order given (back to front), without depth or visibility writes
        for transparent surfaces (into each scissor rectangle, if any)."""
        if not runs:
            return
        GL.glEnable(GL.GL_BLEND)
        GL.glBlendFuncSeparate(GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA, GL.GL_ONE,
                               GL.GL_ONE_MINUS_SRC_ALPHA)
        GL.glDepthMask(GL.GL_FALSE)
        for i in range(vis_targets):
            GL.glColorMaski(1 + i, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE)
        self._draw_groups(gpu, runs, frame, units, ordered=True, scissors=scissors)
        for i in range(vis_targets):
            GL.glColorMaski(1 + i, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDisable(GL.GL_BLEND)

    def _frame_state(self, plan: RenderPlan, maps: list[ShadowMap], params: RenderParams,
                     vis_targets: int) -> _FrameState:
        """The frame's defines and uniforms: the last frame's again for the same plan, request
        and maps' plans (the maps' textures are bound anew by _bind_maps)."""
        sig = (tuple(id(m.plan) for m in maps), vis_targets)
        last = self._frame
        if last is not None and last[0] is plan and last[1] is params and last[2] == sig:
            frame = last[3]
            frame.maps = maps
            frame.ready = set()
            if frame.bare is not None:
                frame.bare.ready = set()
            return frame
        cam = plan.camera
        view_proj = SR.view_projection(cam, plan.origin)  # the plan's region used the same
        if self.reversed_z:
            view_proj = REVERSED_Z @ view_proj
        frame = _FrameState(plan, maps, params, view_proj, cam.position - plan.origin, vis_targets,
                            generic=not params.optimize)
        self._frame = (plan, params, sig, frame)
        return frame

    def _bind_maps(self, maps: list[ShadowMap]) -> list[int]:
        """Bind every map to its own texture unit (from 1; unit 0 is the base colour texture)."""
        units = []
        for i, sm in enumerate(maps):
            GL.glActiveTexture(GL.GL_TEXTURE1 + i)
            GL.glBindTexture(sm.target, sm.texture)
            units.append(1 + i)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        return units

    def _draw_groups(self, gpu: GpuScene, groups: list[tuple[int, int, np.ndarray]],
                     frame: _FrameState, units: list[int], ordered: bool = False,
                     scissors: Sequence[tuple[int, int, int, int]] = ()) -> None:
        """One draw per (GPU primitive, receive flag, slots) group, in the order given; with
        ``scissors``, one per rectangle. The rectangles do not overlap, so each pixel still sees
        the groups in the order given."""
        if scissors and groups:
            GL.glEnable(GL.GL_SCISSOR_TEST)
            try:
                self._draw_each(gpu, groups, frame, units, ordered, scissors)
            finally:
                GL.glDisable(GL.GL_SCISSOR_TEST)
        else:
            self._draw_each(gpu, groups, frame, units, ordered, ())

    def _draw_each(self, gpu: GpuScene, groups: list[tuple[int, int, np.ndarray]],
                   frame: _FrameState, units: list[int], ordered: bool,
                   scissors: Sequence[tuple[int, int, int, int]]) -> None:
        plan = frame.plan
        for p, receive, slots in groups:
            gp = gpu.primitives[p]
            mat = gp.material
            defines, variant = frame.variant(gp)
            self.variants.add(variant)
            prog = self.programs.get("camera_pass.vert", "camera_pass.frag", defines)
            prog.use()
            if prog.id not in frame.ready:  # uniforms stay with the program: once per frame
                # ... and across frames: a program last set up for this very plan (the
                # renderer's plan cache hands the same object back for a repeated request,
                # and the plan's key covers the request's every field) holds them already.
                if prog.frame_plan is not plan or prog.frame_units != units:
                    frame.set_frame_uniforms(prog, units, lenient=mat.unlit or frame.no_color)
                    prog.frame_plan, prog.frame_units = plan, list(units)
                frame.ready.add(prog.id)
            if not frame.no_color or frame.alpha_mask(mat):  # without colour: the cut-out's
                prog.set("u_base_color", mat.base_color)
            if frame.has_uv(gp):
                if gp.texture is not None:
                    gp.bind_texture(0)  # with its glTF sampler
                else:
                    GL.glActiveTexture(GL.GL_TEXTURE0)
                    GL.glBindTexture(GL.GL_TEXTURE_2D, self._white_texture())
                    GL.glBindSampler(0, 0)
                    GL.glVertexAttrib2f(SPARE_UV, 0.0, 0.0)
                prog.set("u_base_texture", 0)
            if frame.generic and not gp.has_color:
                GL.glVertexAttrib4f(SPARE_COLOR, 1.0, 1.0, 1.0, 1.0)
            if frame.alpha_mask(mat):
                prog.set("u_alpha_cutoff", mat.alpha_cutoff if mat.alpha_mode == "MASK" else -1.0)
            if frame.maps and (not mat.unlit or prog.has("u_receive_shadow")):
                prog.set("u_receive_shadow", int(receive))
            if mat.double_sided or mat.alpha_mode == "BLEND":
                GL.glDisable(GL.GL_CULL_FACE)
            else:
                GL.glEnable(GL.GL_CULL_FACE)
                GL.glCullFace(GL.GL_BACK)
            every = not ordered and len(slots) == len(gp.instances)  # ordered: as given
            if not scissors:
                gp.draw(None if every else slots, ordered=ordered)
            for rect in scissors:
                GL.glScissor(*rect)
                gp.draw(None if every else slots, ordered=ordered)
        GL.glDisable(GL.GL_CULL_FACE)

    def read(self, outputs: Sequence[str], n_lights: int, alpha: bool,
             camera: Camera) -> CameraOutputs:
        """Read back the requested outputs of the last frame."""
        if not CAMERA_OUTPUTS.intersection(outputs):  # no camera pass was drawn for them
            return CameraOutputs()
        fb = self.fbo
        if fb is None:
            raise RenderError("the camera pass has not drawn a frame to read")
        out = CameraOutputs()
        if "color" in outputs:
            # Read as the output wants it: GL drops the alpha while it copies, several times
            # faster than NumPy taking three channels of four (a strided copy per pixel), and
            # the rows stay whole for the PNG writer. A flipped view, not a copy (see
            # Framebuffer.read_color).
            if alpha:
                out.color = fb.read_color(0, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, 4, np.uint8,
                                          self.readback)
            else:
                out.color = fb.read_color(0, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, 3, np.uint8,
                                          self.readback)
        if "visibility" in outputs and n_lights > 0:
            parts = [
                fb.read_color(1 + i, _VIS_FORMATS[c][1], GL.GL_FLOAT, c, np.float32,
                              self.readback)
                for i, c in enumerate(visibility_target_channels(n_lights))
            ]
            vis = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=2)
            out.visibility = vis[..., :n_lights]
        if "depth" in outputs:
            out.depth = linear_depth(fb.read_depth(self.readback), camera, self.reversed_z)
        return out

    def release(self) -> None:
        self._frame = None
        self.readback.clear()
        if self.fbo is not None:
            self.fbo.release()
            self.fbo = None
            self._fbo_key = None
        if self._white:
            GL.glDeleteTextures([self._white])
            self._white = 0


class _Unresolved:
    """Marks a lookup not made yet (None is a result: the context has no such function)."""


_UNRESOLVED = _Unresolved()


def _clip_control() -> Callable[[int, int], None] | None:
    """The current context's ``glClipControl`` (core in GL 4.5, else ``ARB_clip_control``), or
    None where it has none.

    Under OSMesa (Mesa 22.3, a 4.5 context) PyOpenGL's core ``GL.glClipControl`` comes out
    unbound while the extension module's, looked up through ``OSMesaGetProcAddress``, is the
    same entry point and works: either is taken.
    """
    from OpenGL.GL.ARB import clip_control

    major = int(GL.glGetIntegerv(GL.GL_MAJOR_VERSION))
    minor = int(GL.glGetIntegerv(GL.GL_MINOR_VERSION))
    if (major, minor) < (4, 5):
        count = int(GL.glGetIntegerv(GL.GL_NUM_EXTENSIONS))
        names = {GL.glGetStringi(GL.GL_EXTENSIONS, i) for i in range(count)}
        if b"GL_ARB_clip_control" not in names:
            return None
    for function in (GL.glClipControl, clip_control.glClipControl):
        if bool(function):
            return function
    return None


def _texel_axes(proj: np.ndarray) -> tuple[float, float]:
    """A map's texel along its x and y axes over its larger side (the plan's ``texel``): 1 and 1
    for a square fit, less than 1 along the shorter side of an oblong one.

    glOrtho and glFrustum put 2 / width at ``proj[0, 0]`` and 2 / height at ``proj[1, 1]`` (world
    units, or slopes for a frustum), so the ratio of sides is the inverse ratio of the two.
    """
    x, y = abs(float(proj[0, 0])), abs(float(proj[1, 1]))
    m = min(x, y)
    return (m / x, m / y)


def spot_axis(position: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, float]:
    """A spot's axis for ``shaders/chunks/lighting.glsl``, origin-relative: its point nearest
    the origin (the scene's centre), shape (3,), and the light's distance to that point along
    the axis (negative where the light is past it), in float64."""
    axis = np.asarray(direction, np.float64)
    offset = float(-np.dot(position, axis))
    return np.asarray(position, np.float64) + axis * offset, offset


def map2d_matrix(plan: LightShadow) -> np.ndarray:
    """World (origin-relative) to a 2D map's lookup coordinates, shape (4, 4), float64:
    ``BIAS @ proj @ view``, whose x, y over w are the map point and, for an orthographic map, z
    the stored depth t = (depth - near) / (far - near).

    A perspective map's z row is replaced by its stored depth too, an affine function of the
    position whose constant is worked out here in float64: the shader used to take
    ``(w - near) / span`` from w, the distance along the light's axis, and where the light is
    far from the scene (1e5 units, its receivers within a few units of that) float32 kept
    nothing of the difference (see light_pass.near_origin).
    """
    m = BIAS @ plan.proj @ plan.view
    if plan.kind == "perspective":
        span = _span(plan.near, plan.far)
        row = -plan.view[2].copy()  # w, the depth along the axis
        row[3] -= plan.near
        m[2] = row / span
    return m


def map2d_plane_factors(plan: LightShadow, step: float, quantisation_steps: float
                 ) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
    """The receiver plane's per-map factors of ``shaders/chunks/shadow_2d.glsl``
    (``u_map2d_plane``, ``u_map2d_depth``): quotients of the map's size, depth range, texel and
    axes, divided once here instead of on every pixel.

    With ``span = far - near``, ``size`` the map's side and ``(ax, ay)`` its :func:`_texel_axes`,
    a map's world texel is ``texel`` (orthographic) or ``texel_w * w`` at the lookup's depth
    ``w`` (perspective); the factors of a perspective map are per unit of ``w``:

    - plane ``xy``: the tangent per unit of the plane's coefficients: ``span / (texel size a)``
      (orthographic), ``1 / (texel_w size a)`` (perspective; the shader scales it by
      ``w / (w - (a, b) . uv)``);
    - plane ``zw``: the stored depth's change per texel per unit of tangent, ``a texel / span``;
    - depth: ``(texel / span, quantisation_steps * step, span)``.
    """
    span = _span(plan.near, plan.far)
    size = float(plan.map_size)
    ax, ay = _texel_axes(plan.proj)
    tx, ty = plan.texel
    texel = ty if plan.kind == "perspective" else tx
    texel = texel if texel > 0.0 else 1.0  # as _span
    if plan.kind == "perspective":
        tan = (1.0 / (texel * size * ax), 1.0 / (texel * size * ay))
    else:
        tan = (span / (texel * size * ax), span / (texel * size * ay))
    plane = (*tan, ax * texel / span, ay * texel / span)
    depth = (texel / span, quantisation_steps * step, span)
    return plane, depth


def _span(near: float, far: float) -> float:
    """A map's depth range ``far - near``: a fit keeps it positive, the guard keeps a degenerate
    one finite."""
    span = far - near
    return span if span > 0.0 else 1.0


def cube_plane_factors(plan: LightShadow, step: float, quantisation_steps: float
                   ) -> tuple[float, float, float, float]:
    """A cube map's factors of ``shaders/chunks/shadow_cube.glsl`` (``u_mapcube_depth``):
    ``(1 / span, 2 / size, 2 / (size span), quantisation_steps * step)``; a face's texel is
    ``2 depth / size`` world units at face depth ``depth`` (90-degree faces)."""
    span = _span(plan.near, plan.far)
    size = float(plan.map_size)
    return (1.0 / span, 2.0 / size, 2.0 / (size * span), quantisation_steps * step)


def cascade_plane_factors(c: LightShadow, step: float, quantisation_steps: float
               ) -> tuple[float, float, float, float]:
    """A cascade's factors of ``shaders/chunks/shadow_csm.glsl`` (``u_csm_depth``): with its
    world texel ``texel`` (larger side), ``span = far - near`` and its :func:`_texel_axes`
    ``(ax, ay)``, ``(ax texel / span, ay texel / span, texel / span,
    quantisation_steps * step)``."""
    texel_t = c.texel[0] / _span(c.near, c.far)
    ax, ay = _texel_axes(c.proj)
    return (ax * texel_t, ay * texel_t, texel_t, quantisation_steps * step)


def _family(m: ShadowMap) -> str:
    """Which of the camera pass's map families samples ``m``: "2d", "cube" or "csm"."""
    if m.plan.cascades:
        return "csm"
    return "cube" if m.plan.kind == "cube" else "2d"


def camera_eye(camera: Camera, eye: np.ndarray) -> np.ndarray:
    """``u_camera_eye``, shape (4,): the eye (origin-relative, ``eye``) with w = 1; for an
    orthographic camera the direction toward the viewer with w = 0 (its view rays are
    parallel)."""
    if camera.orthographic:
        return np.append(-camera.forward, 0.0)
    return np.append(eye, 1.0)


def camera_forward(camera: Camera, eye: np.ndarray) -> np.ndarray:
    """``u_camera_forward``, shape (4,): the view axis, and w such that the view depth of an
    origin-relative point p is ``dot((p, 1), u_camera_forward)``."""
    f = camera.forward
    return np.append(f, -float(f @ eye))


class _FrameState:
    """Defines and uniforms shared by every draw of one frame."""

    def __init__(self, plan: RenderPlan, maps: list[ShadowMap], params: RenderParams,
                 view_proj: np.ndarray, eye: np.ndarray, vis_targets: int, generic: bool):
        self.plan, self.maps, self.params = plan, maps, params
        self.view_proj, self.eye, self.vis_targets = view_proj, eye, vis_targets
        self.generic = generic
        self.depth_only = plan.camera_mode == "depth"
        self.no_color = plan.camera_mode != "shaded"  # visibility or depth: no shading
        self.ready: set[int] = set()  # programs whose frame uniforms are set
        self.bare: _FrameState | None = None  # without_maps()
        self._variants: dict[int, tuple[GpuPrimitive, dict[str, int | bool | str], tuple]] = {}
        # The frame uniforms and the texture units they were worked out for (frame_uniforms).
        self._uniforms: tuple[tuple[int, ...], list[tuple[str, np.ndarray]]] | None = None
        lights = [lp.light for lp in plan.lights]
        self.n_2d = sum(1 for m in maps if _family(m) == "2d")
        self.n_cube = sum(1 for m in maps if _family(m) == "cube")
        self.n_csm = sum(1 for m in maps if _family(m) == "csm")
        # The light types are constants of the variant, so code for absent types is compiled
        # out whatever these say: they only decide which uniforms exist.
        self.has_spot = any(lt.type == "spot" for lt in lights)
        self.has_positional = any(lt.type != "directional" for lt in lights)
        self.has_direction = any(lt.type != "point" for lt in lights)
        shadows = params.shadows
        self.pcf = bool(maps) and (generic or shadows.filter == "pcf")
        self.pcf_radius = shadows.pcf_kernel // 2 if shadows.filter == "pcf" else 0
        # Each light's slot among the 2D maps and among the cube maps, in the order of `maps`;
        # -1 where it has no map of that kind.
        # Each light's slot among the maps of its family (2D, cube, cascaded), in the order of
        # `maps`; -1 where it has none of that family.
        slots: dict[str, dict[int, int]] = {"2d": {}, "cube": {}, "csm": {}}
        for m in maps:
            family = slots[_family(m)]
            family[m.plan.index] = len(family)
        self.map_2d = [slots["2d"].get(lp.index, -1) for lp in plan.lights]
        self.map_cube = [slots["cube"].get(lp.index, -1) for lp in plan.lights]
        self.map_csm = [slots["csm"].get(lp.index, -1) for lp in plan.lights]
        # Per 2D slot, its projection: each map's lookup code is compiled for its own.
        self.persp_2d = [int(m.plan.kind == "perspective") for m in maps if _family(m) == "2d"]
        self.cascades = [len(lp.cascades) for lp in plan.lights]

    def without_maps(self) -> _FrameState:
        """This frame's state for the pixels no shadow can reach: the same lights, outputs and
        uniforms, no shadow maps (so no lookup code in its variants)."""
        if self.bare is None:
            self.bare = _FrameState(self.plan, [], self.params, self.view_proj, self.eye,
                                    self.vis_targets, self.generic)
        return self.bare

    def has_uv(self, gp: GpuPrimitive) -> bool:
        if self.no_color:  # only a cut-out reads its texture
            return self.alpha_mask(gp.material) and gp.texture is not None
        return self.generic or gp.texture is not None

    def alpha_mask(self, mat: Material) -> bool:
        return self.generic or mat.alpha_mode == "MASK"

    def variant(self, gp: GpuPrimitive) -> tuple[dict[str, int | bool | str], tuple]:
        """:meth:`defines` of a primitive and its sorted items (the variant's name), once per
        primitive and frame state."""
        hit = self._variants.get(id(gp))
        if hit is None or hit[0] is not gp:
            d = self.defines(gp, gp.material)
            hit = self._variants[id(gp)] = (gp, d, tuple(sorted(d.items())))
        return hit[1], hit[2]

    def defines(self, gp: GpuPrimitive, mat: Material) -> dict[str, int | bool | str]:
        shadows = self.params.shadows
        has_color = gp.has_color
        if self.depth_only:
            # No lights, maps or outputs but the depth; a cut-out keeps what its coverage reads
            # (the base colour's alpha, the texture's, the vertex colours').
            mask = self.alpha_mask(mat)
            d: dict[str, int | bool | str] = {
                "DEPTH_ONLY": True, "ALPHA_MASK": mask, "LOC_MODEL": gp.loc_model,
                "HAS_UV": self.has_uv(gp), "HAS_COLOR": mask and has_color}
            if d["HAS_UV"]:
                d["LOC_UV"] = gp.loc_uv
            if d["HAS_COLOR"]:
                d["LOC_COLOR"] = gp.loc_color
            return d
        d = {
            "NUM_LIGHTS": len(self.plan.lights),
            "NUM_MAPS_2D": self.n_2d,
            "NUM_MAPS_CUBE": self.n_cube,
            "NUM_MAPS_CSM": self.n_csm,
            "CASCADE_TINT": bool(self.n_csm) and shadows.debug_cascades,
            "HAS_SPOT": self.has_spot,
            "HAS_POSITIONAL": self.has_positional,
            "HAS_UV": self.has_uv(gp),
            "HAS_COLOR": self.generic or has_color and (not self.no_color or self.alpha_mask(mat)),
            "ALPHA_MASK": self.alpha_mask(mat),
            # An unlit surface's visibility is a lit one's: only its colour differs.
            "UNLIT": mat.unlit and not self.no_color,
            "NO_COLOR": self.no_color,
            "OUT_VISIBILITY": self.vis_targets,
            "ENCODING": encodings.ENCODING_ID[shadows.encoding],
            "FILTER_PCF": self.pcf,
            "PCF_RADIUS": self.pcf_radius,
            "NORMAL_OFFSET": bool(self.maps) and shadows.bias.normal_offset > 0,
            "LOC_MODEL": gp.loc_model,
        }
        if self.plan.lights:
            d["LIGHT_TYPES"] = ", ".join(str(LIGHT_TYPES[lp.light.type]) for lp in self.plan.lights)
            d["LIGHT_MAPS_2D"] = ", ".join(str(m) for m in self.map_2d)
            d["LIGHT_MAPS_CUBE"] = ", ".join(str(m) for m in self.map_cube)
            if self.n_2d:
                d["MAP2D_PERSPECTIVE"] = ", ".join(str(k) for k in self.persp_2d)
            if self.n_csm:
                d["LIGHT_MAPS_CSM"] = ", ".join(str(m) for m in self.map_csm)
                d["LIGHT_CASCADES"] = ", ".join(str(c) for c in self.cascades)
        if d["HAS_UV"]:
            d["LOC_UV"] = gp.loc_uv if gp.texture is not None else SPARE_UV
        if d["HAS_COLOR"]:
            d["LOC_COLOR"] = gp.loc_color if has_color else SPARE_COLOR
        return d

    def set_frame_uniforms(self, prog: Program, units: list[int], lenient: bool = False) -> None:
        """Set the frame's uniforms on ``prog`` (bound); every program of the frame takes the
        same values, worked out once (:meth:`frame_uniforms`). ``lenient``: an unlit variant,
        whose compiler dropped the lighting (and with it those uniforms) unless visibility is
        output: only the uniforms it has are set."""
        for name, value in self.frame_uniforms(units):
            if not lenient or prog.has(name):
                prog.set(name, value)

    def frame_uniforms(self, units: list[int]) -> list[tuple[str, np.ndarray]]:
        """The frame's uniforms as (name, value) pairs, the maps bound to ``units``: computed
        on the first program of the frame and reused by the others (each variant of a frame
        declares the same frame uniforms, but the map ones without maps)."""
        key = tuple(units)
        if self._uniforms is not None and self._uniforms[0] == key:
            return self._uniforms[1]
        out: list[tuple[str, object]] = []
        p = self.params
        out.append(("u_view_proj", self.view_proj))
        out.append(("u_ambient", p.ambient))
        lights = self.plan.lights
        if lights:  # without lights only the ambient term remains
            out.append(("u_camera_eye", camera_eye(self.plan.camera, self.eye)))
            out.append(("u_specular", p.specular))
            out.append(("u_shininess", p.shininess))
            origin = self.plan.origin
            if self.has_direction:
                out.append(("u_light_direction", [lp.light.direction for lp in lights]))
            out.append(("u_light_radiance",
                        [np.asarray(lp.light.color) * lp.light.intensity for lp in lights]))
            if self.has_positional:
                out.append(("u_light_position", [lp.light.position - origin for lp in lights]))
                out.append(("u_light_range", [lp.light.range or 0.0 for lp in lights]))
            if self.has_spot:
                # 1 - cos as 2 sin^2(a / 2): exact where cos would round to 1 (lighting.glsl)
                out.append(("u_light_cone", [(2 * np.sin(lp.light.outer_cone / 2) ** 2,
                                              2 * np.sin(lp.light.inner_cone / 2) ** 2)
                                             for lp in lights]))
                axes = [spot_axis(lp.light.position - origin, lp.light.direction)
                        for lp in lights]
                out.append(("u_light_axis_point", [a for a, _ in axes]))
                out.append(("u_light_axis_offset", [o for _, o in axes]))
        if self.maps:
            b = p.shadows.bias
            out.append(("u_bias", (b.constant, b.slope, b.slope_max, b.normal_offset)))
            two_d = [m for m in self.maps if _family(m) == "2d"]
            cubes = [m for m in self.maps if _family(m) == "cube"]
            cascaded = [m for m in self.maps if _family(m) == "csm"]
            if cascaded:
                out += self._cascade_uniforms(units, cascaded, b.quantisation_steps,
                                              b.normal_offset > 0)
            if two_d:
                out.append(("u_map2d", [units[self.maps.index(m)] for m in two_d]))
                out.append(("u_map2d_matrix", [map2d_matrix(m.plan) for m in two_d]))
                out.append(("u_map2d_range", [(m.plan.near, m.plan.far, m.step, m.plan.map_size)
                                              for m in two_d]))
                if b.normal_offset > 0:
                    out.append(("u_map2d_texel", [m.plan.texel for m in two_d]))
                factors = [map2d_plane_factors(m.plan, m.step, b.quantisation_steps)
                           for m in two_d]
                out.append(("u_map2d_plane", [f[0] for f in factors]))
                out.append(("u_map2d_depth", [f[1] for f in factors]))
            if cubes:
                out.append(("u_mapcube", [units[self.maps.index(m)] for m in cubes]))
                out.append(("u_mapcube_position", [m.plan.position for m in cubes]))
                out.append(("u_mapcube_range", [(m.plan.near, m.plan.far, m.plan.map_size, m.step)
                                                for m in cubes]))
                out.append(("u_mapcube_depth", [
                    cube_plane_factors(m.plan, m.step, b.quantisation_steps) for m in cubes]))
        # As arrays once (Program.set takes them as they are, without converting each time).
        values = [(name, np.asarray(v)) for name, v in out]
        self._uniforms = (key, values)
        return values

    def _cascade_uniforms(self, units: list[int], cascaded: list[ShadowMap],
                          quantisation_steps: float, normal_offset: bool
                          ) -> list[tuple[str, object]]:
        """Per cascaded light, its array texture and size; per cascade (``slot * MAX_CASCADES
        + k``, unused entries left as they are), its matrices, receiver-plane factors
        (:func:`cascade_plane_factors`), split and (with a normal offset) texel."""
        n = len(cascaded) * MAX_CASCADES
        matrix = np.tile(np.eye(4), (n, 1, 1))
        view = np.tile(np.eye(4), (n, 1, 1))
        depth = np.zeros((n, 4))
        texel = np.ones(n)
        split = np.zeros((n, 2))
        for s, m in enumerate(cascaded):
            for k, c in enumerate(m.plan.cascades):
                j = s * MAX_CASCADES + k
                matrix[j] = BIAS @ c.proj @ c.view
                view[j] = c.view
                depth[j] = cascade_plane_factors(c, m.step, quantisation_steps)
                texel[j] = c.texel[0]
                split[j] = (min(c.split[1], 3e38), c.blend)
        out: list[tuple[str, object]] = [
            ("u_mapcsm", [units[self.maps.index(m)] for m in cascaded]),
            ("u_csm_size", [float(m.plan.cascades[0].map_size) for m in cascaded]),
            ("u_camera_forward", camera_forward(self.plan.camera, self.eye)),
            ("u_csm_matrix", matrix), ("u_csm_view", view), ("u_csm_depth", depth),
            ("u_csm_split", split)]
        if normal_offset:
            out.append(("u_csm_texel", texel))
        return out
