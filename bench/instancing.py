"""Many instances of one mesh: load, plan, both passes and the shadow error at 1k, 10k and 50k.

Each scene is a field of ``n`` copies of one small box (one :class:`Primitive`, ``n``
:class:`Instance` objects, each turned about +Y and stretched in height, on a square grid) over a
ground plane, lit by one directional light, seen two ways (:data:`VIEWS`): the whole field
(automatic framing, every box in view) and one corner from above (a few hundred boxes in view,
the rest culled). Per size and view it measures:

- **load**: reading a ``.glb`` written with ``EXT_mesh_gpu_instancing`` (one node, ``n``
  instances) when the scene reader expands that extension; otherwise the time to build the
  :class:`Scene` object in Python (the instance matrices and their world bounds), and the table
  says so;
- **first render**: the first ``Renderer.render`` of the scene (includes the upload);
- **plan, light, camera, total**: medians of repeated renders of the uploaded scene, all cases
  interleaved (A B C A B C ...), from ``RenderResult.timings``; the plan and light-map caches
  are emptied before each, so every timed render plans and draws its maps;
- **plan µs / instance**: :func:`make_plan` alone, repeated, over the instance count, with the
  plan's per-scene cache cold (a new scene object) and warm (the same scene again);
- **IoU**: the shadow mask against the ray-traced reference
  (:func:`shadowmap.renderer.testing.measure`, once per case: the reference is slow at 50k);
- **CLI s**: ``shadowmap render`` on the ``.glb`` in a new process, median of :data:`CLI_RUNS`
  runs (``--no-cli`` leaves it out).

With ``--profile`` the 50k render is profiled with cProfile (first render and a repeat) and the
top of each profile is written next to the results. ``--plan-only`` measures just the plan cost.

Writes ``bench/results/instancing.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/instancing.py [--quick] [--repeats N] [--plan-only]
[--profile] [--no-cli] [--sizes 1000,10000,50000]``
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import math
import pstats
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import _common as C  # before anything that imports PyOpenGL: selects the platform
from shadowmap.renderer import Renderer, RenderParams, Scene, load_scene  # noqa: E402
from shadowmap.renderer import testing as T  # noqa: E402
from shadowmap.renderer.camera import resolve_camera  # noqa: E402
from shadowmap.renderer.lights import resolve_lights  # noqa: E402
from shadowmap.renderer.plan import make_plan  # noqa: E402
from shadowmap.renderer.scene import (  # noqa: E402
    Instance,
    Primitive,
    scene_from_meshes,
    world_bounds,
)

SIZES = (1_000, 10_000, 50_000)
QUICK_SIZES = (1_000, 10_000)
#: Grid pitch and box footprint: the boxes stand 1.5 apart, 0.6 wide, 1.0-1.6 tall, so that
#: their shadows fall onto the ground between them and onto their neighbours.
PITCH = 1.5
BOX = (0.6, 1.0, 0.6)
LIGHT = {"type": "directional", "direction": [-0.45, -1.0, -0.3]}
STAGES = ("load", "upload", "plan", "light", "camera", "readback", "total")


# --------------------------------------------------------------------------------------------
# The scene
# --------------------------------------------------------------------------------------------


def box_primitive() -> Primitive:
    """One small box (12 triangles), standing on y = 0 in its local frame."""
    import trimesh

    mesh = trimesh.creation.box(extents=BOX)
    mesh.apply_translation((0.0, BOX[1] / 2, 0.0))
    return scene_from_meshes([mesh], ["box"]).primitives[0]


def grid_matrices(n: int, seed: int = 7) -> np.ndarray:
    """Local-to-world matrices (n, 4, 4) of ``n`` boxes on a square grid centred on the origin.

    Each box is turned about +Y by a random angle and stretched in height by 1.0-1.6, so the
    instances differ in more than their position (and none is mirrored).
    """
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    k = np.arange(n)
    x = (k % side - (side - 1) / 2) * PITCH
    z = (k // side - (side - 1) / 2) * PITCH
    yaw = rng.uniform(0, 2 * math.pi, n)
    height = rng.uniform(1.0, 1.6, n)
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.zeros((n, 4, 4))
    m[:, 0, 0], m[:, 0, 2] = c, s
    m[:, 1, 1] = height
    m[:, 2, 0], m[:, 2, 2] = -s, c
    m[:, 0, 3], m[:, 2, 3] = x, z
    m[:, 3, 3] = 1.0
    return m


def build_scene(n: int, prim: Primitive | None = None) -> Scene:
    """The field of ``n`` boxes as a :class:`Scene` built in Python, with its ground plane."""
    prim = prim or box_primitive()
    local = prim.local_bounds.astype(np.float64)
    instances = [Instance(0, m, name=f"box_{i}", bounds=world_bounds(local, m))
                 for i, m in enumerate(grid_matrices(n))]
    return Scene([prim], instances, key=f"instancing:{n}").with_ground()


def instancing_glb(n: int, prim: Primitive | None = None) -> bytes:
    """A ``.glb`` of the field: one mesh, one node with ``EXT_mesh_gpu_instancing`` (TRANSLATION,
    ROTATION, SCALE accessors of ``n`` instances), and a second node with a ground quad."""
    prim = prim or box_primitive()
    m = grid_matrices(n)
    yaw = np.arctan2(m[:, 0, 2], m[:, 0, 0])
    # Rotation about +Y by yaw as the quaternion (x, y, z, w).
    rot = np.stack([np.zeros(n), np.sin(yaw / 2), np.zeros(n), np.cos(yaw / 2)], axis=1)
    scale = np.stack([np.ones(n), m[:, 1, 1], np.ones(n)], axis=1)
    trans = m[:, :3, 3]
    field = m[:, :3, 3]
    half = float(np.abs(field).max()) * 1.5 + 5.0
    ground_pos = np.array([[-half, 0, -half], [half, 0, -half], [half, 0, half],
                           [-half, 0, half]], np.float32)
    ground_nrm = np.tile(np.array([0, 1, 0], np.float32), (4, 1))
    ground_idx = np.array([0, 2, 1, 0, 3, 2], np.uint32)

    blobs: list[bytes] = []
    views: list[dict] = []
    accessors: list[dict] = []

    def add(arr: np.ndarray, kind: str, component: int, target: int | None = None,
            minmax: bool = False) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        offset = sum(len(b) for b in blobs)
        blobs.append(data + b"\0" * (-len(data) % 4))
        view: dict = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        acc: dict = {"bufferView": len(views) - 1, "componentType": component,
                     "count": int(arr.shape[0]), "type": kind}
        if minmax:
            acc["min"] = arr.min(axis=0).tolist()
            acc["max"] = arr.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    f32, u32 = 5126, 5125
    box = {"POSITION": add(prim.positions, "VEC3", f32, 34962, True),
           "NORMAL": add(prim.normals, "VEC3", f32, 34962)}
    box_idx = add(prim.indices.reshape(-1).astype(np.uint32), "SCALAR", u32, 34963)
    ground = {"POSITION": add(ground_pos, "VEC3", f32, 34962, True),
              "NORMAL": add(ground_nrm, "VEC3", f32, 34962)}
    ground_i = add(ground_idx, "SCALAR", u32, 34963)
    inst = {"TRANSLATION": add(trans.astype(np.float32), "VEC3", f32),
            "ROTATION": add(rot.astype(np.float32), "VEC4", f32),
            "SCALE": add(scale.astype(np.float32), "VEC3", f32)}
    doc = {
        "asset": {"version": "2.0", "generator": "bench/instancing.py"},
        "extensionsUsed": ["EXT_mesh_gpu_instancing"],
        "extensionsRequired": ["EXT_mesh_gpu_instancing"],
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "boxes", "mesh": 0,
             "extensions": {"EXT_mesh_gpu_instancing": {"attributes": inst}}},
            {"name": "ground", "mesh": 1,
             "extras": {"castShadow": False}},
        ],
        "meshes": [
            {"name": "box", "primitives": [{"attributes": box, "indices": box_idx,
                                            "material": 0}]},
            {"name": "ground", "primitives": [{"attributes": ground, "indices": ground_i,
                                               "material": 1}]},
        ],
        "materials": [
            {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.5, 0.3, 1.0]}},
            {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0]},
             "doubleSided": True},
        ],
        "bufferViews": views,
        "accessors": accessors,
        "buffers": [{"byteLength": sum(len(b) for b in blobs)}],
    }
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    binary = b"".join(blobs)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return b"".join([b"glTF", struct.pack("<II", 2, total),
                     struct.pack("<II", len(js), 0x4E4F534A), js,
                     struct.pack("<II", len(binary), 0x004E4942), binary])


def load_or_build(n: int, glb: bytes) -> tuple[Scene, float, str]:
    """(scene, seconds, how): the ``.glb`` through the scene reader when it expands
    ``EXT_mesh_gpu_instancing`` into ``n`` instances, else the scene built in Python."""
    t = time.perf_counter()
    try:
        scene = load_scene(glb, file_type="glb")
    except Exception as exc:  # noqa: BLE001 - a reader without the extension may refuse it
        loaded, why = None, f"{type(exc).__name__}"
    else:
        loaded, why = scene, f"{len(scene.instances)} instances"
    seconds = time.perf_counter() - t
    if loaded is not None and len(loaded.instances) >= n:
        return loaded, seconds, "load_scene of the .glb (EXT_mesh_gpu_instancing)"
    t = time.perf_counter()
    built = build_scene(n)
    return built, time.perf_counter() - t, f"Scene built in Python (the reader gave {why})"


@dataclass(frozen=True)
class View:
    """A camera over the field: ``camera(n)`` gives the request's camera for ``n`` boxes."""

    name: str
    note: str
    camera: Callable[[int], dict | None]


