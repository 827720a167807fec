"""The web page in real headless Chromium against a real server.

The page renders on load with ``?autorender=1`` and sets ``data-state="done"`` on its status
element once both images have loaded; ``--dump-dom`` with a virtual-time budget waits for that,
and ``--screenshot`` shows what a user would see.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from html.parser import HTMLParser
from urllib.parse import quote

import httpx
import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.gl

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def chromium() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("Chromium is not installed (Debian: apt-get install -y chromium); "
                "the page test needs a real browser")


@contextlib.contextmanager
def uvicorn_server(*args: str, ready: str = "/healthz", timeout: float = 90.0,
                   env: dict | None = None) -> Iterator[str]:
    """The service under uvicorn on a free localhost port, in a subprocess; yields its URL once
    ``ready`` answers 200 (``args``: more uvicorn options)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "--factory", "shadowmap.app.main:create_app", "--host",
         "127.0.0.1", "--port", str(port), "--log-level", "warning", *args],
        env=env, stdout=log, stderr=subprocess.STDOUT, cwd=tempfile.gettempdir(),
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None or time.monotonic() > deadline:
                log.seek(0)
                raise RuntimeError("server did not start:\n" + log.read().decode(errors="replace"))
            try:
                if httpx.get(url + ready, timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


@pytest.fixture(scope="module")
def server_url():
    """The service on a free localhost port, in a subprocess."""
    chromium()  # skip before starting anything when there is no browser
    env = dict(os.environ)
    env["SHADOWMAP_MAX_PIXELS"] = str(1024 * 1024)
    with uvicorn_server(env=env) as url:
        yield url


def run_browser(url: str, *args: str) -> subprocess.CompletedProcess:
    """Headless Chromium on ``url`` with a throw-away profile and no background traffic."""
    with tempfile.TemporaryDirectory(prefix="shadowmap-chromium-",
                                     ignore_cleanup_errors=True) as profile:
        # (Chromium's helper processes may still write to the profile as it is removed.)
        cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--disable-extensions", "--hide-scrollbars", f"--user-data-dir={profile}",
               "--virtual-time-budget=60000", *args, url]
        return subprocess.run(cmd, capture_output=True, timeout=180)


class _Elements(HTMLParser):
    """Attributes of the elements with an id."""

    def __init__(self) -> None:
        super().__init__()
        self.by_id: dict[str, dict[str, str]] = {}
        self.text: dict[str, str] = {}
        self._open: str | None = None

    def handle_starttag(self, tag, attrs):
        a = {k: v or "" for k, v in attrs}
        if "id" in a:
            self.by_id[a["id"]] = a
            self._open = a["id"]

    def handle_data(self, data):
        if self._open:
            self.text[self._open] = self.text.get(self._open, "") + data

    def handle_endtag(self, tag):
        self._open = None


def data_png(src: str) -> np.ndarray:
    prefix = "data:image/png;base64,"
    assert src.startswith(prefix), src[:80]
    return np.array(Image.open(io.BytesIO(base64.b64decode(src[len(prefix):]))))


@pytest.mark.parametrize("debug", ["light_depth", "depth"])
def test_page_renders_on_load(server_url, debug):
    done = run_browser(f"{server_url}/?autorender=1&width=320&height=240&debug={debug}",
                       "--dump-dom")
    dom = done.stdout.decode(errors="replace")
    page = _Elements()
    page.feed(dom)
    status = page.by_id.get("status", {})
    assert status.get("data-state") == "done", (page.text.get("status"), done.stderr[-2000:])
    color = data_png(page.by_id["color-img"]["src"])
    assert color.shape == (240, 320, 3)
    assert color.reshape(-1, 3).std(axis=0).max() > 10
    shown = data_png(page.by_id["debug-img"]["src"])
    if debug == "depth":
        assert shown.shape == (240, 320) and shown.dtype == np.uint16
    else:
        assert shown.ndim == 2 and shown.shape[0] == shown.shape[1]  # a square shadow map
    assert page.text["debug-cap"].startswith(debug)
    timings = dom.split('id="timings"', 1)[1].split("</table>", 1)[0]
    assert "readback" in timings and "encode" in timings
    if debug == "light_depth":
        # Stretched over the drawn depths, not the fitted range: from black to near-white, and
        # not a nearly black picture; the caption says so.
        drawn = shown[shown < 255]
        assert drawn.size > 0.05 * shown.size
        assert drawn.min() <= 2 and drawn.max() >= 250 and drawn.mean() > 40, (
            drawn.min(), drawn.max(), drawn.mean())
        assert "stretched over the drawn depths" in page.text["debug-cap"]


