"""``EXT_texture_webp`` and ``EXT_texture_avif``: a texture's image in WebP or AVIF.

A texture that uses one names its image in the extension (``extensions.EXT_texture_webp.source``)
and may keep a PNG or JPEG in its plain ``source`` as a fallback for readers without it; tools
that make the extension required (gltf-transform's ``webp`` and ``avif`` commands) leave the
fallback out. Both formats are decoded by PIL here (:data:`~..materials.IMAGE_FORMATS`), so the
extension's image is read first and the plain source is the fallback: the loader tries each in
turn and uses the first that decodes.
"""

from __future__ import annotations

from typing import Any

from ..reader import extension

#: The texture-source extensions read, in the order their images are tried.
EXTENSIONS = ("EXT_texture_avif", "EXT_texture_webp")


def candidates(texture: dict[str, Any]) -> list[tuple[Any, str]]:
    """The image indices a texture names, in the order to try them, each with what named it.

    Parameters
    ----------
    texture : dict
        A glTF ``textures`` entry.

    Returns
    -------
    list of (index, str)
        Each extension's ``source`` (as written: the caller checks it is an image index), then
        the plain ``source``; ``("source", ...)`` or the extension's name says where it came
        from. Empty when the texture names no image.
    """
    out: list[tuple[Any, str]] = []
    for name in EXTENSIONS:
        ext = extension(texture, name)
        if ext is not None and "source" in ext:
            out.append((ext["source"], name))
    if "source" in texture:
        out.append((texture["source"], "source"))
    return out
