"""The ``shadowmap render`` command, run as a user would."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

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
        ('{"shadows": {"fit": "scene", "fit": "view"}}', ["{scene}", "--params", "{params}"],
         "the key 'fit' is given twice in one object (at shadows)"),
        (b"\xff\xfe{}", ["{scene}", "--params", "{params}"], "can't decode byte 0xff"),
        # Read up to one byte past the limit: /dev/zero used to be read until memory ran out.
        (None, ["{scene}", "--params", "/dev/zero"], "/dev/zero is over 65536 bytes"),
        (None, ["{bad}"], "glTF"),
    ],
)
def test_bad_input_exits_nonzero_with_one_line(models, tmp_path, setup, args, message):
    params = tmp_path / "p.json"
    if isinstance(setup, bytes):
        params.write_bytes(setup)
    elif setup is not None:
        params.write_text(setup)
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF garbage")
    args = [a.format(scene=models / "Duck.glb", params=params, bad=bad) for a in args]
    proc = shadowmap("render", *args, "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


def test_help_example_json_is_compact_and_is_the_example():
    from shadowmap.renderer.params import EXAMPLE_PARAMS

    proc = shadowmap("render", "--help")
    assert proc.returncode == 0
    text = proc.stdout.split("for example:", 1)[1].lstrip("\n")
    example = text[:text.index("\n}\n") + 2]
    assert json.loads(example) == EXAMPLE_PARAMS
    lines = example.splitlines()
    # One field per line at most, never one number per line (json.dumps(indent=2) gave 50).
    assert len(lines) <= len(EXAMPLE_PARAMS) + 2, example
    assert not any(re.fullmatch(r"\s*-?[\d.]+,?", line) for line in lines), example
    assert max(len(line) for line in lines) <= 100


@pytest.mark.parametrize("width", [20, 40, 92])
def test_compact_json_round_trips(width):
    from shadowmap.cli import compact_json

    value = {"pose": [[1, 0, 0, 0.5], [0, 1, 0, -2.25], [0, 0, 1, 3], [0, 0, 0, 1]],
             "many": list(range(60)), "words": ["a" * 30] * 5, "empty": {}, "none": [],
             "nested": [{"k": [{"x": None, "y": True}]}], "text": "é \" \\ x"}
    text = compact_json(value, width=width)
    assert json.loads(text) == value
    # Numbers fill their lines: a lone one only as the last of a long list.
    lone = [line for line in text.splitlines() if re.fullmatch(r"\s*-?[\d.]+,?", line)]
    assert len(lone) <= 1 and not any(line.endswith(",") for line in lone), text


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


# --- the one-liner flags ---------------------------------------------------------------------

ONE_LINER = ["--size", "800x600", "--light-dir", "-1,-2,-1", "--ground",
             "--camera-orbit", "30deg,60deg,2m"]


@pytest.mark.gl
def test_one_liner_writes_the_png_only(models, tmp_path):
    proc = shadowmap("render", str(models / "Duck.glb"), "-o", "duck.png", *ONE_LINER,
                     cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    image = Image.open(tmp_path / "duck.png")
    assert image.format == "PNG" and image.size == (800, 600)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["duck.png"]  # no ./out without --out


@pytest.mark.gl
def test_dash_output_writes_the_png_to_stdout_and_the_summary_to_stderr(models, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "shadowmap", "render", str(models / "Duck.glb"),
                           "-o", "-", "--size", "64x48"], capture_output=True, cwd=tmp_path,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    image = Image.open(io.BytesIO(proc.stdout))
    assert image.format == "PNG" and image.size == (64, 48)
    assert b"-> standard output" in proc.stderr
    assert list(tmp_path.iterdir()) == []  # no file named "-", no ./out


@pytest.mark.gl
def test_dash_output_to_a_reader_that_leaves_is_an_error(models, tmp_path):
    """A reader gone mid-PNG (| head -c 10) is exit 1, not a silent success with half a file."""
    reader = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.buffer.read(10)"],
                              stdin=subprocess.PIPE)
    proc = subprocess.run([sys.executable, "-m", "shadowmap", "render", str(models / "Duck.glb"),
                           "-o", "-", "--size", "3000x3000"], stdout=reader.stdin,
                          stderr=subprocess.PIPE, text=True, cwd=tmp_path, timeout=120)
    reader.stdin.close()
    reader.wait(30)
    assert proc.returncode == 1, proc.stderr
    assert "standard output closed" in proc.stderr


def test_dash_output_refuses_a_terminal(models, tmp_path):
    """Refused before the render: the PNG's bytes would garble the terminal."""
    import pty

    leader, follower = pty.openpty()
    try:
        proc = subprocess.run([sys.executable, "-m", "shadowmap", "render",
                               str(models / "Duck.glb"), "-o", "-"], stdout=follower,
                              stderr=subprocess.PIPE, text=True, cwd=tmp_path, timeout=120)
    finally:
        os.close(follower)
        os.close(leader)
    assert proc.returncode == 2
    assert "standard output, which is a terminal" in proc.stderr


