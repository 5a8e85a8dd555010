"""A MuJoCo-backed stand-in for the actuators of a hardware plan, on python-can ``virtual`` buses.

:class:`ActuatorEmulator` opens the motor side of every bus of a :class:`HardwarePlan` on an
in-process ``virtual`` channel of its own (:meth:`host_plan` gives the plan the host opens) and
answers each frame like MIT-mode firmware: exactly one reply per received frame (command or
special), in the motor's configured reply variant, with a motor-mode state machine::

    off --enter--> motor mode --exit--> off          (zero: only when off; clear: latched errors)

Commands are applied only in motor mode; entering motor mode starts from a zero command (no
torque). A latched error (injected, or the firmware's over-temperature trip) makes the motor limp
and report its code until it is cleared (``clear``, or ``exit`` once the cause is gone).
A motor that hears nothing for ``watchdog_timeout`` goes limp (zero torque, or pure damping
``limp_kd``) until its next command.

Clock (the choice, and why): **lockstep on the caller's clock**. :meth:`ActuatorEmulator.advance`
takes the time ``now``: physics advances to ``now`` holding the commands the motors have, and
delayed replies that are due go out; :meth:`ActuatorEmulator.answer` then answers the frames
waiting on its buses with the state at ``now`` (:meth:`~ActuatorEmulator.poll` does both). The CAN
robot (its ``peer``) calls them with the nominal time of each control cycle (the deadline slot),
so physics advances exactly one control period per cycle whatever the host's wall-clock timing:
a dry run is deterministic (same seed, same trajectory) and can run faster than real time in
tests, while an overrun that skips a slot still shows up as a command held for two periods,
as on hardware. A reply is therefore answered with the state at the moment its command arrives,
and that command acts over the following period (one period of sense-to-act latency, as a
real bus gives). Delays quantize to polls: a delayed reply is sent at the first poll at or after
its due time, i.e. late by at least one cycle when polled once per cycle.

Faults (:class:`FaultInjection`), per motor, within ``[start, stop)`` emulator seconds, drawn from a
seeded ``numpy.random.Generator`` in a fixed order: ``drop`` or ``delay`` replies with a
probability, ``corrupt`` replies (torn 1..5-byte frames: the motor's byte 0, random bytes),
report an ``error`` code, ``overheat`` (extra heating until the trip), ``silent`` (no replies,
still obeys), ``dead`` (no replies, limp), ``push`` (an external force on a link, to make the
robot fall), ``motor_exit`` (another node sends the motors an exit-motor-mode frame, once, at
``start``: they go limp and report state "disabled"; the host hears the frame too), foreign
traffic on the motors' buses before each poll's replies (``foreign_sync``: a CANopen SYNC, id
0x080 with no data; ``foreign_ids``: 8 random bytes from an id no motor of the bus uses;
``zero_byte``: a frame with no data from such an id), ``duplicate`` (each reply sent twice),
``reorder`` (a poll's replies on a bus sent in reverse order) and ``encoder`` (the position
reported shifted by ``offset`` rad, joint side: a slipped encoder, a joint reported beyond its
limits). The kinds in :data:`HOST_FAULT_KINDS` act on the host (its policy, controller, bus
drivers, process): :mod:`giwbc.runtimes.faults` applies them; the emulator ignores them.
A :class:`Gantry` can hold the base while the motors start (start-up rehearsals).

Speed: every bus speaks MIT mode in the shipped plans, so commands are decoded and replies encoded
for all motors at once (:class:`_MitFirmwareCodec`, bit-identical to the protocol's scalar calls);
python-can's per-frame cost is what remains (~5 us per send or receive on ``virtual``).

Temperature (coil): ``dT/dt = k tau^2 + h - (T - ambient) / time_constant`` with ``k`` such that
the model's rated torque gives ``rated_rise`` kelvin at steady state (:class:`ThermalModel`).
The IMU is MuJoCo's, published to an :class:`ImuChannel` after each physics advance.
"""

from __future__ import annotations

import math
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from giwbc.hal.can_robot import ImuChannel
from giwbc.hal.frames import FramePort, PortGroup, fields, frame_port, frames, frames_of
from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.motor import MotorGroup
from giwbc.hal.protocols import ActuatorProtocol, CanProtocolError, MitProtocol
from giwbc.hal.protocols.mit import COMMAND_LEVELS, CUBEMARS_TEMPERATURE_OFFSET, REPLY_VARIANTS
from giwbc.robot.interface import ImpedanceCommand

if TYPE_CHECKING:
    import mujoco

    from giwbc.robot.description import RobotDescription
    from giwbc.robot.mujoco_robot import MujocoRobot

EMULATOR_FAULT_KINDS = (
    "drop", "delay", "corrupt", "error", "overheat", "silent", "dead", "push",
    "motor_exit", "foreign_sync", "foreign_ids", "zero_byte", "duplicate", "reorder", "encoder",
)  # fmt: skip
# Faults of the host side (policy, controller, bus drivers, the process): see giwbc.runtimes.faults.
HOST_FAULT_KINDS = (
    "policy_nan", "controller_nan", "controller_raise", "qp_infeasible", "driver_raise", "driver_block", "bus_off",
    "keyboard_interrupt", "sigint", "sigterm", "sighup",
)  # fmt: skip
FAULT_KINDS = EMULATOR_FAULT_KINDS + HOST_FAULT_KINDS
_REPLY_FAULTS = frozenset({"drop", "delay", "corrupt", "silent", "duplicate", "reorder"})
_FOREIGN_FAULTS = frozenset({"foreign_sync", "foreign_ids", "zero_byte"})
CANOPEN_SYNC_ID = 0x080
_SEND_DEADLINE = 20e-3  # s a poll's replies may take to send (see ActuatorEmulator._send)
OFF, MOTOR = 0, 1

