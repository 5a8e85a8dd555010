"""The actuator emulator behind Unitree's low-level DDS interface, in its own process, on loopback.

:class:`DdsEmulatorProcess` runs the actuator emulator's MuJoCo robot and motor firmware
(:class:`~giwbc.emulation.emulator.ActuatorEmulator`: physics, motor-mode state machine, command
watchdog, latched errors, thermal model, the emulated IMU, its injected faults) in a child
process and puts it behind ``rt/lowcmd`` / ``rt/lowstate`` as a G1 does (``unitree_hg`` types,
Unitree's CRC), on the loopback interface only (:func:`~giwbc.hal.dds.config.cyclone_config`).
Its CAN buses (python-can ``virtual``, in the child) carry nothing: commands reach the firmware
from the ``LowCmd_`` directly.

* The robot publishes its state from the start (before any command: at rest, physics not
  running; ``tick`` counts the states published), every control period, and right after each
  command it takes (the state after that command's arrival: the host reads it at its next cycle).
  Emulator time 0 is the host's first command, as for :mod:`giwbc.emulation.process`.
* A ``LowCmd_`` with a bad CRC is refused and counted (``counters["crc_errors"]``). Mode byte 1
  on a motor that is off enters motor mode (the firmware's ``enter``), 0 on one that is on exits
  (``exit``); kp, kd, q, dq, tau apply in motor mode. A motor that hears no command for the
  firmware's ``watchdog_timeout`` goes limp and reports mode 0.
* The reported ``motorstate`` is the firmware's latched error code (0: none), temperatures the
  coil's and the driver's, ``mode`` 1 for a motor in motor mode producing its command.

DDS faults (:class:`DdsFault`, emulator time): ``silent`` (no state published), ``stale_state``
(the same state, same tick, published again and again), ``corrupt`` (states with a broken CRC,
with ``probability``), ``drop_commands`` (commands taken and ignored: the firmware's watchdog
then makes the motors limp), ``late_subscriber`` (the robot's reader of ``rt/lowcmd`` is deleted
at ``start``: nobody hears the commands), ``service_active`` (a second participant publishes
``rt/lowcmd``, as the robot's locomotion service does until released), ``service_refuses`` (the
motion switcher answers ReleaseMode with an error and the service keeps running),
``service_mute`` (the motion switcher answers nothing). Motor faults are the
emulator's own (:class:`~giwbc.emulation.faults.FaultInjection` in ``EmulatorConfig.faults``:
``error``, ``overheat``, ``push``, ...).

The robot's own locomotion service (``service``: the name of its mode, e.g. ``"ai"``; None: no
service, the robot already released): a second participant publishes ``rt/lowcmd`` every control
period (its hold of the joints where they are) while its mode is active, and the motion switcher
(:mod:`giwbc.hal.dds.motion_switcher`: ``rt/api/motion_switcher/request`` / ``response``, the
``unitree_api`` types) answers CheckMode (``{"form": "0", "name": <mode or "">}``), ReleaseMode
(the service stops publishing: ``name`` empty) and SelectMode (``{"name": ...}``: it publishes
again). The service's commands stand for the robot's own controller: they reach the host's
listener, not the emulated firmware (the emulator's reader ignores its own process's writers).
"""

from __future__ import annotations

import gc
import json
import math
import os
import time
import traceback
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.emulation.child import ChildEmulator
from giwbc.emulation.config import EmulatorConfig
from giwbc.emulation.emulator import ActuatorEmulator
from giwbc.emulation.firmware import MOTOR, OFF
from giwbc.hal.dds.config import LOOPBACK
from giwbc.hal.dds.messages import OK, LowCmd, LowState
from giwbc.hal.dds.motion_switcher import CHECK_MODE, RELEASE_MODE, RPC_ERR_SERVER_INTERNAL, RPC_OK, SELECT_MODE, RpcEndpoint, response
from giwbc.hal.dds.plan import DdsPlan
from giwbc.hal.dds.transport import LOWCMD_TOPIC, LOWSTATE_TOPIC, DdsTransport
from giwbc.hal.hardware import HardwarePlan
from giwbc.plants import resolve_plant

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

