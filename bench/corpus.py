"""Every model in the models folder under a directional, a spot and a point light: shadow IoU.

The cases of the corpus test (tests/test_gltf_render.py): each file on a ground plane, 640×480,
default settings, with the lights of ``testing.corpus_lights``, scored against the ray-traced
reference; a file that cannot be loaded is listed with the error that names why. Per case: the
map the plan chose, IoU, false and missed shadow (shares of the reference's lit and shadowed
pixels), the shadow's size in pixels (a few hundred pixels of slivers make IoU coarse), and
whether it reaches ``testing.CORPUS_IOU``. No timings: each frame is the first of its scene
(uploads, shader variants), and the cost benchmarks time these models warm. Written to
bench/results/corpus.md and .csv.

    python bench/corpus.py [--quick]
"""

from __future__ import annotations

import time

import numpy as np

from bench import _common as C  # before shadowmap: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams, ShadowMapError  # noqa: E402
from shadowmap.renderer import testing as T  # noqa: E402


def _names(quick: bool) -> list[str]:
    names = sorted(p.name for p in C.models_dir().iterdir() if p.suffix in (".glb", ".gltf"))
    return names[:3] if quick else names


def run(quick: bool, repeats: int) -> None:
    del repeats  # one measured frame per case: this table is about accuracy
    t0 = time.perf_counter()
    r = Renderer()
    rows, csv_rows = [], []
    names = _names(quick)
    progress = C.Progress(len(names) * len(T.CORPUS_LIGHT_KINDS), "corpus")
    try:
        for name in names:
            try:
                scene = C.load_model(name, ground=False)
            except ShadowMapError as exc:
                rows.append([name, "—", type(exc).__name__, "—", "—", "—", "—", str(exc)])
                csv_rows.append({"file": name, "error": f"{type(exc).__name__}: {exc}"})
                for _ in T.CORPUS_LIGHT_KINDS:
                    progress.step()
                continue
            grounded = scene.with_ground()
            for kind, lights in T.corpus_lights(scene).items():
                m = T.measure(r, grounded, RenderParams(lights=lights))
                mt = m.metrics[0]
                lp = m.result.plan["lights"][0]
                ref = m.reference.visibility[..., 0]
                shadow_px = int(((ref < 0.5) & m.reference.valid[..., 0]).sum())
                ok = mt.iou >= T.CORPUS_IOU
                shown = f"{lp.get('shadow_map', '—')} {lp.get('map_size', '')}".strip()
                rows.append([name, kind, shown, C.fmt(mt.iou, 3), C.fmt(mt.false_shadow_pct, 3),
                             C.fmt(mt.missed_shadow_pct, 2), shadow_px,
                             "yes" if ok else "**no**"])
                csv_rows.append({"file": name, "light": kind, "map": lp.get("shadow_map"),
                                 "map_size": lp.get("map_size"), "iou": mt.iou,
                                 "false_shadow_pct": mt.false_shadow_pct,
                                 "missed_shadow_pct": mt.missed_shadow_pct,
                                 "shadow_px": shadow_px, "passes": ok})
                progress.step()
        progress.close()
        info = C.machine_info(r)
    finally:
        r.close()
    table = C.markdown_table(
        ["file", "light", "map", "IoU", "false shadow %", "missed shadow %", "shadow px",
         f"IoU ≥ {T.CORPUS_IOU}"], rows, align="llrrrrrc")
    ious = [c["iou"] for c in csv_rows if "iou" in c]
    failing = [f"{c['file']} ({c['light']})" for c in csv_rows if c.get("passes") is False]
    notes = [
        f"- {len(ious)} cases over {len(names)} files; IoU median {np.median(ious):.3f}, lowest "
        f"{min(ious):.3f}; below {T.CORPUS_IOU}: {', '.join(failing) if failing else 'none'}.",
        "- false shadow: % of the reference's lit pixels drawn shadowed; missed: % of its "
        "shadowed pixels drawn lit.",
    ]
    elapsed = time.perf_counter() - t0
    md = "\n".join([
        "# The model corpus under three lights",
        "",
        "`bench/corpus.py`: every file of the models folder on a ground plane, 640×480, default "
        "settings, under the corpus test's directional, spot and point lights "
        "(`testing.corpus_lights`), against the ray-traced reference.",
        "",
        table,
        "",
        *notes,
        "",
        f"Machine: {info}. Run time {elapsed:.0f} s.",
        "",
    ])
    C.finish(C.results_dir(quick), "corpus", md, csv_rows, [table], notes, elapsed)


if __name__ == "__main__":
    C.bench_main(__doc__, run, "the first three files", 1)
