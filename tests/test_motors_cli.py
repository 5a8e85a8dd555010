"""``giwbc motors`` against the emulator: scan finds a missing and an extra motor, calibrate
recovers a wrong sign and offset and writes a plan that then deploys (the uncalibrated one does
not), zero, monitor, confirmations, and the SocketCAN check."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.apps.motors import add_motors_command, run_motors_command
from giwbc.hal.plan_edit import update_plan_text
from giwbc.hal.hardware import load_hardware
from giwbc.runtimes.phases import StartupConfig

WRONG = {"left_knee_joint": (-1, 0.3), "right_hip_pitch_joint": (-1, -0.2), "left_ankle_pitch_joint": (1, 0.15)}


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


@pytest.fixture
def plans(g1, tmp_path):
    text = (g1.folder / "hardware.toml").read_text()
    shipped = tmp_path / "hardware.toml"
    shipped.write_text(text)
    truth = tmp_path / "truth.toml"
    truth.write_text(update_plan_text(text, {j: {"sign": s, "zero_offset": z} for j, (s, z) in WRONG.items()}))
    return shipped, truth


def motors(*argv: str, answers: tuple[str, ...] = ()) -> tuple[int, list[str]]:
    parser = argparse.ArgumentParser(prog="giwbc")
    add_motors_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["motors", *argv])
    lines: list[str] = []
    replies = list(answers)
    code = run_motors_command(args, out=lines.append, ask=lambda q: (lines.append(q), replies.pop(0))[1])
    return code, lines


def test_scan_dry_run_finds_a_missing_and_an_extra_motor(plans, tmp_path):
    shipped, _ = plans
    text = shipped.read_text()
    host = re.sub(r'\[\[motors\]\]\nbus = "can9"\nid = 2\njoint = "right_wrist_yaw_joint"\n(?:\w+ = .*\n)*', "", text)
    host = host.replace('bus = "can4"\nid = 3\n', 'bus = "can4"\nid = 9\n')  # the plan says id 9, the motor is id 3
    assert host.count("[[motors]]") == text.count("[[motors]]") - 1
    plan = tmp_path / "host.toml"
    plan.write_text(host)
    code, lines = motors("scan", "--hardware", str(plan), "--dry-run", "--dry-run-plan", str(shipped), "--ids", "1-10")
    out = "\n".join(lines)
    assert code == 1
    assert "MISSING 'waist_pitch_joint': no answer from id 9 on can4" in out
    assert "EXTRA id 3 on can4" in out and "EXTRA id 2 on can9" in out
    assert lines[-1] == "differs from the plan: 1 missing, 2 extra (of 28 planned motors)"
    code, lines = motors("scan", "--hardware", str(shipped), "--dry-run", "--ids", "1-3")
    assert code == 0 and lines[-1] == "matches the plan: all 29 planned motors answered, nothing else did"


def test_calibrate_recovers_wrong_signs_and_offsets_and_the_plan_then_deploys(g1, model, plans, tmp_path):
    shipped, truth = plans
    fast = StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.2, off_delay=0.1)

    def rehearse(hardware: Path):
        return deploy(DeployOptions(
            emulate=True, hardware=str(hardware), emulated_hardware=str(truth), controller="pd", seconds=1.0, realtime=False,
            log=str(tmp_path / f"{hardware.stem}.mcap"), startup=fast, reply_timeout=0.01,
        ), model=model, description=g1, out=None)  # fmt: skip

    before = rehearse(shipped)  # the shipped plan on the robot as it really is: never a clean stand
    assert before.exit_code != 0 or not before.standing["stood"]
    code, lines = motors("calibrate", "--hardware", str(shipped), "--dry-run", "--dry-run-plan", str(truth), "--yes", "--write")
    assert code == 0, "\n".join(lines)
    plan = load_hardware(shipped, 500.0, joint_names=g1.joint_names)
    for joint in g1.joint_names:
        _, m = plan.motor(joint)
        sign, offset = WRONG.get(joint, (1, 0.0))
        assert m.sign == sign and m.zero_offset == pytest.approx(offset, abs=2e-3), joint
    assert len(list(tmp_path.glob("hardware.toml.bak-*"))) == 1
    after = rehearse(shipped)
    assert after.exit_code == 0, after.message
    assert after.standing["stood"]


def test_calibrate_asks_before_anything_and_a_no_changes_nothing(plans):
    shipped, truth = plans
    text = shipped.read_text()
    code, lines = motors("calibrate", "--hardware", str(shipped), "--dry-run", "--dry-run-plan", str(truth), "--write", answers=("no",))
    assert code == 1 and lines[-1] == "nothing done" and shipped.read_text() == text


def test_calibrate_dry_run_without_write_leaves_the_plan(plans):
    shipped, truth = plans
    text = shipped.read_text()
    code, lines = motors("calibrate", "--hardware", str(shipped), "--dry-run", "--dry-run-plan", str(truth), "--yes",
                         "--joints", "left_knee_joint")  # fmt: skip
    assert shipped.read_text() == text and any("not written" in line for line in lines)
    assert any("left_knee_joint: sign -1, zero_offset 0.30" in line for line in lines)


def test_zero_and_monitor_dry_run(g1, plans):
    shipped, _ = plans
    code, lines = motors("zero", "left_knee_joint", "--at", "0.25", "--hardware", str(shipped), "--dry-run", "--write",
                         answers=("yes",))  # fmt: skip
    assert code == 0, lines
    assert "set the zero of motor id 1 on can1 (left_knee_joint)" in lines[1]
    _, m = load_hardware(shipped, 500.0).motor("left_knee_joint")
    assert m.zero_offset == 0.25
    code, lines = motors("monitor", "--hardware", str(shipped), "--dry-run", "--count", "1")
    assert code == 0
    row = next(line for line in "\n".join(lines).splitlines() if line.startswith("left_knee_joint"))
    q = float(row.split()[1])
    assert q == pytest.approx(g1.default_positions[g1.joint_names.index("left_knee_joint")], abs=1e-3)


def test_monitor_flags_a_joint_outside_its_limits(plans, tmp_path):
    shipped, _ = plans
    # a wrong zero offset in the plan: the motor was zeroed at 0 rad, the plan says -2.5 rad
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(update_plan_text(shipped.read_text(), {"left_knee_joint": {"zero_offset": -2.5}}))
    code, lines = motors("monitor", "--hardware", str(wrong), "--dry-run", "--dry-run-plan", str(shipped), "--count", "1")
    out = "\n".join(lines)
    assert code == 1 and "OUTSIDE LIMITS" in out and "joint 'left_knee_joint' reads" in out


def test_check_reports_missing_interfaces_here(plans):
    shipped, _ = plans
    code, lines = motors("check", "--hardware", str(shipped))
    if Path("/sys/class/net/can0").exists():
        pytest.skip("this machine has a can0: the verdict depends on its set-up")
    assert code == 1 and "[error] bus 'can0' (can0): interface does not exist" in lines[0]


def test_check_dry_run_checks_the_plan_and_prints_the_bring_up_commands(plans, tmp_path):
    shipped, _ = plans
    code, lines = motors("check", "--hardware", str(shipped), "--dry-run")
    assert code == 0 and "is a valid plan for 29 joints on 10 buses at 500 Hz" in lines[0]
    commands = [line.strip() for line in lines if line.strip().startswith("sudo ip link set")]
    assert len(commands) == 4 * 10 and "sudo ip link set can3 type can bitrate 1000000 restart-ms 100" in commands
    # A plan that cannot work is refused, one line on stderr, whatever the interfaces
    lonely = tmp_path / "lonely.toml"
    lonely.write_text(re.sub(r'\[\[motors\]\]\nbus = "can9"\nid = 2\n(?:\w+ = .*\n)*', "", shipped.read_text()))
    errors: list[str] = []
    parser = argparse.ArgumentParser(prog="giwbc")
    add_motors_command(parser.add_subparsers(dest="command", required=True))
    code = run_motors_command(parser.parse_args(["motors", "check", "--hardware", str(lonely), "--dry-run"]), out=print, err=errors.append)
    assert code == 2 and len(errors) == 1 and "right_wrist_yaw_joint" in errors[0]


@pytest.mark.parametrize("argv", [("monitor", "--count", "-1"), ("monitor", "--hz", "0"), ("monitor", "--hz", "nan"),
                                  ("scan", "--timeout", "-1"), ("scan", "--ids", "x"), ("check", "--rate", "inf"),
                                  ("zero", "left_knee_joint", "--at", "nan"), ("calibrate", "--min-move", "0")])  # fmt: skip
def test_bad_numbers_are_refused_before_any_bus(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        motors(*argv)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert exit_.value.code == 2 and f"argument {argv[1] if argv[1].startswith('--') else argv[2]}:" in err


def test_monitor_counts_refreshes(plans):
    shipped, _ = plans
    code, lines = motors("monitor", "--hardware", str(shipped), "--dry-run", "--count", "2", "--hz", "50")
    assert code == 0 and sum(line.startswith("left_knee_joint") for line in "\n".join(lines).splitlines()) == 2
