"""The ``shadowmap render`` command, run as a user would."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image


def shadowmap(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "shadowmap", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


@pytest.mark.gl
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


@pytest.mark.gl
def test_warnings_go_to_stderr_and_the_report_and_still_exit_0(models, tmp_path):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({
        # Over the CLI renderer's default limit of 8192, and a camera pose with scale.
        "shadows": {"max_map_size": 16384},
        "camera": {"pose": [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 600], [0, 0, 0, 1]]},
    }))
    out = tmp_path / "out"
    proc = shadowmap("render", str(models / "Duck.glb"), "--params", str(params),
                     "--width", "96", "--height", "64", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("shadowmap: warning: ")]
    assert len(lines) >= 2, proc.stderr
    assert any("shadows.max_map_size 16384" in line for line in lines)
    assert any(line.startswith("shadowmap: warning: camera: the pose") for line in lines)
    report = json.loads((out / "report.json").read_text())
    assert [f"shadowmap: warning: {w}" for w in report["warnings"]] == lines
    assert "rendered Duck.glb" in proc.stdout


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
        # resolved against the scene, after the GL context exists
        pytest.param('{"lights": [{"direction": [0, 0, 0]}]}', ["{scene}", "--params", "{params}"],
                     "zero length", marks=pytest.mark.gl),
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


def test_version_and_module_entry_point():
    from shadowmap import __version__

    proc = shadowmap("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"shadowmap {__version__}"
    assert __version__ != "0+unknown"  # read from the installed distribution's metadata


def test_help_touches_no_gl_platform():
    """``--help`` and the library's pure modules import neither PyOpenGL nor pyrender, and
    leave PYOPENGL_PLATFORM alone: the platform is chosen when a Renderer is created."""
    code = (
        "import os, sys\n"
        "os.environ.pop('PYOPENGL_PLATFORM', None)\n"
        "import shadowmap, shadowmap.renderer.params, shadowmap.renderer.scene\n"
        "import shadowmap.renderer.plan, shadowmap.renderer.limits, shadowmap.cli\n"
        "shadowmap.cli.build_parser().format_help()\n"
        "loaded = sorted(m for m in ('OpenGL', 'pyrender') if m in sys.modules)\n"
        "assert not loaded, loaded\n"
        "assert 'PYOPENGL_PLATFORM' not in os.environ\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.gl
def test_a_render_imports_no_mesh_or_viewer_stack(models, tmp_path):
    """A command-line render of a glTF file loads pyrender's offscreen platform alone: not the
    pyrender package, trimesh, scipy or pyglet (about 1.2 s of start-up together), and a later
    ``import pyrender`` still gets the whole package."""
    duck = str(models / "Duck.glb")
    code = (
        "import sys\n"
        "from shadowmap.cli import main\n"
        f"main(['render', {duck!r}, '--out', {str(tmp_path)!r}])\n"
        "loaded = sorted(m for m in ('pyrender', 'trimesh', 'scipy', 'pyglet', 'networkx')\n"
        "                if m in sys.modules)\n"
        "assert not loaded, loaded\n"
        "import pyrender\n"
        "assert hasattr(pyrender, 'OffscreenRenderer')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "color.png").is_file()


def test_namespace_wins_over_a_users_own_app_package(tmp_path):
    """A user's own ``app`` and ``renderer`` packages in the working directory do not shadow
    ours: everything is installed under ``shadowmap``."""
    for name in ("app", "renderer"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("raise ImportError('the user package')\n")
    code = ("import shadowmap.app.main, shadowmap.renderer.render, shadowmap.cli; "
            "print(shadowmap.app.main.__file__)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert str(tmp_path) not in proc.stdout
    assert shadowmap("--version", cwd=tmp_path).returncode == 0
