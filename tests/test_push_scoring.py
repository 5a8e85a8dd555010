"""A push episode counts as a success only after the robot had SETTLE_AFTER_PUSH_S after the push: a late fall
is a failure, and the fall's time after the push is reported."""

from __future__ import annotations

import math

import pytest

from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, fall_times_summary, judge_push


def test_the_settle_window_is_three_seconds() -> None:
    assert SETTLE_AFTER_PUSH_S == 3.0


def test_a_fall_two_seconds_after_the_push_is_a_failure() -> None:
    """Pushed from 1.4 to 1.6 s, fallen at 3.6 s: the old 2.6 s window ended upright 1 s after the push; now a failure."""
    outcome = judge_push(fell=True, fall_time=3.6, end_time=3.6, push_end=1.6, final_tilt=1.2, upright_tilt=0.35)
    assert not outcome.success
    assert outcome.fall_after_push == pytest.approx(2.0)


def test_three_seconds_up_after_the_push_is_a_success() -> None:
    outcome = judge_push(fell=False, fall_time=None, end_time=1.6 + SETTLE_AFTER_PUSH_S, push_end=1.6, final_tilt=0.05,
                         upright_tilt=0.35)
    assert outcome.success and outcome.fall_after_push is None
    # Up but leaning past the limit at the end: not a success either.
    assert not judge_push(fell=False, fall_time=None, end_time=5.0, push_end=1.6, final_tilt=0.4, upright_tilt=0.35).success


def test_an_episode_ending_inside_the_window_cannot_be_a_success() -> None:
    """Up 2 s after the push when the episode ended: refused, not counted either way."""
    with pytest.raises(ValueError, match="2.000 s after its push cannot be judged"):
        judge_push(fell=False, fall_time=None, end_time=3.6, push_end=1.6)
    # ... whereas a fall inside it is judged: it is a failure whenever it happens.
    early = judge_push(fell=True, fall_time=1.5, end_time=1.5, push_end=1.6)
    assert not early.success and early.fall_after_push == pytest.approx(-0.1)  # fell during the push


def test_without_a_push_only_the_fall_and_the_tilt_count() -> None:
    assert judge_push(fell=False, fall_time=None, end_time=0.5, push_end=math.nan).success
    assert judge_push(fell=True, fall_time=0.4, end_time=0.4, push_end=None).fall_after_push is None
    with pytest.raises(ValueError, match="time of its fall"):
        judge_push(fell=True, fall_time=None, end_time=0.4, push_end=1.0)


def test_fall_times_are_listed_sorted() -> None:
    assert fall_times_summary([2.104, 0.5, 1.999]) == {"falls": 3, "fall_after_push_s": [0.5, 2.0, 2.1]}
    assert fall_times_summary([]) == {"falls": 0, "fall_after_push_s": []}
