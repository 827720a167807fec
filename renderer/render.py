"""The renderer: load, plan, light pass, camera pass, read back.

>>> from shadowmap import Renderer, RenderParams, load_scene
>>> with Renderer() as r:                                        # doctest: +SKIP
...     result = r.render(load_scene("Duck.glb"), RenderParams(outputs=["color", "visibility"]))

The GL modules (``gl``, ``passes``) are imported when a :class:`Renderer` is created, after the GL
platform is selected: importing this module, the request model or the scene loader touches no GL
platform.
"""

from __future__ import annotations

import math
import time
import weakref
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .cache import BoundedCache, content_key, parts_key
from .camera import (
    Camera,
    boxes_ahead,
    near_clip_warning,
    orthonormalize_pose,
    resolve_camera,
    view_origin,
)
from .encodings import drawn_range, stretched_image
from .errors import RenderError, RequestError, SceneError, ShadowMapError
from .ground import existing_floor
from .lights import Light, resolve_lights
from .limits import (
    Limits,
    check_gpu_range,
    check_lights,
    check_map_sizes,
    check_request,
    check_scene,
    fit_request,
)
from .params import RenderParams
from .plan import RenderPlan, make_plan
from .plan.plan import SceneFitPlan, light_bytes
from .scene import (
    Instance,
    Scene,
    is_trimesh,
    load_scene,
    read_source,
    scene_from_trimesh,
)

if TYPE_CHECKING:
    from .gl.resources import GpuScene

__all__ = ["LightDepth", "Limits", "RenderResult", "Renderer", "camera_warnings",
           "request_warnings"]


@dataclass
class LightDepth:
    """The ``light_depth`` output of one light.

    Attributes
    ----------
    kind : {"ortho", "perspective", "cube", "cascades"}
    image : ndarray, shape (S, S), (2S, 3S) or (S, K*S), uint8
        Decoded linear depth as grayscale, stretched over the depths drawn into the map (the
        nearest caster black, the farthest 254; :func:`~.encodings.debug_image`), nothing drawn
        = white (cube maps 3 x 2, K cascades side by side, near first, each stretched alone).
    depth : ndarray, shape (S, S), (6, S, S) or (K, S, S), float32
        Decoded linear depth in [0, 1] over [near, far]; NaN where nothing was drawn. Each
        cascade over its own range (``ranges``).
    near, far : float
        World distances the depth is normalised over (cascades: the extremes of ``ranges``).
    ranges : list of (float, float)
        Each cascade's (near, far); empty otherwise.
    shown : (float, float) or None
        World distances ``image`` is stretched over: the nearest and farthest depth drawn
        (cascades: the extremes over them); None when nothing was drawn.
    """

    light: int
    kind: str
    image: np.ndarray
    depth: np.ndarray
    near: float
    far: float
    ranges: list[tuple[float, float]] = field(default_factory=list)
    shown: tuple[float, float] | None = None


def _request_points(params: RenderParams) -> list[np.ndarray]:
    """The positions a request names (camera eye, target and pose; lights' positions, targets
    and poses), world space."""
    out = []
    cam = params.camera
    if cam is not None:
        out += [np.asarray(v, np.float64) for v in (cam.eye, cam.target) if v is not None]
        if cam.pose is not None:
            out.append(np.asarray(cam.pose, np.float64)[:3, 3])
    for lt in params.lights or []:
        if lt.type == "directional":
            continue
        # A point light has no target (each light type has exactly its own fields).
        points = (lt.position, getattr(lt, "target", None))
        out += [np.asarray(v, np.float64) for v in points if v is not None]
        if lt.pose is not None:
            out.append(np.asarray(lt.pose, np.float64)[:3, 3])
    return out


def _light_depths(maps: list) -> list[LightDepth]:
    """The ``light_depth`` output: one per shadowed light; a cascaded light's layers side by
    side, near to far."""
    out: list[LightDepth] = []
    for sm in maps:
        lp = sm.plan
        assert lp.kind is not None  # only lights with a map pass have a ShadowMap
        depth = sm.read_depth()
        if not lp.cascades:
            image, shown = _picture(depth, lp.near, lp.far)
            out.append(LightDepth(lp.index, lp.kind, image, depth, lp.near, lp.far,
                                  shown=shown))
            continue
        parts = [_picture(d, c.near, c.far) for d, c in zip(depth, lp.cascades, strict=True)]
        drawn = [s for _, s in parts if s is not None]
        out.append(LightDepth(lp.index, "cascades", np.concatenate([i for i, _ in parts], axis=1),
                              depth, min(c.near for c in lp.cascades),
                              max(c.far for c in lp.cascades),
                              [(float(c.near), float(c.far)) for c in lp.cascades],
                              (min(s[0] for s in drawn), max(s[1] for s in drawn))
                              if drawn else None))
    return out