# Error codes a motor reports, by reply variant (see giwbc.hal.protocols.mit: CUBEMARS_ERRORS,
# DAMIAO_STATES). Variants without an error field ("original", "voltage") cannot report one.
OVER_CURRENT = {"cubemars": 2, "damiao": 0xA}
OVER_TEMPERATURE = {"cubemars": 1, "damiao": 0xC}


@dataclass(frozen=True)
class ThermalModel:
    """First-order coil temperature of every motor (see the module docstring)."""

    ambient: float = 25.0  # °C
    time_constant: float = 120.0  # s
    rated_rise: float = 40.0  # K at steady state under rated torque
    rated_fraction: float = 0.3  # rated torque as a fraction of the model's torque range
    trip: float = 90.0  # °C: the firmware latches an over-temperature error above this
    mos_fraction: float = 0.4  # driver (MOS) temperature rise as a fraction of the coil's

    def __post_init__(self) -> None:
        if not (self.time_constant > 0 and self.rated_rise > 0 and 0 < self.rated_fraction <= 1):
            raise ValueError("thermal model needs time_constant > 0, rated_rise > 0, 0 < rated_fraction <= 1")

    def heating(self, torque_max: np.ndarray) -> np.ndarray:
        """K/s per (N m)^2 of motor-side torque, per motor."""
        rated = self.rated_fraction * np.asarray(torque_max, dtype=float)
        return self.rated_rise / (rated**2 * self.time_constant)

    def step(self, temperature: np.ndarray, torque: np.ndarray, dt: float, k: np.ndarray, extra: np.ndarray) -> np.ndarray:
        """Exact step of the linear model over ``dt`` with torque and extra heating held (K/s)."""
        steady = self.ambient + (k * torque**2 + extra) * self.time_constant
        return steady + (temperature - steady) * math.exp(-dt / self.time_constant)


@dataclass(frozen=True)
class FaultInjection:
    """One injected fault, active for emulator time in ``[start, stop)``.

    ``joints``: the motors it affects, by joint name (None: every motor). ``probability``: per
    reply, for drop/delay/corrupt. ``delay``: seconds a delayed reply is held. ``error_code``: the
    code reported for ``error`` (default: over-current in the motor's variant). ``heat_rate``: K/s of
    extra heating for ``overheat``. ``force``/``link``: the world force (N) of a ``push``.
    ``offset``: rad (joint side) added to the reported position for ``encoder``. For foreign
    traffic, ``probability`` is per bus and poll, and ``joints`` choose the buses (theirs).
    """

    kind: str
    joints: tuple[str, ...] | None = None
    probability: float = 1.0
    start: float = 0.0
    stop: float = math.inf
    delay: float = 0.004
    error_code: int | None = None
    heat_rate: float = 50.0
    force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    link: str | None = None
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"fault probability must be in [0, 1], got {self.probability}")
        if not self.stop > self.start:
            raise ValueError(f"fault window [{self.start}, {self.stop}) is empty")
        if self.delay < 0 or self.heat_rate < 0 or not math.isfinite(self.offset):
            raise ValueError("delay and heat_rate must be >= 0, offset finite")
        if isinstance(self.joints, str):
            object.__setattr__(self, "joints", (self.joints,))

    def active(self, t: float) -> bool:
        return self.start <= t < self.stop

    @property
    def on_host(self) -> bool:
        """Whether the host applies it (policy, controller, drivers, process), not the emulator."""
        return self.kind in HOST_FAULT_KINDS


@dataclass(frozen=True)
class Gantry:
    """A harness holding the base at its initial pose until ``until`` seconds (a spring-damper
    wrench on the base plus the robot's weight), as a robot hangs while its motors start."""

    until: float
    stiffness: float = 5000.0  # N/m
    damping: float = 200.0  # N s/m (explicit: keep damping * dt / mass of the base link well below 1)
    angular_stiffness: float = 300.0  # N m/rad
    angular_damping: float = 10.0  # N m s/rad


@dataclass(frozen=True)
class EmulatorConfig:
    """Firmware and simulation settings of :class:`ActuatorEmulator`."""

    watchdog_timeout: float = 0.05  # s without a frame before a motor in motor mode goes limp
    limp_kd: float = 0.0  # joint-side damping of a limp motor (0: zero torque, as Ben Katz firmware)
    thermal: ThermalModel = field(default_factory=ThermalModel)
    seed: int | None = 0
    initial_joint_positions: tuple[float, ...] | None = None  # default: the description's pose
    gantry: Gantry | None = None
    faults: tuple[FaultInjection, ...] = ()
    record: bool = False  # keep per-poll snapshots of what the motors apply (tests)
    record_truth: bool = True  # keep (time, base height, base tilt) after every physics advance


@dataclass(frozen=True)
class AppliedSnapshot:
    """What the motors applied after one poll (joint side, description order)."""

    time: float
    mode: np.ndarray  # OFF / MOTOR per joint
    limp: np.ndarray  # no torque from a command (off, timed out, latched error, dead)
    kp: np.ndarray
    kd: np.ndarray
    tau_ff: np.ndarray
    q_ref: np.ndarray


