"""``KHR_materials_unlit``: a material drawn in its base colour, without lighting.

Such a surface's lighting is already in its colour (a photogrammetry scan, baked light), so the
colour image shows its base colour (factor times texture, times vertex colours) as it is: no
ambient, no diffuse or specular term, and no shadow, which is part of lighting; drawing one
over baked light would darken it twice. The surface is still geometry: it casts shadows, cuts
out by alpha, and the ``visibility`` output still gives the shadow each light casts on it.
"""

from __future__ import annotations

from typing import Any

from ..reader import extension

EXTENSION = "KHR_materials_unlit"


def unlit(material: dict[str, Any]) -> bool:
    """Whether a glTF material object carries the extension (its object is empty by design)."""
    return extension(material, EXTENSION) is not None
