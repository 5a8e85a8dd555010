"""Batches of classic CAN frames, and the ports that move them over a python-can bus.

A control cycle of a 29-joint robot moves 58 frames. Through python-can's per-frame API (a
``Message`` per frame, ``BusABC.send``/``recv`` wrappers with their checks, a ``select`` per call)
each frame costs 5 to 15 µs of Python; as one numpy batch, encoded and decoded in one call and
written to the bus's socket one system call per frame, about 1.5 µs.

**Batches** are numpy arrays of :data:`FRAME` records, the 16-byte layout of SocketCAN's
``struct can_frame``: ``can_id`` (the identifier with the EFF / RTR / ERR flags in its top bits),
``len`` (0..8), three reserved bytes, ``data`` (8 bytes, zero-padded). These are exactly the
bytes a Linux ``CAN_RAW`` socket reads and writes.

**Ports** send and receive batches on one bus, in the caller's thread, against absolute
``time.perf_counter()`` deadlines (no ``Notifier`` thread):

- :class:`SocketPort`, for buses whose frames are ``struct can_frame`` datagrams on a socket:
  ``giwbc-unix`` (:mod:`giwbc.hal.unix_bus`) and python-can's ``socketcan`` with classic frames.
  python-can still opens, configures and closes the bus; only the frames bypass its wrappers.
- :class:`MessagePort`, for any other python-can bus (``virtual``, vendor adapters): frames
  cross as ``can.Message`` objects.
- :class:`PortGroup`, the ports of a robot's buses moved in one call each way.

:func:`frame_port` picks the port for a bus. Sending never raises: a frame whose send fails (a
full transmit queue that stays full for ``timeout``, a driver error) is retried ``retries`` times,
then dropped; frames still unsent at the deadline are dropped. Receiving returns at the deadline
at the latest; a driver error ends it early and is returned, not raised.
"""

from __future__ import annotations

import errno
import queue
import select
import socket
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import can
import numpy as np

if TYPE_CHECKING:
    from giwbc.hal.protocols.base import CanFrame

CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_SFF_MASK = 0x000007FF
CAN_EFF_MASK = 0x1FFFFFFF
CLASSIC_FRAME_SIZE = 16
_FD_FRAME_SIZE = 72  # struct canfd_frame: read whole, then skipped (a classic-CAN port)

FRAME = np.dtype([("can_id", "=u4"), ("len", "u1"), ("pad", "u1"), ("res0", "u1"), ("len8_dlc", "u1"), ("data", "u1", (8,))])
"""One classic CAN frame, laid out as SocketCAN's ``struct can_frame`` (16 bytes)."""
assert FRAME.itemsize == CLASSIC_FRAME_SIZE


# ----------------------------------------------------------------------------- batches
def frames(arbitration_ids: Any, data: Any, lengths: Any = 8, extended: Any = False) -> np.ndarray:
    """A batch from identifiers, payloads ``(N, 8)`` uint8 (zero-padded), lengths and the
    extended-id flag (scalars broadcast)."""
    ids = np.asarray(arbitration_ids, dtype=np.uint32).reshape(-1)
    if (np.asarray(lengths) > 8).any() or (np.asarray(lengths) < 0).any():
        raise ValueError(f"a classic CAN frame carries 0..8 data bytes, got lengths {lengths!r} (CAN FD is not supported)")
    out = np.zeros(ids.size, dtype=FRAME)
    out["can_id"] = np.where(np.asarray(extended, dtype=bool), ids | np.uint32(CAN_EFF_FLAG), ids)
    out["len"] = lengths
    out["data"] = np.asarray(data, dtype=np.uint8).reshape(ids.size, 8)
    return out


def frames_of(can_frames: Sequence[CanFrame]) -> np.ndarray:
    """A batch from :class:`~giwbc.hal.protocols.base.CanFrame` objects (payloads of 0..8 bytes)."""
    out = np.zeros(len(can_frames), dtype=FRAME)
    for k, f in enumerate(can_frames):
        n = len(f.data)
        if n > 8 or getattr(f, "is_fd", False):
            raise ValueError(f"a classic CAN frame carries at most 8 bytes, got {n} (CAN FD is not supported)")
        out[k]["can_id"] = f.arbitration_id | (CAN_EFF_FLAG if f.is_extended_id else 0)
        out[k]["len"] = n
        out[k]["data"][:n] = np.frombuffer(bytes(f.data), dtype=np.uint8)
    return out


