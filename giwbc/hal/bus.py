"""One CAN bus in the control loop, and the bus capacity planner.

:class:`CanBusLink` wraps one python-can ``BusABC`` (moved in batches by its
:class:`~giwbc.hal.frames.FramePort`) and one :class:`ActuatorProtocol`. Everything runs in the
caller's thread against absolute ``time.perf_counter()`` deadlines (no ``Notifier`` thread that
could die silently): :meth:`CanBusLink.send` never raises on a full transmit buffer or a driver
error (it retries a bounded number of times, then counts the frame as dropped), and
:meth:`CanBusLink.receive` returns at the deadline at the latest, with the newest reply per motor.

Capacity: per motor and cycle, one command and one reply frame cross the bus. A classic frame with
an 11-bit id and ``d`` data bytes is ``47 + 8 d`` bits nominal (111 for 8 bytes), and bit stuffing
adds up to ``floor((34 + 8 d - 1) / 4)`` more (135 for 8 bytes). A plan is accepted when its
nominal load is at most ``max_load`` (default 80 %: headroom for retransmissions, error frames,
other traffic) *and* its worst-case load (every frame maximally stuffed) is at most 100 %.
"""

from __future__ import annotations

import math
import time
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import can
import numpy as np

from giwbc.hal.kernels import warm_up as warm_up_kernels
from giwbc.hal.frames import FRAME, Received, frame_port, frames, frames_of
from giwbc.hal.protocols.base import (
    ActuatorProtocol,
    CanFrame,
    CommandBatch,
    DecodedReplies,
    FrameTraffic,
    MotorReply,
)
from giwbc.errors import BusCapacityError

DEFAULT_MAX_LOAD = 0.8
CLASSIC_CAN_MAX_BITRATE = 1_000_000


