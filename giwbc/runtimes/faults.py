"""Fault injection on the host side of a deployment, and the fault table's catalogue.

:class:`~giwbc.emulation.faults.FaultInjection` names every fault; the emulator applies those of
the motors and their buses, :class:`HostFaults` those of the host (``HOST_FAULT_KINDS``), each
active in ``[start, stop)`` of robot time:

- ``policy_nan``: the policy's action is NaN (wraps the policy);
- ``controller_nan``: the controller's command is NaN (after the task's controller tick);
- ``controller_raise``: the controller tick raises ``ZeroDivisionError``;
- ``qp_infeasible``: the whole-body controller's QP is made infeasible (an inequality row with
  ``l > u``) before its real solver sees it, so the WBC takes its fallback;
- ``keyboard_interrupt``: the controller tick raises ``KeyboardInterrupt`` (inside the loop);
- ``sigint`` / ``sigterm`` / ``sighup``: the signal is sent once, to the loop's own thread (a process-directed
  signal may land on any thread; this one makes the delivery cycle exact);
- ``driver_raise``, ``driver_block``, ``bus_off``: the python-can driver of the buses of the
  fault's joints (:class:`FaultyBus`) raises ``RuntimeError`` in ``send`` (a driver bug), blocks
  in ``send`` until released (a stuck driver), or refuses every frame with
  ``can.CanOperationError`` and reads nothing (a bus in bus-off).

:data:`FAULT_CASES` is the fault table: each kind once, with what must happen (the fault kind
that stops the run, or None for traffic that must be counted and tolerated), used by the tests
and by ``giwbc deploy --emulate --fault KIND``.
"""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import can
import numpy as np

from giwbc.hal.bus import CanBusLink
from giwbc.emulation import HOST_FAULT_KINDS, FaultInjection
from giwbc.hal.hardware import HardwarePlan
from giwbc.hal.safety import FaultKind
from giwbc.robot.interface import ImpedanceCommand

DRIVER_KINDS = frozenset({"driver_raise", "driver_block", "bus_off"})
TASK_KINDS = frozenset({"controller_nan", "controller_raise", "keyboard_interrupt", "sigint", "sigterm", "sighup"})
_SIGNALS = {"sigint": signal.SIGINT, "sigterm": signal.SIGTERM, "sighup": signal.SIGHUP}


class InjectedFault(ZeroDivisionError):
    """The exception an injected ``controller_raise`` raises."""


class FaultyBus(can.BusABC):
    """A python-can bus whose driver misbehaves while one of ``faults`` is active (``clock``:
    robot time). :meth:`release` lets a blocked ``send`` return (test clean-up)."""

    def __init__(self, bus: can.BusABC, faults: Sequence[FaultInjection], clock: Callable[[], float]) -> None:
        self._bus = bus
        self._faults = tuple(faults)
        self._clock = clock
        self._released = threading.Event()
        self.channel_info = f"faulty {getattr(bus, 'channel_info', 'bus')}"
        self.blocked = 0  # sends that blocked
        super().__init__(channel=getattr(bus, "channel", None) or "faulty")

    def _active(self) -> str | None:
        t = self._clock()
        for f in self._faults:
            if f.active(t):
                return f.kind
        return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        kind = self._active()
        if kind == "driver_raise":
            raise RuntimeError("injected driver bug: send() raised")
        if kind == "bus_off":
            raise can.CanOperationError("Network is down (injected bus-off)", error_code=100)
        if kind == "driver_block":
            self.blocked += 1
            self._released.wait()  # forever, unless released
            raise can.CanOperationError("released after blocking")
        self._bus.send(msg, timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._active() == "bus_off":
            return None
        return self._bus.recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:  # pragma: no cover - recv is overridden
        return self._bus.recv(timeout), False

    def release(self) -> None:
        self._released.set()

    def shutdown(self) -> None:
        self.release()
        super().shutdown()
        self._bus.shutdown()


class InfeasibleQp:
    """A QP solver wrapper that makes the problem infeasible while ``active()`` (one inequality
    row's lower bound above its upper bound), then lets the real solver answer it."""

    def __init__(self, solver: Any, active: Callable[[], bool]) -> None:
        self._solver = solver
        self._active = active
        self.injected = 0

    def solve(self, problem: Any) -> Any:
        if self._active():
            self.injected += 1
            problem = problem.copy()
            if problem.n_in:
                problem.l[0] = problem.u[0] + 1.0
            else:
                problem.lb, problem.ub = np.zeros(problem.n), np.full(problem.n, -1.0)
        return self._solver.solve(problem)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._solver, name)


