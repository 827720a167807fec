"""Shadow error against run time over the shadow settings.

Sweeps encoding (r8, rg8, rgb8, rgba8, depth) x map size (512, 1024, 2048, 4096, auto) x filter
(hard, PCF 3x3, and for the depth encoding PCF 1x1: one bilinear 2x2 compare) x bias
mode over a scene set of the real models (with ground) and stress scenes
(grazing light 5 degrees above a plane, a spot light 100 scene sizes away with a narrow cone, the
caster-on-ground scene at 1/1000 scale).

Bias modes (in shadow-map texels, see :class:`renderer.params.BiasParams`):

- ``slope``: the defaults (constant 0.5, slope 0.25, slope_max 10);
- ``constant``: no slope term, a constant of 3 texels;
- ``normal``: normal offset 1.5 texels with a small slope (0.25) and the default constant.

Per configuration and scene: the error against the ray-traced reference (traced once per scene
and reused by every configuration) from one visibility render, and the median wall time of
repeated colour renders (the production request) after a warm-up, with the light-pass time; the
light-map cache is off, so every render draws its maps.
Per configuration: the mean over scenes of 1 - IoU, of the misclassified percentage and of the
per-scene median times.

A second section sweeps the cascade settings (one map, 2, 3 and 4 cascades, 'auto', 'auto' in
stable mode) over the large scenes of ``shadowmap.renderer.testing`` (terrain to the horizon, a
1-unit box on a 10,000-unit plane, a city grid from street level): the worst IoU over bands of
camera distance, the overall IoU, and the median frame time, interleaved across the settings,
with its ratio to the one-map frame (``cascades_vs_time.{md,csv}``; ``--cascades`` runs only
this section).

Writes ``bench/results/error_vs_time.{csv,md,png}``; prints whether the default configuration
(the shadow settings of ``RenderParams()``) is on the Pareto front of time against mean
misclassified percentage. ``--quick`` writes to ``bench/results/quick/``.

Run: ``PYTHONPATH=. .venv/bin/python bench/error_vs_time.py [--quick] [--repeats N]
[--cascades]``
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass

import numpy as np  # noqa: E402

from bench import _common as C  # before shadowmap: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.metrics import compare_all, shadow_metrics  # noqa: E402
from shadowmap.renderer.params import BiasParams  # noqa: E402
from shadowmap.renderer.reference import trace_reference  # noqa: E402

ENCODINGS = ("r8", "rg8", "rgb8", "rgba8", "depth")
SIZES: tuple = (512, 1024, 2048, 4096, "auto")
# pcf1: one tap; with the depth encoding that is a bilinear 2x2 compare (four texels gathered),
# with the packed encodings the same as hard (so it is swept for depth only).
FILTERS = ("hard", "pcf1", "pcf3")
BIAS_MODES: dict[str, dict] = {
    "slope": {},  # BiasParams() defaults
    "constant": {"slope": 0.0, "constant": 3.0},
    "normal": {"normal_offset": 1.5, "slope": 0.25},
}
SCENES = ("Duck.glb", "BoxTextured.glb", "CesiumMilkTruck.glb", "AlphaBlendModeTest.glb",
          "TestScene.gltf", "grazing_5deg", "far_spot", "caster_1e-3")
QUICK = {
    "encodings": ("r8", "rgba8", "depth"),
    "sizes": (1024, "auto"),
    "filters": FILTERS,
    "bias": ("slope",),
    "scenes": ("BoxTextured.glb", "grazing_5deg", "caster_1e-3"),
}


def _default() -> tuple:
    """The default request's shadow settings as a sweep point (bias: the "slope" mode)."""
    sh = RenderParams().shadows
    name = "hard" if sh.filter == "hard" else f"pcf{sh.pcf_kernel}"
    if sh.bias != BiasParams() or name not in FILTERS:
        raise SystemExit("the default shadow settings are not a point of this sweep")
    return (sh.encoding, sh.map_size, name, "slope")


DEFAULT = _default()


