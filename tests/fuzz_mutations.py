"""Random mutations of real models: the values a broken exporter or a hostile client writes.

Where :mod:`fuzz_cases` holds named cases, each aimed at one rule, :func:`mutations` draws many
unnamed ones: one to three JSON values of a real ``.glb`` (or of one with lights or a texture
transform added, :data:`VARIANTS`) replaced by a neighbour of the value
(an integer off by one or doubled, a component type, a float scaled by 1e30 or set to 1e308, a
string swapped for another glTF keyword, an array shortened or lengthened, an object losing a
key), and now and then a few bytes of the binary chunk overwritten. Numbers stay finite in JSON:
the repairs these reach are the ones that only go wrong in float32 or in a product (a colour of
-1e308, a matrix row of 1e308, a texture coordinate scaled past float32's range).

``tests/test_fuzz.py`` loads and renders each; ``SHADOWMAP_FUZZ_SEED`` picks another draw.
"""

from __future__ import annotations

import copy
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from gltf_files import make_glb, split_glb

#: Models mutated: the small files of the models folder, and ones with skins, morph targets,
#: animations and several meshes and textures.
MODELS = ("cube.glb", "TwoCubes.glb", "BoxTextured.glb", "BoxMeshopt.glb", "Duck.glb",
          "CesiumMan.glb", "Fox.glb", "CesiumMilkTruck.glb")
#: Variants built here from real models, so that the extensions no model in the folder uses
#: are mutated too: the Duck under a spot, a point and a directional light
#: (KHR_lights_punctual), the textured box with a texture transform, a sampler and a cut-out,
#: and the cube drawn 64 times by EXT_mesh_gpu_instancing (float translations and scales,
#: rotations as normalized bytes), and the Duck seen by an orthographic camera of the file
#: (the default view) in an unlit material (KHR_materials_unlit).
VARIANTS = ("Duck.glb+lights", "BoxTextured.glb+transform", "cube.glb+instancing",
            "Duck.glb+ortho_unlit")
_STRINGS = ("", "VEC2", "VEC3", "VEC4", "SCALAR", "MAT2", "MAT4", "data:,", "BLEND", "MASK",
            "x.bin", "image/png")
_INTS = (5120, 5121, 5122, 5123, 5125, 5126, 2**31)