def _corner(n: int) -> float:
    """The field's lower x and z (it is centred on the origin)."""
    return -math.ceil(math.sqrt(n)) * PITCH / 2


VIEWS = (
    View("whole field", "automatic framing: every box in view", lambda n: None),
    # Looking down at one corner of the field from 30 units up: the same few hundred boxes in
    # view at every size, the rest left out of the camera pass.
    View("corner", "looking down at one corner from 30 units up, the rest outside the view",
         lambda n: {"eye": [_corner(n) + 20, 30.0, _corner(n) + 5],
                    "target": [_corner(n) + 20, 0.0, _corner(n) + 22]}),
)


def params_for(camera: dict | None = None, **fields: object) -> RenderParams:
    """The request of every render here: 640x480, one directional light, default shadows."""
    request: dict = {"width": C.WIDTH, "height": C.HEIGHT, "lights": [LIGHT], **fields}
    if camera is not None:
        request["camera"] = camera
    return RenderParams.model_validate(request)


# --------------------------------------------------------------------------------------------
# Measurements
# --------------------------------------------------------------------------------------------


def plan_cost(scene: Scene, params: RenderParams, repeats: int) -> tuple[float, float]:
    """Median seconds of :func:`make_plan` with the per-scene cache cold and warm.

    Cold plans a fresh :class:`Scene` object holding the same instances (nothing cached for it
    yet); warm plans the same scene again.
    """
    camera = resolve_camera(params.camera, scene, params.width, params.height)
    lights = resolve_lights(params.lights, scene)
    lo, hi = scene.bounds
    origin = (lo + hi) / 2
    cold, warm = [], []
    for _ in range(repeats):
        fresh = Scene(scene.primitives, list(scene.instances), scene.cameras, scene.lights,
                      key=scene.key, focus=scene.focus)
        t = time.perf_counter()
        make_plan(fresh, camera, lights, origin, params)
        cold.append(time.perf_counter() - t)
        t = time.perf_counter()
        make_plan(fresh, camera, lights, origin, params)
        warm.append(time.perf_counter() - t)
    return C.median(cold), C.median(warm)


