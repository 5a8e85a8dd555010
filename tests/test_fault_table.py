"""The fault table: every fault kind of :data:`giwbc.runtimes.faults.FAULT_CASES`, injected into an
emulated G1 run (lockstep, unpaced), must be detected within its bound after its onset, damping
must go out at the next cycle, the cause must be named in the summary and the run log, the motors
must be off at the end (those of a bus that cannot be reached: limp on their own timeout), and
the exit code must be the documented one. Foreign-but-harmless traffic is counted, never fatal."""

from __future__ import annotations

import _thread
import math
import threading

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.emulation import EmulatorConfig
from giwbc.runlog import read_log
from giwbc.hal.safety import FaultKind, SafetyConfig
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.realtime import exit_code_for
from giwbc.runtimes.faults import FAULT_CASES, TARGET_JOINT

ONSET = 0.3  # s: after the 0.22 s start-up, while the controller runs
DT = 0.002
# (Unpaced, the watchdog waits at least 1 s of wall time without a cycle: a loaded machine does not trip it.)
SAFETY = SafetyConfig(damping_time=0.1)
STARTUP = StartupConfig(settle_time=0.02, ramp_time=0.2, shutdown_time=0.1, off_delay=0.05)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def _metadata(g1) -> dict:
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


HANG_GUARD = 120.0  # s of wall time: a run still going then is a hang (the guard interrupts the main thread)


def run_case(kind: str, g1, model, tmp_path, *, seconds: float = 0.45):
    """One row of the table: the emulated G1 with the fault injected at ``ONSET``. A run that
    hangs is interrupted after ``HANG_GUARD`` seconds (a failure, not a stuck test session)."""
    guard = threading.Timer(HANG_GUARD, _thread.interrupt_main)
    guard.start()
    try:
        return _run_case(kind, g1, model, tmp_path, seconds)
    finally:
        guard.cancel()


def _run_case(kind: str, g1, model, tmp_path, seconds: float):
    case = FAULT_CASES[kind]
    policy = metadata = None
    task, controller = "stand", "pd"
    if case.needs == "policy":
        task, metadata = "balance", _metadata(g1)
        policy = lambda observation: np.zeros(len(metadata["action_names"]), dtype=np.float32)  # noqa: E731
    if case.needs == "wbc":
        controller = "wbc"
    options = DeployOptions(
        emulate=True, realtime=False, controller=controller, task=task, seconds=seconds, log=str(tmp_path / f"{kind}.mcap"),
        startup=STARTUP, safety=SAFETY, emulator=EmulatorConfig(record=True), faults=case.injections(ONSET),
    )  # fmt: skip
    return deploy(options, policy=policy, policy_metadata=metadata, model=model, description=g1, out=None)


def _is_damping(command, g1) -> bool:
    return max(command["kp"]) == 0 and max(abs(x) for x in command["tau_ff"]) == 0 and np.allclose(command["kd"], SAFETY.damping_kd_scale * g1.kd)


@pytest.mark.parametrize("kind", list(FAULT_CASES))
def test_fault_table(kind, g1, model, tmp_path):
    case = FAULT_CASES[kind]
    outcome = run_case(kind, g1, model, tmp_path)
    result = outcome.result
    assert result is not None, outcome.message
    log = read_log(outcome.log_path)
    emu = outcome.emulator
    stuck = [i for i, m in enumerate(emu.motors) if case.stuck_bus and m.joint == TARGET_JOINT]
    stuck_bus = {emu.plan.buses[int(emu._bus_of[i])].name for i in stuck}
    stuck_motors = np.isin(emu._bus_of, [int(emu._bus_of[i]) for i in stuck])

    if case.expected is None:  # tolerated traffic: a clean run, the traffic counted
        assert outcome.exit_code == 0 and result.ok, (outcome.message, result.faults)
        assert not log.faults and log.event_names()[-1] == "motors_off" and (emu.mode == 0).all()
        if kind in ("foreign_sync", "foreign_ids", "zero_byte"):
            assert sum(m["unknown"] for m in log.topic("/replies")) >= (0.45 - ONSET) / DT
        assert outcome.standing["stood"]
        return

    fault = result.fault
    assert fault is not None and fault.kind is case.expected, result.faults
    # Detected within the bound after the onset (the first cycle at or after ONSET, or when a
    # policy or controller fault first acted).
    onset = outcome.fault_onsets.get(case.make(ONSET)[0].kind, math.ceil(ONSET / DT - 1e-9) * DT)
    lag = round((fault.time - onset) / DT)
    assert 0 <= lag <= case.bound, (fault, onset)
    # The cause, named in the summary and the run log; the documented exit code.
    assert case.expected.value in outcome.message
    assert log.faults[0]["kind"] == case.expected.value and log.faults[0]["cycle"] == fault.cycle
    documented = {"sigint": 130, "sigterm": 143, "sighup": 129, "keyboard_interrupt": 130}.get(kind, 1)
    assert outcome.exit_code == exit_code_for(fault) == documented
    # Damping at the next cycle: in the log (sent by the loop), and applied by the emulated motors.
    if fault.kind is not FaultKind.WATCHDOG:
        after = [m for m in log.topic("/commands") if m["cycle"] > fault.cycle]
        commands = [m for m in after if m["kind"] == "command"]
        assert commands[0]["cycle"] == fault.cycle + 1 and all(_is_damping(m, g1) for m in commands)
        assert after[-1]["kind"] == "exit" and log.event_names()[-1] == "motors_off"
    else:
        assert result.loop_abandoned and "watchdog" in log.event_names()
    # (The watchdog's frames go out from its sender threads: on a loaded machine they may start a step late.)
    steps = 3 if fault.kind is FaultKind.WATCHDOG else 2
    snaps = [s for s in emu.snapshots if fault.time < s.time <= fault.time + steps * DT + 1e-9]
    reachable = ~np.isin(np.arange(g1.dofs), emu.joint_index[stuck_motors])
    assert any((s.kp[reachable] == 0).all() and (np.abs(s.tau_ff[reachable]) < 0.05).all() for s in snaps)
    # Motors off at the end; a bus that cannot be reached leaves its motors to their own timeout (limp).
    assert (emu.mode[~stuck_motors] == 0).all()
    assert emu.limp()[stuck_motors].all()
    assert all(name in outcome.message for name in stuck_bus)  # the bus that could not be reached is named
    if fault.kind is not FaultKind.WATCHDOG:  # and its motors, as not confirmed off
        assert {m.joint for m, stuck in zip(emu.motors, stuck_motors) if stuck} <= set(result.unconfirmed_off)


def test_table_covers_every_kind_of_the_issue():
    assert len(FAULT_CASES) >= 18
    wanted = {"policy_nan", "controller_nan", "qp_infeasible", "controller_raise", "driver_raise", "driver_block", "bus_off",
              "motor_exit", "foreign_sync", "foreign_ids", "zero_byte", "duplicate_replies", "reordered_replies", "joint_limit",
              "keyboard_interrupt", "sigint", "sigterm"}  # fmt: skip
    assert wanted <= set(FAULT_CASES)
