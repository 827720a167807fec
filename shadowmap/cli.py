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
import math
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from .renderer import RenderParams, RenderResult

RENDER_HELP = """\
One-liner (no PARAMS file needed; writes duck.png only):

  shadowmap render Duck.glb -o duck.png --size 800x600 --light-dir -1,-2,-1 --ground \\
      --camera-orbit 30deg,60deg,2m

--camera-orbit THETA,PHI,R is model-viewer's camera-orbit: the camera sits at azimuth THETA
around +Y (0 = in front, on +Z; 90deg = on +X) and polar angle PHI from +Y (0 = straight above,
90deg = level), at distance R from the target (the centre of the scene's bounds, or
--camera-target), looking at it with +Y up. Angles take deg or rad (no unit: rad), R takes m,
cm, mm or no unit (metres), "auto" is 0 for THETA, 75deg for PHI and for R the distance that
frames the scene. Values may be separated by commas or spaces.

Flags override the matching fields of PARAMS: --size/--width/--height set width/height,
--light-dir replaces lights with one directional light, --ground/--no-ground set ground,
--camera-orbit/--camera-target replace camera's pose/eye/target/up (yfov_deg, znear and zfar
stay), --outputs sets outputs.

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

-o FILE writes the colour image as PNG to FILE; without --out nothing else is written.
Writes to OUT (--out; default ./out unless -o is given): color.png, light_depth_<i>.png and
light_depth_<i>.npy per light, visibility.npy (H x W, or H x W x L for several lights),
depth.npy, report.json (timings, GL renderer, the render plan, warnings, and with --reference
the error against the ray-traced reference). Each warning (what the render had to drop or
approximate) is also printed to stderr as "shadowmap: warning: ...".
"""


def _fail(message: str, code: int = 2) -> int:
    print(f"shadowmap: error: {message}", file=sys.stderr)
    return code


def _render(args: argparse.Namespace) -> int:
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
    try:
        orbit = _apply_flags(args, params)
    except ValueError as exc:
        return _fail(str(exc))

    def validate() -> RenderParams | str:
        try:
            return RenderParams.model_validate(params)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "params"
            return f"invalid params: {where}: {first['msg']}"

    request = validate()
    if isinstance(request, str):
        return _fail(request)
    if args.output is not None and "color" not in request.outputs:
        return _fail("-o/--output writes the color output, but outputs leaves it out")
    scene_path = Path(args.scene)
    out = Path(args.out) if args.out is not None else None if args.output else Path("out")
    try:
        resources = None
        if scene_path.suffix.lower() == ".gltf":
            resources = directory_resources(scene_path.parent)
        scene = load_scene(scene_path, resources=resources)
        if orbit is not None:
            try:
                bounds = scene.bounds
            except ValueError as exc:
                return _fail(f"--camera-orbit: {exc}")
            params["camera"] = _orbit_camera(orbit, params.get("camera"), bounds, request)
            request = validate()
            if isinstance(request, str):
                return _fail(request)
        with Renderer() as renderer:
            result = renderer.render(scene, request)
    except RenderError as exc:
        return _fail(str(exc), 3)
    except ShadowMapError as exc:
        return _fail(str(exc))
    if args.output is not None and result.color is not None:
        output = Path(args.output)
        try:
            output.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(result.color).save(output, format="PNG")
        except OSError as exc:
            return _fail(f"cannot write {output}: {exc.strerror or exc}")
    for warning in result.warnings:
        print(f"shadowmap: warning: {' '.join(warning.splitlines())}", file=sys.stderr)
    if out is not None:
        _write_out(out, scene_path, result)
    t = result.timings
    written = ", ".join(str(p) for p in (args.output, out) if p is not None)
    print(f"rendered {scene_path.name} in {t['total'] * 1000:.1f} ms on {result.info['renderer']} "
          f"({result.info['platform']}) -> {written}")
    if result.metrics:
        for i, m in enumerate(result.metrics):
            print(f"light {i}: IoU {m['iou']:.4f}, misclassified {m['misclassified_pct']:.3f}%")
    return 0


