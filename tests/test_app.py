"""The HTTP service end to end: a real uvicorn server in a subprocess, driven with httpx.

Two servers run for the module, both with small limits set through ``SHADOWMAP_*``:

- ``server``: the main one (queue of 32), for good renders, bad input and concurrency;
- ``tiny``: queue of 1 and a 1 s render time limit, started through
  :func:`shadowmap.app.main.run`, for the queue-full (503 + Retry-After) and time-limit (504)
  behaviour.
"""

from __future__ import annotations

import base64
import io
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.gl

REPO = Path(__file__).resolve().parents[1]
MODELS = Path(os.environ.get("SHADOWMAP_MODELS", REPO.parent / "shared" / "models"))

MAX_UPLOAD = 4 * 2**20
MAIN_ENV = {
    "SHADOWMAP_MAX_UPLOAD_BYTES": str(MAX_UPLOAD),
    "SHADOWMAP_ZIP_EXPANSION": "4",
    "SHADOWMAP_MAX_PIXELS": str(1024 * 1024),
    "SHADOWMAP_MAX_MAP_SIZE": "2048",
    "SHADOWMAP_MAX_TRIANGLES": "20000",
    "SHADOWMAP_MAX_LIGHTS": "4",
    "SHADOWMAP_QUEUE_SIZE": "32",
    "SHADOWMAP_RENDER_TIMEOUT": "60",
    "SHADOWMAP_SCENE_CACHE_ENTRIES": "4",
}
TINY_ENV = {
    "SHADOWMAP_MAX_PIXELS": str(2048 * 2048),
    "SHADOWMAP_QUEUE_SIZE": "1",
    "SHADOWMAP_RENDER_TIMEOUT": "1.0",
}
SMALL = {"width": 160, "height": 120}
# Seconds of GL work on llvmpipe (several on 2 cores, plus PNG encoding): 2048^2 pixels lit by
# four point lights with 2048^2 cube maps, every face rendered, 9x9 PCF, colour and visibility
# read back (light_depth would read back 6 x 2048^2 depths per light, over max_request_bytes).
SLOW = {"width": 2048, "height": 2048, "outputs": ["color", "visibility"],
        "lights": [{"type": "point", "position": [-2.0 + 1.3 * i, 2.5, 1.0]} for i in range(4)],
        "shadows": {"map_size": 2048, "pcf_kernel": 9}, "optimize": False}


# ------------------------------------------------------------------------------------------------
# Server processes
# ------------------------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """A service process on a free localhost port; its output goes to a log file."""

    def __init__(self, env: dict[str, str], via_run: bool = False) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tempfile.NamedTemporaryFile(prefix="shadowmap-app-", suffix=".log", delete=False)
        full_env = dict(os.environ)
        full_env.update(env)
        if via_run:
            cmd = [sys.executable, "-c",
                   "from shadowmap.app.main import run; "
                   f"run('127.0.0.1', {self.port}, 1, 'warning')"]
        else:
            cmd = [sys.executable, "-m", "uvicorn", "--factory", "shadowmap.app.main:create_app",
                   "--host", "127.0.0.1", "--port", str(self.port), "--log-level", "warning"]
        self.proc = subprocess.Popen(cmd, env=full_env, stdout=self.log, stderr=subprocess.STDOUT,
                                     cwd=tempfile.gettempdir())

    def wait_ready(self, timeout: float = 90.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log_text()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"server not ready after {timeout} s:\n{self.log_text()}")

    def log_text(self) -> str:
        return Path(self.log.name).read_text(errors="replace")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self.log.close()
        os.unlink(self.log.name)


@pytest.fixture(scope="module")
def servers():
    main, tiny = ServerProcess(MAIN_ENV), ServerProcess(TINY_ENV, via_run=True)
    try:
        main.wait_ready()
        tiny.wait_ready()
        yield main, tiny
        # No request of this module may have crashed a handler.
        for s in (main, tiny):
            assert "Traceback" not in s.log_text(), s.log_text()
    finally:
        main.stop()
        tiny.stop()


@pytest.fixture(scope="module")
def server(servers) -> ServerProcess:
    return servers[0]


@pytest.fixture(scope="module")
def tiny(servers) -> ServerProcess:
    return servers[1]


@pytest.fixture(scope="module")
def client(server):
    with httpx.Client(base_url=server.url, timeout=60) as c:
        yield c


# ------------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------------


def models_dir() -> Path:
    if not MODELS.is_dir():
        pytest.skip(f"no models folder at {MODELS} (set SHADOWMAP_MODELS)")
    return MODELS


def decode_png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return np.array(Image.open(io.BytesIO(data)))


