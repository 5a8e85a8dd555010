"""``giwbc deploy``: the emulated dry run (WBC over the CAN path, real-time paced), the start-up ramp,
policy metadata and hardware checks, the run log, and the command line (with a real SIGINT)."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from giwbc.apps.scene import SCHEMAS as SCENE_SCHEMAS
from giwbc.apps.deploy import DeployError, DeployOptions, add_deploy_command, check_policy_metadata, deploy
from giwbc.emulation import EmulatorConfig, Gantry
from giwbc.runlog import SCHEMAS, read_log
from giwbc.hal.safety import SafetyConfig
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.ramps import min_jerk

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def test_dry_run_holds_g1_standing_with_the_wbc_in_real_time(g1, model, tmp_path):
    options = DeployOptions(
        emulate=True, controller="wbc", seconds=2.0, log=str(tmp_path / "dry.mcap"),
        startup=StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.3, off_delay=0.1),
        safety=SafetyConfig(max_stall=0.5),  # CI machines are shared: a 0.1 s scheduling hiccup is not this test's subject
    )  # fmt: skip
    lines: list[str] = []
    started = time.perf_counter()
    outcome = deploy(options, model=model, description=g1, out=lines.append)
    wall = time.perf_counter() - started
    assert outcome.exit_code == 0, outcome.message
    result = outcome.result
    calibrating = result.phase_times["running"] - result.phase_times["calibrate"]  # held still until the IMU calibrated
    assert outcome.calibration is not None and 0.75 <= calibrating < StartupConfig().calibration_timeout
    # The start-up says what it waits for, once a second while the IMU calibrates (paced: robot time is wall time).
    waits = [line for line in lines if line.startswith("calibrating the IMU: hold the robot still")]
    assert len(waits) >= int(calibrating) // 2 and all("waiting for" in line for line in waits)  # once a second (half, on a loaded machine)
    assert result.ok and result.robot_time == pytest.approx(2.95 + calibrating, abs=0.1)
    # Paced by the wall clock, not run as fast as possible: the run never got ahead of wall time
    # (its own robot time, less one period, at most), and no logged cycle started before its slot.
    assert wall >= result.robot_time - 0.002
    # On a loaded machine the WBC + estimator + emulator cycle can take longer than 2 ms: slots are
    # then skipped (the emulated motors hold the last command), never run in a burst.
    assert result.cycles + result.timing["skipped_slots"] == pytest.approx(result.robot_time / 0.002, abs=5)
    standing = outcome.standing
    assert standing["stood"] and standing["seconds"] >= 1.9 and standing["max_tilt"] < np.radians(5)
    assert any("bus 'can0'" in line for line in lines) and any("stood" in line for line in lines)

    log = read_log(outcome.log_path)
    assert set(log.schemas) == (set(SCHEMAS) - {"/faults"}) | set(SCENE_SCHEMAS) and not log.faults  # with the 3D scene
    assert log.metadata["robot"] == "g1" and log.joint_names == g1.joint_names
    assert [e["detail"]["phase"] for e in log.events if e["event"] == "phase"] == [
        "enable", "settle", "ramp", "calibrate", "running", "shutdown", "damping", "off"]  # fmt: skip
    running = [m for m in log.topic("/commands") if m["phase"] == "running" and m["kind"] == "command"]
    assert len(running) >= 200
    tau = np.array([m["tau_ff"] for m in running[10:]])
    assert np.abs(tau).max() > 5.0 and max(max(m["kp"]) for m in running[10:]) == 0.0  # WBC: feed-forward torques
    timing = log.topic("/timing")
    assert len(timing) == result.cycles
    slots = [m["slot"] for m in timing]
    assert all(b > a for a, b in zip(slots, slots[1:]))  # one cycle per slot at most, never a burst
    assert min(m["lateness_us"] for m in timing) >= 0.0 and max(m["lateness_us"] for m in timing) > 0.0
    estimate = log.array("/estimator", "position")
    truth = outcome.emulator.truth_between(result.phase_times["running"], result.phase_times["shutdown"])
    est_t = log.array("/estimator", "t")
    height = np.interp(truth[:, 0], est_t, estimate[:, 2])
    assert np.abs(height - truth[:, 1]).max() < 0.03  # the estimator tracks the emulated base


def test_start_up_ramps_from_the_measured_pose_with_min_jerk(g1, model, tmp_path):
    crouch = g1.default_positions.copy()
    for side in ("left", "right"):  # legs tucked: the feet hang above the floor
        names = g1.joint_names
        crouch[names.index(f"{side}_hip_pitch_joint")] -= 0.3
        crouch[names.index(f"{side}_knee_joint")] += 0.6
        crouch[names.index(f"{side}_ankle_pitch_joint")] -= 0.3
    ramp = 0.5
    options = DeployOptions(
        emulate=True, controller="pd", seconds=0.5, realtime=False, log=str(tmp_path / "ramp.mcap"),
        startup=StartupConfig(settle_time=0.05, ramp_time=ramp, shutdown_time=0.1, off_delay=0.05),
        emulator=EmulatorConfig(initial_joint_positions=tuple(crouch), gantry=Gantry(until=0.05 + ramp + 0.05)),
    )  # fmt: skip
    outcome = deploy(options, model=model, description=g1, out=None)
    assert outcome.exit_code == 0, outcome.message
    log = read_log(outcome.log_path)
    (start_pose,) = [e["detail"]["q"] for e in log.events if e["event"] == "start_pose"]
    settled = [m for m in log.topic("/replies") if m["t"] < outcome.result.phase_times["ramp"] + 1e-9][-1]
    assert np.allclose(start_pose, settled["q"], atol=1e-5)  # the pose measured at the end of the settling
    assert np.allclose(start_pose, crouch, atol=0.05)  # (hanging in damping, the legs sagged a little)
    ramp_commands = [m for m in log.topic("/commands") if m["phase"] == "ramp" and m["kind"] == "command"]
    q_ref = np.array([m["q_ref"] for m in ramp_commands])
    t0 = outcome.result.phase_times["ramp"]
    s = np.array([(m["t"] - t0) / ramp for m in ramp_commands])  # the command sent at t was computed for t
    phi = np.array([min_jerk(x)[0] for x in s])
    expected = np.asarray(start_pose) + np.outer(phi, g1.default_positions - np.asarray(start_pose))
    assert np.abs(q_ref - expected).max() < 1e-4  # min-jerk from the measured pose...
    assert np.allclose(q_ref[-1], g1.default_positions, atol=1e-4)  # ...to the default pose
    assert np.abs(np.diff(q_ref, axis=0)).max() < 0.01  # smooth: < 1 cm-rad per cycle
    assert outcome.standing["stood"]  # released from the gantry at the default pose, it stands


def test_policy_metadata_is_checked_against_the_robot(g1):
    good = {"joint_names": list(g1.joint_names), "rates": {"agent_hz": 50.0, "controller_hz": 500.0, "physics_hz": 500.0},
            "action_names": ["a"], "observation_names": ["o"]}  # fmt: skip
    assert check_policy_metadata(good, g1, 500.0) == 50.0
    swapped = dict(good, joint_names=[g1.joint_names[1], g1.joint_names[0], *g1.joint_names[2:]])
    with pytest.raises(DeployError, match="joint order"):
        check_policy_metadata(swapped, g1, 500.0)
    with pytest.raises(DeployError, match="missing \\['waist_yaw_joint'\\]"):
        check_policy_metadata(dict(good, joint_names=[j for j in g1.joint_names if j != "waist_yaw_joint"]), g1, 500.0)
    with pytest.raises(DeployError, match="controller at 1000 Hz"):
        check_policy_metadata(dict(good, rates={"agent_hz": 50.0, "controller_hz": 1000.0}), g1, 500.0)
    with pytest.raises(DeployError, match="does not divide"):
        check_policy_metadata(dict(good, rates={"agent_hz": 30.0, "controller_hz": 500.0}), g1, 500.0)
    with pytest.raises(DeployError, match="no rates"):
        check_policy_metadata({k: v for k, v in good.items() if k != "rates"}, g1, 500.0)


def test_deploy_refuses_bad_hardware_and_missing_drivers(g1, tmp_path):
    lines = ["[imu]", 'source = "emulated"', "[[buses]]", 'name = "can0"', 'interface = "socketcan"', 'channel = "can0"',
             "bitrate = 1000000"]  # fmt: skip
    for i, joint in enumerate(g1.joint_names):
        lines += ["[[motors]]", 'bus = "can0"', f"id = {i + 1}", f'joint = "{joint}"', 'model = "AK10-9"', "torque = 200"]
    crowded = tmp_path / "one_bus.toml"
    crowded.write_text("\n".join(lines))
    said: list[str] = []
    outcome = deploy(DeployOptions(hardware=str(crowded), emulate=True), description=g1, out=said.append)
    # The error is the outcome's, for the caller to print once (the command line: on stderr), not also said as progress.
    assert outcome.exit_code == 2 and "over capacity" in outcome.message and not any("over capacity" in line for line in said)
    outcome = deploy(DeployOptions(emulate=False), description=g1, out=None)  # the G1 plan's IMU is emulated
    assert outcome.exit_code == 2 and "--emulate" in outcome.message
    assert '[imu] source = "emulated"' in outcome.message and '"serial"' in outcome.message and '"can"' in outcome.message
    outcome = deploy(DeployOptions(policy=str(tmp_path / "missing.onnx"), emulate=True), description=g1, out=None)
    assert outcome.exit_code == 2 and "no policy file" in outcome.message


def test_cli_arguments():
    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", "--robot", "g1", "--emulate", "--seconds", "3", "--controller", "pd"])
    assert (args.robot, args.emulate, args.seconds, args.controller, args.policy, args.rate) == ("g1", True, 3.0, "pd", None, 500.0)
    assert callable(args.run)


def test_command_line_dry_run_stopped_by_sigint(tmp_path):
    log = tmp_path / "cli.mcap"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "giwbc.apps.deploy", "--emulate", "--controller", "pd", "--seconds", "60", "--ramp", "0.2",
         "--log", str(log), "--json"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        for line in proc.stderr:  # progress goes to stderr with --json
            if line.startswith("running"):
                break
        time.sleep(0.6)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["fault"]["kind"] == "signal" and "SIGINT" in summary["fault"]["message"]
    run_log = read_log(log)
    assert run_log.faults[0]["kind"] == "signal" and run_log.event_names()[-1] == "motors_off"
    assert run_log.topic("/commands")[-1]["kind"] == "exit"


def _run_lockstep(g1, model, tmp_path, controller, rate: float, seconds: float, startup: StartupConfig, **runtime_options):
    """Run ``controller`` in a StandingTask on the lockstep emulator; (result, runtime, log path)."""
    import copy

    from giwbc.hal.can_robot import CanRobot
    from giwbc.emulation import ActuatorEmulator
    from giwbc.hal.hardware import load_hardware
    from giwbc.runlog import RunLogWriter
    from giwbc.runtimes.realtime import RealtimeRuntime
    from giwbc.tasks.standing import StandingTask

    plan = load_hardware(g1.folder / "hardware.toml", rate, joint_names=g1.joint_names, interface="virtual")
    emulator = ActuatorEmulator(plan, g1, EmulatorConfig(), model=copy.copy(model))
    robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator)
    log = RunLogWriter(tmp_path / "run.mcap", g1.joint_names)
    runtime = RealtimeRuntime(StandingTask(controller, g1.default_positions), robot, log=log, startup=startup, **runtime_options)
    try:
        result = runtime.run(None, seconds=seconds)
    finally:
        robot.close()
        emulator.close()
        log.close()
    return result, runtime, log.path


def test_the_controllers_first_tick_is_a_hand_over_not_an_overrun(g1, model, tmp_path):
    """A controller whose first tick after a reset is slow (a QP laid out and solved cold) takes
    over between two cycles: the motors hold the ramp's last command meanwhile, the pause is
    logged, and the first running cycle neither overruns nor skips a slot."""
    from giwbc.robot.standing import PdHold

    class SlowFirstTick(PdHold):
        fresh = True

        def reset(self):
            self.fresh = True

        def __call__(self, robot):
            if self.fresh:
                self.fresh = False
                time.sleep(0.03)  # three 10 ms periods
            return super().__call__(robot)

    startup = StartupConfig(settle_time=0.05, ramp_time=0.2, shutdown_time=0.05, off_delay=0.02)
    result, runtime, log = _run_lockstep(g1, model, tmp_path, SlowFirstTick(g1), 100.0, 0.3, startup, agent_rate=50.0)
    assert result.ok, result.fault
    (handover,) = [e["detail"] for e in read_log(log, topics=["/events"]).events if e["event"] == "handover"]
    assert handover["pause_ms"] >= 30.0
    first = runtime.phase_cycles["running"]
    stats = runtime.clock.stats.between(first, first + 1)  # the cycle after the pause
    assert not stats.overrun[0] and stats.skipped_before[0] == 0
    assert math.isnan(stats.periods[0]) and stats.lateness[0] < 0.005  # the schedule restarted after the pause


def test_garbage_is_collected_between_cycles_while_the_motors_are_on(g1, model, tmp_path):
    """No automatic collection can fire inside a cycle while the motors are on: the runtime
    collects the young generations itself between cycles, and restores the collector at close."""
    import gc

    from giwbc.robot.standing import PdHold

    seen = []

    class Watching(PdHold):
        def __call__(self, robot):
            seen.append(gc.isenabled())
            return super().__call__(robot)

    startup = StartupConfig(settle_time=0.02, ramp_time=0.05, shutdown_time=0.02, off_delay=0.02)
    assert gc.isenabled()
    result, _, log = _run_lockstep(g1, model, tmp_path, Watching(g1), 500.0, 0.2, startup, realtime=False, gc_every=20)
    assert result.ok, result.fault
    assert seen and not any(seen)  # off in every controller tick
    assert gc.isenabled()  # restored
    (summary,) = [e["detail"] for e in read_log(log, topics=["/events"]).events if e["event"] == "garbage_collection"]
    assert summary["young_collections"] >= result.cycles // 20 - 1 and summary["longest_us"] > 0


def test_an_unpaced_run_is_the_same_run_on_a_loaded_machine(g1, model, tmp_path, monkeypatch):
    """An unpaced lockstep run lives in simulated time: a send the host machine preempts (here the
    virtual bus sleeping 8 ms in every 40th send, past the 5 ms a paced cycle's sends may take, and
    25 ms in every 1001st, past the 20 ms the emulator's replies may take) drops no command frame
    and no reply, and the run's replies are bit for bit those of an unloaded run.
    (Before, under a loaded machine's preemption the same walk ended clean or on a soft limit.)"""
    import can.interfaces.virtual as virtual

    def run(name: str) -> tuple[np.ndarray, int]:
        options = DeployOptions(
            emulate=True, controller="pd", seconds=0.4, realtime=False, log=str(tmp_path / f"{name}.mcap"), scene_rate=0.0,
            startup=StartupConfig(settle_time=0.05, ramp_time=0.2, shutdown_time=0.1, off_delay=0.05),
        )  # fmt: skip
        outcome = deploy(options, model=model, description=g1, out=None)
        assert outcome.exit_code == 0, outcome.message
        replies = read_log(outcome.log_path).topic("/replies")
        return np.array([m["q"] for m in replies]), sum(len(m["missing"]) for m in replies)  # joints without a reply

    quiet, quiet_missing = run("quiet")
    send, calls = virtual.VirtualBus.send, [0]

    def preempted(self, msg, timeout=None):
        calls[0] += 1
        if calls[0] % 40 == 0:
            time.sleep(8e-3)
        if calls[0] % 1001 == 0:  # and now and then past the 20 ms the emulator's replies may take
            time.sleep(25e-3)
        return send(self, msg, timeout)

    monkeypatch.setattr(virtual.VirtualBus, "send", preempted)
    loaded, loaded_missing = run("loaded")
    assert calls[0] > 1000  # the sleeps happened (~40 sends a cycle, ~450 cycles)
    assert quiet_missing == loaded_missing == 0
    assert loaded.shape == quiet.shape and np.array_equal(loaded, quiet)
