"""The OpenAPI document is the contract: what it states, that it validates, and that a client
generated from it works against a real server.

The document tests build the app without starting it (no GL); the client test starts the
service under uvicorn, generates a typed client from its live ``/openapi.json`` with
openapi-python-client into a temporary folder, imports it and renders through it.
"""

from __future__ import annotations

import base64
import importlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pydantic import ValidationError

from shadowmap.app.errors import validation_errors
from shadowmap.app.main import create_app
from shadowmap.app.settings import Settings
from shadowmap.renderer import RenderParams
from shadowmap.renderer.params import light_params, parse_json

SMALL = Settings(max_image_side=64, max_pixels=64 * 64, max_map_size=256, max_lights=3)


def spec_of(settings: Settings = SMALL) -> dict:
    return create_app(settings).openapi()


def test_document_validates():
    validator = pytest.importorskip("openapi_spec_validator",
                                    reason="openapi-spec-validator is not installed")
    validator.validate(spec_of())
    validator.validate(spec_of(Settings()))


def test_limits_are_maximums_of_this_instance():
    schemas = spec_of()["components"]["schemas"]
    params = schemas["RenderParams"]["properties"]
    assert params["width"]["maximum"] == params["height"]["maximum"] == 64
    assert params["width"]["default"] == 64 and params["height"]["default"] == 48
    lights = next(s for s in params["lights"]["anyOf"] if s.get("type") == "array")
    assert lights["maxItems"] == 3
    sizes = next(s for s in schemas["ShadowParams"]["properties"]["map_size"]["anyOf"]
                 if s["type"] == "integer")
    assert sizes["enum"] == [16, 32, 64, 128, 256]
    # The library's own schema keeps the renderer's bounds.
    assert RenderParams.model_json_schema()["properties"]["width"]["maximum"] == 16384


def test_missing_features_are_not_offered(monkeypatch):
    import shadowmap.app.main as main

    monkeypatch.setattr(main, "optional_features", lambda: {"reference": False, "exr": False})
    params = spec_of()["components"]["schemas"]["RenderParams"]["properties"]
    assert params["reference"]["enum"] == [False]
    assert params["float_format"]["enum"] == ["png16"]


def _fields(schemas: dict):
    for name, schema in schemas.items():
        for field, prop in schema.get("properties", {}).items():
            yield name, field, prop


REQUEST_MODELS = ("RenderParams", "CameraParams", "DirectionalLight", "SpotLight", "PointLight",
                  "ShadowParams", "BiasParams")


def test_every_request_field_has_a_description_and_an_example():
    schemas = {k: v for k, v in spec_of()["components"]["schemas"].items()
               if k in REQUEST_MODELS}
    assert set(schemas) == set(REQUEST_MODELS)
    for model, field, prop in _fields(schemas):
        assert prop.get("description"), f"{model}.{field} has no description"
        nested = "$ref" in json.dumps(prop)
        assert nested or prop.get("examples"), f"{model}.{field} has no example"
    for model in ("CameraParams", "ShadowParams", "RenderParams", "DirectionalLight"):
        assert schemas[model]["examples"], model


def test_lights_are_a_discriminated_union():
    schemas = spec_of()["components"]["schemas"]
    lights = next(s for s in schemas["RenderParams"]["properties"]["lights"]["anyOf"]
                  if s.get("type") == "array")["items"]
    assert lights["discriminator"]["propertyName"] == "type"
    assert set(lights["discriminator"]["mapping"]) == {"directional", "spot", "point"}
    own = {
        "DirectionalLight": {"type", "pose", "position", "direction", "target", "color",
                             "intensity", "cast_shadows"},
        "SpotLight": {"type", "pose", "position", "direction", "target", "color", "intensity",
                      "inner_cone_deg", "outer_cone_deg", "range", "cast_shadows"},
        "PointLight": {"type", "pose", "position", "color", "intensity", "range",
                       "cast_shadows"},
    }
    for name, fields in own.items():
        assert set(schemas[name]["properties"]) == fields
        assert schemas[name]["additionalProperties"] is False
        assert "type" in schemas[name]["required"]


