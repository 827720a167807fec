"""The ray-traced reference against analytic shadows, and the shadow metrics on hand-made masks.

No OpenGL is needed. Scenes are a ground quad and boxes, so the true shadow of every ground pixel
follows from a ray-plane intersection and a ray-box slab test.
"""

from __future__ import annotations

import dataclasses
import io
import math
import sys

import numpy as np
import pytest
import trimesh
from PIL import Image

from gltf_files import make_glb
from shadowmap.renderer.camera import Camera
from shadowmap.renderer.errors import ReferenceUnavailable
from shadowmap.renderer.lights import Light
from shadowmap.renderer.metrics import ShadowMetrics, compare_all, shadow_metrics
from shadowmap.renderer.plan.geometry import look_at
from shadowmap.renderer.reference import ReferenceResult, trace_reference
from shadowmap.renderer.scene import load_scene, scene_from_meshes

pytest.importorskip("embreex")

W, H = 160, 120
BOX_LO = np.array([-0.5, 1.0, -0.5])
BOX_HI = np.array([0.5, 2.0, 0.5])
EYE = np.array([3.0, 6.0, 8.0])


# ------------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------------


def quad(half: float, y: float, **meta) -> trimesh.Trimesh:
    """Horizontal square of half-size ``half`` at height ``y``, normal +Y."""
    v = np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]], float)
    m = trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)
    m.metadata.update(meta)
    return m


def box(lo=BOX_LO, hi=BOX_HI, **meta) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=np.subtract(hi, lo))
    m.apply_translation((np.asarray(lo) + np.asarray(hi)) / 2)
    m.metadata.update(meta)
    return m


def camera(eye=EYE, target=(0.0, 0.0, 0.0), w=W, h=H, znear=0.1, zfar=100.0) -> Camera:
    return Camera(look_at(np.array(eye, float), np.array(target, float)), math.radians(50), w, h,
                  znear, zfar)


def directional(d) -> Light:
    d = np.asarray(d, float)
    return Light("directional", np.zeros(3), d / np.linalg.norm(d), np.ones(3))


def point(p, rng=None) -> Light:
    return Light("point", np.asarray(p, float), np.array([0.0, 0.0, -1.0]), np.ones(3), range=rng)


def spot(p, d, cone_deg) -> Light:
    d = np.asarray(d, float)
    return Light("spot", np.asarray(p, float), d / np.linalg.norm(d), np.ones(3),
                 outer_cone=math.radians(cone_deg))


def ground_points(cam: Camera, ref: ReferenceResult, half: float = 10.0):
    """Pixels whose visible surface is the ground plane y = 0, and their world points.

    Returns
    -------
    on_ground : ndarray, shape (H, W), bool
    g : ndarray, shape (H, W, 3)
    """
    o, d = cam.pixel_rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 1] / d[:, 1]
    g = o + d * t[:, None]
    depth = t * (d @ -cam.pose[:3, 2])
    inside = (t > 0) & (np.abs(g[:, 0]) < half) & (np.abs(g[:, 2]) < half)
    seen = np.isclose(ref.depth.ravel(), depth, rtol=1e-5)
    return (inside & seen).reshape(cam.height, cam.width), g.reshape(cam.height, cam.width, 3)


def segment_hits_box(p: np.ndarray, q: np.ndarray, lo, hi, t_max=1.0) -> np.ndarray:
    """Whether p + s (q - p), 0 < s < t_max, meets the box [lo, hi] (slab test); shape (N,)."""
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lo) - p) / d
        t2 = (np.asarray(hi) - p) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return (tmax >= np.maximum(tmin, 0.0)) & (tmin < t_max)


def boundary_distance(g: np.ndarray, half=0.5) -> np.ndarray:
    """Distance of ground points (N, 3) from the box footprint's outline."""
    dx = np.abs(np.abs(g[:, 0]) - half)
    dz = np.abs(np.abs(g[:, 2]) - half)
    inside_x, inside_z = np.abs(g[:, 0]) <= half, np.abs(g[:, 2]) <= half
    return np.minimum(np.where(inside_z, dx, np.inf), np.where(inside_x, dz, np.inf))


# ------------------------------------------------------------------------------------------------
# Reference: analytic scenes
# ------------------------------------------------------------------------------------------------


