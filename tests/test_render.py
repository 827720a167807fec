"""End-to-end renders of real glTF scenes, checked against ray-traced hard-shadow truth."""

from __future__ import annotations

import gc
import resource
import threading

import numpy as np
import pytest

from conftest import load_model
from shadowmap.renderer import RenderError, RenderParams, SceneError, load_scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.demo import demo_glb

pytestmark = pytest.mark.gl

MODELS = [
    "AlphaBlendModeTest.glb",
    "BoxTextured.glb",
    "CesiumMilkTruck.glb",
    "Duck.glb",
    "TestScene.gltf",
    "cube.glb",
]


def measure(renderer, scene, params: RenderParams):
    m = T.measure(renderer, scene, params)
    return m.metrics, m.result, m.reference


@pytest.mark.parametrize("name", MODELS)
def test_shadow_mask_matches_reference_on_real_models(renderer, models, name):
    scene = load_model(models, name)
    metrics, result, _ = measure(renderer, scene, RenderParams())
    m = metrics[0]
    assert m.pixels > 10_000
    assert m.iou >= 0.95, (name, m)
    assert result.plan["lights"][0]["shadow_map"] == "ortho"


@pytest.fixture(scope="module")
def demo():
    return load_scene(demo_glb())


DEMO_CAMERA = {"eye": [3.5, 3.0, 5.0], "target": [0.0, 0.4, 0.0]}


@pytest.mark.parametrize(
    "light, kind",
    [
        ({"type": "directional", "direction": [-0.6, -1.0, 0.25]}, "ortho"),
        ({"type": "spot", "position": [-2.5, 4.0, 1.5], "target": [0, 0, 0], "outer_cone_deg": 40},
         "perspective"),
        # A wide cone: cube faces where the seen receivers spread wider than a frustum covers,
        # one frustum around them where they do not (fit.choose_method).
        ({"type": "spot", "position": [-1.5, 2.5, 2.0], "direction": [0.3, -1, -0.2],
          "outer_cone_deg": 80}, "cube"),
        ({"type": "spot", "position": [-2.5, 4.0, 1.5], "target": [0, 0, 0], "outer_cone_deg": 80},
         "perspective"),
        ({"type": "point", "position": [-1.5, 2.5, 2.0]}, "cube"),
        ({"type": "point", "position": [-5.0, 8.0, 3.0]}, "perspective"),
    ],
)
def test_each_light_type_matches_reference(renderer, demo, light, kind):
    params = RenderParams(camera=DEMO_CAMERA, lights=[light])
    metrics, result, _ = measure(renderer, demo, params)
    assert result.plan["lights"][0]["shadow_map"] == kind
    assert metrics[0].iou >= 0.95, metrics[0]
    assert metrics[0].false_shadow_pct < 0.1


