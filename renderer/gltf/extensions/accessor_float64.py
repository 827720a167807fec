"""``KHR_accessor_float64``: accessors of IEEE-754 binary64 (``DOUBLE``, componentType 5130).

A document that lists the extension may use float64 accessors wherever glTF allows float32 ones
(positions, normals, texture coordinates, colours, weights, skin matrices, instance transforms);
the reader reads them as float64 (every attribute is float64 until it is uploaded). The point
of such a file is precision far from its origin (geographic coordinates): a primitive whose
positions are float64 is stored relative to the centre of its box, in float32, and the centre
moves into its instances' float64 matrices (see ``loader``), as the ground plane is placed, so
nothing of float64's precision is lost before the renderer's own origin-relative float32.
Without the declaration, componentType 5130 is refused (glTF 2.0 does not have it).
"""

from __future__ import annotations

EXTENSION = "KHR_accessor_float64"
#: componentType of float64 accessors.
DOUBLE = 5130
