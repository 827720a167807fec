"""Where the camera pass's shadow lookup spends its time: the same frame with less and less of it.

Per scene of ``bench/floor.py`` whose shadows come from 2D maps (directional and spot lights;
640x480, default settings), the camera pass is timed with the lookup of
``shaders/chunks/shadow_2d.glsl`` cut down step by step, each arm drawing the same plan (the same
receivers, shadow region and draws), interleaved:

- *unshadowed*: the light casts no shadow (no lookup code at all);
- *no reads*: the lookup returns 1 at once, after the draws, varyings and uniforms of a lookup
  (what the lookup variant costs before it reads anything);
- *one texel*: one texel read by ``texelFetch`` and compared with the interpolated light depth
  (no receiver plane, no filter);
- *one gather*: the 2x2 texels around the point gathered and compared with the interpolated depth,
  weighted bilinearly (the default filter's reads, without its plane);
- *hard*: ``shadows.filter: "hard"``, the renderer's own: one texel compared with the receiver's
  plane at that texel's centre;
- *default*: the renderer's own default (``pcf``, kernel 1): the 2x2 gather, each texel compared
  with the receiver's plane at its own centre.

The three cut-down arms replace the lookup's body through a shader loader of this script's own
(the renderer's shaders are not changed); their shadows are cruder, their cost is what is
measured. The difference of consecutive arms is what each part adds: the lookup variant's draws
and varyings, a texture read, the other three texels of a gather, the receiver plane.

Writes ``bench/results/lookup_cost.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/lookup_cost.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from bench import _common as C  # first: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.gl.programs import Program, ProgramCache, shader_text  # noqa: E402

QUICK_SCENES = ("Duck", "caster_on_ground")
#: Scenes whose lookup costs less than this (ms) are left out of the summary's shares: their
#: parts are differences of a few hundredths of a millisecond, within the timing noise.
MIN_LOOKUP_MS = 0.5
#: The map-size sweep: scenes and sides (``shadows.map_size``).
SIZE_SCENES = ("Duck", "CesiumMilkTruck", "AlphaBlendModeTest")
SIZES = (256, 512, 1024, 2048, 4096)
QUICK_SIZES = (256, 2048)
#: The line of ``visibility_2d_from`` after which a probe returns.
ANCHOR = "    vec4 range = u_map2d_range[m];\n"
_DEPTH = """
    vec2 uv_ = persp ? c.xy / c.w : c.xy;
    float t_ = c.z - u_map2d_depth[m].y;
"""
#: The cut-down lookups, by arm: GLSL returned right after :data:`ANCHOR` (``range``, ``c`` and
#: ``persp`` are the function's own).
PROBES = {
    "no reads": "    return c.x < -1e30 ? 0.0 : 1.0;\n",
    "one texel": _DEPTH + """
    ivec2 at_ = ivec2(clamp(floor(uv_ * range.w), 0.0, range.w - 1.0));
    return step(t_, texelFetch(map, at_, 0).r);
""",
    "one gather": _DEPTH + """
    vec2 st_ = uv_ * range.w;
    vec2 f_ = fract(st_ - 0.5);
    vec4 lit_ = step(vec4(t_), textureGather(map, (floor(st_ - 0.5) + 1.0) / range.w));
    return mix(mix(lit_.w, lit_.z, f_.x), mix(lit_.x, lit_.y, f_.x), f_.y);
""",
}
#: The map-size sweep's extra arm: *one texel*'s reads with their lookup points drawn 8 times
#: closer together about the map's centre (the same number of reads, on 1/64 of the area).
CLOSER = 8
PROBES["one texel, closer"] = _DEPTH + f"""
    vec2 near_ = 0.5 + (uv_ - 0.5) / {float(CLOSER)};
    ivec2 at_ = ivec2(clamp(floor(near_ * range.w), 0.0, range.w - 1.0));
    return step(t_, texelFetch(map, at_, 0).r);