def _picture(t: np.ndarray, near: float, far: float
             ) -> tuple[np.ndarray, tuple[float, float] | None]:
    """A map's debug picture and the world distances it is stretched over (None: nothing
    drawn), from one pass of :func:`drawn_range` over the map."""
    span = drawn_range(t)
    shown = None if span is None else (float(near + span[0] * (far - near)),
                                       float(near + span[1] * (far - near)))
    return stretched_image(t, span), shown


@dataclass(frozen=True, slots=True, eq=False)
class _RequestBase:
    """What :meth:`Renderer._request_base` settles of a request before its camera.

    ``scene`` is the one drawn (with the ground when asked), ``params`` a private copy of the
    request with its ``max_map_size`` held to what fits (``held``: it was), ``warnings`` the
    file's and the request's so far. The lights are resolved on first use, where a request
    resolves them (after its camera), and kept.
    """

    scene: Scene
    params: RenderParams
    warnings: list[str]
    held: bool
    _lights: list[list[Light]] = field(default_factory=list)

    def lights(self) -> list[Light]:
        """:func:`resolve_lights` of the request's lights (which its camera does not change)."""
        if not self._lights:
            self._lights.append(resolve_lights(self.params.lights, self.scene))
        return self._lights[0]


@dataclass(frozen=True, slots=True, eq=False)
class _Prepared:
    """What :meth:`Renderer._prepare` settles for one request before any GL work.

    ``scene`` is the one drawn (with the ground when asked), ``params`` the request with its
    ``max_map_size`` held to what fits, ``warnings`` the request's and the file's, ``origin``
    where the view's GPU coordinates start (the centre of the scene's bounds, where the upload
    is placed, or a point beside the eye: :func:`view_origin`), ``plan_key`` the plan cache's
    key ("" to plan anew), ``camera_report`` the plan's ``camera`` entry, ``resolve_seconds``
    the time the camera, lights and key took when made.
    """

    scene: Scene
    params: RenderParams
    warnings: list[str]
    camera: Camera
    lights: list[Light]
    origin: np.ndarray
    plan_key: str
    camera_report: dict[str, Any]
    resolve_seconds: float


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
    camera : Camera or None
        The camera the frame was drawn from, as the request resolved it (the file's camera, a
        pose, or the automatic framing of the scene with its ground).
    lights : list of Light
        The lights as resolved for this frame, in the request's order.
    warnings : list of str
        Everything this render had to drop or approximate, one sentence each: the scene's own
        (what loading it left out, :attr:`Scene.warnings`), then the renderer's (a clamped
        setting, a light property it cannot honour, a pose made rigid). Empty when the render
        is exactly what the scene and the request asked for.
    """

    color: np.ndarray | None = None
    visibility: np.ndarray | None = None
    depth: np.ndarray | None = None
    light_depth: list[LightDepth] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    plan: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    metrics: list[dict] | None = None
    camera: Camera | None = None
    lights: list[Light] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def report(self) -> dict[str, Any]:
        """JSON-ready summary: timings, plan, GL info, warnings, metrics."""
        out: dict[str, Any] = {"timings": self.timings, "plan": self.plan, "gl": self.info,
                               "warnings": list(self.warnings)}
        if self.metrics is not None:
            out["metrics"] = self.metrics
        return out


class Renderer:
    """Owns one GL context and everything uploaded to it. Use from one thread only.

    Parameters
    ----------
    platform : {"egl", "osmesa"}, optional
        Defaults to ``PYOPENGL_PLATFORM``, else EGL when it works, else OSMesa.
    limits : Limits, optional
    cache_bytes : int
        Upper bound of GPU memory held by cached scene uploads; 0 disables the upload cache.
    cache_entries : int
        Scenes kept parsed and uploaded, by :func:`~shadowmap.renderer.cache.content_key`;
        0 disables every cache.
    map_cache_bytes : int
        Upper bound of the memory held by cached shadow maps (0 disables the map cache): a
        light whose map an earlier render drew with the same fit (``shadows.fit: "scene"``
        across the views of a scene, or a repeated request) is not drawn again; the plan
        reports it as ``"light_pass": "cached"``.
    """

    def __init__(self, platform: str | None = None, *, limits: Limits | None = None,
                 cache_bytes: int = 256 * 2**20, cache_entries: int = 32,
                 map_cache_bytes: int = 192 * 2**20) -> None:
        from .gl.platform import select_platform

        select_platform(platform)  # before anything imports PyOpenGL
        from .gl.context import GLContext
        from .gl.programs import ProgramCache
        from .passes.camera_pass import CameraPass
        from .passes.light_pass import LightPass

        self.limits = limits or Limits()
        self.context = GLContext(platform)
        self.programs = ProgramCache()
        map_entries = max(cache_entries, 4) if map_cache_bytes and cache_entries else 0
        self.light_pass = LightPass(self.programs, cache_bytes=map_cache_bytes,
                                    cache_entries=map_entries)
        self.camera_pass = CameraPass(self.programs)
        self.cache_bytes = cache_bytes
        self.cache_entries = cache_entries
        #: Parsed scenes by content key.
        self.scenes: BoundedCache[Scene] = BoundedCache(cache_entries)
        #: Render plans by :func:`plan_key`.
        self.plans: BoundedCache[RenderPlan] = BoundedCache(cache_entries * 2)
        #: Lights planned with ``shadows.fit: "scene"``, by :func:`~.plan.plan.scene_fit_key`:
        #: the views of one scene that want the same map size plan each such light once.
        self.scene_fits: BoundedCache[SceneFitPlan] = BoundedCache(cache_entries * 4)
        #: GPU uploads by the scene's key (freed when evicted).
        self.uploads: BoundedCache[GpuScene] = BoundedCache(
            cache_entries, cache_bytes, size=lambda g: g.nbytes, on_evict=lambda g: g.release())
        #: Each source scene's :meth:`Scene.with_ground`, by the source object (see
        #: :meth:`_with_ground`), so that the per-scene arrays of a grounded scene are reused.
        self._grounded: OrderedDict[int, tuple[weakref.ref[Scene], tuple, Scene]] = OrderedDict()
        #: Each source scene's own floor (see :meth:`_own_floor`), by the source object.
        self._floors: OrderedDict[int, tuple[weakref.ref[Scene], Instance | None]] = OrderedDict()
        #: Each request's preparation (see :meth:`_prepare`), by (source scene, request JSON).
        self.requests: OrderedDict[tuple[int, str], tuple[weakref.ref[Scene], tuple, _Prepared]]
        self.requests = OrderedDict()
        #: What requests that differ in their camera alone share (see :meth:`_request_base`),
        #: by (source scene, request JSON without the camera).
        self.request_bases: OrderedDict[tuple[int, str],
                                        tuple[weakref.ref[Scene], tuple, _RequestBase]]
        self.request_bases = OrderedDict()
        self._closed = False

    # -- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Release every GL object and the context. Safe to call twice.

        In a forked copy of the process that made the renderer, nothing is released (the GL
        objects are the parent's, and a GL call there could wait for ever): the renderer is
        only marked closed.
        """
        if self._closed:
            return
        self._closed = True
        if self.context.forked:
            self.context.release()
            return
        try:
            self.context.make_current()
            self._grounded.clear()
            self.requests.clear()
            self.request_bases.clear()
            self.uploads.clear()
            self.light_pass.release()
            self.camera_pass.release()
            self.programs.release()
        finally:
            self.context.release()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def info(self) -> dict[str, str]:
        return self.context.info()

    # -- loading -----------------------------------------------------------------------------

    def load(self, source: str | Path | bytes | Any, *, file_type: str | None = None,
             resources: Mapping[str, bytes] | None = None) -> Scene:
        """Parse a glTF file, or return the scene parsed from the same content before.

        Parameters
        ----------
        source : path, bytes, trimesh.Trimesh or trimesh.Scene
            A file, or a trimesh object (converted by
            :func:`~shadowmap.renderer.scene.scene_from_trimesh`).
        file_type : {"glb", "gltf"}, optional
            Taken from the path's suffix, else detected from the content.
        resources : mapping of str to bytes, optional
            External files of a ``.gltf``; for a path, by default the files it names, read
            from its folder (:func:`~shadowmap.renderer.scene.gltf_resources`).

        Raises
        ------
        SceneError, LimitError
            As :func:`~shadowmap.renderer.load_scene`; ``max_triangles`` comes from
            :attr:`limits`.
        """
        if is_trimesh(source):
            scene = scene_from_trimesh(source, self.limits)
            check_scene(scene, self.limits)
            return scene
        data, file_type, resources = read_source(source, file_type, resources,
                                                 self.limits.max_request_bytes)
        key = content_key(data, resources)
        scene, _, _ = self.scenes.get_or_make(key, lambda: load_scene(
            data, file_type=file_type, resources=resources, limits=self.limits, key=key))
        return scene

    def _with_ground(self, scene: Scene) -> Scene:
        """``scene.with_ground()``, the same object again for the same source scene.

        A new :class:`Scene` per request would miss every per-scene cache (the plan's instance
        arrays, :func:`~shadowmap.renderer.scene.instance_arrays`). The entry is kept while the
        source scene lives and holds the same lists, key and focus (the grounded scene shares
        its cameras and lights lists), for up to ``cache_entries`` source scenes.
        """
        if self.cache_entries <= 0:
            return scene.with_ground()
        state = _ground_state(scene)
        hit = self._grounded.get(id(scene))
        if hit is not None and hit[0]() is scene and _same_state(hit[1], state):
            self._grounded.move_to_end(id(scene))
            return hit[2]
        grounded = scene.with_ground()
        for k in [k for k, v in self._grounded.items() if v[0]() is None]:
            del self._grounded[k]  # their scenes are gone (an id may be reused)
        self._grounded[id(scene)] = (weakref.ref(scene), state, grounded)
        self._grounded.move_to_end(id(scene))
        while len(self._grounded) > self.cache_entries:
            self._grounded.popitem(last=False)
        return grounded

    def _own_floor(self, scene: Scene) -> Instance | None:
        """:func:`~shadowmap.renderer.ground.existing_floor` of a scene, once per scene object
        (kept while the scene lives, for up to ``cache_entries`` scenes)."""
        hit = self._floors.get(id(scene))
        if hit is not None and hit[0]() is scene:
            return hit[1]
        floor = existing_floor(scene)
        if self.cache_entries > 0:
            for k in [k for k, v in self._floors.items() if v[0]() is None]:
                del self._floors[k]
            self._floors[id(scene)] = (weakref.ref(scene), floor)
            while len(self._floors) > self.cache_entries:
                self._floors.popitem(last=False)
        return floor

    def _upload(self, scene: Scene) -> tuple[GpuScene, bool, bool]:
        """The scene's upload, from the cache when the same content came before.

        Returns (upload, kept in the cache, cache hit).
        """
        from .gl.resources import GpuScene

        return self.uploads.get_or_make(scene.key, lambda: GpuScene.upload(scene))

    # -- rendering ---------------------------------------------------------------------------

    def render(self, scene: Scene | str | Path | bytes | Any,
               params: RenderParams | Mapping | None = None,
               *, resources: Mapping[str, bytes] | None = None) -> RenderResult:
        """Render a scene.

        Parameters
        ----------
        scene : Scene, path, bytes, trimesh.Trimesh or trimesh.Scene
            A loaded scene, or a glTF file or trimesh object to load (see :meth:`load`).
        params : RenderParams or dict, optional
        resources : mapping of str to bytes, optional
            External files of a ``.gltf`` given as path or bytes.

        Raises
        ------
        SceneError, RequestError, LimitError, RenderError
        """
        from OpenGL.error import GLError

        if self._closed:
            raise RenderError("the renderer is closed")
        self.context.make_current()
        t0 = time.perf_counter()
        params = _as_params(params)
        if not isinstance(scene, Scene):
            check_request(params, self.limits)  # before a parse the request may not allow
            scene = self.load(scene, resources=resources)
        prep, made = self._prepare(scene, params)
        # The camera, lights and plan key belong to the plan stage (none of it on a repeat).
        resolve = prep.resolve_seconds if made else 0.0
        timings: dict[str, float] = {"load": time.perf_counter() - t0 - resolve, "plan": resolve}
        try:
            result = self._render(prep, timings, t0)
        except ShadowMapError:
            raise
        except GLError as exc:
            raise RenderError(f"OpenGL error: {exc}") from exc
        # The plan's own (cascades it had to cut or coarsen) after the request's; each once.
        result.warnings = list(dict.fromkeys(prep.warnings + result.warnings))
        return result

    def _prepare(self, scene: Scene, params: RenderParams) -> tuple[_Prepared, bool]:
        """Everything a request settles before GL work, the same object again for a repeated one;
        (preparation, made now).

        Validation against the limits, the ground, the resolved camera and lights, the range
        checks and the plan's key are pure functions of the scene object (unchanged, as
        :meth:`_with_ground` compares it), the request and the limits: a client polling one
        view, or a batch's repeated job, does none of it twice. A request that fails a check is
        not kept, so it fails again the same way.
        """
        key = (id(scene), params.model_dump_json()) if self.cache_entries > 0 else None
        state = _ground_state(scene)
        if key is not None:
            hit = self.requests.get(key)
            if hit is not None and hit[0]() is scene and _same_state(hit[1], state):
                self.requests.move_to_end(key)
                return hit[2], False
        prep = self._prepare_new(scene, params, key[1] if key else None)
        if key is not None:
            for k in [k for k, v in self.requests.items() if v[0]() is None]:
                del self.requests[k]  # their scenes are gone (an id may be reused)
            self.requests[key] = (weakref.ref(scene), state, prep)
            while len(self.requests) > 2 * self.cache_entries:
                self.requests.popitem(last=False)
        return prep, True

    def _prepare_new(self, scene: Scene, params: RenderParams,
                     params_json: str | None) -> _Prepared:
        base = self._request_base(scene, params)
        scene, warnings = base.scene, list(base.warnings)
        # The base's copy of the request (its max_map_size held), with this request's camera:
        # only the camera differs between the requests that share a base, and nothing after
        # this point changes the copy.
        params = base.params.model_copy(
            update={"camera": None if params.camera is None
                    else params.camera.model_copy(deep=True)})
        if base.held:
            params_json = None
        # Before the upload and the camera: coordinates float32 cannot hold would overflow there.
        lo, hi = scene.bounds
        check_gpu_range(np.stack([lo, hi]), (lo + hi) / 2, _request_points(params))
        t = time.perf_counter()
        camera = resolve_camera(params.camera, scene, params.width, params.height)
        warnings += camera_warnings(params, scene, camera)
        ahead = boxes_ahead(camera, scene)
        clipped = near_clip_warning(camera, scene, params.camera, ahead)
        if clipped:
            warnings.append(clipped)
        lights = base.lights()
        check_lights(len(lights), self.limits)
        # Again with the file's camera and lights, and the resolved positions. The upload is
        # placed at the centre of the scene's bounds (GpuScene.upload). What the request named
        # passed above: only what the scene placed can fail here.
        origin = (lo + hi) / 2
        check_gpu_range(scene.bounds, origin, [camera.position] + [
            lt.position for lt in lights if lt.type != "directional"], scene_placed=True)
        # A view that looks closely at a part far from the centre is drawn relative to a point
        # beside its eye instead (GpuScene.set_origin).
        placed = view_origin(camera, scene, origin, ahead)
        if placed.warning:
            warnings.append(placed.warning)
        origin = placed.origin
        key = (plan_key(scene, camera, lights, origin, params, params_json)
               if self.plans.enabled else "")
        report = _camera_report(camera, scene)
        report["origin"], report["origin_at"] = origin.tolist(), placed.at
        return _Prepared(scene, params, warnings, camera, lights, origin, key, report,
                         time.perf_counter() - t)

    def _request_base(self, scene: Scene, params: RenderParams) -> _RequestBase:
        """What a request settles before its camera, the same object again for a request that
        differs from an earlier one in its camera alone (a batch's views, a client moving its
        camera): the checks against the limits, the ground, the memory estimate, the copy of
        the request and its lights. Kept like :meth:`_prepare`'s preparations; a request that
        fails a check is not kept."""
        key = ((id(scene), params.model_dump_json(exclude={"camera"}))
               if self.cache_entries > 0 else None)
        state = _ground_state(scene)
        if key is not None:
            hit = self.request_bases.get(key)
            if hit is not None and hit[0]() is scene and _same_state(hit[1], state):
                self.request_bases.move_to_end(key)
                return hit[2]
        base = self._request_base_new(scene, params)
        if key is not None:
            for k in [k for k, v in self.request_bases.items() if v[0]() is None]:
                del self.request_bases[k]  # their scenes are gone (an id may be reused)
            self.request_bases[key] = (weakref.ref(scene), state, base)
            while len(self.request_bases) > self.cache_entries:
                self.request_bases.popitem(last=False)
        return base

    def _request_base_new(self, scene: Scene, params: RenderParams) -> _RequestBase:
        check_request(params, self.limits)
        # A copy, read before the ground is added: what loading left out belongs to the file,
        # and a cached scene's list must not grow with every render.
        warnings = list(scene.warnings)
        if params.ground:
            floor = self._own_floor(scene)
            if floor is None:
                scene = self._with_ground(scene)
            else:
                name = repr(floor.name) if floor.name else "an unnamed instance"
                warnings.append(
                    f"ground: no plane added: the scene has its own floor ({name}, spanning "
                    "its footprint at its lowest point), and a second plane would show under it")
        check_scene(scene, self.limits, params)
        # The memory the render needs, before any GL work: refused over max_request_bytes,
        # except that 'auto' maps are held to the largest size that fits (with a warning).
        top, fitted = fit_request(params, scene, self.limits)
        # The camera's own warnings are judged per camera (_prepare_new): not kept here.
        warnings += _shadow_warnings(params, self.limits) + _light_warnings(params, scene) + fitted
        # A copy the preparation keeps: the caller may change their model afterwards.
        params = params.model_copy(deep=True)
        held = params.shadows.max_map_size != top
        if held:
            params.shadows.max_map_size = top
        # Nothing to draw from any camera (the focus: a ground under a point spans 6e-30).
        focus = scene.bounds if scene.focus is None else scene.focus
        if not np.any(focus[1] > focus[0]):
            raise SceneError("every vertex of the scene lies at one point: no triangle has an "
                             "area to draw")
        return _RequestBase(scene, params, warnings, held)

    def _render(self, prep: _Prepared, timings: dict[str, float], t0: float) -> RenderResult:
        from OpenGL import GL

        from .gl.context import check_gl

        scene, params, camera, lights = prep.scene, prep.params, prep.camera, prep.lights
        t = time.perf_counter()
        gpu, kept, hit = self._upload(scene)
        gpu.set_origin(prep.origin)
        timings["upload"] = time.perf_counter() - t
        try:
            t = time.perf_counter()
            plan, _, plan_hit = self.plans.get_or_make(
                prep.plan_key, lambda: make_plan(scene, camera, lights, prep.origin, params,
                                                 self.scene_fits))
            # Every map is a 2D or 2D array texture (cube faces and cascades are layers).
            check_map_sizes((lp.map_size for lp in plan.map_lights), self.context.max_texture_size)
            timings["plan"] += time.perf_counter() - t

            t = time.perf_counter()
            maps = self.light_pass.render(gpu, plan.lights, params.shadows, scene.key)
            GL.glFinish()
            timings["light"] = time.perf_counter() - t

            t = time.perf_counter()
            self.camera_pass.render(gpu, plan, maps, params)
            GL.glFinish()
            check_gl("camera pass")
            timings["camera"] = time.perf_counter() - t

            t = time.perf_counter()
            # A list[str] copy: CameraPass.read takes list[str], and list is invariant.
            out = self.camera_pass.read(list(params.outputs), len(lights), params.alpha, camera)
            result = RenderResult(color=out.color, visibility=out.visibility, depth=out.depth,
                                  camera=camera, lights=list(lights))
            if "light_depth" in params.outputs:
                result.light_depth = _light_depths(maps)
            check_gl("readback")
            timings["readback"] = time.perf_counter() - t
        finally:
            if not kept:
                gpu.release()
        result.warnings = list(plan.warnings)
        result.plan = self._plan_report(plan, params, hit)
        result.plan["plan_cache"] = "hit" if plan_hit else "miss"
        result.plan["camera"] = {k: list(v) if isinstance(v, list) else v
                                 for k, v in prep.camera_report.items()}
        cached = {m.plan.index for m in maps if m.cached}
        for i, (lp, d) in enumerate(zip(plan.lights, result.plan["lights"], strict=True)):
            if lp.kind is not None:
                d["light_pass"] = "cached" if i in cached else "drawn"
        result.plan["light_passes_cached"] = sum(len(m.plan.maps) for m in maps if m.cached)
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

    @staticmethod
    def _plan_report(plan: RenderPlan, params: RenderParams, hit: bool) -> dict[str, Any]:
        d = plan.to_dict()
        d["scene_cache"] = "hit" if hit else "miss"
        d["encoding"] = params.shadows.encoding
        d["filter"] = params.shadows.filter
        return d

    def _reference_metrics(self, scene: Scene, camera: Camera, lights: list[Light],
                           params: RenderParams, result: RenderResult) -> list[dict[str, Any]]:
        from .metrics import compare_all
        from .reference import trace_reference

        if not lights:
            return []  # no light, no shadow to compare
        vis = result.visibility
        if vis is None:
            # Metrics need the visibility: render it once more with the same settings.
            again = params.model_copy(update={"outputs": ["visibility"], "reference": False})
            vis = self.render(scene, again).visibility
            assert vis is not None  # requested as the only output
        ref = trace_reference(scene, camera, lights)
        out = []
        for m in compare_all(vis, ref):
            d = m.to_dict()
            d["reference_seconds"] = round(ref.seconds, 4)
            out.append(d)
        return out


