"""``KHR_mesh_primitive_restart``: restart values cut a primitive's strips and fans.

glTF forbids an index buffer from holding its type's largest value (0xFF, 0xFFFF, 0xFFFFFFFF),
which graphics APIs read as "end this strip, start another". A document that lists this
extension lifts that rule for strips, fans, line strips and loops: a ``TRIANGLE_STRIP`` or
``TRIANGLE_FAN`` primitive is then several strips or fans in one index buffer, each triangulated
on its own (:func:`~..primitives.triangulate`). Triangle lists still may not hold the value.
"""

from __future__ import annotations

EXTENSION = "KHR_mesh_primitive_restart"