@dataclass(frozen=True)
class Config:
    encoding: str
    size: int | str
    filter: str
    bias: str

    @property
    def name(self) -> str:
        return f"{self.encoding}/{self.size}/{self.filter}/{self.bias}"

    def shadows(self) -> dict:
        kernel = int(self.filter[3:]) if self.filter.startswith("pcf") else 3
        return {"encoding": self.encoding, "map_size": self.size,
                "filter": "hard" if self.filter == "hard" else "pcf", "pcf_kernel": kernel,
                "bias": BIAS_MODES[self.bias]}

    @property
    def is_default(self) -> bool:
        return (self.encoding, self.size, self.filter, self.bias) == DEFAULT


def build_scene(name: str) -> C.BenchScene:
    return C.model_scene(name) if "." in name else C.stress_scene(name)


def pareto(points: list[tuple[float, float]]) -> list[bool]:
    """Which (time, error) points no other point beats in both (<= both, < one)."""
    out = []
    for i, (t, e) in enumerate(points):
        dominated = any(
            (t2 <= t and e2 <= e) and (t2 < t or e2 < e)
            for j, (t2, e2) in enumerate(points) if j != i
        )
        out.append(not dominated)
    return out


def light_mean(vis: np.ndarray, ref) -> dict:
    """Metrics of every light, averaged over lights (the scenes here have one each)."""
    ms = [m.to_dict() for m in compare_all(vis, ref)]
    out = {}
    for key in ("iou", "misclassified_pct", "false_shadow_pct", "missed_shadow_pct",
                "edge_distance_px"):
        vals = [m[key] for m in ms if m[key] is not None]
        out[key] = float(np.mean(vals)) if vals else math.nan
    out["pixels"] = int(sum(m["pixels"] for m in ms))
    return out


def pyrender_point(bench_scenes: list[C.BenchScene], refs: dict, repeats: int,
                   bar: C.Progress) -> tuple[list[dict], float, float]:
    """pyrender's shadows on the directional scenes: rows, mean ms, mean misclassified %."""
    rows = []
    pb = C.PyrenderBaseline(C.WIDTH, C.HEIGHT)
    try:
        for bs in bench_scenes:
            if not bs.directional_only:
                continue
            ps = pb.build(bs)
            t = C.time_interleaved({"sh": lambda ps=ps: pb.render(ps, True)}, repeats)["sh"]
            vis, _ = pb.visibility(ps)
            ref = refs[bs.name]
            m = shadow_metrics(vis, ref.visibility[..., 0], ref.valid[..., 0])
            rows.append({"scene": bs.name, "total_ms": t.ms(), "iou": m.iou,
                         "misclassified_pct": m.misclassified_pct})
            del ps
            bar.step("pyrender " + bs.name)
    finally:
        pb.close()
    return (rows, float(np.mean([r["total_ms"] for r in rows])),
            float(np.mean([r["misclassified_pct"] for r in rows])))


