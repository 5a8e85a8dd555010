"""The hardware side of ``giwbc deploy`` beyond the motors: which IMU a rehearsal imitates, the
SocketCAN pre-flight, the first-run (gantry) limits, and the IMU driver's counters at the end.
Kept apart from :mod:`giwbc.apps.deploy` so that the procedure there stays readable."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from giwbc.emulation import EmulatorConfig, Gantry
from giwbc.errors import DeployError, HardwareConfigError
from giwbc.hal.bringup import FirstRunLimits
from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.imu import rehearsal_imu
from giwbc.hal.preflight import preflight
from giwbc.hal.safety import SafetyConfig


def choose_imu(plan: HardwarePlan, source: str | None, emulate: bool, emulator_mode: str) -> HardwarePlan:
    """The plan with the IMU a rehearsal imitates (``--imu``); DeployError for a combination that
    cannot run."""
    if source is not None:
        if not emulate:
            raise DeployError("--imu chooses the IMU device the emulator imitates (--emulate); on hardware the plan's [imu] decides")
        try:
            plan = plan.with_imu(rehearsal_imu(plan, source))
        except (HardwareConfigError, ValueError) as error:
            raise DeployError(str(error)) from error
    if emulate and emulator_mode == "process" and plan.imu.source != "emulated":
        raise DeployError(f"a {plan.imu.source} IMU is emulated with the lockstep emulator only (--emulator lockstep, or --imu emulated)")
    return plan


def check_interfaces(plan: HardwarePlan, say: Callable[[str], None]) -> None:
    """The SocketCAN pre-flight of the plan's ``socketcan`` buses; DeployError when it fails."""
    if not any(b.interface == "socketcan" for b in plan.buses):
        return
    report = preflight(plan)
    say(str(report))
    if not report.ok:
        raise DeployError("SocketCAN pre-flight failed: run the commands above (or --no-preflight to skip the check)")


def first_run_settings(safety: SafetyConfig | None, say: Callable[[str], None]) -> tuple[FirstRunLimits, SafetyConfig]:
    """The gantry limits and the supervisor's thresholds tightened by them."""
    limits = FirstRunLimits()
    tight = limits.safety(safety or SafetyConfig())
    say(f"first run (gantry): torque x{limits.torque_fraction:g}, gains x{limits.gain_fraction:g}, "
        f"tilt limit {tight.max_tilt:g} rad, joint limits {tight.soft_limit_margin:g} rad inside")  # fmt: skip
    return limits, tight


def with_gantry(config: EmulatorConfig) -> EmulatorConfig:
    """An emulator configuration whose robot hangs on a gantry for the whole run."""
    return config if config.gantry is not None else replace(config, gantry=Gantry(until=math.inf))


def on_channels(plan: HardwarePlan, like: HardwarePlan) -> HardwarePlan:
    """``plan`` (its motors, signs and offsets) on the emulator's buses and IMU device (``like``)."""
    chan = {b.name: (b.interface, b.channel) for b in like.buses}
    buses = tuple(replace(b, interface=chan[b.name][0], channel=chan[b.name][1]) for b in plan.buses)
    return replace(plan, buses=buses, imu=like.imu)


def imu_counters(imu: Any) -> dict[str, int] | None:
    """What a serial or CAN IMU driver counted (None for the emulator's channel)."""
    counters = getattr(imu, "counters", None)
    if counters is None:
        return None
    return dict(counters.as_dict() if hasattr(counters, "as_dict") else counters)


__all__ = ["check_interfaces", "choose_imu", "first_run_settings", "imu_counters", "on_channels", "with_gantry"]
