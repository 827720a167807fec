"""The request model shared by the library, the CLI and the HTTP service.

Everything a render needs besides the scene itself: image size, camera, lights, shadow settings and
which outputs to produce. Every rule that needs no scene is checked here, and each refusal names
its field: structural ones (types, ranges, enumerations) are in the JSON Schema
(``RenderParams.model_json_schema()``, the service's OpenAPI document), and the cross-field ones
JSON Schema cannot state (``znear < zfar``, ``eye`` and ``target`` together, a pose's last row,
...) are written in the descriptions of the fields they concern. What depends on the scene (a
directional light placed at the scene's centre, say) is decided when the request is resolved
against it, see :mod:`renderer.lights` and :mod:`renderer.camera`.

Lights are a discriminated union on ``type`` (:class:`DirectionalLight`, :class:`SpotLight`,
:class:`PointLight`), each with exactly its own fields. From Python a dict or a model validates,
and a dict without ``type`` is a directional light; JSON input (``model_validate_json``, the
HTTP service) must name the ``type``.
"""

from __future__ import annotations

import json
import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    WithJsonSchema,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from .limits import MAX_CASCADES, MAX_LIGHTS, MIN_MAP_SIZE

Encoding = Literal["rgba8", "rgb8", "rg8", "r8", "depth"]
Output = Literal["color", "light_depth", "visibility", "depth"]
FloatFormat = Literal["png16", "exr"]
ENCODINGS: tuple[str, ...] = ("rgba8", "rgb8", "rg8", "r8", "depth")
OUTPUTS: tuple[str, ...] = ("color", "light_depth", "visibility", "depth")
#: Shadow-map sides a request may fix (``map_size``): powers of two.
MAP_SIZES: tuple[int, ...] = tuple(2**k for k in range(4, 15))  # 16 .. 16384


def _integer(value: Any) -> Any:
    """JSON Schema's integer: 39.0 is one (a number with no fraction), true is not.

    Strict validation would refuse 39.0, and a Literal of ints takes True as 1 (True == 1 in
    Python) even in strict mode.
    """
    if isinstance(value, bool):
        raise PydanticCustomError("int_type", "Input should be a valid integer, not a boolean")
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Integer = Annotated[int, BeforeValidator(_integer)]




def _number_or_auto(numbers: tuple[int, ...]) -> WithJsonSchema:
    # Two typed enumerations: code generators cannot type one enum of ints and a string.
    return WithJsonSchema({"anyOf": [{"type": "integer", "enum": list(numbers)},
                                     {"type": "string", "enum": ["auto"]}]})


# One Literal each for validation (not a union with "auto"), so that an error's location is the
# field itself.
MapSize = Annotated[Literal[16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, "auto"],
                    BeforeValidator(_integer), _number_or_auto(MAP_SIZES)]
PcfKernel = Annotated[Literal[1, 3, 5, 7, 9], BeforeValidator(_integer)]
Cascades = Annotated[Literal[1, 2, 3, 4, "auto"], BeforeValidator(_integer),
                     _number_or_auto(tuple(range(1, MAX_CASCADES + 1)))]
DepthBits = Annotated[Literal[16, 32, "auto"], BeforeValidator(_integer), _number_or_auto((16, 32))]
#: Largest image side; the service's ``max_pixels`` (and ``max_image_side``) are usually lower.
MAX_IMAGE_SIDE = 16384
#: Largest magnitude of a coordinate (positions, targets, pose translations), in scene units.
#: The renderer works in float64 relative to the scene's centre, and refuses a view direction
#: shorter than 1e-12 of the position's magnitude, so a unit direction needs positions below
#: 1e12; 1e11 leaves a margin (and is far beyond geographic coordinates in metres, ~1e7).
MAX_COORDINATE = 1e11

assert MIN_MAP_SIZE == MAP_SIZES[0]


def _finite(values: list[float]) -> list[float]:
    if not all(math.isfinite(v) for v in values):
        raise ValueError("must contain only finite numbers (no NaN or Inf)")
    return values


def _finite_matrix(rows: list[list[float]]) -> list[list[float]]:
    for row in rows:
        _finite(row)
    return rows


Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Vec3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3), AfterValidator(_finite)]
Row4 = Annotated[list[Coordinate], Field(min_length=4, max_length=4)]
Mat4 = Annotated[list[Row4], Field(min_length=4, max_length=4), AfterValidator(_finite_matrix)]
Color3 = Annotated[list[Annotated[float, Field(ge=0.0, le=1e4)]], Field(min_length=3, max_length=3)]
Color4 = Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=4, max_length=4)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]

