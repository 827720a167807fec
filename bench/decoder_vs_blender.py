"""Our glTF decoder against Blender's glTF importer: the same files, the same triangles?

Blender as a Python module (``bpy``) reads glTF with a decoder of its own: skins, shape keys
(morph targets), sparse accessors, Draco, EXT_mesh_gpu_instancing. This script loads each file
with both and compares every drawn triangle in world space, so a decoding error of either shows
as triangles in different places. It is a check run by hand: bpy is about 1 GB and is not
installed by CI or ``scripts/bootstrap``. Give it a Python that imports bpy:

    python3 -m venv /tmp/bpy && /tmp/bpy/bin/pip install bpy==5.0.1
    python bench/decoder_vs_blender.py --blender-python /tmp/bpy/bin/python

Three sets of files:

- every model of the models folder;
- files built here, one per glTF feature the models do not exercise (sparse accessors, morph
  targets at mesh and node weights, quantized positions, strips and fans, mirroring nodes,
  GPU instancing, a deep hierarchy whose non-uniform scales and turns compose into a shear,
  a default scene other than the first, cameras and lights on turned nodes, two of them under
  an unevenly scaled parent),
  and one that breaks a glTF rule to show a difference (a node matrix that shears);
- ``--mutations N`` random mutations of the models (``tests/fuzz_mutations.py``, the files
  ``tests/test_fuzz.py`` renders, seed ``--seed``): where both decoders accept a file, each
  disagreement is listed with our warnings for it, and with the file's nodes whose matrix
  flattens what it places (singular, or an axis scaled to almost nothing: glTF allows it, and
  Blender, which imports a node matrix as a location, rotation and scale, draws the flat
  remainder otherwise, where the same matrix with a small but not vanishing scale agrees).

Blender is given each file without its animations (a copy with ``animations`` removed):
Blender poses a skin at the first animation's first frame, this project in the pose the nodes
store (no animation is played). Per file: our triangles and Blender's, the drawn ones
(non-degenerate, duplicates counted once), and the largest distance between a drawn triangle of
one and the nearest of the other (each triangle matched to the one whose centroid is nearest;
the distance of two triangles is the farthest of a corner of one from the nearest corner of the
other), as a share of the diagonal of the two scenes' bounds. *same*: at most
:data:`SAME` both ways. The files' cameras and lights are compared too: each of ours against
Blender's of the same kind nearest it, positions (a share of the scene's size), view and up
directions, and a perspective camera's field of view or a spot light's outer cone; *same*:
within :data:`SAME` and :data:`VIEW_DEGREES`. Written to bench/results/decoder_vs_blender.md
and .csv.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bench import _common as C  # before shadowmap: selects the GL platform
from shadowmap.renderer import ShadowMapError, load_scene  # noqa: E402
from shadowmap.renderer.limits import check_gpu_range  # noqa: E402
from shadowmap.renderer.scene import Scene  # noqa: E402

HERE = Path(__file__).resolve().parent
TESTS = HERE.parent / "tests"
#: Triangles of the two decoders count as the same within this share of the scene's diagonal:
#: float32 positions through a few products differ by about 1e-7 of it.
SAME = 1e-5
#: An axis of a node matrix scaled below this share of another flattens the node (and a
#: determinant below this share of the axes' product): see :func:`flattening_matrices`.
FLAT = 1e-12
#: Cameras' and lights' directions and angles count as the same within this many degrees
#: (Blender keeps them in float32: about 1e-5 degrees apart).
VIEW_DEGREES = 1e-3
#: The share of a node's largest scale :func:`unflattened` gives a flattened axis back.
UNFLATTEN = 1e-3
#: Triangles of the other decoder tried for each one (those with the nearest centroids).
CANDIDATES = 8
#: A triangle is drawn (not degenerate) above this area, as a share of the diagonal squared.
DEGENERATE = 1e-12


# --------------------------------------------------------------------------------------------
# Files built here
# --------------------------------------------------------------------------------------------

FLOAT, UBYTE, SHORT, USHORT = 5126, 5121, 5122, 5123
_DTYPES = {FLOAT: "<f4", UBYTE: "<u1", SHORT: "<i2", USHORT: "<u2"}
_KINDS = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)


class Builder:
    """A small glTF document with buffer 0 as the GLB's binary chunk."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {
            "asset": {"version": "2.0"}, "buffers": [{"byteLength": 0}], "bufferViews": [],
            "accessors": [], "meshes": [], "nodes": [], "scenes": [{"nodes": []}], "scene": 0}
        self.blob = bytearray()

    def view(self, data: bytes) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.blob),
                                        "byteLength": len(data)})
        self.blob += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, values: Any, ctype: int = FLOAT, **fields: Any) -> int:
        arr = np.asarray(values, _DTYPES[ctype])
        acc = {"componentType": ctype, "count": len(arr),
               "type": _KINDS[arr.shape[1] if arr.ndim == 2 else 1],
               "bufferView": self.view(arr.tobytes()), **fields}
        if ctype == FLOAT and arr.ndim == 2 and arr.shape[1] == 3:
            acc.update(min=arr.min(axis=0).tolist(), max=arr.max(axis=0).tolist())
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, *primitives: dict, **fields: Any) -> int:
        self.doc["meshes"].append({"primitives": list(primitives), **fields})
        return len(self.doc["meshes"]) - 1

    def quad(self, positions: np.ndarray = QUAD, **prim: Any) -> int:
        """A mesh of one two-triangle primitive."""
        attrs = {"POSITION": self.accessor(positions), **prim.pop("attributes", {})}
        indices = self.accessor([0, 1, 2, 0, 2, 3], USHORT)
        return self.mesh({"attributes": attrs, "indices": indices, **prim})

    def node(self, root: bool = True, **fields: Any) -> int:
        self.doc["nodes"].append(fields)
        index = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def glb(self) -> bytes:
        self.doc["buffers"][0]["byteLength"] = max(len(self.blob), 4)
        return glb_bytes(self.doc, bytes(self.blob) or b"\0\0\0\0")


