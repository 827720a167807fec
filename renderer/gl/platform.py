"""Choosing the headless OpenGL platform before PyOpenGL is imported.

PyOpenGL binds to a platform (EGL, OSMesa, GLX) the first time ``OpenGL`` is imported, from the
``PYOPENGL_PLATFORM`` environment variable. When the variable is unset this module probes EGL with a
few ``ctypes`` calls (device enumeration and ``eglInitialize``, the same route pyrender takes) and
falls back to OSMesa, then sets the variable so that every later import agrees.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

from ..errors import RenderError

PLATFORMS = ("egl", "osmesa")
EGL_PLATFORM_DEVICE_EXT = 0x313F


def egl_available() -> bool:
    """True when libEGL can enumerate a device and initialise a display on it."""
    try:
        lib = ctypes.CDLL("libEGL.so.1")
    except OSError:
        return False
    get_proc = lib.eglGetProcAddress
    get_proc.restype = ctypes.c_void_p
    get_proc.argtypes = [ctypes.c_char_p]
    query_ptr = get_proc(b"eglQueryDevicesEXT")
    display_ptr = get_proc(b"eglGetPlatformDisplayEXT")
    if not query_ptr or not display_ptr:
        return False
    query = ctypes.CFUNCTYPE(
        ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p), ctypes.POINTER(ctypes.c_int)
    )(query_ptr)
    get_display = ctypes.CFUNCTYPE(
        ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p
    )(display_ptr)
    count = ctypes.c_int(0)
    if not query(0, None, ctypes.byref(count)) or count.value < 1:
        return False
    devices = (ctypes.c_void_p * count.value)()
    query(count.value, devices, ctypes.byref(count))
    display = get_display(EGL_PLATFORM_DEVICE_EXT, devices[0], None)
    if not display:
        return False
    lib.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    lib.eglTerminate.argtypes = [ctypes.c_void_p]
    major, minor = ctypes.c_int(), ctypes.c_int()
    ok = lib.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor))
    if ok:
        lib.eglTerminate(display)
    return bool(ok)


def osmesa_available() -> bool:
    return ctypes.util.find_library("OSMesa") is not None


def select_platform(preferred: str | None = None) -> str:
    """Decide the GL platform and export it as ``PYOPENGL_PLATFORM``.

    Parameters
    ----------
    preferred : {"egl", "osmesa"}, optional
        Overrides the environment. Once PyOpenGL is imported the platform is fixed; asking for a
        different one then raises :class:`RenderError`.

    Returns
    -------
    str
        The platform in use.
    """
    if preferred is not None and not isinstance(preferred, str):
        raise RenderError(f"platform must be one of {', '.join(PLATFORMS)} (or None for the "
                          f"default), not a value of type {type(preferred).__name__}")
    current = os.environ.get("PYOPENGL_PLATFORM", "").lower() or None
    wanted = (preferred or current or "").lower() or None
    if wanted is not None and wanted not in PLATFORMS:
        raise RenderError(f"unsupported GL platform {wanted!r}: use one of {', '.join(PLATFORMS)}")
    if "OpenGL.platform" in sys.modules:
        bound = current or "glx"
        if wanted is not None and wanted != bound:
            raise RenderError(
                f"PyOpenGL is already bound to {bound!r}; set PYOPENGL_PLATFORM={wanted} "
                "before anything imports OpenGL"
            )
        if bound not in PLATFORMS:
            raise RenderError(
                "PyOpenGL was imported before renderer without PYOPENGL_PLATFORM; "
                "set it to 'egl' or 'osmesa' (headless rendering needs one of them)"
            )
        return bound
    if wanted is None:
        if egl_available():
            wanted = "egl"
        elif osmesa_available():
            wanted = "osmesa"
        else:
            raise RenderError(
                "no headless OpenGL found: install Mesa's EGL (libegl1 libegl-mesa0 "
                "libgl1-mesa-dri) or OSMesa (libosmesa6)"
            )
    os.environ["PYOPENGL_PLATFORM"] = wanted
    return wanted
