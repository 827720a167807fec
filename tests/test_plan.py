"""The render plan: what it leaves out, and that leaving it out changes no requested output."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_model
from gltf_files import patch_glb
from shadowmap.renderer import RenderParams, load_scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.demo import demo_glb
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.reference import trace_reference

pytestmark = pytest.mark.gl

CAMERA = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}
ALL = ["color", "visibility", "depth", "light_depth"]


def both(renderer, scene, **params):
    """Render with and without the plan's omissions (same fit and map size either way)."""
    on = renderer.render(scene, RenderParams(optimize=True, **params))
    off = renderer.render(scene, RenderParams(optimize=False, **params))
    on.scene, on.request = scene, params  # for assert_same_outputs
    return on, off


def assert_same_outputs(on, off):
    """The same outputs, but where no shadow can reach on screen: there the optimized frame
    draws no lookup and reads exactly 1, and the ray-traced reference must agree (a lookup there
    can only return a false shadow, e.g. 0.99999994 from a texel weighted 6e-8)."""
    same = np.ones(on.color.shape[:2] if on.color is not None else (0, 0), bool)
    if on.visibility is not None:
        equal = (on.visibility == off.visibility) | (np.isnan(on.visibility)
                                                      & np.isnan(off.visibility))
        differ = ~equal
        if differ.any():
            assert np.all(on.visibility[differ] == 1.0)
            p = RenderParams(optimize=True, **on.request)
            camera = resolve_camera(p.camera, on.scene, p.width, p.height)
            ref = trace_reference(on.scene, camera, resolve_lights(p.lights, on.scene))
            assert np.all(np.nan_to_num(ref.visibility, nan=1.0)[differ] == 1.0)
        same = equal.all(axis=2)
    if on.color is not None:
        diff = np.abs(on.color.astype(int) - off.color.astype(int)).max(axis=2)
        assert diff[same].max() <= 1
    if on.depth is not None:
        np.testing.assert_array_equal(on.depth, off.depth)


def test_objects_far_outside_the_view_are_skipped_everywhere(renderer):
    scene = T.many_small_objects(200)
    on, off = both(renderer, scene, camera=CAMERA, outputs=ALL,
                   lights=[{"direction": [-0.5, -1, -0.3]}])
    assert on.plan["camera_pass"]["skipped"]["outside_view"] == 200
    light = on.plan["lights"][0]
    # The box casts; the ground plane only has receivers on its lit side.
    assert light["casters"] == 1
    assert light["skipped"] == {"outside_frustum": 200, "plane_facing_receivers": 1}
    assert off.plan["lights"][0]["casters"] == 202
    assert_same_outputs(on, off)


def test_non_casters_are_left_out_of_the_light_pass(renderer):
    scene = T.ground_only_receives()
    on, off = both(renderer, scene, camera=CAMERA, outputs=ALL,
                   lights=[{"direction": [-0.5, -1, -0.3]}])
    assert on.plan["lights"][0]["skipped"] == {"non_caster": 1}
    assert on.plan["lights"][0]["casters"] == 2
    assert_same_outputs(on, off)


def test_cast_shadow_false_in_gltf_extras_is_honoured(renderer, tmp_path):
    import trimesh

    scene = trimesh.Scene()
    ground = trimesh.creation.box(extents=(6, 0.1, 6))
    scene.add_geometry(ground, node_name="ground")
    box = trimesh.creation.box(extents=(1, 1, 1))
    scene.add_geometry(box, node_name="box",
                       transform=trimesh.transformations.translation_matrix((0, 1.0, 0)))
    glb = scene.export(file_type="glb")
    # Mark the box a non-caster the three.js way, in the node's extras.
    def box_casts_nothing(doc: dict) -> None:
        for node in doc["nodes"]:
            if node.get("name") == "box":
                node["extras"] = {"castShadow": False}

    out = patch_glb(glb, box_casts_nothing)
    loaded = load_scene(out)
    flags = {i.name: i.cast_shadow for i in loaded.instances}
    assert flags["box"] is False and flags["ground"] is True
    params = RenderParams(camera=CAMERA, outputs=["visibility"])
    r = renderer.render(loaded, params)
    casting = renderer.render(load_scene(glb), params)
    assert r.plan["lights"][0]["skipped"]["non_caster"] == 1
    # What stays shadowed are the ground slab's own sides that face away from the light.
    assert (r.visibility < 0.5).sum() < 0.3 * (casting.visibility < 0.5).sum()


