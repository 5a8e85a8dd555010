"""Motor bring-up on a hardware plan: scan, read without torque, set zero, calibrate sign and
zero offset, check joints against their limits, and the first-run (gantry) settings.

How state is read **without torque**: MIT-mode firmware (Ben Katz's, CubeMars, Damiao) answers
every frame addressed to it with one reply carrying position, velocity and torque, whether the
motor is enabled or not; a disabled motor ignores the command itself. The probe here is the
zero-gain command, ``kp = kd = 0`` and ``torque = 0``, which produces no torque even on a motor
left in motor mode (it makes such a motor limp: bring-up is for a robot that hangs or lies
down). Nothing here sends "enter motor mode". Unknown ids (a scan beyond the plan) get the same
frame with mid-range position, velocity and torque codes (0 in any symmetric range) and zero gains.

Every function works on a :class:`BringupLink`: the plan's buses, one request at a time, replies
collected until a timeout (``peer``: the actuator emulator answering in lockstep, for dry runs
and tests; it is told to answer, never to advance physics, so the emulated robot holds still).

Calibration, per joint (:func:`calibrate_joint`): with the robot in a known posture ``q_known``
(joint angles from the model, e.g. hanging straight on a gantry), the motor reads ``p0``; the
operator moves that joint by hand in its positive direction (as the model defines it) and the
motor reads ``p1``. Then ``sign = sign(p1 - p0)`` and ``zero_offset = q_known - sign * p0 /
gear_ratio`` (the joint angle at which the motor reads 0, :mod:`giwbc.hal.motor`). The result is
refused when the move was too small to tell, or when the known or moved posture falls outside
the joint's limits under the new calibration.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import can
import numpy as np

from giwbc.errors import HardwareConfigError
from giwbc.hal.hardware import BusConfig, HardwarePlan
from giwbc.hal.motor import MotorConfig
from giwbc.hal.protocols import ActuatorProtocol, CanProtocolError, MotorReply
from giwbc.hal.protocols.base import CanFrame
from giwbc.hal.safety import SafetyConfig

PROBE_UNKNOWN = bytes.fromhex("7FFF7FF0000007FF")  # p mid, v mid, kp 0, kd 0, t mid (MIT bit layout)
DAMIAO_STATES = frozenset({0, 1, 8, 9, 10, 11, 12, 13, 14})


class Peer(Protocol):
    """The motors' side when it runs in this process (the emulator): answers waiting frames."""

    time: float

    def answer(self, now: float) -> None: ...


# ----------------------------------------------------------------------------- transport
class BringupLink:
    """The host side of a plan's buses for bring-up: request/reply, one bus at a time.

    ``buses``: open python-can buses by bus name (default: opened from the plan). ``timeout``:
    how long to wait for replies on hardware (s); with a ``peer`` the replies are already there.
    """

    def __init__(
        self,
        plan: HardwarePlan,
        *,
        buses: Mapping[str, can.BusABC] | None = None,
        peer: Peer | None = None,
        timeout: float = 0.02,
    ) -> None:
        self.plan = plan
        self.peer = peer
        self.timeout = timeout
        self._own = buses is None
        self.buses: dict[str, can.BusABC] = dict(buses) if buses is not None else {b.name: b.open() for b in plan.buses}
        self.protocols: dict[str, ActuatorProtocol] = {b.name: b.make_protocol() for b in plan.buses}
        self.sent = 0

    def request(self, bus: str, frames: Sequence[CanFrame], expect: int | None = None) -> list[can.Message]:
        """Send ``frames`` on ``bus``, return the data frames received until ``expect`` of them came
        or the timeout passed (frames already waiting are discarded first: they answer nothing
        asked here)."""
        b = self.buses[bus]
        while b.recv(0.0) is not None:
            pass
        for f in frames:
            b.send(can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=f.is_extended_id))
            self.sent += 1
        if self.peer is not None:
            self.peer.answer(self.peer.time)
        out: list[can.Message] = []
        deadline = time.monotonic() + (0.0 if self.peer is not None else self.timeout)
        while expect is None or len(out) < expect:
            msg = b.recv(max(0.0, deadline - time.monotonic()))
            if msg is None:
                break
            if not (msg.is_error_frame or msg.is_remote_frame):
                out.append(msg)
        return out

    def close(self) -> None:
        if self._own:
            for b in self.buses.values():
                b.shutdown()

    def __enter__(self) -> BringupLink:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def probe_frame(protocol: ActuatorProtocol, motor_id: int) -> CanFrame:
    """The zero-gain, zero-torque command for a motor of the protocol, or the generic probe."""
    try:
        return protocol.encode_command(motor_id, 0.0, 0.0, 0.0, 0.0, 0.0).frame
    except CanProtocolError:
        return CanFrame(motor_id, PROBE_UNKNOWN)


