"""The Robot interface over CAN actuators: one exchange per control cycle on every bus of a plan.

A cycle (:meth:`CanRobot.exchange`) sends the held command to every motor, one frame each, on
all buses first (buses work in parallel), then collects the replies of every bus until all came
or the reply deadline passed. MIT mode is request/response: the replies carry the state the motors
measured when the command arrived, so the command computed from them goes out at the next cycle.

- **State** is joint side (sign, zero offset and gear ratio applied by the plan's ``MotorGroup``);
  a motor that did not reply keeps its last values and its ``stale`` count grows.
- **Commands** are per-joint impedance frames; :meth:`set_joint_torques` sends impedance frames with
  ``kp = kd = 0`` and the torque as feed-forward. All motors are encoded in one vectorized call,
  and the replies of all buses decoded in one (:class:`~giwbc.hal.protocols.multibus.MultiBusCodec`);
  frames cross each bus in batches (:class:`~giwbc.hal.frames.FramePort`: on the bus's socket
  where it has one, giwbc-unix and SocketCAN, without python-can's per-message objects).
- **Late frames**: before sending, frames already waiting (replies that missed an earlier deadline)
  are drained and counted as late, never taken as this cycle's replies.
- **IMU** comes from an :class:`ImuSource` (:mod:`giwbc.hal.imu`; ``emulated``: the emulator's :class:`~giwbc.hal.imu.ImuChannel`).
  A CAN IMU (:class:`~giwbc.hal.can_imu.CanImu`) shares a bus with motors: its frames are taken
  out of what the robot reads on that bus and handed to it, never counted as unknown traffic.
- **Base state** is not measured on hardware: :meth:`base_state`, :meth:`link_pose` and
  :meth:`contact_wrench` raise :class:`BaseStateUnavailable` (never ground truth from a
  simulator). Wrap the robot in :class:`~giwbc.estimation.estimated_robot.EstimatedRobot` for an
  estimated base (``giwbc deploy`` does; the real-time runtime updates it after each exchange).
- ``peer``: an in-process stand-in for the motors (:class:`Peer`, the emulator): told that time
  reached the cycle time before draining (``advance``), and to answer after sending (``answer``),
  so it runs in lockstep (see :mod:`giwbc.emulation.emulator`); None on hardware.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from giwbc.hal.bus import BUS_ERRORS, DROPPED, RECEIVED, RETRIES, SENT, UNKNOWN, VERDICT_COLUMNS, CanBusLink
from giwbc.hal.can_imu import CanImu
from giwbc.hal.frames import GroupReceived, PortGroup, SocketPort
from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.imu import ImuSource
from giwbc.hal.kernels import joint_state_of_replies
from giwbc.hal.motor import MotorGroup
from giwbc.hal.protocols import CORRUPT, REPLY, DecodedReplies
from giwbc.hal.protocols.multibus import MultiBusCodec
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, DescribedRobot, ImuReading
from giwbc.errors import BaseStateUnavailable, NonFiniteCommand

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

COMMAND, ENTER, EXIT = "command", "enter", "exit"
_SEND_COLUMNS = [SENT, DROPPED, RETRIES, BUS_ERRORS]  # link counters, in PortGroup.send's outcome order
assert _SEND_COLUMNS[:3] == [0, 1, 2]  # (exchange adds the first three as one slice)
_SEND_BUDGET = 5e-3  # s: how long sending may take when the caller gives no deadline


class Peer(Protocol):
    """The motors' side of the buses when it runs in this process (the emulator)."""

    def advance(self, now: float) -> None:
        """Time reached ``now``: physics, and replies that became due, happen."""

    def answer(self, now: float) -> None:
        """Answer the frames waiting on the buses."""