def _camera_report(camera: Camera, scene: Scene) -> dict[str, Any]:
    """The camera the render used, for the plan: where it is and looks, and the centre and
    radius of what the automatic camera frames (the scene without an added ground), so that a
    client can orbit it (the web page does)."""
    lo, hi = scene.bounds if scene.focus is None else scene.focus
    return {
        "eye": camera.pose[:3, 3].tolist(),
        "forward": (-camera.pose[:3, 2]).tolist(),
        "up": camera.pose[:3, 1].tolist(),
        **({"projection": "orthographic", "ymag": camera.ymag} if camera.orthographic
           else {"projection": "perspective", "yfov_deg": math.degrees(camera.yfov)}),
        "znear": camera.znear,
        "zfar": camera.zfar,
        "focus_center": ((lo + hi) / 2).tolist(),
        "focus_radius": float(np.linalg.norm(hi - lo)) / 2,
    }


def plan_key(scene: Scene, camera: Camera, lights: list[Light], origin: np.ndarray,
             params: RenderParams, params_json: str | None = None) -> str:
    """Everything :func:`make_plan` reads, as one content key ("" for a scene without a key).

    ``params_json``: ``params.model_dump_json()`` when the caller has it already.
    """
    if not scene.key:
        return ""
    if params_json is None:
        params_json = params.model_dump_json()
    parts = [scene.key.encode(), np.asarray(origin, np.float64).tobytes(),
             camera.pose.tobytes(),
             repr((camera.yfov, camera.ymag, camera.width, camera.height, camera.znear,
                   camera.zfar)).encode(),
             params_json.encode()]
    parts += [light_bytes(lt) for lt in lights]
    return parts_key(parts)


