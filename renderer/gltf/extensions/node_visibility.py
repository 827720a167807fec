"""``KHR_node_visibility``: a node's ``visible: false`` hides it and everything below it.

A hidden node's mesh is not drawn (so it casts no shadow either) and its ``KHR_lights_punctual``
light does not shine; its camera is still a camera (the extension leaves cameras alone). A
``false`` hides the whole subtree, whatever the nodes below it say.
"""

from __future__ import annotations

from typing import Any

from ..reader import brief, extension

EXTENSION = "KHR_node_visibility"


def hides(node: dict[str, Any], warnings: list[str], what: str) -> bool:
    """Whether the node says ``visible: false`` (a value that is not a boolean is warned about
    and read as the default, visible)."""
    ext = extension(node, EXTENSION)
    if ext is None or "visible" not in ext:
        return False
    value = ext["visible"]
    if not isinstance(value, bool):
        warnings.append(f"{what}: {EXTENSION} visible {brief(value)} is not a boolean: the node "
                        "is drawn")
        return False
    return not value


def only_extension(extensions: Any) -> bool:
    """Whether a node's ``extensions`` object holds this extension and nothing else (such a
    node needs no per-node work beyond its visibility)."""
    return isinstance(extensions, dict) and set(extensions) == {EXTENSION}