def glb_bytes(doc: dict, blob: bytes) -> bytes:
    """A GLB of a JSON document and its binary chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = (struct.pack("<II", len(text), 0x4E4F534A) + text
              + struct.pack("<II", len(blob), 0x004E4942) + blob)
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def _turn(axis: tuple[float, float, float], degrees: float) -> list[float]:
    """A unit quaternion (x, y, z, w)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    h = math.radians(degrees) / 2
    return [*(a * math.sin(h)).tolist(), math.cos(h)]


def sparse() -> bytes:
    """Sparse accessors: two of four positions replaced, and a primitive whose positions are
    only a sparse substitution over zeros (no bufferView)."""
    b = Builder()
    base = b.accessor(QUAD)
    b.doc["accessors"][base]["sparse"] = {
        "count": 2,
        "indices": {"bufferView": b.view(np.array([1, 2], "<u1").tobytes()),
                    "componentType": UBYTE},
        "values": {"bufferView": b.view(np.array([[2, 0, 0.5], [2, 1, 0.5]], "<f4").tobytes())}}
    b.doc["accessors"][base].update(min=[0, 0, 0], max=[2, 1, 0.5])
    b.doc["accessors"].append({
        "componentType": FLOAT, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 2, 1],
        "sparse": {"count": 3,
                   "indices": {"bufferView": b.view(np.array([1, 2, 3], "<u2").tobytes()),
                               "componentType": USHORT},
                   "values": {"bufferView": b.view(
                       np.array([[1, 0, 1], [1, 2, 1], [0, 2, 0]], "<f4").tobytes())}}})
    zeros = len(b.doc["accessors"]) - 1
    index = b.accessor([0, 1, 2, 0, 2, 3], USHORT)
    b.node(mesh=b.mesh({"attributes": {"POSITION": base}, "indices": index}))
    b.node(mesh=b.mesh({"attributes": {"POSITION": zeros}, "indices": index}),
           translation=[0, 0, 2])
    return b.glb()


def morph() -> bytes:
    """Morph targets at their default weights: the mesh's, and a node's own."""
    b = Builder()
    lift = b.accessor(np.array([[0, 0, 1], [0, 0, 0], [0, 0, 0], [0, 0, 1]], np.float32))
    push = b.accessor(np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 0, 0]], np.float32))
    mesh = b.quad(targets=[{"POSITION": lift}, {"POSITION": push}])
    b.doc["meshes"][mesh]["weights"] = [0.5, 0.25]
    b.node(mesh=mesh)
    b.node(mesh=mesh, weights=[1.0, -0.5], translation=[3, 0, 0])
    return b.glb()


def quantized() -> bytes:
    """KHR_mesh_quantization: normalized shorts scaled by their node, and plain bytes."""
    b = Builder()
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    shorts = np.array([[0, 0, 0], [32767, 0, 0], [32767, 32767, -32767], [0, 32767, 0]])
    pos = b.accessor(shorts, SHORT, normalized=True, min=[0, 0, -32767],
                     max=[32767, 32767, 0])
    b.node(mesh=b.mesh({"attributes": {"POSITION": pos},
                        "indices": b.accessor([0, 1, 2, 0, 2, 3], USHORT)}),
           scale=[2, 3, 0.5])
    raw = b.accessor(np.array([[0, 0, 0], [4, 0, 0], [4, 4, 2], [0, 4, 0]], np.uint8), UBYTE,
                     min=[0, 0, 0], max=[4, 4, 2])
    b.node(mesh=b.mesh({"attributes": {"POSITION": raw},
                        "indices": b.accessor([0, 1, 2, 0, 2, 3], USHORT)}),
           translation=[0, 0, 3])
    return b.glb()


