"""``KHR_draco_mesh_compression``: one primitive's Draco stream to glTF vertex arrays.

The decoding itself is DracoPy's (Google's Draco decoder). Draco's decoder undoes the stream's
attribute transforms, so quantized positions, texture coordinates and the like come back as the
real values (DracoPy then reads every point of a float attribute with ``ConvertValue<float>``);
nothing here multiplies by a quantization range again. Integer attributes (``COLOR_n`` or
``WEIGHTS_n`` stored as normalized bytes or shorts, ``JOINTS_n``) come back as their integers and
are normalized or narrowed here, per the attribute's Draco data type.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import SceneError

EXTENSION = "KHR_draco_mesh_compression"

# Draco's DataType values (draco/core/draco_types.h), as DracoPy reports them.
_DT_UINT8 = 2
_DT_UINT16 = 4
_DT_UINT32 = 6
_UNSIGNED_MAX = {_DT_UINT8: 255.0, _DT_UINT16: 65535.0, _DT_UINT32: 4294967295.0}

# Components a glTF semantic must have, by its prefix (``TEXCOORD_0`` -> ``TEXCOORD``).
_COMPONENTS: dict[str, tuple[int, ...]] = {
    "POSITION": (3,),
    "NORMAL": (3,),
    "TANGENT": (4,),
    "TEXCOORD": (2,),
    "COLOR": (3, 4),
    "JOINTS": (4,),
    "WEIGHTS": (4,),
}


def decode_primitive(data: bytes, attributes: dict[str, int]) -> dict[str, np.ndarray]:
    """Decode the Draco stream of one glTF primitive.

    Parameters
    ----------
    data : bytes
        The bytes of the extension's ``bufferView``.
    attributes : dict of str to int
        The extension's ``attributes``: glTF semantic (``"POSITION"``, ``"TEXCOORD_0"``, ...) to
        the Draco attribute's unique id.

    Returns
    -------
    dict of str to numpy.ndarray
        One C-contiguous array per semantic of ``attributes``, all with the stream's N points:
        ``POSITION`` and ``NORMAL`` (N, 3) float32, ``TANGENT`` (N, 4) float32, ``TEXCOORD_n``
        (N, 2) float32 as glTF stores them (not flipped), ``COLOR_n`` (N, 3) or (N, 4) float32 in
        [0, 1], ``JOINTS_n`` (N, 4) uint16, ``WEIGHTS_n`` (N, 4) float32; any other semantic
        (``_CUSTOM``) as decoded, float32 or the stream's unsigned integer type, (N, K). Plus
        ``"indices"``: the triangle list, (F * 3,) uint32, every index below N.

    Raises
    ------
    SceneError
        DracoPy is not installed, the data is not a Draco stream or is corrupt, the stream is a
        point cloud, an id of ``attributes`` is not in the stream, or an attribute does not have
        the components its semantic needs.
    """
    try:
        import DracoPy
    except ImportError as exc:
        raise SceneError(f"{EXTENSION}: decoding Draco needs the DracoPy package") from exc

    if not isinstance(attributes, dict):
        raise SceneError(f"{EXTENSION}: 'attributes' must be an object")
    for semantic, uid in attributes.items():
        if not isinstance(semantic, str) or not isinstance(uid, int) or isinstance(uid, bool):
            raise SceneError(
                f"{EXTENSION}: attribute {semantic!r} must map to an integer id, not {uid!r}"
            )
    if "indices" in attributes:
        raise SceneError(f"{EXTENSION}: 'indices' is not a vertex attribute")

    try:
        geometry = DracoPy.decode(bytes(data))
    except (DracoPy.FileTypeException, TypeError, ValueError, RuntimeError, MemoryError) as exc:
        raise SceneError(
            f"{EXTENSION}: the Draco stream ({len(data)} bytes) could not be decoded: {exc}"
        ) from exc
    if not isinstance(geometry, DracoPy.DracoMesh):
        raise SceneError(
            f"{EXTENSION}: the Draco stream is a point cloud (no triangles); a mesh is needed"
        )

    by_id: dict[int, dict[str, Any]] = {}
    for attribute in geometry.attributes:
        by_id.setdefault(int(attribute["unique_id"]), attribute)

    out: dict[str, np.ndarray] = {}
    count: int | None = None
    for semantic, uid in attributes.items():
        attribute = by_id.get(uid)
        if attribute is None:
            raise SceneError(
                f"{EXTENSION}: attribute {semantic} names Draco attribute id {uid}, which the "
                f"stream does not have (its ids: {sorted(by_id)})"
            )
        array = _convert(semantic, attribute)
        if count is None:
            count = len(array)
        elif len(array) != count:
            raise SceneError(
                f"{EXTENSION}: attribute {semantic} has {len(array)} values, others have {count}"
            )
        out[semantic] = array

    if count is None:
        # No attribute asked for: the stream's own point count bounds the indices.
        count = max((_rows(a) for a in geometry.attributes), default=0)
    faces = np.asarray(geometry.faces)
    if faces.size and (faces.ndim != 2 or faces.shape[1] != 3):
        raise SceneError(f"{EXTENSION}: the Draco faces are not triangles")
    indices = np.ascontiguousarray(faces.reshape(-1), dtype=np.uint32)
    if indices.size and int(indices.max()) >= count:
        raise SceneError(
            f"{EXTENSION}: the Draco stream is corrupt: a triangle index {int(indices.max())} is "
            f"past its {count} points"
        )
    out["indices"] = indices
    return out


def _rows(attribute: dict[str, Any]) -> int:
    """How many points an attribute of DracoPy's holds."""
    data = attribute.get("data")
    return 0 if data is None else len(data)


