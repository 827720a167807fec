"""The renderer: load, plan, light pass, camera pass, read back.

>>> from renderer import Renderer, RenderParams, load_scene
>>> with Renderer() as r:                                        # doctest: +SKIP
...     result = r.render(load_scene("Duck.glb"), RenderParams(outputs=["color", "visibility"]))
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from OpenGL import GL
from OpenGL.error import GLError

from .camera import resolve_camera
from .camera_pass import MAX_LIGHTS, CameraPass
from .encodings import debug_image
from .errors import LimitError, RenderError, SceneError, ShadowMapError
from .gpu import GLContext, GpuScene, check_gl
from .light_pass import LightPass
from .lights import resolve_lights
from .params import RenderParams
from .plan import RenderPlan, check_limits, make_plan
from .scene import Scene, load_scene
from .shaders import ProgramCache


@dataclass(frozen=True)
class Limits:
    """Upper bounds a renderer enforces on every request (:class:`LimitError` beyond them)."""

    max_pixels: int = 4096 * 4096
    max_map_size: int = 8192
    max_lights: int = MAX_LIGHTS
    max_triangles: int = 5_000_000


@dataclass
class LightDepth:
    """The ``light_depth`` output of one light.

    Attributes
    ----------
    image : ndarray, shape (S, S) or (2S, 3S), uint8
        Decoded linear depth as grayscale, near = dark, nothing drawn = white (cube maps 3 x 2).
    depth : ndarray, shape (S, S) or (6, S, S), float32
        Decoded linear depth in [0, 1] over [near, far]; NaN where nothing was drawn.
    near, far : float
        World distances the depth is normalised over.
    """

    light: int
    kind: str
    image: np.ndarray
    depth: np.ndarray
    near: float
    far: float


@dataclass
class RenderResult:
    """Outputs of one render; each image is None unless it was requested.

    Attributes
    ----------
    color : ndarray, shape (H, W, 3) or (H, W, 4), uint8
    visibility : ndarray, shape (H, W, L), float32
        Shadow factor the camera pass applied per light: 1 lit, 0 shadowed, fractions from PCF,
        NaN where no geometry.
    depth : ndarray, shape (H, W), float32
        Camera-space depth (distance along the view axis); NaN where no geometry.
    light_depth : list of LightDepth
        One per light that had a light pass.
    timings : dict of str to float
        Seconds per stage: load, upload, plan, light, camera, readback, total.
    plan : dict
        What ran and what was left out (see :mod:`renderer.plan`).
    info : dict
        GL platform, renderer and version strings.
    metrics : list of dict, optional
        Error against the ray-traced reference per light, when ``params.reference``.
    """

    color: np.ndarray | None = None
    visibility: np.ndarray | None = None
    depth: np.ndarray | None = None
    light_depth: list[LightDepth] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    plan: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    metrics: list[dict] | None = None

    def report(self) -> dict:
        """JSON-ready summary: timings, plan, GL info, metrics."""
        out = {"timings": self.timings, "plan": self.plan, "gl": self.info}
        if self.metrics is not None:
            out["metrics"] = self.metrics
        return out


class Renderer:
    """Owns one GL context and everything uploaded to it. Use from one thread only.

    Parameters
    ----------
    platform : {"egl", "osmesa"}, optional
    limits : Limits, optional
    cache_bytes : int
        Upper bound of GPU memory held by cached scene uploads (by content hash); 0 disables.
    cache_entries : int
        Upper bound of the number of cached scene uploads.
    """

    def __init__(self, platform: str | None = None, *, limits: Limits | None = None,
                 cache_bytes: int = 256 * 2**20, cache_entries: int = 32) -> None:
        self.limits = limits or Limits()
        self.context = GLContext(platform)
        self.programs = ProgramCache()
        self.light_pass = LightPass(self.programs)
        self.camera_pass = CameraPass(self.programs)
        self.cache_bytes = cache_bytes
        self.cache_entries = cache_entries
        self._uploads: OrderedDict[str, GpuScene] = OrderedDict()
        self._parsed: OrderedDict[str, Scene] = OrderedDict()  # by SHA-256 of file + resources
        self._closed = False

    # -- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Release every GL object and the context. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self.context.make_current()
            for gs in self._uploads.values():
                gs.release()
            self._uploads.clear()
            self.light_pass.release()
            self.camera_pass.release()
            self.programs.release()
        finally:
            self.context.release()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def info(self) -> dict:
        return self.context.info()

    # -- rendering ---------------------------------------------------------------------------

    def _upload(self, scene: Scene) -> tuple[GpuScene, bool, bool]:
        """The scene's upload, from the cache when the same content came before.

        Returns (upload, kept in the cache, cache hit).
        """
        if self.cache_bytes <= 0 or self.cache_entries <= 0 or not scene.key:
            return GpuScene.upload(scene), False, False
        gs = self._uploads.get(scene.key)
        if gs is not None:
            self._uploads.move_to_end(scene.key)
            return gs, True, True
        gs = self._uploads[scene.key] = GpuScene.upload(scene)
        while len(self._uploads) > 1 and (
            len(self._uploads) > self.cache_entries
            or sum(g.nbytes for g in self._uploads.values()) > self.cache_bytes
        ):
            _, old = self._uploads.popitem(last=False)
            old.release()
        return gs, True, False

    def _load(self, source: str | Path | bytes, resources: Mapping[str, bytes] | None) -> Scene:
        """Parse a file, or take the parsed scene of the same bytes from the last few calls."""
        try:
            data = Path(source).read_bytes() if isinstance(source, (str, Path)) else bytes(source)
        except OSError as exc:
            raise SceneError(f"cannot read {source}: {exc.strerror}") from None
        digest = hashlib.sha256(data)
        for name in sorted(resources or {}):
            digest.update(name.encode() + b"\0" + resources[name])
        key = digest.hexdigest()
        scene = self._parsed.get(key)
        if scene is not None:
            self._parsed.move_to_end(key)
            return scene
        file_type = Path(source).suffix if isinstance(source, (str, Path)) else None
        scene = load_scene(data, file_type=file_type, resources=resources,
                           max_triangles=self.limits.max_triangles)
        if self.cache_entries > 0:
            self._parsed[key] = scene
            while len(self._parsed) > self.cache_entries:
                self._parsed.popitem(last=False)
        return scene

    def render(self, scene: Scene | str | Path | bytes, params: RenderParams | Mapping | None = None,
               *, resources: Mapping[str, bytes] | None = None) -> RenderResult:
        """Render a scene.

        Parameters
        ----------
        scene : Scene, path or bytes
            A loaded scene, or a glTF file to load (see :func:`renderer.load_scene`).
        params : RenderParams or dict, optional
        resources : mapping of str to bytes, optional
            External files of a ``.gltf`` given as path or bytes.

        Raises
        ------
        SceneError, RequestError, LimitError, RenderError
        """
        if self._closed:
            raise RenderError("the renderer is closed")
        self.context.make_current()
        t0 = time.perf_counter()
        if params is None:
            params = RenderParams()
        elif not isinstance(params, RenderParams):
            params = RenderParams.model_validate(params)
        timings: dict[str, float] = {}
        if not isinstance(scene, Scene):
            scene = self._load(scene, resources)
        if params.ground:
            scene = scene.with_ground()
        timings["load"] = time.perf_counter() - t0
        check_limits(scene, params, self.limits)
        if params.shadows.max_map_size > self.limits.max_map_size:
            params = params.model_copy(deep=True)
            params.shadows.max_map_size = self.limits.max_map_size
        try:
            return self._render(scene, params, timings, t0)
        except ShadowMapError:
            raise
        except GLError as exc:
            raise RenderError(f"OpenGL error: {exc}") from exc

    def _render(self, scene: Scene, params: RenderParams, timings: dict, t0: float) -> RenderResult:
        t = time.perf_counter()
        gpu, kept, hit = self._upload(scene)
        timings["upload"] = time.perf_counter() - t
        try:
            t = time.perf_counter()
            camera = resolve_camera(params.camera, scene, params.width, params.height)
            lights = resolve_lights(params.lights, scene)
            if len(lights) > self.limits.max_lights:
                raise LimitError("max_lights", f"{len(lights)} lights is over the limit of "
                                 f"{self.limits.max_lights}")
            plan = make_plan(scene, camera, lights, gpu.origin, params)
            self._check_map_sizes(plan)
            timings["plan"] = time.perf_counter() - t

            t = time.perf_counter()
            maps = self.light_pass.render(gpu, plan.lights, params.shadows)
            GL.glFinish()
            timings["light"] = time.perf_counter() - t

            t = time.perf_counter()
            self.camera_pass.render(gpu, plan, maps, params)
            GL.glFinish()
            check_gl("camera pass")
            timings["camera"] = time.perf_counter() - t

            t = time.perf_counter()
            out = self.camera_pass.read(params.outputs, len(lights), params.alpha, camera)
            result = RenderResult(color=out.color, visibility=out.visibility, depth=out.depth)
            if "light_depth" in params.outputs:
                for sm in maps:
                    depth = sm.read_depth()
                    result.light_depth.append(
                        LightDepth(sm.plan.index, sm.plan.kind, debug_image(depth), depth,
                                   sm.plan.near, sm.plan.far)
                    )
            check_gl("readback")
            timings["readback"] = time.perf_counter() - t
        finally:
            if not kept:
                gpu.release()
        result.plan = self._plan_report(plan, params, hit)
        result.plan["shader_variants"] = {
            "light_pass": _variant_names(self.light_pass.variants),
            "camera_pass": _variant_names(self.camera_pass.variants),
        }
        result.info = self.context.info()
        if params.reference:
            t = time.perf_counter()
            result.metrics = self._reference_metrics(scene, camera, lights, params, result)
            timings["reference"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - t0
        result.timings = {k: round(v, 6) for k, v in timings.items()}
        return result

    def _check_map_sizes(self, plan: RenderPlan) -> None:
        limit = min(self.context.max_texture_size, self.context.max_cube_size)
        for lp in plan.map_lights:
            if lp.size > limit:
                raise LimitError("max_map_size", f"map size {lp.size} exceeds this GPU's limit {limit}")

    @staticmethod
    def _plan_report(plan: RenderPlan, params: RenderParams, hit: bool) -> dict:
        d = plan.to_dict()
        d["scene_cache"] = "hit" if hit else "miss"
        d["encoding"] = params.shadows.encoding
        d["filter"] = params.shadows.filter
        return d

    def _reference_metrics(self, scene, camera, lights, params, result) -> list[dict]:
        from .metrics import shadow_metrics
        from .reference import trace_reference

        vis = result.visibility
        if vis is None:
            # Metrics need the visibility: render it once more with the same settings.
            again = params.model_copy(update={"outputs": ["visibility"], "reference": False})
            vis = self.render(scene, again).visibility
        ref = trace_reference(scene, camera, lights)
        out = []
        for i in range(len(lights)):
            m = shadow_metrics(vis[..., i], ref.visibility[..., i], ref.valid[..., i]).to_dict()
            m["reference_seconds"] = round(ref.seconds, 4)
            out.append(m)
        return out


def _variant_names(variants: set[tuple]) -> list[str]:
    """Each program variant as its switched-on features, e.g. ``"HAS_UV FILTER_PCF PCF_RADIUS=1"``.

    Attribute locations are left out (they only follow the vertex layout).
    """
    out = []
    for defines in variants:
        parts = []
        for name, value in defines:
            if name.startswith(("LOC_", "LIGHT_")) or value is False or (not isinstance(value, bool) and value == 0):
                continue
            parts.append(name if value is True else f"{name}={value}")
        out.append(" ".join(parts))
    return sorted(set(out))