"""
#: The tiled-layout probe: *one texel*'s reads at the memory positions a map stored in tiles
#: of these texel sizes (tiles row by row, texels row by row in a tile) would give them, against
#: the same address arithmetic for the map's own row-by-row layout. The texels read are the
#: wrong ones; where they lie in memory is what a tiled map's reads would touch.
TILES = ((8, 4), (64, 32))
TILE_SIZES = (1024, 2048, 4096)


def _addressed(index: str) -> str:
    """A probe reading the texel at linear position ``index`` (GLSL of ``at_``, ``W_``)."""
    return _DEPTH + f"""
    int W_ = int(range.w);
    ivec2 at_ = ivec2(clamp(floor(uv_ * range.w), 0.0, range.w - 1.0));
    int idx_ = {index};
    return step(t_, texelFetch(map, ivec2(idx_ % W_, idx_ / W_), 0).r);
"""


PROBES["rows, addressed"] = _addressed("at_.y * W_ + at_.x")
for _tw, _th in TILES:
    PROBES[f"tiles {_tw}x{_th}"] = _addressed(
        f"((at_.y / {_th}) * (W_ / {_tw}) + at_.x / {_tw}) * {_tw * _th} "
        f"+ (at_.y % {_th}) * {_tw} + at_.x % {_tw}")
TILE_ARMS = ("rows, addressed", *(f"tiles {tw}x{th}" for tw, th in TILES))
ARMS = ("unshadowed", "no reads", "one texel", "one gather", "hard", "default")
#: What each arm adds to the one before it, as the table names it.
STEPS = (("no reads", "unshadowed", "draws, varyings"), ("one texel", "no reads", "a texel read"),
         ("one gather", "one texel", "3 more texels (gather)"),
         ("default", "one gather", "receiver plane"))


class _LenientProgram(Program):
    """A probe drops uniforms the lookup no longer reads: setting those is not an error here."""

    def set(self, name, value) -> None:  # type: ignore[no-untyped-def]
        if self.has(name):
            super().set(name, value)


class _ProbeCache(ProgramCache):
    program_type = _LenientProgram


def probe_loader(body: str):  # type: ignore[no-untyped-def]
    """A shader loader that returns ``body`` from every 2D lookup (``visibility_2d_from``)."""
    def load(name: str) -> str:
        text = shader_text(name)
        if name.endswith("shadow_2d.glsl"):
            if text.count(ANCHOR) != 1:
                raise RuntimeError(f"{name}: the probe's anchor {ANCHOR.strip()!r} is not there "
                                   "once; update bench/lookup_cost.py")
            text = text.replace(ANCHOR, ANCHOR + body)
        return text
    return load


@contextmanager
def programs(r: Renderer, cache: ProgramCache | None) -> Iterator[None]:
    """Draw the camera pass with ``cache``'s programs (None: the renderer's own)."""
    own = r.camera_pass.programs
    if cache is not None:
        r.camera_pass.programs = cache
    try:
        yield
    finally:
        r.camera_pass.programs = own


def render_with(r: Renderer, cache: ProgramCache | None, scene, params: RenderParams
                ):  # type: ignore[no-untyped-def]
    """``r.render(scene, params)`` with the camera pass drawn by ``cache``'s programs."""
    with programs(r, cache):
        return r.render(scene, params)


def two_d_only(result) -> bool:  # type: ignore[no-untyped-def]
    """Every shadowed light of the plan looked up in one 2D map (no cube, no cascades)."""
    kinds = [lp["shadow_map"] for lp in result.plan["lights"] if lp.get("shadow_map")]
    return bool(kinds) and all(k in ("ortho", "perspective") for k in kinds)


