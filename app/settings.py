"""Service settings, read from the environment (``SHADOWMAP_*``) when the app is created.

Every limit has a default that suits a small CPU-only (llvmpipe) deployment; raise them for bigger
machines, e.g. ``SHADOWMAP_MAX_PIXELS=33554432 SHADOWMAP_RENDER_TIMEOUT=300 shadowmap serve``.
"""

from __future__ import annotations

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from shadowmap.renderer.limits import MAX_LIGHTS, Limits


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
    max_map_size : int
        Largest shadow-map side; ``map_size: "auto"`` is clamped to it. A point light's cube
        map at this size holds ``6 * max_map_size**2`` depth values, read back as float32.
    max_triangles : int
        Most triangles a scene may draw (counting every instance).
    max_lights : int
        Most lights per request (the renderer supports at most 8).
    render_timeout : float
        Seconds a request may spend waiting in the queue plus rendering before it gets 503/504.
    queue_size : int
        Renders that may wait for the GL thread; a request beyond it gets 503 with Retry-After.
        Each waiting render holds its upload (and unpacked zip) in memory, so the worst case is
        about ``queue_size * max_upload_bytes * (1 + zip_expansion)``.
    scene_cache_entries : int
        Scenes the renderer keeps parsed and uploaded, by content hash (0 disables both caches).
    gpu_cache_bytes : int
        GPU memory the renderer may keep for uploaded scenes (0 disables the upload cache).
    startup_timeout : float
        Seconds to wait for the GL context at start-up before giving up.
    """

    model_config = SettingsConfigDict(env_prefix="SHADOWMAP_", extra="ignore")

    max_upload_bytes: int = Field(default=32 * 2**20, ge=1024)
    zip_expansion: float = Field(default=4.0, ge=1.0, le=1000.0)
    max_zip_entries: int = Field(default=1000, ge=1)
    max_pixels: int = Field(default=4096 * 4096, ge=1)
    max_map_size: int = Field(default=4096, ge=16, le=16384)
    max_triangles: int = Field(default=2_000_000, ge=1)
    max_lights: int = Field(default=MAX_LIGHTS, ge=1, le=MAX_LIGHTS)
    render_timeout: float = Field(default=60.0, gt=0.0)
    queue_size: int = Field(default=8, ge=1)
    scene_cache_entries: int = Field(default=4, ge=0)
    gpu_cache_bytes: int = Field(default=256 * 2**20, ge=0)
    startup_timeout: float = Field(default=60.0, gt=0.0)

    def limits(self) -> Limits:
        """The renderer's :class:`~shadowmap.renderer.limits.Limits` from these settings."""
        return Limits(max_pixels=self.max_pixels, max_map_size=self.max_map_size,
                      max_lights=self.max_lights, max_triangles=self.max_triangles)

    @property
    def max_unzipped_bytes(self) -> int:
        """Largest total size the files of a ``.zip`` upload may unpack to."""
        return int(self.max_upload_bytes * self.zip_expansion)