@dataclass(frozen=True, slots=True)
class FrameFields:
    """The fields of a batch, split out: identifier (flags removed), flags, payload length."""

    arbitration_id: np.ndarray
    extended: np.ndarray
    remote: np.ndarray
    error: np.ndarray
    length: np.ndarray


def fields(batch: np.ndarray) -> FrameFields:
    """Identifier (11 or 29 bits, as python-can gives it), flags and length of every frame."""
    can_id = batch["can_id"].astype(np.int64)
    extended = (can_id & CAN_EFF_FLAG) != 0
    return FrameFields(
        np.where(extended, can_id & CAN_EFF_MASK, can_id & CAN_SFF_MASK),
        extended,
        (can_id & CAN_RTR_FLAG) != 0,
        (can_id & CAN_ERR_FLAG) != 0,
        batch["len"].astype(np.int64),
    )


def payload(record: np.void) -> bytes:
    """The payload bytes of one record (``len`` of them; a record cannot hold more than 8)."""
    return record["data"].tobytes()[: min(int(record["len"]), 8)]


def to_message(record: np.void) -> can.Message:
    """One record as a python-can message (``ValueError`` for a record saying more than 8 bytes:
    a classic frame cannot carry them, and they are never cut)."""
    if record["len"] > 8:
        raise ValueError(f"a classic CAN frame record says {int(record['len'])} data bytes (at most 8); not sent")
    can_id = int(record["can_id"])
    extended = bool(can_id & CAN_EFF_FLAG)
    return fast_message(
        can_id & (CAN_EFF_MASK if extended else CAN_SFF_MASK), payload(record), extended,
        remote=bool(can_id & CAN_RTR_FLAG), error=bool(can_id & CAN_ERR_FLAG),
    )  # fmt: skip


def from_messages(messages: Sequence[can.Message]) -> np.ndarray:
    """A batch from python-can messages (classic frames; longer payloads are cut at 8 bytes and
    keep their length, so a protocol rejects them)."""
    out = np.zeros(len(messages), dtype=FRAME)
    if not messages:
        return out
    out["can_id"] = [
        m.arbitration_id | (CAN_EFF_FLAG if m.is_extended_id else 0) | (CAN_RTR_FLAG if m.is_remote_frame else 0)
        | (CAN_ERR_FLAG if m.is_error_frame else 0)
        for m in messages
    ]  # fmt: skip
    out["len"] = [min(len(m.data), 255) for m in messages]
    out["data"] = np.frombuffer(b"".join(bytes(m.data[:8]).ljust(8, b"\0") for m in messages), dtype=np.uint8).reshape(-1, 8)
    return out


class FastMessage(can.Message):
    """A ``can.Message`` whose construction and deep copy are cheap.

    python-can's ``virtual`` interface deep-copies every frame for every receiver; the generic
    ``Message.__deepcopy__`` costs ~13 us (it deep-copies the ``bytearray``), this one ~3 us.
    Other interfaces only read the attributes, so to them it is a plain message.
    """

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, Any] | None) -> FastMessage:
        c = _new(FastMessage)
        c.timestamp = self.timestamp
        c.arbitration_id = self.arbitration_id
        c.is_extended_id = self.is_extended_id
        c.is_remote_frame = self.is_remote_frame
        c.is_error_frame = self.is_error_frame
        c.channel = self.channel
        c.dlc = self.dlc
        c.data = bytearray(self.data)
        c.is_fd = self.is_fd
        c.is_rx = self.is_rx
        c.bitrate_switch = self.bitrate_switch
        c.error_state_indicator = self.error_state_indicator
        return c


