"""The Robot interface over Unitree's low-level DDS interface (``rt/lowcmd`` / ``rt/lowstate``).

:class:`DdsRobot` is driven by the same real-time runtime and safety supervisor as the CAN robot
(it is one, to them: a :class:`~giwbc.hal.can_robot.CanRobot` whose exchange speaks DDS, and
whose one "bus" is ``rt/lowcmd``). A cycle (:meth:`DdsRobot.exchange`):

1. takes every ``LowState_`` that arrived since the last cycle (the robot publishes at its own
   500 Hz; nothing waits): each is checked (size, encapsulation, Unitree's CRC: a failure counts
   as a corrupt frame, ``report.corrupt``) and its ``tick`` must be after the last one taken (a
   repeated or older tick is stale or out of order: counted in ``report.unknown`` and dropped);
   the newest good one is the cycle's state (older good ones: ``report.late``). No good new
   state: every joint is missing this cycle and its ``stale`` count grows (the supervisor stops on
   ``max_missing_cycles``);
2. reads the joints by name (the plan's slot of each joint), the temperatures (the hotter of
   the two Unitree reports), the motor error bits (``motorstate``, non-zero: a motor error), the
   motor's mode byte (enabled or not, ``report.status`` once giwbc enabled the motors) and the IMU
   (``imu_state``: quaternion w, x, y, z; gyroscope; accelerometer);
3. publishes one ``LowCmd_`` (the state arrived one period after the command it answers:
   ``reply_lag`` 1): mode byte 1 with the held impedance command once enabled (``enter``), mode 0
   and no gains before that and after ``exit`` (zero gain: the motors produce no torque);
   ``mode_pr`` from the plan, ``mode_machine`` echoed from the robot's state, Unitree's CRC.

Link faults, reported as the link's driver error (the supervisor stops at once, damping then
zero gain): a publish DDS refuses, no reader of ``rt/lowcmd`` matched (the robot stopped
listening, or a subscriber that never came), another participant publishing ``rt/lowcmd`` (the
robot's own locomotion service was not released). At construction the robot waits up to the
plan's ``state_timeout`` for a first good state and refuses to start (one line) when none came,
when nobody reads ``rt/lowcmd``, or when someone else already commands the robot.

:meth:`emergency_stop`: the watchdog's stop without the loop (damping, then zero gain), from
messages encoded up front.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.errors import DdsLinkError, HardwareConfigError
from giwbc.hal.can_robot import COMMAND, ENTER, EXIT, CanRobot, CycleReport
from giwbc.hal.dds.messages import OK, LowCmd, LowState
from giwbc.hal.dds.plan import DDS_BUS, DdsPlan
from giwbc.hal.dds.transport import LOWCMD_TOPIC, LOWSTATE_TOPIC, DdsTransport
from giwbc.robot.interface import ImpedanceCommand, ImuReading

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

ENABLED, DISABLED = 1, 0  # the mode byte of MotorCmd_ / MotorState_
ENABLE_GRACE_CYCLES = 10  # cycles after enabling before a motor reporting mode 0 is a fault (states in flight predate the enable)
LINK_CHECK_CYCLES = 5  # cycles between two checks of the readers discovery matched (a list of handles each time)
_HALF = 1 << 31
_STATE_COLUMNS = [0, 1, 3]  # MotorState_'s floats q, dq, ddq, tau_est: the joint state's q, dq, tau
_IDL_ROWS = [0, 1, 4, 2, 3]  # MotorCmd_'s floats q, dq, tau, kp, kd from the held rows q, v, kp, kd, tau


def tick_after(tick: int, last: int | None) -> bool:
    """Whether ``tick`` comes after ``last`` (uint32, wrapping)."""
    return last is None or 0 < ((tick - last) & 0xFFFFFFFF) < _HALF


class DdsRobot(CanRobot):
    """A robot whose joints are commanded over DDS (module docstring). ``transport``: an open
    :class:`DdsTransport` (default: opened from the plan's interface and domain)."""

    def __init__(self, description: RobotDescription, plan: DdsPlan, *, transport: DdsTransport | None = None,
                 wait_for_state: bool = True) -> None:  # fmt: skip  (CanRobot.__init__ is CAN's: not called)
        self.after_close: Callable[[], None] | None = None  # run once by close() (the service's restore: motors off by then)
        self.description = description
        self.plan = plan  # type: ignore[assignment]
        names = description.joint_names
        self.slots = np.array(plan.slot_array(names), dtype=np.int64)
        self.transport = transport or DdsTransport(plan.domain, plan.interface, publish=LOWCMD_TOPIC, subscribe=LOWSTATE_TOPIC,
                                                   listen=True, source=plan.source)  # fmt: skip
        self.peer = None
        self.wait_for_replies = False  # the state of a command is read at the next cycle
        self.imu_source = None
        self.links = []
        self._init_joint_state(description)
        dofs = description.dofs
        self.crc_errors = 0  # states refused for a bad CRC (or size, or encapsulation)
        self.out_of_order = 0  # states whose tick was not after the last one taken
        self.foreign_commands = 0  # rt/lowcmd messages another participant published
        self.enabled = False
        self._enabled_cycle = 0
        self.state = LowState()
        self.lowcmd = LowCmd()
        self.lowcmd.field("mode_pr")[0] = plan.mode_pr
        self._cmd_mode_machine = self.lowcmd.field("mode_machine")
        self._modes_on: bool | None = None  # whether the LowCmd_'s mode bytes say enabled (None: not written yet)
        self._tick: int | None = None
        self._mode_machine = 0
        self._readers = 1
        self._zeros = np.zeros(dofs)
        if wait_for_state:
            try:
                self._connect(plan.state_timeout)
            except BaseException:
                self.close()
                raise

    # --- start-up -----------------------------------------------------------------------------
    def _connect(self, timeout: float) -> None:
        """Wait for the robot's first good state and a reader of our commands; refuse a robot
        that someone else commands (HardwareConfigError, one line)."""
        where = f"{self.plan.source}: DDS domain {self.plan.domain} on {self.plan.interface!r}"
        end = time.monotonic() + timeout
        while True:
            if self._take_states()[0]:
                break
            if time.monotonic() > end:
                raise HardwareConfigError(f"{where}: no valid {LOWSTATE_TOPIC} within {timeout:g} s: is the robot on, on this interface "
                                          f"and domain, and its low-level interface up? ({self.crc_errors} refused)")  # fmt: skip
            time.sleep(0.002)
        if not self.transport.wait_matched(max(0.0, end - time.monotonic()) + 0.5):
            raise HardwareConfigError(f"{where}: the robot publishes {LOWSTATE_TOPIC} but nobody reads {LOWCMD_TOPIC}")
        time.sleep(0.02)  # a few of its periods: a locomotion service still running publishes meanwhile
        if self.transport.foreign():
            raise HardwareConfigError(f"{where}: another participant publishes {LOWCMD_TOPIC}: the robot's locomotion service is still "
                                      "active; release it first (README: the G1 over DDS)")  # fmt: skip

    # --- the cycle ----------------------------------------------------------------------------
    def _take_states(self) -> tuple[bool, int, int, int]:
        """Take the waiting states; load the newest good one. (new, late, corrupt, out of order)"""
        got = self.transport.take(32)
        state = self.state
        best, late, corrupt, stale = None, 0, 0, 0
        last = self._tick
        for k, data in enumerate(got):
            if state.load(data) != OK:
                corrupt += 1
                continue
            tick = int(state.tick[0])
            if not tick_after(tick, last):
                stale += 1
                continue
            if best is not None:
                late += 1
            best, last = k, tick
        self.crc_errors += corrupt
        self.out_of_order += stale
        if best is None:
            return False, late, corrupt, stale
        if best != len(got) - 1 or state.status != OK:
            state.load(got[best])
        self._tick = last
        self._mode_machine = int(state.mode_machine[0])
        return True, late, corrupt, stale

    def exchange(self, t: float, deadline: float | None = None, kind: str = COMMAND) -> CycleReport:
        """One cycle at time ``t`` (module docstring). Never raises for link trouble: it is in the report."""
        if kind not in (COMMAND, ENTER, EXIT):
            raise ValueError(f"exchange kind must be command, enter or exit, got {kind!r}")
        self._now = float(t)
        started = time.perf_counter()
        new, late, corrupt, stale = self._take_states()
        s, slots = self.state, self.slots
        if new:
            self._joint_state[:] = s.floats[slots][:, _STATE_COLUMNS].T  # q, dq, tau_est: one gather
            self._temperature[:] = s.temperature[slots].max(axis=1)
            self._error[:] = s.motorstate[slots]
            self._status[:] = s.modes[slots] if self.enabled and self.cycle - self._enabled_cycle > ENABLE_GRACE_CYCLES else -1
            self._stale[:] = 0
            self._replied[:] = True
            w, x, y, z = s.quaternion.tolist()
            self._imu = ImuReading(np.array((x, y, z, w)), s.gyroscope.astype(float), s.accelerometer.astype(float), float(t))
            self._imu_time = float(t)
        else:
            self._stale += 1
        receive_s = time.perf_counter() - started

        t0 = time.perf_counter()
        error: BaseException | None = None
        sent = self._publish(kind)
        if not sent:
            error = DdsLinkError(f"DDS refused to publish {LOWCMD_TOPIC} ({self.transport.write_errors} refused so far)")
        if self.cycle % LINK_CHECK_CYCLES == 0:
            self._readers = self.transport.matched_readers()
        if not self._readers:
            error = DdsLinkError(f"no reader of {LOWCMD_TOPIC} matched: the robot does not hear the commands (it stopped "
                                 "listening, or its subscriber never came)")  # fmt: skip
        foreign = self.transport.foreign()
        if foreign:
            self.foreign_commands += foreign
            error = DdsLinkError(f"another participant publishes {LOWCMD_TOPIC} ({foreign} message(s) this cycle): the robot's "
                                 "locomotion service is active; release it before a run (README: the G1 over DDS)")  # fmt: skip
        dropped = 0 if sent else 1
        self.send_dropped += dropped
        send_s = time.perf_counter() - t0
        self._time = float(t)
        missing = np.full(self.dofs, not new)
        report = CycleReport(
            self.cycle, float(t), kind, missing, self._stale.copy(), self._error.copy(), self._temperature.copy(),
            late, np.array([corrupt]), stale, dropped, 0, new, send_s, receive_s,
            self._status.copy(), np.array([int(sent and error is None)]), np.array([int(error is not None)]), (error,),
        )  # fmt: skip
        self.late_frames += late
        self.cycle += 1
        return report

    def _publish(self, kind: str) -> bool:
        """Fill and publish this cycle's LowCmd_."""
        m, slots = self.lowcmd, self.slots
        if kind == ENTER:
            if not self.enabled:
                self._enabled_cycle = self.cycle
            self.enabled = True
        elif kind == EXIT:
            self.enabled = False
        self._cmd_mode_machine[0] = self._mode_machine
        if self._modes_on is not self.enabled:  # the mode bytes change only when the motors are enabled or not
            modes = np.zeros(len(m.floats), dtype=np.uint8)
            if self.enabled:
                modes[slots] = ENABLED
            m.set_modes(modes)
            self._modes_on = self.enabled
        if self.enabled and kind == COMMAND:
            c, held = self.command, self._held_rows()
            if held is not None:  # set_joint_impedance's rows: one assignment
                m.floats[slots] = held[_IDL_ROWS].T
            else:
                m.q[slots], m.dq[slots], m.tau[slots], m.kp[slots], m.kd[slots] = c.q_ref, c.v_ref, c.tau_ff, c.kp, c.kd
        else:  # enter (motors on, no torque yet), exit and before enabling: no gains, no torque
            m.floats[:] = 0.0
            m.q[slots] = self._q
        return self.transport.write(m.seal())

    # --- the watchdog's stop --------------------------------------------------------------------
    def emergency_stop(self, damping: ImpedanceCommand) -> DdsEmergencyStop:
        return DdsEmergencyStop(self, damping)

    def close(self) -> None:
        """Close the transport (the motors are not touched: stop them first), then run ``after_close``."""
        transport = getattr(self, "transport", None)
        if transport is not None:
            transport.close()
        after, self.after_close = getattr(self, "after_close", None), None
        if after is not None:
            after()


class DdsEmergencyStop:
    """Damping then zero gain on every motor, published without the loop's exchange (the
    watchdog's stop, :mod:`giwbc.runtimes.watchdog`); both messages encoded up front."""

    def __init__(self, robot: DdsRobot, damping: ImpedanceCommand) -> None:
        self.robot = robot
        slots = robot.slots
        m = LowCmd()
        m.field("mode_pr")[0] = robot.lowcmd.field("mode_pr")[0]
        m.field("mode_machine")[0] = robot._mode_machine
        modes = np.zeros(len(m.floats), dtype=np.uint8)
        modes[slots] = ENABLED
        m.set_modes(modes)
        m.q[slots], m.dq[slots], m.tau[slots], m.kp[slots], m.kd[slots] = damping.q_ref, damping.v_ref, damping.tau_ff, damping.kp, damping.kd
        self.damping = m.seal()
        m.set_modes(np.zeros(len(m.floats), dtype=np.uint8))
        m.floats[:] = 0.0
        self.off = m.seal()

    def run(self, t0: float, period: float, damping_time: float, exit_steps: int, *, realtime: bool = True) -> dict[str, Any]:
        transport, clock = self.robot.transport, time.perf_counter
        start = clock()
        steps, exit_steps = max(1, int(round(damping_time / period))), max(1, exit_steps)
        sent = 0
        for k in range(steps + exit_steps):
            if realtime:
                due = start + k * period
                if clock() < due:
                    time.sleep(due - clock())
            sent += transport.write(self.damping if k < steps else self.off)
        self.robot.enabled = False
        return {"time": t0 + (steps + exit_steps) * period, "damping_steps": steps, "exit_steps": exit_steps,
                "unreachable_buses": [] if sent else [DDS_BUS], "frames_sent": sent}  # fmt: skip


__all__ = ["DISABLED", "ENABLED", "DdsEmergencyStop", "DdsRobot", "tick_after"]