def find_wbc(task: Any) -> Any:
    """The whole-body controller of a deployment task (stand with ``wbc``, balance with ``wbc``)."""
    balance = getattr(getattr(task, "controller", None), "balance", None)
    wbc = getattr(balance, "wbc", None)
    if wbc is None:
        raise ValueError("qp_infeasible needs a task run by the whole-body controller (--controller wbc)")
    return wbc


class HostFaults:
    """The host-side faults of a deployment (see the module docstring)."""

    def __init__(self, faults: Sequence[FaultInjection]) -> None:
        self.faults = tuple(f for f in faults if f.on_host)
        self.buses: list[FaultyBus] = []
        self.onsets: dict[str, float] = {}  # robot time at which each controller or policy fault first acted
        self._signalled: set[int] = set()

    def __bool__(self) -> bool:
        return bool(self.faults)

    def _of(self, kinds: frozenset[str] | set[str]) -> list[FaultInjection]:
        return [f for f in self.faults if f.kind in kinds]

    def links(self, plan: HardwarePlan, clock: Callable[[], float]) -> list[CanBusLink] | None:
        """The plan's links, the buses of driver faults wrapped in :class:`FaultyBus` (None when
        there are none)."""
        driver = self._of(DRIVER_KINDS)
        if not driver:
            return None
        links = []
        for bus in plan.buses:
            link = bus.open_link()
            joints = {m.joint for m in bus.motors}
            mine = [f for f in driver if f.joints is None or joints & set(f.joints)]
            if mine:
                faulty = FaultyBus(link.bus, mine, clock)
                self.buses.append(faulty)
                link = CanBusLink(faulty, link.protocol, name=link.name, send_timeout=link.send_timeout, max_retries=link.max_retries)
            links.append(link)
        return links

    def wrap_task(self, task: Any, robot: Any) -> None:
        """Controller faults: around the task's controller tick (and in its WBC's solver)."""
        for f in self._of({"qp_infeasible"}):
            wbc = find_wbc(task)
            def active(f: FaultInjection = f) -> bool:
                on = f.active(robot.time())
                if on:
                    self.onsets.setdefault(f.kind, robot.time())
                return on

            wbc.solver = InfeasibleQp(wbc.solver, active)
        faults = self._of(TASK_KINDS)
        if not faults:
            return
        inner = task.apply_command

        def apply_command() -> None:
            t = robot.time()
            active = [f for f in faults if f.active(t)]
            for f in active:
                self.onsets.setdefault(f.kind, t)
                if f.kind == "keyboard_interrupt":
                    raise KeyboardInterrupt
                if f.kind == "controller_raise":
                    raise InjectedFault("injected controller fault")
                if f.kind in _SIGNALS and id(f) not in self._signalled:
                    self._signalled.add(id(f))
                    signal.pthread_kill(threading.get_ident(), _SIGNALS[f.kind])
            inner()
            if any(f.kind == "controller_nan" for f in active):
                n = robot.dofs
                nan = np.full(n, math.nan)
                robot.set_joint_impedance(ImpedanceCommand(robot.joint_positions(), np.zeros(n), np.zeros(n), np.zeros(n), nan))

        task.apply_command = apply_command

    def wrap_policy(self, policy: Callable[[np.ndarray], np.ndarray] | None, robot: Any) -> Callable[[np.ndarray], np.ndarray] | None:
        faults = self._of({"policy_nan"})
        if not faults or policy is None:
            return policy

        def faulty(observation: np.ndarray) -> np.ndarray:
            action = np.asarray(policy(observation), dtype=np.float32)
            if any(f.active(robot.time()) for f in faults):
                self.onsets.setdefault("policy_nan", robot.time())
                action = np.full_like(action, np.nan)
            return action

        return faulty

    def release(self) -> None:
        """Let blocked drivers return (clean-up after a ``driver_block`` run)."""
        for bus in self.buses:
            bus.release()


# ----------------------------------------------------------------------------- the fault table
TARGET_JOINT = "left_knee_joint"  # on the G1's bus can1


@dataclass(frozen=True)
class FaultCase:
    """One row of the fault table: how to inject it and what must happen.

    ``expected``: the fault kind that stops the run (None: tolerated traffic, counted, exit 0);
    ``bound``: cycles from onset to detection at most (2; reply loss and corrupt frames need
    ``max_missing_cycles`` / ``max_corrupt_frames`` = 3 cycles, i.e. onset + 2; the watchdog
    counts wall time, ``watchdog_periods`` periods (unpaced: at least 1 s), its robot-time bound is 1 cycle); ``needs``:
    ``"policy"`` (the balance task with a policy) or ``"wbc"`` (the whole-body controller);
    ``stuck_bus``: the fault leaves one bus unreachable (its motors fall back on their own timeout)."""

    kind: str
    make: Callable[[float], tuple[FaultInjection, ...]]
    expected: FaultKind | None
    description: str
    bound: int = 2
    needs: str | None = None
    stuck_bus: bool = False

    def injections(self, onset: float) -> tuple[FaultInjection, ...]:
        return self.make(onset)


