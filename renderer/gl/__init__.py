"""Everything that talks to OpenGL: the context, programs built from ``shaders/``, and resources.

PyOpenGL binds to a platform the first time it is imported, so this package selects one (EGL,
else OSMesa, unless ``PYOPENGL_PLATFORM`` says) before any of its modules imports ``OpenGL``.
Nothing outside ``gl`` and ``passes`` imports PyOpenGL, so loading scenes and planning never
touch a GL platform.
"""

from .platform import select_platform

select_platform()