def post_scene(client: httpx.Client, name: str, data: bytes, params: dict | str | None = None,
               accept: str = "image/png") -> httpx.Response:
    files = {"scene": (name, data, "application/octet-stream")}
    form = {}
    if params is not None:
        form["params"] = params if isinstance(params, str) else json.dumps(params)
    return client.post("/render", files=files, data=form, headers={"Accept": accept})


def post_params(client: httpx.Client, params: dict | str,
                accept: str = "image/png") -> httpx.Response:
    body = params if isinstance(params, str) else json.dumps(params)
    return client.post("/render", content=body,
                       headers={"Content-Type": "application/json", "Accept": accept})


def assert_error(resp: httpx.Response, status: int, error: str | None = None,
                 limit: str | None = None) -> dict:
    assert resp.status_code == status, resp.text[:500]
    assert resp.headers["content-type"].startswith("application/json")
    body = resp.json()
    assert isinstance(body["error"], str) and isinstance(body["detail"], str), body
    if error is not None:
        assert body["error"] == error, body
    if limit is not None:
        assert body["limit"] == limit, body
    return body


def assert_picture(resp: httpx.Response, width: int, height: int) -> np.ndarray:
    """A 200 PNG of the given size that shows something (not one flat colour)."""
    assert resp.status_code == 200, resp.text[:500]
    assert resp.headers["content-type"] == "image/png"
    img = decode_png(resp.content)
    assert img.shape[:2] == (height, width)
    assert img.reshape(-1, img.shape[-1]).std(axis=0).max() > 5.0
    return img


def server_timing(resp: httpx.Response) -> dict[str, float]:
    """Stage name -> milliseconds from the ``Server-Timing`` header."""
    out = {}
    for item in resp.headers["server-timing"].split(","):
        name, *fields = [f.strip() for f in item.split(";")]
        durations = [float(f[4:]) for f in fields if f.startswith("dur=")]
        out[name] = durations[0] if durations else float("nan")
    return out


def gltf_with_buffer_uri(uri: str) -> bytes:
    """TestScene.gltf with its buffer pointing at ``uri``."""
    doc = json.loads((models_dir() / "TestScene.gltf").read_text())
    doc["buffers"][0]["uri"] = uri
    return json.dumps(doc).encode()


def zip_bytes(entries: dict[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in entries.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=compression)
    return buf.getvalue()


def understate_zip_sizes(data: bytes, entry: str, size: int) -> bytes:
    """Rewrite the declared uncompressed size of ``entry`` (local and central headers)."""
    out = bytearray(data)
    name = entry.encode()
    pos = 0
    while (pos := out.find(b"PK\x03\x04", pos)) >= 0:
        n = int.from_bytes(out[pos + 26:pos + 28], "little")
        if out[pos + 30:pos + 30 + n] == name:
            out[pos + 22:pos + 26] = size.to_bytes(4, "little")
        pos += 4
    pos = 0
    while (pos := out.find(b"PK\x01\x02", pos)) >= 0:
        n = int.from_bytes(out[pos + 28:pos + 30], "little")
        if out[pos + 46:pos + 46 + n] == name:
            out[pos + 24:pos + 28] = size.to_bytes(4, "little")
        pos += 4
    return bytes(out)


def trimesh_glb(mesh) -> bytes:
    return mesh.scene().export(file_type="glb")


def embedded_gltf() -> bytes:
    """A .gltf whose buffers are data: URIs, from a trimesh export (a box on a slab)."""
    import trimesh

    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(4, 0.1, 4)), node_name="slab")
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="box",
                       transform=trimesh.transformations.translation_matrix((0, 0.6, 0)))
    files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)
    assert len(files) == 1
    data = next(iter(files.values()))
    assert b"data:application/octet-stream;base64," in data
    return data


# ------------------------------------------------------------------------------------------------
# Service basics
# ------------------------------------------------------------------------------------------------


def test_health_version_and_docs(client):
    h = client.get("/healthz")
    assert h.status_code == 200
    body = h.json()
    assert body["status"] == "ok" and body["worker"]["alive"]
    assert body["gl"]["platform"] in ("egl", "osmesa") and body["gl"]["renderer"]
    v = client.get("/version").json()
    assert v["name"] == "shadowmap-service" and v["version"]
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()
    render = spec["paths"]["/render"]["post"]
    assert set(render["responses"]["200"]["content"]) == {"image/png", "multipart/mixed",
                                                          "application/json"}
    assert "multipart/form-data" in render["requestBody"]["content"]
    assert "model/gltf-binary" in render["requestBody"]["content"]
    assert "RenderParams" in spec["components"]["schemas"]
    assert "RenderJSON" in spec["components"]["schemas"]


