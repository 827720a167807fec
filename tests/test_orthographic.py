"""Orthographic cameras: from the request (``camera.projection``) and from glTF files.

Small exact cases of the camera's matrices and rays, then renders against the ray-traced
reference: the shadows, and the depth output (linear in an orthographic view's depth buffer).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from gltf_files import make_glb, split_glb
from shadowmap.batch.worker import camera_meta
from shadowmap.renderer import RenderParams, load_scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import Camera, resolve_camera
from shadowmap.renderer.demo import demo_glb
from shadowmap.renderer.plan.geometry import look_at
from shadowmap.renderer.scene import SceneCamera


def ortho_camera(w: int = 40, h: int = 20, ymag: float = 2.0) -> Camera:
    pose = look_at(np.array([1.0, 2.0, 10.0]), np.array([1.0, 2.0, 0.0]))
    return Camera(pose, math.radians(45), w, h, 1.0, 21.0, ymag)


def test_the_projection_maps_the_view_box_onto_clip_space():
    cam = ortho_camera()
    assert cam.orthographic
    corners = cam.frustum_corners()  # a box: the near and far faces are the same size
    np.testing.assert_allclose(corners[:4, :2], corners[4:, :2])
    np.testing.assert_allclose(np.ptp(corners[:, 0]), 8.0)  # 2 x ymag x aspect
    np.testing.assert_allclose(np.ptp(corners[:, 1]), 4.0)  # 2 x ymag
    clip = np.c_[corners, np.ones(8)] @ (cam.projection @ cam.view_from(np.zeros(3))).T
    np.testing.assert_allclose(clip[:, 3], 1.0)  # no perspective divide
    np.testing.assert_allclose(np.abs(clip[:, :3]), 1.0, atol=1e-12)
    np.testing.assert_allclose(clip[:4, 2], -1.0, atol=1e-12)  # near face first


def test_pixel_rays_are_parallel_and_a_pixel_apart():
    cam = ortho_camera(w=4, h=2, ymag=1.0)
    origins, dirs = cam.pixel_rays()
    np.testing.assert_allclose(dirs, np.tile([0.0, 0.0, -1.0], (8, 1)), atol=1e-12)
    # Pixel centres on the plane through the eye, row 0 at the top, one pixel_size apart.
    assert cam.pixel_size(5.0) == cam.pixel_size(500.0) == 1.0
    np.testing.assert_allclose(origins[0], [1.0 - 1.5, 2.0 + 0.5, 10.0])
    np.testing.assert_allclose(origins[1] - origins[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(origins[4] - origins[0], [0.0, -1.0, 0.0])


def test_params_keep_ymag_and_yfov_to_their_own_projection():
    RenderParams(camera={"projection": "orthographic", "ymag": 2.0})
    RenderParams(camera={"projection": "orthographic"})
    for camera, field in (({"ymag": 2.0}, "ymag"),
                          ({"projection": "perspective", "ymag": 2.0}, "ymag"),
                          ({"projection": "orthographic", "yfov_deg": 30}, "yfov_deg")):
        with pytest.raises(ValidationError) as e:
            RenderParams(camera=camera)
        assert e.value.errors()[0]["loc"][-1] == field
    with pytest.raises(ValidationError):
        RenderParams(camera={"projection": "orthographic", "ymag": 0})


@pytest.fixture(scope="module")
def demo():
    return load_scene(demo_glb())


def test_an_orthographic_camera_without_ymag_shows_the_whole_scene(demo):
    lo, hi = demo.bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    for camera in ({"projection": "orthographic"},
                   {"projection": "orthographic", "eye": [9, 1, 0], "target": [0, 3, 1]}):
        cam = resolve_camera(RenderParams(camera=camera).camera, demo, 320, 200)
        assert cam.orthographic
        ndc = np.c_[corners, np.ones(8)] @ (cam.projection @ cam.view_from(np.zeros(3))).T
        assert np.all(np.abs(ndc[:, :3]) < 1.0), ndc


def _with_camera(glb: bytes, camera: dict) -> bytes:
    """``glb`` with ``camera`` on a new root node 10 units up, looking down."""
    doc, blob = split_glb(glb)
    doc["cameras"] = [camera]
    doc["nodes"].append({"camera": 0, "translation": [0, 10, 0],
                         "rotation": [-math.sqrt(0.5), 0, 0, math.sqrt(0.5)]})
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    return make_glb(doc, blob)


def test_a_files_orthographic_camera_is_used_unless_the_request_names_a_projection(renderer):
    data = _with_camera(demo_glb(), {"type": "orthographic", "orthographic": {
        "xmag": 3.0, "ymag": 1.5, "znear": 0.01, "zfar": 50}})
    scene = load_scene(data)
    assert scene.cameras == [SceneCamera(scene.cameras[0].pose, None, 0.01, 50.0, 2.0, 1.5)]
    result = renderer.render(scene, RenderParams(width=64, height=48))
    assert result.plan["camera"]["projection"] == "orthographic"
    assert result.plan["camera"]["ymag"] == 1.5
    np.testing.assert_allclose(result.plan["camera"]["forward"], [0, -1, 0], atol=1e-12)
    persp = renderer.render(scene, RenderParams(width=64, height=48,
                                                camera={"projection": "perspective"}))
    assert persp.plan["camera"]["projection"] == "perspective"
    assert persp.plan["camera"]["yfov_deg"] == 45.0
    # And the other way: the file's perspective camera, seen orthographically from its place.
    data = _with_camera(demo_glb(), {"type": "perspective", "perspective": {"yfov": 0.5}})
    scene = load_scene(data)
    ortho = renderer.render(scene, RenderParams(width=64, height=48,
                                                camera={"projection": "orthographic"}))
    assert ortho.plan["camera"]["projection"] == "orthographic"
    np.testing.assert_allclose(ortho.plan["camera"]["eye"], [0, 10, 0], atol=1e-12)
    cam = resolve_camera(RenderParams(camera={"projection": "orthographic"}).camera, scene, 64,
                         48)
    assert cam.ymag == ortho.plan["camera"]["ymag"] > 0


def test_a_files_orthographic_camera_takes_its_nodes_scale():
    """A camera under a root scaled by 0.01 (as in files converted from other formats): its
    ymag and clip distances are in the node's units, 1/100 of them in the scene's."""
    data = _with_camera(demo_glb(), {"type": "orthographic", "orthographic": {
        "xmag": 300.0, "ymag": 150.0, "znear": 1.0, "zfar": 5000}})
    doc, blob = split_glb(data)
    node = doc["nodes"][-1]
    node["translation"] = [0, 1000, 0]
    roots = doc["scenes"][doc.get("scene", 0)]["nodes"]
    roots.remove(len(doc["nodes"]) - 1)
    doc["nodes"].append({"scale": [0.01, 0.01, 0.01], "children": [len(doc["nodes"]) - 1]})
    roots.append(len(doc["nodes"]) - 1)
    scene = load_scene(make_glb(doc, blob))
    (cam,) = scene.cameras
    assert cam.ymag == pytest.approx(1.5) and cam.aspect == pytest.approx(2.0)
    assert (cam.znear, cam.zfar) == pytest.approx((0.01, 50.0))
    np.testing.assert_allclose(cam.pose[:3, 3], [0, 10, 0])
    np.testing.assert_allclose(np.linalg.svd(cam.pose[:3, :3], compute_uv=False), 1.0)


@pytest.mark.parametrize("ymag", [0, "1", None, -0.0])
def test_a_files_orthographic_camera_without_a_usable_ymag_is_left_out(ymag):
    scene = load_scene(_with_camera(demo_glb(), {"type": "orthographic", "orthographic": {
        "xmag": 1, "ymag": ymag, "znear": 0, "zfar": 10}}))
    assert not scene.cameras
    assert any("no valid ymag" in w for w in scene.warnings), scene.warnings


LIGHTS = {
    "directional": {"type": "directional", "direction": [-0.4, -1, -0.3]},
    "spot": {"type": "spot", "position": [2, 4, 2], "direction": [-0.5, -1, -0.5],
             "outer_cone_deg": 50},
    "point": {"type": "point", "position": [1.5, 3, 1]},
}


@pytest.mark.parametrize("light", sorted(LIGHTS))
@pytest.mark.parametrize("fit", ["view", "scene"])
def test_orthographic_shadows_and_depth_match_the_ray_traced_reference(renderer, demo, light,
                                                                       fit):
    pytest.importorskip("embreex")
    params = RenderParams(
        width=320, height=240, lights=[LIGHTS[light]], shadows={"fit": fit},
        camera={"eye": [3.5, 3, 5], "target": [0, 0.4, 0], "projection": "orthographic",
                "ymag": 1.8},
        outputs=["color", "visibility", "depth"], reference=True)
    result = renderer.render(demo, params)
    assert result.metrics[0]["iou"] >= 0.98, result.metrics
    from shadowmap.renderer.lights import resolve_lights
    from shadowmap.renderer.reference import trace_reference

    ref = trace_reference(demo, result.camera, resolve_lights(params.lights, demo))
    truth = ref.depth.reshape(result.depth.shape)
    assert np.array_equal(np.isnan(result.depth), np.isnan(truth))
    # Linear window depth: float32 steps of the depth range, not of a 1/z curve.
    np.testing.assert_allclose(result.depth, truth, rtol=0, atol=1e-5 * result.camera.zfar)


def test_cascades_follow_an_orthographic_view(renderer, demo):
    pytest.importorskip("embreex")
    params = RenderParams(
        width=320, height=240, lights=[LIGHTS["directional"]], shadows={"cascades": 3},
        camera={"eye": [3.5, 3, 5], "target": [0, 0.4, 0], "projection": "orthographic",
                "ymag": 1.8},
        outputs=["color", "visibility"], reference=True)
    result = renderer.render(demo, params)
    assert len(result.plan["lights"][0]["cascades"]) == 3
    assert result.metrics[0]["iou"] >= 0.97, result.metrics


def test_batch_intrinsics_of_an_orthographic_camera_project_world_points_to_pixels():
    cam = ortho_camera(w=40, h=20, ymag=2.0)
    meta = camera_meta(cam)
    assert meta["projection"] == "orthographic" and meta["xmag"] == 4.0
    k, rt = np.array(meta["K"]), np.array(meta["world_to_camera_opencv"])
    # A point 1 unit right of and 0.5 below the view's centre, anywhere along the axis.
    for depth in (3.0, 17.0):
        p = rt @ np.array([2.0, 1.5, 10.0 - depth, 1.0])
        assert p[2] == pytest.approx(depth)
        u, v, _ = k @ np.array([p[0], p[1], 1.0])
        assert (u, v) == pytest.approx((20 + 1 * 5.0, 10 + 0.5 * 5.0))


@pytest.mark.parametrize("scale, offset", [(1e-3, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e5)])
def test_the_same_shadows_at_any_scale_and_offset(renderer, scale, offset):
    """The orthographic view of a scene scaled and moved far out, with its camera and lights
    moved alike, scores as the original does against its own reference."""
    pytest.importorskip("embreex")
    scene = T.caster_on_ground()
    spot = {"type": "spot", "position": [-3.0, 6.0, 2.0], "target": [0, 0, 0],
            "outer_cone_deg": 45}

    def params(s: float, o: float) -> dict:
        def move(p):
            return (np.asarray(p, float) * s + o).tolist()

        return {"camera": {"eye": move([3, 4, 5]), "target": move([0, 0, 0]),
                           "projection": "orthographic", "ymag": 2.5 * s},
                "lights": [{**spot, "position": move(spot["position"]),
                            "target": move(spot["target"])},
                           {"type": "directional", "direction": [-0.5, -1.0, -0.3]}]}

    for a, b in T.moved_metrics(renderer, scene, params, scale, offset):
        assert a.iou >= 0.95
        assert abs(a.iou - b.iou) <= 0.01, (a, b)
