"""A supervisor that cannot hang (issue #13): the runtime's own time advances whatever the exchange
does, a driver bug is a counted error not an escaped exception, the watchdog stops the motors of a
loop that never comes back, signals reach a loop running in another thread, and the supervisor
names bus-off, driver bugs and motors that left motor mode."""

from __future__ import annotations

import _thread
import copy
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import can
import numpy as np
import pytest

from giwbc.emulation import EmulatorConfig
from giwbc.hal.frames import MessagePort, frames
from giwbc.runlog import read_log
from giwbc.hal.safety import FaultKind, SafetyConfig, SafetySupervisor, SignalWatch
from giwbc.runtimes.phases import StartupConfig

ROOT = Path(__file__).resolve().parents[1]
DT = 0.002
T_FAULT = 0.3
STARTUP = StartupConfig(settle_time=0.02, ramp_time=0.2, shutdown_time=0.1, off_delay=0.05)
HANG_GUARD = 120.0  # s: a run still going then is a hang; the guard interrupts it (a failure, not a stuck session)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def run_lockstep(g1, model, tmp_path, *, policy=None, safety=None, patch=None, seconds=0.4):
    """A standing PD run on the lockstep emulator, unpaced; ``patch(robot)`` may break the robot.
    Returns (result, runtime, emulator, log path)."""
    from giwbc.robot.standing import PdHold
    from giwbc.hal.can_robot import CanRobot
    from giwbc.emulation import ActuatorEmulator
    from giwbc.hal.hardware import load_hardware
    from giwbc.runlog import RunLogWriter
    from giwbc.runtimes.realtime import RealtimeRuntime
    from giwbc.tasks.standing import StandingTask

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    emulator = ActuatorEmulator(plan, g1, EmulatorConfig(record=True), model=copy.copy(model))
    robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator)
    if patch is not None:
        patch(robot)
    log = RunLogWriter(tmp_path / "run.mcap", g1.joint_names)
    runtime = RealtimeRuntime(StandingTask(PdHold(g1), g1.default_positions), robot, log=log, startup=STARTUP, realtime=False,
                              safety=safety or SafetyConfig(damping_time=0.1))  # fmt: skip
    guard = threading.Timer(HANG_GUARD, _thread.interrupt_main)
    guard.start()
    try:
        result = runtime.run(policy, seconds=seconds)
    finally:
        guard.cancel()
        log.close()
    return result, runtime, emulator, robot, log.path


def test_an_exchange_that_always_raises_still_ends_in_a_bounded_stop(g1, model, tmp_path):
    """Defect 1: robot time advanced only on a successful exchange, so the safe stop of a robot
    whose exchange raises looped forever. Now the stop is a bounded number of cycles."""

    def patch(robot):
        exchange = robot.exchange

        def broken(t, deadline=None, kind="command"):
            if t >= T_FAULT:
                raise RuntimeError("driver bug: adapter unplugged")
            return exchange(t, deadline, kind)

        robot.exchange = broken

    result, runtime, emulator, robot, log = run_lockstep(g1, model, tmp_path, patch=patch)
    robot.close()
    emulator.close()
    fault = result.fault
    assert fault.kind is FaultKind.DRIVER_ERROR and "RuntimeError: driver bug" in fault.message
    assert fault.time == pytest.approx(T_FAULT, abs=0.5 * DT)
    assert runtime.phase == "off" and result.exit_code == 1
    # Damping for damping_time after the fault, then the exit attempts: the whole stop is bounded.
    stop_cycles = result.cycles - round(T_FAULT / DT)
    assert stop_cycles <= round(0.1 / DT) + StartupConfig().exit_attempts + 2
    events = read_log(log, topics=["/events"]).event_names()
    assert events[-1] == "motors_off"


