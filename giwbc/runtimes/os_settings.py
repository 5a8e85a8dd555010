"""Process and thread settings of the real-time loop: ``SCHED_FIFO`` for the loop's thread while
the motors are on, and the garbage collector's state, both restored at the end
(:class:`ProcessSettings`, a mixin of :class:`~giwbc.runtimes.realtime.RealtimeRuntime`, whose
docstring explains ``rt_priority``, ``freeze_gc`` and ``gc_every``)."""

from __future__ import annotations

import gc
import os
from typing import Any


class ProcessSettings:
    """Raise and restore the loop thread's scheduling and the garbage collector (see the module
    docstring). Expects the runtime's ``rt_priority``, ``scheduler``, ``_schedulers``,
    ``_gc_was_enabled``, ``_gc_frozen`` attributes and its ``_event`` method (the run log's events)."""

    rt_priority: int | None
    scheduler: str
    _schedulers: list[tuple[int, tuple[int, Any]]]
    _gc_was_enabled: bool | None
    _gc_frozen: bool

    def _restore_process_state(self) -> None:
        """The garbage collector as it was before the motors started."""
        if self._gc_was_enabled is not None:
            if self._gc_was_enabled:
                gc.enable()
            self._gc_was_enabled = None
        if self._gc_frozen:
            gc.unfreeze()
            self._gc_frozen = False

    def _raise_priority(self) -> None:
        """``SCHED_FIFO`` for the loop's thread (the run log is written by a process of its own,
        at normal priority)."""
        if self.rt_priority is None or not hasattr(os, "sched_setscheduler"):
            return
        detail: dict[str, Any] = {"policy": "SCHED_FIFO", "priority": self.rt_priority}
        try:
            previous = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            self._schedulers.append((0, previous))
            self.scheduler = f"SCHED_FIFO {self.rt_priority}"
        except OSError as error:
            detail = {"refused": str(error)}
            self.scheduler = f"default (SCHED_FIFO {self.rt_priority} refused: {error})"
            self._restore_priority()
        self._event("scheduler", detail)

    def _restore_priority(self) -> None:
        while self._schedulers:
            tid, (policy, param) = self._schedulers.pop()
            try:
                os.sched_setscheduler(tid, policy, param)
            except OSError:
                pass


__all__ = ["ProcessSettings"]