def test_light_that_reaches_nothing_visible_gets_no_pass(renderer):
    scene = T.caster_on_ground()
    away = {"type": "spot", "position": [0, 3, 0], "direction": [0, 1, 0], "outer_cone_deg": 30}
    on, off = both(renderer, scene, camera=CAMERA, outputs=ALL, lights=[away])
    assert on.plan["lights"][0]["skipped_pass"] == "no_visible_receiver"
    assert on.plan["light_passes"] == 0 and on.light_depth == []
    assert_same_outputs(on, off)
    assert np.all(on.visibility[np.isfinite(on.visibility)] == 1.0)


def test_scene_without_lights_has_no_light_pass(renderer):
    r = renderer.render(T.caster_on_ground(), RenderParams(camera=CAMERA, lights=[]))
    assert r.plan["light_passes"] == 0
    assert r.plan["shader_variants"]["light_pass"] == []
    assert r.color.shape == (480, 640, 3)


def test_shader_variants_follow_the_scene(renderer, models):
    textured = load_model(models, "BoxTextured.glb", ground=True)
    r = renderer.render(textured, RenderParams(shadows={"filter": "hard"}))
    variants = r.plan["shader_variants"]["camera_pass"]
    # The textured box samples its texture; the added ground (no texture) does not.
    assert any("HAS_UV" in v for v in variants) and any("HAS_UV" not in v for v in variants)
    assert not any("FILTER_PCF" in v for v in variants)  # no PCF loop with hard filtering
    assert not any("HAS_SPOT" in v or "HAS_POSITIONAL" in v for v in variants)
    assert not any("ALPHA_TEST" in v for v in r.plan["shader_variants"]["light_pass"])
    cutouts = load_model(models, "AlphaBlendModeTest.glb")
    r = renderer.render(cutouts, RenderParams())
    assert any("ALPHA_TEST" in v for v in r.plan["shader_variants"]["light_pass"])
    assert any("ALPHA_MASK" in v for v in r.plan["shader_variants"]["camera_pass"])


@pytest.mark.parametrize("name", [
    "BoxTextured.glb", "AlphaBlendModeTest.glb", "CesiumMilkTruck.glb"])
def test_specialised_variants_equal_the_generic_program(renderer, models, name):
    # optimize=False draws every primitive with one all-features variant (white texture and
    # vertex colour stand-ins, PCF loop, spot and range code): the pictures must agree.
    scene = load_model(models, name)
    lights = [{"direction": [-0.5, -1, 0.2]},
              {"type": "spot", "position": [2, 4, 3], "target": [0, 0, 0], "outer_cone_deg": 50}]
    on, off = both(renderer, scene, outputs=["color", "visibility"], lights=lights)
    assert_same_outputs(on, off)


def test_outputs_not_requested_are_not_computed(renderer):
    scene = T.caster_on_ground()
    r = renderer.render(scene, RenderParams(camera=CAMERA, outputs=["color"]))
    assert r.visibility is None and r.depth is None and r.light_depth == []
    assert all("OUT_VISIBILITY" not in v for v in r.plan["shader_variants"]["camera_pass"])
    r = renderer.render(scene, RenderParams(camera=CAMERA, outputs=["color", "visibility"]))
    assert all("OUT_VISIBILITY=1" in v for v in r.plan["shader_variants"]["camera_pass"])


@pytest.mark.parametrize("name", ["AlphaBlendModeTest.glb", "CesiumMilkTruck.glb",
                                  "TestScene.gltf"])
def test_a_depth_only_request_draws_no_light_pass_and_no_shading(renderer, models, name):
    """Depth alone shows no shadow and no colour: no light pass, and a camera pass that only
    discards cut-outs (blended surfaces, which write no depth, are not drawn). Its depth is the
    shaded frame's, bit for bit, cut-outs and blended surfaces included (AlphaBlendModeTest)."""
    scene = load_model(models, name)
    request = {"width": 320, "height": 240, "ground": True}
    shaded = renderer.render(scene, RenderParams(outputs=["color", "depth"], **request))
    on, off = both(renderer, scene, outputs=["depth"], **request)
    np.testing.assert_array_equal(on.depth, shaded.depth)
    np.testing.assert_array_equal(off.depth, shaded.depth)
    assert np.isfinite(on.depth).mean() > 0.5
    assert on.color is None and on.visibility is None and on.light_depth == []
    assert on.plan["light_passes"] == 0 and on.plan["camera_pass"]["draws"] == "depth"
    assert {lp["skipped_pass"] for lp in on.plan["lights"]} == {"no_shadow_output"}
    variants = on.plan["shader_variants"]["camera_pass"]
    assert variants and all("DEPTH_ONLY" in v.split() and "NUM_LIGHTS" not in v for v in variants)
    # Without optimize everything is drawn as for the colour.
    assert off.plan["light_passes"] >= 1 and off.plan["camera_pass"]["draws"] == "shaded"
    # With the maps' own picture asked for, the light passes run and the camera pass is the
    # same depth-only one (it reads no map).
    maps = renderer.render(scene, RenderParams(outputs=["depth", "light_depth"], **request))
    np.testing.assert_array_equal(maps.depth, shaded.depth)
    assert maps.plan["camera_pass"]["draws"] == "depth" and len(maps.light_depth) >= 1


