"""The library's exception family.

Every error the library raises on purpose derives from :class:`ShadowMapError`. The HTTP layer maps
these classes to status codes; the library itself knows nothing of HTTP.
"""

from __future__ import annotations


class ShadowMapError(Exception):
    """Base class of every error raised on purpose by :mod:`renderer`."""


class SceneError(ShadowMapError):
    """The scene cannot be used: corrupt or truncated glTF, unsafe URI, no geometry, ..."""


class UnsupportedExtension(SceneError):
    """The file requires glTF extensions (``extensionsRequired``) this loader does not implement.

    Attributes
    ----------
    extensions : list of str
        The required extension names that are not supported, in the file's order.
    """

    def __init__(self, extensions: list[str], message: str | None = None) -> None:
        self.extensions = list(extensions)
        super().__init__(message or (
            "the file requires glTF extensions this renderer does not support: "
            + ", ".join(self.extensions)))

    def __reduce__(self) -> tuple[type, tuple[list[str], str]]:
        # Pickled with its attributes (an error sent back from a worker process).
        return type(self), (self.extensions, str(self))


class UnsupportedVersion(SceneError):
    """The file is well-formed glTF of a version this loader does not read.

    Attributes
    ----------
    field : str
        ``"asset.version"`` (major version not 2) or ``"asset.minVersion"`` (newer than 2.0).
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.field, str(self))


class RequestError(ShadowMapError, ValueError):
    """The request is invalid (params that do not validate) or impossible (e.g. a spot light
    with no direction).

    Attributes
    ----------
    errors : list of dict
        For params that do not validate: pydantic's errors, each with ``loc`` (list of str),
        ``msg`` and ``type``; empty otherwise.
    """

    def __init__(self, message: str, errors: list[dict[str, object]] | None = None) -> None:
        super().__init__(message)
        self.errors = list(errors or [])

    def __reduce__(self) -> tuple[type, tuple[str, list[dict[str, object]]]]:
        return type(self), (str(self), self.errors)


class LimitError(ShadowMapError):
    """A configured limit (triangles, image size, map size, lights, time) was exceeded.

    Attributes
    ----------
    limit : str
        Name of the setting that was exceeded, e.g. ``"max_triangles"``.
    """

    def __init__(self, limit: str, message: str) -> None:
        super().__init__(message)
        self.limit = limit

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.limit, str(self))


class RenderError(ShadowMapError):
    """OpenGL failed: no context, a GL error, an incomplete framebuffer, ..."""


class ShaderError(RenderError):
    """A shader failed to compile or link; the message names the file(s)."""


class ReferenceUnavailable(ShadowMapError):
    """The ray-traced reference needs ``embreex``, its error metrics ``scipy`` (both in the
    ``reference`` extra: ``pip install shadowmap-service[reference]``)."""


class ExrUnavailable(ShadowMapError):
    """``float_format: "exr"`` needs the ``OpenEXR`` package (``pip install OpenEXR``; it is in
    the ``server`` extra)."""