@dataclass
class EmulatorCounters:
    """Per motor (plan order): frames heard, replies sent, and what faults did to replies."""

    frames: np.ndarray
    commands: np.ndarray  # impedance commands applied (in motor mode)
    specials: np.ndarray
    replies: np.ndarray
    dropped: np.ndarray
    delayed: np.ndarray
    corrupted: np.ndarray
    ignored: int = 0  # frames no configured motor accepts
    polls: int = 0
    physics_steps: int = 0

    @classmethod
    def zeros(cls, n: int) -> EmulatorCounters:
        z = lambda: np.zeros(n, dtype=np.int64)  # noqa: E731
        return cls(z(), z(), z(), z(), z(), z(), z())


class ActuatorEmulator:
    """The motors of ``plan`` on virtual buses, driving a MuJoCo model of ``description``.

    ``model``: an ``MjModel`` to use (it is modified: gains live in actuator parameters), e.g. a
    copy of a cached one; default: built from the description (slow, ~1 s). ``interface`` and
    ``bus_options``: the python-can interface of its channels (``"giwbc-unix"`` with
    ``{"serve": True}`` when it runs in its own process, :mod:`giwbc.hal.emulator_process`).
    """

    def __init__(
        self,
        plan: HardwarePlan,
        description: RobotDescription,
        config: EmulatorConfig | None = None,
        *,
        model: mujoco.MjModel | None = None,
        channel_prefix: str | None = None,
        interface: str = "virtual",
        bus_options: dict[str, Any] | None = None,
    ) -> None:
        from giwbc.robot.mujoco_robot import MujocoRobot

        self.config = c = config or EmulatorConfig()
        self.description = description
        names = description.joint_names
        self.plan = plan
        self._routing = plan.routing(names)  # validates the plan against the robot
        prefix = channel_prefix or f"giwbc-emu-{uuid.uuid4().hex[:12]}"  # channels of its own
        self._host_plan = replace(
            plan,
            buses=tuple(replace(b, interface=interface, channel=f"{prefix}/{b.name}") for b in plan.buses),
        )
        self.robot: MujocoRobot = MujocoRobot(description, model)
        period = 1.0 / plan.control_rate
        substeps = max(1, math.ceil(period / description.timestep - 1e-9))
        self.physics_dt = period / substeps
        self.robot.model.opt.timestep = self.physics_dt

        # Motors in plan order; per-bus protocols and ports.
        self.motors = plan.motors
        n = len(self.motors)
        self.group = MotorGroup(self.motors)
        self.joint_index = np.array([names.index(m.joint) for m in self.motors], dtype=np.int64)
        self.protocols: list[ActuatorProtocol] = []
        self.buses: list[can.BusABC] = []
        self.ports: list[FramePort] = []
        # Per bus and 11-bit id: the global motor index (-1: no motor of this bus has that id).
        self._motor_at = np.full((len(plan.buses), 0x800), -1, dtype=np.int64)
        first = 0
        for b, bus in enumerate(self._host_plan.buses):
            self.protocols.append(bus.make_protocol())
            self.buses.append(can.Bus(interface=interface, channel=bus.channel, **(bus_options or {})))
            self.ports.append(frame_port(self.buses[-1]))
            for i, m in enumerate(bus.motors):
                if m.can_id <= 0x7FF:
                    self._motor_at[b, m.can_id] = first + i
            first += len(bus.motors)
        self._ports = PortGroup(self.ports)
        self._bus_of = np.repeat(np.arange(len(plan.buses)), [len(b.motors) for b in plan.buses])
        self._fired: set[int] = set()  # one-shot faults (motor_exit) already applied, by position in self.faults
        self._no_wait = ([0.0] * len(self.ports), [0] * len(self.ports))  # replies go out now or never
        self._variant = [m.reply for m in self.motors]
        self._torque_max = np.array([m.model.torque.magnitude for m in self.motors])
        self._heating = c.thermal.heating(self._torque_max)
        self._codec = _MitFirmwareCodec.for_buses(self.protocols, self.motors)

        # Firmware state (plan order).
        self.mode = np.full(n, OFF, dtype=np.int8)
        self.error = np.zeros(n, dtype=np.int64)  # latched error code (0: none)
        self.timed_out = np.zeros(n, dtype=bool)
        self.last_frame = np.full(n, -math.inf)  # emulator time of each motor's last frame
        self.zero = self.group.offset.copy()  # joint angle at which each motor reads 0
        self.command = np.zeros((n, 5))  # motor side: position, velocity, kp, kd, torque
        self.temperature = np.full(n, c.thermal.ambient)
        self.dead = np.zeros(n, dtype=bool)
        self.counters = EmulatorCounters.zeros(n)
        self.rng = np.random.default_rng(c.seed)
        self.faults: list[FaultInjection] = []
        self._fault_motors: list[np.ndarray] = []
        self._wrench_links: set[str] = set()
        for f in c.faults:
            self.add_fault(f)
        self.imu_channel = ImuChannel()
        self.snapshots: list[AppliedSnapshot] = []
        self.truth: list[tuple[float, float, float]] = []  # ground truth for judging a dry run, never sent to the host
        self._delayed: list[tuple[float, int, np.ndarray]] = []  # (due, bus, one-frame batch)
        self._impedance = ImpedanceCommand.damping(description.dofs, 0.0)
        self._closed = False

        if c.initial_joint_positions is not None:
            q = description.default_configuration()
            q[7 if description.floating_base else 0 :] = np.asarray(c.initial_joint_positions, dtype=float)
            self.robot.reset(q)
        self._base_pose0 = self.robot.data.qpos[:7].copy() if description.floating_base else None
        self._weight = description.total_mass * 9.81
        self._apply_commands()
        self._publish_imu()

    # ------------------------------------------------------------------ wiring
    def host_plan(self) -> HardwarePlan:
        """The plan the host opens: the same buses, on this emulator's virtual channels."""
        return self._host_plan

    @property
    def time(self) -> float:
        """Emulator (physics) time, s."""
        return float(self.robot.data.time)

    def add_fault(self, fault: FaultInjection) -> None:
        """Inject a fault (its window is in emulator time)."""
        names = self.description.joint_names
        if fault.joints is None:
            motors = np.ones(len(self.motors), dtype=bool)
        else:
            unknown = [j for j in fault.joints if j not in names]
            if unknown:
                raise ValueError(f"fault on unknown joint(s) {unknown}")
            motors = np.isin([m.joint for m in self.motors], fault.joints)
        if fault.kind == "push":
            if fault.link is None:
                fault = replace(fault, link=self.description.base_link)
            self.robot.link_pose(fault.link)  # raises KeyError for an unknown link
            self._wrench_links.add(fault.link)  # type: ignore[arg-type]
        self.faults.append(fault)
        self._fault_motors.append(motors)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for b in self.buses:
                b.shutdown()

    def __enter__(self) -> ActuatorEmulator:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ the clock
    def poll(self, now: float) -> None:
        """:meth:`advance` then :meth:`answer`: everything that happens by ``now``."""
        self.advance(now)
        self.answer(now)

    def advance(self, now: float) -> None:
        """Advance physics to ``now`` and send the delayed replies due by then."""
        self._advance(now)
        if self._delayed:
            self._release(now)

    def answer(self, now: float, buses: Sequence[int] | None = None) -> None:
        """Answer every waiting frame (on ``buses``, ascending, when the caller knows which have
        frames) with the state at ``now`` (physics is advanced first if needed). The replies of
        one call report the state after all of its frames."""
        if now > self.time + 0.5 * self.physics_dt:
            self.advance(now)
        self.counters.polls += 1
        bus, index, special, values = self._receive(buses)
        if self.faults:
            self._foreign_traffic(self.time)
        if len(index):
            self._answer(bus, index, special, values, self.time)
        if self.config.record:
            self.snapshots.append(self._snapshot())

    def _advance(self, now: float) -> None:
        """Step physics to ``now`` (watchdog checked before every step), then heat, trip, IMU."""
        robot, dt, c = self.robot, self.physics_dt, self.config
        steps = int(math.floor((now - self.time) / dt + 1e-6))
        if steps > 0:
            for _ in range(steps):
                t = self.time
                late = (self.mode == MOTOR) & ~self.timed_out & (t - self.last_frame > c.watchdog_timeout)
                if late.any():
                    self.timed_out |= late
                    self._apply_commands()
                if self._wrench_links or c.gantry is not None:
                    self._external_forces(t)
                robot.step(1)
            self.counters.physics_steps += steps
            extra = np.zeros(len(self.motors))
            for f, motors in zip(self.faults, self._fault_motors):
                if f.kind == "overheat" and f.active(self.time):
                    extra[motors] += f.heat_rate
            torque = self._applied_motor_torque()
            self.temperature = c.thermal.step(self.temperature, torque, steps * dt, self._heating, extra)
            self._publish_imu()
            if c.record_truth and self.description.floating_base:
                qpos = robot.data.qpos
                tilt = math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (qpos[4] ** 2 + qpos[5] ** 2))))
                self.truth.append((self.time, float(qpos[2]), tilt))
        if self.faults or self.error.any() or self.temperature.max() > c.thermal.trip:
            self._update_faults(self.time)

    def _update_faults(self, t: float) -> None:
        """Time-driven firmware state: over-temperature trips, injected errors, dead motors."""
        error = self.error.copy()
        tripped = (self.temperature > self.config.thermal.trip) & (error == 0)
        for i in np.flatnonzero(tripped):
            error[i] = OVER_TEMPERATURE.get(self._variant[i], 1)
        dead = np.zeros(len(self.motors), dtype=bool)
        for k, (f, motors) in enumerate(zip(self.faults, self._fault_motors)):
            if f.kind == "motor_exit" and f.active(t) and k not in self._fired:
                self._fired.add(k)
                self._foreign_exit(motors)
            if f.active(t):
                if f.kind == "error":
                    for i in np.flatnonzero(motors & (error == 0)):
                        error[i] = f.error_code if f.error_code is not None else OVER_CURRENT.get(self._variant[i], 1)
                elif f.kind == "dead":
                    dead |= motors
        if not (np.array_equal(error, self.error) and np.array_equal(dead, self.dead)):
            self.error, self.dead = error, dead
            self._apply_commands()

    def _foreign_exit(self, motors: np.ndarray) -> None:
        """Another node sends ``motors`` an exit-motor-mode frame: they leave motor mode (limp,
        state "disabled"), and the host hears the frame on their buses."""
        for i in np.flatnonzero(motors).tolist():
            b = int(self._bus_of[i])
            self._state_machine(i, "exit", (math.nan,) * 5, self.time)
            self._send(b, frames_of([self.protocols[b].exit_motor_mode(self.motors[i].can_id)]))
        self._apply_commands()

    def _foreign_traffic(self, t: float) -> None:
        """Frames from other nodes on the faults' buses, ahead of this poll's replies."""
        rng = self.rng
        for f, motors in zip(self.faults, self._fault_motors):
            if f.kind not in _FOREIGN_FAULTS or not f.active(t):
                continue
            for b in np.unique(self._bus_of[motors]).tolist():
                if rng.random() >= f.probability:
                    continue
                if f.kind == "foreign_sync":
                    batch = frames([CANOPEN_SYNC_ID], np.zeros((1, 8), dtype=np.uint8), lengths=0)
                else:
                    free = np.flatnonzero(self._motor_at[b] < 0)
                    host = self.protocols[b].host_id
                    free = free[(free != (host if host is not None else -1)) & (free != 0)]
                    length = 8 if f.kind == "foreign_ids" else 0
                    data = rng.integers(0, 256, (1, 8), dtype=np.uint8) if length else np.zeros((1, 8), dtype=np.uint8)
                    batch = frames([int(rng.choice(free))], data, lengths=length)
                self._send(b, batch)

    def _external_forces(self, t: float) -> None:
        """Pushes and the gantry, as world wrenches on bodies (set, not accumulated, every step)."""
        robot = self.robot
        wrenches = {link: np.zeros(6) for link in self._wrench_links}
        g = self.config.gantry
        if g is not None:
            wrenches.setdefault(self.description.base_link, np.zeros(6))
        for f in self.faults:
            if f.kind == "push" and f.active(t):
                wrenches[f.link][:3] += f.force  # type: ignore[index]
        if g is not None and self.description.floating_base and t < g.until:
            data, pose0 = robot.data, self._base_pose0
            force = g.stiffness * (pose0[:3] - data.qpos[:3]) - g.damping * data.qvel[:3]
            force[2] += self._weight
            # Orientation error: vector part of q0 * conj(q) (MuJoCo's w, x, y, z), world frame.
            w0, v0 = pose0[3], pose0[4:7]
            w1, v1 = data.qpos[3], -data.qpos[4:7]
            err = 2.0 * (w0 * v1 + w1 * v0 + np.cross(v0, v1))
            if w0 * w1 - v0 @ v1 < 0:
                err = -err
            torque = g.angular_stiffness * err - g.angular_damping * robot.base_state().angular_velocity
            wrenches[self.description.base_link] += np.concatenate([force, torque])
        for link, wrench in wrenches.items():
            robot.set_external_wrench(link, wrench[:3], wrench[3:])

    def _release(self, now: float) -> None:
        due = [d for d in self._delayed if d[0] <= now + 1e-9]
        if not due:
            return
        self._delayed = [d for d in self._delayed if d[0] > now + 1e-9]
        for _, b, frame in due:
            self._send(b, frame)

    # ------------------------------------------------------------------ frames
    def _receive(self, buses: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray, list[str | None], np.ndarray]:
        """Every waiting frame a motor accepts, decoded: bus, motor index, special frame name (None
        for a command) and the five command values (position, velocity, kp, kd, torque; NaN for
        special frames), in arrival order per bus. A host that closed its end raises
        ``can.CanOperationError``."""
        if buses is not None and not len(buses):
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), [], np.zeros((0, 5))
        got = self._ports.receive(None, buses=buses)
        for error in got.errors:
            if error is not None:
                raise error if isinstance(error, can.CanError) else can.CanOperationError(str(error))
        self.counters.ignored += sum(got.skipped)
        if not len(got.frames):
            return got.bus, got.bus, [], np.zeros((0, 5))
        f = fields(got.frames)
        plain = ~(f.extended | f.remote | f.error) & (f.length == 8)
        index = np.where(plain, self._motor_at[got.bus, np.where(plain, f.arbitration_id, 0)], -1)
        accepted = np.flatnonzero(index >= 0)  # for a motor of this bus, and well formed; the rest is ignored
        self.counters.ignored += len(index) - len(accepted)
        bus, index, data = got.bus[accepted], index[accepted], got.frames["data"][accepted]
        if not len(index):
            return bus, index, [], np.zeros((0, 5))
        if self._codec is not None:
            special, values = self._codec.decode_commands(index, data)
            return bus, index, special, values
        keep, specials, rows = [], [], []
        for k, (b, i, payload) in enumerate(zip(bus.tolist(), index.tolist(), data)):
            try:
                cmd = self.protocols[b].decode_command(self.motors[i].can_id, payload.tobytes())
            except CanProtocolError:
                self.counters.ignored += 1
                continue
            keep.append(k)
            specials.append(cmd.special)
            rows.append((cmd.position, cmd.velocity, cmd.kp, cmd.kd, cmd.torque))
        return bus[keep], index[keep], specials, np.array(rows, dtype=float).reshape(-1, 5)

    def _answer(self, bus: np.ndarray, index: np.ndarray, special: list[str | None], values: np.ndarray, t: float) -> None:
        """Run the state machine for every frame, then reply (faults permitting)."""
        cnt = self.counters
        active = [(f, m) for f, m in zip(self.faults, self._fault_motors) if f.active(t) and f.kind in _REPLY_FAULTS]
        np.add.at(cnt.frames, index, 1)
        if all(sp is None for sp in special) and np.bincount(index, minlength=len(self.motors)).max() <= 1:
            changed = self._commands(index, values, t)
        else:
            changed = False
            for i, sp, row in zip(index.tolist(), special, values.tolist()):
                if not self.dead[i]:
                    self.last_frame[i] = t
                    changed |= self._state_machine(i, sp, row, t)
        if changed:
            self._apply_commands()
        answering = ~self.dead[index]
        for f, m in active:
            if f.kind == "silent":
                answering &= ~m[index]
        bus, index = bus[answering], index[answering]
        if not len(index):
            return
        replies = self._encode_replies(bus, index)
        if not active:
            self._send_by_bus(bus, replies)
            np.add.at(cnt.replies, index, 1)
            return
        rng = self.rng
        out: list[tuple[int, np.ndarray]] = []
        for b, i, reply in zip(bus.tolist(), index.tolist(), replies):
            frame = reply.reshape(1).copy()
            send = True
            copies = 1
            for f, m in active:
                if not m[i] or f.kind in ("silent", "reorder"):
                    continue
                if f.kind == "duplicate" and rng.random() < f.probability:
                    copies = 2
                    continue
                if f.kind == "drop" and rng.random() < f.probability:
                    cnt.dropped[i] += 1
                    send = False
                    break
                if f.kind == "corrupt" and rng.random() < f.probability:
                    cnt.corrupted[i] += 1  # the motor's byte 0, then 0..4 random bytes: a torn reply
                    length = int(rng.integers(1, 6))
                    frame["len"] = length
                    frame["data"][0, 1:] = 0
                    frame["data"][0, 1:length] = rng.integers(0, 256, length - 1, dtype=np.uint8)
                elif f.kind == "delay" and rng.random() < f.probability:
                    cnt.delayed[i] += 1
                    cnt.replies[i] += 1
                    self._delayed.append((t + f.delay, b, frame))
                    send = False
                    break
            if send:
                out.extend([(b, frame)] * copies)
                cnt.replies[i] += 1
        for f, m in active:  # reversed per bus: the buses of the motors the fault names
            if f.kind == "reorder":
                for b in np.unique(self._bus_of[m]).tolist():
                    at = [k for k, (bb, _) in enumerate(out) if bb == b]
                    for k, frame in zip(at, [out[k][1] for k in reversed(at)]):
                        out[k] = (b, frame)
        for b, frame in out:
            self._send(b, frame)

    def _send(self, b: int, batch: np.ndarray) -> None:
        """Send on bus ``b`` now or never: a full host queue loses the reply, as a real bus under
        overload would: no waiting for room. The deadline only bounds a send the host machine
        preempts (firmware is not preempted: a loaded test machine must not drop replies)."""
        self.ports[b].send(batch, time.perf_counter() + _SEND_DEADLINE, timeout=0.0, retries=0)

    def _send_by_bus(self, bus: np.ndarray, batch: np.ndarray) -> None:
        """Send each frame of ``batch`` on its bus (``bus`` ascending, as frames are received)."""
        bounds = np.searchsorted(bus, np.arange(len(self.ports) + 1)).tolist()
        self._ports.send(batch, bounds, time.perf_counter() + _SEND_DEADLINE, timeout=self._no_wait[0], retries=self._no_wait[1])

    def _commands(self, index: np.ndarray, values: np.ndarray, t: float) -> bool:
        """Plain command frames, one per motor in ``index`` (the every-cycle path, vectorized)."""
        alive = ~self.dead[index]
        index, values = index[alive], values[alive]
        self.last_frame[index] = t
        was_limp = self.timed_out[index].any()
        self.timed_out[index] = False
        on = self.mode[index] == MOTOR
        index, values = index[on], values[on]
        self.counters.commands[index] += 1
        if was_limp or not np.array_equal(self.command[index], values):
            self.command[index] = values
            return True
        return False

    def _encode_replies(self, bus: np.ndarray, index: np.ndarray) -> np.ndarray:
        """The reply frames of motors ``index`` (on buses ``bus``) with the state now."""
        position, velocity, torque = self._motor_state()
        th = self.config.thermal
        coil = self.temperature[index]
        mos = th.ambient + th.mos_fraction * (coil - th.ambient)
        error = self.error[index]
        status = np.where(error != 0, np.minimum(error, 15), (self.mode[index] == MOTOR).astype(np.int64))
        if self._codec is not None:
            data, lengths, arb = self._codec.encode_replies(index, position[index], velocity[index], torque[index], coil, mos, error, status)
            return frames(arb, data, lengths)
        out = []
        for k, (b, i) in enumerate(zip(bus.tolist(), index.tolist())):
            damiao = self._variant[i] == "damiao"
            out.append(self.protocols[b].encode_reply(
                self.motors[i].can_id, float(position[i]), float(velocity[i]), float(torque[i]),
                temperature=float(mos[k] if damiao else coil[k]), rotor_temperature=float(coil[k]),
                error_code=int(min(error[k], 255)), status=int(status[k]),
            ))  # fmt: skip
        return frames_of(out)

    def _state_machine(self, i: int, special: str | None, values: Sequence[float], t: float) -> bool:
        """Off / motor mode / latched errors for one frame; returns whether applied commands changed."""
        cnt = self.counters
        was_limp = bool(self.timed_out[i])
        self.timed_out[i] = False
        if special is None:
            if self.mode[i] == MOTOR:
                cnt.commands[i] += 1
                row = self.command[i]
                if was_limp or row[0] != values[0] or row[1] != values[1] or row[2] != values[2] or row[3] != values[3] or row[4] != values[4]:
                    row[:] = values
                    return True
            return was_limp
        cnt.specials[i] += 1
        if special == "enter":
            if self.error[i] == 0:
                self.mode[i] = MOTOR
                self.command[i] = 0.0
        elif special == "exit":
            self.mode[i] = OFF
            self.command[i] = 0.0
            if self.error[i] and self.temperature[i] < self.config.thermal.trip and not self._injected_error(i, t):
                self.error[i] = 0
        elif special == "zero":
            if self.mode[i] == OFF:
                self.zero[i] = self.robot.joint_positions()[self.joint_index[i]]
        elif special == "clear":
            if self.temperature[i] < self.config.thermal.trip and not self._injected_error(i, t):
                self.error[i] = 0
        return True

    def _injected_error(self, i: int, t: float) -> bool:
        return any(f.kind == "error" and f.active(t) and m[i] for f, m in zip(self.faults, self._fault_motors))

    def _motor_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Motor-side (position, velocity, torque) of every motor now."""
        q = self.robot.joint_positions()[self.joint_index]
        dq = self.robot.joint_velocities()[self.joint_index]
        for f, motors in zip(self.faults, self._fault_motors):
            if f.kind == "encoder" and f.active(self.time):
                q = q + np.where(motors, f.offset, 0.0)
        position = self.group.sign * self.group.gear * (q - self.zero)
        velocity = self.group.sign * self.group.gear * dq
        return position, velocity, self._applied_motor_torque()

    # ------------------------------------------------------------------ physics side
    def limp(self) -> np.ndarray:
        """Motors producing no commanded torque: off, timed out, latched error or dead."""
        return (self.mode != MOTOR) | self.timed_out | (self.error != 0) | self.dead

    def _apply_commands(self) -> None:
        """Turn the motors' commands (motor side) into the joint impedance MuJoCo evaluates."""
        g = self.group
        p, v, kp, kd, tau = self.command.T
        q_ref = g.sign * p / g.gear + self.zero
        v_ref = g.sign * v / g.gear
        g2 = g.gear**2
        kp_j, kd_j, tau_j = kp * g2, kd * g2, g.sign * g.gear * tau
        limp = self.limp()
        kp_j = np.where(limp, 0.0, kp_j)
        kd_j = np.where(limp, self.config.limp_kd, kd_j)
        tau_j = np.where(limp, 0.0, tau_j)
        v_ref = np.where(limp, 0.0, v_ref)
        imp, j = self._impedance, self.joint_index
        imp.q_ref[j], imp.v_ref[j], imp.kp[j], imp.kd[j], imp.tau_ff[j] = q_ref, v_ref, kp_j, kd_j, tau_j
        self.robot.set_joint_impedance(imp)

    def _applied_motor_torque(self) -> np.ndarray:
        tau = self.robot.joint_efforts()[self.joint_index]
        return self.group.sign * tau / self.group.gear

    def _publish_imu(self) -> None:
        self.imu_channel.publish(self.robot.imu())

    def _snapshot(self) -> AppliedSnapshot:
        imp = self._impedance
        n = self.description.dofs
        mode = np.zeros(n, dtype=np.int8)
        limp = np.zeros(n, dtype=bool)
        mode[self.joint_index] = self.mode
        limp[self.joint_index] = self.limp()
        return AppliedSnapshot(self.time, mode, limp, imp.kp.copy(), imp.kd.copy(), imp.tau_ff.copy(), imp.q_ref.copy())

    # ------------------------------------------------------------------ inspection
    def truth_between(self, start: float, stop: float = math.inf) -> np.ndarray:
        """Ground truth rows (time, base height, tilt rad) with ``start <= time < stop``."""
        rows = np.array(self.truth, dtype=float).reshape(-1, 3)
        return rows[(rows[:, 0] >= start) & (rows[:, 0] < stop)]

    def joint_temperatures(self) -> np.ndarray:
        """Coil temperature per joint (description order)."""
        out = np.full(self.description.dofs, np.nan)
        out[self.joint_index] = self.temperature
        return out

    def motor_index(self, joint: str) -> int:
        """Plan-order index of the motor driving ``joint``."""
        for i, m in enumerate(self.motors):
            if m.joint == joint:
                return i
        raise KeyError(f"no motor drives joint {joint!r}")