DDS_FAULT_KINDS = ("silent", "stale_state", "corrupt", "drop_commands", "late_subscriber", "service_active", "service_refuses", "service_mute")
RPC_ERR_SERVER_API_NOT_IMPL = 3203  # the SDK's code for an API the service does not have
MODE_MACHINE = 5  # LowState_.mode_machine the emulated G1 reports (the host echoes it; giwbc does not interpret it)


@dataclass(frozen=True)
class DdsFault:
    """A fault of the emulated robot's DDS side, active in ``[start, stop)`` emulator seconds."""

    kind: str
    start: float = 0.0
    stop: float = math.inf
    probability: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in DDS_FAULT_KINDS:
            raise ValueError(f"unknown DDS fault kind {self.kind!r}; known: {', '.join(DDS_FAULT_KINDS)}")
        if not self.stop > self.start or not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"DDS fault {self.kind}: window [{self.start}, {self.stop}) empty or probability not in [0, 1]")

    def active(self, t: float) -> bool:
        return self.start <= t < self.stop


def emulation_domain(pid: int | None = None) -> int:
    """A DDS domain of this run's own on loopback (1..200): rehearsals on one machine do not meet."""
    return 1 + (os.getpid() if pid is None else pid) % 200


class DdsEmulatorProcess(ChildEmulator):
    """The emulated G1 behind DDS in a child process (module docstring).

    ``plan``: the DDS plan (its interface is replaced by loopback, its domain by ``domain``,
    default :func:`emulation_domain`); ``motors``: the hardware plan whose motor models the
    firmware emulates (the robot's CAN reference plan); ``faults``: :class:`DdsFault` s; ``cpu``:
    pin the child to this CPU (keep the control loop on another); ``service``: the locomotion
    service's mode active at start (module docstring), None: none."""

    label = "DDS emulator process"

    def __init__(self, plan: DdsPlan, motors: HardwarePlan, description: RobotDescription, config: EmulatorConfig | None = None, *,
                 faults: tuple[DdsFault, ...] = (), domain: int | None = None, start_timeout: float = 60.0, plant: Any = None,
                 cpu: int | None = None, service: str | None = None) -> None:  # fmt: skip
        plan.validate_joints(description.joint_names)
        motors.routing(description.joint_names)
        if plant is not None:
            plant = resolve_plant(description, plant)
        self.plan = plan.with_interface(LOOPBACK, emulation_domain() if domain is None else domain)
        self.config = config or EmulatorConfig()
        self.faults = tuple(faults)
        self.service = service
        self.counters: dict[str, int] = {}
        self.scheduler = "default" if cpu is None else f"CPU {cpu}, default"
        args = (self.plan, motors, description, self.config, self.faults, plant, cpu, service)
        self.physics_dt: float | None = float(self._start(_serve, args, "giwbc-dds-emulator", start_timeout))

    def host_plan(self) -> DdsPlan:
        """The plan the host uses: loopback, this emulator's domain."""
        return self.plan

    def _done(self, payload: Any) -> None:
        self.truth, self.counters = payload


# ----------------------------------------------------------------------------- the child
def _serve(plan: DdsPlan, motors: HardwarePlan, description: RobotDescription, config: EmulatorConfig, faults: tuple[DdsFault, ...],
           plant: Any, cpu: int | None, service: str | None, conn: Any) -> None:  # fmt: skip
    try:
        _Robot(plan, motors, description, config, faults, conn, plant, cpu, service).run()
    except BaseException:  # noqa: BLE001 - reported to the parent
        try:
            conn.send(("error", traceback.format_exc()))
        except OSError:
            pass


