"""Worker processes for evaluation sweeps, safe whatever threads this process already runs.

A pool forked from a process with other threads (Ray's client, a logger, a watchdog) can inherit a
lock held by one of them and hang forever. Workers here come from a forkserver — a clean,
single-threaded process started on first use — or are spawned where there is no forkserver.
Jobs and results must be picklable; each worker imports what it runs once.

:func:`map_jobs` runs jobs on such a pool and, for a progress bar, reports the units (episodes) each
worker finishes as they finish, not when its whole job returns. :func:`quiet_banners` keeps
third-party start-up banners printed by C libraries (PyBullet's "build time") out of a command's output.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.pool
import os
import queue as queue_module
import re
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

J = TypeVar("J")
R = TypeVar("R")

# Lines C libraries print to stdout/stderr when they start, dropped from a command's output.
BANNERS = re.compile(rb"^pybullet build time: .*$\n?", re.MULTILINE)
_POLL_S = 0.1  # how often the parent looks for finished units while the pool works


def _context() -> multiprocessing.context.BaseContext:
    return multiprocessing.get_context("forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn")


def process_pool(processes: int) -> multiprocessing.pool.Pool:
    """A pool of ``processes`` workers started from a forkserver (or spawned), never forked from here."""
    return _context().Pool(int(processes))


def _call_ticking(packed: tuple[Callable[..., Any], Any, Any]) -> Any:
    """In a worker: ``function(job, tick)`` with ``tick(n)`` telling the parent ``n`` more units are done."""
    function, job, done = packed
    return function(job, done.put)


def map_jobs(function: Callable[..., R], jobs: Sequence[J], workers: int,
             advance: Callable[[int], None] | None = None) -> list[R]:
    """``[function(job) for job in jobs]`` in order, on ``workers`` processes (0: in this process).

    With ``advance``, ``function`` is called as ``function(job, tick)`` and each ``tick(n)`` it makes
    reaches ``advance(n)`` in this process while the pool works (through a manager queue), so a
    progress bar moves as episodes finish. Results do not depend on ``advance``.
    """
    if workers <= 0:
        if advance is None:
            return [function(job) for job in jobs]
        return [function(job, advance) for job in jobs]
    with process_pool(min(workers, max(1, len(jobs)))) as pool:
        if advance is None:
            return pool.map(function, jobs)
        with _context().Manager() as manager:
            done = manager.Queue()
            pending = pool.map_async(_call_ticking, [(function, job, done) for job in jobs])
            while not pending.ready():
                try:
                    advance(done.get(timeout=_POLL_S))
                except queue_module.Empty:
                    pass
            while True:  # every tick was put before its job returned: drain what is left
                try:
                    advance(done.get_nowait())
                except queue_module.Empty:
                    break
            return pending.get()


@contextlib.contextmanager
def quiet_banners(fd: int = 2) -> Iterator[None]:
    """Drop C-level start-up banners (:data:`BANNERS`) written to ``fd`` inside the block; anything
    else written there (warnings, errors) is passed on when the block ends."""
    stream = sys.stderr if fd == 2 else sys.stdout
    with contextlib.suppress(AttributeError, ValueError):
        stream.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), fd)
        try:
            yield
        finally:
            with contextlib.suppress(AttributeError, ValueError):
                stream.flush()
            os.dup2(saved, fd)
            os.close(saved)
            capture.seek(0)
            rest = BANNERS.sub(b"", capture.read())
            if rest:
                os.write(fd, rest)