@pytest.mark.parametrize("name", ["AlphaBlendModeTest.glb", "CesiumMilkTruck.glb",
                                  "TestScene.gltf"])
def test_a_visibility_request_without_colour_runs_the_lookups_alone(renderer, models, name):
    """Visibility without colour: the lookups of every light kind (cascades, spot, point), no
    shading, no blended surfaces (they write no visibility); the same visibility and depth as
    the shaded frame's, bit for bit."""
    scene = load_model(models, name)
    lights = [{"direction": [-0.5, -1, 0.2]},
              {"type": "spot", "position": [2, 4, 3], "target": [0, 0, 0], "outer_cone_deg": 50},
              {"type": "point", "position": [0.5, 3, 0.5]}]
    request = {"width": 320, "height": 240, "ground": True, "lights": lights}
    shaded = renderer.render(scene, RenderParams(outputs=["color", "visibility", "depth"],
                                                 **request))
    alone = renderer.render(scene, RenderParams(outputs=["visibility", "depth"], **request))
    np.testing.assert_array_equal(alone.visibility, shaded.visibility)
    np.testing.assert_array_equal(alone.depth, shaded.depth)
    assert (alone.visibility == 0).any() and alone.color is None
    assert alone.plan["camera_pass"]["draws"] == "visibility"
    assert alone.plan["light_passes"] == shaded.plan["light_passes"] >= 3
    variants = alone.plan["shader_variants"]["camera_pass"]
    assert variants and all("NO_COLOR" in v.split() and "UNLIT" not in v.split()
                            for v in variants)


def test_a_light_depth_only_request_draws_no_camera_pass(renderer):
    scene = T.caster_on_ground()
    with_colour = renderer.render(scene, RenderParams(camera=CAMERA,
                                                      outputs=["color", "light_depth"]))
    alone = renderer.render(scene, RenderParams(camera=CAMERA, outputs=["light_depth"]))
    assert alone.plan["camera_pass"]["draws"] == "none"
    assert alone.plan["camera_pass"]["drawn"] == 0 and alone.timings["camera"] < 0.001
    assert alone.plan["shader_variants"]["camera_pass"] == []
    assert alone.color is None and alone.depth is None and alone.visibility is None
    assert len(alone.light_depth) == len(with_colour.light_depth) == 1
    np.testing.assert_array_equal(alone.light_depth[0].depth, with_colour.light_depth[0].depth)


def test_same_bytes_are_parsed_and_uploaded_once(renderer):
    data = demo_glb()
    renderer.context.make_current()
    renderer.scenes.clear()  # independent of what earlier tests rendered
    renderer.uploads.clear()
    first = renderer.render(data, RenderParams(width=64, height=48))
    hits = renderer.scenes.hits
    again = renderer.render(data, RenderParams(width=64, height=48))
    assert first.plan["scene_cache"] == "miss"
    assert again.plan["scene_cache"] == "hit"
    assert renderer.scenes.hits == hits + 1 and len(renderer.scenes) == 1


def test_auto_map_size_follows_the_view(renderer):
    scene = T.caster_on_ground()
    near = renderer.render(scene, RenderParams(camera={"eye": [2, 2, 3], "target": [0, 0.5, 0]}))
    far = renderer.render(scene, RenderParams(camera={"eye": [20, 20, 30], "target": [0, 0.5, 0]}))
    small = renderer.render(scene, RenderParams(width=160, height=120,
                                                camera={"eye": [2, 2, 3], "target": [0, 0.5, 0]}))
    sizes = [r.plan["lights"][0]["map_size"] for r in (near, far, small)]
    assert sizes[0] > sizes[1] and sizes[0] > sizes[2], sizes


def test_tighter_fit_does_not_raise_the_error(renderer):
    # Fitting to what the camera sees (and auto size) against the whole-scene fit of the same
    # map size: the error against the reference must not grow.
    scene = T.many_small_objects(50)
    fitted = T.measure(renderer, scene, RenderParams(camera=CAMERA, shadows={"map_size": 1024}))
    whole = T.measure(renderer, scene, RenderParams(camera=CAMERA, optimize=False,
                                                    shadows={"map_size": 1024}))
    assert fitted.metrics[0].misclassified_pct <= whole.metrics[0].misclassified_pct + 1e-9