def _write_out(out: Path, scene_path: Path, result: RenderResult) -> None:
    import numpy as np
    from PIL import Image

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


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_ANGLE_UNITS = {"deg": math.pi / 180, "rad": 1.0, "": 1.0}
_LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "": 1.0}


def _parts(flag: str, text: str, count: int) -> list[str]:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    if len(parts) != count:
        raise ValueError(f"{flag} takes {count} comma-separated values, not {text!r}")
    return parts


def _vector(flag: str, text: str) -> list[float]:
    """``x,y,z`` as three finite floats."""
    values = []
    for part in _parts(flag, text, 3):
        try:
            v = float(part)
        except ValueError:
            raise ValueError(f"{flag}: {part!r} is not a number (expected x,y,z)") from None
        if not math.isfinite(v):
            raise ValueError(f"{flag}: {part!r} is not a finite number")
        values.append(v)
    return values


def _size(text: str) -> tuple[int, int]:
    """``WxH`` (``800x600``) as two positive integers."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not m:
        raise ValueError(f"--size must be WIDTHxHEIGHT in pixels (e.g. 800x600), not {text!r}")
    w, h = int(m[1]), int(m[2])
    if w < 1 or h < 1:
        raise ValueError(f"--size {text}: width and height must be at least 1")
    return w, h


def _quantity(flag: str, what: str, text: str, units: dict[str, float]) -> float:
    m = re.fullmatch(f"({_NUMBER})([a-z]*)", text)
    if not m or m[2] not in units:
        names = "/".join(u for u in units if u)
        raise ValueError(f"{flag}: {what} {text!r} must be a number with an optional unit "
                         f"({names}) or auto")
    return float(m[1]) * units[m[2]]


def _orbit(text: str) -> tuple[float, float, float | None]:
    """model-viewer's ``camera-orbit``: (theta, phi) in radians and the radius (None: auto)."""
    theta_s, phi_s, r_s = _parts("--camera-orbit", text, 3)
    flag = "--camera-orbit"
    theta = 0.0 if theta_s == "auto" else _quantity(flag, "azimuth", theta_s, _ANGLE_UNITS)
    phi = math.radians(75) if phi_s == "auto" else _quantity(flag, "polar angle", phi_s,
                                                              _ANGLE_UNITS)
    radius = None if r_s == "auto" else _quantity(flag, "radius", r_s, _LENGTH_UNITS)
    if not (math.isfinite(theta) and math.isfinite(phi)):
        raise ValueError(f"{flag}: angles must be finite, not {text!r}")
    if not 0 <= phi <= math.pi * (1 + 1e-12):
        raise ValueError(f"{flag}: the polar angle must be between 0deg and 180deg, not {phi_s}")
    if radius is not None and not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"{flag}: the radius must be greater than 0, not {r_s}")
    return theta, phi, radius


class _Orbit:
    def __init__(self, theta: float, phi: float, radius: float | None,
                 target: list[float] | None) -> None:
        self.theta, self.phi, self.radius, self.target = theta, phi, radius, target


def _apply_flags(args: argparse.Namespace, params: dict[str, Any]) -> _Orbit | None:
    """Write the flags over the fields of ``params``; the camera orbit, which needs the scene's
    bounds, is returned for later. Raises ValueError with a one-line message."""
    if args.size is not None:
        if args.width is not None or args.height is not None:
            raise ValueError("give --size or --width/--height, not both")
        params["width"], params["height"] = _size(args.size)
    for key in ("width", "height"):
        if getattr(args, key) is not None:
            params[key] = getattr(args, key)
    if args.reference:
        params["reference"] = True
    if args.outputs:
        params["outputs"] = args.outputs.split(",")
    if args.ground is not None:
        params["ground"] = args.ground
    if args.light_dir is not None:
        direction = _vector("--light-dir", args.light_dir)
        if not any(direction):
            raise ValueError("--light-dir must not be the zero vector")
        params["lights"] = [{"type": "directional", "direction": direction}]
    if args.camera_orbit is None and args.camera_target is None:
        return None
    theta, phi, radius = _orbit(args.camera_orbit or "auto,auto,auto")
    target = None
    if args.camera_target is not None:
        target = _vector("--camera-target", args.camera_target)
    return _Orbit(theta, phi, radius, target)