# ----------------------------------------------------------------------------- scan
@dataclass(frozen=True)
class Answer:
    """A reply to a probe of one id: its length and byte 0 tell the firmware family."""

    bus: str
    motor_id: int
    length: int
    variant: str  # see reply_variant
    reply: MotorReply | None  # decoded when the id is in the plan on this bus


@dataclass(frozen=True)
class ScanReport:
    answers: tuple[Answer, ...]
    missing: tuple[tuple[str, int, str], ...]  # (bus, id, joint) planned, no answer
    extra: tuple[tuple[str, int], ...]  # (bus, id) answered, not planned there
    wrong_bus: tuple[tuple[str, int, str, str], ...]  # (joint, id, planned bus, bus where that id answered)

    @property
    def ok(self) -> bool:
        return not (self.missing or self.extra)

    def __str__(self) -> str:
        lines = [f"{len(self.answers)} motor(s) answered"]
        for a in self.answers:
            lines.append(f"  {a.bus} id {a.motor_id}: {a.variant} reply ({a.length} bytes)")
        for bus, i, joint in self.missing:
            lines.append(f"MISSING {joint!r}: no answer from id {i} on {bus}")
        for bus, i in self.extra:
            lines.append(f"EXTRA id {i} on {bus}: answers but the plan has no motor there")
        for joint, i, planned, seen in self.wrong_bus:
            lines.append(f"WRONG BUS? {joint!r} is planned as id {i} on {planned}; id {i} answers on {seen}")
        return "\n".join(lines)


def reply_variant(motor_id: int, data: bytes) -> str:
    """The MIT reply family a reply's length and byte 0 suggest (see :mod:`giwbc.hal.protocols.mit`):
    ``original`` (6 bytes), ``voltage`` (7), ``cubemars`` (8, byte 0 = id), ``damiao`` (8, byte 0 =
    state << 4 | id & 0xF with a nonzero state), ``cubemars|damiao`` (8 bytes, byte 0 = id < 16: a
    disabled Damiao motor looks exactly like a CubeMars one), or ``unknown``."""
    if not data:
        return "unknown"
    b0 = data[0]
    if b0 == motor_id:
        if len(data) == 8:
            return "cubemars|damiao" if motor_id < 16 else "cubemars"
        return {6: "original", 7: "voltage"}.get(len(data), "unknown")
    if len(data) == 8 and (b0 & 0x0F) == (motor_id & 0x0F) and (b0 >> 4) in DAMIAO_STATES:
        return "damiao"
    return "unknown"


def scan(
    link: BringupLink, ids: Iterable[int] = range(1, 33), buses: Sequence[str] | None = None, retries: int = 2
) -> ScanReport:
    """Probe every id of ``ids`` (and every planned id) on every bus, one at a time, and compare
    who answered with the plan; a planned id that is silent is probed ``retries`` more times."""
    plan = link.plan
    answers: list[Answer] = []
    names = list(buses) if buses is not None else [b.name for b in plan.buses]
    for name in names:
        cfg = plan.bus(name)
        protocol = link.protocols[name]
        planned = {m.can_id for m in cfg.motors}
        for i in sorted(set(ids) | planned):
            got = link.request(name, [probe_frame(protocol, i)])
            for _ in range(retries if i in planned and not got else 0):  # a planned motor gets more tries
                got = link.request(name, [probe_frame(protocol, i)])
                if got:
                    break
            for msg in got:
                if cfg.host_id is not None and msg.arbitration_id != cfg.host_id and msg.arbitration_id != i:
                    continue  # not a reply to us
                data = bytes(msg.data)
                variant = reply_variant(i, data)
                if variant == "unknown":
                    continue
                reply = None
                if i in planned:
                    try:
                        reply = protocol.decode(msg.arbitration_id, data, msg.is_extended_id)
                    except CanProtocolError:
                        reply = None
                answers.append(Answer(name, i, len(data), variant, reply))
                break
    found = {(a.bus, a.motor_id) for a in answers}
    missing = tuple((b.name, m.can_id, m.joint) for b in plan.buses if b.name in names for m in b.motors if (b.name, m.can_id) not in found)
    planned_at = {(b.name, m.can_id) for b in plan.buses for m in b.motors}
    extra = tuple(sorted(k for k in found if k not in planned_at))
    wrong = tuple((joint, i, bus, other) for bus, i, joint in missing for other, j in extra if j == i and other != bus)
    return ScanReport(tuple(answers), missing, extra, wrong)


