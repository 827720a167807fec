"""Warnings: everything a render had to drop or approximate is listed in ``result.warnings``, in
``report()``, and (see test_app.py, test_cli.py) in the service's responses and on the CLI's
stderr.

The pure tests judge requests without GL (``request_warnings``, the header's cap); the GL ones
check that a render carries the scene's warnings and the renderer's own.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from shadowmap.renderer import Limits, RenderParams
from shadowmap.renderer import testing as T
from shadowmap.renderer.render import request_warnings
from shadowmap.renderer.scene import SceneLight

LOOK = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}


def warnings_of(limits: Limits | None = None, scene=None, **params) -> list[str]:
    return request_warnings(RenderParams(**params), scene or T.caster_on_ground(),
                            limits or Limits())


# -- the renderer's own findings (no GL) ---------------------------------------------------------


def test_a_plain_request_has_no_warnings():
    assert warnings_of() == []
    assert warnings_of(camera=LOOK, lights=[{"type": "spot", "position": [0, 4, 0],
                                            "direction": [0, -1, 0], "range": 9}]) == []


def test_explicit_max_map_size_over_the_limit_is_reported():
    (w,) = warnings_of(Limits(max_map_size=2048), shadows={"max_map_size": 4096})
    assert "shadows.max_map_size 4096" in w and "2048" in w
    # The default under a lower limit is the service's configuration, not the request's.
    assert warnings_of(Limits(max_map_size=2048)) == []
    # An explicit map size is not bounded by max_map_size: nothing was clamped.
    assert warnings_of(Limits(max_map_size=2048),
                       shadows={"max_map_size": 4096, "map_size": 1024}) == []
    assert warnings_of(Limits(max_map_size=4096), shadows={"max_map_size": 4096}) == []


def test_unused_settings_are_reported():
    (w,) = warnings_of(shadows={"filter": "hard", "pcf_kernel": 5})
    assert "pcf_kernel 5" in w
    # A light has only its own fields: one the type has no use for is refused, not ignored.
    for light in ({"type": "point", "position": [0, 3, 0], "direction": [0, -1, 0]},
                  {"type": "directional", "direction": [0, -1, 0], "range": 4.0}):
        with pytest.raises(ValidationError):
            warnings_of(lights=[light])


def test_poses_made_rigid_are_reported():
    scaled = [[2, 0, 0, 0], [0, 2, 0, 1], [0, 0, 2, 6], [0, 0, 0, 1]]
    assert warnings_of(camera={"pose": scaled}) == [
        "camera: the pose has scale or shear: its nearest rotation is used"]
    assert warnings_of(lights=[{"pose": scaled}]) == [
        "light 0: the pose has scale or shear: its nearest rotation is used"]
    # Rigid poses are no warning; mirrored ones are refused by the request model.
    rigid = np.eye(4)
    rigid[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]
    rigid[:3, 3] = [5, 1, 0]
    assert warnings_of(camera={"pose": rigid.tolist()}) == []
    mirrored = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]]
    with pytest.raises(ValidationError):
        warnings_of(camera={"pose": mirrored})


def test_camera_up_along_the_view_is_reported():
    down = {"eye": [0, 6, 0], "target": [0, 0, 0]}
    (w,) = warnings_of(camera={**down, "up": [0, 1, 0]})
    assert w.startswith("camera: up") and "parallel" in w
    assert warnings_of(camera=down) == []  # no up given: any up is as good
    assert warnings_of(camera={**LOOK, "up": [0, 1, 0]}) == []
    assert warnings_of(camera={**LOOK, "up": [0.2, 3.0, 0.0]}) == []  # honoured, not unit


def test_what_resolving_the_files_lights_changed_is_reported():
    scene = T.caster_on_ground()
    pose = np.eye(4)
    pose[:3, 3] = (0, 4, 0)
    scene.lights = [
        SceneLight("spot", pose, (1, 1, 1), 1.0, None, 0.0, math.pi / 2),
        SceneLight("point", pose, (1, 1, 1), 800.0, None, 0.0, math.pi / 4),
        SceneLight("area", pose, (1, 1, 1), 1.0, None, 0.0, math.pi / 4),
        SceneLight("directional", pose, (1, 1, 1), 3.0, None, 0.0, math.pi / 4),
        SceneLight("spot", pose, (1, 1, 1), 1.0, 5.0, 0.5, 0.3),
    ]
    found = request_warnings(RenderParams(), scene, Limits())
    assert found == [
        "light 0 of the file: outer cone angle 90 degrees clamped to 89.5",
        "light 1 of the file: intensity 800 (candela) is not used: a file's spot and point "
        "lights shine at 1",
        "light 2 of the file: type 'area' is not supported: rendered as a directional light",
        "light 4 of the file: inner cone angle 28.6479 degrees clamped to 17.1715",
    ]
    # Lights given in the request replace the file's: nothing of the file's was changed.
    assert request_warnings(RenderParams(lights=[{}]), scene, Limits()) == []


# -- the header's cap (no GL) ----------------------------------------------------------------


def test_warnings_header_is_compact_ascii_json():
    from shadowmap.app.encode import warnings_header

    assert warnings_header([]) == "[]"
    text = ["light 0: ignored", "matériau «verre»:\nline\tbreak \x7f"]
    value = warnings_header(text)
    assert value.isascii() and all(0x20 <= ord(c) < 0x7F for c in value)
    assert json.loads(value) == text
    assert value.startswith('["light 0') and ", " not in value


def test_warnings_header_is_capped_with_a_count_of_the_rest():
    from shadowmap.app.encode import WARNING_ITEM_MAX, WARNINGS_HEADER_MAX, warnings_header

    many = [f"warning {i}: " + "x" * 80 for i in range(100)]
    value = warnings_header(many)
    assert len(value) <= WARNINGS_HEADER_MAX
    items = json.loads(value)
    kept = len(items) - 1
    assert 10 < kept < 100 and items[:kept] == many[:kept]
    assert items[-1] == f"... and {100 - kept} more"
    # One very long warning is cut rather than crowding out the others.
    items = json.loads(warnings_header(["y" * 10_000, "short"]))
    assert len(items[0]) == WARNING_ITEM_MAX and items[0].endswith("...")
    assert items[1] == "short"
    # A tight limit still says how many there were.
    assert json.loads(warnings_header(["z" * 100] * 3, limit=60)) == ["... and 3 more"]


def test_json_body_has_the_warnings():
    from shadowmap.app.encode import RenderJSON, json_body

    body = json.loads(json_body([], {"plan": {}, "gl": {}, "warnings": ["a", "b"]}, {}))
    assert body["warnings"] == ["a", "b"]
    assert RenderJSON.model_validate(body).warnings == ["a", "b"]
    assert "warnings" in RenderJSON.model_json_schema()["properties"]


# -- renders (GL) ----------------------------------------------------------------------------


def _scene_with_warnings(*warnings: str, floor: bool = True):
    scene = T.caster_on_ground() if floor else _box_scene()
    scene.warnings = list(warnings)  # what a loader found
    scene.key += ":with-warnings"
    return scene


def _box_scene():
    import trimesh

    from shadowmap.renderer.scene import scene_from_meshes

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.apply_translation((0.0, 0.5, 0.0))
    return scene_from_meshes([box], ["box"])


@pytest.mark.gl
def test_render_lists_the_scenes_warnings_then_its_own(renderer):
    scene = _scene_with_warnings("material 0: KHR_materials_clearcoat is not supported: dropped",
                                 "texture 1: KTX2 image not decoded: dropped")
    params = RenderParams(width=96, height=64, camera=LOOK,
                          shadows={"filter": "hard", "pcf_kernel": 3})
    result = renderer.render(scene, params)
    assert result.warnings == [
        "material 0: KHR_materials_clearcoat is not supported: dropped",
        "texture 1: KTX2 image not decoded: dropped",
        "shadows.pcf_kernel 3 is not used: the filter is 'hard'",
    ]
    report = result.report()
    assert report["warnings"] == result.warnings
    json.dumps(report["warnings"])  # JSON-ready
    # The scene's list is read, not extended: a second render says the same.
    again = renderer.render(scene, params)
    assert again.warnings == result.warnings
    assert scene.warnings == result.warnings[:2]


@pytest.mark.gl
def test_warnings_survive_the_ground_and_are_listed_once(renderer):
    # A box alone: no floor of its own, so ground=True adds the plane.
    scene = _scene_with_warnings("mesh 2: primitive mode LINES is not drawn", "same twice",
                                 "same twice", floor=False)
    result = renderer.render(scene, RenderParams(width=96, height=64, camera=LOOK, ground=True))
    assert result.warnings == ["mesh 2: primitive mode LINES is not drawn", "same twice"]


@pytest.mark.gl
def test_a_clean_render_has_no_warnings(renderer):
    result = renderer.render(T.caster_on_ground(), RenderParams(width=96, height=64, camera=LOOK))
    assert result.warnings == [] and result.report()["warnings"] == []


@pytest.mark.gl
def test_camera_warnings_follow_each_camera_of_requests_alike_otherwise(renderer):
    """Requests that differ in their camera alone share what the renderer settles before the
    camera; the camera's own warnings are each request's. A batch's views and a moving client
    send such requests: one view's warning must not stay with the next, nor a clean view's
    silence hide the next one's."""
    scene = T.caster_on_ground()
    down = {"eye": [0, 6, 0], "target": [0, 0, 0]}
    scaled = [[2, 0, 0, 0], [0, 2, 0, 1], [0, 0, 2, 6], [0, 0, 0, 1]]
    cameras = [LOOK, {**down, "up": [0, 1, 0]}, {**LOOK, "up": [0, 1, 0]}, {"pose": scaled},
               {**down, "up": [0, -1, 0]}, LOOK]
    said = [renderer.render(scene, RenderParams(width=96, height=64, camera=c)).warnings
            for c in cameras]
    assert said == [[], [f"camera: up {[0.0, 1.0, 0.0]} is parallel to the view direction: "
                         "another up vector is used"], [],
                    ["camera: the pose has scale or shear: its nearest rotation is used"],
                    [f"camera: up {[0.0, -1.0, 0.0]} is parallel to the view direction: "
                     "another up vector is used"], []]
    # An up vector whose squares underflow keeps its direction: honoured, not replaced.
    tiny = renderer.render(scene, RenderParams(width=96, height=64,
                                               camera={**LOOK, "up": [0, 1e-200, 0]}))
    plain = renderer.render(scene, RenderParams(width=96, height=64,
                                                camera={**LOOK, "up": [0, 1, 0]}))
    assert tiny.warnings == []
    np.testing.assert_array_equal(tiny.camera.pose, plain.camera.pose)


@pytest.mark.gl
def test_clamped_max_map_size_is_reported_and_still_clamped(renderer):
    params = RenderParams(width=96, height=64, camera=LOOK, shadows={"max_map_size": 16384})
    assert renderer.limits.max_map_size < 16384
    result = renderer.render(T.caster_on_ground(), params)
    (w,) = result.warnings
    assert "shadows.max_map_size 16384" in w
    assert all(lp["map_size"] <= renderer.limits.max_map_size for lp in result.plan["lights"])
