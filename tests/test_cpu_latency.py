"""The real-time runtime's CPU wake-up latency request (Linux PM QoS, ``/dev/cpu_dma_latency``):
held while the motors are on, released at the end, refused without harm."""

from __future__ import annotations

import argparse
import copy
import math
import os
import struct

import pytest

from giwbc.runlog import read_log
from giwbc.runtimes.os_settings import CPU_LATENCY_DEVICE, ProcessSettings
from giwbc.runtimes.phases import StartupConfig

STARTUP = StartupConfig(settle_time=0.02, ramp_time=0.05, shutdown_time=0.02, off_delay=0.02)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def _run(g1, model, tmp_path, on_tick, **runtime_options):
    """A short unpaced lockstep run of a joint-PD hold that calls ``on_tick(runtime)`` every tick;
    (result, runtime, log path)."""
    from giwbc.emulation import ActuatorEmulator, EmulatorConfig
    from giwbc.hal.can_robot import CanRobot
    from giwbc.hal.hardware import load_hardware
    from giwbc.robot.standing import PdHold
    from giwbc.runlog import RunLogWriter
    from giwbc.runtimes.realtime import RealtimeRuntime
    from giwbc.tasks.standing import StandingTask

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    emulator = ActuatorEmulator(plan, g1, EmulatorConfig(), model=copy.copy(model))
    robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator)
    log = RunLogWriter(tmp_path / "run.mcap", g1.joint_names)
    holder: dict = {}

    class Watching(PdHold):
        def __call__(self, robot):
            on_tick(holder["runtime"])
            return super().__call__(robot)

    try:
        runtime = RealtimeRuntime(StandingTask(Watching(g1), g1.default_positions), robot, log=log, startup=STARTUP, realtime=False,
                                  **runtime_options)  # fmt: skip
        holder["runtime"] = runtime
        result = runtime.run(None, seconds=0.1)
    finally:
        robot.close()
        emulator.close()
        log.close()
    return result, runtime, log.path


def _events(path, name: str) -> list[dict]:
    return [e["detail"] for e in read_log(path, topics=["/events"]).events if e["event"] == name]


def test_the_request_is_written_while_the_motors_are_on_and_released_at_the_end(g1, model, tmp_path, monkeypatch):
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(ProcessSettings, "cpu_latency_device", str(device))
    held = []

    def on_tick(runtime) -> None:
        fd = runtime._cpu_latency_fd
        held.append(fd is not None and os.path.samefile(f"/proc/self/fd/{fd}", device))

    result, runtime, log = _run(g1, model, tmp_path, on_tick, cpu_latency=0.0)
    assert result.ok, result.fault
    assert held and all(held)  # open in every controller tick
    assert struct.unpack("=i", device.read_bytes()) == (0,)  # the kernel's format: one native int32, µs
    assert runtime._cpu_latency_fd is None  # closed: the kernel ends the request
    assert runtime.cpu_idle == "wake-up latency <= 0 us (PM QoS)"
    assert _events(log, "cpu_latency") == [{"latency_us": 0, "device": str(device)}]


def test_a_refused_request_is_logged_and_the_run_goes_on(g1, model, tmp_path, monkeypatch):
    monkeypatch.setattr(ProcessSettings, "cpu_latency_device", str(tmp_path / "absent" / "cpu_dma_latency"))
    result, runtime, log = _run(g1, model, tmp_path, lambda runtime: None, cpu_latency=20.0)
    assert result.ok, result.fault
    assert runtime.cpu_idle.startswith("default (wake-up latency 20 us refused:")
    (event,) = _events(log, "cpu_latency")
    assert event["latency_us"] == 20 and "No such file" in event["refused"]


def test_no_request_by_default(g1, model, tmp_path, monkeypatch):
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(ProcessSettings, "cpu_latency_device", str(device))
    result, runtime, log = _run(g1, model, tmp_path, lambda runtime: None)
    assert result.ok and runtime.cpu_idle == "default"
    assert device.read_bytes() == b"" and _events(log, "cpu_latency") == []


def _kernel_latency() -> int:
    with open(CPU_LATENCY_DEVICE, "rb") as device:
        return struct.unpack("=i", device.read(4))[0]


@pytest.mark.skipif(not os.access(CPU_LATENCY_DEVICE, os.R_OK | os.W_OK), reason=f"{CPU_LATENCY_DEVICE} not writable here (needs root)")
def test_the_kernel_holds_the_bound_during_the_run_only(g1, model, tmp_path):
    """Read back from the kernel: its effective wake-up latency bound is the request during the run
    (no other process on this machine asks for less than 3 µs) and what it was after."""
    before = _kernel_latency()
    seen = []
    result, _, _ = _run(g1, model, tmp_path, lambda runtime: seen.append(_kernel_latency()), cpu_latency=3.0)
    assert result.ok, result.fault
    assert seen and max(seen) <= 3
    assert _kernel_latency() == before


def test_a_bad_bound_is_refused_before_anything_starts(g1, model, tmp_path):
    from giwbc.apps.deploy import add_deploy_command

    for bad in (-1.0, math.nan, 3e9):  # (3e9 µs: beyond the kernel's int32 request)
        with pytest.raises(ValueError, match="cpu_latency"):
            _run(g1, model, tmp_path, lambda runtime: None, cpu_latency=bad)
    parser = argparse.ArgumentParser()
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    with pytest.raises(SystemExit) as exit_:  # refused by the option's type, before anything runs
        parser.parse_args(["deploy", "--robot", "g1", "--emulate", "--cpu-latency", "-5", "--log", str(tmp_path / "never.mcap")])
    assert exit_.value.code == 2
    assert not (tmp_path / "never.mcap").exists()


def test_deploy_says_what_the_kernel_granted(tmp_path, capsys):
    """``giwbc deploy --cpu-latency 0`` prints the loop's scheduling and the CPUs' idle states as
    granted (a refusal included: the run goes on either way)."""
    from giwbc.apps.deploy import add_deploy_command

    parser = argparse.ArgumentParser()
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", "--robot", "g1", "--emulate", "--unpaced", "--controller", "pd", "--seconds", "0.1",
                              "--ramp", "0.2", "--cpu-latency", "0", "--scene-rate", "0", "--log", str(tmp_path / "run.mcap")])
    assert args.run(args) == 0
    (line,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("control loop:")]
    granted = os.access(CPU_LATENCY_DEVICE, os.W_OK)
    assert line.endswith("wake-up latency <= 0 us (PM QoS)") if granted else "refused" in line
