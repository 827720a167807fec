"""CPU mirrors of the depth encodings in ``shaders/chunks/depth_encoding.glsl``.

Used to decode read-back shadow maps (the ``light_depth`` output) and to check the GL packing in
the tests. Each function works on arrays of any shape. :data:`ENCODING_ID` is also the shaders'
``ENC_*`` (see :mod:`.shader_constants`); :data:`STEP` is each encoding's depth step, which the
passes hand the shaders per map (``ShadowMap.step``; a 16-bit depth texture's is 1/65535).
"""

from __future__ import annotations

import numpy as np

# Step of each encoding in units of the normalised depth t ("depth": a 32-bit float depth
# texture). The byte packings carry 24 bits: that is all a float32 depth holds, so rgba8's fourth
# byte adds nothing in practice.
STEP = {
    "r8": 1.0 / 255.0,
    "rg8": 1.0 / 2550.0,
    "rgb8": 2.0**-24,
    "rgba8": 2.0**-24,
    "depth": 2.0**-24,
}
CHANNELS = {"r8": 1, "rg8": 2, "rgb8": 3, "rgba8": 4, "depth": 0}
ENCODING_ID = {"depth": 0, "r8": 1, "rg8": 2, "rgb8": 3, "rgba8": 4}


def _bytes(t: np.ndarray) -> np.ndarray:
    """Four bytes of t, most significant first; shape (..., 4) uint8."""
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0 - 2.0**-24)
    q = np.floor(t * 2.0**32).astype(np.uint64)
    return np.stack([(q >> s) & 0xFF for s in (24, 16, 8, 0)], axis=-1).astype(np.uint8)


def encode(t: np.ndarray, encoding: str) -> np.ndarray:
    """Bytes the light pass stores for depths ``t``; shape (..., 4) uint8 (RGBA)."""
    t = np.asarray(t, np.float64)
    out = np.zeros(t.shape + (4,), np.uint8)
    out[..., 3] = 255
    if encoding == "r8":
        out[..., 0] = np.rint(np.clip(t, 0, 1) * 255)
    elif encoding == "rg8":
        value = np.clip(t, 0, 1) * 10.0
        whole = np.floor(value)
        out[..., 0] = np.rint(whole * 0.1 * 255)
        out[..., 1] = np.rint((value - whole) * 255)
    elif encoding == "rgb8":
        b = _bytes(t)
        out[..., 0], out[..., 1], out[..., 2] = b[..., 2], b[..., 1], b[..., 0]
    elif encoding == "rgba8":
        out[:] = _bytes(t)
    else:
        raise ValueError(f"{encoding!r} has no colour packing")
    return out


def decode(rgba: np.ndarray, encoding: str) -> np.ndarray:
    """Normalised depth from stored RGBA8 texels (..., 4) uint8; float64, same leading shape."""
    c = np.asarray(rgba, np.float64)
    if encoding == "r8":
        return c[..., 0] / 255.0
    if encoding == "rg8":
        return (np.floor(c[..., 0] / 255.0 * 10.0 + 0.5) + c[..., 1] / 255.0) * 0.1
    if encoding == "rgb8":
        return c[..., 0] / 2.0**24 + c[..., 1] / 2.0**16 + c[..., 2] / 2.0**8
    if encoding == "rgba8":
        # Big-endian uint32 view of the four bytes: one pass instead of four.
        words = np.ascontiguousarray(rgba, dtype=np.uint8).view(">u4")[..., 0]
        return words / 2.0**32
    raise ValueError(f"{encoding!r} has no colour packing")


#: Rows of a map handled at once where a read-back passes over it several times (the map's
#: picture, :func:`debug_image`; its empty texels, ``light_pass.copy_marking_empty``): a block
#: stays in the CPU's caches between the passes (a 4096-texel row of float32 is 16 KiB).
ROW_BLOCK = 64


def drawn_range(t: np.ndarray) -> tuple[float, float] | None:
    """The smallest and largest depth drawn into a decoded map (None when nothing was drawn).

    Parameters
    ----------
    t : ndarray
        Decoded linear depth, NaN where nothing was drawn.
    """
    # fmin and fmax pass over NaN: two reads of the map, no mask or copy of it.
    flat = np.asarray(t).reshape(-1)
    with np.errstate(invalid="ignore"):
        finite = np.where(np.isinf(flat), np.nan, flat) if np.isinf(flat).any() else flat
    lo = np.fmin.reduce(finite, initial=np.inf)
    if not np.isfinite(lo):
        return None
    return float(lo), float(np.fmax.reduce(finite, initial=-np.inf))


def debug_image(t: np.ndarray) -> np.ndarray:
    """8-bit grayscale picture of a decoded map, stretched over the depths drawn into it: the
    nearest caster = black (0), the farthest = 254, empty = white (255).

    A map's range is fitted to every receiver its light reaches, which can be much deeper than
    the casters (a ground plane, a far wall): over the fitted range the casters would all be a
    few levels of near-black. The drawn range is :func:`drawn_range` (in units of the map's
    range, so ``near + t * (far - near)`` in scene units).

    Parameters
    ----------
    t : ndarray, shape (S, S) or (6, S, S)
        Decoded linear depth, NaN where nothing was drawn. Cube maps are laid out 3 x 2
        (+X -X +Y / -Y +Z -Z) and stretched over the drawn depths of all six faces.

    Returns
    -------
    ndarray, shape (S, S) or (2S, 3S), uint8
    """
    return stretched_image(t, drawn_range(t))


def stretched_image(t: np.ndarray, span: tuple[float, float] | None) -> np.ndarray:
    """:func:`debug_image` of ``t`` over ``span``, its :func:`drawn_range` when the caller has
    it already (None: nothing drawn)."""
    lo, hi = span if span is not None else (0.0, 1.0)
    scale = np.float32(254.0 / (hi - lo) if hi > lo else 0.0)  # one depth drawn: all black
    low = np.float32(lo)
    # A block of rows at a time through one float32 scratch block that stays in the CPU's
    # caches (a map of 4096² is 64 MiB a pass); NaN passes through the arithmetic and the clip,
    # and only then becomes white.
    flat = np.asarray(t, np.float32).reshape(-1, t.shape[-1])
    out = np.empty(flat.shape, np.uint8)
    scratch = np.empty((ROW_BLOCK, flat.shape[1]), np.float32)
    with np.errstate(invalid="ignore"):
        for r in range(0, len(flat), ROW_BLOCK):
            block = flat[r:r + ROW_BLOCK]
            v = scratch[:len(block)]
            np.subtract(block, low, out=v)
            v *= scale
            np.clip(v, 0.0, 254.0, out=v)
            np.rint(v, out=v)
            np.copyto(v, np.float32(255.0), where=np.isnan(v))
            out[r:r + ROW_BLOCK] = v
    img = out.reshape(t.shape)
    if img.ndim == 3:
        halves = [np.concatenate(list(img[r * 3 : r * 3 + 3]), axis=1) for r in range(2)]
        img = np.concatenate(halves, axis=0)
    return img