# --------------------------------------------------------------------------- capacity
def frame_bits(data_bytes: int, *, extended_id: bool = False, worst_case: bool = False) -> int:
    """Bit times of one classic CAN data frame, interframe space included.

    Nominal: SOF, id, control, data, CRC, delimiters, ACK, EOF, 3-bit IFS (111 for 8 bytes, 11-bit
    id). ``worst_case`` adds the maximum number of stuff bits (135 for 8 bytes, 11-bit id).
    """
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN frames carry 0..8 data bytes, got {data_bytes}")
    stuffed = (54 if extended_id else 34) + 8 * data_bytes  # SOF..CRC: the bits subject to stuffing
    nominal = stuffed + 13  # CRC delimiter 1, ACK 2, EOF 7, IFS 3
    return nominal + ((stuffed - 1) // 4 if worst_case else 0)


@dataclass(frozen=True, slots=True)
class BusLoad:
    """Traffic of one bus per control cycle and the resulting utilisation (fractions, 1.0 = full)."""

    bus: str
    bitrate: int
    rate_hz: float
    n_motors: int
    bits_nominal: int  # per cycle
    bits_worst: int  # per cycle

    @property
    def nominal(self) -> float:
        return self.bits_nominal * self.rate_hz / self.bitrate

    @property
    def worst_case(self) -> float:
        return self.bits_worst * self.rate_hz / self.bitrate

    def __str__(self) -> str:
        return (
            f"bus {self.bus!r}: {self.n_motors} motors at {self.rate_hz:g} Hz on {self.bitrate} bit/s: "
            f"load {100 * self.nominal:.1f}% nominal, {100 * self.worst_case:.1f}% worst-case with bit stuffing"
        )


def bus_load(
    bitrate: int,
    n_motors: int,
    rate_hz: float,
    *,
    command_bytes: int = 8,
    reply_bytes: int | Sequence[int] = 8,
    extended_id: bool = False,
    name: str = "bus",
) -> BusLoad:
    """Load of ``n_motors`` motors exchanging one command and one reply per cycle at ``rate_hz``.

    ``reply_bytes`` may be one length for all motors or one per motor.
    """
    replies = [reply_bytes] * n_motors if isinstance(reply_bytes, int) else list(reply_bytes)
    if len(replies) != n_motors:
        raise ValueError(f"{len(replies)} reply lengths for {n_motors} motors")
    traffic = [FrameTraffic(command_bytes, r, extended_id) for r in replies]
    return traffic_load(traffic, bitrate, rate_hz, name=name)


def traffic_load(traffic: Sequence[FrameTraffic], bitrate: int, rate_hz: float, *, name: str = "bus") -> BusLoad:
    """Load of per-motor traffic (one command and one reply each per cycle)."""
    if not (isinstance(bitrate, int) and 0 < bitrate <= CLASSIC_CAN_MAX_BITRATE):
        raise ValueError(f"bus {name!r}: bitrate must be an integer in 1..{CLASSIC_CAN_MAX_BITRATE}, got {bitrate!r}")
    if not rate_hz > 0:
        raise ValueError(f"control rate must be > 0 Hz, got {rate_hz}")
    nominal = worst = 0
    for t in traffic:
        for d in (t.command_bytes, t.reply_bytes):
            nominal += frame_bits(d, extended_id=t.extended_id)
            worst += frame_bits(d, extended_id=t.extended_id, worst_case=True)
    return BusLoad(name, bitrate, float(rate_hz), len(traffic), nominal, worst)


def check_capacity(load: BusLoad, max_load: float = DEFAULT_MAX_LOAD) -> BusLoad:
    """``load`` if it fits (nominal <= max_load and worst case <= 100 %), else BusCapacityError."""
    problem = capacity_problem(load, max_load)
    if problem:
        raise BusCapacityError(problem)
    return load


def capacity_problem(load: BusLoad, max_load: float = DEFAULT_MAX_LOAD) -> str | None:
    """Why ``load`` does not fit, or None."""
    if not 0 < max_load <= 1:
        raise ValueError(f"max_load must be in (0, 1], got {max_load}")
    if load.nominal <= max_load and load.worst_case <= 1.0:
        return None
    return (
        f"bus {load.bus!r} over capacity at {load.rate_hz:g} Hz: load {100 * load.nominal:.1f}% nominal, "
        f"{100 * load.worst_case:.1f}% worst-case with bit stuffing ({load.n_motors} motors, {load.bitrate} bit/s); "
        f"limit {100 * max_load:.0f}% nominal and 100% worst-case"
    )


@dataclass(frozen=True, slots=True)
class BusPlanSpec:
    """What the planner needs to know about one bus."""

    name: str
    bitrate: int
    traffic: tuple[FrameTraffic, ...]
    max_load: float = DEFAULT_MAX_LOAD
    extra_bits: tuple[int, int] = (0, 0)  # per cycle, nominal and worst case: other periodic frames (a CAN IMU)


def plan_bus_loads(buses: Iterable[BusPlanSpec], rate_hz: float) -> dict[str, BusLoad]:
    """Loads of all buses at ``rate_hz``; BusCapacityError listing every bus over its limit."""
    loads: dict[str, BusLoad] = {}
    problems: list[str] = []
    for b in buses:
        load = traffic_load(b.traffic, b.bitrate, rate_hz, name=b.name)
        if b.extra_bits != (0, 0):
            load = replace(load, bits_nominal=load.bits_nominal + b.extra_bits[0], bits_worst=load.bits_worst + b.extra_bits[1])
        loads[b.name] = load
        problem = capacity_problem(load, b.max_load)
        if problem:
            problems.append(problem)
    if problems:
        raise BusCapacityError("; ".join(problems))
    return loads


# --------------------------------------------------------------------------- link
@dataclass(frozen=True, slots=True)
class LinkCounters:
    """Counts since the link was opened. ``errors`` are CAN error frames seen on the bus,
    ``bus_errors`` exceptions raised by the python-can driver (send or receive)."""

    sent: int = 0
    dropped: int = 0  # frames given up: send failed after retries, or their deadline had passed
    retries: int = 0
    received: int = 0  # valid replies decoded
    errors: int = 0
    unknown: int = 0  # frames from no configured motor (unknown id, foreign, remote frames)
    corrupt: int = 0  # frames for us that could not be decoded (length, content)
    bus_errors: int = 0


# Columns of a link's counter row (LinkCounters' field order): a robot driving several links keeps
# their rows in one array and updates them all in one operation per cycle.
SENT, DROPPED, RETRIES, RECEIVED, ERRORS, UNKNOWN, CORRUPT, BUS_ERRORS = range(8)
# Verdict (REPLY, UNKNOWN, CORRUPT, ERROR_FRAME) -> counter column.
VERDICT_COLUMNS = np.array([RECEIVED, UNKNOWN, CORRUPT, ERRORS], dtype=np.int64)


@dataclass(frozen=True, slots=True)
class ReceiveResult:
    """What one :meth:`CanBusLink.receive` call collected: the newest reply per motor id, the
    expected motors that did not reply, and a snapshot of the link's counters."""

    replies: dict[int, MotorReply]
    missing: tuple[int, ...]
    counters: LinkCounters

    @property
    def complete(self) -> bool:
        return not self.missing


class CanBusLink:
    """One python-can bus driven by one actuator protocol, from the control loop's thread.

    ``send_timeout``: how long one frame may wait for room in the transmit queue (further capped by
    the call's deadline); ``max_retries``: extra attempts per frame after a failed one before the
    frame is dropped. ``port``: how frames cross (default: :func:`~giwbc.hal.frames.frame_port`).
    """

    def __init__(
        self,
        bus: can.BusABC,
        protocol: ActuatorProtocol,
        *,
        name: str = "",
        send_timeout: float = 200e-6,
        max_retries: int = 2,
    ) -> None:
        if send_timeout < 0 or max_retries < 0:
            raise ValueError("send_timeout and max_retries must be >= 0")
        self.bus = bus
        self.port = frame_port(bus)
        self.protocol = protocol
        self.name = name or str(getattr(bus, "channel_info", "can"))
        self.send_timeout = float(send_timeout)
        self.max_retries = int(max_retries)
        self.counts = np.zeros(8, dtype=np.int64)  # see LinkCounters; a robot may replace it by a row of its own array
        # The reply decode's compiled kernel ready now (compiled once per machine, ~1 s without numba's cache;
        # then loaded or already in memory): a protocol builds its decoder at its first receive, inside a deadline.
        warm_up_kernels()

    @property
    def counters(self) -> LinkCounters:
        """A snapshot of the counters."""
        return LinkCounters(*self.counts.tolist())

    # ------------------------------------------------------------------ send
    def send(self, batch: Sequence[CanFrame] | CommandBatch | np.ndarray, deadline: float | None = None) -> int:
        """Send frames in order; returns how many went out. Never raises for driver errors.

        ``batch``: :data:`~giwbc.hal.frames.FRAME` records, a :class:`CommandBatch` or
        :class:`CanFrame` objects. A frame whose send fails is retried up to ``max_retries`` times,
        then dropped. Each attempt waits at most ``send_timeout`` and never past ``deadline``
        (absolute ``time.perf_counter()`` seconds); frames still unsent at the deadline are all
        counted as dropped, so the call returns at the deadline at the latest (plus one driver call).
        """
        if isinstance(batch, CommandBatch):
            batch = frames(batch.arbitration_ids, batch.data, extended=batch.is_extended_id)
        elif not (isinstance(batch, np.ndarray) and batch.dtype == FRAME):
            batch = frames_of(batch)
        outcome = self.port.send(batch, math.inf if deadline is None else deadline, timeout=self.send_timeout, retries=self.max_retries)
        self.counts[[SENT, DROPPED, RETRIES, BUS_ERRORS]] += (outcome.sent, outcome.dropped, outcome.retries, outcome.errors)
        return outcome.sent

    # --------------------------------------------------------------- receive
    def receive_frames(self, deadline: float | None = None, limit: int | None = None) -> Received:
        """Frames until ``deadline`` (None: those already waiting) or ``limit`` of them, undecoded;
        a driver error ends the read (counted, and in the result)."""
        received = self.port.receive(deadline, limit)
        self.counts[UNKNOWN] += received.skipped
        self.counts[BUS_ERRORS] += received.error is not None
        return received

    def tally(self, decoded: DecodedReplies) -> None:
        """Count decoded frames by verdict (valid replies, unknown, corrupt, error frames)."""
        np.add.at(self.counts, VERDICT_COLUMNS[decoded.verdict], 1)

    def receive(self, deadline: float, expect: Collection[int] | None = None) -> ReceiveResult:
        """Collect replies until every expected motor has replied or ``deadline`` passes.

        ``deadline`` is absolute ``time.perf_counter()`` seconds; ``expect`` the motor ids awaited
        (default: all motors of the protocol; empty: collect until the deadline). Error frames,
        frames for unknown ids and undecodable frames are counted and skipped. A driver error ends
        the call early (counted), rather than spinning until the deadline.
        """
        expected = set(self.protocol.index) if expect is None else set(expect)
        replies: dict[int, MotorReply] = {}
        done = False
        while True:
            # Once all replied, the frames already waiting are read too: a reply's newest copy counts.
            waiting = None if done or not expected else len(expected.difference(replies))
            received = self.receive_frames(None if done else deadline, waiting)
            decoded = self.protocol.decode_frames(received.frames)
            self.tally(decoded)
            for k in np.flatnonzero(decoded.valid):
                reply = decoded.reply(int(k))
                assert reply is not None
                replies[reply.motor_id] = reply
            if done or received.error is not None:
                break
            done = bool(expected) and expected.issubset(replies)
            if not done and time.perf_counter() >= deadline:
                break
        missing = tuple(sorted(expected.difference(replies)))
        return ReceiveResult(replies, missing, self.counters)

    def exchange(self, batch: CommandBatch, deadline: float) -> ReceiveResult:
        """Send a command batch for all motors, then receive until all replied or ``deadline`` passes."""
        self.send(batch, deadline)
        return self.receive(deadline)

    def close(self) -> None:
        self.bus.shutdown()

    def __enter__(self) -> CanBusLink:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


__all__ = [
    "CLASSIC_CAN_MAX_BITRATE",
    "DEFAULT_MAX_LOAD",
    "BusCapacityError",
    "BusLoad",
    "BusPlanSpec",
    "CanBusLink",
    "BUS_ERRORS",
    "DROPPED",
    "LinkCounters",
    "RETRIES",
    "SENT",
    "UNKNOWN",
    "VERDICT_COLUMNS",
    "ReceiveResult",
    "bus_load",
    "capacity_problem",
    "check_capacity",
    "frame_bits",
    "plan_bus_loads",
    "traffic_load",
]
