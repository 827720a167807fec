"""The same renders by two versions of the code, interleaved render by render: what a change costs.

Timings taken in two runs of a benchmark differ by more than most changes (these machines are
noisy), so a change to the shaders or the passes is measured here against an earlier commit in
one run: each version renders in a process of its own (its own GL context, its own package
tree), and the two take turns, one render each, the order swapped every repeat. Both processes
load the scenes through their own ``bench/_common.py`` and render them with their own defaults
(``--params`` adds fields, e.g. ``'{"shadows": {"cascades": 3}}'``), so the rendering code is
what differs. Per scene: the median camera-pass and light-pass times and wall time of each,
their ratio, and how many pixels of the colour output differ (the pictures of a change meant to
be invisible should not).

The other version is ``git archive REV`` unpacked into a temporary folder and imported from there
(``shadowmap`` laid out as the installed namespace is), run from that folder; the working tree
is the current one, or with ``--against REV2`` another unpacked commit (a change measured after
the fact: REV its parent, REV2 the change). Each process reports where it imported
``shadowmap.renderer`` and ``bench/_common.py`` from, and a process that did not import its own
version's stops the run. (Until this check, the earlier commit's process imported the working
tree's renderer through the editable install: every comparison before it set the working tree
against itself.) ``--keep-freed`` makes both processes keep freed memory, as the service's and
the batch's render workers do.

``--new-camera`` gives every render a camera no render used before (the scene's own, turned
further about the vertical each time, the same for both versions): each plans anew, as a batch's
views and a moving client's requests do, and the plan stage is where a change to planning shows.

Writes ``bench/results/ab_commits_<REV's short hash>[_<REV2's>][_new_camera].{md,csv}``: one
pair of files per comparison, so that a comparison a note quotes is not replaced by the next one.

``--scenes`` takes model names without extension, stress scene names and ``boxes_10k``, the
10,000 instances of ``bench/floor.py`` (not among the default scenes).

Run: ``PYTHONPATH=. .venv/bin/python bench/ab_commits.py REV [--against REV2]
[--scenes Duck,room_point,boxes_10k] [--repeats N] [--params JSON] [--keep-freed]
[--new-camera]``
"""

from __future__ import annotations

import argparse
import io
import itertools
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import _common as C

#: Lines of the protocol on a child's stdout start with this (anything else it prints is passed
#: on to our stderr).
TAG = "@@ab "
#: The child: renders on request, answers one tagged JSON line per request. It imports only what
#: every version of ``bench/_common.py`` offers.
CHILD = r'''
import ctypes, json, sys, time
import numpy as np

if sys.argv[2] == "keep":  # glibc's trim and mmap thresholds, as keep_freed_memory() sets them
    mallopt = ctypes.CDLL(None).mallopt
    mallopt(-1, 64 << 20)
    mallopt(-3, 32 << 20)
from bench import _common as C
from shadowmap.renderer import Renderer

TAG = "@@ab "
r = Renderer()
scenes, params = {}, {}
extra = json.loads(sys.argv[1])

def scene(name, turn=None):
    if name not in scenes:
        if name.startswith("boxes_"):  # bench/floor.py's many-instances scene
            from bench import floor
            bs = floor.instances_scene()
        else:
            bs = C.model_scene(name + ".glb") if name + ".glb" in C.MODEL_NAMES else (
                C.model_scene(name + ".gltf") if name + ".gltf" in C.MODEL_NAMES
                else C.stress_scene(name))
        scenes[name] = bs
        params[name] = bs.params(**extra)
    bs = scenes[name]
    if turn is None:
        return bs.scene, params[name]
    # A camera no render has used: the scene's own turned about the vertical through the centre
    # of the scene's bounds by `turn` steps of a third of a degree (a plan of its own each time).
    cam = bs.resolved()[0]
    centre = np.asarray(bs.scene.bounds, np.float64).mean(axis=0)
    a = np.radians(turn / 3.0)
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    eye = centre + rot @ (np.asarray(cam.pose[:3, 3], np.float64) - centre)
    return bs.scene, bs.params(camera={"eye": eye.tolist(), "target": centre.tolist()}, **extra)

def reply(obj):
    sys.stdout.write(TAG + json.dumps(obj) + "\n")
    sys.stdout.flush()

import shadowmap.renderer
reply({"ready": True, "info": dict(r.info), "renderer": shadowmap.renderer.__file__,
       "bench": C.__file__})
for line in sys.stdin:
    req = json.loads(line)
    try:
        s, p = scene(req["scene"], req.get("turn"))
        if req["op"] == "render":
            t = time.perf_counter()
            res = r.render(s, p)
            wall = time.perf_counter() - t
            reply({"wall": wall, "timings": {k: float(v) for k, v in res.timings.items()}})
        elif req["op"] == "image":
            np.save(req["path"], r.render(s, p).color)
            reply({"saved": req["path"]})
    except Exception as exc:
        reply({"error": f"{type(exc).__name__}: {exc}"})
'''


