"""The run log: one MCAP file per run, JSON messages with a JSON schema per channel.

Channels (``log_time`` = ``publish_time`` = robot time of the cycle in ns since the run started):

=================  ==========================================================================
``/commands``      what went out: cycle, phase, frame kind, q_ref, v_ref, kp, kd, tau_ff
``/replies``       what came back: q, dq, tau, temperature, error codes, missing joints, late,
                   corrupt and unknown frames
``/estimator``     the IMU sample (quaternion x, y, z, w, angular velocity, acceleration, its
                   time) and the estimate from it: base position, quaternion, linear / angular
                   velocity, contacts, estimator faults (null without an estimator)
``/timing``        deadline slot, lateness, period, work and bus times (us), overrun flag
``/faults``        every fault: kind, message, cycle, time, joints
``/events``        phase changes and notes (start-up pose, clamped fields, shutdown)
=================  ==========================================================================

Arrays are in the order of the ``joint_names`` run metadata. :func:`read_log` loads a file back.

Who writes it: a logger process (:class:`RunLogWriter` starts it). The control loop only packs
each record in binary and hands a cycle's records over in one datagram; formatting, compression
and disk writes happen in the logger, on another CPU when there is one, never in the loop.
Faults and events are on disk before the logger reads on, and the logger finishes the file with
what it received if the control process dies. Numbers are written with 6 significant digits;
non-finite values become ``null``.
"""

from __future__ import annotations

import collections
import json
import math
import os
import socket
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.hal import children

_ARRAY = {"type": "array", "items": {"type": ["number", "null"]}}
_NULLABLE = {"type": ["array", "null"], "items": {"type": ["number", "null"]}}

_INTS = {"type": "array", "items": {"type": "integer"}}
_BASE = {"cycle": {"type": "integer"}, "t": {"type": "number"}}


def _schema(title: str, properties: Mapping[str, Any], required: Iterable[str] = ()) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": {**_BASE, **properties},
        "required": ["cycle", "t", *required],
    }


SCHEMAS: Mapping[str, dict[str, Any]] = {
    "/commands": _schema(
        "giwbc.Commands",
        {"phase": {"type": "string"}, "kind": {"type": "string"}, "q_ref": _ARRAY, "v_ref": _ARRAY, "kp": _ARRAY, "kd": _ARRAY, "tau_ff": _ARRAY},
        ("phase", "kind"),
    ),
    "/replies": _schema(
        "giwbc.Replies",
        {
            "q": _ARRAY, "dq": _ARRAY, "tau": _ARRAY, "temperature": _ARRAY, "error_code": _INTS, "missing": _INTS,
            "late": {"type": "integer"}, "corrupt": {"type": "integer"}, "unknown": {"type": "integer"},
        },
        ("q", "dq", "tau", "missing"),
    ),  # fmt: skip
    "/estimator": _schema(
        "giwbc.Estimate",
        {
            "imu_quaternion": _NULLABLE, "imu_angular_velocity": _NULLABLE, "imu_linear_acceleration": _NULLABLE,
            "imu_time": {"type": ["number", "null"]},
            "position": _NULLABLE, "quaternion": _NULLABLE, "linear_velocity": _NULLABLE, "angular_velocity": _NULLABLE,
            "contacts": {"type": "array", "items": {"type": "boolean"}}, "faults": {"type": "array", "items": {"type": "string"}},
        },
    ),  # fmt: skip
    "/timing": _schema(
        "giwbc.Timing",
        {
            "slot": {"type": "integer"}, "lateness_us": {"type": "number"}, "period_us": {"type": ["number", "null"]},
            "work_us": {"type": "number"}, "send_us": {"type": "number"}, "receive_us": {"type": "number"},
            "overrun": {"type": "boolean"},
        },
    ),  # fmt: skip
    "/faults": _schema(
        "giwbc.Fault",
        {"kind": {"type": "string"}, "message": {"type": "string"}, "joints": {"type": "array", "items": {"type": "string"}}},
        ("kind", "message"),
    ),
    "/events": _schema("giwbc.Event", {"event": {"type": "string"}, "detail": {"type": "object"}}, ("event",)),
}

def json_floats(values: Any) -> str:
    """A JSON array of numbers (6 significant digits; NaN and inf become null)."""
    a = np.asarray(values, dtype=float).ravel()
    if not np.all(np.isfinite(a)):
        return json.dumps([float(f"{x:.6g}") if np.isfinite(x) else None for x in a.tolist()])
    return "[" + ",".join(["%.6g"] * a.size) % tuple(a.tolist()) + "]"


