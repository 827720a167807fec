"""Ours against three.js on the same GL driver: frame time and shadow accuracy, side by side.

three.js (``bench/threejs/``: r187 from npm, driven by puppeteer-core) runs in headless Chromium,
whose WebGL goes through ANGLE to the host's EGL: on this machine the same Mesa llvmpipe our
renderer uses (the table's footer names both drivers). Per scene, at 640x480:

- ours: ``renderer.render`` with default settings, every frame drawing its light pass (the
  light-map cache off), colour read back into numpy;
- three.js: the same triangles, instance matrices, materials (Phong, base colour, texture, alpha
  mode, sidedness), camera and lights, ``PCFShadowMap`` with a 2048x2048 map per light and the
  shadow camera fitted to the scene's box, shadow maps redrawn every frame, timed in the page
  from ``renderer.render`` to the end of a ``readPixels`` of the whole frame;
- frames interleaved in runs of :data:`RUN` frames each: ours, three.js reading back every
  pixel, three.js reading back one (the wait without the copy), repeated; medians over every
  frame. Each side gets the same runs: the first frame of a run starts with caches the other
  side has just used (the notes give what that costs ours: its first frames over the rest);
- shadow IoU of both against the ray-traced reference. three.js's mask is read off its own
  shadowed, unshadowed and ambient-only frames, as pyrender's is in ``bench/shadow_cost.py``.

Needs Chromium (Debian: ``apt-get install chromium``) and ``npm ci`` in ``bench/threejs`` (the
script runs it when ``node_modules`` is missing; puppeteer-core downloads no browser). Writes
``bench/results/vs_threejs.{md,csv}`` and ``vs_threejs_check.png`` (three.js's frame and mask
next to ours and the reference's, to check the port by eye); ``--quick`` writes to
``bench/results/quick/``.

Run: ``PYTHONPATH=. .venv/bin/python bench/vs_threejs.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench import _common as C  # before shadowmap: selects the GL platform
from shadowmap.renderer import Renderer  # noqa: E402
from shadowmap.renderer.metrics import compare_all, shadow_metrics  # noqa: E402
from shadowmap.renderer.reference import trace_reference  # noqa: E402

HERE = Path(__file__).resolve().parent / "threejs"
MAP_SIZE = 2048  # three.js's map per light (page.js)
AMBIENT = 0.25
QUICK_SCENES = ("BoxTextured", "caster_on_ground")
CHECK_SCENE = "TestScene"
#: The aim of the performance issue: half of three.js's frame time.
TARGET_RATIO = 0.5


def _b64(a: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype).tobytes()).decode()


def _png_b64(rgba: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba, np.uint8)).save(buf, "PNG", compress_level=1)
    return base64.b64encode(buf.getvalue()).decode()


def describe(bs: C.BenchScene) -> dict:
    """``bs`` as page.js builds it: primitives, instances, camera, lights (matrices
    column-major)."""
    camera, lights = bs.resolved()
    lo, hi = (np.asarray(b, float) for b in bs.scene.bounds)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    prims = []
    for p in bs.scene.primitives:
        m = p.material
        prims.append({
            "positions": _b64(p.positions, np.float32), "normals": _b64(p.normals, np.float32),
            "uv": _b64(p.uv, np.float32) if p.uv is not None else None,
            "colors": _b64(p.colors, np.float32) if p.colors is not None else None,
            "indices": _b64(p.indices, np.uint32),
            "material": {"base_color": [float(v) for v in m.base_color],
                         "texture": _png_b64(m.texture) if m.texture is not None else None,
                         "alpha_mode": m.alpha_mode, "alpha_cutoff": float(m.alpha_cutoff),
                         "double_sided": bool(m.double_sided)},
        })
    insts = [{"primitive": int(i.primitive), "matrix": i.matrix.T.ravel().tolist(),
              "cast_shadow": bool(i.cast_shadow), "receive_shadow": bool(i.receive_shadow)}
             for i in bs.scene.instances]
    out_lights, texel = [], []
    for lt in lights:
        d = {"type": lt.type, "direction": lt.direction.tolist(), "position": lt.position.tolist(),
             "color": [float(v) for v in lt.color], "intensity": float(lt.intensity),
             "range": lt.range, "inner_cone": lt.inner_cone, "outer_cone": lt.outer_cone,
             "cast_shadows": bool(lt.cast_shadows)}
        out_lights.append(d)
        if lt.type == "directional":
            texel.append(2 * radius / MAP_SIZE)
        else:
            half = lt.outer_cone if lt.type == "spot" else math.pi / 4
            dist = float(np.linalg.norm(centre - lt.position))
            texel.append(2 * dist * math.tan(half) / MAP_SIZE)
    return {
        "primitives": prims, "instances": insts, "lights": out_lights, "texel_world": texel,
        "ambient": AMBIENT, "bounds": [lo.tolist(), hi.tolist()],
        "camera": {"yfov": camera.yfov, "znear": camera.znear, "zfar": camera.zfar,
                   "pose": camera.pose.T.ravel().tolist(), "width": camera.width,
                   "height": camera.height},
    }


class ThreeJs:
    """three.js in headless Chromium behind ``bench/threejs/driver.mjs`` (JSON lines on stdio)."""

    def __init__(self) -> None:
        node = shutil.which("node")
        browser = next((shutil.which(b) for b in ("chromium", "chromium-browser")
                        if shutil.which(b)), None)
        if node is None or browser is None:
            raise SystemExit("vs_threejs needs node and chromium (Debian: apt-get install "
                             "nodejs npm chromium)")
        if not (HERE / "node_modules" / "three").is_dir():
            subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=HERE, check=True,
                           env={**os.environ, "PUPPETEER_SKIP_DOWNLOAD": "1"})
        self.proc = subprocess.Popen([node, str(HERE / "driver.mjs")], cwd=HERE, text=True,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     env={**os.environ, "CHROMIUM": browser}, bufsize=1)

    def call(self, **msg) -> dict:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the three.js driver exited")
        reply = json.loads(line)
        if "error" in reply:
            raise RuntimeError(f"three.js: {reply['error']}")
        return reply

    def image(self, mode: str, width: int, height: int) -> np.ndarray:
        raw = base64.b64decode(self.call(cmd="image", mode=mode)["rgba"])
        return np.frombuffer(raw, np.uint8).reshape(height, width, 4)[::-1, :, :3]

    def visibility(self, width: int, height: int) -> np.ndarray:
        """three.js's mask (H, W) for its first light: 1 lit, 0 shadowed, NaN undetermined."""
        sh, un, amb = (self.image(m, width, height).astype(np.float32)
                       for m in ("shadowed", "unshadowed", "ambient"))
        contrib = (un - amb).max(axis=2)
        lost = (un - sh).max(axis=2)
        vis = np.where(lost > 0.5 * contrib, 0.0, 1.0).astype(np.float32)
        vis[contrib < C.PYRENDER_MIN_LEVELS] = np.nan
        return vis

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write(json.dumps({"cmd": "quit"}) + "\n")
                self.proc.stdin.close()
            except BrokenPipeError:
                pass
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def save_check(path: Path, three: ThreeJs, r: Renderer, bs: C.BenchScene, tvis: np.ndarray,
               ref) -> None:
    """A 2x2 picture: three.js's frame | ours / three.js's derived mask | the reference's mask."""
    from PIL import Image

    camera, _ = bs.resolved()
    theirs = three.image("shadowed", camera.width, camera.height)
    ours = r.render(bs.scene, bs.params()).color[..., :3]

    def gray(v: np.ndarray) -> np.ndarray:
        return np.dstack([(np.nan_to_num(v, nan=0.5) * 255).astype(np.uint8)] * 3)

    ref_v = np.where(ref.valid[..., 0], ref.visibility[..., 0], np.nan)
    Image.fromarray(np.vstack([np.hstack([theirs, ours]),
                               np.hstack([gray(tvis), gray(ref_v)])])).save(path)