POSE_RULES = (
    "Row-major 4×4, the last row [0, 0, 0, 1]; its 3×3 part must be invertible and not mirrored "
    "(positive determinant). Scale and shear are removed (the nearest rotation is used, with a "
    "warning)."
)
_IDENTITY_POSE: Any = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 6.0],
                  [0.0, 0.0, 0.0, 1.0]]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _refuse(model: str, problems: list[tuple[str, str, Any]]) -> None:
    """Raise one ValidationError whose errors sit at the named fields (not at the model), so
    that each cross-field refusal names its field (``/camera/zfar`` over HTTP)."""
    if problems:
        raise ValidationError.from_exception_data(model, [
            InitErrorDetails(type=PydanticCustomError("cross_field", message), loc=(name,),
                             input=value)
            for name, message, value in problems
        ])


def pose_problem(pose: list[list[float]]) -> str | None:
    """Why a 4×4 pose has no orientation, or None (the check of
    :func:`renderer.camera.orthonormalize_pose`, without a scene)."""
    m = np.asarray(pose, np.float64)
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        return "the pose's last row must be [0, 0, 0, 1]"
    r = m[:3, :3]
    s = np.linalg.svd(r, compute_uv=False)
    if s[-1] <= 1e-9 * max(s[0], 1e-300) or np.linalg.det(r) <= 0:
        return "the pose is singular or mirrored: it has no orientation"
    return None


def _zero_length(v: list[float]) -> bool:
    # numpy's norm, as the resolver computes it (components near 1e-160 square to zero).
    n = float(np.linalg.norm(np.asarray(v, np.float64)))
    return not n > 1e-300


def _same_point(a: list[float], b: list[float]) -> bool:
    # The resolver's test (geometry.pose_from_direction): no direction shorter than 1e-12 of
    # the position's magnitude.
    pa = np.asarray(a, np.float64)
    n = float(np.linalg.norm(np.asarray(b, np.float64) - pa))
    return not n > 1e-12 * max(1.0, float(np.max(np.abs(pa))))