def test_vertical_sun_shadow_is_box_footprint():
    scene = scene_from_meshes([quad(10, 0.0), box()])
    cam = camera()
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    assert ref.visibility.shape == (H, W, 1) and ref.visibility.dtype == np.float32
    assert ref.valid.shape == (H, W, 1) and ref.depth.shape == (H, W)
    on_ground, g = ground_points(cam, ref)
    assert on_ground.sum() > 0.4 * H * W
    vis, valid = ref.visibility[..., 0], ref.valid[..., 0]
    assert valid[on_ground].all()
    gp = g[on_ground]
    expected = (np.abs(gp[:, 0]) < 0.5) & (np.abs(gp[:, 2]) < 0.5)
    assert expected.sum() > 50
    got = vis[on_ground] < 0.5
    assert (got == expected).mean() >= 0.995
    assert np.all(boundary_distance(gp[got != expected]) < 1e-3)
    # The box's top faces the sun and is lit; its vertical sides are edge-on and not valid.
    box_px = np.isfinite(ref.depth) & ~on_ground
    assert np.all(vis[box_px & valid] == 1.0)
    assert (box_px & ~valid).sum() > 0


def test_oblique_sun_matches_slab_test():
    d = np.array([-0.4, -1.0, -0.3])
    scene = scene_from_meshes([quad(10, 0.0), box()])
    cam = camera()
    ref = trace_reference(scene, cam, [directional(d)])
    on_ground, g = ground_points(cam, ref)
    gp = g[on_ground]
    far = gp - d / np.linalg.norm(d) * 1e3
    expected = segment_hits_box(gp, far, BOX_LO, BOX_HI)
    got = ref.visibility[..., 0][on_ground] < 0.5
    assert expected.sum() > 50
    assert (got == expected).mean() >= 0.995


@pytest.mark.parametrize("offset", [0.0, 1e6])
def test_a_small_casters_shadow_on_a_huge_plane(offset):
    """A 1-unit box on a 10,000-unit plane in one mesh, seen from a few units away: shadow-ray
    offsets from the local geometry keep the box's contact and edges in the truth (an offset
    of a fixed fraction of the scene, 1e-5 of its diagonal, lifts the rays 0.14 units)."""
    h = 0.5
    big = quad(5000.0, 0.0)
    cube = box((-h, 0.0, -h), (h, 1.0, h))
    mesh = trimesh.util.concatenate([big, cube])
    mesh.apply_translation([offset, 0.0, offset])
    scene = scene_from_meshes([mesh])
    shift = np.array([offset, 0.0, offset])
    cam = camera(eye=np.array([3.0, 2.5, 4.0]) + shift, target=np.array([0.0, 0.3, 0.0]) + shift,
                 w=320, h=240, znear=0.5, zfar=200.0)
    d = np.array([0.5, -1.0, 0.7])
    ref = trace_reference(scene, cam, [directional(d)])
    o, rays = cam.pixel_rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 1] / rays[:, 1]
    g = o + rays * t[:, None]
    depth = t * (rays @ -cam.pose[:3, 2])
    on_ground = ((t > 0) & np.isclose(ref.depth.ravel(), depth, rtol=1e-5)).reshape(240, 320)
    gp = g.reshape(240, 320, 3)[on_ground]
    far = gp - d / np.linalg.norm(d) * 1e3
    expected = segment_hits_box(gp, far, shift + (-h, 0, -h), shift + (h, 1.0, h))
    got = ref.visibility[..., 0][on_ground] < 0.5
    assert expected.sum() > 1000
    assert (got == expected).mean() >= 0.999
    # Mismatches only at the outline: every ray through the box shrunk by about a pixel here
    # (0.02 units; a pixel spans 0.019 units at 5 units) is shadowed, and none that misses
    # the box grown by as much.
    e = 0.02
    inner = segment_hits_box(gp, far, shift + (-h + e, 0, -h + e), shift + (h - e, 1 - e, h - e))
    outer = segment_hits_box(gp, far, shift + (-h - e, 0, -h - e), shift + (h + e, 1 + e, h + e))
    assert inner.sum() > 0.9 * expected.sum()
    assert got[inner].all() and not got[~outer].any()


