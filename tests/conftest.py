"""Shared fixtures: the test models, one GL renderer per session, ray-traced references."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def models_dir() -> Path:
    """The glTF test scenes: $SHADOWMAP_MODELS, else ../shared/models beside the checkout."""
    env = os.environ.get("SHADOWMAP_MODELS")
    path = Path(env) if env else ROOT.parent / "shared" / "models"
    if not (path / "Duck.glb").is_file():
        raise RuntimeError(f"test models not found in {path}: set SHADOWMAP_MODELS")
    return path


@pytest.fixture(scope="session")
def models() -> Path:
    return models_dir()


@pytest.fixture(scope="session")
def renderer():
    """One GL context for the whole session (a GL context belongs to one thread)."""
    from shadowmap.renderer import Renderer

    r = Renderer()
    yield r
    r.close()


#: GL renderers that rasterize on the CPU (EGL and OSMesa both name Mesa's llvmpipe).
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast")


@pytest.fixture(scope="session")
def software_gl(renderer) -> str:
    """For tests whose slow case is slow only on a CPU rasterizer: the renderer's name, or a skip.

    A render meant to outlast a timeout (eight 81-tap point lights at 2896x2896 take about 9 s
    on llvmpipe here) finishes in a fraction of a second on a GPU, so the timeout under test
    would never fire there.
    """
    name = renderer.info["renderer"]
    if not any(s in name.lower() for s in SOFTWARE_GL):
        pytest.skip(f"the slow case is calibrated for a CPU rasterizer; {name} renders it at once")
    return name


def _gl_errors() -> list[int]:
    from OpenGL import GL

    errors = []
    while (err := GL.glGetError()) != GL.GL_NO_ERROR and len(errors) < 16:
        errors.append(int(err))
    return errors


@pytest.fixture(autouse=True)
def no_gl_errors(request):
    """Every test on the session's GL context leaves no GL error behind (moderngl's ``ctx``
    fixture): errors recorded before the test are reported as the earlier test's, not this one's.
    """
    if "renderer" not in request.fixturenames:
        yield
        return
    r = request.getfixturevalue("renderer")
    r.context.make_current()
    before = _gl_errors()
    assert not before, f"GL errors left by an earlier test: {[hex(e) for e in before]}"
    yield
    if r.closed:
        return
    r.context.make_current()
    after = _gl_errors()
    assert not after, f"GL errors after the test: {[hex(e) for e in after]}"


def load_model(models: Path, name: str, ground: bool = True):
    from shadowmap.renderer import load_scene

    path = models / name
    resources = None
    if name.endswith(".gltf"):
        resources = {p.name: p.read_bytes() for p in models.iterdir() if p.suffix == ".bin"}
    scene = load_scene(path, resources=resources)
    return scene.with_ground() if ground else scene