def _ints(values: Any) -> str:
    return "[" + ",".join(map(str, np.asarray(values, dtype=np.int64).ravel().tolist())) + "]"


class _FloatBlock:
    """Several float arrays of fixed sizes rendered as JSON members with one ``%`` operation
    (one finiteness check, one format string): the per-cycle fast path."""

    def __init__(self, fields: Sequence[tuple[str, int]]) -> None:
        self.fields = tuple(fields)
        self.format = ",".join(f'"{k}":[' + ",".join(["%.6g"] * n) + "]" for k, n in self.fields)
        self.size = sum(n for _, n in self.fields)

    def render(self, *arrays: Any) -> str:
        flat = np.concatenate([np.asarray(a, dtype=float).ravel() for a in arrays])
        if flat.size == self.size and np.isfinite(flat).all():
            return self.format % tuple(flat.tolist())
        return ",".join(f'"{k}":{json_floats(a)}' for (k, _), a in zip(self.fields, arrays))


# ----------------------------------------------------------------------------- the wire
# A datagram carries records, each: u32 length, then a header (u8 record type, u64 cycle, f64 robot
# time) and the record's body (see the methods of RunLogWriter). Native byte order: one machine.
_COMMANDS, _REPLIES, _ESTIMATOR, _TIMING, _FAULT, _EVENT, _CLOSE = range(1, 8)
_HEADER = struct.Struct("=BQd")
_LENGTH = struct.Struct("=I")
_COUNTS = struct.Struct("=qqq")  # late, corrupt, unknown
_TIMES = struct.Struct("=qddddd?")  # slot, lateness, period (NaN: none), work, send, receive (us), overrun
_ESTIMATE_FLAGS = struct.Struct("=??H")  # has an IMU sample, has an estimate, bytes of the fault list (JSON)
_MAX_DATAGRAM = 64 * 1024  # a cycle's records are ~3 kB; more goes out in several datagrams
_TOPIC = {_COMMANDS: "/commands", _REPLIES: "/replies", _ESTIMATOR: "/estimator", _TIMING: "/timing", _FAULT: "/faults", _EVENT: "/events"}


def _text(value: str) -> bytes:
    raw = value.encode()[:255]
    return bytes((len(raw),)) + raw


def _floats(*arrays: Any) -> bytes:
    return np.concatenate([np.asarray(a, dtype=float).ravel() for a in arrays]).tobytes()


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
    """

    def __init__(self, path: str | os.PathLike[str], joint_names: Sequence[str], metadata: Mapping[str, Any] | None = None,
                 *, chunk_size: int = 256 * 1024, backlog: int = 4096, cpus: Iterable[int] | None = None) -> None:  # fmt: skip
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.joint_names = tuple(joint_names)
        meta = {"joint_names": list(self.joint_names), **(metadata or {})}
        self.counts: dict[str, int] = {topic: 0 for topic in SCHEMAS}  # records handed over, per channel
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
        args = (child, self._sock, self.path, self.joint_names, meta, chunk_size, cpus)
        self._process = children.start(_serve, args, "giwbc-runlog")
        child.close()
        self._sock.setblocking(False)

    @property
    def pid(self) -> int | None:
        """The logger process's id."""
        return self._process.pid

    # --- records: the control loop's side, packed and buffered -----------------------------------
    def _record(self, kind: int, cycle: int, t: float, body: bytes) -> None:
        if self._closed:
            raise ValueError(f"the run log {self.path} is closed")
        buffer = self._buffer
        buffer += _LENGTH.pack(_HEADER.size + len(body))
        buffer += _HEADER.pack(kind, max(0, int(cycle)), float(t))
        buffer += body
        self._buffered += 1
        self.counts[_TOPIC[kind]] += 1

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


