"""Turning an HTTP request into a scene upload and render params, within the configured limits.

Nothing here touches the file system or the network: the scene, its buffers and textures come
only from the request body (a single file or a ``.zip``), and the loader refuses any URI that is
not a plain relative name inside the upload.
"""

from __future__ import annotations

import io
import posixpath
import zipfile
import zlib
from collections.abc import AsyncIterable
from dataclasses import dataclass, field

from shadowmap.renderer import RenderParams, SceneError
from shadowmap.renderer.limits import MAX_PARAMS_BYTES
from shadowmap.renderer.params import parse_json

from .errors import ServiceError
from .settings import Settings

SCENE_SUFFIXES = (".glb", ".gltf")
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # local file header; empty archive
GLB_MAGIC = b"glTF"

#: Raw (non-multipart) request bodies accepted as a scene, by media type.
RAW_SCENE_TYPES = {
    "model/gltf-binary": "glb",
    "model/gltf+json": "gltf",
    "application/zip": "zip",
    "application/x-zip-compressed": "zip",
    "application/octet-stream": None,  # sniffed from the first bytes
}


@dataclass
class SceneUpload:
    """One scene as uploaded, ready for :meth:`shadowmap.renderer.Renderer.load`.

    Attributes
    ----------
    data : bytes
        The ``.glb`` or ``.gltf`` file.
    file_type : {"glb", "gltf"}
    resources : dict of str to bytes
        Other files of a ``.zip`` upload, by their path relative to the scene file.
    name : str
        File name, for messages.
    """

    data: bytes
    file_type: str
    resources: dict[str, bytes] = field(default_factory=dict)
    name: str = "scene"


# --------------------------------------------------------------------------------------------
# Body
# --------------------------------------------------------------------------------------------


def too_large(limit: str, detail: str) -> ServiceError:
    return ServiceError(413, "payload_too_large", detail, limit=limit)


def check_content_length(header: str | None, limit: int) -> None:
    """Refuse a declared body size over the limit before reading any of it."""
    if header is None:
        return
    try:
        declared = int(header)
    except ValueError:
        raise ServiceError(400, "bad_request", "Content-Length is not a number") from None
    if declared > limit:
        raise too_large("max_upload_bytes",
                        f"the request body of {declared} bytes is over the limit of {limit} bytes")


async def read_limited(chunks: AsyncIterable[bytes], limit: int) -> bytes:
    """Collect an async stream of byte chunks, failing as soon as it grows past ``limit``.

    Counting matters even after :func:`check_content_length`: a chunked request declares no size.
    """
    buf = bytearray()
    async for chunk in chunks:
        buf += chunk
        if len(buf) > limit:
            raise too_large("max_upload_bytes",
                            f"the request body is over the limit of {limit} bytes")
    return bytes(buf)


# --------------------------------------------------------------------------------------------
# Params
# --------------------------------------------------------------------------------------------


def parse_params(text: str | bytes) -> RenderParams:
    """Parse the ``params`` JSON into the request model, strictly.

    JSON types are taken as they are (no ``0`` for a boolean, no ``false`` or ``"1"`` for a
    number) and every light names its ``type``: the service's OpenAPI document is the contract,
    where the library's Python API converts. ``NaN`` and ``Infinity`` are not JSON, and
    ``1e999`` (infinity) is no finite number: all three are refused.

    Raises
    ------
    ServiceError
        413 when the text is over :data:`MAX_PARAMS_BYTES`.
    pydantic.ValidationError
        When the text is not JSON, or not an object matching
        :class:`shadowmap.renderer.RenderParams`.
    """
    if len(text) > MAX_PARAMS_BYTES:
        raise too_large("max_params_bytes", f"params is {len(text)} bytes, over the limit of "
                        f"{MAX_PARAMS_BYTES} bytes")
    return parse_json(text)


# --------------------------------------------------------------------------------------------
# Scene files
# --------------------------------------------------------------------------------------------


def scene_kind(data: bytes, filename: str | None, declared: str | None) -> str:
    """'glb', 'gltf' or 'zip': from the file name, else the media type, else the first bytes."""
    if filename:
        suffix = posixpath.splitext(filename.lower())[1]
        if suffix in (".glb", ".gltf", ".zip"):
            return suffix[1:]
        if suffix:
            raise SceneError(f"unsupported scene file {filename!r}: use .glb, .gltf or .zip")
    if declared:
        return declared
    if data[:4] in ZIP_MAGIC:
        return "zip"
    return "glb" if data[:4] == GLB_MAGIC else "gltf"


