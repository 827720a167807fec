"""``scripts/gpu-check``: its steps, their summary and where its results go."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The container's test stage holds the tests and the installed package, not scripts/ or bench/.
pytestmark = pytest.mark.skipif(
    not (ROOT / "scripts" / "gpu-check").is_file() or not (ROOT / "bench").is_dir(),
    reason="no scripts/ and bench/ beside the tests (the container)")


@pytest.mark.gl
def test_device_step_names_the_renderer_and_only_chosen_steps_run(tmp_path):
    out = tmp_path / "results"
    env = {**os.environ, "PYTHON": sys.executable, "GPU_CHECK_STEPS": "device"}
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu-check"), str(out)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = (out / "summary.txt").read_text().splitlines()
    assert [line.split()[:2] for line in summary] == [["device", "ok"]]
    log = (out / "device.log").read_text()
    assert "'platform': 'egl'" in log and "'renderer': " in log, log
    assert summary[0] in proc.stdout


def test_a_failing_step_is_recorded_and_the_next_one_runs(tmp_path):
    out = tmp_path / "results"
    # A Python that fails every step: each is recorded with its exit status, none stops the run.
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho broken >&2\nexit 3\n")
    fake.chmod(0o755)
    env = {**os.environ, "PYTHON": str(fake), "GPU_CHECK_STEPS": "device floor"}
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu-check"), str(out)], env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    summary = [line.split(None, 1) for line in (out / "summary.txt").read_text().splitlines()]
    assert [(name, rest.split("  ")[0]) for name, rest in summary] == [
        ("device", "failed (exit 3)"), ("floor", "failed (exit 3)")]
    assert (out / "floor.log").read_text() == "broken\n"


def test_benchmarks_write_where_the_setting_says(tmp_path):
    """SHADOWMAP_BENCH_RESULTS moves every benchmark's output folder (smoke runs to its quick/)."""
    code = ("from bench._common import results_dir; "
            "print(results_dir()); print(results_dir(quick=True))")
    env = {**os.environ, "SHADOWMAP_BENCH_RESULTS": str(tmp_path / "gpu"),
           "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == [str(tmp_path / "gpu"), str(tmp_path / "gpu" / "quick")]
    assert (tmp_path / "gpu" / "quick").is_dir()
    env.pop("SHADOWMAP_BENCH_RESULTS")
    code = "from bench._common import results_dir; print(results_dir())"  # exists already
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.stdout.split()[0] == str(ROOT / "bench" / "results")
