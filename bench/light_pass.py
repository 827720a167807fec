"""What the light pass costs, and what leaving out the far side of closed casters saves.

A closed caster (its triangles close a surface: :func:`shadowmap.renderer.plan.instances.
primitive_closure`) seen from a light outside it first shows the light its faces turned toward
it; the faces turned away lie behind them and change no texel of the map. The plan marks such
casters one-sided (:func:`shadowmap.renderer.plan.plan.one_sided_casters`) and the light pass
culls their far faces. Per scene of ``bench/floor.py`` (640x480, default settings) and, for three
scenes, at fixed map sizes, interleaved with rotation:

- *both faces*: the plan with no caster one-sided (every face drawn, as before the rule);
- *one-sided*: the plan as made.

Each frame draws its light pass (the light-map cache emptied first); the light pass's fenced
time (``timings["light"]``) and the whole frame are reported, and the two arms' maps are read
back and compared texel for texel: they agree but where a closed caster's front and back faces
meet at its silhouette, whose texel centres both cover at nearly one depth, and drawing both kept
the back face's when rounding put it a step nearer (the front face is the true first surface).
*Closure ms*: deciding which
primitives are closed, once per scene on its first shadowed plan (then cached).

Writes ``bench/results/light_pass.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/light_pass.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from bench import _common as C  # first: selects the GL platform
from bench.floor import instances_scene  # noqa: E402
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.plan import instances as I  # noqa: E402
from shadowmap.renderer.plan import plan as P  # noqa: E402

QUICK_SCENES = ("Duck", "caster_on_ground")
SIZE_SCENES = ("Duck", "CesiumMilkTruck", "boxes_10k")
SIZES = (1024, 2048, 4096)
QUICK_SIZES = (2048,)
_ONE_SIDED = P.one_sided_casters


def _both_faces(ctx: Any, m: Any) -> np.ndarray:
    return np.zeros(0, np.int8)


def _arm(p: RenderParams, k: int) -> RenderParams:
    """The same request as another object (its own plan in the renderer's plan cache)."""
    return p.model_copy(update={"background": [0.0, 0.0, 0.0, k / 100]})


def call(r: Renderer, scene, p: RenderParams, one_sided: bool):
    """One frame with its light pass drawn; the plan made with or without one-sided casters."""
    P.one_sided_casters = _ONE_SIDED if one_sided else _both_faces
    try:
        r.light_pass.cache.clear()
        return r.render(scene, p)
    finally:
        P.one_sided_casters = _ONE_SIDED


def maps_of(r: Renderer, scene, p: RenderParams, one_sided: bool
            ) -> tuple[list[np.ndarray], Any, np.ndarray]:
    """The light pass's maps of one frame, read back (NaN where nothing was drawn), with the
    plan and the upload's origin."""
    P.one_sided_casters = _ONE_SIDED if one_sided else _both_faces
    try:
        r.light_pass.cache.clear()
        r.plans.clear()
        from shadowmap.renderer.camera import resolve_camera
        from shadowmap.renderer.lights import resolve_lights

        gpu, _, _ = r._upload(scene)
        camera = resolve_camera(p.camera, scene, p.width, p.height)
        plan = P.make_plan(scene, camera, resolve_lights(p.lights, scene), gpu.origin, p)
        maps = r.light_pass.render(gpu, plan.lights, p.shadows, "")
        return [m.read_depth() for m in maps], plan, gpu.origin
    finally:
        P.one_sided_casters = _ONE_SIDED


def map_difference(a: list[np.ndarray], b: list[np.ndarray]) -> tuple[int, float]:
    """(texels whose depth differs, the largest difference in steps of 1/65535)."""
    if len(a) != len(b) or any(x.shape != y.shape for x, y in zip(a, b, strict=True)):
        raise AssertionError("the two arms drew different maps")
    differ, largest = 0, 0.0
    for x, y in zip(a, b, strict=True):
        if not np.array_equal(np.isnan(x), np.isnan(y)):
            raise AssertionError("the two arms covered different texels")
        d = np.abs(x.astype(np.float64) - y)[~np.isnan(x)]
        differ += int(np.count_nonzero(d))
        largest = max(largest, float(d.max(initial=0.0)) * 65535)
    return differ, largest


def traced_depths(scene, plan, origin: np.ndarray, rows: np.ndarray, cols: np.ndarray
                  ) -> np.ndarray:
    """The first surface's stored depth t at texel centres of the plan's one 2D map, ray traced
    (trimesh + Embree, origin-relative: float32 near the scene); NaN where a ray hits nothing.

    Both kinds of 2D map store view depth linearly over [near, far]
    (``chunks/shadow_2d.glsl``); row 0 is the top of the light's view (``read_depth``).
    """
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    lp = plan.lights[0]
    tris = np.concatenate([scene.world_triangles(i, origin) for i in scene.instances])
    mesh = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3),
                           process=False)
    size = lp.map_size
    x, y = (cols + 0.5) / size * 2 - 1, 1 - (rows + 0.5) / size * 2
    inv = np.linalg.inv(lp.proj @ lp.view)

    def unproject(z: float) -> np.ndarray:
        v = np.stack([x, y, np.full_like(x, z), np.ones_like(x)], axis=1) @ inv.T
        return v[:, :3] / v[:, 3:]

    start, end = unproject(-1.0), unproject(1.0)
    direction = end - start
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    hits, ray, _ = RayMeshIntersector(mesh).intersects_location(start, direction,
                                                                multiple_hits=False)
    t = np.full(len(start), np.nan)
    depth = -(hits @ lp.view[2, :3] + lp.view[2, 3])
    t[ray] = (depth - lp.near) / (lp.far - lp.near)
    return t


