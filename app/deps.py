"""FastAPI dependencies: settings, the render supervisor, and the parsed render input."""

from __future__ import annotations

import asyncio
import importlib.util
import math
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Annotated

from fastapi import Depends, Request
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import FormData, UploadFile
from starlette.requests import ClientDisconnect

from shadowmap.renderer import LimitError, RenderParams
from shadowmap.renderer.demo import DEMO_PARAMS, demo_glb
from shadowmap.renderer.exr import exr_available
from shadowmap.renderer.limits import check_request
from shadowmap.renderer.params import EXAMPLE_PARAMS

from .errors import ServiceError
from .settings import Settings
from .supervisor import Supervisor
from .upload import (
    GLB_MAGIC,
    RAW_SCENE_TYPES,
    ZIP_MAGIC,
    SceneUpload,
    check_content_length,
    parse_params,
    read_limited,
    scene_kind,
    scene_upload,
)

FORM_PARTS = ("scene", "params")


# The dependencies are ``async def`` although they do not await: FastAPI runs a plain ``def``
# dependency in its thread pool, a thread hop per request for an attribute lookup.
async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_worker(request: Request) -> Supervisor:
    worker = getattr(request.app.state, "worker", None)
    if worker is None:
        raise ServiceError(503, "unavailable", "the renderer is not running",
                           headers={"Retry-After": "10"})
    return worker


SettingsDep = Annotated[Settings, Depends(get_settings)]
WorkerDep = Annotated[Supervisor, Depends(get_worker)]


@lru_cache(maxsize=1)
def demo_upload() -> SceneUpload:
    """The built-in demo scene as an upload (built once per process)."""
    data = demo_glb()
    return SceneUpload(data, "glb", {}, "demo.glb")


@dataclass
class RenderInput:
    """What ``POST /render`` received, validated.

    Attributes
    ----------
    upload : SceneUpload
        The scene (the demo scene when the request had none).
    params : RenderParams
    started : float
        ``time.perf_counter()`` when the request began.
    read_seconds : float
        Time spent reading and unpacking the body.
    """

    upload: SceneUpload
    params: RenderParams
    started: float
    read_seconds: float


def _media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def _form(request: Request, body: bytes, max_part: int) -> FormData:
    """Parse a form from the already-read (size-checked) body."""
    sent = False

    async def receive() -> dict:
        nonlocal sent
        if sent:
            return {"type": "http.disconnect"}
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    return await Request(request.scope, receive).form(max_files=4, max_fields=8,
                                                       max_part_size=max_part)


async def _part_bytes(value: UploadFile | str) -> bytes:
    if isinstance(value, str):
        return value.encode("utf-8")
    return await value.read()


def _empty_multipart(body: bytes, content_type: str) -> bool:
    """Whether a multipart body is well formed and holds no part: nothing, or the closing
    delimiter alone (a malformed body, e.g. with the wrong boundary, parses to no parts too)."""
    if not body.strip():
        return True
    boundary = ""
    for item in content_type.split(";")[1:]:
        key, _, value = item.strip().partition("=")
        if key.lower() == "boundary":
            boundary = value.strip().strip('"')
    return bool(boundary) and body.strip() == f"--{boundary}--".encode("latin-1", "replace")


def optional_features() -> dict[str, bool]:
    """What this installation can do beyond plain renders, for the request checks and the
    schema: the ray-traced reference (``embreex``, and ``scipy`` for its metrics: the
    ``reference`` extra) and OpenEXR output (``OpenEXR``)."""
    return {"reference": all(importlib.util.find_spec(m) is not None for m in ("embreex", "scipy")),
            "exr": exr_available()}


def default_size(settings: Settings) -> tuple[int, int]:
    """The image size of a request that gives none: the library's 640 × 480, scaled down (same
    aspect) to fit this service's ``max_image_side`` and ``max_pixels``."""
    width = RenderParams.model_fields["width"].default
    height = RenderParams.model_fields["height"].default
    scale = min(1.0, settings.max_image_side / max(width, height),
                math.sqrt(settings.max_pixels / (width * height)))
    return max(1, int(width * scale)), max(1, int(height * scale))


def with_default_size(params: RenderParams, settings: Settings) -> RenderParams:
    """``params`` with this service's default width and height where it gives none (the
    OpenAPI document shows them as the defaults)."""
    width, height = default_size(settings)
    update = {name: value for name, value in (("width", width), ("height", height))
              if name not in params.model_fields_set}
    return params.model_copy(update=update) if update else params