@dataclass(frozen=True)
class CycleReport:
    """What one exchange saw. Per-joint arrays are in description order."""

    cycle: int
    time: float
    kind: str
    missing: np.ndarray  # bool: no valid reply this cycle
    stale: np.ndarray  # consecutive cycles without a valid reply
    error_code: np.ndarray  # reported error (0 none, -1 not reported by the variant / never replied)
    temperature: np.ndarray  # °C, NaN where not reported
    late: int  # frames that arrived after their cycle's deadline (drained before sending)
    corrupt: np.ndarray  # per bus: undecodable frames this cycle (late ones included)
    unknown: int  # frames from no configured motor
    send_dropped: int  # command frames that could not be sent
    clamped: int  # command fields clamped to the motors' ranges
    imu_fresh: bool  # the IMU produced a new sample since the last cycle
    send_s: float  # wall time spent sending (s)
    receive_s: float  # wall time spent collecting replies (s)
    status: np.ndarray | None = None  # reported motor state (Damiao: 0 disabled, 1 enabled, >= 8 error; -1 not reported)
    bus_sent: np.ndarray | None = None  # per bus: frames the driver took this cycle
    bus_errors: np.ndarray | None = None  # per bus: driver errors while sending this cycle
    driver_errors: tuple[BaseException | None, ...] = ()  # per bus: the driver's last exception this cycle

    @property
    def complete(self) -> bool:
        return not np.count_nonzero(self.missing)