def test_no_geometry_pixels_are_nan_and_invalid():
    scene = scene_from_meshes([box()])
    cam = camera(eye=(0, 1.5, 2.5), target=(0, 1.5, 0))
    ref = trace_reference(scene, cam, [directional([0, -1, 0]), point([0, 5, 0])])
    miss = ~np.isfinite(ref.depth)
    assert 0.1 < miss.mean() < 0.95
    assert np.all(np.isnan(ref.visibility[miss])) and not ref.valid[miss].any()
    assert np.all(np.isfinite(ref.visibility[~miss]))
    # The front face is flat at z = 0.5: depth is exactly the distance to that plane.
    centre = ref.depth[H // 2, W // 2]
    assert centre == pytest.approx(2.5 - 0.5, rel=1e-6)


def test_spot_cone_limits_valid_and_shadow_matches():
    light_pos = np.array([0.3, 6.0, 0.2])
    cone = 20.0
    scene = scene_from_meshes([quad(10, 0.0), box()])
    cam = camera()
    ref = trace_reference(scene, cam, [spot(light_pos, [0, -1, 0], cone)])
    on_ground, g = ground_points(cam, ref)
    gp = g[on_ground]
    v = gp - light_pos
    angle = np.degrees(np.arccos(-v[:, 1] / np.linalg.norm(v, axis=1)))
    valid = ref.valid[..., 0][on_ground]
    inside = angle < cone
    assert inside.sum() > 100 and (~inside).sum() > 100
    clear = np.abs(angle - cone) > 1e-6
    assert np.array_equal(valid[clear], inside[clear])
    expected = segment_hits_box(gp, np.broadcast_to(light_pos, gp.shape), BOX_LO, BOX_HI)
    got = ref.visibility[..., 0][on_ground] < 0.5
    assert expected[inside].sum() > 50
    assert (got == expected).mean() >= 0.995


def test_point_light_shadow_and_range():
    light_pos = np.array([1.2, 5.0, 0.7])
    scene = scene_from_meshes([quad(10, 0.0), box()])
    cam = camera()
    ref = trace_reference(scene, cam, [point(light_pos), point(light_pos, rng=6.0)])
    on_ground, g = ground_points(cam, ref)
    gp = g[on_ground]
    expected = segment_hits_box(gp, np.broadcast_to(light_pos, gp.shape), BOX_LO, BOX_HI)
    got = ref.visibility[..., 0][on_ground] < 0.5
    assert expected.sum() > 50
    assert (got == expected).mean() >= 0.995
    assert ref.valid[..., 0][on_ground].all()
    # Range: only ground within 6 units of the light stays valid; visibility is unchanged.
    dist = np.linalg.norm(gp - light_pos, axis=1)
    in_range = ref.valid[..., 1][on_ground]
    assert (dist > 6).sum() > 100
    clear = np.abs(dist - 6) > 1e-6
    assert np.array_equal(in_range[clear], dist[clear] <= 6)
    assert np.array_equal(ref.visibility[..., 0], ref.visibility[..., 1], equal_nan=True)


def test_light_at_the_eye_sees_no_shadow():
    """Everything the camera sees is visible from a point light at the camera."""
    scene = scene_from_meshes([quad(10, 0.0), box(), box((1, 0, 1), (2, 3, 1.5))])
    cam = camera()
    ref = trace_reference(scene, cam, [point(cam.position)])
    ok = ref.valid[..., 0]
    assert ok.sum() > 0.5 * H * W
    assert np.all(ref.visibility[..., 0][ok] == 1.0)


def test_cast_shadow_false_casts_nothing():
    scene = scene_from_meshes([quad(10, 0.0), box(castShadow=False)])
    cam = camera()
    ref = trace_reference(scene, cam, [directional([0, -1, 0]), point([1, 5, 1])])
    hit = np.isfinite(ref.depth)
    assert np.all(ref.visibility[hit] == 1.0)
    on_ground, _ = ground_points(cam, ref)
    assert (hit & ~on_ground).sum() > 100  # the box is still drawn


def test_receive_shadow_false_is_not_valid():
    scene = scene_from_meshes([quad(10, 0.0, receiveShadow=False), box()])
    cam = camera()
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    on_ground, _ = ground_points(cam, ref)
    assert on_ground.sum() > 1000
    assert not ref.valid[..., 0][on_ground].any()
    # Visibility is still traced there, and the box's top is a valid receiver.
    assert (ref.visibility[..., 0][on_ground] == 0).sum() > 50
    assert ref.valid[..., 0][~on_ground].sum() > 50


@pytest.mark.parametrize("scale", [1e-3, 1e4])
def test_scale_and_translation_invariance(scale):
    offset = np.array([1e5, -1e5, 1e5])

    def build(s, t):
        scene = scene_from_meshes([quad(10, 0.0), box(), box((1, 0, 1), (2, 3, 1.5))])
        m = np.eye(4)
        m[:3, :3] *= s
        m[:3, 3] = t
        scene.instances[:] = [dataclasses.replace(inst, matrix=m, bounds=inst.bounds * s + t)
                              for inst in scene.instances]
        pose = look_at(EYE * s + t, t)
        cam = Camera(pose, math.radians(50), W, H, 0.1 * s, 100 * s)
        lights = [directional([-0.4, -1, -0.3]), point(np.array([1.2, 5.0, 0.7]) * s + t)]
        return trace_reference(scene, cam, lights)

    base = build(1.0, np.zeros(3))
    moved = build(scale, offset)
    for k in range(2):
        a = base.valid[..., k] & (base.visibility[..., k] < 0.5)
        b = moved.valid[..., k] & (moved.visibility[..., k] < 0.5)
        assert a.sum() > 100
        assert (a != b).mean() <= 0.005
        assert (base.valid[..., k] != moved.valid[..., k]).mean() <= 0.005
    both = np.isfinite(base.depth) & np.isfinite(moved.depth)
    assert (np.isfinite(base.depth) != np.isfinite(moved.depth)).mean() <= 0.005
    np.testing.assert_allclose(moved.depth[both] / scale, base.depth[both], rtol=1e-4)


def _textured_quad(alpha_grid: np.ndarray, mode: str, base_alpha=1.0) -> trimesh.Trimesh:
    """Quad at y = 1.5 over x, z in [-1, 1]; u runs with x, image columns left to right."""
    m = quad(1.0, 1.5)
    rgba = np.full(alpha_grid.shape + (4,), 200, np.uint8)
    rgba[..., 3] = alpha_grid
    mat = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(rgba, "RGBA"),
        baseColorFactor=[1.0, 1.0, 1.0, base_alpha],
        alphaMode=mode,
        alphaCutoff=0.5,
    )
    uv = np.column_stack([(m.vertices[:, 0] + 1) / 2, (m.vertices[:, 2] + 1) / 2])
    m.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return m