def strips_and_fans() -> bytes:
    """Triangle strips and fans, indexed and not: triangulated at load by both."""
    b = Builder()
    ring = np.array([[math.cos(a), math.sin(a), 0.1 * k] for k, a in
                     enumerate(np.linspace(0, 1.5 * math.pi, 6))], np.float32)
    zigzag = np.array([[k // 2, k % 2, 0.2 * k] for k in range(7)], np.float32)
    fan_points = np.concatenate([[[0, 0, 0.5]], ring]).astype(np.float32)
    for i, (mode, pos, idx) in enumerate([(5, zigzag, None), (5, zigzag, [6, 5, 4, 3, 2, 1, 0]),
                                          (6, fan_points, None),
                                          (6, fan_points, [0, 6, 5, 4, 3, 2, 1])]):
        prim: dict[str, Any] = {"attributes": {"POSITION": b.accessor(pos)}, "mode": mode}
        if idx is not None:
            prim["indices"] = b.accessor(idx, USHORT)
        b.node(mesh=b.mesh(prim), translation=[3 * i, 0, 0])
    return b.glb()


def mirrored() -> bytes:
    """Mirroring nodes (negative determinant): a negative scale, a turned mirror matrix, and a
    child under a mirrored parent."""
    b = Builder()
    mesh = b.quad(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.5], [0, 1, 0]], np.float32))
    b.node(mesh=mesh, scale=[-1, 1, 1])
    m = np.diag([1.0, -1.0, 1.0, 1.0])
    c, s = math.cos(0.5), math.sin(0.5)
    turn = np.array([[c, 0, s, 2], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])
    b.node(mesh=mesh, matrix=(turn @ m).T.ravel().tolist())
    child = b.node(root=False, mesh=mesh, rotation=_turn((0, 0, 1), 30), translation=[1, 0, 0])
    b.node(children=[child], scale=[1, 1, -2], translation=[0, 3, 0])
    return b.glb()


def instancing() -> bytes:
    """EXT_mesh_gpu_instancing: eight instances from float translations and scales and
    normalized-short rotations, under a turned node."""
    b = Builder()
    b.doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    k = np.arange(8)
    translation = np.stack([k % 4 * 1.5, k // 4 * 2.0, 0.1 * k], axis=1).astype(np.float32)
    scale = np.stack([1 + 0.1 * k, np.ones(8), 0.5 + 0.2 * k], axis=1).astype(np.float32)
    rotation = np.array([_turn((1, 0.5 * i, 0.2), 20 * i) for i in range(8)])
    shorts = np.round(rotation * 32767).astype(np.int16)
    b.node(mesh=b.quad(), rotation=_turn((0, 1, 0), 25), extensions={
        "EXT_mesh_gpu_instancing": {"attributes": {
            "TRANSLATION": b.accessor(translation), "SCALE": b.accessor(scale),
            "ROTATION": b.accessor(shorts, SHORT, normalized=True)}}})
    return b.glb()


def hierarchy() -> bytes:
    """Five levels of TRS, each a non-uniform scale and a turn: their product shears, which
    glTF allows (each node's own transform is a TRS)."""
    b = Builder()
    mesh = b.quad()
    parent = None
    for level in range(5):
        node = b.node(root=parent is None, mesh=mesh, translation=[1, 0.5 * level, 0],
                      rotation=_turn((level, 1, 0.5), 35 + 10 * level),
                      scale=[1.5, 0.6 + 0.1 * level, 1.2])
        if parent is not None:
            b.doc["nodes"][parent]["children"] = [node]
        parent = node
    return b.glb()


def scenes() -> bytes:
    """Two scenes, the file's default the second: only its node is drawn."""
    b = Builder()
    mesh = b.quad()
    b.node(mesh=mesh)
    b.doc["scenes"].append({"nodes": [b.node(root=False, mesh=mesh, translation=[5, 0, 0])]})
    b.doc["scene"] = 1
    return b.glb()


def cameras_and_lights() -> bytes:
    """Cameras (perspective; orthographic) and KHR_lights_punctual lights (spot, point,
    directional) on turned nodes, the perspective camera and the spot under a turned parent
    scaled unevenly (their world matrices shear)."""
    b = Builder()
    b.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    b.doc["cameras"] = [
        {"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1, "aspectRatio": 1.5}},
        {"type": "orthographic",
         "orthographic": {"xmag": 2.0, "ymag": 1.5, "znear": 0.1, "zfar": 50.0}}]
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "spot", "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}},
        {"type": "point"}, {"type": "directional"}]}}
    b.node(mesh=b.quad())
    camera = b.node(root=False, camera=0, translation=[0, 1, 5], rotation=_turn((1, 0, 0), -10))
    spot = b.node(root=False, translation=[0, 2, 1], rotation=_turn((1, 0, 0), -45),
                  extensions={"KHR_lights_punctual": {"light": 0}})
    # Non-uniform: the children's world matrices shear, and they face along their -Z axes.
    b.node(children=[camera, spot], rotation=_turn((0, 1, 0), 30), scale=[2, 3, 1])
    b.node(camera=1, translation=[3, 3, 3], rotation=_turn((1, -1, 0), -40))
    for k, axis in enumerate([(0, 1, 1), (1, 2, -1)], start=1):
        b.node(translation=[k - 1.0, 4.0, 1.0], rotation=_turn(axis, -60 + 20 * k),
               extensions={"KHR_lights_punctual": {"light": k}})
    return b.glb()