class _Robot:
    """The child's emulated G1: the actuator emulator, its DDS endpoints, its clock."""

    def __init__(self, plan: DdsPlan, motors: HardwarePlan, description: RobotDescription, config: EmulatorConfig,
                 faults: tuple[DdsFault, ...], conn: Any, plant: Any, cpu: int | None = None, service: str | None = None) -> None:  # fmt: skip
        self.conn, self.faults = conn, faults
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        model = description.build_mujoco() if plant is None else None
        quiet = replace(config, faults=tuple(config.faults))
        self.emulator = e = ActuatorEmulator(motors, description, quiet, model=model, plant=plant)
        self.slots = np.array(plan.slot_array(description.joint_names), dtype=np.int64)[e.joint_index]  # per motor (plan order)
        self.transport = DdsTransport(plan.domain, plan.interface, publish=LOWSTATE_TOPIC, subscribe=LOWCMD_TOPIC, source="emulator",
                                      local=False)  # fmt: skip
        self.mode = service or ""  # the locomotion service's active mode ("" released)
        self.service = (DdsTransport(plan.domain, plan.interface, publish=LOWCMD_TOPIC, subscribe=None, source="emulator")
                        if service or any(f.kind == "service_active" for f in faults) else None)  # fmt: skip
        self.switcher = RpcEndpoint(plan.domain, plan.interface, server=True, source="emulator") if service else None
        self.cmd, self.state, self.service_cmd = LowCmd(), LowState(), LowCmd()
        self.state.field("mode_machine")[0] = MODE_MACHINE
        self.rng = np.random.default_rng(None if config.seed is None else (config.seed, 0xDD5))
        self.period = 1.0 / plan.control_rate
        self.torque_max = np.array([m.model.torque.magnitude for m in e.motors])
        self.counters = {"commands": 0, "crc_errors": 0, "states": 0, "dropped_commands": 0, "foreign": 0, "service_commands": 0,
                         "releases": 0, "selects": 0, "rpc_requests": 0}  # fmt: skip
        self.tick = 0
        self.frozen: bytes | None = None

    def active(self, kind: str, t: float) -> DdsFault | None:
        return next((f for f in self.faults if f.kind == kind and f.active(t)), None)

    def run(self) -> None:
        from cyclonedds.core import ReadCondition, SampleState, WaitSet

        e, conn = self.emulator, self.conn
        waitset = WaitSet(self.transport.participant)
        waitset.attach(ReadCondition(self.transport.reader, SampleState.Any))
        gc.collect()
        gc.freeze()
        conn.send(("ready", e.physics_dt))
        clock = time.perf_counter
        start: float | None = None
        next_state = clock()
        running = True
        try:
            while running:
                now_wall = clock()
                wait = max(0.0, next_state - now_wall)
                if start is not None:
                    wait = min(wait, max(0.0, start + e.time + e.physics_dt - now_wall))
                if self.transport.reader is not None:
                    waitset.wait(int(wait * 1e9))
                else:
                    time.sleep(wait)
                if conn.poll(0):
                    kind, _ = conn.recv()
                    running = kind != "stop"
                t = 0.0 if start is None else clock() - start
                took = self.commands(t)
                if took and start is None:
                    start, t = clock(), 0.0
                if start is not None:
                    e.advance(clock() - start)
                    t = e.time
                if self.transport.reader is not None and self.active("late_subscriber", t):
                    self.transport.drop_reader()  # (the wait set is not waited on again: no reader)
                if took or clock() >= next_state:
                    self.publish(t)
                    next_state = max(next_state + self.period, clock() - self.period)
                if self.service is not None and self.active("service_active", t) and took:
                    self.service.write(self.service_cmd.seal())
                if self.switcher is not None:
                    self.serve_switcher(t)
            conn.send(("done", (np.array(e.truth, dtype=float).reshape(-1, 5), dict(self.counters))))
        finally:
            e.close()
            self.transport.close()
            if self.service is not None:
                self.service.close()
            if self.switcher is not None:
                self.switcher.close()

    def commands(self, t: float) -> bool:
        """Take the waiting commands and hand each good one to the firmware; whether any came."""
        got = self.transport.take(16)
        if not got:
            return False
        if self.active("drop_commands", t):
            self.counters["dropped_commands"] += len(got)
            return True
        e, cmd, slots = self.emulator, self.cmd, self.slots
        for data in got:
            if cmd.load(data) != OK:
                self.counters["crc_errors"] += 1
                continue
            self.counters["commands"] += 1
            on = cmd.modes[slots] == 1
            rows = np.array((cmd.q[slots], cmd.dq[slots], cmd.kp[slots], cmd.kd[slots], cmd.tau[slots]), dtype=float)
            values = e.group.commands_to_motor(rows).T.copy()  # motor side: position, velocity, kp, kd, torque
            values[:, 2:4] = np.maximum(values[:, 2:4], 0.0)
            values[:, 4] = np.clip(values[:, 4], -self.torque_max, self.torque_max)
            now = e.time
            special = False
            for i in np.flatnonzero(on & (e.mode == OFF)).tolist():
                special |= e._state_machine(i, "enter", values[i], now)  # the firmware's own state machine
            for i in np.flatnonzero(~on & (e.mode == MOTOR)).tolist():
                special |= e._state_machine(i, "exit", values[i], now)
            changed = e._commands(np.arange(len(slots)), values, now)
            if changed or special:
                e._apply_commands()
        return True

    def serve_switcher(self, t: float) -> None:
        """Answer the motion switcher's requests waiting (module docstring; faults permitting)."""
        for request in self.switcher.take():
            self.counters["rpc_requests"] += 1
            if self.active("service_mute", t):
                continue
            api = request.header.identity.api_id
            code, data = RPC_OK, ""
            if api == CHECK_MODE:
                data = json.dumps({"form": "0", "name": self.mode})
            elif api == RELEASE_MODE:
                if self.active("service_refuses", t):
                    code = RPC_ERR_SERVER_INTERNAL
                else:
                    self.mode = ""
                    self.counters["releases"] += 1
            elif api == SELECT_MODE:
                try:
                    self.mode = str(json.loads(request.parameter)["name"])
                    self.counters["selects"] += 1
                except (ValueError, KeyError, TypeError):
                    code = RPC_ERR_SERVER_INTERNAL
            else:
                code = RPC_ERR_SERVER_API_NOT_IMPL
            self.switcher.write(response(request, code, data))

    def publish(self, t: float) -> None:
        """Publish the state now (faults permitting)."""
        if self.active("silent", t):
            return
        if self.active("stale_state", t):
            if self.frozen is None:
                self.frozen = self.state.seal()
            self.transport.write(self.frozen)
            return
        e, s, slots = self.emulator, self.state, self.slots
        position, velocity, torque = e._motor_state()
        q, dq, tau = e.group.state_to_joint(position, velocity, torque)
        s.q[slots], s.dq[slots], s.tau_est[slots] = q, dq, tau
        th = e.config.thermal
        s.temperature[slots, 0] = np.round(e.temperature)
        s.temperature[slots, 1] = np.round(th.ambient + th.mos_fraction * (e.temperature - th.ambient))
        s.motorstate[slots] = e.error
        modes = np.zeros(len(s.floats), dtype=np.uint8)
        modes[slots] = ((e.mode == MOTOR) & ~e.limp()).astype(np.uint8)
        s.set_modes(modes)
        reading = e.imu_channel.read()
        if reading is not None:
            x, y, z, w = np.asarray(reading.quaternion, dtype=float)
            s.quaternion[:] = (w, x, y, z)
            s.gyroscope[:] = reading.angular_velocity
            s.accelerometer[:] = reading.linear_acceleration
        self.tick += 1
        s.tick[0] = self.tick
        data = s.seal()
        fault = self.active("corrupt", t)
        if fault is not None and self.rng.random() < fault.probability:
            raw = bytearray(data)
            raw[100] ^= 0x40  # a flipped bit in motor 0's record: the CRC no longer matches
            data = bytes(raw)
        self.transport.write(data)
        self.counters["states"] += 1
        if self.service is not None:  # what the locomotion service would command: hold the joints where they are
            c = self.service_cmd
            modes = np.zeros(len(c.floats), dtype=np.uint8)
            modes[slots] = 1
            c.set_modes(modes)
            c.q[slots] = q
            if self.mode:  # the locomotion service runs: it commands the motors every period
                self.service.write(c.seal())
                self.counters["service_commands"] += 1


__all__ = ["DDS_FAULT_KINDS", "DdsEmulatorProcess", "DdsFault", "emulation_domain"]
