"""HTTP latency and throughput against the library's own render time.

Starts the real service (``shadowmap serve``) with 1 and then 2 worker processes on a free
localhost port, posts a real model, and reports latency (p50, p95) of sequential requests and the
throughput of concurrent clients, next to the median time of the same render in-process. The
sequential requests alternate with the in-process renders (one each, in turn), so that both
medians come from the same minutes of this noisy machine; the service's ``Server-Timing`` says
where the rest of a request's time goes.

Its ``pipe`` stage (the task and the answer between the server process and its render worker
process) is set beside the bare cost of the same messages: a real ``RenderTask`` holding the model
and a ``RenderReply`` holding a PNG of the response's size, sent through the same kind of pipe to
a spawned process that answers ``started`` and ``done`` as the worker does, at once and after
10 ms of work (a render's length, during which the server process waits blocked).

    python bench/http_latency.py [--quick] [--model Duck.glb] [--requests 40]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench._common import results_dir
from shadowmap.renderer import Renderer, RenderParams, load_scene

if TYPE_CHECKING:
    from shadowmap.app.worker import RenderReply

ROOT = Path(__file__).resolve().parents[1]
PARAMS = {"width": 640, "height": 480, "ground": True}


def models_dir() -> Path:
    env = os.environ.get("SHADOWMAP_MODELS")
    return Path(env) if env else ROOT.parent / "shared" / "models"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def progress(done: int, total: int, label: str) -> None:
    width = 30
    filled = int(width * done / max(total, 1))
    print(f"\r{label:28s} [{'#' * filled}{'.' * (width - filled)}] {done}/{total}",
          end="" if done < total else "\n", file=sys.stderr, flush=True)


class Library:
    """The same render in-process: the scene parsed once (the service keeps parsed uploads by
    hash, so a repeated upload compares with this), or parsed from the file's bytes every time."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.params = RenderParams(**PARAMS)
        self.r = Renderer()
        self.scene = load_scene(data)
        self.r.render(self.scene, self.params)  # warm-up: shaders, upload

    def cached(self) -> float:
        t = time.perf_counter()
        self.r.render(self.scene, self.params)
        return time.perf_counter() - t

    def parsed(self) -> float:
        t = time.perf_counter()
        self.r.render(load_scene(self.data), self.params)
        return time.perf_counter() - t

    def close(self) -> None:
        self.r.close()


class Server:
    """``shadowmap serve`` in a subprocess, stopped on exit."""

    def __init__(self, workers: int) -> None:
        self.port = free_port()
        env = dict(os.environ, SHADOWMAP_QUEUE_SIZE="64")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "shadowmap", "serve", "--port", str(self.port),
             "--workers", str(workers)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=ROOT,
        )
        self.url = f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> Server:
        import httpx

        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError("the server exited during start-up")
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        raise RuntimeError("the server did not answer /healthz within 90 s")

    def __exit__(self, *exc) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def post(client, url: str, data: bytes, name: str, stages: dict | None = None) -> float:
    t = time.perf_counter()
    r = client.post(url + "/render", files={"scene": (name, data)},
                    data={"params": json.dumps(PARAMS)}, timeout=120)
    r.raise_for_status()
    elapsed = time.perf_counter() - t
    if stages is not None:
        for item in r.headers.get("server-timing", "").split(","):
            parts = dict(p.strip().split("=", 1) if "=" in p else (p.strip(), "")
                         for p in item.split(";"))
            name_ = next(iter(parts))
            if "dur" in parts:
                stages.setdefault(name_, []).append(float(parts["dur"]))
    return elapsed


