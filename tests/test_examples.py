"""The files in examples/ are what examples/make_models.py makes, and each params file is a
valid request."""

from __future__ import annotations

import json
import runpy
from pathlib import Path

import numpy as np
import pytest

from shadowmap.renderer import RenderParams, load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

pytestmark = pytest.mark.skipif(not (EXAMPLES / "make_models.py").is_file(),
                                reason="examples/ is not beside the tests")


def _geometry(scene) -> list[tuple[str, np.ndarray]]:
    """Each instance's name and world-space triangles, in name order."""
    return sorted(((i.name, scene.world_triangles(i)) for i in scene.instances),
                  key=lambda item: item[0])


def _same(a, b) -> bool:
    return [n for n, _ in a] == [n for n, _ in b] and all(
        np.allclose(x, y, atol=1e-6) for (_, x), (_, y) in zip(a, b, strict=True))


def test_the_scenes_are_what_make_models_writes(tmp_path):
    runpy.run_path(str(EXAMPLES / "make_models.py"), run_name="make_models")["main"](tmp_path)
    for name in ("demo.glb", "objects.glb"):
        assert _same(_geometry(load_scene(EXAMPLES / name)),
                     _geometry(load_scene(tmp_path / name))), name
    folder = EXAMPLES / "demo_gltf"
    gltf = load_scene(folder / "demo.gltf")
    assert _same(_geometry(gltf), _geometry(load_scene(EXAMPLES / "demo.glb")))
    assert {n for n, _ in _geometry(load_scene(EXAMPLES / "objects.glb"))} == {
        "box", "sphere", "pole"}


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.json")))
def test_params_files_are_valid_requests(name):
    RenderParams.model_validate(json.loads((EXAMPLES / name).read_text()))
