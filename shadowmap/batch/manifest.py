"""Batch jobs: the manifest format, job ids, and the hash of a job's inputs.

A manifest is JSON Lines, one job per line::

    {"id": "duck-0", "scene": "models/Duck.glb", "params": {"width": 96, "height": 72}}
    {"id": "demo-orbit", "scene": {"builtin": "demo"},
     "params": {"outputs": ["color", "visibility"], "shadows": {"fit": "scene"}},
     "views": [{"eye": [4, 3, 4], "target": [0, 0.4, 0]}, {"eye": [-4, 3, 4], "target": [0, 0, 0]}],
     "lights": [[{"type": "directional", "direction": [-1, -2, -1]}],
                [{"type": "spot", "position": [0, 4, 0], "target": [0, 0, 0]}]]}

``scene``
    A ``.glb`` or ``.gltf`` path, relative to the manifest's folder (a ``.gltf``'s buffers and
    images are read from beside it, only those it names), or ``{"builtin": "demo"}``.
``params``
    The request, as for ``shadowmap render --params`` (:class:`~shadowmap.RenderParams`).
``views``, ``lights``
    Optional variations of the same scene: a list of cameras (``params.camera`` fields) and a
    list of light lists (``params.lights``). Every view is rendered with every light list, on the
    same loaded scene, each into its own folder (``view_000``, ``light_001``,
    ``view_000_light_001``).
``id``
    Optional; names the job's output folder. Defaults to ``line-<n>`` (the 1-based line number).

Blank lines and lines starting with ``#`` are skipped. A line that is not a valid job becomes a
:class:`Job` with :attr:`Job.error` set, which the batch records and moves past.
"""

from __future__ import annotations

import codecs
import hashlib
import json
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from shadowmap.renderer import Limits, RenderParams, ShadowMapError
from shadowmap.renderer.cache import content_key
from shadowmap.renderer.errors import SceneError
from shadowmap.renderer.limits import check_request
from shadowmap.renderer.params import RepeatedKey, load_json
from shadowmap.renderer.scene import gltf_resources, read_regular_file

from .errors import JobError, error_of

__all__ = ["MAX_JOB_RENDERS", "Job", "SceneRef", "Variation", "load_manifest", "parse_job"]

#: Bumped when the files a job writes change, so that a resumed batch renders old jobs again.
OUTPUT_FORMAT = 1
#: Job ids name folders: letters, digits, ``.``, ``_``, ``-``; not starting with a dot.
_ID = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")
_JOB_FIELDS = {"id", "scene", "params", "views", "lights"}
#: Renders one job may ask for by default (its views times its light lists): every one is
#: validated before the batch starts and gets its own folder, so a short manifest line must not
#: expand into millions of them (``render_many(max_job_renders=...)``, ``--max-job-renders``).
MAX_JOB_RENDERS = 10_000
#: Longest manifest line read by default, in bytes (``load_manifest(max_line_bytes=...)``,
#: ``--max-line-bytes``): a job is a few hundred bytes, 10,000 views a few hundred kB. A longer
#: line is an error record, passed over without being held in memory: a line is read whole
#: before it is parsed, and a file with no newline would otherwise be read whole.
MAX_LINE_BYTES = 16 * 2**20


@dataclass(frozen=True)
class SceneRef:
    """Where a job's scene comes from.

    Attributes
    ----------
    builtin : str or None
        ``"demo"`` for the built-in demo scene.
    path : Path or None
        An absolute path to a ``.glb`` or ``.gltf``.
    """

    builtin: str | None = None
    path: Path | None = None
    #: Most bytes read for the scene: its file, and apart from it the files a ``.gltf`` names
    #: (the limits' ``max_request_bytes``; None: no bound but the file's own size).
    max_bytes: int | None = None

    @property
    def key(self) -> str:
        """Names the source (not its content): jobs with the same key share one read."""
        return f"builtin:{self.builtin}" if self.builtin else f"file:{self.path}"

    def read(self) -> SceneBytes:
        """The scene's bytes and, for a ``.gltf``, the external files it names.

        Raises
        ------
        SceneError
            A missing or unreadable file, one that is no regular file (a FIFO, a device: see
            :func:`~shadowmap.renderer.scene.read_regular_file`), or a URI that leaves the
            file's folder (:func:`~shadowmap.renderer.scene.gltf_resources`; a file it names
            that is missing is the loader's to report).
        LimitError
            More than :attr:`max_bytes`.
        """
        if self.builtin == "demo":
            from shadowmap.renderer.demo import demo_glb

            return SceneBytes(demo_glb(), None, "glb")
        assert self.path is not None
        try:
            data = read_regular_file(self.path, str(self.path), self.max_bytes)
        except OSError as exc:
            raise SceneError(f"cannot read {self.path}: {exc.strerror}") from None
        suffix = self.path.suffix.lower().lstrip(".")
        resources = (gltf_resources(self.path, data, self.max_bytes) if suffix == "gltf"
                     else None)
        return SceneBytes(data, resources, suffix or None)


