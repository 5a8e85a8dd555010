"""giwbc deploy --transport dds on the DDS emulator (its own process, loopback only): a clean run
stands, each DDS row of the fault table ends in damping within 2 cycles with its cause logged and
exit 1, and every DDS configuration error is one line with exit 2 before any motor is enabled."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("cyclonedds")

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.apps.deploy_dds import DDS_FAULT_CASES
from giwbc.hal.safety import SafetyConfig
from giwbc.runlog import read_log
from giwbc.runtimes.phases import StartupConfig

STARTUP = StartupConfig(settle_time=0.05, ramp_time=0.3, shutdown_time=0.1, off_delay=0.05)
# Two processes on their own clocks share a CI machine's CPUs without real-time priority: tolerate
# scheduling stalls of the emulator (as tests/test_emulator_process.py does).
TOLERANT = SafetyConfig(max_missing_cycles=25, imu_timeout_cycles=50, damping_time=0.1)
FAULT_AT = 0.25  # s after the start-up (0.35 s)


def _options(tmp_path, **overrides) -> DeployOptions:
    values = dict(emulate=True, emulator_mode="process", controller="pd", seconds=1.0, log=str(tmp_path / "run.mcap"), startup=STARTUP,
                  safety=TOLERANT, transport="dds")  # fmt: skip
    return DeployOptions(**{**values, **overrides})


@pytest.mark.slow
def test_a_pd_hold_over_dds_stands_clean(g1, tmp_path) -> None:
    outcome = deploy(_options(tmp_path), description=g1, out=None)
    assert outcome.exit_code == 0, outcome.message
    result = outcome.result
    assert result.ok and result.cycles > 500
    assert outcome.standing is not None and outcome.standing["stood"] and outcome.standing["seconds"] > 0.9
    emulator = outcome.emulator
    assert emulator.failure is None and not emulator.alive
    assert emulator.counters["crc_errors"] == 0 and emulator.counters["commands"] > 0.5 * result.cycles
    log = read_log(outcome.log_path)
    assert not log.faults and log.event_names()[-1] == "motors_off"


@pytest.mark.slow
@pytest.mark.parametrize("row", sorted(DDS_FAULT_CASES))
def test_dds_fault_rows_end_in_damping(g1, tmp_path, row: str) -> None:
    case = DDS_FAULT_CASES[row]
    start = STARTUP.settle_time + STARTUP.ramp_time + FAULT_AT
    outcome = deploy(_options(tmp_path, faults=case.injections(start)), description=g1, out=None)
    result = outcome.result
    assert outcome.exit_code == 1, outcome.message
    fault = result.fault
    assert fault is not None and fault.kind is case.expected, outcome.message
    assert fault.time >= start - 0.05  # not before the injection (emulator and host clocks agree to a period or so)
    log = read_log(outcome.log_path)
    assert log.faults[0]["kind"] == case.expected.value and log.faults[0]["message"]
    commands = [m for m in log.topic("/commands") if m["cycle"] > fault.cycle and m["kind"] == "command"]
    assert commands and commands[0]["cycle"] <= fault.cycle + 2  # damping from the next cycles on
    assert max(commands[0]["kp"]) == 0 and max(abs(x) for x in commands[0]["tau_ff"]) == 0 and min(commands[0]["kd"]) > 0
    assert log.event_names()[-1] == "motors_off"
    assert outcome.standing is not None and outcome.standing["stood"]


LO_PLAN = (Path(__file__).resolve().parents[1] / "robots" / "g1" / "hardware_dds.toml").read_text()


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "giwbc.apps.cli", "deploy", *args, "--log", str(cwd / "x.mcap")], cwd=cwd,
                          capture_output=True, text=True, timeout=120)  # fmt: skip


def _plan(tmp_path: Path, name: str, **changes: str) -> str:
    text = LO_PLAN
    for old, new in changes.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("args, message", [
    (("--transport", "dds", "--emulate"), "the DDS emulator runs in its own process"),
    (("--transport", "dds", "--emulate", "--emulator", "process", "--hardware", "robots/g1/hardware.toml"), "--transport dds needs a DDS plan"),
    (("--emulate", "--emulator", "process", "--hardware", "robots/g1/hardware_dds.toml"), "run it with --transport dds"),
    (("--emulate", "--fault", "dds_silent"), "is a DDS fault: it needs --transport dds"),
    (("--transport", "dds", "--emulate", "--emulator", "process", "--fault", "bus_off"), "act on CAN buses"),
    (("--transport", "dds", "--emulate", "--emulator", "process", "--imu", "serial"), "IMU is the one in its rt/lowstate"),
    (("--transport", "dds", "--hardware", "{nosuch}"), "network interface 'nosuch0' does not exist on this machine"),
    (("--transport", "dds", "--hardware", "{domain}"), "DDS domain id must be an integer from 0 to 232"),
    (("--transport", "dds", "--emulate", "--emulator", "process", "--restore-service"), "--restore-service selects the mode --release-service"),
    (("--emulate", "--release-service"), "they need --transport dds"),
])  # fmt: skip
def test_dds_configuration_errors_are_one_line(args, message, tmp_path) -> None:
    repo = Path(__file__).resolve().parents[1]
    plans = {"{nosuch}": _plan(tmp_path, "nosuch", **{'interface = "eth0"': 'interface = "nosuch0"'}),
             "{domain}": _plan(tmp_path, "domain", **{"domain = 0": "domain = 250"})}  # fmt: skip
    done = _cli(*[plans.get(a, a) for a in args], cwd=repo)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("giwbc deploy: error: ")


@pytest.mark.slow
def test_no_robot_on_the_interface_is_one_line(tmp_path) -> None:
    """On loopback, on a domain nobody uses: refused before any motor is enabled (nothing leaves the machine)."""
    repo = Path(__file__).resolve().parents[1]
    plan = _plan(tmp_path, "lo", **{'interface = "eth0"': 'interface = "lo"', "domain = 0": "domain = 231", "state_timeout = 3.0": "state_timeout = 0.5"})
    done = _cli("--transport", "dds", "--hardware", plan, cwd=repo)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no valid rt/lowstate within 0.5 s" in lines[0]
