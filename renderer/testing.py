"""Scenes and measurements for tests and benchmarks: a public, documented module.

``shadowmap.renderer.testing`` is part of the library's API so that users can check their own
settings the way this project's tests and benchmarks do:

- :func:`measure`: render a scene's visibility and compare every light with the ray-traced
  reference (needs ``embreex``, the ``reference`` extra).
- Scene builders for stiff and extreme cases: a caster over a ground plane at any scale and
  offset, grazing light, thin sheets, contact, a room for point lights, many small objects; and
  large scenes seen from the ground (:func:`terrain_to_horizon`, :func:`small_caster_on_huge_plane`,
  :func:`city_grid`), each with the camera it is meant to be seen from.
- :func:`band_metrics`: the shadow error in bands of camera distance (near, middle, far).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from .camera import resolve_camera
from .lights import resolve_lights
from .params import RenderParams
from .scene import Instance, Material, Scene, scene_from_meshes, world_bounds

if TYPE_CHECKING:
    import trimesh

    from .metrics import ShadowMetrics
    from .render import Renderer


@dataclass
class Measurement:
    """One render compared with the reference.

    metrics : list of ShadowMetrics, one per light; result : RenderResult; reference :
    ReferenceResult; seconds : wall time of the render call.
    """

    metrics: list
    result: object
    reference: object
    seconds: float


def measure(renderer: Renderer, scene: Scene,
            params: RenderParams | dict[str, Any] | None = None) -> Measurement:
    """Render visibility with ``params`` and compare each light with the ray-traced reference."""
    from .metrics import compare_all
    from .reference import trace_reference

    if not isinstance(params, RenderParams):
        params = RenderParams.model_validate(params or {})
    params = params.model_copy(update={"outputs": sorted(set(params.outputs) | {"visibility"})})
    t = time.perf_counter()
    result = renderer.render(scene, params)
    seconds = time.perf_counter() - t
    vis = result.visibility
    assert vis is not None  # requested above
    camera = resolve_camera(params.camera, scene, params.width, params.height)
    lights = resolve_lights(params.lights, scene)
    ref = trace_reference(scene, camera, lights)
    return Measurement(compare_all(vis, ref), result, ref, seconds)


def moved_metrics(renderer: Renderer, scene: Scene,
                  params: Callable[[float, float], dict[str, Any]], scale: float,
                  offset: float) -> list[tuple[ShadowMetrics, ShadowMetrics]]:
    """Per light, the metrics of ``scene`` rendered with ``params(1, 0)`` beside those of the
    scene scaled by ``scale`` and moved by ``offset`` on every axis (:func:`transformed`),
    rendered with ``params(scale, offset)``: the request moved alike."""
    base = measure(renderer, scene, params(1.0, 0.0)).metrics
    moved = measure(renderer, transformed(scene, scale, (offset,) * 3),
                    params(scale, offset)).metrics
    return list(zip(base, moved, strict=True))


def transformed(scene: Scene, scale: float = 1.0,
                offset: Sequence[float] = (0.0, 0.0, 0.0)) -> Scene:
    """The same scene scaled about the origin and then translated (in float64 node matrices),
    with the file's cameras and lights: placed alike, their ranges (near and far planes, a
    light's range) scaled, their orientation kept."""
    m = np.diag([scale, scale, scale, 1.0])
    m[:3, 3] = offset
    instances = [
        Instance(
            inst.primitive,
            m @ inst.matrix,
            inst.cast_shadow,
            inst.receive_shadow,
            inst.name,
            world_bounds(scene.primitives[inst.primitive].local_bounds.astype(np.float64),
                          m @ inst.matrix),
        )
        for inst in scene.instances
    ]
    focus = None if scene.focus is None else scene.focus * scale + np.asarray(offset)

    def placed(pose: np.ndarray) -> np.ndarray:
        out = np.array(pose, np.float64)
        out[:3, 3] = out[:3, 3] * scale + np.asarray(offset, np.float64)
        return out

    def scaled(value: float | None) -> float | None:
        return None if value is None else value * scale

    cameras = [dataclasses.replace(c, pose=placed(c.pose), znear=scaled(c.znear),
                                   zfar=scaled(c.zfar), ymag=scaled(c.ymag))
               for c in scene.cameras]
    lights = [dataclasses.replace(light, pose=placed(light.pose), range=scaled(light.range))
              for light in scene.lights]
    return Scene(scene.primitives, instances, cameras, lights,
                 key=f"{scene.key}:{scale!r}:{tuple(offset)!r}", focus=focus,
                 warnings=list(scene.warnings))