def check_service_limits(params: RenderParams, settings: Settings) -> None:
    """What the service refuses beyond the library's limits (the OpenAPI document states each
    as a maximum or an enumeration).

    Raises
    ------
    LimitError
        ``max_image_side``.
    ServiceError
        422 ``unavailable_feature``: ``reference`` without embreex, ``float_format: "exr"``
        without OpenEXR (the served schema then allows neither), naming the field.
    """
    for name in ("width", "height"):
        value = getattr(params, name)
        if value > settings.max_image_side:
            raise LimitError("max_image_side", f"{name} {value} is over the limit of "
                             f"{settings.max_image_side} pixels (max_image_side)")
    features = optional_features()
    if params.reference and not features["reference"]:
        raise ServiceError(422, "unavailable_feature", "reference: the ray-traced reference "
                           "needs embreex and scipy (the reference extra), which this service "
                           "does not have", field="/reference")
    if params.float_format == "exr" and not features["exr"]:
        raise ServiceError(422, "unavailable_feature", "float_format 'exr' needs the OpenEXR "
                           "package, which this service does not have", field="/float_format")


async def read_render_input(request: Request, settings: SettingsDep) -> RenderInput:
    """Read the body of ``POST /render`` within the limits and validate it.

    Accepted bodies: ``multipart/form-data`` with parts ``scene`` (file) and ``params`` (JSON);
    a raw scene (``model/gltf-binary``, ``model/gltf+json``, ``application/zip``,
    ``application/octet-stream``) with ``params`` in the query; ``application/json`` holding the
    params alone (renders the demo scene); or nothing (the demo scene with its own params).
    """
    t0 = time.perf_counter()
    query = request.query_params.getlist("params")
    if len(query) > 1:
        raise ServiceError(422, "invalid_params", "the query names params more than once",
                           field="/params")
    limit = settings.max_upload_bytes
    check_content_length(request.headers.get("content-length"), limit)
    deadline = settings.upload_timeout
    try:
        # One deadline for the whole body, not per chunk: a client trickling a byte at a time
        # would otherwise hold its connection (and the bytes so far) for ever.
        async with asyncio.timeout(deadline):
            body = await read_limited(request.stream(), limit)
    except ClientDisconnect:
        # Nobody is left to answer; a 4xx keeps it out of the error log.
        raise ServiceError(400, "client_disconnected",
                           "the client left during the upload") from None
    except TimeoutError:
        # The rest of the body may still come: close the connection rather than read it.
        raise ServiceError(408, "upload_timeout", f"the request body did not arrive within "
                           f"{deadline:g} s", limit="upload_timeout",
                           headers={"Connection": "close"}) from None
    media = _media_type(request)

    scene: tuple[bytes, str | None, str | None] | None = None  # data, filename, declared kind
    texts: list[bytes] = [query[0].encode("utf-8")] if query else []
    where = "query"
    if media in ("multipart/form-data", "application/x-www-form-urlencoded"):
        if media != "multipart/form-data" and body[:4] in (GLB_MAGIC, *ZIP_MAGIC):
            # curl --data-binary sends files as urlencoded forms unless told otherwise
            raise ServiceError(415, "unsupported_media_type", "the body looks like a scene file: "
                               "send it with Content-Type: model/gltf-binary (or application/zip), "
                               "or as a multipart/form-data part named 'scene'")
        form = await _form(request, body, max_part=limit)
        if (media == "multipart/form-data" and not form
                and not _empty_multipart(body, request.headers.get("content-type", ""))):
            raise ServiceError(400, "bad_request", "the multipart body holds no parts (is it "
                               "malformed, or its boundary wrong?)")
        try:
            seen = set()
            for name, value in form.multi_items():
                if name not in FORM_PARTS:
                    raise ServiceError(422, "invalid_request", f"unexpected form part {name!r}: "
                                       "the parts are 'scene' (a file) and 'params' (JSON)")
                if name in seen:
                    raise ServiceError(422, "invalid_request",
                                       f"the form part {name!r} is repeated")
                seen.add(name)
                data = await _part_bytes(value)
                if name == "scene":
                    filename = value.filename if isinstance(value, UploadFile) else None
                    scene = (data, filename, None)
                else:
                    texts.append(data)
                    where = "form part"
        finally:
            await form.close()
    elif media == "application/json":
        # An empty body is no body (the params are optional); anything else must be JSON,
        # whitespace alone included (no JSON text is empty).
        if body:
            texts.append(body)
            where = "body"
    elif media in RAW_SCENE_TYPES or (not media and body):
        if body:
            scene = (body, None, RAW_SCENE_TYPES.get(media))
    elif media or body:
        raise ServiceError(415, "unsupported_media_type", f"cannot take a {media!r} body: send "
                           "multipart/form-data, model/gltf-binary, model/gltf+json, "
                           "application/zip or application/json")

    if len(texts) > 1:
        # One place per content type; the query is the raw scene body's (multipart has its
        # params part, a JSON body is the params).
        raise ServiceError(422, "invalid_params", f"params given twice (in the query and in "
                           f"the {where}): the query is for raw scene bodies only",
                           field="/params")
    render_params = parse_params(texts[0]) if texts else None
    if scene is None:
        upload = await run_in_threadpool(demo_upload)
        if render_params is None:
            # Its size is the service's default size (below), like any request without one.
            render_params = RenderParams.model_validate(
                {k: v for k, v in DEMO_PARAMS.items() if k not in ("width", "height")})
        elif render_params.camera is None:
            # The demo's own viewpoint suits it better than an automatic framing.
            camera = RenderParams.model_validate({"camera": DEMO_PARAMS["camera"]}).camera
            render_params = render_params.model_copy(update={"camera": camera})
    else:
        if scene_kind(*scene) == "zip":
            # Unpacking is CPU work: kept off the event loop.
            upload = await run_in_threadpool(scene_upload, scene[0], scene[1], settings,
                                             scene[2])
        else:  # a .glb or .gltf is only classified here (the worker hashes and parses it)
            upload = scene_upload(scene[0], scene[1], settings, scene[2])
        if render_params is None:
            render_params = RenderParams()
    render_params = with_default_size(render_params, settings)
    # The limits that need no scene, before the request takes a place in the queue.
    check_service_limits(render_params, settings)
    check_request(render_params, settings.limits())
    return RenderInput(upload, render_params, t0, time.perf_counter() - t0)