@dataclass(frozen=True)
class SceneBytes:
    """A scene file's content, as a worker loads it (``Renderer.load(data, ...)``)."""

    data: bytes
    resources: dict[str, bytes] | None
    file_type: str | None

    @property
    def digest(self) -> str:
        return content_key(self.data, self.resources)

    @property
    def nbytes(self) -> int:
        return len(self.data) + sum(len(v) for v in (self.resources or {}).values())


@dataclass(frozen=True)
class Variation:
    """One render of a job: its folder (relative to the job's) and its request."""

    name: str
    params: dict[str, Any]
    view: int | None = None
    lights: int | None = None


@dataclass
class Job:
    """One line of a manifest.

    Attributes
    ----------
    id : str
    scene : SceneRef or None
    params : dict
        The request as given (validated when the job is made).
    views : list of dict, optional
    lights : list of list of dict, optional
    line : int or None
        1-based line in the manifest.
    error : JobError or None
        Why the job cannot run (a bad line, bad params, a limit), found before any render.
    input_hash : str
        Set by :meth:`SceneHasher.hash_inputs`: the job's description and its scene's content.
    scene_digest : str
        Set with it: the scene's content alone (workers cache loaded scenes by it).
    """

    id: str
    scene: SceneRef | None = None
    params: dict[str, Any] = field(default_factory=dict)
    views: list[dict[str, Any]] | None = None
    lights: list[list[dict[str, Any]]] | None = None
    line: int | None = None
    error: JobError | None = None
    input_hash: str = ""
    scene_digest: str = ""

    def variations(self) -> list[Variation]:
        """Every (view, light list) pair, in order: views outer, light lists inner."""
        views: list[dict[str, Any] | None] = list(self.views) if self.views else [None]
        lights: list[list[dict[str, Any]] | None] = list(self.lights) if self.lights else [None]
        out = []
        for i, view in enumerate(views):
            for j, light in enumerate(lights):
                params = dict(self.params)
                parts = []
                if view is not None:
                    params["camera"] = view
                    parts.append(f"view_{i:03d}")
                if light is not None:
                    params["lights"] = light
                    parts.append(f"light_{j:03d}")
                out.append(Variation("_".join(parts), params, i if self.views else None,
                                     j if self.lights else None))
        return out

    def describe(self) -> dict[str, Any]:
        """What the hash covers besides the scene's content."""
        return {"format": OUTPUT_FORMAT, "params": self.params, "views": self.views,
                "lights": self.lights}


def _validate(job: Job, limits: Limits) -> None:
    """Every variation's request validates and is within the limits a request can break alone."""
    for v in job.variations():
        try:
            params = RenderParams.model_validate(v.params)
        except ValueError as exc:  # pydantic's ValidationError is a ValueError
            where = f" ({v.name})" if v.name else ""
            raise JobError("invalid_params", f"invalid params{where}: {_first_error(exc)}",
                           errors=_errors(exc)) from None
        try:
            check_request(params, limits)
        except ShadowMapError as exc:
            raise error_of(exc) from None


def _first_error(exc: ValueError) -> str:
    errors = _errors(exc)
    if not errors:
        return str(exc)
    first = errors[0]
    return f"{'.'.join(str(p) for p in first['loc']) or 'params'}: {first['msg']}"


def _errors(exc: ValueError) -> list[dict[str, Any]]:
    get = getattr(exc, "errors", None)
    if get is None:
        return []
    return [{"loc": [str(p) for p in e["loc"]], "msg": str(e["msg"]), "type": str(e["type"])}
            for e in get()]


