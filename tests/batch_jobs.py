"""The 200-job manifest of the batch tests and benchmark, and checks of a batch's outputs."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

SIZE = {"width": 96, "height": 72}
#: Real models of the manifest (tests/conftest.py's models folder), each with a ground plane.
MODELS = ("Duck.glb", "BoxTextured.glb", "CesiumMilkTruck.glb", "TestScene.gltf")
#: The bad jobs and the error each must be recorded with.
BAD = {
    "bad-missing-file": "invalid_scene",
    "bad-truncated-glb": "invalid_scene",
    "bad-width": "invalid_params",
    "bad-unknown-field": "invalid_params",
    "bad-over-max-pixels": "limit_exceeded",
    "bad-zero-direction": "invalid_params",
}


def light(k: int) -> dict[str, Any]:
    a = 2 * math.pi * k / 7
    return {"type": "directional", "direction": [math.cos(a), -1.5, math.sin(a)]}


def manifest_entries(models: Path, folder: Path, count: int = 200) -> list[dict[str, Any]]:
    """``count`` jobs: the demo scene and the real models, several outputs, some with views and
    light variations, and the :data:`BAD` ones spread among them."""
    (folder / "truncated.glb").write_bytes((models / "Duck.glb").read_bytes()[:4000])
    bad = [
        {"id": "bad-missing-file", "scene": "no-such-file.glb", "params": SIZE},
        {"id": "bad-truncated-glb", "scene": "truncated.glb", "params": SIZE},
        {"id": "bad-width", "scene": {"builtin": "demo"}, "params": {"width": 0}},
        {"id": "bad-unknown-field", "scene": {"builtin": "demo"}, "params": {"widht": 5}},
        {"id": "bad-over-max-pixels", "scene": {"builtin": "demo"},
         "params": {"width": 5000, "height": 4000}},
        {"id": "bad-zero-direction", "scene": {"builtin": "demo"},
         "params": {**SIZE, "lights": [{"direction": [0, 0, 0]}]}},
    ]
    outputs = (["color"], ["color", "visibility"], ["color", "depth", "light_depth"],
               ["visibility", "depth"])
    good: list[dict[str, Any]] = []
    k = 0
    while len(good) + len(bad) < count:
        scene: Any = {"builtin": "demo"} if k % 3 == 0 else str(models / MODELS[k % len(MODELS)])
        params: dict[str, Any] = {**SIZE, "outputs": outputs[k % len(outputs)],
                                  "lights": [light(k)]}
        # Every model on a ground plane; every other demo job asks for one too, which its own
        # floor keeps out (a warning, and an automatic framing without it).
        if k % 3 or k % 6 == 3:
            params["ground"] = True
        job: dict[str, Any] = {"id": f"job-{k:03d}", "scene": scene, "params": params}
        if k % 10 == 4:  # views of one scene, one light fit for all of them
            job["params"] = {**params, "shadows": {"fit": "scene"}}
            job["views"] = [{"eye": [3 * math.cos(a), 2.0, 3 * math.sin(a)], "target": [0, 0.3, 0]}
                            for a in (0.3, 1.9, 3.5)]
            if k % 20 == 14:  # the last one orthographic
                job["views"][-1].update(projection="orthographic", ymag=1.5)
        if k % 10 == 7:
            job["lights"] = [[light(k)], [light(k + 3)]]
        good.append(job)
        k += 1
    out = list(good)
    for i, b in enumerate(bad):  # spread through the batch
        out.insert(5 + i * (len(out) // len(bad)), b)
    return out


def write_manifest(path: Path, entries: list[dict[str, Any]], extra_lines: tuple[str, ...] = ()
                   ) -> Path:
    lines = [json.dumps(e) for e in entries] + list(extra_lines)
    path.write_text("\n".join(lines) + "\n")
    return path


def single_render(renderer: Any, entry: dict[str, Any], variation: dict[str, Any]) -> Any:
    """The same render on its own: a fresh load of the scene, one render call."""
    from shadowmap.renderer.demo import demo_glb
    from shadowmap.renderer.scene import load_scene

    scene_spec = entry["scene"]
    if isinstance(scene_spec, dict):
        scene = load_scene(demo_glb(), file_type="glb")
    else:
        path = Path(scene_spec)
        resources = None
        if path.suffix == ".gltf":
            doc = json.loads(path.read_text())
            resources = {b["uri"]: (path.parent / b["uri"]).read_bytes()
                         for b in doc.get("buffers", []) if "uri" in b}
        scene = load_scene(path, resources=resources)
    return renderer.render(scene, variation)


def variations(entry: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    out = []
    views = entry.get("views") or [None]
    lights = entry.get("lights") or [None]
    for i, v in enumerate(views):
        for j, lt in enumerate(lights):
            params = dict(entry["params"])
            parts = []
            if v is not None:
                params["camera"] = v
                parts.append(f"view_{i:03d}")
            if lt is not None:
                params["lights"] = lt
                parts.append(f"light_{j:03d}")
            out.append(("_".join(parts), params))
    return out


def assert_same_as_single(renderer: Any, out: Path, entry: dict[str, Any]) -> None:
    """Every output file of a batch job equals the same render done on its own."""
    from PIL import Image

    for name, params in variations(entry):
        folder = out / entry["id"] / name if name else out / entry["id"]
        result = single_render(renderer, entry, params)
        meta = json.loads((folder / "meta.json").read_text())
        assert meta["camera"]["width"] == params["width"]
        if result.color is not None:
            img = np.asarray(Image.open(io.BytesIO((folder / "color.png").read_bytes())))
            assert np.array_equal(img, result.color), (entry["id"], name)
        if result.visibility is not None:
            vis = np.load(folder / "visibility.npy")
            assert np.array_equal(vis, result.visibility[..., 0], equal_nan=True)
            png = np.asarray(Image.open(folder / "visibility_0.png")).astype(np.int64)
            # round(v * 65535) of the float32 factor, computed exactly (in float64).
            want = np.rint(np.nan_to_num(result.visibility[..., 0].astype(np.float64)) * 65535)
            assert np.array_equal(png, want.astype(np.int64))
        if result.depth is not None:
            assert np.array_equal(np.load(folder / "depth.npy"), result.depth, equal_nan=True)
            assert (folder / "depth.png").is_file()
        for ld in result.light_depth:
            assert np.array_equal(np.load(folder / f"light_depth_{ld.light}.npy"), ld.depth,
                                  equal_nan=True)


def latest_records(out: Path) -> dict[str, dict[str, Any]]:
    recs: dict[str, dict[str, Any]] = {}
    for line in (out / "results.jsonl").read_text().splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        recs[rec["id"]] = rec
    return recs


def check_batch(out: Path, entries: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Every good job ok with its files, every bad one an error with its code."""
    recs = latest_records(out)
    assert set(recs) == {e["id"] for e in entries}
    for e in entries:
        rec = recs[e["id"]]
        if e["id"] in BAD:
            assert rec["status"] == "error", rec
            assert rec["error"]["error"] == BAD[e["id"]], rec
            assert rec["error"]["detail"]
            assert not (out / e["id"]).exists()
        else:
            assert rec["status"] == "ok", rec
            for name in rec["outputs"]:
                assert (out / e["id"] / name).is_file()
    assert recs["bad-over-max-pixels"]["error"]["limit"] == "max_pixels"
    return recs