class RawClient:
    """The same request as :func:`post` from a plain socket: its bytes built once (by httpx, so
    they are the same multipart body), sent on one keep-alive connection, the response read up
    to its Content-Length. What httpx's own work adds to a request (building and parsing it in
    Python) is then told apart from what the service and the transport take, as a load
    generator such as wrk measures a server."""

    def __init__(self, port: int, data: bytes, name: str) -> None:
        import httpx

        request = httpx.Request("POST", f"http://127.0.0.1:{port}/render",
                                files={"scene": (name, data)},
                                data={"params": json.dumps(PARAMS)})
        body = request.read()
        self.blob = (f"POST /render HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                     f"Content-Type: {request.headers['content-type']}\r\n"
                     f"Content-Length: {len(body)}\r\n\r\n").encode() + body
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def post(self) -> float:
        t = time.perf_counter()
        self.sock.sendall(self.blob)
        buf = b""
        while b"\r\n\r\n" not in buf:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise RuntimeError("the server closed the connection")
            buf += chunk
        head, rest = buf.split(b"\r\n\r\n", 1)
        lines = head.split(b"\r\n")
        if not lines[0].startswith(b"HTTP/1.1 200"):
            raise RuntimeError(f"answered {lines[0].decode(errors='replace')}")
        length = next(int(v) for k, _, v in (ln.partition(b":") for ln in lines[1:])
                      if k.strip().lower() == b"content-length")
        while len(rest) < length:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise RuntimeError("the server closed the connection")
            rest += chunk
        return time.perf_counter() - t

    def close(self) -> None:
        self.sock.close()


def run(workers: int, data: bytes, name: str, n: int, clients: int, lib: Library) -> dict:
    import httpx

    stages: dict[str, list[float]] = {}
    with Server(workers) as server, httpx.Client() as client:
        raw = RawClient(server.port, data, name)
        for _ in range(2 * workers):  # warm every worker process
            post(client, server.url, data, name)
            raw.post()
        body_bytes = len(client.post(server.url + "/render", files={"scene": (name, data)},
                                     data={"params": json.dumps(PARAMS)}, timeout=120).content)
        latencies, raw_latencies, cached, parsed = [], [], [], []
        for i in range(n):
            # One of each in turn: the ratio compares like with like on a noisy machine.
            cached.append(lib.cached())
            latencies.append(post(client, server.url, data, name, stages))
            raw_latencies.append(raw.post())
            if i % 2 == 0:
                parsed.append(lib.parsed())
            progress(i + 1, n, f"{workers} worker(s), sequential")
        raw.close()
        total = n * 2
        done = 0
        t0 = time.perf_counter()
        with ThreadPoolExecutor(clients) as pool:
            with httpx.Client() as shared:
                futures = [pool.submit(post, shared, server.url, data, name) for _ in range(total)]
                for f in futures:
                    f.result()
                    done += 1
                    progress(done, total, f"{workers} worker(s), {clients} clients")
        wall = time.perf_counter() - t0
    lat = np.array(latencies) * 1000
    return {"workers": workers, "p50": float(np.percentile(lat, 50)),
            "p95": float(np.percentile(lat, 95)), "throughput": total / wall,
            "raw_p50": float(np.percentile(np.array(raw_latencies) * 1000, 50)),
            "library": float(np.median(cached) * 1000),
            "library_parsed": float(np.median(parsed) * 1000),
            "stages": {k: float(np.median(v)) for k, v in stages.items()},
            "body_bytes": body_bytes}


IPC_ROUNDS = 200
IPC_WORK = 0.010  # seconds the echo process works between "started" and "done"


def _ipc_echo(conn: Connection, reply: RenderReply, work: float) -> None:
    """The worker's side of the pipe, without the render: "started", ``work`` seconds of busy
    CPU, then "done" with ``reply``."""
    while (message := conn.recv()) is not None:
        conn.send(("started", message[1].job_id))
        t = time.perf_counter()
        while time.perf_counter() - t < work:
            pass
        conn.send(("done", message[1].job_id, reply))