class _MitFirmwareCodec:
    """The firmware side of MIT mode for every motor at once (plan order), vectorized.

    Bit-identical to :meth:`MitProtocol.decode_command` and :meth:`MitProtocol.encode_reply` (the
    emulator tests compare them on random values for every reply variant); the emulator answers
    29 motors per cycle, and the scalar calls cost ~10 us per frame.
    """

    _SHIFTS = np.array([48, 36, 24, 12, 0], dtype=np.uint64)
    _LEVELS = np.array(COMMAND_LEVELS, dtype=np.uint64)
    _CODES = {name: k for k, name in enumerate(("original", "voltage", "cubemars", "damiao"))}

    def __init__(self, protocols: Sequence[MitProtocol], motors: Sequence[Any]) -> None:
        lo = np.array([[r.min for r in m.model.ranges] for m in motors], dtype=float)
        span = np.array([[r.span for r in m.model.ranges] for m in motors], dtype=float)
        self.lo, self.span = lo, span
        self.hi = np.array([[r.max for r in m.model.ranges] for m in motors], dtype=float)
        self.levels = np.array(COMMAND_LEVELS, dtype=float)
        self.variant = np.array([self._CODES[m.reply] for m in motors], dtype=np.int64)
        self.length = np.array([REPLY_VARIANTS[m.reply].length for m in motors], dtype=np.int64)
        self.can_id = np.array([m.can_id for m in motors], dtype=np.int64)
        bus_of = [b for b, p in enumerate(protocols) for _ in p.motors]
        self.arb = np.array([protocols[b].host_id or 0 for b in bus_of], dtype=np.int64)
        self.voltage_lsb = np.array([protocols[b].voltage_lsb for b in bus_of], dtype=float)
        # Replies: the position, velocity and torque ranges; byte 0 without Damiao's state nibble.
        fields = [0, 1, 4]
        self._lo3, self._hi3, self._span3 = lo[:, fields].copy(), self.hi[:, fields].copy(), span[:, fields].copy()
        self._levels3 = self.levels[fields].copy()
        self._damiao = self.variant == 3
        self._byte0 = np.where(self._damiao, self.can_id & 0x0F, self.can_id & 0xFF).astype(np.uint64)
        self._variants = set(self.variant.tolist())

    @classmethod
    def for_buses(cls, protocols: Sequence[ActuatorProtocol], motors: Sequence[Any]) -> _MitFirmwareCodec | None:
        """The codec when every bus speaks MIT mode, else None (the scalar protocol calls are used)."""
        if all(type(p) is MitProtocol for p in protocols):
            return cls(protocols, motors)  # type: ignore[arg-type]
        return None

    def decode_commands(self, index: np.ndarray, payload: Any) -> tuple[list[str | None], np.ndarray]:
        """8-byte command frames of motors ``index`` (payloads ``(M, 8)`` uint8, or their bytes
        joined): special names (None for a command) and the five values (position, velocity, kp,
        kd, torque; NaN for special frames)."""
        data = np.ascontiguousarray(np.frombuffer(payload, dtype=np.uint8) if isinstance(payload, bytes) else payload, dtype=np.uint8).reshape(-1, 8)
        special_mask = (data[:, :7] == 0xFF).all(axis=1) & (data[:, 7] >= 0xFB) & (data[:, 7] <= 0xFE)
        words = data.view(">u8").reshape(-1).astype(np.uint64)
        codes = (words[:, None] >> self._SHIFTS) & self._LEVELS
        values = codes.astype(float) * self.span[index] / self.levels + self.lo[index]
        values[special_mask] = np.nan
        names = _SPECIAL_NAMES
        special = [names[int(last)] if sp else None for sp, last in zip(special_mask.tolist(), data[:, 7].tolist())]
        return special, values

    def encode_replies(
        self,
        index: np.ndarray,
        position: np.ndarray,
        velocity: np.ndarray,
        torque: np.ndarray,
        temperature: np.ndarray,
        mos_temperature: np.ndarray,
        error: np.ndarray,
        status: np.ndarray,
        voltage: float = 24.0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reply payloads (M, 8) uint8 (zero-padded), their lengths and arbitration ids.

        Built as one big-endian 64-bit word per reply: byte 0, the position / velocity / torque
        codes (quantized exactly as the protocol's scalar encoder does), bytes 6 and 7."""
        values = np.column_stack((position, velocity, torque))
        if np.isnan(values).any():
            values = np.nan_to_num(values, nan=0.0, posinf=np.inf, neginf=-np.inf)
        lo = self._lo3[index]
        x = np.clip(values, lo, self._hi3[index])
        x -= lo
        x *= self._levels3
        x /= self._span3[index]
        x -= 0.5
        np.ceil(x, out=x)
        word = (x.astype(np.uint64) << _REPLY_SHIFTS).sum(axis=1, dtype=np.uint64)
        byte0 = self._byte0[index]
        damiao = self._damiao[index]
        if 3 in self._variants:
            byte0 = byte0 | (damiao * (np.asarray(status, dtype=np.int64) << 4)).astype(np.uint64)
        word |= byte0 << np.uint64(56)
        if self._variants - {0}:  # variants with bytes 6 and 7
            variant = self.variant[index]
            b6 = np.where(damiao, mos_temperature, np.where(variant == 2, temperature - CUBEMARS_TEMPERATURE_OFFSET,
                          np.where(variant == 1, voltage / self.voltage_lsb[index], 0.0)))  # fmt: skip
            b7 = np.where(damiao, _byte(temperature), np.where(variant == 2, np.minimum(error, 255), 0))
            word |= (_byte(b6).astype(np.uint64) << np.uint64(8)) | b7.astype(np.uint64)
        data = word.astype(">u8").view(np.uint8).reshape(len(index), 8)
        return data, self.length[index], self.arb[index]


_REPLY_SHIFTS = np.array([40, 28, 16], dtype=np.uint64)  # position, velocity, torque codes in the reply word
_SPECIAL_NAMES = {0xFC: "enter", 0xFD: "exit", 0xFE: "zero", 0xFB: "clear"}


def _byte(x: np.ndarray) -> np.ndarray:
    """Nearest unsigned byte, saturating, NaN -> 0 (the protocol's reply byte rule)."""
    x = np.asarray(x, dtype=float)
    return np.clip(np.rint(np.where(np.isnan(x), 0.0, x)), 0, 255).astype(np.int64)


__all__ = [
    "CANOPEN_SYNC_ID",
    "EMULATOR_FAULT_KINDS",
    "FAULT_KINDS",
    "HOST_FAULT_KINDS",
    "MOTOR",
    "OFF",
    "ActuatorEmulator",
    "AppliedSnapshot",
    "EmulatorConfig",
    "EmulatorCounters",
    "FaultInjection",
    "Gantry",
    "ThermalModel",
]
