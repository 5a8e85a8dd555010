"""Ray, imported only here and only when asked for: connecting to a cluster, and seeded jobs as Ray tasks.

``connect(None)`` starts a local Ray instance with this machine's CPUs (on 127.0.0.1, no dashboard,
no usage statistics); ``connect("host:6379")`` joins a cluster started with ``ray start --head``.
:class:`RayRunner` maps a module-level function over jobs as Ray tasks and returns the results in
job order, so a caller that sorts or aggregates them gets the same answer as on one machine. A task
whose worker process or node dies is retried (``max_retries``; every job here is a seeded, pure
function of its arguments, so a retry gives the same result); when retries run out the run fails
with :class:`~giwbc.errors.WorkerLostError` naming the job -- an episode is never dropped silently.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, TypeVar

from giwbc.errors import UnavailableError, WorkerLostError

J = TypeVar("J")
R = TypeVar("R")

LOCAL = "local"  # ``--ray`` without an address
INSTALL_HINT = "pip install 'giwbc[ray]'"


def require_ray() -> ModuleType:
    """The ``ray`` module, or a one-line :class:`UnavailableError` saying how to install it."""
    try:
        import ray
    except ImportError as error:
        raise UnavailableError(f"Ray is not installed ({error}): {INSTALL_HINT}") from None
    return ray


def system_failures(ray: ModuleType) -> tuple[type[BaseException], ...]:
    """Ray errors meaning a process, node or object was lost (not an exception raised by our own code)."""
    ex = ray.exceptions
    return (ex.WorkerCrashedError, ex.NodeDiedError, ex.RayActorError, ex.ObjectLostError, ex.LocalRayletDiedError,
            ex.OutOfMemoryError, ex.TaskCancelledError)


@dataclass
class Connection:
    """A connected Ray runtime; ``started`` if :func:`connect` started it (and :meth:`close` stops it)."""

    address: str
    started: bool
    ray: ModuleType = field(repr=False)

    @property
    def cpus(self) -> int:
        """CPUs of the whole cluster (all nodes that have joined so far)."""
        return int(self.ray.cluster_resources().get("CPU", 1))

    def close(self) -> None:
        if self.started and self.ray.is_initialized():
            self.ray.shutdown()

    def __enter__(self) -> "Connection":
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def connect(address: str | None = None, *, num_cpus: int | None = None, object_store_mb: int | None = None) -> Connection:
    """Join the Ray cluster at ``address``, or start a local instance (``None`` or ``"local"``).

    An already initialized Ray runtime in this process is reused as it is (whatever the address).
    ``num_cpus``: CPUs of a local instance (default: the machine's); ignored when joining a cluster.
    A local instance's workers keep the driver's niceness (Ray's default renices them by +15); on a
    cluster that is ``RAY_worker_niceness=0`` in the environment of ``ray start``.
    """
    ray = require_ray()
    if ray.is_initialized():
        return Connection(ray.get_runtime_context().gcs_address, False, ray)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # nothing leaves the machine on our behalf
    try:
        if address in (None, "", LOCAL):
            # Ray renices its workers by +15 (worker_niceness): on a busy machine our env actors and episode tasks
            # then get a fraction of the CPU share of the learner or of a fork pool's workers (measured: G1 steps up to
            # ~1.8x slower at load 20 on 2 vCPUs); the workers do the work here, so they run at the driver's niceness
            kwargs: dict[str, Any] = {"num_cpus": num_cpus, "_system_config": {"worker_niceness": 0}}
            if object_store_mb is not None:
                kwargs["object_store_memory"] = object_store_mb * 2**20
            ray.init(address=LOCAL, include_dashboard=False, _node_ip_address="127.0.0.1", **kwargs)
        else:
            ray.init(address=address)
    except (ConnectionError, ValueError, RuntimeError) as error:
        raise UnavailableError(f"cannot connect to the Ray cluster at {address!r}: {error}") from None
    return Connection(ray.get_runtime_context().gcs_address, True, ray)


@dataclass
class RayRunner:
    """Maps a function over independent jobs as Ray tasks (one CPU each), results in job order.

    ``max_retries``: how many times a job is re-run after its worker process or node died. A job
    raising an exception of its own is not retried: the exception reaches the caller as it is.
    """

    connection: Connection
    max_retries: int = 3

    @property
    def cpus(self) -> int:
        return self.connection.cpus

    def map(self, function: Callable[[J], R], jobs: Sequence[J], describe: Callable[[J], str] = repr) -> list[R]:
        """``[function(job) for job in jobs]``, run as Ray tasks; fails fast with :class:`WorkerLostError`."""
        ray = self.connection.ray
        remote = ray.remote(num_cpus=1, max_retries=self.max_retries, retry_exceptions=False)(function)
        refs = [remote.remote(job) for job in jobs]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[Any] = [None] * len(refs)
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                if pending:  # and whatever else has finished meanwhile: O(n) waits, not O(n^2), on a big sweep
                    more, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
                    done += more
                for ref in done:
                    try:
                        results[index[ref]] = ray.get(ref)
                    except system_failures(ray) as error:
                        raise WorkerLostError(
                            f"a Ray worker died running {getattr(function, '__name__', 'a job')}({describe(jobs[index[ref]])}) "
                            f"after {self.max_retries} retries: {type(error).__name__}: {first_line(error)}") from None
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
        return results


def first_line(error: BaseException) -> str:
    """The first non-empty line of an error's message (Ray's carry whole tracebacks)."""
    lines = [line for line in str(error).strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


# --- command line ------------------------------------------------------------------------------
def add_ray_argument(parser: argparse.ArgumentParser) -> None:
    """``--ray [ADDRESS]``: no address, a local Ray instance with this machine's CPUs; with one, that cluster."""
    parser.add_argument("--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
                        help="run on Ray (needs the ray extra): without ADDRESS a local instance with this machine's CPUs, "
                             "with one (host:port, or 'auto') the cluster started by `ray start --head`")
