"""The deadline clock's idle guarantee: under SCHED_FIFO the loop must sleep part of every period
(Linux stops a real-time thread busy more than 95 % of a second for the rest of it), whatever the
spin before the deadline."""

from __future__ import annotations

import time

from giwbc.runtimes.clock import DeadlineClock


def test_a_spin_as_long_as_the_period_still_sleeps_min_idle_every_cycle(monkeypatch) -> None:
    slept: list[float] = []
    real_sleep = time.sleep

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        real_sleep(seconds)

    monkeypatch.setattr(time, "sleep", sleep)
    period, min_idle = 0.002, 0.00012
    clock = DeadlineClock(period, spin=period, min_idle=min_idle)
    for _ in range(30):
        clock.wait()
        clock.done()
    # one sleep per cycle, none shorter than min_idle (the spin alone would have left none)
    assert len(slept) == 30 and min(slept) >= min_idle
    assert len(clock.stats.work) == 30


def test_a_short_spin_sleeps_until_spin_before_the_deadline(monkeypatch) -> None:
    slept: list[float] = []
    monkeypatch.setattr(time, "sleep", lambda seconds: slept.append(seconds))
    period, spin = 0.004, 0.0005
    clock = DeadlineClock(period, spin=spin, min_idle=0.0002)
    clock.wait()  # the first slot is due at once
    clock.done()
    clock.wait()
    assert slept and period - spin - 0.0005 < slept[-1] <= period - spin
