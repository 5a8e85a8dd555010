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

Faults (:class:`~giwbc.emulation.faults.FaultInjection`, applied by :class:`~giwbc.emulation.faults.FaultEffects`)
act on replies, firmware state and the physics; see :mod:`giwbc.emulation.faults`.
A :class:`~giwbc.emulation.config.Gantry` can hold the base while the motors start (start-up rehearsals).

Speed: every bus speaks MIT mode in the shipped plans, so commands are decoded and replies encoded
for all motors at once (:class:`~giwbc.emulation.firmware.MitFirmwareCodec`, bit-identical to the protocol's scalar calls);
python-can's per-frame cost is what remains (~5 us per send or receive on ``virtual``).

Temperature: :class:`~giwbc.emulation.thermal.ThermalModel`. The IMU is MuJoCo's, published to an :class:`~giwbc.hal.imu.ImuChannel` after each physics advance,
and, when the plan's IMU is ``serial`` or ``can``, sent as that device's bytes
(:mod:`~giwbc.emulation.imu_devices`: a pseudo-terminal whose path :meth:`host_plan` gives, or
frames on the IMU's bus), so the host reads it through its real driver. With
:attr:`EmulatorConfig.imu` it carries a real IMU's errors (:class:`~giwbc.robot.noise.SensorModel`:
biases drawn once from the seed, noise, latency counted in published samples, dropouts, no orientation output
for a ``mems`` profile); :attr:`ActuatorEmulator.imu_errors` keeps what was drawn, for judging a calibration.
"""

from __future__ import annotations

import math
import time
import uuid
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from giwbc.errors import PlantMismatchError
from giwbc.emulation.config import AppliedSnapshot, EmulatorConfig, EmulatorCounters
from giwbc.emulation.faults import _REPLY_FAULTS, FaultEffects, FaultInjection
from giwbc.emulation.firmware import MOTOR, OFF, MitFirmwareCodec
from giwbc.hal.frames import FramePort, PortGroup, fields, frame_port, frames, frames_of
from giwbc.emulation.imu_devices import SerialImuDevice, imu_device_for
from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.imu import ImuChannel
from giwbc.hal.motor import MotorGroup
from giwbc.hal.protocols import ActuatorProtocol, CanProtocolError
from giwbc.robot.interface import ImpedanceCommand
from giwbc.plants import PlantSpec, resolve_plant
from giwbc.robot.mujoco_robot import MujocoRobot
from giwbc.robot.noise import SensorErrors, SensorModel

if TYPE_CHECKING:
    import mujoco

    from giwbc.robot.description import RobotDescription

_SEND_DEADLINE = 20e-3  # s a poll's replies may take to send (see ActuatorEmulator._send)


class ActuatorEmulator(FaultEffects):
    """The motors of ``plan`` on virtual buses, driving a MuJoCo model of ``description``.

    ``model``: an ``MjModel`` to use (it is modified: gains live in actuator parameters), e.g. a
    copy of a cached one; default: built from the description (slow, ~1 s). ``plant``: the plant
    instead (a shipped variant's name, a variant ``.toml``, an MJCF file, an ``MjModel``:
    :func:`giwbc.plants.resolve_plant`; its actuator lag and torque-speed envelope act behind the
    firmware's torque). ``interface`` and
    ``bus_options``: the python-can interface of its channels (``"giwbc-unix"`` with
    ``{"serve": True}`` when it runs in its own process, :mod:`giwbc.emulation.process`).
    """

    def __init__(
        self,
        plan: HardwarePlan,
        description: RobotDescription,
        config: EmulatorConfig | None = None,
        *,
        model: mujoco.MjModel | None = None,
        plant: PlantSpec = None,
        channel_prefix: str | None = None,
        interface: str = "virtual",
        bus_options: dict[str, Any] | None = None,
        send_deadline: float = _SEND_DEADLINE,
    ) -> None:
        """``send_deadline``: s a poll's replies may take to send (``math.inf`` for a run in simulated
        time, where the host machine's preemption must not drop a reply)."""
        self.config = c = config or EmulatorConfig()
        self.send_deadline = float(send_deadline)
        self.description = description
        names = description.joint_names
        self.plan = plan
        self._routing = plan.routing(names)  # validates the plan against the robot
        prefix = channel_prefix or f"giwbc-emu-{uuid.uuid4().hex[:12]}"  # channels of its own
        self._host_plan = replace(
            plan,
            buses=tuple(replace(b, interface=interface, channel=f"{prefix}/{b.name}") for b in plan.buses),
        )
        if plant is not None:
            if model is not None:
                raise PlantMismatchError("give the emulator's plant once: model= or plant=, not both")
            self.robot: MujocoRobot = MujocoRobot(description, **resolve_plant(description, plant).robot_options())  # type: ignore[arg-type]
        else:
            self.robot = MujocoRobot(description, model)
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
        self._codec = MitFirmwareCodec.for_buses(self.protocols, self.motors)

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
        self.imu_errors: SensorErrors | None = None  # the IMU's drawn errors (None: exact)
        self._imu_model: SensorModel | None = None
        if c.imu is not None:
            imu_rng = np.random.default_rng(None if c.seed is None else (c.seed, 0x1A0))  # a stream of its own
            self.imu_errors = c.imu.errors(imu_rng)
            self._imu_model = SensorModel(self.robot, self.imu_errors, imu_rng)
        # A serial or CAN IMU in the plan: its bytes too, for the host's real driver (the channel
        # keeps every sample, for tests).
        self.imu_device = imu_device_for(plan.imu, {b.name: p for b, p in zip(plan.buses, self.ports)})
        if isinstance(self.imu_device, SerialImuDevice):
            self._host_plan = self._host_plan.with_imu(replace(plan.imu, device=self.imu_device.path))
        self.snapshots: list[AppliedSnapshot] = []
        self.truth: list[tuple[float, ...]] = []  # ground truth (time, height, tilt, x, y) for judging a dry run, never sent to the host
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
            if self.imu_device is not None:
                self.imu_device.close()
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
                self.truth.append((self.time, float(qpos[2]), tilt, float(qpos[0]), float(qpos[1])))
        if self.faults or self.error.any() or self.temperature.max() > c.thermal.trip:
            self._update_faults(self.time)

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
        self._send_faulty(bus, index, replies, active, t)

    def _send(self, b: int, batch: np.ndarray) -> None:
        """Send on bus ``b`` now or never: a full host queue loses the reply, as a real bus under
        overload would: no waiting for room. The deadline only bounds a send the host machine
        preempts (firmware is not preempted: a loaded test machine must not drop replies)."""
        self.ports[b].send(batch, time.perf_counter() + self.send_deadline, timeout=0.0, retries=0)

    def _send_by_bus(self, bus: np.ndarray, batch: np.ndarray) -> None:
        """Send each frame of ``batch`` on its bus (``bus`` ascending, as frames are received)."""
        bounds = np.searchsorted(bus, np.arange(len(self.ports) + 1)).tolist()
        self._ports.send(batch, bounds, time.perf_counter() + self.send_deadline, timeout=self._no_wait[0], retries=self._no_wait[1])

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
        if self.faults and any(f.kind == "imu_silent" and f.active(self.time) for f in self.faults):
            return
        model = self._imu_model
        reading = self.robot.imu() if model is None else model.imu()
        self.imu_channel.publish(reading)
        if self.imu_device is not None:
            self.imu_device.publish(reading)

    @property
    def imu_gyro_bias(self) -> np.ndarray | None:
        """The emulated IMU's gyro bias now (rad/s, IMU frame; turn-on plus random walk), None for an exact IMU."""
        return None if self._imu_model is None else self._imu_model.gyro_bias.copy()

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
        """Ground truth rows (time, base height, tilt rad, base x, base y) with ``start <= time < stop``."""
        rows = np.array(self.truth, dtype=float).reshape(-1, 5)
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


__all__ = ["ActuatorEmulator"]
