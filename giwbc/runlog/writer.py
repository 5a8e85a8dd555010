"""The control loop's side of the run log: :class:`RunLogWriter` packs records and hands them to
the logger process (:mod:`giwbc.runlog.sink`); see :mod:`giwbc.runlog` for the channels."""

from __future__ import annotations

import collections
import json
import math
import os
import socket
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.runlog.schema import (
    _CLOSE, _COMMANDS, _COUNTS, _ESTIMATE_FLAGS, _ESTIMATOR, _EVENT, _FAULT, _HEADER, _LENGTH, _MAX_DATAGRAM, _NUMERIC, _REPLIES,
    _TIMES, _TIMING, _TOPIC, SCHEMAS, _floats, _plain, _text,
)  # fmt: skip
from giwbc.runlog.channels import NumericChannel
from giwbc.runlog.extension import LogExtension
from giwbc.runlog.sink import _serve
from giwbc.util import children


class RunLogWriter:
    """Writes one run's MCAP log (see the module docstring) from a logger process of its own.

    The control loop must neither format, compress nor write the log: each call packs its record
    in binary (a few µs) into a buffer that :meth:`flush` hands to the logger in one datagram (the
    real-time runtime flushes once per cycle). Faults and events are flushed at once, and the
    logger writes them to disk before it reads on. When the socket is full (the logger is behind)
    datagrams wait in an ordered backlog of at most ``backlog``; beyond it the oldest are dropped,
    counted in :attr:`dropped` and noted in the log. The logger ignores SIGINT and SIGTERM (a
    Ctrl-C stops the run, not its log) and finishes the file with what it received should this
    process die. :meth:`close` waits until the file is complete; OSError if writing it failed.

    ``cpus``: the CPUs the logger may run on (Linux), e.g. all but the control loop's: on a kernel
    without full preemption, a logger inside a long write() on the loop's CPU delays the loop's
    wake-up, whatever the loop's priority.

    ``extension``: more channels derived from each cycle's records in the logger process (e.g. the
    robot's 3D scene, :mod:`giwbc.runlog.extension`); it is handed to the forked logger as it is.

    ``channels``: fixed-size numeric channels of the run's own (e.g. the walker's state,
    :mod:`giwbc.runlog.channels`), written with :meth:`channel`.
    """

    def __init__(self, path: str | os.PathLike[str], joint_names: Sequence[str], metadata: Mapping[str, Any] | None = None,
                 *, chunk_size: int = 256 * 1024, backlog: int = 4096, cpus: Iterable[int] | None = None,
                 extension: LogExtension | None = None, channels: Sequence[NumericChannel] = ()) -> None:  # fmt: skip
        channels = tuple(channels)
        topics = [c.topic for c in channels]
        if len(set(topics)) != len(topics) or len(channels) > 255:
            raise ValueError(f"numeric channels need distinct topics (at most 255), got {topics}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.joint_names = tuple(joint_names)
        meta = {"joint_names": list(self.joint_names), **(metadata or {})}
        self.counts: dict[str, int] = {topic: 0 for topic in (*SCHEMAS, *topics)}  # records handed over, per channel
        self._channels = {c.topic: (bytes((i,)), c.size) for i, c in enumerate(channels)}
        self.dropped = 0  # records lost because the logger fell too far behind
        self._noted_drops = 0
        self._buffer = bytearray()
        self._buffered = 0  # records in the buffer
        self._backlog: collections.deque[tuple[bytes, int]] = collections.deque()  # (datagram, records)
        self._backlog_limit = max(1, int(backlog))
        self._closed = False
        self._last_words: bytes | None = None  # the logger's final status, once read
        self._sock, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        _grow_send_buffer(self._sock)
        cpus = None if cpus is None else sorted(set(cpus))
        args = (child, self._sock, self.path, self.joint_names, meta, chunk_size, cpus, extension, channels)
        self._process = children.start(_serve, args, "giwbc-runlog")
        child.close()
        self._sock.setblocking(False)

    @property
    def pid(self) -> int | None:
        """The logger process's id."""
        return self._process.pid

    # --- records: the control loop's side, packed and buffered -----------------------------------
    def _record(self, kind: int, cycle: int, t: float, body: bytes, topic: str | None = None) -> None:
        if self._closed:
            raise ValueError(f"the run log {self.path} is closed")
        buffer = self._buffer
        buffer += _LENGTH.pack(_HEADER.size + len(body))
        buffer += _HEADER.pack(kind, max(0, int(cycle)), float(t))
        buffer += body
        self._buffered += 1
        self.counts[topic or _TOPIC[kind]] += 1

    def commands(self, cycle: int, t: float, phase: str, kind: str, q_ref: Any, v_ref: Any, kp: Any, kd: Any, tau_ff: Any) -> None:
        self._record(_COMMANDS, cycle, t, _text(phase) + _text(kind) + _floats(q_ref, v_ref, kp, kd, tau_ff))

    def replies(self, cycle: int, t: float, q: Any, dq: Any, tau: Any, temperature: Any, error_code: Any,
                missing: Any, late: int, corrupt: int, unknown: int) -> None:  # fmt: skip
        body = (_floats(q, dq, tau, temperature) + np.asarray(error_code, dtype=np.int64).tobytes()
                + np.asarray(missing, dtype=bool).tobytes() + _COUNTS.pack(int(late), int(corrupt), int(unknown)))  # fmt: skip
        self._record(_REPLIES, cycle, t, body)

    def estimator(self, cycle: int, t: float, imu: Any, estimate: Any) -> None:
        """The IMU sample (an ``ImuReading`` or None) and the estimate (an ``Estimate`` or None)."""
        parts = []
        if imu is not None:
            parts.append(_floats(imu.quaternion, imu.angular_velocity, imu.linear_acceleration, [imu.time]))
        faults = b""
        if estimate is not None:
            b = estimate.base
            contacts = np.asarray(estimate.contacts, dtype=bool).ravel()
            parts.append(_floats(b.position, b.quaternion, b.linear_velocity, b.angular_velocity))
            parts.append(bytes((len(contacts),)) + contacts.tobytes())
            if not estimate.faults.ok:
                faults = json.dumps([r.split(":", 1)[0] for r in estimate.faults.reasons]).encode()
        flags = _ESTIMATE_FLAGS.pack(imu is not None, estimate is not None, len(faults))
        self._record(_ESTIMATOR, cycle, t, flags + b"".join(parts) + faults)

    def timing(self, cycle: int, t: float, slot: int, lateness_us: float, period_us: float | None, work_us: float,
               send_us: float, receive_us: float, overrun: bool) -> None:  # fmt: skip
        period = math.nan if period_us is None else float(period_us)
        body = _TIMES.pack(int(slot), float(lateness_us), period, float(work_us), float(send_us), float(receive_us), bool(overrun))
        self._record(_TIMING, cycle, t, body)

    def channel(self, topic: str, cycle: int, t: float, values: np.ndarray) -> None:
        """One record of the numeric channel ``topic`` (declared at construction): ``values``, its
        ``size`` numbers (a float64 vector: no conversion; copied at once)."""
        entry = self._channels.get(topic)
        if entry is None:
            raise ValueError(f"no numeric channel {topic!r} in the run log {self.path} (declared: {', '.join(self._channels) or 'none'})")
        index, size = entry
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (size,):
            raise ValueError(f"channel {topic}: need {size} values, got shape {values.shape}")
        self._record(_NUMERIC, cycle, t, index + values.tobytes(), topic)

    def fault(self, fault: Any) -> None:
        """A :class:`~giwbc.hal.safety.Fault`: handed over at once, on disk before the logger reads on."""
        d = fault.as_dict()
        body = json.dumps({"cycle": d["cycle"], "t": d["time"], **{k: d[k] for k in ("kind", "message", "joints")}})
        self._record(_FAULT, d["cycle"], d["time"], body.encode())
        self.flush()

    def event(self, cycle: int, t: float, event: str, detail: Mapping[str, Any] | None = None, *, flush: bool = True) -> None:
        body = json.dumps({"cycle": cycle, "t": t, "event": event, "detail": _plain(detail or {})})
        self._record(_EVENT, cycle, t, body.encode())
        if flush:
            self.flush()

    # --- hand-over ----------------------------------------------------------------------------
    def flush(self) -> None:
        """Hand the buffered records to the logger without waiting (see the class docstring).
        OSError if the logger is gone."""
        if self._buffered:
            data, records = bytes(self._buffer), self._buffered
            self._buffer.clear()
            self._buffered = 0
            self._backlog.extend(_datagrams(data, records))
        backlog, send = self._backlog, self._sock.send
        while backlog:
            try:
                send(backlog[0][0])
            except BlockingIOError:
                break
            except OSError as error:
                reason = self._logger_status() or str(error)
                raise OSError(f"the run logger stopped ({reason}); the log {self.path} is incomplete") from error
            backlog.popleft()
        while len(backlog) > self._backlog_limit:  # the logger is far behind: the oldest go
            self.dropped += backlog.popleft()[1]
        if self.dropped > self._noted_drops and not backlog:
            self._note_drops()
            self.flush()

    def _note_drops(self) -> None:
        self._noted_drops = self.dropped
        self.event(0, 0.0, "log_dropped", {"records": self.dropped, "note": "the logger fell behind: records were dropped"}, flush=False)

    def _logger_status(self) -> str | None:
        """What the logger said when it ended, if it did (why it failed), kept for :meth:`close`."""
        if self._last_words is None:
            try:
                self._last_words = self._sock.recv(64 * 1024, socket.MSG_DONTWAIT) or None
            except OSError:
                return None
        return self._last_words.decode(errors="replace") if self._last_words else None

    def close(self) -> None:
        """Hand everything over, let the logger finish the file (summary, indexes) and wait for it."""
        if self._closed:
            return
        try:
            self.flush()
        except OSError:
            pass
        if self.dropped > self._noted_drops:
            self._note_drops()
        self._closed = True
        data, self._buffer = bytes(self._buffer), bytearray()
        try:
            self._sock.settimeout(30.0)
            for datagram, _ in [*self._backlog, *_datagrams(data, 0)] if data else self._backlog:
                self._sock.send(datagram)
            self._backlog.clear()
            self._sock.send(_LENGTH.pack(_HEADER.size) + _HEADER.pack(_CLOSE, 0, 0.0))
        except OSError:
            pass  # the logger is gone: what it said (if anything) is below
        try:
            reply = self._last_words or self._sock.recv(64 * 1024)
        except OSError as error:
            reply = f"the run logger did not answer: {error}".encode()
        finally:
            children.stop(self._process, 30.0)
            self._sock.close()
        if reply != b"ok":
            raise OSError(reply.decode(errors="replace") or f"the run logger ended without finishing {self.path}")

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _grow_send_buffer(sock: socket.socket, size: int = 4 << 20) -> None:
    """As much socket buffer as allowed (root may exceed ``net.core.wmem_max``)."""
    for option in (getattr(socket, "SO_SNDBUFFORCE", 32), socket.SO_SNDBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, size)
            return
        except OSError:
            continue


def _datagrams(data: bytes, records: int) -> list[tuple[bytes, int]]:
    """``data`` (``records`` length-prefixed records) cut at record boundaries into datagrams of at
    most ``_MAX_DATAGRAM`` bytes (a bigger record alone in one), with their record counts."""
    if len(data) <= _MAX_DATAGRAM:
        return [(data, records)]
    out: list[tuple[bytes, int]] = []
    start = k = count = 0
    while k < len(data):
        (size,) = _LENGTH.unpack_from(data, k)
        end = k + _LENGTH.size + size
        if end - start > _MAX_DATAGRAM and k > start:
            out.append((data[start:k], count))
            start, count = k, 0
        k, count = end, count + 1
    out.append((data[start:], count))
    return out


__all__ = ["RunLogWriter"]