# ----------------------------------------------------------------------------- the logger process
class _McapSink:
    """The MCAP file (in the logger process): JSON messages, a JSON schema per channel, LZ4 chunks."""

    def __init__(self, path: Path, joint_names: Sequence[str], metadata: Mapping[str, Any], chunk_size: int) -> None:
        from mcap.writer import CompressionType, Writer

        self._file = open(path, "wb")  # noqa: SIM115 - closed in finish()
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.LZ4)
        self._writer.start(profile="", library="giwbc")
        self._channels: dict[str, int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        self._writer.add_metadata("run", {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()})
        self._sequence: dict[str, int] = {topic: 0 for topic in SCHEMAS}
        n = self.n = len(joint_names)
        self._commands = _FloatBlock([(k, n) for k in ("q_ref", "v_ref", "kp", "kd", "tau_ff")])
        self._replies = _FloatBlock([(k, n) for k in ("q", "dq", "tau", "temperature")])
        self._imu = _FloatBlock([("imu_quaternion", 4), ("imu_angular_velocity", 3), ("imu_linear_acceleration", 3)])
        self._estimate = _FloatBlock([("position", 3), ("quaternion", 4), ("linear_velocity", 3), ("angular_velocity", 3)])

    def _add(self, topic: str, t: float, payload: str, *, flush: bool = False) -> None:
        ns = max(0, int(round(t * 1e9)))
        self._writer.add_message(self._channels[topic], ns, payload.encode(), ns, self._sequence[topic])
        self._sequence[topic] += 1
        if flush:  # faults and events: on disk now, whatever happens next
            self._writer.flush()
            self._file.flush()

    def write(self, record: memoryview) -> None:
        """One record from the wire (see :class:`RunLogWriter`)."""
        kind, cycle, t = _HEADER.unpack_from(record)
        body = record[_HEADER.size :]
        head = f'{{"cycle":{cycle},"t":{t!r}'
        n = self.n
        if kind == _COMMANDS:
            phase, k = _read_text(body, 0)
            frame_kind, k = _read_text(body, k)
            values = np.frombuffer(body, dtype=float, count=5 * n, offset=k).reshape(5, n)
            self._add("/commands", t, f'{head},"phase":"{phase}","kind":"{frame_kind}",{self._commands.render(*values)}}}')
        elif kind == _REPLIES:
            values = np.frombuffer(body, dtype=float, count=4 * n).reshape(4, n)
            error = np.frombuffer(body, dtype=np.int64, count=n, offset=32 * n)
            missing = np.frombuffer(body, dtype=bool, count=n, offset=40 * n)
            late, corrupt, unknown = _COUNTS.unpack_from(body, 41 * n)
            self._add("/replies", t, (
                f'{head},{self._replies.render(*values)},"error_code":{_ints(error)},"missing":{_ints(np.flatnonzero(missing))},'
                f'"late":{late},"corrupt":{corrupt},"unknown":{unknown}}}'
            ))  # fmt: skip
        elif kind == _ESTIMATOR:
            self._add("/estimator", t, f"{head},{self._estimator_body(body)}}}")
        elif kind == _TIMING:
            slot, lateness, period, work, send, receive, overrun = _TIMES.unpack_from(body)
            period_text = "null" if math.isnan(period) else f"{period:.1f}"
            self._add("/timing", t, (
                f'{head},"slot":{slot},"lateness_us":{lateness:.1f},"period_us":{period_text},"work_us":{work:.1f},'
                f'"send_us":{send:.1f},"receive_us":{receive:.1f},"overrun":{"true" if overrun else "false"}}}'
            ))  # fmt: skip
        elif kind in (_FAULT, _EVENT):
            self._add(_TOPIC[kind], t, bytes(body).decode(), flush=True)

    def _estimator_body(self, body: memoryview) -> str:
        has_imu, has_estimate, fault_bytes = _ESTIMATE_FLAGS.unpack_from(body)
        k = _ESTIMATE_FLAGS.size
        if has_imu:
            v = np.frombuffer(body, dtype=float, count=11, offset=k)
            sample = self._imu.render(v[:4], v[4:7], v[7:10]) + f',"imu_time":{float(v[10])!r}'
            k += 11 * 8
        else:
            sample = '"imu_quaternion":null,"imu_angular_velocity":null,"imu_linear_acceleration":null,"imu_time":null'
        if not has_estimate:
            return sample + ',"position":null,"quaternion":null,"linear_velocity":null,"angular_velocity":null,"contacts":[],"faults":[]'
        v = np.frombuffer(body, dtype=float, count=13, offset=k)
        k += 13 * 8
        n_contacts = body[k]
        contacts = np.frombuffer(body, dtype=bool, count=n_contacts, offset=k + 1)
        k += 1 + n_contacts
        faults = bytes(body[k : k + fault_bytes]).decode() if fault_bytes else "[]"
        flags = "[" + ",".join("true" if c else "false" for c in contacts.tolist()) + "]"
        return f'{sample},{self._estimate.render(v[:3], v[3:7], v[7:10], v[10:13])},"contacts":{flags},"faults":{faults}'

    def finish(self) -> None:
        try:
            self._writer.finish()
        finally:
            self._file.close()


def _read_text(body: memoryview, k: int) -> tuple[str, int]:
    n = body[k]
    return bytes(body[k + 1 : k + 1 + n]).decode(), k + 1 + n


def _serve(sock: socket.socket, parent_end: socket.socket, path: Path, joint_names: Sequence[str], metadata: Mapping[str, Any],
           chunk_size: int, cpus: list[int] | None) -> None:  # fmt: skip
    """The logger process: write records until told to close, or until the control process is gone."""
    parent_end.close()
    try:
        os.nice(10)  # the control loop first: a logger behind by a few cycles loses nothing (backlog)
        if cpus:
            os.sched_setaffinity(0, cpus)
    except (OSError, AttributeError):
        pass
    try:
        sink = _McapSink(path, joint_names, metadata, chunk_size)
    except OSError as error:
        sock.send(f"cannot write the run log {path}: {error}".encode())
        return
    status = b"ok"
    try:
        closing = False
        while not closing:
            data = sock.recv(1 << 20)
            if not data:
                break  # the control process is gone: finish the file with what came
            view, k = memoryview(data), 0
            while k < len(view):
                (size,) = _LENGTH.unpack_from(view, k)
                record = view[k + _LENGTH.size : k + _LENGTH.size + size]
                k += _LENGTH.size + size
                if record[0] == _CLOSE:
                    closing = True
                    break
                sink.write(record)
    except Exception as error:  # noqa: BLE001 - a full disk, a bad record: said at close
        status = f"writing the run log {path} failed: {type(error).__name__}: {error}".encode()
    finally:
        try:
            sink.finish()
        except Exception as error:  # noqa: BLE001
            status = f"finishing the run log {path} failed: {type(error).__name__}: {error}".encode()
        try:
            sock.send(status)
        except OSError:
            pass


def _plain(value: Any) -> Any:
    """JSON-ready copy (numpy arrays and scalars to lists and numbers)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


@dataclass
class RunLog:
    """A run log read back: run metadata and the messages of every channel, in order."""

    path: Path
    metadata: dict[str, Any]
    messages: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    schemas: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.metadata.get("joint_names", ()))

    def topic(self, name: str) -> list[dict[str, Any]]:
        return self.messages.get(name, [])

    def array(self, topic: str, key: str) -> np.ndarray:
        """One field of every message of a channel stacked into an array (None -> NaN)."""
        rows = [m[key] for m in self.topic(topic)]
        if rows and isinstance(rows[0], list):
            return np.array([[np.nan if x is None else x for x in r] for r in rows], dtype=float)
        return np.array([np.nan if x is None else x for x in rows], dtype=float)

    @property
    def faults(self) -> list[dict[str, Any]]:
        return self.topic("/faults")

    @property
    def events(self) -> list[dict[str, Any]]:
        return self.topic("/events")

    def event_names(self) -> list[str]:
        return [e["event"] for e in self.events]


def read_log(path: str | os.PathLike[str], topics: Iterable[str] | None = None) -> RunLog:
    """Load a run log (all channels, or ``topics``). A log whose run did not finish (no summary,
    a torn last record) is read sequentially up to the damage."""
    from mcap.reader import NonSeekingReader, make_reader

    path = Path(path)
    wanted = None if topics is None else set(topics)
    log = RunLog(path, {})
    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            metadata = list(reader.iter_metadata())
            records = list(reader.iter_messages(topics=wanted, log_time_order=False))
        except Exception:  # noqa: BLE001 - unfinished file: fall back to a sequential read
            f.seek(0)
            metadata, records = [], []
            try:
                for record in NonSeekingReader(f).iter_messages(topics=wanted, log_time_order=False):
                    records.append(record)
            except Exception:  # noqa: BLE001 - torn record at the end of a crashed run
                pass
            f.seek(0)
            try:
                for record in NonSeekingReader(f).iter_metadata():
                    metadata.append(record)
            except Exception:  # noqa: BLE001
                pass
    for record in metadata:
        if record.name == "run":
            log.metadata = {k: _maybe_json(v) for k, v in record.metadata.items()}
    for schema, channel, message in records:
        log.messages.setdefault(channel.topic, []).append(json.loads(message.data))
        if schema is not None and channel.topic not in log.schemas:
            log.schemas[channel.topic] = json.loads(schema.data)
    for msgs in log.messages.values():
        msgs.sort(key=lambda m: (m.get("cycle", 0), m.get("t", 0.0)))
    return log


def _maybe_json(value: str) -> Any:
    try:
        return json.loads(value)
    except (json.JSONDecodeError, TypeError):
        return value


__all__ = ["SCHEMAS", "RunLog", "RunLogWriter", "json_floats", "read_log"]