def test_mask_texture_casts_only_where_opaque():
    # Left image column (u < 0.5, x < 0) transparent, right column opaque.
    caster = _textured_quad(np.array([[0, 255], [0, 255]], np.uint8), "MASK")
    scene = scene_from_meshes([quad(10, 0.0), caster])
    assert scene.primitives[1].material.alpha_mode == "MASK"
    assert scene.primitives[1].material.texture is not None
    cam = camera(eye=(0.5, 8.0, 3.0))
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    on_ground, g = ground_points(cam, ref)
    gp = g[on_ground]
    got = ref.visibility[..., 0][on_ground] < 0.5
    expected = (gp[:, 0] > 0) & (gp[:, 0] < 1) & (np.abs(gp[:, 2]) < 1)
    assert expected.sum() > 100
    assert (got == expected).mean() >= 0.995
    # Primary rays see through the cut-out half: the ground under it is on screen.
    assert ((gp[:, 0] < 0) & (gp[:, 0] > -1) & (np.abs(gp[:, 2]) < 1)).sum() > 100


@pytest.mark.parametrize("base_alpha, casts", [(0.6, True), (0.3, False)])
def test_blend_is_invisible_to_camera_and_casts_above_half(base_alpha, casts):
    sheet = quad(1.0, 1.5)
    mat = trimesh.visual.material.PBRMaterial(baseColorFactor=[1, 1, 1, base_alpha],
                                              alphaMode="BLEND")
    sheet.visual = trimesh.visual.TextureVisuals(material=mat)
    scene = scene_from_meshes([quad(10, 0.0), sheet])
    assert scene.primitives[1].material.alpha_mode == "BLEND"
    cam = camera()
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    on_ground, g = ground_points(cam, ref)
    assert on_ground.sum() == np.isfinite(ref.depth).sum()  # only the ground is "seen"
    gp = g[on_ground]
    under = (np.abs(gp[:, 0]) < 1) & (np.abs(gp[:, 2]) < 1)
    got = ref.visibility[..., 0][on_ground] < 0.5
    expected = under if casts else np.zeros_like(under)
    assert (got == expected).mean() >= 0.995


