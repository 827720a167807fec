"""Service settings, read from the environment (``SHADOWMAP_*``) when the app is created.

Every limit has a default that suits a small CPU-only (llvmpipe) deployment; raise them for bigger
machines, e.g. ``SHADOWMAP_MAX_PIXELS=33554432 SHADOWMAP_RENDER_TIMEOUT=300 shadowmap serve``.
"""

from __future__ import annotations

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from shadowmap.hosts import MAX_SECONDS
from shadowmap.renderer.allocator import KEEP_FREED_BYTES
from shadowmap.renderer.limits import MAX_LIGHTS, Limits
from shadowmap.renderer.params import MAX_IMAGE_SIDE


class Settings(BaseSettings):
    """Limits and tuning of one service process.

    Attributes
    ----------
    max_upload_bytes : int
        Largest request body (the scene file plus the params); 413 beyond it.
    zip_expansion : float
        A ``.zip`` upload may unpack to at most ``max_upload_bytes * zip_expansion`` bytes (413
        beyond it, limit name ``max_unzipped_bytes``).
    max_zip_entries : int
        Most files a ``.zip`` upload may hold.
    max_pixels : int
        Largest ``width * height`` of a request.
    max_image_side : int
        Largest ``width`` and largest ``height`` of a request (the OpenAPI document gives the
        smaller of this and ``max_pixels`` as their maximum).
    max_map_size : int
        Largest shadow-map side; ``map_size: "auto"`` is clamped to it. A point light's cube
        map at this size holds ``6 * max_map_size**2`` depth values, read back as float32.
    max_triangles : int
        Most triangles a scene may draw (counting every instance).
    max_lights : int
        Most lights per request (the renderer supports at most 8).
    max_nodes : int
        Most nodes a glTF file may hold (and joints its drawn skins may list); checked from
        the JSON before any other work, as are the next four.
    max_depth : int
        Deepest node hierarchy.
    max_instances : int
        Most drawn instances (mesh nodes, ``EXT_mesh_gpu_instancing`` instances each).
    max_primitives : int
        Most primitives drawn, summed over every use of a mesh.
    max_texture_pixels : int
        Most texture pixels decoded for one scene, over all its images.
    max_request_bytes : int
        Most memory one request may need, estimated before the work: the scene's accessors as
        decoded, then shadow maps, framebuffers, read-backs and the scene's upload (422
        ``limit_exceeded`` beyond it; ``map_size: "auto"`` is held to what fits instead). It
        bounds how far one render takes the worker above its own few hundred MB; a worker left
        above ``max_worker_memory_bytes`` is replaced after the render.
    render_timeout : float
        Seconds a request may spend waiting in the queue plus rendering before it gets 503 (still
        queued) or 504 (rendering; the render is stopped: its worker process is killed and
        replaced). Time the service spends restarting a worker is not charged to waiting jobs.
    queue_size : int
        Hard cap on the renders that may wait for the worker, whatever their expected time; a
        request beyond it gets 503 ``queue_full`` with Retry-After. Each waiting render holds its
        upload (and unpacked zip) in memory, so the worst case is about
        ``queue_size * max_upload_bytes * (1 + zip_expansion)``.
    scene_cache_entries : int
        Scenes the renderer keeps parsed and uploaded, by content hash (0 disables both caches).
    gpu_cache_bytes : int
        GPU memory the renderer may keep for uploaded scenes (0 disables the upload cache).
    light_map_cache_bytes : int
        Memory the renderer may keep for drawn shadow maps, so that a request whose light fits
        as an earlier one's (``shadows.fit: "scene"`` over one scene, a repeated request) does
        not draw them again (0 disables the map cache).
    startup_timeout : float
        Seconds to wait for the GL context at start-up before giving up.
    max_expected_wait : float
        Admission by time: a render is queued only while the expected wait ahead of it (the
        estimated cost of the queued renders plus the rest of the running one, from recent render
        times of similar requests) is under this many seconds, and under ``render_timeout``;
        otherwise 503 ``queue_full`` with Retry-After from that wait.
    max_renders_per_worker : int
        Renders after which the worker process is replaced by a fresh one, between renders and
        without failing a request (like gunicorn's ``max_requests``; 0: never).
    max_worker_memory_bytes : int
        Resident memory of the worker process above which it is replaced after its render (like
        Celery's ``max_memory_per_child``; 0: no cap).
    keep_freed_bytes : int
        Freed memory the worker process keeps for its next renders instead of giving it back
        to the system, where each reuse would be page faults again
        (:func:`shadowmap.renderer.allocator.keep_freed_memory`; glibc only; 0: the C
        library's defaults). Counted in its resident memory.
    upload_timeout : float
        Seconds a client may take to send the request body; 408 and the connection closed after.
    send_timeout : float
        Seconds the service may wait on a client to read its response (its send buffer full),
        summed over the response; the connection is dropped after (applied by ``shadowmap
        serve``). A client that stops reading a large response would otherwise hold its
        connection, one of the ``limit_concurrency`` places, and the response's bytes for ever.
    keep_alive_timeout : int
        Seconds an idle connection stays open (uvicorn ``timeout_keep_alive``; applied by
        ``shadowmap serve``, which also closes a new connection that sends nothing in this time).
    limit_concurrency : int
        Most connections (and requests) at once; more get 503 from the server (uvicorn
        ``limit_concurrency``, applied by ``shadowmap serve``).
    shutdown_timeout : float
        Seconds a shutdown waits for running requests (uvicorn ``timeout_graceful_shutdown``,
        applied by ``shadowmap serve``); a worker still rendering then is killed.
    """

    model_config = SettingsConfigDict(env_prefix="SHADOWMAP_", extra="ignore")

    max_upload_bytes: int = Field(default=32 * 2**20, ge=1024)
    zip_expansion: float = Field(default=4.0, ge=1.0, le=1000.0, allow_inf_nan=False)
    max_zip_entries: int = Field(default=1000, ge=1)
    max_pixels: int = Field(default=4096 * 4096, ge=1)
    max_image_side: int = Field(default=MAX_IMAGE_SIDE, ge=1, le=MAX_IMAGE_SIDE)
    max_map_size: int = Field(default=4096, ge=16, le=16384)
    max_triangles: int = Field(default=2_000_000, ge=1)
    max_lights: int = Field(default=MAX_LIGHTS, ge=1, le=MAX_LIGHTS)
    render_timeout: float = Field(default=60.0, gt=0.0, le=MAX_SECONDS,
                                  allow_inf_nan=False)
    queue_size: int = Field(default=32, ge=1)
    scene_cache_entries: int = Field(default=4, ge=0)
    gpu_cache_bytes: int = Field(default=256 * 2**20, ge=0)
    light_map_cache_bytes: int = Field(default=192 * 2**20, ge=0)
    startup_timeout: float = Field(default=60.0, gt=0.0, le=MAX_SECONDS,
                                  allow_inf_nan=False)
    max_nodes: int = Field(default=Limits.max_nodes, ge=1)
    max_depth: int = Field(default=Limits.max_depth, ge=1)
    max_instances: int = Field(default=Limits.max_instances, ge=1)
    max_primitives: int = Field(default=Limits.max_primitives, ge=1)
    max_texture_pixels: int = Field(default=Limits.max_texture_pixels, ge=1)
    max_request_bytes: int = Field(default=Limits.max_request_bytes, ge=2**20)

    # -- the service process model: worker process, admission by time, slow clients ----------
    max_expected_wait: float = Field(default=30.0, gt=0.0, le=MAX_SECONDS,
                                  allow_inf_nan=False)
    max_renders_per_worker: int = Field(default=500, ge=0)
    max_worker_memory_bytes: int = Field(default=1536 * 2**20, ge=0)
    keep_freed_bytes: int = Field(default=KEEP_FREED_BYTES, ge=0, le=2**31 - 1)
    upload_timeout: float = Field(default=30.0, gt=0.0, le=MAX_SECONDS,
                                  allow_inf_nan=False)
    send_timeout: float = Field(default=30.0, gt=0.0, le=MAX_SECONDS, allow_inf_nan=False)
    keep_alive_timeout: int = Field(default=5, ge=1, le=MAX_SECONDS)
    limit_concurrency: int = Field(default=64, ge=1)
    shutdown_timeout: float = Field(default=10.0, ge=0.0, le=MAX_SECONDS,
                                  allow_inf_nan=False)

    def limits(self) -> Limits:
        """The renderer's :class:`~shadowmap.renderer.limits.Limits` from these settings."""
        return Limits(max_pixels=self.max_pixels, max_map_size=self.max_map_size,
                      max_lights=self.max_lights, max_triangles=self.max_triangles,
                      max_nodes=self.max_nodes, max_depth=self.max_depth,
                      max_instances=self.max_instances, max_primitives=self.max_primitives,
                      max_texture_pixels=self.max_texture_pixels,
                      max_request_bytes=self.max_request_bytes)

    @property
    def max_unzipped_bytes(self) -> int:
        """Largest total size the files of a ``.zip`` upload may unpack to."""
        return int(self.max_upload_bytes * self.zip_expansion)