def _ground_state(scene: Scene) -> tuple[tuple, tuple]:
    """What :meth:`Scene.with_ground` reads of a scene: (objects, compared by identity; values,
    compared by equality)."""
    return ((scene.instances, scene.primitives, scene.cameras, scene.lights, scene.focus),
            (len(scene.instances), len(scene.primitives), scene.key))


def _same_state(a: tuple[tuple, tuple], b: tuple[tuple, tuple]) -> bool:
    return all(x is y for x, y in zip(a[0], b[0], strict=True)) and a[1] == b[1]


def _as_params(params: RenderParams | Mapping | None) -> RenderParams:
    """The request model from a model, a mapping or nothing (the defaults).

    Raises
    ------
    RequestError
        When a mapping does not validate (the library's own error, not pydantic's).
    """
    if params is None:
        return RenderParams()
    if isinstance(params, RenderParams):
        return params
    from pydantic import ValidationError

    try:
        return RenderParams.model_validate(params)
    except ValidationError as exc:
        # Pydantic's messages, kept whole in ``errors`` (without the inputs, which may be
        # large or not JSON) and the first five in the message.
        errors: list[dict[str, object]] = []
        parts: list[str] = []
        for e in exc.errors():
            loc = [str(p) for p in e["loc"]]
            errors.append({"loc": loc, "msg": str(e["msg"]), "type": str(e["type"])})
            parts.append(f"{'.'.join(loc) or 'params'}: {e['msg']}")
        more = f" (and {len(parts) - 5} more)" if len(parts) > 5 else ""
        raise RequestError("invalid params: " + "; ".join(parts[:5]) + more, errors) from exc


