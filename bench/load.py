"""Load: 16 clients for a minute against a real server, and the 32-render burst.

Starts ``shadowmap serve`` with its default settings on a free localhost port, then

1. **the burst**: 16 clients post 2 small renders each (demo scene, 160x120), released together
   by a barrier, the case the issue found answered 15-19 times 503 by a fixed-count queue: all
   32 must be 200;
2. **sustained load**: 16 clients post renders back to back for 60 s (``--quick``: 10 s), a mix
   of sizes and scenes (60 % demo scene at 320x240, 30 % Duck.glb at 640x480, 10 % the demo at
   1280x960 with two lights). A client answered 503 waits what Retry-After says (as a polite
   client would) before its next request.

Reported: p50, p95 and p99 latency of the 2xx answers, the counts of 2xx, 503 (by error code)
and anything else, throughput, and the Retry-After values given. Written to
bench/results/load.md.

Run: ``PYTHONPATH=. .venv/bin/python bench/load.py [--quick] [--seconds S] [--clients N]``
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import threading
import time
from collections import Counter

import numpy as np

from bench import _common as C
from bench.soak import Server

SMALL = {"width": 160, "height": 120}
MIX = [
    (0.6, None, {"width": 320, "height": 240}),
    (0.3, "Duck.glb", {"width": 640, "height": 480, "ground": True}),
    (0.1, None, {"width": 1280, "height": 960,
                 "lights": [{"type": "directional", "direction": [-0.6, -1.0, 0.25]},
                            {"type": "spot", "position": [2.0, 3.0, 2.0],
                             "target": [0.0, 0.0, 0.0]}]}),
]


class Tally:
    """Statuses, error codes, latencies and Retry-After values, from many threads."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.statuses: Counter[int] = Counter()
        self.errors: Counter[str] = Counter()
        self.ok_seconds: list[float] = []
        self.retry_after: list[int] = []
        self.wall = 0.0  # seconds the phase took

    def add(self, status: int, seconds: float, error: str | None = None,
            retry_after: int | None = None) -> None:
        with self.lock:
            self.statuses[status] += 1
            if 200 <= status < 300:
                self.ok_seconds.append(seconds)
            if error is not None:
                self.errors[error] += 1
            if retry_after is not None:
                self.retry_after.append(retry_after)

    def count(self, low: int, high: int) -> int:
        return sum(v for k, v in self.statuses.items() if low <= k < high)

    def percentiles(self) -> tuple[float, float, float]:
        if not self.ok_seconds:
            nan = float("nan")
            return nan, nan, nan
        p = np.percentile(np.array(self.ok_seconds) * 1e3, [50, 95, 99])
        return float(p[0]), float(p[1]), float(p[2])


def post(client, duck: bytes, model: str | None, params: dict):
    if model is None:
        return client.post("/render", content=json.dumps(params),
                           headers={"Content-Type": "application/json", "Accept": "image/png"})
    return client.post("/render", files={"scene": (model, duck, "model/gltf-binary")},
                       data={"params": json.dumps(params)}, headers={"Accept": "image/png"})


def record(tally: Tally, client, duck: bytes, model: str | None, params: dict) -> int | None:
    """One request into the tally; the Retry-After of a 503, else None."""
    import httpx

    t0 = time.perf_counter()
    try:
        resp = post(client, duck, model, params)
    except httpx.HTTPError as exc:
        tally.add(0, time.perf_counter() - t0, f"transport {type(exc).__name__}")
        return None
    seconds = time.perf_counter() - t0
    error = retry = None
    if resp.status_code >= 300:
        try:
            error = f"{resp.status_code} {resp.json().get('error')}"
        except ValueError:
            error = f"{resp.status_code} (not JSON)"
        if "retry-after" in resp.headers:
            retry = int(resp.headers["retry-after"])
    tally.add(resp.status_code, seconds, error, retry)
    return retry


def burst(url: str, duck: bytes, clients: int, each: int) -> Tally:
    import httpx

    tally = Tally()
    barrier = threading.Barrier(clients)

    def client() -> None:
        with httpx.Client(base_url=url, timeout=120) as c:
            barrier.wait()
            for _ in range(each):
                record(tally, c, duck, None, SMALL)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    tally.wall = time.perf_counter() - t0
    return tally