def parse_job(entry: object, base_dir: Path, line: int | None = None,
              limits: Limits | None = None, max_job_renders: int = MAX_JOB_RENDERS) -> Job:
    """A job from one manifest entry (a decoded JSON line, or a dict given to ``render_many``).

    Never raises for bad input: the returned job then carries :attr:`Job.error`; one asking
    for more than ``max_job_renders`` renders (views times light lists) is refused before any of
    them is validated (``limit_exceeded``, limit ``max_job_renders``).
    """
    default_id = f"line-{line}" if line is not None else "job"
    if not isinstance(entry, dict):
        return Job(default_id, line=line, error=JobError(
            "invalid_job", f"a job must be a JSON object, not {type(entry).__name__}"))
    raw_id = entry.get("id", default_id)
    job_id = raw_id if isinstance(raw_id, str) and _ID.fullmatch(raw_id) else default_id
    job = Job(job_id, line=line)
    try:
        if job_id != raw_id:
            raise JobError("invalid_job", f"id {raw_id!r} must be 1-128 letters, digits, '.', "
                           "'_' or '-', not starting with '.'")
        unknown = sorted(set(entry) - _JOB_FIELDS)
        if unknown:
            raise JobError("invalid_job", f"unknown field(s) {', '.join(unknown)}; a job has "
                           f"{', '.join(sorted(_JOB_FIELDS))}")
        job.scene = _scene_ref(entry.get("scene"), base_dir,
                               (limits or Limits()).max_request_bytes)
        params = _plain(entry.get("params", {}), "params")
        if not isinstance(params, dict):
            raise JobError("invalid_params", "params must be a JSON object")
        job.params = params
        views, lights = entry.get("views"), entry.get("lights")
        # Counted before anything is copied or validated: a short line can ask for millions.
        n_views = len(views) if isinstance(views, (list, tuple)) else 1
        n_lights = len(lights) if isinstance(lights, (list, tuple)) else 1
        if n_views * n_lights > max_job_renders:
            raise JobError("limit_exceeded", f"the job asks for {n_views * n_lights} renders "
                           f"({n_views} views x {n_lights} light lists), over the limit of "
                           f"{max_job_renders} per job", limit="max_job_renders")
        views, lights = _plain(views, "views"), _plain(lights, "lights")
        if views is not None and not (isinstance(views, list) and views
                                      and all(isinstance(v, dict) for v in views)):
            raise JobError("invalid_job", "views must be a non-empty list of camera objects")
        if lights is not None and not (isinstance(lights, list) and lights
                                       and all(isinstance(v, list) for v in lights)):
            raise JobError("invalid_job", "lights must be a non-empty list of light lists")
        job.views, job.lights = views, lights
        _validate(job, limits or Limits())
    except JobError as exc:
        job.error = exc
    return job


def _plain(value: Any, what: str) -> Any:
    """``value`` as JSON data, which a job's hash and ``meta.json`` are made of.

    A manifest line is JSON already; an entry given from Python may hold what the library
    takes too: numpy arrays and scalars (as lists and numbers), tuples (as lists) and sets (as
    sorted lists: a set's order differs from one run to the next, and the hash must not).

    Raises
    ------
    JobError
        ``invalid_job``: another type, or nesting too deep to encode.
    """
    def default(o: Any) -> Any:
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, (set, frozenset)):
            return sorted(o, key=lambda v: json.dumps(v, sort_keys=True, default=default))
        raise TypeError(f"values of type {type(o).__name__} are not JSON data")

    try:
        return json.loads(json.dumps(value, default=default))
    except RecursionError:
        raise JobError("invalid_job", f"{what} nests too deep") from None
    except (TypeError, ValueError) as exc:
        raise JobError("invalid_job", f"{what} must be JSON data (objects, lists, strings, "
                       f"numbers, booleans, null): {exc}") from None


def _scene_ref(value: object, base_dir: Path, max_bytes: int | None = None) -> SceneRef:
    if isinstance(value, dict):
        if value == {"builtin": "demo"}:
            return SceneRef(builtin="demo")
        raise JobError("invalid_job", f"unknown scene {json.dumps(_plain(value, 'scene'))}: "
                       'give a path or {"builtin": "demo"}')
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if not isinstance(value, str) or not value or "\0" in value:
        raise JobError("invalid_job", "scene must be a path (relative to the manifest) or "
                       '{"builtin": "demo"}')
    return SceneRef(path=(base_dir / value).resolve(), max_bytes=max_bytes)


