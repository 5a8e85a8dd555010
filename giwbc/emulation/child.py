"""What the emulators that run in a child process share: starting the child, its control pipe,
stopping it and bringing back its ground truth.

:class:`~giwbc.emulation.process.EmulatorProcess` (CAN, on giwbc-unix channels) and
:class:`~giwbc.emulation.dds_emulator.DdsEmulatorProcess` (DDS on loopback) differ in what runs in
the child and what it sends back; the parent's side of the child's life is this one class.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from giwbc.util import children


class ChildEmulator:
    """The parent's side of an emulator in a child process (module docstring).

    :meth:`_start` forks ``target(*args, pipe)`` and waits for its first message; the child ends
    with ``("done", payload)`` when told ``("stop", None)`` (handed to :meth:`_done`), or reports
    ``("error", traceback)``. :meth:`close` stops it, collects the payload, and releases what the
    subclass holds (:meth:`_release`). ``label`` names the child in errors."""

    label = "emulator process"

    def _start(self, target: Callable[..., None], args: tuple[Any, ...], name: str, start_timeout: float) -> Any:
        """Start the child (``args`` then its end of the pipe) and return the payload of its first
        message (closing it and raising RuntimeError when it failed to start)."""
        self.truth = np.zeros((0, 5))
        self.failure: str | None = None  # why the child did not end cleanly (after close())
        self._closed = False
        self._conn, child = multiprocessing.get_context("fork").Pipe()
        self._process = children.start(target, (*args, child), name)  # motors do not hear Ctrl-C (see children)
        child.close()
        try:
            kind, payload = self._receive(start_timeout, "start")
        except BaseException:
            self.close()
            raise
        if kind != "ready":
            self.close()
            raise RuntimeError(f"the {self.label} failed to start:\n{payload}")
        return payload

    @property
    def alive(self) -> bool:
        return self._process.is_alive()

    @property
    def pid(self) -> int | None:
        return self._process.pid

    def truth_between(self, start: float, stop: float = math.inf) -> np.ndarray:
        """Ground truth rows (time, base height, tilt rad, base x, base y) with ``start <= time < stop``, after :meth:`close`."""
        rows = self.truth
        return rows[(rows[:, 0] >= start) & (rows[:, 0] < stop)]

    def close(self, timeout: float = 10.0) -> None:
        """Stop the child, collect its results, release what it shared (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._process.is_alive():
                self._conn.send(("stop", None))
        except OSError:
            pass  # it is ending by itself (the host closed its side): its results may be in the pipe
        try:
            kind, payload = self._receive(timeout, "stop")
            if kind == "done":
                self._done(payload)
        except (RuntimeError, OSError, EOFError) as error:
            self.failure = str(error)  # a failed, dead or stuck child: terminated below
        finally:
            children.stop(self._process, timeout)
            self._conn.close()
            self._release()

    def _done(self, payload: Any) -> None:
        """The child's results (its ``done`` message)."""
        raise NotImplementedError

    def _release(self) -> None:
        """Release what the parent shares with the child (after it stopped)."""

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _send(self, message: tuple[str, Any]) -> None:
        if self._closed and message[0] != "stop":
            raise RuntimeError(f"the {self.label} is closed")
        self._conn.send(message)

    def _receive(self, timeout: float, what: str) -> tuple[str, Any]:
        """The child's next message within ``timeout`` s; RuntimeError when it died, stayed silent,
        closed its pipe or reported an error."""
        deadline = time.monotonic() + timeout
        while not self._conn.poll(0.05):
            if not self._process.is_alive():
                raise RuntimeError(f"the {self.label} died (exit code {self._process.exitcode}) before {what}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the {self.label} did not answer within {timeout:g} s ({what})")
        try:
            kind, payload = self._conn.recv()
        except EOFError:
            raise RuntimeError(f"the {self.label} closed its pipe before {what}") from None
        if kind == "error":
            raise RuntimeError(f"the {self.label} failed:\n{payload}")
        return kind, payload


__all__ = ["ChildEmulator"]
