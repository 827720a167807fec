"""Error responses: every failure leaves the service as JSON ``{"error": ..., "detail": ...}``.

The library's exceptions are mapped here, in one place, so routes never build error responses:

===========================  ======  ===========================================
exception                    status  ``error``
===========================  ======  ===========================================
:class:`ServiceError`        varies  set by the raiser (e.g. ``queue_full``)
``UnsupportedExtension``     422     ``unsupported_extension`` (plus ``extensions``)
``UnsupportedVersion``       422     ``unsupported_version`` (plus ``field``)
``SceneError`` (any other)   400     ``invalid_scene``
``RequestError``             422     ``invalid_request`` (plus ``errors``)
``LimitError``               422     ``limit_exceeded`` (plus ``limit``)
pydantic ``ValidationError`` 422     ``invalid_params`` (plus ``errors``)
``ReferenceUnavailable``     501     ``reference_unavailable``
``RenderError``              500     ``render_failed`` (logged)
anything else                500     ``internal_error`` (logged)
===========================  ======  ===========================================
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from shadowmap.renderer import (
    LimitError,
    ReferenceUnavailable,
    RenderError,
    RequestError,
    SceneError,
    ShadowMapError,
    UnsupportedExtension,
    UnsupportedVersion,
)

log = logging.getLogger("shadowmap.app")


class ErrorBody(BaseModel):
    """The body of every error response."""

    error: str
    detail: str
    limit: str | None = None
    errors: list[dict[str, Any]] | None = None
    extensions: list[str] | None = None
    field: str | None = None


class ServiceError(Exception):
    """An error the service raises itself, with its HTTP status.

    Parameters
    ----------
    status : int
    error : str
        Short machine-readable code, e.g. ``"payload_too_large"``.
    detail : str
        Human-readable explanation.
    limit : str, optional
        Name of the exceeded setting, for limit errors.
    headers : dict, optional
        Extra response headers, e.g. ``Retry-After``.
    """

    def __init__(self, status: int, error: str, detail: str, *, limit: str | None = None,
                 headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.error = error
        self.detail = detail
        self.limit = limit
        self.headers = headers or {}


def error_response(status: int, error: str, detail: str, *, limit: str | None = None,
                   errors: list[dict] | None = None,
                   headers: dict[str, str] | None = None,
                   **extra: Any) -> JSONResponse:
    """A JSON error response with the common shape; ``extra`` adds fields of :class:`ErrorBody`."""
    body: dict[str, Any] = {"error": error, "detail": detail}
    if limit is not None:
        body["limit"] = limit
    if errors is not None:
        body["errors"] = errors
    body.update(extra)
    return JSONResponse(body, status_code=status, headers=headers)


def _validation_errors(exc: ValidationError | RequestValidationError) -> list[dict]:
    """Pydantic's error list without inputs or contexts (they may hold non-JSON values)."""
    out = []
    for e in exc.errors():
        out.append({"loc": [str(p) for p in e.get("loc", ())], "msg": str(e.get("msg", "")),
                    "type": str(e.get("type", ""))})
    return out


def _summary(errors: list[dict]) -> str:
    parts = [f"{'.'.join(e['loc']) or 'params'}: {e['msg']}" for e in errors[:5]]
    more = f" (and {len(errors) - 5} more)" if len(errors) > 5 else ""
    return "; ".join(parts) + more


def _slug(phrase: str) -> str:
    return "_".join(phrase.lower().replace("-", " ").split()) or "error"


def install_handlers(app: FastAPI) -> None:
    """Register the exception handlers that give every error the JSON shape above."""

    @app.exception_handler(ServiceError)
    async def _service(request: Request, exc: ServiceError) -> JSONResponse:
        return error_response(exc.status, exc.error, exc.detail, limit=exc.limit,
                              headers=exc.headers)

    # Registered before SceneError: Starlette picks the handler of the closest class in the MRO.
    @app.exception_handler(UnsupportedExtension)
    async def _extension(request: Request, exc: UnsupportedExtension) -> JSONResponse:
        return error_response(422, "unsupported_extension", str(exc), extensions=exc.extensions)

    @app.exception_handler(UnsupportedVersion)
    async def _version(request: Request, exc: UnsupportedVersion) -> JSONResponse:
        return error_response(422, "unsupported_version", str(exc), field=exc.field)

    @app.exception_handler(SceneError)
    async def _scene(request: Request, exc: SceneError) -> JSONResponse:
        return error_response(400, "invalid_scene", str(exc))

    @app.exception_handler(RequestError)
    async def _request(request: Request, exc: RequestError) -> JSONResponse:
        # Params that did not validate in the library keep pydantic's list of errors.
        return error_response(422, "invalid_request", str(exc), errors=exc.errors or None)

    @app.exception_handler(LimitError)
    async def _limit(request: Request, exc: LimitError) -> JSONResponse:
        return error_response(422, "limit_exceeded", str(exc), limit=exc.limit)

    @app.exception_handler(ReferenceUnavailable)
    async def _reference(request: Request, exc: ReferenceUnavailable) -> JSONResponse:
        return error_response(501, "reference_unavailable", str(exc))

    @app.exception_handler(RenderError)
    async def _render(request: Request, exc: RenderError) -> JSONResponse:
        log.error("render failed: %s", exc, exc_info=exc)
        return error_response(500, "render_failed", str(exc))

    @app.exception_handler(ShadowMapError)
    async def _library(request: Request, exc: ShadowMapError) -> JSONResponse:
        log.error("renderer error: %s", exc, exc_info=exc)
        return error_response(500, "render_failed", str(exc))

    @app.exception_handler(ValidationError)
    async def _params(request: Request, exc: ValidationError) -> JSONResponse:
        errors = _validation_errors(exc)
        return error_response(422, "invalid_params", _summary(errors), errors=errors)

    @app.exception_handler(RequestValidationError)
    async def _fastapi_validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _validation_errors(exc)
        return error_response(422, "invalid_request", _summary(errors), errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        from http import HTTPStatus

        try:
            phrase = HTTPStatus(exc.status_code).phrase
        except ValueError:
            phrase = "error"
        return error_response(exc.status_code, _slug(phrase), str(exc.detail),
                              headers=getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        # Runs in Starlette's outermost middleware, which re-raises afterwards so the server
        # logs the traceback; the client still gets JSON.
        log.error("unexpected error on %s %s", request.method, request.url.path, exc_info=exc)
        return error_response(500, "internal_error",
                              f"unexpected {type(exc).__name__}; see the server log")
