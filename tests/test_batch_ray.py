"""The Ray backend and Ray Serve on a local cluster (``ray.init(num_cpus=2)``, once for the
module): the 200-job manifest, a killed actor, and the HTTP service's answers."""

from __future__ import annotations

import io
import json
import os
import signal

import numpy as np
import pytest

from batch_jobs import BAD, assert_same_as_single, check_batch, manifest_entries, write_manifest

ray = pytest.importorskip("ray", reason="the ray extra is not installed")

from shadowmap.batch import render_many  # noqa: E402
from shadowmap.batch.ray import RayBackend  # noqa: E402

# Ray's actors hold the same Renderer as the local pool's workers, which test_batch runs on
# both platforms.
pytestmark = [pytest.mark.gl, pytest.mark.one_platform]


@pytest.fixture(scope="module")
def cluster():
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=256 * 2**20,
             log_to_driver=False, configure_logging=False)
    try:
        yield
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def manifest(cluster, tmp_path_factory, models):
    folder = tmp_path_factory.mktemp("ray-batch")
    entries = manifest_entries(models, folder)
    return entries, write_manifest(folder / "jobs.jsonl", entries), folder


def test_ray_batch_equals_single_renders(manifest, renderer):
    entries, path, folder = manifest
    out = folder / "out"
    with RayBackend(actors=2) as backend:
        report = render_many(path, out, backend=backend)
        assert len({r["worker"]["pid"] for r in report.records if "worker" in r}) == 2
        # Each distinct scene went to the object store once: the demo, 4 models and the
        # truncated file (read like any other; its parse fails in the actor).
        assert backend.scene_puts == 6
    assert report.backend == "ray"
    assert report.counts == {"ok": 200 - len(BAD), "error": len(BAD), "failed": 0}
    check_batch(out, entries)
    by_id = {e["id"]: e for e in entries}
    for job_id in ("job-000", "job-001", "job-002", "job-004", "job-007", "job-011"):
        assert_same_as_single(renderer, out, by_id[job_id])
    assert render_many(path, out, ray="auto").skipped == 200  # resume, through render_many's own


def test_killed_actor_is_replaced_and_its_job_retried(cluster, tmp_path):
    entries = [{"id": f"j{i:02d}", "scene": {"builtin": "demo"},
                "params": {"width": 96, "height": 72, "outputs": ["color", "depth"]}}
               for i in range(24)]
    killed: list[int] = []

    class KillOnce:
        def start(self, total: int, skipped: int) -> None:
            pass

        def update(self, record: dict) -> None:
            if len(killed) == 0 and record["id"] >= "j04":
                killed.append(record["worker"]["pid"])
                os.kill(record["worker"]["pid"], signal.SIGKILL)

    with RayBackend(actors=2) as backend:
        report = render_many(entries, tmp_path / "out", backend=backend, progress=KillOnce())
        assert backend.replaced == 1
        pids = {i["pid"] for i in backend.identities()}
    assert report.counts == {"ok": 24, "error": 0, "failed": 0}
    assert killed[0] not in pids and len(pids) == 2
    retried = [r for r in report.records if r["attempts"] == 2]
    assert len(retried) == 1 and retried[0]["worker"]["pid"] in pids


# ------------------------------------------------------------------------------------------------
# Ray Serve: the same answers as the plain service
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def served(cluster, models):
    """The service on Ray Serve (2 replicas) and the plain service, with the same settings."""
    from shadowmap.app import ray_serve
    from test_app import MAIN_ENV, ServerProcess, free_port

    httpx = pytest.importorskip("httpx")
    plain = ServerProcess(MAIN_ENV)
    port = free_port()
    saved = dict(os.environ)
    os.environ.update(MAIN_ENV)
    try:
        ray_serve.deploy("127.0.0.1", port, replicas=2, num_cpus=0.5)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    try:
        plain.wait_ready()
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60) as rs, \
                httpx.Client(base_url=plain.url, timeout=60) as pl:
            yield rs, pl
    finally:
        plain.stop()
        from ray import serve

        serve.shutdown()


def _requests(models):
    duck = (models / "Duck.glb").read_bytes()
    small = {"width": 160, "height": 120}
    files = {"scene": ("Duck.glb", duck, "application/octet-stream")}
    return [
        ("get", "/healthz", {}),
        ("get", "/nope", {}),
        ("post", "/render", {}),
        ("post", "/render", {"files": files, "data": {"params": json.dumps({**small,
                                                                            "ground": True})}}),
        ("post", "/render", {"files": files, "data": {"params": json.dumps(
            {**small, "outputs": ["color", "depth"]})},
            "headers": {"Accept": "application/json"}}),
        ("post", "/render", {"files": {"scene": ("Duck.glb", duck[:5000], "x/y")}}),
        ("post", "/render", {"content": '{"widht": 100}',
                             "headers": {"Content-Type": "application/json"}}),
        ("post", "/render", {"content": json.dumps({"width": 2048, "height": 1024}),
                             "headers": {"Content-Type": "application/json"}}),
        ("post", "/render", {"content": b"hello", "headers": {"Content-Type": "text/plain"}}),
    ]


def test_ray_serve_answers_like_the_plain_service(served, models):
    from PIL import Image

    rs, pl = served
    for method, url, kwargs in _requests(models):
        a, b = getattr(rs, method)(url, **kwargs), getattr(pl, method)(url, **kwargs)
        assert a.status_code == b.status_code, (url, a.text[:300], b.text[:300])
        kind = a.headers["content-type"]
        assert kind == b.headers["content-type"]
        if kind == "image/png":
            assert np.array_equal(np.asarray(Image.open(io.BytesIO(a.content))),
                                  np.asarray(Image.open(io.BytesIO(b.content))))
            assert a.headers["x-render-plan"] == b.headers["x-render-plan"]
        elif a.status_code >= 400:
            ea, eb = a.json(), b.json()
            assert ea["error"] == eb["error"] and ea.get("limit") == eb.get("limit"), (ea, eb)
        elif url == "/render":
            ja, jb = a.json(), b.json()
            assert ja["outputs"] == jb["outputs"] and ja["warnings"] == jb["warnings"]
    # Both replicas answer (each has its own render worker process).
    workers = {rs.get("/healthz").json()["worker"]["pid"] for _ in range(20)}
    assert len(workers) == 2
