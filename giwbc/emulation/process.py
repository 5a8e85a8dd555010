"""The actuator emulator in its own process, as motors run on their own hardware.

In lockstep (:class:`~giwbc.emulation.emulator.ActuatorEmulator` as the CAN robot's ``peer``) the
control loop pays for the emulator's physics and firmware in every cycle, which real motors never
cost it. :class:`EmulatorProcess` runs the same emulator in a child process instead, on
:mod:`giwbc.hal.unix_bus` channels, on its own clock:

* it starts when the host's first frame arrives (emulator time 0 is the host's first cycle, so
  ground-truth times line up with the runtime's to about a period) and then advances physics in
  real time, one physics step whenever one is due, answering frames as soon as they arrive —
  what firmware does; the host gets replies asynchronously, late ones are late;
* the IMU is published through a shared-memory mailbox (:class:`SharedImuChannel`), the
  cross-process form of the in-process ``emulated`` IMU source;
* faults are injected from the start (``EmulatorConfig.faults``) or with :meth:`add_fault`;
* :meth:`close` stops the child and brings back its ground truth, counters, CPU time and how late it
  ran (:class:`EmulatorStalls`: a missing-replies stop with the emulator milliseconds late at
  real-time priority is the machine's, not the motors').

A dry run in this mode is real-time and not bit-reproducible (two clocks); tests that need
determinism use lockstep. An error in the child is reported by the parent with the child's
traceback, and a child that dies shows up as motors that stop answering (the safety supervisor
stops the run).
"""

from __future__ import annotations

import copy
import gc
import os
import select
import time
import traceback
import uuid
from dataclasses import dataclass, replace
from multiprocessing import shared_memory
from typing import TYPE_CHECKING, Any

import numpy as np

import can

from giwbc.emulation.child import ChildEmulator
from giwbc.emulation.config import EmulatorConfig, EmulatorCounters
from giwbc.plants import resolve_plant
from giwbc.emulation.emulator import ActuatorEmulator
from giwbc.emulation.faults import FaultInjection
from giwbc.hal.can_robot import ENTER, CanRobot
from giwbc.hal.hardware import HardwarePlan
from giwbc.robot.interface import ImuReading
from giwbc.robot.standing import pd_hold_command

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

INTERFACE = "giwbc-unix"
_IMU_FIELDS = 13  # sequence, time, quaternion (4), angular velocity (3), linear acceleration (3)
BURST_WAIT = 80e-6  # s from the first frame of a burst of commands to its answer
IMU_READ_WAIT = 50e-6  # s a reader waits for a write in progress before reporting no new sample


class SharedImuChannel:
    """IMU mailbox in shared memory: one writer (the emulator process), readers anywhere.

    A sequence lock: the writer makes the sequence odd, writes, makes it even; a reader retries
    when it saw an odd sequence or a change, so it never returns a torn sample.
    """

    def __init__(self, name: str | None = None) -> None:
        self._owner = name is None
        size = _IMU_FIELDS * 8
        self._shm = shared_memory.SharedMemory(create=True, size=size) if name is None else shared_memory.SharedMemory(name=name)
        self._values = np.ndarray((_IMU_FIELDS,), dtype=np.float64, buffer=self._shm.buf)
        if self._owner:
            self._values[:] = 0.0
        self.published = 0

    @property
    def name(self) -> str:
        return self._shm.name

    def publish(self, reading: ImuReading) -> None:
        values = self._values
        values[0] += 1.0  # odd: writing
        values[1] = reading.time
        values[2:6] = reading.quaternion
        values[6:9] = reading.angular_velocity
        values[9:12] = reading.linear_acceleration
        values[0] += 1.0  # even: consistent
        self.published += 1

    def read(self) -> ImuReading | None:
        """The newest consistent sample, or ``None``: nothing published yet, or the writer is in
        the middle of a write for longer than :data:`IMU_READ_WAIT`.

        A writer preempted mid-write (a loaded machine) is not a fault: the reader gives up after
        a bounded wait and reports no new sample this cycle, as a real IMU that has not sent one.
        A writer that really is stuck then shows up as a stale IMU, which the safety supervisor
        stops on after ``imu_timeout_cycles``.
        """
        values = self._values
        deadline = 0.0
        while True:
            before = values[0]
            if before == 0.0:
                return None  # nothing published yet
            if before % 2.0 == 0.0:
                sample = values.copy()
                if values[0] == before:
                    return ImuReading(sample[2:6], sample[6:9], sample[9:12], float(sample[1]))
            now = time.perf_counter()
            if deadline == 0.0:
                deadline = now + IMU_READ_WAIT
            elif now > deadline:
                return None

    def close(self) -> None:
        del self._values
        self._shm.close()
        if self._owner:
            self._shm.unlink()


