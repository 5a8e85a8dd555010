"""How every push protocol scores an episode: success only after a settle window past the push.

A robot that is still up one second after a push may be falling: the slow topples (a foot
rolling, a capture step too short) take two to three seconds to end on the ground. Every push
protocol of this package (``giwbc evaluate``, both protocols; ``giwbc sim-to-sim``;
``benchmarks/locomotion.py``) therefore runs each episode to at least
:data:`SETTLE_AFTER_PUSH_S` after its (last) push ends and judges it with :func:`judge_push`,
which refuses to call an episode a success before that, and says when each fall happened,
counted from the end of the push.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SETTLE_AFTER_PUSH_S = 3.0  # s the robot must stay up after a push ends before the episode counts as a success
_TIME_TOLERANCE = 1e-6  # s: simulated times are sums of time steps


@dataclass(frozen=True)
class PushOutcome:
    """The judgement of one pushed episode."""

    success: bool
    fall_after_push: float | None  # s from the end of the push to the fall (< 0: during the push); None: no fall


def judge_push(*, fell: bool, fall_time: float | None, end_time: float, push_end: float | None,
               final_tilt: float = 0.0, upright_tilt: float = math.inf) -> PushOutcome:
    """Success: no fall, at least :data:`SETTLE_AFTER_PUSH_S` s between the end of the push and the
    end of the episode, and the base tilt at the end under ``upright_tilt`` (rad). ``push_end``:
    when the (last) push ended, s; ``None`` or nan when no push came (then only the fall and the
    tilt count). ValueError for an unfallen episode that ended inside the settle window: it cannot be
    judged, and counting it either way would be a guess."""
    pushed = push_end is not None and math.isfinite(push_end)
    if fell:
        if fall_time is None or not math.isfinite(fall_time):
            raise ValueError("a fallen episode needs the time of its fall")
        return PushOutcome(False, fall_time - push_end if pushed else None)
    if pushed and end_time < push_end + SETTLE_AFTER_PUSH_S - _TIME_TOLERANCE:
        raise ValueError(f"an episode that ends {end_time - push_end:.3f} s after its push cannot be judged: success needs "
                         f"{SETTLE_AFTER_PUSH_S:g} s after the push ends")
    return PushOutcome(final_tilt < upright_tilt, None)


def fall_times_summary(falls: list[float]) -> dict[str, object]:
    """The falls of an arm: how many, and when after the push ended (s, sorted, 2 decimals)."""
    ordered = sorted(round(f, 2) for f in falls)
    return {"falls": len(ordered), "fall_after_push_s": ordered}


__all__ = ["SETTLE_AFTER_PUSH_S", "PushOutcome", "fall_times_summary", "judge_push"]
