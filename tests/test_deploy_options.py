"""``giwbc deploy`` refuses bad input before anything starts: numbers through argparse types, the
library's :class:`DeployOptions` on construction, ``--walker`` JSON, a foot-contact controller on
a gantry, a real-time priority the kernel refuses; the gantry rehearsal of the README runs; a
fault's line is bounded and an overloaded emulated host is named as the cause."""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from giwbc.apps.deploy import DeployOptions, add_deploy_command, deploy, run_deploy_command
from giwbc.apps.deploy_diagnosis import fault_summary, overload_note
from giwbc.errors import ConfigError
from giwbc.hal.hardware import load_hardware
from giwbc.hal.safety import Fault, FaultKind

ROOT = Path(__file__).resolve().parents[1]


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["deploy", *argv])


@pytest.mark.parametrize("argv", [
    ("--ramp", "nan"), ("--ramp", "-1"), ("--ramp", "0"), ("--fault-at", "nan"), ("--seconds", "nan"), ("--seconds", "-1"),
    ("--seconds", "inf"), ("--seconds", "1e12"), ("--rt-priority", "500"), ("--rt-priority", "0"), ("--scene-rate", "-1"),
    ("--rate", "0"), ("--rate", "nan"), ("--cpu-latency", "-1"), ("--foxglove-port", "70000"), ("--foxglove-port", "80"), ("--vx", "nan"), ("--vx", "5"),
    ("--walk-delay", "-1"), ("--yaw-rate", "inf"),
])  # fmt: skip
def test_bad_numbers_are_refused_by_argparse(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        parse("--emulate", *argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert argv[0] in err[-1] and "expected" in err[-1]


def test_options_from_python_are_checked_when_built():
    for field, value in [("seconds", math.nan), ("seconds", -1.0), ("control_rate", 0.0), ("control_rate", math.inf),
                         ("scene_rate", -1.0), ("rt_priority", 500), ("cpu_latency", math.nan), ("reply_timeout", 0.0),
                         ("log_every", 0), ("controller", "fast"), ("emulator_mode", "remote"), ("foxglove_port", 0)]:  # fmt: skip
        with pytest.raises(ConfigError, match=field):
            DeployOptions(**{field: value})
    with pytest.raises(ConfigError, match="walker: hip_roll_gain"):
        DeployOptions(controller="walk", walker={"hip_roll_gain": math.nan})
    assert DeployOptions().controller == "wbc" and DeployOptions(first_run=True).controller == "pd"


def test_reply_lag_needs_the_emulator_and_fits_its_mode(capsys):
    with pytest.raises(SystemExit):
        parse("--emulate", "--reply-lag", "2")
    assert "--reply-lag" in capsys.readouterr().err
    assert parse("--emulate", "--reply-lag", "1").reply_lag == 1
    for values, match in [({"reply_lag": 2, "emulate": True}, "reply_lag must be 0 or 1"), ({"reply_lag": 1}, "needs --emulate"),
                          ({"reply_lag": 0, "emulate": True, "emulator_mode": "process"}, "next cycle")]:  # fmt: skip
        with pytest.raises(ConfigError, match=match):
            DeployOptions(**values)


def test_replies_read_at_the_next_cycle_in_lockstep(g1, tmp_path):
    """``--reply-lag 1`` on the lockstep emulator: the process emulator's timing in the emulator's
    time. The enable cycle reads no reply yet (they come at the next one), the run is clean; with
    the default the enable cycle reads every reply."""
    from giwbc.runlog import read_log

    first = {}
    for lag in (0, 1):
        options = DeployOptions(emulate=True, realtime=False, controller="pd", seconds=0.2, reply_lag=lag, log=str(tmp_path / f"{lag}.mcap"))
        outcome = deploy(options, description=g1, out=None)
        assert outcome.exit_code == 0, outcome.message
        replies = read_log(outcome.log_path).topic("/replies")
        first[lag] = [any(m["missing"]) for m in replies[:3]]
    assert first[0] == [False, False, False] and first[1] == [True, False, False]


def test_a_foot_contact_controller_on_a_gantry_is_refused_before_anything_starts(g1, capsys):
    for controller in ("wbc", "walk"):
        outcome = deploy(DeployOptions(emulate=True, first_run=True, controller=controller), description=g1, out=None)
        assert outcome.exit_code == 2 and "--controller pd" in outcome.message and outcome.result is None
    code = run_deploy_command(parse("--emulate", "--first-run", "--controller", "wbc"))
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    assert captured.err.count("\n") == 1 and captured.err.startswith("giwbc deploy: error: --first-run")


def test_walker_json_numbers_must_be_finite(capsys):
    for text in ('{"hip_roll_gain": NaN}', '{"hip_roll_gain": 1e999}', '{"adapt_freeze_time": -Infinity}'):
        code = run_deploy_command(parse("--emulate", "--controller", "walk", "--walker", text))
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("giwbc deploy: error: --walker") and err.count("\n") == 1


def test_a_refused_real_time_priority_stops_before_any_bus(g1, monkeypatch):
    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    outcome = deploy(DeployOptions(emulate=True, controller="pd", rt_priority=80), description=g1, out=None)
    assert outcome.exit_code == 2 and outcome.result is None and outcome.emulator is None
    assert "--rt-priority 80" in outcome.message and "CAP_SYS_NICE" in outcome.message


def test_missing_replies_on_every_joint_summarized_per_bus(g1):
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names)
    message = "no valid reply for >= 3 cycles: " + ", ".join(f"{j} (3)" for j in g1.joint_names)
    assert len(message) > 700
    line = fault_summary(Fault(FaultKind.MISSING_REPLIES, message, 1200, 2.4, tuple(g1.joint_names)), plan)
    assert len(line) < 250 and "\n" not in line and "29 of 29 joints on 10 of 10 buses (every motor on can0, can1," in line
    some = tuple(j for j in g1.joint_names if plan.motor(j)[0].name in ("can0", "can1"))[:5]  # can0's 3, 2 of can1's
    line = fault_summary(Fault(FaultKind.MISSING_REPLIES, message, 1200, 2.4, some), plan)
    assert f"5 of 29 joints on 2 of 10 buses (every motor on can0; can1 {some[3]}, {some[4]})" in line
    assert fault_summary(Fault(FaultKind.INTERNAL, "runtime error\nTraceback ...\n" + "x" * 5000, 3, 0.0)).count("\n") == 0


class _Result:
    def __init__(self, kind: FaultKind, **timing: object) -> None:
        self.fault = Fault(kind, "x", 10, 0.02)
        self.timing = {"cycles": 1000, "period_us": 2000.0, "overruns": 0, "skipped_slots": 0, **timing}


def test_overload_is_named_only_for_an_emulated_timing_or_reply_fault_with_evidence():
    loaded = (5.2, 2)
    assert "overloaded" in overload_note(True, _Result(FaultKind.MISSING_REPLIES), loaded)
    assert "--unpaced" in overload_note(True, _Result(FaultKind.TIMING, skipped_slots=180), None)
    assert "50 of 1000 cycles overran" in overload_note(True, _Result(FaultKind.TIMING, overruns=50), (0.1, 2))
    assert overload_note(False, _Result(FaultKind.MISSING_REPLIES), loaded) is None  # real motors: the robot's fault until shown otherwise
    assert overload_note(True, _Result(FaultKind.FALL), loaded) is None
    assert overload_note(True, _Result(FaultKind.MISSING_REPLIES), (0.5, 2)) is None  # no evidence


def test_an_emulator_process_that_ran_periods_late_is_named_as_the_cause():
    """A quiet load average, no overrun, but the emulator process measured itself 7.1 ms late
    (EmulatorStalls): that is the evidence, said with its time; a stall within two periods is none."""
    from giwbc.emulation.process import EmulatorStalls

    note = overload_note(True, _Result(FaultKind.MISSING_REPLIES), (0.5, 2), EmulatorStalls(7.1e-3, 14.97, 2))
    assert note is not None and "ran 7.1 ms after its physics step was due, at t = 14.97 s" in note
    assert overload_note(True, _Result(FaultKind.MISSING_REPLIES), (0.5, 2), EmulatorStalls(3.5e-3, 1.0, 1)) is None
    assert overload_note(False, _Result(FaultKind.MISSING_REPLIES), (0.5, 2), EmulatorStalls(7.1e-3, 14.97, 2)) is None


def test_the_readme_gantry_rehearsal_runs_and_says_what_it_does(tmp_path):
    """The README's gantry step, as written, from a folder of its own (its log lands there)."""
    proc = subprocess.run(
        [sys.executable, "-m", "giwbc.apps.deploy", "--robot", "g1", "--emulate", "--first-run", "--seconds", "2"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    assert "running stand (pd)" in proc.stdout and "ramping to the default pose" in proc.stdout and "stood" in proc.stdout
    assert "clean run" in proc.stdout.splitlines()[-1] and len(list((tmp_path / "runs").glob("deploy-g1-*.mcap"))) == 1
    assert "giwbc deploy --robot g1 --emulate --first-run --seconds 2" in (ROOT / "README.md").read_text()
