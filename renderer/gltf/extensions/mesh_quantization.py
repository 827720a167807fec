"""``KHR_mesh_quantization``: the component types vertex attributes may use.

Without the extension glTF requires float positions and normals; with it, positions may be
8/16-bit integers (normalized or not), normals normalized 8/16-bit signed integers, texture
coordinates any 8/16-bit form. The loader accepts these forms whether or not the file declares
the extension (the data means the same), so a file that forgets to declare it still loads.
"""

from __future__ import annotations

from ..accessors import (
    BYTE,
    FLOAT_ONLY,
    NORMALIZED_INTS,
    QUANTIZED,
    SHORT,
    UNSIGNED_BYTE,
    UNSIGNED_SHORT,
)

EXTENSION = "KHR_mesh_quantization"

POSITION = QUANTIZED
NORMAL = FLOAT_ONLY | {(BYTE, True), (SHORT, True)}
TEXCOORD = QUANTIZED
COLOR = FLOAT_ONLY | {(UNSIGNED_BYTE, True), (UNSIGNED_SHORT, True)}
JOINTS = frozenset({(UNSIGNED_BYTE, False), (UNSIGNED_SHORT, False)})
WEIGHTS = FLOAT_ONLY | {(UNSIGNED_BYTE, True), (UNSIGNED_SHORT, True)}
#: Morph-target displacements (POSITION, NORMAL): floats or normalized/plain 8/16-bit integers.
TARGET = QUANTIZED
__all__ = ["COLOR", "JOINTS", "NORMAL", "NORMALIZED_INTS", "POSITION", "TARGET", "TEXCOORD",
           "WEIGHTS"]
