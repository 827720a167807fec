"""The offscreen OpenGL context: pyrender's EGL or OSMesa platform, one per thread.

Importing this package selects the GL platform (see :mod:`.platform`) before PyOpenGL is
imported; :class:`~shadowmap.renderer.Renderer` selects it explicitly before importing it.
"""

from __future__ import annotations

import threading

from OpenGL import GL

from ..errors import RenderError
from .platform import select_platform


class GLContext:
    """An offscreen OpenGL context on one thread.

    Parameters
    ----------
    platform : {"egl", "osmesa"}, optional
        Defaults to ``PYOPENGL_PLATFORM`` (selected, or probed, by
        :func:`.platform.select_platform`).
    """

    def __init__(self, platform: str | None = None) -> None:
        self.platform = select_platform(platform)
        self.thread = threading.get_ident()
        try:
            if self.platform == "egl":
                from pyrender.platforms import egl

                self._platform = egl.EGLPlatform(16, 16, device=egl.get_device_by_index(0))
            else:
                from pyrender.platforms.osmesa import OSMesaPlatform

                self._platform = OSMesaPlatform(16, 16)
            self._platform.init_context()
            self._platform.make_current()
            if self.platform == "egl":
                GLContext._live_egl += 1
        except Exception as exc:
            raise RenderError(f"cannot create an {self.platform} GL context: {exc}") from exc
        self.renderer = GL.glGetString(GL.GL_RENDERER).decode()
        self.version = GL.glGetString(GL.GL_VERSION).decode()
        self.max_texture_size = int(GL.glGetIntegerv(GL.GL_MAX_TEXTURE_SIZE))
        self.max_cube_size = int(GL.glGetIntegerv(GL.GL_MAX_CUBE_MAP_TEXTURE_SIZE))

    def check_thread(self) -> None:
        if threading.get_ident() != self.thread:
            raise RenderError("a GL context must be used from the thread that created it")

    def make_current(self) -> None:
        self.check_thread()
        self._platform.make_current()

    _live_egl = 0  # EGL contexts alive in this process, which share one EGLDisplay

    def release(self) -> None:
        """Destroy the context. Safe to call twice."""
        if self._platform is None:
            return
        platform, self._platform = self._platform, None
        if self.platform != "egl":
            platform.delete_context()
            return
        # pyrender's delete_context() terminates the EGLDisplay, which every context of the
        # process shares: terminate it only with the last one.
        from OpenGL import EGL

        display = platform._egl_display
        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(display, platform._egl_context)
        GLContext._live_egl -= 1
        if GLContext._live_egl == 0:
            EGL.eglTerminate(display)

    def info(self) -> dict:
        return {"platform": self.platform, "renderer": self.renderer, "version": self.version}


def check_gl(where: str) -> None:
    """Raise :class:`RenderError` if GL recorded an error (PyOpenGL checks most calls already)."""
    err = GL.glGetError()
    if err != GL.GL_NO_ERROR:
        raise RenderError(f"OpenGL error 0x{err:04x} in {where}")