def test_page_and_demo_scene(client):
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'id="status"' in page.text and "http://" not in page.text and "https://" not in page.text
    demo = client.get("/demo.glb")
    assert demo.status_code == 200 and demo.content[:4] == b"glTF"
    assert demo.headers["content-type"] == "model/gltf-binary"


def test_unknown_route_is_json(client):
    assert_error(client.get("/nope"), 404, "not_found")
    assert_error(client.get("/render"), 405, "method_not_allowed")


# ------------------------------------------------------------------------------------------------
# Good renders
# ------------------------------------------------------------------------------------------------


def test_demo_without_anything(client):
    """``curl -X POST /render -o out.png``: no body at all renders the demo scene."""
    resp = client.post("/render")
    img = assert_picture(resp, 640, 480)
    assert img.shape[2] == 3
    timing = server_timing(resp)
    for stage in ("read", "queue", "parse", "upload", "light", "camera", "readback", "encode",
                  "pipe", "hop", "total"):
        assert stage in timing and timing[stage] >= 0, timing
    # The stages follow one another: together they fit in the total (each rounded to 0.01 ms).
    assert sum(v for k, v in timing.items() if k != "total") <= timing["total"] + 0.01 * len(
        timing), timing
    assert list(timing)[-3:] == ["pipe", "hop", "total"]
    plan = json.loads(resp.headers["x-render-plan"])
    assert plan["light_passes"] == 1 and plan["outputs"] == ["color"]


@pytest.mark.parametrize("name", ["AlphaBlendModeTest.glb", "BoxTextured.glb",
                                  "CesiumMilkTruck.glb", "Duck.glb", "cube.glb"])
def test_render_model_glb(client, name):
    data = (models_dir() / name).read_bytes()
    resp = post_scene(client, name, data, {**SMALL, "ground": True})
    assert_picture(resp, 160, 120)
    assert json.loads(resp.headers["x-render-plan"])["camera_pass"]["drawn"] >= 1


def test_render_model_raw_body(client):
    data = (models_dir() / "Duck.glb").read_bytes()
    resp = client.post("/render", content=data, params={"params": json.dumps(SMALL)},
                       headers={"Content-Type": "model/gltf-binary"})
    assert_picture(resp, 160, 120)


@pytest.mark.parametrize("folder", ["", "model/"])
def test_render_gltf_zip(client, folder):
    d = models_dir()
    archive = zip_bytes({f"{folder}TestScene.gltf": (d / "TestScene.gltf").read_bytes(),
                         f"{folder}TestScene.bin": (d / "TestScene.bin").read_bytes(),
                         "README.txt": b"not part of the scene"})
    assert_picture(post_scene(client, "TestScene.zip", archive, SMALL), 160, 120)


def test_render_embedded_gltf(client):
    assert_picture(post_scene(client, "embedded.gltf", embedded_gltf(), SMALL), 160, 120)


def test_light_inside_geometry_renders(client):
    # A point light in the middle of the demo's box: every receiver is shadowed, still a render.
    params = {**SMALL, "lights": [{"type": "point", "position": [-1.0, 0.5, 0.2]}]}
    assert post_params(client, params).status_code == 200


def test_scene_cache_hit(client):
    data = (models_dir() / "BoxTextured.glb").read_bytes()
    params = {"width": 96, "height": 64}
    post_scene(client, "a.glb", data, params)
    resp = post_scene(client, "b.glb", data, params)
    assert resp.status_code == 200
    assert 'parse;dur=' in resp.headers["server-timing"]
    assert 'desc="scene cache hit"' in resp.headers["server-timing"]
    assert json.loads(resp.headers["x-render-plan"])["scene_cache"] == "hit"