def test_orbit_eye_follows_model_viewer():
    from shadowmap.cli import _orbit, orbit_eye

    theta, phi, r = _orbit("30deg,60deg,2m")
    eye = orbit_eye(np.zeros(3), theta, phi, r)
    s = np.sin(np.radians(60))
    np.testing.assert_allclose(eye, [2 * s * 0.5, 2 * 0.5, 2 * s * np.cos(np.radians(30))])
    # theta 0 is in front (+Z), 90deg on +X, phi 0 straight above; rad, cm and bare numbers
    np.testing.assert_allclose(orbit_eye(np.ones(3), *_orbit("0 1.5707963267948966rad 50cm")),
                               [1, 1, 1.5], atol=1e-12)
    np.testing.assert_allclose(orbit_eye(np.zeros(3), *_orbit("90deg,90deg,3")), [3, 0, 0],
                               atol=1e-12)
    assert _orbit("auto,auto,auto") == (0.0, pytest.approx(np.radians(75)), None)


@pytest.mark.gl
def test_camera_orbit_equals_the_explicit_eye_and_flags_override_params(models, tmp_path):
    """--camera-orbit around the bounds' centre renders the same image as the equivalent
    eye/target request, and every flag wins over the PARAMS file's field."""
    from shadowmap.cli import _orbit, orbit_eye
    from shadowmap.renderer import load_scene

    lo, hi = load_scene(models / "Duck.glb").bounds
    centre = (lo + hi) / 2
    eye = orbit_eye(centre, *_orbit("30deg,60deg,2m"))
    explicit = tmp_path / "explicit.json"
    explicit.write_text(json.dumps({
        "width": 800, "height": 600, "ground": True,
        "camera": {"eye": eye.tolist(), "target": centre.tolist()},
        "lights": [{"type": "directional", "direction": [-1, -2, -1]}],
    }))
    # Everything the flags set is different here; yfov_deg stays from the file.
    overridden = tmp_path / "overridden.json"
    overridden.write_text(json.dumps({
        "width": 64, "height": 48, "ground": False,
        "camera": {"pose": np.eye(4).tolist()},
        "lights": [{"type": "point", "position": [1, 3, 1]}, {"direction": [0, -1, 0]}],
    }))
    a, b = tmp_path / "a", tmp_path / "b"
    proc = shadowmap("render", str(models / "Duck.glb"), "--params", str(explicit),
                     "--out", str(a))
    assert proc.returncode == 0, proc.stderr
    proc = shadowmap("render", str(models / "Duck.glb"), "--params", str(overridden),
                     *ONE_LINER, "--out", str(b), "-o", str(tmp_path / "c.png"))
    assert proc.returncode == 0, proc.stderr
    first = np.asarray(Image.open(a / "color.png"))
    assert first.shape == (600, 800, 3)
    np.testing.assert_array_equal(first, np.asarray(Image.open(b / "color.png")))
    np.testing.assert_array_equal(first, np.asarray(Image.open(tmp_path / "c.png")))
    assert (b / "report.json").is_file()


