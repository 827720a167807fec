"""The library's exception family.

Every error the library raises on purpose derives from :class:`ShadowMapError`. Each class names
its machine-readable :attr:`~ShadowMapError.code` and the fields that go with it
(:meth:`~ShadowMapError.fields`): the one place those are decided. The HTTP layer gives each code
its status and a batch records the same code for a failed job; the library itself knows nothing
of HTTP.
"""

from __future__ import annotations

from typing import Any


class ShadowMapError(Exception):
    """Base class of every error raised on purpose by :mod:`renderer`.

    Attributes
    ----------
    code : str
        Machine-readable name of the failure (a class attribute), e.g. ``"invalid_scene"``.
    """

    code = "render_failed"

    def fields(self) -> dict[str, Any]:
        """What a report of this error carries besides its code and message (``limit``,
        ``extensions``, ``field``, ``errors``); empty by default."""
        return {}


class SceneError(ShadowMapError):
    """The scene cannot be used: corrupt or truncated glTF, unsafe URI, no geometry, ..."""

    code = "invalid_scene"


class UnsupportedExtension(SceneError):
    """The file requires glTF extensions (``extensionsRequired``) this loader does not implement.

    Attributes
    ----------
    extensions : list of str
        The required extension names that are not supported, in the file's order.
    """

    code = "unsupported_extension"

    def __init__(self, extensions: list[str], message: str | None = None) -> None:
        self.extensions = list(extensions)
        super().__init__(message or (
            "the file requires glTF extensions this renderer does not support: "
            + ", ".join(self.extensions)))

    def __reduce__(self) -> tuple[type, tuple[list[str], str]]:
        # Pickled with its attributes (an error sent back from a worker process).
        return type(self), (self.extensions, str(self))

    def fields(self) -> dict[str, Any]:
        return {"extensions": self.extensions}


class UnsupportedVersion(SceneError):
    """The file is well-formed glTF of a version this loader does not read.

    Attributes
    ----------
    field : str
        ``"asset.version"`` (major version not 2) or ``"asset.minVersion"`` (newer than 2.0).
    """

    code = "unsupported_version"

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.field, str(self))

    def fields(self) -> dict[str, Any]:
        return {"field": self.field}


class RequestError(ShadowMapError, ValueError):
    """The request is invalid (params that do not validate) or impossible (e.g. a spot light
    with no direction).

    Attributes
    ----------
    errors : list of dict
        For params that do not validate: pydantic's errors, each with ``loc`` (list of str),
        ``msg`` and ``type``; empty otherwise.
    """

    code = "invalid_request"

    def __init__(self, message: str, errors: list[dict[str, object]] | None = None) -> None:
        super().__init__(message)
        self.errors = list(errors or [])

    def __reduce__(self) -> tuple[type, tuple[str, list[dict[str, object]]]]:
        return type(self), (str(self), self.errors)

    def fields(self) -> dict[str, Any]:
        return {"errors": self.errors} if self.errors else {}


class FileFormatError(ShadowMapError, ValueError):
    """A file the library reads back (:func:`~renderer.exr.read_exr`'s OpenEXR) cannot be read:
    missing, not of that format, truncated or corrupt."""

    code = "invalid_file"


class LimitError(ShadowMapError):
    """A configured limit (triangles, image size, map size, lights, time) was exceeded.

    Attributes
    ----------
    limit : str
        Name of the setting that was exceeded, e.g. ``"max_triangles"``.
    """

    code = "limit_exceeded"

    def __init__(self, limit: str, message: str) -> None:
        super().__init__(message)
        self.limit = limit

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.limit, str(self))

    def fields(self) -> dict[str, Any]:
        return {"limit": self.limit}


class RenderError(ShadowMapError):
    """OpenGL failed: no context, a GL error, an incomplete framebuffer, ..."""


class ShaderError(RenderError):
    """A shader failed to compile or link; the message names the file(s)."""


class ReferenceUnavailable(ShadowMapError):
    """The ray-traced reference needs ``embreex``, its error metrics ``scipy`` (both in the
    ``reference`` extra: ``pip install shadowmap-service[reference]``)."""

    code = "reference_unavailable"


class ExrUnavailable(ShadowMapError):
    """``float_format: "exr"`` needs the ``OpenEXR`` package (``pip install OpenEXR``; it is in
    the ``server`` extra)."""

    code = "unavailable_feature"

    def fields(self) -> dict[str, Any]:
        return {"field": "/float_format"}