def _box(extents: npt.ArrayLike, centre: npt.ArrayLike, **meta: bool) -> trimesh.Trimesh:
    import trimesh

    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(centre)
    mesh.metadata.update(meta)
    return mesh


def _plane(size: float, y: float = 0.0, **meta: bool) -> trimesh.Trimesh:
    import trimesh

    h = size / 2
    mesh = trimesh.Trimesh(
        vertices=[[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]],
        faces=[[0, 2, 1], [0, 3, 2]],
        process=False,
    )
    mesh.metadata.update(meta)
    return mesh


def caster_on_ground() -> Scene:
    """A unit box floating 0.5 above a 6 x 6 ground plane, plus a post touching the ground."""
    return scene_from_meshes(
        [_plane(6.0), _box((1, 1, 1), (0, 1.0, 0)), _box((0.3, 1.2, 0.3), (1.6, 0.6, 0.8))],
        ["ground", "box", "post"],
    )


def grazing_plane() -> Scene:
    """A large flat ground and a low wall: acne shows on the ground under grazing light."""
    return scene_from_meshes(
        [_plane(20.0), _box((4, 0.5, 0.2), (0, 0.25, -2))], ["ground", "wall"]
    )


def room() -> Scene:
    """A closed 8 x 4 x 8 room of six inward-facing walls, with a box and a pillar inside."""
    import trimesh

    walls, names = [], []
    h = np.array([4.0, 2.0, 4.0])
    centre = np.array([0.0, 2.0, 0.0])
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            corners = []
            for cu, cv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = centre.copy()
                p[axis] += sign * h[axis]
                p[u] += cu * h[u]
                p[v] += cv * h[v]
                corners.append(p)
            wall = trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)
            if np.dot(wall.face_normals[0], centre - corners[0]) < 0:
                wall.invert()  # face the inside
            walls.append(wall)
            names.append(f"wall_{'xyz'[axis]}{'-+'[sign > 0]}")
    return scene_from_meshes(
        walls + [_box((1, 1, 1), (1.5, 0.5, 1.0)), _box((0.4, 3.0, 0.4), (-1.5, 1.5, -1.0))],
        names + ["box", "pillar"],
    )


def thin_sheets() -> Scene:
    """Two-sided zero-thickness sheets (a roof and a tilted panel) above the ground."""
    import trimesh

    roof = _plane(1.5, 1.2)
    panel = trimesh.Trimesh(
        vertices=[[1.0, 0.3, -0.5], [2.0, 0.3, -0.5], [2.0, 1.3, 0.2], [1.0, 1.3, 0.2]],
        faces=[[0, 1, 2], [0, 2, 3]],
        process=False,
    )
    scene = scene_from_meshes([_plane(8.0), roof, panel], ["ground", "roof", "panel"])
    scene.primitives[1:] = [
        dataclasses.replace(p, material=Material(p.material.base_color, double_sided=True))
        for p in scene.primitives[1:]]
    return scene


def degenerate_geometry() -> Scene:
    """Zero-area triangles, duplicated vertices and a lone triangle over a ground plane."""
    import trimesh

    box = trimesh.creation.box(extents=(1, 1, 1))
    box.apply_translation((0, 1.0, 0))
    v = np.vstack([box.vertices, box.vertices[:3]])  # duplicated vertices
    f = np.vstack([box.faces, [[0, 0, 1], [8, 9, 10], [2, 2, 2]]])  # zero-area and duplicates
    messy = trimesh.Trimesh(vertices=v, faces=f, process=False)
    lone = trimesh.Trimesh(vertices=[[1.2, 0.8, 0.5], [2.2, 0.8, 0.5], [1.7, 0.8, -0.5]],
                           faces=[[0, 1, 2]], process=False)
    scene = scene_from_meshes([_plane(6.0), messy, lone], ["ground", "messy", "lone"])
    prim = scene.primitives[2]
    scene.primitives[2] = dataclasses.replace(
        prim, material=Material(prim.material.base_color, double_sided=True))
    return scene


