"""Reading a run log back (:func:`read_log`): every channel's messages as plain Python values."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.runlog.channels import WALKER_TOPIC


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

    @property
    def walker(self) -> list[dict[str, Any]]:
        """The walking controller's state, one message per logged control tick (``/walker``,
        :mod:`giwbc.apps.deploy_walk_log`; empty when no walker ran or the log predates it)."""
        return self.topic(WALKER_TOPIC)

    def changes(self, topic: str, keys: Sequence[str]) -> list[dict[str, Any]]:
        """The messages of ``topic`` where the values of ``keys`` differ from the message before
        (the first included): e.g. the walker's phase sequence, ``changes("/walker", ("phase", "stance"))``."""
        out, previous = [], None
        for message in self.topic(topic):
            values = tuple(message.get(k) for k in keys)
            if values != previous:
                out.append(message)
                previous = values
        return out


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


__all__ = ["RunLog", "read_log"]