def test_gltf_texcoord_v_zero_is_top_image_row():
    """A hand-written glTF: TEXCOORD_0 v = 0 at z = -1; the image's top row is transparent."""
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[1, :, 3] = 255  # bottom row (v >= 0.5, z > 0) opaque
    png = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(png, format="PNG")
    png = png.getvalue()

    def quad_arrays(half, y):
        pos = np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]],
                       np.float32)
        uv = np.column_stack([(pos[:, 0] / half + 1) / 2, (pos[:, 2] / half + 1) / 2])
        return pos, uv.astype(np.float32)

    ground, _ = quad_arrays(10.0, 0.0)
    sheet, uv = quad_arrays(1.0, 1.5)
    idx = np.array([0, 2, 1, 0, 3, 2], np.uint16)
    chunks = [ground.tobytes(), sheet.tobytes(), uv.tobytes(), idx.tobytes() + b"\0\0", png]
    views, blob = [], b""
    for c in chunks:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(c)})
        blob += c
    views[3]["byteLength"] = idx.nbytes

    def vec_acc(view, arr, kind):
        return {"bufferView": view, "componentType": 5126, "count": len(arr), "type": kind,
                **({"min": arr.min(0).tolist(), "max": arr.max(0).tolist()} if kind == "VEC3"
                   else {})}

    gltf = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": [
            vec_acc(0, ground, "VEC3"), vec_acc(1, sheet, "VEC3"), vec_acc(2, uv, "VEC2"),
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
        "images": [{"bufferView": 4, "mimeType": "image/png"}],
        "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
                       "alphaMode": "MASK", "alphaCutoff": 0.5, "doubleSided": True}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 3}]},
            {"primitives": [{"attributes": {"POSITION": 1, "TEXCOORD_0": 2}, "indices": 3,
                             "material": 0}]},
        ],
        "nodes": [{"mesh": 0}, {"mesh": 1}],
        "scenes": [{"nodes": [0, 1]}],
    }
    scene = load_scene(make_glb(gltf, blob), file_type="glb")
    assert any(p.material.alpha_mode == "MASK" and p.material.texture is not None
               for p in scene.primitives)
    cam = camera(eye=(0.5, 8.0, 3.0))
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    on_ground, g = ground_points(cam, ref)
    gp = g[on_ground]
    got = ref.visibility[..., 0][on_ground] < 0.5
    expected = (np.abs(gp[:, 0]) < 1) & (gp[:, 2] > 0) & (gp[:, 2] < 1)
    assert expected.sum() > 100
    assert (got == expected).mean() >= 0.995


def _sheet_over_ground(facing_up: bool, double_sided: bool = False, mirror: bool = False):
    """A 2 x 2 sheet 1.5 over the ground, its front up or down, single- or double-sided, and
    placed by a node that mirrors it along x (it lies where it did: glTF winds a mirrored
    node's faces clockwise, so its front side stays the one it had)."""
    from shadowmap.renderer.scene import Instance, world_bounds

    sheet = quad(1.0, 1.5)
    if not facing_up:
        sheet.invert()
    if double_sided:
        sheet.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(doubleSided=True))
    scene = scene_from_meshes([quad(10, 0.0), sheet])
    if mirror:
        inst = scene.instances[1]
        m = np.diag([-1.0, 1.0, 1.0, 1.0])
        local = scene.primitives[inst.primitive].local_bounds.astype(np.float64)
        scene.instances[1] = Instance(inst.primitive, m, inst.cast_shadow, inst.receive_shadow,
                                      inst.name, world_bounds(local, m))
    return scene


