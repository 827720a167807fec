"""Blender's side of ``bench/decoder_vs_blender.py``: run by a Python that imports ``bpy``.

For each ``[source, target]`` pair of the JSON list named on the command line, import the glTF
file ``source`` into an empty Blender scene with Blender's own importer and save the
world-space triangles of every mesh it drew (instances included, skins and shape keys
evaluated) to ``target`` (``.npy``, shape (F, 3, 3), float64) in glTF's axes: Blender's
importer turns +Y up into +Z up, (x, y, z) -> (x, -z, y), and this turns it back. Beside it,
``target + ".views.json"`` lists the cameras and lights Blender made: each one's kind, its pose
(camera- or light-to-world, looking down -Z, glTF axes, unit axes) and its angle (a perspective
camera's vertical field of view, a spot light's outer cone; None otherwise). A file the
importer refuses leaves ``target + ".err"`` with the error instead.

    python-with-bpy bench/blender_triangles.py pairs.json

Nothing here imports the project: Blender's Python has only bpy and numpy.
"""

from __future__ import annotations

import json
import sys

import bpy  # type: ignore[import-not-found]
import numpy as np


def world_triangles() -> np.ndarray:
    """Every evaluated mesh instance of the current scene as triangles, glTF axes."""
    graph = bpy.context.evaluated_depsgraph_get()
    parts = []
    for inst in graph.object_instances:
        ob = inst.object
        if ob.type != "MESH":
            continue
        mesh = ob.to_mesh()
        try:
            mesh.calc_loop_triangles()
            co = np.empty(len(mesh.vertices) * 3, np.float64)
            mesh.vertices.foreach_get("co", co)
            index = np.empty(len(mesh.loop_triangles) * 3, np.int64)
            mesh.loop_triangles.foreach_get("vertices", index)
        finally:
            ob.to_mesh_clear()
        m = np.array(inst.matrix_world, np.float64)
        w = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        parts.append(np.stack([w[:, 0], w[:, 2], -w[:, 1]], axis=1)[index.reshape(-1, 3)])
    return np.concatenate(parts) if parts else np.zeros((0, 3, 3))


#: Blender's axes to glTF's: (x, y, z) -> (x, z, -y).
TO_GLTF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Blender's light types by glTF's names.
LIGHT_TYPES = {"SUN": "directional", "SPOT": "spot", "POINT": "point"}


def views() -> list[dict]:
    """The current scene's cameras and lights (see the module's docstring)."""
    out = []
    for ob in bpy.context.scene.objects:
        if ob.type not in ("CAMERA", "LIGHT"):
            continue
        m = np.array(ob.matrix_world, np.float64)
        pose = np.eye(4)
        axes = TO_GLTF @ m[:3, :3]
        pose[:3, :3] = axes / np.linalg.norm(axes, axis=0)
        pose[:3, 3] = TO_GLTF @ m[:3, 3]
        if ob.type == "CAMERA":
            kind = "camera"
            angle = ob.data.angle_y if ob.data.type == "PERSP" else None
        else:
            kind = LIGHT_TYPES.get(ob.data.type, ob.data.type.lower())
            angle = ob.data.spot_size / 2 if ob.data.type == "SPOT" else None
        out.append({"kind": kind, "pose": pose.tolist(), "angle": angle})
    return out


def main() -> None:
    with open(sys.argv[1]) as f:
        pairs = json.load(f)
    for source, target in pairs:
        try:
            bpy.ops.wm.read_factory_settings(use_empty=True)
            bpy.ops.import_scene.gltf(filepath=source)
            np.save(target, world_triangles())
            with open(target + ".views.json", "w") as f:
                json.dump(views(), f)
        except Exception as exc:  # noqa: BLE001 (the importer's refusal, of any kind, is a result)
            with open(target + ".err", "w") as f:
                f.write(f"{type(exc).__name__}: {exc}"[:2000])


if __name__ == "__main__":
    main()