def scenes(quick: bool) -> list[C.BenchScene]:
    out = C.model_scenes() + [C.stress_scene(n) for n in C.STRESS_SCENES]
    if quick:
        out = [s for s in out if s.name in QUICK_SCENES]
    return out


def run(quick: bool, repeats: int) -> None:
    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    rows, csv_rows = [], []
    r = Renderer(map_cache_bytes=0)  # every frame of ours draws its light pass, as three's do
    three = ThreeJs()
    info: dict = {}
    check_scene = "none"
    try:
        bench_scenes = scenes(quick)
        bar = C.Progress(len(bench_scenes), "vs_threejs")
        for bs in bench_scenes:
            p = bs.params()
            info = three.call(cmd="load", scene=describe(bs))
            r.render(bs.scene, p)
            three.call(cmd="time", frames=RUN, shadows=True)  # warm-up
            ours, theirs, theirs_1px, ours_first = [], [], [], []
            for _ in range(repeats):
                for k in range(RUN):
                    t0 = time.perf_counter()
                    r.render(bs.scene, p)
                    ours.append(1e3 * (time.perf_counter() - t0))
                    if k == 0:
                        ours_first.append(ours[-1])
                theirs += three.call(cmd="time", frames=RUN, shadows=True)["ms"]
                theirs_1px += three.call(cmd="time", frames=RUN, shadows=True, whole=False)["ms"]
            camera, lights = bs.resolved()
            ref = trace_reference(bs.scene, camera, lights)
            vis = r.render(bs.scene, bs.params(outputs=["visibility"])).visibility
            our_iou = float(np.mean([m.iou for m in compare_all(vis, ref)]))
            tvis = three.visibility(camera.width, camera.height)
            if bs.name == CHECK_SCENE or (quick and bs.name == QUICK_SCENES[0]):
                save_check(out_dir / "vs_threejs_check.png", three, r, bs, tvis, ref)
                check_scene = bs.name
            valid = ref.valid[..., 0]
            undetermined = 100.0 * float((np.isnan(tvis) & valid).sum()) / max(valid.sum(), 1)
            their_iou = shadow_metrics(tvis, ref.visibility[..., 0], ref.valid[..., 0]).iou
            o, t, t1 = C.median(ours), C.median(theirs), C.median(theirs_1px)
            ratio = o / t
            rows.append([bs.name, lights[0].type, C.fmt(o, 2), C.fmt(t, 2),
                         C.fmt(ratio, 2) + ("" if ratio <= TARGET_RATIO else " ✗"),
                         C.fmt(t1, 2), C.fmt(o / t1, 2),
                         C.fmt(our_iou, 3), C.fmt(their_iou, 3)])
            csv_rows.append({
                "scene": bs.name, "light_type": lights[0].type,
                "triangles": bs.scene.triangle_count, "ours_ms": round(o, 3),
                "threejs_ms": round(t, 3), "ours_over_threejs": round(ratio, 4),
                "threejs_1px_ms": round(t1, 3), "ours_over_threejs_1px": round(o / t1, 4),
                "ours_iou": round(our_iou, 5), "threejs_iou": round(their_iou, 5),
                "threejs_undetermined_pct": round(undetermined, 3), "repeats": repeats,
                "ours_first_over_rest": round(
                    C.median(ours_first) / C.median([x for i, x in enumerate(ours) if i % RUN]),
                    4),
            })
            bar.step(bs.name)
        bar.close()
        machine = C.machine_info(r)
    finally:
        three.close()
        r.close()

    ratios = [c["ours_over_threejs"] for c in csv_rows]
    gmean = float(np.exp(np.mean(np.log(ratios))))
    iou_o = float(np.median([c["ours_iou"] for c in csv_rows]))
    iou_t = float(np.median([c["threejs_iou"] for c in csv_rows]))
    headers = ["scene", "light", "ours ms", "three.js ms", "ours / three.js",
               "three.js ms, 1-pixel read", "ours / that", "ours IoU", "three.js IoU"]
    gmean_1px = float(np.exp(np.mean(np.log([c["ours_over_threejs_1px"] for c in csv_rows]))))
    table = C.markdown_table(headers, rows)
    notes = [
        f"Geometric mean of ours / three.js frame time: {gmean:.2f} (the aim: at most "
        f"{TARGET_RATIO}, half of three.js's frame time); {gmean_1px:.2f} against three.js "
        "frames that read back one pixel only (the wait for the frame without the copy of it "
        "out of Chromium's GPU process, which a frame for display would not make; ours still "
        "reads back every pixel).",
        f"Median shadow IoU against the ray-traced reference: ours {iou_o:.3f}, three.js "
        f"{iou_t:.3f}.",
        "three.js's mask is undetermined (the light adds < "
        f"{C.PYRENDER_MIN_LEVELS:g} grey levels) on at most "
        f"{max(c['threejs_undetermined_pct'] for c in csv_rows):.2f} % of the reference's valid "
        "pixels; those are left out of its IoU.",
        f"Ours, the first frame of each run over the others (median over scenes): "
        f"{np.median([c['ours_first_over_rest'] for c in csv_rows]):.2f}: it starts with "
        "caches three.js's frames have just used.",
    ]
    elapsed = time.perf_counter() - t_start
    md = "\n".join([
        "# Ours against three.js on the same llvmpipe",
        "",
        "640x480. Ours: default settings, each frame drawing its light pass, colour read back. "
        f"three.js r{info.get('revision', '?')}: `PCFShadowMap`, {MAP_SIZE}x{MAP_SIZE} map per "
        "light, shadow camera fitted to the scene's box, maps redrawn each frame, timed in the "
        "page from `render` to the end of a whole-frame `readPixels`. The same geometry, "
        f"instance matrices, materials, camera and lights; frames interleaved in runs of {RUN} "
        "(ours, three.js reading back every pixel, three.js reading back one; "
        f"{repeats} times), medians over every frame. IoU of the shadow mask against the "
        "ray-traced reference; three.js's mask read off its shadowed, unshadowed and "
        "ambient-only frames.",
        "",
        table,
        "",
        *[f"- {n}" for n in notes],
        "",
        "![three.js against ours](vs_threejs_check.png)",
        "",
        f"`vs_threejs_check.png` ({check_scene}): top, three.js's frame and ours; bottom, "
        "three.js's derived mask and the reference's (white lit, black shadowed, grey not "
        "evaluated).",
        "",
        f"Machine: ours {machine}; three.js through Chromium's WebGL: {info.get('renderer', '?')}. "
        f"Run time {elapsed:.0f} s" + (" (--quick)." if quick else "."),
        "",
    ])
    C.finish(out_dir, "vs_threejs", md, csv_rows, [table], notes, elapsed,
             extra=["vs_threejs_check.png"])


#: Rounds of interleaved frames per scene.
REPEATS = 15
#: Frames in a row per side and round: ours as many as three.js's page times per call.
RUN = 2


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if "--repeats" not in args and "--quick" not in args:
        args += ["--repeats", str(REPEATS)]
    C.bench_main(__doc__, run, "two scenes, 3 repeats (smoke run)", 3, args)


if __name__ == "__main__":
    sys.exit(main())