@pytest.mark.gl
def test_params_from_a_fifo_as_a_shell_gives_them(models, tmp_path):
    """``--params <(...)``: the file is a pipe, read as it comes (with a byte order mark, as
    some editors write one)."""
    fifo = tmp_path / "params.json"
    os.mkfifo(fifo)
    proc = subprocess.Popen([sys.executable, "-m", "shadowmap", "render", str(models / "Duck.glb"),
                             "--params", str(fifo), "-o", str(tmp_path / "c.png")],
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    with open(fifo, "wb") as f:
        f.write(b'\xef\xbb\xbf{"width": 64, "height": 48}')
    assert proc.wait(120) == 0, proc.stderr.read() if proc.stderr else ""
    assert Image.open(tmp_path / "c.png").size == (64, 48)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--size", "800"], "--size must be WIDTHxHEIGHT"),
        (["--size", "0x600"], "at least 1"),
        (["--size", "800x600", "--width", "10"], "not both"),
        (["--camera-orbit", "30deg,60deg"], "takes 3"),
        (["--camera-orbit", "30deg,60grad,2m"], "polar angle"),
        (["--camera-orbit", "30deg,200deg,2m"], "between 0deg and 180deg"),
        (["--camera-orbit", "30deg,60deg,-2m"], "greater than 0"),
        (["--camera-orbit", "30deg,60deg,2km"], "radius"),
        (["--camera-target", "1,2"], "takes 3"),
        (["--light-dir", "-1,x,-1"], "not a number"),
        (["--light-dir", "0,0,0"], "zero vector"),
        (["--light-dir", "1,nan,0"], "finite"),
        (["-o", "x.png", "--outputs", "depth"], "color"),
        (["--outputs", ""], "names no output"),
        (["--outputs", " , "], "names no output"),
        (["-o", ""], "-o/--output is empty"),
        (["--out", " "], "--out is empty"),
    ],
)
def test_bad_flag_values_exit_2_with_one_line(models, tmp_path, args, message):
    proc = shadowmap("render", str(models / "Duck.glb"), *args, cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr
    assert lines[0].startswith("shadowmap: error: ")


@pytest.mark.parametrize("args", [["--out", "taken"], ["-o", "taken/x.png"],
                                  ["--out", "taken/sub"]])
def test_output_folders_that_cannot_be_made_fail_before_the_render(models, tmp_path, args):
    """A file where a folder must go is one line and exit 2, before any GL work (it used to be a
    traceback after the render)."""
    (tmp_path / "taken").write_text("a file")
    proc = shadowmap("render", str(models / "Duck.glb"), *args, cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("shadowmap: error: cannot write taken"), lines


def test_render_help_is_plain_text_with_the_one_liner():
    proc = shadowmap("render", "--help")
    assert proc.returncode == 0
    assert "shadowmap render Duck.glb -o duck.png --size 800x600" in proc.stdout
    assert "``" not in proc.stdout and ":mod:" not in proc.stdout
    top = shadowmap("--help")
    assert top.returncode == 0 and "``" not in top.stdout and ":mod:" not in top.stdout


# --- scripts/serve ---------------------------------------------------------------------------

ROOT = Path(__file__).resolve().parents[1]
# The container's test stage holds the tests and the installed package, not the scripts.
needs_scripts = pytest.mark.skipif(not (ROOT / "scripts" / "serve").is_file(),
                                   reason="no scripts/ beside the tests (the container)")


def _serve_dry_run(root, *args, **env):
    return subprocess.run(["bash", str(root / "scripts" / "serve"), *args], capture_output=True,
                          text=True, timeout=60,
                          env={**os.environ, "SHADOWMAP_DRY_RUN": "1", **env})


@needs_scripts
def test_serve_script_passes_host_port_workers_through():
    proc = _serve_dry_run(ROOT, "--port", "8080", "--host", "0.0.0.0", "--workers", "2",
                          SHADOWMAP_WORKERS="3")
    assert proc.returncode == 0, proc.stderr
    line = proc.stdout.strip()
    assert line.startswith("would run: ") and line.split()[2].endswith("/.venv/bin/shadowmap")
    # the environment's value first, so the command line's wins (argparse keeps the last)
    assert line.split()[3:] == ["serve", "--workers", "3", "--port", "8080", "--host", "0.0.0.0",
                                "--workers", "2"]


@needs_scripts
@pytest.mark.parametrize(
    "stamp_extras, env, installs",
    [
        ("server,test,bench", {}, None),           # serve: a test venv covers [server]
        ("server", {}, None),
        ("server", {"SHADOWMAP_EXTRAS": "server,test"}, "server,test"),
        ("test", {}, "server"),
        (None, {}, "server"),                      # no stamp yet
    ],
)
def test_serve_installs_the_server_extra_only(tmp_path, stamp_extras, env, installs):
    """A copy of the scripts beside a fake venv: the dry run says whether pip would run and
    with which extras; the stamp is kept when it records the extras asked for."""
    import shutil

    shutil.copytree(ROOT / "scripts", tmp_path / "scripts")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    (tmp_path / ".venv" / "bin" / "python").symlink_to(sys.executable)
    if stamp_extras is not None:
        digest = hashlib.sha256((tmp_path / "pyproject.toml").read_bytes()).hexdigest()
        (tmp_path / ".venv" / ".setup-stamp").write_text(f"{digest} [{stamp_extras}]\n")
    proc = _serve_dry_run(tmp_path, **env)
    assert proc.returncode == 0, proc.stderr
    if installs is None:
        assert "pip install" not in proc.stderr, proc.stderr
    else:
        assert f'would run pip install -e ".[{installs}]"' in proc.stderr, proc.stderr
    assert proc.stdout.strip().endswith("/.venv/bin/shadowmap serve")


@needs_scripts
@pytest.mark.slow
def test_serve_script_serves_on_the_given_port(tmp_path):
    import socket
    import time
    import urllib.request

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(["bash", str(ROOT / "scripts" / "serve"), "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while True:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2) as r:
                    assert r.status == 200
                    break
            except OSError:
                assert time.monotonic() < deadline, "the service did not start"
                time.sleep(0.5)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
