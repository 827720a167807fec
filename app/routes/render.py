"""``POST /render``: validate, queue to the render worker, answer with what it encoded."""

from __future__ import annotations

import re
import time

from fastapi import APIRouter, Request
from fastapi.responses import Response

from ..deps import RENDER_PARAMETERS, RENDER_REQUEST_BODY, RenderInputDep, WorkerDep
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
_STRING = {"type": "string"}

#: ``Server-Timing`` comes with every response (the middleware adds ``total`` where the route
#: gives no breakdown).
SERVER_TIMING = {
    "Server-Timing": {"description": "milliseconds per stage: read, queue, parse, upload, plan, "
                      "light, camera, readback, reference, encode, pipe (the task and its "
                      "answer between the server's processes), hop (the answer's way to the "
                      "event loop), total (errors: total only)",
                      "required": True, "schema": _STRING,
                      "example": "read;dur=0.40, queue;dur=0.02, total;dur=41.70"},
}
RETRY_AFTER = {
    "Retry-After": {"description": "seconds after which a retry may be served",
                    "required": True, "schema": {"type": "string", "pattern": "^[0-9]+$"},
                    "example": "10"},
}


def error(description: str, headers: dict | None = None) -> dict:
    """An error response of the OpenAPI document: JSON ``ErrorBody``, with its headers."""
    return {"model": ErrorBody, "description": description,
            "headers": {**SERVER_TIMING, **(headers or {})}}


RESPONSES: dict = {
    200: {
        "description": "The render. `image/png` (default when `color` is among the outputs, "
        "else `multipart/mixed`): the colour image. `multipart/mixed`: one part per output "
        "(`color`, `light_depth_<i>`, `visibility_<i>` as 16-bit round(v*65535) with no "
        "geometry = 0, `depth` as 16-bit normalised over the image's depth range with no "
        "geometry = 65535; with `float_format: \"exr\"` depth and visibility as OpenEXR), "
        "named in Content-Disposition. `application/json`: the same files base64-encoded plus "
        "timings, plan, GL info, warnings and metrics. Chosen by `Accept`.",
        "content": {
            "image/png": _BINARY,
            "multipart/mixed": _BINARY,
            "application/json": {"schema": {"$ref": "#/components/schemas/RenderJSON"}},
        },
        "headers": {
            **SERVER_TIMING,
            "X-Render-Plan": {"description": "what ran and what was left out (compact JSON)",
                              "required": True, "schema": _STRING},
            "X-Render-Warnings": {
                "description": "what the render had to drop or approximate: a compact JSON list "
                "of sentences, ASCII only (other characters as JSON \\u escapes), `[]` when "
                f"none. At most {WARNINGS_HEADER_MAX} characters: warnings that do not fit are "
                f"counted in a last item `\"... and N more\"`, and one over {WARNING_ITEM_MAX} "
                "characters is cut to end in `...`; the JSON response's `warnings` field has "
                "them all in full",
                "required": True,
                "schema": _STRING,
                "example": '["light 0 of the file: outer cone angle 90 degrees clamped to 89.5"]',
            },
        },
    },
    400: error("`invalid_scene`: the scene is not a glTF 2.0 file this renderer can read, or "
               "is unsafe (a URI outside the upload), or a bad zip; `bad_request`: a malformed "
               "multipart body or Content-Length; `client_disconnected`"),
    406: error("`not_acceptable`: `Accept` names none of image/png, multipart/mixed, "
               "application/json (or a range holding one), or asks for image/png while "
               "`outputs` leaves out `color`"),
    408: error("`upload_timeout`: the body did not arrive within `upload_timeout` seconds",
               {"Connection": {"description": "close: the rest of the body is not read",
                               "required": True, "schema": {"type": "string", "enum": ["close"]}}}),
    413: error("`payload_too_large`: the body (`max_upload_bytes`), the params "
               "(`max_params_bytes`), or an unpacked zip (`max_unzipped_bytes`, "
               "`max_zip_entries`) over the limit named in `limit`"),
    415: error("`unsupported_media_type`: a body that is not multipart/form-data, "
               "model/gltf-binary, model/gltf+json, application/zip or application/json"),
    422: error("`invalid_params`: params that do not validate (`errors`, and `field` the JSON "
               "pointer of the first, e.g. `/camera/zfar`: the rules between fields are written "
               "in the schema's descriptions), or params both in the query and the body; "
               "`invalid_request`: impossible with this scene (a directional light at the "
               "scene's centre) or a form part other than scene and params; `limit_exceeded`: "
               "a setting named in `limit` (max_pixels, max_image_side, max_map_size, "
               "max_lights, max_triangles, max_request_bytes, ...); `unavailable_feature`: "
               "`reference` or `float_format: exr` where this service cannot (the schema's "
               "enumerations then leave them out); `unsupported_extension` (listed in "
               "`extensions`) or `unsupported_version` (`field`) of the glTF file"),
    500: error("`render_failed`: an OpenGL failure (logged)"),
    503: error("not rendered, retry later: `queue_full` (the expected wait is over "
               "`max_expected_wait`, or `queue_size` renders wait), `render_timeout` (the time "
               "ran out in the queue), `worker_restarted` (the worker died during this render), "
               "`unavailable` or `shutting_down`", RETRY_AFTER),
    504: error("`render_timeout`: the render ran past `render_timeout` and was stopped (its "
               "worker process is replaced)"),
}

_TOTAL = re.compile(r"(^|, )total;dur=[0-9.]+$")

router = APIRouter(tags=["render"])


@router.post(
    "/render",
    summary="Render a glTF scene with shadow maps",
    operation_id="render",
    response_class=Response,
    responses=RESPONSES,
    openapi_extra={"requestBody": RENDER_REQUEST_BODY, "parameters": RENDER_PARAMETERS},
)
async def render(request: Request, inp: RenderInputDep, worker: WorkerDep) -> Response:
    """Render the uploaded scene (or the built-in demo scene when there is none).

    Send the scene as the `scene` part of a `multipart/form-data` body with the request as JSON
    in the `params` part, or as a raw `model/gltf-binary` body with `params` in the query. The
    response's media type follows `Accept` (the 200 response's content types).
    """
    # Accept is read here, not declared as a parameter: OpenAPI describes it by the response
    # media types (an `Accept` header parameter is ignored by the specification).
    accept = request.headers.get("accept")
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
        # The worker's total ends before its answer crossed the pipe; this one is the request's,
        # after the two stages the worker cannot see: `pipe`, the task and the answer between
        # the processes, and `hop`, the answer's way from the supervisor's thread to this
        # coroutine on the event loop.
        now = time.perf_counter()
        total = f"total;dur={(now - inp.started) * 1000.0:.2f}"
        if reply.answered:
            total = (f"pipe;dur={reply.pipe * 1000.0:.2f}, "
                     f"hop;dur={(now - reply.answered) * 1000.0:.2f}, " + total)
        headers["server-timing"] = _TOTAL.sub(lambda m: m.group(1) + total, timing)
    return Response(reply.body, media_type=reply.media_type, headers=headers)


# Referenced from the 200 response above; registered in the OpenAPI components by main.py.
RESPONSE_MODELS = (RenderJSON,)