def load_manifest(path: str | Path, limits: Limits | None = None,
                  max_job_renders: int = MAX_JOB_RENDERS,
                  max_line_bytes: int = MAX_LINE_BYTES) -> list[Job]:
    """Every job of a JSON Lines manifest, in order (bad lines as jobs with an error; see
    :func:`parse_job` for ``limits`` and ``max_job_renders``).

    The file is UTF-8 (a byte order mark first is allowed, as some editors write one), one
    JSON object per line, LF or CRLF; blank lines and lines starting with ``#`` are passed
    over. A line that is not UTF-8 or not JSON, or longer than ``max_line_bytes``, is an
    error record and the rest are read. A FIFO (``<(generate-jobs)``) is read as it comes.

    Raises
    ------
    OSError
        The manifest cannot be read.
    """
    path = Path(path)
    base = path.resolve().parent
    jobs = []
    with open(path, "rb") as f:
        for n, raw in enumerate(_lines(f, max_line_bytes), start=1):
            def bad(code: str, detail: str, n: int = n, **extra: Any) -> None:
                jobs.append(Job(f"line-{n}", line=n, error=JobError(code, detail, **extra)))

            if raw is None:
                bad("limit_exceeded", f"line {n} is over {max_line_bytes} bytes",
                    limit="max_line_bytes")
                continue
            if n == 1 and raw.startswith(codecs.BOM_UTF8):
                raw = raw[len(codecs.BOM_UTF8):]
            try:
                text = raw.decode("utf-8").strip()
            except UnicodeDecodeError as exc:
                bad("invalid_job", f"line {n} is not UTF-8 text (byte {exc.start + 1})")
                continue
            if not text or text.startswith("#"):
                continue
            try:
                entry = load_json(text)
            except RepeatedKey as exc:
                bad("invalid_job", f"line {n}: {exc}")
                continue
            except (ValueError, RecursionError) as exc:
                why = "it nests too deep" if isinstance(exc, RecursionError) else str(exc)
                bad("invalid_job", f"line {n} is not JSON: {why}")
                continue
            jobs.append(parse_job(entry, base, n, limits, max_job_renders))
    return _unique_ids(jobs)


def _lines(f: BinaryIO, max_bytes: int) -> Iterator[bytes | None]:
    """The lines of ``f`` (with their line ends), None for one over ``max_bytes``: that one is
    read on to its end a chunk at a time and dropped."""
    while True:
        line = f.readline(max_bytes + 1)
        if not line:
            return
        if len(line) > max_bytes and not line.endswith(b"\n"):
            while (rest := f.readline(1 << 20)) and not rest.endswith(b"\n"):
                pass
            yield None
            continue
        yield line


def _unique_ids(jobs: list[Job]) -> list[Job]:
    """A second job with an id already used is an error (both would write one folder)."""
    seen: set[str] = set()
    for job in jobs:
        if job.id in seen and job.error is None:
            job.error = JobError("invalid_job", f"id {job.id!r} is used by an earlier job")
            job.id = f"{job.id}.line-{job.line}" if job.line is not None else f"{job.id}.dup"
        seen.add(job.id)
    return jobs


class SceneHasher:
    """Hashes of job inputs, reading each scene source once per run (by path, size, mtime)."""

    def __init__(self) -> None:
        self._digests: dict[tuple, str] = {}

    def scene_digest(self, ref: SceneRef) -> str:
        if ref.builtin:
            from shadowmap import __version__

            # The demo is generated by the installed version: its bytes are that version's.
            return f"builtin:{ref.builtin}:{__version__}"
        assert ref.path is not None
        try:
            st = os.stat(ref.path)
        except OSError as exc:
            raise SceneError(f"cannot read {ref.path}: {exc.strerror}") from None
        key = (ref.key, st.st_size, st.st_mtime_ns)
        if key not in self._digests:
            self._digests[key] = ref.read().digest
        return self._digests[key]

    def hash_inputs(self, job: Job) -> str:
        """SHA-256 of the job's description and its scene's content; sets ``job.input_hash``.

        A job whose scene cannot be read gets :attr:`Job.error` (and a hash of its description).
        """
        described = json.dumps(job.describe(), sort_keys=True, separators=(",", ":"))
        digest = hashlib.sha256(described.encode())
        if job.scene is not None and job.error is None:
            try:
                job.scene_digest = self.scene_digest(job.scene)
                digest.update(b"\0" + job.scene_digest.encode())
            except ShadowMapError as exc:
                job.error = error_of(exc)
        job.input_hash = digest.hexdigest()
        return job.input_hash
