"""Float outputs as OpenEXR (``float_format: "exr"``): read back with OpenEXR, they are the
renderer's arrays, bit for bit, from the library, the CLI and over HTTP; without the package
the CLI exits 2 and the service answers 422 ``unavailable_feature`` before rendering."""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys

import httpx
import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from shadowmap.renderer import (  # noqa: E402
    FileFormatError,
    LimitError,
    RenderParams,
    load_scene,
    read_exr,
    write_exr,
)
from shadowmap.renderer.demo import demo_glb  # noqa: E402
from shadowmap.renderer.exr import exr_bytes  # noqa: E402

TWO_LIGHTS = {
    "width": 96, "height": 72,
    "camera": {"eye": [3.5, 3.0, 5.0], "target": [0.0, 0.4, 0.0]},
    "lights": [{"type": "directional", "direction": [-0.6, -1.0, 0.25]},
               {"type": "spot", "position": [2, 4, 2], "target": [0, 0, 0]}],
    "outputs": ["color", "visibility", "depth"],
}


def equal(a: np.ndarray, b: np.ndarray) -> bool:
    """Same shape, dtype and bits (NaN where the other has NaN)."""
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def test_bytes_round_trip_keeps_nan_inf_and_attributes(tmp_path):
    rng = np.random.default_rng(0)
    z = rng.normal(size=(7, 5)).astype(np.float32) * 1e6
    z[0, 0], z[1, 1], z[2, 2] = np.nan, np.inf, -np.inf
    channels, header = read_exr(exr_bytes({"Z": z}, {"near": 0.25, "light": 3}))
    assert list(channels) == ["Z"] and equal(channels["Z"], z)
    assert header["near"] == 0.25 and header["light"] == 3
    write_exr(tmp_path / "z.exr", {"Z": z})
    assert equal(read_exr(tmp_path / "z.exr")[0]["Z"], z)
    with pytest.raises(ValueError):
        exr_bytes({"A": z, "B": z[:3]})
    with pytest.raises(ValueError):
        exr_bytes({})


@pytest.mark.gl
def _with_data_window(data: bytes, x1: int, y1: int) -> bytes:
    """``data`` (an EXR) with its header's data window's upper corner set to (x1, y1)."""
    key = b"dataWindow\x00box2i\x00"
    at = data.index(key) + len(key) + 4  # after the attribute's size
    return data[:at] + np.array([0, 0, x1, y1], "<i4").tobytes() + data[at + 16:]


def test_read_exr_refuses_a_data_window_over_max_pixels_before_reading_pixels():
    good = exr_bytes({"Z": np.ones((3, 4), np.float32)})
    hostile = _with_data_window(good, 59_999, 59_999)  # 13 GiB of float32 asked for
    with pytest.raises(LimitError, match="60000x60000 pixels, over the limit") as info:
        read_exr(hostile)
    assert info.value.limit == "max_pixels"
    with pytest.raises(LimitError):
        read_exr(good, max_pixels=11)
    channels, _ = read_exr(bytearray(good), max_pixels=12)
    assert channels["Z"].shape == (3, 4)


@pytest.mark.parametrize("source", [
    b"", b"garbage", "truncated", "cut short", "/nonexistent/depth.exr", "folder",
    "nul\x00.exr", 3, None, "/dev/zero",
])
def test_read_exr_of_anything_else_is_a_file_format_error(source, tmp_path):
    good = exr_bytes({"Z": np.ones((3, 4), np.float32)})
    source = {"truncated": good[:40], "cut short": good[:-10],
              "folder": tmp_path}.get(source, source)  # type: ignore[arg-type]
    with pytest.raises(FileFormatError) as info:
        read_exr(source)  # type: ignore[arg-type]
    assert info.value.code == "invalid_file"
    assert "\x00" not in str(info.value)


