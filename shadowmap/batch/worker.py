"""What a batch worker does with one job: load its scene once, render every variation on it, and
return the files to write.

The same :class:`JobRunner` runs in a process of the local pool (:mod:`.local`) and in a Ray actor
(:mod:`.ray`). It owns one :class:`~shadowmap.Renderer` (one GL context) for its lifetime, so
consecutive jobs of the same scene reuse its parse and upload, and the views of one job are
rendered back to back on the same loaded scene (with ``shadows.fit: "scene"`` the light pass of
the first view is reused by the next ones, see ``light_passes_cached`` in ``meta.json``).

Files are returned as bytes (PNG and ``.npy`` encoded here, in parallel across workers) and
written by the driver: workers need no shared file system with it.
"""

from __future__ import annotations

import io
import json
import math
import os
import socket
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from shadowmap.renderer import Limits, Renderer, RenderParams, RenderResult, Scene
from shadowmap.renderer.camera import Camera
from shadowmap.renderer.lights import Light
from shadowmap.renderer.png import depth_u16, png_bytes, visibility_u16

from .errors import JobError, error_of
from .manifest import SceneBytes

__all__ = ["JobOutcome", "JobRunner", "Task"]

#: Scenes a worker keeps loaded (by content digest), so that jobs of one scene skip the fetch.
SCENE_ENTRIES = 8


@dataclass(frozen=True)
class Task:
    """One job as sent to a worker: small, picklable, no scene bytes.

    Attributes
    ----------
    job_id : str
    scene_digest : str
        Content digest of the scene (the worker's cache key).
    scene_label : str
        The manifest's name for the scene, for ``meta.json``.
    variations : list of (str, dict)
        Folder name (``""``: the job's own folder) and the request of each render.
    input_hash : str
    attempt : int
        1 for the first try, 2 for the retry after a worker died.
    """

    job_id: str
    scene_digest: str
    scene_label: str
    variations: tuple[tuple[str, dict[str, Any]], ...]
    input_hash: str
    attempt: int = 1


@dataclass
class JobOutcome:
    """What a worker returns for a task.

    Attributes
    ----------
    files : dict of str to bytes
        Relative path (under the job's folder) -> content.
    error : dict or None
        :meth:`JobError.to_dict`, when the job failed.
    seconds : float
        Wall time in the worker, fetch and encoding included.
    render_seconds : float
        The renders' own ``timings["total"]``, summed.
    worker : dict
        ``pid`` and ``host`` of the worker.
    light_passes_cached : int
        Light maps reused from an earlier view instead of drawn.
    """

    job_id: str
    input_hash: str
    attempt: int
    files: dict[str, bytes] = field(default_factory=dict)
    error: dict[str, Any] | None = None
    seconds: float = 0.0
    render_seconds: float = 0.0
    fetch_seconds: float = 0.0
    worker: dict[str, Any] = field(default_factory=dict)
    light_passes_cached: int = 0

    @property
    def ok(self) -> bool:
        return self.error is None


def worker_identity() -> dict[str, Any]:
    return {"pid": os.getpid(), "host": socket.gethostname()}


class JobRunner:
    """Renders tasks with one GL context (use from one thread).

    Parameters
    ----------
    platform : {"egl", "osmesa"}, optional
    limits : Limits, optional
    """

    def __init__(self, platform: str | None = None, limits: Limits | None = None) -> None:
        self.renderer = Renderer(platform, limits=limits)
        self._scenes: OrderedDict[str, Scene] = OrderedDict()
        self.identity = worker_identity()

    def close(self) -> None:
        self.renderer.close()

    def run(self, task: Task, fetch: Callable[[], SceneBytes]) -> JobOutcome:
        """Render every variation of ``task``; a failure becomes the outcome's ``error``.

        Parameters
        ----------
        task : Task
        fetch : callable
            Returns the scene's bytes; called only when this worker has not loaded the scene
            already.
        """
        t0 = time.perf_counter()
        out = JobOutcome(task.job_id, task.input_hash, task.attempt, worker=self.identity)
        try:
            scene, out.fetch_seconds = self._scene(task, fetch)
            files: dict[str, bytes] = {}
            for name, raw in task.variations:
                params = RenderParams.model_validate(raw)
                result = self.renderer.render(scene, params)
                out.render_seconds += result.timings.get("total", 0.0)
                out.light_passes_cached += int(result.plan.get("light_passes_cached", 0))
                prefix = f"{name}/" if name else ""
                for rel, data in variation_files(result, task, name, raw).items():
                    files[prefix + rel] = data
            out.files = files
        except JobError as exc:
            out.error = exc.to_dict()
        except Exception as exc:  # noqa: BLE001  (any failure of one job is its record)
            out.error = error_of(exc).to_dict()
        out.seconds = time.perf_counter() - t0
        return out

    def _scene(self, task: Task, fetch: Callable[[], SceneBytes]) -> tuple[Scene, float]:
        hit = self._scenes.get(task.scene_digest)
        if hit is not None:
            self._scenes.move_to_end(task.scene_digest)
            return hit, 0.0
        t = time.perf_counter()
        sb = fetch()
        fetched = time.perf_counter() - t
        scene = self.renderer.load(sb.data, file_type=sb.file_type, resources=sb.resources)
        self._scenes[task.scene_digest] = scene
        while len(self._scenes) > SCENE_ENTRIES:
            self._scenes.popitem(last=False)
        return scene, fetched