def _variant_names(variants: set[tuple]) -> list[str]:
    """Each program variant as its switched-on features, e.g. ``"HAS_UV FILTER_PCF PCF_RADIUS=1"``.

    Attribute locations (``LOC_*``) and the per-light lists (``LIGHT_TYPES``, ``LIGHT_MAPS_2D``,
    ``LIGHT_MAPS_CUBE``) are left out: they only follow the vertex layout and the plan's lights.
    """
    return list(_names_of(frozenset(variants)))


@lru_cache(maxsize=256)
def _names_of(variants: frozenset[tuple]) -> tuple[str, ...]:
    """:func:`_variant_names` of one set of variants (frames repeat theirs)."""
    out = []
    for defines in variants:
        parts = []
        for name, value in defines:
            if (name.startswith(("LOC_", "LIGHT_")) or value is False
                    or (not isinstance(value, bool) and value == 0)):
                continue
            parts.append(name if value is True else f"{name}={value}")
        out.append(" ".join(parts))
    return tuple(sorted(set(out)))


# --------------------------------------------------------------------------------------------
# Warnings: what the renderer itself drops or approximates
# --------------------------------------------------------------------------------------------

#: Largest difference from a rotation that a pose may show before it counts as scaled or
#: sheared: poses written with six decimals are rigid to about 1e-6.
RIGID_TOLERANCE = 1e-5


