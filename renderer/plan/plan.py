"""The render plan: what must run for this scene and request, decided before any GL work.

For every light the plan fits a shadow frustum to the casters that matter and the receivers the
camera sees (:mod:`.fit`: an orthographic box for directional lights, an off-axis perspective
frustum for spot lights, six cube faces for point lights and very wide spots), picks the map
size, and lists the casters to draw (:mod:`.culling`). With ``optimize`` it also records what it
leaves out and why: objects outside the view, non-casters, casters outside a light's frustum or
behind every receiver, whole light passes and cube faces that reach nothing visible.

Every step is a pure function of the scene, the resolved camera and lights, the origin and the
request: nothing is filled in afterwards, and no input is changed. All positions here are
relative to the scene's origin (see :class:`renderer.gl.resources.GpuScene`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .cascades import CascadeFit, plan_cascades
from .context import MIN_AUTO_MAP, SHADOW_OUTPUTS, PlanContext, SizeRead, camera_mode
from .culling import near_first, select_casters
from .fit import (
    DEPTH_STEP_WARN_TEXELS,
    MIN_MAP_NEAR_SHARE,
    Fit,
    Skip,
    Subject,
    choose_method,
    depth16_is_enough,
    depth_step,
    texel_at,
)
from .geometry import corner_max, corner_min, points_product
from .instances import _frozen
from .shadow_region import (
    MAX_SPLIT_RECEIVERS,
    MIN_REGION_PIXELS,
    PairBoxes,
    ShadowRegion,
    lookup_reach,
    plan_region,
    view_projection,
)

if TYPE_CHECKING:  # the camera and lights import this package: types only, no import cycle
    from ..cache import BoundedCache
    from ..camera import Camera
    from ..lights import Light
    from ..params import RenderParams, ShadowParams
    from ..scene import Scene


@dataclass(frozen=True)
class LightShadow:
    """How one light is shadowed (three.js's ``LightShadow``): its map, or why it has none.

    Attributes
    ----------
    index : int
        The light's position in the request's list.
    light : Light
    position : ndarray, shape (3,)
        The light's position relative to the origin.
    kind : {"ortho", "perspective", "cube"} or None
        None: no light pass (see ``reason``); the light still shades, with visibility 1.
    reason : str or None
        Why there is no pass: "cast_shadows_false", "no_caster", "no_visible_receiver",
        "no_caster_in_frustum", "no_shadow_output" (with ``optimize``: the outputs asked
        for show no shadow, depth alone), "no_shadow_in_view" (no caster's shadow volume reaches a
        visible pixel of a receiver) or "below_precision" (the casters are narrower than
        float32 resolves at their distance from the origin, or a spot or point light's depth
        range rounds away; with a warning).
    view : ndarray, shape (4, 4)
        World (origin-relative) to light view (2D maps).
    proj : ndarray, shape (4, 4)
    near, far : float
        Range of the linear depth stored in the map.
    map_size : int
        Map texels per side.
    texel : tuple of float
        World size of a texel at light depth d is ``texel[0] + texel[1] * d``.
    casters : list of int
        Scene instance indices drawn into the map.
    faces : list of int
        Cube faces rendered (cube maps only).
    face_views : list of ndarray
        View matrix (4, 4) of each of the 6 faces (cube maps only).
    skipped : dict of str to int
        What the pass leaves out, by reason (non-zero counts only).
    cascades : tuple of LightShadow
        A cascaded directional light's maps, near to far (empty otherwise): each one an
        ``"ortho"`` map with its own fit, casters, ``cascade`` number and ``split``. This entry
        then describes the nearest cascade.
    cascade : int
        This map's cascade number (-1: not a cascade).
    split : tuple of float
        Camera distances (along the view axis) this cascade is chosen for: ``(near, far)``.
    blend : float
        Width of the band before ``split[1]`` where this cascade fades into the next.
    texel_pixels : float
        Camera pixels one texel of this cascade covers at its near end (0: not a cascade).
    needed : float
        The texels per side its seen receivers want at one camera pixel per texel, before
        ``max_map_size``: spot maps, the most demanding seen receiver; orthographic and cube
        maps, the nearest (as their 'auto' size weighs them); 0: not known (cascades).
    texel_depth : float
        Perspective and cube maps: the light depth of the receivers its size is chosen for (a
        typical one's); 0 for orthographic maps, whose texels are the same at every depth.
    near_clipped : int
        Perspective and cube maps: casters wholly ahead of the light that begin nearer than the
        map's near plane (:data:`~.fit.MIN_MAP_NEAR_SHARE` of its far plane), clipped from it;
        the plan warns of them.
    depth_bits : int
        Bits of the light's depth texture (every cascade's: one array texture) with the
        ``depth`` encoding, 16 or 32 (:func:`depth_bits`); 0 for the byte encodings and without
        a pass.
    one_sided : ndarray, shape (len(casters),), int8
        Per caster, the faces its draw leaves out (:func:`one_sided_casters`): +1 those wound
        clockwise in the map (GL's back faces), -1 the counter-clockwise ones, 0 none; empty
        when no caster leaves any out.
    """

    index: int
    light: Light
    position: np.ndarray
    kind: str | None = None
    reason: str | None = None
    view: np.ndarray = field(default_factory=lambda: np.eye(4))
    proj: np.ndarray = field(default_factory=lambda: np.eye(4))
    near: float = 0.0
    far: float = 1.0
    map_size: int = 0
    texel: tuple[float, float] = (0.0, 0.0)
    casters: list[int] = field(default_factory=list)
    faces: list[int] = field(default_factory=list)
    face_views: list[np.ndarray] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)
    cascades: tuple[LightShadow, ...] = ()
    cascade: int = -1
    split: tuple[float, float] = (0.0, math.inf)
    blend: float = 0.0
    texel_pixels: float = 0.0
    needed: float = 0.0
    texel_depth: float = 0.0
    near_clipped: int = 0
    depth_bits: int = 0
    one_sided: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))

    @property
    def maps(self) -> tuple[LightShadow, ...]:
        """The maps this light renders: its cascades, or itself (none without a pass)."""
        if self.kind is None:
            return ()
        return self.cascades or (self,)

    @classmethod
    def cascaded(cls, index: int, light: Light, position: np.ndarray,
                 fits: list[CascadeFit]) -> LightShadow:
        """A directional light with one map per cascade (near to far)."""
        maps = tuple(
            dataclasses.replace(
                cls.fitted(index, light, position, f.fit, f.casters, f.skipped),
                cascade=k, split=(f.slice.near, f.slice.far), blend=f.slice.blend,
                texel_pixels=f.texel_pixels)
            for k, f in enumerate(fits))
        return dataclasses.replace(maps[0], cascades=maps)

    @classmethod
    def fitted(cls, index: int, light: Light, position: np.ndarray, fit: Fit,
               casters: list[int], skipped: dict[str, int]) -> LightShadow:
        """A light with a pass: the fitted map, its casters and what it leaves out."""
        return cls(index=index, light=light, position=position, kind=fit.kind, view=fit.view,
                   proj=fit.proj, near=fit.near, far=fit.far, map_size=fit.map_size,
                   texel=fit.texel, casters=casters, faces=fit.faces, face_views=fit.face_views,
                   skipped=skipped, needed=fit.needed, near_clipped=fit.near_clipped,
                   texel_depth=fit.texel_depth)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"type": self.light.type, "shadow_map": self.kind}
        if self.kind is None:
            d["skipped_pass"] = self.reason
            return d
        d.update(
            map_size=self.map_size,
            casters=len(self.casters),
            skipped=dict(self.skipped),
            near=self.near,
            far=self.far,
            one_sided=int(np.count_nonzero(self.one_sided)),
        )
        if self.depth_bits:
            d["depth_bits"] = self.depth_bits
        if self.kind == "cube":
            d["faces"] = list(self.faces)
        if self.cascades:
            d.update(
                map_size=max(c.map_size for c in self.cascades),
                casters=len(set().union(*(c.casters for c in self.cascades))),
                cascades=[{"split": [c.split[0], c.split[1]], "blend": c.blend,
                           "map_size": c.map_size, "texel_pixels": c.texel_pixels,
                           "casters": len(c.casters),
                           "one_sided": int(np.count_nonzero(c.one_sided)),
                           "skipped": dict(c.skipped), "near": c.near, "far": c.far}
                          for c in self.cascades],
            )
            del d["skipped"], d["near"], d["far"], d["one_sided"]
        return d


@dataclass(frozen=True)
class RenderPlan:
    """Everything decided before GL work; ``to_dict`` is the report given to users.

    Attributes
    ----------
    camera : Camera
    origin : ndarray, shape (3,)
    visible : list of int
        Instances the camera pass draws, in its order: nearest first with ``optimize``
        (:func:`.culling.near_first`), else the file's.
    culled : int
        Instances it leaves out (outside the view).
    lights : list of LightShadow
        One per light, in the request's order.
    outputs : list of str
    optimize : bool
    warnings : list of str
        What the plan had to approximate (cascades cut by the map slots, maps that would need
        more than the size limit).
    fit : {"view", "scene"}
        What the maps cover: the receivers the camera sees, or all of them
        (``shadows.fit``).
    shadow_region : ShadowRegion or None
        Where on screen any light's lookup may return less than 1
        (:mod:`.shadow_region`); None without ``optimize``, below
        :data:`~.shadow_region.MIN_REGION_PIXELS` camera pixels or past
        :data:`~.shadow_region.MAX_SPLIT_RECEIVERS` visible receivers (lookups on every
        receiver), and without any map (no lookup anywhere).
    unlit_receivers : int
        Receiving instances of unlit materials left out of the maps' receivers: their colour
        shows no shadow and no ``visibility`` (or ``light_depth``) output asks for it
        (:func:`.context.shown_receivers`).
    camera_mode : {"shaded", "visibility", "depth", "none"}
        What the camera pass draws for the outputs (:func:`.context.camera_mode`).
    """

    camera: Camera
    origin: np.ndarray
    visible: list[int]
    culled: int
    lights: list[LightShadow]
    outputs: list[str]
    optimize: bool
    warnings: list[str] = field(default_factory=list)
    fit: str = "view"
    shadow_region: ShadowRegion | None = None
    unlit_receivers: int = 0
    camera_mode: str = "shaded"

    @property
    def map_lights(self) -> list[LightShadow]:
        """Every map the light pass renders, in light order: one per shadowed light, one per
        cascade for a cascaded one."""
        return [m for lp in self.lights for m in lp.maps]

    def to_dict(self) -> dict[str, Any]:
        drawn = 0 if self.camera_mode == "none" else len(self.visible)
        camera_pass: dict[str, Any] = {"drawn": drawn, "draws": self.camera_mode,
                                       "order": "near_first" if self.optimize else "file",
                                       "skipped": {"outside_view": self.culled}}
        if self.shadow_region is not None and self.map_lights:
            camera_pass["shadow_region"] = self.shadow_region.to_dict()
        if self.unlit_receivers:
            camera_pass["skipped"]["unlit_receivers"] = self.unlit_receivers
        return {
            "optimize": self.optimize,
            "camera_pass": camera_pass,
            "lights": [lp.to_dict() for lp in self.lights],
            "light_passes": len(self.map_lights),
            "fit": self.fit,
            "outputs": self.outputs,
        }


def make_plan(
    scene: Scene,
    camera: Camera,
    lights: list[Light],
    origin: np.ndarray,
    params: RenderParams,
    scene_fits: BoundedCache[SceneFitPlan] | None = None,
) -> RenderPlan:
    """Decide the passes, frusta, map sizes and draw lists of one render.

    Limits are checked before planning (:mod:`~shadowmap.renderer.limits`).

    Parameters
    ----------
    scene : Scene
    camera : Camera
        Resolved (:func:`~shadowmap.renderer.camera.resolve_camera`).
    lights : list of Light
        Resolved (:func:`~shadowmap.renderer.lights.resolve_lights`).
    origin : ndarray, shape (3,)
        World point the plan's positions are relative to (the upload's origin).
    params : RenderParams
    scene_fits : BoundedCache of SceneFitPlan, optional
        Lights already planned with ``shadows.fit: "scene"`` (:func:`scene_fit_key`): such a
        light's plan reads nothing of the camera but its 'auto' map size, so the views of one
        scene that want the same size plan it once. The plan is the same with or without it.
    """
    ctx = PlanContext.build(scene, camera, origin, params)
    n = len(scene.instances)
    # With optimize: what the camera may see, nearest first (fewer pixels shaded twice);
    # without: every instance, in the file's order.
    visible = (near_first(ctx, np.flatnonzero(ctx.in_view)).tolist() if params.optimize
               else list(range(n)))
    if params.shadows.fit == "scene":
        # Maps over every receiver, whatever the camera sees: one map per light, no cascades.
        shadow_ctx = ctx.scene_fit()
        fits = [_plan_scene_fit(shadow_ctx, scene, i, light, scene_fits)
                for i, light in enumerate(lights)]
        planned = [lp for lp, _ in fits]
        kept = [k for _, k in fits]
    else:
        planned = _cascade(ctx, [plan_light(ctx, i, light) for i, light in enumerate(lights)])
        kept = [None] * len(planned)
    region = None
    mode = camera_mode(params)
    # Past MAX_SPLIT_RECEIVERS visible receivers each one would be drawn with lookups anyway;
    # without a map, or without lookups in the camera pass, there is no lookup to leave out (nor a
    # region in the report).
    if (params.optimize and mode in ("shaded", "visibility")
            and camera.width * camera.height >= MIN_REGION_PIXELS
            and any(lp.maps for lp in planned)
            and int(ctx.receive[visible].sum()) <= MAX_SPLIT_RECEIVERS):
        planned, region = _shadow_region(ctx, planned, np.asarray(visible, np.intp), kept)
    warnings = [_resolution_warning(lp, params) for lp in planned if lp.needed > lp.map_size]
    warnings += [_precision_warning(lp) for lp in planned if lp.reason == "below_precision"]
    warnings += [_near_warning(lp) for lp in planned if lp.near_clipped]
    warnings += [_depth_step_warning(lp, params) for lp in planned if lp.kind is not None]
    return RenderPlan(
        camera=camera,
        origin=origin,
        visible=visible,
        culled=n - len(visible),
        lights=planned,
        outputs=list(params.outputs),
        optimize=params.optimize,
        warnings=[w for w in warnings if w],
        fit=params.shadows.fit,
        shadow_region=region,
        unlit_receivers=int(np.count_nonzero(ctx.arrays.receive != ctx.receive))
        if ctx.arrays is not None else 0,
        camera_mode=mode,
    )


def light_bytes(light: Light) -> bytes:
    """Everything of a resolved light that a plan reads, as bytes for a content key."""
    return b"".join([light.position.tobytes(), light.direction.tobytes(),
                     np.asarray(light.color).tobytes(),
                     repr((light.type, light.intensity, light.inner_cone, light.outer_cone,
                           light.range, light.cast_shadows)).encode()])


def scene_fit_key(ctx: PlanContext, scene: Scene, index: int, light: Light) -> str:
    """The content key of light ``index``'s plan in a scene-fit context (``""``: not kept).

    What :func:`plan_light` reads there, but for the camera: the scene, the origin, the shadow
    parameters and ``optimize``, the light, the receivers. Of the camera it reads only the
    'auto' map size (:meth:`PlanContext.map_size_for`), which the memo checks itself
    (:class:`SceneFitPlan`). A spot light's fit also reads the camera's position for its
    resolution warning, so spot lights are planned every time, and so are point lights fitted
    with a frustum.
    """
    if not scene.key or light.type == "spot":
        return ""
    from ..cache import parts_key

    # The context's map-size bound and margin come from the shadow parameters; its receivers
    # from the outputs too (:func:`.context.shown_receivers`).
    return parts_key([scene.key.encode(), np.asarray(ctx.origin, np.float64).tobytes(),
                      ctx.params.shadows.model_dump_json().encode(),
                      repr((index, ctx.optimize)).encode(), light_bytes(light),
                      np.packbits(ctx.receive).tobytes()])


@dataclass(frozen=True)
class SceneFitPlan:
    """A scene-fit light's plan and the map sizes it asked for (a :class:`~.context.SizeRead`
    per :meth:`PlanContext.map_size_for` call). Another view reuses it when each call would give
    it the same size."""

    light: LightShadow
    sizes: tuple[SizeRead, ...]
    #: Its (caster, receiver) pairs' swept boxes over every receiver, per lookup reach, made
    #: by the first view that plans a shadow region (:meth:`pairs`).
    _pairs: dict[float, PairBoxes | None] = field(default_factory=dict, compare=False,
                                                   repr=False)

    def pairs(self, ctx: PlanContext, pad_texels: float) -> PairBoxes | None:
        """:meth:`PairBoxes.every` of this light in the context's scene, made once (the memo's
        key holds what they read: the scene, the origin, the receivers, the shadow parameters)."""
        if pad_texels not in self._pairs:
            self._pairs[pad_texels] = PairBoxes.every(self.light, ctx.bounds, ctx.receive,
                                                      pad_texels)
        return self._pairs[pad_texels]

    def refit(self, ctx: PlanContext) -> LightShadow | None:
        """The kept plan for the view of ``ctx``, with what its receivers want
        (:attr:`LightShadow.needed`, of the last size asked), or None when a size differs."""
        needed = self.light.needed
        for read in self.sizes:
            got, needed = ctx.map_size_and_need(read.world, read.receivers, read.cube,
                                                read.toward, read.stretch)
            if got != read.size:
                return None
        return dataclasses.replace(self.light, needed=needed)


def _plan_scene_fit(ctx: PlanContext, scene: Scene, index: int, light: Light,
                    memo: BoundedCache[SceneFitPlan] | None
                    ) -> tuple[LightShadow, SceneFitPlan | None]:
    """:func:`plan_light` in a scene-fit context, through ``memo`` where one is given; and the
    memo's entry, where the light's plan is kept."""
    key = scene_fit_key(ctx, scene, index, light) if memo is not None else ""
    if memo is None or not key:
        return plan_light(ctx, index, light), None
    kept = memo.get(key)
    if kept is not None:
        light_plan = kept.refit(ctx)
        if light_plan is not None:
            return light_plan, kept
        memo.discard(key)  # this view wants another map size: planned again, kept instead
    sizes: list[SizeRead] = []
    planned = plan_light(dataclasses.replace(ctx, sizes_read=sizes), index, light)
    # A frustum (a point light far from the scene: fit.choose_method) reads the camera for its
    # resolution warning, as a spot's does: planned every time.
    if planned.kind == "perspective":
        return planned, None
    kept = SceneFitPlan(planned, tuple(sizes))
    memo.put(key, kept)
    return planned, kept


def _shadow_region(ctx: PlanContext, planned: list[LightShadow], visible: np.ndarray,
                   kept: list[SceneFitPlan | None]) -> tuple[list[LightShadow], ShadowRegion]:
    """Where the lights' lookups may shade (:mod:`.shadow_region`), and the lights again, less
    the passes of those whose shadows reach no visible pixel (kept when their light-depth image
    is asked for). ``kept``: per light, its scene-fit memo entry or None."""
    shadows = ctx.params.shadows
    reach = lookup_reach(shadows.pcf_kernel // 2 if shadows.filter == "pcf" else 0,
                         shadows.bias.normal_offset)
    camera = ctx.camera
    pairs = [None if k is None or lp.kind is None else k.pairs(ctx, reach)
             for lp, k in zip(planned, kept, strict=True)]
    reached, region = plan_region(planned, ctx.bounds, visible, ctx.receive,
                                  view_projection(camera, ctx.origin), camera.width,
                                  camera.height, reach, pairs)
    if "light_depth" in ctx.params.outputs:  # the light's picture is asked for: keep its pass
        return planned, region
    return [LightShadow(index=lp.index, light=lp.light, position=lp.position,
                        reason="no_shadow_in_view") if lp.kind is not None and not ok else lp
            for lp, ok in zip(planned, reached, strict=True)], region


def _resolution_warning(lp: LightShadow, params: RenderParams) -> str:
    """A map that cannot give the seen receivers the texel size they want (one camera pixel per
    texel at the nearest: :attr:`LightShadow.needed`) within ``max_map_size`` (half of it per
    cube face): what it would need, and how much coarser the limit leaves their shadows. A
    directional light's cascades, where the plan made them, are sized to the view instead."""
    top = params.shadows.max_map_size
    if lp.kind == "cube":
        top = max(top // 2, MIN_AUTO_MAP)
    if params.shadows.map_size != "auto" or lp.cascades or lp.needed <= top:
        return ""
    want = 1 << max(0, int(math.ceil(math.log2(lp.needed))))
    limit = f"max_map_size {params.shadows.max_map_size}"
    if lp.kind == "cube":
        limit += f" ({lp.map_size} per cube face)"
    hint = ""
    if params.shadows.fit == "scene":
        hint = ("; the map covers every receiver of the scene (shadows.fit \"scene\"): "
                "fit \"view\" fits it to what the camera sees")
    return (f"light {lp.index}: the {lp.light.type} light's map would need {want}x{want} "
            f"texels for its nearest visible receivers; {limit} leaves their shadows up to "
            f"{lp.needed / lp.map_size:.1f}x coarser{hint}")


def _precision_warning(lp: LightShadow) -> str:
    """A light whose map would hold rounding noise: a directional light's casters too narrow
    for their distance from the scene's centre (:data:`~.fit.MIN_RELATIVE_EXTENT`), or a spot
    or point light's depth range from its nearest caster to its deepest receiver rounded away
    (:func:`~.fit._map_depth_range`)."""
    if lp.light.type == "directional":
        return (f"light {lp.index}: no shadow: what casts it is narrower than the GPU's float32 "
                "positions resolve that far from the scene's centre (under a millionth of its "
                "distance), so its map would hold rounding noise; the light shines unshadowed")
    return (f"light {lp.index}: no shadow: the depths from the light to its nearest caster and "
            "to its deepest receiver round to one number (the scene is too small for how far "
            "out it lies), so its map would hold rounding noise; the light shines unshadowed")


def _depth_step_warning(lp: LightShadow, params: RenderParams) -> str:
    """A map whose depth steps over its depth range (nearest caster to deepest receiver) add a
    quantisation bias over :data:`~.fit.DEPTH_STEP_WARN_TEXELS` of its texels where its
    receivers are (:attr:`LightShadow.texel_depth`): the bias that keeps rounding from
    shadowing a receiver then also lifts the shadows of casters within that distance of it (one
    map over receivers orders of magnitude farther from the light than the ones it is sized
    for)."""
    shadows = params.shadows

    def texels(m: LightShadow) -> float:
        return _quantisation_world(m, params, lp.depth_bits) / max(
            texel_at(m.texel_depth, m.texel), 1e-300)

    worst = max(lp.maps, key=texels)
    q, n = _quantisation_world(worst, params, lp.depth_bits), texels(worst)
    if not n > DEPTH_STEP_WARN_TEXELS:
        return ""
    bits = (f"{lp.depth_bits}-bit{' float' if lp.depth_bits == 32 else ''} depth"
            if shadows.encoding == "depth" else f"the {shadows.encoding} encoding")
    hint = ""
    if shadows.fit == "scene":
        hint = ("; the map covers every receiver of the scene (shadows.fit \"scene\"): "
                "fit \"view\" fits its range to what the camera sees")
    return (f"light {lp.index}: the {lp.light.type} light's map stores depths from "
            f"{worst.near:.3g} to {worst.far:.3g} units ({bits}), so its quantisation bias "
            f"({shadows.bias.quantisation_steps:g} steps) is {q:.3g} units, {n:.0f} texels "
            f"where its receivers are: the shadows of casters that near to what they fall on "
            f"are lost{hint}")


def _quantisation_world(m: LightShadow, params: RenderParams, depth_bits: int) -> float:
    """Map ``m``'s quantisation bias in world units (``depth_bits``: its light's)."""
    step = depth_step(params.shadows.encoding, depth_bits)
    return params.shadows.bias.quantisation_steps * step * (m.far - m.near)


def _near_warning(lp: LightShadow) -> str:
    """A spot or point light with casters nearer to it than its map's near plane comes
    (:data:`~.fit.MIN_MAP_NEAR_SHARE` of its far plane)."""
    return (f"light {lp.index}: {lp.near_clipped} caster(s) begin nearer to the {lp.light.type} "
            f"light than its map's near plane ({lp.near:.3g} units, {MIN_MAP_NEAR_SHARE:.2g} of "
            f"its far plane at {lp.far:.3g}): what lies nearer casts no shadow")


def _cascade(ctx: PlanContext, planned: list[LightShadow]) -> list[LightShadow]:
    """Directional lights with cascades where one map is not enough (:mod:`.cascades`)."""
    out = []
    for lp in planned:
        if lp.kind != "ortho" or ctx.params.shadows.cascades == 1:
            out.append(lp)
            continue
        single = Fit(kind="ortho", view=lp.view, proj=lp.proj, near=lp.near, far=lp.far,
                     map_size=lp.map_size, texel=lp.texel)
        fits = plan_cascades(ctx, lp.light, lp.position, single)
        if fits:
            lp = LightShadow.cascaded(lp.index, lp.light, lp.position, fits)
            maps = tuple(dataclasses.replace(c, one_sided=one_sided_casters(ctx, c))
                         for c in lp.cascades)
            lp = dataclasses.replace(maps[0], cascades=maps)
            lp = dataclasses.replace(lp, depth_bits=depth_bits(ctx.params.shadows, lp))
        out.append(lp)
    return out


def depth_bits(shadows: ShadowParams, lp: LightShadow) -> int:
    """Bits of a light's depth texture: ``shadows.depth_bits``, or with ``"auto"`` 16 where
    every map of the light fits them (:func:`~.fit.depth16_is_enough`), else 32; 0 for the byte
    encodings (their colour texture is RGBA8) and for a light without a pass."""
    if shadows.encoding != "depth" or lp.kind is None:
        return 0
    if shadows.depth_bits != "auto":
        return int(shadows.depth_bits)
    return 16 if all(depth16_is_enough(m.near, m.far, m.texel) for m in lp.maps) else 32


def plan_light(ctx: PlanContext, index: int, light: Light) -> LightShadow:
    """How one light is shadowed: the steps every kind shares around its reach and fit.

    A light gets no pass when it casts no shadow, when nothing casts, when it reaches no visible
    receiver, or when no caster lies between it and one.
    """
    position = light.position - ctx.origin
    outcome = _shadow(ctx, Subject(light, position, ctx.receivers()))
    if isinstance(outcome, Skip):
        return LightShadow(index=index, light=light, position=position, reason=outcome.reason)
    fit, casters, skipped = outcome
    lp = LightShadow.fitted(index, light, position, fit, casters, skipped)
    return dataclasses.replace(lp, depth_bits=depth_bits(ctx.params.shadows, lp),
                               one_sided=one_sided_casters(ctx, lp))


def one_sided_casters(ctx: PlanContext, m: LightShadow) -> np.ndarray:
    """Which faces of each caster of map ``m`` its draw can leave out without changing a texel.

    A caster qualifies when its primitive's triangles close a surface
    (:func:`.instances.primitive_closure`; not for a texture-cut shadow), and its whole box lies
    beyond the map's near plane: then the light is outside it, and no face is clipped away to
    open it. Seen from outside a closed surface, the first face on every ray is turned toward
    the ray's origin, so the faces turned away lie behind it: they change no depth the map
    stores, and are left out (for closed casters, about half the light pass's fragments).
    Without ``optimize``, none.

    Parameters
    ----------
    ctx : PlanContext
    m : LightShadow
        One map: a light without cascades, or one cascade.

    Returns
    -------
    ndarray, shape (len(m.casters),), int8
        +1: leave out GL's back faces (the surface winds counter-clockwise seen from outside);
        -1: the front faces (it winds the other way); 0: draw both. Empty when all are 0.
    """
    empty = np.zeros(0, np.int8)
    if not ctx.optimize or ctx.arrays is None or m.kind is None or not m.casters:
        return empty
    casters = np.asarray(m.casters, np.intp)
    closure = ctx.arrays.closure()[casters]
    if not closure.any():
        return empty
    if m.kind == "cube":
        # A face frustum's part nearer than ``near`` lies within this Chebyshev distance of the
        # light (90-degree faces: within ``near`` on every axis).
        spread = max(1.0, 1.0 / abs(m.proj[0, 0]), 1.0 / abs(m.proj[1, 1]))
        lo, hi = ctx.bounds[casters, 0], ctx.bounds[casters, 1]
        gap = corner_max(np.maximum(np.maximum(lo - m.position, m.position - hi), 0.0))
        beyond = gap > m.near * spread
    else:
        corners = ctx.corners[casters]  # (K, 8, 3)
        depth = -(points_product(corners, m.view[2, :3]) + m.view[2, 3])  # view depth (K, 8)
        beyond = corner_min(depth) >= m.near
    out = np.where(beyond, closure, 0).astype(np.int8)
    return _frozen(out) if out.any() else empty


def _shadow(ctx: PlanContext, s: Subject) -> tuple[Fit, list[int], dict[str, int]] | Skip:
    """(fit, casters to draw, skip counts) of one light, or why it has no pass."""
    if not s.light.cast_shadows:
        return Skip("cast_shadows_false")
    if ctx.optimize and not SHADOW_OUTPUTS.intersection(ctx.params.outputs):
        return Skip("no_shadow_output")
    if not ctx.cast.any():
        return Skip("no_caster")
    if len(s.receivers) == 0:
        return Skip("no_visible_receiver")
    method, s = choose_method(ctx, s)
    reach = method.reach(ctx, s)
    if isinstance(reach, Skip):
        return reach
    chosen = select_casters(ctx, s.light, s.position, s.receivers, reach.in_frustum,
                            reach.depth_min, reach.far)
    if not chosen.fit.any():
        return Skip("no_caster_in_frustum")
    fit = method.fit(ctx, s, reach, chosen.fit)
    if isinstance(fit, Skip):
        return fit
    # The reach's own counts (cube faces) first, then the casters', as the report lists them.
    skipped = {k: v for k, v in {**reach.skipped, **chosen.skipped}.items() if v}
    return fit, chosen.casters, skipped
