"""PNG files of rendered outputs: the one writer the service, the CLI's batch command and the
benchmarks share.

It needs only numpy and a deflate compressor, so a library install can write the same files as
the HTTP service (which re-exports these names from :mod:`shadowmap.app.encode`).

``color`` is stored as rendered (8-bit RGB or RGBA); the light-depth debug images as 8-bit grey;
the shadow factor as 16-bit grey (:func:`visibility_u16`) and the camera depth as 16-bit grey
normalised over its finite range (:func:`depth_u16`).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable

import numpy as np

__all__ = ["PNG_COMPRESS_LEVEL", "PNG_DEFLATE", "depth_u16", "png_bytes", "visibility_u16"]

PNG_COMPRESS_LEVEL = 1  # zlib level: the time of higher levels buys little size on renders


def _deflate() -> tuple[str, Callable[[bytes | memoryview], bytes]]:
    """The deflate compressor for PNG data: ISA-L's zlib-compatible one when installed (the
    ``server`` extra has it), else zlib; both at level 1 and both writing zlib streams, so any
    PNG reader decodes either."""
    try:
        from isal import isal_zlib
    except ImportError:
        return "zlib", lambda data: zlib.compress(data, PNG_COMPRESS_LEVEL)
    return "isal", lambda data: isal_zlib.compress(data, PNG_COMPRESS_LEVEL)


#: Which compressor :func:`png_bytes` uses ("isal" or "zlib"), and the function itself.
PNG_DEFLATE, _compress = _deflate()

_PNG_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # grey, RGB, RGBA


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bytes(image: np.ndarray) -> bytes:
    """PNG of a uint8 (H, W), (H, W, 3), (H, W, 4) or uint16 (H, W) array.

    Written directly (no per-row filter, deflate level 1, with :data:`PNG_DEFLATE`): for a
    rendered frame this takes about a third of the time of an encoder that tries every row
    filter with zlib, for files about a third larger; ISA-L's deflate takes about a quarter of
    zlib's time (``bench/png_encode.py``).
    """
    a = np.asarray(image)
    if a.dtype not in (np.uint8, np.uint16) or a.ndim not in (2, 3):
        raise ValueError(f"cannot write a PNG of a {a.dtype} array of shape {a.shape}")
    h, w = a.shape[:2]
    channels = 1 if a.ndim == 2 else a.shape[2]
    if channels not in _PNG_COLOUR_TYPE:
        raise ValueError(f"cannot write a PNG with {channels} channels")
    # One copy, from whatever strides the image has (a render's rows come flipped, as GL
    # reads them) into the filtered rows: filter byte 0 (none), then the row, big-endian.
    dtype = np.dtype(">u2" if a.dtype == np.uint16 else np.uint8)
    raw = np.empty((h, w * channels * dtype.itemsize + 1), np.uint8)
    raw[:, 0] = 0
    raw[:, 1:].view(dtype).reshape(h, w, channels)[...] = a.reshape(h, w, channels)
    header = struct.pack(">IIBBBBB", w, h, 8 * a.dtype.itemsize, _PNG_COLOUR_TYPE[channels],
                         0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", header)
            + _png_chunk(b"IDAT", _compress(raw.data))
            + _png_chunk(b"IEND", b""))


def visibility_u16(v: np.ndarray) -> np.ndarray:
    """Shadow factor in [0, 1] -> uint16 ``round(v * 65535)``; NaN (no geometry) -> 0."""
    # In float64, in place: fmax and fmin take the number over a NaN, so NaN and -inf end at 0
    # and +inf at 65535, as clipping the factor to [0, 1] first would (the same values).
    f = np.multiply(v, 65535.0, dtype=np.float64)
    np.fmax(f, 0.0, out=f)
    np.fmin(f, 65535.0, out=f)
    np.rint(f, out=f)
    return f.astype(np.uint16)


def depth_u16(d: np.ndarray) -> tuple[np.ndarray, float | None, float | None]:
    """Camera depth -> uint16 normalised over its finite range; NaN (no geometry) -> 65535.

    Returns
    -------
    image : ndarray, shape (H, W), uint16
    near, far : float or None
        The depth range mapped to 0 and 65534 (None when the image has no geometry).
    """
    finite = np.isfinite(d)
    if not finite.any():
        return np.full(d.shape, 65535, np.uint16), None, None
    near = float(np.min(d, where=finite, initial=np.inf))
    far = float(np.max(d, where=finite, initial=-np.inf))
    span = far - near if far > near else 1.0
    # Over the whole image in place (no gathering of the finite pixels), then the others set.
    f = np.subtract(d, near, dtype=np.float64)
    f /= span
    f *= 65534.0
    np.rint(f, out=f)
    np.putmask(f, ~finite, 65535.0)
    return f.astype(np.uint16), near, far
