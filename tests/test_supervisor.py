"""The service's process model: a render worker process that is stopped at the time limit,
replaced when it dies, recycled for flat memory; admission by expected wait; slow clients.

The pure parts (cost model, error transport) run without GL; everything else runs against real
servers started through :func:`shadowmap.app.main.run` (so the uvicorn settings apply), each
with the few settings its case needs.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import httpx
import pytest

from shadowmap.app.supervisor import KILL_GRACE, CostModel, size_class
from shadowmap.app.worker import ErrorPayload
from shadowmap.renderer import (
    LimitError,
    RenderParams,
    RequestError,
    SceneError,
    UnsupportedExtension,
    UnsupportedVersion,
)
from test_app import SMALL, ServerProcess, assert_error, assert_picture, post_params

#: The time limit of the limits server: far below any SLOW render (3 s with 5 point lights on
#: llvmpipe, 2 cores, about 10 s with 8), far above a SMALL one (about 20 ms).
TIMEOUT = 1.0
LIMITS_ENV = {
    "SHADOWMAP_RENDER_TIMEOUT": str(TIMEOUT),
    "SHADOWMAP_UPLOAD_TIMEOUT": "1",
    "SHADOWMAP_KEEP_ALIVE_TIMEOUT": "1",
    "SHADOWMAP_QUEUE_SIZE": "4",
}


def slow(lights: int) -> dict:
    """Seconds of GL work: 2048^2 pixels, ``lights`` point lights with 2048^2 cube maps, 9x9 PCF.

    Each light count is its own size class, so a case's cost estimates are not taught by
    another case's.
    """
    return {"width": 2048, "height": 2048, "outputs": ["color"], "optimize": False,
            "shadows": {"map_size": 2048, "pcf_kernel": 9},
            "lights": [{"type": "point", "position": [-2.0 + 0.55 * i, 2.5, 1.0]}
                       for i in range(lights)]}


# ------------------------------------------------------------------------------------------------
# Servers
# ------------------------------------------------------------------------------------------------


@contextmanager
def serving(*envs: dict[str, str]) -> Iterator[list[ServerProcess]]:
    """Servers with these settings, started together; no handler may have crashed in them."""
    servers = [ServerProcess(env, via_run=True) for env in envs]
    try:
        for s in servers:
            s.wait_ready()
        yield servers
        for s in servers:
            assert "Traceback" not in s.log_text(), s.log_text()
    finally:
        for s in servers:
            s.stop()


@pytest.fixture(scope="module")
def limits_server() -> Iterator[ServerProcess]:
    with serving(LIMITS_ENV) as (server,):
        yield server


@pytest.fixture(scope="module")
def default_server() -> Iterator[ServerProcess]:
    """Every setting at its default (a 60 s time limit: slow renders run to their end)."""
    with serving({}) as (server,):
        yield server


def health(server: ServerProcess) -> dict:
    return httpx.get(server.url + "/healthz", timeout=5).json()["worker"]


def health_when(server: ServerProcess, test, timeout: float = 30.0,
                what: str = "the condition") -> dict:
    """The worker state, polled until ``test(state)`` holds."""

    def check() -> dict | None:
        state = health(server)
        return state if test(state) else None

    return wait_for(check, timeout, what)


def wait_for(predicate, timeout: float = 30.0, what: str = "the condition") -> dict:
    """Poll until ``predicate()`` returns something true; return it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what} did not happen within {timeout} s")