def test_multipart_outputs(client):
    params = {**SMALL, "outputs": ["color", "light_depth", "visibility", "depth"]}
    resp = post_params(client, params, accept="multipart/mixed")
    assert resp.status_code == 200, resp.text
    ctype = resp.headers["content-type"]
    assert ctype.startswith("multipart/mixed")
    boundary = ctype.split("boundary=")[1].strip('"').encode()
    parts = {}
    for chunk in resp.content.split(b"--" + boundary)[1:-1]:
        head, _, body = chunk.strip(b"\r\n").partition(b"\r\n\r\n")
        headers = dict(line.split(": ", 1) for line in head.decode().split("\r\n"))
        assert headers["Content-Type"] == "image/png"
        name = headers["Content-Disposition"].split('name="')[1].split('"')[0]
        parts[name] = (headers, decode_png(body))
    assert set(parts) == {"color", "light_depth_0", "visibility_0", "depth"}
    assert parts["color"][1].shape == (120, 160, 3)
    vis = parts["visibility_0"][1]
    assert vis.shape == (120, 160) and vis.dtype == np.uint16
    assert vis.min() == 0 and vis.max() == 65535  # the demo has shadowed and lit pixels
    depth_headers, depth = parts["depth"]
    assert depth.dtype == np.uint16 and depth.min() == 0 and depth.max() == 65535  # 65535: sky
    assert float(depth_headers["X-Depth-Near"]) < float(depth_headers["X-Depth-Far"])
    ld_headers, ld = parts["light_depth_0"]
    assert ld.dtype == np.uint8 and ld.shape[0] == ld.shape[1] and ld_headers["X-Light"] == "0"
    assert "readback" in server_timing(resp) and json.loads(resp.headers["x-render-plan"])


def test_json_outputs(client):
    params = {**SMALL, "outputs": ["color", "light_depth", "depth"], "alpha": True}
    resp = post_params(client, params, accept="application/json")
    assert resp.status_code == 200 and resp.headers["content-type"] == "application/json"
    body = resp.json()
    assert set(body["outputs"]) == {"color", "light_depth_0", "depth"}
    color = decode_png(base64.b64decode(body["outputs"]["color"]["png"]))
    assert color.shape == (120, 160, 4)
    ld = body["outputs"]["light_depth_0"]
    assert ld["kind"] == "ortho" and ld["near"] < ld["far"] and ld["bit_depth"] == 8
    assert body["outputs"]["depth"]["bit_depth"] == 16
    for stage in ("queue", "parse", "light", "camera", "readback", "encode", "total"):
        assert body["timings"][stage] >= 0
    assert body["plan"]["lights"][0]["shadow_map"] == "ortho"
    assert body["gl"]["renderer"]
    assert "x-render-plan" in resp.headers and "server-timing" in resp.headers


def _multipart(resp: httpx.Response) -> dict[str, tuple[dict[str, str], bytes]]:
    boundary = resp.headers["content-type"].split("boundary=")[1].strip('"').encode()
    parts = {}
    for chunk in resp.content.split(b"--" + boundary)[1:-1]:
        head, _, body = chunk[2:-2].partition(b"\r\n\r\n")  # CRLF after the boundary, before
        headers = dict(line.split(": ", 1) for line in head.decode().split("\r\n"))
        parts[headers["Content-Disposition"].split('name="')[1].split('"')[0]] = (headers, body)
    return parts


def test_exr_outputs_are_the_render_arrays(client, renderer):
    """float_format exr: depth and visibility_<i> as float32 OpenEXR parts (multipart) and
    base64 fields (JSON), equal to the library's arrays for the same request; PNG16 stays the
    default."""
    pytest.importorskip("OpenEXR")
    from shadowmap.renderer import RenderParams, load_scene, read_exr
    from shadowmap.renderer.demo import demo_glb

    params = {**SMALL, "outputs": ["color", "visibility", "depth"], "float_format": "exr",
              "camera": {"eye": [3.5, 3.0, 5.0], "target": [0.0, 0.4, 0.0]},
              "lights": [{"type": "directional", "direction": [-0.6, -1.0, 0.25]},
                         {"type": "point", "position": [1.5, 3.0, 1.5]}]}
    expect = renderer.render(load_scene(demo_glb()), RenderParams.model_validate(params))
    resp = post_params(client, params, accept="multipart/mixed")
    assert resp.status_code == 200, resp.text
    parts = _multipart(resp)
    assert set(parts) == {"color", "visibility_0", "visibility_1", "depth"}
    assert parts["color"][0]["Content-Type"] == "image/png"
    headers, body = parts["depth"]
    assert headers["Content-Type"] == "image/x-exr" and 'filename="depth.exr"' in (
        headers["Content-Disposition"])
    depth = read_exr(body)[0]["Z"]
    assert depth.dtype == np.float32 and depth.shape == (120, 160)
    np.testing.assert_array_equal(depth, expect.depth)  # NaN where no geometry, on both sides
    for i in range(2):
        headers, body = parts[f"visibility_{i}"]
        assert headers["Content-Type"] == "image/x-exr" and headers["X-Light"] == str(i)
        np.testing.assert_array_equal(read_exr(body)[0]["Y"], expect.visibility[..., i])
    body = post_params(client, params, accept="application/json").json()
    out = body["outputs"]["depth"]
    assert out["media_type"] == "image/x-exr" and out["bit_depth"] == 32 and "png" not in out
    np.testing.assert_array_equal(read_exr(base64.b64decode(out["exr"]))[0]["Z"], expect.depth)
    # The same request as 16-bit PNG agrees within its quantisation.
    png = post_params(client, {**params, "float_format": "png16"}, accept="application/json")
    d16 = png.json()["outputs"]["depth"]
    assert d16["media_type"] == "image/png" and d16["bit_depth"] == 16
    v = decode_png(base64.b64decode(d16["png"])).astype(np.float64)
    finite = np.isfinite(expect.depth)
    assert np.array_equal(v < 65535, finite)
    decoded = d16["near"] + v[finite] / 65534 * (d16["far"] - d16["near"])
    assert np.abs(decoded - expect.depth[finite]).max() <= (d16["far"] - d16["near"]) / 65534


