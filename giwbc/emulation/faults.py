"""Injected faults: what can be injected (:class:`FaultInjection`) and how the emulator applies
the motor-side ones (:class:`FaultEffects`); :mod:`giwbc.runtimes.faults` applies the host's.

Faults, per motor, within ``[start, stop)`` emulator seconds, drawn from a seeded
``numpy.random.Generator`` in a fixed order: ``drop`` or ``delay`` replies with a probability,
``corrupt`` replies (torn 1..5-byte frames: the motor's byte 0, random bytes), report an ``error``
code, ``overheat`` (extra heating until the trip), ``silent`` (no replies, still obeys), ``dead``
(no replies, limp), ``push`` (an external force on a link, to make the robot fall), ``motor_exit``
(another node sends the motors an exit-motor-mode frame, once, at ``start``: they go limp and
report state "disabled"; the host hears the frame too), foreign traffic on the motors' buses before
each poll's replies (``foreign_sync``: a CANopen SYNC, id 0x080 with no data; ``foreign_ids``: 8
random bytes from an id no motor of the bus uses; ``zero_byte``: a frame with no data from such an
id), ``duplicate`` (each reply sent twice), ``reorder`` (a poll's replies on a bus sent in reverse
order), ``encoder`` (the position reported shifted by ``offset`` rad, joint side) and
``imu_silent`` (the IMU sends nothing: no channel sample, no serial bytes, no CAN frames). The kinds in
:data:`HOST_FAULT_KINDS` act on the host (its policy, controller, bus drivers, process).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from giwbc.emulation.firmware import OVER_CURRENT, OVER_TEMPERATURE
from giwbc.hal.frames import frames, frames_of

if TYPE_CHECKING:
    from giwbc.emulation.emulator import ActuatorEmulator

EMULATOR_FAULT_KINDS = (
    "drop", "delay", "corrupt", "error", "overheat", "silent", "dead", "push",
    "motor_exit", "foreign_sync", "foreign_ids", "zero_byte", "duplicate", "reorder", "encoder", "imu_silent",
)  # fmt: skip
# Faults of the host side (policy, controller, bus drivers, the process): see giwbc.runtimes.faults.
HOST_FAULT_KINDS = (
    "policy_nan", "controller_nan", "controller_raise", "qp_infeasible", "driver_raise", "driver_block", "bus_off",
    "keyboard_interrupt", "sigint", "sigterm", "sighup",
)  # fmt: skip
FAULT_KINDS = EMULATOR_FAULT_KINDS + HOST_FAULT_KINDS
_REPLY_FAULTS = frozenset({"drop", "delay", "corrupt", "silent", "duplicate", "reorder"})
_FOREIGN_FAULTS = frozenset({"foreign_sync", "foreign_ids", "zero_byte"})
CANOPEN_SYNC_ID = 0x080


@dataclass(frozen=True)
class FaultInjection:
    """One injected fault, active for emulator time in ``[start, stop)``.

    ``joints``: the motors it affects, by joint name (None: every motor). ``probability``: per
    reply, for drop/delay/corrupt. ``delay``: seconds a delayed reply is held. ``error_code``: the
    code reported for ``error`` (default: over-current in the motor's variant). ``heat_rate``: K/s of
    extra heating for ``overheat``. ``force``/``link``: the world force (N) of a ``push``.
    ``offset``: rad (joint side) added to the reported position for ``encoder``. For foreign
    traffic, ``probability`` is per bus and poll, and ``joints`` choose the buses (theirs).
    """

    kind: str
    joints: tuple[str, ...] | None = None
    probability: float = 1.0
    start: float = 0.0
    stop: float = math.inf
    delay: float = 0.004
    error_code: int | None = None
    heat_rate: float = 50.0
    force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    link: str | None = None
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"fault probability must be in [0, 1], got {self.probability}")
        if not self.stop > self.start:
            raise ValueError(f"fault window [{self.start}, {self.stop}) is empty")
        if self.delay < 0 or self.heat_rate < 0 or not math.isfinite(self.offset):
            raise ValueError("delay and heat_rate must be >= 0, offset finite")
        if isinstance(self.joints, str):
            object.__setattr__(self, "joints", (self.joints,))

    def active(self, t: float) -> bool:
        return self.start <= t < self.stop

    @property
    def on_host(self) -> bool:
        """Whether the host applies it (policy, controller, drivers, process), not the emulator."""
        return self.kind in HOST_FAULT_KINDS


class FaultEffects:
    """The motor-side faults' effects, as methods of :class:`~giwbc.emulation.emulator.ActuatorEmulator`
    (a mixin: they read and change the emulator's firmware state, ``faults`` and ``rng``)."""

    def _update_faults(self, t: float) -> None:
        """Time-driven firmware state: over-temperature trips, injected errors, dead motors."""
        error = self.error.copy()
        tripped = (self.temperature > self.config.thermal.trip) & (error == 0)
        for i in np.flatnonzero(tripped):
            error[i] = OVER_TEMPERATURE.get(self._variant[i], 1)
        dead = np.zeros(len(self.motors), dtype=bool)
        for k, (f, motors) in enumerate(zip(self.faults, self._fault_motors)):
            if f.kind == "motor_exit" and f.active(t) and k not in self._fired:
                self._fired.add(k)
                self._foreign_exit(motors)
            if f.active(t):
                if f.kind == "error":
                    for i in np.flatnonzero(motors & (error == 0)):
                        error[i] = f.error_code if f.error_code is not None else OVER_CURRENT.get(self._variant[i], 1)
                elif f.kind == "dead":
                    dead |= motors
        if not (np.array_equal(error, self.error) and np.array_equal(dead, self.dead)):
            self.error, self.dead = error, dead
            self._apply_commands()

    def _foreign_exit(self, motors: np.ndarray) -> None:
        """Another node sends ``motors`` an exit-motor-mode frame: they leave motor mode (limp,
        state "disabled"), and the host hears the frame on their buses."""
        for i in np.flatnonzero(motors).tolist():
            b = int(self._bus_of[i])
            self._state_machine(i, "exit", (math.nan,) * 5, self.time)
            self._send(b, frames_of([self.protocols[b].exit_motor_mode(self.motors[i].can_id)]))
        self._apply_commands()

    def _foreign_traffic(self, t: float) -> None:
        """Frames from other nodes on the faults' buses, ahead of this poll's replies."""
        rng = self.rng
        for f, motors in zip(self.faults, self._fault_motors):
            if f.kind not in _FOREIGN_FAULTS or not f.active(t):
                continue
            for b in np.unique(self._bus_of[motors]).tolist():
                if rng.random() >= f.probability:
                    continue
                if f.kind == "foreign_sync":
                    batch = frames([CANOPEN_SYNC_ID], np.zeros((1, 8), dtype=np.uint8), lengths=0)
                else:
                    free = np.flatnonzero(self._motor_at[b] < 0)
                    host = self.protocols[b].host_id
                    free = free[(free != (host if host is not None else -1)) & (free != 0)]
                    length = 8 if f.kind == "foreign_ids" else 0
                    data = rng.integers(0, 256, (1, 8), dtype=np.uint8) if length else np.zeros((1, 8), dtype=np.uint8)
                    batch = frames([int(rng.choice(free))], data, lengths=length)
                self._send(b, batch)

    def _external_forces(self, t: float) -> None:
        """Pushes and the gantry, as world wrenches on bodies (set, not accumulated, every step)."""
        robot = self.robot
        wrenches = {link: np.zeros(6) for link in self._wrench_links}
        g = self.config.gantry
        if g is not None:
            wrenches.setdefault(self.description.base_link, np.zeros(6))
        for f in self.faults:
            if f.kind == "push" and f.active(t):
                wrenches[f.link][:3] += f.force  # type: ignore[index]
        if g is not None and self.description.floating_base and t < g.until:
            data, pose0 = robot.data, self._base_pose0
            force = g.stiffness * (pose0[:3] - data.qpos[:3]) - g.damping * data.qvel[:3]
            force[2] += self._weight
            # Orientation error: vector part of q0 * conj(q) (MuJoCo's w, x, y, z), world frame.
            w0, v0 = pose0[3], pose0[4:7]
            w1, v1 = data.qpos[3], -data.qpos[4:7]
            err = 2.0 * (w0 * v1 + w1 * v0 + np.cross(v0, v1))
            if w0 * w1 - v0 @ v1 < 0:
                err = -err
            torque = g.angular_stiffness * err - g.angular_damping * robot.base_state().angular_velocity
            wrenches[self.description.base_link] += np.concatenate([force, torque])
        for link, wrench in wrenches.items():
            robot.set_external_wrench(link, wrench[:3], wrench[3:])

    def _send_faulty(self: ActuatorEmulator, bus: np.ndarray, index: np.ndarray, replies: np.ndarray,
                     active: list[tuple[FaultInjection, np.ndarray]], t: float) -> None:  # fmt: skip
        """Send a poll's replies through the reply faults active now (drop, delay, corrupt,
        duplicate, reorder), drawing from ``rng`` in reply order."""
        cnt = self.counters
        rng = self.rng
        out: list[tuple[int, np.ndarray]] = []
        for b, i, reply in zip(bus.tolist(), index.tolist(), replies):
            frame = reply.reshape(1).copy()
            send = True
            copies = 1
            for f, m in active:
                if not m[i] or f.kind in ("silent", "reorder"):
                    continue
                if f.kind == "duplicate" and rng.random() < f.probability:
                    copies = 2
                    continue
                if f.kind == "drop" and rng.random() < f.probability:
                    cnt.dropped[i] += 1
                    send = False
                    break
                if f.kind == "corrupt" and rng.random() < f.probability:
                    cnt.corrupted[i] += 1  # the motor's byte 0, then 0..4 random bytes: a torn reply
                    length = int(rng.integers(1, 6))
                    frame["len"] = length
                    frame["data"][0, 1:] = 0
                    frame["data"][0, 1:length] = rng.integers(0, 256, length - 1, dtype=np.uint8)
                elif f.kind == "delay" and rng.random() < f.probability:
                    cnt.delayed[i] += 1
                    cnt.replies[i] += 1
                    self._delayed.append((t + f.delay, b, frame))
                    send = False
                    break
            if send:
                out.extend([(b, frame)] * copies)
                cnt.replies[i] += 1
        for f, m in active:  # reversed per bus: the buses of the motors the fault names
            if f.kind == "reorder":
                for b in np.unique(self._bus_of[m]).tolist():
                    at = [k for k, (bb, _) in enumerate(out) if bb == b]
                    for k, frame in zip(at, [out[k][1] for k in reversed(at)]):
                        out[k] = (b, frame)
        for b, frame in out:
            self._send(b, frame)


__all__ = ["CANOPEN_SYNC_ID", "EMULATOR_FAULT_KINDS", "FAULT_KINDS", "HOST_FAULT_KINDS", "FaultEffects", "FaultInjection"]
