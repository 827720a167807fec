"""Error responses: every failure leaves the service as JSON ``{"error": ..., "detail": ...}``.

The library's exceptions carry their own code and fields (``renderer/errors.py``); the statuses are
given here, in one place, so routes never build error responses:

===========================  ======  ===========================================
exception                    status  ``error``
===========================  ======  ===========================================
:class:`ServiceError`        varies  set by the raiser (e.g. ``queue_full``)
``UnsupportedExtension``     422     ``unsupported_extension`` (plus ``extensions``)
``UnsupportedVersion``       422     ``unsupported_version`` (plus ``field``)
``SceneError`` (any other)   400     ``invalid_scene``
``RequestError``             422     ``invalid_request`` (plus ``errors``)
``LimitError``               422     ``limit_exceeded`` (plus ``limit``)
pydantic ``ValidationError`` 422     ``invalid_params`` (plus ``errors``, each with its JSON
                                     ``pointer``, and ``field``: the first pointer)
``ReferenceUnavailable``     501     ``reference_unavailable``
``ExrUnavailable``           422     ``unavailable_feature`` (plus ``field``)
``FileFormatError``          400     ``invalid_file`` (``read_exr``'s; no route reads a file)
``RenderError``              500     ``render_failed`` (logged)
anything else                500     ``internal_error`` (logged)
===========================  ======  ===========================================
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from shadowmap.renderer import RequestError, ShadowMapError

log = logging.getLogger("shadowmap.app")

#: HTTP status of each library error code (:attr:`ShadowMapError.code`); a code not listed
#: (``render_failed``) is 500.
STATUS = {
    "unsupported_extension": 422,
    "unsupported_version": 422,
    "invalid_scene": 400,
    "invalid_file": 400,  # a library reader's (read_exr): the service reads no such file
    "invalid_request": 422,
    "limit_exceeded": 422,
    "reference_unavailable": 501,
    "unavailable_feature": 422,
}


class FieldError(BaseModel):
    """One reason a request did not validate."""

    loc: list[str] = Field(description="where, as path items (names and list indices)",
                           examples=[["camera", "zfar"]])
    pointer: str = Field(description="where, as a JSON pointer (RFC 6901) into the params",
                         examples=["/camera/zfar"])
    msg: str = Field(description="what is wrong", examples=["zfar must be greater than znear"])
    type: str = Field(description="pydantic's error type; 'cross_field' for a rule between "
                      "fields that the schema states only in words", examples=["cross_field"])


class ErrorBody(BaseModel):
    """The body of every error response."""

    error: str = Field(description="machine-readable code, e.g. invalid_params, "
                       "limit_exceeded, queue_full", examples=["invalid_params"])
    detail: str = Field(description="what went wrong, in words",
                        examples=["camera.zfar: zfar must be greater than znear"])
    limit: str | None = Field(default=None, description="the setting that was exceeded "
                              "(limit_exceeded, payload_too_large)", examples=["max_pixels"])
    errors: list[FieldError] | None = Field(default=None, description="every validation error "
                                            "(invalid_params, invalid_request)")
    extensions: list[str] | None = Field(default=None, description="glTF extensions the scene "
                                         "requires and this renderer does not implement")
    field: str | None = Field(default=None, description="the field at fault: a JSON pointer "
                              "into the params (the first of errors), or the glTF field "
                              "(unsupported_version)", examples=["/camera/zfar"])


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
    field : str, optional
        The field at fault, as a JSON pointer into the params (e.g. ``"/reference"``).
    """

    def __init__(self, status: int, error: str, detail: str, *, limit: str | None = None,
                 headers: dict[str, str] | None = None, field: str | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.error = error
        self.detail = detail
        self.limit = limit
        self.headers = headers or {}
        self.field = field


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


#: Tags of the light union: pydantic puts the chosen one in an error's location, after the
#: light's index; the request has no such level.
_UNION_TAGS = frozenset({"directional", "spot", "point"})


def _field_path(loc: tuple[Any, ...]) -> list[str]:
    path: list[str] = []
    for i, item in enumerate(loc):
        if (item in _UNION_TAGS and i >= 2 and isinstance(loc[i - 1], int)
                and loc[i - 2] == "lights"):
            continue
        path.append(str(item))
    return path


def json_pointer(path: Sequence[str]) -> str:
    """RFC 6901 pointer of a path (``~`` and ``/`` escaped); ``""`` is the whole document."""
    return "".join("/" + p.replace("~", "~0").replace("/", "~1") for p in path)


def validation_errors(exc: ValidationError | RequestValidationError) -> list[dict]:
    """Pydantic's error list without inputs or contexts (they may hold non-JSON values), each
    with its JSON pointer into the params."""
    out = []
    for e in exc.errors():
        path = _field_path(tuple(e.get("loc", ())))
        out.append({"loc": path, "pointer": json_pointer(path), "msg": str(e.get("msg", "")),
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
        if exc.field is not None:
            return error_response(exc.status, exc.error, exc.detail, limit=exc.limit,
                                  headers=exc.headers, field=exc.field)
        return error_response(exc.status, exc.error, exc.detail, limit=exc.limit,
                              headers=exc.headers)

    @app.exception_handler(ShadowMapError)
    async def _library(request: Request, exc: ShadowMapError) -> JSONResponse:
        # The code and its fields come from the exception class (renderer/errors.py); only the
        # status is decided here.
        status = STATUS.get(exc.code, 500)
        extra = exc.fields()
        if isinstance(exc, RequestError):
            # Params that did not validate in the library keep pydantic's list of errors.
            errors = [{"loc": [str(p) for p in e.get("loc", [])],  # type: ignore[attr-defined]
                       "msg": str(e.get("msg", "")), "type": str(e.get("type", ""))}
                      for e in exc.errors]
            for e in errors:
                e["pointer"] = json_pointer(e["loc"])
            extra["errors"] = errors or None
        if status >= 500:
            log.error("render failed: %s", exc, exc_info=exc)
        return error_response(status, exc.code, str(exc), **extra)

    @app.exception_handler(ValidationError)
    async def _params(request: Request, exc: ValidationError) -> JSONResponse:
        errors = validation_errors(exc)
        return error_response(422, "invalid_params", _summary(errors), errors=errors,
                              field=errors[0]["pointer"] if errors else None)

    @app.exception_handler(RequestValidationError)
    async def _fastapi_validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = validation_errors(exc)
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
