"""The deployed walking controller's state in the run log: the ``/walker`` channel
(:data:`WALKER_CHANNEL`), one record per control tick, filled by :class:`WalkerRecorder` in the
control loop (``giwbc deploy --controller walk`` and a walking policy: :mod:`giwbc.apps.deploy_run`).

A record says what the walker did at that tick (:class:`~giwbc.locomotion.walker.WalkerState`
and the tick's WBC result): ``phase`` (``stand``, ``double``, ``single``), ``stance`` (the
carrying foot in single support; the next one in double support), the touch-down counts,
``phase_time`` (s since the phase began) and ``phase_left`` (s to its planned end: the touch-down
in single support; null standing), the measured DCM, its reference and their difference, the CoP asked for, the
disturbance estimate; in single support (null otherwise) the swing foot's landing as the footstep
plan put it (``nominal_target``), as the step adapter moved it (``planned_target``) and after the
step residual (``target``: where the swing goes), the adapter's move (``adjustment``, m) and its
change of the touch-down time (``timing_adjustment``, s, + later); the command walked at; and the
WBC tick's outcome: ``wbc`` ``guess`` (the active-set guess answered), ``backend`` (the QP backend
did), ``failed`` (the QP failed: the fallback command) or ``invalid_state`` (a non-finite state),
with the backend's iterations, the failures in a row and the tick's time (µs).

The tick ran at the record's ``t`` (the robot's time of that cycle; its command goes out at the
next cycle). The record is one float64 vector filled from one list (no dict or string in the
loop: ~2 µs, and ~1 µs to hand it to the writer), rendered with its names in the logger process
(:mod:`giwbc.runlog.channels`). A tick is logged once: a cycle where the walker did not tick (the
start-up ramp) logs nothing, nor does the runtime's hand-over tick (run between two cycles).
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.runlog.channels import WALKER_TOPIC, Field, NumericChannel

PHASES = tuple(p.value for p in Phase)
SIDES = ("left", "right")
WBC_OUTCOMES = ("guess", "backend", "failed", "invalid_state")
_GUESS = "active-set guess"  # WbcResult.message when the active-set guess answered (giwbc.control.wbc)

WALKER_CHANNEL = NumericChannel(WALKER_TOPIC, "giwbc.Walker", (
    Field("phase", kind="label", labels=PHASES), Field("stance", kind="label", labels=SIDES),
    Field("steps", kind="integer"), Field("recovery_steps", kind="integer"), Field("early_touchdowns", kind="integer"),
    Field("late_touchdowns", kind="integer"),
    Field("phase_time"), Field("phase_left"),
    Field("dcm", 2), Field("dcm_ref", 2), Field("dcm_error", 2), Field("cop", 2), Field("disturbance", 2),
    Field("nominal_target", 2), Field("planned_target", 2), Field("target", 2), Field("adjustment", 2), Field("timing_adjustment"),
    Field("command", 3),
    Field("wbc", kind="label", labels=WBC_OUTCOMES), Field("wbc_iterations", kind="integer"), Field("wbc_failures", kind="integer"),
    Field("wbc_us"),
))  # fmt: skip
_PHASE_INDEX = {p: float(i) for i, p in enumerate(Phase)}
_STATUS = {"qp_failed": 2.0, "invalid_state": 3.0}
_NO_SWING = [math.nan] * 9  # nominal_target .. timing_adjustment outside single support


class WalkerRecorder:
    """A :class:`~giwbc.runlog.channels.CycleRecorder` of a :class:`WalkingController`: its
    :data:`WALKER_CHANNEL` record for each new tick (see the module docstring)."""

    channel = WALKER_CHANNEL

    def __init__(self, walker: WalkingController) -> None:
        self.walker = walker
        self._values = np.full(WALKER_CHANNEL.size, np.nan)
        self._last = None  # the WbcResult last recorded

    def sample(self) -> np.ndarray | None:
        """This tick's record, or None when the walker has not ticked since the last one. The
        vector is reused: the writer copies it at once."""
        walker = self.walker
        result = walker.last_result
        if result is None or result is self._last:
            return None
        self._last = result
        s = walker.state
        start, nominal_end, planned_end = walker.phase_times()
        t = result.t
        dcm, ref = s.dcm.tolist(), s.dcm_ref.tolist()
        if s.phase is Phase.SINGLE:
            nominal, planned = s.nominal_target.tolist(), s.planned_target.tolist()
            swing = [*nominal, *planned, *s.target.tolist(), planned[0] - nominal[0], planned[1] - nominal[1], planned_end - nominal_end]
        else:
            swing = _NO_SWING
        c = walker.command
        outcome = (0.0 if result.message == _GUESS else 1.0) if result.ok else _STATUS.get(result.status.value, 2.0)
        # One list in the channel's field order, copied in at once (half the time of slice by slice).
        self._values[:] = [
            _PHASE_INDEX[s.phase], 0.0 if s.stance == "left" else 1.0, s.steps, s.recovery_steps, s.early_touchdowns, s.late_touchdowns,
            t - start, planned_end - t if planned_end != math.inf else math.nan,
            *dcm, *ref, dcm[0] - ref[0], dcm[1] - ref[1], *s.cop.tolist(), *s.disturbance.tolist(),
            *swing, c.vx, c.vy, c.yaw_rate,
            outcome, result.iterations, walker.wbc.consecutive_failures, result.timings.total * 1e6,
        ]  # fmt: skip
        return self._values


__all__ = ["PHASES", "WALKER_CHANNEL", "WBC_OUTCOMES", "WalkerRecorder"]
