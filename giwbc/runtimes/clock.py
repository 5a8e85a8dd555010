"""The real-time runtime's pacing: absolute deadlines (:class:`DeadlineClock`) and per-cycle timing
statistics (:class:`TimingStats`).

Control cycle ``k`` is due at ``start + k * period`` on ``time.perf_counter()``; the loop sleeps
until ``spin`` before the deadline (at least ``min_idle``), then spins. A long spin keeps the loop's
CPU from other processes between cycles, and with it the caches the cycle's code runs from: on a
shared 2-vCPU guest, spinning 1.2 ms of a 2 ms period cut the walking deploy loop's host work by
~15 % (``benchmarks/deploy_loop.py --spin``), at the price of a core kept busy. A cycle whose work ends after the next deadline is
an **overrun**; when a whole period is missed the clock skips to the current slot (counted as
skipped) instead of bursting to catch up. The robot's time is the slot's nominal time
``k * period``, which is also the clock the emulator runs on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class TimingStats:
    """Per-cycle timing, seconds: lateness of each cycle start (after its deadline), period since
    the previous start (NaN for the first), work (wall) and CPU time, overrun flag, skipped slots."""

    lateness: list[float] = field(default_factory=list)
    periods: list[float] = field(default_factory=list)
    work: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    overrun: list[bool] = field(default_factory=list)
    skipped_before: list[int] = field(default_factory=list)

    @property
    def overruns(self) -> int:
        return int(sum(self.overrun))

    @property
    def skipped(self) -> int:
        return int(sum(self.skipped_before))

    def between(self, start: int, stop: int | None = None) -> TimingStats:
        """The cycles ``start:stop`` (e.g. one phase)."""
        s = slice(start, stop)
        return TimingStats(self.lateness[s], self.periods[s], self.work[s], self.cpu[s], self.overrun[s], self.skipped_before[s])

    def summary(self, period: float) -> dict[str, Any]:
        """p50 / p99 / max in microseconds (period error = |period - nominal|), overrun counts."""

        def pct(values: Any, scale: float = 1e6) -> dict[str, float | None]:
            a = np.asarray(values, dtype=float) * scale
            a = a[np.isfinite(a)]
            if not a.size:
                return {"p50": None, "p99": None, "max": None}
            return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}

        return {
            "cycles": len(self.lateness),
            "period_us": period * 1e6,
            "period_error_us": pct(np.abs(np.asarray(self.periods, dtype=float) - period)),
            "lateness_us": pct(self.lateness),
            "work_us": pct(self.work),
            "cpu_us": pct(self.cpu),
            "overruns": self.overruns,
            "skipped_slots": self.skipped,
        }


class DeadlineClock:
    """Absolute deadlines ``start + k * period`` on ``perf_counter`` (see the module docstring).

    ``realtime=False`` runs slots back to back (tests, faster-than-real-time rehearsals): the
    robot time still advances one period per cycle, so an emulated run is the same.
    """

    def __init__(self, period: float, *, realtime: bool = True, spin: float = 250e-6, min_idle: float = 0.0) -> None:
        if not period > 0 or spin < 0 or not 0 <= min_idle < period:
            raise ValueError(f"need period > 0, spin >= 0, 0 <= min_idle < period; got {period}, {spin}, {min_idle}")
        self.period = float(period)
        self.realtime = realtime
        self.spin = float(spin)
        self.min_idle = float(min_idle)  # sleep at least this long per cycle, even when late
        self.start: float | None = None
        self.slot = -1
        self.stats = TimingStats()
        self._last_start: float | None = None
        self._cycle_start = 0.0
        self._cpu_start = 0.0

    def deadline(self, slot: int) -> float:
        assert self.start is not None
        return self.start + slot * self.period

    @property
    def next_deadline(self) -> float:
        return self.deadline(self.slot + 1)

    @property
    def cycle_start(self) -> float:
        """When the current cycle actually started (``perf_counter``)."""
        return self._cycle_start

    def wait(self) -> tuple[int, float]:
        """Block until the next slot is due; returns (slot, lateness in s)."""
        clock = time.perf_counter
        if self.start is None:
            self.start = clock()
        slot = self.slot + 1
        if not self.realtime:
            self.slot = slot
            now = clock()
            self._begin(now, 0.0, 0)
            return slot, 0.0
        due = self.deadline(slot)
        now = clock()
        idle = self.min_idle  # still to sleep this cycle
        if idle and now > due - idle:
            # Late or nearly: yield anyway, so a busy loop under SCHED_FIFO stays below the kernel's
            # RT throttling limit (exceeding it stops the thread for the rest of the second).
            time.sleep(idle)
            now = clock()
            idle = 0.0
        skipped = 0
        if now - due >= self.period:  # missed at least one whole slot: resynchronise
            current = int((now - self.start) / self.period)
            skipped = current - slot
            slot = current
        else:
            # At least min_idle asleep however long the spin: a spin as long as the slack (a loop
            # that owns its core keeps it, and its caches, to itself) stays under RT throttling.
            remaining = max(due - now - self.spin, idle)
            if remaining > 0:
                time.sleep(remaining)
            while clock() < due:
                pass
            now = clock()
        self.slot = slot
        lateness = now - due  # from the deadline this cycle was first due at (skips included)
        self._begin(now, lateness, skipped)
        return slot, lateness

    def resync(self) -> None:
        """Restart the schedule from now: the next slot is due one period from now. After a
        deliberate pause between cycles (the hand-over) nothing counts as an overrun or a skipped
        slot, and the period across the pause is not measured (NaN)."""
        if self.realtime and self.start is not None:
            self.start = time.perf_counter() - self.slot * self.period
            self._last_start = None

    def _begin(self, now: float, lateness: float, skipped: int) -> None:
        st = self.stats
        st.periods.append(now - self._last_start if self._last_start is not None else math.nan)
        self._last_start = now
        st.lateness.append(lateness)
        st.skipped_before.append(skipped)
        self._cycle_start = now
        self._cpu_start = time.thread_time()

    def done(self) -> tuple[float, bool]:
        """End of the cycle's work: (work seconds, overrun)."""
        now = time.perf_counter()
        work = now - self._cycle_start
        st = self.stats
        st.work.append(work)
        st.cpu.append(time.thread_time() - self._cpu_start)
        overrun = self.realtime and now > self.next_deadline
        st.overrun.append(overrun)
        return work, overrun


__all__ = ["DeadlineClock", "TimingStats"]