def fast_message(arbitration_id: int, data: bytes, is_extended_id: bool = False, *, remote: bool = False,
                 error: bool = False, timestamp: float = 0.0) -> FastMessage:  # fmt: skip
    """A frame as ``can.Message(arbitration_id=..., data=..., is_extended_id=...)`` makes it,
    built without the generic constructor's argument handling."""
    c = _new(FastMessage)
    c.timestamp = timestamp
    c.arbitration_id = arbitration_id
    c.is_extended_id = is_extended_id
    c.is_remote_frame = remote
    c.is_error_frame = error
    c.channel = None
    c.data = bytearray(data)
    c.dlc = len(c.data)
    c.is_fd = False
    c.is_rx = True
    c.bitrate_switch = False
    c.error_state_indicator = False
    return c


_new = FastMessage.__new__


# ----------------------------------------------------------------------------- ports
@dataclass(frozen=True, slots=True)
class SendOutcome:
    """What one :meth:`FramePort.send` did: frames sent, dropped, retried attempts, driver errors."""

    sent: int = 0
    dropped: int = 0
    retries: int = 0
    errors: int = 0


@dataclass(frozen=True, slots=True)
class Received:
    """What one :meth:`FramePort.receive` read: the classic frames (a batch), how many other
    datagrams were skipped (CAN FD frames on a classic port), and the driver error that ended
    the read early, if any."""

    frames: np.ndarray
    skipped: int = 0
    error: Exception | None = None


class FramePort(ABC):
    """Sends and receives batches on one python-can bus (see the module docstring)."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.last_error: BaseException | None = None  # the driver's last exception while sending (kept for the log)

    @abstractmethod
    def send(self, batch: np.ndarray, deadline: float, *, timeout: float = 200e-6, retries: int = 2) -> SendOutcome:
        """Send ``batch`` in order (see the module docstring for the retry policy)."""

    @abstractmethod
    def receive(self, deadline: float | None = None, limit: int | None = None) -> Received:
        """Frames until ``deadline`` (absolute ``perf_counter`` s; None: only those already
        waiting) or, with ``limit``, until that many were read."""

    def send_raw(self, raw: bytes, deadline: float, timeout: float, retries: int) -> tuple[int, int, int, int]:
        """:meth:`send` for frames as bytes (16 each): (sent, dropped, retries, errors)."""
        o = self.send(np.frombuffer(raw, dtype=FRAME), deadline, timeout=timeout, retries=retries)
        return o.sent, o.dropped, o.retries, o.errors

    def wait_fd(self) -> int | None:
        """A descriptor that becomes readable when frames arrive, or None (then the port is polled)."""
        return None

    def pending(self) -> bool | None:
        """Whether frames are waiting, when the port can tell without reading one (None: unknown)."""
        return None

    def receive_raw(self, chunks: list[bytes], deadline: float | None, limit: int | None) -> tuple[int, int, Exception | None]:
        """:meth:`receive` appending the frames' bytes to ``chunks``: (frames read, skipped, error)."""
        received = self.receive(deadline, limit)
        if len(received.frames):
            chunks.append(received.frames.tobytes())
        return len(received.frames), received.skipped, received.error


def frame_port(bus: can.BusABC) -> FramePort:
    """The fastest port for ``bus``: :class:`SocketPort` where its frames are classic
    ``struct can_frame`` datagrams on a socket we can read (giwbc-unix; socketcan without software
    filters), :class:`MessagePort` otherwise.

    Batches are classic frames: a bus opened for CAN FD (``fd=True``) is refused with
    ``can.CanInitializationError``, as giwbc-unix refuses it, rather than having its FD frames cut
    or dropped. (A classic port that still meets an FD frame skips it and counts it.)"""
    if getattr(bus, "protocol", None) in (can.CanProtocol.CAN_FD, can.CanProtocol.CAN_FD_NON_ISO):
        raise can.CanInitializationError(
            f"{getattr(bus, 'channel_info', bus)!s}: the batched frame path carries classic CAN frames only "
            "(struct can_frame, 8 data bytes); open the bus without fd=True"
        )
    if hasattr(type(bus), "frame_socket"):  # giwbc-unix: its socket, or None until the peer connects
        return SocketPort(bus, lambda: bus.frame_socket)  # type: ignore[attr-defined]
    if type(bus).__name__ == "SocketcanBus" and isinstance(getattr(bus, "socket", None), socket.socket):
        if not bus.filters:  # software filters need python-can's path
            sock = bus.socket  # type: ignore[attr-defined]
            return SocketPort(bus, lambda: sock)
    return MessagePort(bus)


