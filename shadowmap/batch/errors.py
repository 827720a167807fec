"""A failed job as data: the error code and detail that ``results.jsonl`` records.

The codes are the library's (:attr:`ShadowMapError.code`, which the HTTP service answers with too:
``invalid_scene``, ``limit_exceeded``, ...), so a job fails in a batch with the same name it would
fail with over HTTP, plus the batch's own:
``invalid_job`` (a manifest line that is not a job), ``worker_died`` (its worker process or
actor died twice) and ``timeout`` (it ran past the batch's time limit twice).
"""

from __future__ import annotations

from typing import Any

from shadowmap.renderer.errors import ShadowMapError

__all__ = ["JobError", "error_of"]


class JobError(Exception):
    """Why a job has no outputs.

    Parameters
    ----------
    code : str
        Machine-readable, e.g. ``limit_exceeded``.
    detail : str
        One sentence.
    **extra
        Fields recorded beside them (``limit``, ``errors``, ``extensions``, ``field``).
    """

    def __init__(self, code: str, detail: str, **extra: Any) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail
        self.extra = {k: v for k, v in extra.items() if v is not None}

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild, (self.code, self.detail, self.extra))

    def to_dict(self) -> dict[str, Any]:
        return {"error": self.code, "detail": self.detail, **self.extra}


def _rebuild(code: str, detail: str, extra: dict[str, Any]) -> JobError:
    return JobError(code, detail, **extra)


def error_of(exc: BaseException) -> JobError:
    """The record of a library error, with the HTTP service's codes."""
    if isinstance(exc, JobError):
        return exc
    text = " ".join(str(exc).splitlines()) or type(exc).__name__
    if isinstance(exc, ShadowMapError):
        return JobError(exc.code, text, **exc.fields())
    return JobError("internal_error", f"{type(exc).__name__}: {text}")