def sustained(url: str, duck: bytes, clients: int, seconds: float, seed: int) -> Tally:
    import httpx

    tally = Tally()
    stop_at = time.perf_counter() + seconds
    weights = [w for w, _, _ in MIX]

    def client(index: int) -> None:
        rng = random.Random(seed * 1000 + index)
        with httpx.Client(base_url=url, timeout=300) as c:
            while time.perf_counter() < stop_at:
                _, model, params = rng.choices(MIX, weights=weights)[0]
                retry = record(tally, c, duck, model, params)
                if retry is not None:
                    time.sleep(max(0.0, min(retry, stop_at - time.perf_counter())))

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    bar = C.Progress(int(seconds), "load")
    for t in threads:
        t.start()
    while any(t.is_alive() for t in threads):
        time.sleep(1.0)
        bar.step(f"{sum(tally.statuses.values())} answers")
    bar.close()
    return tally


def describe(tally: Tally) -> list[str]:
    p50, p95, p99 = tally.percentiles()
    others = tally.count(0, 200) + tally.count(300, 503) + tally.count(504, 1000)
    lines = [f"2xx: {tally.count(200, 300)}, 503: {tally.statuses.get(503, 0)}, other: {others}",
             f"latency of 2xx: p50 {p50:.0f} ms, p95 {p95:.0f} ms, p99 {p99:.0f} ms"]
    if tally.errors:
        lines.append("not 2xx: " + ", ".join(f"{k} x{v}" for k, v in tally.errors.most_common()))
    if tally.retry_after:
        lines.append(f"Retry-After given: min {min(tally.retry_after)} s, median "
                     f"{int(np.median(tally.retry_after))} s, max {max(tally.retry_after)} s")
    return lines


def run(quick: bool, seconds: float, clients: int, seed: int) -> None:
    started = time.perf_counter()
    duck = (C.models_dir() / "Duck.glb").read_bytes()
    with Server() as server:
        burst_tally = burst(server.url, duck, clients=16, each=2)
        load_tally = sustained(server.url, duck, clients, seconds, seed)
        final = server.health()
    p50, p95, p99 = load_tally.percentiles()
    total = sum(load_tally.statuses.values())
    rows = [{"phase": "burst (16 x 2 small)", "requests": sum(burst_tally.statuses.values()),
             "2xx": burst_tally.count(200, 300), "503": burst_tally.statuses.get(503, 0),
             "p50_ms": round(burst_tally.percentiles()[0], 1),
             "p95_ms": round(burst_tally.percentiles()[1], 1),
             "p99_ms": round(burst_tally.percentiles()[2], 1),
             "per_s": round(sum(burst_tally.statuses.values()) / burst_tally.wall, 1)},
            {"phase": f"{clients} clients, {seconds:g} s", "requests": total,
             "2xx": load_tally.count(200, 300), "503": load_tally.statuses.get(503, 0),
             "p50_ms": round(p50, 1), "p95_ms": round(p95, 1), "p99_ms": round(p99, 1),
             "per_s": round(total / seconds, 1)}]
    table = C.markdown_table(["phase", "requests", "2xx", "503", "p50 ms", "p95 ms", "p99 ms",
                              "answers/s"],
                             [[r["phase"], r["requests"], r["2xx"], r["503"], r["p50_ms"],
                               r["p95_ms"], r["p99_ms"], r["per_s"]] for r in rows])
    burst_ok = burst_tally.count(200, 300) == 32
    notes = [f"- burst: {'all 32 answered 200' if burst_ok else 'NOT all 32 answered 200'}; "
             + "; ".join(describe(burst_tally)),
             "- sustained: " + "; ".join(describe(load_tally)),
             f"- server after the run: {final['renders']} renders, {final['restarts']} "
             f"restarts, {final['recycles']} recycles, {final['timeouts']} timeouts"]
    md = "\n".join([
        "# Load: 16 clients, and the 32-render burst", "",
        __doc__.split("\n\n")[1].replace("\n", " "), "",
        table, "", *notes, "",
        f"Default settings; {os.cpu_count()} CPU cores, PYOPENGL_PLATFORM="
        f"{os.environ.get('PYOPENGL_PLATFORM')}; seed {seed}; {C.code_state()}.", ""])
    out = C.results_dir(quick)
    C.finish(out, "load", md, rows, [table], notes, time.perf_counter() - started)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10 s of sustained load")
    ap.add_argument("--seconds", type=float, default=None, help="sustained load (default 60)")
    ap.add_argument("--clients", type=int, default=16)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    seconds = args.seconds or (10.0 if args.quick else 60.0)
    run(args.quick, seconds, args.clients, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
