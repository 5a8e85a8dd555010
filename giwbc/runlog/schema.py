"""The run log's format: the MCAP channels' JSON schemas, the JSON number rendering, and the
binary records the control loop hands to the logger (the wire between :mod:`~giwbc.runlog.writer`
and :mod:`~giwbc.runlog.sink`)."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Mapping, Sequence
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


# ----------------------------------------------------------------------------- the wire
# A datagram carries records, each: u32 length, then a header (u8 record type, u64 cycle, f64 robot
# time) and the record's body (see the methods of RunLogWriter). Native byte order: one machine.
_COMMANDS, _REPLIES, _ESTIMATOR, _TIMING, _FAULT, _EVENT, _CLOSE, _NUMERIC = range(1, 9)  # _NUMERIC: u8 channel index, then float64s
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


__all__ = ["SCHEMAS", "json_floats"]
