"""``POST /render``: validate, queue to the render worker, answer with what it encoded."""

from __future__ import annotations

import re
import time
from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi.responses import Response

from ..deps import RENDER_REQUEST_BODY, RenderInputDep, WorkerDep
from ..encode import (
    FORMATS,
    MEDIA_PNG,
    WARNING_ITEM_MAX,
    WARNINGS_HEADER_MAX,
    RenderJSON,
    choose_format,
)
from ..errors import ErrorBody, ServiceError

_BINARY = {"schema": {"type": "string", "format": "binary"}}

RESPONSES: dict = {
    200: {
        "description": "The render. `image/png` (default): the colour image. `multipart/mixed`: "
        "one PNG part per output (`color`, `light_depth_<i>`, `visibility_<i>` as 16-bit "
        "round(v*65535) with no geometry = 0, `depth` as 16-bit normalised over the image's "
        "depth range with no geometry = 65535), named in Content-Disposition. "
        "`application/json`: the same PNGs base64-encoded plus timings, plan, GL info, "
        "warnings and metrics. Every response has `Server-Timing`, `X-Render-Plan` and "
        "`X-Render-Warnings` (compact JSON).",
        "content": {
            "image/png": _BINARY,
            "multipart/mixed": _BINARY,
            "application/json": {"schema": {"$ref": "#/components/schemas/RenderJSON"}},
        },
        "headers": {
            "Server-Timing": {"description": "read, queue, parse, upload, plan, light, camera, "
                              "readback, encode, total (ms)", "schema": {"type": "string"}},
            "X-Render-Plan": {"description": "what ran and what was left out (JSON)",
                              "schema": {"type": "string"}},
            "X-Render-Warnings": {
                "description": "what the render had to drop or approximate: a compact JSON list "
                "of sentences, ASCII only (other characters as JSON \\u escapes), `[]` when "
                f"none. At most {WARNINGS_HEADER_MAX} characters: warnings that do not fit are "
                f"counted in a last item `\"... and N more\"`, and one over {WARNING_ITEM_MAX} "
                "characters is cut to end in `...`; the JSON response's `warnings` field has "
                "them all in full",
                "schema": {"type": "string"},
                "example": '["light 0 of the file: outer cone angle 90 degrees clamped to 89.5"]',
            },
        },
    },
    400: {"model": ErrorBody, "description": "invalid or unsafe scene file, bad zip"},
    408: {"model": ErrorBody, "description": "the body did not arrive within `upload_timeout` "
          "(the connection is closed)"},
    406: {"model": ErrorBody, "description": "no acceptable response format"},
    413: {"model": ErrorBody, "description": "upload (or unpacked zip) over the limit"},
    415: {"model": ErrorBody, "description": "unsupported request body type"},
    422: {"model": ErrorBody, "description": "params invalid or impossible, over a limit, or a "
          "scene that needs a glTF extension (`unsupported_extension`, listed in `extensions`) or "
          "version (`unsupported_version`, `field`) this renderer does not implement"},
    500: {"model": ErrorBody, "description": "OpenGL failure"},
    503: {"model": ErrorBody, "description": "not queued: `queue_full` (the expected wait is over "
          "`max_expected_wait`, or `queue_size` renders wait), `render_timeout` (the time ran out "
          "in the queue), `worker_restarted` (the worker died during this render), `unavailable` "
          "or `shutting_down`; always with Retry-After"},
    504: {"model": ErrorBody, "description": "the render ran past `render_timeout` and was stopped "
          "(its worker process is replaced)"},
}

_TOTAL = re.compile(r"(^|, )total;dur=[0-9.]+$")

router = APIRouter(tags=["render"])


@router.post(
    "/render",
    summary="Render a glTF scene with shadow maps",
    response_class=Response,
    responses=RESPONSES,
    openapi_extra={"requestBody": RENDER_REQUEST_BODY},
)
async def render(
    request: Request,
    inp: RenderInputDep,
    worker: WorkerDep,
    accept: Annotated[str | None, Header(description="image/png, multipart/mixed or "
                                         "application/json")] = None,
) -> Response:
    """Render the uploaded scene (or the built-in demo scene when there is none).

    Send the scene as the `scene` part of a `multipart/form-data` body with the request as JSON
    in the `params` part, or as a raw `model/gltf-binary` body with `params` in the query.
    """
    outputs = inp.params.outputs
    media = choose_format(accept, outputs)
    if media is None:
        raise ServiceError(406, "not_acceptable", f"cannot answer {accept!r}: the formats are "
                           + ", ".join(FORMATS))
    if media == MEDIA_PNG and "color" not in outputs:
        raise ServiceError(406, "not_acceptable", "an image/png response is the color output, "
                           "which params.outputs leaves out: add it, or accept multipart/mixed "
                           "or application/json")
    params = inp.params
    if media == MEDIA_PNG and outputs != ["color"]:
        # The PNG response holds only the colour image: skip rendering and reading back the rest.
        params = params.model_copy(update={"outputs": ["color"]})
    # The worker process renders and encodes: the images never enter this process.
    reply = await worker.render(inp.upload, params, media, outputs, inp.read_seconds,
                                inp.started, disconnected=request.is_disconnected)
    headers = dict(reply.headers)
    timing = headers.get("server-timing")
    if timing is not None:
        # The worker's total ends before its answer crossed the pipe; this one is the request's.
        total = f"total;dur={(time.perf_counter() - inp.started) * 1000.0:.2f}"
        headers["server-timing"] = _TOTAL.sub(lambda m: m.group(1) + total, timing)
    return Response(reply.body, media_type=reply.media_type, headers=headers)


# Referenced from the 200 response above; registered in the OpenAPI components by main.py.
RESPONSE_MODELS = (RenderJSON,)