class CanRobot(DescribedRobot):
    """A robot whose joints are the CAN actuators of ``plan`` (see the module docstring).

    ``links``: open :class:`CanBusLink` per bus in plan order (default: opened from the plan).
    ``reply_timeout``: how long after sending a cycle waits for replies at most (s).
    ``send_budget``: how long a cycle's sends may take when :meth:`exchange` is given no deadline (s).
    ``wait_for_replies=False``: a cycle does not wait; it first takes the frames that arrived
    since the last one (the replies to the previous cycle's commands: state one period old), then
    sends. The loop then never blocks on the bus, which suits motors that answer later than a
    fraction of the period (the emulator in its own process); a reply missing at the next cycle
    counts as missing. With a lockstep ``peer`` it answers after the sends and its replies wait
    for the next cycle: the same one-cycle reply lag in the emulator's time, deterministic.
    """

    def __init__(
        self,
        description: RobotDescription,
        plan: HardwarePlan,
        *,
        imu: ImuSource | None = None,
        peer: Peer | None = None,
        links: Sequence[CanBusLink] | None = None,
        reply_timeout: float = 0.8e-3,
        wait_for_replies: bool = True,
        send_budget: float = _SEND_BUDGET,
    ) -> None:
        self.description = description
        self.plan = plan
        names = description.joint_names
        plan.routing(names)  # validates: one motor per joint
        self.links = list(links) if links is not None else [b.open_link() for b in plan.buses]
        if len(self.links) != len(plan.buses):
            raise ValueError(f"{len(self.links)} links for {len(plan.buses)} buses")
        self.imu_source = imu
        # A CAN IMU's frames arrive with the motors' replies: handed to it before decoding.
        self._can_imu = imu if isinstance(imu, CanImu) else None
        self._imu_bus = -1
        if self._can_imu is not None:
            names_ = [b.name for b in plan.buses]
            if self._can_imu.bus not in names_:
                raise ValueError(f"the CAN IMU's bus {self._can_imu.bus!r} is not one of the plan's buses {names_}")
            self._imu_bus = names_.index(self._can_imu.bus)
        self.peer = peer
        self.reply_timeout = float(reply_timeout)
        self.send_budget = float(send_budget)
        self.wait_for_replies = bool(wait_for_replies)

        self.motors = plan.motors
        self.group = MotorGroup(self.motors)
        self.joint_index = np.array([names.index(m.joint) for m in self.motors], dtype=np.int64)
        self.codec = MultiBusCodec([link.protocol for link in self.links])
        if self.codec.motors != tuple(self.motors):
            raise ValueError("the links' protocols must drive the plan's motors, in plan order")
        bounds = self.codec.bounds  # motors of bus b: bounds[b]:bounds[b + 1]
        self._bounds = bounds.tolist()
        self._bus_sizes, self._bus_starts = np.diff(bounds), bounds[:-1]
        self.ports = PortGroup([link.port for link in self.links])
        # The ports that keep a driver's exception while sending (python-can buses; a socket port
        # counts its failures and keeps none): only theirs are reset and read each cycle.
        self._error_ports = [(b, port) for b, port in enumerate(self.ports.ports) if type(port) is not SocketPort]
        self._no_driver_errors: tuple[BaseException | None, ...] = (None,) * len(self.links)
        self._send_timeouts = [link.send_timeout for link in self.links]
        self._send_retries = [link.max_retries for link in self.links]
        # Every link's counters, one row each, updated in one operation per cycle.
        self._link_counts = np.vstack([link.counts for link in self.links])
        for b, link in enumerate(self.links):
            link.counts = self._link_counts[b]
        self._plan_order = np.arange(len(self.motors))  # the steady state: one reply per motor, in plan order
        self._plan_order_bytes = self._plan_order.tobytes()
        # What a steady read adds to the link counters: every motor's reply received on its bus.
        plan_bus = np.repeat(np.arange(len(self.links)), np.diff(bounds))
        self._steady_counts = np.bincount(plan_bus * 8 + RECEIVED, minlength=self._link_counts.size).reshape(self._link_counts.shape)
        self._no_corrupt = np.zeros(len(self.links), dtype=np.int64)
        self._no_frames = np.zeros(len(self.links), dtype=np.int64)  # expected per bus when draining
        self._all_sent = [(int(size), 0, 0, 0) for size in self._bus_sizes]  # PortGroup.send's outcome when all went out
        self._all_sent_array = np.array(self._all_sent, dtype=np.int64).reshape(len(self.links), 4)
        self._all_sent_array.flags.writeable = False

        self._init_joint_state(description)
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the steady joint-state update and the held command's
        encoder for the arrays this robot passes them (on copies and zeros), so a first compile never
        lands inside a control cycle."""
        m = len(self.motors)
        steady = np.zeros((m, 3))
        joint_state_of_replies(steady, self.group._state_scale, self.group._state_offset, self.joint_index, steady[:, 0].copy(),
                               steady[:, 1].copy(), np.zeros(m, dtype=np.int64), self._joint_state.copy(), self._temperature.copy(),
                               self._error.copy())  # fmt: skip
        self.codec.encode_held(np.zeros((5, self.dofs)), self.joint_index, self.group._command_scale, self.group._command_offset)

    def _init_joint_state(self, description: RobotDescription) -> None:
        """The per-joint state, command and counters every link kind keeps (CAN here, DDS in
        :class:`~giwbc.hal.dds.robot.DdsRobot`), allocated once: the cycle writes into them."""
        dofs = description.dofs
        self._joint_state = np.zeros((3, dofs))  # q, dq, tau: written in one assignment per cycle
        self._q, self._dq, self._tau = self._joint_state
        self._measured = tuple(a.view() for a in (self._q, self._dq, self._tau))  # read-only views, made once
        for view in self._measured:
            view.flags.writeable = False
        self._temperature = np.full(dofs, np.nan)
        self._error = np.full(dofs, -1, dtype=np.int64)
        self._status = np.full(dofs, -1, dtype=np.int64)
        self._stale = np.zeros(dofs, dtype=np.int64)
        self._replied = np.zeros(dofs, dtype=bool)
        self._all_replied = np.ones(dofs, dtype=bool)  # what a cycle where every motor replied reports (read-only)
        self._all_replied.flags.writeable = False
        self._effort = description.effort_limits
        self._neg_effort = -self._effort
        self._gain_scale = 1.0
        self.command = ImpedanceCommand.damping(dofs, 0.0)
        self._held: tuple[Any, ...] | None = None  # (command, its (5, dofs) rows, its fields) when set_joint_impedance made it
        self.clamp_counts = np.zeros((dofs, 5), dtype=np.int64)  # per joint and field, cumulative
        self.cycle = 0
        self._time = 0.0
        self._now = 0.0  # the time of the cycle in progress (host-clock stamp of CAN IMU samples)
        self._imu: ImuReading | None = None
        self._imu_time: float | None = None
        self.late_frames = 0
        self.send_dropped = 0

    @property
    def reply_lag(self) -> int:
        """Cycles from a frame going out to its reply being read: 0 when a cycle waits for the
        replies, 1 when it reads them at the next cycle (``wait_for_replies=False``)."""
        return 0 if self.wait_for_replies else 1

    # --- identity -------------------------------------------------------------------------
    def time(self) -> float:
        """The time of the last exchange (the cycle time the runtime gave it), s."""
        return self._time

    # --- the cycle ------------------------------------------------------------------------
    def exchange(self, t: float, deadline: float | None = None, kind: str = COMMAND) -> CycleReport:
        """One cycle at time ``t``: send the held command (or ``enter``/``exit`` frames) to every
        motor, collect replies until all came, ``reply_timeout`` after sending, or ``deadline``
        (absolute ``perf_counter`` seconds, default: 5 ms from now) passed; read the IMU (the
        report's ``imu_fresh`` says whether a new sample came). Never raises for bus trouble: it is in the report. (With
        ``wait_for_replies=False`` the replies are collected first, see the class docstring.)"""
        if kind not in (COMMAND, ENTER, EXIT):
            raise ValueError(f"exchange kind must be command, enter or exit, got {kind!r}")
        peer = self.peer
        self._now = float(t)
        started = time.perf_counter()
        if peer is not None:
            peer.advance(t)
            if deadline is not None:  # the emulator's work is not the host's: it does not eat the deadline
                deadline += time.perf_counter() - started
        deferred = not self.wait_for_replies
        if deferred:  # the replies to the previous cycle: whatever arrived, without waiting
            received = time.perf_counter()
            replied, corrupt, unknown = self._collect(None)
            late, corrupt_late, unknown_late = 0, 0, 0
            receive_s = time.perf_counter() - received
        else:
            late, corrupt_late, unknown_late = self._drain()
        t0 = time.perf_counter()
        if deadline is None:
            deadline = t0 + self.send_budget
        batch, clamped = self._frames(kind)
        error_ports = self._error_ports
        for _, port in error_ports:
            port.last_error = None
        sent_per_bus = self.ports.send(batch, self._bounds, deadline, timeout=self._send_timeouts, retries=self._send_retries)
        driver_errors = self._no_driver_errors
        if error_ports:
            errors_now = list(driver_errors)
            for b, port in error_ports:
                errors_now[b] = port.last_error
            driver_errors = tuple(errors_now)
        counts = self._link_counts  # += outcomes in the columns SENT, DROPPED, RETRIES (0-2) and BUS_ERRORS
        if sent_per_bus == self._all_sent:  # every frame went out at the first attempt
            outcomes = self._all_sent_array
            counts[:, SENT] += self._bus_sizes
            dropped = 0
        else:
            outcomes = np.array(sent_per_bus)
            counts[:, :3] += outcomes[:, :3]
            counts[:, BUS_ERRORS] += outcomes[:, 3]
            dropped = int(outcomes[:, 1].sum())
        self.send_dropped += dropped
        t1 = sent = time.perf_counter()
        if deferred and peer is not None:
            peer.answer(t)  # lockstep, replies read at the next cycle: the process emulator's timing, deterministic
        if not deferred:
            if peer is not None:
                peer.answer(t)  # the emulator's work is not reply latency: the timeout starts after it
                answered = time.perf_counter()
                deadline += answered - t1
                t1 = answered
            replied, corrupt, unknown = self._collect(min(t1 + self.reply_timeout, deadline))
            receive_s = time.perf_counter() - t1

        if replied is self._all_replied:  # every motor replied: the steady state
            missing = np.zeros(self.dofs, dtype=bool)
            self._stale = np.zeros(self.dofs, dtype=np.int64)
            self._replied.fill(True)
        else:
            missing = ~replied
            self._stale = np.where(replied, 0, self._stale + 1)
            self._replied |= replied
        if not deferred:  # (deferred: nothing was drained)
            corrupt += corrupt_late
        unknown += unknown_late
        imu_fresh = self._read_imu()
        self._time = float(t)
        report = CycleReport(
            self.cycle, float(t), kind, missing, self._stale.copy(), self._error.copy(), self._temperature.copy(),
            late, corrupt, unknown, dropped, clamped, imu_fresh, sent - t0, receive_s,
            self._status.copy(), outcomes[:, 0].copy(), outcomes[:, 3].copy(), driver_errors,
        )  # fmt: skip
        self.cycle += 1
        return report

    def _frames(self, kind: str) -> tuple[np.ndarray, int]:
        """One frame per motor (plan order) and how many fields were clamped."""
        if kind != COMMAND:
            return self.codec.special_frames(kind), 0
        c = self.command
        held = self._held_rows()
        if held is not None:
            fast = self.codec.encode_held(held, self.joint_index, self.group._command_scale, self.group._command_offset)
            if fast is not None:  # one compiled call (a NaN falls through: the general path names it)
                batch, clamp, n_clamped = fast
                if n_clamped:
                    np.add.at(self.clamp_counts, self.joint_index, clamp.astype(np.int64))
                return batch, n_clamped
            rows = held.take(self.joint_index, axis=1)
        else:
            rows = np.array((c.q_ref, c.v_ref, c.kp, c.kd, c.tau_ff), dtype=float)[:, self.joint_index]
        rows = self.group.commands_to_motor(rows)
        encoded = self.codec.encode_rows(rows)
        batch, clamp = encoded if encoded is not None else self.codec.encode_commands(*rows)
        n_clamped = int(np.count_nonzero(clamp))
        if n_clamped:
            np.add.at(self.clamp_counts, self.joint_index, clamp.astype(np.int64))
        return batch, n_clamped

    def _held_rows(self) -> np.ndarray | None:
        """The held command as ``(5, dofs)`` rows (q, v, kp, kd, tau; checked and finite) when
        :meth:`set_joint_impedance` made it and its fields are still those rows' views; None otherwise."""
        c, held = self.command, self._held
        if (held is not None and held[0] is c and c.q_ref is held[2] and c.v_ref is held[3] and c.kp is held[4] and c.kd is held[5]
                and c.tau_ff is held[6]):  # fmt: skip
            return held[1]
        return None

    def _receive(self, deadline: float | None, expect: bool = True) -> tuple[DecodedReplies, np.ndarray, int]:
        """Frames from every bus, decoded together: until each bus's motors all replied or
        ``deadline`` passed, or (``deadline`` None) those already waiting (``expect``: one reply per
        motor is expected to wait, read without probing). Returns the decoded frames (in arrival
        order per bus), the bus of each, and how many frames no protocol can read (CAN FD on a
        classic bus).

        All buses are served together (a silent motor on one bus does not hold up the others), and
        a bus whose frames were not one reply per motor (stray, corrupt or repeated frames) is read
        again for the motors still missing; at the deadline, whatever already waits on those buses
        is read too, so a stray frame never hides a reply that came in time. Copies of a reply
        already waiting when all replied are read as well: the newest copy counts, as it does when
        replies are read at the next cycle."""
        ports, codec = self.ports, self.codec
        if deadline is None:
            got = self._imu_frames(ports.receive(None, self._bus_sizes if expect else self._no_frames, drain=True))
            received = [got]
            batch, bus = got.frames, got.bus
            decoded = codec.decode_replies(bus, batch)
        else:
            got = self._imu_frames(ports.receive(deadline, self._bus_sizes))
            received = [got]
            batch, bus = got.frames, got.bus
            decoded = codec.decode_replies(bus, batch)
            failed = {b for b, error in enumerate(got.errors) if error is not None}
            while True:
                heard = np.zeros(len(self.motors), dtype=bool)
                heard[decoded.index[decoded.verdict == REPLY]] = True
                need = self._bus_sizes - np.add.reduceat(heard, self._bus_starts)
                again = [b for b in np.flatnonzero(need > 0).tolist() if b not in failed]
                if not again:
                    break
                past = time.perf_counter() >= deadline
                more = self._imu_frames(ports.receive(None, None, again) if past else ports.receive(deadline, need, again))
                received.append(more)
                failed.update(b for b, error in enumerate(more.errors) if error is not None)
                if len(more.frames):
                    batch, bus = self._merge(batch, bus, more)
                    decoded = codec.decode_replies(bus, batch)
                if past:
                    break
            live = [b for b in range(len(self.links)) if b not in failed]
            more = self._imu_frames(ports.receive(None, self._no_frames, live, drain=True))  # copies already waiting: one select()
            if len(more.frames):
                received.append(more)
                batch, bus = self._merge(batch, bus, more)
                decoded = codec.decode_replies(bus, batch)
        skipped = 0
        for part in received:
            self._count_received(part)
            skipped += sum(part.skipped)
        if decoded.index.tobytes() == self._plan_order_bytes:  # every motor once, in plan order: all replies, each on its bus
            self._link_counts += self._steady_counts
        elif len(bus):
            self._link_counts += np.bincount(bus * 8 + VERDICT_COLUMNS[decoded.verdict], minlength=self._link_counts.size).reshape(self._link_counts.shape)
        return decoded, bus, skipped

    def _imu_frames(self, got: GroupReceived) -> GroupReceived:
        """Hand the CAN IMU's frames in ``got`` to it; ``got`` without them."""
        if self._can_imu is None or not len(got.frames):
            return got
        on_bus = got.bus == self._imu_bus
        if not on_bus.any():
            return got
        taken = np.zeros(len(got.frames), dtype=bool)
        taken[on_bus] = self._can_imu.take(got.frames[on_bus], now=self._now)
        if not taken.any():
            return got
        return replace(got, frames=got.frames[~taken], bus=got.bus[~taken])

    @staticmethod
    def _merge(batch: np.ndarray, bus: np.ndarray, more: Any) -> tuple[np.ndarray, np.ndarray]:
        """``batch`` and the frames of ``more``, in bus order, arrival order within a bus."""
        order = np.argsort(np.concatenate([bus, more.bus]), kind="stable")
        merged = np.frombuffer(batch.tobytes() + more.frames.tobytes(), dtype=batch.dtype)[order]
        return merged, np.concatenate([bus, more.bus])[order]

    def _count_received(self, got: Any) -> None:
        """Datagrams a read skipped (CAN FD frames) and driver errors, per bus."""
        if any(got.skipped) or any(e is not None for e in got.errors):
            self._link_counts[:, UNKNOWN] += got.skipped
            self._link_counts[:, BUS_ERRORS] += [e is not None for e in got.errors]

    def _drain(self) -> tuple[int, np.ndarray, int]:
        """Read frames already waiting (late replies, stray frames): (late, corrupt per bus, unknown)."""
        decoded, bus, skipped = self._receive(None, expect=False)
        late = decoded.count(REPLY)
        self.late_frames += late
        corrupt = np.bincount(bus[decoded.verdict == CORRUPT], minlength=len(self.links))
        return late, corrupt, len(decoded) - late - int(corrupt.sum()) + skipped

    def _collect(self, deadline: float | None) -> tuple[np.ndarray, np.ndarray, int]:
        """Receive every bus's replies (see :meth:`_receive`) and update the joint state with the
        newest reply of each motor. Returns (replied per joint, corrupt frames per bus, unknown frames)."""
        decoded, bus, skipped = self._receive(deadline)
        if decoded.index.tobytes() == self._plan_order_bytes:  # the steady state: every motor once, in order
            joint_state_of_replies(decoded.state, self.group._state_scale, self.group._state_offset, self.joint_index,
                                   decoded.rotor_temperature, decoded.temperature, decoded.error_code, self._joint_state,
                                   self._temperature, self._error)  # fmt: skip
            self._status[self.joint_index] = decoded.status
            return self._all_replied, self._no_corrupt.copy(), skipped
        corrupt = np.bincount(bus[decoded.verdict == CORRUPT], minlength=len(self.links))
        rows = np.flatnonzero(decoded.verdict == REPLY)
        unknown = len(decoded) - len(rows) - int(corrupt.sum()) + skipped
        index = decoded.index[rows]
        n = len(self.motors)
        if len(index) and np.bincount(index, minlength=n).max() > 1:  # a motor replied twice: the newest counts
            newest = np.full(n, -1, dtype=np.int64)
            np.maximum.at(newest, index, np.arange(len(index)))
            keep = newest[newest >= 0]
            rows, index = rows[keep], index[keep]
        state = self.group.states_to_joint(decoded.state[rows], index)
        j = self.joint_index[index]
        self._joint_state[:, j] = state.T
        rotor, reported = decoded.rotor_temperature[rows], decoded.temperature[rows]
        self._temperature[j] = np.where(np.isnan(rotor), reported, rotor)  # the coil's where reported
        self._error[j] = decoded.error_code[rows]
        self._status[j] = decoded.status[rows]
        replied = np.zeros(self.description.dofs, dtype=bool)
        replied[j] = True
        return replied, corrupt, unknown

    def _read_imu(self) -> bool:
        if self.imu_source is None:
            return False
        reading = self.imu_source.read()
        if reading is None:
            return False
        fresh = self._imu_time is None or reading.time != self._imu_time
        self._imu, self._imu_time = reading, reading.time
        return fresh

    # --- joints ---------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        return self._q.copy()

    def joint_velocities(self) -> np.ndarray:
        return self._dq.copy()

    def joint_efforts(self) -> np.ndarray:
        return self._tau.copy()

    def joint_temperatures(self) -> np.ndarray:
        """Last reported motor temperature per joint (°C, NaN where never reported)."""
        return self._temperature.copy()

    @property
    def replied_once(self) -> np.ndarray:
        """Joints whose motor has replied at least once."""
        return self._replied.copy()

    # --- base, links, contacts, sensors -----------------------------------------------------
    def imu(self) -> ImuReading:
        if self._imu is None:
            raise RuntimeError("no IMU sample yet (no IMU source, or it has not published)")
        return self._imu

    def base_state(self) -> BaseState:
        raise BaseStateUnavailable("the CAN robot measures no base state: wrap it in EstimatedRobot (giwbc.estimation)")

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        raise BaseStateUnavailable(f"the CAN robot measures no link pose ({link!r}): wrap it in EstimatedRobot (giwbc.estimation)")

    def contact_wrench(self, link: str) -> ContactWrench:
        raise BaseStateUnavailable(f"the CAN robot measures no contact force ({link!r}): wrap it in EstimatedRobot (giwbc.estimation)")

    # --- commands -------------------------------------------------------------------------
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        """Torque commands: impedance frames with ``kp = kd = 0``, clipped to the effort limits."""
        zeros = np.zeros(self.dofs)
        self.command = ImpedanceCommand(self._q.copy(), zeros, zeros.copy(), zeros.copy(), np.clip(torques, -self._effort, self._effort))

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        """Hold ``command`` (copied) until the next one; it goes out at every following exchange."""
        try:
            rows = np.array([command.q_ref, command.v_ref, command.kp, command.kd, command.tau_ff], dtype=float)
        except ValueError as error:
            raise ValueError(f"impedance command fields must each have {self.dofs} entries: {error}") from None
        if rows.shape != (5, self.dofs):
            raise ValueError(f"impedance command fields must each have {self.dofs} entries, got shape {rows.shape}")
        if np.count_nonzero(~np.isfinite(rows)):
            raise NonFiniteCommand(f"impedance command is not finite: {command}")
        if np.count_nonzero(rows[2:4] < 0):
            raise ValueError("impedance gains kp and kd must be >= 0")
        torque = rows[4]  # clipped to the effort limits (finite: min(max(.)) is np.clip, without its wrapper)
        np.minimum(np.maximum(torque, self._neg_effort, out=torque), self._effort, out=torque)
        if self._gain_scale != 1.0:
            rows[2:4] *= self._gain_scale
        self.command = ImpedanceCommand(rows[0], rows[1], rows[2], rows[3], rows[4])
        c = self.command
        self._held = (c, rows, c.q_ref, c.v_ref, c.kp, c.kd, c.tau_ff)  # the exchange encodes these rows (the fields are views of them)

    def reduce_limits(self, torque_fraction: float, gain_fraction: float) -> None:
        """A first run (the robot on a gantry): feed-forward torques clamped to ``torque_fraction``
        of the effort limits, and every command's kp and kd scaled by ``gain_fraction`` (both in (0, 1])."""
        if not (0 < torque_fraction <= 1 and 0 < gain_fraction <= 1):
            raise ValueError(f"fractions must be in (0, 1], got torque {torque_fraction}, gains {gain_fraction}")
        self._effort = self.description.effort_limits * torque_fraction
        self._neg_effort = -self._effort
        self._gain_scale = float(gain_fraction)

    # --- latest measurements, without copies (the runtime and the supervisor read them) ---------
    @property
    def measured(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint positions, velocities, efforts as last measured (read-only views of the buffers
        each exchange writes into)."""
        return self._measured  # type: ignore[return-value]

    @property
    def latest_imu(self) -> ImuReading | None:
        return self._imu

    def close(self) -> None:
        """Shut the buses down (motors are not touched: stop them first)."""
        for link in self.links:
            try:
                link.close()
            except Exception:  # noqa: BLE001 - closing must not fail a shutdown
                pass

    def __enter__(self) -> CanRobot:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


__all__ = [
    "COMMAND",
    "ENTER",
    "EXIT",
    "BaseStateUnavailable",
    "CanRobot",
    "NonFiniteCommand",
    "CycleReport",
    "Peer",
]
