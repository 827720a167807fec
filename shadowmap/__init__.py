"""shadowmap-service: shadowed renders of glTF scenes, as a library, a command line and a service.

>>> from shadowmap import Renderer, RenderParams, load_scene
>>> with Renderer() as r:                                        # doctest: +SKIP
...     result = r.render(load_scene("Duck.glb"), RenderParams(outputs=["color"]))

The installed namespace holds ``shadowmap.renderer`` (the library), ``shadowmap.shaders`` (its
GLSL), ``shadowmap.app`` (the HTTP service, with the ``server`` extra) and ``shadowmap.cli``.
"""

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

from .renderer import *  # noqa: F403  (the library's public API, listed in its __all__)
from .renderer import __all__ as _library_api

DISTRIBUTION = "shadowmap-service"

try:
    __version__ = _version(DISTRIBUTION)  # written once, in pyproject.toml
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [*_library_api, "DISTRIBUTION", "__version__"]
