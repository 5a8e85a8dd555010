"""The fault matrix, end to end on the emulator: each fault ends in damping within two control cycles
(seen in the log and by the emulated motors), then motors off, with the cause logged and no
exception escaping. Plus the supervisor's checks on synthetic cycles and the signal watch."""

from __future__ import annotations

import math
import os
import signal

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.hal.can_robot import CycleReport
from giwbc.emulation import EmulatorConfig, FaultInjection
from giwbc.runlog import read_log
from giwbc.hal.safety import FaultKind, SafetyConfig, SafetySupervisor, SignalWatch
from giwbc.robot.interface import ImuReading
from giwbc.robot.noise import SensorNoiseConfig

T_FAULT = 0.3  # s: after the 0.22 s start-up, while the controller runs
DT = 0.002
SAFETY = SafetyConfig(damping_time=0.1)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


@pytest.fixture
def run(g1, model, tmp_path):
    from giwbc.runtimes.phases import StartupConfig

    def go(faults=(), *, task="stand", policy=None, seconds=0.6, safety=SAFETY, **emulator):
        options = DeployOptions(
            emulate=True, realtime=False, controller="pd", task=task, seconds=seconds, log=str(tmp_path / "run.mcap"),
            startup=StartupConfig(settle_time=0.02, ramp_time=0.2, shutdown_time=0.1, off_delay=0.05),
            safety=safety, emulator=EmulatorConfig(record=True, **emulator), faults=tuple(faults),
        )  # fmt: skip
        metadata = _metadata(g1) if policy is not None else None
        return deploy(options, policy=policy, policy_metadata=metadata, model=model, description=g1, out=None)

    return go


def _metadata(g1) -> dict:
    """A test policy's metadata: the balance task's layout (joint-PD residuals), the robot's joints."""
    from giwbc.tasks.rates import Rates
    from giwbc.tasks.balance import G1Balance

    class _Joints:
        joint_names, dofs = g1.joint_names, g1.dofs

    task = G1Balance(g1, controller="pd")
    task.bind(_Joints(), Rates(50.0, 500.0, 500.0))  # type: ignore[arg-type]
    return {
        "joint_names": list(g1.joint_names), "rates": {"agent_hz": 50.0, "controller_hz": 500.0},
        "action_names": list(task.action_names()), "observation_names": list(task.observation_names()),
        "env_kwargs": {"controller": "pd"},
    }  # fmt: skip


def assert_safe_stop(outcome, kind: FaultKind, g1, joints: tuple[str, ...] = ()):
    """The run stopped on ``kind``: damping out within two cycles (log and motors), motors off."""
    result = outcome.result
    assert outcome.exit_code != 0 and result is not None
    fault = result.fault
    assert fault is not None and fault.kind is kind, result.faults
    for joint in joints:
        assert joint in fault.joints
    log = read_log(outcome.log_path)
    assert log.faults[0]["kind"] == kind.value and log.faults[0]["cycle"] == fault.cycle
    damping_kd = SAFETY.damping_kd_scale * g1.kd

    def is_damping(m):
        return max(m["kp"]) == 0 and max(abs(x) for x in m["tau_ff"]) == 0 and np.allclose(m["kd"], damping_kd)

    after = [m for m in log.topic("/commands") if m["cycle"] > fault.cycle]
    commands = [m for m in after if m["kind"] == "command"]
    assert commands and commands[0]["cycle"] <= fault.cycle + 2 and is_damping(commands[0])
    assert all(is_damping(m) for m in commands)  # damping until the motors are switched off
    assert after[-1]["kind"] == "exit"
    assert (commands[-1]["t"] - fault.time) >= SAFETY.damping_time - 2 * DT
    assert log.event_names()[-1] == "motors_off"
    # The emulated motors applied it: no stiffness, no feed-forward (0 quantizes to < 0.05 N m) within two cycles.
    emu = outcome.emulator
    snaps = [s for s in emu.snapshots if fault.time < s.time <= fault.time + 2 * DT + 1e-9]
    assert any((s.kp == 0).all() and (np.abs(s.tau_ff) < 0.05).all() for s in snaps)
    assert (emu.mode == 0).all()  # every motor off
    return fault, log


def test_clean_run_has_no_fault(run, g1):
    outcome = run()
    assert outcome.exit_code == 0 and outcome.result.ok and outcome.standing["stood"]
    log = read_log(outcome.log_path)
    assert not log.faults and log.event_names()[-1] == "motors_off"


def test_full_reply_loss_on_one_motor(run, g1):
    outcome = run([FaultInjection("drop", ("left_knee_joint",), start=T_FAULT)])
    fault, _ = assert_safe_stop(outcome, FaultKind.MISSING_REPLIES, g1, ("left_knee_joint",))
    assert fault.time == pytest.approx(T_FAULT + 2 * DT, abs=1.5 * DT)  # the third silent cycle
    assert fault.joints == ("left_knee_joint",)


def test_random_reply_loss(run, g1):
    outcome = run([FaultInjection("drop", probability=0.3, start=T_FAULT)])
    fault, log = assert_safe_stop(outcome, FaultKind.MISSING_REPLIES, g1)
    missing = [len(m["missing"]) for m in log.topic("/replies") if T_FAULT <= m["t"] <= fault.time]
    assert np.mean(missing) == pytest.approx(0.3 * g1.dofs, rel=0.4)


def test_delayed_replies(run, g1):
    outcome = run([FaultInjection("delay", ("right_hip_pitch_joint",), start=T_FAULT, delay=0.0015)])
    fault, log = assert_safe_stop(outcome, FaultKind.MISSING_REPLIES, g1, ("right_hip_pitch_joint",))
    assert "late frame" in fault.message
    assert sum(m["late"] for m in log.topic("/replies") if m["t"] <= fault.time) >= 2


def test_corrupt_frames(run, g1):
    outcome = run([FaultInjection("corrupt", ("left_elbow_joint",), start=T_FAULT)])
    fault, log = assert_safe_stop(outcome, FaultKind.CORRUPT_FRAMES, g1)
    assert "can6" in fault.message  # the elbow's bus
    assert sum(m["corrupt"] for m in log.topic("/replies") if m["t"] <= fault.time) == 3


def test_motor_error_code(run, g1):
    outcome = run([FaultInjection("error", ("left_knee_joint",), start=T_FAULT)])
    fault, _ = assert_safe_stop(outcome, FaultKind.MOTOR_ERROR, g1, ("left_knee_joint",))
    assert "left_knee_joint=10" in fault.message  # Damiao over-current state 0xA


def test_over_temperature(run, g1):
    outcome = run([FaultInjection("overheat", ("right_knee_joint",), start=T_FAULT, heat_rate=3000.0)])
    fault, log = assert_safe_stop(outcome, FaultKind.OVER_TEMPERATURE, g1, ("right_knee_joint",))
    knee = g1.joint_names.index("right_knee_joint")
    temps = [m["temperature"][knee] for m in log.topic("/replies") if m["cycle"] <= fault.cycle]
    assert temps[0] == pytest.approx(25.0, abs=1.0) and SAFETY.max_temperature < temps[-1] < 90.0  # before the firmware trips


def test_fall(run, g1):
    outcome = run([FaultInjection("push", force=(0.0, 300.0, 0.0), start=T_FAULT, stop=T_FAULT + 0.4)], seconds=1.2)
    fault, log = assert_safe_stop(outcome, FaultKind.FALL, g1)
    imu = log.array("/estimator", "imu_quaternion")
    tilt = np.degrees(np.arccos(np.clip(1 - 2 * (imu[:, 0] ** 2 + imu[:, 1] ** 2), -1, 1)))
    assert tilt[: int(T_FAULT / DT) - 5].max() < 5.0 and tilt.max() > np.degrees(SAFETY.max_tilt)


def test_fall_with_a_mems_imu_without_orientation_output(run, g1):
    """The same push, the emulated IMU a MEMS one (no orientation output, biased gyro): the
    supervisor's own gyro + gravity tilt still sees the fall, as the base passes the limit."""
    mems = SensorNoiseConfig.profile("mems")
    outcome = run([FaultInjection("push", force=(0.0, 300.0, 0.0), start=T_FAULT, stop=T_FAULT + 0.4)], seconds=1.2, imu=mems)
    fault, log = assert_safe_stop(outcome, FaultKind.FALL, g1)
    assert np.isnan(log.array("/estimator", "imu_quaternion")).all()  # the host never saw an orientation
    truth = outcome.emulator.truth_between(0.0, fault.time + 1e-9)
    assert abs(truth[:, 2].max() - SAFETY.max_tilt) < 0.1  # caught at the limit (truth 37.7 deg for 40.1), not long before or after
    assert truth[truth[:, 0] < T_FAULT, 2].max() < np.radians(5.0)  # no false alarm before the push


def test_policy_nan(run, g1):
    calls = []

    def policy(observation):
        calls.append(observation)
        action = np.zeros(g1.dofs, dtype=np.float32)
        if len(calls) >= 5:
            action[3] = np.nan
        return action

    outcome = run(task="balance", policy=policy)
    fault, _ = assert_safe_stop(outcome, FaultKind.NONFINITE_POLICY, g1)
    assert len(calls) == 5  # not called again after the fault


def test_sigint_sent_to_the_process(run, g1):
    previous = signal.getsignal(signal.SIGINT)
    calls = []

    def policy(observation):
        calls.append(1)
        if len(calls) == 4:
            os.kill(os.getpid(), signal.SIGINT)
        return np.zeros(g1.dofs, dtype=np.float32)

    outcome = run(task="balance", policy=policy)
    fault, _ = assert_safe_stop(outcome, FaultKind.SIGNAL, g1)
    assert "SIGINT" in fault.message and outcome.exit_code == 130
    assert signal.getsignal(signal.SIGINT) is previous  # the runtime restored the handler


def test_controller_nan_and_exceptions(g1, model, tmp_path):
    from giwbc.hal.can_robot import CanRobot
    from giwbc.emulation import ActuatorEmulator
    from giwbc.hal.hardware import load_hardware
    from giwbc.robot.standing import pd_hold_command
    from giwbc.runtimes.phases import StartupConfig
    from giwbc.runtimes.realtime import RealtimeRuntime
    from giwbc.tasks.standing import StandingTask

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    for bad, kind in (("nan", FaultKind.NONFINITE_COMMAND), ("raise", FaultKind.CONTROLLER_ERROR)):
        emu = ActuatorEmulator(plan, g1, EmulatorConfig(record=True), model=model.__copy__())
        robot = CanRobot(g1, emu.host_plan(), imu=emu.imu_channel, peer=emu)

        def controller(r, bad=bad):
            command = pd_hold_command(g1)
            if r.time() > T_FAULT:
                if bad == "raise":
                    raise ZeroDivisionError("boom")
                command.tau_ff[0] = np.inf
            return command

        runtime = RealtimeRuntime(StandingTask(controller, g1.default_positions), robot, safety=SAFETY, realtime=False,
                                  startup=StartupConfig(settle_time=0.02, ramp_time=0.2))  # fmt: skip
        result = runtime.run(None, seconds=0.5)
        robot.close()
        emu.close()
        assert result.fault is not None and result.fault.kind is kind, result.faults
        assert result.fault.time == pytest.approx(T_FAULT, abs=1.5 * DT) and result.exit_code == 1
        assert runtime.phase == "off" and (emu.mode == 0).all()
        snaps = [s for s in emu.snapshots if result.fault.time < s.time <= result.fault.time + 2 * DT + 1e-9]
        assert any((s.kp == 0).all() and (np.abs(s.tau_ff) < 0.05).all() for s in snaps)


def test_a_motor_that_never_answers_stops_the_start_up(run, g1):
    outcome = run([FaultInjection("dead", ("waist_pitch_joint",))])
    result = outcome.result
    assert outcome.exit_code == 1 and result.fault.kind is FaultKind.STARTUP
    assert "waist_pitch_joint" in result.fault.message
    assert "ramp" not in result.phase_times and (outcome.emulator.mode == 0).all()


# ----------------------------------------------------------------------------- supervisor units
def report(g1, cycle=0, **fields) -> CycleReport:
    n = g1.dofs
    base = dict(cycle=cycle, time=cycle * DT, kind="command", missing=np.zeros(n, bool), stale=np.zeros(n, np.int64),
                error_code=np.zeros(n, np.int64), temperature=np.full(n, 30.0), late=0, corrupt=np.zeros(10, np.int64),
                unknown=0, send_dropped=0, clamped=0, imu_fresh=True, send_s=0.0, receive_s=0.0)  # fmt: skip
    base.update(fields)
    return CycleReport(**base)


LEVEL = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]))


def test_supervisor_quiet_when_all_is_well(g1):
    sup = SafetySupervisor(g1, SAFETY)
    q = g1.default_positions
    for c in range(20):
        assert sup.check(report(g1, c), q, np.zeros(g1.dofs), np.zeros(g1.dofs), LEVEL) == []


