"""``ground: true`` on a scene that already stands on a floor adds no second one, and says so."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shadowmap.renderer import RenderParams, load_scene, scene_from_trimesh
from shadowmap.renderer.demo import demo_glb
from shadowmap.renderer.ground import existing_floor


def _scene(*parts: tuple[trimesh.Trimesh, tuple[float, float, float]]):
    scene = trimesh.Scene()
    for i, (mesh, at) in enumerate(parts):
        scene.add_geometry(mesh, node_name=f"n{i}",
                           transform=trimesh.transformations.translation_matrix(at))
    return scene_from_trimesh(scene)


BOX = trimesh.creation.box(extents=(1, 1, 1))
SLAB = trimesh.creation.box(extents=(6, 0.1, 6))


def test_the_demo_floor_is_found():
    floor = existing_floor(load_scene(demo_glb()))
    assert floor is not None and floor.name == "ground"


@pytest.mark.parametrize(("parts", "found"), [
    (((SLAB, (0, -0.05, 0)), (BOX, (0, 0.5, 0))), True),  # a box standing on a slab
    (((BOX, (0, 0.5, 0)),), False),  # a box alone
    (((SLAB, (0, -0.05, 0)), (BOX, (0, -1.5, 0))), False),  # something under the slab
    (((trimesh.creation.box(extents=(2, 0.1, 2)), (0, -0.05, 0)), (BOX, (2.5, 0.5, 0))),
     False),  # a slab that does not span the scene
    (((trimesh.creation.box(extents=(6, 1.5, 6)), (0, -0.75, 0)), (BOX, (0, 0.5, 0))),
     False),  # a thick block, not a floor
    (((trimesh.creation.icosphere(radius=3), (0, 0, 0)), (BOX, (0, 3.5, 0))), False),
])
def test_existing_floor(parts, found):
    assert (existing_floor(_scene(*parts)) is not None) == found


def test_a_flat_scene_has_no_floor_of_its_own():
    assert existing_floor(_scene((SLAB, (0, 0, 0)))) is None


@pytest.mark.gl
def test_ground_on_a_floored_scene_is_left_out_with_a_warning(renderer):
    params = {"width": 160, "height": 120, "camera": {"eye": [3.5, 3, 5], "target": [0, 0.4, 0]}}
    scene = load_scene(demo_glb())
    plain = renderer.render(scene, RenderParams.model_validate(params))
    grounded = renderer.render(scene, RenderParams.model_validate({**params, "ground": True}))
    np.testing.assert_array_equal(grounded.color, plain.color)
    assert [w for w in grounded.warnings if "own floor" in w] and not plain.warnings
    # Without a floor the plane is added: it receives the objects' shadows.
    objects = _scene((BOX, (0, 0.5, 0)))
    bare = renderer.render(objects, RenderParams.model_validate(params))
    with_ground = renderer.render(objects, RenderParams.model_validate({**params, "ground": True}))
    assert not any("own floor" in w for w in with_ground.warnings)
    assert np.abs(with_ground.color.astype(int) - bare.color.astype(int)).mean() > 5


def test_no_camera_sees_ground_under_an_object_resting_on_it():
    """The added plane touches the scene's lowest point to within ``GROUND_GAP``: a slab on it
    leaves no crevice under its front edge where the truth is ground in the slab's shadow.

    The light comes from the front: every surface the camera sees is lit, except ground that
    shows through a gap under the slab. The camera is turned a little so that the edge crosses
    pixel rows and some pixel centres would fall in such a gap (the plane used to lie 1e-4 of the
    scene's height below it: 13 shadowed pixels here).
    """
    from shadowmap.renderer.camera import resolve_camera
    from shadowmap.renderer.lights import resolve_lights
    from shadowmap.renderer.reference import trace_reference

    slab = trimesh.creation.box(extents=(8.6, 0.2, 1.3))
    wall = trimesh.creation.box(extents=(8.6, 3, 0.1))
    scene = _scene((slab, (0, 0, -0.1)), (wall, (0, 1.6, -0.7))).with_ground()
    params = RenderParams.model_validate({
        "width": 640, "height": 480, "camera": {"eye": [2.5, 3, 8], "target": [0, 0.5, 0]},
        "lights": [{"type": "directional", "direction": [-0.1, -1, -0.2]}]})
    camera = resolve_camera(params.camera, scene, params.width, params.height)
    ref = trace_reference(scene, camera, resolve_lights(params.lights, scene))
    seen = ref.valid[..., 0]
    assert seen.sum() > 100_000
    assert int((ref.visibility[..., 0][seen] < 0.5).sum()) == 0
