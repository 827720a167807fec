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
