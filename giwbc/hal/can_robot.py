"""The Robot interface over CAN actuators: one exchange per control cycle on every bus of a plan.

A cycle (:meth:`CanRobot.exchange`) sends the held command to every motor, one frame each, on
all buses first (buses work in parallel), then collects the replies of every bus until all came
or the reply deadline passed. MIT mode is request/response: the replies carry the state the motors
measured when the command arrived, so the command computed from them goes out at the next cycle.

- **State** is joint side (sign, zero offset and gear ratio applied by the plan's ``MotorGroup``);
  a motor that did not reply keeps its last values and its ``stale`` count grows.
- **Commands** are per-joint impedance frames; :meth:`set_joint_torques` sends impedance frames with
  ``kp = kd = 0`` and the torque as feed-forward. All motors are encoded in one vectorized call.
- **Late frames**: before sending, frames already waiting (replies that missed an earlier deadline)
  are drained and counted as late, never taken as this cycle's replies.
- **IMU** comes from an :class:`ImuSource` (``emulated``: the emulator's :class:`ImuChannel`).
- **Base state** is not measured on hardware: it comes from an attached
  :class:`~giwbc.robot.estimator.StateEstimator`, updated once per exchange. Without one,
  :meth:`base_state` raises :class:`BaseStateUnavailable` (never ground truth from a simulator).
- ``peer``: an in-process stand-in for the motors (:class:`Peer`, the emulator): told that time
  reached the cycle time before draining (``advance``), and to answer after sending (``answer``),
  so it runs in lockstep (see :mod:`giwbc.hal.emulator`); None on hardware.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import can
import numpy as np

from giwbc.hal.bus import CanBusLink
from giwbc.hal.hardware import HardwarePlan, ImuConfig
from giwbc.hal.motor import MotorGroup
from giwbc.hal.protocols import CanProtocolError, MitProtocol, UnknownMotorError
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, DescribedRobot, ImuReading

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription
    from giwbc.robot.estimator import Estimate, StateEstimator

COMMAND, ENTER, EXIT = "command", "enter", "exit"
_SEND_BUDGET = 5e-3  # s: how long sending may take when the caller gives no deadline


class BaseStateUnavailable(RuntimeError):
    """The CAN robot measures no base state: attach an estimator."""


class NonFiniteCommand(ValueError):
    """A command with NaN or infinite entries (from a policy or controller): never sent."""


class FastMessage(can.Message):
    """A ``can.Message`` whose deep copy is cheap.

    python-can's ``virtual`` interface deep-copies every frame for every receiver; the generic
    ``Message.__deepcopy__`` costs ~13 us (it deep-copies the ``bytearray``), this one ~3 us.
    Other interfaces only read the attributes, so to them it is a plain message.
    """

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, Any] | None) -> FastMessage:
        c = _new(FastMessage)
        c.timestamp = self.timestamp
        c.arbitration_id = self.arbitration_id
        c.is_extended_id = self.is_extended_id
        c.is_remote_frame = self.is_remote_frame
        c.is_error_frame = self.is_error_frame
        c.channel = self.channel
        c.dlc = self.dlc
        c.data = bytearray(self.data)
        c.is_fd = self.is_fd
        c.is_rx = self.is_rx
        c.bitrate_switch = self.bitrate_switch
        c.error_state_indicator = self.error_state_indicator
        return c


def fast_message(arbitration_id: int, data: bytes, is_extended_id: bool = False) -> FastMessage:
    """A data frame (what ``can.Message(arbitration_id=..., data=..., is_extended_id=...)`` makes,
    built without the generic constructor's argument handling: this runs ~60 times per cycle)."""
    c = _new(FastMessage)
    c.timestamp = 0.0
    c.arbitration_id = arbitration_id
    c.is_extended_id = is_extended_id
    c.is_remote_frame = False
    c.is_error_frame = False
    c.channel = None
    c.data = bytearray(data)
    c.dlc = len(c.data)
    c.is_fd = False
    c.is_rx = True
    c.bitrate_switch = False
    c.error_state_indicator = False
    return c


_new = FastMessage.__new__


class Peer(Protocol):
    """The motors' side of the buses when it runs in this process (the emulator)."""

    def advance(self, now: float) -> None:
        """Time reached ``now``: physics, and replies that became due, happen."""

    def answer(self, now: float) -> None:
        """Answer the frames waiting on the buses."""


class ImuSource(Protocol):
    """Where IMU samples come from: ``read()`` returns the newest sample (None before the first)."""

    def read(self) -> ImuReading | None: ...


class ImuChannel:
    """In-process mailbox for IMU samples: a producer (the emulator) publishes, the robot reads."""

    def __init__(self) -> None:
        self._latest: ImuReading | None = None
        self.published = 0

    def publish(self, reading: ImuReading) -> None:
        self._latest = reading
        self.published += 1

    def read(self) -> ImuReading | None:
        return self._latest


def imu_source_for(config: ImuConfig, channel: ImuChannel | None = None) -> ImuSource:
    """The IMU source a plan asks for. ``emulated`` needs the emulator's channel; ``serial`` and
    ``can`` IMUs have no driver yet and raise ``NotImplementedError`` naming what is missing."""
    if config.source == "emulated":
        if channel is None:
            raise ValueError("the hardware plan's IMU is 'emulated': it exists only with the actuator emulator (--emulate)")
        return channel
    where = config.device if config.source == "serial" else f"bus {config.bus} id 0x{config.can_id or 0:X}"
    raise NotImplementedError(f"no driver for a {config.source!r} IMU ({where}) yet; use an emulated IMU")


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

    @property
    def complete(self) -> bool:
        return not bool(self.missing.any())


@dataclass
class _Tally:
    """Frames a cycle could not use: undecodable per bus, and unknown (error, remote, no such motor)."""

    corrupt: np.ndarray
    unknown: int = 0


class CanRobot(DescribedRobot):
    """A robot whose joints are the CAN actuators of ``plan`` (see the module docstring).

    ``links``: open :class:`CanBusLink` per bus in plan order (default: opened from the plan).
    ``reply_timeout``: how long after sending a cycle waits for replies at most (s).
    ``wait_for_replies=False``: a cycle does not wait; it first takes the frames that arrived
    since the last one (the replies to the previous cycle's commands: state one period old), then
    sends. The loop then never blocks on the bus, which suits motors that answer later than a
    fraction of the period (the emulator in its own process); a reply missing at the next cycle
    counts as missing.
    """

    def __init__(
        self,
        description: RobotDescription,
        plan: HardwarePlan,
        *,
        imu: ImuSource | None = None,
        estimator: StateEstimator | None = None,
        peer: Peer | None = None,
        links: Sequence[CanBusLink] | None = None,
        reply_timeout: float = 0.8e-3,
        wait_for_replies: bool = True,
    ) -> None:
        self.description = description
        self.plan = plan
        names = description.joint_names
        plan.routing(names)  # validates: one motor per joint
        self.links = list(links) if links is not None else [b.open_link() for b in plan.buses]
        if len(self.links) != len(plan.buses):
            raise ValueError(f"{len(self.links)} links for {len(plan.buses)} buses")
        self.imu_source = imu
        self.estimator = estimator
        self.peer = peer
        self.reply_timeout = float(reply_timeout)
        self.wait_for_replies = bool(wait_for_replies)
        if peer is not None and not self.wait_for_replies:
            raise ValueError("a lockstep peer answers within the cycle: wait_for_replies=False needs motors with a clock of their own")

        self.motors = plan.motors
        self.group = MotorGroup(self.motors)
        n = len(self.motors)
        self.joint_index = np.array([names.index(m.joint) for m in self.motors], dtype=np.int64)
        self._ids = [m.can_id for m in self.motors]
        self._bus_slices: list[slice] = []
        self._slot: list[dict[int, int]] = []
        first = 0
        for bus in plan.buses:
            self._bus_slices.append(slice(first, first + len(bus.motors)))
            self._slot.append({m.can_id: first + i for i, m in enumerate(bus.motors)})
            first += len(bus.motors)
        self._encoder = _one_encoder(self.links, self.motors)

        dofs = description.dofs
        self._q = np.zeros(dofs)
        self._dq = np.zeros(dofs)
        self._tau = np.zeros(dofs)
        self._temperature = np.full(dofs, np.nan)
        self._error = np.full(dofs, -1, dtype=np.int64)
        self._stale = np.zeros(dofs, dtype=np.int64)
        self._replied = np.zeros(dofs, dtype=bool)
        self._effort = description.effort_limits
        self.command = ImpedanceCommand.damping(dofs, 0.0)
        self.clamp_counts = np.zeros((dofs, 5), dtype=np.int64)  # per joint and field, cumulative
        self.cycle = 0
        self._time = 0.0
        self._imu: ImuReading | None = None
        self._imu_time: float | None = None
        self._estimate: Estimate | None = None
        self.late_frames = 0
        self.send_dropped = 0
        self._pin: Any = None

    # --- identity -------------------------------------------------------------------------
    def time(self) -> float:
        """The time of the last exchange (the cycle time the runtime gave it), s."""
        return self._time

    # --- the cycle ------------------------------------------------------------------------
    def exchange(self, t: float, deadline: float | None = None, kind: str = COMMAND) -> CycleReport:
        """One cycle at time ``t``: send the held command (or ``enter``/``exit`` frames) to every
        motor, collect replies until all came, ``reply_timeout`` after sending, or ``deadline``
        (absolute ``perf_counter`` seconds, default: 5 ms from now) passed; read the IMU and update
        the estimator. Never raises for bus trouble: it is in the report. (With
        ``wait_for_replies=False`` the replies are collected first, see the class docstring.)"""
        if kind not in (COMMAND, ENTER, EXIT):
            raise ValueError(f"exchange kind must be command, enter or exit, got {kind!r}")
        peer = self.peer
        started = time.perf_counter()
        if peer is not None:
            peer.advance(t)
            if deadline is not None:  # the emulator's work is not the host's: it does not eat the deadline
                deadline += time.perf_counter() - started
        deferred = not self.wait_for_replies
        if deferred:  # the replies to the previous cycle: whatever arrived, without waiting
            received = time.perf_counter()
            replied, corrupt, unknown = self._collect(received)
            late, corrupt_late, unknown_late = 0, 0, 0
            receive_s = time.perf_counter() - received
        else:
            late, corrupt_late, unknown_late = self._drain()
        t0 = time.perf_counter()
        if deadline is None:
            deadline = t0 + _SEND_BUDGET
        messages, clamped = self._frames(kind)
        dropped = 0
        for link, sl in zip(self.links, self._bus_slices):
            dropped += _send(link, messages[sl], deadline)
        self.send_dropped += dropped
        t1 = sent = time.perf_counter()
        if not deferred:
            if peer is not None:
                peer.answer(t)  # the emulator's work is not reply latency: the timeout starts after it
                answered = time.perf_counter()
                deadline += answered - t1
                t1 = answered
            limit = min(t1 + self.reply_timeout, deadline)
            replied, corrupt, unknown = self._collect(limit)
            receive_s = time.perf_counter() - t1

        missing = ~replied
        self._stale = np.where(replied, 0, self._stale + 1)
        self._replied |= replied
        corrupt += corrupt_late
        unknown += unknown_late
        imu_fresh = self._read_imu()
        self._time = float(t)
        if self.estimator is not None and imu_fresh:
            from giwbc.robot.estimator import Measurement

            self._estimate = self.estimator.update(Measurement(self._imu, self._q.copy(), self._dq.copy(), self._tau.copy()))
        report = CycleReport(
            self.cycle, float(t), kind, missing, self._stale.copy(), self._error.copy(), self._temperature.copy(),
            late, corrupt, unknown, dropped, clamped, imu_fresh, sent - t0, receive_s,
        )  # fmt: skip
        self.cycle += 1
        return report

    def _frames(self, kind: str) -> tuple[list[FastMessage], int]:
        """One frame per motor (plan order) and how many fields were clamped."""
        ids = self._ids
        if kind == COMMAND:
            c, j = self.command, self.joint_index
            p, v, kp, kd, tau = self.group.command_to_motor(c.q_ref[j], c.v_ref[j], c.kp[j], c.kd[j], c.tau_ff[j])
            data, clamp = self._encoder(p, v, kp, kd, tau)
            n_clamped = int(np.count_nonzero(clamp))
            if n_clamped:
                np.add.at(self.clamp_counts, j, clamp.astype(np.int64))
            raw = data.tobytes()
            return [fast_message(a, raw[8 * i : 8 * i + 8]) for i, a in enumerate(ids)], n_clamped
        out = []
        for link, sl in zip(self.links, self._bus_slices):
            protocol = link.protocol
            make = protocol.enter_motor_mode if kind == ENTER else protocol.exit_motor_mode
            for motor_id in ids[sl]:
                f = make(motor_id)
                out.append(fast_message(f.arbitration_id, f.data, f.is_extended_id))
        return out, 0

    def _replies(self, b: int, deadline: float, tally: _Tally, expected: int | None = None) -> Iterator[Any]:
        """Decoded motor replies arriving on bus ``b`` until ``deadline`` (absolute ``perf_counter``
        seconds; a past deadline reads only what is already waiting) or, with ``expected``, until
        that many distinct motors replied. Error, remote and unknown frames and undecodable ones are counted
        in ``tally``; a driver error ends the bus's reading. A bus that hands over its whole queue
        at once (``drain``, giwbc-unix) is read that way when there is nothing to wait for."""
        link = self.links[b]
        bus, decode = link.bus, link.protocol.decode
        clock = time.perf_counter
        drain = getattr(bus, "drain", None)
        seen: set[int] | None = None
        if drain is not None and deadline <= clock():
            try:
                frames: Iterable[can.Message] = drain()
            except (can.CanError, OSError):
                return
        else:
            frames = _received(bus, deadline)
            seen = set() if expected is not None else None
        if expected == 0:
            return
        for msg in frames:
            if msg.is_error_frame or msg.is_remote_frame:
                tally.unknown += 1
                continue
            try:
                reply = decode(msg.arbitration_id, msg.data, msg.is_extended_id)
            except UnknownMotorError:
                tally.unknown += 1
                continue
            except CanProtocolError:
                tally.corrupt[b] += 1
                continue
            yield reply
            if seen is not None:  # waiting for the bus's replies: stop once every motor's came
                seen.add(reply.motor_id)
                if len(seen) >= expected:  # type: ignore[operator]
                    return

    def _drain(self) -> tuple[int, np.ndarray, int]:
        """Read frames already waiting (late replies, stray frames): (late, corrupt per bus, unknown)."""
        tally = _Tally(np.zeros(len(self.links), dtype=np.int64))
        late = sum(1 for b in range(len(self.links)) for _ in self._replies(b, 0.0, tally))
        self.late_frames += late
        return late, tally.corrupt, tally.unknown

    def _collect(self, deadline: float) -> tuple[np.ndarray, np.ndarray, int]:
        """Receive every bus's replies until each is complete or ``deadline`` passed; update the
        joint state. Returns (replied per joint, corrupt frames per bus, unknown frames)."""
        n = len(self.motors)
        got = np.zeros(n, dtype=bool)
        pos, vel, tor = np.zeros(n), np.zeros(n), np.zeros(n)
        temp = np.full(n, np.nan)
        err = np.full(n, -1, dtype=np.int64)
        tally = _Tally(np.zeros(len(self.links), dtype=np.int64))
        for b, slot in enumerate(self._slot):
            for r in self._replies(b, deadline, tally, expected=len(slot)):
                i = slot[r.motor_id]
                got[i] = True
                pos[i], vel[i], tor[i] = r.position, r.velocity, r.torque
                temperature = r.rotor_temperature if r.rotor_temperature is not None else r.temperature
                if temperature is not None:
                    temp[i] = temperature
                if r.error_code is not None:
                    err[i] = r.error_code
        q, dq, tau = self.group.state_to_joint(pos, vel, tor)
        j = self.joint_index[got]
        self._q[j], self._dq[j], self._tau[j] = q[got], dq[got], tau[got]
        self._temperature[j], self._error[j] = temp[got], err[got]
        replied = np.zeros(self.description.dofs, dtype=bool)
        replied[j] = True
        return replied, tally.corrupt, tally.unknown

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

    @property
    def estimate(self) -> Estimate:
        """The estimator's latest output."""
        if self.estimator is None:
            raise BaseStateUnavailable(
                "the CAN robot measures no base state: attach a StateEstimator (CanRobot(..., estimator=...))"
            )
        if self._estimate is None:
            return self.estimator.estimate
        return self._estimate

    def base_state(self) -> BaseState:
        return self.estimate.base

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The estimate's Pinocchio ``(q, v)`` (base from the estimator, joints as measured)."""
        if not self.floating_base:
            return self.joint_positions(), self.joint_velocities()
        estimate = self.estimate
        return estimate.q.copy(), estimate.v.copy()

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """A link's world pose at the estimated configuration."""
        import pinocchio as pin

        if self._pin is None:
            model = self.description.build_pinocchio()
            self._pin = (model, model.createData())
        model, data = self._pin
        frame = model.getFrameId(link)
        if frame >= model.nframes:
            raise KeyError(f"robot {self.name!r} has no link {link!r}")
        pin.framesForwardKinematics(model, data, self.generalized_state()[0])
        placement = data.oMf[frame]
        return placement.translation.copy(), placement.rotation.copy()

    def contact_wrench(self, link: str) -> ContactWrench:
        """The estimator's ground force on a contact link (acting at its sole centre)."""
        contacts = self.description.contacts
        names = [c.link for c in contacts]
        if link not in names:
            raise KeyError(f"no contact on link {link!r}; contacts are on {names}")
        k = names.index(link)
        estimate = self.estimate
        force = np.asarray(estimate.contact_forces[k], dtype=float)
        _, rotation = self.link_pose(link)
        lever = rotation @ np.asarray(contacts[k].center, dtype=float)
        return ContactWrench(force.copy(), np.cross(lever, force), bool(estimate.contacts[k]))

    # --- commands -------------------------------------------------------------------------
    def set_joint_torques(self, torques: np.ndarray) -> None:
        """Torque commands: impedance frames with ``kp = kd = 0``, clipped to the effort limits."""
        torques = np.asarray(torques, dtype=float)
        if torques.shape != (self.dofs,):
            raise ValueError(f"expected {self.dofs} joint torques, got shape {torques.shape}")
        if not np.all(np.isfinite(torques)):
            raise NonFiniteCommand(f"joint torques are not finite: {torques}")
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
        if not np.isfinite(rows).all():
            raise NonFiniteCommand(f"impedance command is not finite: {command}")
        if (rows[2:4] < 0).any():
            raise ValueError("impedance gains kp and kd must be >= 0")
        np.clip(rows[4], -self._effort, self._effort, out=rows[4])
        self.command = ImpedanceCommand(rows[0], rows[1], rows[2], rows[3], rows[4])

    # --- latest measurements, without copies (the runtime and the supervisor read them) ---------
    @property
    def measured(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint positions, velocities, efforts as last measured (read-only views)."""
        views = tuple(a.view() for a in (self._q, self._dq, self._tau))
        for v in views:
            v.flags.writeable = False
        return views  # type: ignore[return-value]

    @property
    def latest_imu(self) -> ImuReading | None:
        return self._imu

    @property
    def latest_estimate(self) -> Estimate | None:
        """The estimate of the last exchange (None without an estimator or before its first update)."""
        return self._estimate

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


def _received(bus: can.BusABC, deadline: float) -> Iterator[can.Message]:
    """Frames from ``bus`` until ``deadline`` (absolute ``perf_counter`` s) passes or a driver error."""
    clock = time.perf_counter
    while True:
        left = deadline - clock()
        try:
            msg = bus.recv(timeout=left if left > 0 else 0.0)
        except (can.CanError, OSError):
            return
        if msg is None:
            return
        yield msg


def _send(link: CanBusLink, messages: Sequence[can.Message], deadline: float) -> int:
    """Send in order with the link's retry policy; returns how many were dropped (never raises)."""
    bus, dropped = link.bus, 0
    for k, msg in enumerate(messages):
        attempt = 0
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                return dropped + len(messages) - k
            try:
                bus.send(msg, timeout=min(link.send_timeout, left))
            except (can.CanError, OSError):
                if attempt >= link.max_retries:
                    dropped += 1
                    break
                attempt += 1
            else:
                break
    return dropped


def _one_encoder(links: Sequence[CanBusLink], motors: Sequence[Any]) -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """A function encoding every motor's command at once: ``(p, v, kp, kd, tau) -> (data (N, 8),
    clamped (N, 5))``, plan order.

    When every bus speaks MIT mode, one :class:`MitProtocol` over all motors does it in a single
    vectorized call (command payloads do not depend on CAN ids, so the motors are renumbered to
    make ids unique across buses); otherwise each bus's protocol encodes its slice.
    """
    if all(type(link.protocol) is MitProtocol for link in links) and len(motors) <= 0xFF:
        encoder = MitProtocol([replace(m, can_id=i + 1, reply="original") for i, m in enumerate(motors)])

        def encode(*values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            batch = encoder.encode_commands(*values)
            return batch.data, batch.clamped

        return encode

    sizes = [len(link.protocol.motors) for link in links]
    bounds = np.cumsum([0, *sizes])

    def encode_per_bus(*values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        data, clamped = [], []
        for link, a, b in zip(links, bounds[:-1], bounds[1:]):
            batch = link.protocol.encode_commands(*(v[a:b] for v in values))
            data.append(batch.data)
            clamped.append(batch.clamped)
        return np.vstack(data), np.vstack(clamped)

    return encode_per_bus


__all__ = [
    "COMMAND",
    "ENTER",
    "EXIT",
    "BaseStateUnavailable",
    "CanRobot",
    "NonFiniteCommand",
    "CycleReport",
    "FastMessage",
    "ImuChannel",
    "ImuSource",
    "Peer",
    "fast_message",
    "imu_source_for",
]