def ipc_round_trip(data: bytes, body_bytes: int, work: float) -> float:
    """Median ms a task and its reply spend between two processes, less ``work``."""
    import multiprocessing as mp

    from shadowmap.app.worker import RenderReply, RenderTask

    task = RenderTask(1, data, "glb", {}, RenderParams.model_validate(PARAMS), "image/png",
                      ["color"], {"read": 0.001, "queue": 0.0002}, 0.001)
    reply = RenderReply(os.urandom(body_bytes), "image/png", {"x-render-plan": "{}" * 400},
                        work, True)
    ctx = mp.get_context("spawn")
    conn, child_end = ctx.Pipe(duplex=True)
    proc = ctx.Process(target=_ipc_echo, args=(child_end, reply, work), daemon=True)
    proc.start()
    child_end.close()
    times = []
    try:
        for k in range(IPC_ROUNDS + 10):
            t = time.perf_counter()
            conn.send(("render", task))
            conn.recv()
            conn.recv()
            if k >= 10:
                times.append(time.perf_counter() - t - work)
    finally:
        conn.send(None)
        proc.join(10)
    return float(np.median(times) * 1000)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="Duck.glb")
    ap.add_argument("--requests", type=int, default=40, help="sequential requests per run")
    ap.add_argument("--clients", type=int, default=4, help="concurrent clients")
    ap.add_argument("--quick", action="store_true", help="10 requests, 1 worker")
    args = ap.parse_args(argv)
    n = 10 if args.quick else args.requests
    data = (models_dir() / args.model).read_bytes()
    lib = Library(data)
    try:
        rows = [run(w, data, args.model, n, args.clients, lib)
                for w in ((1,) if args.quick else (1, 2))]
    finally:
        lib.close()
    body_bytes = int(rows[0]["body_bytes"])
    ipc = {work: ipc_round_trip(data, body_bytes, work) for work in (0.0, IPC_WORK)}
    lines = [
        f"# HTTP latency: {args.model} with a ground plane, 640x480, default settings",
        "",
        "Library render in-process, median of the renders interleaved with each row's "
        "sequential requests: with the scene loaded once (the service keeps parsed uploads by "
        "hash) and parsing the file every time.",
        "",
        "| workers | library ms | library, parsing ms | p50 ms | p95 ms | HTTP over library at "
        "p50 | p50, plain socket client ms | plain client over library at p50 | throughput, "
        f"{args.clients} clients (renders/s) |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        over = (r["p50"] / r["library"] - 1) * 100
        raw_over = (r["raw_p50"] / r["library"] - 1) * 100
        lines.append(f"| {r['workers']} | {r['library']:.1f} | {r['library_parsed']:.1f} | "
                     f"{r['p50']:.1f} | {r['p95']:.1f} | {over:+.0f} % | "
                     f"{r['raw_p50']:.1f} | {raw_over:+.0f} % | {r['throughput']:.1f} |")
    st = rows[0]["stages"]
    inside = sum(v for k, v in st.items() if k != "total")
    lines += ["", f"{n} sequential requests (each after one in-process render, and each "
              "followed by the same request from a plain socket client: its bytes built once, "
              f"sent on one keep-alive connection) and {2 * n} "
              "concurrent ones per row; multipart upload of the .glb, PNG response, httpx as "
              "the client except in the plain client's column. Target: HTTP "
              "p50 at most 1.15x the library render. "
              f"{os.cpu_count()} CPU cores, "
              f"PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')}.",
              "", "Where a request's time goes, one server process (medians of its "
              "`Server-Timing`, ms): "
              + ", ".join(f"{k} {v:.2f}" for k, v in st.items())
              + "; the plain client's p50 less the server's total: "
              f"{rows[0]['raw_p50'] - st.get('total', 0):.2f} "
              "(transport, the framework outside the route, the event loop); httpx's p50 less "
              f"the plain client's: {rows[0]['p50'] - rows[0]['raw_p50']:.2f} (the client's own "
              f"work: building the multipart request, reading the response). Stages sum to "
              f"{inside:.2f}.",
              "", f"The same messages between two processes alone (a {len(data):,}-byte "
              f"model in the task, a {body_bytes:,}-byte body in the reply, the same kind of "
              f"pipe; medians of {IPC_ROUNDS}): {ipc[0.0]:.2f} ms when the other process answers "
              f"at once, {ipc[IPC_WORK]:.2f} ms when it works {IPC_WORK * 1000:.0f} ms first, "
              "as a render does, while this one waits blocked (the `pipe` stage above: "
              f"{st.get('pipe', float('nan')):.2f} ms)."]
    text = "\n".join(lines)
    print(text)
    if not args.quick:
        (results_dir() / "http_latency.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