# ----------------------------------------------------------------------------- monitor
@dataclass(frozen=True)
class JointReadings:
    """Joint-side state of every planned motor (plan order), read without torque."""

    joints: tuple[str, ...]
    motor_position: np.ndarray  # motor side, rad (raw: no sign or offset)
    position: np.ndarray  # joint side (sign, zero_offset, gear applied), rad
    velocity: np.ndarray
    torque: np.ndarray
    temperature: np.ndarray  # °C, NaN where the reply carries none
    error_code: np.ndarray  # -1 where unknown
    replied: np.ndarray  # bool

    def table(self, limits: Mapping[str, tuple[float, float]] | None = None) -> str:
        """A terminal table: joint, position (rad and deg), velocity, torque, temperature, flags."""
        head = f"{'joint':<28} {'q rad':>8} {'q deg':>8} {'dq':>7} {'tau':>7} {'T °C':>6}  flags"
        rows = [head]
        for k, j in enumerate(self.joints):
            if not self.replied[k]:
                rows.append(f"{j:<28} {'--':>8} {'--':>8} {'--':>7} {'--':>7} {'--':>6}  NO REPLY")
                continue
            flags = []
            if self.error_code[k] > 0:
                flags.append(f"error {self.error_code[k]}")
            if limits and j in limits and not limits[j][0] <= self.position[k] <= limits[j][1]:
                flags.append("OUTSIDE LIMITS")
            t = "" if math.isnan(self.temperature[k]) else f"{self.temperature[k]:.0f}"
            rows.append(
                f"{j:<28} {self.position[k]:8.3f} {math.degrees(self.position[k]):8.1f} {self.velocity[k]:7.2f} "
                f"{self.torque[k]:7.2f} {t:>6}  {' '.join(flags)}"
            )
        return "\n".join(rows)


def read_joints(link: BringupLink, joints: Sequence[str] | None = None) -> JointReadings:
    """Probe the planned motors (or those of ``joints``), all of a bus at once, and convert each
    reply to the joint side; a motor that did not answer within the link's timeout is NaN."""
    plan = link.plan
    names = tuple(joints) if joints is not None else plan.joints
    n = len(names)
    raw, pos, vel, tau, temp = (np.full(n, np.nan) for _ in range(5))
    err = np.full(n, -1, dtype=np.int64)
    ok = np.zeros(n, dtype=bool)
    by_bus: dict[str, list[int]] = {}
    for k, joint in enumerate(names):
        by_bus.setdefault(plan.motor(joint)[0].name, []).append(k)
    for bus_name, rows in by_bus.items():
        replies = _read_motors(link, plan.bus(bus_name), [plan.motor(names[k])[1] for k in rows])
        for k in rows:
            _, motor = plan.motor(names[k])
            reply = replies.get(motor.can_id)
            if reply is None:
                continue
            ok[k] = True
            raw[k] = reply.position
            pos[k] = motor.position_to_joint(reply.position)
            vel[k] = motor.velocity_to_joint(reply.velocity)
            tau[k] = motor.torque_to_joint(reply.torque)
            temp[k] = reply.temperature if reply.temperature is not None else np.nan
            err[k] = reply.error_code if reply.error_code is not None else -1
    return JointReadings(names, raw, pos, vel, tau, temp, err, ok)


