"""Materials: the base colour (factor and texture), alpha mode and cutoff, double-sidedness.

What the renderer draws from a glTF material is its base colour: ``pbrMetallicRoughness``'s
``baseColorFactor`` and ``baseColorTexture`` (with its ``texCoord`` set and
``KHR_texture_transform``), or, for a material without ``pbrMetallicRoughness``, the diffuse
colour of ``KHR_materials_pbrSpecularGlossiness``. Textures are decoded once per image with PIL
(PNG, JPEG, WebP) under a pixel-count limit per image and, with ``max_texture_pixels``, over all
of them (a :class:`~shadowmap.renderer.errors.LimitError`); a texture that cannot be used
(undecodable, too large, a missing file) is dropped with a warning naming the image and the
material, and the render then uses the base colour factor. An image URI that could leave the
upload is refused (:class:`~shadowmap.renderer.errors.SceneError`), as a buffer's is. The
texture's sampler gives its filters and wrap modes (:class:`~shadowmap.renderer.scene.Sampler`);
a value glTF does not define is replaced by the default, with a warning.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import LimitError, SceneError
from ..scene import MAG_FILTERS, MIN_FILTERS, WRAPS, Material, Sampler, safe_uri
from .extensions import (
    materials_unlit,
    specular_glossiness,
    texture_sources,
    texture_transform,
)
from .reader import (
    Buffers,
    Resolver,
    brief,
    exception_text,
    extension,
    get_list,
    is_data_uri,
    load_uri,
)

#: Largest texture decoded (pixels): 64 Mpixel, like PIL's ``Image.MAX_IMAGE_PIXELS`` guard.
MAX_TEXTURE_PIXELS = 64 * 2**20
#: Image formats decoded: glTF's PNG and JPEG, WebP (EXT_texture_webp) and AVIF (EXT_texture_avif).
IMAGE_FORMATS = ("PNG", "JPEG", "WEBP", "AVIF")
ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")
#: How far past glTF's [0, 1] a colour (factor or COLOR_0) may lie before its clamping is
#: worth a warning: an exporter's rounding just past 1 is not.
COLOUR_SLACK = 1e-3


def clamp_colour(values: npt.ArrayLike) -> tuple[np.ndarray, bool]:
    """``values`` clipped to glTF's colour range [0, 1], and whether they lay further outside
    it than :data:`COLOUR_SLACK` (worth a warning). Any shape; float64 out."""
    values = np.asarray(values, np.float64)
    outside = bool(values.size) and (values.min() < -COLOUR_SLACK
                                     or values.max() > 1.0 + COLOUR_SLACK)
    return np.clip(values, 0.0, 1.0), outside


@dataclass(frozen=True, eq=False)
class MaterialUse:
    """A material as primitives use it.

    Attributes
    ----------
    material : Material
        With its texture when it has one that decoded.
    untextured : Material
        The same without the texture, for a primitive that lacks the texture's UV set.
    tex_coord : int
        The ``TEXCOORD_n`` set the base-colour texture reads (after a ``KHR_texture_transform``
        override).
    uv_transform : ndarray or None, shape (3, 3)
        ``KHR_texture_transform`` of the base-colour texture, on glTF UVs.
    name : str
        How warnings name the material.
    """

    material: Material
    untextured: Material
    tex_coord: int = 0
    uv_transform: np.ndarray | None = None
    name: str = "the default material"


def _label(kind: str, index: int, spec: Any) -> str:
    name = spec.get("name") if isinstance(spec, dict) else None
    if isinstance(name, str) and name:
        return f"{kind} {index} ({brief(name)})"
    return f"{kind} {index}"


def decode_image(data: bytes, max_pixels: int | None = None,
                 on_size: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Decode a PNG, JPEG or WebP image to RGBA.

    The size is checked from the header, before any pixel is decoded.

    Parameters
    ----------
    data : bytes
    max_pixels : int, optional
        Default :data:`MAX_TEXTURE_PIXELS`.
    on_size : callable, optional
        Called with (width, height) once the header is read, before the pixels are decoded
        (it may raise to stop the decode).

    Returns
    -------
    ndarray, shape (H, W, 4), uint8
        Rows top to bottom as in the file.

    Raises
    ------
    ValueError
        Too many pixels.
    Exception
        Whatever PIL raises on data it cannot decode.
    """
    from PIL import Image

    max_pixels = MAX_TEXTURE_PIXELS if max_pixels is None else max_pixels
    with Image.open(io.BytesIO(data), formats=IMAGE_FORMATS) as im:
        w, h = im.size
        if w * h > max_pixels:
            raise ValueError(f"{w}x{h} pixels is over the limit of {max_pixels}")
        if w * h == 0:
            raise ValueError("the image has no pixels")
        if on_size is not None:
            on_size(w, h)
        rgba = im.convert("RGBA")
    return np.asarray(rgba, dtype=np.uint8)