class CameraParams(_Model):
    """The viewing camera.

    Give either ``pose`` (4×4 camera-to-world, row-major, the camera looks down its local −Z with +Y
    up, as in glTF) or ``eye`` and ``target`` (with ``up``). With neither, the scene's first glTF
    camera is used, else the camera is framed automatically on the scene's bounds. ``projection``
    picks a perspective camera (``yfov_deg``) or an orthographic one (``ymag``).
    """

    # Whole-object examples: the fields' own examples together would break the rules between
    # them (pose with eye), and API tools build an example from them where there is none.
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"eye": [3.0, 2.5, 4.0], "target": [0.0, 0.5, 0.0], "yfov_deg": 45.0},
        {"pose": _IDENTITY_POSE, "znear": 0.1, "zfar": 100.0},
        {"eye": [0.0, 6.0, 0.5], "target": [0.0, 0.0, 0.0], "projection": "orthographic",
         "ymag": 2.0},
    ]})

    pose: Mat4 | None = Field(
        default=None,
        description="camera-to-world matrix (scene units); the camera looks down its local −Z "
        "with +Y up, as in glTF. Not with eye/target. " + POSE_RULES,
        examples=[_IDENTITY_POSE],
    )
    eye: Vec3 | None = Field(
        default=None,
        description="camera position (scene units); goes with target, not with pose",
        examples=[[3.0, 2.5, 4.0]],
    )
    target: Vec3 | None = Field(
        default=None,
        description="the point the camera looks at (scene units); goes with eye, and must differ "
        "from it (by more than 1e-12 of eye's largest coordinate)",
        examples=[[0.0, 0.5, 0.0]],
    )
    up: Vec3 = Field(
        default_factory=lambda: [0.0, 1.0, 0.0],
        description="world direction that appears up in the picture (with eye/target; any "
        "length). Along the view direction, or zero, it is replaced (with a warning)",
        examples=[[0.0, 1.0, 0.0]],
    )
    projection: Literal["perspective", "orthographic"] | None = Field(
        default=None,
        description="'perspective' (with yfov_deg) or 'orthographic' (parallel rays, with "
        "ymag); omitted: the file camera's when that camera is used, else perspective",
        examples=["orthographic"],
    )
    yfov_deg: float = Field(default=45.0, gt=0.5, lt=179.0,
                            description="vertical field of view, degrees (perspective only)",
                            examples=[45.0])
    ymag: FiniteFloat | None = Field(
        default=None, ge=1e-9, le=MAX_COORDINATE,
        description="orthographic only: half the picture's height (scene units, as glTF's "
        "ymag; the width follows the image's aspect); omitted: the scene's bounding sphere "
        "fills the picture",
        examples=[2.0],
    )
    znear: FiniteFloat | None = Field(
        default=None, ge=1e-9, le=MAX_COORDINATE,
        description="near clip distance along the view axis (scene units); fitted to the scene "
        "when omitted. With zfar: must be smaller than zfar",
        examples=[0.1],
    )
    zfar: FiniteFloat | None = Field(
        default=None, ge=1e-9, le=MAX_COORDINATE,
        description="far clip distance along the view axis (scene units); fitted to the scene "
        "when omitted. With znear: must be greater than znear",
        examples=[100.0],
    )

    @model_validator(mode="after")
    def _one_way(self) -> CameraParams:
        problems: list[tuple[str, str, Any]] = []
        if self.pose is not None:
            for name in ("eye", "target"):
                if getattr(self, name) is not None:
                    problems.append((name, "give either pose or eye/target, not both",
                                     getattr(self, name)))
            if not problems and (why := pose_problem(self.pose)):
                problems.append(("pose", why, self.pose))
        elif self.eye is not None and self.target is None:
            problems.append(("target", "eye and target go together: target is missing", None))
        elif self.target is not None and self.eye is None:
            problems.append(("eye", "eye and target go together: eye is missing", None))
        elif self.eye is not None and self.target is not None and _same_point(self.eye,
                                                                                self.target):
            problems.append(("target", "target must differ from eye", self.target))
        if self.znear is not None and self.zfar is not None and self.zfar <= self.znear:
            problems.append(("zfar", "zfar must be greater than znear", self.zfar))
        if self.ymag is not None and self.projection != "orthographic":
            problems.append(("ymag", "ymag goes with projection 'orthographic'", self.ymag))
        if self.projection == "orthographic" and "yfov_deg" in self.model_fields_set:
            problems.append(("yfov_deg", "yfov_deg is a perspective camera's: an orthographic "
                             "one takes ymag", self.yfov_deg))
        _refuse("CameraParams", problems)
        return self


_LIGHT_COLOR = Field(default_factory=lambda: [1.0, 1.0, 1.0],
                     description="linear RGB multiplier of the light (0 to 10000 each)",
                     examples=[[1.0, 0.95, 0.9]])
_LIGHT_INTENSITY = Field(default=1.0, ge=0.0, le=1e6,
                         description="scale of the diffuse and specular terms (unitless; 1 = the "
                         "surface's base colour at normal incidence)", examples=[1.0])
_CAST_SHADOWS = Field(default=True, description="draw a shadow map for this light; false: it "
                      "lights everything it reaches", examples=[True])
_RANGE = Field(default=None, ge=1e-6, le=MAX_COORDINATE,
               description="cut-off distance (scene units): light fades to zero there with "
               "glTF's smooth window; omitted: unlimited", examples=[20.0])


class _LightBase(_Model):
    def _pose_problems(self) -> list[tuple[str, str, Any]]:
        problems: list[tuple[str, str, Any]] = []
        pose = getattr(self, "pose", None)
        if pose is not None:
            for name in ("position", "direction", "target"):
                if getattr(self, name, None) is not None:
                    problems.append((name, "give either pose or position/direction/target, "
                                     "not both", getattr(self, name)))
            if not problems and (why := pose_problem(pose)):
                problems.append(("pose", why, pose))
            return problems
        position = getattr(self, "position", None)
        direction = getattr(self, "direction", None)
        target = getattr(self, "target", None)
        if direction is not None and target is not None:
            problems.append(("target", "give either direction or target, not both", target))
        elif direction is not None and _zero_length(direction):
            problems.append(("direction", "direction has zero length", direction))
        elif target is not None and position is None:
            problems.append(("position", "target needs a position", None))
        elif target is not None and position is not None and _same_point(position, target):
            problems.append(("target", "target must differ from position", target))
        return problems