def _one(kind: str, **options: Any) -> Callable[[float], tuple[FaultInjection, ...]]:
    return lambda onset: (FaultInjection(kind, start=onset, **options),)


_knee = (TARGET_JOINT,)
FAULT_CASES: dict[str, FaultCase] = {c.kind: c for c in (
    FaultCase("policy_nan", _one("policy_nan"), FaultKind.NONFINITE_POLICY, "the policy outputs NaN", needs="policy"),
    FaultCase("controller_nan", _one("controller_nan"), FaultKind.NONFINITE_COMMAND, "the controller outputs NaN"),
    FaultCase("qp_infeasible", _one("qp_infeasible"), FaultKind.CONTROLLER_FAILED, "the WBC's QP is infeasible", needs="wbc"),
    FaultCase("controller_raise", _one("controller_raise"), FaultKind.CONTROLLER_ERROR, "the controller raises"),
    FaultCase("driver_raise", _one("driver_raise", joints=_knee), FaultKind.DRIVER_ERROR, "can1's driver raises RuntimeError in send",
              stuck_bus=True),
    FaultCase("driver_block", _one("driver_block", joints=_knee), FaultKind.WATCHDOG, "can1's driver blocks in send forever",
              bound=1, stuck_bus=True),
    FaultCase("bus_off", _one("bus_off", joints=_knee), FaultKind.BUS_OFF, "can1 in bus-off: every send refused", stuck_bus=True),
    FaultCase("motor_exit", _one("motor_exit", joints=_knee), FaultKind.MOTOR_DISABLED, "another node sends exit-motor-mode to the knee"),
    FaultCase("reply_loss", _one("drop", joints=_knee), FaultKind.MISSING_REPLIES, "the knee stops replying"),
    FaultCase("corrupt_replies", _one("corrupt", joints=_knee), FaultKind.CORRUPT_FRAMES, "the knee's replies are torn"),
    FaultCase("motor_error", _one("error", joints=_knee), FaultKind.MOTOR_ERROR, "the knee reports over-current"),
    FaultCase("joint_limit", _one("encoder", joints=_knee, offset=-3.0), FaultKind.JOINT_LIMIT, "the knee reads beyond its limit"),
    FaultCase("keyboard_interrupt", _one("keyboard_interrupt"), FaultKind.INTERRUPTED, "KeyboardInterrupt raised in the loop"),
    FaultCase("sigint", _one("sigint"), FaultKind.SIGNAL, "SIGINT"),
    FaultCase("sigterm", _one("sigterm"), FaultKind.SIGNAL, "SIGTERM"),
    FaultCase("sighup", _one("sighup"), FaultKind.SIGNAL, "SIGHUP (the operator's terminal went away)"),
    FaultCase("foreign_sync", _one("foreign_sync"), None, "a CANopen SYNC on every bus, every cycle"),
    FaultCase("foreign_ids", _one("foreign_ids"), None, "8-byte frames from ids no motor uses, every cycle"),
    FaultCase("zero_byte", _one("zero_byte"), None, "zero-byte frames from ids no motor uses, every cycle"),
    FaultCase("duplicate_replies", _one("duplicate"), None, "every reply arrives twice"),
    FaultCase("reordered_replies", _one("reorder"), None, "each bus's replies arrive in reverse order"),
)}  # fmt: skip


def fault_case(kind: str) -> FaultCase:
    """The table's row for ``kind`` (ValueError naming the known kinds)."""
    try:
        return FAULT_CASES[kind]
    except KeyError:
        raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULT_CASES)}") from None


def shifted(faults: Sequence[FaultInjection], by: float) -> tuple[FaultInjection, ...]:
    """``faults`` with their windows moved ``by`` seconds later."""
    return tuple(replace(f, start=f.start + by, stop=f.stop + by) for f in faults)


__all__ = [
    "DRIVER_KINDS",
    "FAULT_CASES",
    "HOST_FAULT_KINDS",
    "FaultCase",
    "FaultyBus",
    "HostFaults",
    "InfeasibleQp",
    "InjectedFault",
    "fault_case",
    "find_wbc",
    "shifted",
]
