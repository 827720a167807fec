"""shadowmap-service renderer: two-pass shadow maps for glTF scenes in an offscreen GL context.

The GL platform (EGL, else OSMesa) is chosen when this package is imported, before PyOpenGL
binds to one; set ``PYOPENGL_PLATFORM`` to force it.
"""

from .platform import select_platform

PLATFORM = select_platform()

from .errors import (  # noqa: E402
    LimitError,
    ReferenceUnavailable,
    RenderError,
    RequestError,
    SceneError,
    ShaderError,
    ShadowMapError,
)
from .params import RenderParams  # noqa: E402
from .render import Limits, RenderResult, Renderer  # noqa: E402
from .scene import Scene, load_scene  # noqa: E402

__version__ = "0.1.0"
__all__ = [
    "LimitError",
    "Limits",
    "PLATFORM",
    "ReferenceUnavailable",
    "RenderError",
    "RenderParams",
    "RenderResult",
    "Renderer",
    "RequestError",
    "Scene",
    "SceneError",
    "ShaderError",
    "ShadowMapError",
    "load_scene",
]
