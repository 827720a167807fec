"""The ``shadowmap`` command: render a scene to files, or serve the HTTP API.

It sits above both the library and the service: ``render`` uses :mod:`shadowmap.renderer` only,
``serve`` imports :mod:`shadowmap.app` when it runs (the ``server`` extra). Errors in the input
(bad file, bad JSON, impossible values) exit with status 2 and one line on stderr; a GL failure
exits with status 3; ``serve`` without the ``server`` extra exits with status 4. What a render had
to drop or approximate is printed to stderr as ``shadowmap: warning: ...``, one line each, and
the command still exits with status 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RENDER_HELP = """\
PARAMS is a JSON file with the request (all fields optional), for example:

{example}

Fields: width, height; camera {{pose 4x4 | eye, target, up; yfov_deg; znear; zfar}} (omitted: the
file's camera, else framed automatically); lights [{{type directional|spot|point; pose 4x4 |
position, direction | position, target; color; intensity; inner_cone_deg; outer_cone_deg; range;
cast_shadows}}] (omitted: the file's KHR_lights_punctual lights, else one default);
ambient; background; specular; shininess; shadows {{encoding rgba8|rgb8|rg8|r8|depth; map_size
16..16384 | "auto"; filter hard|pcf; pcf_kernel; bias {{constant; slope; slope_max;
normal_offset; polygon_offset; quantisation_steps}}}}; outputs [color, light_depth, visibility,
depth]; alpha; ground; reference; optimize.

Writes to OUT: color.png, light_depth_<i>.png and light_depth_<i>.npy per light,
visibility.npy (H x W, or H x W x L for several lights), depth.npy, report.json (timings, GL
renderer, the render plan, warnings, and with --reference the error against the ray-traced
reference). Each warning (what the render had to drop or approximate) is also printed to stderr
as "shadowmap: warning: ...".
"""


def _fail(message: str, code: int = 2) -> int:
    print(f"shadowmap: error: {message}", file=sys.stderr)
    return code


def _render(args: argparse.Namespace) -> int:
    import numpy as np
    from PIL import Image
    from pydantic import ValidationError

    from .renderer import Renderer, RenderParams, load_scene
    from .renderer.errors import RenderError, ShadowMapError
    from .renderer.scene import directory_resources

    params: dict = {}
    if args.params:
        try:
            params = json.loads(Path(args.params).read_text(), parse_constant=_no_constants)
        except OSError as exc:
            return _fail(f"cannot read {args.params}: {exc.strerror}")
        except ValueError as exc:
            return _fail(f"{args.params} is not valid JSON: {exc}")
        if not isinstance(params, dict):
            return _fail(f"{args.params} must hold a JSON object")
    for key in ("width", "height"):
        if getattr(args, key) is not None:
            params[key] = getattr(args, key)
    if args.reference:
        params["reference"] = True
    if args.outputs:
        params["outputs"] = args.outputs.split(",")
    try:
        request = RenderParams.model_validate(params)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "params"
        return _fail(f"invalid params: {where}: {first['msg']}")
    scene_path = Path(args.scene)
    out = Path(args.out)
    try:
        resources = None
        if scene_path.suffix.lower() == ".gltf":
            resources = directory_resources(scene_path.parent)
        scene = load_scene(scene_path, resources=resources)
        with Renderer() as renderer:
            result = renderer.render(scene, request)
    except RenderError as exc:
        return _fail(str(exc), 3)
    except ShadowMapError as exc:
        return _fail(str(exc))
    out.mkdir(parents=True, exist_ok=True)
    if result.color is not None:
        Image.fromarray(result.color).save(out / "color.png")
    for ld in result.light_depth:
        Image.fromarray(ld.image).save(out / f"light_depth_{ld.light}.png")
        np.save(out / f"light_depth_{ld.light}.npy", ld.depth)
    if result.visibility is not None:
        vis = result.visibility
        np.save(out / "visibility.npy", vis[..., 0] if vis.shape[2] == 1 else vis)
    if result.depth is not None:
        np.save(out / "depth.npy", result.depth)
    report = result.report()
    report["scene"] = str(scene_path)
    (out / "report.json").write_text(json.dumps(report, indent=2, default=_jsonable))
    # What the render dropped or approximated: worth a line each (names from the file may hold
    # line breaks), but not a failure.
    for warning in result.warnings:
        print(f"shadowmap: warning: {' '.join(warning.splitlines())}", file=sys.stderr)
    t = result.timings
    print(f"rendered {scene_path.name} in {t['total'] * 1000:.1f} ms on {result.info['renderer']} "
          f"({result.info['platform']}) -> {out}")
    if result.metrics:
        for i, m in enumerate(result.metrics):
            print(f"light {i}: IoU {m['iou']:.4f}, misclassified {m['misclassified_pct']:.3f}%")
    return 0


def _no_constants(name: str) -> float:
    raise ValueError(f"{name} is not allowed (numbers must be finite)")


def _jsonable(value: object) -> object:
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def _serve(args: argparse.Namespace) -> int:
    try:
        from .app.main import run
    except ImportError as exc:
        return _fail(f"serving needs the server extra ({exc.name or exc} is missing): "
                     "pip install 'shadowmap-service[server]'", 4)

    from pydantic import ValidationError

    overrides = {name: getattr(args, name) for name in SERVE_SETTINGS}
    try:
        run(host=args.host, port=args.port, workers=args.workers, **overrides)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "settings"
        return _fail(f"invalid setting: {where}: {first['msg']}")
    return 0


#: ``serve`` options that set a service setting (``--upload-timeout`` is ``upload_timeout``, the
#: same as ``SHADOWMAP_UPLOAD_TIMEOUT``), with their type and help.
SERVE_SETTINGS: dict[str, tuple[type, str]] = {
    "upload_timeout": (float, "seconds a client may take to send the request body (408 after)"),
    "keep_alive_timeout": (int, "seconds an idle connection stays open, and a new one may take "
                           "to send its request head"),
    "limit_concurrency": (int, "most connections at once (more get 503)"),
    "shutdown_timeout": (float, "seconds a shutdown waits for running requests; a render still "
                         "running then is stopped"),
}


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .renderer.params import EXAMPLE_PARAMS

    parser = argparse.ArgumentParser(
        prog="shadowmap",
        description="Render glTF scenes with shadow maps, or serve them over HTTP.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser(
        "render",
        help="render a glTF scene to files",
        description="Render SCENE (.glb or .gltf; a .gltf's external files are read from its "
        "folder) with shadows.",
        epilog=RENDER_HELP.format(example=json.dumps(EXAMPLE_PARAMS, indent=2)),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("scene")
    r.add_argument("--params", metavar="PARAMS.json", help="request as JSON (see below)")
    r.add_argument("--width", type=int)
    r.add_argument("--height", type=int)
    r.add_argument("--outputs", help="comma-separated: color,light_depth,visibility,depth")
    r.add_argument("--reference", action="store_true",
                   help="also measure the error against the ray-traced reference")
    r.add_argument("--out", default="out", help="output folder (default: ./out)")
    r.set_defaults(func=_render)
    s = sub.add_parser("serve", help="run the HTTP service")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--workers", type=int, default=1,
                   help="server processes (each with its own render worker process)")
    for name, (kind, text) in SERVE_SETTINGS.items():
        s.add_argument("--" + name.replace("_", "-"), type=kind, default=None, dest=name,
                       help=f"{text} (default: $SHADOWMAP_{name.upper()}, else the setting's "
                       "default)")
    s.set_defaults(func=_serve)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
