"""What ``giwbc deploy`` says about a fault: one bounded line (:func:`fault_summary`) and, for an
emulated run stopped on timing or missing replies on an overloaded host, that the host was the
cause and what to do (:func:`overload_note`).

Why: an emulated deploy beside busy processes stopped on ``missing_replies`` naming all 29 joints
in one 1.3 kB line, or on ``timing`` ("cycle started 365.5 ms after its deadline"); both read as a
robot or wiring fault, while the emulator (lockstep: the loop's own thread; process: a process
beside it) simply got no CPU in time. The full fault stays in the run log (``/faults``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.safety import Fault, FaultKind

MAX_NAMES = 3  # joints named per bus in a summary
MAX_MESSAGE = 300  # characters of a fault's own message in the summary line
HOST_FAULTS = (FaultKind.TIMING, FaultKind.MISSING_REPLIES)  # what an overloaded host shows as on the emulator
OVERRUN_SHARE = 0.01  # a run with more overrunning cycles than this share was starved of CPU
WORK_OVER_CPU = 2.0  # ... or whose slowest cycles took this many times their own CPU time (waiting for a CPU)
STALL_PERIODS = 2.0  # an emulator process that ran this many periods late was not given a CPU (its own work is < 1 period)


def _joints_by_bus(joints: Sequence[str], plan: HardwarePlan | None) -> str:
    """``N of M joints on K of B buses (every motor on can0, can1; can4 a, b +2 more)``: buses
    whose every motor is in ``joints`` named alone, the others' joints (at most :data:`MAX_NAMES` each)."""
    more = lambda names: ", ".join(names[:MAX_NAMES]) + (f" +{len(names) - MAX_NAMES} more" if len(names) > MAX_NAMES else "")  # noqa: E731
    if plan is None:
        return f"{len(joints)} joint(s): {more(list(joints))}"
    groups: dict[str, list[str]] = {}
    for joint in joints:
        try:
            bus = plan.motor(joint)[0].name
        except KeyError:
            bus = "?"
        groups.setdefault(bus, []).append(joint)
    sizes = {b.name: len(b.motors) for b in plan.buses}
    groups = {bus: groups[bus] for bus in [*sizes, "?"] if bus in groups}  # the plan's bus order
    whole = [bus for bus, names in groups.items() if len(names) == sizes.get(bus, -1)]
    parts = [f"every motor on {', '.join(whole)}"] if whole else []
    parts += [f"{bus} {more(names)}" for bus, names in groups.items() if bus not in whole]
    return f"{len(joints)} of {len(plan.joints)} joints on {len(groups)} of {len(plan.buses)} buses ({'; '.join(parts)})"


def fault_summary(fault: Fault | None, plan: HardwarePlan | None = None) -> str:
    """One line of bounded length for a person: the fault's kind, cycle and time, and its message
    (its first line, at most :data:`MAX_MESSAGE` characters); for a fault on many joints (missing
    replies, ...) the joints counted and grouped by bus, a few named each."""
    if fault is None:
        return "no fault"
    head = f"{fault.kind.value} at cycle {fault.cycle} (t = {fault.time:.3f} s)"
    if len(fault.joints) > MAX_NAMES:
        detail = fault.message.split(":", 1)[0]  # "no valid reply for >= 3 cycles"
        return f"{head}: {detail}: {_joints_by_bus(list(fault.joints), plan)}"
    message = fault.message.strip().splitlines()[0] if fault.message.strip() else ""
    if len(message) > MAX_MESSAGE or "\n" in fault.message.strip():
        message = message[:MAX_MESSAGE].rstrip() + " ... (whole message in the run log)"
    return f"{head}: {message}"


def load_average() -> tuple[float, int] | None:
    """The host's 1-minute load average and its CPUs (None where the platform has none)."""
    try:
        return os.getloadavg()[0], os.cpu_count() or 1
    except (AttributeError, OSError):
        return None


def overload_evidence(timing: Mapping[str, Any], load: tuple[float, int] | None, stalls: Any = None) -> list[str]:
    """What says the host could not give the loop (and the emulator) its CPU: the emulator process
    running more than :data:`STALL_PERIODS` periods after its physics step was due (``stalls``,
    :class:`~giwbc.emulation.process.EmulatorStalls`: measured, the strongest evidence), more
    runnable processes than CPUs, overrunning cycles, skipped slots, cycles whose wall time far
    exceeded their CPU time (the thread waited for a CPU)."""
    evidence = []
    period = float(timing.get("period_us") or 0.0) * 1e-6
    if stalls is not None and period > 0 and stalls.longest > STALL_PERIODS * period:
        evidence.append(f"the emulator process ran {stalls.longest * 1e3:.1f} ms after its physics step was due, at t = {stalls.at:.2f} s, "
                        f"{stalls.over_period} time(s) more than a period late")  # fmt: skip
    if load is not None and load[0] >= load[1]:
        evidence.append(f"load average {load[0]:.1f} on {load[1]} CPUs")
    cycles = max(int(timing.get("cycles") or 0), 1)
    overruns, skipped = int(timing.get("overruns") or 0), int(timing.get("skipped_slots") or 0)
    if overruns > OVERRUN_SHARE * cycles:
        evidence.append(f"{overruns} of {cycles} cycles overran")
    if skipped:
        evidence.append(f"{skipped} slots skipped")
    work, cpu = (timing.get("work_us") or {}).get("max"), (timing.get("cpu_us") or {}).get("max")
    if work and cpu and work > WORK_OVER_CPU * cpu and work > float(timing.get("period_us") or 0.0):
        evidence.append(f"the slowest cycle took {work / 1e3:.1f} ms of wall time, no cycle more than {cpu / 1e3:.1f} ms of CPU")
    return evidence


def overload_note(emulated: bool, result: Any, load: tuple[float, int] | None, stalls: Any = None) -> str | None:
    """For an emulated run stopped on timing or missing replies with evidence of an overloaded
    host (``stalls``: the emulator process's, when it ran in one): the evidence and what to do;
    None otherwise (on real motors such a fault is the robot's or the bus's until shown otherwise)."""
    fault = getattr(result, "fault", None)
    if not emulated or fault is None or fault.kind not in HOST_FAULTS:
        return None
    evidence = overload_evidence(result.timing, load, stalls)
    if not evidence:
        return None
    return (f"The host looked overloaded ({', '.join(evidence)}): the emulator got no CPU in time, which is not a robot fault. "
            "Retry with fewer other processes running, --emulator lockstep (one thread), or --unpaced (lockstep, in the "
            "emulator's time)")  # fmt: skip


__all__ = ["fault_summary", "load_average", "overload_evidence", "overload_note"]