# --------------------------------------------------------------------------------------------
# Files of one render
# --------------------------------------------------------------------------------------------


def npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def camera_meta(camera: Camera) -> dict[str, Any]:
    """Intrinsics and extrinsics of a resolved camera.

    ``camera_to_world`` is the glTF/OpenGL pose (the camera looks down its −Z, +Y up);
    ``K`` and ``world_to_camera_opencv`` are the same camera in the computer-vision convention
    (x right, y down, z forward; pixel ``(u, v)`` has its centre at ``u + 0.5, v + 0.5`` with row
    0 at the top of every image). Perspective: ``K @ (R X + t)`` projects a world point to
    pixels (after dividing by its z). Orthographic (``projection``, ``ymag``): ``K @ (R X + t)``
    with the camera point's z replaced by 1, i.e. ``fx``, ``fy`` are pixels per scene unit.
    """
    cx, cy = camera.width / 2, camera.height / 2
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    if camera.orthographic:
        assert camera.ymag is not None
        f = camera.height / 2 / camera.ymag
        lens: dict[str, Any] = {"projection": "orthographic", "ymag": camera.ymag,
                                "xmag": camera.ymag * camera.width / camera.height}
    else:
        f = camera.height / 2 / math.tan(camera.yfov / 2)
        lens = {"projection": "perspective", "yfov_deg": math.degrees(camera.yfov)}
    return {
        "width": camera.width, "height": camera.height,
        **lens, "znear": camera.znear, "zfar": camera.zfar,
        "fx": f, "fy": f, "cx": cx, "cy": cy,
        "K": [[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]],
        "camera_to_world": camera.pose.tolist(),
        "world_to_camera_opencv": (flip @ np.linalg.inv(camera.pose)).tolist(),
    }


def light_meta(light: Light) -> dict[str, Any]:
    d: dict[str, Any] = {"type": light.type, "color": light.color.tolist(),
                         "intensity": float(light.intensity),
                         "cast_shadows": bool(light.cast_shadows)}
    if light.type != "point":
        d["direction"] = light.direction.tolist()
    if light.type != "directional":
        d["position"] = light.position.tolist()
        d["range"] = light.range
    if light.type == "spot":
        d["inner_cone_deg"] = math.degrees(light.inner_cone)
        d["outer_cone_deg"] = math.degrees(light.outer_cone)
    return d


def _jsonable(value: object) -> object:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


def variation_files(result: RenderResult, task: Task, name: str, raw: dict[str, Any]
                    ) -> dict[str, bytes]:
    """The files of one render: the requested images as PNG (and arrays as ``.npy``) and
    ``meta.json``, whose camera and lights are the ones the render resolved
    (:attr:`RenderResult.camera`, :attr:`RenderResult.lights`)."""
    files: dict[str, bytes] = {}
    meta_outputs: dict[str, Any] = {}
    if result.color is not None:
        files["color.png"] = png_bytes(result.color)
        meta_outputs["color"] = "color.png"
    if result.visibility is not None:
        vis = result.visibility
        names = []
        for i in range(vis.shape[2]):
            files[f"visibility_{i}.png"] = png_bytes(visibility_u16(vis[..., i]))
            names.append(f"visibility_{i}.png")
        files["visibility.npy"] = npy_bytes(vis[..., 0] if vis.shape[2] == 1 else vis)
        meta_outputs["visibility"] = {"png": names, "npy": "visibility.npy",
                                      "png_scale": "round(v * 65535); no geometry = 0"}
    if result.depth is not None:
        img, near, far = depth_u16(result.depth)
        files["depth.png"] = png_bytes(img)
        files["depth.npy"] = npy_bytes(result.depth)
        meta_outputs["depth"] = {"png": "depth.png", "npy": "depth.npy", "near": near, "far": far,
                                 "png_scale": "near + v / 65534 * (far - near); 65535 = none"}
    if result.light_depth:
        entries = []
        for ld in result.light_depth:
            files[f"light_depth_{ld.light}.png"] = png_bytes(ld.image)
            files[f"light_depth_{ld.light}.npy"] = npy_bytes(ld.depth)
            entries.append({"light": ld.light, "kind": ld.kind, "near": ld.near, "far": ld.far,
                            "ranges": ld.ranges, "png": f"light_depth_{ld.light}.png",
                            "npy": f"light_depth_{ld.light}.npy"})
        meta_outputs["light_depth"] = entries
    if result.camera is None:
        raise ValueError("a render result without its camera")
    meta = {
        "job": task.job_id,
        "variation": name or None,
        "scene": task.scene_label,
        "params": raw,
        "camera": camera_meta(result.camera),
        "lights": [light_meta(lt) for lt in result.lights],
        "outputs": meta_outputs,
        "timings": result.timings,
        "plan": result.plan,
        "warnings": result.warnings,
        "gl": result.info,
    }
    if result.metrics is not None:
        meta["metrics"] = result.metrics
    files["meta.json"] = json.dumps(meta, indent=1, default=_jsonable).encode()
    return files