RenderInputDep = Annotated[RenderInput, Depends(read_render_input)]

_PARAMS_REF = {"$ref": "#/components/schemas/RenderParams"}
_SCENE_FILE = {"type": "string", "format": "binary"}
#: Media types a scene part may declare (the file name or the first bytes decide, see
#: :func:`shadowmap.app.upload.scene_upload`).
SCENE_PART_TYPES = "model/gltf-binary, model/gltf+json, application/zip, application/octet-stream"

#: Body schemas of ``POST /render`` for the OpenAPI document (the route reads the body itself,
#: to count bytes as they arrive). One place for the params per content type: the ``params``
#: part of a form, the query of a raw scene body, the body itself when it is JSON.
RENDER_REQUEST_BODY = {
    "required": False,
    "description": "Omitted (or an empty form): the built-in demo scene (`GET /demo.glb`) with "
    "its own params. A JSON body: the params, for the demo scene.",
    "content": {
        "multipart/form-data": {
            "schema": {
                "type": "object",
                "additionalProperties": False,
                "properties": {
                    "scene": {**_SCENE_FILE,
                              "description": ".glb, .gltf with embedded buffers, or .zip holding "
                              "one .gltf/.glb and its files (a glTF 2.0 scene: the kind is read "
                              "from the file name's suffix, else the first bytes); omitted: the "
                              "demo scene"},
                    "params": {**_PARAMS_REF,
                               "description": "the request, a JSON object (this part's "
                               "Content-Type is application/json); omitted: the defaults, or "
                               "the demo scene's own params without a scene"},
                },
            },
            "encoding": {
                "params": {"contentType": "application/json"},
                "scene": {"contentType": SCENE_PART_TYPES},
            },
        },
        "model/gltf-binary": {"schema": {**_SCENE_FILE, "description": "a .glb file"}},
        "model/gltf+json": {"schema": {**_SCENE_FILE,
                                       "description": "a .gltf file with embedded buffers"}},
        "application/zip": {"schema": {**_SCENE_FILE, "description": "a .zip holding one "
                                       ".gltf/.glb and the files it refers to"}},
        "application/json": {"schema": _PARAMS_REF, "example": EXAMPLE_PARAMS},
    },
}

#: The query of ``POST /render``.
RENDER_PARAMETERS = [
    {
        "name": "params",
        "in": "query",
        "required": False,
        "description": "The request as JSON, for a raw scene body (model/gltf-binary, "
        "model/gltf+json, application/zip). Not with a multipart or JSON body, which carry "
        "their own params (422 `invalid_params`, field `/params`).",
        "content": {"application/json": {"schema": _PARAMS_REF,
                                         "example": {"width": 320, "height": 240}}},
    },
]
