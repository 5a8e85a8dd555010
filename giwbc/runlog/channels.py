"""Fixed-size numeric channels: a controller's own per-cycle state in the run log.

A :class:`NumericChannel` declares a record of named fields (numbers, integers, labels drawn from
a fixed list, and fixed-size arrays of numbers); per cycle the control loop hands over one float64
vector of :attr:`NumericChannel.size` values (:meth:`RunLogWriter.channel
<giwbc.runlog.writer.RunLogWriter.channel>`: one ``tobytes``, no dict or string built in the loop)
and the logger process renders it as a JSON message with those names, under the channel's JSON
schema. A :class:`CycleRecorder` fills that vector from whatever it watches (the walker:
:mod:`giwbc.apps.deploy_walk_log`); the real-time runtime asks each of its recorders once per
logged cycle.

A channel's schema (its ``title`` and fields) is stored in the MCAP file with its messages, as the
built-in channels' are: a reader takes the layout from the file. A new field is a new schema (the
title names the record; change it when a field changes meaning).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from giwbc.runlog.schema import SCHEMAS, _schema, json_floats

WALKER_TOPIC = "/walker"  # the walking controller's state (giwbc.apps.deploy_walk_log)
KINDS = ("number", "integer", "label")


@dataclass(frozen=True)
class Field:
    """One field of a :class:`NumericChannel`: ``size`` values (1: a scalar, more: an array of
    numbers); ``kind`` ``number``, ``integer`` or ``label`` (the value indexes ``labels``)."""

    name: str
    size: int = 1
    kind: str = "number"
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"field {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if self.size < 1 or (self.size > 1 and self.kind != "number"):
            raise ValueError(f"field {self.name!r}: size must be >= 1 (arrays of numbers only), got {self.size} of {self.kind}")
        if (self.kind == "label") != bool(self.labels):
            raise ValueError(f"field {self.name!r}: labels are for (and needed by) a label field")

    def json_schema(self) -> dict[str, Any]:
        if self.kind == "label":
            return {"enum": [*self.labels, None]}
        item = {"type": ["integer" if self.kind == "integer" else "number", "null"]}
        return item if self.size == 1 else {"type": "array", "items": item, "minItems": self.size, "maxItems": self.size}


class NumericChannel:
    """A run-log channel of fixed-size numeric records (see the module docstring). Non-finite
    values are written as ``null``, as in the built-in channels; labels out of range too."""

    def __init__(self, topic: str, title: str, fields: Sequence[Field]) -> None:
        names = [f.name for f in fields]
        if not topic.startswith("/") or topic in SCHEMAS:
            raise ValueError(f"a numeric channel needs a topic of its own starting with '/', got {topic!r}")
        if len(set(names)) != len(names) or {"cycle", "t"} & set(names):
            raise ValueError(f"channel {topic}: field names must be unique and not 'cycle' or 't', got {names}")
        self.topic, self.title, self.fields = topic, title, tuple(fields)
        self.size = sum(f.size for f in self.fields)
        self.offsets: dict[str, slice] = {}
        k = 0
        for f in self.fields:
            self.offsets[f.name] = slice(k, k + f.size)
            k += f.size
        self._labels = [(self.offsets[f.name].start, f.labels) for f in self.fields if f.kind == "label"]
        # The fast path: one format string for a record of finite values.
        number = {"number": "%.6g", "integer": "%d", "label": '"%s"'}
        self._format = ",".join(
            f'"{f.name}":' + (number[f.kind] if f.size == 1 else "[" + ",".join(["%.6g"] * f.size) + "]") for f in self.fields
        )

    def schema(self) -> dict[str, Any]:
        """The channel's JSON schema (the fields required)."""
        return _schema(self.title, {f.name: f.json_schema() for f in self.fields}, [f.name for f in self.fields])

    def render(self, values: np.ndarray) -> str:
        """The JSON members of one record (without braces, ``cycle`` and ``t``): in the logger process."""
        args = values.tolist()
        if np.isfinite(values).all():
            for k, labels in self._labels:
                i = int(args[k])
                if not 0 <= i < len(labels):
                    break
                args[k] = labels[i]
            else:
                return self._format % tuple(args)
        return ",".join(f'"{f.name}":{_value(f, values[self.offsets[f.name]])}' for f in self.fields)


def _value(field: Field, values: np.ndarray) -> str:
    """One field as JSON, any value allowed (the slow path)."""
    if field.size > 1:
        return json_floats(values)
    x = float(values[0])
    if not np.isfinite(x):
        return "null"
    if field.kind == "label":
        k = int(x)
        return f'"{field.labels[k]}"' if 0 <= k < len(field.labels) and k == x else "null"
    return "%d" % x if field.kind == "integer" else "%.6g" % x


class CycleRecorder(Protocol):
    """Fills one :class:`NumericChannel`'s record each logged cycle (in the control loop: keep it small)."""

    channel: NumericChannel

    def sample(self) -> np.ndarray | None:
        """This cycle's values (float64, ``channel.size``; the writer copies them at once), or None
        when there is nothing new to log."""
        ...


__all__ = ["KINDS", "WALKER_TOPIC", "CycleRecorder", "Field", "NumericChannel"]
