"""Shared pieces of the benchmark scripts: scenes, timing, progress, tables, pyrender baseline.

Import this module before anything that imports PyOpenGL: it defaults ``PYOPENGL_PLATFORM`` to
EGL and imports :mod:`renderer`, which binds the platform.
"""

from __future__ import annotations

import csv
import math
import os
import statistics
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from shadowmap.renderer import (  # noqa: E402
    Renderer,
    RenderParams,
    Scene,
    load_scene,
    testing,
)
from shadowmap.renderer.camera import Camera, resolve_camera  # noqa: E402
from shadowmap.renderer.lights import Light, resolve_lights  # noqa: E402
from shadowmap.renderer.params import light_params  # noqa: E402
from shadowmap.renderer.plan.geometry import pose_from_direction  # noqa: E402
from shadowmap.renderer.scene import Material  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
WIDTH, HEIGHT = 640, 480
DEFAULT_REPEATS = 5

#: The glTF test models used by the benchmarks (cube.glb is BoxTextured's geometry untextured).
MODEL_NAMES = ("Duck.glb", "BoxTextured.glb", "CesiumMilkTruck.glb", "AlphaBlendModeTest.glb",
               "TestScene.gltf")


def models_dir() -> Path:
    """The test models: ``$SHADOWMAP_MODELS``, else ``<repo>/../shared/models``."""
    env = os.environ.get("SHADOWMAP_MODELS")
    path = Path(env) if env else ROOT.parent / "shared" / "models"
    if not (path / "Duck.glb").is_file():
        raise SystemExit(f"test models not found in {path}: set SHADOWMAP_MODELS")
    return path


def results_dir(quick: bool = False) -> Path:
    """``$SHADOWMAP_BENCH_RESULTS``, else ``bench/results/``; smoke runs (``--quick``) write to
    its ``quick/`` folder instead.

    Results from another kind of machine (a GPU, say) go to a folder of their own, so that they
    never replace this machine's, which the README quotes.
    """
    env = os.environ.get("SHADOWMAP_BENCH_RESULTS")
    base = Path(env) if env else RESULTS
    path = base / "quick" if quick else base
    path.mkdir(parents=True, exist_ok=True)
    return path


# --------------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------------


@dataclass
class BenchScene:
    """A scene with the request fields that go with it.

    Attributes
    ----------
    name : str
    scene : Scene
        Already with its ground plane (requests never set ``ground``).
    lights : list of dict
        Explicit light fields (:data:`~shadowmap.renderer.params.LightParams`), so that a
        variant (e.g. without shadows) changes nothing else.
    camera : dict or None
        :class:`CameraParams` fields; None frames the scene automatically (or the file's camera).
    kind : {"model", "stress"}
    """

    name: str
    scene: Scene
    lights: list[dict]
    camera: dict | None = None
    kind: str = "model"
    note: str = ""

    def params(self, width: int = WIDTH, height: int = HEIGHT, **fields) -> RenderParams:
        """A request for this scene; ``fields`` override RenderParams fields (e.g. shadows)."""
        base: dict = {"width": width, "height": height, "lights": self.lights}
        if self.camera is not None:
            base["camera"] = self.camera
        base.update(fields)
        return RenderParams.model_validate(base)

    def resolved(self, width: int = WIDTH, height: int = HEIGHT) -> tuple[Camera, list[Light]]:
        """The camera and lights every render of this scene uses."""
        p = self.params(width, height)
        camera = resolve_camera(p.camera, self.scene, width, height)
        return camera, resolve_lights(p.lights, self.scene)

    def turned(self, turn: int, width: int = WIDTH, height: int = HEIGHT,
               **fields) -> RenderParams:
        """A request from a camera no other ``turn`` gives: this scene's own camera turned
        about the vertical through the centre of the scene's bounds by ``turn`` thirds of a
        degree, looking at that centre. Each such request plans anew (the renderer's plans
        are kept per request), as a batch's views and a moving client's requests do."""
        camera = self.resolved(width, height)[0]
        centre = np.asarray(self.scene.bounds, np.float64).mean(axis=0)
        a = math.radians(turn / 3.0)
        rot = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0],
                        [-math.sin(a), 0.0, math.cos(a)]])
        eye = centre + rot @ (np.asarray(camera.pose[:3, 3], np.float64) - centre)
        return self.params(width, height, camera={"eye": eye.tolist(),
                                                  "target": centre.tolist()}, **fields)

    @property
    def directional_only(self) -> bool:
        return all(lt.get("type", "directional") == "directional" for lt in self.lights)


