"""The control loop's watchdog, and the stop it makes without the loop.

:class:`LoopWatchdog` is a thread of its own, started when the motors may be on. Every
``poll`` seconds it looks at the runtime's cycle count; when no cycle completed for ``timeout``
seconds (the loop is stuck: a driver that never returns, a hung policy or controller), or a safe
stop runs past its deadline (``SafetyConfig.stop_margin`` beyond its nominal length), it calls
:meth:`~giwbc.runtimes.realtime.RealtimeRuntime.take_over`, which abandons the loop and runs an
:class:`EmergencyStop`.

:class:`EmergencyStop` does not depend on the loop or on any exchange succeeding: the damping and
exit-motor-mode frames are encoded once, up front; each bus has a sender thread of its own, so a
driver stuck in ``send`` holds up only its own bus (its motors fall back on their own timeout);
every step waits for the senders at most one period (at least ``min_wait``); the whole stop is
a fixed number of steps.
In lockstep emulation the emulator (the robot's ``peer``) is advanced and polled as the loop would.

Limits: a thread needs the interpreter lock, so a call stuck in C code *holding* it (no blocking
I/O call does) would stop the watchdog too; nothing in-process can help then, only the motors'
own timeout.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.hal.can_robot import EXIT

if TYPE_CHECKING:
    from giwbc.hal.can_robot import CanRobot
    from giwbc.hal.frames import FramePort
    from giwbc.robot.interface import ImpedanceCommand
    from giwbc.runtimes.realtime import RealtimeRuntime


class LoopWatchdog:
    """Watches a runtime's cycles from a thread of its own (see the module docstring).

    ``timeout``: seconds without a completed cycle before it takes over; ``rt_priority``: the
    loop's ``SCHED_FIFO`` priority, if any (the watchdog asks for one more, so a spinning loop
    cannot starve it)."""

    def __init__(self, runtime: RealtimeRuntime, timeout: float, *, rt_priority: int | None = None, poll: float | None = None) -> None:
        if not timeout > 0:
            raise ValueError(f"watchdog timeout must be > 0, got {timeout}")
        self.runtime = runtime
        self.timeout = float(timeout)
        # A quarter of the timeout: each wake-up takes the interpreter lock from a busy loop.
        self.poll = float(poll) if poll is not None else self.timeout / 4
        self.rt_priority = rt_priority
        self.fired: str | None = None  # why it took over, once it did
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="giwbc-watchdog", daemon=True)

    def start(self) -> LoopWatchdog:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop watching (the loop ended on its own). Never waits for a take-over in progress."""
        self._stop.set()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _serve(self) -> None:
        if self.rt_priority is not None and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(min(self.rt_priority + 1, 99)))
            except OSError:
                pass
        runtime = self.runtime
        clock = time.perf_counter
        seen, since = -1, clock()
        while not self._stop.wait(self.poll):
            now = clock()
            cycles = runtime._cycles
            if cycles != seen:
                seen, since = cycles, now
            if runtime.phase in ("idle", "off"):
                since = now  # nothing to watch (not started yet, or done)
                continue
            reason = None
            if now - since > self.timeout:
                reason = f"no control cycle for {1e3 * (now - since):.0f} ms (limit {1e3 * self.timeout:.0f} ms): the loop is stuck"
            elif runtime.stop_deadline is not None and now > runtime.stop_deadline:
                reason = f"the safe stop overran its deadline by {1e3 * (now - runtime.stop_deadline):.0f} ms"
            if reason is not None:
                self.fired = reason
                runtime.take_over(reason)
                return


