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
import io
import json
import math
import os
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
--camera-orbit/--camera-target replace camera's pose/eye/target/up (projection, yfov_deg, ymag,
znear and zfar stay), --outputs sets outputs.

PARAMS is a JSON file with the request (all fields optional), for example:

{example}

Fields: width, height; camera {{pose 4x4 | eye, target, up; projection perspective (yfov_deg) |
orthographic (ymag); znear; zfar}} (omitted: the
file's camera, else framed automatically); lights [{{type directional|spot|point; pose 4x4 |
position, direction | position, target; color; intensity; inner_cone_deg, outer_cone_deg (spot);
range (spot, point); cast_shadows}}] (each type only its own fields; a point light has a pose or
a position; omitted: the file's KHR_lights_punctual lights, else one default);
ambient; background; specular; shininess; shadows {{encoding rgba8|rgb8|rg8|r8|depth; map_size
16..16384 | "auto"; filter hard|pcf; pcf_kernel; bias {{constant; slope; slope_max;
normal_offset; polygon_offset; quantisation_steps}}}}; outputs [color, light_depth, visibility,
depth]; alpha; ground; reference; optimize; float_format png16|exr.

-o FILE writes the colour image as PNG to FILE; without --out nothing else is written. -o -
writes it to standard output (redirected or piped), and the summary line to standard error.
Writes to OUT (--out; default ./out unless -o is given): color.png, light_depth_<i>.png and
light_depth_<i>.npy per light, visibility.npy (H x W, or H x W x L for several lights),
depth.npy, report.json (timings, GL renderer, the render plan, warnings, and with --reference
the error against the ray-traced reference). With --float-format exr (or float_format "exr"
in PARAMS) also depth.exr (channel Z: depth in scene units) and visibility_<i>.exr per light
(channel Y: 1 lit .. 0 shadowed), raw float32, NaN where there is no geometry. Each warning
(what the render had to drop or approximate) is also printed to stderr as
"shadowmap: warning: ...".
"""


def compact_json(value: object, width: int = 92, indent: int = 2, _at: int = 0,
                 _prefix: int = 0) -> str:
    """JSON as a person writes it: a value that fits on the rest of its line stays on one line
    (``[3, 2.5, 4]``, a small object), a longer object or list gets one item per line, and a
    long list of numbers or strings fills its lines.

    ``json.loads(compact_json(v)) == v`` for any JSON value ``v``.

    Parameters
    ----------
    value : JSON value
    width : int
        Longest line aimed at (a single item longer than that still goes on one line).
    indent : int
        Spaces per nesting level.
    """
    flat = json.dumps(value, separators=(", ", ": "))
    if _at + _prefix + len(flat) <= width or not isinstance(value, (dict, list)) or not value:
        return flat
    pad = " " * (_at + indent)
    if isinstance(value, dict):
        items = [f"{pad}{json.dumps(k)}: "
                 + compact_json(v, width, indent, _at + indent, len(json.dumps(k)) + 2)
                 for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * _at + "}"
    if not any(isinstance(v, (dict, list)) for v in value):
        # Scalars: as many to a line as fit.
        lines, line = [], ""
        for v in value:
            word = json.dumps(v)
            if line and len(pad) + len(line) + len(word) + 2 > width:
                lines.append(line + ",")
                line = ""
            line += (", " if line else "") + word
        lines.append(line)
        return "[\n" + "\n".join(pad + x for x in lines) + "\n" + " " * _at + "]"
    items = [pad + compact_json(v, width, indent, _at + indent) for v in value]
    return "[\n" + ",\n".join(items) + "\n" + " " * _at + "]"


def _fail(message: str, code: int = 2) -> int:
    print(f"shadowmap: error: {message}", file=sys.stderr)
    return code


def _render(args: argparse.Namespace) -> int:
    from PIL import Image
    from pydantic import ValidationError

    from .renderer import Renderer, RenderParams, load_scene
    from .renderer.errors import RenderError, ShadowMapError
    from .renderer.exr import exr_available

    params: dict = {}
    if args.params:
        from .renderer.limits import MAX_PARAMS_BYTES
        from .renderer.params import RepeatedKey, load_json

        try:
            # At most one byte past the limit: a FIFO (--params <(...)) is read as it comes,
            # and /dev/zero is not read to the end of memory.
            with open(args.params, "rb") as f:
                text = f.read(MAX_PARAMS_BYTES + 1)
            if len(text) > MAX_PARAMS_BYTES:
                return _fail(f"{args.params} is over {MAX_PARAMS_BYTES} bytes: a request's "
                             "params are a few kB")
            params = load_json(text.decode("utf-8-sig"))
        except OSError as exc:
            return _fail(f"cannot read {args.params}: {exc.strerror}")
        except RepeatedKey as exc:
            return _fail(f"{args.params}: {exc}")
        except ValueError as exc:
            return _fail(f"{args.params} is not valid JSON: {exc}")
        if not isinstance(params, dict):
            return _fail(f"{args.params} must hold a JSON object")
    try:
        orbit = _apply_flags(args, params)
    except ValueError as exc:
        return _fail(str(exc))
    for flag, value in (("-o/--output", args.output), ("--out", args.out)):
        if value is not None and not value.strip():
            return _fail(f"{flag} is empty: give a path")
    to_stdout = args.output == "-"
    if to_stdout and sys.stdout.isatty():
        # Before the render: a PNG's bytes would garble the terminal.
        return _fail("-o - writes the PNG to standard output, which is a terminal here: "
                     "redirect it (> image.png) or pipe it")

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
    if request.float_format == "exr" and out is not None and not exr_available():
        # Before the render: the files are written after it.
        return _fail("float_format exr needs the OpenEXR package: pip install 'OpenEXR>=3.5'")
    # The folders too: a path that cannot be one fails now, not after the render.
    folders = [out, Path(args.output).parent if args.output not in (None, "-") else None]
    for folder in (f for f in folders if f is not None):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            return _fail(f"cannot write {folder}: {exc.strerror or exc}")
    try:
        scene = load_scene(scene_path)  # a .gltf's files are read from beside it
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
    if to_stdout and result.color is not None:
        png = io.BytesIO()
        Image.fromarray(result.color).save(png, format="PNG")
        try:
            # os.write until every byte is taken: a reader that leaves mid-write makes the
            # write return short, and only the next one fails.
            sys.stdout.flush()
            data = memoryview(png.getbuffer())
            while data:
                data = data[os.write(sys.stdout.fileno(), data):]
        except BrokenPipeError:  # the reader left (| head -c): nothing more to write to
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return _fail("standard output closed before the PNG was written", 1)
        except OSError as exc:
            return _fail(f"cannot write the PNG to standard output: {exc.strerror or exc}")
    elif args.output is not None and result.color is not None:
        output = Path(args.output)
        try:
            Image.fromarray(result.color).save(output, format="PNG")
        except OSError as exc:
            return _fail(f"cannot write {output}: {exc.strerror or exc}")
    for warning in result.warnings:
        print(f"shadowmap: warning: {' '.join(warning.splitlines())}", file=sys.stderr)
    if out is not None:
        try:
            _write_out(out, scene_path, result, request.float_format)
        except OSError as exc:
            return _fail(f"cannot write {exc.filename or out}: {exc.strerror or exc}")
    t = result.timings
    written = ", ".join("standard output" if p == "-" else str(p)
                        for p in (args.output, out) if p is not None)
    # With -o -, standard output holds the PNG: the summary goes to standard error.
    report = sys.stderr if to_stdout else sys.stdout
    print(f"rendered {scene_path.name} in {t['total'] * 1000:.1f} ms on {result.info['renderer']} "
          f"({result.info['platform']}) -> {written}", file=report)
    if result.metrics:
        for i, m in enumerate(result.metrics):
            print(f"light {i}: IoU {m['iou']:.4f}, misclassified {m['misclassified_pct']:.3f}%",
                  file=report)
    return 0


def _write_out(out: Path, scene_path: Path, result: RenderResult,
               float_format: str = "png16") -> None:
    import numpy as np
    from PIL import Image

    from .renderer.exr import DEPTH_CHANNEL, VISIBILITY_CHANNEL, write_exr

    out.mkdir(parents=True, exist_ok=True)
    if result.color is not None:
        Image.fromarray(result.color).save(out / "color.png")
    for ld in result.light_depth:
        Image.fromarray(ld.image).save(out / f"light_depth_{ld.light}.png")
        np.save(out / f"light_depth_{ld.light}.npy", ld.depth)
    if result.visibility is not None:
        vis = result.visibility
        np.save(out / "visibility.npy", vis[..., 0] if vis.shape[2] == 1 else vis)
        if float_format == "exr":  # one file per light, as the service's visibility_<i> parts
            for i in range(vis.shape[2]):
                write_exr(out / f"visibility_{i}.exr", {VISIBILITY_CHANNEL: vis[..., i]},
                          {"light": i})
    if result.depth is not None:
        np.save(out / "depth.npy", result.depth)
        if float_format == "exr":
            write_exr(out / "depth.exr", {DEPTH_CHANNEL: result.depth})
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
    if args.outputs is not None:
        params["outputs"] = [o.strip() for o in args.outputs.split(",") if o.strip()]
        if not params["outputs"]:
            raise ValueError("--outputs names no output: give one or more of "
                             "color,light_depth,visibility,depth")
    if args.float_format is not None:
        params["float_format"] = args.float_format
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
        if args.ray is not None:
            return _serve_ray(args, overrides)
        run(host=args.host, port=args.port, workers=args.workers, **overrides)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "settings"
        return _fail(f"invalid setting: {where}: {first['msg']}")
    except ValueError as exc:  # --workers, --port (app.main.check_server)
        return _fail(f"--{str(exc)}")
    except OSError as exc:  # cannot listen on --host:--port
        return _fail(exc.strerror or str(exc), 3)
    return 0


def _serve_ray(args: argparse.Namespace, overrides: dict[str, Any]) -> int:
    """``serve --ray``: the same app on Ray Serve, ``--replicas`` copies."""
    try:
        import ray  # noqa: F401

        from .app import ray_serve
        from .hosts import check_address
    except ImportError as exc:
        return _fail(f"--ray needs the ray extra ({exc.name or exc} is missing): "
                     "pip install 'shadowmap-service[server,ray]'", 4)
    if args.replicas < 1:
        return _fail("--replicas must be at least 1")
    # Connection handling is Ray Serve's proxy's: these uvicorn options have no effect there.
    for name in ("keep_alive_timeout", "limit_concurrency", "send_timeout"):
        overrides.pop(name, None)
    address = None if args.ray == "auto" else args.ray
    try:
        check_address(address)
        ray_serve.run(args.host, args.port, args.replicas, address=address, **overrides)
    except RuntimeError as exc:  # the cluster cannot be reached or joined
        return _fail(str(exc), 3)
    return 0


def _batch(args: argparse.Namespace) -> int:
    from .batch import render_many
    from .hosts import check_seconds, check_workers
    from .renderer.errors import RenderError

    try:
        if args.workers is not None and args.ray is None:  # local processes
            check_workers(args.workers, "--workers")
        elif args.workers is not None and args.workers < 1:  # Ray actors, maybe elsewhere
            raise ValueError("--workers must be at least 1")
        if args.timeout is not None:
            check_seconds(args.timeout, "--timeout")
        if args.max_job_renders < 1:
            raise ValueError("--max-job-renders must be at least 1")
        if args.max_line_bytes < 1:
            raise ValueError("--max-line-bytes must be at least 1")
    except ValueError as exc:
        return _fail(str(exc))
    if args.ray is not None:
        try:
            import ray  # noqa: F401
        except ImportError:
            return _fail("--ray needs the ray extra: pip install 'shadowmap-service[ray]'", 4)
    progress = None if args.quiet else _BatchBar()
    failure: tuple[str, int] | None = None
    try:
        report = render_many(args.manifest, args.out, workers=args.workers, ray=args.ray,
                             actors=args.workers if args.ray is not None else None,
                             timeout=args.timeout, progress=progress, resume=not args.force,
                             max_job_renders=args.max_job_renders,
                             max_line_bytes=args.max_line_bytes)
    except OSError as exc:
        failure = (f"{exc.filename or args.manifest}: {exc.strerror or exc}", 2)
    except (RuntimeError, RenderError) as exc:
        failure = (str(exc), 3)
    finally:
        if progress is not None:
            progress.close()  # before any message: the bar's line ends first
    if failure is not None:
        return _fail(*failure)
    for rec in report.records:
        if rec["status"] != "ok":
            err = rec["error"]
            print(f"shadowmap: {rec['status']}: {rec['id']}: {err['error']}: {err['detail']}",
                  file=sys.stderr)
    c = report.counts
    done = sum(c.values())
    rate = done / report.seconds if report.seconds > 0 else 0.0
    print(f"batch: {c['ok']} ok, {c['error']} error, {c['failed']} failed, {report.skipped} "
          f"already done; {done} jobs in {report.seconds:.1f} s ({rate:.1f} jobs/s, "
          f"{report.backend or 'no'} backend) -> {Path(args.out) / 'results.jsonl'}")
    return 0 if c["failed"] == 0 else 1


class _BatchBar:
    """tqdm's bar on stderr: jobs done, jobs/s and the time left."""

    def __init__(self) -> None:
        self.bar: Any = None

    def start(self, total: int, skipped: int) -> None:
        from tqdm import tqdm

        note = f" ({skipped} already done)" if skipped else ""
        self.bar = tqdm(total=total, unit="job", desc="batch" + note, file=sys.stderr,
                        dynamic_ncols=True)

    def update(self, record: dict[str, Any]) -> None:
        if self.bar is not None:
            self.bar.update(1)
            if record["status"] != "ok":
                self.bar.set_postfix_str(f"last {record['status']}: {record['id']}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


BATCH_HELP = """\
MANIFEST is JSON Lines, one job a line:

  {"id": "duck-1", "scene": "models/Duck.glb", "params": {"width": 640, "ground": true}}
  {"id": "demo-views", "scene": {"builtin": "demo"}, "params": {"outputs": ["color", "depth"]},
   "views": [{"eye": [4, 3, 4], "target": [0, 0, 0]}, {"eye": [-4, 3, 4], "target": [0, 0, 0]}],
   "lights": [[{"type": "directional", "direction": [-1, -2, -1]}]]}

scene is a .glb/.gltf path relative to the manifest (a .gltf's files are read from beside it), or
{"builtin": "demo"}; params is the request of `shadowmap render --params`; views (cameras) and
lights (light lists) are optional variations, each rendered on the same loaded scene into
OUT/<id>/view_<i>[_light_<j>]/. Each render writes color.png, visibility_<i>.png and
visibility.npy, depth.png and depth.npy, light_depth_<i>.png/.npy (the outputs it asks for) and
meta.json (camera intrinsics and extrinsics, lights, timings, plan, warnings, metrics).

OUT/results.jsonl gets one record per job: status ok, error (bad file, bad params, over a limit:
the batch goes on) or failed (its worker died twice, or --timeout twice). Running the same
command again skips jobs already done with the same inputs (job id and a hash of the job and its
scene file), so a killed batch resumes where it stopped. Exit status 1 when a job failed.
"""


#: ``serve`` options that set a service setting (``--upload-timeout`` is ``upload_timeout``, the
#: same as ``SHADOWMAP_UPLOAD_TIMEOUT``), with their type and help.
SERVE_SETTINGS: dict[str, tuple[type, str]] = {
    "upload_timeout": (float, "seconds a client may take to send the request body (408 after)"),
    "send_timeout": (float, "seconds a client may keep a response waiting by not reading it "
                     "(the connection is dropped after)"),
    "keep_alive_timeout": (int, "seconds an idle connection stays open, and a new one may take "
                           "to send its request head"),
    "limit_concurrency": (int, "most connections at once (more get 503)"),
    "shutdown_timeout": (float, "seconds a shutdown waits for running requests; a render still "
                         "running then is stopped"),
}


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .batch.manifest import MAX_JOB_RENDERS, MAX_LINE_BYTES
    from .hosts import MAX_WORKERS_PER_CPU
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
        epilog=RENDER_HELP.format(example=compact_json(EXAMPLE_PARAMS)),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("scene")
    r.add_argument("--params", metavar="PARAMS.json", help="request as JSON (see below)")
    r.add_argument("-o", "--output", metavar="FILE",
                   help="write the colour image to FILE as PNG ('-': to standard output)")
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
    r.add_argument("--float-format", choices=("png16", "exr"), default=None,
                   help="exr: also write depth and visibility as float32 OpenEXR files "
                   "(depth.exr, visibility_<i>.exr)")
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
                   help="server processes (each with its own render worker process; at "
                   f"most {MAX_WORKERS_PER_CPU} per CPU)")
    for name, (kind, text) in SERVE_SETTINGS.items():
        s.add_argument("--" + name.replace("_", "-"), type=kind, default=None, dest=name,
                       help=f"{text} (default: $SHADOWMAP_{name.upper()}, else the setting's "
                       "default)")
    s.add_argument("--ray", nargs="?", const="auto", default=None, metavar="ADDRESS",
                   help="serve on Ray Serve instead: 'auto' (the default when given without a "
                   "value) joins this machine's Ray cluster or starts one; or a cluster address")
    s.add_argument("--replicas", type=int, default=1,
                   help="with --ray: copies of the service, each with its own render worker")
    s.set_defaults(func=_serve)
    b = sub.add_parser(
        "batch", help="render the jobs of a manifest to files (resumable; local or on Ray)",
        description="Render every job of MANIFEST.jsonl to OUT/<job id>/.",
        epilog=BATCH_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("manifest", metavar="MANIFEST.jsonl")
    b.add_argument("--out", metavar="DIR", required=True, help="output folder")
    b.add_argument("--workers", type=int, default=None,
                   help="worker processes (with --ray: actors); default: what this machine "
                   "(or cluster) uses well")
    b.add_argument("--ray", metavar="auto|ADDRESS", default=None,
                   help="run on Ray: 'auto' joins this machine's Ray cluster or starts one; "
                   "or a cluster address (ray://head:10001)")
    b.add_argument("--timeout", type=float, default=None,
                   help="seconds one job may run before its worker is killed")
    b.add_argument("--max-job-renders", type=int, default=MAX_JOB_RENDERS, metavar="N",
                   help="renders one job may ask for (views x light lists); a job asking for "
                   f"more is recorded as an error (default {MAX_JOB_RENDERS})")
    b.add_argument("--max-line-bytes", type=int, default=MAX_LINE_BYTES, metavar="N",
                   help="longest manifest line read; a longer one is recorded as an error "
                   f"(default {MAX_LINE_BYTES})")
    b.add_argument("--force", action="store_true",
                   help="render every job again, even those already done")
    b.add_argument("--quiet", action="store_true",
                   help="no progress bar (for logs): failed jobs and the summary only")
    b.set_defaults(func=_batch)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(_join_signed_values(sys.argv[1:] if argv is None else argv))
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
