"""FastAPI dependencies: settings, the render supervisor, and the parsed render input."""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Annotated

from fastapi import Depends, Query, Request
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import FormData, UploadFile
from starlette.requests import ClientDisconnect

from shadowmap.renderer import RenderParams
from shadowmap.renderer.demo import DEMO_PARAMS, demo_glb
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
    scene_upload,
)

FORM_PARTS = ("scene", "params")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_worker(request: Request) -> Supervisor:
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


async def read_render_input(
    request: Request,
    settings: SettingsDep,
    params: Annotated[
        str | None,
        Query(description="RenderParams as JSON, for a raw (non-multipart) scene body",
              examples=['{"width": 320, "height": 240}']),
    ] = None,
) -> RenderInput:
    """Read the body of ``POST /render`` within the limits and validate it.

    Accepted bodies: ``multipart/form-data`` with parts ``scene`` (file) and ``params`` (JSON);
    a raw scene (``model/gltf-binary``, ``model/gltf+json``, ``application/zip``,
    ``application/octet-stream``) with ``params`` in the query; ``application/json`` holding the
    params alone (renders the demo scene); or nothing (the demo scene with its own params).
    """
    t0 = time.perf_counter()
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
    texts: list[bytes] = [params.encode("utf-8")] if params is not None else []
    if media in ("multipart/form-data", "application/x-www-form-urlencoded"):
        if media != "multipart/form-data" and body[:4] in (GLB_MAGIC, *ZIP_MAGIC):
            # curl --data-binary sends files as urlencoded forms unless told otherwise
            raise ServiceError(415, "unsupported_media_type", "the body looks like a scene file: "
                               "send it with Content-Type: model/gltf-binary (or application/zip), "
                               "or as a multipart/form-data part named 'scene'")
        form = await _form(request, body, max_part=limit)
        if media == "multipart/form-data" and not form:
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
        finally:
            await form.close()
    elif media == "application/json":
        if body.strip():
            texts.append(body)
    elif media in RAW_SCENE_TYPES or (not media and body):
        if body:
            scene = (body, None, RAW_SCENE_TYPES.get(media))
    elif media or body:
        raise ServiceError(415, "unsupported_media_type", f"cannot take a {media!r} body: send "
                           "multipart/form-data, model/gltf-binary, model/gltf+json, "
                           "application/zip or application/json")

    if len(texts) > 1:
        raise ServiceError(422, "invalid_params",
                           "params given twice (in the query and in the body): give them once")
    render_params = parse_params(texts[0]) if texts else None
    if scene is None:
        upload = await run_in_threadpool(demo_upload)
        if render_params is None:
            render_params = RenderParams.model_validate(DEMO_PARAMS)
        elif render_params.camera is None:
            # The demo's own viewpoint suits it better than an automatic framing.
            camera = RenderParams.model_validate({"camera": DEMO_PARAMS["camera"]}).camera
            render_params = render_params.model_copy(update={"camera": camera})
    else:
        # Hashing and unpacking are CPU work: keep them off the event loop.
        upload = await run_in_threadpool(scene_upload, scene[0], scene[1], settings, scene[2])
        if render_params is None:
            render_params = RenderParams()
    # The limits that need no scene, before the request takes a place in the queue.
    check_request(render_params, settings.limits())
    return RenderInput(upload, render_params, t0, time.perf_counter() - t0)


RenderInputDep = Annotated[RenderInput, Depends(read_render_input)]

#: Body schemas of ``POST /render`` for the OpenAPI document (the route reads the body itself,
#: to count bytes as they arrive).
RENDER_REQUEST_BODY = {
    "required": False,
    "content": {
        "multipart/form-data": {
            "schema": {
                "type": "object",
                "properties": {
                    "scene": {"type": "string", "format": "binary",
                              "description": ".glb, .gltf with embedded buffers, or .zip holding "
                              "one .gltf/.glb and its files; omitted: the demo scene"},
                    "params": {"type": "string", "description": "RenderParams as JSON",
                               "example": json.dumps(EXAMPLE_PARAMS)},
                },
            },
        },
        "model/gltf-binary": {"schema": {"type": "string", "format": "binary"}},
        "model/gltf+json": {"schema": {"type": "string", "format": "binary"}},
        "application/zip": {"schema": {"type": "string", "format": "binary"}},
        "application/json": {
            "schema": {"$ref": "#/components/schemas/RenderParams"},
            "example": EXAMPLE_PARAMS,
        },
    },
}