_FULL = (errno.EAGAIN, errno.EWOULDBLOCK, errno.ENOBUFS)  # SocketCAN reports a full queue as ENOBUFS
_NO_FRAMES = np.zeros(0, dtype=FRAME)
_POLL_SLICE = 100e-6  # s: how long a group waits before polling again buses it cannot select() on


def _send_frame(sock: socket.socket, frame: bytes, timeout: float) -> bool:
    """One attempt: send now, or wait at most ``timeout`` for room and send; False on failure."""
    try:
        sock.send(frame, socket.MSG_DONTWAIT)
        return True
    except OSError as error:
        if error.errno not in _FULL:
            return False  # the other end is gone, the interface is down: a driver error
    select.select([], [sock], [], timeout)
    try:
        sock.send(frame, socket.MSG_DONTWAIT)
        return True
    except OSError:
        return False


def _send_raw(sock: socket.socket, raw: bytes, deadline: float, timeout: float, retries: int) -> tuple[int, int, int, int]:
    """Send the frames of ``raw`` (16 bytes each) in order: (sent, dropped, retries, errors)."""
    n = len(raw) // CLASSIC_FRAME_SIZE
    send, clock, flags = sock.send, time.perf_counter, socket.MSG_DONTWAIT
    sent = retried = errors = 0
    for k in range(0, len(raw), CLASSIC_FRAME_SIZE):
        frame = raw[k : k + CLASSIC_FRAME_SIZE]
        if clock() >= deadline:
            break
        try:
            send(frame, flags)  # the common case, inline: no queue trouble
            sent += 1
            continue
        except OSError:
            pass
        attempt = 0
        while True:
            errors += 1
            if attempt >= retries:
                break
            attempt += 1
            retried += 1
            left = deadline - clock()
            if left <= 0:
                break
            if _send_frame(sock, frame, min(timeout, left)):
                sent += 1
                break
    return sent, n - sent, retried, errors


def _receive_raw(sock: socket.socket, chunks: list[bytes], deadline: float | None, limit: int | None,
                 name: str) -> tuple[int, int, Exception | None]:  # fmt: skip
    """Append classic frames from ``sock`` to ``chunks`` until ``deadline`` (None: only those
    waiting) or ``limit`` of them: (frames read, other datagrams skipped, driver error or None)."""
    recv, flags = sock.recv, socket.MSG_DONTWAIT
    got = skipped = 0
    while limit is None or got < limit:
        try:
            data = recv(_FD_FRAME_SIZE, flags)
        except (BlockingIOError, InterruptedError):
            if deadline is None:
                break
            left = deadline - time.perf_counter()
            if left <= 0 or not select.select([sock], [], [], left)[0]:
                break
            continue
        except OSError as e:
            return got, skipped, can.CanOperationError(f"{name}: receive failed ({e})")
        if len(data) == CLASSIC_FRAME_SIZE:
            chunks.append(data)
            got += 1
        elif not data:
            return got, skipped, can.CanOperationError(f"{name}: the other end closed the channel")
        else:
            skipped += 1
    return got, skipped, None