def test_ground_on_the_demo_adds_no_second_floor(server_url):
    """The demo scene has its own floor: ticking "ground plane" adds none (the picture is the
    same as without) and the page lists the warning that says why."""
    pages, warnings = {}, {}
    for ground in ("0", "1"):
        done = run_browser(f"{server_url}/?autorender=1&width=320&height=240&ground={ground}",
                           "--dump-dom")
        dom = done.stdout.decode(errors="replace")
        page = _Elements()
        page.feed(dom)
        assert page.by_id["status"].get("data-state") == "done", page.text.get("status")
        pages[ground] = page
        warnings[ground] = dom.split('id="warnings"', 1)[1].split("</ul>", 1)[0]
    with_ground, without = (data_png(pages[g].by_id["color-img"]["src"]) for g in ("1", "0"))
    np.testing.assert_array_equal(with_ground, without)
    assert "own floor" in warnings["1"] and "own floor" not in warnings["0"]
    sent = json.loads(pages["1"].text["request"])
    assert sent["ground"] is True


# --- Driving the page: Chromium's DevTools protocol ------------------------------------------


class DevToolsPage:
    """One page of a headless Chromium, driven over the DevTools protocol (real mouse and wheel
    events through ``Input.dispatchMouseEvent``, script through ``Runtime.evaluate``)."""

    def __init__(self, ws) -> None:
        self.ws = ws  # a websockets.sync.client connection
        self.next_id = 0

    def call(self, method: str, timeout: float = 60.0, **params) -> dict:
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            message = json.loads(self.ws.recv(timeout=max(deadline - time.monotonic(), 0.01)))
            if message.get("id") == self.next_id:  # events and other replies are skipped
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                           awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 120.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                value = self.evaluate(expression)
            except RuntimeError:  # the page is still loading (its elements are not there yet)
                value = None
            if value:
                return value
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {expression}; status: "
                             + str(self.evaluate("document.getElementById('status').textContent")))

    def mouse(self, kind: str, x: float, y: float, **extra) -> None:
        self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, **extra)


