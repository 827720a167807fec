"""Stiff and extreme cases for every depth encoding: IoU and acne against the ray-traced reference.

The same cases as tests/test_stability.py, run for all five encodings (the tests assert on the
default only) and for the ``depth`` encoding held to 32 bits (``depth_bits: 32``; the ``depth``
column is ``auto``, which picks 16 bits where the map's depth range allows; each case's name
says what it picked), plus close views of a part of a vast scene (``testing.part_far_out``),
a model a millionth of a unit across far from the world's origin, plus the large scenes of
tests/test_cascades.py (terrain to the horizon, a small box on a 10,000-unit plane, a city
grid from street level; at the origin and 1e6 away) scored by their worst band of camera
distance. Printed as a Markdown table and written to bench/results/stability.md.

    python bench/stability.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from bench import _common as C
from bench._common import results_dir
from shadowmap.renderer import Renderer, RenderParams
from shadowmap.renderer import testing as T
from shadowmap.renderer.params import ENCODINGS

#: The table's columns: every encoding (``depth`` with ``depth_bits: auto``), and ``depth`` at
#: 32 bits.
COLUMNS = {**{enc: {"encoding": enc} for enc in ENCODINGS},
           "depth, 32-bit": {"encoding": "depth", "depth_bits": 32}}
CAMERA = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}


def _far_spot(distance: float) -> dict:
    d = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    cone = math.degrees(math.atan(5.0 / distance)) * 1.2
    return {"type": "spot", "position": (-d * distance).tolist(), "target": [0, 0, 0],
            "outer_cone_deg": cone}


def _grazing_at(elevation: float) -> dict:
    e = math.radians(elevation)
    return {"type": "directional", "direction": [0.3 * math.cos(e), -math.sin(e), math.cos(e)]}


def cases(quick: bool):
    """(name, scene, params, criterion) for every case; criterion is "iou", "acne", or the band
    edges of a large scene (every band's IoU must pass)."""
    base = T.caster_on_ground()
    grazing = T.grazing_plane()
    out = [
        ("spot light at 40 (LIGHT_Y)", base, dict(camera=CAMERA, lights=[_far_spot(40)]), "iou"),
        ("spot light 100x scene size", base, dict(camera=CAMERA, lights=[_far_spot(600)]), "iou"),
        ("spot light 1000x scene size", base, dict(camera=CAMERA, lights=[_far_spot(6000)]), "iou"),
        ("directional from 1000x away", base, dict(camera=CAMERA, lights=[
            {"type": "directional", "position": [-1800, 6000, -1200], "target": [0, 0, 0]}]),
         "iou"),
    ]
    for e in (10, 5, 2, 0.3):
        out.append((f"grazing light {e} deg", grazing,
                    dict(camera={"eye": [0, 6, 12], "target": [0, 0, 0]}, lights=[_grazing_at(e)]),
                    "acne"))
    # The same 0.3 degrees from spot and point lights 200 units away (a point light's map is
    # then one frustum around the scene).
    far = (-np.asarray(_grazing_at(0.3)["direction"]) * 200.0).tolist()
    for kind, lt in (("spot", {"type": "spot", "position": far, "target": [0, 0, 0],
                               "outer_cone_deg": 5}),
                     ("point", {"type": "point", "position": far})):
        out.append((f"grazing {kind} light 0.3 deg, 200 away", grazing,
                    dict(camera={"eye": [0, 6, 12], "target": [0, 0, 0]}, lights=[lt]), "iou"))
    plain = T.pebbles_on_a_plain()
    for e in (30, 5):
        out.append((f"pebbles on a 400-unit plain, light {e} deg", plain,
                    dict(camera={"eye": [0, 3, 6], "target": [0, 0, 0]}, lights=[_grazing_at(e)]),
                    "iou"))
    light = {"type": "directional", "direction": [-0.5, -1.0, -0.3]}
    for scale, off in ((1e-3, 0.0), (1e4, 0.0), (1.0, 1e5)):
        o = np.array([off] * 3)
        cam = {"eye": (np.array(CAMERA["eye"]) * scale + o).tolist(),
               "target": (np.array(CAMERA["target"]) * scale + o).tolist()}
        out.append((f"scale {scale:g}, offset {off:g}", T.transformed(base, scale, (off,) * 3),
                    dict(camera=cam, lights=[light]), "iou"))
    # A close view of one part of a vast scene (its other part 1e5 or 1e7 units away, the
    # scene's centre half-way): drawn relative to a point beside the eye.
    for far in (1e5, 1e7):
        out.append((f"close view of a part {far:g} from the rest", T.part_far_out(far),
                    dict(camera={"eye": [far + 2, 3, 3], "target": [far, 0.5, 0]},
                         lights=[{"direction": [-0.3, -1.0, -0.2]}]), "iou"))
    # A model a millionth of a unit across on its ground, far from the world's origin, seen by
    # its file's camera (moved with it): 1.83e8 out, where float64 world coordinates step by
    # 3e-8, a twentieth of it; 9.15e9 out, where they step by 1.9e-6, more than its width, under
    # a point light 3630 sizes away.
    duck = C.load_model("Duck.glb")
    out.append(("Duck 1e-6 units across, 1.83e8 out", T.transformed(duck, 5.05e-7,
                                                                   (0.0, 1.83e8, 0.47)),
                dict(lights=[{"direction": [0.2, -1.0, 0.1]}]), "iou"))
    tiny = T.transformed(duck, 4.363e-7, (9.15e9, 0.0, -1.64))
    lo, hi = tiny.bounds
    to_light = np.array([0.523, -0.614, 0.591]) * float(np.linalg.norm(hi - lo)) * 3630
    out.append(("Duck 7e-7 units across, 9.15e9 out, point light", tiny,
                dict(lights=[{"type": "point", "position": ((lo + hi) / 2 - to_light).tolist()}]),
                "iou"))
    out += [
        ("spot cone 179 deg", base, dict(camera=CAMERA, lights=[
            {"type": "spot", "position": [0.5, 2.5, 0.5], "direction": [0, -1, 0],
             "outer_cone_deg": 89.5}]), "iou"),
        ("point light in a room", T.room(), dict(
            camera={"eye": [3.0, 3.5, 3.0], "target": [-2, -1, -2]},
            lights=[{"type": "point", "position": [0, 2, 0]}]), "iou"),
        ("thin two-sided sheets", T.thin_sheets(), dict(camera=CAMERA, lights=[
            {"direction": [-0.4, -1, -0.3]}]), "iou"),
        ("degenerate triangles", T.degenerate_geometry(), dict(camera=CAMERA, lights=[
            {"direction": [-0.4, -1, -0.3]}]), "iou"),
        ("contact shadow", base, dict(camera={"eye": [3.5, 1.5, 3.0], "target": [1.6, 0.3, 0.8]},
                                      lights=[{"direction": [-0.6, -0.5, -0.4]}]), "iou"),
    ]
    # Large scenes seen from the ground (cascades), at the origin and 1e6 away: the criterion is
    # the worst band of camera distance (near, middle, far).
    for make in (T.terrain_to_horizon, T.small_caster_on_huge_plane, T.city_grid):
        large = make()
        for off in (0.0, 1e6):
            shift = np.array([off, 0.0, off])
            scene = T.transformed(large.scene, offset=tuple(shift)) if off else large.scene
            cam = {k: (np.asarray(v) + shift).tolist() for k, v in large.camera.items()}
            name = make.__name__.replace("_", " ") + (f", offset {off:g}" if off else "")
            out.append((name, scene, dict(camera=cam, lights=[large.light]), large.bands))
    return out[:6] if quick else out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few cases only")
    args = ap.parse_args(argv)
    started = time.perf_counter()
    rows = []
    with Renderer() as r:
        todo = cases(args.quick)
        for k, (name, scene, params, criterion) in enumerate(todo):
            cells = []
            bits = []
            for enc, shadows in COLUMNS.items():
                p = RenderParams(**params, shadows=shadows)
                meas = T.measure(r, scene, p)
                m = meas.metrics[0]
                iou = m.iou
                if isinstance(criterion, tuple):  # the worst distance band
                    iou = min(b.iou for b in T.band_metrics(meas.result.visibility,
                                                            meas.reference, criterion))
                ok = m.false_shadow_pct <= 0.1 if criterion == "acne" else iou >= 0.95
                cells.append((iou, m.false_shadow_pct, ok))
                if enc == "depth":
                    bits = [lp.get("depth_bits") for lp in meas.result.plan["lights"]]
            rows.append((name + f" ({'/'.join(map(str, bits))}-bit)", criterion, cells))
            print(f"\r{k + 1}/{len(todo)} {name:40s}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    head = "| case (depth bits auto chose) | criterion | " + " | ".join(COLUMNS) + " |"
    lines = [head, "| :--- | :--- |" + " ---: |" * len(COLUMNS)]
    for name, criterion, cells in rows:
        shown = []
        for iou, acne, ok in cells:
            value = f"{acne:.3f} % acne" if criterion == "acne" else f"IoU {iou:.3f}"
            shown.append(f"{value} {'pass' if ok else '**FAIL**'}")
        crit = {"acne": "false shadow ≤ 0.1 %", "iou": "IoU ≥ 0.95"}.get(
            criterion if isinstance(criterion, str) else "", "every band IoU ≥ 0.95")
        lines.append(f"| {name} | {crit} | " + " | ".join(shown) + " |")
    info = r.info
    text = "\n".join(lines)
    footer = (f"\n\n{info['renderer']} ({info['platform']}), 640x480, default settings but for "
              f"the encoding; {time.perf_counter() - started:.0f} s.\n")
    print(text + footer)
    if not args.quick:
        (results_dir() / "stability.md").write_text("# Stiff and extreme cases, every encoding\n\n"
                                              + text + footer)
    return 0


if __name__ == "__main__":
    sys.exit(main())