class SocketPort(FramePort):
    """Frames as ``struct can_frame`` datagrams on the bus's socket, one system call each.

    ``sock`` returns the socket (or None while there is none yet: frames sent then are lost, as
    on a bus with no other node, and counted by the bus, see :class:`~giwbc.hal.unix_bus.UnixCanBus`).
    """

    def __init__(self, bus: can.BusABC, sock: Any) -> None:
        super().__init__(bus)
        self._socket_of_bus = sock
        self._socket: socket.socket | None = None
        self.name = str(getattr(bus, "channel_info", "can"))

    def socket(self) -> socket.socket | None:
        """The bus's socket, None while there is none yet; ``can.CanError`` once the bus is closed."""
        if self._socket is None:  # kept once there: a bus's socket lives as long as the bus
            self._socket = self._socket_of_bus()
        return self._socket

    def wait_fd(self) -> int | None:
        try:
            sock = self.socket()
        except (can.CanError, OSError):
            return None
        return None if sock is None else sock.fileno()

    def send(self, batch: np.ndarray, deadline: float, *, timeout: float = 200e-6, retries: int = 2) -> SendOutcome:
        return SendOutcome(*self.send_raw(batch.tobytes(), deadline, timeout, retries))

    def send_raw(self, raw: bytes, deadline: float, timeout: float, retries: int) -> tuple[int, int, int, int]:
        """:meth:`send` for frames already as bytes: (sent, dropped, retries, errors)."""
        n = len(raw) // CLASSIC_FRAME_SIZE
        try:
            sock = self.socket()
        except (can.CanError, OSError):  # a closed bus
            return 0, n, 0, 1
        if sock is None:
            note = getattr(self.bus, "note_unsent", None)
            if note is not None:
                note(n)
            return n, 0, 0, 0
        return _send_raw(sock, raw, deadline, timeout, retries)

    def receive(self, deadline: float | None = None, limit: int | None = None) -> Received:
        chunks: list[bytes] = []
        got, skipped, error = self.receive_raw(chunks, deadline, limit)
        return Received(np.frombuffer(b"".join(chunks), dtype=FRAME) if chunks else _NO_FRAMES, skipped, error)

    def receive_raw(self, chunks: list[bytes], deadline: float | None, limit: int | None) -> tuple[int, int, Exception | None]:
        """:meth:`receive` appending each frame's 16 bytes to ``chunks``: (read, skipped, error)."""
        try:
            sock = self.socket()
        except (can.CanError, OSError) as e:  # a closed bus
            return 0, 0, e
        if sock is None:
            return 0, 0, None
        return _receive_raw(sock, chunks, deadline, limit, self.name)


@dataclass(frozen=True, slots=True)
class GroupReceived:
    """What one :meth:`PortGroup.receive` read: the frames of every bus (in bus order, arrival
    order within a bus), the bus of each, and per bus the skipped datagrams and the driver error."""

    frames: np.ndarray
    bus: np.ndarray
    skipped: tuple[int, ...]
    errors: tuple[Exception | None, ...]


