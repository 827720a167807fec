"""The limits every request is held to: one definition, one place that checks them.

:class:`Limits` is built by whoever configures a renderer (the service builds it from its
settings, see ``Settings.limits()``). The checks, cheapest first:

- :func:`check_count`, called by :func:`shadowmap.renderer.gltf.admission.admit`: what a glTF
  document asks of the loader, counted from its JSON alone before any buffer is decoded (nodes,
  hierarchy depth, instances, primitives, triangles, and the bytes its accessors decode to,
  against ``max_request_bytes``);
- :func:`check_request` needs only the request, so the service runs it before a request takes
  a place in the queue (pixels, map size, lights, and the memory the request needs at least);
- :func:`check_scene` runs once the scene is known, before any GL work, and
  :func:`fit_request` holds the whole render (shadow maps, framebuffers, read-backs, the scene's
  upload) to ``max_request_bytes``;
- :func:`check_map_sizes` holds the plan's maps to what the GPU supports.

Each raises :class:`~shadowmap.renderer.errors.LimitError` naming the exceeded setting.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from .encodings import CHANNELS
from .errors import LimitError

if TYPE_CHECKING:
    from .params import RenderParams
    from .scene import Scene

#: Lights one camera pass shades: the size of its uniform arrays and of its visibility targets
#: (two RGBA targets of four lights each).
MAX_LIGHTS = 8
#: Cascades of one directional light (``ShadowParams.max_cascades``' upper bound); a cascaded
#: light's maps are the layers of one array texture.
MAX_CASCADES = 4
#: Smallest shadow-map side (``ShadowParams.map_size``'s lower bound).
MIN_MAP_SIZE = 16
#: Faces of a point light's cube map; every other light has one.
CUBE_FACES = 6
MIB = 2**20
#: Largest request params, as JSON text: a real request is a few kB even with 8 lights. The
#: service refuses a longer ``params`` part (413, ``max_params_bytes``) and the command line a
#: longer ``--params`` file, before parsing either.
MAX_PARAMS_BYTES = 64 * 1024
#: Largest coordinate, relative to the scene's centre, the GPU is given: float32 holds 3.4e38,
#: and the shaders square distances (a length, a dot product), so 1e18 squared still fits.
MAX_COORDINATE = 1e18


@dataclass(frozen=True)
class Limits:
    """Upper bounds a renderer enforces on every request.

    The defaults of the counts and of ``max_request_bytes`` suit a small CPU-only deployment
    (llvmpipe on 2 cores, a few GiB of memory); the service sets every field from its settings.

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
    max_nodes : int
        Most nodes a glTF file may hold: every node is read and placed in the hierarchy, drawn
        or not. 32,768 nodes load in about half a second. Also the most joints the drawn skins
        may list together (joints are nodes; each skin's matrices are computed from its list).
    max_depth : int
        Deepest node hierarchy (a root alone is depth 1). World matrices are computed one level
        at a time, about 40 µs a level: 1,024 levels cost 40 ms, a 100,000-deep chain seconds.
        Skeletons are seldom deeper than 100.
    max_instances : int
        Most drawn instances: the scene's nodes with a mesh, an ``EXT_mesh_gpu_instancing`` node
        counting its instances. 100,000 instances of a small mesh load and render in about a
        second.
    max_primitives : int
        Most primitives drawn, summed over every use of a mesh (a mesh of 3 primitives on 10
        nodes is 30). Each is decoded, uploaded and drawn on its own: about 0.4 ms each to load.
    max_texture_pixels : int
        Most texture pixels decoded for one scene, over all its images; each is held as RGBA8
        in memory and again, with its mipmaps, on the GPU: 64 Mpixel is 256 MiB plus 341 MiB.
    max_request_bytes : int
        Most memory one request may need, estimated before the work (:func:`request_bytes`):
        the scene's accessors as decoded, checked from the JSON before decoding, then the
        render's shadow maps (lights × faces × cascades × size² × bytes per texel: 6 faces for
        a point light, ``max_cascades`` layers of half the side for a directional light with
        ``cascades: "auto"``), camera framebuffers, read-backs and the scene's upload, checked
        before any GL work. llvmpipe
        keeps GL textures in system memory, so all of it is RAM (the estimate is within 10% of
        the resident growth measured on llvmpipe). 1.5 GiB takes a 4096² map for each of 8
        spot lights (0.5 GiB), a 4096² picture with colour and depth (1.1 GiB, with one
        directional light's 4 cascades), or a 2048² picture lit by 4 point lights with 2048²
        cube maps and colour, visibility and light_depth out (1.3 GiB); not 8 point lights with
        4096² cube maps (3 GiB of maps, which took a server from 850 MB to 3.8 GB). A request
        over it is refused, except that ``map_size: "auto"`` is held to the largest size that
        fits, with a warning.
    """

    max_pixels: int = 4096 * 4096
    max_map_size: int = 8192
    max_lights: int = MAX_LIGHTS
    max_triangles: int = 5_000_000
    max_nodes: int = 32_768
    max_depth: int = 1_024
    max_instances: int = 100_000
    max_primitives: int = 10_000
    max_texture_pixels: int = 64 * MIB
    max_request_bytes: int = 1536 * MIB

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            # Whole numbers only: a NaN compares false with everything, so it would be no limit
            # at all, and a string failed with a TypeError from the comparison below.
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ValueError(f"{f.name} must be a whole number, not {value!r}")
            object.__setattr__(self, f.name, int(value))  # a numpy integer, say
            if value < 1:
                raise ValueError(f"{f.name} must be at least 1")
        if not 1 <= self.max_lights <= MAX_LIGHTS:
            raise ValueError(f"max_lights must be from 1 to {MAX_LIGHTS}")


# --------------------------------------------------------------------------------------------
# Counts (the glTF admission check)
# --------------------------------------------------------------------------------------------

#: What each count limit counts, for messages.
_COUNTED = {
    "max_nodes": "nodes",
    "max_depth": "levels of node hierarchy",
    "max_instances": "drawn instances",
    "max_primitives": "drawn primitives (over every use of each mesh)",
    "max_triangles": "triangles",
    "max_texture_pixels": "texture pixels",
}


def check_count(limit: str, value: int, limits: Limits, *, at_least: bool = False,
                where: str = "the scene", noun: str | None = None) -> None:
    """Refuse a count over the limit named ``limit`` (a field of :class:`Limits`).

    Parameters
    ----------
    limit : str
        e.g. ``"max_nodes"``.
    value : int
    at_least : bool
        ``value`` is a lower bound (a walk stopped as soon as it was over).
    where : str
        What has that many, for the message.
    noun : str, optional
        What is counted, for the message (default: the limit's own).

    Raises
    ------
    LimitError
        ``value`` is over ``getattr(limits, limit)``.
    """
    top = getattr(limits, limit)
    if value > top:
        count = f"at least {value}" if at_least else f"{value}"
        raise LimitError(limit, f"{where} has {count} {noun or _COUNTED.get(limit, limit)}, "
                         f"over the limit of {top} ({limit})")


def check_decoded_bytes(nbytes: int, limits: Limits) -> None:
    """Refuse a scene whose accessors decode to more than ``max_request_bytes``.

    Raises
    ------
    LimitError
        ``max_request_bytes``.
    """
    if nbytes > limits.max_request_bytes:
        raise LimitError("max_request_bytes", f"the scene's drawn accessors decode to about "
                         f"{_mib(nbytes)}, over the limit of {_mib(limits.max_request_bytes)} "
                         "per request (max_request_bytes)")


def check_lights(count: int, limits: Limits) -> None:
    """Refuse more lights than ``limits.max_lights``."""
    if count > limits.max_lights:
        raise LimitError("max_lights", f"{count} lights is over the limit of {limits.max_lights}")


# --------------------------------------------------------------------------------------------
# Memory of a render
# --------------------------------------------------------------------------------------------


def map_texel_bytes(encoding: str, depth_bits: int | str = "auto") -> int:
    """GPU bytes per shadow-map texel: the ``depth`` encoding renders into one depth texture,
    ``DEPTH_COMPONENT16`` with ``depth_bits: 16`` and ``DEPTH_COMPONENT32F`` otherwise (the
    estimate comes before the plan, so ``"auto"`` counts the larger), the colour encodings into
    an RGBA8 texture plus a ``DEPTH_COMPONENT32F`` renderbuffer for the depth test
    (``passes/light_pass.py``)."""
    if CHANNELS[encoding] == 0:
        return 2 if depth_bits == 16 else 4
    return 4 + 4


#: ``light_depth`` read-back bytes per texel of every map: the float32 depths and the uint8
#: picture kept, with some slack (6); plus, for the one face being read at a time, its raw
#: float32 read-back (a depth texture: 4 per texel of a face) or a colour encoding's bytes and
#: the float64 steps of its decode (40). ``tests/test_limits.py`` checks in a fresh process
#: that the estimate is at least what the read-back raises the peak by (two 1024² cube maps,
#: both kinds of map).
LIGHT_DEPTH_TEXEL_BYTES = 6
LIGHT_DEPTH_FACE_BYTES = {"depth": 4, "encoded": 40}
#: Camera framebuffer bytes per pixel: the RGBA8 colour and the DEPTH_COMPONENT32F depth
#: (``passes/camera_pass.py``); plus the visibility targets' float32 channels
#: (:func:`visibility_target_channels`).
CAMERA_PIXEL_BYTES = 4 + 4
VISIBILITY_CHANNEL_BYTES = 4
#: Read-back bytes per pixel of each output: colour as RGBA8 and its RGB copy and PNG (12);
#: depth as float32, three float64 steps of the linearisation and the float32 result (32);
#: visibility: the read of each target's channels (4 each) and the float32 slice of each light
#: (4). Measured at 2048² with 4 point lights and 2048² maps: colour only 464 MB in all
#: (estimate 465 MiB), with depth 564 MB (593), with visibility 644 MB (657).
COLOR_READBACK_BYTES = 12
DEPTH_READBACK_BYTES = 32
VISIBILITY_READBACK_LIGHT_BYTES = 4
#: The ray-traced reference: float64 triangles, normals and embree's float32 copy per
#: triangle, and per pixel the rays and hits of the camera and of each light.
REFERENCE_TRIANGLE_BYTES = 160
REFERENCE_PIXEL_BYTES = 128
REFERENCE_PIXEL_LIGHT_BYTES = 64
#: The GPU's copy of an instance: its float32 model matrix and draw bookkeeping.
INSTANCE_UPLOAD_BYTES = 96


@dataclass(frozen=True)
class RequestBytes:
    """The memory a render needs, by part (bytes); see :func:`request_bytes`.

    Attributes
    ----------
    maps : int
        Shadow maps on the GPU: lights with a map × faces × cascades × size² × bytes per texel
        (automatic cascades: layers of half the largest side).
    map_readback : int
        The ``light_depth`` output.
    framebuffer : int
        The camera pass's colour, depth and visibility targets.
    readback : int
        The ``color``, ``visibility`` and ``depth`` outputs.
    scene : int
        The scene's upload: vertices, indices, textures with mipmaps, instance matrices.
    reference : int
        The ray-traced reference, when asked for.
    map_size : int
        The map side the estimate assumes.
    """

    maps: int
    map_readback: int
    framebuffer: int
    readback: int
    scene: int
    reference: int
    map_size: int

    @property
    def total(self) -> int:
        return (self.maps + self.map_readback + self.framebuffer + self.readback + self.scene
                + self.reference)

    def describe(self) -> str:
        parts = [("shadow maps", self.maps), ("light_depth read-back", self.map_readback),
                 ("framebuffers", self.framebuffer), ("read-back", self.readback),
                 ("scene upload", self.scene), ("reference", self.reference)]
        return ", ".join(f"{name} {_mib(n)}" for name, n in parts if n)


def _mib(n: int) -> str:
    return f"{n / MIB:,.0f} MiB" if n >= 10 * MIB else f"{n / MIB:,.1f} MiB"


def visibility_target_channels(n_lights: int) -> list[int]:
    """Float32 channels of each of the camera pass's visibility targets for ``n_lights``
    lights, four lights a target: a target holds what its lights need, one (R32F), two (RG32F)
    or four (RGBA32F: three take four, as RGB32F need not be colour-renderable). One light's
    visibility is then a quarter of the memory to write, read back and copy."""
    out = []
    for first in range(0, n_lights, 4):
        c = min(4, n_lights - first)
        out.append(4 if c == 3 else c)
    return out


def request_lights(params: RenderParams, scene: Scene | None = None) -> list[tuple[str, bool]]:
    """(type, casts a shadow) of each light the render will shade: the request's, else the
    scene's ``KHR_lights_punctual`` lights, else the one default directional light (also what
    is assumed without a scene, a lower bound)."""
    if params.lights is not None:
        return [(lp.type, lp.cast_shadows) for lp in params.lights]
    if scene is not None and scene.lights:
        return [(sl.type, True) for sl in scene.lights]
    return [("directional", True)]


def scene_upload_bytes(scene: Scene) -> int:
    """Bytes of the scene's GPU upload: float32 vertex attributes, uint32 indices, each
    distinct texture as RGBA8 with its mipmaps (4/3) and, for a cut-out caster's, its R8 alpha
    copy (:class:`~shadowmap.renderer.gl.resources.Texture2D`), and the instances."""
    total = 0
    textures: dict[int, int] = {}
    for p in scene.primitives:
        total += p.positions.nbytes + p.normals.nbytes + p.indices.nbytes
        total += (p.uv.nbytes if p.uv is not None else 0)
        total += (p.colors.nbytes if p.colors is not None else 0)
        tex = p.material.texture
        if tex is not None:
            alpha = tex.nbytes // 4 if p.material.shadow_cutoff is not None else 0
            textures[id(tex)] = max(textures.get(id(tex), 0), tex.nbytes * 4 // 3 + alpha)
    return total + sum(textures.values()) + INSTANCE_UPLOAD_BYTES * len(scene.instances)


def request_bytes(params: RenderParams, lights: Sequence[tuple[str, bool]], map_size: int,
                  scene: Scene | None = None) -> RequestBytes:
    """Estimate the memory one render needs, before it runs.

    Parameters
    ----------
    params : RenderParams
    lights : sequence of (type, casts a shadow)
        The lights shaded (:func:`request_lights`).
    map_size : int
        The side of every light's map (for ``"auto"``: the largest the plan may choose).
    scene : Scene, optional
        Adds its upload (:func:`scene_upload_bytes`) and the reference's triangles.

    Returns
    -------
    RequestBytes
        The parts; ``.total`` is what :func:`fit_request` holds to ``max_request_bytes``.
        Every map is counted at full size, whether or not the plan draws it.
    """
    texel = map_texel_bytes(params.shadows.encoding, params.shadows.depth_bits)
    shadows = params.shadows
    cascades = shadows.cascades if shadows.cascades != "auto" else shadows.max_cascades
    cubes = sum(1 for kind, casts in lights if casts and kind == "point")
    # A directional light has one map, or its cascades: layers of at most half the largest
    # side each when the size is automatic (the plan's rule), of the given size otherwise.
    per_sun = max(1.0, cascades / 4 if shadows.map_size == "auto" else float(cascades))
    maps_2d = sum(per_sun if kind == "directional" else 1.0
                  for kind, casts in lights if casts and kind != "point")
    texels = int((cubes * CUBE_FACES + maps_2d) * map_size * map_size)
    maps = texels * texel
    map_readback = 0
    if "light_depth" in params.outputs and texels:
        face = LIGHT_DEPTH_FACE_BYTES["depth" if shadows.encoding == "depth" else "encoded"]
        map_readback = texels * LIGHT_DEPTH_TEXEL_BYTES + map_size * map_size * face
    pixels = params.width * params.height
    n_lights = len(lights)
    channels = (sum(visibility_target_channels(n_lights)) if "visibility" in params.outputs
                else 0)
    framebuffer = pixels * (CAMERA_PIXEL_BYTES + channels * VISIBILITY_CHANNEL_BYTES)
    readback = 0
    if "color" in params.outputs:
        readback += pixels * COLOR_READBACK_BYTES
    if "depth" in params.outputs:
        readback += pixels * DEPTH_READBACK_BYTES
    if channels:
        readback += pixels * (channels * VISIBILITY_CHANNEL_BYTES
                              + n_lights * VISIBILITY_READBACK_LIGHT_BYTES)
    scene_bytes = scene_upload_bytes(scene) if scene is not None else 0
    reference = 0
    if params.reference:
        triangles = scene.triangle_count if scene is not None else 0
        reference = (triangles * REFERENCE_TRIANGLE_BYTES
                     + pixels * (REFERENCE_PIXEL_BYTES + n_lights * REFERENCE_PIXEL_LIGHT_BYTES))
    return RequestBytes(maps, map_readback, framebuffer, readback, scene_bytes, reference,
                        map_size)


def _over_budget(estimate: RequestBytes, limits: Limits, why: str) -> LimitError:
    return LimitError("max_request_bytes", f"the request needs about {_mib(estimate.total)} "
                      f"({estimate.describe()}){why}, over the limit of "
                      f"{_mib(limits.max_request_bytes)} per request (max_request_bytes)")


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------


def check_request(params: RenderParams, limits: Limits) -> None:
    """The limits a request can break on its own, without its scene.

    The memory checked here is a lower bound (no scene, ``"auto"`` maps at their smallest, the
    file's lights not known): what is refused here would be refused with the scene too.

    Raises
    ------
    LimitError
        ``max_pixels``, ``max_map_size`` (an explicit map size), ``max_lights`` (lights
        listed in the request) or ``max_request_bytes``.
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
    least = request_bytes(params, request_lights(params),
                          MIN_MAP_SIZE if size == "auto" else size)
    if least.total > limits.max_request_bytes:
        raise _over_budget(least, limits, "")


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


def fit_request(params: RenderParams, scene: Scene, limits: Limits) -> tuple[int, list[str]]:
    """Hold a render to ``max_request_bytes``, before any GL work.

    An explicit ``map_size`` is estimated as asked; ``"auto"`` at the largest side the plan may
    choose (:func:`max_map_size`), halved until the estimate fits.

    Returns
    -------
    max_map_size : int
        The largest map side the render may use (``ShadowParams.max_map_size`` for the plan).
    warnings : list of str
        One when ``"auto"`` maps were held below :func:`max_map_size` to fit.

    Raises
    ------
    LimitError
        ``max_request_bytes``: over the limit with the maps as asked, or with ``"auto"`` maps at
        their smallest.
    """
    lights = request_lights(params, scene)
    top = max_map_size(params, limits)
    asked = params.shadows.map_size
    estimate = request_bytes(params, lights, top if asked == "auto" else asked, scene)
    if estimate.total <= limits.max_request_bytes:
        return top, []
    if asked != "auto":
        raise _over_budget(estimate, limits, f" with map_size {asked}")
    size = top
    while size > MIN_MAP_SIZE and estimate.total > limits.max_request_bytes:
        size = max(MIN_MAP_SIZE, 1 << ((size - 1).bit_length() - 1))  # the next power of 2 down
        estimate = request_bytes(params, lights, size, scene)
    if estimate.total > limits.max_request_bytes:
        raise _over_budget(estimate, limits, " even with the smallest shadow maps")
    return size, [f"shadows: map_size 'auto' is held to at most {size} (not {top}) so that the "
                  f"request fits the limit of {_mib(limits.max_request_bytes)} per request "
                  "(max_request_bytes)"]


def check_map_sizes(sizes: Iterable[int], gpu_max: int) -> None:
    """Refuse a planned map larger than the GPU supports (``GL_MAX_*TEXTURE_SIZE``)."""
    for size in sizes:
        if size > gpu_max:
            raise LimitError("max_map_size", f"map size {size} exceeds this GPU's limit {gpu_max}")


def check_gpu_range(bounds: np.ndarray, origin: np.ndarray,
                    points: Sequence[np.ndarray] = (), scene_placed: bool = False) -> None:
    """Refuse a render whose coordinates relative to the scene's centre (what the GPU gets, in
    float32) go past :data:`MAX_COORDINATE`: past it the shaders' squared distances overflow
    to infinity and the picture would silently lose its shading or shadows.

    Parameters
    ----------
    bounds : ndarray, shape (2, 3)
        The scene's world box.
    origin : ndarray, shape (3,)
        The centre positions are uploaded relative to.
    points : sequence of ndarray, shape (3,)
        The camera and the positioned lights (directional lights have no position that
        matters).
    scene_placed : bool
        The points that can fail were placed by the scene, not the request: the automatic
        camera (which stands back from a huge scene) or the file's camera and lights.

    Raises
    ------
    SceneError
        The scene itself is too large, or so is what it placed (``scene_placed``).
    RequestError
        The request's camera or light is too far from the scene.
    """
    from .errors import RequestError, SceneError

    with np.errstate(over="ignore", invalid="ignore"):
        half = float(np.max(np.abs(np.asarray(bounds, np.float64) - origin)))
        if not half <= MAX_COORDINATE:
            raise SceneError(f"the scene reaches {half:.3g} units from its centre: more than "
                             f"the GPU's float32 coordinates hold here ({MAX_COORDINATE:g})")
        for p in points:
            d = float(np.max(np.abs(np.asarray(p, np.float64) - origin)))
            if not d <= MAX_COORDINATE:
                what = ("the camera (the automatic one, or the file's) or a light of the file"
                        if scene_placed else "the camera or a light")
                raise (SceneError if scene_placed else RequestError)(
                    f"{what} is {d:.3g} units from the scene's centre: more than the GPU's "
                    f"float32 coordinates hold here ({MAX_COORDINATE:g})")
