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

Arrays are in the order of the ``joint_names`` run metadata. Faults and events are flushed to
disk when written, so a crash keeps them. :func:`read_log` loads a file back.

Numbers are written with 6 significant digits (the fast path, ~4x quicker than ``json.dumps``
on float lists); non-finite values become ``null``.
"""

from __future__ import annotations

import json
import os
import queue
import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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


class _BackgroundFile:
    """A write-only binary stream whose ``write`` hands the bytes to a thread that writes the file.

    The control loop must not block on the disk (page-cache writeback can stall a ``write`` for
    tens of ms); the writer thread spends its time in the ``write`` system call, which releases the
    GIL. ``tell`` counts the bytes handed over; ``flush`` does not wait (the thread writes as soon
    as it can); ``close`` waits until everything is in the file.
    """

    def __init__(self, path: Path) -> None:
        self._file = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._queue: queue.Queue[bytes | None] = queue.Queue()
        self._position = 0
        self.error: OSError | None = None
        self._thread = threading.Thread(target=self._drain, name="giwbc-runlog", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while True:
            data = self._queue.get()
            try:
                if data is None:
                    return
                if self.error is None:
                    self._file.write(data)
            except OSError as error:  # a full disk must not stop the robot: remembered, reported at close
                self.error = error
            finally:
                self._queue.task_done()

    def write(self, data: bytes) -> int:
        chunk = bytes(data)
        self._queue.put(chunk)
        self._position += len(chunk)
        return len(chunk)

    def tell(self) -> int:
        return self._position

    @property
    def thread_id(self) -> int | None:
        """The writer thread's native id (to give it the control loop's scheduling policy)."""
        return self._thread.native_id

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self._file.close()


class RunLogWriter:
    """Writes one run's MCAP log (see the module docstring). Use as a context manager or close().

    Messages are serialized and chunked (LZ4, ``chunk_size`` bytes) in the caller's thread; the file
    itself is written by a background thread, so the control loop never waits for the disk.
    """

    def __init__(self, path: str | os.PathLike[str], joint_names: Sequence[str], metadata: Mapping[str, Any] | None = None,
                 *, chunk_size: int = 64 * 1024) -> None:  # fmt: skip
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = _BackgroundFile(self.path)
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.LZ4)  # type: ignore[arg-type]
        self._writer.start(profile="", library="giwbc")
        self._channels: dict[str, int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        self.joint_names = tuple(joint_names)
        meta = {"joint_names": list(self.joint_names), **(metadata or {})}
        self._writer.add_metadata("run", {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.items()})
        self.counts: dict[str, int] = {topic: 0 for topic in SCHEMAS}
        n = len(self.joint_names)
        self._commands = _FloatBlock([(k, n) for k in ("q_ref", "v_ref", "kp", "kd", "tau_ff")])
        self._replies = _FloatBlock([(k, n) for k in ("q", "dq", "tau", "temperature")])
        self._imu = _FloatBlock([("imu_quaternion", 4), ("imu_angular_velocity", 3), ("imu_linear_acceleration", 3)])
        self._estimate = _FloatBlock([("position", 3), ("quaternion", 4), ("linear_velocity", 3), ("angular_velocity", 3)])
        self._closed = False

    @property
    def thread_id(self) -> int | None:
        """Native id of the thread writing the file: a runtime running under ``SCHED_FIFO`` gives it
        the same policy, or a preempted writer holding the GIL would stall the loop."""
        return self._file.thread_id

    def _add(self, topic: str, t: float, payload: str, *, flush: bool = False) -> None:
        ns = max(0, int(round(t * 1e9)))
        self._writer.add_message(self._channels[topic], ns, payload.encode(), ns, self.counts[topic])
        self.counts[topic] += 1
        if flush:
            self._writer.flush()

    def commands(self, cycle: int, t: float, phase: str, kind: str, q_ref: Any, v_ref: Any, kp: Any, kd: Any, tau_ff: Any) -> None:
        body = self._commands.render(q_ref, v_ref, kp, kd, tau_ff)
        self._add("/commands", t, f'{{"cycle":{cycle},"t":{float(t)!r},"phase":"{phase}","kind":"{kind}",{body}}}')

    def replies(self, cycle: int, t: float, q: Any, dq: Any, tau: Any, temperature: Any, error_code: Any,
                missing: Any, late: int, corrupt: int, unknown: int) -> None:  # fmt: skip
        body = self._replies.render(q, dq, tau, temperature)
        self._add("/replies", t, (
            f'{{"cycle":{cycle},"t":{float(t)!r},{body},"error_code":{_ints(error_code)},'
            f'"missing":{_ints(np.flatnonzero(missing))},"late":{int(late)},"corrupt":{int(corrupt)},"unknown":{int(unknown)}}}'
        ))  # fmt: skip

    def estimator(self, cycle: int, t: float, imu: Any, estimate: Any) -> None:
        """The IMU sample (an ``ImuReading`` or None) and the estimate (an ``Estimate`` or None)."""
        if imu is None:
            sample = '"imu_quaternion":null,"imu_angular_velocity":null,"imu_linear_acceleration":null,"imu_time":null'
        else:
            sample = self._imu.render(imu.quaternion, imu.angular_velocity, imu.linear_acceleration) + f',"imu_time":{float(imu.time)!r}'
        if estimate is None:
            body = '"position":null,"quaternion":null,"linear_velocity":null,"angular_velocity":null,"contacts":[],"faults":[]'
        else:
            b = estimate.base
            faults = [] if estimate.faults.ok else [r.split(":", 1)[0] for r in estimate.faults.reasons]
            contacts = "[" + ",".join("true" if c else "false" for c in np.asarray(estimate.contacts).ravel().tolist()) + "]"
            body = (
                self._estimate.render(b.position, b.quaternion, b.linear_velocity, b.angular_velocity)
                + f',"contacts":{contacts},"faults":{json.dumps(faults)}'
            )
        self._add("/estimator", t, f'{{"cycle":{cycle},"t":{float(t)!r},{sample},{body}}}')

    def timing(self, cycle: int, t: float, slot: int, lateness_us: float, period_us: float | None, work_us: float,
               send_us: float, receive_us: float, overrun: bool) -> None:  # fmt: skip
        period = "null" if period_us is None else f"{period_us:.1f}"
        self._add("/timing", t, (
            f'{{"cycle":{cycle},"t":{float(t)!r},"slot":{slot},"lateness_us":{lateness_us:.1f},"period_us":{period},'
            f'"work_us":{work_us:.1f},"send_us":{send_us:.1f},"receive_us":{receive_us:.1f},"overrun":{"true" if overrun else "false"}}}'
        ))  # fmt: skip

    def fault(self, fault: Any) -> None:
        """A :class:`~giwbc.hal.safety.Fault` (flushed to disk at once)."""
        d = fault.as_dict()
        self._add("/faults", d["time"], json.dumps({"cycle": d["cycle"], "t": d["time"], **{k: d[k] for k in ("kind", "message", "joints")}}), flush=True)

    def event(self, cycle: int, t: float, event: str, detail: Mapping[str, Any] | None = None, *, flush: bool = True) -> None:
        self._add("/events", t, json.dumps({"cycle": cycle, "t": t, "event": event, "detail": _plain(detail or {})}), flush=flush)

    def close(self) -> None:
        """Finish the file (summary, indexes) and wait until it is on disk; OSError if writing failed."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()
        if self._file.error is not None:
            raise self._file.error

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


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