@pytest.mark.parametrize("facing_up, double_sided, mirror, seen", [
    (True, False, False, True),
    (False, False, False, False),
    (False, True, False, True),
    (True, False, True, True),
    (False, False, True, False),
])
def test_the_camera_sees_past_the_back_of_single_sided_faces(facing_up, double_sided, mirror,
                                                            seen):
    """Primary rays pass through the back of a single-sided face, as the camera pass culls it
    (a room of inward-facing walls seen from outside shows its inside: the reference saw the
    walls' backs, and its metrics read IoU 0 against a right picture); a double-sided face
    stops them from both sides, and a mirrored node keeps its front side. Shadow rays stop at
    either side: the sheet shadows the ground under it in every case."""
    scene = _sheet_over_ground(facing_up, double_sided, mirror)
    assert scene.primitives[1].material.double_sided == double_sided
    cam = camera()
    ref = trace_reference(scene, cam, [directional([0, -1, 0])])
    on_ground, g = ground_points(cam, ref)
    assert (on_ground.sum() < np.isfinite(ref.depth).sum()) == seen
    gp = g[on_ground]
    under = (np.abs(gp[:, 0]) < 1) & (np.abs(gp[:, 2]) < 1)
    assert under.sum() > 50
    got = ref.visibility[..., 0][on_ground] < 0.5
    assert (got == under).mean() >= 0.995


def test_light_without_shadows_is_all_lit():
    scene = scene_from_meshes([quad(10, 0.0), box()])
    sun = directional([0, -1, 0])
    sun = Light(sun.type, sun.position, sun.direction, sun.color, cast_shadows=False)
    ref = trace_reference(scene, camera(), [sun])
    hit = np.isfinite(ref.depth)
    assert np.all(ref.visibility[hit] == 1.0) and ref.valid.sum() > 0


def test_missing_embreex_raises_reference_unavailable(monkeypatch):
    monkeypatch.setitem(sys.modules, "embreex", None)  # makes `import embreex` fail
    scene = scene_from_meshes([box()])
    with pytest.raises(ReferenceUnavailable, match="embreex"):
        trace_reference(scene, camera(), [directional([0, -1, 0])])


def test_missing_scipy_raises_reference_unavailable(monkeypatch):
    """scipy is in the reference extra, not the service's install: without it the metrics say
    what to install instead of failing with an ImportError (a 500 over HTTP)."""
    truth = np.zeros((10, 12), bool)
    truth[2:6, 3:8] = True
    rend = np.roll(truth, 1, axis=1)
    monkeypatch.setitem(sys.modules, "scipy", None)  # makes `from scipy import ...` fail
    monkeypatch.setitem(sys.modules, "scipy.ndimage", None)
    with pytest.raises(ReferenceUnavailable, match="scipy"):
        shadow_metrics(_vis(rend), _vis(truth), np.ones_like(truth))
    # Masks without a boundary need no distance transform, so no scipy.
    empty = np.zeros_like(truth)
    assert shadow_metrics(_vis(empty), _vis(empty), np.ones_like(truth)).iou == 1.0


def test_service_without_scipy_refuses_the_reference_before_rendering(monkeypatch):
    """The service offers the reference (else 422 unavailable_feature, before any render) only
    where both embreex and scipy are installed."""
    pytest.importorskip("fastapi")
    import importlib.util

    from shadowmap.app import deps

    assert deps.optional_features()["reference"] is True
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "scipy" else find_spec(name, *a))
    assert deps.optional_features()["reference"] is False


# ------------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------------


def _vis(mask: np.ndarray) -> np.ndarray:
    """Visibility image from a shadow mask: 0 in shadow, 1 lit."""
    return np.where(mask, 0.0, 1.0)


def test_metrics_iou_and_counts():
    truth = np.zeros((10, 10), bool)
    truth[0, :6] = True  # 6 shadowed
    rend = np.zeros((10, 10), bool)
    rend[0, 4:8] = True  # 4 shadowed, 2 shared
    m = shadow_metrics(_vis(rend), _vis(truth), np.ones((10, 10), bool))
    assert m.pixels == 100
    assert m.iou == pytest.approx(2 / 8)
    assert m.misclassified_pct == pytest.approx(6.0)
    assert m.false_shadow_pct == pytest.approx(100 * 2 / 94)
    assert m.missed_shadow_pct == pytest.approx(100 * 4 / 6)


