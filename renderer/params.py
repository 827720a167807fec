"""The request model shared by the library, the CLI and the HTTP service.

Everything a render needs besides the scene itself: image size, camera, lights, shadow settings and
which outputs to produce. Validation here is structural (types, ranges, finite numbers); whether a
pose means anything (e.g. a zero-length direction) is decided when the request is resolved against a
scene, see :mod:`renderer.lights` and :mod:`renderer.camera`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from .limits import MAX_CASCADES

Encoding = Literal["rgba8", "rgb8", "rg8", "r8", "depth"]
Output = Literal["color", "light_depth", "visibility", "depth"]
ENCODINGS: tuple[str, ...] = ("rgba8", "rgb8", "rg8", "r8", "depth")


def _finite(values: list[float]) -> list[float]:
    if not all(math.isfinite(v) for v in values):
        raise ValueError("must contain only finite numbers (no NaN or Inf)")
    return values


def _finite_matrix(rows: list[list[float]]) -> list[list[float]]:
    for row in rows:
        _finite(row)
    return rows


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3), AfterValidator(_finite)]
Row4 = Annotated[list[float], Field(min_length=4, max_length=4)]
Mat4 = Annotated[list[Row4], Field(min_length=4, max_length=4), AfterValidator(_finite_matrix)]
Color3 = Annotated[list[Annotated[float, Field(ge=0.0, le=1e4)]], Field(min_length=3, max_length=3)]
Color4 = Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=4, max_length=4)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class CameraParams(_Model):
    """The viewing camera.

    Give either ``pose`` (4×4 camera-to-world, row-major, the camera looks down its local −Z with +Y
    up, as in glTF) or ``eye`` and ``target`` (with ``up``). With neither, the scene's first glTF
    camera is used, else the camera is framed automatically on the scene's bounds.
    """

    pose: Mat4 | None = None
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 = Field(default_factory=lambda: [0.0, 1.0, 0.0])
    yfov_deg: float = Field(default=45.0, gt=0.5, lt=179.0, description="vertical field of view")
    znear: FiniteFloat | None = Field(default=None, gt=0, description="auto-fitted when omitted")
    zfar: FiniteFloat | None = Field(default=None, gt=0, description="auto-fitted when omitted")

    @model_validator(mode="after")
    def _one_way(self) -> CameraParams:
        if self.pose is not None and (self.eye is not None or self.target is not None):
            raise ValueError("give either pose or eye/target, not both")
        if (self.eye is None) != (self.target is None):
            raise ValueError("eye and target go together")
        if self.znear is not None and self.zfar is not None and self.zfar <= self.znear:
            raise ValueError("zfar must be greater than znear")
        return self


class LightParams(_Model):
    """One light. Its pose is given in one of three ways.

    - ``pose``: 4×4 light-to-world matrix; the light sits at the translation and looks down its
      local −Z (glTF ``KHR_lights_punctual``);
    - ``position`` and/or ``direction`` (the way the light shines);
    - ``position`` and ``target`` (the light shines from position toward target).

    A directional light needs only a direction; a point light only a position; a spot light both.
    """

    type: Literal["directional", "spot", "point"] = "directional"
    pose: Mat4 | None = None
    position: Vec3 | None = None
    direction: Vec3 | None = None
    target: Vec3 | None = None
    color: Color3 = Field(default_factory=lambda: [1.0, 1.0, 1.0])
    intensity: float = Field(default=1.0, ge=0.0, le=1e6)
    inner_cone_deg: float = Field(default=0.0, ge=0.0, lt=90.0, description="spot: half-angle")
    outer_cone_deg: float = Field(default=30.0, gt=0.0, le=89.5, description="spot: half-angle")
    range: FiniteFloat | None = Field(default=None, gt=0,
                                      description="spot/point: cut-off distance")
    cast_shadows: bool = True

    @model_validator(mode="after")
    def _pose_given_once(self) -> LightParams:
        if self.pose is not None and any(
            v is not None for v in (self.position, self.direction, self.target)
        ):
            raise ValueError("give either pose or position/direction/target, not both")
        if self.direction is not None and self.target is not None:
            raise ValueError("give either direction or target, not both")
        if self.inner_cone_deg >= self.outer_cone_deg and self.type == "spot":
            raise ValueError("inner_cone_deg must be smaller than outer_cone_deg")
        return self


class BiasParams(_Model):
    """Depth bias, in shadow-map texels so that results do not change with the scene's scale.

    The compare uses ``receiver_depth - bias <= stored_depth`` with
    ``bias = texel * (constant + slope * min(tan(acos(N·L)), slope_max)) + quantisation``, where
    ``texel`` is the world size of one shadow-map texel at the receiver and ``quantisation`` is
    ``quantisation_steps`` steps of the depth encoding. ``normal_offset`` moves the lookup point
    along the surface normal by that many texels (scaled by sin of the light angle), and
    ``polygon_offset`` adds ``factor × depth slope + units × encoding step`` to the stored depth in
    the light pass (glPolygonOffset's formula).
    """

    constant: float = Field(default=0.5, ge=0.0, le=100.0)
    slope: float = Field(default=1.0, ge=0.0, le=100.0)
    slope_max: float = Field(default=10.0, gt=0.0, le=1000.0)
    normal_offset: float = Field(default=0.0, ge=0.0, le=100.0)
    polygon_offset: tuple[float, float] = (0.0, 0.0)
    quantisation_steps: float = Field(default=1.5, ge=0.0, le=100.0)


class ShadowParams(_Model):
    """How shadows are computed."""

    encoding: Encoding = "depth"
    map_size: int | Literal["auto"] = Field(
        default="auto",
        description="texels per side (power of two), or 'auto': the smallest power of two whose "
        "texel covers at most half a camera pixel on the visible receivers",
    )
    max_map_size: int = Field(default=4096, ge=16, le=16384)
    filter: Literal["hard", "pcf"] = "pcf"
    pcf_kernel: int = Field(
        default=1, ge=1, le=9,
        description="odd kernel width in taps; with the depth encoding each tap is a hardware "
        "bilinear 2x2 compare",
    )
    bias: BiasParams = Field(default_factory=BiasParams)
    cascades: int | Literal["auto"] = Field(
        default="auto",
        description="directional lights: shadow maps along the view (cascaded shadow maps), "
        "from 1 to max_cascades, or 'auto': one map when it gives at most about one camera "
        "pixel per texel on the nearest visible receiver, else the fewest cascades that do "
        "(up to max_cascades)",
    )
    max_cascades: int = Field(default=MAX_CASCADES, ge=1, le=MAX_CASCADES,
                              description="most cascades 'auto' may choose per light")
    cascade_split: float = Field(
        default=0.8, ge=0.0, le=1.0,
        description="the practical split scheme's blend: 1 splits the view distance "
        "logarithmically, 0 uniformly",
    )
    cascade_blend: float = Field(
        default=0.1, ge=0.0, le=0.5,
        description="fraction of each cascade's depth range, at its far end, over which its "
        "shadow fades into the next cascade's",
    )
    stable_cascades: bool = Field(
        default=False,
        description="fit each cascade to its whole slice of the view (a sphere) and snap it to "
        "whole texels, so that shadows do not shimmer as the camera moves; coarser texels",
    )
    debug_cascades: bool = Field(
        default=False, description="tint the colour output by the cascade each pixel reads")

    @model_validator(mode="after")
    def _sizes(self) -> ShadowParams:
        if isinstance(self.map_size, int):
            if self.map_size < 16 or self.map_size > 16384 or self.map_size & (self.map_size - 1):
                raise ValueError("map_size must be a power of two from 16 to 16384, or 'auto'")
            if self.map_size > self.max_map_size:
                raise ValueError("map_size must not exceed max_map_size")
        if self.pcf_kernel % 2 == 0:
            raise ValueError("pcf_kernel must be odd")
        if self.cascades != "auto" and not 1 <= self.cascades <= self.max_cascades:
            raise ValueError("cascades must be from 1 to max_cascades, or 'auto'")
        return self


def _default_outputs() -> list[Output]:
    return ["color"]


class RenderParams(_Model):
    """One render request (the JSON body of ``params`` in the CLI and the HTTP API)."""

    width: int = Field(default=640, ge=1, le=16384)
    height: int = Field(default=480, ge=1, le=16384)
    camera: CameraParams | None = None
    lights: list[LightParams] | None = Field(
        default=None, description="omitted: the file's KHR_lights_punctual lights, else one default"
    )
    ambient: Color3 = Field(default_factory=lambda: [0.25, 0.25, 0.25])
    background: Color4 = Field(default_factory=lambda: [1.0, 1.0, 1.0, 1.0])
    specular: float = Field(default=0.25, ge=0.0, le=10.0)
    shininess: float = Field(default=32.0, ge=1.0, le=4096.0)
    shadows: ShadowParams = Field(default_factory=ShadowParams)
    outputs: list[Output] = Field(default_factory=_default_outputs, min_length=1)
    alpha: bool = Field(default=False, description="color output with an alpha channel")
    ground: bool = Field(
        default=False, description="add a ground plane under the scene to receive its shadows"
    )
    reference: bool = Field(default=False, description="also trace the ray-traced reference")
    optimize: bool = Field(
        default=True, description="leave out work the scene does not need (render plan)"
    )

    @model_validator(mode="after")
    def _unique_outputs(self) -> RenderParams:
        self.outputs = list(dict.fromkeys(self.outputs))
        return self


EXAMPLE_PARAMS: dict = {
    "width": 640,
    "height": 480,
    "camera": {"eye": [3, 2.5, 4], "target": [0, 0.5, 0], "yfov_deg": 45},
    "lights": [{"type": "directional", "direction": [-0.4, -1.0, -0.3], "intensity": 1.0}],
    "shadows": {"encoding": "depth", "map_size": "auto", "filter": "pcf", "pcf_kernel": 1},
    "outputs": ["color", "light_depth", "visibility"],
}