def nearer_truth(scene, a: list[np.ndarray], b: list[np.ndarray], plan, origin: np.ndarray
                 ) -> float:
    """Of the texels where the two arms differ, the share where the one-sided map's depth is at
    least as near the ray-traced first surface as the both-faces map's (NaN: none differ, or
    the map is no single 2D map)."""
    lights = [lp for lp in plan.lights if lp.kind is not None]
    if len(a) != 1 or len(lights) != 1 or lights[0].kind == "cube" or lights[0].cascades:
        return float("nan")
    x, y = a[0].astype(np.float64), b[0].astype(np.float64)
    rows, cols = np.nonzero(~np.isnan(x) & (x != y))
    if not len(rows):
        return float("nan")
    t = traced_depths(scene, plan, origin, rows, cols)
    ok = ~np.isnan(t)
    both, one = np.abs(x[rows, cols] - t)[ok], np.abs(y[rows, cols] - t)[ok]
    return float(np.mean(one <= both)) if ok.any() else float("nan")


def closure_ms(scene) -> float:
    """Deciding every primitive's closure afresh (what a scene's first shadowed plan adds)."""
    t = time.perf_counter()
    for prim in scene.primitives:
        I._CLOSURE.pop(prim, None)
        I.primitive_closure(prim)
    return (time.perf_counter() - t) * 1e3


def large_closure_ms(repeats: int) -> tuple[int, float]:
    """(triangles, median ms) of deciding the closure of one large closed mesh: an icosphere
    of 327,680 triangles (its vertices split per triangle, as a file splits them at creases,
    would only add to the weld)."""
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    prim = scene_from_meshes([trimesh.creation.icosphere(subdivisions=7)], ["sphere"]).primitives[0]
    times = []
    for _ in range(max(3, repeats)):
        I._CLOSURE.pop(prim, None)
        t = time.perf_counter()
        assert I.primitive_closure(prim) == 1
        times.append((time.perf_counter() - t) * 1e3)
    return len(prim.indices), C.median(times)


def one_sided_counts(result) -> tuple[int, int]:
    """(casters, one-sided casters) over the plan's maps, as the plan reports them."""
    casters = sided = 0
    for lt in result.plan["lights"]:
        for m in lt.get("cascades") or ([lt] if lt.get("shadow_map") else []):
            casters += m["casters"]
            sided += m.get("one_sided", 0)
    return casters, sided


