"""Held heading of stance feet: the yaw reference that bounds heading drift while a foot is down.

A loaded stance foot does not turn on the ground, so the world heading it had when it came down
(the base's estimated heading plus the leg's encoder-measured yaw) is a reference for the base's
heading for as long as it stays down: the difference between the held and the current estimated
foot heading is the base's heading error, and integrated it is the yaw gyro bias, which nothing
else observes without a magnetometer or an orientation output.

A slip (the foot twisting on the ground) must re-anchor the held heading, or the estimator would
follow the twist. A slip is told from a gyro bias by its speed: the estimated foot heading drifts
at the residual yaw bias (well under a degree per second after the start-up calibration), while
a twist turns it by ``twist`` within ``twist_time``. The check compares the current heading with
the one at the start of the previous window of ``twist_time`` (so any turn faster than
``twist / twist_time`` is seen whole within one comparison), never with the held heading itself:
a threshold on the held error would re-anchor on the bias's own drift and the yaw bias would
never be learnt.
"""

from __future__ import annotations

import math

__all__ = ["FootHeadings"]


class FootHeadings:
    """Per foot: the held heading (rad, world) while it stays loaded, and slip detection (module doc)."""

    def __init__(self, n_feet: int, twist: float, twist_time: float) -> None:
        if twist <= 0.0 or twist_time <= 0.0:
            raise ValueError(f"foot twist threshold and time must be > 0, got {twist} rad in {twist_time} s")
        self.n_feet = n_feet
        self.twist = twist
        self.twist_time = twist_time
        self.reset()

    def reset(self) -> None:
        self.held: list[float | None] = [None] * self.n_feet
        self._marks: list[list[float] | None] = [None] * self.n_feet  # [t_window, heading_window, heading_previous_window]
        self.twists = 0  # re-anchors after a slip
        self.anchored_at: list[float | None] = [None] * self.n_feet  # when each held heading was taken

    def lift(self, foot: int) -> None:
        """The foot left the ground (or is not loaded): its heading is no longer held."""
        self.held[foot] = None
        self._marks[foot] = None
        self.anchored_at[foot] = None

    def update(self, foot: int, now: float, heading: float) -> float:
        """The loaded foot's current estimated heading (rad); returns the held heading less it
        (wrapped to [-pi, pi]), 0 when it was just anchored or re-anchored after a slip."""
        held, marks = self.held[foot], self._marks[foot]
        if held is None or marks is None:
            self._anchor(foot, now, heading)
            return 0.0
        if abs(math.remainder(heading - marks[2], math.tau)) > self.twist:  # turned fast: a slip
            self.twists += 1
            self._anchor(foot, now, heading)
            return 0.0
        if now - marks[0] >= self.twist_time:  # roll the windows
            marks[0], marks[2], marks[1] = now, marks[1], heading
        return math.remainder(held - heading, math.tau)

    def _anchor(self, foot: int, now: float, heading: float) -> None:
        self.held[foot] = heading
        self._marks[foot] = [now, heading, heading]
        self.anchored_at[foot] = now