def sheared() -> bytes:
    """A node matrix that shears, against glTF's rule that it decompose into translation,
    rotation and scale: this project draws it as written (with a warning), Blender decomposes
    it, so the two differ by design."""
    b = Builder()
    m = np.eye(4)
    m[0, 1] = 0.5
    b.node(mesh=b.quad(), matrix=m.T.ravel().tolist())
    return b.glb()


#: The built files, by name.
BUILT = {"sparse.glb": sparse, "morph.glb": morph, "quantized.glb": quantized,
         "strips_fans.glb": strips_and_fans, "mirrored.glb": mirrored,
         "instancing.glb": instancing, "hierarchy.glb": hierarchy, "scenes.glb": scenes,
         "cameras_lights.glb": cameras_and_lights, "sheared_matrix.glb": sheared}


# --------------------------------------------------------------------------------------------
# The comparison
# --------------------------------------------------------------------------------------------

def without_animations(data: bytes) -> bytes:
    """A glTF's bytes (GLB or JSON) without its ``animations``; unreadable ones as they are."""
    try:
        if data[:4] == b"glTF":
            length = struct.unpack_from("<I", data, 12)[0]
            doc = json.loads(data[20:20 + length])
            rest = data[20 + length:]
            if not isinstance(doc, dict) or doc.pop("animations", None) is None:
                return data
            text = json.dumps(doc).encode()
            text += b" " * (-len(text) % 4)
            chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
            return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks
        doc = json.loads(data)
        if not isinstance(doc, dict) or doc.pop("animations", None) is None:
            return data
        return json.dumps(doc).encode()
    except (ValueError, struct.error):
        return data


def flattening_matrices(data: bytes | Path) -> list[int]:
    """Nodes whose ``matrix`` flattens what it places: singular, or an axis scaled below
    :data:`FLAT` of another. glTF allows them (a zero scale hides a node); Blender, which
    imports a node matrix as a location, rotation and scale, draws the flat remainder under
    such a matrix otherwise (listed per file, not a verdict)."""
    raw = data.read_bytes() if isinstance(data, Path) else data
    try:
        if raw[:4] == b"glTF":
            doc = json.loads(raw[20:20 + struct.unpack_from("<I", raw, 12)[0]])
        else:
            doc = json.loads(raw)
        nodes = doc.get("nodes", [])
        out = []
        for i, node in enumerate(nodes):
            m = node.get("matrix") if isinstance(node, dict) else None
            if not (isinstance(m, list) and len(m) == 16):
                continue
            with np.errstate(all="ignore"):
                axes = np.asarray(m, np.float64).reshape(4, 4)[:3, :3]  # rows: the axes
                scales = np.linalg.norm(axes, axis=1)
                flat = not (abs(np.linalg.det(axes)) > FLAT * np.prod(scales)
                            and scales.min() > FLAT * scales.max())
            if flat:
                out.append(i)
        return out
    except (ValueError, TypeError, AttributeError, struct.error, np.linalg.LinAlgError):
        return []


def drawn(tris: np.ndarray, diagonal: float) -> np.ndarray:
    """The non-degenerate triangles, each once (duplicates, as Blender's mesh keeps one)."""
    with np.errstate(all="ignore"):
        area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                              axis=1)
        tris = tris[area > DEGENERATE * diagonal ** 2]
        # Corners to a grid of 1e-7 of the diagonal, in a fixed order within each triangle.
        grid = np.round(tris / (1e-7 * diagonal)).astype(np.int64)
    order = np.lexsort((grid[..., 2], grid[..., 1], grid[..., 0]), axis=-1)
    key = np.take_along_axis(grid, order[..., None], axis=1).reshape(len(grid), 9)
    _, first = np.unique(key, axis=0, return_index=True)
    return tris[np.sort(first)]