@pytest.mark.parametrize("light", [
    {"type": "directional", "direction": [-0.6, -1.0, 0.25]},
    {"type": "spot", "position": [-2.5, 4.0, 1.5], "target": [0, 0, 0], "outer_cone_deg": 40},
    {"type": "point", "position": [-1.5, 2.5, 2.0]},
])
def test_sixteen_bit_maps_shadow_like_thirty_two_bit_ones(renderer, demo, light):
    from OpenGL import GL

    out = {}
    for bits in (16, 32):
        params = RenderParams(camera=DEMO_CAMERA, lights=[light],
                              shadows={"depth_bits": bits, "map_size": 1024})
        metrics, result, _ = measure(renderer, demo, params)
        assert result.plan["lights"][0]["depth_bits"] == bits
        # The map really is a texture of that many bits, and counted at its size.
        fbs = [fb for fbs in renderer.light_pass.pool.values() for fb in fbs]
        fbs += [fb for _, fb in renderer.light_pass.cache.values()]
        fb = next(f for f in fbs if f.width == 1024 and f.depth_texture
                  and (f.nbytes // (1024 * 1024 * max(f.layers, 1))) == bits // 8)
        GL.glBindTexture(fb.target, fb.depth_texture)
        assert GL.glGetTexLevelParameteriv(fb.target, 0, GL.GL_TEXTURE_DEPTH_SIZE) == bits
        GL.glBindTexture(fb.target, 0)
        out[bits] = (metrics[0], result.visibility[..., 0])
    (m16, v16), (m32, v32) = out[16], out[32]
    assert m16.iou >= 0.95 and abs(m16.iou - m32.iou) <= 0.002, (m16, m32)
    both = np.isfinite(v16) & np.isfinite(v32)
    assert np.mean(np.abs(v16[both] - v32[both]) > 0.5) < 5e-4


def test_point_light_beside_its_casters_matches_reference(renderer):
    """A low point light whose casters fit in a narrow cone gets one frustum around them
    (plan.fit.caster_cone): the ground outside it, some of it behind the light, is lit."""
    params = RenderParams(camera={"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]},
                          lights=[{"type": "point", "position": [-2.5, 1.8, 0.0]}])
    metrics, result, _ = measure(renderer, T.ground_only_receives(), params)
    assert result.plan["lights"][0]["shadow_map"] == "perspective"
    assert metrics[0].iou >= 0.98, metrics[0]
    assert metrics[0].false_shadow_pct < 0.05, metrics[0]


def test_several_lights_have_one_map_and_one_visibility_each(renderer, demo):
    lights = [
        {"type": "directional", "direction": [-0.6, -1.0, 0.25]},
        # Close enough that its seen receivers spread past a frustum: cube faces (fit.seen_cone).
        {"type": "point", "position": [1.0, 1.8, 0.5], "intensity": 0.5},
        {"type": "spot", "position": [0, 4, 0], "direction": [0, -1, 0], "outer_cone_deg": 35},
    ]
    params = RenderParams(camera=DEMO_CAMERA, lights=lights, outputs=["color", "light_depth"])
    metrics, result, _ = measure(renderer, demo, params)
    assert result.visibility.shape == (480, 640, 3)
    assert [ld.kind for ld in result.light_depth] == ["ortho", "cube", "perspective"]
    for m in metrics:
        assert m.iou >= 0.95, m


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6])
def test_each_lights_visibility_is_its_own_whatever_the_target_layout(renderer, demo, n):
    """Visibility targets hold what their lights need (one, two or four channels, four lights
    a target): light i of an n-light render reads as it does rendered alone."""
    lights = [{"type": "directional", "direction": [-0.6 + 0.25 * i, -1.0, 0.25 - 0.1 * i],
               "intensity": 0.3} for i in range(n)]
    both = renderer.render(demo, RenderParams(camera=DEMO_CAMERA, lights=lights,
                                              outputs=["visibility"]))
    assert both.visibility.shape == (480, 640, n) and both.visibility.dtype == np.float32
    for i, light in enumerate(lights):
        alone = renderer.render(demo, RenderParams(camera=DEMO_CAMERA, lights=[light],
                                                   outputs=["visibility"]))
        np.testing.assert_array_equal(both.visibility[..., i], alone.visibility[..., 0])
        lit = np.nanmean(alone.visibility[..., 0])
        assert 0.05 < lit < 0.999, (i, lit)  # shadow somewhere, light elsewhere


def test_outputs_are_only_what_was_asked_for(renderer, demo):
    r = renderer.render(demo, RenderParams(outputs=["color"]))
    assert r.color.shape == (480, 640, 3) and r.color.dtype == np.uint8
    assert r.visibility is None and r.depth is None and r.light_depth == []
    r = renderer.render(demo, RenderParams(outputs=["depth"], alpha=True))
    assert r.color is None and r.depth.shape == (480, 640)


def test_readback_reuses_a_frame_only_once_nothing_holds_it(renderer, demo):
    import weakref

    lights = [{"type": "directional", "direction": [-0.6, -1.0, 0.25]}]
    lit = RenderParams(outputs=["color", "visibility", "depth"], lights=lights)
    dark = RenderParams(outputs=["color", "visibility", "depth"],
                        lights=[{**lights[0], "intensity": 0.05}])
    held = renderer.render(demo, lit)
    kept = {k: np.array(getattr(held, k)) for k in ("color", "visibility", "depth")}
    # Frames rendered while `held` lives (one more than the arrays kept per shape) must not be
    # written into its arrays.
    for _ in range(3):
        other = renderer.render(demo, dark)
        assert not np.array_equal(other.color, kept["color"])
    for k, v in kept.items():
        np.testing.assert_array_equal(getattr(held, k), v)
    # Once let go, the next frame is read into the same array (the allocation is what it saves).
    del held, other
    first = renderer.render(demo, dark)
    base = weakref.ref(first.color.base)
    del first
    again = renderer.render(demo, lit)
    assert again.color.base is base()
    np.testing.assert_array_equal(again.color, kept["color"])
    np.testing.assert_array_equal(again.visibility, kept["visibility"])


def test_readback_buffers_bound_what_they_keep():
    import weakref

    from shadowmap.renderer.gl.resources import ReadbackBuffers

    pool = ReadbackBuffers(per_shape=2)
    a = pool.take((4, 5, 3), np.uint8)
    b = pool.take((4, 5, 3), np.uint8)
    assert a is not b  # `a` is held here
    c = pool.take((4, 5, 3), np.uint8)  # both held: a third, the oldest let go
    assert c is not a and c is not b and pool.nbytes == 2 * 60
    del b
    assert pool.take((4, 5, 3), np.uint8).base is None  # a kept one, not a view
    view = c[::-1]
    del c
    d = pool.take((4, 5, 3), np.uint8)
    assert not np.shares_memory(d, view)  # a view still refers to its array
    assert pool.take((4, 5), np.float32).dtype == np.float32
    pool.clear()
    assert pool.nbytes == 0
    small = ReadbackBuffers(per_shape=2, max_bytes=100)
    big = small.take((10, 11), np.uint8)  # 110 bytes: handed out, not kept
    assert small.nbytes == 0
    del big
    first = weakref.ref(small.take((5, 5), np.uint8))  # 25 bytes: kept
    assert small.take((5, 5), np.uint8) is first() and small.nbytes == 25
    none = ReadbackBuffers(per_shape=0)  # keeps nothing: a new array every time
    assert none.take((2, 2), np.uint8) is not none.take((2, 2), np.uint8) and none.nbytes == 0


def test_visibility_is_nan_where_no_geometry_and_depth_matches_reference(renderer, models):
    scene = load_model(models, "Duck.glb", ground=False)
    params = RenderParams(outputs=["visibility", "depth"])
    _, result, ref = measure(renderer, scene, params)
    vis = result.visibility[..., 0]
    geometry = np.isfinite(ref.depth)
    # Pixels on silhouettes may differ by one; everything else agrees on where geometry is.
    assert np.mean(np.isfinite(vis) == geometry) > 0.995
    both = geometry & np.isfinite(result.depth)
    rel = np.abs(result.depth[both] - ref.depth[both]) / ref.depth[both]
    assert np.median(rel) < 1e-3


def _sheets_far_away(gap: float):
    """Two 400-unit sheets facing a camera at the origin, 350 units away and ``gap`` apart, the
    farther one first in the scene (drawn first: only the depth test keeps it behind)."""
    import trimesh

    from shadowmap.renderer import scene_from_meshes

    def sheet(z: float) -> trimesh.Trimesh:
        h = 200.0
        return trimesh.Trimesh(vertices=[[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]],
                               faces=[[0, 1, 2], [0, 2, 3]], process=False)

    scene = scene_from_meshes([sheet(-350.0), sheet(-350.0 + gap)], ["far", "near"])
    # The near plane 1e-4 of the far one: what the automatic near plane is for a camera
    # inside a wide ground's bounds.
    params = RenderParams.model_validate({
        "width": 64, "height": 48, "outputs": ["color", "depth"],
        "camera": {"eye": [0, 0, 0], "target": [0, 0, -1], "znear": 0.093, "zfar": 932.0},
        "lights": [{"type": "directional", "direction": [0, 0, -1], "cast_shadows": False}]})
    return scene, params


def test_depth_keeps_surfaces_apart_far_from_a_close_near_plane(renderer):
    """Surfaces 3 cm apart 350 units away, through a near plane 0.093 units away: the nearer
    one wins every pixel and the depth output reads it (with depth growing to the far plane a
    float buffer held about 0.08 units there, and the farther sheet showed through)."""
    scene, params = _sheets_far_away(0.03)
    depth = renderer.render(scene, params).depth
    assert np.all(np.isfinite(depth))
    # Depth along the view axis: the near sheet's 349.97 at every pixel, to a float32 step.
    np.testing.assert_allclose(depth, 349.97, rtol=1e-6)


def test_standard_depth_range_where_clip_control_is_missing(renderer, demo):
    """Without glClipControl the camera pass draws with GL's default depth range: the same
    picture and, within the precision that range has, the same depth."""
    from shadowmap.renderer import Renderer

    params = RenderParams(outputs=["color", "visibility", "depth"])
    reversed_ = renderer.render(demo, params)
    with Renderer() as plain:
        plain.camera_pass._clip_control = None  # as on a context without GL 4.5
        standard = plain.render(demo, params)
        assert not plain.camera_pass.reversed_z
    assert renderer.camera_pass.reversed_z
    # Surfaces meeting at an edge may swap a pixel; nothing else differs.
    differ = np.any(reversed_.color != standard.color, axis=-1)
    assert differ.mean() < 1e-3
    same = ~differ
    np.testing.assert_array_equal(reversed_.visibility[same], standard.visibility[same])
    both = same & np.isfinite(standard.depth)
    np.testing.assert_array_equal(np.isfinite(reversed_.depth), np.isfinite(standard.depth))
    np.testing.assert_allclose(reversed_.depth[both], standard.depth[both], rtol=1e-4)


def test_light_depth_debug_image(renderer, demo):
    r = renderer.render(demo, RenderParams(camera=DEMO_CAMERA, outputs=["light_depth"]))
    (ld,) = r.light_depth
    assert ld.image.dtype == np.uint8 and ld.image.shape == ld.depth.shape
    drawn = np.isfinite(ld.depth)
    assert drawn.any() and (~drawn).any()
    assert np.all(ld.image[~drawn] == 255)  # nothing drawn: white
    assert np.nanmin(ld.depth) >= 0 and np.nanmax(ld.depth) <= 1
    # Near is dark: the darkest pixel holds the smallest depth.
    darkest = ld.depth.flat[np.argmin(np.where(drawn, ld.image, 255))]
    assert darkest - np.nanmin(ld.depth) <= 1 / 254


def test_timings_cover_every_stage(renderer, demo):
    r = renderer.render(demo, RenderParams())
    for stage in ("load", "upload", "plan", "light", "camera", "readback", "total"):
        assert r.timings[stage] >= 0
    assert r.info["platform"] in ("egl", "osmesa")


def test_sources_neither_paths_nor_bytes_are_scene_errors(renderer):
    """Renderer.load reads its source as load_scene does: None or a point cloud is a SceneError
    naming what it got (it used to be a TypeError from bytes())."""
    import trimesh

    for source, text in ((None, "NoneType"), (trimesh.PointCloud(np.zeros((3, 3))), "PointCloud")):
        with pytest.raises(SceneError, match=f"from a value of type {text}: give a path"):
            renderer.render(source, {"width": 16, "height": 12})


def test_close_is_idempotent_and_final():
    from shadowmap.renderer import Renderer

    r = Renderer()
    r.close()
    r.close()
    with pytest.raises(RenderError, match="closed"):
        r.render(load_scene(demo_glb()))


@pytest.mark.parametrize("platform, message", [
    ("bogus", "unsupported GL platform 'bogus': use one of egl, osmesa"),
    (3, "platform must be one of egl, osmesa (or None for the default), not a value of type int"),
])
def test_an_unknown_platform_is_a_render_error_before_any_context(platform, message):
    from shadowmap.renderer import Renderer

    with pytest.raises(RenderError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Renderer(platform=platform)


@pytest.mark.parametrize("kind", ["point", "spot"])
def test_a_depth_range_rounded_away_is_a_warning_not_a_crash(renderer, kind):
    """A box on a ground 1.2e-6 units wide lit from 1e10 units away: float64's steps there
    (1.9e-6) put its nearest caster and deepest receiver at one depth, and the map's
    projection divided by their difference (ZeroDivisionError, found by the scaling fuzz).
    The light gets no pass and says why."""
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    s = 2e-7
    ground = trimesh.creation.box(extents=(6 * s, 0.01 * s, 6 * s))
    box = trimesh.creation.box(extents=(s, s, s))
    box.apply_translation((0, s, 0))
    light = {"type": kind, "position": [8e9, 5e9, -3e9]}
    if kind == "spot":
        light["target"] = [0.0, 0.0, 0.0]
    result = renderer.render(scene_from_meshes([ground, box]),
                             {"width": 64, "height": 48, "lights": [light]})
    assert result.plan["lights"][0]["skipped_pass"] == "below_precision"
    assert any("round to one number" in w for w in result.warnings)


def test_context_refuses_other_threads(renderer, demo):
    errors = []

    def work():
        try:
            renderer.render(demo, RenderParams(width=32, height=32))
        except RenderError as exc:
            errors.append(exc)

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert errors and "thread" in str(errors[0])


def test_a_forked_process_is_refused_and_the_parent_renders_on(renderer, demo):
    """A forked copy of the process (a multiprocessing pool's default start method on Linux,
    with a renderer made before it) has the context's memory but none of the driver's threads:
    its first render used to wait for ever. It is a RenderError now, its close() touches no GL,
    and the parent's renderer is unharmed."""
    import os
    import time

    params = RenderParams(width=32, height=24)
    before = renderer.render(demo, params).color
    pid = os.fork()
    if pid == 0:  # the child: exit status 0 only when both went as they should
        code = 1
        try:
            renderer.render(demo, params)
        except RenderError as exc:
            code = 0 if "forked copy" in str(exc) else 2
        try:
            renderer.close()
            renderer.close()
        except BaseException:  # noqa: BLE001 - any failure is the child's exit status
            code = 3
        os._exit(code)
    deadline = time.monotonic() + 60
    while (done := os.waitpid(pid, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    if done[0] == 0:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child hung")
    assert os.waitstatus_to_exitcode(done[1]) == 0
    assert not renderer.closed
    np.testing.assert_array_equal(renderer.render(demo, params).color, before)


def test_map_pool_never_frees_a_map_the_frame_still_samples(renderer, demo):
    """A frame with more maps than the framebuffer pool holds, at sizes the pool has not seen,
    keeps every one of its maps alive until the camera pass has sampled them."""
    lights = [{"direction": [-0.5, -1, 0.2]},
              {"type": "spot", "position": [2, 4, 2], "target": [0, 0, 0], "outer_cone_deg": 40},
              {"type": "point", "position": [-1.5, 3, 1.0]}]

    def render(size):
        return renderer.render(demo, RenderParams(camera=DEMO_CAMERA, lights=lights,
                                                  outputs=["visibility"],
                                                  shadows={"map_size": size}))

    pool = renderer.light_pass
    render(512)
    expected = render(1024).visibility  # a pool large enough for both frames
    saved = pool.pool_size, pool.cache.max_entries
    pool.release()
    # The pool alone (the map cache would keep the maps out of it).
    pool.pool_size, pool.cache.max_entries = 2, 0
    try:
        render(512)
        got = render(1024)
        held = [fb for fbs in pool.pool.values() for fb in fbs]
        assert len(held) == 3 and all(fb.fbo for fb in held)  # this frame's maps, alive
    finally:
        pool.pool_size, pool.cache.max_entries = saved
    np.testing.assert_array_equal(got.visibility, expected)


@pytest.mark.slow
def test_500_renders_do_not_grow_memory(renderer):
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    def scene(i):
        box = trimesh.creation.box(extents=(1, 1 + i * 1e-3, 1))
        ground = trimesh.creation.box(extents=(5, 0.1, 5))
        ground.apply_translation((0, -0.6, 0))
        return scene_from_meshes([box, ground])

    params = RenderParams(width=64, height=48, outputs=["color", "visibility", "light_depth"])
    for i in range(50):  # warm-up: programs, pools, caches
        renderer.render(scene(i), params)
    gc.collect()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for i in range(50, 550):
        renderer.render(scene(i), params)
    gc.collect()
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grown_mb < 40, f"RSS grew by {grown_mb:.1f} MB over 500 renders"
    assert len(renderer.uploads) <= renderer.cache_entries
    assert renderer.uploads.nbytes <= renderer.cache_bytes
    assert sum(len(v) for v in renderer.light_pass.pool.values()) <= renderer.light_pass.pool_size


def test_reference_metrics_without_lights_are_empty(renderer, demo):
    # No light, no shadow to compare: an empty list, whatever the outputs (schemathesis found a
    # server error here: the metrics asked for a visibility image no light has).
    for outputs in (["color"], ["visibility"]):
        r = renderer.render(demo, RenderParams(lights=[], reference=True, outputs=outputs,
                                               width=32, height=24))
        assert r.metrics == [] and r.visibility is None


def test_a_closed_room_seen_from_outside_matches_the_reference(renderer):
    """The camera outside a room of inward-facing, single-sided walls sees into it past their
    backs (the camera pass culls them), the floor in the shadow of the ceiling: the reference
    sees the same (it saw the walls' lit backs, and read IoU 0 against this picture)."""
    for direction in ([-0.3, -1.0, -0.2], [0.5, -0.3, 0.2]):
        result = renderer.render(T.room(), RenderParams.model_validate({
            "width": 160, "height": 120, "reference": True,
            "lights": [{"direction": direction}]}))
        (m,) = result.metrics
        assert m["iou"] >= 0.98 and m["pixels"] > 2000, m
