"""Encoding render results for HTTP: PNG images, ``multipart/mixed``, JSON, and the headers.

Image outputs and how they are stored as PNG:

``color``
    8-bit RGB (RGBA with ``alpha: true``), as rendered.
``light_depth_<i>``
    8-bit grayscale of light ``i``'s shadow map, stretched over the depths drawn into it: the
    nearest caster = black, the farthest = 254, no caster = white (255). ``shown_near`` and
    ``shown_far`` (world units) are that stretched range, ``near`` and ``far`` the map's own
    (fitted) range. Cube maps (point lights) are laid out 3 x 2 faces (+X -X +Y / -Y +Z -Z).
``visibility_<i>``
    16-bit grayscale of light ``i``'s shadow factor: ``round(v * 65535)`` with v = 1 lit and
    v = 0 shadowed (fractions from PCF); pixels with no geometry are 0, like full shadow.
``depth``
    16-bit grayscale of the camera-space depth (distance along the view axis), normalised over
    the finite depths of the image: ``round((d - near) / (far - near) * 65534)``, so the nearest
    pixel is 0 and the farthest 65534; pixels with no geometry are 65535 (white). ``near`` and
    ``far`` (world units) are given with the image; decode with
    ``d = near + v / 65534 * (far - near)`` for ``v < 65535``.

With ``float_format: "exr"``, ``depth`` and ``visibility_<i>`` are OpenEXR files instead
(``image/x-exr``, 32-bit float, the raw values: see :mod:`shadowmap.renderer.exr`).

With ``multipart/mixed`` the extra values travel as part headers (``X-Depth-Near``,
``X-Depth-Far``, ``X-Shown-Near``, ``X-Shown-Far``, ``X-Light``); with JSON they are fields
beside the base64 file (``png``, or ``exr``).
"""

from __future__ import annotations

import base64
import json
import math
import secrets
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, Field
from starlette.responses import Response

from shadowmap.renderer import RenderResult
from shadowmap.renderer.exr import DEPTH_CHANNEL, MEDIA_EXR, VISIBILITY_CHANNEL, exr_bytes

# The PNG writer is the library's (``shadowmap batch`` writes the same files), re-exported here.
from shadowmap.renderer.png import (  # noqa: F401  (re-exported)
    PNG_COMPRESS_LEVEL,
    PNG_DEFLATE,
    depth_u16,
    png_bytes,
    visibility_u16,
)
from shadowmap.renderer.render import LightDepth

MEDIA_PNG = "image/png"
MEDIA_MULTIPART = "multipart/mixed"
MEDIA_JSON = "application/json"
FORMATS = (MEDIA_PNG, MEDIA_MULTIPART, MEDIA_JSON)


@dataclass
class EncodedImage:
    """One output as a PNG (or, for float outputs with ``float_format: "exr"``, an OpenEXR)
    file, with what is needed to interpret it."""

    name: str
    data: bytes
    width: int
    height: int
    bit_depth: int
    meta: dict[str, Any] = field(default_factory=dict)
    media_type: str = "image/png"

    @property
    def suffix(self) -> str:
        """The file name's extension: ``.png`` or ``.exr``."""
        return ".exr" if self.media_type == MEDIA_EXR else ".png"


class ImageJSON(BaseModel):
    """One image output in a JSON response."""

    png: str | None = Field(default=None, description="the PNG file, base64-encoded")
    exr: str | None = Field(
        default=None, description="float_format 'exr' (depth, visibility_<i>): the OpenEXR file, "
        "base64-encoded (float32 channel Z or Y, NaN where no geometry)")
    media_type: str = Field(default="image/png", description="image/png or image/x-exr")
    width: int
    height: int
    bit_depth: int = Field(description="8 or 16 bits per channel (PNG), 32 (EXR float)")
    light: int | None = Field(default=None, description="light index (light_depth, visibility)")
    kind: str | None = Field(default=None, description="light_depth: ortho, perspective or cube")
    near: float | None = Field(default=None, description="depth range start (world units)")
    far: float | None = Field(default=None, description="depth range end (world units)")
    shown_near: float | None = Field(
        default=None, description="light_depth: the nearest depth drawn into the map (world "
        "units), black in the picture")
    shown_far: float | None = Field(
        default=None, description="light_depth: the farthest depth drawn into the map (world "
        "units), level 254 in the picture")


