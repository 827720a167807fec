"""Write the example scenes of this folder from the built-in demo scene.

    python examples/make_models.py [FOLDER]     # default: the folder of this file

- ``demo.glb``: the demo scene (``shadowmap.renderer.demo.demo_glb``, what ``GET /demo.glb``
  serves and what ``POST /render`` draws without a scene): a box, a sphere and a pole on its
  own floor, a 6 x 0.1 x 6 slab;
- ``objects.glb``: the same three objects without the floor, for ``--ground``/``"ground": true``;
- ``demo_gltf/demo.gltf`` and ``demo_gltf/demo.bin``: ``demo.glb`` as a ``.gltf`` whose buffer is
  an external file, the layout that is uploaded as a zip.

The scenes are made by this project (MIT, like the code); nothing here comes from elsewhere.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path


def split_glb(glb: bytes) -> tuple[dict, bytes]:
    """The JSON and the binary chunk of a GLB file."""
    magic, version, length = struct.unpack_from("<4sII", glb, 0)
    if magic != b"glTF" or version != 2 or length != len(glb):
        raise ValueError("not a glTF 2.0 binary file")
    chunks, offset = {}, 12
    while offset < length:
        size, kind = struct.unpack_from("<I4s", glb, offset)
        chunks[kind] = glb[offset + 8:offset + 8 + size]
        offset += 8 + size
    return json.loads(chunks[b"JSON"]), chunks.get(b"BIN\x00", b"")


def join_glb(gltf: dict, binary: bytes) -> bytes:
    """A GLB file of a glTF JSON document and its binary chunk."""
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary),
                                                                          b"BIN\x00") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def without_node(glb: bytes, name: str) -> bytes:
    """``glb`` with the node called ``name`` taken out of its scenes (its mesh is left unused)."""
    gltf, binary = split_glb(glb)
    index = next(i for i, node in enumerate(gltf["nodes"]) if node.get("name") == name)
    for holder in gltf.get("scenes", []) + gltf["nodes"]:
        for key in ("nodes", "children"):
            if index in holder.get(key, []):
                holder[key] = [i for i in holder[key] if i != index]
    return join_glb(gltf, binary)


def main(folder: Path) -> None:
    from shadowmap.renderer.demo import demo_glb

    glb = demo_glb()
    (folder / "demo.glb").write_bytes(glb)
    (folder / "objects.glb").write_bytes(without_node(glb, "ground"))
    gltf, binary = split_glb(glb)
    gltf["buffers"] = [{"uri": "demo.bin", "byteLength": len(binary)}]
    (folder / "demo_gltf").mkdir(exist_ok=True)
    (folder / "demo_gltf" / "demo.gltf").write_text(json.dumps(gltf, indent=1) + "\n")
    (folder / "demo_gltf" / "demo.bin").write_bytes(binary)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)
