"""Small GL programs that run one shader library function per pixel (see shaders/*_probe.frag)."""

from __future__ import annotations

import numpy as np
from OpenGL import GL

from shadowmap.renderer import encodings
from shadowmap.renderer.gl.resources import Framebuffer

PROBE_VERT = "fullscreen.vert"


def _texture(data: np.ndarray, internal, fmt, typ) -> int:
    h, w = data.shape[:2]
    tex = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
    # Row 0 of the array is texel row 0 (v = 0): the probes address texels, not pictures.
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, internal, w, h, 0, fmt, typ, np.ascontiguousarray(data))
    for p in (GL.GL_TEXTURE_MIN_FILTER, GL.GL_TEXTURE_MAG_FILTER):
        GL.glTexParameteri(GL.GL_TEXTURE_2D, p, GL.GL_NEAREST)
    for p in (GL.GL_TEXTURE_WRAP_S, GL.GL_TEXTURE_WRAP_T):
        GL.glTexParameteri(GL.GL_TEXTURE_2D, p, GL.GL_CLAMP_TO_EDGE)
    return tex


def _run(renderer, frag, defines, inputs: dict[str, int], w, h, target, uniforms=None):
    """Draw the probe into a w x h target; returns the read-back array with row 0 = texel row 0.

    ``frag`` is the probe's fragment main file, or a ready :class:`Program` (``defines`` unused).
    """
    renderer.context.make_current()
    if isinstance(frag, str):
        prog = renderer.programs.get(PROBE_VERT, frag, defines)
    else:
        prog = frag
    internal, fmt, typ, channels, dtype = target
    fb = Framebuffer(w, h, [(internal, fmt, typ)], None)
    vao = GL.glGenVertexArrays(1)
    try:
        fb.bind()
        prog.use()
        for unit, (name, tex) in enumerate(inputs.items()):
            GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
            GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
            prog.set(name, unit)
        for name, value in (uniforms or {}).items():
            prog.set(name, value)
        GL.glDisable(GL.GL_DEPTH_TEST)
        GL.glDisable(GL.GL_BLEND)
        GL.glBindVertexArray(vao)
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        GL.glBindVertexArray(0)
        out = fb.read_color(0, fmt, typ, channels, dtype)[::-1]  # undo the picture flip
        return np.array(out)
    finally:
        GL.glDeleteVertexArrays(1, [vao])
        GL.glActiveTexture(GL.GL_TEXTURE0)
        fb.release()


def gpu_encode(renderer, t: np.ndarray, encoding: str) -> np.ndarray:
    """Bytes the GLSL encoder stores for depths ``t`` (H, W) -> (H, W, 4) uint8."""
    h, w = t.shape
    tex = _texture(t.astype(np.float32), GL.GL_R32F, GL.GL_RED, GL.GL_FLOAT)
    try:
        return _run(renderer, "encoding_probe.frag",
                    {"ENCODING": encodings.ENCODING_ID[encoding], "ENCODE": 1},
                    {"u_input": tex}, w, h,
                    (GL.GL_RGBA8, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, 4, np.uint8))
    finally:
        GL.glDeleteTextures([tex])


def gpu_decode(renderer, rgba: np.ndarray, encoding: str) -> np.ndarray:
    """Depth the GLSL decoder reads from stored bytes (H, W, 4) uint8 -> (H, W) float32."""
    h, w = rgba.shape[:2]
    tex = _texture(rgba.astype(np.uint8), GL.GL_RGBA8, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)
    try:
        out = _run(renderer, "encoding_probe.frag",
                   {"ENCODING": encodings.ENCODING_ID[encoding], "ENCODE": 0},
                   {"u_input": tex}, w, h,
                   (GL.GL_R32F, GL.GL_RED, GL.GL_FLOAT, 1, np.float32))
        return out[..., 0]
    finally:
        GL.glDeleteTextures([tex])


def gpu_compare(renderer, depth_map: np.ndarray, queries: np.ndarray, encoding: str,
                pcf_radius: int = 0, dref_v: float = 0.0) -> np.ndarray:
    """shadow_2d() for each query (u, v, ref) or (u, v, ref, dref_u) against a depth map (S, S)
    of linear depths; ``dref`` is the receiver plane's depth change per texel along u and v."""
    s = depth_map.shape[0]
    if encoding == "depth":
        map_tex = _texture(depth_map.astype(np.float32), GL.GL_DEPTH_COMPONENT32F,
                           GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
    else:
        map_tex = _texture(encodings.encode(depth_map, encoding), GL.GL_RGBA8, GL.GL_RGBA,
                           GL.GL_UNSIGNED_BYTE)
    q = np.zeros((1, len(queries), 4), np.float32)
    queries = np.asarray(queries, np.float32)
    q[0, :, :queries.shape[1]] = queries
    q_tex = _texture(q, GL.GL_RGBA32F, GL.GL_RGBA, GL.GL_FLOAT)
    try:
        defines = {"ENCODING": encodings.ENCODING_ID[encoding], "FILTER_PCF": int(pcf_radius > 0),
                   "PCF_RADIUS": pcf_radius}
        out = _run(renderer, "compare_probe.frag", defines,
                   {"u_map": map_tex, "u_queries": q_tex}, len(queries), 1,
                   (GL.GL_R32F, GL.GL_RED, GL.GL_FLOAT, 1, np.float32),
                   uniforms={"u_map_size": float(s), "u_dref_v": float(dref_v)})
        return out[0, :, 0]
    finally:
        GL.glDeleteTextures([map_tex, q_tex])
