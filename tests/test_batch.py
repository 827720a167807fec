"""``shadowmap batch`` on the local process pool: outputs, bad jobs, resume after SIGKILL, workers
that die or hang."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from batch_jobs import (
    BAD,
    SIZE,
    assert_same_as_single,
    check_batch,
    latest_records,
    manifest_entries,
    write_manifest,
)
from shadowmap.batch import render_many
from shadowmap.batch.manifest import SceneHasher, load_manifest, parse_job
from shadowmap.batch.results import write_job_files
from shadowmap.renderer import Limits

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def batch(tmp_path_factory, models):
    """The 200-job manifest rendered once with one local worker."""
    folder = tmp_path_factory.mktemp("batch")
    entries = manifest_entries(models, folder)
    manifest = write_manifest(folder / "jobs.jsonl", entries)
    out = folder / "out"
    report = render_many(manifest, out, workers=1)
    return entries, manifest, out, report


def test_every_good_job_is_rendered_and_bad_ones_are_recorded(batch):
    entries, _, out, report = batch
    assert len(entries) == 200
    counts = report.counts
    assert counts == {"ok": 200 - len(BAD), "error": len(BAD), "failed": 0}
    recs = check_batch(out, entries)
    multi = recs["job-004"]
    assert multi["variations"] == 3 and len([n for n in multi["outputs"]
                                             if n.endswith("meta.json")]) == 3
    # The views of a fit-"scene" job share one light pass: the second and third reuse it.
    assert multi["light_passes_cached"] == 2


def test_outputs_equal_single_renders(batch, renderer):
    entries, _, out, _ = batch
    by_id = {e["id"]: e for e in entries}
    # Every scene, every output set, views and light variations.
    for job_id in ("job-000", "job-001", "job-002", "job-003", "job-004", "job-005",
                   "job-006", "job-007", "job-014", "job-017", "job-123"):
        assert_same_as_single(renderer, out, by_id[job_id])


def test_meta_json(batch):
    _, _, out, _ = batch
    meta = json.loads((out / "job-004" / "view_001" / "meta.json").read_text())
    cam = meta["camera"]
    assert cam["width"] == SIZE["width"] and cam["height"] == SIZE["height"]
    assert cam["K"][0][2] == SIZE["width"] / 2 and cam["fx"] == cam["fy"] > 0
    pose = cam["camera_to_world"]
    assert pose[3] == [0, 0, 0, 1]
    assert [round(v, 9) for v in (pose[0][3], pose[1][3], pose[2][3])] == [
        round(v, 9) for v in meta["params"]["camera"]["eye"]]
    assert meta["lights"][0]["type"] == "directional"
    assert meta["plan"]["fit"] == "scene"
    assert {"load", "light", "camera", "total"} <= set(meta["timings"])
    assert isinstance(meta["warnings"], list)
    assert cam["projection"] == "perspective" and cam["yfov_deg"] == 45.0
    # An orthographic view: fx and fy are pixels per scene unit.
    ortho = json.loads((out / "job-014" / "view_002" / "meta.json").read_text())["camera"]
    assert ortho["projection"] == "orthographic" and ortho["ymag"] == 1.5
    assert ortho["fy"] == SIZE["height"] / 2 / 1.5 and "yfov_deg" not in ortho


def test_meta_json_describes_the_frame_drawn(batch):
    """Every view's meta.json gives the camera and lights the render resolved: its camera pose is
    the one the plan reports, also where the scene's own floor kept the ground out of an
    automatic framing (the demo scene with ``ground: true``)."""
    _, _, out, _ = batch
    metas = sorted(out.glob("job-*/**/meta.json"))
    assert len(metas) > 150
    own_floor = 0
    for path in metas:
        meta = json.loads(path.read_text())
        pose = meta["camera"]["camera_to_world"]
        eye = [pose[0][3], pose[1][3], pose[2][3]]
        planned = meta["plan"]["camera"]
        assert eye == pytest.approx(planned["eye"], rel=1e-12, abs=1e-12), path
        assert meta["camera"]["znear"] == pytest.approx(planned["znear"], rel=1e-12), path
        assert len(meta["lights"]) == len(meta["plan"]["lights"]), path
        own_floor += any("its own floor" in w for w in meta["warnings"]) and \
            "camera" not in meta["params"]
    assert own_floor > 0  # the case above is in the manifest


def test_rerun_skips_everything(batch):
    _, manifest, out, _ = batch
    before = (out / "results.jsonl").read_text()
    report = render_many(manifest, out, workers=1)
    assert report.skipped == 200 and report.records == []
    assert (out / "results.jsonl").read_text() == before


@pytest.mark.one_platform
def test_changed_inputs_are_rendered_again(tmp_path, models):
    entries = [{"id": "a", "scene": {"builtin": "demo"}, "params": SIZE},
               {"id": "b", "scene": str(models / "Duck.glb"), "params": SIZE}]
    out = tmp_path / "out"
    assert render_many(entries, out, workers=1).counts["ok"] == 2
    entries[0]["params"] = {**SIZE, "ambient": [0.5, 0.5, 0.5]}
    report = render_many(entries, out, workers=1)
    assert report.skipped == 1 and [r["id"] for r in report.records] == ["a"]
    hashes = [json.loads(line)["hash"] for line in (out / "results.jsonl").read_text().split()]
    assert len(hashes) == 3 and hashes[0] != hashes[2]


def test_manifest_errors_are_jobs(tmp_path):
    path = tmp_path / "m.jsonl"
    path.write_text('{"id": "x", "scene": {"builtin": "demo"}}\nnot json\n[1]\n\n# comment\n'
                    '{"id": "x", "scene": {"builtin": "demo"}}\n{"id": "../up", "scene": "a.glb"}\n'
                    '{"scene": {"builtin": "moon"}}\n'
                    '{"id": "y", "scene": {"builtin": "demo"},'
                    ' "params": {"width": 8, "width": 9}}\n')
    jobs = load_manifest(path)
    assert [j.id for j in jobs] == ["x", "line-2", "line-3", "x.line-6", "line-7", "line-8",
                                    "line-9"]
    assert jobs[0].error is None
    assert all(j.error is not None and j.error.code == "invalid_job" for j in jobs[1:])
    assert jobs[-1].error is not None and jobs[-1].error.detail == (
        "line 9: the key 'width' is given twice in one object (at params)")


@pytest.mark.one_platform
def test_sigkill_halfway_then_resume(tmp_path, models):
    """A batch killed with SIGKILL (driver and workers) resumes: the second run renders only the
    jobs without a record, and every job ends with exactly its one result."""
    entries = manifest_entries(models, tmp_path)
    manifest = write_manifest(tmp_path / "jobs.jsonl", entries)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "shadowmap", "batch", str(manifest), "--out",
                             str(out), "--workers", "1", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    results = out / "results.jsonl"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            if results.exists() and results.read_text().count("\n") >= 80:
                break
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            time.sleep(0.05)
        else:
            pytest.fail("the batch did not reach 80 records")
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(10)
    done_before = latest_records(out)
    assert 80 <= len(done_before) < 200
    report = render_many(manifest, out, workers=1)
    assert report.skipped == len(done_before)
    again = {r["id"] for r in report.records}
    assert again.isdisjoint(done_before) and again | set(done_before) == {e["id"] for e in entries}
    check_batch(out, entries)
    assert not (out / ".partial").exists()


@pytest.mark.one_platform
def test_dead_worker_is_replaced_and_its_job_retried(tmp_path, models):
    """A worker killed in the middle of a job: a new one takes its place, the job is rendered on
    the second try and the batch goes on."""
    entries = [{"id": f"j{i:02d}", "scene": {"builtin": "demo"},
                "params": {**SIZE, "outputs": ["color", "visibility"]}} for i in range(12)]
    killed: list[int] = []

    class KillOnce:
        def start(self, total: int, skipped: int) -> None:
            pass

        def update(self, record: dict) -> None:
            # The worker that sent this record is rendering the next job already.
            if record["id"] == "j03" and not killed:
                killed.append(record["worker"]["pid"])
                os.kill(record["worker"]["pid"], signal.SIGKILL)

    report = render_many(entries, tmp_path / "out", workers=1, progress=KillOnce())
    assert report.counts == {"ok": 12, "error": 0, "failed": 0}
    retried = [r for r in report.records if r["attempts"] == 2]
    assert len(retried) == 1 and retried[0]["worker"]["pid"] != killed[0]


@pytest.mark.one_platform
def test_hung_job_is_killed_retried_once_then_failed(tmp_path, software_gl):
    """Past ``timeout``, a job's worker is killed; the job is tried once more and then recorded
    as failed, and the jobs after it are rendered (3 s: a new worker's first job builds the demo
    scene, about 1.7 s here; the slow one takes about 9 s on llvmpipe: eight point lights, each
    pixel reading 81 packed texels per light)."""
    slow = {"width": 2896, "height": 2896, "outputs": ["color", "visibility"],
            "lights": [{"type": "point", "position": [-2.0 + 0.6 * i, 2.5, 1.0]}
                       for i in range(8)],
            "shadows": {"map_size": 512, "pcf_kernel": 9, "encoding": "rgba8"},
            "optimize": False}
    entries = [{"id": "quick-1", "scene": {"builtin": "demo"}, "params": SIZE},
               {"id": "slow", "scene": {"builtin": "demo"}, "params": slow},
               {"id": "quick-2", "scene": {"builtin": "demo"}, "params": SIZE}]
    report = render_many(entries, tmp_path / "out", workers=1, timeout=3.0)
    recs = {r["id"]: r for r in report.records}
    assert recs["slow"]["status"] == "failed" and recs["slow"]["error"]["error"] == "timeout"
    assert recs["slow"]["attempts"] == 2
    assert recs["quick-1"]["status"] == recs["quick-2"]["status"] == "ok"
    # A failed job is tried again by the next run (it may have been the machine, not the job).
    report = render_many(entries, tmp_path / "out", workers=1, timeout=3.0)
    assert report.skipped == 2 and [r["id"] for r in report.records] == ["slow"]


def test_cli(tmp_path):
    manifest = write_manifest(tmp_path / "m.jsonl", [
        {"id": "demo", "scene": {"builtin": "demo"},
         "params": {**SIZE, "outputs": ["color", "depth"]}},
        {"id": "bad", "scene": "missing.glb", "params": SIZE}])
    run = [sys.executable, "-m", "shadowmap", "batch", str(manifest), "--out",
           str(tmp_path / "out")]
    proc = subprocess.run(run, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "1 ok, 1 error, 0 failed" in proc.stdout
    assert "job/s" in proc.stderr  # tqdm's bar
    assert "error: bad: invalid_scene" in proc.stderr
    assert sorted(p.name for p in (tmp_path / "out" / "demo").iterdir()) == [
        "color.png", "depth.npy", "depth.png", "meta.json"]
    proc = subprocess.run(run + ["--quiet"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "2 already done" in proc.stdout
    assert "job/s" not in proc.stderr
    bad = subprocess.run([sys.executable, "-m", "shadowmap", "batch", str(tmp_path / "nope"),
                          "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert bad.returncode == 2 and "shadowmap: error:" in bad.stderr


@pytest.mark.one_platform
def test_renders_per_job_are_limited(tmp_path):
    """Views times light lists over ``max_job_renders`` is an error record, found before any
    variation is validated or rendered; the other jobs run."""
    views = [{"eye": [4, 3, 4 + k], "target": [0, 0, 0]} for k in range(3)]
    lights = [[{"type": "directional", "direction": [-1, -2, -1 - k]}] for k in range(2)]
    entries = [
        {"id": "six", "scene": {"builtin": "demo"}, "params": SIZE, "views": views,
         "lights": lights},
        # One more view, and an invalid one: the count is refused first.
        {"id": "eight", "scene": {"builtin": "demo"}, "params": SIZE,
         "views": views + [{"eye": "up"}], "lights": lights},
        {"id": "views", "scene": {"builtin": "demo"}, "params": SIZE, "views": views * 3},
    ]
    path = write_manifest(tmp_path / "m.jsonl", entries)
    jobs = {j.id: j for j in load_manifest(path, max_job_renders=6)}
    assert jobs["six"].error is None and len(jobs["six"].variations()) == 6
    for name, text in (("eight", "8 renders (4 views x 2 light lists)"),
                       ("views", "9 renders (9 views x 1 light lists)")):
        err = jobs[name].error
        assert err is not None and err.code == "limit_exceeded", name
        assert err.extra == {"limit": "max_job_renders"} and text in err.detail
        assert "over the limit of 6 per job" in err.detail
    assert load_manifest(path)[1].error.code == "invalid_params"  # under the default limit
    report = render_many(path, tmp_path / "out", workers=1, max_job_renders=6)
    recs = {r["id"]: r for r in report.records}
    assert recs["six"]["status"] == "ok" and recs["six"]["variations"] == 6
    assert recs["eight"]["status"] == recs["views"]["status"] == "error"
    assert recs["eight"]["error"]["limit"] == "max_job_renders"
    assert not (tmp_path / "out" / "eight").exists()
    run = [sys.executable, "-m", "shadowmap", "batch", str(path), "--out", str(tmp_path / "o"),
           "--quiet"]
    proc = subprocess.run(run + ["--max-job-renders", "8"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "1 ok, 2 error, 0 failed" in proc.stdout
    assert "error: views: limit_exceeded: the job asks for 9 renders" in proc.stderr
    assert "error: eight: invalid_params" in proc.stderr
    bad = subprocess.run(run + ["--max-job-renders", "0"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--max-job-renders must be at least 1" in bad.stderr


def test_entries_from_python(tmp_path, models):
    """Entries given from Python may hold what the library takes (numpy values, tuples, sets,
    paths) and hash as the same job written as JSON; what is not JSON data is an error record,
    and so is nesting too deep, in an entry or a manifest line, not an exception."""
    plain = {"id": "j", "scene": str(models / "Duck.glb"),
             "params": {"width": 32, "height": 24, "outputs": ["color", "depth"]},
             "views": [{"eye": [3.0, 2.0, 4.0], "target": [0, 0, 0]}]}
    numpy_ = {"id": "j", "scene": models / "Duck.glb",
              "params": {"width": np.int64(32), "height": 24, "outputs": {"depth", "color"}},
              "views": ({"eye": np.array([3.0, 2.0, 4.0]), "target": (0, 0, 0)},)}
    hasher = SceneHasher()
    jobs = [parse_job(e, tmp_path) for e in (plain, numpy_)]
    assert [j.error for j in jobs] == [None, None]
    assert hasher.hash_inputs(jobs[0]) == hasher.hash_inputs(jobs[1])
    assert jobs[1].params["outputs"] == ["color", "depth"] and jobs[1].views == plain["views"]
    deep: list = []
    inner = deep
    for _ in range(5000):
        inner.append([])
        inner = inner[0]
    for entry, text in (({**plain, "params": {"width": object()}},
                         "params must be JSON data (objects, lists, strings, numbers, booleans, "
                         "null): values of type object are not JSON data"),
                        ({**plain, "views": [{"eye": deep}]}, "views nests too deep"),
                        ({**plain, "scene": "a\0b.glb"}, "scene must be a path")):
        job = parse_job(entry, tmp_path)
        assert job.error is not None and job.error.code == "invalid_job"
        assert text in job.error.detail
        hasher.hash_inputs(job)  # an error job is hashed and recorded too
    path = tmp_path / "m.jsonl"
    path.write_text('{"id": "deep", "params": ' + "[" * 100_000 + "]" * 100_000 + "}\n")
    [job] = load_manifest(path)
    assert job.error is not None and job.error.detail == "line 1 is not JSON: it nests too deep"


def test_library_does_not_import_batch():
    """The library is imported by batch, never the other way round."""
    root = Path(__file__).resolve().parents[1] / "renderer"
    if not root.is_dir():
        pytest.skip("renderer/ is not beside the tests")
    for path in root.rglob("*.py"):
        text = path.read_text()
        assert "shadowmap.batch" not in text and "from ..batch" not in text, path


@pytest.mark.one_platform
def test_scene_files_that_are_no_regular_files_or_too_large_are_error_records(tmp_path, models):
    """A FIFO would block the batch's reading of it forever and /dev/zero would fill memory:
    each is an error record before anything is read, as is a file over the limits'
    ``max_request_bytes``; the other jobs run."""
    os.mkfifo(tmp_path / "pipe.glb")
    (tmp_path / "zero.glb").symlink_to("/dev/zero")
    (tmp_path / "Duck.glb").write_bytes((models / "Duck.glb").read_bytes())
    entries = [{"id": name, "scene": f"{name}.glb", "params": SIZE}
               for name in ("pipe", "zero", "Duck")]
    report = render_many(entries, tmp_path / "out", base_dir=tmp_path, workers=1)
    recs = {r["id"]: r for r in report.records}
    assert recs["Duck"]["status"] == "ok"
    # A scene's path is resolved: the link is named by what it links to.
    for name, path in (("pipe", "pipe.glb is a FIFO"), ("zero", "/dev/zero is a device")):
        assert recs[name]["status"] == "error", name
        assert recs[name]["error"]["error"] == "invalid_scene"
        assert f"{path}, not a regular file" in recs[name]["error"]["detail"]
    # A file of 1.1 MB against a limit of 0.5 MB, which the request itself stays within.
    (tmp_path / "big.glb").write_bytes((models / "Duck.glb").read_bytes() + bytes(10**6))
    report = render_many([{"id": "big", "scene": "big.glb", "params": SIZE}], tmp_path / "small",
                         base_dir=tmp_path, workers=1, limits=Limits(max_request_bytes=500_000))
    (rec,) = report.records
    assert rec["status"] == "error" and rec["error"]["limit"] == "max_request_bytes"
    assert "over the 500000 this request may read" in rec["error"]["detail"]


@pytest.mark.one_platform
def test_manifest_bytes_a_text_reader_would_stop_at(tmp_path):
    """A byte order mark (as some editors write) and CRLF line ends are read; a line that is not
    UTF-8, or longer than ``max_line_bytes``, is an error record and the next lines are read;
    before, the first raised UnicodeDecodeError out of the batch and a BOM made line 1 an
    error."""
    job = json.dumps({"id": "demo", "scene": {"builtin": "demo"}, "params": SIZE}).encode()
    path = tmp_path / "m.jsonl"
    path.write_bytes(b"\xef\xbb\xbf" + job + b"\r\n\xff\xfe not text\r\n" + b"x" * 5000 + b"\r\n"
                     + job.replace(b'"demo",', b'"last",', 1) + b"\r\n")
    jobs = load_manifest(path, max_line_bytes=1000)
    assert [(j.id, j.error.code if j.error else None) for j in jobs] == [
        ("demo", None), ("line-2", "invalid_job"), ("line-3", "limit_exceeded"), ("last", None)]
    assert jobs[1].error.detail == "line 2 is not UTF-8 text (byte 1)"
    assert jobs[2].error.extra == {"limit": "max_line_bytes"}
    assert "line 3 is over 1000 bytes" in jobs[2].error.detail
    assert load_manifest(path, max_line_bytes=5002)[2].error.code == "invalid_job"  # not JSON
    run = [sys.executable, "-m", "shadowmap", "batch", str(path), "--out", str(tmp_path / "o"),
           "--quiet", "--max-line-bytes", "1000"]
    proc = subprocess.run(run, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "2 ok, 2 error, 0 failed" in proc.stdout
    assert "error: line-3: limit_exceeded: line 3 is over 1000 bytes" in proc.stderr


def test_job_files_stay_in_the_job_folder(tmp_path):
    files = {"view_001/color.png": b"png", "meta.json": b"{}", "view_001/depth.npy": b"npy"}
    assert write_job_files(tmp_path, "job", files) == sorted(files)
    assert (tmp_path / "job" / "view_001" / "color.png").read_bytes() == b"png"
    assert (tmp_path / "job" / "meta.json").read_bytes() == b"{}"
    for bad in ("../escape.png", "/tmp/abs.png", "view/../../up.png", "", "a\\..\\b.png"):
        with pytest.raises(ValueError, match="leaves the job's folder"):
            write_job_files(tmp_path, "other", {"meta.json": b"{}", bad: b"x"})
        # Refused before anything is written: no job folder, nothing outside it.
        assert not (tmp_path / "other").exists()
        assert not (tmp_path / "escape.png").exists() and not (tmp_path.parent / "up.png").exists()