#: ``shadowmap render`` runs per case (the median is reported).
CLI_RUNS = 3


def cli_run(glb: bytes, n: int, camera: dict | None) -> dict | None:
    """``shadowmap render`` on the ``.glb`` in a new process: its wall time (imports, context and
    shader compilation included) and its own timings; None when the command fails or renders
    fewer than ``n`` boxes (a reader without the instancing extension)."""
    exe = Path(sys.executable).with_name("shadowmap")
    if not exe.is_file():
        return None
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"field_{n}.glb"
        path.write_bytes(glb)
        request: dict = {"lights": [LIGHT]}
        if camera is not None:
            request["camera"] = camera
        params = Path(tmp) / "params.json"
        params.write_text(json.dumps(request))
        t = time.perf_counter()
        proc = subprocess.run([str(exe), "render", str(path), "--params", str(params),
                               "--out", str(Path(tmp) / "out")], capture_output=True, text=True)
        seconds = time.perf_counter() - t
        if proc.returncode != 0:
            return None
        report = json.loads((Path(tmp) / "out" / "report.json").read_text())
        seen = report["plan"]["camera_pass"]
        if seen["drawn"] + sum(seen["skipped"].values()) < n:
            return None
        return {"seconds": seconds, "timings": report.get("timings", {})}


def profile(fn: Callable[[], object], top: int = 30) -> str:
    """The top of a cProfile run of ``fn``, by internal time and by cumulative time."""
    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    out = io.StringIO()
    stats = pstats.Stats(prof, stream=out)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)
    return out.getvalue()