def unpack(rev: str, into: Path) -> str:
    """Unpack ``git archive rev`` into ``into/tree`` and lay out ``into/pkg/shadowmap`` as the
    installed namespace (``shadowmap.renderer`` is the tree's ``renderer/``, and so on); returns
    the commit's short hash."""
    commit = subprocess.run(["git", "rev-parse", "--short", rev], cwd=C.ROOT, check=True,
                            capture_output=True, text=True).stdout.strip()
    data = subprocess.run(["git", "archive", "--format=tar", commit], cwd=C.ROOT, check=True,
                          capture_output=True).stdout
    tree = into / "tree"
    tree.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(tree, filter="data")
    pkg = into / "pkg" / "shadowmap"
    pkg.mkdir(parents=True)
    for entry in (tree / "shadowmap").iterdir():
        (pkg / entry.name).symlink_to(entry)
    for sub in ("renderer", "app", "shaders"):
        (pkg / sub).symlink_to(tree / sub)
    return commit


class Version:
    """One version's render process."""

    def __init__(self, label: str, root: Path, cwd: Path, pythonpath: list[Path], extra: dict,
                 keep_freed: bool = False) -> None:
        """``root``: the version's source tree, whose ``renderer/`` and ``bench/`` the process
        must import (checked: a wrong path would compare a version with itself); ``cwd``: the
        folder the process runs in, which Python puts first on its path."""
        self.label = label
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(str(p) for p in pythonpath))
        env.setdefault("PYOPENGL_PLATFORM", "egl")
        env["SHADOWMAP_MODELS"] = str(C.models_dir())  # the unpacked tree has no shared/ beside it
        # ``-c`` puts the working folder first on sys.path: an unpacked commit runs in its
        # package folder, whose ``shadowmap`` is the whole namespace (the tree's own
        # ``shadowmap/`` lacks ``renderer``, which this project's editable install would then
        # supply from the working tree).
        self.proc = subprocess.Popen(
            [sys.executable, "-c", CHILD, json.dumps(extra), "keep" if keep_freed else "-"],
            cwd=cwd, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            bufsize=1)
        ready = self.read()
        self.info: dict[str, str] = ready["info"]
        for what in ("renderer", "bench"):
            path = Path(ready[what]).resolve()
            if not path.is_relative_to(root.resolve()):
                self.close()
                raise RuntimeError(f"{label}: imported its {what} from {path}, not from {root}")

    def read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(TAG):
                reply = json.loads(line[len(TAG):])
                if "error" in reply:
                    raise RuntimeError(f"{self.label}: {reply['error']}")
                return reply
            sys.stderr.write(line)
        raise RuntimeError(f"the {self.label} process ended (exit status {self.proc.wait()})")

    def ask(self, **req: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self.read()

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=30)


def compare(a: Version, b: Version, scene: str, repeats: int, warmup: int = 3,
            new_camera: bool = False, turns: itertools.count | None = None
            ) -> dict[str, dict[str, list[float]]]:
    """Render ``scene`` ``repeats`` times in each version, alternating (A B, B A, A B, ...);
    with ``new_camera`` each pair of renders from a camera turned further (``turns``: the step
    counter, shared by every scene and round so that no camera comes back)."""
    turns = turns if turns is not None else itertools.count(1)

    def turn() -> dict[str, int]:
        return {"turn": next(turns)} if new_camera else {}

    for _ in range(warmup):
        t = turn()
        a.ask(op="render", scene=scene, **t)
        b.ask(op="render", scene=scene, **t)
    out: dict[str, dict[str, list[float]]] = {a.label: {}, b.label: {}}
    for k in range(repeats):
        t = turn()
        for v in ((a, b) if k % 2 == 0 else (b, a)):
            r = v.ask(op="render", scene=scene, **t)
            out[v.label].setdefault("wall", []).append(r["wall"])
            for stage, sec in r["timings"].items():
                out[v.label].setdefault(stage, []).append(sec)
    return out