def _read_motors(link: BringupLink, bus: BusConfig, motors: Sequence[MotorConfig], attempts: int = 3) -> dict[int, MotorReply]:
    """Probe each of ``motors`` (on ``bus``) and decode the replies, by CAN id; motors that did not
    answer are probed again, ``attempts`` times in all (a frame lost on a busy bus is not a dead motor)."""
    protocol = link.protocols[bus.name]
    out: dict[int, MotorReply] = {}
    for _ in range(attempts):
        todo = [m for m in motors if m.can_id not in out]
        if not todo:
            break
        wanted = {m.can_id for m in todo}
        for msg in link.request(bus.name, [probe_frame(protocol, m.can_id) for m in todo], expect=len(todo)):
            try:
                reply = protocol.decode(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
            except CanProtocolError:
                continue  # foreign traffic
            if reply.motor_id in wanted:
                out[reply.motor_id] = reply
    return out


def _read_motor(link: BringupLink, bus: BusConfig, motor: MotorConfig) -> MotorReply | None:
    return _read_motors(link, bus, [motor]).get(motor.can_id)


def limit_violations(
    joints: Sequence[str], position: np.ndarray, limits: Mapping[str, tuple[float, float]], margin: float = 0.0
) -> list[str]:
    """Clear messages for joints whose position is outside ``[lo - margin, hi + margin]``."""
    out = []
    for j, q in zip(joints, position):
        if j not in limits or not math.isfinite(q):
            continue
        lo, hi = limits[j]
        if not lo - margin <= q <= hi + margin:
            out.append(
                f"joint {j!r} reads {q:.3f} rad ({math.degrees(q):.1f} deg), outside its limits [{lo:.3f}, {hi:.3f}] rad: "
                "its sign or zero_offset is wrong (run `giwbc motors calibrate`), or the joint really is there "
                "(move it back by hand, motors off)"
            )
    return out


def description_limits(joint_names: Sequence[str], lower: np.ndarray, upper: np.ndarray) -> dict[str, tuple[float, float]]:
    """``{joint: (lower, upper)}`` from a description's position limits (finite ones only)."""
    return {j: (float(lo), float(hi)) for j, lo, hi in zip(joint_names, lower, upper) if np.isfinite(lo) and np.isfinite(hi)}


# ----------------------------------------------------------------------------- zero
@dataclass(frozen=True)
class ZeroRecord:
    joint: str
    bus: str
    motor_id: int
    joint_angle: float  # where the joint was when its motor was zeroed: the new zero_offset
    motor_before: float  # motor position read before
    motor_after: float  # and after (should be ~0)


def set_zero(link: BringupLink, joint: str, joint_angle: float = 0.0) -> ZeroRecord:
    """Make the motor of ``joint`` read 0 where it stands (exit motor mode first: firmware zeroes
    only a disabled motor), and return the record whose ``joint_angle`` becomes the plan's
    ``zero_offset`` (:func:`giwbc.hal.plan_edit.update_plan`)."""
    bus, motor = link.plan.motor(joint)
    protocol = link.protocols[bus.name]
    before = _read_motor(link, bus, motor)
    if before is None:
        raise HardwareConfigError(f"motor of joint {joint!r} (id {motor.can_id} on {bus.name}) does not answer: not zeroed")
    link.request(bus.name, [protocol.exit_motor_mode(motor.can_id)])
    link.request(bus.name, [protocol.set_zero(motor.can_id)])
    after = _read_motor(link, bus, motor)
    if after is None:
        raise HardwareConfigError(f"motor of joint {joint!r} stopped answering after set zero")
    step = motor.model.position.span / 65535
    if abs(after.position) > 2 * step + 1e-9:
        raise HardwareConfigError(
            f"motor of joint {joint!r} reads {after.position:.4f} rad after set zero (expected 0): the firmware ignored it"
        )
    return ZeroRecord(joint, bus.name, motor.can_id, joint_angle, before.position, after.position)


# ----------------------------------------------------------------------------- calibration
@dataclass(frozen=True)
class JointCalibration:
    joint: str
    sign: int
    zero_offset: float
    moved: float  # joint rad the hand move measured (|dp| / gear)
    problems: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.problems


def calibrate_joint(
    motor: MotorConfig,
    p_known: float,
    p_moved: float,
    q_known: float,
    limits: tuple[float, float] | None = None,
    min_move: float = 0.1,
) -> JointCalibration:
    """Sign and zero offset of one joint from two motor readings (module docstring)."""
    dp = p_moved - p_known
    moved = abs(dp) / motor.gear_ratio
    sign = 1 if dp >= 0 else -1
    zero_offset = q_known - sign * p_known / motor.gear_ratio
    problems = []
    if moved < min_move:
        problems.append(f"moved only {moved:.3f} rad (< {min_move} rad): move the joint further in its positive direction")
    if limits is not None:
        lo, hi = limits
        q_moved = q_known + moved
        if not lo <= q_known <= hi:
            problems.append(f"the known posture {q_known:.3f} rad is outside the joint's limits [{lo:.3f}, {hi:.3f}]")
        elif not q_moved <= hi + 0.05:
            problems.append(
                f"the hand move reaches {q_moved:.3f} rad, past the upper limit {hi:.3f}: moved the wrong way, "
                "or the robot was not in the known posture"
            )
    return JointCalibration(motor.joint, sign, float(zero_offset), float(moved), tuple(problems))


class CalibrationSession:
    """The guided calibration: :meth:`record_known_posture` once, then :meth:`record_move` per
    joint after the operator moved it by hand; :meth:`results` for what to write."""

    def __init__(self, link: BringupLink, q_known: Mapping[str, float], limits: Mapping[str, tuple[float, float]] | None = None,
                 min_move: float = 0.1) -> None:  # fmt: skip
        self.link = link
        self.q_known = dict(q_known)
        self.limits = dict(limits or {})
        self.min_move = min_move
        self.p_known: dict[str, float] = {}
        self.calibrations: dict[str, JointCalibration] = {}

    def record_known_posture(self) -> list[str]:
        """Read every motor in the known posture; joints that did not answer (empty: all did)."""
        r = read_joints(self.link, tuple(self.q_known))
        self.p_known = {j: float(p) for j, p, ok in zip(r.joints, r.motor_position, r.replied) if ok}
        return [j for j, ok in zip(r.joints, r.replied) if not ok]

    def record_move(self, joint: str) -> JointCalibration:
        """Read ``joint`` after the operator moved it in its positive direction."""
        if joint not in self.p_known:
            raise HardwareConfigError(f"no known-posture reading for {joint!r}: record the known posture first")
        r = read_joints(self.link, (joint,))
        if not r.replied[0]:
            raise HardwareConfigError(f"motor of joint {joint!r} does not answer")
        _, motor = self.link.plan.motor(joint)
        cal = calibrate_joint(motor, self.p_known[joint], float(r.motor_position[0]), self.q_known[joint], self.limits.get(joint), self.min_move)
        self.calibrations[joint] = cal
        return cal

    def results(self) -> dict[str, dict[str, float | int]]:
        """``{joint: {"sign": s, "zero_offset": z}}`` for the joints calibrated without problems."""
        return {j: {"sign": c.sign, "zero_offset": c.zero_offset} for j, c in self.calibrations.items() if c.ok}


# ----------------------------------------------------------------------------- first run
@dataclass(frozen=True)
class FirstRunLimits:
    """Reduced limits for a first run with the robot hanging on a gantry."""

    torque_fraction: float = 0.3  # x each motor's torque (commands clamped to it)
    gain_fraction: float = 0.5  # x the description's kp and kd
    max_tilt: float = 0.35  # rad (the gantry keeps the base near upright: more means it slipped)
    soft_limit_margin: float = 0.1  # rad inside the joint limits
    velocity_scale: float = 0.5  # x the velocity limits
    max_temperature: float = 65.0  # °C

    def safety(self, base: SafetyConfig) -> SafetyConfig:
        """``base`` with the tighter thresholds (never looser than ``base``)."""
        return replace(
            base,
            max_tilt=min(base.max_tilt, self.max_tilt),
            soft_limit_margin=max(base.soft_limit_margin, self.soft_limit_margin),
            velocity_scale=min(base.velocity_scale, self.velocity_scale),
            max_temperature=min(base.max_temperature, self.max_temperature),
            torque_scale=min(base.torque_scale, self.torque_fraction),
        )

    def torque_limits(self, plan: HardwarePlan, joint_names: Sequence[str]) -> np.ndarray:
        """Joint-side torque limit per joint (robot order): the fraction of the motor's range."""
        return np.array([self.torque_fraction * plan.motor(j)[1].joint_effort_limit for j in joint_names])


__all__ = [
    "Answer",
    "BringupLink",
    "CalibrationSession",
    "FirstRunLimits",
    "JointCalibration",
    "JointReadings",
    "ScanReport",
    "ZeroRecord",
    "calibrate_joint",
    "description_limits",
    "limit_violations",
    "probe_frame",
    "read_joints",
    "reply_variant",
    "scan",
    "set_zero",
]
