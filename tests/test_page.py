"""The web page in real headless Chromium against a real server.

The page renders on load with ``?autorender=1`` and sets ``data-state="done"`` on its status
element once both images have loaded; ``--dump-dom`` with a virtual-time budget waits for that,
and ``--screenshot`` shows what a user would see.
"""

from __future__ import annotations

import base64
import contextlib
import io
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from html.parser import HTMLParser

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
    with tempfile.TemporaryDirectory(prefix="shadowmap-chromium-") as profile:
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