def request_warnings(params: RenderParams, scene: Scene, limits: Limits) -> list[str]:
    """What a render of ``scene`` with ``params`` leaves out of the request or approximates.

    The renderer keeps its behaviour in each case (it clamps, makes rigid, ignores); this only
    says so. A request that cannot be rendered at all is not judged here: it fails later with
    its own error.

    Parameters
    ----------
    params : RenderParams
        The request as given, before the renderer clamps anything.
    scene : Scene
        Its lights are read when the request lists none.
    limits : Limits

    Returns
    -------
    list of str
        One sentence per finding, naming the setting or the light.
    """
    return (_shadow_warnings(params, limits) + camera_warnings(params, scene)
            + _light_warnings(params, scene))


def _shadow_warnings(params: RenderParams, limits: Limits) -> list[str]:
    out: list[str] = []
    shadows = params.shadows
    # Only an explicit value (the default under a lower limit is the service's configuration,
    # not a request cut short), and only for automatic sizes, the only ones it bounds.
    if ("max_map_size" in shadows.model_fields_set and shadows.map_size == "auto"
            and shadows.max_map_size > limits.max_map_size):
        out.append(f"shadows.max_map_size {shadows.max_map_size} is over the limit of "
                   f"{limits.max_map_size}: automatic map sizes stop at {limits.max_map_size}")
    if ("pcf_kernel" in shadows.model_fields_set and shadows.pcf_kernel > 1
            and shadows.filter == "hard"):
        out.append(f"shadows.pcf_kernel {shadows.pcf_kernel} is not used: the filter is 'hard'")
    return out