class RenderJSON(BaseModel):
    """The ``application/json`` response of ``POST /render``."""

    outputs: dict[str, ImageJSON] = Field(
        description="color, light_depth_<i>, visibility_<i>, depth: whichever were requested"
    )
    timings: dict[str, float] = Field(description="seconds per stage")
    plan: dict[str, Any] = Field(description="what the render ran and what it left out")
    gl: dict[str, Any] = Field(description="GL platform, renderer and version")
    metrics: list[dict[str, Any]] | None = Field(
        default=None, description="error against the ray-traced reference, per light"
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="everything the render had to drop or approximate, one sentence each: what "
        "loading the scene left out (unsupported extensions, materials, textures...), then the "
        "renderer's own (a clamped setting, a light property it cannot honour, a pose made "
        "rigid); empty when the render is what the scene and params asked for. The same list, "
        "capped, is in the X-Render-Warnings header",
    )


# --------------------------------------------------------------------------------------------
# Content negotiation
# --------------------------------------------------------------------------------------------


def _accept_ranges(accept: str) -> list[tuple[str, float]]:
    ranges = []
    for item in accept.split(","):
        fields = [f.strip() for f in item.split(";")]
        media = fields[0].lower()
        if not media:
            continue
        q = 1.0
        for f in fields[1:]:
            if f.lower().startswith("q="):
                try:
                    q = float(f[2:])
                except ValueError:
                    q = 0.0
        ranges.append((media, q if math.isfinite(q) else 0.0))
    return ranges


def _quality(offer: str, ranges: list[tuple[str, float]]) -> float:
    """q of the most specific media range matching ``offer`` (RFC 9110 precedence)."""
    kind = offer.split("/")[0]
    best, best_rank = 0.0, -1
    for media, q in ranges:
        rank = 2 if media == offer else 1 if media == f"{kind}/*" else 0 if media == "*/*" else -1
        if rank > best_rank:
            best, best_rank = q, rank
    return best if best_rank >= 0 else 0.0


def choose_format(accept: str | None, outputs: Sequence[str]) -> str | None:
    """The response media type for an ``Accept`` header, or None when none is acceptable.

    Among equally acceptable types PNG wins when the colour image was requested (so plain
    ``curl`` gets a picture), else ``multipart/mixed``, then JSON.
    """
    ranges = _accept_ranges(accept or "*/*") or [("*/*", 1.0)]
    order = (MEDIA_PNG, MEDIA_MULTIPART, MEDIA_JSON) if "color" in outputs else (
        MEDIA_MULTIPART, MEDIA_JSON, MEDIA_PNG)
    scored = [(_quality(m, ranges), -i, m) for i, m in enumerate(order)]
    q, _, media = max(scored)
    return media if q > 0 else None


# --------------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------------


def _shown_range(ld: LightDepth) -> dict[str, float]:
    """World distances the light-depth picture is stretched over (:func:`debug_image`): the
    nearest and farthest depth drawn; cascades, each stretched alone, give the extremes."""
    return {"shown_near": ld.shown[0], "shown_far": ld.shown[1]} if ld.shown else {}