@dataclass(frozen=True)
class EmulatorStalls:
    """How late the emulator process ran: its wake-ups measured against the physics step that was
    due (what a timer wake-up is for). A process at real-time priority that still ran milliseconds
    late was not given a CPU: the machine's doing (other real-time work, a virtual CPU the
    hypervisor held), not the emulated motors' nor the host's. Emulator time is seconds since the
    host's first frame."""

    longest: float  # s: the latest a wake-up came after its physics step was due
    at: float  # emulator time that step was due, s
    over_period: int  # wake-ups later than one control period


class EmulatorProcess(ChildEmulator):
    """An :class:`~giwbc.emulation.emulator.ActuatorEmulator` of ``plan`` in a child process (module docstring).

    ``rt_priority``: the child runs under ``SCHED_FIFO`` at this priority (Linux, needs
    CAP_SYS_NICE; refused silently otherwise, see :attr:`scheduler`): motors have hardware of their
    own, and a host loop at real-time priority must not starve them of the CPU. ``cpu``: pin the
    child to this CPU (keep the control loop on another one). ``plant``: the simulated plant
    (:func:`giwbc.plants.resolve_plant`; default the description's model), checked here, built in the child.
    """

    def __init__(
        self,
        plan: HardwarePlan,
        description: RobotDescription,
        config: EmulatorConfig | None = None,
        *,
        rt_priority: int | None = None,
        cpu: int | None = None,
        start_timeout: float = 60.0,
        plant: Any = None,
    ) -> None:
        plan.routing(description.joint_names)  # validates here, with a clear error, before spawning
        if plant is not None:
            plant = resolve_plant(description, plant)  # refused here, in one line, not in the child
        self.config = config or EmulatorConfig()
        prefix = f"giwbc-emu-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._host_plan = replace(plan, buses=tuple(replace(b, interface=INTERFACE, channel=f"{prefix}/{b.name}") for b in plan.buses))
        self.imu_channel = SharedImuChannel()
        self.counters: EmulatorCounters | None = None
        self.cpu_seconds: float | None = None  # the child's user + system CPU time, after close()
        self.stalls: EmulatorStalls | None = None  # how late the child ran, after close()
        self.scheduler = "default"  # the child's scheduling policy, as it could set it
        args = (plan, description, self.config, prefix, self.imu_channel.name, rt_priority, cpu, plant)
        dt, scheduler = self._start(_serve, args, "giwbc-emulator", start_timeout)
        self.physics_dt: float | None = float(dt)
        self.scheduler = str(scheduler)

    def host_plan(self) -> HardwarePlan:
        """The plan the host opens: the same buses on this emulator's ``giwbc-unix`` channels."""
        return self._host_plan

    def add_fault(self, fault: FaultInjection) -> None:
        """Inject a fault (its window is in emulator time: seconds since the host's first frame)."""
        self._send(("fault", fault))

    def _done(self, payload: Any) -> None:
        self.truth, self.counters, self.cpu_seconds, self.stalls = payload

    def _release(self) -> None:
        self.imu_channel.close()


# ----------------------------------------------------------------------------- the child
def _serve(plan: HardwarePlan, description: RobotDescription, config: EmulatorConfig, prefix: str, imu_name: str,
           rt_priority: int | None, cpu: int | None, plant: Any, conn: Any) -> None:  # fmt: skip
    """The child's main: build the emulator, wait for the host, then run in real time until told to stop."""
    try:
        _run(plan, description, config, prefix, imu_name, conn, rt_priority, cpu, plant)
    except BaseException:  # noqa: BLE001 - reported to the parent, which decides
        try:
            conn.send(("error", traceback.format_exc()))
        except OSError:
            pass


def _rehearse(plan: HardwarePlan, description: RobotDescription, config: EmulatorConfig, model: Any, prefix: str,
              cycles: int = 20, plant: Any = None) -> None:  # fmt: skip
    """A short private lockstep run (enter motor mode, hold the default pose) on a throwaway
    emulator, over giwbc-unix channels of its own (``prefix``): the first passes through numpy,
    MuJoCo, the codecs and the transport cost milliseconds each, which the real run's first
    replies must not pay (they would come cycles late)."""
    quiet = replace(config, faults=(), record=False, record_truth=False)
    with ActuatorEmulator(plan, description, quiet, model=model, plant=plant, channel_prefix=prefix, interface=INTERFACE,
                          bus_options={"serve": True}) as emulator:
        robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator)
        try:
            period = 1.0 / plan.control_rate
            robot.exchange(0.0, kind=ENTER)
            robot.set_joint_impedance(pd_hold_command(description))
            for k in range(1, cycles):
                robot.exchange(k * period)
        finally:
            robot.close()