def test_warnings_in_the_header_of_every_format_and_in_json(client):
    # max_map_size over this server's limit (2048) is clamped; a PCF kernel means nothing to
    # the hard filter: both rendered as before, and both said.
    params = {**SMALL, "shadows": {"max_map_size": 4096, "filter": "hard", "pcf_kernel": 5},
              "lights": [{"type": "directional", "direction": [-0.5, -1.0, 0.2]}]}
    expected = [
        "shadows.max_map_size 4096 is over the limit of 2048: automatic map sizes stop at 2048",
        "shadows.pcf_kernel 5 is not used: the filter is 'hard'",
    ]
    for accept in ("image/png", "multipart/mixed", "application/json"):
        resp = post_params(client, params, accept=accept)
        assert resp.status_code == 200, resp.text[:500]
        header = resp.headers["x-render-warnings"]
        assert header.isascii() and json.loads(header) == expected, header
        assert "x-render-plan" in resp.headers
        if accept == "application/json":
            assert resp.json()["warnings"] == expected
    # Uploads too, and a render with nothing to report says so with an empty list.
    resp = post_scene(client, "Duck.glb", (models_dir() / "Duck.glb").read_bytes(), SMALL,
                      accept="application/json")
    assert resp.status_code == 200
    assert json.loads(resp.headers["x-render-warnings"]) == resp.json()["warnings"]
    assert post_params(client, SMALL).headers["x-render-warnings"] == "[]"


def test_openapi_documents_the_warnings(client):
    spec = client.get("/openapi.json").json()
    ok = spec["paths"]["/render"]["post"]["responses"]["200"]
    assert "X-Render-Warnings" in ok["headers"]
    assert "warnings" in spec["components"]["schemas"]["RenderJSON"]["properties"]


def test_accept_without_color_prefers_multipart(client):
    params = {**SMALL, "outputs": ["depth"]}
    resp = post_params(client, params, accept="*/*")
    assert resp.status_code == 200 and resp.headers["content-type"].startswith("multipart/mixed")
    assert_error(post_params(client, params, accept="image/png"), 406, "not_acceptable")


def test_sixteen_concurrent_clients(client, server):
    reference = decode_png(post_params(client, SMALL).content)

    def one(i: int) -> tuple[int, np.ndarray]:
        # Even clients repeat the reference request; odd ones ask for their own size.
        params = SMALL if i % 2 == 0 else {"width": 96 + 8 * i, "height": 72}
        with httpx.Client(base_url=server.url, timeout=120) as c:
            return i, assert_picture(post_params(c, params), params["width"], params["height"])

    with ThreadPoolExecutor(16) as pool:
        results = list(pool.map(one, range(16)))
    for i, img in results:
        if i % 2 == 0:
            assert np.array_equal(img, reference)
    assert client.get("/healthz").json()["worker"]["queued"] == 0


# ------------------------------------------------------------------------------------------------
# Bad input: always a 4xx with a JSON body, never a 500, never a dead worker
# ------------------------------------------------------------------------------------------------


def test_upload_too_large_declared(client):
    resp = client.post("/render", content=b"\0" * (MAX_UPLOAD + 1),
                       headers={"Content-Type": "model/gltf-binary"})
    assert_error(resp, 413, "payload_too_large", "max_upload_bytes")


