"""``KHR_materials_pbrSpecularGlossiness``: its diffuse colour and texture stand in for the base
colour when a material has no ``pbrMetallicRoughness`` (specular and glossiness are not used:
the renderer has its own specular term)."""

from __future__ import annotations

from typing import Any

from ..reader import extension

EXTENSION = "KHR_materials_pbrSpecularGlossiness"


def base_colour(material: dict[str, Any]) -> tuple[Any, Any] | None:
    """(diffuseFactor, diffuseTexture) of the extension, as raw JSON, or None without it."""
    ext = extension(material, EXTENSION)
    if ext is None:
        return None
    return ext.get("diffuseFactor"), ext.get("diffuseTexture")