class Materials:
    """The document's materials, each built once, with their textures decoded once per image.

    Parameters
    ----------
    buffers : Buffers
    resolver : Resolver
        External images by relative name.
    warnings : list of str
        Where messages about dropped or approximated parts are appended.
    max_texture_pixels : int, optional
        Most pixels decoded over all images (``Limits.max_texture_pixels``).
    """

    def __init__(self, buffers: Buffers, resolver: Resolver, warnings: list[str],
                 max_texture_pixels: int | None = None) -> None:
        self.doc = buffers.doc
        self.buffers = buffers
        self.resolver = resolver
        self.warnings = warnings
        self.specs = get_list(self.doc, "materials")
        self.textures = get_list(self.doc, "textures")
        self.images = get_list(self.doc, "images")
        self.samplers = get_list(self.doc, "samplers")
        self._uses: dict[int | None, MaterialUse] = {}
        self._images: dict[int, np.ndarray | str] = {}
        self.max_texture_pixels = max_texture_pixels
        #: Pixels of the images decoded so far (counted from their headers, before decoding:
        #: an image that fails part way has cost its memory all the same).
        self.pixels = 0

    def get(self, index: int | None) -> MaterialUse:
        """The material ``index`` (None: glTF's default material)."""
        use = self._uses.get(index)
        if use is None:
            use = self._uses[index] = self._build(index)
        return use

    # -- building --------------------------------------------------------------------------

    def _build(self, index: int | None) -> MaterialUse:
        if index is None:
            default = Material(np.ones(4, np.float32))
            return MaterialUse(default, default)
        spec = self.specs[index]
        if not isinstance(spec, dict):
            raise SceneError(f"malformed glTF: material {index} is not an object")
        label = _label("material", index, spec)
        factor_json: Any = None
        tex_info: Any = None
        pbr = spec.get("pbrMetallicRoughness")
        if isinstance(pbr, dict):
            factor_json, tex_info = pbr.get("baseColorFactor"), pbr.get("baseColorTexture")
        elif (sg := specular_glossiness.base_colour(spec)) is not None:
            factor_json, tex_info = sg
        factor = self._factor(factor_json, label)
        alpha_mode = spec.get("alphaMode", "OPAQUE")
        if not isinstance(alpha_mode, str) or alpha_mode not in ALPHA_MODES:
            self.warnings.append(f"{label}: unknown alphaMode {brief(alpha_mode)}, drawn OPAQUE")
            alpha_mode = "OPAQUE"
        cutoff = self._cutoff(spec, label, alpha_mode)
        double_sided = spec.get("doubleSided", False) is True
        untextured = Material(factor, None, alpha_mode, cutoff, double_sided,
                              materials_unlit.unlit(spec))
        texture, tex_coord, transform, sampler = self._texture(tex_info, label)
        material = (untextured if texture is None
                    else dataclasses.replace(untextured, texture=texture, sampler=sampler))
        return MaterialUse(material, untextured, tex_coord, transform, label)

    def _factor(self, value: Any, label: str) -> np.ndarray:
        if value is None:
            return np.ones(4, np.float32)
        if (isinstance(value, list) and len(value) == 4
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
                and all(math.isfinite(v) for v in value)):
            # Outside glTF's range the shading (and float32) would quietly go wrong.
            factor, outside = clamp_colour(value)
            if outside:
                self.warnings.append(f"{label}: base colour factor {brief(value)} is outside "
                                     "[0, 1]; clamped")
            return factor.astype(np.float32)
        self.warnings.append(f"{label}: base colour factor {brief(value)} is not 4 finite numbers; "
                             "white is used")
        return np.ones(4, np.float32)

    def _cutoff(self, spec: dict[str, Any], label: str, alpha_mode: str) -> float:
        if "alphaCutoff" not in spec:
            return 0.5  # glTF's default, only when the file gives none (0 is a valid cutoff)
        value = spec["alphaCutoff"]
        if (isinstance(value, bool) or not isinstance(value, int | float)
                or not math.isfinite(value) or value < 0):
            self.warnings.append(f"{label}: alphaCutoff {brief(value)} is not a number >= 0; 0.5 "
                                 "is used")
            return 0.5
        cutoff = float(value)
        if alpha_mode == "MASK" and cutoff > 1.0:
            self.warnings.append(f"{label} is fully cut out: alphaMode MASK with alphaCutoff "
                                 f"{cutoff} > 1 keeps no pixel (it is drawn nowhere and casts "
                                 "no shadow)")
        return cutoff

    def _texture(self, info: Any, label: str
                 ) -> tuple[np.ndarray | None, int, np.ndarray | None, Sampler]:
        """(texture, texCoord set, uv transform, sampler) of a textureInfo."""
        if info is None:
            return None, 0, None, Sampler()
        if not isinstance(info, dict):
            self.warnings.append(f"{label}: base colour texture is not an object: dropped")
            return None, 0, None, Sampler()
        tex_coord = info.get("texCoord", 0)
        if isinstance(tex_coord, bool) or not isinstance(tex_coord, int) or tex_coord < 0:
            self.warnings.append(f"{label}: texCoord {brief(tex_coord)} is invalid; 0 is used")
            tex_coord = 0
        transform = None
        tt = extension(info, texture_transform.EXTENSION)
        if tt is not None:
            transform = texture_transform.uv_matrix(tt, label)
            tex_coord = texture_transform.tex_coord(tt, tex_coord, label)
        tex = info.get("index")
        if isinstance(tex, bool) or not isinstance(tex, int) or not 0 <= tex < len(self.textures):
            self.warnings.append(f"{label}: base colour texture {brief(tex)} does not exist: "
                                 "dropped, the base colour factor is used")
            return None, tex_coord, transform, Sampler()
        tspec = self.textures[tex]
        tspec = tspec if isinstance(tspec, dict) else {}
        sources = [(s, by) for s, by in texture_sources.candidates(tspec)
                   if not isinstance(s, bool) and isinstance(s, int) and 0 <= s < len(self.images)]
        if not sources:
            self.warnings.append(f"{label}: texture {tex} has no image source this loader reads"
                                 ": dropped, the base colour factor is used")
            return None, tex_coord, transform, Sampler()
        # The first image that decodes (an extension's WebP or AVIF, then the plain source);
        # one that does not is named, with what stood in for it.
        failed: list[str] = []
        for source, by in sources:
            image = self._image(source)
            what = _label("image", source, self.images[source])
            if by != "source":
                what += f" ({by})"
            if not isinstance(image, str):
                if failed:
                    self.warnings.append(f"{'; '.join(failed)}; {what} is used instead")
                return image, tex_coord, transform, self._sampler(tspec, label)
            failed.append(f"{what} of {label}: {image}")
        self.warnings.append(f"{'; '.join(failed)}; the texture is dropped and the base colour "
                             "factor is used")
        return None, tex_coord, transform, Sampler()

    def _sampler(self, tspec: dict[str, Any], label: str) -> Sampler:
        """The texture's sampler: its filters and wrap modes, glTF's defaults where it gives
        none (and for no sampler), a value glTF does not define replaced with a warning."""
        index = tspec.get("sampler")
        if index is None:
            return Sampler()
        if isinstance(index, bool) or not isinstance(index, int) or not (
                0 <= index < len(self.samplers)) or not isinstance(self.samplers[index], dict):
            self.warnings.append(f"{label}: sampler {brief(index)} does not exist; the texture "
                                 "repeats, bilinear and trilinear")
            return Sampler()
        spec = self.samplers[index]
        default = Sampler()
        values = {}
        for key, field, allowed in (("magFilter", "mag_filter", MAG_FILTERS),
                                    ("minFilter", "min_filter", MIN_FILTERS),
                                    ("wrapS", "wrap_s", WRAPS), ("wrapT", "wrap_t", WRAPS)):
            value = spec.get(key, getattr(default, field))
            if isinstance(value, bool) or not isinstance(value, int) or value not in allowed:
                fallback = getattr(default, field)
                self.warnings.append(f"{label}: sampler {index} {key} {brief(value)} is not a "
                                     f"glTF value; {allowed[fallback]} is used")
                value = fallback
            values[field] = value
        return Sampler(**values)

    def _image(self, index: int) -> np.ndarray | str:
        """The decoded image, or why it cannot be used."""
        if index in self._images:
            return self._images[index]
        spec = self.images[index]
        label = _label("image", index, spec)
        uri = spec.get("uri") if isinstance(spec, dict) and "bufferView" not in spec else None
        if isinstance(uri, str) and not is_data_uri(uri):
            safe_uri(uri, label)  # an unsafe URI is refused, as a buffer's: not a missing file
        result: np.ndarray | str
        try:
            if not isinstance(spec, dict):
                raise SceneError("malformed image")
            if "bufferView" in spec:
                bv = spec["bufferView"]
                if isinstance(bv, bool) or not isinstance(bv, int):
                    raise SceneError(f"bufferView {brief(bv)} is not an index")
                data = self.buffers.view(bv)
            elif "uri" in spec:
                data = load_uri(spec["uri"], self.resolver, "the image")
            else:
                raise SceneError("the image has neither a uri nor a bufferView")
        except SceneError as exc:
            result = f"cannot be read ({exc})"
        else:
            try:
                result = decode_image(data, on_size=lambda w, h: self._count(w, h, label))
            except LimitError:
                raise
            except Exception as exc:  # noqa: BLE001 - PIL raises many types on bad input
                result = f"cannot be decoded ({exception_text(exc)})"
        self._images[index] = result
        return result

    def _count(self, width: int, height: int, label: str) -> None:
        """Count an image about to be decoded; refuse it when it would take the decoded pixels
        over ``max_texture_pixels``."""
        total = self.pixels + width * height
        self.pixels = total
        if self.max_texture_pixels is not None and total > self.max_texture_pixels:
            raise LimitError("max_texture_pixels", f"{label} ({width}x{height}) takes the "
                             f"scene's textures to {total:,} pixels, over the limit of "
                             f"{self.max_texture_pixels:,} (max_texture_pixels)")