def test_a_policy_that_never_returns_is_stopped_by_the_watchdog(g1, model, tmp_path):
    """A loop stuck outside any exchange (a hung policy): the watchdog switches every motor to
    damping and then off, and run() returns with the cause."""
    release = threading.Event()
    calls = []

    def policy(observation):
        calls.append(1)
        if len(calls) > 3:
            release.wait()  # hangs until the test ends
        return np.zeros(0, dtype=np.float32)

    try:
        result, runtime, emulator, robot, log = run_lockstep(g1, model, tmp_path, policy=policy)
    finally:
        release.set()
    runtime._loop_thread.join(5.0)
    robot.close()
    emulator.close()
    assert result.fault.kind is FaultKind.WATCHDOG and "no control cycle" in result.fault.message
    assert result.exit_code == 1 and runtime.phase == "off"
    assert runtime.emergency["unreachable_buses"] == [] and runtime.emergency["damping_steps"] == round(0.1 / DT)
    assert (emulator.mode == 0).all()  # every motor off
    snaps = [s for s in emulator.snapshots if s.time > result.fault.time + 0.5 * DT]
    # The watchdog's first frames: damping (its sender threads may start a step late on a loaded machine).
    assert any((s.kp == 0).all() and (np.abs(s.tau_ff) < 0.05).all() for s in snaps[:3])
    events = read_log(log, topics=["/events"]).event_names()
    assert "watchdog" in events and events[-1] == "motors_off"


class _BuggyBus(can.BusABC):
    """A python-can driver with a bug: send and recv raise RuntimeError."""

    def __init__(self) -> None:
        super().__init__(channel="buggy")

    def send(self, msg, timeout=None):
        raise RuntimeError("driver bug in send")

    def _recv_internal(self, timeout):
        raise RuntimeError("driver bug in recv")


def test_a_driver_bug_is_a_counted_error_not_an_escaped_exception():
    """Defect 1's cause: a non-``can.CanError`` from ``bus.send`` escaped the exchange (and stopped
    the other buses' frames). Now the frame is dropped, the error counted and kept for the log."""
    bus = _BuggyBus()
    port = MessagePort(bus)
    batch = frames([1, 2], np.zeros((2, 8), dtype=np.uint8))
    outcome = port.send(batch, float("inf"), timeout=0.0, retries=1)
    assert (outcome.sent, outcome.dropped, outcome.errors) == (0, 2, 4)
    assert isinstance(port.last_error, RuntimeError)
    received = port.receive(None)
    assert len(received.frames) == 0 and isinstance(received.error, RuntimeError)
    bus.shutdown()


def test_signal_watch_sees_a_signal_delivered_to_another_thread():
    """The loop runs in a thread of its own; Python runs handlers only in the main thread, so the
    loop reads the wake-up fd: a signal delivered to the loop's thread is seen at once there."""
    watch = SignalWatch().install()
    seen = []

    def loop():
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
        seen.append(watch.poll())

    try:
        worker = threading.Thread(target=loop)
        worker.start()
        worker.join()
    finally:
        watch.restore()
    assert seen == [signal.SIGTERM] and watch.name == "SIGTERM"


def _report(g1, **fields):
    from giwbc.hal.can_robot import CycleReport

    n = g1.dofs
    base = dict(cycle=0, time=0.0, kind="command", missing=np.zeros(n, bool), stale=np.zeros(n, np.int64),
                error_code=np.zeros(n, np.int64), temperature=np.full(n, 30.0), late=0, corrupt=np.zeros(10, np.int64),
                unknown=0, send_dropped=0, clamped=0, imu_fresh=True, send_s=0.0, receive_s=0.0)  # fmt: skip
    base.update(fields)
    return CycleReport(**base)


def test_supervisor_names_a_motor_out_of_motor_mode_bus_off_and_driver_bugs(g1):
    """Defects 2 and 5 at the supervisor: Damiao state 0 is a fault (not-reported states, -1, are
    not); a bus whose driver refused every frame for ``bus_off_cycles`` is bus-off, named with the
    driver's error; a driver raising what no CAN driver should is a driver error at once."""
    from giwbc.robot.interface import ImuReading

    level = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]))
    q0, zeros = g1.default_positions, np.zeros(g1.dofs)
    buses = tuple(f"can{b}" for b in range(10))
    status = np.where(np.arange(g1.dofs) < 20, 1, -1)
    sup = SafetySupervisor(g1, SafetyConfig(), bus_names=buses)
    assert sup.check(_report(g1, status=status), q0, zeros, zeros, level) == []
    knee = g1.joint_names.index("left_knee_joint")
    status[knee] = 0
    (fault,) = sup.check(_report(g1, status=status), q0, zeros, zeros, level)
    assert fault.kind is FaultKind.MOTOR_DISABLED and fault.joints == ("left_knee_joint",)
    missing = np.zeros(g1.dofs, bool)
    missing[knee] = True  # a stale state from a motor that did not reply this cycle is not read
    assert sup.check(_report(g1, status=status, missing=missing), q0, zeros, zeros, level) == []

    sup = SafetySupervisor(g1, SafetyConfig(), bus_names=buses)
    sent, errors = np.full(10, 3), np.zeros(10, np.int64)
    sent[1], errors[1] = 0, 9
    causes = (None, can.CanOperationError("Network is down")) + (None,) * 8
    assert sup.check(_report(g1, bus_sent=sent, bus_errors=errors, driver_errors=causes), q0, zeros, zeros, level) == []
    (fault,) = sup.check(_report(g1, bus_sent=sent, bus_errors=errors, driver_errors=causes), q0, zeros, zeros, level)
    assert fault.kind is FaultKind.BUS_OFF and "can1 (CanOperationError: Network is down)" in fault.message
    bug = (None, RuntimeError("oops")) + (None,) * 8
    (fault,) = SafetySupervisor(g1, SafetyConfig(), bus_names=buses).check(
        _report(g1, bus_sent=sent, bus_errors=errors, driver_errors=bug), q0, zeros, zeros, level)
    assert fault.kind is FaultKind.DRIVER_ERROR and "can1: RuntimeError: oops" in fault.message


