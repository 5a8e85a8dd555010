"""benchmarks/locomotion.py's gait-phase protocol: the phase of a push from a contact schedule, and its tables."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "locomotion.py"
_SPEC = importlib.util.spec_from_file_location("benchmark_locomotion", _PATH)
bench = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(bench)

# A hand-built schedule: right touch-downs at 0.5 s + k, left at 1.0 s + k (a 1 s step pair), then a slower pair from 3.0 s to 4.2 s.
SCHEDULE = [(0.5, "right"), (1.0, "left"), (1.5, "right"), (2.0, "left"), (2.5, "right"), (3.0, "left"), (3.7, "right"), (4.2, "left")]


def test_push_phase_is_the_fraction_of_the_left_to_left_step_pair() -> None:
    assert bench.push_phase(1.0, SCHEDULE) == 0.0  # at a left touch-down
    assert bench.push_phase(1.5, SCHEDULE) == pytest.approx(0.5)  # at the right touch-down between
    assert bench.push_phase(2.8, SCHEDULE) == pytest.approx(0.8)
    assert bench.push_phase(3.6, SCHEDULE) == pytest.approx(0.6 / 1.2)  # the longer pair
    with pytest.raises(ValueError, match="step pair"):
        bench.push_phase(0.7, SCHEDULE)  # before the first left touch-down
    with pytest.raises(ValueError, match="step pair"):
        bench.push_phase(4.5, SCHEDULE)  # after the last: no next left touch-down


def test_phase_start_inverts_push_phase_in_the_anchored_pair() -> None:
    for phase in bench.PHASES:
        start = bench.phase_start(phase, SCHEDULE, anchor=2.6)  # the pair 3.0 -> 4.2 s
        assert 3.0 <= start < 4.2
        assert bench.push_phase(start, SCHEDULE) == pytest.approx(phase)
    with pytest.raises(ValueError, match="full step pair"):
        bench.phase_start(0.2, SCHEDULE, anchor=3.5)


def test_success_table_counts_each_phase_and_direction() -> None:
    results = [{"phase": p, "direction": d, "success": (p == 0.0) or (d == 0.0 and p < 0.5)} for p in (0.0, 0.2, 0.4, 0.6) for d in (0.0, 1.571)]
    by_phase = bench.success_table(results, "phase")
    assert list(by_phase) == ["0", "0.2", "0.4", "0.6"]
    assert [by_phase[k]["success"] for k in by_phase] == [2, 1, 1, 0]
    assert all(row["episodes"] == 2 for row in by_phase.values())
    assert by_phase["0.2"]["rate"] == 0.5
    by_direction = bench.success_table(results, "direction")
    assert by_direction["0"] == {"success": 3, "episodes": 4, "rate": 0.75, "ci95": bench._wilson(3, 4)}
    assert by_direction["1.571"]["success"] == 1
    low, high = by_direction["0"]["ci95"]
    assert 0.0 < low < 0.75 < high <= 1.0  # Wilson: around the rate, inside [0, 1]
    assert bench._wilson(0, 8)[0] == 0.0 and bench._wilson(8, 8)[1] == 1.0


def test_contact_schedule_of_a_short_in_place_run_alternates_feet() -> None:
    """Closed loop, 4 s stepping in place: the touch-downs alternate and a step pair lasts about two steps."""
    schedule = bench.ContactSchedule()
    run = bench.simulate_walk(bench.load("g1"), (0.0, 0.0, 0.0), 4.0, step_in_place=True, seed=50001, observe=schedule)
    assert not run.fell
    sides = [side for _, side in schedule.touchdowns]
    assert len(sides) >= 4 and all(a != b for a, b in zip(sides, sides[1:]))
    t0, t1 = bench.step_pair(schedule.touchdowns[-1][0] - 0.01, schedule.touchdowns)
    assert 0.6 < t1 - t0 < 1.6 and math.isfinite(bench.push_phase(0.5 * (t0 + t1), schedule.touchdowns))