def _paths(doc: Any, rng: random.Random, prefix: tuple = ()) -> list[tuple]:
    """Paths to values in ``doc``: every key, and up to 4 items of each array."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for key, value in doc.items():
            out += _paths(value, rng, (*prefix, key))
    elif isinstance(doc, list):
        items = range(len(doc)) if len(doc) <= 4 else sorted(rng.sample(range(len(doc)), 4))
        for i in items:
            out += _paths(doc[i], rng, (*prefix, i))
    return out


def _neighbour(old: Any, rng: random.Random) -> Any:
    """A value near ``old`` in type or meaning."""
    if isinstance(old, bool) or old is None:
        return rng.choice([0, 1, "x", None, [], {}])
    if isinstance(old, int):
        return rng.choice([old + 1, old - 1, old * 2, -old, 0, old + 4, 2**32 + old,
                           *_INTS])
    if isinstance(old, float):
        return rng.choice([old * 1e30, -old, 0.0, 1e-30, old + 1, 1e308, -1e308, old * 1e-30])
    if isinstance(old, str):
        return rng.choice([*_STRINGS, old + "x"])
    if isinstance(old, list):
        if old and rng.random() < 0.5:
            shorter = list(old)
            del shorter[rng.randrange(len(shorter))]
            return shorter
        return old + old[:1] if old else [0]
    if isinstance(old, dict):
        fewer = dict(old)
        if fewer and rng.random() < 0.6:
            fewer.pop(rng.choice(list(fewer)))
        return fewer
    return None


def _variant(name: str, models: Path) -> tuple[dict, bytes]:
    """The document and binary chunk of a :data:`VARIANTS` entry."""
    base, _, extra = name.partition("+")
    doc, blob = split_glb((models / base).read_bytes())
    if extra == "lights":
        doc["extensionsUsed"] = [*doc.get("extensionsUsed", []), "KHR_lights_punctual"]
        doc.setdefault("extensions", {})["KHR_lights_punctual"] = {"lights": [
            {"type": "spot", "intensity": 40, "range": 20, "color": [1, 0.9, 0.8],
             "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.6}},
            {"type": "point", "intensity": 30, "range": 50},
            {"type": "directional", "intensity": 2}]}
        first = len(doc["nodes"])
        doc["nodes"] += [
            {"translation": [0, 300, 200], "rotation": [-0.3826834, 0, 0, 0.9238795],
             "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"translation": [150, 200, -100], "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"rotation": [-0.5, 0.2, 0, 0.84], "extensions": {"KHR_lights_punctual": {"light": 2}}}]
        doc["scenes"][doc.get("scene", 0)]["nodes"] += [first, first + 1, first + 2]
    elif extra == "transform":
        doc["extensionsUsed"] = [*doc.get("extensionsUsed", []), "KHR_texture_transform"]
        material = doc["materials"][0]
        material.update(alphaMode="MASK", alphaCutoff=0.3, doubleSided=True)
        material["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
            "KHR_texture_transform": {"offset": [0.1, 0.2], "rotation": 0.3, "scale": [2.0, 0.5],
                                      "texCoord": 0}}
        doc["samplers"] = [{"wrapS": 33648, "wrapT": 33071, "magFilter": 9729,
                            "minFilter": 9987}]
        doc["textures"][0]["sampler"] = 0
    elif extra == "ortho_unlit":
        doc["extensionsUsed"] = [*doc.get("extensionsUsed", []), "KHR_materials_unlit"]
        doc["materials"][0].setdefault("extensions", {})["KHR_materials_unlit"] = {}
        # The file's own camera, where it stands, made orthographic.
        doc["cameras"][0] = {"type": "orthographic", "orthographic": {
            "xmag": 375.0, "ymag": 250.0, "znear": 0.5, "zfar": 2000.0}}
    elif extra == "instancing":
        doc["extensionsUsed"] = [*doc.get("extensionsUsed", []), "EXT_mesh_gpu_instancing"]
        k = 64
        grid = np.stack(np.meshgrid(np.arange(8), np.arange(8), indexing="ij"), -1).reshape(k, 2)
        columns = {
            "TRANSLATION": (np.c_[grid[:, 0] * 3.0, np.zeros(k), grid[:, 1] * 3.0], 5126, False),
            "ROTATION": (np.tile([0, 90, 0, 90], (k, 1)), 5120, True),
            "SCALE": (np.c_[np.linspace(0.5, 1.5, k)].repeat(3, axis=1), 5126, False),
        }
        attributes = {}
        for key, (values, ctype, normalized) in columns.items():
            data = np.asarray(values, np.int8 if ctype == 5120 else np.float32).tobytes()
            blob += b"\0" * (-len(blob) % 4)
            doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob),
                                       "byteLength": len(data)})
            blob += data
            accessor = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": ctype,
                        "count": k, "type": "VEC4" if key == "ROTATION" else "VEC3"}
            if normalized:
                accessor["normalized"] = True
            doc["accessors"].append(accessor)
            attributes[key] = len(doc["accessors"]) - 1
        doc["buffers"][0]["byteLength"] = len(blob)
        mesh_node = next(node for node in doc["nodes"] if "mesh" in node)
        mesh_node.setdefault("extensions", {})["EXT_mesh_gpu_instancing"] = {
            "attributes": attributes}
    return doc, blob


def mutations(models: Path, count: int, seed: int) -> Iterator[tuple[str, bytes]]:
    """``count`` mutated GLB files as (name, bytes), the same ones for the same seed.

    The name says the model, the draw's number and the paths changed (enough to rebuild the
    case from the seed).
    """
    rng = random.Random(seed)
    files = {name: split_glb((models / name).read_bytes()) for name in MODELS}
    files.update({name: _variant(name, models) for name in VARIANTS})
    names = [*MODELS, *VARIANTS]
    for k in range(count):
        name = rng.choice(names)
        doc, blob = files[name]
        doc = copy.deepcopy(doc)
        changed = []
        for _ in range(rng.choice([1, 1, 2, 3])):
            path = rng.choice(_paths(doc, rng))
            parent = doc
            try:
                for key in path[:-1]:
                    parent = parent[key]
                parent[path[-1]] = _neighbour(parent[path[-1]], rng)
            except (KeyError, IndexError, TypeError):  # an earlier change moved the path away
                continue
            changed.append("/".join(map(str, path)))
        data = bytearray(blob)
        if data and rng.random() < 0.2:
            for _ in range(rng.randrange(1, 8)):
                data[rng.randrange(len(data))] = rng.randrange(256)
            changed.append("bytes")
        yield f"{name} #{k} {', '.join(changed)}", make_glb(doc, bytes(data))
