"""Small valid glTF scenes for the API tests: a box on a slab as ``.glb``, as ``.gltf`` with an
embedded buffer, and as a ``.zip`` of ``.gltf`` + ``.bin``."""

from __future__ import annotations

import base64
import io
import json
import struct
import zipfile

import numpy as np


def _box_document() -> tuple[dict, bytes]:
    """A unit box standing on a 4 × 4 slab, off the origin (its centre is no round number)."""
    box = np.array([[x, y, z] for x in (0.3, 1.3) for y in (0.0, 1.0) for z in (-0.4, 0.6)],
                   np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    box_idx = [i for a, b, c, d in quads for i in (a, b, c, a, c, d)]
    slab = np.array([[-2.1, -0.05, -1.9], [1.9, -0.05, -1.9], [1.9, -0.05, 2.1],
                     [-2.1, -0.05, 2.1]], np.float32)
    slab_idx = [0, 2, 1, 0, 3, 2]
    positions = np.concatenate([box, slab])
    indices = np.array(box_idx + [8 + i for i in slab_idx], np.uint16)
    blob = positions.tobytes() + indices.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions.nbytes},
            {"buffer": 0, "byteOffset": positions.nbytes, "byteLength": indices.nbytes},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3",
             "min": positions.min(axis=0).tolist(), "max": positions.max(axis=0).tolist()},
            {"bufferView": 1, "componentType": 5123, "count": len(indices), "type": "SCALAR"},
        ],
    }
    return doc, blob


def box_glb() -> bytes:
    """The box scene as ``.glb``."""
    doc, blob = _box_document()
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = (struct.pack("<II", len(js), 0x4E4F534A) + js
            + struct.pack("<II", len(blob), 0x004E4942) + blob)
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def box_gltf_embedded() -> bytes:
    """The box scene as ``.gltf`` with its buffer in a data URI."""
    doc, blob = _box_document()
    doc["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                + base64.b64encode(blob).decode())
    return json.dumps(doc).encode()


def box_zip() -> bytes:
    """The box scene as a ``.zip`` of ``box.gltf`` and ``box.bin``."""
    doc, blob = _box_document()
    doc["buffers"][0]["uri"] = "box.bin"
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("box.gltf", json.dumps(doc))
        z.writestr("box.bin", blob)
    return out.getvalue()