def _convert(semantic: str, attribute: dict[str, Any]) -> np.ndarray:
    """One decoded Draco attribute as the array its glTF semantic uses.

    Parameters
    ----------
    semantic : str
        The glTF semantic, e.g. ``"COLOR_0"``.
    attribute : dict
        DracoPy's attribute: ``data`` (float32, uint8, or uint32 for 16 and 32-bit integers),
        ``data_type`` (Draco's) and ``num_components``.

    Returns
    -------
    numpy.ndarray
        (N, K), C-contiguous, typed as :func:`decode_primitive` says.
    """
    components = int(attribute.get("num_components") or 0)
    data = attribute.get("data")
    raw = np.zeros((0, components), np.float32) if data is None else np.asarray(data)
    if raw.ndim != 2:
        raw = raw.reshape(-1, max(components, 1))
    data_type = int(attribute.get("data_type") or 0)
    floating = raw.dtype.kind == "f"

    kind = semantic.split("_", 1)[0] if semantic[:1] != "_" else semantic
    allowed = _COMPONENTS.get(kind)
    if allowed is not None and raw.shape[1] not in allowed:
        need = " or ".join(str(n) for n in allowed)
        raise SceneError(
            f"{EXTENSION}: attribute {semantic} has {raw.shape[1]} components, not {need}"
        )

    if kind == "JOINTS":
        if floating:
            if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
                raise SceneError(f"{EXTENSION}: attribute {semantic} holds non-integer joints")
        if raw.size and (raw.min() < 0 or raw.max() > 65535):
            raise SceneError(f"{EXTENSION}: attribute {semantic} has a joint index past 65535")
        return np.ascontiguousarray(raw, dtype=np.uint16)
    if kind in ("COLOR", "WEIGHTS", "TEXCOORD"):
        # glTF stores these as floats or as normalized unsigned bytes / shorts.
        if floating:
            return np.ascontiguousarray(raw, dtype=np.float32)
        scale = _UNSIGNED_MAX.get(data_type, float(np.iinfo(raw.dtype).max))
        return np.ascontiguousarray(raw.astype(np.float64) / scale, dtype=np.float32)
    if allowed is not None:
        # POSITION, NORMAL, TANGENT: floats (integers, where quantized by the glTF exporter and
        # not by Draco, keep their integer values as floats).
        return np.ascontiguousarray(raw, dtype=np.float32)
    # Application-specific attributes: as decoded, 16-bit integers back in 16 bits.
    if not floating and data_type == _DT_UINT16:
        return np.ascontiguousarray(raw, dtype=np.uint16)
    return np.ascontiguousarray(raw)
