"""``EXT_meshopt_compression``: one compressed bufferView back to its plain bytes.

The codecs (attributes, triangles, indices) and the filters (octahedral, quaternion, exponential)
are meshoptimizer's own C++ decoders, through the ``meshopt`` package (a binding of meshoptimizer's
encoder and decoder shaped like its JavaScript module, ``decode_gltf_buffer``). The checks here are
the extension's validity rules, so that a bad file is a :class:`SceneError` naming the extension
and not a crash or an odd result.

Spec: https://github.com/KhronosGroup/glTF/tree/main/extensions/2.0/Vendor/EXT_meshopt_compression
"""

from __future__ import annotations

import numpy as np

from ...errors import SceneError

EXTENSION = "EXT_meshopt_compression"
MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
FILTERS = ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL")

# Most output bytes one input byte can stand for, per mode: in the attribute codec a block of at
# most 256 elements costs at least stride / 4 bytes (version 1's control bytes; version 0 needs
# more), a triangle at least its one code byte, an index at least one varint byte. Larger claims
# cannot come from a valid stream, and are refused before any memory is set aside for them.
_ATTRIBUTE_RATIO = 1024


def decode_buffer_view(
    source: bytes, count: int, byte_stride: int, mode: str, filter: str | None
) -> bytes:
    """Decompress one ``EXT_meshopt_compression`` bufferView.

    Parameters
    ----------
    source : bytes
        The compressed bytes: the extension's ``byteLength`` bytes at its ``byteOffset`` in its
        ``buffer``.
    count : int
        The extension's ``count``: elements (``ATTRIBUTES``) or indices (``TRIANGLES``,
        ``INDICES``).
    byte_stride : int
        The extension's ``byteStride``: bytes per element (a multiple of 4, at most 256) or per
        index (2 or 4).
    mode : str
        ``"ATTRIBUTES"``, ``"TRIANGLES"`` or ``"INDICES"``.
    filter : str or None
        ``None`` or ``"NONE"``, or (``ATTRIBUTES`` only) ``"OCTAHEDRAL"`` (stride 4 or 8),
        ``"QUATERNION"`` (stride 8) or ``"EXPONENTIAL"``.

    Returns
    -------
    bytes
        Exactly ``count * byte_stride`` bytes, the filter applied: the data as the accessors of
        the parent bufferView read it (indices little-endian).

    Raises
    ------
    SceneError
        The parameters break the extension's rules, the data is corrupt or too short, or the
        ``meshopt`` package is not installed.
    """
    name = "NONE" if filter is None else filter
    _check(source, count, byte_stride, mode, name)
    try:
        import meshopt
    except ImportError as exc:
        raise SceneError(f"{EXTENSION}: decoding needs the meshopt package") from exc

    size = count * byte_stride
    if count == 0:
        return b""
    try:
        decoded = meshopt.decode_gltf_buffer(
            bytes(source), count, byte_stride, mode, None if name == "NONE" else name
        )
    except (ValueError, RuntimeError, MemoryError) as exc:
        raise SceneError(
            f"{EXTENSION}: the {mode} data ({len(source)} bytes for {count} x {byte_stride}) "
            f"is corrupt: {exc}"
        ) from exc
    array = np.ascontiguousarray(decoded)
    if array.dtype.itemsize > 1:
        array = array.astype(array.dtype.newbyteorder("<"), copy=False)
    out = array.tobytes()
    if len(out) != size:
        raise SceneError(
            f"{EXTENSION}: the {mode} decoder gave {len(out)} bytes, not {count} x {byte_stride}"
        )
    return out


def _check(source: bytes, count: int, byte_stride: int, mode: str, name: str) -> None:
    """Raise :class:`SceneError` unless the arguments obey the extension's rules."""
    for label, value in (("count", count), ("byteStride", byte_stride)):
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise SceneError(f"{EXTENSION}: {label} must be a non-negative integer, not {value!r}")
    if mode not in MODES:
        raise SceneError(f"{EXTENSION}: unknown mode {mode!r} (one of {', '.join(MODES)})")
    if name not in FILTERS:
        raise SceneError(f"{EXTENSION}: unknown filter {name!r} (one of {', '.join(FILTERS)})")
    if mode == "ATTRIBUTES":
        if byte_stride == 0 or byte_stride % 4 or byte_stride > 256:
            raise SceneError(
                f"{EXTENSION}: ATTRIBUTES needs a byteStride that is a multiple of 4 up to 256, "
                f"not {byte_stride}"
            )
        if name == "OCTAHEDRAL" and byte_stride not in (4, 8):
            raise SceneError(f"{EXTENSION}: OCTAHEDRAL needs byteStride 4 or 8, not {byte_stride}")
        if name == "QUATERNION" and byte_stride != 8:
            raise SceneError(f"{EXTENSION}: QUATERNION needs byteStride 8, not {byte_stride}")
        limit = _ATTRIBUTE_RATIO * len(source)
        fits = count * byte_stride <= limit
    else:
        if byte_stride not in (2, 4):
            raise SceneError(f"{EXTENSION}: {mode} needs byteStride 2 or 4, not {byte_stride}")
        if name != "NONE":
            raise SceneError(f"{EXTENSION}: {mode} data cannot have filter {name}")
        if mode == "TRIANGLES" and count % 3:
            raise SceneError(f"{EXTENSION}: TRIANGLES needs a count divisible by 3, not {count}")
        fits = count <= (3 * len(source) if mode == "TRIANGLES" else len(source))
    if not fits:
        raise SceneError(
            f"{EXTENSION}: {len(source)} bytes of {mode} data cannot hold {count} x {byte_stride}"
        )
