"""Whether a scene already stands on a floor of its own, so ``ground: true`` adds none.

:meth:`Scene.with_ground` lays a plane three times the scene's footprint just below its lowest
point. On a scene that already has a floor there (a slab under a product shot, a stage, the demo
scene's own ground) that plane shows as a second, larger floor around and under the first one.
:func:`existing_floor` finds such a floor; the renderer then leaves the plane out and says so in
the render's warnings.
"""

from __future__ import annotations

import numpy as np

from .scene import Instance, Scene, instance_arrays

#: Share of the scene's extent along X and along Z a floor spans, at least.
FLOOR_COVER = 0.9
#: Thickest floor, as a share of the scene's larger horizontal extent.
FLOOR_THICKNESS = 0.05
#: Share of the scene's footprint the floor's upward-facing triangles cover, at least.
FLOOR_AREA = 0.8
#: Floors with more triangles than this are judged by their box alone (the area check reads
#: every triangle in world space).
FLOOR_CHECK_TRIANGLES = 200_000


def existing_floor(scene: Scene) -> Instance | None:
    """The scene's own floor, if it has one: a thin, shadow-receiving instance at the scene's
    lowest point that spans its footprint (``FLOOR_COVER`` of the X and Z extents) with
    upward-facing (+Y, glTF's up) triangles covering ``FLOOR_AREA`` of it.

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    Instance or None
        The largest such instance; None when there is none (or the scene is flat or empty).
    """
    if not scene.instances:
        return None
    arrays = instance_arrays(scene)
    lo, hi = arrays.box
    extent = hi - lo
    foot = float(max(extent[0], extent[2]))
    if not np.isfinite(foot) or foot <= 0 or extent[1] <= FLOOR_THICKNESS * foot:
        return None  # a flat scene is all floor: the added plane is its only receiver below
    boxes = arrays.bounds
    size = boxes[:, 1] - boxes[:, 0]
    candidates = np.flatnonzero(
        arrays.receive
        & (size[:, 0] >= FLOOR_COVER * extent[0]) & (size[:, 2] >= FLOOR_COVER * extent[2])
        & (size[:, 1] <= FLOOR_THICKNESS * foot)
        & (boxes[:, 0, 1] <= lo[1] + 1e-3 * foot))
    # Largest first: the one a second plane would show under.
    for i in sorted(candidates.tolist(), key=lambda i: -float(size[i, 0] * size[i, 2])):
        inst = scene.instances[i]
        if _up_area(scene, inst) >= FLOOR_AREA * float(extent[0] * extent[2]):
            return inst
    return None


def _up_area(scene: Scene, inst: Instance) -> float:
    """Area, projected on the XZ plane, of an instance's triangles that face +Y (either way
    for a double-sided material); infinite for meshes over :data:`FLOOR_CHECK_TRIANGLES`."""
    prim = scene.primitives[inst.primitive]
    if len(prim.indices) > FLOOR_CHECK_TRIANGLES:
        return float("inf")
    tri = scene.world_triangles(inst)
    if not len(tri):
        return 0.0
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    ny = np.divide(normal[:, 1], length, out=np.zeros_like(length), where=length > 0)
    if prim.material.double_sided:
        ny = np.abs(ny)
    # |n| / 2 is the triangle's area, times n_y its projection on the XZ plane.
    return float(np.sum(np.abs(normal[:, 1])[ny > 0.99]) / 2)
