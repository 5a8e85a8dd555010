"""``giwbc deploy --emulate`` with each IMU source read through its real driver (an Xsens MTi on a
pseudo-terminal, a CAN IMU on a motor bus), the pre-enable limit check, the first-run (gantry)
mode, and the SocketCAN pre-flight on real buses."""

from __future__ import annotations

import os
import pty

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.emulation import EmulatorConfig, FaultInjection
from giwbc.hal.can_imu import example_layout
from giwbc.hal.safety import SafetyConfig
from giwbc.runlog import read_log
from giwbc.runtimes.phases import StartupConfig

FAST = StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.2, off_delay=0.1)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def run(g1, model, tmp_path, **options):
    lines: list[str] = []
    # lockstep replies are queued before the host reads: a long timeout only matters on a loaded machine
    settings = dict(emulate=True, controller="wbc", seconds=1.5, realtime=False, log=str(tmp_path / "run.mcap"), startup=FAST,
                    reply_timeout=0.01)  # fmt: skip
    opts = DeployOptions(**{**settings, **options})
    outcome = deploy(opts, model=model, description=g1, out=lines.append)
    return outcome, lines


@pytest.mark.parametrize("source", ["serial", "can"])
def test_g1_stands_with_the_imu_read_through_its_driver(g1, model, tmp_path, source):
    outcome, lines = run(g1, model, tmp_path, imu=source)
    assert outcome.exit_code == 0, outcome.message
    assert outcome.standing["stood"] and outcome.standing["max_tilt"] < np.radians(5)
    assert any(f"IMU: {source}" in line for line in lines)
    device = outcome.emulator.imu_device
    log = read_log(outcome.log_path)
    gyro = log.array("/estimator", "imu_angular_velocity")
    gyro = gyro[np.isfinite(gyro).all(axis=1)]
    assert len(gyro) > 500
    counts = outcome.imu_counters
    assert any(line.startswith("IMU driver: ") for line in lines)
    if source == "serial":
        assert device.written > 500 and device.dropped == 0
        # the host parsed the emulator's MTData2 messages: all of them but those before the port opened
        assert device.written - 2 <= counts["samples"] <= device.written
        assert counts["checksum_errors"] == 0 and counts["incomplete"] == 0
    else:
        assert device.sent > 1500 and device.dropped <= 0.01 * device.sent  # a send stalled on a loaded machine: dropped
        assert device.sent - 3 * 2 <= counts["frames"] <= device.sent
        assert counts["samples"] >= (counts["frames"] - 3 * counts["incomplete"]) // 3 - 1
        lsb = example_layout().frames[1].fields[0].scale
        np.testing.assert_allclose(gyro / lsb, np.round(gyro / lsb), atol=1e-3)  # 16-bit codes on the wire
        assert sum(m["unknown"] for m in log.topic("/replies")) == 0  # the IMU's frames went to the IMU
    # the estimator, fed only by the driver's samples, tracks the emulated base
    estimate = log.array("/estimator", "position")
    est_t = log.array("/estimator", "t")
    truth = outcome.emulator.truth_between(0.5, 1.9)
    height = np.interp(truth[:, 0], est_t, estimate[:, 2])
    assert np.abs(height - truth[:, 1]).max() < 0.03


@pytest.mark.parametrize("source", ["serial", "can"])
def test_a_silent_imu_is_detected_as_stale(g1, model, tmp_path, source):
    onset = FAST.settle_time + FAST.ramp_time + 0.3
    outcome, _ = run(g1, model, tmp_path, imu=source, emulator=EmulatorConfig(faults=(FaultInjection("imu_silent", start=onset),)))
    fault = outcome.result.fault
    assert outcome.exit_code == 1 and fault.kind.value == "imu"
    cycles = SafetyConfig().imu_timeout_cycles
    assert onset < fault.time <= onset + (cycles + 2) * 0.002


def test_a_joint_outside_its_limits_at_start_is_refused(g1, model, tmp_path):
    # a slipped encoder / wrong zero: the left knee reads 1.5 rad beyond where it is
    fault = FaultInjection("encoder", joints=("left_knee_joint",), offset=-1.5)
    outcome, lines = run(g1, model, tmp_path, emulator=EmulatorConfig(faults=(fault,)))
    assert outcome.exit_code == 1
    fault = outcome.result.fault
    assert fault.kind.value == "startup" and fault.joints == ("left_knee_joint",)
    assert "refusing to enable the motors" in fault.message and "left_knee_joint reads" in fault.message
    assert "giwbc motors calibrate" in fault.message
    emu = outcome.emulator
    assert emu.counters.specials.sum() > 0  # only exit frames: never entered motor mode
    phases = [e["detail"]["phase"] for e in read_log(outcome.log_path).events if e["event"] == "phase"]
    assert "enable" not in phases and phases[-1] == "off"


def test_first_run_mode_hangs_on_a_gantry_with_reduced_limits(g1, model, tmp_path):
    outcome, lines = run(g1, model, tmp_path, first_run=True, controller="pd", estimator=False)
    assert outcome.exit_code == 0, outcome.message
    assert any("first run (gantry)" in line for line in lines)
    log = read_log(outcome.log_path)
    kp = np.array([m["kp"] for m in log.topic("/commands") if m["phase"] == "running"])
    assert kp.max() == pytest.approx(0.5 * g1.kp.max())  # gains halved
    assert outcome.emulator.config.gantry is not None


def test_preflight_runs_before_real_buses_open(g1, tmp_path):
    master, slave = pty.openpty()  # a serial IMU that opens: the buses are what is checked
    hw = tmp_path / "hardware.toml"
    imu = f'source = "serial"\ndevice = "{os.ttyname(slave)}"'
    hw.write_text((g1.folder / "hardware.toml").read_text().replace('source = "emulated"', imu))
    said: list[str] = []
    try:
        outcome = deploy(DeployOptions(hardware=str(hw), emulate=False), description=g1, out=said.append)
    finally:
        os.close(master)
        os.close(slave)
    assert outcome.exit_code == 2
    assert "pre-flight failed" in outcome.message
    text = "\n".join(said)
    assert "bus 'can0' (can0): interface does not exist" in text or "sudo ip link set can0" in text


def test_imu_option_needs_the_emulator(g1):
    outcome = deploy(DeployOptions(emulate=False, imu="serial"), description=g1, out=None)
    assert outcome.exit_code == 2 and "--emulate" in outcome.message


def test_safety_start_tolerance_is_configurable():
    assert SafetyConfig().start_limit_tolerance == pytest.approx(0.1)