def encode_outputs(result: RenderResult, names: Sequence[str],
                   float_format: str = "png16") -> list[EncodedImage]:
    """Encode the requested outputs of a render as PNG (or OpenEXR) images.

    Parameters
    ----------
    result : RenderResult
    names : list of str
        Output kinds to encode (``color``, ``light_depth``, ``visibility``, ``depth``); kinds the
        result does not hold are skipped.
    float_format : {"png16", "exr"}
        How ``depth`` and ``visibility_<i>`` are written: 16-bit PNG, or raw float32 OpenEXR
        (:mod:`shadowmap.renderer.exr`).

    Raises
    ------
    ExrUnavailable
        ``exr`` without the OpenEXR package.
    """
    exr = float_format == "exr"
    images: list[EncodedImage] = []
    if "color" in names and result.color is not None:
        c = result.color
        images.append(EncodedImage("color", png_bytes(c), c.shape[1], c.shape[0], 8))
    if "light_depth" in names:
        for ld in result.light_depth:
            img = ld.image
            images.append(EncodedImage(
                f"light_depth_{ld.light}", png_bytes(img), img.shape[1], img.shape[0], 8,
                {"light": ld.light, "kind": ld.kind, "near": float(ld.near), "far": float(ld.far),
                 **_shown_range(ld)},
            ))
    if "visibility" in names and result.visibility is not None:
        vis = result.visibility
        for i in range(vis.shape[2]):
            if exr:
                images.append(EncodedImage(
                    f"visibility_{i}", exr_bytes({VISIBILITY_CHANNEL: vis[..., i]}, {"light": i}),
                    vis.shape[1], vis.shape[0], 32, {"light": i}, MEDIA_EXR))
                continue
            images.append(EncodedImage(f"visibility_{i}", png_bytes(visibility_u16(vis[..., i])),
                                       vis.shape[1], vis.shape[0], 16, {"light": i}))
    if "depth" in names and result.depth is not None:
        d = result.depth
        if exr:
            images.append(EncodedImage("depth", exr_bytes({DEPTH_CHANNEL: d}), d.shape[1],
                                       d.shape[0], 32, {}, MEDIA_EXR))
        else:
            img, near, far = depth_u16(d)
            images.append(EncodedImage("depth", png_bytes(img), img.shape[1], img.shape[0], 16,
                                       {"near": near, "far": far}))
    return images


# --------------------------------------------------------------------------------------------
# Bodies
# --------------------------------------------------------------------------------------------