def test_every_status_is_documented_with_its_headers():
    paths = spec_of()["paths"]
    render = paths["/render"]["post"]["responses"]
    assert set(render) >= {"200", "400", "406", "408", "413", "415", "422", "500", "503", "504"}
    for status, response in render.items():
        assert "Server-Timing" in response["headers"], status
        if status != "200":
            schema = response["content"]["application/json"]["schema"]
            assert schema == {"$ref": "#/components/schemas/ErrorBody"}, status
    assert "Retry-After" in render["503"]["headers"]
    assert {"X-Render-Plan", "X-Render-Warnings"} <= set(render["200"]["headers"])
    assert {"/", "/docs", "/redoc", "/healthz", "/version", "/demo.glb"} <= set(paths)
    body = paths["/render"]["post"]["requestBody"]["content"]
    assert body["multipart/form-data"]["encoding"]["params"]["contentType"] == "application/json"
    assert body["multipart/form-data"]["schema"]["properties"]["params"]["$ref"].endswith(
        "/RenderParams")
    query = paths["/render"]["post"]["parameters"][0]
    assert query["name"] == "params" and "application/json" in query["content"]


@pytest.mark.parametrize("text", [
    '{"ground": 0}', '{"alpha": 1}', '{"optimize": "true"}', '{"reference": 0}',
    '{"specular": false}', '{"width": "64"}', '{"width": true}',
    '{"shadows": {"bias": {"constant": false}}}',
    '{"shadows": {"bias": {"polygon_offset": [0, false]}}}', '{"shadows": {"pcf_kernel": true}}',
    '{"lights": [{"direction": [0, -1, 0]}]}',  # JSON names the light's type
])
def test_json_types_are_strict(text):
    with pytest.raises(ValidationError):
        parse_json(text)


