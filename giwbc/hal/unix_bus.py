"""A python-can bus between two processes of one machine: ``can.Bus(interface="giwbc-unix", channel=...)``.

Why: the actuator emulator can run in its own process (as motors run on their own hardware) only
if the bus crosses processes, and python-can's ``virtual`` interface is in-process while
SocketCAN/vcan and UDP multicast are not available everywhere. This bus is a Linux ``AF_UNIX``
``SOCK_SEQPACKET`` connection in the abstract namespace (``"\\0giwbc-can/<channel>"``: no file, no
network), one datagram per frame in SocketCAN's ``struct can_frame`` layout (32-bit id with the
EFF/RTR/ERR flags, length, 8 data bytes), so a frame costs one system call each way.

A channel has two ends: the motor side serves (``serve=True``: bind and listen; the host is
accepted when it connects, at the first send or receive after that) and the host connects
(retrying for ``connect_timeout`` s, then a clear error naming the channel). Like a real bus with
no other node, frames sent before the peer is there are lost (counted in :attr:`unsent`).

``send`` waits at most ``timeout`` for room in the socket buffer, then raises
``can.CanOperationError`` (a full transmit queue); a closed peer raises ``can.CanOperationError``
on send and receive. Registered with python-can through the ``can.interface`` entry point.

Classic CAN only. The channel carries ``struct can_frame`` (at most 8 data bytes), what the
emulator and every protocol here (MIT mode) use, and what the batched frame path
(:mod:`giwbc.hal.frames`) moves; nothing is cut to fit: ``fd=True`` is refused when the bus is
opened (``can.CanInitializationError``), an FD message or a payload over 8 bytes when it is sent
(``can.CanOperationError``), and a datagram that is not a classic frame when it is received
(``can.CanOperationError``, never read as a shorter frame). A protocol that needs CAN FD (moteus)
would add the ``struct canfd_frame`` layout (72-byte datagrams, BRS/ESI flags) to both ends and to
the frame batches together.
"""

from __future__ import annotations

import errno
import select
import socket
import struct
import time
from typing import Any

import can

from giwbc.hal.frames import CAN_EFF_FLAG, CAN_EFF_MASK, CAN_ERR_FLAG, CAN_RTR_FLAG, CAN_SFF_MASK, fast_message

_FRAME = struct.Struct("=IB3x8s")  # struct can_frame: can_id, len, pad, data[8]
_MAX_DATAGRAM = 256  # recv size: larger than any CAN datagram, so a non-classic one is seen whole, never cut to 16 bytes


def channel_address(channel: str) -> bytes:
    """The abstract-namespace address of a channel (Linux)."""
    if not channel or "\0" in channel:
        raise ValueError(f"a giwbc-unix channel is a non-empty name without NUL bytes, got {channel!r}")
    return b"\0giwbc-can/" + channel.encode()