def test_upload_too_large_chunked(client):
    def body():  # a generator: httpx sends it chunked, with no Content-Length
        for _ in range(5):
            yield b"\0" * (MAX_UPLOAD // 4)

    resp = client.post("/render", content=body(), headers={"Content-Type": "model/gltf-binary"})
    assert "content-length" not in resp.request.headers
    assert_error(resp, 413, "payload_too_large", "max_upload_bytes")


def test_upload_too_large_multipart(client):
    resp = post_scene(client, "big.glb", b"glTF" + b"\0" * MAX_UPLOAD, SMALL)
    assert_error(resp, 413, "payload_too_large", "max_upload_bytes")


def _model(name: str) -> bytes:
    return (models_dir() / name).read_bytes()


def _model_uri(as_uri: bool) -> str:
    path = models_dir().resolve() / "TestScene.bin"
    return path.as_uri() if as_uri else str(path)


def _corrupt_json_chunk() -> bytes:
    glb = _model("cube.glb")
    return glb[:20] + b"{{{{" + glb[24:]  # the JSON chunk starts at byte 20


BAD_SCENES = {
    "truncated glb": lambda: ("Duck.glb", _model("Duck.glb")[:5000]),
    "wrong magic": lambda: ("Duck.glb", b"NOPE" + _model("Duck.glb")[4:]),
    "corrupt json chunk": lambda: ("cube.glb", _corrupt_json_chunk()),
    "garbage gltf": lambda: ("scene.gltf", b"\xff\xfe not json at all"),
    "gltf without asset": lambda: ("scene.gltf", b'{"meshes": []}'),
    "empty scene": lambda: ("empty.gltf", b'{"asset": {"version": "2.0"}, "scenes": [{}]}'),
    "empty file": lambda: ("empty.glb", b""),
    "unknown suffix": lambda: ("Duck.obj", _model("Duck.glb")),
    "gltf missing its buffer": lambda: ("TestScene.gltf", _model("TestScene.gltf")),
    "uri parent": lambda: ("s.gltf", gltf_with_buffer_uri("../models/TestScene.bin")),
    "uri absolute": lambda: ("s.gltf", gltf_with_buffer_uri(_model_uri(False))),
    "uri file": lambda: ("s.gltf", gltf_with_buffer_uri(_model_uri(True))),
    "not a zip": lambda: ("scene.zip", _model("Duck.glb")),
    "truncated zip": lambda: ("scene.zip", zip_bytes({"cube.glb": _model("cube.glb")})[:60]),
    "zip dotdot": lambda: ("scene.zip", zip_bytes({"cube.glb": _model("cube.glb"),
                                                   "../evil.bin": b"x"})),
    "zip absolute": lambda: ("scene.zip", zip_bytes({"/tmp/cube.glb": _model("cube.glb")})),
    "zip without scene": lambda: ("scene.zip", zip_bytes({"readme.txt": b"hello"})),
    "zip with two scenes": lambda: ("scene.zip", zip_bytes({"a.glb": _model("cube.glb"),
                                                            "b.glb": _model("cube.glb")})),
}


@pytest.mark.parametrize("case", list(BAD_SCENES))
def test_bad_scene(client, case):
    name, data = BAD_SCENES[case]()
    assert_error(post_scene(client, name, data, SMALL), 400, "invalid_scene")


@pytest.mark.parametrize("asset, extra, error, key, value", [
    ({"version": "2.0"}, {"extensionsUsed": ["KHR_fake", "EXT_other"],
                          "extensionsRequired": ["KHR_fake", "EXT_other"]},
     "unsupported_extension", "extensions", ["KHR_fake", "EXT_other"]),
    ({"version": "2.0", "minVersion": "2.1"}, {}, "unsupported_version", "field",
     "asset.minVersion"),
    ({"version": "3.0"}, {}, "unsupported_version", "field", "asset.version"),
])
def test_unsupported_gltf_is_422_naming_what(client, asset, extra, error, key, value):
    doc = json.loads(embedded_gltf())
    doc["asset"] = asset
    doc.update(extra)
    body = assert_error(post_scene(client, "scene.gltf", json.dumps(doc).encode(), SMALL), 422,
                        error)
    assert body[key] == value


def test_uri_http_is_never_fetched(client):
    """A buffer URI naming a live local HTTP port: refused, and nothing connects to it."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
        listener.setblocking(False)
        port = listener.getsockname()[1]
        for uri in (f"http://127.0.0.1:{port}/TestScene.bin", f"//127.0.0.1:{port}/TestScene.bin"):
            resp = post_scene(client, "s.gltf", gltf_with_buffer_uri(uri), SMALL)
            assert_error(resp, 400, "invalid_scene")
        with pytest.raises(BlockingIOError):
            listener.accept()


def test_zip_bomb_declared(client):
    d = models_dir()
    archive = zip_bytes({"TestScene.gltf": (d / "TestScene.gltf").read_bytes(),
                         "TestScene.bin": b"\0" * (64 * 2**20)})  # ~64 kB compressed
    assert len(archive) < MAX_UPLOAD
    assert_error(post_scene(client, "bomb.zip", archive, SMALL), 413, "payload_too_large",
                 "max_unzipped_bytes")


def test_zip_bomb_understated(client):
    """Declared sizes lie (small); the bytes produced while unpacking are what counts."""
    d = models_dir()
    archive = zip_bytes({"TestScene.gltf": (d / "TestScene.gltf").read_bytes(),
                         "TestScene.bin": b"\0" * (64 * 2**20)})
    archive = understate_zip_sizes(archive, "TestScene.bin", 1000)
    resp = post_scene(client, "bomb.zip", archive, SMALL)
    assert resp.status_code in (400, 413), resp.text
    assert_error(resp, resp.status_code)


BAD_PARAMS = {
    "not json": ("{", "invalid_params"),
    "json array": ("[1, 2]", "invalid_params"),
    "NaN literal": ('{"width": NaN}', "invalid_params"),
    "NaN in vector": ('{"lights": [{"direction": [NaN, -1, 0]}]}', "invalid_params"),
    "Infinity literal": ('{"ambient": [Infinity, 0, 0]}', "invalid_params"),
    "-Infinity literal": ('{"camera": {"eye": [-Infinity, 1, 1], "target": [0, 0, 0]}}',
                          "invalid_params"),
    "overflowing number": ('{"lights": [{"direction": [1e999, -1, 0]}]}', "invalid_params"),
    "unknown field": ('{"widht": 100}', "invalid_params"),
    "wrong type": ('{"width": "wide"}', "invalid_params"),
    "out of range": ('{"width": 0}', "invalid_params"),
    "bad output": ('{"outputs": ["normals"]}', "invalid_params"),
    # Rules between fields (and what needs no scene) are the request model's: 422 naming the
    # field by JSON pointer.
    "zero light direction": ('{"lights": [{"type": "directional", "direction": [0, 0, 0]}]}',
                             "invalid_params"),
    "camera eye at target": ('{"camera": {"eye": [1, 1, 1], "target": [1, 1, 1]}}',
                             "invalid_params"),
    "singular camera pose": ('{"camera": {"pose": [[0,0,0,0],[0,0,0,0],[0,0,0,0],[0,0,0,1]]}}',
                             "invalid_params"),
    "light without a type": ('{"lights": [{"direction": [0, -1, 0]}]}', "invalid_params"),
    "zero for a boolean": ('{"ground": 0}', "invalid_params"),
    "false for a number": ('{"specular": false}', "invalid_params"),
    "key given twice": ('{"width": 64, "width": 100000}', "invalid_params"),
}


@pytest.mark.parametrize("text, field, msg", [
    ('{"width": 64, "width": 100000}', "/width", "the key 'width' is given twice in one object"),
    ('{"lights": [{"type": "directional", "direction": [0, -1, 0]}], "lights": []}', "/lights",
     "the key 'lights' is given twice"),
    ('{"lights": [{"type": "point", "position": [0, 3, 0], "position": [9, 9, 9]}]}',
     "/lights/0/position", "the key 'position' is given twice in one object (at lights[0])"),
    ('{"shadows": {"fit": "scene", "fit": "view"}}', "/shadows/fit", "(at shadows)"),
])
def test_a_key_given_twice_is_refused_at_its_place(client, text, field, msg):
    """JSON leaves an object's repeated key open (most parsers keep the last value): refused,
    naming where, rather than rendering what the sender half asked for."""
    body = assert_error(post_params(client, text), 422, "invalid_params")
    assert body["field"] == field and msg in body["errors"][0]["msg"], body


@pytest.mark.parametrize("case", list(BAD_PARAMS))
def test_bad_params(client, case):
    text, error = BAD_PARAMS[case]
    assert_error(post_params(client, text), 422, error)


def test_params_too_large(client):
    text = json.dumps({"width": 100, "lights": [{"direction": [0, -1, 0]}] * 3000})
    assert_error(post_params(client, text), 413, "payload_too_large", "max_params_bytes")


def test_bad_params_in_query_and_form(client):
    data = (models_dir() / "cube.glb").read_bytes()
    resp = client.post("/render", content=data, params={"params": '{"width": NaN}'},
                       headers={"Content-Type": "model/gltf-binary"})
    assert_error(resp, 422, "invalid_params")
    body = assert_error(post_scene(client, "cube.glb", data, '{"height": "x"}'), 422,
                        "invalid_params")
    assert body["errors"][0]["loc"] == ["height"]


LIMITS = {
    "max_pixels": {"width": 2048, "height": 1024},
    "max_map_size": {**SMALL, "shadows": {"map_size": 4096, "max_map_size": 4096}},
    "max_lights": {**SMALL, "lights": [{"type": "directional", "direction": [0, -1, 0]}] * 5},
}


@pytest.mark.parametrize("limit", list(LIMITS))
def test_over_limit(client, limit):
    assert_error(post_params(client, LIMITS[limit]), 422, "limit_exceeded", limit)


def test_over_triangle_limit(client):
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=5)  # 20480 triangles, limit 20000
    resp = post_scene(client, "sphere.glb", trimesh_glb(mesh), SMALL)
    assert_error(resp, 422, "limit_exceeded", "max_triangles")


def test_bad_requests(client):
    assert_error(client.post("/render", content=b"hello", headers={"Content-Type": "text/plain"}),
                 415, "unsupported_media_type")
    glb = (models_dir() / "cube.glb").read_bytes()
    # curl --data-binary without a Content-Type sends an urlencoded form
    assert_error(client.post("/render", content=glb,
                             headers={"Content-Type": "application/x-www-form-urlencoded"}),
                 415, "unsupported_media_type")
    assert_error(client.post("/render", files={"model": ("cube.glb", glb)}), 422, "invalid_request")
    assert_error(client.post("/render", headers={"Accept": "text/html"}), 406, "not_acceptable")
    assert_error(client.post("/render", params={"params": "{}"}, content=b"{}",
                             headers={"Content-Type": "application/json"}), 422, "invalid_params")
    # A JSON body of whitespace alone is no JSON (an empty one is no body: the demo's params).
    for blank in (b"\r", b" \n\t"):
        assert_error(client.post("/render", content=blank,
                                 headers={"Content-Type": "application/json"}), 422,
                     "invalid_params")
    empty = client.post("/render", content=b"", headers={"Content-Type": "application/json"})
    assert empty.status_code == 200 and empty.headers["content-type"] == "image/png"
    assert_error(client.post("/render", content=b"--x\r\nbroken",
                             headers={"Content-Type": "multipart/form-data; boundary=x"}), 400,
                 "bad_request")


def test_worker_survives_bad_input(client):
    """After every bad request above, the same process still renders and reports healthy."""
    assert_picture(post_params(client, SMALL), 160, 120)
    health = client.get("/healthz").json()
    assert health["status"] == "ok" and health["worker"]["alive"]


# ------------------------------------------------------------------------------------------------
# Load: a full queue and the time limit (the tiny server)
# ------------------------------------------------------------------------------------------------


def wait_idle(url: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        w = httpx.get(url + "/healthz", timeout=5).json()["worker"]
        if w["busy_seconds"] is None and w["queued"] == 0:
            return
        time.sleep(0.1)
    raise AssertionError("the worker did not become idle")


@pytest.mark.slow
def test_render_timeout_then_healthy(tiny):
    with httpx.Client(base_url=tiny.url, timeout=60) as c:
        t0 = time.monotonic()
        resp = post_params(c, SLOW, accept="multipart/mixed")
        if resp.status_code == 200:
            pytest.skip("this machine renders SLOW within the 1 s limit; cannot provoke a timeout")
        body = assert_error(resp, 504, "render_timeout", "render_timeout")
        # The render is stopped, not left running: its worker process is replaced.
        assert "stopped" in body["detail"]
        assert time.monotonic() - t0 < 10
        # Health answers at once while the new worker starts.
        t0 = time.monotonic()
        health = c.get("/healthz")
        assert health.status_code == 200 and time.monotonic() - t0 < 1.0
        assert health.json()["worker"]["timeouts"] >= 1
        wait_idle(tiny.url)
        assert_picture(post_params(c, SMALL), 160, 120)


@pytest.mark.slow
def test_queue_full_gives_503_with_retry_after(tiny):
    barrier = threading.Barrier(6)

    def one(_: int) -> httpx.Response:
        with httpx.Client(base_url=tiny.url, timeout=60) as c:
            barrier.wait()
            return post_params(c, SLOW, accept="multipart/mixed")

    with ThreadPoolExecutor(6) as pool:
        responses = list(pool.map(one, range(6)))
    statuses = sorted(r.status_code for r in responses)
    assert set(statuses) <= {200, 503, 504}, statuses
    full = [r for r in responses if r.status_code == 503]
    assert full, statuses
    assert any(r.json()["error"] == "queue_full" for r in full), [r.json() for r in full]
    for r in full:
        assert_error(r, 503)
        assert int(r.headers["retry-after"]) >= 1
    assert httpx.get(tiny.url + "/healthz", timeout=5).status_code == 200
    wait_idle(tiny.url)
    with httpx.Client(base_url=tiny.url, timeout=60) as c:
        assert_picture(post_params(c, SMALL), 160, 120)