def _light_warnings(params: RenderParams, scene: Scene) -> list[str]:
    if params.lights is None:
        return _file_light_warnings(scene)
    return [f"light {k}: the pose has scale or shear: its nearest rotation is used"
            for k, lp in enumerate(params.lights)
            if lp.pose is not None and not _is_rigid(lp.pose, f"light {k}")]


def _is_rigid(pose: list[list[float]], what: str) -> bool:
    """Whether a request's pose is a rotation and translation already (true when it cannot be
    made rigid at all: that is the render's error to raise, not a warning)."""
    given = np.asarray(pose, np.float64)
    try:
        rigid = orthonormalize_pose(given, what)
    except RequestError:
        return True
    scale = max(1.0, float(np.max(np.abs(given[:3, :3]))))
    return bool(np.allclose(rigid[:3, :3], given[:3, :3], rtol=0.0, atol=RIGID_TOLERANCE * scale))


def camera_warnings(params: RenderParams, scene: Scene,
                    camera: Camera | None = None) -> list[str]:
    """What the request's camera was made into: a pose with scale or shear made rigid, an
    ``up`` along the view direction replaced. Judged per camera: requests that differ in their
    camera alone share everything else the renderer settles (:meth:`Renderer._request_base`).

    Parameters
    ----------
    params : RenderParams
    scene : Scene
    camera : Camera, optional
        ``params.camera`` resolved, where the caller has it.
    """
    cam = params.camera
    if cam is None:
        return []
    if cam.pose is not None:
        if not _is_rigid(cam.pose, "camera"):
            return ["camera: the pose has scale or shear: its nearest rotation is used"]
        return []
    if cam.eye is None or "up" not in cam.model_fields_set:
        return []
    if camera is None:
        try:
            camera = resolve_camera(cam, scene, params.width, params.height)
        except RequestError:
            return []
    pose = camera.pose
    # The up vector was honoured when the camera's +Y is its part across the view axis; when it
    # lies along the axis it has no such part and another one was chosen.
    up = np.asarray(cam.up, np.float64)
    if up.any():
        up = up / np.abs(up).max()  # the direction alone: tiny components would square to 0
    z = pose[:3, 2]
    across = up - np.dot(up, z) * z
    length = float(np.linalg.norm(across))
    if length > 1e-9 * max(float(np.linalg.norm(up)), 1e-300) and np.allclose(
            pose[:3, 1], across / length, rtol=0.0, atol=1e-6):
        return []
    return [f"camera: up {cam.up} is parallel to the view direction: another up vector is used"]


