"""Soak: thousands of varied renders through a real server; does resident memory stay flat?

Starts ``shadowmap serve`` with its default settings on a free localhost port and posts 2,000
renders (``--quick``: 200) from two clients: the real test models (``../shared/models``, ``.gltf``
files with their buffers as a ``.zip``), the built-in demo scene, image sizes from 160x120 to
1280x960, one to three lights of every type, every shadow-map encoding and filter, automatic and
fixed map sizes, and PNG, multipart and JSON responses, drawn from a seeded generator. Every 100
renders it prints the resident memory of the server process and of its render worker process
(``/proc/<pid>/statm``; the worker's pid from ``/healthz``), which the issue's "done when" bounds
at 1.5 times its value at render 200. Written to bench/results/soak.md and .csv.

Run: ``PYTHONPATH=. .venv/bin/python bench/soak.py [--quick] [--renders N] [--clients N]``
"""

from __future__ import annotations

import argparse
import io
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections import Counter

from bench import _common as C

#: Models posted, with the weight of each in the mix; .gltf files travel as a .zip with every
#: .bin of the folder.
MODELS = {"Duck.glb": 3, "BoxTextured.glb": 2, "CesiumMilkTruck.glb": 3,
          "AlphaBlendModeTest.glb": 2, "Fox.glb": 2, "CesiumMan.glb": 2, "TwoCubes.glb": 1,
          "BoxMeshopt.glb": 1, "cube.glb": 1, "TestScene.gltf": 2, "BoxDraco.gltf": 1,
          "Animation_Skin_01.gltf": 1, None: 3}  # None: the demo scene (no upload)
SIZES = [(160, 120), (320, 240), (640, 480), (800, 600), (1024, 768), (1280, 960)]
ENCODINGS = ["rgba8", "rgb8", "rg8", "r8", "depth"]
MAP_SIZES: list[int | str] = ["auto", "auto", 512, 1024, 2048]
ACCEPTS = {"image/png": 6, "multipart/mixed": 2, "application/json": 1}
EXTRA_OUTPUTS = ["light_depth", "visibility", "depth"]
CHECKPOINT = 100


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_bytes(pid: int | None) -> int | None:
    """Resident memory of a process from ``/proc/<pid>/statm``; None when it is gone."""
    if pid is None:
        return None
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