class DirectionalLight(_LightBase):
    """A light infinitely far away (the sun): parallel rays along ``direction``.

    Its way is one of ``direction``; ``position`` and ``target`` (it shines from position toward
    target); ``position`` alone (toward the scene's centre); ``pose`` (along its local −Z); or
    nothing (a default from above and to the side).
    """

    model_config = ConfigDict(json_schema_extra=lambda s: _light_schema(s, [
        {"type": "directional", "direction": [-0.5, -1.0, 0.2]},
        {"type": "directional", "position": [2.0, 5.0, 1.0], "target": [0.0, 0.0, 0.0]}]))

    type: Literal["directional"] = Field(default="directional",
                                         description="the light's kind", examples=["directional"])
    pose: Mat4 | None = Field(
        default=None, description="light-to-world matrix: the light shines down its local −Z "
        "(glTF KHR_lights_punctual). Not with position/direction/target. " + POSE_RULES,
        examples=[_IDENTITY_POSE])
    position: Vec3 | None = Field(
        default=None, description="a point on the light's axis (scene units): with target, the "
        "light shines from it toward target; alone, toward the scene's centre (which it must not "
        "be at)", examples=[[2.0, 5.0, 1.0]])
    direction: Vec3 | None = Field(
        default=None, description="the way the light travels (any non-zero length); not with "
        "target", examples=[[-0.5, -1.0, 0.2]])
    target: Vec3 | None = Field(
        default=None, description="the point the light shines toward, from position (needs "
        "position, must differ from it; not with direction)", examples=[[0.0, 0.0, 0.0]])
    color: Color3 = _LIGHT_COLOR
    intensity: float = _LIGHT_INTENSITY
    cast_shadows: bool = _CAST_SHADOWS

    @model_validator(mode="after")
    def _pose_given_once(self) -> DirectionalLight:
        _refuse("DirectionalLight", self._pose_problems())
        return self


class SpotLight(_LightBase):
    """A cone of light from ``position``: ``position`` with ``direction`` or ``target``, or
    ``pose``."""

    model_config = ConfigDict(json_schema_extra=lambda s: _light_schema(s, [
        {"type": "spot", "position": [-2.0, 4.0, 2.0], "target": [0.0, 0.0, 0.0],
         "outer_cone_deg": 35.0, "inner_cone_deg": 20.0}]))

    type: Literal["spot"] = Field(default="spot", description="the light's kind",
                                  examples=["spot"])
    pose: Mat4 | None = Field(
        default=None, description="light-to-world matrix: the light sits at the translation and "
        "shines down its local −Z (glTF KHR_lights_punctual). Not with "
        "position/direction/target. " + POSE_RULES, examples=[_IDENTITY_POSE])
    position: Vec3 | None = Field(
        default=None, description="where the light sits (scene units); required unless pose is "
        "given", examples=[[-2.0, 4.0, 2.0]])
    direction: Vec3 | None = Field(
        default=None, description="the cone's axis (any non-zero length); one of direction or "
        "target is required unless pose is given", examples=[[0.5, -1.0, -0.5]])
    target: Vec3 | None = Field(
        default=None, description="the point the cone's axis passes through (scene units; must "
        "differ from position); instead of direction", examples=[[0.0, 0.0, 0.0]])
    color: Color3 = _LIGHT_COLOR
    intensity: float = _LIGHT_INTENSITY
    inner_cone_deg: float = Field(
        default=0.0, ge=0.0, lt=90.0,
        description="half-angle of the fully lit core, degrees; must be smaller than "
        "outer_cone_deg", examples=[20.0])
    outer_cone_deg: float = Field(
        default=30.0, gt=0.0, le=89.5,
        description="half-angle where the light ends, degrees (above 60 the map is a cube)",
        examples=[35.0])
    range: FiniteFloat | None = _RANGE
    cast_shadows: bool = _CAST_SHADOWS

    @model_validator(mode="after")
    def _pose_given_once(self) -> SpotLight:
        problems = self._pose_problems()
        if self.pose is None and not problems:
            if self.position is None:
                problems.append(("position", "a spot light needs a position (or a pose)", None))
            if self.direction is None and self.target is None:
                problems.append(("direction", "a spot light needs a direction or a target (or "
                                 "a pose)", None))
        if self.inner_cone_deg >= self.outer_cone_deg:
            problems.append(("inner_cone_deg", "inner_cone_deg must be smaller than "
                             "outer_cone_deg", self.inner_cone_deg))
        _refuse("SpotLight", problems)
        return self