def jsonable(obj: Any) -> Any:
    """Plain JSON types: numpy scalars and arrays converted, non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def multipart_body(images: list[EncodedImage]) -> tuple[bytes, str]:
    """A ``multipart/mixed`` body with one PNG (or EXR) part per image.

    Returns
    -------
    body : bytes
    content_type : str
        Including the boundary.
    """
    boundary = "shadowmap-" + secrets.token_hex(12)
    out = bytearray()
    for im in images:
        headers = [
            f"Content-Type: {im.media_type}",
            f'Content-Disposition: inline; name="{im.name}"; filename="{im.name}{im.suffix}"',
            f"Content-Length: {len(im.data)}",
        ]
        if "light" in im.meta:
            headers.append(f"X-Light: {im.meta['light']}")
        for key in ("near", "far"):
            if im.meta.get(key) is not None:
                headers.append(f"X-Depth-{key.capitalize()}: {im.meta[key]!r}")
            if im.meta.get("shown_" + key) is not None:
                headers.append(f"X-Shown-{key.capitalize()}: {im.meta['shown_' + key]!r}")
        out += f"--{boundary}\r\n".encode() + "\r\n".join(headers).encode() + b"\r\n\r\n"
        out += im.data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out), f'{MEDIA_MULTIPART}; boundary="{boundary}"'


def json_body(images: list[EncodedImage], report: dict[str, Any],
              timings: dict[str, float]) -> bytes:
    """The JSON response: base64 PNGs (``png``) or EXRs (``exr``) plus timings, plan, GL info,
    warnings and metrics."""
    outputs = {}
    for im in images:
        entry = {im.suffix[1:]: base64.b64encode(im.data).decode("ascii"),
                 "media_type": im.media_type, "width": im.width, "height": im.height,
                 "bit_depth": im.bit_depth}
        entry.update(im.meta)
        outputs[im.name] = entry
    body = {"outputs": outputs, "timings": timings, "plan": report.get("plan", {}),
            "gl": report.get("gl", {}), "warnings": report.get("warnings", [])}
    if report.get("metrics") is not None:
        body["metrics"] = report["metrics"]
    return json.dumps(jsonable(body), allow_nan=False, separators=(",", ":")).encode()


# --------------------------------------------------------------------------------------------
# Headers
# --------------------------------------------------------------------------------------------


def server_timing(stages: dict[str, float], notes: dict[str, str] | None = None) -> str:
    """``Server-Timing`` header value from seconds per stage (the header wants milliseconds)."""
    notes = notes or {}
    items = []
    for name, seconds in stages.items():
        item = f"{name};dur={seconds * 1000.0:.2f}"
        if name in notes:
            item += f';desc="{notes[name]}"'
        items.append(item)
    return ", ".join(items)


def plan_header(plan: dict[str, Any]) -> str:
    """Compact ASCII JSON of the render plan, for ``X-Render-Plan``."""
    return json.dumps(jsonable(plan), separators=(",", ":"), ensure_ascii=True, allow_nan=False)


#: Longest ``X-Render-Warnings`` value, in characters: well inside the 8 KiB that common servers
#: and proxies allow for all headers together, beside ``X-Render-Plan``.
WARNINGS_HEADER_MAX = 2048
#: Longest single warning in the header; longer ones end in "...", so that one long warning
#: cannot crowd out the rest (the JSON body has them in full).
WARNING_ITEM_MAX = 300


def warnings_header(warnings: Sequence[str], limit: int = WARNINGS_HEADER_MAX) -> str:
    """Compact ASCII JSON list of the render's warnings, for ``X-Render-Warnings``.

    As many warnings as fit in ``limit`` characters, in order, then ``"... and N more"`` for the
    rest; ``[]`` when there are none.

    Parameters
    ----------
    warnings : list of str
    limit : int
        Upper bound of the value's length; at least enough for the tail alone (about 30).
    """
    def dumps(items: list[str]) -> str:
        # ensure_ascii escapes everything outside ASCII and JSON escapes control characters;
        # DEL is neither, and not allowed in a header value either.
        text = json.dumps(items, separators=(",", ":"), ensure_ascii=True)
        return text.replace("\x7f", "\\u007f")

    items = [w if len(w) <= WARNING_ITEM_MAX else w[:WARNING_ITEM_MAX - 3] + "..."
             for w in warnings]
    kept: list[str] = []
    for i, item in enumerate(items):
        rest = len(items) - i - 1
        tail = [f"... and {rest} more"] if rest else []
        if len(dumps([*kept, item, *tail])) > limit:
            break
        kept.append(item)
    if len(kept) < len(items):
        kept.append(f"... and {len(items) - len(kept)} more")
    return dumps(kept)


# --------------------------------------------------------------------------------------------
# Responses
# --------------------------------------------------------------------------------------------

#: Renderer stages reported in ``Server-Timing``, in pipeline order.
RENDER_STAGES = ("upload", "plan", "light", "camera", "readback", "reference")


def build_response(media: str, result: RenderResult, outputs: Sequence[str],
                   before: dict[str, float], notes: dict[str, str], started: float,
                   float_format: str = "png16") -> Response:
    """The HTTP response of a finished render, with ``Server-Timing``, ``X-Render-Plan`` and
    ``X-Render-Warnings``.

    Parameters
    ----------
    media : str
        One of :data:`FORMATS`.
    result : RenderResult
    outputs : list of str
        The requested outputs (PNG responses carry only the colour image).
    before : dict of str to float
        Seconds spent before the renderer's own stages (read, queue, parse).
    notes : dict of str to str
        ``desc`` of some stages, e.g. ``{"parse": "scene cache hit"}``.
    started : float
        ``time.perf_counter()`` at the start of the request.
    float_format : {"png16", "exr"}
        The request's ``float_format`` (see :func:`encode_outputs`).
    """
    t = time.perf_counter()
    images = encode_outputs(result, ["color"] if media == MEDIA_PNG else outputs, float_format)
    stages = dict(before)
    stages["parse"] = stages.get("parse", 0.0) + result.timings.get("load", 0.0)
    for name in RENDER_STAGES:
        if name in result.timings:
            stages[name] = result.timings[name]
    stages["encode"] = time.perf_counter() - t
    if media == MEDIA_PNG:
        body, content_type = images[0].data, MEDIA_PNG
    elif media == MEDIA_MULTIPART:
        body, content_type = multipart_body(images)
    else:
        timings = {k: round(v, 6) for k, v in stages.items()}
        timings["render"] = result.timings.get("total", 0.0)
        timings["total"] = round(time.perf_counter() - started, 6)
        body, content_type = json_body(images, result.report(), timings), MEDIA_JSON
    stages["total"] = time.perf_counter() - started
    headers = {
        "Server-Timing": server_timing(stages, notes),
        "X-Render-Plan": plan_header(result.plan),
        "X-Render-Warnings": warnings_header(result.warnings),
        "Cache-Control": "no-store",
    }
    if media == MEDIA_PNG:
        headers["Content-Disposition"] = 'inline; filename="color.png"'
    return Response(body, media_type=content_type, headers=headers)