@contextlib.contextmanager
def devtools(url: str) -> Iterator[DevToolsPage]:
    """Headless Chromium with a DevTools port, on ``url``; yields the page."""
    from websockets.sync.client import connect

    with tempfile.TemporaryDirectory(prefix="shadowmap-chromium-",
                                     ignore_cleanup_errors=True) as profile:
        # (Chromium's helper processes may still write to the profile as it is removed.)
        log = tempfile.TemporaryFile()
        proc = subprocess.Popen(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-extensions", "--hide-scrollbars", "--window-size=1280,1000",
             "--remote-debugging-port=0", f"--user-data-dir={profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=log)
        try:
            # Chromium writes the port it chose to DevToolsActivePort in the profile.
            port_file = os.path.join(profile, "DevToolsActivePort")
            deadline = time.monotonic() + 60
            while not (os.path.exists(port_file) and open(port_file).read().strip()):
                if proc.poll() is not None or time.monotonic() > deadline:
                    log.seek(0)
                    raise RuntimeError("Chromium did not start: " + log.read().decode()[-2000:])
                time.sleep(0.1)
            port = open(port_file).read().split()[0]
            # The page URL is the query: its own "&"s escaped, or its parameters after the
            # first would be read as the endpoint's.
            target = httpx.put(f"http://127.0.0.1:{port}/json/new?{quote(url, safe=':/?=')}",
                               timeout=30).json()
            with connect(target["webSocketDebuggerUrl"], max_size=None, open_timeout=30) as ws:
                yield DevToolsPage(ws)
        finally:
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
            log.close()


IDLE = ("document.getElementById('status').dataset.state === 'done' && !busy && !again "
        "&& Number(document.getElementById('status').dataset.renders) >= {n}")


def _renders(page: DevToolsPage) -> int:
    return int(page.evaluate("Number(document.getElementById('status').dataset.renders || 0)"))


def _render_done(page: DevToolsPage, after: int) -> tuple[dict, np.ndarray]:
    """Wait for a render past the ``after``-th to finish with nothing more queued; the request
    it sent and the colour image it shows."""
    page.wait_for(IDLE.format(n=after + 1))
    sent = json.loads(page.evaluate("document.getElementById('request').textContent"))
    return sent, data_png(page.evaluate("document.getElementById('color-img').src"))


def _image_centre(page: DevToolsPage) -> tuple[float, float]:
    x, y = page.evaluate(
        "(() => { const im = document.getElementById('color-img'); im.scrollIntoView();"
        " const r = im.getBoundingClientRect(); return [r.left + r.width / 2,"
        " r.top + r.height / 2]; })()")
    return float(x), float(y)


def test_drag_and_wheel_orbit_the_camera(server_url):
    with devtools(f"{server_url}/?autorender=1&width=320&height=240") as page:
        first, image0 = _render_done(page, 0)
        assert "camera" not in first  # the first render frames the scene itself
        camera = json.loads(page.evaluate("document.getElementById('plan').textContent"))[
            "camera"]
        centre = np.array(camera["focus_center"])
        eye0 = np.array(camera["eye"])
        radius = np.linalg.norm(eye0 - centre)

        # Drag 120 px to the right: the camera swings around +Y, at the same height and
        # distance, looking at the same point.
        x, y = _image_centre(page)
        width = page.evaluate("document.getElementById('color-img').clientWidth")
        n = _renders(page)
        page.mouse("mousePressed", x, y, button="left", buttons=1, clickCount=1)
        for step in range(1, 7):
            page.mouse("mouseMoved", x + 20 * step, y, button="left", buttons=1)
        page.mouse("mouseReleased", x + 120, y, button="left", buttons=0, clickCount=1)
        sent, image1 = _render_done(page, n)
        eye1 = np.array(sent["camera"]["eye"])
        np.testing.assert_allclose(sent["camera"]["target"], centre, atol=1e-9)
        assert abs(np.linalg.norm(eye1 - centre) - radius) < 1e-6 * radius
        assert abs(eye1[1] - eye0[1]) < 1e-6 * radius
        swing = math.atan2(*(eye0 - centre)[[0, 2]]) - math.atan2(*(eye1 - centre)[[0, 2]])
        assert math.isclose(swing % (2 * math.pi), 120 * math.pi / width, rel_tol=1e-3)
        assert np.abs(image1.astype(int) - image0.astype(int)).mean() > 3  # a different view

        # Wheel toward the scene: closer, along the same line.
        n = _renders(page)
        page.mouse("mouseWheel", x, y, deltaX=0, deltaY=-300)
        sent, image2 = _render_done(page, n)
        eye2 = np.array(sent["camera"]["eye"])
        assert math.isclose(np.linalg.norm(eye2 - centre), radius * math.exp(-0.3), rel_tol=1e-6)
        np.testing.assert_allclose((eye2 - centre) / np.linalg.norm(eye2 - centre),
                                   (eye1 - centre) / radius, atol=1e-9)
        assert np.abs(image2.astype(int) - image1.astype(int)).mean() > 3


def test_the_projection_selector_and_an_orthographic_orbit(server_url):
    """The projection selector asks for an orthographic camera (the whole scene in view); the
    orbit takes its projection from the plan, the wheel then scales ymag, not the distance;
    switching back to perspective keeps what is in view at the target's distance."""
    with devtools(f"{server_url}/?autorender=1&width=320&height=240&projection=orthographic"
                  ) as page:
        first, image0 = _render_done(page, 0)
        assert first["camera"] == {"projection": "orthographic"}
        camera = json.loads(page.evaluate("document.getElementById('plan').textContent"))[
            "camera"]
        assert camera["projection"] == "orthographic" and camera["ymag"] > 0
        ymag = camera["ymag"]
        x, y = _image_centre(page)
        n = _renders(page)
        page.mouse("mouseWheel", x, y, deltaX=0, deltaY=-300)
        zoomed, image1 = _render_done(page, n)
        assert zoomed["camera"]["projection"] == "orthographic"
        assert math.isclose(zoomed["camera"]["ymag"], ymag * math.exp(-0.3), rel_tol=1e-9)
        assert "yfov_deg" not in zoomed["camera"]
        np.testing.assert_allclose(zoomed["camera"]["eye"], camera["eye"], rtol=1e-12)
        assert np.abs(image1.astype(int) - image0.astype(int)).mean() > 3

        n = _renders(page)
        page.evaluate("(() => { const s = document.getElementById('projection');"
                      " s.value = 'perspective'; s.dispatchEvent(new Event('change')); })()")
        persp, _ = _render_done(page, n)
        assert persp["camera"]["yfov_deg"] == 45 and "ymag" not in persp["camera"]
        target = np.array(persp["camera"]["target"])
        distance = np.linalg.norm(np.array(persp["camera"]["eye"]) - target)
        assert math.isclose(distance * math.tan(math.radians(22.5)), zoomed["camera"]["ymag"],
                            rel_tol=1e-9)
        plan = json.loads(page.evaluate("document.getElementById('plan').textContent"))
        assert plan["camera"]["projection"] == "perspective"


def test_light_azimuth_and_elevation_set_the_direction(server_url):
    with devtools(f"{server_url}/?autorender=1&width=320&height=240&debug=light_depth") as page:
        first, image0 = _render_done(page, 0)
        n = _renders(page)
        # As a user does: move the sliders (keyboard on the focused range inputs), then let go.
        for slider, key, times in (("light-az", "ArrowRight", 40), ("light-el", "ArrowLeft", 25)):
            page.evaluate(f"document.getElementById('{slider}').focus()")
            for _ in range(times):
                for kind in ("keyDown", "keyUp"):
                    page.call("Input.dispatchKeyEvent", type=kind, key=key, code=key,
                              windowsVirtualKeyCode=39 if key == "ArrowRight" else 37)
        az = float(page.evaluate("document.getElementById('light-az').value"))
        el = float(page.evaluate("document.getElementById('light-el').value"))
        sent, image1 = _render_done(page, n)
        a, e = math.radians(az), math.radians(el)
        expect = [-math.cos(e) * math.sin(a), -math.sin(e), -math.cos(e) * math.cos(a)]
        np.testing.assert_allclose(sent["lights"][0]["direction"], expect, atol=1e-4)
        before = first["lights"][0]["direction"]
        assert not np.allclose(before, sent["lights"][0]["direction"], atol=1e-2)
        assert np.abs(image1.astype(int) - image0.astype(int)).mean() > 1  # the shadows moved


def test_page_screenshot(server_url, tmp_path):
    shot = tmp_path / "page.png"
    done = run_browser(f"{server_url}/?autorender=1&width=480&height=360",
                       f"--screenshot={shot}", "--window-size=1280,1000")
    assert shot.is_file(), done.stderr[-2000:]
    if os.environ.get("SHADOWMAP_KEEP_SCREENSHOT"):  # to look at it: a path to copy it to
        shutil.copy(shot, os.environ["SHADOWMAP_KEEP_SCREENSHOT"])
    img = np.array(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape[:2] == (1000, 1280)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    # The demo's red box and blue sphere are on screen, and so is the gray shadow-map image.
    assert ((r - g > 40) & (r - b > 40)).sum() > 2000
    assert ((b - r > 35) & (b > g)).sum() > 2000
    gray = (abs(r - g) < 3) & (abs(g - b) < 3) & (r > 40) & (r < 200)
    assert gray.sum() > 5000