def test_command_line_fault_rehearsal_with_a_driver_stuck_forever(tmp_path):
    """``giwbc deploy --emulate --fault driver_block``: can1's driver blocks in send forever; the
    watchdog stops the motors and the process still exits, with the documented code and cause."""
    log = tmp_path / "cli.mcap"
    proc = subprocess.run(
        [sys.executable, "-m", "giwbc.apps.deploy", "--emulate", "--controller", "pd", "--seconds", "1.0", "--ramp", "0.2",
         "--fault", "driver_block", "--fault-at", "0.2", "--log", str(log), "--json"],
        cwd=ROOT, capture_output=True, text=True, timeout=HANG_GUARD, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr[-2000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    # (A loaded machine may stop the real-time lockstep run earlier, e.g. on late replies: the
    # stuck driver then hangs the safe stop, and the watchdog ends that.)
    assert "watchdog" in summary["faults"] and "watchdog" in summary["message"]
    run_log = read_log(log, topics=["/faults", "/events"])
    assert "watchdog" in [f["kind"] for f in run_log.faults] and run_log.event_names()[-1] == "motors_off"


def test_command_line_refuses_an_unknown_fault(capsys):
    import argparse

    from giwbc.apps.deploy import add_deploy_command

    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", "--emulate", "--fault", "gremlins"])
    assert args.run(args) == 2
    err = capsys.readouterr().err
    assert "unknown fault 'gremlins'" in err and "bus_off" in err  # the known kinds are listed


class _Loop:
    """What the watchdog reads of a runtime: phase, cycle count, stop deadline; records take-overs."""

    def __init__(self, phase: str) -> None:
        self.phase, self._cycles, self.stop_deadline = phase, 0, None
        self.reasons: list[str] = []
        self.taken = threading.Event()

    def take_over(self, reason: str) -> bool:
        self.reasons.append(reason)
        self.taken.set()
        return True


def test_watchdog_fires_on_a_stalled_loop_and_on_an_overrunning_stop_only():
    from giwbc.runtimes.watchdog import LoopWatchdog

    idle = _Loop("idle")  # nothing to watch before the motors start, however long
    dog = LoopWatchdog(idle, 0.02, poll=0.005).start()
    assert not idle.taken.wait(0.1)
    dog.stop()

    cycling = _Loop("running")  # a loop that keeps producing cycles is never taken over
    dog = LoopWatchdog(cycling, 0.5, poll=0.005).start()
    for _ in range(40):
        cycling._cycles += 1
        assert not cycling.taken.wait(0.005)
    dog.stop()

    stalled = _Loop("running")
    dog = LoopWatchdog(stalled, 0.02, poll=0.005).start()
    assert stalled.taken.wait(HANG_GUARD) and "no control cycle" in stalled.reasons[0]
    assert dog.fired == stalled.reasons[0] and len(stalled.reasons) == 1

    import time

    overrun = _Loop("damping")  # cycling, but past the stop's deadline
    overrun.stop_deadline = time.perf_counter() + 0.03
    dog = LoopWatchdog(overrun, 10.0, poll=0.005).start()
    while not overrun.taken.is_set() and time.perf_counter() < overrun.stop_deadline + HANG_GUARD:
        overrun._cycles += 1
        time.sleep(0.002)
    assert "overran its deadline" in overrun.reasons[0]