def farthest(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance from a triangle of ``a`` to the nearest triangle of ``b``: of the
    :data:`CANDIDATES` triangles of ``b`` whose centroids are nearest its own, the one whose
    farthest corner from its own nearest corner is nearest (triangles that share a centroid,
    as overlapping ones of a broken file do, are told apart by their corners)."""
    from scipy.spatial import cKDTree

    if len(a) == 0 or len(b) == 0:
        return 0.0 if len(a) == len(b) else math.inf
    k = min(CANDIDATES, len(b))
    _, nearest = cKDTree(b.mean(axis=1)).query(a.mean(axis=1), k=k)
    m = b[nearest.reshape(len(a), k)]  # (F, k, 3, 3)
    d = np.linalg.norm(a[:, None, :, None, :] - m[:, :, None, :, :], axis=4)  # (F, k, 3, 3)
    apart = np.maximum(d.min(axis=3).max(axis=2), d.min(axis=2).max(axis=2))  # (F, k)
    return float(apart.min(axis=1).max())


def compare(ours: np.ndarray, theirs: np.ndarray) -> dict[str, Any]:
    """Counts, drawn counts and the largest distance (a share of the diagonal) both ways."""
    points = np.concatenate([ours.reshape(-1, 3), theirs.reshape(-1, 3)])
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) == 0:
        diagonal = 1.0
    else:
        with np.errstate(over="ignore"):
            diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    finite = bool(np.isfinite(ours).all() and np.isfinite(theirs).all()
                  and math.isfinite(diagonal))
    out: dict[str, Any] = {"ours": len(ours), "blender": len(theirs)}
    if not finite:
        return {**out, "drawn_ours": None, "drawn_blender": None, "distance": math.nan,
                "verdict": "not finite"}
    a, b = drawn(ours, diagonal), drawn(theirs, diagonal)
    distance = max(farthest(a, b), farthest(b, a)) / diagonal
    return {**out, "drawn_ours": len(a), "drawn_blender": len(b), "distance": distance,
            "verdict": "same" if distance <= SAME else "differs"}


def world_triangles(data: bytes | Path) -> tuple[np.ndarray, list[str], list[dict[str, Any]]]:
    """Our decoder's drawn triangles of a file, world space, its warnings, and its cameras and
    lights (:func:`scene_views`).

    Raises
    ------
    ShadowMapError
        The file is refused at load, or its scene by the range check every render makes.
    """
    with np.errstate(all="ignore"), warnings.catch_warnings():
        # A mutation's huge values overflow where the render would refuse them: compared here.
        warnings.simplefilter("ignore", RuntimeWarning)
        scene = load_scene(data)
        # What every render checks before it draws: a scene float32 cannot place is refused.
        lo, hi = scene.bounds
        check_gpu_range(np.stack([lo, hi]), (lo + hi) / 2)
        views = scene_views(scene)
        if not scene.instances:
            return np.zeros((0, 3, 3)), scene.warnings, views
        tris = np.concatenate([scene.world_triangles(i) for i in scene.instances])
    return tris, scene.warnings, views


def scene_views(scene: Scene) -> list[dict[str, Any]]:
    """The scene's cameras and lights as ``bench/blender_triangles.py`` lists Blender's: kind
    (``camera`` or the light's type), pose (4, 4) and angle (a perspective camera's vertical
    field of view, a spot light's outer cone, radians; None otherwise)."""
    out = [{"kind": "camera", "pose": c.pose, "angle": c.yfov} for c in scene.cameras]
    out += [{"kind": lt.type, "pose": lt.pose,
             "angle": lt.outer_cone if lt.type == "spot" else None} for lt in scene.lights]
    return out


def _apart(v: dict[str, Any], t: dict[str, Any], scale: float) -> tuple[float, float, float]:
    """Two views' distance (a share of ``scale``), the larger of the angles between their view
    and up directions, and between their angles (degrees); NaN where either is not finite."""
    def view_and_up(pose: Any) -> tuple[np.ndarray, np.ndarray]:
        # The up axis made perpendicular to the view axis: Blender keeps a sheared world
        # matrix (its columns unit here, not perpendicular), this project a rotation.
        m = np.asarray(pose, np.float64)
        z, y = m[:3, 2], m[:3, 1] - (m[:3, 1] @ m[:3, 2]) * m[:3, 2]
        return z, y / np.linalg.norm(y)

    p, q = np.asarray(v["pose"], np.float64), np.asarray(t["pose"], np.float64)
    turn = max(math.degrees(math.acos(min(1.0, max(-1.0, float(a @ b)))))
               for a, b in zip(view_and_up(p), view_and_up(q), strict=True))
    if v["angle"] is None or t["angle"] is None:
        gap = 0.0 if v["angle"] is t["angle"] else math.inf
    else:
        gap = math.degrees(abs(float(v["angle"]) - float(t["angle"])))
    return float(np.linalg.norm(p[:3, 3] - q[:3, 3])) / scale, turn, gap


def compare_views(ours: list[dict[str, Any]], theirs: list[dict[str, Any]],
                  size: float) -> dict[str, Any]:
    """Each of our cameras and lights against Blender's of the same kind nearest it: the
    largest distance between positions (a share of ``size``, or of the position's own distance
    from the origin where that is larger), between view directions and between up directions
    (each made perpendicular to its view direction; degrees), and between angles (degrees).
    *same*: the same kinds, as many of each, each within :data:`SAME`, :data:`VIEW_DEGREES`
    and :data:`VIEW_DEGREES`."""
    out: dict[str, Any] = {"views": f"{len(ours)} / {len(theirs)}"}
    if sorted(v["kind"] for v in ours) != sorted(v["kind"] for v in theirs):
        return {**out, "views_verdict": "differs (kinds)"}
    position = turn = angle = 0.0
    left = list(theirs)
    with np.errstate(all="ignore"):
        for v in ours:
            scale = max(size, float(np.linalg.norm(np.asarray(v["pose"])[:3, 3])), 1e-30)
            k = min((k for k, t in enumerate(left) if t["kind"] == v["kind"]),
                    key=lambda k, v=v, scale=scale: _apart(v, left[k], scale)[:2])
            d, a, g = _apart(v, left.pop(k), scale)
            # np.maximum keeps a NaN (a pose that is not finite), where max() would drop it.
            position, turn, angle = (float(np.maximum(x, y)) for x, y in
                                     ((position, d), (turn, a), (angle, g)))
    same = position <= SAME and turn <= VIEW_DEGREES and angle <= VIEW_DEGREES
    return {**out, "view_position": position, "view_degrees": turn, "view_angle": angle,
            "views_verdict": "same" if same else "differs"}


def blender_triangles(python: str, files: list[tuple[str, bytes | Path]], work: Path
                      ) -> dict[str, tuple[np.ndarray, list[dict[str, Any]]] | str]:
    """Blender's triangles, cameras and lights of each (name, bytes or path), or the
    importer's error."""
    pairs = []
    for k, (name, source) in enumerate(files):
        folder = work / str(k)
        folder.mkdir(parents=True)
        if isinstance(source, Path):
            # A .gltf's external files are found beside it: link them into the folder.
            for sibling in source.parent.iterdir():
                if sibling != source and sibling.is_file():
                    os.symlink(sibling, folder / sibling.name)
            data = source.read_bytes()
        else:
            data = source
        path = folder / (name if isinstance(source, Path) else f"{k}.glb")
        path.write_bytes(without_animations(data))
        pairs.append([str(path), str(folder / "tris.npy")])
    left = pairs
    while left:
        (work / "pairs.json").write_text(json.dumps(left))
        code = subprocess.run([python, str(HERE / "blender_triangles.py"),
                               str(work / "pairs.json")], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL).returncode
        done = [Path(t).exists() or Path(t + ".err").exists() for _, t in left]
        if code == 0 or all(done):
            break
        # Blender died on a file: that file is its result, and the rest get a new process.
        stop = done.index(False)
        Path(left[stop][1] + ".err").write_text(f"Blender exited with code {code}")
        left = left[stop + 1:]
    out: dict[str, tuple[np.ndarray, list[dict[str, Any]]] | str] = {}
    for (name, _), (_, target) in zip(files, pairs, strict=True):
        err = Path(target + ".err")
        out[name] = err.read_text() if err.exists() else (
            np.load(target), json.loads(Path(target + ".views.json").read_text()))
    return out


def mutations(count: int, seed: int) -> Iterator[tuple[str, bytes]]:
    """The fuzz tests' mutated models (``tests/fuzz_mutations.py``)."""
    sys.path.insert(0, str(TESTS))
    import fuzz_mutations  # type: ignore[import-not-found]

    yield from fuzz_mutations.mutations(C.models_dir(), count, seed)


def _short(text: str, n: int = 160) -> str:
    text = " ".join(text.split()).replace("|", "\\|")
    return text if len(text) <= n else text[:n - 3] + "..."


def compare_files(blender_python: str, files: list[tuple[str, bytes | Path]], kind: str,
                  work: Path) -> list[dict[str, Any]]:
    """One row per file: both decoders' triangles compared, or who refused it."""
    theirs = blender_triangles(blender_python, files, work) if files else {}
    rows = []
    for name, source in files:
        row: dict[str, Any] = {"set": kind, "file": name}
        try:
            ours, said, views = world_triangles(source)
        except ShadowMapError as exc:
            ours, said, views = None, [], []
            row["our_error"] = f"{type(exc).__name__}: {exc}"
        blender = theirs[name]
        if isinstance(blender, str):
            row["blender_error"] = blender
        if ours is not None and not isinstance(blender, str):
            row.update(compare(ours, blender[0]))
            finite = ours.reshape(-1, 3)
            finite = finite[np.isfinite(finite).all(axis=1)]
            size = float(np.linalg.norm(np.ptp(finite, axis=0))) if len(finite) else 1.0
            row.update(compare_views(views, blender[1], size if math.isfinite(size) else 1.0))
        else:
            row["verdict"] = ("both refuse" if ours is None and isinstance(blender, str)
                              else "we refuse" if ours is None else "Blender refuses")
        row["warnings"] = said
        row["flattening_matrices"] = flattening_matrices(source)
        rows.append(row)
    return rows


def mutations_of(files: list[tuple[str, bytes | Path]]) -> Iterator[tuple[str, bytes]]:
    """The mutated files' bytes (every mutation is a GLB in memory)."""
    for name, source in files:
        assert isinstance(source, bytes), name
        yield name, source


def unflattened(data: bytes, nodes: list[int]) -> bytes:
    """A GLB with the flattening matrices of ``nodes`` given back some depth: each axis scaled
    below :data:`UNFLATTEN` of the node's largest is scaled to that share (a zero axis takes the
    direction of the cross product of the other two)."""
    length = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + length])
    blob_length = struct.unpack_from("<I", data, 20 + length)[0]
    blob = data[28 + length:28 + length + blob_length]
    for i in nodes:
        m = np.asarray(doc["nodes"][i]["matrix"], np.float64).reshape(4, 4)
        axes = m[:3, :3]  # rows: the axes (glTF matrices are column-major)
        scales = np.linalg.norm(axes, axis=1)
        size = UNFLATTEN * (scales.max() or 1.0)
        for k in np.flatnonzero(scales < size).tolist():
            a = axes[k] if scales[k] > 0 else np.cross(axes[(k + 1) % 3], axes[(k + 2) % 3])
            n = np.linalg.norm(a)
            axes[k] = size * (a / n if n > 0 else np.eye(3)[k])
        doc["nodes"][i]["matrix"] = m.ravel().tolist()
    return glb_bytes(doc, blob)


