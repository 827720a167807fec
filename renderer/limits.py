"""The limits every request is held to: one definition, one place that checks them.

:class:`Limits` is built by whoever configures a renderer (the service builds it from its
settings, see ``Settings.limits()``). :func:`check_request` needs only the request, so the
service runs it before a request takes a place in the queue; :func:`check_scene` runs once the
scene is known, before any GL work; :func:`check_map_sizes` holds the plan's maps to the limit
and to what the GPU supports. Each raises :class:`~shadowmap.renderer.errors.LimitError` naming
the exceeded setting.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .errors import LimitError

if TYPE_CHECKING:
    from .params import RenderParams
    from .scene import Scene

#: Lights one camera pass shades: the size of its uniform arrays and of its visibility targets
#: (two RGBA targets of four lights each).
MAX_LIGHTS = 8


@dataclass(frozen=True)
class Limits:
    """Upper bounds a renderer enforces on every request.

    Attributes
    ----------
    max_pixels : int
        Largest ``width * height``.
    max_map_size : int
        Largest shadow-map side; ``map_size: "auto"`` is clamped to it.
    max_lights : int
        Most lights per request (at most :data:`MAX_LIGHTS`).
    max_triangles : int
        Most triangles a scene may draw, counting every instance.
    """

    max_pixels: int = 4096 * 4096
    max_map_size: int = 8192
    max_lights: int = MAX_LIGHTS
    max_triangles: int = 5_000_000

    def __post_init__(self) -> None:
        if not 1 <= self.max_lights <= MAX_LIGHTS:
            raise ValueError(f"max_lights must be from 1 to {MAX_LIGHTS}")


def check_lights(count: int, limits: Limits) -> None:
    """Refuse more lights than ``limits.max_lights``."""
    if count > limits.max_lights:
        raise LimitError("max_lights", f"{count} lights is over the limit of {limits.max_lights}")


def check_request(params: RenderParams, limits: Limits) -> None:
    """The limits a request can break on its own, without its scene.

    Raises
    ------
    LimitError
        ``max_pixels``, ``max_map_size`` (an explicit map size) or ``max_lights`` (lights
        listed in the request).
    """
    if params.width * params.height > limits.max_pixels:
        raise LimitError("max_pixels", f"{params.width}x{params.height} is over the limit of "
                         f"{limits.max_pixels} pixels")
    size = params.shadows.map_size
    if size != "auto" and size > limits.max_map_size:
        raise LimitError("max_map_size",
                         f"map_size {size} is over the limit of {limits.max_map_size}")
    if params.lights is not None:
        check_lights(len(params.lights), limits)


def check_scene(scene: Scene, limits: Limits, params: RenderParams | None = None) -> None:
    """The limits that depend on the scene: its triangles, and the file's own lights when the
    request lists none.

    Raises
    ------
    LimitError
        ``max_triangles`` or ``max_lights``.
    """
    if scene.triangle_count > limits.max_triangles:
        raise LimitError("max_triangles", f"the scene has {scene.triangle_count} triangles, over "
                         f"the limit of {limits.max_triangles}")
    if params is not None and params.lights is None:
        check_lights(len(scene.lights), limits)


def max_map_size(params: RenderParams, limits: Limits) -> int:
    """The largest map side a request may get: its own ``max_map_size``, clamped to the limit."""
    return min(params.shadows.max_map_size, limits.max_map_size)


def check_map_sizes(sizes: Iterable[int], gpu_max: int) -> None:
    """Refuse a planned map larger than the GPU supports (``GL_MAX_*TEXTURE_SIZE``)."""
    for size in sizes:
        if size > gpu_max:
            raise LimitError("max_map_size", f"map size {size} exceeds this GPU's limit {gpu_max}")
