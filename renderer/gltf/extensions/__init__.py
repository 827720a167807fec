"""glTF extensions, registered by their glTF name.

:data:`SUPPORTED` is the one list of what the loader implements: the file's
``extensionsRequired`` is checked against it (anything else is
:class:`~shadowmap.renderer.errors.UnsupportedExtension`), and unknown names in
``extensionsUsed`` are ignored with a warning in ``Scene.warnings``. Each implemented extension
with code of its own has a module here named after it: ``draco`` (KHR_draco_mesh_compression),
``meshopt`` (EXT_meshopt_compression), ``gpu_instancing``, ``texture_transform``,
``lights_punctual``, ``specular_glossiness``, ``texture_sources`` (EXT_texture_webp and
EXT_texture_avif), ``node_visibility``, ``primitive_restart``, ``accessor_float64``,
``materials_unlit``;
``KHR_mesh_quantization`` is the set of component types the accessor checks allow
(``mesh_quantization``).

:data:`IGNORED` lists extensions accepted and ignored: each only changes shading terms this
renderer does not have (its model is base colour x (ambient + visibility x (diffuse +
specular)), with its own specular term), so leaving it out cannot change geometry, alpha
cut-outs or shadows. Not among them, on purpose: ``KHR_materials_transmission`` and
``KHR_materials_volume`` (light passes through, so shadows would be lighter),
``KHR_texture_basisu`` (KTX2
textures, which no decoder here reads: the base-colour texture, hence its cut-outs, would be
lost), ``EXT_meshopt_compression``-like codecs other than the two implemented, and
``KHR_materials_pbrSpecularGlossiness`` beyond its diffuse colour (listed, partial).
"""

from __future__ import annotations

from typing import Any

from ...errors import UnsupportedExtension

#: Extensions whose content shapes what is drawn, by glTF name.
IMPLEMENTED: dict[str, str] = {
    "KHR_draco_mesh_compression": "Draco-compressed primitives, decoded at load",
    "EXT_meshopt_compression": "meshoptimizer-compressed buffer views, decoded at load",
    "KHR_mesh_quantization": "8/16-bit integer positions, normals, texture coordinates",
    "KHR_texture_transform": "offset/rotation/scale/texCoord of the base-colour texture, "
                             "applied to the primitive's UVs (it moves alpha cut-outs)",
    "EXT_mesh_gpu_instancing": "one instance per TRANSLATION/ROTATION/SCALE entry",
    "KHR_lights_punctual": "directional, point and spot lights",
    "KHR_materials_pbrSpecularGlossiness": "base colour only: diffuseFactor and diffuseTexture "
                                           "when the material has no pbrMetallicRoughness",
    "KHR_accessor_float64": "float64 accessors wherever float32 ones are allowed; float64 "
                            "positions kept relative to their primitive's centre",
    "KHR_mesh_primitive_restart": "restart values in strip and fan indices start a new strip "
                                  "or fan",
    "KHR_node_visibility": "visible: false hides a node's subtree (meshes and lights; cameras "
                           "stay)",
    "EXT_texture_webp": "WebP textures, read before the texture's plain source (its fallback)",
    "EXT_texture_avif": "AVIF textures, read before the texture's plain source (its fallback)",
    "KHR_materials_unlit": "the colour image shows the base colour as it is (no lighting, no "
                           "shadow); the surface still casts shadows and has visibility",
}

#: Extensions accepted and ignored: their absence changes no geometry, cut-out or shadow.
IGNORED: dict[str, str] = {
    "KHR_materials_emissive_strength": "ignored: emission only (the renderer draws none)",
    "KHR_materials_ior": "ignored: index of refraction of the specular layer",
    "KHR_materials_specular": "ignored: specular strength and colour (own specular term)",
    "KHR_materials_clearcoat": "ignored: a specular coat layer",
    "KHR_materials_sheen": "ignored: a cloth sheen layer",
    "KHR_materials_iridescence": "ignored: thin-film colour shift of the specular",
    "KHR_materials_anisotropy": "ignored: anisotropic specular highlights",
    "KHR_materials_dispersion": "ignored: dispersion of light refracted by transmission "
                                "(itself not drawn, and warned about)",
    "KHR_materials_variants": "ignored: alternative materials; the default mapping is drawn",
    "EXT_mesh_primitive_restart": "ignored: groups of primitives to draw as one with restart "
                                  "values; the primitives themselves are drawn",
    "KHR_animation_pointer": "ignored: animations are not played",
    "KHR_xmp_json_ld": "ignored: metadata",
    "EXT_mesh_features": "ignored: feature IDs of vertices and texels (metadata)",
    "EXT_structural_metadata": "ignored: properties attached to features (metadata)",
}

#: Everything the loader accepts, by glTF name, with a one-line description.
SUPPORTED: dict[str, str] = {**IMPLEMENTED, **IGNORED}


def check_extensions(doc: dict[str, Any]) -> list[str]:
    """Check the document's extension lists against :data:`SUPPORTED`.

    Returns
    -------
    list of str
        A warning for each optional extension in ``extensionsUsed`` that is not supported.

    Raises
    ------
    UnsupportedExtension
        A name in ``extensionsRequired`` is not in :data:`SUPPORTED`.
    """
    required = _names(doc, "extensionsRequired")
    missing = [name for name in required if name not in SUPPORTED]
    if missing:
        raise UnsupportedExtension(missing)
    warnings = []
    for name in _names(doc, "extensionsUsed"):
        if name not in SUPPORTED:
            warnings.append(f"ignored optional extension {name}")
    return warnings


def uses(doc: dict[str, Any], name: str) -> bool:
    """Whether the document lists extension ``name`` in ``extensionsUsed`` (for extensions that
    apply to the whole document: KHR_mesh_primitive_restart, KHR_accessor_float64)."""
    return name in _names(doc, "extensionsUsed")


def _names(doc: dict[str, Any], key: str) -> list[str]:
    value = doc.get(key, [])
    if not isinstance(value, list):
        return []
    out: list[str] = []
    for name in value:
        if isinstance(name, str) and name not in out:
            out.append(name)
    return out