class PointLight(_LightBase):
    """A light shining every way from ``position`` (or a pose's translation); shadows from a
    cube map."""

    model_config = ConfigDict(json_schema_extra=lambda s: _light_schema(s, [
        {"type": "point", "position": [1.0, 3.0, 1.0], "range": 20.0}]))

    type: Literal["point"] = Field(default="point", description="the light's kind",
                                   examples=["point"])
    pose: Mat4 | None = Field(
        default=None, description="light-to-world matrix; only its translation matters. Not "
        "with position. " + POSE_RULES, examples=[_IDENTITY_POSE])
    position: Vec3 | None = Field(
        default=None, description="where the light sits (scene units); required unless pose is "
        "given", examples=[[1.0, 3.0, 1.0]])
    color: Color3 = _LIGHT_COLOR
    intensity: float = _LIGHT_INTENSITY
    range: FiniteFloat | None = _RANGE
    cast_shadows: bool = _CAST_SHADOWS

    @model_validator(mode="after")
    def _pose_given_once(self) -> PointLight:
        problems = self._pose_problems()
        if self.pose is None and self.position is None:
            problems.append(("position", "a point light needs a position (or a pose)", None))
        _refuse("PointLight", problems)
        return self


def _light_schema(schema: dict[str, Any], examples: list[dict[str, Any]]) -> None:
    # ``type`` has a default in Python (SpotLight(position=...) needs no type=), but JSON must
    # name it: the discriminator of the union below.
    schema["required"] = ["type", *[r for r in schema.get("required", []) if r != "type"]]
    schema["examples"] = examples


#: One light of a request: a discriminated union on ``type``.
LightParams = Annotated[DirectionalLight | SpotLight | PointLight, Field(discriminator="type")]
_LIGHT: TypeAdapter[LightParams] = TypeAdapter(LightParams)


def _typed(value: Any) -> Any:
    if isinstance(value, dict) and "type" not in value:
        return {**value, "type": "directional"}
    return value


def light_params(value: Any) -> LightParams:
    """A light from a dict (without ``type``: directional) or a light model.

    Raises
    ------
    pydantic.ValidationError
    """
    return _LIGHT.validate_python(_typed(value))


class BiasParams(_Model):
    """Depth bias, in shadow-map texels so that results do not change with the scene's scale.

    The compare uses ``receiver_depth - bias <= stored_depth`` with
    ``bias = texel * (constant + slope * min(tan(acos(N·L)), slope_max)) + quantisation``, where
    ``texel`` is the world size of one shadow-map texel at the receiver and ``quantisation`` is
    ``quantisation_steps`` steps of the depth encoding. Every texel a lookup reads is compared
    against the receiver's plane at that texel's centre, where the light pass stored its depth,
    so a planar receiver needs no slope term to stay free of acne: ``slope`` covers curved
    surfaces, whose neighbouring triangles leave their plane. ``normal_offset`` moves the lookup
    point along the surface normal by that many texels (scaled by sin of the light angle), and
    ``polygon_offset`` adds ``factor × depth slope + units × encoding step`` to the stored depth in
    the light pass (glPolygonOffset's formula).
    """

    constant: float = Field(default=0.5, ge=0.0, le=100.0,
                            description="constant bias, texels", examples=[0.5])
    slope: float = Field(default=0.25, ge=0.0, le=100.0,
                         description="slope-scaled bias, texels per unit tan(angle to the light)",
                         examples=[0.25])
    slope_max: float = Field(default=10.0, gt=0.0, le=1000.0,
                             description="largest tan(angle) the slope term uses (unitless)",
                             examples=[10.0])
    normal_offset: float = Field(default=0.0, ge=0.0, le=100.0,
                                 description="lookup point moved along the normal, texels "
                                 "(times sin of the light angle)", examples=[0.0])
    polygon_offset: tuple[Annotated[float, Field(ge=-1000.0, le=1000.0)],
                          Annotated[float, Field(ge=-1000.0, le=1000.0)]] = Field(
        default=(0.0, 0.0),
        description="[factor, units] of glPolygonOffset in the light pass: factor × depth slope "
        "+ units × encoding step added to the stored depth",
        examples=[[0.0, 0.0]],
    )
    quantisation_steps: float = Field(default=1.5, ge=0.0, le=100.0,
                                      description="bias in steps of the depth encoding (its "
                                      "resolution: 2^-8 for r8, 2^-24 for depth)", examples=[1.5])


