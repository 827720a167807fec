"""The ``shadowmap render`` command, run as a user would."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.gl


def shadowmap(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "shadowmap", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


def test_render_writes_every_output(models, tmp_path):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({
        "outputs": ["color", "light_depth", "visibility", "depth"], "ground": True,
        "lights": [{"direction": [-0.5, -1, 0.2]}, {"type": "point", "position": [1, 3, 1]}],
    }))
    out = tmp_path / "out"
    proc = shadowmap("render", str(models / "TestScene.gltf"), "--params", str(params),
                     "--width", "320", "--height", "240", "--out", str(out), "--reference")
    assert proc.returncode == 0, proc.stderr
    assert Image.open(out / "color.png").size == (320, 240)
    assert Image.open(out / "light_depth_0.png").mode == "L"
    assert (out / "light_depth_1.png").is_file()
    vis = np.load(out / "visibility.npy")
    assert vis.shape == (240, 320, 2) and vis.dtype == np.float32
    report = json.loads((out / "report.json").read_text())
    assert set(report) >= {"timings", "plan", "gl", "metrics"}
    assert report["metrics"][0]["iou"] >= 0.95
    assert "IoU" in proc.stdout


def test_help_documents_the_json(models):
    proc = shadowmap("render", "--help")
    assert proc.returncode == 0
    assert '"shadows"' in proc.stdout and "light_depth" in proc.stdout


@pytest.mark.parametrize(
    "setup, args, message",
    [
        (None, ["missing.glb"], "cannot read"),
        ("not json", ["{scene}", "--params", "{params}"], "not valid JSON"),
        ('{"width": 0}', ["{scene}", "--params", "{params}"], "width"),
        ('{"lights": [{"direction": [0, 0, 0]}]}', ["{scene}", "--params", "{params}"], "zero length"),
        ('{"width": NaN}', ["{scene}", "--params", "{params}"], "NaN"),
        (None, ["{bad}"], "glTF"),
    ],
)
def test_bad_input_exits_nonzero_with_one_line(models, tmp_path, setup, args, message):
    params = tmp_path / "p.json"
    if setup is not None:
        params.write_text(setup)
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF garbage")
    args = [a.format(scene=models / "Duck.glb", params=params, bad=bad) for a in args]
    proc = shadowmap("render", *args, "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr
