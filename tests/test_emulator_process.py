"""The actuator emulator in its own process: a real-time dry run over giwbc-unix channels, a motor
that stops answering ends in damping, the IMU crosses processes intact, the child's errors surface."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.emulation import EmulatorConfig, FaultInjection
from giwbc.emulation.process import EmulatorProcess, SharedImuChannel
from giwbc.hal.hardware import load_hardware
from giwbc.runlog import read_log
from giwbc.hal.safety import FaultKind, SafetyConfig
from giwbc.robot.interface import ImuReading
from giwbc.runtimes.phases import StartupConfig

STARTUP = StartupConfig(settle_time=0.05, ramp_time=0.3, shutdown_time=0.1, off_delay=0.05)
# Two processes on their own clocks share a CI machine's CPUs without real-time priority: tolerate
# scheduling stalls of the emulator up to 50 ms (the default, 3 cycles, is for a loop at SCHED_FIFO).
TOLERANT = SafetyConfig(max_missing_cycles=25, imu_timeout_cycles=50, damping_time=0.1)


def _options(tmp_path, **overrides) -> DeployOptions:
    values = dict(emulate=True, emulator_mode="process", controller="pd", seconds=1.0, log=str(tmp_path / "run.mcap"), startup=STARTUP,
                  safety=TOLERANT)  # fmt: skip
    return DeployOptions(**{**values, **overrides})


def test_dry_run_in_real_time_with_the_emulator_in_its_own_process(g1, tmp_path) -> None:
    outcome = deploy(_options(tmp_path), description=g1, out=None)
    assert outcome.exit_code == 0, outcome.message
    result = outcome.result
    assert result.ok and result.cycles > 500  # start-up, 1 s of control, shutdown at 500 Hz
    assert outcome.standing is not None and outcome.standing["stood"] and outcome.standing["seconds"] > 0.9
    emulator = outcome.emulator
    assert emulator.failure is None and not emulator.alive
    frames = emulator.counters.frames
    assert frames.min() >= 0.9 * result.cycles  # every motor heard (nearly) every cycle's frame
    assert np.array_equal(emulator.counters.replies, frames)  # and answered each one
    log = read_log(outcome.log_path)
    assert not log.faults and log.event_names()[-1] == "motors_off"


def test_a_motor_that_stops_answering_ends_in_damping(g1, tmp_path) -> None:
    dead = FaultInjection("silent", ("right_knee_joint",), start=0.6)
    outcome = deploy(_options(tmp_path, faults=(dead,)), description=g1, out=None)
    result = outcome.result
    assert outcome.exit_code == 1 and result.fault is not None
    fault = result.fault
    assert fault.kind is FaultKind.MISSING_REPLIES and fault.joints == ("right_knee_joint",)
    log = read_log(outcome.log_path)
    assert log.faults[0]["kind"] == FaultKind.MISSING_REPLIES.value
    commands = [m for m in log.topic("/commands") if m["cycle"] > fault.cycle and m["kind"] == "command"]
    assert commands and commands[0]["cycle"] <= fault.cycle + 2
    assert max(commands[0]["kp"]) == 0 and max(abs(x) for x in commands[0]["tau_ff"]) == 0  # damping
    assert log.event_names()[-1] == "motors_off"


def test_an_unpaced_run_needs_the_lockstep_emulator(g1, tmp_path) -> None:
    outcome = deploy(_options(tmp_path, realtime=False), description=g1, out=None)
    assert outcome.exit_code == 2 and "lockstep" in outcome.message


def test_the_shared_imu_mailbox_round_trips() -> None:
    writer = SharedImuChannel()
    reader = SharedImuChannel(writer.name)
    try:
        assert reader.read() is None
        sample = ImuReading(np.array([0.1, -0.2, 0.3, 0.9]), np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.5, 9.81]), 1.25)
        writer.publish(sample)
        got = reader.read()
        assert got.time == 1.25
        for field in ("quaternion", "angular_velocity", "linear_acceleration"):
            assert np.array_equal(getattr(got, field), getattr(sample, field))
    finally:
        reader.close()
        writer.close()


def test_a_write_in_progress_is_no_new_sample_not_a_crash() -> None:
    """A writer preempted in the middle of a write (odd sequence) on a loaded machine: the reader
    waits a bounded time, then reports no new sample (the CAN robot keeps the last one and the
    supervisor's IMU timeout catches a writer that stays stuck); once the write ends it reads."""
    writer = SharedImuChannel()
    reader = SharedImuChannel(writer.name)
    try:
        sample = ImuReading(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]), 0.5)
        writer.publish(sample)
        values = np.ndarray((13,), dtype=np.float64, buffer=writer._shm.buf)
        values[0] += 1.0  # the writer starts a write and is preempted
        start = time.perf_counter()
        assert reader.read() is None
        assert time.perf_counter() - start < 0.05
        values[0] += 1.0  # the write completes
        assert reader.read().time == 0.5
    finally:
        del values
        reader.close()
        writer.close()


def test_a_child_that_cannot_start_is_a_clear_error(g1) -> None:
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    bad = EmulatorConfig(initial_joint_positions=(0.0,) * 3)  # wrong length: the emulator raises in the child
    with pytest.raises(RuntimeError, match="emulator process failed"):
        EmulatorProcess(plan, g1, bad)


def test_lockstep_replies_read_a_cycle_later_are_the_state_one_period_old(g1) -> None:
    """``wait_for_replies=False`` with a lockstep peer: the process emulator's timing (replies read
    at the next cycle) in the emulator's time. Same frames at the same emulator times as a cycle
    that waits, so the same trajectory: the joint state read at cycle k is, bit for bit, the one the
    waiting robot read at cycle k - 1; the IMU is not delayed (read after the emulator advanced to
    the cycle's time, as the process emulator's mailbox gives it)."""
    from giwbc.emulation import ActuatorEmulator
    from giwbc.hal.can_robot import ENTER, CanRobot
    from giwbc.robot.standing import pd_hold_command

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    period = 1.0 / plan.control_rate
    runs = {}
    for wait in (True, False):
        with ActuatorEmulator(plan, g1) as emulator:
            # (no wall-clock bounds: a loaded machine must not make a lockstep reply miss its cycle)
            robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator, wait_for_replies=wait, reply_timeout=10.0,
                             send_budget=math.inf)  # fmt: skip
            try:
                assert robot.reply_lag == (0 if wait else 1)
                first = robot.exchange(0.0, kind=ENTER)
                assert first.missing.all() != wait  # nothing to read yet when the replies wait for the next cycle
                robot.set_joint_impedance(pd_hold_command(g1))
                q, imu_times = [], []
                for k in range(1, 30):
                    report = robot.exchange(k * period)
                    assert report.complete
                    q.append(robot.joint_positions())
                    imu_times.append(robot.imu().time)
            finally:
                robot.close()
        runs[wait] = np.array(q), np.array(imu_times)
    (q_wait, imu_wait), (q_late, imu_late) = runs[True], runs[False]
    assert np.abs(np.diff(q_wait, axis=0)).max() > 1e-4  # the joints move (the robot settles under the hold)
    assert np.array_equal(q_late[1:], q_wait[:-1])
    assert not np.array_equal(q_late[1:], q_wait[1:])
    assert np.allclose(imu_wait, np.arange(1, 30) * period) and np.array_equal(imu_late, imu_wait)


def test_a_stalled_emulator_process_measures_its_stall(g1) -> None:
    """The child stopped for 80 ms (SIGSTOP: no CPU, as a machine that gives it none) while the
    host runs deferred 500 Hz cycles: the stall it brings back covers it, at the time it happened."""
    import os
    import signal

    from giwbc.hal.can_robot import ENTER, CanRobot
    from giwbc.robot.standing import pd_hold_command

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    period = 1.0 / plan.control_rate
    with EmulatorProcess(plan, g1) as emulator:
        robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, wait_for_replies=False)
        try:
            start = time.perf_counter()
            robot.exchange(0.0, kind=ENTER)
            robot.set_joint_impedance(pd_hold_command(g1))
            for k in range(1, 150):
                time.sleep(max(0.0, start + k * period - time.perf_counter()))
                if k == 75:
                    stopped_at = time.perf_counter() - start  # ~ emulator time: its 0 is the host's first frame
                    os.kill(emulator.pid, signal.SIGSTOP)
                    time.sleep(0.08)
                    os.kill(emulator.pid, signal.SIGCONT)
                robot.exchange(k * period)
        finally:
            robot.close()
    stalls = emulator.stalls
    assert stalls is not None and emulator.failure is None
    assert stalls.longest >= 0.07 and stalls.over_period >= 1
    assert abs(stalls.at - stopped_at) < 0.01  # the physics step due right after the stop began

