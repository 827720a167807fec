"""What the service and the batch check about the machines they run on, before starting
anything there: how many worker processes this machine takes (``shadowmap serve --workers``, the
batch's local pool), and whether a Ray cluster answers at an address (``--ray ADDRESS``).

Given a ``HOST:PORT`` that nothing answers on, ``ray.init`` keeps trying to reach the cluster for
minutes before it gives up (each of its tries waits for the cluster's ID), and a malformed address
raises a bare ``ValueError`` from inside Ray. :func:`check_address` answers both in seconds, with
the address in the message. It opens one TCP connection; it does not import Ray.
"""

from __future__ import annotations

import os
import socket

__all__ = ["CONNECT_TIMEOUT", "MAX_SECONDS", "MAX_WORKERS_PER_CPU", "check_address",
           "check_seconds", "check_workers", "usable_cpus"]

#: The longest time limit the service's settings and the batch's ``timeout`` may give, a week:
#: the waits they set are in ``select``/``epoll`` and the event loop, which take at most 2**31 ms
#: (about 24.8 days) and fail past it (every render did).
MAX_SECONDS = 7 * 86400

#: Worker processes per CPU at most: each holds a GL context (and, for the service, a render
#: worker process besides), and on llvmpipe one render already uses every core. Asked for 1000,
#: ``serve`` had filled 15 of this machine's 24 GiB with over 200 processes, its main process
#: stuck past SIGTERM, when it was killed.
MAX_WORKERS_PER_CPU = 4

#: Seconds to wait for a cluster's port to accept a connection.
CONNECT_TIMEOUT = 10.0
#: Addresses Ray resolves itself (this machine's cluster): nothing to check.
LOCAL = ("auto", "local")


def check_address(address: str | None, timeout: float = CONNECT_TIMEOUT) -> None:
    """Refuse a Ray address that is malformed or that nothing answers on.

    Parameters
    ----------
    address : str or None
        ``None``, ``"auto"`` or ``"local"`` (this machine's cluster: not checked), ``HOST:PORT``
        (a cluster's GCS) or ``ray://HOST:PORT`` (Ray Client); IPv6 hosts in brackets.
    timeout : float
        Seconds the port may take to accept a connection.

    Raises
    ------
    RuntimeError
        The address is not one of those forms, or its port refused or did not accept a
        connection within ``timeout``.
    """
    if address is None or address in LOCAL:
        return
    target = address.removeprefix("ray://")
    host, sep, port = target.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RuntimeError(f"{address!r} is not a Ray cluster address: give auto, HOST:PORT (the "
                           "head's GCS port, 6379 by default) or ray://HOST:PORT (Ray Client, "
                           "10001 by default)")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except TimeoutError:
        raise RuntimeError(f"cannot reach the Ray cluster at {address}: no answer within "
                           f"{timeout:g} s") from None
    except OSError as exc:
        raise RuntimeError(f"cannot reach the Ray cluster at {address}: "
                           f"{exc.strerror or exc}") from None


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity, where the platform says)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def check_workers(workers: int, what: str = "workers") -> None:
    """Refuse a number of worker processes under 1 or over :data:`MAX_WORKERS_PER_CPU` per
    usable CPU.

    Raises
    ------
    ValueError
        Naming ``what`` (e.g. ``--workers``), the range and why.
    """
    most = MAX_WORKERS_PER_CPU * usable_cpus()
    if not 1 <= workers <= most:
        raise ValueError(f"{what} must be from 1 to {most} here ({MAX_WORKERS_PER_CPU} per "
                         f"CPU: each is a process with its own GL context), not {workers}")


def check_seconds(value: float, what: str) -> None:
    """Refuse a time limit that is not a number of seconds above 0 and at most
    :data:`MAX_SECONDS` (NaN, infinity, 0, negative).

    Raises
    ------
    ValueError
        Naming ``what`` (e.g. ``--timeout``).
    """
    if not 0 < value <= MAX_SECONDS:
        raise ValueError(f"{what} must be a number of seconds above 0 and at most {MAX_SECONDS} "
                         f"(a week), not {value}")
