"""PNG encoding of rendered frames: zlib level 1 against ISA-L's zlib-compatible deflate.

For each model (:data:`bench._common.MODEL_NAMES`) one 640×480 colour frame is rendered with the
default settings (plus a 1920×1080 frame of the first model), then the service's PNG writer
(:func:`shadowmap.renderer.png.png_bytes`: no row filter, deflate level 1) is timed on it with
each compressor, interleaved (zlib, isal, zlib, ...). Every ISA-L file is decoded back with
Pillow and compared with the frame. Medians of ``--repeats`` calls.

Then the 16-bit images of each model's render (visibility and depth, 640×480): the library's
conversions (``visibility_u16``, ``depth_u16`` of :mod:`shadowmap.renderer.png`, in place in
float64) against the plain formulas they implement (:func:`plain_visibility_u16`,
:func:`plain_depth_u16`: clip and round, the finite pixels gathered), interleaved; both must give
the same values.

Writes ``bench/results/png_encode.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/png_encode.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import io
import time
import zlib

import numpy as np

from bench import _common as C  # before anything that imports PyOpenGL: selects the platform
from shadowmap.renderer import RenderParams  # noqa: E402
from shadowmap.renderer import png as encode  # noqa: E402  (the service's PNG writer)


def _frames(r: C.Renderer, quick: bool) -> list[tuple[str, np.ndarray]]:
    out = []
    names = C.MODEL_NAMES[:2] if quick else C.MODEL_NAMES
    for name in names:
        scene = C.load_model(name)
        out.append((name, r.render(scene, RenderParams(lights=C.light_dicts(scene))).color))
    scene = C.load_model(names[0])
    big = r.render(scene, RenderParams(width=1920, height=1080, lights=C.light_dicts(scene)))
    out.append((f"{names[0]} 1920×1080", big.color))
    return out


def plain_visibility_u16(v: np.ndarray) -> np.ndarray:
    """``round(clip(v, 0, 1) * 65535)`` in float64, NaN -> 0, written out plainly."""
    v = np.nan_to_num(v.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return np.rint(np.clip(v, 0.0, 1.0) * 65535.0).astype(np.uint16)


def plain_depth_u16(d: np.ndarray) -> tuple[np.ndarray, float | None, float | None]:
    """``round((d - near) / (far - near) * 65534)`` over the finite pixels, 65535 elsewhere."""
    finite = np.isfinite(d)
    out = np.full(d.shape, 65535, np.uint16)
    if not finite.any():
        return out, None, None
    near, far = float(d[finite].min()), float(d[finite].max())
    span = far - near if far > near else 1.0
    out[finite] = np.rint((d[finite].astype(np.float64) - near) / span * 65534.0).astype(np.uint16)
    return out, near, far


def _conversions(r: C.Renderer, quick: bool, repeats: int) -> tuple[list[list], list[dict]]:
    """The third table's rows: each model's visibility and depth converted both ways."""
    names = C.MODEL_NAMES[:2] if quick else C.MODEL_NAMES
    rows, csv_rows = [], []
    for name in names:
        scene = C.load_model(name)
        result = r.render(scene, RenderParams(lights=C.light_dicts(scene),
                                              outputs=["visibility", "depth"]))
        vis, depth = result.visibility[..., 0], result.depth
        assert np.array_equal(encode.visibility_u16(vis), plain_visibility_u16(vis)), name
        ours, plain = encode.depth_u16(depth), plain_depth_u16(depth)
        assert np.array_equal(ours[0], plain[0]) and ours[1:] == plain[1:], name
        t = C.time_interleaved({
            "vis": lambda v=vis: encode.visibility_u16(v),
            "vis_plain": lambda v=vis: plain_visibility_u16(v),
            "depth": lambda d=depth: encode.depth_u16(d),
            "depth_plain": lambda d=depth: plain_depth_u16(d),
        }, repeats, rotate=True)
        ms = {k: v.ms() for k, v in t.items()}
        rows.append([name, C.fmt(ms["vis_plain"], 2), C.fmt(ms["vis"], 2),
                     C.fmt(ms["vis"] / ms["vis_plain"], 3), C.fmt(ms["depth_plain"], 2),
                     C.fmt(ms["depth"], 2), C.fmt(ms["depth"] / ms["depth_plain"], 3)])
        csv_rows.append({"frame": f"{name} 16-bit", **{f"{k}_ms": v for k, v in ms.items()}})
    return rows, csv_rows


def run(quick: bool, repeats: int) -> None:
    from isal import isal_zlib
    from PIL import Image

    t_start = time.perf_counter()
    out_dir = C.results_dir(quick)
    compressors = {
        "zlib": lambda data: zlib.compress(data, encode.PNG_COMPRESS_LEVEL),
        "isal": lambda data: isal_zlib.compress(data, encode.PNG_COMPRESS_LEVEL),
    }
    rows, csv_rows = [], []
    r = C.Renderer()
    try:
        frames = _frames(r, quick)
        conv_rows, conv_csv = _conversions(r, quick, repeats)
        footer = C.machine_info(r)
    finally:
        r.close()
    for name, frame in frames:
        files: dict[str, bytes] = {}

        def writer(kind: str, frame: np.ndarray = frame,
                   files: dict[str, bytes] = files) -> bytes:
            saved = encode._compress
            encode._compress = compressors[kind]
            try:
                files[kind] = encode.png_bytes(frame)
            finally:
                encode._compress = saved
            return files[kind]

        t = C.time_interleaved({k: (lambda k=k: writer(k)) for k in compressors}, repeats)
        back = np.asarray(Image.open(io.BytesIO(files["isal"])))
        assert np.array_equal(back, frame), f"{name}: the ISA-L PNG does not decode to the frame"
        z, i = t["zlib"].ms(), t["isal"].ms()
        kb_z, kb_i = len(files["zlib"]) / 1024, len(files["isal"]) / 1024
        rows.append([name, C.fmt(z, 2), C.fmt(i, 2), C.fmt(i / z, 3), C.fmt(kb_z, 0),
                     C.fmt(kb_i, 0)])
        csv_rows.append({"frame": name, "zlib_ms": z, "isal_ms": i, "ratio": i / z,
                         "zlib_kib": kb_z, "isal_kib": kb_i})
    table = C.markdown_table(["frame", "zlib ms", "isal ms", "isal / zlib", "zlib KiB",
                              "isal KiB"], rows)
    conv = C.markdown_table(["model", "visibility, plain formula ms", "visibility ms",
                             "visibility: ours / plain", "depth, plain formula ms", "depth ms",
                             "depth: ours / plain"], conv_rows)
    md = (f"# PNG encoding: zlib level 1 against ISA-L (`bench/png_encode.py`)\n\n{table}\n\n"
          f"Medians of {repeats} interleaved calls of `png_bytes` per compressor; in use: "
          f"`{encode.PNG_DEFLATE}`.\n\n## The 16-bit images: the library's conversions against "
          f"the plain formulas\n\n{conv}\n\n640x480 visibility (light 0) and depth of each "
          f"model's render; medians of {repeats} interleaved calls, each repeat starting one arm "
          f"later; both give the same values. {footer}\n")
    C.finish(out_dir, "png_encode", md, csv_rows + conv_csv, [table, conv], [],
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "two models, 5 repeats", 5, argv)


if __name__ == "__main__":
    main()
