"""The built-in demo scene: a few primitives on a ground plane, as binary glTF.

It is generated (not shipped) so the service and the tests can render something meaningful with no
file at hand: a box, a sphere, a thin cylinder on a slab that receives their shadows.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=1)
def demo_glb() -> bytes:
    """The demo scene as ``.glb`` bytes (about 60 kB)."""
    import trimesh

    def colored(mesh: trimesh.Trimesh, rgba: tuple[int, int, int, int]) -> trimesh.Trimesh:
        mesh.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(baseColorFactor=rgba)
        )
        return mesh

    scene = trimesh.Scene()
    ground = trimesh.creation.box(extents=(6.0, 0.1, 6.0))
    ground.unmerge_vertices()
    ground = colored(ground, (200, 200, 190, 255))
    scene.add_geometry(ground, node_name="ground",
                       transform=trimesh.transformations.translation_matrix((0, -0.05, 0)))
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.unmerge_vertices()  # flat faces: one normal per face corner
    box = colored(box, (200, 70, 60, 255))
    rot = trimesh.transformations.rotation_matrix(np.radians(30), (0, 1, 0))
    scene.add_geometry(box, node_name="box",
                       transform=trimesh.transformations.translation_matrix((-1.0, 0.5, 0.2)) @ rot)
    sphere = colored(trimesh.creation.icosphere(subdivisions=3, radius=0.6), (70, 120, 200, 255))
    scene.add_geometry(sphere, node_name="sphere",
                       transform=trimesh.transformations.translation_matrix((0.9, 0.6, -0.4)))
    pole = colored(trimesh.creation.cylinder(radius=0.06, height=2.0, sections=24),
                   (60, 160, 90, 255))
    up = trimesh.transformations.rotation_matrix(np.radians(-90), (1, 0, 0))
    scene.add_geometry(pole, node_name="pole",
                       transform=trimesh.transformations.translation_matrix((0.3, 1.0, 1.2)) @ up)
    return scene.export(file_type="glb")


DEMO_PARAMS: dict = {
    "width": 640,
    "height": 480,
    "camera": {"eye": [3.5, 3.0, 5.0], "target": [0.0, 0.4, 0.0], "yfov_deg": 45},
    "lights": [{"type": "directional", "direction": [-0.6, -1.0, 0.25]}],
    "outputs": ["color", "light_depth"],
}