def part_far_out(far: float, origin_box: bool = True) -> Scene:
    """A vast scene of two parts: a 10 x 10 tile with a box and a post on it (the caster on
    the ground of :func:`caster_on_ground`, a larger tile), placed ``far`` units along X by its
    instance matrices (as glTF nodes place parts), and a unit box at the world's origin
    (``origin_box``). The scene's centre lies half-way between; a close view of the tile
    needs the precision that only an origin beside the eye gives."""
    parts = [_plane(10.0), _box((1, 1, 1), (0, 1.0, 0)), _box((0.3, 1.2, 0.3), (1.6, 0.6, 0.8))]
    built = scene_from_meshes(parts + ([_box((1, 1, 1), (0, 0.5, 0))] if origin_box else []))
    instances = []
    for i, inst in enumerate(built.instances):
        m = np.eye(4)
        m[0, 3] = far if i < len(parts) else 0.0
        local = built.primitives[inst.primitive].local_bounds.astype(np.float64)
        instances.append(Instance(inst.primitive, m, inst.cast_shadow, inst.receive_shadow,
                                  inst.name, world_bounds(local, m)))
    return Scene(built.primitives, instances, key=f"part_far_out:{far!r}:{origin_box}")


def many_small_objects(n: int = 200, seed: int = 3) -> Scene:
    """A box over a ground plane, plus ``n`` small boxes 60-90 units away along +Z (behind a
    camera at positive Z looking at the origin)."""
    rng = np.random.default_rng(seed)
    meshes = [_plane(6.0), _box((1, 1, 1), (0, 1.0, 0))]
    for _ in range(n):
        # Behind a camera that looks toward -Z at the origin, and beside the ground.
        c = (rng.uniform(-30, 30), rng.uniform(-5, 30), rng.uniform(60, 90))
        meshes.append(_box((0.3, 0.3, 0.3), c))
    return scene_from_meshes(meshes, ["ground", "box"] + [f"far_{i}" for i in range(n)])


def pebbles_on_a_plain(size: float = 400.0) -> Scene:
    """Seven 0.3-unit cubes on a ground plane ``size`` units wide, seen up to the horizon.

    The ground casts too (no extras): a fit that covered every caster would spread the map over
    the whole plain.
    """
    meshes = [_plane(size)]
    for x in np.linspace(-3, 3, 7):
        meshes.append(_box((0.3, 0.3, 0.3), (x, 0.15, 0.0)))
    return scene_from_meshes(meshes, ["ground"] + [f"pebble_{i}" for i in range(7)])


@dataclass(frozen=True)
class LargeScene:
    """A large scene and how it is meant to be seen.

    Attributes
    ----------
    scene : Scene
    camera : dict
        The request's ``camera`` (eye, target).
    light : dict
        A directional light (the request's ``lights`` entry).
    bands : tuple of float
        Camera distances that separate the bands of :func:`band_metrics`.
    """

    scene: Scene
    camera: dict
    light: dict
    bands: tuple[float, ...]


def terrain_to_horizon(size: float = 1000.0) -> LargeScene:
    """A ``size``-unit ground and boxes from 4 to 400 units away, seen from 2 units up looking
    toward the horizon: one map over the whole view leaves nothing for the near boxes."""
    meshes = [_plane(size)]
    names = ["terrain"]
    for k, z in enumerate((4, 7, 12, 20, 35, 60, 100, 170, 280, 400)):
        side = 0.4 + 0.02 * z  # farther boxes are larger, so each spans a few pixels
        for x in (-1.5, 1.5):
            meshes.append(_box((side, side * 2, side), (x * (1 + z / 12), side, -z)))
            names.append(f"box_{k}_{'lr'[x > 0]}")
    camera = {"eye": [0.0, 2.0, 2.0], "target": [0.0, 0.6, -30.0]}
    light = {"type": "directional", "direction": [0.6, -0.5, 0.45]}
    return LargeScene(scene_from_meshes(meshes, names), camera, light, (15.0, 80.0))


def small_caster_on_huge_plane(size: float = 10_000.0) -> LargeScene:
    """A 1-unit box on a ``size``-unit ground, both in one mesh (one instance, one box over the
    whole plane for the planner), seen from a few units away."""
    import trimesh

    mesh = trimesh.util.concatenate([_plane(size), _box((1, 1, 1), (0, 0.5, 0))])
    camera = {"eye": [3.0, 2.5, 4.0], "target": [0.0, 0.3, 0.0]}
    light = {"type": "directional", "direction": [0.5, -1.0, 0.7]}
    return LargeScene(scene_from_meshes([mesh], ["ground_and_box"]), camera, light, (8.0, 40.0))