def test_supervisor_limits(g1):
    names, q0, zeros = g1.joint_names, g1.default_positions, np.zeros(g1.dofs)
    sup = SafetySupervisor(g1, SAFETY)
    knee = names.index("left_knee_joint")
    lower, _ = g1.position_limits
    q = q0.copy()
    q[knee] = lower[knee] + 0.5 * SAFETY.soft_limit_margin  # starting on a stop is not a fault...
    assert sup.check(report(g1), q, zeros, zeros, LEVEL) == []
    q[knee] = q0[knee]
    assert sup.check(report(g1, 1), q, zeros, zeros, LEVEL) == []
    q[knee] = lower[knee] + 0.5 * SAFETY.soft_limit_margin  # ...going there after being inside is
    (fault,) = sup.check(report(g1, 2), q, zeros, zeros, LEVEL)
    assert fault.kind is FaultKind.JOINT_LIMIT and fault.joints == ("left_knee_joint",)

    sup = SafetySupervisor(g1, SAFETY)
    dq = zeros.copy()
    dq[names.index("waist_yaw_joint")] = -1.01 * g1.velocity_limits[names.index("waist_yaw_joint")]
    (fault,) = sup.check(report(g1), q0, dq, zeros, LEVEL)
    assert fault.kind is FaultKind.VELOCITY_LIMIT and fault.joints == ("waist_yaw_joint",)

    tau = zeros.copy()
    tau[knee] = 1.2 * g1.effort_limits[knee]
    for c in range(SAFETY.torque_cycles - 1):
        assert sup.check(report(g1, c), q0, zeros, tau, LEVEL) == []
    (fault,) = sup.check(report(g1, 9), q0, zeros, tau, LEVEL)
    assert fault.kind is FaultKind.TORQUE_LIMIT


def test_supervisor_comms_imu_and_tilt(g1):
    q0, zeros = g1.default_positions, np.zeros(g1.dofs)
    sup = SafetySupervisor(g1, SAFETY, bus_names=tuple(f"can{b}" for b in range(10)))
    corrupt = np.zeros(10, np.int64)
    corrupt[4] = 1
    kinds = [[f.kind for f in sup.check(report(g1, c, corrupt=corrupt if c % 20 == 0 else np.zeros(10, np.int64)), q0, zeros, zeros, LEVEL)]
             for c in range(60)]  # fmt: skip
    assert kinds[40] == [FaultKind.CORRUPT_FRAMES]  # the third within 50 cycles
    assert all(k == [] for k in kinds[:40])
    stale = np.zeros(g1.dofs, np.int64)
    stale[2] = SAFETY.max_missing_cycles
    (fault,) = SafetySupervisor(g1, SAFETY).check(report(g1, stale=stale), q0, zeros, zeros, LEVEL)
    assert fault.kind is FaultKind.MISSING_REPLIES and fault.joints == (g1.joint_names[2],)

    sup = SafetySupervisor(g1, SAFETY)
    for c in range(SAFETY.imu_timeout_cycles - 1):
        assert sup.check(report(g1, c, imu_fresh=False), q0, zeros, zeros, LEVEL) == []
    assert [f.kind for f in sup.check(report(g1, 50, imu_fresh=False), q0, zeros, zeros, LEVEL)] == [FaultKind.IMU]
    bad = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.array([np.nan, 0, 0]), np.zeros(3))
    assert [f.kind for f in SafetySupervisor(g1, SAFETY).check(report(g1), q0, zeros, zeros, bad)] == [FaultKind.IMU]
    angle = SAFETY.max_tilt + 0.05
    tilted = ImuReading(np.array([math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)]), np.zeros(3), np.zeros(3))
    (fault,) = SafetySupervisor(g1, SAFETY).check(report(g1), q0, zeros, zeros, tilted)
    assert fault.kind is FaultKind.FALL
    yawed = ImuReading(np.array([0.0, 0.0, math.sin(1.0), math.cos(1.0)]), np.zeros(3), np.zeros(3))
    assert SafetySupervisor(g1, SAFETY).check(report(g1), q0, zeros, zeros, yawed) == []  # heading is not tilt

    errors = np.zeros(g1.dofs, np.int64)
    errors[0] = 0xB
    temps = np.full(g1.dofs, np.nan)  # variants without a temperature report NaN: never a fault
    temps[1] = SAFETY.max_temperature + 1
    faults = SafetySupervisor(g1, SAFETY).check(report(g1, error_code=errors, temperature=temps), q0, zeros, zeros, LEVEL)
    assert [f.kind for f in faults] == [FaultKind.MOTOR_ERROR, FaultKind.OVER_TEMPERATURE]


def test_signal_watch_records_and_restores():
    previous = signal.getsignal(signal.SIGTERM)
    watch = SignalWatch()
    with watch:
        assert watch.installed and signal.getsignal(signal.SIGTERM) is not previous
        os.kill(os.getpid(), signal.SIGTERM)
        assert watch.name == "SIGTERM"
        watch.trigger(signal.SIGINT)  # the handler path: the first signal is kept
        assert watch.received == signal.SIGTERM
    assert not watch.installed and signal.getsignal(signal.SIGTERM) is previous