def run(quick: bool, repeats: int) -> None:
    t_start = time.perf_counter()
    scenes = [*C.model_scenes(), *(C.stress_scene(n) for n in C.STRESS_SCENES),
              instances_scene()]
    if quick:
        scenes = [s for s in scenes if s.name in QUICK_SCENES]
    sizes = QUICK_SIZES if quick else SIZES
    size_scenes = [s for s in scenes if s.name in SIZE_SCENES]
    cases: list[tuple[C.BenchScene, str | int]] = [(s, "auto") for s in scenes]
    cases += [(s, size) for size in sizes for s in size_scenes]
    r = Renderer()
    bar = C.Progress(len(cases), "light pass")
    rows, size_rows, csv_rows = [], [], []
    for bs, size in cases:
        p = bs.params(shadows={"map_size": size})
        arms = {"both faces": _arm(p, 1), "one-sided": _arm(p, 2)}
        scene = bs.scene
        t = C.time_interleaved({k: (lambda q=q, k=k, s=scene: call(r, s, q, k == "one-sided"))
                                for k, q in arms.items()}, repeats, warmup=2, rotate=True)
        (a, _, _), (b, plan, origin) = (maps_of(r, bs.scene, p, False),
                                        maps_of(r, bs.scene, p, True))
        differ, steps = map_difference(a, b)
        nearer = nearer_truth(bs.scene, a, b, plan, origin)
        casters, sided = one_sided_counts(t["one-sided"].last)
        light = {k: t[k].ms("light") for k in arms}
        frame = {k: t[k].ms() for k in arms}
        saved = 1 - light["one-sided"] / light["both faces"]
        map_sizes = sorted({m["map_size"] for lt in t["one-sided"].last.plan["lights"]
                            if lt.get("shadow_map")
                            for m in (lt.get("cascades") or [lt])})
        row = [bs.name, "/".join(map(str, map_sizes)) or "-", f"{sided} of {casters}",
               C.fmt(light["both faces"], 2), C.fmt(light["one-sided"], 2),
               f"{100 * saved:.0f} %", C.fmt(frame["both faces"], 2),
               C.fmt(frame["one-sided"], 2), f"{differ} ({steps:.1f})" if differ else "0",
               "—" if np.isnan(nearer) else f"{100 * nearer:.0f} %"]
        if size == "auto":
            row.insert(3, C.fmt(closure_ms(bs.scene), 2))
            rows.append(row)
        else:
            size_rows.append(row)
        csv_rows.append({"scene": bs.name, "map_size": size, "casters": casters,
                         "one_sided": sided, "light_both_ms": round(light["both faces"], 3),
                         "light_one_sided_ms": round(light["one-sided"], 3),
                         "frame_both_ms": round(frame["both faces"], 3),
                         "frame_one_sided_ms": round(frame["one-sided"], 3),
                         "texels_differing": differ, "largest_difference_steps": steps,
                         "one_sided_nearer_traced": nearer})
        bar.step(f"{bs.name} {size}")
    bar.close()
    head = ["scene", "map size", "one-sided casters", "light pass, both faces ms",
            "light pass, one-sided ms", "light pass saved", "frame, both faces ms",
            "frame, one-sided ms", "texels differing (largest, steps)",
            "of those, one-sided as near the traced depth"]
    table = C.markdown_table(head[:3] + ["closure ms"] + head[3:], rows)
    size_table = C.markdown_table(head, size_rows)
    auto = [c for c in csv_rows if c["map_size"] == "auto" and c["one_sided"]]
    ratios = [c["light_one_sided_ms"] / c["light_both_ms"] for c in auto]
    geo = float(np.exp(np.mean(np.log(ratios)))) if ratios else float("nan")
    notes = [f"- Scenes with one-sided casters: the light pass takes {geo:.2f}x its time with "
             f"both faces drawn (geometric mean over {len(ratios)} scenes, default map sizes).",
             f"- Texels whose depth differs between the arms: at most "
             f"{max(c['texels_differing'] for c in csv_rows)} per frame, by at most "
             f"{max(c['largest_difference_steps'] for c in csv_rows):.1f} steps of 1/65535 "
             "of the map's depth range."]
    tris, big_ms = large_closure_ms(repeats)
    notes.append(f"- Closure of one closed mesh of {tris:,} triangles: {big_ms:.0f} ms (median "
                 f"of {max(3, repeats)}; once per primitive, kept with the scene).")
    traced = [c for c in csv_rows if c["texels_differing"] and not np.isnan(
        c["one_sided_nearer_traced"])]
    if traced:
        total = sum(c["texels_differing"] for c in traced)
        share = sum(c["one_sided_nearer_traced"] * c["texels_differing"] for c in traced) / total
        notes.append(f"- Of the {total} differing texels of single 2D maps, the one-sided map "
                     f"is at least as near the ray-traced first surface in {100 * share:.0f} %.")
    md = "\n".join([
        "# The light pass: leaving out the far side of closed casters", "",
        f"640x480, default settings (`map_size` as given), medians of {repeats} interleaved "
        "calls (each repeat starting one arm later) after two warm-ups; every frame draws its "
        "light pass. *Both faces*: the plan with no caster one-sided; *one-sided*: as made. "
        "*Light pass*: its fenced time (`timings[\"light\"]`). *Texels differing*: the two "
        "arms' maps read back and compared texel for texel, with the largest difference in "
        "steps of 1/65535 of the map's depth range (only at silhouettes, where a closed "
        "caster's front and back faces meet); *as near the traced depth*: the share of those "
        "texels where the one-sided map is at least as near the ray-traced first surface as the "
        "map with both faces (single 2D maps). *Closure ms*: deciding which primitives close a "
        "surface, once per scene.", "", table, "",
        "## Fixed map sizes", "", size_table, "", *notes, "",
        f"Machine: {C.machine_info(r)}. Run time {time.perf_counter() - t_start:.0f} s.", ""])
    r.close()
    C.finish(C.results_dir(quick), "light_pass", md, csv_rows, [table, size_table], notes,
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "two scenes, one map size, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