def _unpacked(label: str, into: Path, extra: dict, keep_freed: bool) -> Version:
    """The render process of a commit :func:`unpack` laid out in ``into``."""
    return Version(label, into / "tree", into / "pkg", [into / "pkg", into / "tree"], extra,
                   keep_freed)


def _pixels_differing(a: Version, b: Version, scene: str, folder: Path) -> int:
    """Pixels of ``scene``'s colour output that differ between the versions (any channel; -1
    when the images' shapes differ)."""
    import numpy as np

    paths = [folder / f"{scene}_{k}.npy" for k in range(2)]
    a.ask(op="image", scene=scene, path=str(paths[0]))
    b.ask(op="image", scene=scene, path=str(paths[1]))
    ia, ib = (np.load(p).astype(np.int16) for p in paths)
    return int((np.abs(ia - ib).max(axis=-1) > 0).sum()) if ia.shape == ib.shape else -1


def run(rev: str, scenes: list[str], repeats: int, rounds: int, extra: dict,
        keep_freed: bool = False, against: str | None = None, new_camera: bool = False) -> None:
    t_start = time.perf_counter()
    stages = ("plan", "camera", "light", "readback", "wall")
    turns = itertools.count(1)
    # per scene, version and stage: the median of each round
    medians: dict[str, dict[str, dict[str, list[float]]]] = {}
    differ: dict[str, int] = {}
    info: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="ab_commits_") as tmp:
        root = Path(tmp)
        commit = unpack(rev, root / "rev")
        if against is not None:
            other = unpack(against, root / "against")
            here, b_label = f"commit {other}", other
        else:
            here, b_label = C.code_state(), "working tree"
        bar = C.Progress(rounds * len(scenes), "ab_commits")
        try:
            for k in range(rounds):
                # Fresh processes each round: a process's timings can settle at a few per cent
                # (sometimes tens of per cent on one scene) from another's of the same code
                # (where its buffers happen to lie), so one pair of processes is one sample.
                base = _unpacked(commit, root / "rev", extra, keep_freed)
                work = (_unpacked(b_label, root / "against", extra, keep_freed)
                        if against is not None
                        else Version(b_label, C.ROOT, C.ROOT, [C.ROOT], extra, keep_freed))
                info = work.info
                try:
                    for name in scenes:
                        t = compare(base, work, name, repeats, new_camera=new_camera,
                                    turns=turns)
                        for label, key in ((commit, "a"), (b_label, "b")):
                            for stage in stages:
                                v = t[label].get(stage, [])
                                medians.setdefault(name, {}).setdefault(key, {}).setdefault(
                                    stage, []).append(1e3 * C.median(v) if v else math.nan)
                        if k == 0:
                            differ[name] = _pixels_differing(base, work, name, root)
                        bar.step(f"round {k + 1}: {name}")
                finally:
                    base.close()
                    work.close()
        finally:
            bar.close()
    rows, csv_rows = [], []
    for name in scenes:
        m = medians[name]
        cells = {f"{stage}_{key}": C.median(m[key][stage]) for key in "ab" for stage in stages}
        # The ratio is taken within each round (the pair ran side by side, through the same
        # spells of a busy machine), then the median over the rounds.
        for stage in ("plan", "camera", "readback", "wall"):
            cells[f"{stage}_ratio"] = C.median([b / a for a, b in zip(m["a"][stage], m["b"][stage],
                                                                      strict=True)])
        rows.append([name, *(C.fmt(cells[f"{st}_{v}"], 3) for st in stages for v in "ab"),
                     *(C.fmt(cells[f"{st}_ratio"], 3)
                       for st in ("plan", "camera", "readback", "wall")),
                     str(differ[name])])
        csv_rows.append({"scene": name, **{k: round(v, 4) for k, v in cells.items()},
                         "pixels_differing": differ[name]})
    machine = f"{info.get('platform')}, {info.get('renderer')}, GL {info.get('version')}"
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    b = b_label
    headers = ["scene", f"plan ms, {commit}", f"plan ms, {b}", f"camera ms, {commit}",
               f"camera ms, {b}", f"light ms, {commit}", f"light ms, {b}",
               f"readback ms, {commit}", f"readback ms, {b}", f"wall ms, {commit}",
               f"wall ms, {b}", f"plan, {b} / {commit}", f"camera, {b} / {commit}",
               f"readback, {b} / {commit}", f"wall, {b} / {commit}", "pixels differing"]

    def geomean(key: str) -> float:
        vals = [r[key] for r in csv_rows if r[key] > 0]
        return math.exp(sum(map(math.log, vals)) / len(vals)) if vals else math.nan

    summary = (f"- Camera pass, {b} over {commit}: geometric mean {geomean('camera_ratio'):.3f}"
               f"; wall time {geomean('wall_ratio'):.3f}; plan stage {geomean('plan_ratio'):.3f}"
               f"; over {len(csv_rows)} scenes; pixels differing in "
               f"{sum(r['pixels_differing'] != 0 for r in csv_rows)} of them.")
    md = "\n".join([
        f"# The same renders by {commit} and by "
        + (f"{b}" if against is not None else f"the working tree ({here})"), "",
        f"640x480, default settings{', with ' + json.dumps(extra) if extra else ''}; each version "
        f"in a process of its own, one render each in turn (the order swapped every repeat), "
        f"{repeats} repeats after 3 warm-ups; the median of each of {rounds} rounds, each with "
        f"a fresh pair of processes, and the median of those; each ratio is taken within each "
        f"round, then their median. Stages: the renderer's own timings "
        f"(`RenderResult.timings`); "
        + ("each render from a camera no render used before (the scene's own turned about "
           "the vertical through the scene's centre by a further third of a degree, the same "
           "camera for both versions), so each plans anew and fits its light anew, as a batch's "
           "views and a moving client's requests do. " if new_camera else
           "the light pass is drawn once and cached, as a repeated request's is. ")
        + "Pixels differing: of the colour output (the scene's own camera), any channel."
        + (" Both processes keep freed memory for their next renders (glibc's trim and mmap "
           "thresholds, as `keep_freed_memory()` sets them in the service's and the batch's "
           "workers)." if keep_freed else ""), "",
        C.markdown_table(headers, rows), "", summary, "",
        f"Machine: {machine}; {os.cpu_count()} CPU cores (load average {load} at the end); "
        f"Python {sys.version.split()[0]}. Run time {time.perf_counter() - t_start:.0f} s.", ""])
    out_dir = C.results_dir()
    stem = (f"ab_commits_{commit}" + (f"_{b}" if against is not None else "")
            + ("_new_camera" if new_camera else ""))
    (out_dir / f"{stem}.md").write_text(md)
    C.write_csv(out_dir / f"{stem}.csv", csv_rows)
    print(md)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rev", help="the commit to compare the working tree against")
    ap.add_argument("--against", default=None,
                    help="another commit to compare with REV instead of the working tree")
    ap.add_argument("--scenes", default=",".join(
        [n.rsplit(".", 1)[0] for n in C.MODEL_NAMES] + list(C.STRESS_SCENES)),
        help="comma-separated: model names without extension, stress scene names, boxes_10k")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=9, help="fresh process pairs, one after another")
    ap.add_argument("--params", default="{}", help="RenderParams fields added to each scene's")
    ap.add_argument("--keep-freed", action="store_true",
                    help="both processes keep freed memory, as the service's and the batch's "
                    "render workers do (shadowmap.renderer.allocator)")
    ap.add_argument("--new-camera", action="store_true",
                    help="each render from a camera no render used before: the plan and the "
                    "light fit made anew every time, as for a batch's views")
    args = ap.parse_args()
    run(args.rev, [s for s in args.scenes.split(",") if s], args.repeats, args.rounds,
        json.loads(args.params), args.keep_freed, args.against, args.new_camera)


if __name__ == "__main__":
    main()
