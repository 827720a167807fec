"""The same HTTP service, replicated on Ray Serve: ``shadowmap serve --ray [--replicas N]``.

Each replica is a Ray actor that builds the app with :func:`shadowmap.app.main.create_app` (the
factory ``shadowmap serve`` uses) and runs its lifespan, so it has its own render worker process
(its own GL context), queue, limits and error handling; Ray Serve's HTTP proxy spreads requests
over the replicas. Routes, limits (``SHADOWMAP_*`` settings, passed to every replica) and error
bodies are those of the plain service. The proxy, not uvicorn, holds the connections, so
``keep_alive_timeout``, ``limit_concurrency``, ``send_timeout`` and the request-head deadline of
``shadowmap serve`` do not apply; Ray Serve's own HTTP options do.

On a cluster with GPUs each replica asks for one GPU and renders on that EGL device.
``ray`` is imported when this runs (the ``ray`` extra).
"""

from __future__ import annotations

import os
import time
from typing import Any

from fastapi import FastAPI

from shadowmap.hosts import check_address

from .settings import Settings

APP_NAME = "shadowmap"
#: Environment variables every replica gets from the process that deploys it: the service's
#: settings and the GL platform choice.
_ENV_PREFIXES = ("SHADOWMAP_", "PYOPENGL_PLATFORM", "LP_NUM_THREADS")


def build_app() -> FastAPI:
    """The app of one replica (called by Ray Serve in the replica's process)."""
    import ray

    gpus = ray.get_gpu_ids()
    if gpus:  # the GPU Ray gave this replica; its render worker inherits the variable
        os.environ["SHADOWMAP_EGL_DEVICE"] = str(int(gpus[0]))
    from .main import create_app

    return create_app()


def replica_env(overrides: dict[str, Any] | None = None) -> dict[str, str]:
    """The variables given to each replica: this process's ``SHADOWMAP_*`` (and GL platform)
    settings, with ``overrides`` (setting name -> value) on top.

    Raises
    ------
    TypeError
        An override that is not a setting.
    pydantic.ValidationError
        A setting out of range (checked here, before anything is deployed).
    """
    env = {k: v for k, v in os.environ.items() if k.startswith(_ENV_PREFIXES)}
    for name, value in (overrides or {}).items():
        if name not in Settings.model_fields:
            raise TypeError(f"unknown setting {name!r}")
        if value is not None:
            env[f"SHADOWMAP_{name.upper()}"] = str(value)
    saved = dict(os.environ)
    try:
        os.environ.update(env)
        Settings()  # validates every setting as the replicas will read them
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return env


def application(replicas: int = 1, *, num_cpus: float = 1.0, num_gpus: float | None = None,
                env: dict[str, str] | None = None) -> Any:
    """The Ray Serve application: ``replicas`` copies of the service.

    Parameters
    ----------
    replicas : int
    num_cpus : float
        CPUs each replica asks Ray for.
    num_gpus : float, optional
        Default: 1 when the cluster has GPUs, else 0.
    env : dict, optional
        Variables for the replicas (:func:`replica_env`).
    """
    import ray
    from ray import serve

    if num_gpus is None:
        num_gpus = 1.0 if ray.is_initialized() and ray.cluster_resources().get("GPU", 0) else 0.0
    options: dict[str, Any] = {"num_cpus": num_cpus, "num_gpus": num_gpus}
    if env:
        options["runtime_env"] = {"env_vars": env}
    deployment: Any = serve.deployment(
        serve.ingress(build_app)(), name=APP_NAME, num_replicas=replicas,
        ray_actor_options=options,
        # A replica starts a render worker and renders the demo scene before it is ready.
        health_check_timeout_s=60.0)
    return deployment.bind()


def deploy(host: str = "127.0.0.1", port: int = 8000, replicas: int = 1, *,
           address: str | None = None, num_cpus: float = 1.0, num_gpus: float | None = None,
           **overrides: Any) -> None:
    """Start (or join) Ray, start Serve's proxy on ``host:port`` and deploy the service.

    Returns once every replica is ready. ``address``: as ``ray.init`` (None: this machine's
    cluster, or a new local one).

    Raises
    ------
    RuntimeError
        The cluster at ``address`` cannot be reached or joined
        (:func:`shadowmap.hosts.check_address`).
    """
    import ray
    from ray import serve

    env = replica_env(overrides)
    if not ray.is_initialized():
        check_address(address)  # in seconds, where ray.init would retry for minutes
        try:
            ray.init(address=address)
        except (ConnectionError, ValueError) as exc:  # something else answers there
            raise RuntimeError(f"cannot join the Ray cluster at {address}: {exc}") from None
    serve.start(http_options={"host": host, "port": port})
    serve.run(application(replicas, num_cpus=num_cpus, num_gpus=num_gpus, env=env),
              name=APP_NAME, route_prefix="/")


def run(host: str = "127.0.0.1", port: int = 8000, replicas: int = 1, *,
        address: str | None = None, **overrides: Any) -> None:
    """:func:`deploy`, then serve until Ctrl-C or SIGTERM; then remove the deployment (and stop
    the local Ray instance when this process started it)."""
    import signal

    from ray import serve

    def stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt  # SIGTERM (systemd, docker stop) ends it like Ctrl-C

    import ray

    started = not ray.is_initialized() and address is None
    deploy(host, port, replicas, address=address, **overrides)
    signal.signal(signal.SIGTERM, stop)  # after ray.init, which installs its own handler
    print(f"shadowmap: serving on http://{host}:{port} with {replicas} Ray Serve "
          f"replica{'s' if replicas != 1 else ''} (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        serve.delete(APP_NAME)
        if started:  # this process started the local Ray instance: stop it whole
            import ray

            serve.shutdown()
            ray.shutdown()