def light_dicts(scene: Scene, lights: list[dict] | None = None) -> list[dict]:
    """The lights a request would use (given, else the file's, else the default) as explicit dicts.

    The file's ``KHR_lights_punctual`` lights and the default light are resolved by
    :func:`renderer.lights.resolve_lights` and written back as position + direction.
    """
    params = None if lights is None else [light_params(lt) for lt in lights]
    out = []
    for lt in resolve_lights(params, scene):
        d: dict = {
            "type": lt.type,
            "direction": [float(v) for v in lt.direction],
            "color": [float(v) for v in lt.color],
            "intensity": float(lt.intensity),
            "cast_shadows": bool(lt.cast_shadows),
        }
        if lt.type != "directional":
            d["position"] = [float(v) for v in lt.position]
            if lt.range is not None:
                d["range"] = float(lt.range)
        if lt.type == "point":
            del d["direction"]
        if lt.type == "spot":
            d["inner_cone_deg"] = math.degrees(lt.inner_cone)
            d["outer_cone_deg"] = math.degrees(lt.outer_cone)
        out.append(d)
    return out


def without_shadows(lights: list[dict]) -> list[dict]:
    return [{**lt, "cast_shadows": False} for lt in lights]


def load_model(name: str, ground: bool = True) -> Scene:
    """A test model by file name, with a ground plane under it by default."""
    scene = load_scene(models_dir() / name)  # a .gltf's files are read from beside it
    return scene.with_ground() if ground else scene


def model_scene(name: str) -> BenchScene:
    scene = load_model(name)
    return BenchScene(name.rsplit(".", 1)[0], scene, light_dicts(scene), kind="model")


def model_scenes(names: Iterable[str] = MODEL_NAMES) -> list[BenchScene]:
    return [model_scene(n) for n in names]


def _scene_size(scene: Scene) -> tuple[np.ndarray, float]:
    lo, hi = scene.bounds
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo))


def stress_scene(name: str) -> BenchScene:
    """One of the stress scenes by name (see :data:`STRESS_SCENES`)."""
    if name == "caster_on_ground":
        s = testing.caster_on_ground()
        return BenchScene(name, s, light_dicts(s), kind="stress")
    if name == "caster_1e-3":
        s = testing.transformed(testing.caster_on_ground(), 1e-3)
        return BenchScene(name, s, light_dicts(s), kind="stress",
                          note="caster_on_ground scaled by 1/1000")
    if name == "grazing_5deg":
        s = testing.grazing_plane()
        # Light 5 degrees above the ground, across the wall: a long shadow behind it on a plane
        # seen at a grazing angle by the light (acne-prone).
        elev, azim = math.radians(5.0), math.radians(20.0)
        d = [math.sin(azim) * math.cos(elev), -math.sin(elev), -math.cos(azim) * math.cos(elev)]
        return BenchScene(name, s, light_dicts(s, [{"type": "directional", "direction": d}]),
                          kind="stress", note="grazing_plane, light 5 deg above the ground")
    if name == "far_spot":
        s = testing.caster_on_ground()
        centre, diag = _scene_size(s)
        d = np.array([0.3, 1.0, 0.2])
        pos = centre + d / np.linalg.norm(d) * 100 * diag
        half = math.degrees(math.atan(0.6 * diag / (100 * diag)))
        lt = {"type": "spot", "position": pos.tolist(), "target": centre.tolist(),
              "outer_cone_deg": half, "inner_cone_deg": half * 0.8}
        return BenchScene(name, s, light_dicts(s, [lt]), kind="stress",
                          note="caster_on_ground, spot 100 scene sizes away, narrow cone")
    if name == "thin_sheets":
        s = testing.thin_sheets()
        return BenchScene(name, s, light_dicts(s), kind="stress")
    if name == "degenerate":
        s = testing.degenerate_geometry()
        return BenchScene(name, s, light_dicts(s), kind="stress")
    if name == "room_point":
        s = testing.room()
        lt = {"type": "point", "position": [0.5, 3.2, 0.3]}
        cam = {"eye": [3.5, 3.2, 3.5], "target": [0.0, 0.8, 0.0]}
        return BenchScene(name, s, light_dicts(s, [lt]), camera=cam, kind="stress",
                          note="closed room, point light inside")
    raise KeyError(name)


STRESS_SCENES = ("caster_on_ground", "caster_1e-3", "grazing_5deg", "far_spot", "thin_sheets",
                 "degenerate", "room_point")


