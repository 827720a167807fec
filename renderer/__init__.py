"""The shadowmap library: two-pass shadow maps for glTF scenes in an offscreen GL context.

Installed as ``shadowmap.renderer``; the documented imports are re-exported by ``shadowmap``.
Importing it (the request model, the scene loader, the planner) touches no GL platform: the
platform (EGL, else OSMesa; ``PYOPENGL_PLATFORM`` forces one) is selected when a
:class:`Renderer` is created.

Modules: ``params`` (the request model), ``scene`` (glTF loading), ``limits``, ``cache``,
``camera`` and ``lights`` (resolving a request), ``plan`` (the render plan, no GL), ``gl``
(context, programs, resources), ``passes`` (light pass, camera pass), ``render`` (the
:class:`Renderer`), ``exr`` (depth and visibility as OpenEXR), ``reference`` and ``metrics``
(ray-traced truth and the error against it), ``testing`` (scene builders and measurement for
tests and benchmarks).
"""

from .errors import (
    ExrUnavailable,
    FileFormatError,
    LimitError,
    ReferenceUnavailable,
    RenderError,
    RequestError,
    SceneError,
    ShaderError,
    ShadowMapError,
    UnsupportedExtension,
    UnsupportedVersion,
)
from .exr import read_exr, write_exr
from .limits import Limits
from .params import RenderParams
from .render import Renderer, RenderResult
from .scene import Scene, load_scene, scene_from_meshes, scene_from_trimesh

__all__ = [
    "ExrUnavailable",
    "FileFormatError",
    "LimitError",
    "Limits",
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
    "UnsupportedExtension",
    "UnsupportedVersion",
    "load_scene",
    "read_exr",
    "scene_from_meshes",
    "scene_from_trimesh",
    "write_exr",
]