def test_python_api_stays_convenient():
    p = RenderParams(ground=1, width=64.0, lights=[{"direction": [0, -1, 0]}])
    assert p.ground is True and p.width == 64 and p.lights[0].type == "directional"
    assert light_params({"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0]}).type \
        == "spot"
    assert parse_json('{"width": 32.0}').width == 32  # JSON Schema's integer


@pytest.mark.parametrize("params, pointer", [
    ({"camera": {"znear": 3, "zfar": 1}}, "/camera/zfar"),
    ({"camera": {"eye": [1, 2, 3]}}, "/camera/target"),
    ({"camera": {"eye": [1, 2, 3], "target": [1, 2, 3]}}, "/camera/target"),
    ({"camera": {"pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}},
     "/camera/pose"),
    ({"lights": [{"type": "spot", "position": [0, 3, 0], "direction": [0, -1, 0],
                  "inner_cone_deg": 40, "outer_cone_deg": 30}]}, "/lights/0/inner_cone_deg"),
    ({"lights": [{"type": "point"}]}, "/lights/0/position"),
    ({"lights": [{"type": "directional", "direction": [0, 0, 0]}]}, "/lights/0/direction"),
    ({"shadows": {"fit": "scene", "cascades": 3}}, "/shadows/cascades"),
])
def test_cross_field_rules_name_the_field(params, pointer):
    with pytest.raises(ValidationError) as info:
        parse_json(json.dumps(params))
    errors = validation_errors(info.value)
    assert errors[0]["pointer"] == pointer and errors[0]["type"] == "cross_field", errors


def test_a_light_has_only_its_own_fields():
    with pytest.raises(ValidationError):
        parse_json('{"lights": [{"type": "point", "position": [0, 3, 0], "direction": [0,-1,0]}]}')
    with pytest.raises(ValidationError):
        parse_json('{"lights": [{"type": "directional", "range": 3}]}')


# ------------------------------------------------------------------------------------------------
# A generated client against the real server
# ------------------------------------------------------------------------------------------------


def _generate_client(spec: dict, folder: Path) -> str:
    """Generate a client package with openapi-python-client; returns its import name."""
    exe = shutil.which("openapi-python-client", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("openapi-python-client is not installed (the test extra has it)")
    spec_path = folder / "openapi.json"
    spec_path.write_text(json.dumps(spec))
    package = "shadowmap_generated_client"
    proc = subprocess.run([exe, "generate", "--path", str(spec_path), "--meta", "none",
                           "--output-path", str(folder / package)],
                          capture_output=True, text=True, timeout=300, cwd=folder)
    assert proc.returncode == 0 and (folder / package / "__init__.py").is_file(), (
        proc.stdout[-4000:] + proc.stderr[-4000:])
    # What it could not model it says; the models and the form and JSON bodies must be there.
    assert "ShadowParams" not in proc.stdout and "RenderParams" not in proc.stdout, proc.stdout
    return package


def _png(b64: str) -> np.ndarray:
    data = base64.b64decode(b64)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(Image.open(io.BytesIO(data)))


@pytest.mark.gl
def test_generated_client_renders(tmp_path):
    import os

    import httpx

    from api_scenes import box_glb
    from test_page import uvicorn_server

    env = {**os.environ, "SHADOWMAP_MAX_PIXELS": str(320 * 240)}
    with uvicorn_server(env=env) as url:
        spec = httpx.get(url + "/openapi.json").json()
        package = _generate_client(spec, tmp_path)
        sys.path.insert(0, str(tmp_path))
        try:
            client_mod = importlib.import_module(package)
            render = importlib.import_module(f"{package}.api.render.render")
            models = importlib.import_module(f"{package}.models")
            types = importlib.import_module(f"{package}.types")
            client = client_mod.Client(base_url=url, headers={"Accept": "application/json"},
                                       timeout=httpx.Timeout(120.0))
            # The demo scene, params as the JSON body, typed all the way.
            params = models.RenderParams(
                width=96, height=72, ground=False,
                outputs=[models.RenderParamsOutputsItem("color")],
                lights=[models.DirectionalLight(type_="directional",
                                                direction=[-0.5, -1.0, 0.2])])
            reply = render.sync(client=client, body=params)
            assert isinstance(reply, models.RenderJSON), reply
            color = _png(reply.outputs["color"].png)
            assert color.shape[:2] == (72, 96) and color.std() > 5
            # An uploaded scene lit by a spot light, as multipart: the params part is JSON.
            spot = models.SpotLight(type_="spot", position=[0.8, 3.0, 0.1],
                                    target=[0.8, 0.0, 0.1], outer_cone_deg=40.0)
            form = models.RenderFilesBody(
                scene=types.File(payload=io.BytesIO(box_glb()), file_name="box.glb"),
                params=models.RenderParams(
                    width=80, height=60, lights=[spot],
                    camera=models.CameraParams(eye=[3.0, 3.0, 4.0], target=[0.8, 0.3, 0.1]),
                    outputs=[models.RenderParamsOutputsItem("color"),
                             models.RenderParamsOutputsItem("visibility")]))
            reply = render.sync(client=client, body=form)
            assert isinstance(reply, models.RenderJSON), reply
            color = _png(reply.outputs["color"].png)
            visibility = _png(reply.outputs["visibility_0"].png)
            assert color.shape[:2] == (60, 80) and visibility.dtype == np.uint16
            # The spot light's cone lights part of the picture; the box shadows part of it.
            assert (visibility == 65535).any() and (visibility < 65535).any()
            assert reply.plan["lights"][0]["shadow_map"] in ("perspective", "cube")
            # An impossible request is a typed error naming the field.
            bad = models.RenderParams(camera=models.CameraParams(znear=5.0, zfar=1.0))
            error = render.sync(client=client, body=bad)
            assert isinstance(error, models.ErrorBody) and error.field == "/camera/zfar"
        finally:
            sys.path.remove(str(tmp_path))
            for name in [m for m in sys.modules if m.split(".")[0] == package]:
                del sys.modules[name]