def untextured(scene: Scene) -> Scene:
    """The same scene with base colour only: no textures, no UVs, no vertex colours."""
    prims = [replace(p, material=Material(p.material.base_color, alpha_mode=p.material.alpha_mode,
                                          alpha_cutoff=p.material.alpha_cutoff,
                                          double_sided=p.material.double_sided),
                     uv=None, colors=None)
             for p in scene.primitives]
    return Scene(prims, scene.instances, scene.cameras, scene.lights,
                 key=scene.key + ":untextured" if scene.key else "", focus=scene.focus)


# --------------------------------------------------------------------------------------------
# Progress and timing
# --------------------------------------------------------------------------------------------


class Progress:
    """A one-line progress bar on stderr (redrawn at most ten times a second)."""

    def __init__(self, total: int, label: str = "", width: int = 28) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.width = width
        self.done = 0
        self.start = time.perf_counter()
        self._last = 0.0
        self._tty = sys.stderr.isatty()
        self._draw("")

    def step(self, note: str = "", n: int = 1) -> None:
        self.done += n
        now = time.perf_counter()
        if self.done >= self.total:
            return  # close() draws the last line
        # Off a terminal every redraw would become a line of its own: draw every ~10 % only.
        if self._tty and now - self._last < 0.1:
            return
        if not self._tty and self.done % max(self.total // 10, 1):
            return
        self._last = now
        self._draw(note)

    def _draw(self, note: str) -> None:
        frac = min(self.done / self.total, 1.0)
        fill = int(round(frac * self.width))
        elapsed = time.perf_counter() - self.start
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        line = (f"{self.label} [{'#' * fill}{'.' * (self.width - fill)}] {self.done}/{self.total} "
                f"{_mmss(elapsed)} eta {_mmss(eta)} {note}")
        if self._tty:
            sys.stderr.write("\r" + line[:150].ljust(150))
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def close(self) -> None:
        self.done = self.total
        self._draw("done")
        if self._tty:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _mmss(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--"
    m, s = divmod(int(round(seconds)), 60)
    return f"{m:02d}:{s:02d}"


def median(values: Sequence[float]) -> float:
    return float(statistics.median(values)) if values else math.nan


def p90(values: Sequence[float]) -> float:
    """90th percentile (linear interpolation); with 5 samples it lies between the top two."""
    return float(np.percentile(values, 90)) if len(values) else math.nan


@dataclass
class Timing:
    """Repeated measurements of one call.

    Attributes
    ----------
    wall : list of float
        Seconds of each timed call, measured around it.
    stages : dict of str to list of float
        ``RenderResult.timings`` of each timed call, by stage.
    last : object
        What the last timed call returned (e.g. its RenderResult, for the plan report).
    """

    wall: list[float] = field(default_factory=list)
    stages: dict[str, list[float]] = field(default_factory=dict)
    last: object = None

    def add(self, seconds: float, result=None) -> None:
        self.wall.append(seconds)
        for k, v in (getattr(result, "timings", None) or {}).items():
            self.stages.setdefault(k, []).append(v)
        self.last = result

    def ms(self, stage: str | None = None) -> float:
        """Median milliseconds of the wall time, or of one render stage."""
        values = self.wall if stage is None else self.stages.get(stage, [])
        return 1e3 * median(values)

    def p90_ms(self, stage: str | None = None) -> float:
        values = self.wall if stage is None else self.stages.get(stage, [])
        return 1e3 * p90(values)


def time_interleaved(calls: dict[str, Callable[[], object]], repeats: int = DEFAULT_REPEATS,
                     warmup: int = 1, rotate: bool = False) -> dict[str, Timing]:
    """Warm every call up, then time them in turn (A B A B ...) so drift hits all alike.

    The first call of a configuration compiles shaders and allocates maps; ``warmup`` calls of
    each are made and discarded first. With ``rotate``, repeat k starts at the k-th call (A B C,
    B C A, C A B, ...): a call that runs right after one drawing the same plan finds its data in
    the CPU's caches and runs a few per cent faster, and rotating gives every call each place
    after every other equally often.
    """
    for fn in calls.values():
        for _ in range(warmup):
            fn()
    out = {name: Timing() for name in calls}
    items = list(calls.items())
    for k in range(repeats):
        turn = items[k % len(items):] + items[:k % len(items)] if rotate else items
        for name, fn in turn:
            t = time.perf_counter()
            result = fn()
            out[name].add(time.perf_counter() - t, result)
    return out


def time_render(r: Renderer, scene, params: RenderParams, repeats: int = DEFAULT_REPEATS,
                warmup: int = 1) -> Timing:
    """Median-ready timings of ``r.render(scene, params)`` after ``warmup`` discarded calls."""
    return time_interleaved({"x": lambda: r.render(scene, params)}, repeats, warmup)["x"]


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def fmt(value, digits: int = 1) -> str:
    """A table cell: floats with ``digits`` decimals, NaN/None as an em dash."""
    if value is None:
        return "—"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence],
                   align: str | None = None) -> str:
    """A GitHub Markdown table; ``align`` is one of l/r/c per column (default: first l, rest r)."""
    headers = list(headers)
    align = align or "l" + "r" * (len(headers) - 1)
    rule = {"l": ":---", "r": "---:", "c": ":---:"}
    lines = ["| " + " | ".join(headers) + " |",
             "| " + " | ".join(rule[a] for a in align) + " |"]
    for row in rows:
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |")
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows of dicts to CSV, columns in first-seen order."""
    cols: list[str] = []
    for r in rows:
        cols.extend(k for k in r if k not in cols)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})


def code_state() -> str:
    """The commit measured, and whether renderer/ or shaders/ had uncommitted changes."""
    import subprocess

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                                  timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--", "renderer", "shaders")
    return f"commit {head}" + (" + uncommitted changes in renderer/ or shaders/" if dirty else "")


def machine_info(r: Renderer) -> str:
    """One line naming the GL renderer, CPU count and load, for result footers."""
    info = r.info
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    return (f"{info['platform']}, {info['renderer']}, GL {info['version']}; "
            f"{os.cpu_count()} CPU cores (load average {load} at the end); "
            f"Python {sys.version.split()[0]}; {code_state()}")


# --------------------------------------------------------------------------------------------
# pyrender's built-in shadows, as a baseline
# --------------------------------------------------------------------------------------------

#: pyrender's light is made brighter than ours so that lit and shadowed pixels differ by many
#: levels even on dark textures; intensity does not change the work done.
PYRENDER_INTENSITY = 4.0
#: A pixel is "undetermined" when the light adds fewer grey levels than this to it.
PYRENDER_MIN_LEVELS = 3.0


@dataclass
class PyrenderScene:
    scene: object  # pyrender.Scene
    light_nodes: list
    light: list  # pyrender.DirectionalLight


class PyrenderBaseline:
    """pyrender's OffscreenRenderer with its built-in directional shadows, on our scenes.

    The same geometry (our primitives placed by our instance matrices), materials (base colour,
    texture, alpha mode, double-sidedness), camera and light directions.
    """

    def __init__(self, width: int = WIDTH, height: int = HEIGHT) -> None:
        # pyrender imports its viewer, which loads pyglet's X11 window code unless pyglet runs
        # headless: on a machine without X libraries (a GPU server, say) the import fails.
        # Offscreen rendering uses none of it.
        os.environ.setdefault("PYGLET_HEADLESS", "true")
        import pyrender

        self.pyrender = pyrender
        self.width, self.height = width, height
        self.off = pyrender.OffscreenRenderer(width, height)

    def close(self) -> None:
        """Free pyrender's GL objects and context, leaving the shared EGL display initialised.

        pyrender's own ``delete`` terminates the EGLDisplay, which every EGL context of the process
        shares (the renderer's included).
        """
        off = self.off
        if off is None or off._platform is None:
            return
        self.off = None
        platform = off._platform
        platform.make_current()
        off._renderer.delete()
        if hasattr(platform, "_egl_display"):
            from OpenGL import EGL

            EGL.eglMakeCurrent(platform._egl_display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE,
                               EGL.EGL_NO_CONTEXT)
            EGL.eglDestroyContext(platform._egl_display, platform._egl_context)
        else:
            platform.delete_context()
        off._renderer = None
        off._platform = None  # its __del__ then does nothing

    def build(self, bs: BenchScene) -> PyrenderScene:
        """A pyrender scene of ``bs`` (directional lights only: pyrender's shadow support)."""
        pr = self.pyrender
        if not bs.directional_only:
            raise ValueError(f"{bs.name}: pyrender baseline supports directional lights only")
        camera, lights = bs.resolved(self.width, self.height)
        scene = pr.Scene(ambient_light=[0.25, 0.25, 0.25], bg_color=[1.0, 1.0, 1.0, 1.0])
        meshes = []
        for prim in bs.scene.primitives:
            mat = prim.material
            tex = None
            if mat.texture is not None and prim.uv is not None:
                tex = pr.Texture(source=mat.texture, source_channels="RGBA")
            material = pr.MetallicRoughnessMaterial(
                baseColorFactor=np.asarray(mat.base_color, np.float64),
                baseColorTexture=tex,
                metallicFactor=0.0,
                roughnessFactor=1.0,
                alphaMode=mat.alpha_mode,
                alphaCutoff=mat.alpha_cutoff,
                doubleSided=mat.double_sided,
            )
            p = pr.Primitive(positions=prim.positions, normals=prim.normals,
                             texcoord_0=prim.uv if tex is not None else None,
                             color_0=prim.colors, indices=prim.indices, material=material)
            meshes.append(pr.Mesh([p]))
        for inst in bs.scene.instances:
            scene.add(meshes[inst.primitive], pose=inst.matrix)
        cam = pr.PerspectiveCamera(yfov=camera.yfov, znear=camera.znear, zfar=camera.zfar,
                                   aspectRatio=camera.width / camera.height)
        scene.add(cam, pose=camera.pose)
        nodes, objs = [], []
        centre = (bs.scene.bounds[0] + bs.scene.bounds[1]) / 2
        for lt in lights:
            light = pr.DirectionalLight(color=lt.color, intensity=lt.intensity * PYRENDER_INTENSITY)
            # The node's -Z is the direction the light travels.
            nodes.append(scene.add(light, pose=pose_from_direction(centre, lt.direction)))
            objs.append(light)
        return PyrenderScene(scene, nodes, objs)

    def render(self, ps: PyrenderScene, shadows: bool) -> np.ndarray:
        """Colour image (H, W, 3) uint8 with or without directional shadows."""
        flags = self.pyrender.RenderFlags
        color, _ = self.off.render(ps.scene, flags.SHADOWS_DIRECTIONAL if shadows else flags.NONE)
        return color

    def visibility(self, ps: PyrenderScene) -> tuple[np.ndarray, dict]:
        """pyrender's shadow mask for its first light, read off its images.

        The light's contribution is ``unshadowed − ambient only``; a pixel is shadowed when the
        shadowed image lost more than half of it. Pixels the light adds fewer than
        :data:`PYRENDER_MIN_LEVELS` grey levels to are undetermined (NaN), as is the background.

        Returns
        -------
        vis : ndarray, shape (H, W), float32
            1 lit, 0 shadowed, NaN undetermined.
        images : dict of str to ndarray
            ``shadowed``, ``unshadowed``, ``ambient`` colour images.
        """
        sh = self.render(ps, True).astype(np.float32)
        un = self.render(ps, False).astype(np.float32)
        saved = [lt.intensity for lt in ps.light]
        for lt in ps.light:
            lt.intensity = 0.0
        try:
            amb = self.render(ps, False).astype(np.float32)
        finally:
            for lt, v in zip(ps.light, saved, strict=True):
                lt.intensity = v
        contrib = (un - amb).max(axis=2)
        lost = (un - sh).max(axis=2)
        vis = np.where(lost > 0.5 * contrib, 0.0, 1.0).astype(np.float32)
        vis[contrib < PYRENDER_MIN_LEVELS] = np.nan
        images = {"shadowed": sh.astype(np.uint8), "unshadowed": un.astype(np.uint8),
                  "ambient": amb.astype(np.uint8)}
        return vis, images


def finish(out_dir: Path, stem: str, md: str, csv_rows: list[dict], blocks: Sequence[str],
           notes: Sequence[str], elapsed: float, extra: Sequence[str] = ()) -> None:
    """Write ``stem``.md and ``stem``.csv, print the tables and notes, and say what was written."""
    (out_dir / f"{stem}.md").write_text(md)
    write_csv(out_dir / f"{stem}.csv", csv_rows)
    for block in blocks:
        print(block)
        print()
    for n in notes:
        print(n)
    written = ", ".join([f"{stem}.csv", *extra])
    print(f"\nwrote {out_dir / (stem + '.md')}, {written} ({elapsed:.0f} s)")


def bench_main(doc: str, run: Callable[[bool, int], None], quick_help: str, quick_repeats: int,
               argv: list[str] | None = None) -> None:
    """The shared command line: ``--quick`` for a smoke run, ``--repeats N``."""
    import argparse

    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=quick_help)
    ap.add_argument("--repeats", type=int, default=None,
                    help=f"timed calls per variant (default {DEFAULT_REPEATS}, "
                    f"quick {quick_repeats})")
    args = ap.parse_args(argv)
    run(args.quick, args.repeats or (quick_repeats if args.quick else DEFAULT_REPEATS))
