"""The offscreen OpenGL context: pyrender's EGL or OSMesa platform, one per thread.

Importing this package selects the GL platform (see :mod:`.platform`) before PyOpenGL is
imported; :class:`~shadowmap.renderer.Renderer` selects it explicitly before importing it.
"""

from __future__ import annotations

import ctypes
import importlib
import importlib.util
import os
import sys
import threading
from pathlib import Path
from types import ModuleType

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
        self.pid = os.getpid()
        try:
            module = pyrender_platform(self.platform)
            if self.platform == "egl":
                # SHADOWMAP_EGL_DEVICE picks one of several GPUs (a batch actor sets it to the
                # GPU Ray gave it); the first device otherwise.
                device = module.get_device_by_index(egl_device_index())
                self._platform = module.EGLPlatform(16, 16, device=device)
                init_egl_context(self._platform)
            else:
                self._platform = module.OSMesaPlatform(16, 16)
                self._platform.init_context()
            self._platform.make_current()
            if self.platform == "egl":
                GLContext._live_egl += 1
        except Exception as exc:
            raise RenderError(f"cannot create an {self.platform} GL context: {exc}") from exc
        self.renderer = GL.glGetString(GL.GL_RENDERER).decode()
        self.version = GL.glGetString(GL.GL_VERSION).decode()
        self.max_texture_size = int(GL.glGetIntegerv(GL.GL_MAX_TEXTURE_SIZE))

    @property
    def forked(self) -> bool:
        """Whether this is a forked copy of the process that made the context.

        A fork copies the context's memory but none of the driver's threads (llvmpipe's
        rasterizer threads, a GPU driver's): a GL call there can wait for ever on work no
        thread will do, and its main thread has the same identity as the parent's.
        """
        return os.getpid() != self.pid

    def check_thread(self) -> None:
        if self.forked:
            raise RenderError(
                f"this renderer's GL context was made in process {self.pid}, and this is a "
                f"forked copy of it ({os.getpid()}): make a Renderer in each process (e.g. in "
                "a multiprocessing pool's initializer), or use the 'spawn' or 'forkserver' "
                "start method")
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
        if self.forked:
            return  # the parent's context, which is not this process's to destroy (nor can it)
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


_PLATFORMS_PACKAGE = "shadowmap.renderer.gl._pyrender_platforms"


def pyrender_platform(name: str) -> ModuleType:
    """pyrender's offscreen platform module ``pyrender.platforms.<name>`` (``egl``, ``osmesa``).

    Importing the ``pyrender`` package imports its scene graph and viewer, and with them trimesh,
    scipy, networkx and pyglet (about 1.2 s of a 3 s command-line render here), while a context
    needs only ``pyrender/platforms/``, whose modules import nothing from pyrender outside that
    folder. So, unless pyrender is imported already, the folder is loaded as a package of its own
    (under a private name, so a later ``import pyrender`` still gets the whole package).

    Raises
    ------
    RenderError
        pyrender is not installed.
    """
    if "pyrender" in sys.modules:
        return importlib.import_module(f"pyrender.platforms.{name}")
    if _PLATFORMS_PACKAGE not in sys.modules:
        spec = importlib.util.find_spec("pyrender")  # finds the package without running it
        if spec is None or not spec.submodule_search_locations:
            raise RenderError("pyrender is not installed (pip install pyrender2)")
        folder = Path(next(iter(spec.submodule_search_locations))) / "platforms"
        pkg_spec = importlib.util.spec_from_file_location(
            _PLATFORMS_PACKAGE, folder / "__init__.py", submodule_search_locations=[str(folder)])
        if pkg_spec is None or pkg_spec.loader is None:
            raise RenderError(f"cannot load pyrender's platforms from {folder}")
        package = importlib.util.module_from_spec(pkg_spec)
        sys.modules[_PLATFORMS_PACKAGE] = package
        try:
            pkg_spec.loader.exec_module(package)
        except BaseException:
            del sys.modules[_PLATFORMS_PACKAGE]
            raise
    return importlib.import_module(f"{_PLATFORMS_PACKAGE}.{name}")