class ShadowParams(_Model):
    """How shadows are computed."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"encoding": "depth", "map_size": "auto", "filter": "pcf", "pcf_kernel": 3},
        {"map_size": 256, "cascades": 1, "fit": "scene"},
    ]})

    encoding: Encoding = Field(
        default="depth",
        description="how the light pass stores depth: 'depth', a depth texture (16-bit or "
        "32-bit float, see depth_bits); 'rgba8', 'rgb8', 'rg8', 'r8', linear depth packed into "
        "that many 8-bit colour channels", examples=["depth"])
    depth_bits: DepthBits = Field(
        default="auto",
        description="bits of a map's depth texture (encoding 'depth'): 16 or 32 (float), or "
        "'auto': 16 where one 16-bit step of the map's depth range is at most an eighth of its "
        "finest texel (the quantisation bias then stays under a fifth of a texel), else 32",
        examples=["auto", 32])
    map_size: MapSize = Field(
        default="auto",
        description="texels per side (a power of two, at most the service's max_map_size), or "
        "'auto': the smallest power of two whose texel covers at most half a camera pixel on "
        "the visible receivers, and at most one pixel along its stretch on their flat faces "
        "lit at a grazing angle (one power of two more at the most), up to max_map_size",
        examples=["auto", 1024],
    )
    max_map_size: Integer = Field(
        default=4096, ge=16, le=16384,
        description="largest side 'auto' may choose, texels (held to the service's own "
        "max_map_size, with a warning); an explicit map_size is not bounded by it",
        examples=[4096])
    filter: Literal["hard", "pcf"] = Field(
        default="pcf", description="'hard': one compare per pixel; 'pcf': percentage-closer "
        "filtering over pcf_kernel × pcf_kernel taps", examples=["pcf"])
    pcf_kernel: PcfKernel = Field(
        default=1,
        description="odd kernel width in taps (pcf only); with the depth encoding each tap is a "
        "bilinear 2x2 compare, each texel against the receiver's plane at its centre",
        examples=[3],
    )
    bias: BiasParams = Field(default_factory=BiasParams, description="depth bias, in texels")
    cascades: Cascades = Field(
        default="auto",
        description="directional lights: shadow maps along the view (cascaded shadow maps), "
        "1 to 4, or 'auto': one map when it gives at most about one camera pixel per texel on "
        "the nearest visible receiver, else the fewest cascades that do (up to max_cascades). "
        "With fit 'scene': 'auto' or 1",
        examples=["auto", 3],
    )
    max_cascades: Integer = Field(default=MAX_CASCADES, ge=1, le=MAX_CASCADES,
                              description="most cascades 'auto' may choose per light",
                              examples=[MAX_CASCADES])
    cascade_split: float = Field(
        default=0.8, ge=0.0, le=1.0,
        description="the practical split scheme's blend (unitless): 1 splits the view distance "
        "logarithmically, 0 uniformly",
        examples=[0.8],
    )
    cascade_blend: float = Field(
        default=0.1, ge=0.0, le=0.5,
        description="fraction of each cascade's depth range, at its far end, over which its "
        "shadow fades into the next cascade's",
        examples=[0.1],
    )
    stable_cascades: bool = Field(
        default=False,
        description="fit each cascade to its whole slice of the view (a sphere) and snap it to "
        "whole texels, so that shadows do not shimmer as the camera moves; coarser texels",
        examples=[False],
    )
    debug_cascades: bool = Field(
        default=False, description="tint the colour output by the cascade each pixel reads",
        examples=[False])
    fit: Literal["view", "scene"] = Field(
        default="view",
        description="what each light's map covers: 'view', the receivers the camera sees (the "
        "sharpest map for this view); 'scene', every receiver, so that the map does not depend "
        "on the camera and one light pass serves every view of the scene (it is cached across "
        "renders, see the plan's 'light_pass'); one map per light, no cascades (cascades must "
        "be 'auto' or 1)",
        examples=["view"],
    )

    @model_validator(mode="after")
    def _one_map(self) -> ShadowParams:
        if self.fit == "scene" and self.cascades != "auto" and self.cascades > 1:
            _refuse("ShadowParams", [("cascades", "cascades follow the view: fit 'scene' has "
                                      "one map per light", self.cascades)])
        return self


def _default_outputs() -> list[Output]:
    return ["color"]


class RenderParams(_Model):
    """One render request (the JSON body of ``params`` in the CLI and the HTTP API)."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"width": 320, "height": 240, "ground": True,
         "lights": [{"type": "directional", "direction": [-0.5, -1.0, 0.2]}]},
        {"width": 320, "height": 240, "outputs": ["color", "light_depth", "visibility"],
         "camera": {"eye": [3.0, 2.5, 4.0], "target": [0.0, 0.5, 0.0]},
         "lights": [{"type": "spot", "position": [-2.0, 4.0, 2.0], "target": [0.0, 0.0, 0.0],
                     "outer_cone_deg": 35.0}],
         "shadows": {"map_size": 256, "pcf_kernel": 3}},
    ]})

    width: Integer = Field(default=640, ge=1, le=MAX_IMAGE_SIDE,
                       description="image width, pixels; width × height at most the service's "
                       "max_pixels", examples=[640])
    height: Integer = Field(default=480, ge=1, le=MAX_IMAGE_SIDE,
                        description="image height, pixels; width × height at most the "
                        "service's max_pixels", examples=[480])
    camera: CameraParams | None = Field(
        default=None, description="omitted: the file's first camera, else framed on the scene")
    lights: list[LightParams] | None = Field(
        default=None, max_length=MAX_LIGHTS,
        description="omitted: the file's KHR_lights_punctual lights, else one default "
        "directional light; [] renders with ambient light only",
        examples=[[{"type": "directional", "direction": [-0.5, -1.0, 0.2]}]],
    )
    ambient: Color3 = Field(default_factory=lambda: [0.25, 0.25, 0.25],
                            description="linear RGB ambient term, never shadowed",
                            examples=[[0.25, 0.25, 0.25]])
    background: Color4 = Field(default_factory=lambda: [1.0, 1.0, 1.0, 1.0],
                               description="RGBA (0 to 1) of pixels with no geometry",
                               examples=[[1.0, 1.0, 1.0, 1.0]])
    specular: float = Field(default=0.25, ge=0.0, le=10.0,
                            description="strength of the Blinn-Phong highlight (unitless)",
                            examples=[0.25])
    shininess: float = Field(default=32.0, ge=1.0, le=4096.0,
                             description="Blinn-Phong exponent (unitless)", examples=[32.0])
    shadows: ShadowParams = Field(default_factory=ShadowParams,
                                  description="how shadows are computed")
    outputs: list[Output] = Field(
        default_factory=_default_outputs, min_length=1, max_length=len(OUTPUTS),
        description="what to compute and return (repeats are ignored): 'color', 'light_depth' "
        "(each light's map), 'visibility' (each light's shadow factor), 'depth' (camera depth)",
        examples=[["color", "light_depth"]])
    alpha: bool = Field(default=False, description="color output with an alpha channel",
                        examples=[False])
    ground: bool = Field(
        default=False, description="add a ground plane under the scene to receive its shadows",
        examples=[True])
    reference: bool = Field(default=False, description="also trace the ray-traced reference "
                            "(needs embreex) and return the error metrics", examples=[False])
    optimize: bool = Field(
        default=True, description="leave out work the scene does not need (render plan)",
        examples=[True])
    float_format: FloatFormat = Field(
        default="png16",
        description="how the depth and visibility outputs are written (HTTP parts, the CLI's "
        "files): 'png16', 16-bit grayscale PNG (visibility round(v*65535), depth normalised "
        "over the image's depth range); 'exr', OpenEXR with raw float32 values (depth in "
        "scene units in channel Z, visibility 0..1 in channel Y, NaN where there is no "
        "geometry), one file per light like the PNGs",
        examples=["png16"],
    )

    @field_validator("lights", mode="before")
    @classmethod
    def _default_light_type(cls, value: Any, info: ValidationInfo) -> Any:
        # From Python a light without a type is directional; JSON (the HTTP API) must say.
        if info.mode == "python" and isinstance(value, list):
            return [_typed(v) for v in value]
        return value

    @model_validator(mode="after")
    def _unique_outputs(self) -> RenderParams:
        self.outputs = list(dict.fromkeys(self.outputs))
        return self