def orbit_eye(target: np.ndarray, theta: float, phi: float, radius: float) -> np.ndarray:
    """The eye of model-viewer's ``camera-orbit`` (+Y up, theta 0 on +Z, 90deg on +X)."""
    import numpy as np

    offset = np.array([math.sin(phi) * math.sin(theta), math.cos(phi),
                       math.sin(phi) * math.cos(theta)])
    return np.asarray(target, np.float64) + radius * offset


def _orbit_camera(orbit: _Orbit, camera: object, bounds: np.ndarray,
                  request: RenderParams) -> dict[str, Any]:
    """The request's camera with ``eye``/``target``/``up`` from the orbit (``pose`` dropped)."""
    import numpy as np

    lo, hi = np.asarray(bounds, np.float64)
    centre = (lo + hi) / 2
    target = np.array(orbit.target, np.float64) if orbit.target is not None else centre
    radius = orbit.radius
    if radius is None:
        # The automatic camera's framing distance (renderer.camera.resolve_camera), from the
        # target: the bounding sphere fits the vertical and horizontal field of view.
        sphere = max(float(np.linalg.norm(hi - lo)) / 2, 1e-30)
        yfov = math.radians(request.camera.yfov_deg if request.camera else 45.0)
        aspect = request.width / request.height
        half = min(yfov, 2 * math.atan(math.tan(yfov / 2) * aspect)) / 2
        radius = (sphere / math.sin(half) * 1.05 + float(np.linalg.norm(target - centre)))
    eye = orbit_eye(target, orbit.theta, orbit.phi, radius)
    out = {k: v for k, v in camera.items() if k != "pose"} if isinstance(camera, dict) else {}
    out.update(eye=eye.tolist(), target=target.tolist(), up=[0.0, 1.0, 0.0])
    return out


#: Options whose value may start with "-" (``--light-dir -1,-2,-1``): argparse would take it for
#: an option, so it is joined to its option (``--light-dir=-1,-2,-1``) before parsing.
_SIGNED_VALUE_OPTIONS = ("--light-dir", "--camera-orbit", "--camera-target")


def _join_signed_values(argv: list[str]) -> list[str]:
    out: list[str] = []
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--":
            out.extend(argv[i:])
            break
        if (arg in _SIGNED_VALUE_OPTIONS and i + 1 < len(argv)
                and re.match(r"-[\d.]", argv[i + 1])):
            out.append(f"{arg}={argv[i + 1]}")
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


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
    r.add_argument("-o", "--output", metavar="FILE",
                   help="write the colour image to FILE as PNG")
    r.add_argument("--size", metavar="WxH", help="image size in pixels, e.g. 800x600")
    r.add_argument("--width", type=int)
    r.add_argument("--height", type=int)
    r.add_argument("--light-dir", metavar="X,Y,Z",
                   help="one directional light shining along X,Y,Z (replaces the lights)")
    r.add_argument("--ground", action=argparse.BooleanOptionalAction, default=None,
                   help="add a ground plane under the scene to receive its shadows")
    r.add_argument("--camera-orbit", metavar="THETA,PHI,R",
                   help="camera position as model-viewer's camera-orbit, e.g. 30deg,60deg,2m "
                   "(see below)")
    r.add_argument("--camera-target", metavar="X,Y,Z",
                   help="point the orbit camera looks at (default: the centre of the scene's "
                   "bounds)")
    r.add_argument("--outputs", help="comma-separated: color,light_depth,visibility,depth")
    r.add_argument("--reference", action="store_true",
                   help="also measure the error against the ray-traced reference")
    r.add_argument("--out", metavar="DIR",
                   help="folder for every output and report.json (default: ./out, none when -o "
                   "is given)")
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
    args = build_parser().parse_args(_join_signed_values(sys.argv[1:] if argv is None else argv))
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
