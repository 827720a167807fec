"""One-sided casters: the light pass leaves out the far side of closed surfaces.

Small exact cases for :func:`primitive_closure` (which meshes close a surface, and which way they
wind) and for the plan's rule (:func:`one_sided_casters`: only with the light outside, nothing
clipped by the near plane, no texture cut-out); then the maps themselves, drawn both ways and
compared texel for texel, for every kind of map, mirrored instances and an inside-out mesh; and a
light shut in a closed box, which must keep the ground outside it dark.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from maps import assert_same_but_silhouettes
from shadowmap.renderer import RenderParams, Scene
from shadowmap.renderer import testing as T
from shadowmap.renderer.camera import resolve_camera
from shadowmap.renderer.lights import resolve_lights
from shadowmap.renderer.plan import instances as I
from shadowmap.renderer.plan import make_plan
from shadowmap.renderer.plan import plan as P
from shadowmap.renderer.scene import Instance, Material, Primitive, scene_from_meshes, world_bounds

SIZE = {"width": 160, "height": 120}
CAMERA = {"eye": [0.0, 4.5, 7.5], "target": [0.0, 0.6, 0.0]}


def _prim(positions, faces, **material) -> Primitive:
    p = np.asarray(positions, np.float32)
    return Primitive(p, np.zeros_like(p), np.asarray(faces, np.uint32).reshape(-1, 3),
                     Material(np.ones(4, np.float32), **material))


def _box(**kw) -> Primitive:
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return _prim(m.vertices, m.faces, **kw)


def _split_box() -> Primitive:
    """A box with its own three vertices per triangle (as a file splits them at creases)."""
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return _prim(m.vertices[m.faces].reshape(-1, 3), np.arange(3 * len(m.faces)))


def closure(prim: Primitive) -> int:
    I._CLOSURE.pop(prim, None)
    return I.primitive_closure(prim)


# -- which meshes close a surface -------------------------------------------------------------


def test_a_box_is_closed_and_wound_outward():
    assert closure(_box()) == 1


def test_vertices_split_at_creases_are_welded():
    assert closure(_split_box()) == 1


def test_an_inside_out_box_winds_the_other_way():
    box = _box()
    assert closure(_prim(box.positions, box.indices[:, ::-1])) == -1


def test_an_open_box_is_open():
    box = _box()
    assert closure(_prim(box.positions, box.indices[2:])) == 0


def test_one_flipped_triangle_breaks_the_winding():
    f = _box().indices.copy()
    f[0] = f[0, ::-1]
    assert closure(_prim(_box().positions, f)) == 0


def test_a_doubled_face_is_not_a_closed_surface():
    box = _box()
    assert closure(_prim(box.positions, np.vstack([box.indices, box.indices[:1]]))) == 0


def test_degenerate_triangles_are_left_out_of_the_test():
    box = _box()
    f = np.vstack([box.indices, [[0, 0, 1], [2, 3, 2]]])
    assert closure(_prim(box.positions, f)) == 1


def test_a_flat_quad_is_open_and_so_is_a_sheet_with_both_sides():
    quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    assert closure(_prim(quad, [[0, 1, 2], [0, 2, 3]])) == 0
    # Both windings of one quad: four triangles meet at the diagonal, so it is no surface's.
    assert closure(_prim(quad, [[0, 1, 2], [0, 2, 3], [2, 1, 0], [3, 2, 0]])) == 0
    # A tetrahedron is closed.
    tet = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    assert closure(_prim(tet, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])) == 1


def test_minus_zero_is_zero():
    # A box with a corner at the origin, whose copies of that corner differ in the zeros' signs.
    box = _split_box()
    p = box.positions + np.float32(0.5)
    corner = np.flatnonzero(~p.any(axis=1))
    assert len(corner) > 1
    p[corner[0]] = -p[corner[0]]
    assert np.signbit(p[corner[0]]).all() and not np.signbit(p[corner[1]]).any()
    assert closure(_prim(p, box.indices)) == 1


def test_an_empty_primitive_is_open():
    assert closure(_prim(np.zeros((0, 3)), np.zeros((0, 3)))) == 0


# -- the plan's rule ------------------------------------------------------------------------


def _scene(*casters: tuple[Primitive, np.ndarray]) -> Scene:
    """A ground plane (a receiver that casts nothing) and the given (primitive, matrix) pairs."""
    ground = scene_from_meshes([T._plane(9.0)], ["ground"])
    ground.instances[0] = dataclasses.replace(ground.instances[0], cast_shadow=False)
    prims, insts = list(ground.primitives), list(ground.instances)
    for prim, m in casters:
        prims.append(prim)
        local = prim.local_bounds.astype(np.float64)
        insts.append(Instance(len(prims) - 1, m, name=f"c{len(insts)}",
                              bounds=world_bounds(local, m)))
    return Scene(prims, insts, key=f"one-sided-{id(prims)}")


def _lift(y: float, x: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, 0.0)
    return m


def _plan(scene: Scene, light: dict, **params):
    p = RenderParams(camera=CAMERA, lights=[light], **SIZE, **params)
    camera = resolve_camera(p.camera, scene, p.width, p.height)
    return make_plan(scene, camera, resolve_lights(p.lights, scene), np.zeros(3), p)


SUN = {"type": "directional", "direction": [0.3, -1.0, -0.2]}


def test_closed_casters_are_one_sided_and_reported():
    scene = _scene((_box(), _lift(1.0)), (_prim(_box().positions, _box().indices[2:]),
                                          _lift(1.0, 1.5)))
    lp = _plan(scene, SUN).lights[0]
    assert sorted(lp.casters) == [1, 2]
    assert dict(zip(lp.casters, lp.one_sided.tolist(), strict=True)) == {1: 1, 2: 0}
    assert lp.to_dict()["one_sided"] == 1


def test_an_inside_out_caster_leaves_out_the_other_side():
    box = _box()
    lp = _plan(_scene((_prim(box.positions, box.indices[:, ::-1]), _lift(1.0))), SUN).lights[0]
    assert lp.one_sided.tolist() == [-1]


def test_without_optimize_every_face_is_drawn():
    lp = _plan(_scene((_box(), _lift(1.0))), SUN, optimize=False).lights[0]
    assert lp.one_sided.size == 0 and lp.to_dict()["one_sided"] == 0


def test_a_texture_cut_out_draws_both_sides():
    texture = np.full((4, 4, 4), 255, np.uint8)
    box = _box(texture=texture, alpha_mode="MASK")
    box = dataclasses.replace(box, uv=np.zeros((len(box.positions), 2), np.float32))
    lp = _plan(_scene((box, _lift(1.0))), SUN).lights[0]
    assert lp.one_sided.size == 0


@pytest.mark.parametrize("light", [
    {"type": "point", "position": [0.0, 1.0, 0.0]},
    {"type": "spot", "position": [0.0, 1.0, 0.0], "direction": [0.0, -1.0, 0.0],
     "outer_cone_deg": 60},
], ids=["point", "spot"])
def test_a_light_inside_a_closed_caster_draws_both_sides(light):
    lp = _plan(_scene((_box(), _lift(1.0))), light).lights[0]
    assert lp.kind is not None and sorted(lp.casters) == [1]
    assert not lp.one_sided.any()


def test_a_caster_reaching_nearer_than_the_near_plane_draws_both_sides():
    scene = _scene((_box(), _lift(1.0)))
    lp = _plan(scene, {"type": "spot", "position": [0.0, 3.0, 0.0],
                       "direction": [0.0, -1.0, 0.0], "outer_cone_deg": 60}).lights[0]
    assert lp.one_sided.tolist() == [1]
    # The same map with its near plane pushed past the box's top: the box would be cut open.
    ctx = P.PlanContext.build(scene, resolve_camera(
        RenderParams(camera=CAMERA, **SIZE).camera, scene, 160, 120), np.zeros(3),
        RenderParams(camera=CAMERA, **SIZE))
    import dataclasses

    cut = dataclasses.replace(lp, near=1.6)
    assert P.one_sided_casters(ctx, cut).size == 0


def test_cascades_decide_per_cascade():
    scene = _scene(*[(_box(), _lift(0.6, x)) for x in (-3.0, 0.0, 3.0)])
    lp = _plan(scene, SUN, shadows={"cascades": 3}).lights[0]
    assert lp.cascades
    for c in lp.cascades:
        assert c.one_sided.tolist() == [1] * len(c.casters)
    assert all("one_sided" in c for c in lp.to_dict()["cascades"])


# -- the maps, drawn both ways --------------------------------------------------------------


def _maps(renderer, scene: Scene, p: RenderParams, one_sided: bool
          ) -> list[tuple[np.ndarray, float]]:
    """The light pass's maps, read back, and each one's depth step, with the plan's one-sided
    casters or without any."""
    saved = P.one_sided_casters
    if not one_sided:
        P.one_sided_casters = lambda ctx, m: np.zeros(0, np.int8)
    try:
        gpu, _, _ = renderer._upload(scene)
        camera = resolve_camera(p.camera, scene, p.width, p.height)
        plan = make_plan(scene, camera, resolve_lights(p.lights, scene), gpu.origin, p)
        assert any(m.one_sided.any() for m in plan.map_lights) == one_sided
        maps = renderer.light_pass.render(gpu, plan.lights, p.shadows, "")
        return [(m.read_depth(), m.step) for m in maps]
    finally:
        P.one_sided_casters = saved


def _tilted(extents=(0.7, 1.0, 0.5)) -> Primitive:
    m = trimesh.creation.box(extents=extents)
    m.apply_transform(trimesh.transformations.rotation_matrix(0.5, [0, 0, 1]))
    m.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1, 0, 0]))
    return _prim(m.vertices, m.faces)


def _mirror_x(x: float) -> np.ndarray:
    m = _lift(1.1, x)
    m[0, 0] = -1.0
    return m


MAP_LIGHTS = {
    "directional": SUN,
    "cascades": SUN,
    "spot": {"type": "spot", "position": [0.5, 5.0, 2.0], "target": [0, 0, 0],
             "outer_cone_deg": 45},
    "point": {"type": "point", "position": [0.4, 3.5, 1.8]},
}


@pytest.mark.gl
@pytest.mark.parametrize("encoding", ["depth", "rgba8"])
@pytest.mark.parametrize("light", list(MAP_LIGHTS))
def test_maps_are_the_same_with_the_far_side_left_out(renderer, light, encoding):
    inverted = _tilted()
    inverted = _prim(inverted.positions, inverted.indices[:, ::-1])
    scene = _scene((_tilted(), _lift(1.1, -1.2)), (_tilted(), _mirror_x(0.4)),
                   (inverted, _lift(1.0, 1.8)), (_prim(T._plane(1.0).vertices,
                                                      T._plane(1.0).faces), _lift(2.2)))
    p = RenderParams(camera=CAMERA, lights=[MAP_LIGHTS[light]], **SIZE,
                     shadows={"encoding": encoding, "map_size": 512,
                              "cascades": 3 if light == "cascades" else 1})
    both, one = _maps(renderer, scene, p, False), _maps(renderer, scene, p, True)
    assert len(both) == len(one)
    for (a, step), (b, _) in zip(both, one, strict=True):
        assert_same_but_silhouettes(a, b, step)


@pytest.mark.gl
def test_a_real_model_keeps_its_map_within_a_step_at_the_silhouette(renderer, models):
    from conftest import load_model

    scene = load_model(models, "Duck.glb")
    p = RenderParams(**SIZE, shadows={"map_size": 2048})
    ((a, step),), ((b, _),) = _maps(renderer, scene, p, False), _maps(renderer, scene, p, True)
    assert step == pytest.approx(1 / 65535)  # 'auto' depth bits: 16
    assert_same_but_silhouettes(a, b, step)


@pytest.mark.gl
@pytest.mark.parametrize("light", [
    {"type": "point", "position": [0.0, 1.0, 0.0]},
    # (a cone over the whole ground: outside a cone the shadow factor is 1, as nothing is lit)
    {"type": "spot", "position": [0.0, 1.0, 0.0], "direction": [0.0, -1.0, 0.0],
     "outer_cone_deg": 85},
], ids=["point", "spot"])
def test_a_light_shut_in_a_closed_box_leaves_the_ground_dark(renderer, light):
    p = RenderParams(camera=CAMERA, lights=[light], **SIZE, outputs=["visibility", "depth"])
    r = renderer.render(_scene((_box(), _lift(1.0))), p)
    # The ground's pixels: where the ground alone shows at the same depth.
    alone = renderer.render(_scene(), p).depth
    ground = np.isfinite(r.depth) & np.isclose(r.depth, alone, rtol=1e-5)
    vis = r.visibility[..., 0][ground]
    assert vis.size > 5000
    # Only the box's own faces are lit from inside; the ground around it is in its shadow.
    assert np.mean(vis > 0.5) < 0.2


def test_the_map_cache_keeps_one_sided_maps_apart():
    import dataclasses

    from shadowmap.renderer.params import ShadowParams
    from shadowmap.renderer.passes.light_pass import map_key

    lp = _plan(_scene((_box(), _lift(1.0))), SUN).lights[0]
    both = dataclasses.replace(lp, one_sided=np.zeros(0, np.int8))
    shadows = ShadowParams()
    assert map_key("s", np.zeros(3), lp, shadows) != map_key("s", np.zeros(3), both, shadows)
    assert map_key("s", np.zeros(3), lp, shadows) == map_key(
        "s", np.zeros(3), dataclasses.replace(lp), shadows)