class Server:
    """``shadowmap serve`` in a subprocess (settings from ``env``), stopped on exit."""

    def __init__(self, env: dict[str, str] | None = None, ready_timeout: float = 120.0) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "shadowmap", "serve", "--port", str(self.port)],
            stdout=self.log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})},
            cwd=tempfile.gettempdir())
        self.ready_timeout = ready_timeout

    def __enter__(self) -> Server:
        import httpx

        deadline = time.monotonic() + self.ready_timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited during start-up:\n{self.log_text()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        raise RuntimeError(f"the server did not answer /healthz in {self.ready_timeout} s")

    def __exit__(self, *exc: object) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()

    def log_text(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace")

    def health(self) -> dict:
        import httpx

        return httpx.get(self.url + "/healthz", timeout=10).json()["worker"]


def scene_files() -> dict[str, tuple[str, bytes]]:
    """Upload name and bytes of each model: a .glb as it is, a .gltf zipped with the .bin files."""
    folder = C.models_dir()
    bins = {p.name: p.read_bytes() for p in folder.iterdir() if p.suffix == ".bin"}
    out = {}
    for name in MODELS:
        if name is None:
            continue
        data = (folder / name).read_bytes()
        if name.endswith(".gltf"):
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
                zf.writestr(name, data)
                for bin_name, blob in bins.items():
                    zf.writestr(bin_name, blob)
            out[name] = (name.replace(".gltf", ".zip"), buf.getvalue())
        else:
            out[name] = (name, data)
    return out


def random_light(rng: random.Random) -> dict:
    kind = rng.choice(["directional", "directional", "spot", "point"])
    if kind == "directional":
        return {"type": kind, "direction": [rng.uniform(-1, 1), -1.0, rng.uniform(-1, 1)]}
    position = [rng.uniform(-3, 3), rng.uniform(2, 5), rng.uniform(-3, 3)]
    if kind == "spot":
        return {"type": kind, "position": position, "target": [0.0, 0.0, 0.0],
                "outer_cone_deg": rng.uniform(20, 60)}
    return {"type": kind, "position": position}


def random_request(rng: random.Random) -> tuple[str | None, dict, str]:
    """(model name or None for the demo, params, Accept) of one render."""
    model = rng.choices(list(MODELS), weights=list(MODELS.values()))[0]
    width, height = rng.choice(SIZES)
    accept = rng.choices(list(ACCEPTS), weights=list(ACCEPTS.values()))[0]
    outputs = ["color"]
    if accept != "image/png":
        outputs += rng.sample(EXTRA_OUTPUTS, rng.randint(1, len(EXTRA_OUTPUTS)))
    params = {
        "width": width, "height": height, "ground": model is not None,
        "lights": [random_light(rng) for _ in range(rng.choice([1, 1, 2, 3]))],
        "shadows": {"encoding": rng.choice(ENCODINGS), "map_size": rng.choice(MAP_SIZES),
                    "filter": rng.choice(["pcf", "pcf", "hard"]),
                    "pcf_kernel": rng.choice([1, 3, 5])},
        "outputs": outputs,
    }
    return model, params, accept


def post(client, files: dict[str, tuple[str, bytes]], model: str | None, params: dict,
         accept: str):
    headers = {"Accept": accept}
    if model is None:
        return client.post("/render", content=json.dumps(params),
                           headers={**headers, "Content-Type": "application/json"})
    name, data = files[model]
    return client.post("/render", files={"scene": (name, data, "application/octet-stream")},
                       data={"params": json.dumps(params)}, headers=headers)


def mib(value: int | None) -> str:
    return "—" if value is None else f"{value / 2**20:.0f}"


def run(renders: int, clients: int, quick: bool, seed: int) -> None:
    import httpx

    started = time.perf_counter()
    files = scene_files()
    rng = random.Random(seed)
    plan = [random_request(rng) for _ in range(renders)]
    lock = threading.Lock()
    statuses: Counter[int] = Counter()
    errors: Counter[str] = Counter()
    latencies: list[float] = []
    checkpoints: list[dict] = []
    next_index = 0
    done = 0

    with Server() as server:
        bar = C.Progress(renders, "soak")

        def checkpoint(n: int) -> None:
            h = server.health()
            row = {"renders": n, "server_mib": rss_bytes(server.proc.pid),
                   "worker_mib": rss_bytes(h["pid"]), "worker_pid": h["pid"],
                   "recycles": h["recycles"], "restarts": h["restarts"],
                   "p50_ms": round(1e3 * statistics.median(latencies[-CHECKPOINT:]), 1),
                   "non_200": sum(v for k, v in statuses.items() if k != 200)}
            checkpoints.append(row)
            print(f"\n{n:5d} renders: server {mib(row['server_mib'])} MiB, worker "
                  f"{mib(row['worker_mib'])} MiB (pid {row['worker_pid']}, {row['recycles']} "
                  f"recycles, {row['restarts']} restarts), p50 {row['p50_ms']} ms, "
                  f"{row['non_200']} not 200", file=sys.stderr, flush=True)

        def client_loop() -> None:
            nonlocal next_index, done
            with httpx.Client(base_url=server.url, timeout=300) as c:
                while True:
                    with lock:
                        if next_index >= renders:
                            return
                        model, params, accept = plan[next_index]
                        next_index += 1
                    t0 = time.perf_counter()
                    error = None
                    try:
                        resp = post(c, files, model, params, accept)
                        status = resp.status_code
                        if status != 200:
                            error = f"{status} {resp.json().get('error')}"
                    except httpx.HTTPError as exc:
                        status, error = 0, f"transport {type(exc).__name__}"
                    seconds = time.perf_counter() - t0
                    with lock:
                        statuses[status] += 1
                        if error is not None:
                            errors[error] += 1
                        latencies.append(seconds)
                        done += 1
                        n = done
                        bar.step(f"{status}")
                        if n % CHECKPOINT == 0:
                            checkpoint(n)

        threads = [threading.Thread(target=client_loop) for _ in range(clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        bar.close()
        final = server.health()
        log = server.log_text()
    elapsed = time.perf_counter() - started

    # The bound: after warm-up (render 200), resident memory stays within 1.5x.
    base = next((r for r in checkpoints if r["renders"] == 200), None)
    verdicts = []
    for key, label in (("server_mib", "server"), ("worker_mib", "worker")):
        values = [r[key] for r in checkpoints if r["renders"] >= 200 and r[key] is not None]
        if base is None or base[key] is None or not values:
            verdicts.append(f"{label}: not enough checkpoints for the 1.5x bound")
            continue
        ratio = max(values) / base[key]
        verdicts.append(f"{label}: peak {max(values) / 2**20:.0f} MiB from render 200 on, "
                        f"{ratio:.2f}x its {base[key] / 2**20:.0f} MiB at render 200 "
                        f"({'within' if ratio <= 1.5 else 'OVER'} the 1.5x bound)")
    rows = [[r["renders"], mib(r["server_mib"]), mib(r["worker_mib"]), r["worker_pid"],
             r["recycles"], r["restarts"], r["p50_ms"], r["non_200"]] for r in checkpoints]
    table = C.markdown_table(["renders", "server MiB", "worker MiB", "worker pid", "recycles",
                              "restarts", "p50 ms (last 100)", "not 200 (so far)"], rows)
    status_line = ", ".join(f"{k}: {v}" for k, v in sorted(statuses.items()))
    error_line = ", ".join(f"{k} x{v}" for k, v in errors.most_common()) or "none"
    tracebacks = log.count("Traceback")
    md = "\n".join([
        "# Soak: resident memory over varied renders", "",
        __doc__.split("\n\n")[1].replace("\n", " "), "",
        table, "",
        *[f"- {v}" for v in verdicts],
        f"- statuses: {status_line}; not 200: {error_line}",
        f"- {final['renders']} renders, {final['recycles']} worker recycles, "
        f"{final['restarts']} restarts, {final['timeouts']} timeouts; tracebacks in the server "
        f"log: {tracebacks}",
        f"- p50 {1e3 * statistics.median(latencies):.0f} ms, p95 "
        f"{1e3 * sorted(latencies)[int(0.95 * (len(latencies) - 1))]:.0f} ms per render, "
        f"{clients} clients, seed {seed}, {elapsed:.0f} s in all",
        "",
        f"Default settings (recycling after max_renders_per_worker, or over "
        f"max_worker_memory_bytes). {os.cpu_count()} CPU cores, PYOPENGL_PLATFORM="
        f"{os.environ.get('PYOPENGL_PLATFORM')}; {C.code_state()}.", ""])
    out = C.results_dir(quick)
    # The server's own messages (worker restarts and recycles, errors), without the access log.
    (out / "soak.log").write_text("".join(
        line + "\n" for line in log.splitlines() if '"POST /render' not in line
        and '"GET /healthz' not in line))
    C.finish(out, "soak", md, checkpoints, [table], verdicts + [status_line], elapsed,
             extra=["soak.log"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="200 renders (a smoke run)")
    ap.add_argument("--renders", type=int, default=None, help="renders in all (default 2000)")
    ap.add_argument("--clients", type=int, default=2, help="concurrent clients (default 2)")
    ap.add_argument("--seed", type=int, default=12)
    args = ap.parse_args(argv)
    renders = args.renders or (200 if args.quick else 2000)
    run(renders, args.clients, args.quick, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
