"""PNG encoding of rendered frames: zlib level 1 against ISA-L's zlib-compatible deflate.

For each model (:data:`bench._common.MODEL_NAMES`) one 640×480 colour frame is rendered with the
default settings (plus a 1920×1080 frame of the first model), then the service's PNG writer
(:func:`shadowmap.renderer.png.png_bytes`: no row filter, deflate level 1) is timed on it with
each compressor, interleaved (zlib, isal, zlib, ...). Every ISA-L file is decoded back with
Pillow and compared with the frame. Medians of ``--repeats`` calls.

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
    md = (f"# PNG encoding: zlib level 1 against ISA-L (`bench/png_encode.py`)\n\n{table}\n\n"
          f"Medians of {repeats} interleaved calls of `png_bytes` per compressor; in use: "
          f"`{encode.PNG_DEFLATE}`. {footer}\n")
    C.finish(out_dir, "png_encode", md, csv_rows, [table], [], time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "two models, 5 repeats", 5, argv)


if __name__ == "__main__":
    main()