class UnixCanBus(can.BusABC):
    """One end of a two-node CAN channel between processes (see the module docstring)."""

    def __init__(
        self,
        channel: str,
        *,
        serve: bool = False,
        connect_timeout: float = 5.0,
        fd: bool = False,
        _socket: socket.socket | None = None,
        **kwargs: Any,
    ) -> None:
        if fd:
            raise can.CanInitializationError(
                f"giwbc-unix channel {channel!r}: CAN FD is not supported (the channel carries classic frames, "
                "struct can_frame, at most 8 data bytes); open it with fd=False"
            )
        self.channel = channel
        self.channel_info = f"giwbc-unix {channel}" + (" (motor side)" if serve else "")
        self.unsent = 0
        self._listener: socket.socket | None = None
        self._sock: socket.socket | None = None
        self._closed = False
        if _socket is not None:
            self._connected(_socket)
        elif serve:
            listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            try:
                listener.bind(channel_address(channel))
            except OSError as error:
                listener.close()
                raise can.CanInitializationError(f"giwbc-unix channel {channel!r} is already served by another process ({error})") from error
            listener.listen(1)
            listener.setblocking(False)
            self._listener = listener
        else:
            self._connected(self._connect(channel, connect_timeout))
        super().__init__(channel=channel, **kwargs)

    @classmethod
    def pair(cls, channel: str = "pair") -> tuple[UnixCanBus, UnixCanBus]:
        """Two connected ends in this process (tests): (host, motor side)."""
        a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        return cls(channel, _socket=a), cls(channel, _socket=b)

    @staticmethod
    def _connect(channel: str, timeout: float) -> socket.socket:
        address = channel_address(channel)
        deadline = time.monotonic() + timeout
        while True:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            try:
                sock.connect(address)
                return sock
            except OSError as error:
                sock.close()
                if error.errno not in (errno.ECONNREFUSED, errno.ENOENT, errno.EAGAIN) or time.monotonic() >= deadline:
                    raise can.CanInitializationError(f"no motor side serves giwbc-unix channel {channel!r} ({error})") from error
                time.sleep(0.01)

    def _connected(self, sock: socket.socket) -> None:
        sock.setblocking(False)
        self._sock = sock

    def accept(self, timeout: float) -> bool:
        """Accept the host if it is there (waiting at most ``timeout``); True when connected."""
        listener = self._listener
        if listener is None:
            return self._sock is not None
        if not select.select([listener], [], [], max(0.0, timeout))[0]:
            return False
        try:
            sock, _ = listener.accept()
        except BlockingIOError:
            return False
        self._connected(sock)
        listener.close()
        self._listener = None
        return True

    @property
    def connected(self) -> bool:
        return self._sock is not None

    @property
    def frame_socket(self) -> socket.socket | None:
        """The connected socket (accepting a waiting host first), None while nobody is on the
        bus; ``can.CanOperationError`` once closed. :class:`~giwbc.hal.frames.SocketPort` moves
        whole batches of frames on it, bypassing the per-message API."""
        if self._sock is None:
            if self._closed:
                raise can.CanOperationError(f"{self.channel_info} is closed")
            self.accept(0.0)
        return self._sock

    def note_unsent(self, frames: int) -> None:
        """Count frames sent while nobody was on the bus (lost)."""
        self.unsent += frames

    def fileno(self) -> int:
        """The descriptor to wait on: the connection, or the listening socket before it."""
        sock = self._sock if self._sock is not None else self._listener
        if sock is None:
            raise can.CanOperationError(f"{self.channel_info} is closed")
        return sock.fileno()

    # ------------------------------------------------------------------ frames
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        sock = self._sock
        if sock is None and not self.accept(0.0):
            if self._closed:
                raise can.CanOperationError(f"{self.channel_info} is closed")
            self.unsent += 1  # nobody on the bus yet
            return
        sock = self._sock
        assert sock is not None
        frame = self._frame(msg)
        if self._try_send(sock, frame):
            return
        # The buffer is full: wait for room, at most `timeout` (select: microsecond timeouts).
        if (timeout is None or timeout > 0) and select.select([], [sock], [], timeout)[1] and self._try_send(sock, frame):
            return
        raise can.CanOperationError(f"{self.channel_info}: transmit buffer full")

    def _frame(self, msg: can.Message) -> bytes:
        """``msg`` as a ``struct can_frame``; ``can.CanOperationError`` for what one cannot carry."""
        data = bytes(msg.data)
        if msg.is_fd or len(data) > 8 or not 0 <= msg.dlc <= 8:
            raise can.CanOperationError(
                f"{self.channel_info}: a CAN FD frame or a payload over 8 bytes cannot be sent (classic CAN only: "
                f"is_fd={msg.is_fd}, {len(data)} data bytes, dlc {msg.dlc}); nothing was sent"
            )
        can_id = msg.arbitration_id
        if msg.is_extended_id:
            can_id |= CAN_EFF_FLAG
        if msg.is_remote_frame:
            can_id |= CAN_RTR_FLAG
        if msg.is_error_frame:
            can_id |= CAN_ERR_FLAG
        length = msg.dlc if msg.is_remote_frame else len(data)  # a remote frame: the requested length, no data
        return _FRAME.pack(can_id, length, b"" if msg.is_remote_frame else data)

    def _try_send(self, sock: socket.socket, frame: bytes) -> bool:
        """Send without waiting: False when the buffer is full, an error when the peer is gone."""
        try:
            sock.send(frame)
            return True
        except BlockingIOError:
            return False
        except OSError as error:
            raise can.CanOperationError(f"{self.channel_info}: the other end is gone ({error})") from error

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        sock = self._sock
        if sock is None:
            if self._closed:
                raise can.CanOperationError(f"{self.channel_info} is closed")
            started = time.perf_counter()
            if not self.accept(1e9 if timeout is None else timeout):
                return None, False
            if timeout is not None:
                timeout = max(0.0, timeout - (time.perf_counter() - started))
            sock = self._sock
            assert sock is not None
        try:
            data = sock.recv(_MAX_DATAGRAM)
        except BlockingIOError:
            if timeout is not None and timeout <= 0:
                return None, False
            if not select.select([sock], [], [], timeout)[0]:  # (select: microsecond timeouts, poll: milliseconds)
                return None, False
            try:
                data = sock.recv(_MAX_DATAGRAM)
            except BlockingIOError:
                return None, False
            except OSError as error:
                raise can.CanOperationError(f"{self.channel_info}: the other end is gone ({error})") from error
        except OSError as error:
            raise can.CanOperationError(f"{self.channel_info}: the other end is gone ({error})") from error
        if not data:
            raise can.CanOperationError(f"{self.channel_info}: the other end closed the channel")
        return self._message(data), False

    @staticmethod
    def _message(data: bytes) -> can.Message:
        if len(data) != _FRAME.size:
            raise can.CanOperationError(
                f"giwbc-unix: a {len(data)}-byte datagram is not a classic CAN frame (CAN FD is not supported); dropped"
            )
        can_id, length, payload = _FRAME.unpack(data)
        if length > 8:
            raise can.CanOperationError(f"giwbc-unix: a classic CAN frame says {length} data bytes (at most 8); dropped")
        extended = bool(can_id & CAN_EFF_FLAG)
        remote = bool(can_id & CAN_RTR_FLAG)
        msg = fast_message(
            can_id & (CAN_EFF_MASK if extended else CAN_SFF_MASK), b"" if remote else payload[:length], extended,
            remote=remote, error=bool(can_id & CAN_ERR_FLAG), timestamp=time.time(),
        )  # fmt: skip
        msg.dlc = length
        return msg

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        for sock in (self._sock, self._listener):
            if sock is not None:
                sock.close()
        self._sock = self._listener = None
        super().shutdown()


__all__ = ["UnixCanBus", "channel_address"]