def _control(conn: Any, emulator: Any) -> bool:
    """Handle one message from the parent; False when told to stop."""
    kind, payload = conn.recv()
    if kind == "fault":
        emulator.add_fault(payload)
    return kind != "stop"


def _run(plan: HardwarePlan, description: RobotDescription, config: EmulatorConfig, prefix: str, imu_name: str, conn: Any,
         rt_priority: int | None, cpu: int | None, plant: Any = None) -> None:  # fmt: skip
    model = description.build_mujoco() if plant is None else None
    _rehearse(plan, description, config, copy.copy(model) if plant is None else None, f"{prefix}-rehearsal", plant=plant)
    emulator = ActuatorEmulator(plan, description, config, model=model, plant=plant, channel_prefix=prefix, interface=INTERFACE,
                                bus_options={"serve": True})
    imu = SharedImuChannel(imu_name)
    emulator.imu_channel = imu
    emulator._publish_imu()  # the first sample, at rest, before the host's first cycle
    # As the real-time runtime does: collect the set-up's garbage and freeze what is left, so no
    # full collection of the heap (tens of ms) stalls the replies later.
    gc.collect()
    gc.freeze()
    scheduler = "default"
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
        scheduler = f"CPU {cpu}, default"
    if rt_priority is not None and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
            scheduler = f"SCHED_FIFO {rt_priority}" + ("" if cpu is None else f" on CPU {cpu}")
        except (OSError, ValueError) as error:
            scheduler = f"default (SCHED_FIFO refused: {error})"
    conn.send(("ready", (emulator.physics_dt, scheduler)))
    control = conn.fileno()
    listening = {bus.fileno(): (b, bus) for b, bus in enumerate(emulator.buses)}  # until the host connects each bus
    connected: dict[int, int] = {}  # descriptor -> bus index
    start: float | None = None
    clock = time.perf_counter
    dt = emulator.physics_dt
    period = 1.0 / plan.control_rate
    longest, longest_at, over_period = 0.0, 0.0, 0  # wake-ups after a due physics step (EmulatorStalls)
    running = True
    # select(), not poll(): poll's timeouts are whole milliseconds, select's microseconds.
    try:
        while running:
            timeout = None if start is None else max(0.0, start + emulator.time + dt - clock())
            ready, _, _ = select.select([control, *listening, *connected], [], [], timeout)
            if start is not None:
                late = clock() - start - emulator.time - dt  # > 0: a physics step was due that long ago
                if late > longest:
                    longest, longest_at = late, emulator.time + dt
                if late > period:
                    over_period += 1
            frames = False
            for fd in ready:
                if fd == control:
                    running = _control(conn, emulator)
                elif fd in listening:
                    b, bus = listening.pop(fd)
                    if bus.accept(0.0):
                        connected[bus.fileno()] = b
                    else:  # a spurious wake-up: keep listening
                        listening[fd] = (b, bus)
                else:
                    frames = True
            if not running:
                break
            buses: list[int] = []
            if frames:
                # A cycle's frames come as a burst (the host sends every motor's frame at once):
                # let the burst arrive, then answer it as one batch, reading only the buses that
                # have frames (a wake-up for a physics step reads none).
                select.select([], [], [], BURST_WAIT)
                buses = sorted(connected[fd] for fd in select.select(list(connected), [], [], 0)[0])
            if start is None:
                if not frames:
                    continue
                start = clock()  # emulator time 0: the host's first frame
            now = clock() - start
            try:
                emulator.advance(now)
                emulator.answer(now, buses)
            except can.CanOperationError:
                running = False  # the host closed its buses
        cpu = os.times()
        stalls = EmulatorStalls(longest, longest_at, over_period)
        conn.send(("done", (np.array(emulator.truth, dtype=float).reshape(-1, 5), emulator.counters, cpu.user + cpu.system, stalls)))
    finally:
        emulator.close()
        imu.close()


__all__ = ["EmulatorProcess", "EmulatorStalls", "SharedImuChannel"]
