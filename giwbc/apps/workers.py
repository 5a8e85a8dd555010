"""Worker processes for evaluation sweeps, safe whatever threads this process already runs.

A pool forked from a process with other threads (Ray's client, a logger, a watchdog) can inherit a
lock held by one of them and hang forever. Workers here come from a forkserver — a clean,
single-threaded process started on first use — or are spawned where there is no forkserver.
Jobs and results must be picklable; each worker imports what it runs once.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.pool


def process_pool(processes: int) -> multiprocessing.pool.Pool:
    """A pool of ``processes`` workers started from a forkserver (or spawned), never forked from here."""
    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    return multiprocessing.get_context(method).Pool(int(processes))