class RepeatedKey(ValueError):
    """A JSON object of a request names a key twice (:func:`load_json`).

    JSON leaves the meaning open (RFC 8259: most parsers keep the last value, some refuse), and
    keeping one silently renders something the sender did not all ask for: two ``lights``
    lists, say, of which the first would be dropped.

    Attributes
    ----------
    path : tuple of str or int
        Where the repeated key is: object keys and list indices from the top, the key last.
    """

    def __init__(self, path: tuple[str | int, ...]) -> None:
        self.path = path
        where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path[:-1])
        super().__init__(f"the key {path[-1]!r} is given twice in one object"
                         + (f" (at {where.lstrip('.')})" if where else ""))


class _Repeated(dict[str, Any]):
    """A JSON object that named a key more than once, and the first such key."""

    repeated: str


def _marked(out: dict[str, Any], pairs: list[tuple[str, Any]]) -> _Repeated:
    """``out``, built from ``pairs`` that name a key more than once, marked with the first."""
    marked = _Repeated(out)
    seen: set[str] = set()
    for key, _ in pairs:
        if key in seen:
            marked.repeated = key
            break
        seen.add(key)
    return marked


def _repeated_path(value: Any) -> tuple[str | int, ...] | None:
    """The path of the first repeated key under ``value`` (depth first), or None."""
    stack: list[tuple[Any, tuple[str | int, ...]]] = [(value, ())]
    while stack:
        node, path = stack.pop()
        if isinstance(node, _Repeated):
            return (*path, node.repeated)
        if isinstance(node, dict):
            stack.extend((v, (*path, k)) for k, v in reversed(node.items()))
        elif isinstance(node, list):
            stack.extend((v, (*path, i)) for i, v in reversed(list(enumerate(node))))
    return None


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not allowed (numbers must be finite)")