def scene_upload(data: bytes, filename: str | None, settings: Settings,
                 declared: str | None = None) -> SceneUpload:
    """Classify an uploaded file and unpack it when it is a ``.zip``.

    Parameters
    ----------
    data : bytes
    filename : str, optional
        The name the client gave the file part.
    settings : Settings
    declared : {"glb", "gltf", "zip"}, optional
        Kind implied by the request's media type, used when there is no file name.

    Raises
    ------
    SceneError
        Empty file, unknown suffix, or a bad or unsafe ``.zip``.
    ServiceError
        413 when a ``.zip`` unpacks to more than the limit.
    """
    if not data:
        raise SceneError("the scene file is empty")
    kind = scene_kind(data, filename, declared)
    name = filename or f"scene.{kind}"
    if kind != "zip":
        return SceneUpload(data, kind, {}, name)
    scene_name, scene_data, resources = unpack_zip(
        data, settings.max_unzipped_bytes, settings.max_zip_entries
    )
    ft = posixpath.splitext(scene_name.lower())[1][1:]
    return SceneUpload(scene_data, ft, resources, f"{name}:{scene_name}")


def _entry_name(raw: str) -> str:
    """A zip entry's name as a clean relative path; SceneError when it could leave the archive."""
    name = raw.replace("\\", "/")
    parts = name.split("/")
    if name.startswith("/") or ":" in parts[0] or ".." in parts or "\0" in name:
        raise SceneError(f"refusing zip entry {raw!r}: only relative names inside the archive "
                         "are allowed")
    return posixpath.normpath(name)


def unpack_zip(data: bytes, max_bytes: int,
               max_entries: int) -> tuple[str, bytes, dict[str, bytes]]:
    """Unpack a ``.zip`` holding one ``.gltf``/``.glb`` and the files it refers to.

    Sizes are checked twice: the declared sizes before anything is unpacked, then the bytes
    actually produced while unpacking (a crafted archive may under-declare).

    Returns
    -------
    scene_name : str
    scene_data : bytes
    resources : dict of str to bytes
        Every other file, by its path relative to the scene file's folder (files outside that
        folder cannot be referenced by a safe URI and are left out).
    """
    if data[:4] not in ZIP_MAGIC:
        raise SceneError("not a zip archive (the file does not start with a zip header)")
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
        infos = archive.infolist()
    except (zipfile.BadZipFile, zlib.error, ValueError, EOFError, OSError) as exc:
        raise SceneError(f"not a valid zip archive: {exc}") from None
    files = []
    for info in infos:
        name = _entry_name(info.filename)
        if info.is_dir() or name.startswith("__MACOSX/"):
            continue
        files.append((name, info))
    if len(files) > max_entries:
        raise too_large("max_zip_entries",
                        f"the archive holds {len(files)} files, over the limit of {max_entries}")
    declared = sum(info.file_size for _, info in files)
    if declared > max_bytes:
        raise too_large("max_unzipped_bytes", f"the archive unpacks to {declared} bytes, over "
                        f"the limit of {max_bytes} bytes")
    scenes = [name for name, _ in files if posixpath.splitext(name.lower())[1] in SCENE_SUFFIXES]
    if len(scenes) != 1:
        found = ", ".join(scenes[:5]) if scenes else "none"
        raise SceneError(f"the archive must hold exactly one .gltf or .glb file (found {found})")
    scene_name = scenes[0]
    folder = posixpath.dirname(scene_name)
    total = 0
    contents: dict[str, bytes] = {}
    for name, info in files:
        buf = bytearray()
        try:
            with archive.open(info) as f:
                while chunk := f.read(1 << 16):
                    buf += chunk
                    total += len(chunk)
                    if total > max_bytes:
                        raise too_large("max_unzipped_bytes", "the archive unpacks to more than "
                                        f"the limit of {max_bytes} bytes")
        except ServiceError:
            raise
        except (zipfile.BadZipFile, zlib.error, RuntimeError, NotImplementedError, ValueError,
                EOFError, OSError) as exc:
            # RuntimeError: encrypted entry; NotImplementedError: unknown compression method.
            raise SceneError(f"cannot unpack zip entry {name!r}: {exc}") from None
        contents[name] = bytes(buf)
    resources = {}
    for name, blob in contents.items():
        if name == scene_name:
            continue
        rel = posixpath.relpath(name, folder) if folder else name
        if not rel.startswith("../"):
            resources[rel] = blob
    return scene_name, contents[scene_name], resources
