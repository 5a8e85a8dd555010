"""Process and thread settings of the real-time loop: ``SCHED_FIFO`` for the loop's thread while
the motors are on, the CPUs' wake-up latency (a Linux PM QoS request), and the garbage
collector's state, all restored at the end (:class:`ProcessSettings`, a mixin of
:class:`~giwbc.runtimes.realtime.RealtimeRuntime`, whose docstring explains ``rt_priority``,
``cpu_latency``, ``freeze_gc`` and ``gc_every``).

The wake-up latency: between cycles the loop sleeps, and an idle CPU enters an idle state
whose exit costs time and, on a virtual machine, gives the physical core to other guests (its
caches come back cold). Writing a latency bound to ``/dev/cpu_dma_latency`` asks the kernel's
idle governor to keep every CPU in states that wake within it (0: polling) for as long as the
file stays open, as ``cyclictest`` does; the request ends when it is closed (at the end of the
run, or when the process dies). Measured on a 2-vCPU KVM guest, deploy loop at 500 Hz
(``benchmarks/deploy_loop.py --cpu-latency 0 -1``), walking, 9 pairs of alternated runs: the
median host work per cycle lower in 7 (by 14 % at the median of the pairs), its p99 in 6 (by 9 %).

``SCHED_FIFO`` asked for and refused is an error, not a warning: :func:`probe_rt_priority` tries
the priority (and restores the thread's scheduling) before any bus is opened, so that a run asked
to be real-time never drives motors without it (``giwbc deploy --rt-priority`` exits 2 naming the
fix). A refusal inside the runtime itself (the probe passed, the kernel changed its mind) is
still logged and the run goes on: the motors are on by then, and stopping is no safer."""

from __future__ import annotations

import gc
import math
import os
import struct
from typing import Any

CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"  # Linux PM QoS: the CPUs' wake-up latency bound, µs (int32)
MAX_CPU_LATENCY_US = 2_000_000_000  # the kernel's own default bound (no request), the most an int32 request may ask
RT_PRIORITY_RANGE = (1, 99)  # Linux SCHED_FIFO priorities (sched_get_priority_min/max)


def check_rt_priority(value: int | None) -> int | None:
    """``value`` when it is a ``SCHED_FIFO`` priority (1 to 99), None for none; ``ValueError`` otherwise."""
    if value is None:
        return None
    low, high = RT_PRIORITY_RANGE
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"rt_priority must be a SCHED_FIFO priority from {low} to {high} (or None), got {value!r}")
    return value


def probe_rt_priority(value: int) -> str | None:
    """Whether the kernel grants this thread ``SCHED_FIFO`` at ``value``: None when it does (the
    thread's scheduling is restored at once), else why not, with the usual fixes."""
    if not hasattr(os, "sched_setscheduler"):
        return "this platform has no SCHED_FIFO (Linux only)"
    try:
        previous = (os.sched_getscheduler(0), os.sched_getparam(0))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(value))
    except OSError as error:
        return (f"the kernel refused SCHED_FIFO priority {value} ({error.strerror or error}): run as root, give the "
                "interpreter CAP_SYS_NICE (setcap cap_sys_nice+ep), or raise the user's rtprio limit (ulimit -r, "
                "/etc/security/limits.conf); or leave --rt-priority out to run on the default scheduler")  # fmt: skip
    try:
        os.sched_setscheduler(0, *previous)
    except OSError:
        pass
    return None


def check_cpu_latency(value: float | None) -> float | None:
    """``value`` (µs) when it is a wake-up latency bound the kernel takes (0 to 2·10⁹), None for
    none; ``ValueError`` naming it otherwise."""
    if value is None:
        return None
    if not (math.isfinite(value) and 0 <= value <= MAX_CPU_LATENCY_US):
        raise ValueError(f"cpu_latency must be a number of microseconds from 0 to {MAX_CPU_LATENCY_US} (or None), got {value}")
    return float(value)


class ProcessSettings:
    """Raise and restore the loop thread's scheduling, the CPUs' wake-up latency and the garbage
    collector (see the module docstring). Expects the runtime's ``rt_priority``, ``scheduler``,
    ``_schedulers``, ``cpu_latency``, ``cpu_idle``, ``_cpu_latency_fd``, ``_gc_was_enabled``,
    ``_gc_frozen`` attributes and its ``_event`` method (the run log's events)."""

    rt_priority: int | None
    scheduler: str
    _schedulers: list[tuple[int, tuple[int, Any]]]
    cpu_latency: float | None
    cpu_idle: str
    _cpu_latency_fd: int | None
    _gc_was_enabled: bool | None
    _gc_frozen: bool
    cpu_latency_device: str = CPU_LATENCY_DEVICE

    def _hold_cpu_latency(self) -> None:
        """Ask for the CPUs' wake-up latency bound ``cpu_latency`` (µs) until the run ends; where
        the kernel refuses (no such device, no permission) the run goes on, and says so."""
        if self.cpu_latency is None or self._cpu_latency_fd is not None:
            return
        bound = int(round(self.cpu_latency))
        fd = None
        try:
            fd = os.open(self.cpu_latency_device, os.O_WRONLY | getattr(os, "O_CLOEXEC", 0))
            os.write(fd, struct.pack("=i", bound))
        except OSError as error:
            if fd is not None:
                os.close(fd)
            self.cpu_idle = f"default (wake-up latency {bound} us refused: {error})"
            self._event("cpu_latency", {"latency_us": bound, "refused": str(error)})
            return
        self._cpu_latency_fd = fd
        self.cpu_idle = f"wake-up latency <= {bound} us (PM QoS)"
        self._event("cpu_latency", {"latency_us": bound, "device": self.cpu_latency_device})

    def _release_cpu_latency(self) -> None:
        """End the wake-up latency request (closing the file ends it)."""
        fd, self._cpu_latency_fd = self._cpu_latency_fd, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass

    def _restore_process_state(self) -> None:
        """The CPUs' wake-up latency and the garbage collector as they were before the motors started."""
        self._release_cpu_latency()
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


__all__ = ["MAX_CPU_LATENCY_US", "RT_PRIORITY_RANGE", "ProcessSettings", "check_cpu_latency", "check_rt_priority", "probe_rt_priority"]
