"""Child processes of a deployment (the actuator emulator, the run logger): forked, deaf to Ctrl-C.

A Ctrl-C in a terminal signals the whole process group. The control loop turns it into a clean
stop (damping, motors off, the cause logged); its helpers must not die of it on the way, or the
stop would see silent motors and a torn log. So a child ignores SIGINT and SIGTERM, and the
signals are blocked around the fork, so none arrives before the child has set that up. A child
ends when its parent tells it to or goes away; a stuck one is killed (SIGKILL), see :func:`stop`.

Fork, not spawn: spawn would re-import the user's main script in the child (a script without an
``if __name__ == "__main__"`` guard would start a second run); nothing of the parent is used in
the child but the arguments.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections.abc import Callable
from typing import Any

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def start(target: Callable[..., Any], args: tuple[Any, ...], name: str) -> multiprocessing.process.BaseProcess:
    """Fork a daemon child running ``target(*args)`` with SIGINT and SIGTERM ignored."""
    process = multiprocessing.get_context("fork").Process(target=_deaf, args=(target, args), name=name, daemon=True)
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        process.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
    return process


def stop(process: multiprocessing.process.BaseProcess, timeout: float) -> None:
    """Wait ``timeout`` s for ``process`` to end, then kill it."""
    process.join(timeout)
    if process.is_alive():
        process.kill()
        process.join(1.0)


def _deaf(target: Callable[..., Any], args: tuple[Any, ...]) -> None:
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)  # what came meanwhile is discarded
    target(*args)


__all__ = ["STOP_SIGNALS", "start", "stop"]