class PortGroup:
    """The ports of several buses (a robot's), moved in one call each way.

    A control cycle touches every bus twice; going through one port object and one batch per bus
    costs Python overhead per bus, and joining per-bus record arrays costs numpy's structured-dtype
    handling. The group sends one batch split by bus and receives every bus's frames as bytes,
    turned into one batch at the end.
    """

    def __init__(self, ports: Sequence[FramePort]) -> None:
        self.ports = tuple(ports)
        self._buses = np.arange(len(self.ports), dtype=np.int64)
        # Every port a SocketPort whose socket is there: the sockets (a SocketPort keeps its socket
        # once it has one, so they stay the ports' own); until then, None.
        self._direct: tuple[socket.socket, ...] | None = None

    def _direct_sockets(self) -> tuple[socket.socket, ...] | None:
        """The sockets of every bus when each port is a :class:`SocketPort` that has its socket
        (then the group moves frames on them itself, as the ports would, without a call per
        port); None otherwise (a MessagePort, a bus whose peer has not connected yet)."""
        if self._direct is None and self.ports and all(type(p) is SocketPort and p._socket is not None for p in self.ports):
            self._direct = tuple(p._socket for p in self.ports)  # type: ignore[attr-defined]
        return self._direct

    def send(self, batch: np.ndarray, bounds: Sequence[int], deadline: float, *, timeout: Sequence[float],
             retries: Sequence[int]) -> list[tuple[int, int, int, int]]:  # fmt: skip
        """Send ``batch[bounds[b]:bounds[b + 1]]`` on bus ``b``, buses in order, each with its
        ``timeout`` and ``retries``; per bus: (sent, dropped, retries, errors), as
        :meth:`FramePort.send` counts them."""
        raw = batch.tobytes()
        size = CLASSIC_FRAME_SIZE
        direct = self._direct_sockets()
        if direct is not None:  # SocketPort.send_raw of each, without the calls
            return [
                _send_raw(sock, raw[size * a : size * b], deadline, t, r)
                for sock, a, b, t, r in zip(direct, bounds[:-1], bounds[1:], timeout, retries)
            ]
        return [
            port.send_raw(raw[size * a : size * b], deadline, t, r)
            for port, a, b, t, r in zip(self.ports, bounds[:-1], bounds[1:], timeout, retries)
        ]

    def receive(self, deadline: float | None = None, need: Sequence[int] | None = None, buses: Sequence[int] | None = None,
                *, drain: bool = False) -> GroupReceived:  # fmt: skip
        """Frames of every bus (or of ``buses``, ascending), all buses served together: each bus is
        read until it gave ``need[b]`` frames (None: everything) or ``deadline`` passed (None: only
        the frames already waiting). A bus waiting for frames never holds up another: what is
        waiting is read from every bus first, then one ``select()`` over the buses still short
        wakes on whichever has frames, until the deadline. With ``drain`` and no deadline, ``need``
        is what each bus is expected to hold and everything waiting is read: the expected frames
        first, then one ``select()`` over all sockets finds the buses holding more (late or stray
        frames), instead of probing every bus for "nothing left" (a raised BlockingIOError each).
        Returns by the deadline (plus one read per bus)."""
        n = len(self.ports)
        per_bus: list[list[bytes]] = [[] for _ in range(n)]
        counts = np.zeros(n, dtype=np.int64)
        skipped = [0] * n
        errors: list[Exception | None] = [None] * n
        order = self._buses if buses is None else buses
        ports = self.ports
        short = []
        direct = self._direct_sockets()
        needs = None if need is None else need.tolist() if isinstance(need, np.ndarray) else need
        for b in order:
            limit = None if needs is None else int(needs[b])
            if limit == 0:
                continue
            if direct is not None:  # SocketPort.receive_raw, without the call
                counts[b], skipped[b], errors[b] = _receive_raw(direct[b], per_bus[b], None, limit, ports[b].name)  # type: ignore[attr-defined]
            else:
                counts[b], skipped[b], errors[b] = ports[b].receive_raw(per_bus[b], None, limit)
            if errors[b] is None and (limit is None or counts[b] < limit):
                short.append(b)
        if deadline is not None:
            clock = time.perf_counter
            while short:
                left = deadline - clock()
                if left <= 0:
                    break
                for b in self._ready(short, left):
                    limit = None if need is None else int(need[b]) - int(counts[b])
                    got, more, errors[b] = ports[b].receive_raw(per_bus[b], None, limit)
                    counts[b] += got
                    skipped[b] += more
                short = [b for b in short if errors[b] is None and (need is None or counts[b] < need[b])]
        elif drain and need is not None:
            for b in self._more_waiting([b for b in order if errors[b] is None]):
                got, more, errors[b] = ports[b].receive_raw(per_bus[b], None, None)
                counts[b] += got
                skipped[b] += more
        raw = b"".join([chunk for chunks in per_bus for chunk in chunks])
        batch = np.frombuffer(raw, dtype=FRAME) if raw else _NO_FRAMES
        return GroupReceived(batch, np.repeat(self._buses, counts), tuple(skipped), tuple(errors))

    def _sockets(self, buses: Sequence[int]) -> tuple[dict[int, int], list[int]]:
        """The descriptors of ``buses`` to wait on ({fd: bus}) and the buses without one (a port
        with no socket yet, a python-can bus that has no descriptor): those are polled."""
        direct = self._direct_sockets()
        if direct is not None:  # every bus a socket: its descriptor, unless it was closed (then as below)
            found: dict[int, int] = {}
            for b in buses:
                fd = direct[b].fileno()
                if fd < 0:
                    break
                found[fd] = b
            else:
                return found, []
        sockets: dict[int, int] = {}
        polled = []
        ports = self.ports
        for b in buses:
            port = ports[b]
            sock = port._socket if type(port) is SocketPort else None  # the common case, without calls
            fd = port.wait_fd() if sock is None else sock.fileno()
            if fd is None or fd < 0:
                polled.append(b)
            else:
                sockets[fd] = b
        return sockets, polled

    def _ready(self, buses: Sequence[int], timeout: float) -> list[int]:
        """The buses among ``buses`` with frames waiting, waiting at most ``timeout`` for one. Buses
        that cannot be waited on are polled: returned at once when their port says frames are
        waiting, after a short slice when it cannot tell."""
        sockets, polled = self._sockets(buses)
        pending = [(b, self.ports[b].pending()) for b in polled]
        waiting = [b for b, p in pending if p]
        unknown = [b for b, p in pending if p is None]
        if waiting:
            timeout = 0.0
        elif polled:
            timeout = min(timeout, _POLL_SLICE)
        ready = select.select(list(sockets), [], [], timeout)[0] if sockets else (time.sleep(timeout) or [])
        return sorted(waiting + unknown + [sockets[fd] for fd in ready])

    def _more_waiting(self, buses: Sequence[int]) -> list[int]:
        """The buses among ``buses`` with frames still waiting: one select() over their sockets
        (a bus that cannot be waited on counts as possibly waiting, unless its port knows better)."""
        sockets, polled = self._sockets(buses)
        polled = [b for b in polled if self.ports[b].pending() is not False]
        ready = select.select(list(sockets), [], [], 0)[0] if sockets else []
        return sorted(polled + [sockets[fd] for fd in ready])