def blender_version(python: str) -> str:
    """The version of the Blender module ``python`` imports; exits with the reason if none."""
    try:
        proc = subprocess.run([python, "-c", "import bpy; print(bpy.app.version_string)"],
                              capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as exc:
        raise SystemExit(f"--blender-python {python}: {exc}") from exc
    lines = proc.stdout.strip().splitlines()
    if proc.returncode or not lines:
        why = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise SystemExit(f"--blender-python {python} does not import bpy: {why}")
    return lines[-1]


def run(blender_python: str, count: int, seed: int) -> None:
    t0 = time.perf_counter()
    models = sorted(p for p in C.models_dir().iterdir() if p.suffix in (".glb", ".gltf"))
    sets: dict[str, list[tuple[str, bytes | Path]]] = {
        "model": [(p.name, p) for p in models],
        "built": [(name, make()) for name, make in BUILT.items()],
        "mutation": list(mutations(count, seed)) if count else []}
    version = blender_version(blender_python)
    work = Path(tempfile.mkdtemp(prefix="decoder_vs_blender_"))
    rows: list[dict[str, Any]] = []
    try:
        for kind, files in sets.items():
            rows += compare_files(blender_python, files, kind, work / kind)
        # A difference under a flattening matrix: the same file with the flat axes given a
        # small depth again, to tell the flattening from anything else in the file.
        mutated = dict(mutations_of(sets["mutation"]))
        flat = [r for r in rows if r["set"] == "mutation" and r["flattening_matrices"]
                and "differs" in (r["verdict"], r.get("views_verdict"))]
        again = compare_files(blender_python, [
            (r["file"], unflattened(mutated[r["file"]], r["flattening_matrices"]))
            for r in flat], "unflattened", work / "unflattened")
        for r, a in zip(flat, again, strict=True):
            r["unflattened"] = a["verdict"]
            r["unflattened_views"] = a.get("views_verdict", "—")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report(rows, version, count, seed, time.perf_counter() - t0)


def report(rows: list[dict[str, Any]], version: str, count: int, seed: int,
           elapsed: float) -> None:
    def table(kind: str) -> list[list[Any]]:
        out = []
        for r in (r for r in rows if r["set"] == kind):
            said = r.get("blender_error") or r.get("our_error") or "; ".join(r["warnings"])
            out.append([r["file"], r.get("ours", "—"), r.get("blender", "—"),
                        f"{r['drawn_ours']} / {r['drawn_blender']}"
                        if r.get("drawn_ours") is not None else "—",
                        f"{r['distance']:.1e}" if "distance" in r else "—",
                        r["verdict"], r.get("views", "—"), r.get("views_verdict", "—"),
                        _short(said or "")])
        return out

    headers = ["file", "our triangles", "Blender's", "drawn, ours / Blender's",
               "largest distance", "verdict", "cameras and lights, ours / Blender's",
               "their poses and angles", "our warnings, or the refusal"]
    blocks = [C.markdown_table(headers, table("model")), C.markdown_table(headers, table("built"))]
    mutated = [r for r in rows if r["set"] == "mutation"]
    tally: dict[str, int] = {}
    for r in mutated:
        tally[r["verdict"]] = tally.get(r["verdict"], 0) + 1
    silent = [r for r in mutated if r["verdict"] == "differs" and not r["warnings"]]
    warned = [r for r in mutated if r["verdict"] == "differs" and r["warnings"]]
    notes = [f"- Mutations: {count} (seed {seed}): "
             + ", ".join(f"{v} {k}" for k, v in sorted(tally.items())) + "." if count else
             "- Mutations: none (`--mutations N` adds them)."]
    if count:
        flat = [r for r in silent if r["flattening_matrices"]]
        same = sum(r.get("unflattened") == "same" for r in flat)
        notes.append(f"- Accepted by both and different: {len(warned)} with a warning of ours "
                     f"for the file, {len(silent)} without. {len(flat)} of these lie under a "
                     "node matrix that flattens (singular, or an axis scaled below "
                     f"{FLAT:g} of another: glTF allows it); with those axes scaled to "
                     f"{UNFLATTEN:g} of the largest instead, {same} of them give the same "
                     "triangles.")
    diff_rows = [[r["file"], r.get("drawn_ours"), r.get("drawn_blender"),
                  f"{r['distance']:.1e}", _short("; ".join(r["warnings"]) or "—"),
                  ", ".join(map(str, r["flattening_matrices"])) or "—",
                  r.get("unflattened", "—")]
                 for r in warned + silent]
    sections = []
    if diff_rows:
        sections.append("Mutations accepted by both whose triangles differ")
        blocks.append(C.markdown_table(["mutation (model, draw, paths changed)", "drawn, ours",
                                        "Blender's", "largest distance", "our warnings",
                                        "nodes whose matrix flattens",
                                        f"those axes at {UNFLATTEN:g} of the largest"],
                                       diff_rows))
    if count:
        both = [r for r in mutated if "views_verdict" in r]
        views_off = [r for r in both if r["views_verdict"] != "same"]
        notes.append(f"- Cameras and lights of the {len(both)} mutations both accept: "
                     f"{len(both) - len(views_off)} the same, {len(views_off)} not "
                     f"({sum(bool(r['warnings']) for r in views_off)} of them with a warning "
                     "of ours for the file).")
        view_rows = [[r["file"], r["views"], r["views_verdict"],
                      f"{r.get('view_position', math.nan):.1e}",
                      f"{r.get('view_degrees', math.nan):.2g}",
                      f"{r.get('view_angle', math.nan):.2g}",
                      _short("; ".join(r["warnings"]) or "—"),
                      ", ".join(map(str, r["flattening_matrices"])) or "—",
                      r.get("unflattened_views", "—")] for r in views_off]
        flat_views = [r for r in views_off if r["flattening_matrices"]]
        notes.append(f"- Of those {len(views_off)}, {len(flat_views)} lie under a node matrix "
                     f"that flattens; with those axes scaled to {UNFLATTEN:g} of the largest "
                     f"instead, {sum(r.get('unflattened_views') == 'same' for r in flat_views)}"
                     " of them give the same cameras and lights.")
        if view_rows:
            sections.append("Mutations accepted by both whose cameras or lights differ")
            blocks.append(C.markdown_table(
                ["mutation", "cameras and lights, ours / Blender's", "verdict",
                 "position apart (share)", "directions apart (degrees)",
                 "angles apart (degrees)", "our warnings", "nodes whose matrix flattens",
                 f"those axes at {UNFLATTEN:g} of the largest"], view_rows))
    same = sum(r["verdict"] == "same" for r in rows if r["set"] != "mutation")
    compared = sum("distance" in r for r in rows if r["set"] != "mutation")
    with_views = [r for r in rows if r["set"] != "mutation"
                  and r.get("views", "0 / 0") != "0 / 0"]
    views_same = sum(r["views_verdict"] == "same" for r in with_views)
    notes.insert(0, f"- Models and built files: {same} of {compared} compared are the same "
                 f"(largest distance at most {SAME:g} of the diagonal); of the "
                 f"{len(with_views)} with cameras or lights, {views_same} give the same ones "
                 f"(positions within {SAME:g} of the scene's size, directions and angles "
                 f"within {VIEW_DEGREES:g} degrees).")
    md = (
        "# Our glTF decoder against Blender's importer\n\n"
        "`bench/decoder_vs_blender.py`: each file loaded by this project's decoder and by "
        f"Blender {version}'s glTF importer (`bpy`; Blender given the file without its "
        "animations), every drawn triangle compared in world space. *drawn*: non-degenerate "
        "triangles, duplicates once; *largest distance*: from a drawn triangle of one to the "
        "nearest of the other, farthest corner from nearest corner, either way, as a share of "
        f"the scenes' diagonal; *same*: at most {SAME:g}.\n\n"
        "## The models folder\n\n" + blocks[0] + "\n\n"
        "## Files built by the script (one glTF feature each)\n\n" + blocks[1] + "\n\n"
        + "".join(f"## {title}\n\n{block}\n\n" for title, block in zip(
            sections, blocks[2:], strict=True))
        + "\n".join(notes) + "\n\n"
        f"Python {sys.version.split()[0]}; {C.code_state()}. Run time {elapsed:.0f} s.\n")
    csv_rows = [{k: (json.dumps(v) if isinstance(v, list) else v) for k, v in r.items()}
                for r in rows]
    C.finish(C.results_dir(), "decoder_vs_blender", md, csv_rows, blocks, notes, elapsed)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blender-python", required=True,
                    help="a Python interpreter that imports bpy (Blender as a module)")
    ap.add_argument("--mutations", type=int, default=0,
                    help="random mutations of the models to compare too (default 0)")
    ap.add_argument("--seed", type=int, default=1, help="the mutations' seed (default 1)")
    args = ap.parse_args(argv)
    run(args.blender_python, args.mutations, args.seed)


if __name__ == "__main__":
    main()
