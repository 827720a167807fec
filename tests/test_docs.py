"""``/docs`` (Swagger UI) and ``/redoc`` (ReDoc) work offline: their assets are served by the app.

In-process (httpx, no lifespan, so no GL): the pages refer only to local URLs, which answer with
the JS and CSS. In headless Chromium against a real server with every host but 127.0.0.1
unresolvable: Swagger UI renders the operations and ReDoc renders the API.
"""

from __future__ import annotations

import asyncio
import re
from html.parser import HTMLParser

import httpx
import pytest

from test_page import chromium, run_browser, uvicorn_server

BASE = "http://app"


class _Refs(HTMLParser):
    """Every ``src`` and ``href`` attribute, and the page's inline script text."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.script = ""
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name in ("src", "href") and value:
                self.urls.append(value)
        self._in_script = tag == "script"

    def handle_data(self, data):
        if self._in_script:
            self.script += data

    def handle_endtag(self, tag):
        self._in_script = False


def _get_all(paths: list[str]) -> list[httpx.Response]:
    from shadowmap.app.main import create_app

    async def requests() -> list[httpx.Response]:
        # ASGITransport runs no lifespan: no render worker, which these pages do not need.
        transport = httpx.ASGITransport(app=create_app())
        async with httpx.AsyncClient(transport=transport, base_url=BASE) as c:
            return [await c.get(p) for p in paths]

    return asyncio.run(requests())


def _local_refs(html: str) -> list[str]:
    refs = _Refs()
    refs.feed(html)
    urls = refs.urls + re.findall(r"""url:\s*['"]([^'"]+)['"]""", refs.script)
    urls += re.findall(r"""Redoc\.init\(\s*['"]([^'"]+)['"]""", refs.script)
    urls += re.findall(r"""spec-url=['"]([^'"]+)['"]""", html)
    absolute = re.findall(r"https?://[^\s'\"<>)]+", html)
    assert not absolute, f"the page refers to other hosts: {absolute}"
    assert urls and all(u.startswith("/") for u in urls), urls
    return urls


@pytest.mark.parametrize(("page", "assets"), [
    ("/docs", {"/static/docs/swagger-ui-bundle.js": "javascript",
               "/static/docs/swagger-ui.css": "css",
               "/static/docs/favicon.png": "image/png"}),
    ("/redoc", {"/static/docs/redoc.standalone.js": "javascript",
                "/static/docs/favicon.png": "image/png"}),
])
def test_page_refers_only_to_local_assets(page, assets):
    (resp,) = _get_all([page])
    assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/html")
    urls = _local_refs(resp.text)
    assert set(assets) <= set(urls), urls
    fetched = _get_all(urls)
    for url, r in zip(urls, fetched, strict=True):
        assert r.status_code == 200, url
        if url in assets:
            assert assets[url] in r.headers["content-type"], (url, r.headers["content-type"])
            assert len(r.content) > 1000, url
    assert "/openapi.json" in urls
    assert "/render" in fetched[urls.index("/openapi.json")].json()["paths"]


def test_docs_pages_are_documented_and_their_assets_are_not():
    (resp,) = _get_all(["/openapi.json"])
    paths = resp.json()["paths"]
    for page in ("/docs", "/redoc"):
        assert "text/html" in paths[page]["get"]["responses"]["200"]["content"], page
    assert not any(p.startswith(("/static", "/docs/oauth2")) for p in paths), list(paths)
    assert _get_all(["/docs/oauth2-redirect"])[0].status_code == 200


@pytest.fixture(scope="module")
def docs_server():
    """The app on a free localhost port, without its lifespan (no render worker, no GL)."""
    chromium()  # skip before starting anything when there is no browser
    with uvicorn_server("--lifespan", "off", ready="/openapi.json", timeout=60) as url:
        yield url


# Every host name but 127.0.0.1 fails to resolve, and no proxy: as on a machine without internet.
OFFLINE = ("--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--no-proxy-server")


def _offline_dom(url: str) -> str:
    done = run_browser(url, *OFFLINE, "--dump-dom")
    # Swagger UI puts a zero-width space before each "/" of a path, to let it wrap.
    return done.stdout.decode(errors="replace").replace("\u200b", "")


def test_swagger_ui_renders_offline(docs_server):
    dom = _offline_dom(docs_server + "/docs")
    assert 'class="swagger-ui"' in dom, dom[-2000:]
    assert dom.count("opblock-summary-path") >= 3, dom[-2000:]
    assert 'data-path="/render"' in dom or ">/render<" in dom, dom[-2000:]
    assert "Failed to load API definition" not in dom


def test_redoc_renders_offline(docs_server):
    dom = _offline_dom(docs_server + "/redoc")
    assert "shadowmap-service" in dom and "/render" in dom, dom[-2000:]
    assert 'id="operation/' in dom, dom[-2000:]  # an operation's section, so ReDoc ran
