"""Accessors decoded with numpy: every component type, normalized integers, interleaved views,
matrix column padding, sparse substitution, and bounds checks.

An accessor is read once and kept (read-only), so a mesh used by many nodes is decoded once.
Which component types an attribute may use (``KHR_mesh_quantization`` widens them) is checked by
:func:`check_type`, with the caller's name for the attribute in the message.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import SceneError, UnsupportedExtension
from .extensions import accessor_float64, uses
from .reader import Buffers, brief, get_index, get_int, get_list

BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT, UNSIGNED_INT, FLOAT = 5120, 5121, 5122, 5123, 5125, 5126
#: KHR_accessor_float64's float64 component type (only in documents that declare it).
DOUBLE = accessor_float64.DOUBLE

#: componentType -> little-endian numpy dtype.
COMPONENT_DTYPES: dict[int, np.dtype[Any]] = {
    BYTE: np.dtype("<i1"),
    UNSIGNED_BYTE: np.dtype("<u1"),
    SHORT: np.dtype("<i2"),
    UNSIGNED_SHORT: np.dtype("<u2"),
    UNSIGNED_INT: np.dtype("<u4"),
    FLOAT: np.dtype("<f4"),
    DOUBLE: np.dtype("<f8"),
}
COMPONENT_NAMES = {BYTE: "BYTE", UNSIGNED_BYTE: "UNSIGNED_BYTE", SHORT: "SHORT",
                   UNSIGNED_SHORT: "UNSIGNED_SHORT", UNSIGNED_INT: "UNSIGNED_INT", FLOAT: "FLOAT",
                   DOUBLE: "DOUBLE"}
#: type -> (rows, columns): vectors are columns of one, matrices square.
TYPE_SHAPES = {"SCALAR": (1, 1), "VEC2": (2, 1), "VEC3": (3, 1), "VEC4": (4, 1),
               "MAT2": (2, 2), "MAT3": (3, 3), "MAT4": (4, 4)}
#: Largest accessor without a bufferView (zeros plus sparse values) this loader allocates, in
#: bytes: a few bytes of JSON must not claim gigabytes.
MAX_ACCESSOR_BYTES = 256 * 2**20

# Component sets by use, as (componentType, normalized) pairs. Float64 goes wherever float32
# does (KHR_accessor_float64; Accessors.info refuses it in documents that do not declare it).
FLOAT_ONLY = frozenset({(FLOAT, False), (DOUBLE, False)})
NORMALIZED_INTS = frozenset({(t, True) for t in (BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT)})
PLAIN_INTS = frozenset({(t, False) for t in (BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT)})
#: Every float or 8/16-bit integer form (KHR_mesh_quantization's widest sets).
QUANTIZED = FLOAT_ONLY | NORMALIZED_INTS | PLAIN_INTS


@dataclass(frozen=True)
class AccessorInfo:
    """The declared shape of one accessor (read from JSON only, no data touched).

    Attributes
    ----------
    index : int
    component_type : int
    type : str
        ``SCALAR``, ``VEC2`` ... ``MAT4``.
    count : int
    normalized : bool
    """

    index: int
    component_type: int
    type: str
    count: int
    normalized: bool

    @property
    def dtype(self) -> np.dtype[Any]:
        return COMPONENT_DTYPES[self.component_type]

    @property
    def components(self) -> int:
        rows, cols = TYPE_SHAPES[self.type]
        return rows * cols

    def describe(self) -> str:
        norm = " normalized" if self.normalized else ""
        return f"{self.type} {COMPONENT_NAMES[self.component_type]}{norm}"


def normalize(values: np.ndarray) -> np.ndarray:
    """Integer components as the floats a normalized accessor means (glTF 2.0 3.11).

    Signed types map to [-1, 1] with ``max(c / MAX, -1)``, unsigned to [0, 1].

    Parameters
    ----------
    values : ndarray of int8, uint8, int16, uint16 or uint32

    Returns
    -------
    ndarray of float32, same shape
    """
    info = np.iinfo(values.dtype)
    out = values.astype(np.float32) / np.float32(info.max)
    if info.min < 0:
        np.maximum(out, -1.0, out=out)
    return out


def check_type(info: AccessorInfo, types: Collection[str],
               components: Collection[tuple[int, bool]], what: str) -> str | None:
    """Why ``info`` cannot be used as ``what``, or None when it can.

    Parameters
    ----------
    types : collection of str
        Allowed accessor types.
    components : collection of (componentType, normalized)
        Allowed component forms.
    """
    if info.type not in types or (info.component_type, info.normalized) not in components:
        return (f"{what} is accessor {info.index} of type {info.describe()}, which is not "
                f"allowed (allowed: {'/'.join(sorted(types))})")
    return None


class Accessors:
    """Reads a document's accessors into numpy arrays, each once.

    Parameters
    ----------
    buffers : Buffers
    """

    def __init__(self, buffers: Buffers) -> None:
        self.buffers = buffers
        self.specs = get_list(buffers.doc, "accessors")
        self._cache: dict[int, np.ndarray] = {}
        self.float64 = uses(buffers.doc, accessor_float64.EXTENSION)

    def __len__(self) -> int:
        return len(self.specs)

    def info(self, index: int) -> AccessorInfo:
        """The declared type of accessor ``index``; SceneError when malformed."""
        what = f"accessor {index}"
        if not 0 <= index < len(self.specs) or not isinstance(self.specs[index], dict):
            raise SceneError(f"{what} does not exist")
        spec = self.specs[index]
        ctype = spec.get("componentType")
        if not isinstance(ctype, int) or ctype not in COMPONENT_DTYPES:
            raise SceneError(f"{what}: componentType {ctype!r} is not a glTF 2.0 component type")
        if ctype == DOUBLE and not self.float64:
            raise SceneError(f"{what}: componentType {DOUBLE} (DOUBLE) needs "
                             f"{accessor_float64.EXTENSION}, which the file does not declare")
        kind = spec.get("type")
        if not isinstance(kind, str) or kind not in TYPE_SHAPES:
            raise SceneError(f"{what}: type {kind!r} is not a glTF 2.0 accessor type")
        count = get_int(spec, "count", what, minimum=1)
        normalized = spec.get("normalized", False)
        if not isinstance(normalized, bool):
            raise SceneError(f"{what}: normalized must be true or false, not "
                             f"{brief(normalized)}")
        if normalized and ctype in (FLOAT, DOUBLE, UNSIGNED_INT):
            raise SceneError(f"{what}: normalized must be false for {COMPONENT_NAMES[ctype]}")
        return AccessorInfo(index, ctype, kind, count, normalized)

    def count(self, index: int) -> int:
        """The declared element count (JSON only)."""
        return self.info(index).count

    def read(self, index: int) -> np.ndarray:
        """The elements of accessor ``index``.

        Returns
        -------
        ndarray, read-only
            Shape (count,) for SCALAR, (count, n) for VECn, (count, n, n) for MATn (rows,
            columns: glTF stores columns first, this is the usual row-major matrix). Dtype: the
            component type's, or float32 when ``normalized``.

        Raises
        ------
        SceneError
            Reading past the end of the view or buffer, a byteStride shorter than an element,
            bad sparse indices, or an accessor too large to allocate.
        """
        cached = self._cache.get(index)
        if cached is not None:
            return cached
        info = self.info(index)
        spec = self.specs[index]
        values = self._dense(info, spec)
        if "sparse" in spec:
            values = self._sparse(info, spec["sparse"], values)
        rows, cols = TYPE_SHAPES[info.type]
        if cols > 1:
            # (count, columns, rows) in memory order -> (count, rows, columns)
            values = values.reshape(info.count, cols, rows).transpose(0, 2, 1)
        elif rows == 1:
            values = values.reshape(info.count)
        if info.normalized:
            values = normalize(values)
        values = np.ascontiguousarray(values)
        values.flags.writeable = False
        self._cache[index] = values
        return values

    def read_float(self, index: int) -> np.ndarray:
        """:meth:`read` as float64 (non-normalized integers keep their integer values).

        Signalling NaNs come out quiet (without numpy's cast warning): what a NaN costs is
        decided, and said, by the attribute's reader."""
        with np.errstate(invalid="ignore"):
            return self.read(index).astype(np.float64)

    # -- internals -------------------------------------------------------------------------

    @staticmethod
    def _layout(info: AccessorInfo) -> tuple[int, int, int]:
        """(element size in bytes, column stride, rows): matrix columns start on 4-byte
        boundaries (glTF 2.0 3.6.2.4), so MAT2 of bytes and MAT3 of bytes/shorts are padded."""
        rows, cols = TYPE_SHAPES[info.type]
        size = info.dtype.itemsize
        col = rows * size
        if cols > 1:
            col += -col % 4
        return col * cols, col, rows

    def _strided(self, info: AccessorInfo, data: bytes, offset: int, stride: int,
                 count: int) -> np.ndarray:
        """``count`` elements from ``data`` at ``offset`` every ``stride`` bytes, as a copy of
        shape (count, columns * rows) in memory order."""
        elem, col, rows = self._layout(info)
        cols = TYPE_SHAPES[info.type][1]
        itemsize = info.dtype.itemsize
        arr = np.ndarray(shape=(count, cols, rows), dtype=info.dtype, buffer=data, offset=offset,
                         strides=(stride, col, itemsize))
        return arr.reshape(count, cols * rows).copy()

    def _view_bytes(self, view_index: int, what: str) -> bytes:
        """The view's bytes, with errors about the view or its buffer naming the accessor."""
        try:
            return self.buffers.view(view_index)
        except UnsupportedExtension:
            raise
        except SceneError as exc:
            raise SceneError(f"{what}: {exc}") from None

    def _dense(self, info: AccessorInfo, spec: dict[str, Any]) -> np.ndarray:
        what = f"accessor {info.index}"
        elem, _, _ = self._layout(info)
        view_index = get_index(spec, "bufferView", len(self.buffers.views), what)
        if view_index is None:
            # No data: zeros, to be filled by sparse substitution (glTF 2.0 3.6.2.3).
            if info.count * elem > MAX_ACCESSOR_BYTES:
                raise SceneError(f"{what}: {info.count} elements is too large to allocate")
            return np.zeros((info.count, info.components), info.dtype)
        view = self.buffers.view_spec(view_index, what)
        offset = get_int(spec, "byteOffset", what, default=0)
        stride = elem
        if "byteStride" in view:
            stride = get_int(view, "byteStride", f"bufferView {view_index}", minimum=1)
            if stride < elem:
                raise SceneError(f"{what}: bufferView {view_index} has byteStride {stride}, "
                                 f"shorter than one {info.describe()} element ({elem} bytes)")
        length = get_int(view, "byteLength", f"bufferView {view_index}", minimum=1)
        need = offset + stride * (info.count - 1) + elem
        if need > length:
            raise SceneError(f"{what} reads past the end of bufferView {view_index}: it needs "
                             f"{need} bytes (byteOffset {offset}, {info.count} x stride "
                             f"{stride}), the view has {length}")
        data = self._view_bytes(view_index, what)
        if need > len(data):  # a decoder that returned less than the view declares
            raise SceneError(f"{what} reads past the end of the data of bufferView {view_index}"
                             f" ({need} > {len(data)} bytes)")
        return self._strided(info, data, offset, stride, info.count)

    def _sparse(self, info: AccessorInfo, sparse: Any, values: np.ndarray) -> np.ndarray:
        """Substitute the sparse elements into ``values`` (shape (count, n))."""
        what = f"accessor {info.index} sparse"
        if not isinstance(sparse, dict):
            raise SceneError(f"{what}: not an object")
        n = get_int(sparse, "count", what, minimum=1)
        if n > info.count:
            raise SceneError(f"{what}: count {n} exceeds the accessor's count {info.count}")
        idx_spec, val_spec = sparse.get("indices"), sparse.get("values")
        if not isinstance(idx_spec, dict) or not isinstance(val_spec, dict):
            raise SceneError(f"{what}: 'indices' and 'values' must be objects")
        ictype = idx_spec.get("componentType")
        if not isinstance(ictype, int) or ictype not in (UNSIGNED_BYTE, UNSIGNED_SHORT,
                                                          UNSIGNED_INT):
            raise SceneError(f"{what}: indices componentType {ictype!r} is not an unsigned "
                             "integer type")
        idx_info = AccessorInfo(info.index, ictype, "SCALAR", n, False)
        indices = self._tight(idx_info, idx_spec, f"{what} indices").reshape(n).astype(np.int64)
        vals = self._tight(AccessorInfo(info.index, info.component_type, info.type, n, False),
                           val_spec, f"{what} values")
        if indices.size and (indices.max() >= info.count):
            raise SceneError(f"{what}: index {int(indices.max())} is outside the accessor's "
                             f"{info.count} elements")
        out = values.copy() if not values.flags.writeable else values
        out[indices] = vals
        return out

    def _tight(self, info: AccessorInfo, spec: dict[str, Any], what: str) -> np.ndarray:
        """Tightly packed elements of a sparse ``indices`` or ``values`` block."""
        view_index = get_index(spec, "bufferView", len(self.buffers.views), what, required=True)
        assert view_index is not None
        offset = get_int(spec, "byteOffset", what, default=0)
        elem, _, _ = self._layout(info)
        view = self.buffers.view_spec(view_index, what)
        length = get_int(view, "byteLength", f"bufferView {view_index}", minimum=1)
        need = offset + elem * info.count
        if need > length:
            raise SceneError(f"{what} reads past the end of bufferView {view_index}: it needs "
                             f"{need} bytes, the view has {length}")
        data = self._view_bytes(view_index, what)
        if need > len(data):
            raise SceneError(f"{what} reads past the end of the data of bufferView {view_index}")
        return self._strided(info, data, offset, elem, info.count)
