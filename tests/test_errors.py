"""One name per failure: the library's error classes carry their code, and the HTTP service and
a batch report that same code with the same fields."""

from __future__ import annotations

import asyncio
import json

import pytest
from fastapi import FastAPI, Request

from shadowmap.app.errors import STATUS, install_handlers
from shadowmap.batch.errors import error_of
from shadowmap.renderer.errors import (
    ExrUnavailable,
    LimitError,
    ReferenceUnavailable,
    RenderError,
    RequestError,
    SceneError,
    ShaderError,
    ShadowMapError,
    UnsupportedExtension,
    UnsupportedVersion,
)

CASES = [
    (SceneError("truncated GLB"), 400, {}),
    (UnsupportedExtension(["EXT_x", "KHR_y"]), 422, {"extensions": ["EXT_x", "KHR_y"]}),
    (UnsupportedVersion("asset.version", "glTF 1.0"), 422, {"field": "asset.version"}),
    (RequestError("spot light without a direction"), 422, {}),
    (LimitError("max_triangles", "too many triangles"), 422, {"limit": "max_triangles"}),
    (ReferenceUnavailable("no embreex"), 501, {}),
    (ExrUnavailable("no OpenEXR"), 422, {"field": "/float_format"}),
    (RenderError("incomplete framebuffer"), 500, {}),
    (ShaderError("camera_pass.frag:3: syntax error"), 500, {}),
    (ShadowMapError("anything else"), 500, {}),
]


def _service_answer(exc: Exception) -> tuple[int, dict]:
    """What the service's handlers answer when a route raises ``exc``."""
    app = FastAPI()
    install_handlers(app)
    handler = app.exception_handlers[ShadowMapError]
    scope = {"type": "http", "method": "POST", "path": "/render", "headers": [],
             "query_string": b""}
    response = asyncio.run(handler(Request(scope), exc))
    return response.status_code, json.loads(response.body)


@pytest.mark.parametrize(("exc", "status", "fields"), CASES,
                         ids=[type(c[0]).__name__ for c in CASES])
def test_the_service_and_a_batch_name_an_error_alike(exc, status, fields):
    got_status, body = _service_answer(exc)
    job = error_of(exc).to_dict()
    assert got_status == status == STATUS.get(exc.code, 500)
    assert body["error"] == job["error"] == exc.code
    assert body["detail"] == job["detail"] == str(exc)
    for name, value in fields.items():
        assert body[name] == job[name] == value


def test_params_errors_keep_their_locations_in_both():
    exc = RequestError("1 error", [{"loc": ["camera", "zfar"], "msg": "too small",
                                    "type": "cross_field"}])
    _, body = _service_answer(exc)
    assert body["errors"][0]["pointer"] == "/camera/zfar"
    assert error_of(exc).to_dict()["errors"][0]["loc"] == ["camera", "zfar"]


def test_every_code_of_a_library_error_has_its_status():
    codes = {cls.code for cls in _subclasses(ShadowMapError)}
    assert codes - set(STATUS) == {"render_failed"}


def _subclasses(cls: type) -> set[type]:
    out = {cls}
    for sub in cls.__subclasses__():
        out |= _subclasses(sub)
    return out