def test_encoded_outputs_equal_the_result_arrays(renderer):
    from shadowmap.app.encode import MEDIA_EXR, encode_outputs

    result = renderer.render(load_scene(demo_glb()), RenderParams.model_validate(TWO_LIGHTS))
    assert np.isnan(result.depth).any() and np.isfinite(result.depth).any()  # sky and scene
    images = {im.name: im for im in encode_outputs(result, TWO_LIGHTS["outputs"], "exr")}
    assert set(images) == {"color", "visibility_0", "visibility_1", "depth"}
    assert images["color"].media_type == "image/png"
    depth = images["depth"]
    assert depth.media_type == MEDIA_EXR and depth.bit_depth == 32 and depth.suffix == ".exr"
    assert equal(read_exr(depth.data)[0]["Z"], result.depth)
    for i in range(2):
        channels, header = read_exr(images[f"visibility_{i}"].data)
        assert equal(channels["Y"], result.visibility[..., i]) and header["light"] == i
    # Both lights shadow something, and each file is its own light's.
    v = result.visibility
    assert not np.array_equal(v[..., 0], v[..., 1], equal_nan=True)
    # The default stays 16-bit PNG.
    png = {im.name: im for im in encode_outputs(result, TWO_LIGHTS["outputs"])}
    assert png["depth"].media_type == "image/png" and png["depth"].bit_depth == 16


def _shadowmap(*args, cwd, env=None):
    return subprocess.run([sys.executable, "-m", "shadowmap", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300, env=env)


@pytest.mark.gl
def test_cli_writes_exr_beside_the_npy(tmp_path):
    scene = tmp_path / "demo.glb"
    scene.write_bytes(demo_glb())
    params = tmp_path / "p.json"
    params.write_text(json.dumps(TWO_LIGHTS))
    proc = _shadowmap("render", str(scene), "--params", str(params), "--float-format", "exr",
                      "--out", "out", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "out"
    assert equal(read_exr(out / "depth.exr")[0]["Z"], np.load(out / "depth.npy"))
    vis = np.load(out / "visibility.npy")
    for i in range(2):
        assert equal(read_exr(out / f"visibility_{i}.exr")[0]["Y"], vis[..., i])
    # float_format in the params file does the same; without it, no EXR.
    params.write_text(json.dumps({**TWO_LIGHTS, "float_format": "exr"}))
    proc = _shadowmap("render", str(scene), "--params", str(params), "--out", "b", cwd=tmp_path)
    assert proc.returncode == 0 and (tmp_path / "b" / "visibility_1.exr").is_file()
    proc = _shadowmap("render", str(scene), "--out", "c", cwd=tmp_path)
    assert proc.returncode == 0 and not list((tmp_path / "c").glob("*.exr"))


@pytest.fixture
def no_openexr_env(tmp_path):
    """An environment in which ``import OpenEXR`` fails, as where the package is missing."""
    shadow = tmp_path / "shadow"
    (shadow / "OpenEXR").mkdir(parents=True)
    (shadow / "OpenEXR" / "__init__.py").write_text("raise ImportError('no OpenEXR here')\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(shadow), *filter(None, [env.get("PYTHONPATH")])])
    return env


def test_cli_without_openexr_exits_2_before_rendering(tmp_path, no_openexr_env):
    proc = _shadowmap("render", "missing-but-not-read.glb", "--float-format", "exr",
                      cwd=tmp_path, env=no_openexr_env)
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("shadowmap: error: ") and "OpenEXR" in line


@pytest.mark.gl
def test_http_without_openexr_is_422_before_rendering(no_openexr_env):
    from test_page import uvicorn_server

    with uvicorn_server(env=no_openexr_env) as url:
        params = {"width": 32, "height": 24, "outputs": ["depth"], "float_format": "exr"}
        resp = httpx.post(url + "/render", json=params, headers={"Accept": "application/json"},
                          timeout=60)
        assert resp.status_code == 422, resp.text
        body = resp.json()
        assert body["error"] == "unavailable_feature" and body["field"] == "/float_format"
        assert "OpenEXR" in body["detail"]
        # Refused before the render: no render stage in the timing.
        assert "light;" not in resp.headers.get("server-timing", "")
        # PNG output is unaffected.
        params["float_format"] = "png16"
        resp = httpx.post(url + "/render", json=params, headers={"Accept": "application/json"},
                          timeout=60)
        assert resp.status_code == 200
        assert base64.b64decode(resp.json()["outputs"]["depth"]["png"])[:4] == b"\x89PNG"