def run(quick: bool, repeats: int) -> None:
    t_start = time.perf_counter()
    r = Renderer()  # the light pass is drawn once and cached: the camera pass is what is timed
    caches = {arm: _ProbeCache(probe_loader(body)) for arm, body in PROBES.items()}
    scenes = C.model_scenes() + [C.stress_scene(n) for n in C.STRESS_SCENES]
    if quick:
        scenes = [s for s in scenes if s.name in QUICK_SCENES]
    bar = C.Progress(len(scenes) + (1 if quick else len(SIZE_SCENES)), "lookup_cost")
    rows: list[list[str]] = []
    csv_rows: list[dict[str, Any]] = []
    skipped: list[str] = []
    for bs in scenes:
        scene = bs.scene
        default = bs.params()
        if not two_d_only(r.render(scene, default)):
            skipped.append(bs.name)
            bar.step(bs.name)
            continue
        params: dict[str, RenderParams] = {
            "unshadowed": bs.params(lights=C.without_shadows(bs.lights)),
            "hard": bs.params(shadows={"filter": "hard"}),
            "default": default,
            **{arm: default for arm in PROBES},
        }

        t = C.time_interleaved(
            {arm: (lambda arm=arm, scene=scene, params=params:
                   render_with(r, caches.get(arm), scene, params[arm])) for arm in ARMS},
            repeats, warmup=2, rotate=True)
        ms = {arm: t[arm].ms("camera") for arm in ARMS}
        extra = ms["default"] - ms["unshadowed"]
        parts = {label: ms[a] - ms[b] for a, b, label in STEPS}
        rows.append([bs.name, *(C.fmt(ms[a], 2) for a in ARMS), C.fmt(extra, 2),
                     *(f"{100 * v / extra:.0f} %" if extra > 0 else "—" for v in parts.values())])
        csv_rows.append({"scene": bs.name, **{f"{a.replace(' ', '_')}_camera_ms": round(ms[a], 3)
                                               for a in ARMS},
                         "lookup_ms": round(extra, 3),
                         **{label: round(v, 3) for label, v in parts.items()}})
        bar.step(bs.name)
    sizes = QUICK_SIZES if quick else SIZES
    size_rows = []
    tile_rows: list[list[Any]] = []
    for name in SIZE_SCENES[:1] if quick else SIZE_SCENES:
        bs = C.model_scene(name + ".glb")
        calls = {}
        for size in sizes:
            p = bs.params(shadows={"map_size": size})
            for arm in ("no reads", "one texel", "one texel, closer"):
                calls[f"{size} {arm}"] = (lambda arm=arm, p=p, bs=bs:
                                          render_with(r, caches[arm], bs.scene, p))
        t = C.time_interleaved(calls, repeats, warmup=2, rotate=True)
        auto = r.render(bs.scene, bs.params()).plan["lights"][0]["map_size"]
        for s in sizes:
            base = t[f"{s} no reads"].ms("camera")
            read = t[f"{s} one texel"].ms("camera") - base
            closer = t[f"{s} one texel, closer"].ms("camera") - base
            size_rows.append([bs.name, auto, s, C.fmt(read, 2), C.fmt(closer, 2)])
            csv_rows.append({"scene": f"{bs.name} (map size sweep)", "auto_map_size": auto,
                             "map_size": s, "texel_read_ms": round(read, 3),
                             "texel_read_closer_ms": round(closer, 3)})
        bar.step(f"{bs.name} sizes")
        if quick:
            continue
        calls = {}
        for size in TILE_SIZES:
            p = bs.params(shadows={"map_size": size})
            for arm in ("no reads", *TILE_ARMS):
                calls[f"{size} {arm}"] = (lambda arm=arm, p=p, bs=bs:
                                          render_with(r, caches[arm], bs.scene, p))
        t = C.time_interleaved(calls, repeats, warmup=2, rotate=True)
        for size in TILE_SIZES:
            base = t[f"{size} no reads"].ms("camera")
            reads = {arm: t[f"{size} {arm}"].ms("camera") - base for arm in TILE_ARMS}
            tile_rows.append([bs.name, size, *(C.fmt(v, 2) for v in reads.values())])
            csv_rows.append({"scene": f"{bs.name} (tiled layouts)", "map_size": size,
                             **{f"{arm.replace(' ', '_').replace(',', '')}_ms": round(v, 3)
                                for arm, v in reads.items()}})
    bar.close()
    tile_table = C.markdown_table(["scene", "map size", "a texel read, rows ms",
                                   *(f"in {tw}×{th}-texel tiles ms" for tw, th in TILES)],
                                  tile_rows)
    size_table = C.markdown_table(["scene", "auto map size", "map size", "a texel read ms",
                                   f"the same reads {CLOSER}× closer ms"], size_rows)
    table = C.markdown_table(
        ["scene", *(f"{a} ms" for a in ARMS), "lookup ms (default − unshadowed)",
         *(f"{label}" for _, _, label in STEPS)], rows)
    shares: dict[str, list[float]] = {label: [] for _, _, label in STEPS}
    weighed = [c for c in csv_rows if c.get("lookup_ms", 0.0) >= MIN_LOOKUP_MS]
    for c in weighed:
        for label in shares:
            shares[label].append(c[label] / c["lookup_ms"])
    summary = ", ".join(f"{label} {100 * C.median(v):.0f} %" for label, v in shares.items())
    notes = [f"- Median share of the lookup's cost over the {len(weighed)} scenes whose lookup "
             f"costs at least {MIN_LOOKUP_MS} ms ({', '.join(c['scene'] for c in weighed)}; "
             f"below that the parts are within the timing noise): {summary}." if weighed else
             f"- No scene's lookup cost {MIN_LOOKUP_MS} ms or more: no shares summarised.",
             "- The three cut-down arms draw wrong shadows (no plane, no filter); only their time "
             "is compared."]
    if skipped:
        notes.append(f"- Not measured (their lookups are not 2D-map lookups): "
                     f"{', '.join(skipped)}.")
    md = "\n".join([
        "# Where the shadow lookup's time goes", "",
        f"640x480, default settings, the camera pass alone (`camera` stage), medians of "
        f"{repeats} interleaved calls after two warm-ups, each repeat starting one arm later "
        "(every arm runs after every other equally often); the light pass drawn once and "
        "cached. "
        "Each column drops a part of the lookup (see `bench/lookup_cost.py`): *no reads* "
        "returns 1 after the lookup variant's draws and varyings, *one texel* reads one texel "
        "and compares it with the interpolated depth, *one gather* reads the 2×2 texels and "
        "weighs them bilinearly, *hard* is `filter: \"hard\"` (one texel against the receiver's "
        "plane), *default* the default `pcf` kernel 1 (the 2×2 texels, each against the "
        "receiver's plane). The last four columns: what each part adds, as a share of the "
        "default's lookup cost.", "", table, "", *notes, "",
        "## A texel read against the map's size", "",
        "The same scenes with `shadows.map_size` fixed: the camera-pass time of *one texel* less "
        "that of *no reads*, per side; and the same reads with their points drawn "
        f"{CLOSER}× closer together about the map's centre (as many reads, from 1/{CLOSER**2} "
        "of the map's area). The camera pass reads the same number of texels at every size; "
        "what grows is where they lie in memory (a map is stored row by row: the texels under "
        "one block of screen pixels span more rows, cache lines and pages as the map grows). "
        "Where the closer reads cost what a small map's do at every size, the growth is the "
        "reads' spread over memory, not the texture's size.", "", size_table, "",
        *(["## A tiled map", "",
           "The same reads at the memory positions a map stored in tiles would give them (the "
           "texels read are wrong ones; where they lie is what a tiled map's reads would touch): "
           "the camera-pass time less that of *no reads*, with the same address arithmetic for "
           "the map's own layout, row by row, and for tiles of "
           + " and ".join(f"{tw}×{th}" for tw, th in TILES) + " texels (one 64-byte cache line "
           "and one 4 KiB page of 16-bit texels), tiles row by row and texels row by row in a "
           "tile. Where the tiled columns cost what the rows' does, storing the map in tiles "
           "(a pass after the light pass) would not make its reads cheaper.", "", tile_table,
           ""] if tile_rows else []),
        f"Machine: {C.machine_info(r)}. Run time {time.perf_counter() - t_start:.0f} s.", ""])
    for cache in caches.values():
        cache.release()
    r.close()
    out = C.results_dir(quick)
    C.finish(out, "lookup_cost", md, csv_rows, [table, size_table, tile_table], notes,
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "two scenes, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
