"""The service's pure parts, without GL: response format negotiation, 16-bit encodings, and the
JSON error shape of the app's handlers (in-process, no lifespan, so no GL thread)."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from test_app import assert_error


@pytest.mark.parametrize(("accept", "outputs", "expected"), [
    (None, ["color"], "image/png"),
    ("*/*", ["color", "depth"], "image/png"),
    ("*/*", ["depth"], "multipart/mixed"),
    ("application/json", ["color"], "application/json"),
    ("image/*;q=0.5, application/json", ["color"], "application/json"),
    ("multipart/mixed, image/png;q=0", ["color"], "multipart/mixed"),
    ("image/png;q=0, */*", ["color"], "multipart/mixed"),
    ("text/html", ["color"], None),
])
def test_choose_format(accept, outputs, expected):
    from shadowmap.app.encode import choose_format

    assert choose_format(accept, outputs) == expected


def test_16_bit_encodings():
    from shadowmap.app.encode import depth_u16, visibility_u16

    vis = visibility_u16(np.array([[0.0, 1.0, 0.5, np.nan]], np.float32))
    assert vis.tolist() == [[0, 65535, 32768, 0]]
    depth, near, far = depth_u16(np.array([[2.0, 4.0, 3.0, np.nan]], np.float32))
    assert (near, far) == (2.0, 4.0) and depth.tolist() == [[0, 65534, 32767, 65535]]
    empty, near, far = depth_u16(np.full((2, 2), np.nan, np.float32))
    assert near is None and far is None and (empty == 65535).all()


def test_16_bit_encodings_equal_their_formulas():
    """The in-place conversions give exactly round(clip(v, 0, 1) * 65535) and
    round((d - near) / (far - near) * 65534) in float64, on random images with NaN, infinities
    and values that fall halfway between two levels."""
    from shadowmap.app.encode import depth_u16, visibility_u16

    rng = np.random.default_rng(11)
    for k in range(60):
        v = (rng.random((24, 32)) * (1 + k % 3) - 0.2 * (k % 2)).astype(np.float32)
        spots = rng.permutation(v.size)[:40]
        v.flat[spots[:8]] = np.nan
        v.flat[spots[8:12]] = np.inf
        v.flat[spots[12:16]] = -np.inf
        v.flat[spots[16:40]] = (rng.integers(0, 65535, 24) + 0.5) / 65535  # halfway
        clean = np.nan_to_num(v.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0)
        expected = np.rint(np.clip(clean, 0.0, 1.0) * 65535.0).astype(np.uint16)
        assert np.array_equal(visibility_u16(v), expected)

        d = (rng.random((24, 32)) * 10 + 1).astype(np.float32)
        d.flat[spots[:8]] = np.nan
        d.flat[spots[8:10]] = np.inf if k % 2 else np.nan
        finite = np.isfinite(d)
        near, far = float(d[finite].min()), float(d[finite].max())
        want = np.full(d.shape, 65535, np.uint16)
        want[finite] = np.rint((d[finite].astype(np.float64) - near) / (far - near)
                               * 65534.0).astype(np.uint16)
        got, got_near, got_far = depth_u16(d)
        assert (got_near, got_far) == (near, far) and np.array_equal(got, want)
    flat, near, far = depth_u16(np.full((2, 3), 4.0, np.float32))  # one depth: span 1
    assert (near, far) == (4.0, 4.0) and (flat == 0).all()


def test_unexpected_error_is_json():
    """Handlers turn any exception into the JSON error shape (in-process, no GL needed)."""
    import asyncio

    from shadowmap.app.main import create_app

    app = create_app()

    @app.get("/boom")
    def boom():
        raise RuntimeError("kaboom")

    async def requests() -> list[httpx.Response]:
        # ASGITransport runs no lifespan: there is no GL thread behind this app.
        transport = httpx.ASGITransport(app=app, raise_app_exceptions=False)
        async with httpx.AsyncClient(transport=transport, base_url="http://app") as c:
            return [await c.get("/boom"), await c.post("/render"), await c.get("/version")]

    boom_resp, render_resp, version_resp = asyncio.run(requests())
    assert_error(boom_resp, 500, "internal_error")
    assert_error(render_resp, 503, "unavailable")
    assert "server-timing" in version_resp.headers


@pytest.mark.parametrize("shape,dtype", [((7, 5), np.uint8), ((7, 5, 3), np.uint8),
                                         ((7, 5, 4), np.uint8), ((6, 9), np.uint16)])
def test_png_round_trips_with_either_compressor(monkeypatch, shape, dtype):
    """The PNG writer's output decodes to the array exactly with ISA-L's deflate (the server
    extra installs it) and with zlib, its fallback when isal is not installed."""
    import io
    import sys

    from PIL import Image

    from shadowmap.renderer import png as encode  # the writer app/encode.py re-exports

    rng = np.random.default_rng(3)
    a = rng.integers(0, np.iinfo(dtype).max, size=shape, dtype=dtype, endpoint=True)
    a[0] = 0  # a run the compressor can shorten
    assert encode.PNG_DEFLATE == "isal"
    monkeypatch.setitem(sys.modules, "isal", None)  # makes `import isal` fail
    kind, fallback = encode._deflate()
    assert kind == "zlib"
    files = {"isal": encode.png_bytes(a)}
    monkeypatch.setattr(encode, "_compress", fallback)
    files["zlib"] = encode.png_bytes(a)
    assert files["isal"] != files["zlib"]  # two different encoders really ran
    for data in files.values():
        back = np.asarray(Image.open(io.BytesIO(data)))
        assert back.dtype == a.dtype or dtype == np.uint16  # Pillow reads 16-bit grey as I;16
        assert np.array_equal(back.astype(np.int64), a.astype(np.int64))