def city_grid(n: int = 1000, pitch: float = 12.0, seed: int = 5) -> LargeScene:
    """``n`` boxes (blocks 4-8 units wide, 4-30 tall) on a square grid of streets over a ground,
    seen from street level (1.7 units up) along a street."""
    rng = np.random.default_rng(seed)
    side = int(math.ceil(math.sqrt(n)))
    meshes = [_plane(side * pitch * 1.5)]
    names = ["ground"]
    half = (side - 1) / 2
    for k in range(n):
        i, j = divmod(k, side)
        w, d = rng.uniform(4, 8, 2)
        h = rng.uniform(4, 30)
        centre = ((i - half) * pitch, h / 2, (j - half) * pitch)
        meshes.append(_box((w, h, d), centre))
        names.append(f"block_{i}_{j}")
    street = (0.5 - half % 1) * pitch  # the x of a street between two rows of blocks
    camera = {"eye": [street, 1.7, half * pitch], "target": [street, 4.0, -half * pitch]}
    light = {"type": "directional", "direction": [-0.45, -0.75, -0.5]}
    return LargeScene(scene_from_meshes(meshes, names), camera, light, (30.0, 150.0))


def band_metrics(rendered: np.ndarray, reference: object, bands: Sequence[float],
                 light: int = 0) -> list:
    """Shadow metrics of one light in bands of camera distance.

    Parameters
    ----------
    rendered : ndarray, shape (H, W, L)
        ``RenderResult.visibility``.
    reference : ReferenceResult
        Its depth (camera z) decides the band of each pixel.
    bands : sequence of float
        Increasing distances: ``k`` of them make ``k + 1`` bands (near to far).
    light : int

    Returns
    -------
    list of ShadowMetrics
        One per band, near first.
    """
    from .metrics import shadow_metrics

    ref: Any = reference  # a ReferenceResult (imported lazily: it needs embreex)
    depth = np.asarray(ref.depth, np.float64)
    valid = np.asarray(ref.valid)[..., light].astype(np.bool_)
    vis_ref = np.asarray(ref.visibility)[..., light]
    edges = [0.0, *bands, np.inf]
    out = []
    for lo, hi in itertools.pairwise(edges):
        band = valid & (depth >= lo) & (depth < hi)
        out.append(shadow_metrics(rendered[..., light], vis_ref, band))
    return out


def ground_only_receives() -> Scene:
    """The caster-on-ground scene with ``castShadow = false`` on the ground (three.js extras)."""
    scene = caster_on_ground()
    scene.instances[0] = dataclasses.replace(scene.instances[0], cast_shadow=False)
    return scene


#: The lights the corpus test and ``bench/corpus.py`` shine on every model, and the shadow IoU
#: each must reach against the reference.
CORPUS_LIGHT_KINDS = ("directional", "spot", "point")
CORPUS_IOU = 0.97


def corpus_lights(scene: Scene) -> dict[str, list[dict]]:
    """A directional, a spot and a point light for ``scene``, placed from its bounds (request
    dicts, one list per kind of :data:`CORPUS_LIGHT_KINDS`): the spot and the point light above
    the scene, 2.1 and 1.6 bounding radii from its centre, off to one side."""
    lo, hi = scene.bounds
    c = (lo + hi) / 2
    r = float(np.linalg.norm(hi - lo)) / 2
    return {
        "directional": [{"type": "directional", "direction": [-0.5, -1.0, 0.2]}],
        "spot": [{"type": "spot", "position": (c + np.array([0.3, 2.0, 0.4]) * r).tolist(),
                  "target": c.tolist(), "outer_cone_deg": 50}],
        "point": [{"type": "point", "position": (c + np.array([0.2, 1.5, 0.3]) * r).tolist()}],
    }


__all__ = [
    "CORPUS_IOU",
    "CORPUS_LIGHT_KINDS",
    "LargeScene",
    "Measurement",
    "band_metrics",
    "city_grid",
    "corpus_lights",
    "small_caster_on_huge_plane",
    "terrain_to_horizon",
    "caster_on_ground",
    "degenerate_geometry",
    "grazing_plane",
    "ground_only_receives",
    "many_small_objects",
    "measure",
    "pebbles_on_a_plain",
    "room",
    "thin_sheets",
    "transformed",
]