def test_metrics_acne_only_and_leak_only():
    valid = np.ones((10, 10), bool)
    lit = np.zeros((10, 10), bool)
    acne = np.zeros((10, 10), bool)
    acne[2, :5] = True
    m = shadow_metrics(_vis(acne), _vis(lit), valid)
    assert m.false_shadow_pct == pytest.approx(5.0)
    assert m.missed_shadow_pct == 0.0 and m.iou == 0.0
    m = shadow_metrics(_vis(lit), _vis(acne), valid)  # every true shadow leaked
    assert m.missed_shadow_pct == pytest.approx(100.0) and m.false_shadow_pct == 0.0
    m = shadow_metrics(_vis(lit), _vis(lit), valid)
    assert m.iou == 1.0 and m.misclassified_pct == 0.0 and math.isnan(m.edge_distance_px)
    d = m.to_dict()
    assert d["edge_distance_px"] is None and d["pixels"] == 100


def test_metrics_only_evaluate_valid_finite_pixels():
    truth = np.zeros((4, 5), bool)
    rend = np.ones((4, 5), bool)
    valid = np.zeros((4, 5), bool)
    valid[0] = True
    ref = _vis(truth)
    ref[0, 0] = np.nan
    out = _vis(rend)
    out[0, 1] = np.nan
    m = shadow_metrics(out, ref, valid)
    assert m.pixels == 3
    assert m.false_shadow_pct == pytest.approx(100.0)


def test_edge_distance_of_shifted_boundary_is_the_shift():
    truth = np.zeros((30, 40), bool)
    truth[:, :15] = True
    for shift in (1, 3, 7):
        rend = np.zeros_like(truth)
        rend[:, : 15 + shift] = True
        m = shadow_metrics(_vis(rend), _vis(truth), np.ones_like(truth))
        assert m.edge_distance_px == pytest.approx(shift)
    same = shadow_metrics(_vis(truth), _vis(truth), np.ones_like(truth))
    assert same.edge_distance_px == 0.0 and same.iou == 1.0


def test_edge_distance_of_shifted_square_matches_brute_force():
    truth = np.zeros((20, 24), bool)
    truth[5:12, 6:13] = True
    rend = np.roll(truth, (2, 3), axis=(0, 1))
    m = shadow_metrics(_vis(rend), _vis(truth), np.ones_like(truth))

    def edges(mask):
        pts = []
        for y, x in zip(*np.nonzero(mask), strict=True):
            nbs = [(y + dy, x + dx) for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1))]
            if any(0 <= a < 20 and 0 <= b < 24 and not mask[a, b] for a, b in nbs):
                pts.append((y, x))
        return np.array(pts, float)

    a, b = edges(rend), edges(truth)
    dist = np.linalg.norm(a[:, None] - b[None], axis=2)
    expected = (dist.min(axis=1).sum() + dist.min(axis=0).sum()) / (len(a) + len(b))
    assert m.edge_distance_px == pytest.approx(expected)
    assert 0 < m.edge_distance_px <= math.hypot(2, 3)


def test_edge_distance_when_one_mask_has_no_edge():
    truth = np.zeros((6, 8), bool)
    rend = truth.copy()
    rend[2:4, 2:4] = True
    m = shadow_metrics(_vis(rend), _vis(truth), np.ones_like(truth))
    assert m.edge_distance_px == pytest.approx(math.hypot(6, 8))
    # A boundary against unevaluated pixels is no edge.
    valid = rend.copy()
    m = shadow_metrics(_vis(rend), _vis(rend), valid)
    assert math.isnan(m.edge_distance_px) and m.pixels == 4


def test_compare_all_per_light():
    scene = scene_from_meshes([quad(10, 0.0), box()])
    ref = trace_reference(scene, camera(w=64, h=48),
                          [directional([0, -1, 0]), point([1.2, 5.0, 0.7])])
    out = compare_all(ref.visibility.copy(), ref)
    assert len(out) == 2 and all(isinstance(m, ShadowMetrics) for m in out)
    assert all(m.iou == 1.0 and m.misclassified_pct == 0.0 and m.edge_distance_px == 0.0
               for m in out)
    assert out[0].pixels == int(ref.valid[..., 0].sum())
    with pytest.raises(ValueError):
        compare_all(ref.visibility[..., :1], ref)