class MessagePort(FramePort):
    """Frames as ``can.Message`` objects through python-can's own ``send`` and ``recv``."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(bus)
        try:
            fd = bus.fileno()
        except (NotImplementedError, can.CanError, OSError, AttributeError):
            fd = None
        self._fd = fd if isinstance(fd, int) and fd >= 0 else None
        queue_ = getattr(bus, "queue", None)  # python-can's virtual bus: its receive queue
        self._queue = queue_ if isinstance(queue_, queue.Queue) else None

    def wait_fd(self) -> int | None:
        return self._fd

    def pending(self) -> bool | None:
        return None if self._queue is None else not self._queue.empty()

    def send(self, batch: np.ndarray, deadline: float, *, timeout: float = 200e-6, retries: int = 2) -> SendOutcome:
        bus, clock = self.bus, time.perf_counter
        n = len(batch)
        if n and batch["len"].max() > 8:
            raise ValueError("a classic CAN frame record says more than 8 data bytes; nothing was sent")
        sent = retried = errors = 0
        for k in range(n):
            msg = to_message(batch[k])
            attempt = 0
            while True:
                left = deadline - clock()
                if left <= 0:
                    return SendOutcome(sent, n - sent, retried, errors)
                try:
                    bus.send(msg, timeout=min(timeout, left))
                    sent += 1
                    break
                except Exception as e:  # noqa: BLE001 - any driver error (a driver bug too) drops the frame, never the cycle
                    self.last_error = e
                    errors += 1
                    if attempt >= retries:
                        break
                    attempt += 1
                    retried += 1
        return SendOutcome(sent, n - sent, retried, errors)

    def receive(self, deadline: float | None = None, limit: int | None = None) -> Received:
        bus, clock = self.bus, time.perf_counter
        messages: list[can.Message] = []
        skipped = 0
        error: Exception | None = None
        while limit is None or len(messages) < limit:
            left = 0.0 if deadline is None else max(0.0, deadline - clock())
            try:
                msg = bus.recv(timeout=left)
            except Exception as e:  # noqa: BLE001 - returned, not raised (see the module docstring)
                error = e
                break
            if msg is None:
                break
            if msg.is_fd:
                skipped += 1
                continue
            messages.append(msg)
        return Received(from_messages(messages), skipped, error)


__all__ = [
    "CAN_EFF_FLAG",
    "CAN_EFF_MASK",
    "CAN_ERR_FLAG",
    "CAN_RTR_FLAG",
    "CAN_SFF_MASK",
    "FRAME",
    "FastMessage",
    "FrameFields",
    "FramePort",
    "GroupReceived",
    "MessagePort",
    "PortGroup",
    "Received",
    "SendOutcome",
    "SocketPort",
    "fast_message",
    "fields",
    "frame_port",
    "frames",
    "frames_of",
    "from_messages",
    "payload",
    "to_message",
]