def process_gone(pid: int) -> bool:
    """True when ``pid`` no longer runs (gone, or a zombie waiting to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def post_async(url: str, params: dict, results: dict, key: str) -> threading.Thread:
    """POST in a thread; the response (and its round-trip seconds) lands in ``results[key]``."""

    def run() -> None:
        t0 = time.monotonic()
        try:
            with httpx.Client(base_url=url, timeout=120) as c:
                results[key] = (post_params(c, params), time.monotonic() - t0)
        except httpx.HTTPError as exc:
            results[key] = (exc, time.monotonic() - t0)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


# ------------------------------------------------------------------------------------------------
# Pure parts
# ------------------------------------------------------------------------------------------------


def test_cost_model_learns_per_class_and_falls_back_to_the_overall_mean():
    model = CostModel(prior=0.05)
    small = size_class(RenderParams(width=160, height=120), 60_000)
    big = size_class(RenderParams.model_validate(slow(8)), 60_000)
    assert small != big
    assert model.estimate(small) == model.estimate(big) == 0.05
    model.observe(small, 0.02)
    model.observe(small, 0.04)
    assert 0.02 < model.estimate(small) < 0.04
    # A class never seen is estimated at the mean of everything seen so far.
    assert model.estimate(big) == pytest.approx(model.overall)
    # A stopped job teaches a lower bound, and does not move the overall mean.
    overall = model.overall
    model.observe_at_least(big, 1.0)
    assert model.estimate(big) == 1.0 and model.overall == overall
    model.observe_at_least(big, 0.5)
    assert model.estimate(big) == 1.0


def test_size_class_separates_what_makes_a_render_slow():
    base = RenderParams(width=640, height=480)
    variants = [
        RenderParams(width=2560, height=1920),
        RenderParams.model_validate({"lights": [{"direction": [0, -1, 0]}] * 3}),
        RenderParams.model_validate({"lights": [{"type": "point", "position": [0, 2, 0]}]}),
        RenderParams.model_validate({"shadows": {"map_size": 4096}}),
        RenderParams.model_validate({"outputs": ["color", "depth", "visibility"]}),
    ]
    classes = {size_class(p, 60_000) for p in [base, *variants]}
    assert len(classes) == 1 + len(variants)
    assert size_class(base, 60_000) != size_class(base, 60_000_000)
    # Nearly the same request is the same class.
    assert size_class(RenderParams(width=650, height=480), 61_000) == size_class(base, 60_000)


@pytest.mark.parametrize("exc", [
    LimitError("max_triangles", "too many triangles"),
    UnsupportedExtension(["KHR_fake"]),
    UnsupportedVersion("asset.version", "glTF 3.0"),
    RequestError("zero-length direction"),
    RequestError("width: too small", [{"loc": ["width"], "msg": "too small", "type": "ge"}]),
    SceneError("truncated"),
])
def test_library_errors_cross_the_pipe_with_their_attributes(exc):
    import pickle

    back = pickle.loads(pickle.dumps(ErrorPayload.of(exc))).rebuild()
    assert type(back) is type(exc) and str(back) == str(exc)
    assert vars(back) == vars(exc)


def test_other_errors_cross_the_pipe_as_themselves_or_as_a_runtime_error():
    class Local(Exception):  # not importable by name: cannot be pickled
        pass

    back = ErrorPayload.of(KeyError("k")).rebuild()
    assert type(back) is KeyError and back.args == ("k",)
    back = ErrorPayload.of(Local("odd")).rebuild()
    assert type(back) is RuntimeError and "Local" in str(back) and "odd" in str(back)


def test_run_refuses_an_unknown_setting():
    from shadowmap.app.main import run

    with pytest.raises(TypeError, match="no_such_setting"):
        run(no_such_setting=1)


# ------------------------------------------------------------------------------------------------
# The time limit
# ------------------------------------------------------------------------------------------------


@pytest.mark.gl
@pytest.mark.slow
def test_slow_render_is_stopped_and_the_next_request_served(limits_server, software_gl):
    before = health(limits_server)
    with httpx.Client(base_url=limits_server.url, timeout=60) as c:
        t0 = time.monotonic()
        resp = post_params(c, slow(8))
        took = time.monotonic() - t0
        body = assert_error(resp, 504, "render_timeout", "render_timeout")
        assert f"{TIMEOUT:g} s" in body["detail"] and "stopped" in body["detail"]
        # Answered at the limit, not when the render would have ended (about 10 s).
        assert TIMEOUT * 0.9 <= took < TIMEOUT + KILL_GRACE + 1.0, took
        # The very next request waits for the new worker only, then renders normally.
        t0 = time.monotonic()
        assert_picture(post_params(c, SMALL), 160, 120)
        took = time.monotonic() - t0
    after = health(limits_server)
    assert took < TIMEOUT + after["restart_seconds"] + 1.0, (took, after)
    assert after["timeouts"] == before["timeouts"] + 1
    assert after["restarts"] == before["restarts"] + 1
    assert after["pid"] != before["pid"]
    wait_for(lambda: process_gone(before["pid"]), 5, "the old worker's exit")


def test_a_queued_job_past_its_deadline_frees_its_place_at_once():
    """No worker takes jobs off this supervisor's queue (it is not started): a job whose time
    runs out there is answered 503 and its place is free for the next one at once."""
    import asyncio

    from shadowmap.app.errors import ServiceError
    from shadowmap.app.settings import Settings
    from shadowmap.app.supervisor import Supervisor
    from shadowmap.app.upload import SceneUpload

    supervisor = Supervisor(Settings(render_timeout=0.3, queue_size=1))
    upload = SceneUpload(b"glTF", "glb")
    params = RenderParams()

    async def main() -> None:
        t0 = time.monotonic()
        first = asyncio.create_task(supervisor.render(upload, params, "image/png", ["color"]))
        await asyncio.sleep(0.05)
        with pytest.raises(ServiceError) as full:  # the one place is taken
            supervisor.submit(upload, params, "image/png", ["color"])
        assert (full.value.status, full.value.error, full.value.limit) == (503, "queue_full",
                                                                           "queue_size")
        with pytest.raises(ServiceError) as late:
            await first
        assert (late.value.status, late.value.error) == (503, "render_timeout")
        assert 0.3 <= time.monotonic() - t0 < 0.6
        assert int(late.value.headers["Retry-After"]) >= 1
        assert supervisor.snapshot()["queued"] == 0
        supervisor.submit(upload, params, "image/png", ["color"])  # admitted: the place is free

    asyncio.run(main())


@pytest.mark.gl
@pytest.mark.slow
def test_a_job_whose_client_gives_up_leaves_the_queue_at_once(default_server, software_gl):
    """A small job waits behind a slow render; its client gives up after 0.3 s. The job leaves
    the queue then, while the slow render still runs, and is never rendered."""
    url = default_server.url
    results: dict = {}
    first = post_async(url, slow(5), results, "slow")
    before = health_when(default_server, lambda w: w["busy_seconds"] is not None,
                         what="the slow render")
    with pytest.raises(httpx.ReadTimeout), httpx.Client(base_url=url, timeout=0.3) as c:
        post_params(c, SMALL)
    state = health_when(default_server, lambda w: w["queued"] == 0, timeout=2.0,
                        what="the abandoned job leaving the queue")
    # Still the slow render (about 3 s): the queue emptied while it ran.
    assert state["busy_seconds"] is not None and state["pid"] == before["pid"], state
    first.join(60)
    assert_picture(results["slow"][0], 2048, 2048)
    after = health(default_server)
    assert after["renders"] == before["renders"] + 1, after  # the abandoned one never ran
    with httpx.Client(base_url=url, timeout=60) as c:
        assert_picture(post_params(c, SMALL), 160, 120)


@pytest.mark.gl
@pytest.mark.slow
def test_a_worker_that_dies_is_replaced_and_its_request_answered(default_server):
    url = default_server.url
    # Killed during a render: that request gets 503 worker_restarted, with Retry-After, when
    # the worker dies (not when the render would have ended, about 3 s in).
    results: dict = {}
    thread = post_async(url, slow(4), results, "killed")
    state = health_when(default_server, lambda w: w["busy_seconds"] is not None,
                        what="the render")
    os.kill(state["pid"], signal.SIGKILL)
    killed = time.monotonic()
    thread.join(30)
    resp, _ = results["killed"]
    assert_error(resp, 503, "worker_restarted")
    assert int(resp.headers["retry-after"]) >= 1 and time.monotonic() - killed < 1.5
    with httpx.Client(base_url=url, timeout=60) as c:
        assert_picture(post_params(c, SMALL), 160, 120)
        # Killed while idle: noticed and replaced; the next request is served (sent to the
        # dead worker, it had not started there: it is retried on the new one).
        pid = health(default_server)["pid"]
        os.kill(pid, signal.SIGKILL)
        assert_picture(post_params(c, SMALL), 160, 120)
    after = health(default_server)
    assert after["pid"] != pid and after["restarts"] >= state["restarts"] + 2


# ------------------------------------------------------------------------------------------------
# Slow and idle clients
# ------------------------------------------------------------------------------------------------


def read_response(sock: socket.socket, timeout: float) -> tuple[bytes, float, bool]:
    """Everything the server sends within ``timeout``; (data, seconds, closed by the server)."""
    sock.settimeout(0.2)
    data = b""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            continue
        except ConnectionResetError:
            return data, time.monotonic() - t0, True
        if not chunk:
            return data, time.monotonic() - t0, True
        data += chunk
    return data, time.monotonic() - t0, False


@pytest.mark.gl
def test_a_client_that_sends_headers_and_no_body_gets_408_and_is_dropped(limits_server):
    with socket.create_connection(("127.0.0.1", limits_server.port)) as sock:
        sock.sendall(b"POST /render HTTP/1.1\r\nHost: x\r\nContent-Type: model/gltf-binary\r\n"
                     b"Content-Length: 100000\r\n\r\nglTF")
        data, took, closed = read_response(sock, 10)
    head, _, body = data.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 408"), data[:300]
    assert json.loads(body)["error"] == "upload_timeout"
    assert json.loads(body)["limit"] == "upload_timeout"
    assert closed and 0.9 <= took < 3.0, took


@pytest.mark.gl
def test_idle_and_half_open_connections_are_closed(limits_server):
    """keep_alive_timeout (1 s here) bounds a connection that sends nothing, one that sends half
    a request head, and an idle keep-alive connection after its response."""
    port = limits_server.port
    with socket.create_connection(("127.0.0.1", port)) as silent, \
            socket.create_connection(("127.0.0.1", port)) as half:
        half.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        for sock in (silent, half):
            data, took, closed = read_response(sock, 10)
            assert closed and data == b"" and took < 3.0, (data, took)
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        data, took, closed = read_response(sock, 10)
        assert data.startswith(b"HTTP/1.1 200") and closed and took < 3.0, (data[:100], took)


#: A response larger than the kernel's socket buffers can hold (4 MiB of send buffer at most by
#: default, /proc/sys/net/ipv4/tcp_wmem): about 7 MB of JSON (colour, depth and visibility, the
#: last two also as float32 OpenEXR), rendered in about 2 s on llvmpipe.
BIG_RESPONSE = {"width": 4096, "height": 4096, "outputs": ["color", "depth", "visibility"],
                "float_format": "exr"}


@pytest.mark.gl
@pytest.mark.slow
def test_a_client_that_stops_reading_its_response_is_dropped_after_send_timeout():
    """A client that sends a request and never reads the answer would hold its connection, one
    of the limit_concurrency places (2 here: itself and one more), and the response's bytes for
    ever; send_timeout (2 s) drops it. A client that reads the same response gets all of it."""
    with serving({"SHADOWMAP_SEND_TIMEOUT": "2", "SHADOWMAP_LIMIT_CONCURRENCY": "2"}) as (s,):
        params = json.dumps(BIG_RESPONSE).encode()
        body = (b'--b\r\nContent-Disposition: form-data; name="params"\r\n\r\n' + params
                + b"\r\n--b--\r\n")
        request = (b"POST /render HTTP/1.1\r\nHost: x\r\nAccept: application/json\r\n"
                   b"Content-Type: multipart/form-data; boundary=b\r\n"
                   b"Content-Length: %d\r\n\r\n" % len(body)) + body
        with httpx.Client(base_url=s.url, timeout=60) as client:
            whole = client.post("/render", content=request.partition(b"\r\n\r\n")[2],
                                headers={"Accept": "application/json",
                                         "Content-Type": "multipart/form-data; boundary=b"})
            assert whole.status_code == 200, whole.text[:300]
            size = len(whole.content)
            assert size > 6_000_000 and set(whole.json()["outputs"]) >= {"color", "depth"}
        with socket.socket() as stalled:
            # A small receive window, set before the connection opens, as a slow reader's.
            stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            stalled.connect(("127.0.0.1", s.port))
            stalled.sendall(request)

            def served() -> bool:  # 503 while the stalled connection holds its place
                return httpx.get(s.url + "/healthz", timeout=5).status_code == 200

            wait_for(served, 30, "a free connection place")
            # What the kernel had taken in is still read, then the end: no whole response.
            data, _, closed = read_response(stalled, 10)
        assert closed and data.startswith(b"HTTP/1.1 200"), data[:100]
        assert len(data) < size, (len(data), size)
@pytest.mark.gl
@pytest.mark.slow
def test_shutdown_is_bounded_while_a_render_runs():
    shutdown = 1.5
    server = ServerProcess({"SHADOWMAP_SHUTDOWN_TIMEOUT": str(shutdown),
                            "SHADOWMAP_RENDER_TIMEOUT": "120"}, via_run=True)
    try:
        server.wait_ready()
        results: dict = {}
        post_async(server.url, slow(8), results, "running")
        state = health_when(server, lambda w: w["busy_seconds"] is not None,
                            what="the render")
        t0 = time.monotonic()
        server.proc.send_signal(signal.SIGTERM)
        server.proc.wait(30)
        took = time.monotonic() - t0
        # The graceful period, then the worker is killed at once (not after its ~10 s render).
        assert took < shutdown + KILL_GRACE + 2.0, (took, server.log_text())
        # uvicorn ends by raising the signal it caught again, for whoever started it.
        assert server.proc.returncode in (0, -signal.SIGTERM), server.log_text()
        wait_for(lambda: process_gone(state["pid"]), 5, "the worker's exit")
    finally:
        server.stop()


# ------------------------------------------------------------------------------------------------
# Flat memory: recycling
# ------------------------------------------------------------------------------------------------


@pytest.mark.gl
@pytest.mark.slow
def test_workers_recycle_after_n_renders_and_over_the_memory_cap_failing_nothing():
    by_count = {"SHADOWMAP_MAX_RENDERS_PER_WORKER": "3"}
    by_memory = {"SHADOWMAP_MAX_WORKER_MEMORY_BYTES": str(64 * 2**20)}  # below any worker's
    with serving(by_count, by_memory) as servers:
        for server in servers:
            pids = set()
            with httpx.Client(base_url=server.url, timeout=60) as c:
                for i in range(6):
                    params = {"width": 96 + 16 * i, "height": 72}
                    assert_picture(post_params(c, params), params["width"], 72)
                    # The replacement starts beside the worker and takes over between renders.
                    state = health_when(server, lambda w: not w["replacing"],
                                        what="the replacement taking over")
                    pids.add(state["pid"])
                    if server is servers[0]:
                        assert state["worker_renders"] == (i + 1) % 3, state
            state = health(server)
            assert state["renders"] == 6 and state["failures"] == 0, state
            assert state["restarts"] == 0, state
            assert state["recycles"] == (2 if server is servers[0] else 6), (
                state, server.log_text())
            # By count: the first worker and two replacements; by memory: one per render.
            assert len(pids) == (3 if server is servers[0] else 6), pids
        assert "max_renders_per_worker" in servers[0].log_text()
        assert "max_worker_memory_bytes" in servers[1].log_text()


# ------------------------------------------------------------------------------------------------
# Admission by expected wait
# ------------------------------------------------------------------------------------------------


def burst(url: str, params: dict, clients: int, each: int) -> list[httpx.Response]:
    barrier = threading.Barrier(clients)

    def client(_: int) -> list[httpx.Response]:
        with httpx.Client(base_url=url, timeout=120) as c:
            barrier.wait()
            return [post_params(c, params) for _ in range(each)]

    with ThreadPoolExecutor(clients) as pool:
        return [r for rs in pool.map(client, range(clients)) for r in rs]


@pytest.mark.gl
@pytest.mark.slow
def test_a_burst_of_32_small_renders_from_16_clients_all_succeed_with_default_settings(
        default_server):
    responses = burst(default_server.url, SMALL, clients=16, each=2)
    assert [r.status_code for r in responses] == [200] * 32, [
        (r.status_code, r.text[:200]) for r in responses if r.status_code != 200]
    assert health(default_server)["queued"] == 0


@pytest.mark.gl
@pytest.mark.slow
def test_admission_refuses_by_expected_wait_with_retry_after_from_it():
    # About 0.2 s each on llvmpipe (2 cores): the limit admits the running one and one or two.
    medium = {"width": 1280, "height": 960, "shadows": {"map_size": 4096, "pcf_kernel": 5}}
    with serving({"SHADOWMAP_MAX_EXPECTED_WAIT": "0.3", "SHADOWMAP_QUEUE_SIZE": "32"}) as (s,):
        with httpx.Client(base_url=s.url, timeout=60) as c:
            for _ in range(3):  # teach the cost of this size
                assert post_params(c, medium).status_code == 200
        responses = burst(s.url, medium, clients=8, each=1)
        codes = sorted(r.status_code for r in responses)
        assert set(codes) == {200, 503}, codes
        for r in responses:
            if r.status_code == 503:
                body = assert_error(r, 503, "queue_full", "max_expected_wait")
                assert "over the limit of 0.3 s" in body["detail"]
                assert 1 <= int(r.headers["retry-after"]) <= 30
        # Far fewer admitted than the 32 queue places would allow.
        assert codes.count(200) < 8


def test_serve_refuses_an_invalid_setting_in_one_line():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "shadowmap", "serve", "--port", "1",
                           "--shutdown-timeout", "-1"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "invalid setting: shutdown_timeout" in lines[0], proc.stderr


@pytest.mark.parametrize("args, env, message", [
    (["--workers", "0"], {}, "--workers must be from 1 to"),
    (["--workers", "100000"], {}, "--workers must be from 1 to"),
    (["--port", "70000"], {}, "--port must be from 0 to 65535, not 70000"),
    ([], {"SHADOWMAP_RENDER_TIMEOUT": "1e9"}, "invalid setting: render_timeout: Input should be "
     "less than or equal to 604800"),
    (["--shutdown-timeout", "inf"], {}, "invalid setting: shutdown_timeout: Input should be a "
     "finite number"),
])
def test_serve_refuses_out_of_range_values_before_starting(args, env, message):
    """One line, exit 2, before any worker starts (1000 workers took this machine down, and a
    timeout past epoll's range failed every request)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "shadowmap", "serve", "--port", "1", *args],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, **env})
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


def test_serve_refuses_a_port_it_cannot_listen_on():
    from shadowmap.app.main import check_server

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}: Address already "
                           "in use"):
            check_server("127.0.0.1", port, 1)
    with pytest.raises(OSError, match="cannot listen on nohost.invalid:8000"):
        check_server("nohost.invalid", 8000, 1)
    check_server("127.0.0.1", 0, 1)


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parent = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(parent, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process tree from /proc")
def test_server_processes_end_with_a_killed_main_process(tmp_path):
    """``serve --workers 2`` with its main process SIGKILLed: its two server processes and their
    render workers end too (they kept serving, holding the port and their memory)."""
    import subprocess
    import sys

    from test_app import free_port

    port = free_port()
    with open(tmp_path / "serve.log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "shadowmap", "serve", "--port", str(port),
                                 "--workers", "2"], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    def serving() -> bool:
        try:
            up = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False
        # Two server processes, each with its render worker (and multiprocessing's tracker).
        return up and len([p for p in _descendants(proc.pid) if not process_gone(p)]) >= 4

    try:
        wait_for(serving, timeout=120, what="two server processes with their render workers")
        below = _descendants(proc.pid)
    finally:
        proc.kill()
        proc.wait(10)
    try:
        wait_for(lambda: all(process_gone(p) for p in below), timeout=60,
                 what="the server processes to end with their main process")
    finally:
        for p in below:
            if not process_gone(p):
                os.kill(p, signal.SIGKILL)