#: Core-profile versions asked for, newest first; the shaders need 4.1.
EGL_CONTEXT_VERSIONS = ((4, 6), (4, 5), (4, 4), (4, 3), (4, 2), (4, 1))


def init_egl_context(platform: object) -> None:
    """Create the EGL context of pyrender's ``EGLPlatform`` with the newest core profile.

    pyrender's own ``init_context`` asks for exactly 4.1. Mesa answers with its newest version
    all the same, NVIDIA's driver with 4.1, which lacks ``glMultiDrawElementsIndirect`` (4.3), so
    instanced scenes would draw one call per run of instances. This is that method with the
    versions of :data:`EGL_CONTEXT_VERSIONS` tried in turn; it sets the attributes pyrender's
    ``make_current`` and :meth:`GLContext.release` read.

    Raises
    ------
    RenderError
        No display, no configuration, or no context of any of those versions.
    """
    from OpenGL import EGL, arrays

    config_attributes = arrays.GLintArray.asArray([
        EGL.EGL_SURFACE_TYPE, EGL.EGL_PBUFFER_BIT,
        EGL.EGL_BLUE_SIZE, 8, EGL.EGL_RED_SIZE, 8, EGL.EGL_GREEN_SIZE, 8,
        EGL.EGL_DEPTH_SIZE, 24,
        EGL.EGL_COLOR_BUFFER_TYPE, EGL.EGL_RGB_BUFFER,
        EGL.EGL_RENDERABLE_TYPE, EGL.EGL_OPENGL_BIT,
        EGL.EGL_CONFORMANT, EGL.EGL_OPENGL_BIT,
        EGL.EGL_NONE,
    ])
    # Without X: a DISPLAY in the environment would make EGL look for that X server.
    display_env = os.environ.pop("DISPLAY", None)
    try:
        display = platform._egl_device.get_display()  # type: ignore[attr-defined]
    finally:
        if display_env is not None:
            os.environ["DISPLAY"] = display_env
    major, minor = ctypes.c_long(), ctypes.c_long()
    configs = (EGL.EGLConfig * 1)()
    count = ctypes.c_long()
    if not EGL.eglInitialize(display, major, minor):
        raise RenderError("eglInitialize failed")
    if not EGL.eglChooseConfig(display, config_attributes, configs, 1, count) or not count.value:
        raise RenderError("no EGL configuration for an offscreen OpenGL context")
    if not EGL.eglBindAPI(EGL.EGL_OPENGL_API):
        raise RenderError("eglBindAPI(EGL_OPENGL_API) failed")
    context = None
    for version in EGL_CONTEXT_VERSIONS:
        attributes = arrays.GLintArray.asArray([
            EGL.EGL_CONTEXT_MAJOR_VERSION, version[0],
            EGL.EGL_CONTEXT_MINOR_VERSION, version[1],
            EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
            EGL.EGL_NONE,
        ])
        try:
            context = EGL.eglCreateContext(display, configs[0], EGL.EGL_NO_CONTEXT, attributes)
        except EGL.EGLError:  # EGL_BAD_MATCH: the driver has no such version
            context = None
        if context:
            break
    if not context:
        raise RenderError("no OpenGL core-profile context of version 4.1 or newer")
    platform._egl_display = display  # type: ignore[attr-defined]
    platform._egl_context = context  # type: ignore[attr-defined]


def egl_device_index() -> int:
    """The EGL device to render on: ``SHADOWMAP_EGL_DEVICE`` (an index), else 0."""
    value = os.environ.get("SHADOWMAP_EGL_DEVICE", "").strip()
    if not value:
        return 0
    try:
        index = int(value)
    except ValueError:
        raise RenderError(f"SHADOWMAP_EGL_DEVICE must be a device index, not {value!r}") from None
    if index < 0:
        raise RenderError(f"SHADOWMAP_EGL_DEVICE must not be negative, not {index}")
    return index


def check_gl(where: str) -> None:
    """Raise :class:`RenderError` if GL recorded an error (PyOpenGL checks most calls already)."""
    err = GL.glGetError()
    if err != GL.GL_NO_ERROR:
        raise RenderError(f"OpenGL error 0x{err:04x} in {where}")