def run(quick: bool, repeats: int, sizes: tuple[int, ...], plan_only: bool,
        do_profile: bool, cli: bool) -> None:
    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    prim = box_primitive()
    cases = [(n, v) for n in sizes for v in VIEWS]
    bar = C.Progress(len(sizes) + len(cases) * (1 if plan_only else 4), "instancing")
    rows: dict[tuple[int, str], dict] = {}
    scenes: dict[int, Scene] = {}
    glbs: dict[int, bytes] = {}
    loads: dict[int, tuple[float, str]] = {}
    for n in sizes:
        glbs[n] = instancing_glb(n, prim)
        scene, load_s, how = load_or_build(n, glbs[n])
        scenes[n], loads[n] = scene, (load_s, how)
        bar.step(f"{n} load")
    for n, v in cases:
        cold, warm = plan_cost(scenes[n], params_for(v.camera(n)), max(repeats, 3))
        rows[n, v.name] = {"instances": n, "view": v.name, "load_ms": 1e3 * loads[n][0],
                           "load": loads[n][1], "plan_cold_ms": 1e3 * cold,
                           "plan_warm_ms": 1e3 * warm,
                           "plan_cold_us_per_instance": 1e6 * cold / n,
                           "plan_warm_us_per_instance": 1e6 * warm / n}
        bar.step(f"{n} {v.name} plan")
    plan_headers = ["instances", "view", "make_plan ms, new scene", "µs / instance",
                    "make_plan ms, same scene", "µs / instance"]
    plan_rows = [[f"{x['instances']:,}", x["view"], C.fmt(x["plan_cold_ms"], 2),
                  C.fmt(x["plan_cold_us_per_instance"], 2), C.fmt(x["plan_warm_ms"], 2),
                  C.fmt(x["plan_warm_us_per_instance"], 2)] for x in rows.values()]
    plan_table = C.markdown_table(plan_headers, plan_rows, "llrrrr")
    if plan_only:
        bar.close()
        print(plan_table)
        print(f"\n{C.code_state()}; not written to bench/results (--plan-only)")
        return

    r = Renderer()
    try:
        r.render(build_scene(16, prim), params_for())  # shaders compiled before any timing
        for n, v in cases:
            t = time.perf_counter()
            res = r.render(scenes[n], params_for(v.camera(n)))
            rows[n, v.name]["first_render_ms"] = 1e3 * (time.perf_counter() - t)
            rows[n, v.name]["first_upload_ms"] = 1e3 * res.timings["upload"]
            bar.step(f"{n} {v.name} first render")
        def render(n: int, view: View) -> Callable[[], object]:
            def run() -> object:
                # A repeated request would take its checks, plan and maps from the caches: time
                # the work.
                r.requests.clear()
                r.plans.clear()
                r.light_pass.cache.clear()
                return r.render(scenes[n], params_for(view.camera(n)))
            return run

        timed = C.time_interleaved({f"{n} {v.name}": render(n, v) for n, v in cases}, repeats,
                                   warmup=0)
        for (n, v), t_ in zip(cases, timed.values(), strict=True):
            x = rows[n, v.name]
            for s in STAGES:
                if s != "load":
                    x[f"{s}_ms"] = t_.ms(s)
            x["render_ms"], x["render_p90_ms"] = t_.ms(), t_.p90_ms()
            plan = t_.last.plan  # type: ignore[attr-defined]
            x["drawn"] = plan["camera_pass"]["drawn"]
            x["culled"] = plan["camera_pass"]["skipped"].get("outside_view", 0)
            x["casters"] = plan["lights"][0].get("casters")
            x["map_size"] = plan["lights"][0].get("map_size")
        bar.step("timed renders", len(cases))
        for n, v in cases:
            x = rows[n, v.name]
            m = T.measure(r, scenes[n], params_for(v.camera(n)))
            metric = m.metrics[0]
            x["iou"], x["misclassified_pct"] = metric.iou, metric.misclassified_pct
            x["missed_shadow_pct"] = metric.missed_shadow_pct
            x["reference_s"] = m.reference.seconds
            bar.step(f"{n} {v.name} reference")
            # A new process each time: the median of three, as one run is at the machine's mercy.
            runs = [cli_run(glbs[n], n, v.camera(n)) for _ in range(CLI_RUNS)] if cli else []
            done = (None if not runs or any(d is None for d in runs)
                    else sorted(runs, key=lambda d: d["seconds"])[len(runs) // 2])
            x["cli_s"] = None if done is None else done["seconds"]
            x["cli_render_ms"] = None if done is None else 1e3 * done["timings"].get("total", 0)
            bar.step(f"{n} {v.name} command line")
        bar.close()
        profiles = []
        if do_profile:
            n = max(sizes)
            params = params_for()
            fresh = Renderer()
            try:
                fresh.render(build_scene(16, prim), params)  # shaders compiled, as in a service
                scene = load_or_build(n, glbs[n])[0]  # a new scene object: nothing cached
                once = profile(lambda: fresh.render(scene, params))
                again = profile(lambda: fresh.render(scene, params))
                profiles += [(f"first render of {n:,} instances, whole field (upload; the plan "
                              "reads the scene's arrays)", once),
                             (f"repeat render of {n:,} instances, whole field (upload and plan "
                              "arrays cached)", again)]
            finally:
                fresh.close()
        machine = C.machine_info(r)
    finally:
        r.close()

    headers = ["instances", "view", "load ms", "first render ms", "plan ms", "light ms",
               "camera ms", "total ms", "drawn", "casters", "map", "IoU", "reference s", "CLI s"]
    table = C.markdown_table(headers, [[
        f"{x['instances']:,}", x["view"], C.fmt(x["load_ms"]), C.fmt(x["first_render_ms"]),
        C.fmt(x["plan_ms"], 2),
        C.fmt(x["light_ms"]), C.fmt(x["camera_ms"]), C.fmt(x["render_ms"]), x["drawn"],
        x["casters"], x["map_size"], C.fmt(x["iou"], 3), C.fmt(x["reference_s"]),
        C.fmt(x["cli_s"], 2)] for x in rows.values()], "llrrrrrrrrrrrr")
    sources = sorted({x["load"] for x in rows.values()})
    notes = [f"load: {'; '.join(sources)}."]
    if not cli:
        notes.append("CLI s: not run (--no-cli).")
    elif any(x["cli_s"] is None for x in rows.values()):
        notes.append("CLI s: — where `shadowmap render` failed or the reader did not expand "
                     "EXT_mesh_gpu_instancing.")
    else:
        notes.append("CLI s: `shadowmap render field.glb --params ...` in a new process: Python "
                     "start, imports, GL context, shader compilation, load and one render "
                     f"(median of {CLI_RUNS} runs).")
    notes += [f"{v.name}: {v.note}." for v in VIEWS]
    elapsed = time.perf_counter() - t_start
    md = [
        "# Many instances of one mesh",
        "",
        f"A field of boxes (one primitive of {len(prim.indices)} triangles, one instance per box, "
        f"turned and stretched at random, pitch {PITCH}) over a ground plane that casts nothing; "
        f"one directional light; {C.WIDTH}x{C.HEIGHT}, default shadow settings. Times are "
        f"medians of {repeats} renders of the uploaded scene, all cases interleaved, each "
        "planning and drawing its maps (plan and light-map caches emptied first); *first "
        "render* includes the upload (shaders already compiled); IoU is the shadow mask against "
        "the ray-traced reference (one measurement per case).",
        "",
        table,
        "",
        *[f"- {n}" for n in notes],
        "",
        "## The plan alone",
        "",
        "`make_plan` called directly (camera and light resolved once), median of repeats: with "
        "a new Scene object each time (the per-scene arrays are read from the instances again) "
        "and with the same scene again (they come from the plan's cache).",
        "",
        plan_table,
        "",
        f"Machine: {machine}. Run time {elapsed:.0f} s" + (" (--quick)." if quick else "."),
        "",
    ]
    extra = []
    if profiles:
        text = "\n\n".join(f"== {title} ==\n{body}" for title, body in profiles)
        (out_dir / "instancing_profile.txt").write_text(text)
        extra.append("instancing_profile.txt")
    csv_rows = [{**x, "repeats": repeats} for x in rows.values()]
    C.finish(out_dir, "instancing", "\n".join(md), csv_rows, [table, plan_table], notes,
             elapsed, extra)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1k and 10k only, 3 repeats")
    ap.add_argument("--repeats", type=int, default=None,
                    help=f"timed renders per size (default {C.DEFAULT_REPEATS}, quick 3)")
    ap.add_argument("--sizes", default=None, help="instance counts, comma-separated")
    ap.add_argument("--plan-only", action="store_true",
                    help="only the cost of make_plan per instance (nothing written)")
    ap.add_argument("--profile", action="store_true",
                    help="cProfile the largest size's render (instancing_profile.txt)")
    ap.add_argument("--no-cli", action="store_true", help="leave out the command-line runs")
    args = ap.parse_args(argv)
    sizes = (tuple(int(s) for s in args.sizes.split(",")) if args.sizes
             else QUICK_SIZES if args.quick else SIZES)
    run(args.quick, args.repeats or (3 if args.quick else C.DEFAULT_REPEATS), sizes,
        args.plan_only, args.profile, not args.no_cli)


if __name__ == "__main__":
    main()
