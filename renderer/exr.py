"""Float outputs as OpenEXR: the camera depth and the per-light visibility, raw float32.

16-bit PNG (the default ``float_format``) quantises and normalises each image over its own range;
an EXR keeps the values the renderer computed, bit for bit:

``depth.exr``
    One channel ``Z``: camera-space depth (distance along the view axis) in scene units; NaN
    where no geometry was drawn (the background), as in :attr:`RenderResult.depth`.
``visibility_<i>.exr``
    One channel ``Y`` per file, one file per light (the PNG outputs' naming): light ``i``'s
    shadow factor, 1 lit, 0 shadowed, fractions from PCF; NaN where no geometry was drawn.

Both are single-part scanline images with ZIP compression (lossless), 32-bit float pixels, row
0 at the top, like the PNGs. The optional ``near``/``far`` and ``light`` values travel as header
attributes. Writing needs the ``OpenEXR`` package (PyPI ``OpenEXR`` 3.x, in the ``server``
extra); without it :class:`ExrUnavailable` is raised.
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ExrUnavailable, FileFormatError, LimitError, SceneError
from .limits import Limits

MEDIA_EXR = "image/x-exr"
DEPTH_CHANNEL = "Z"
VISIBILITY_CHANNEL = "Y"

__all__ = ["DEPTH_CHANNEL", "MEDIA_EXR", "VISIBILITY_CHANNEL", "ExrUnavailable", "exr_available",
           "exr_bytes", "read_exr", "write_exr"]


def _openexr() -> Any:
    try:
        import OpenEXR
    except ImportError:
        raise ExrUnavailable(
            "float_format 'exr' needs the OpenEXR package: pip install 'OpenEXR>=3.5' (it is "
            "in the shadowmap-service[server] extra)") from None
    return OpenEXR


def exr_available() -> bool:
    """Whether :func:`exr_bytes` can write (the ``OpenEXR`` package imports)."""
    try:
        _openexr()
    except ExrUnavailable:
        return False
    return True


def exr_bytes(channels: Mapping[str, np.ndarray],
              attributes: Mapping[str, float | int | str] | None = None) -> bytes:
    """An OpenEXR file of float32 channels, as bytes.

    Parameters
    ----------
    channels : mapping of str to ndarray, each shape (H, W)
        Channel name to pixels; converted to float32 (NaN and Inf kept).
    attributes : mapping, optional
        Extra header attributes (numbers or strings), e.g. ``{"near": 0.5}``.

    Raises
    ------
    ExrUnavailable
        The ``OpenEXR`` package is not installed.
    ValueError
        No channel, or channels of different or non-2-D shapes.
    """
    exr = _openexr()
    if not channels:
        raise ValueError("an EXR needs at least one channel")
    pixels = {name: np.ascontiguousarray(a, dtype=np.float32) for name, a in channels.items()}
    shapes = {a.shape for a in pixels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must be 2-D arrays of one shape, not {sorted(shapes)}")
    header: dict[str, Any] = {"compression": exr.ZIP_COMPRESSION, "type": exr.scanlineimage}
    for key, value in (attributes or {}).items():
        header[key] = value if isinstance(value, str) else (
            int(value) if isinstance(value, (int, np.integer)) else float(value))
    stream = io.BytesIO()
    exr.File(header, pixels).write(stream)
    return stream.getvalue()


def write_exr(path: str | Path, channels: Mapping[str, np.ndarray],
              attributes: Mapping[str, float | int | str] | None = None) -> None:
    """Write :func:`exr_bytes` to ``path``."""
    Path(path).write_bytes(exr_bytes(channels, attributes))


def read_exr(source: str | os.PathLike[str] | bytes | bytearray | memoryview,
             max_pixels: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The channels (float32 arrays by name) and header of an EXR file or its bytes.

    The header is read first: a data window over ``max_pixels`` is refused before any pixel
    is, as a corrupt or hostile header can ask for any size (60,000² is 13 GiB per channel).

    Parameters
    ----------
    source : path or bytes-like
        A file's path, or the file's content.
    max_pixels : int, optional
        The most pixels per channel read; default :attr:`Limits.max_pixels` (the largest image
        a render makes under the default limits).

    Returns
    -------
    channels : dict of str to ndarray, each shape (H, W)
    header : dict
        The file's header attributes (``dataWindow``, ``compression``, ``near``, ...).

    Raises
    ------
    ExrUnavailable
        The ``OpenEXR`` package is not installed.
    FileFormatError
        The file cannot be read, or is not an OpenEXR image (truncated, corrupt).
    LimitError
        Its data window holds more than ``max_pixels`` pixels (``limit`` ``"max_pixels"``).
    """
    exr = _openexr()
    if isinstance(source, (bytes, bytearray, memoryview)):
        data, name = bytes(source), "the EXR data"
    elif isinstance(source, (str, os.PathLike)):
        from .scene import read_regular_file

        name = os.fsdecode(source).replace("\x00", "\\x00")
        try:
            data = read_regular_file(Path(source), name)  # not a FIFO or /dev/zero
        except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
            raise FileFormatError(f"cannot read {name}: "
                                  f"{getattr(exc, 'strerror', None) or exc}") from None
        except SceneError as exc:
            raise FileFormatError(str(exc)) from None
    else:
        raise FileFormatError(f"read_exr reads a path or bytes, not {type(source).__name__}")
    limit = Limits().max_pixels if max_pixels is None else int(max_pixels)
    try:
        (x0, y0), (x1, y1) = exr.File(io.BytesIO(data), header_only=True).header()["dataWindow"]
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        raise FileFormatError(f"{name} is not an OpenEXR image this can read ({exc})") from None
    width, height = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
    if width <= 0 or height <= 0:
        raise FileFormatError(f"{name} has an empty data window ({width}x{height})")
    if width * height > limit:
        raise LimitError("max_pixels", f"{name} is {width}x{height} pixels, over the limit of "
                         f"{limit}: pass read_exr(..., max_pixels=N) to read it")
    try:
        f = exr.File(io.BytesIO(data), separate_channels=True)
        channels = {key: np.asarray(ch.pixels) for key, ch in f.channels().items()}
    except (RuntimeError, ValueError, MemoryError) as exc:
        raise FileFormatError(f"{name}: its pixels cannot be read ({exc})") from None
    return channels, dict(f.header())