def plot(path, agg: list[dict], pyr: tuple[float, float] | None, ref_ms: float,
         title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, LogLocator

    colours = dict(zip(ENCODINGS, ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"),
                       strict=True))
    markers = {"hard": "o", "pcf1": "^", "pcf3": "s"}
    fig, ax = plt.subplots(figsize=(10, 6.5), dpi=110)
    errs = [a["misclassified_pct"] for a in agg] + ([pyr[1]] if pyr else [])
    positive = [e for e in errs if e > 0]
    floor = (min(positive) / 2) if positive else 1e-3
    for a in agg:
        ax.scatter(a["total_ms"], max(a["misclassified_pct"], floor), s=30,
                   c=colours[a["encoding"]], marker=markers[a["filter"]], alpha=0.75,
                   edgecolors="none", zorder=3)
    front = sorted((a for a in agg if a["pareto"]), key=lambda a: a["total_ms"])
    if front:
        xs = [a["total_ms"] for a in front]
        ys = [max(a["misclassified_pct"], floor) for a in front]
        ax.step(xs, ys, where="post", color="black", lw=1.2, zorder=2, label="Pareto front")
        # Label at most ~8 front points, spread along it, so that labels stay legible.
        step = max(1, math.ceil(len(front) / 8))
        for a in front[::step] + ([front[-1]] if (len(front) - 1) % step else []):
            ax.annotate(a["config"], (a["total_ms"], max(a["misclassified_pct"], floor)),
                        xytext=(5, 4), textcoords="offset points", fontsize=7, color="0.2")
    for a in agg:
        if a["default"]:
            ax.scatter(a["total_ms"], max(a["misclassified_pct"], floor), s=260,
                       facecolors="none", edgecolors="red", linewidths=2.0, zorder=4)
            ax.annotate(f"default (RenderParams()): {a['config']}",
                        (a["total_ms"], max(a["misclassified_pct"], floor)),
                        xytext=(-60, -45), textcoords="offset points", color="red", fontsize=9,
                        arrowprops={"arrowstyle": "->", "color": "red", "lw": 0.8})
    if pyr:
        ax.scatter([pyr[0]], [max(pyr[1], floor)], marker="*", s=260, c="black", zorder=5)
        ax.annotate("pyrender built-in shadows\n(directional scenes)", (pyr[0], pyr[1]),
                    xytext=(8, 4), textcoords="offset points", fontsize=8)
    ax.scatter([ref_ms], [floor], marker="v", s=140, c="dimgray", zorder=5, clip_on=False)
    ax.annotate("ray-traced reference\n(error 0, drawn at the axis floor)", (ref_ms, floor),
                xytext=(-40, 12), textcoords="offset points", fontsize=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor, top=max(errs + [floor]) * 2.5)
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(plain)
        axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
    ax.set_xlabel("median render time, mean over scenes (ms, log)")
    ax.set_ylabel("misclassified pixels, mean over scenes (%, log)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    handles = [Line2D([], [], ls="", marker="o", color=colours[e], label=e) for e in ENCODINGS]
    handles += [Line2D([], [], ls="", marker=m, color="gray", label=f) for f, m in markers.items()]
    handles += [Line2D([], [], color="black", label="Pareto front"),
                Line2D([], [], ls="", marker="o", mfc="none", mec="red", ms=12, label="default")]
    ax.legend(handles=handles, fontsize=8, loc="lower left", ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run(quick: bool, repeats: int) -> None:
    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    if quick:
        grid = (QUICK["encodings"], QUICK["sizes"], QUICK["filters"], QUICK["bias"])
        scene_names = QUICK["scenes"]
    else:
        grid = (ENCODINGS, SIZES, FILTERS, tuple(BIAS_MODES))
        scene_names = SCENES
    configs = [Config(*c) for c in itertools.product(*grid)
               if c[2] != "pcf1" or c[0] == "depth"]
    bench_scenes = [build_scene(n) for n in scene_names]
    n_dir = sum(bs.directional_only for bs in bench_scenes)
    bar = C.Progress(len(bench_scenes) * (len(configs) + 1) + n_dir, "error_vs_time")

    rows: list[dict] = []
    refs = {}
    r = Renderer(map_cache_bytes=0)  # every render draws its light pass
    try:
        for bs in bench_scenes:
            camera, lights = bs.resolved()
            ref = refs[bs.name] = trace_reference(bs.scene, camera, lights)
            bar.step(f"{bs.name}: reference")
            for cfg in configs:
                # One visibility render gives the error; it also warms up the shadow maps.
                res = r.render(bs.scene, bs.params(shadows=cfg.shadows(), outputs=["visibility"]))
                m = light_mean(res.visibility, ref)
                p = bs.params(shadows=cfg.shadows())
                t = C.time_render(r, bs.scene, p, repeats)
                plan = t.last.plan["lights"][0]
                rows.append({
                    "config": cfg.name, "encoding": cfg.encoding, "map_size": cfg.size,
                    "filter": cfg.filter, "bias": cfg.bias, "scene": bs.name,
                    "map_size_used": plan.get("map_size"), "map_kind": plan.get("shadow_map"),
                    "iou": round(m["iou"], 6), "one_minus_iou": round(1 - m["iou"], 6),
                    "misclassified_pct": round(m["misclassified_pct"], 5),
                    "false_shadow_pct": round(m["false_shadow_pct"], 5),
                    "missed_shadow_pct": round(m["missed_shadow_pct"], 5),
                    "edge_distance_px": round(m["edge_distance_px"], 4),
                    "pixels": m["pixels"],
                    "total_ms": round(t.ms(), 3), "total_p90_ms": round(t.p90_ms(), 3),
                    "light_ms": round(t.ms("light"), 3), "camera_ms": round(t.ms("camera"), 3),
                    "reference_ms": round(ref.seconds * 1e3, 1), "repeats": repeats,
                    "default": cfg.is_default,
                })
                bar.step(f"{bs.name} {cfg.name}")
        machine = C.machine_info(r)
    finally:
        r.close()
    pyr_rows, pyr_ms, pyr_err = pyrender_point(bench_scenes, refs, repeats, bar)
    bar.close()

    # Aggregate per configuration over scenes.
    agg: list[dict] = []
    for cfg in configs:
        rs = [x for x in rows if x["config"] == cfg.name]
        agg.append({
            "config": cfg.name, "encoding": cfg.encoding, "map_size": cfg.size,
            "filter": cfg.filter, "bias": cfg.bias, "default": cfg.is_default,
            "total_ms": float(np.mean([x["total_ms"] for x in rs])),
            "light_ms": float(np.mean([x["light_ms"] for x in rs])),
            "one_minus_iou": float(np.mean([x["one_minus_iou"] for x in rs])),
            "misclassified_pct": float(np.mean([x["misclassified_pct"] for x in rs])),
            "worst_misclassified_pct": float(np.max([x["misclassified_pct"] for x in rs])),
        })
    for a, on in zip(agg, pareto([(a["total_ms"], a["misclassified_pct"]) for a in agg]),
                     strict=True):
        a["pareto"] = on
    agg.sort(key=lambda a: a["total_ms"])
    ref_ms = float(np.mean([ref.seconds * 1e3 for ref in refs.values()]))
    dir_names = {x["scene"] for x in pyr_rows}
    default = next((a for a in agg if a["default"]), None)

    # Summary lines.
    notes = []
    if default is not None:
        if default["pareto"]:
            notes.append(f"The default configuration ({default['config']}) is on the Pareto front.")
        else:
            better = [a for a in agg if a is not default
                      and a["total_ms"] <= default["total_ms"]
                      and a["misclassified_pct"] <= default["misclassified_pct"]]
            better.sort(key=lambda a: a["misclassified_pct"])
            notes.append(
                f"The default configuration ({default['config']}) is NOT on the Pareto front: "
                f"{len(better)} configurations are at least as fast and as accurate, e.g. "
                + ", ".join(f"{a['config']} ({a['total_ms']:.1f} ms, "
                            f"{a['misclassified_pct']:.3f} %)" for a in better[:3]) + "."
            )
        faster = [a for a in agg if a["total_ms"] <= default["total_ms"]]
        as_good = [a for a in agg if a["misclassified_pct"] <= default["misclassified_pct"]]
        best_err = min(a["misclassified_pct"] for a in faster)
        best_ms = min(a["total_ms"] for a in as_good)
        notes.append(
            f"Default: {default['total_ms']:.1f} ms, {default['misclassified_pct']:.4f} % "
            f"misclassified, 1-IoU {default['one_minus_iou']:.4f}. Best error at no more time: "
            f"{best_err:.4f} %; least time at no more error: {best_ms:.1f} ms "
            f"(timings are medians of {repeats} calls on a shared machine: differences of a few "
            "ms are within their noise)."
        )
        d_sub = [x for x in rows if x["default"] and x["scene"] in dir_names]
        if d_sub:
            notes.append(
                f"On pyrender's scenes (directional light: {', '.join(sorted(dir_names))}) the "
                f"default takes {np.mean([x['total_ms'] for x in d_sub]):.1f} ms with "
                f"{np.mean([x['misclassified_pct'] for x in d_sub]):.3f} % misclassified; "
                f"pyrender {pyr_ms:.1f} ms with {pyr_err:.3f} %."
            )
    notes.append(f"Ray-traced reference: {ref_ms:.0f} ms per scene on average (error 0 by "
                 "definition; traced once per scene).")
    front = [a["config"] for a in agg if a["pareto"]]
    notes.append(f"Pareto front ({len(front)}): {', '.join(front)}.")

    # Tables.
    headers = ["configuration", "mean ms", "light ms", "mean 1−IoU", "mean misclassified %",
               "worst misclassified %", "Pareto"]
    table_rows = [[
        ("**" + a["config"] + "** (default)") if a["default"] else a["config"],
        C.fmt(a["total_ms"]), C.fmt(a["light_ms"]), C.fmt(a["one_minus_iou"], 4),
        C.fmt(a["misclassified_pct"], 3), C.fmt(a["worst_misclassified_pct"], 3),
        "★" if a["pareto"] else "",
    ] for a in agg]
    table = C.markdown_table(headers, table_rows, "lrrrrrc")
    per_scene_cfgs = [a["config"] for a in agg if a["pareto"] or a["default"]]
    ps_headers = ["configuration"] + [bs.name for bs in bench_scenes]
    ps_rows = []
    for name in per_scene_cfgs:
        cells = []
        for bs in bench_scenes:
            x = next(x for x in rows if x["config"] == name and x["scene"] == bs.name)
            cells.append(f"{x['misclassified_pct']:.3f} / {x['total_ms']:.0f}")
        label = f"**{name}** (default)" if name == Config(*DEFAULT).name else name
        ps_rows.append([label] + cells)
    cells = []
    for bs in bench_scenes:
        p = next((x for x in pyr_rows if x["scene"] == bs.name), None)
        cells.append(f"{p['misclassified_pct']:.3f} / {p['total_ms']:.0f}" if p else "—")
    ps_rows.append(["pyrender built-in"] + cells)
    ps_table = C.markdown_table(ps_headers, ps_rows)
    elapsed = time.perf_counter() - t_start

    scene_desc = ", ".join(bs.name + (f" ({bs.note})" if bs.note else "") for bs in bench_scenes)
    md = "\n".join([
        "# Shadow error against render time",
        "",
        f"{len(configs)} configurations (encoding x map size x filter x bias mode) on "
        f"{len(bench_scenes)} scenes at 640x480: {scene_desc}. "
        "Error: shadow mask against the ray-traced reference over its valid pixels, mean over "
        f"scenes. Time: median wall time of {repeats} colour renders after a warm-up (light-map "
        "cache off: each render draws its maps), mean over "
        "scenes (light ms: the light-pass stage). Bias modes: slope = defaults (constant 0.5, "
        "slope 0.25 texels); constant = 3 texels, no slope; normal = normal offset 1.5 texels, "
        "slope 0.25. ★ = on the Pareto front of mean time against mean misclassified %. Sorted by "
        "time.",
        "",
        *[f"- {n}" for n in notes],
        "",
        "![error against time](error_vs_time.png)",
        "",
        table,
        "",
        "## Per scene: the Pareto configurations, the default and pyrender",
        "",
        "Each cell: misclassified % / median ms (pyrender: directional scenes only).",
        "",
        ps_table,
        "",
        f"Machine: {machine}. Run time {elapsed:.0f} s" + (" (--quick)." if quick else "."),
        "",
    ])
    title = (f"Shadow error vs time: {len(configs)} configurations, {len(bench_scenes)} scenes, "
             f"640x480, llvmpipe" + (" (quick)" if quick else ""))
    plot(out_dir / "error_vs_time.png", agg, (pyr_ms, pyr_err) if pyr_rows else None, ref_ms,
         title)
    C.finish(out_dir, "error_vs_time", md, rows, [table, ps_table], notes, elapsed,
             extra=["error_vs_time.png"])


CASCADE_CONFIGS: dict[str, dict] = {
    "one map": {"cascades": 1},
    "2 cascades": {"cascades": 2},
    "3 cascades": {"cascades": 3},
    "4 cascades": {"cascades": 4},
    "auto (default)": {},
    "auto, stable": {"stable_cascades": True},
}
LARGE_SCENES = ("terrain_to_horizon", "small_caster_on_huge_plane", "city_grid")


def run_cascades(quick: bool, repeats: int) -> None:
    """The cascade settings over the large scenes: worst band IoU and time against one map."""
    from shadowmap.renderer import testing as T

    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    names = LARGE_SCENES[:2] if quick else LARGE_SCENES
    rows: list[dict] = []
    with Renderer(map_cache_bytes=0) as r:  # every render draws its light pass
        for name in names:
            large = getattr(T, name)()
            params = {k: RenderParams(lights=[large.light], camera=large.camera, shadows=v)
                      for k, v in CASCADE_CONFIGS.items()}
            errors = {}
            for k, p in params.items():
                m = T.measure(r, large.scene, p)
                bands = T.band_metrics(m.result.visibility, m.reference, large.bands)
                lp = m.result.plan["lights"][0]
                errors[k] = (m.metrics[0].iou, min(b.iou for b in bands),
                             [b.iou for b in bands], lp)
            times = C.time_interleaved(
                {k: (lambda p=p, s=large.scene: r.render(s, p)) for k, p in params.items()},
                repeats)
            base = times["one map"].ms()
            for k in params:
                iou, worst, per_band, lp = errors[k]
                cascades = lp.get("cascades", [])
                rows.append({
                    "scene": name, "config": k, "iou": round(iou, 4), "worst_band_iou":
                    round(worst, 4), "band_iou": " / ".join(f"{b:.3f}" for b in per_band),
                    "cascades": len(cascades) or 1,
                    "map_size": cascades[0]["map_size"] if cascades else lp.get("map_size"),
                    "total_ms": round(times[k].ms(), 2), "light_ms": round(times[k].ms("light"), 2),
                    "camera_ms": round(times[k].ms("camera"), 2),
                    "plan_ms": round(times[k].ms("plan"), 2),
                    "ratio_to_one_map": round(times[k].ms() / base, 3),
                })
        machine = C.machine_info(r)
    headers = ["scene", "setting", "maps", "map size", "IoU", "worst band IoU",
               "IoU near / mid / far", "ms", "light ms", "camera ms", "× one map"]
    table = C.markdown_table(headers, [[
        x["scene"].replace("_", " "), x["config"], x["cascades"], x["map_size"],
        C.fmt(x["iou"], 3), C.fmt(x["worst_band_iou"], 3), x["band_iou"],
        C.fmt(x["total_ms"]), C.fmt(x["light_ms"]), C.fmt(x["camera_ms"]),
        C.fmt(x["ratio_to_one_map"], 2)] for x in rows], "llrrrrlrrrr")
    elapsed = time.perf_counter() - t_start
    md = "\n".join([
        "# Cascaded shadow maps: error against time on large scenes",
        "",
        "640x480, one directional light, default settings but for the cascades. IoU: shadow "
        "mask against the ray-traced reference; bands: camera distance near / middle / far "
        "(edges in `shadowmap.renderer.testing`). Times: medians of "
        f"{repeats} colour renders per setting, interleaved; × one map: the setting's time over "
        "the one-map frame of the same scene.",
        "",
        table,
        "",
        f"Machine: {machine}. Run time {elapsed:.0f} s" + (" (--quick)." if quick else "."),
        "",
    ])
    C.finish(out_dir, "cascades_vs_time", md, rows, [table], [], elapsed)


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    cascades_only = "--cascades" in args
    args = [a for a in args if a != "--cascades"]

    def both(quick: bool, repeats: int) -> None:
        if not cascades_only:
            run(quick, repeats)
        run_cascades(quick, repeats)

    C.bench_main(__doc__ or "", both,
                 "a few configurations on 3 scenes, 2 repeats (smoke run)", 2, args)


if __name__ == "__main__":
    sys.exit(main())
