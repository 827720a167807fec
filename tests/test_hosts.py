"""What is checked about the machine before anything starts: worker process counts (the
service's and the batch's local pool), and ``--ray ADDRESS`` (a malformed address, or one nothing
answers on, fails in seconds with the address in the message, where ``ray.init`` would retry for
minutes). Needs no Ray for the checks; the command-line cases need the ray extra."""

from __future__ import annotations

import re
import socket
import subprocess
import sys

import pytest

from shadowmap.hosts import (
    MAX_SECONDS,
    MAX_WORKERS_PER_CPU,
    check_address,
    check_seconds,
    check_workers,
    usable_cpus,
)


def _closed_port() -> int:
    """A localhost port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("address", [None, "auto", "local"])
def test_this_machines_cluster_is_not_checked(address):
    check_address(address, timeout=0.01)


@pytest.mark.parametrize("address", ["garbage", "head", "head:", ":6379", "head:port",
                                     "head:0", "head:70000", "ray://", "ray://head"])
def test_malformed_addresses(address):
    with pytest.raises(RuntimeError, match=f"^{address!r} is not a Ray cluster address: give "
                       "auto, HOST:PORT"):
        check_address(address)


def test_a_port_that_refuses_or_a_host_that_does_not_resolve():
    port = _closed_port()
    for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}", f"[::1]:{port}"):
        with pytest.raises(RuntimeError,
                           match=f"^cannot reach the Ray cluster at {re.escape(address)}: "):
            check_address(address)
    with pytest.raises(RuntimeError, match="cannot reach the Ray cluster at nohost.invalid:6379"):
        check_address("nohost.invalid:6379")


def test_a_listening_port_passes():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        check_address(f"127.0.0.1:{port}")
        check_address(f"ray://localhost:{port}")


@pytest.mark.parametrize("command", [["batch", "{manifest}", "--out", "{out}"], ["serve"]])
def test_command_line_fails_fast(tmp_path, command):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    manifest = tmp_path / "m.jsonl"
    manifest.write_text('{"id": "d", "scene": {"builtin": "demo"}}\n')
    args = [a.format(manifest=manifest, out=tmp_path / "o") for a in command]
    address = f"127.0.0.1:{_closed_port()}"
    proc = subprocess.run([sys.executable, "-m", "shadowmap", *args, "--ray", address],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("shadowmap: error: ") and f"cannot reach the Ray cluster at {address}" \
        in last, proc.stderr
    assert not (tmp_path / "o" / "d").exists()


def test_worker_counts():
    most = MAX_WORKERS_PER_CPU * usable_cpus()
    for ok in (1, most):
        check_workers(ok)
    for bad in (0, -1, most + 1):
        with pytest.raises(ValueError, match=f"^--workers must be from 1 to {most} here "
                           rf"\({MAX_WORKERS_PER_CPU} per CPU: each is a process with its own GL "
                           rf"context\), not {bad}$"):
            check_workers(bad, "--workers")


def test_batch_refuses_more_local_workers_than_the_machine_takes(tmp_path):
    from shadowmap.batch import LocalPool

    most = MAX_WORKERS_PER_CPU * usable_cpus()
    with pytest.raises(ValueError, match="workers must be from 1 to"):
        LocalPool(most + 1)
    manifest = tmp_path / "m.jsonl"
    manifest.write_text('{"id": "d", "scene": {"builtin": "demo"}}\n')
    proc = subprocess.run([sys.executable, "-m", "shadowmap", "batch", str(manifest), "--out",
                           str(tmp_path / "o"), "--workers", str(most + 1)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"shadowmap: error: --workers must be from 1 to {most} here "
                                   f"({MAX_WORKERS_PER_CPU} per CPU: each is a process with its "
                                   f"own GL context), not {most + 1}"), proc.stderr


def test_time_limits(tmp_path):
    """A batch's timeout is seconds above 0 and at most a week: 1e12 ended in an OverflowError
    traceback, and -1, 0 and NaN were taken (every job then failed, or none could)."""
    from shadowmap.batch import render_many

    for ok in (0.001, 30, MAX_SECONDS):
        check_seconds(ok, "--timeout")
    for bad in (0, -1, float("nan"), float("inf"), MAX_SECONDS + 1, 1e12):
        with pytest.raises(ValueError, match=f"^--timeout must be a number of seconds above 0 "
                           f"and at most {MAX_SECONDS} \\(a week\\), not "):
            check_seconds(bad, "--timeout")
    with pytest.raises(ValueError, match="^timeout must be"):
        render_many(tmp_path / "missing.jsonl", tmp_path / "o", timeout=-1)
    assert not (tmp_path / "o").exists()
    manifest = tmp_path / "m.jsonl"
    manifest.write_text('{"id": "d", "scene": {"builtin": "demo"}}\n')
    proc = subprocess.run([sys.executable, "-m", "shadowmap", "batch", str(manifest), "--out",
                           str(tmp_path / "o"), "--timeout", "1e12"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip() == (
        f"shadowmap: error: --timeout must be a number of seconds above 0 and at most "
        f"{MAX_SECONDS} (a week), not 1000000000000.0"), proc.stderr