def _file_light_warnings(scene: Scene) -> list[str]:
    """What resolving the file's ``KHR_lights_punctual`` lights changed about them."""
    if not scene.lights:  # the default light is the renderer's own
        return []
    out: list[str] = []
    for k, (sl, light) in enumerate(zip(scene.lights, resolve_lights(None, scene), strict=True)):
        what = f"light {k} of the file"
        if light.type != sl.type:
            out.append(f"{what}: type {sl.type!r} is not supported: rendered as a "
                       f"{light.type} light")
        if not np.isclose(light.intensity, sl.intensity, rtol=1e-9, atol=0.0):
            if light.type == "directional":
                out.append(f"{what}: intensity {sl.intensity:g} clamped to {light.intensity:g}")
            else:  # glTF gives them in candela, which has no fixed relation to this shading
                out.append(f"{what}: intensity {sl.intensity:g} (candela) is not used: a file's "
                           f"spot and point lights shine at {light.intensity:g}")
        if light.type == "spot":
            for name, given, used in (("outer", sl.outer_cone, light.outer_cone),
                                      ("inner", sl.inner_cone, light.inner_cone)):
                if not np.isclose(given, used, rtol=1e-9, atol=0.0):
                    out.append(f"{what}: {name} cone angle {np.degrees(given):.6g} degrees "
                               f"clamped to {np.degrees(used):.6g}")
    return out