class _BusSender:
    """One bus's sender thread: frames handed over go out in the background; a bus whose
    previous frames are still going (a stuck driver) is skipped."""

    def __init__(self, port: FramePort, timeout: float, retries: int, name: str) -> None:
        self.port = port
        self.timeout, self.retries = timeout, retries
        self.busy = False
        self.sent: dict[str, int] = {}  # frames sent, per tag (damping, exit)
        self.idle = threading.Event()
        self.idle.set()
        self._jobs: queue.SimpleQueue[tuple[bytes, float, str] | None] = queue.SimpleQueue()
        threading.Thread(target=self._serve, name=f"giwbc-stop-{name}", daemon=True).start()

    def submit(self, raw: bytes, budget: float, tag: str) -> bool:
        """Hand over ``raw``; it may take ``budget`` seconds from when the thread starts on it.
        False when the previous frames are still going."""
        if self.busy:
            return False
        self.busy = True
        self.idle.clear()
        self._jobs.put((raw, budget, tag))
        return True

    def close(self) -> None:
        self._jobs.put(None)

    def _serve(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            raw, budget, tag = job
            try:
                # The budget runs from now: on a loaded machine the thread may start late.
                sent, _, _, _ = self.port.send_raw(raw, time.perf_counter() + budget, self.timeout, self.retries)
                self.sent[tag] = self.sent.get(tag, 0) + sent
            except BaseException:  # noqa: BLE001 - a driver's exception is the driver's; the others go on
                pass
            finally:
                self.busy = False
                self.idle.set()


class EmergencyStop:
    """Damping, then exit motor mode, for every motor of ``robot``, without its exchange (see the
    module docstring)."""

    def __init__(self, robot: CanRobot, damping: ImpedanceCommand, *, send_timeout: float = 200e-6, retries: int = 1,
                 min_wait: float = 10e-3, final_wait: float = 0.2) -> None:  # fmt: skip
        self.robot = robot
        self.min_wait = min_wait  # s a step waits for its senders at least (a thread's wake-up on a loaded machine)
        self.final_wait = final_wait  # s the stop waits at its end for senders still going
        self.ports = list(robot.ports.ports)
        self.names = [b.name for b in robot.plan.buses]
        self.bounds = [int(b) for b in robot.codec.bounds]
        fields = np.array([damping.q_ref, damping.v_ref, damping.kp, damping.kd, damping.tau_ff], dtype=float)
        rows = robot.group.commands_to_motor(fields[:, robot.joint_index])
        self.damping_frames = robot.codec.encode_commands(*rows)[0].tobytes()
        self.exit_frames = robot.codec.special_frames(EXIT).tobytes()
        self._senders = [_BusSender(p, send_timeout, retries, n) for p, n in zip(self.ports, self.names)]

    def _step(self, raw: bytes, tag: str, t: float, wait: float) -> None:
        """Advance the lockstep peer to ``t``, hand every bus its frames, wait at most ``wait``
        seconds for them, let the peer answer."""
        peer = self.robot.peer
        if peer is not None:
            peer.advance(t)
        deadline = time.perf_counter() + wait
        size = 16
        handed = [s.submit(raw[size * a : size * b], wait, tag) for s, a, b in zip(self._senders, self.bounds[:-1], self.bounds[1:])]
        for s, ok in zip(self._senders, handed):
            if ok:
                s.idle.wait(max(0.0, deadline - time.perf_counter()))
        if peer is not None:
            peer.answer(t)

    def run(self, t0: float, period: float, damping_time: float, exit_steps: int, *, realtime: bool = True) -> dict[str, Any]:
        """Damping every period for ``damping_time``, then ``exit_steps`` periods of exit frames,
        from robot time ``t0`` on; paced by the wall clock when ``realtime``. Returns what it
        reached: the buses no exit frame reached (a stuck driver), steps, the robot time at the end."""
        clock = time.perf_counter
        start = clock()
        steps = max(1, int(round(damping_time / period)))
        exit_steps = max(1, exit_steps)
        wait = max(period, self.min_wait)
        t = t0
        for k in range(steps + exit_steps):
            if realtime:
                due = start + k * period
                if clock() < due:
                    time.sleep(due - clock())
            t = t0 + (k + 1) * period
            damping = k < steps
            self._step(self.damping_frames if damping else self.exit_frames, "damping" if damping else "exit", t, wait)
        end = clock() + self.final_wait  # senders still going (a slow thread, not a stuck driver): a last chance
        for s in self._senders:
            s.idle.wait(max(0.0, end - clock()))
        if self.robot.peer is not None:
            self.robot.peer.answer(t)
        for s in self._senders:
            s.close()
        return {
            "time": t,
            "damping_steps": steps,
            "exit_steps": exit_steps,
            "unreachable_buses": [n for n, s in zip(self.names, self._senders) if not s.sent.get("exit")],
            "frames_sent": int(sum(sum(s.sent.values()) for s in self._senders)),
        }


__all__ = ["EmergencyStop", "LoopWatchdog"]