def load_json(text: str | bytes) -> Any:
    """A request's JSON text (params, a batch manifest's line) as Python values: ``json.loads``
    without ``NaN`` and ``Infinity`` (not JSON) and without a key given twice in one object.

    Raises
    ------
    RepeatedKey
        An object names a key twice.
    ValueError
        Not JSON (``json.JSONDecodeError``), ``NaN`` or ``Infinity``, an integer of more digits
        than Python converts.
    RecursionError
        Nested deeper than the parser goes.
    """
    repeated = False

    def json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        nonlocal repeated
        out = dict(pairs)
        if len(out) == len(pairs):
            return out
        repeated = True
        return _marked(out, pairs)

    value = json.loads(text, object_pairs_hook=json_object, parse_constant=_no_constant)
    if repeated:  # only then is the tree walked, for the first repeated key's path
        path = _repeated_path(value)
        assert path is not None
        raise RepeatedKey(path)
    return value


def parse_json(text: str | bytes) -> RenderParams:
    """Validate request JSON strictly: JSON types as they are (no ``0`` for a boolean, no
    ``"1"`` for a number, no ``false`` for a number), every light with its ``type``, no key
    given twice in one object (:class:`RepeatedKey`, reported at its path).

    Raises
    ------
    pydantic.ValidationError
    """
    try:
        load_json(text)
    except RepeatedKey as exc:
        raise ValidationError.from_exception_data("RenderParams", [InitErrorDetails(
            type=PydanticCustomError("repeated_key", str(exc)), loc=exc.path,
            input=exc.path[-1])]) from None
    except (ValueError, RecursionError):
        pass  # not JSON, or no finite number: the model's own error says where
    return RenderParams.model_validate_json(text, strict=True)


EXAMPLE_PARAMS: dict = {
    "width": 640,
    "height": 480,
    "camera": {"eye": [3, 2.5, 4], "target": [0, 0.5, 0], "yfov_deg": 45},
    "lights": [{"type": "directional", "direction": [-0.4, -1.0, -0.3], "intensity": 1.0}],
    "shadows": {"encoding": "depth", "map_size": "auto", "filter": "pcf", "pcf_kernel": 1},
    "outputs": ["color", "light_depth", "visibility"],
}
