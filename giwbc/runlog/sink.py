"""The logger process: receives the control loop's binary records and writes the MCAP file
(JSON messages, a JSON schema per channel, LZ4 chunks); see :mod:`giwbc.runlog`."""

from __future__ import annotations

import json
import math
import os
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.runlog.extension import LogExtension, RobotState
from giwbc.runlog.schema import (
    _CLOSE, _COMMANDS, _COUNTS, _ESTIMATE_FLAGS, _ESTIMATOR, _EVENT, _FAULT, _HEADER, _LENGTH, _NUMERIC, _REPLIES, _TIMES,
    _TIMING, _TOPIC, SCHEMAS, _FloatBlock, _ints,
)  # fmt: skip
from giwbc.runlog.channels import NumericChannel

# ----------------------------------------------------------------------------- the logger process
class _McapSink:
    """The MCAP file (in the logger process): JSON messages, a JSON schema per channel, LZ4 chunks."""

    def __init__(self, path: Path, joint_names: Sequence[str], metadata: Mapping[str, Any], chunk_size: int,
                 extension: LogExtension | None = None, channels: Sequence[NumericChannel] = ()) -> None:  # fmt: skip
        from mcap.writer import CompressionType, Writer

        self._file = open(path, "wb")  # noqa: SIM115 - closed in finish()
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.LZ4)
        self._writer.start(profile="", library="giwbc")
        self._channels: dict[str, int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        self._numeric = tuple(channels)
        for channel in self._numeric:
            schema = channel.schema()
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[channel.topic] = self._writer.register_channel(channel.topic, "json", sid)
        self.extension = extension
        self.state = RobotState()  # the robot at the end of the last cycle, for the extension
        for topic, schema in (extension.schemas() if extension is not None else {}).items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        self._writer.add_metadata("run", {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()})
        self._sequence: dict[str, int] = {topic: 0 for topic in self._channels}
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
            if self.extension is not None:
                self.state.q, self.state.tau = values[0].copy(), values[2].copy()
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
            if self.extension is not None:  # the cycle's last record: the extension sees the whole cycle
                self.state.t = t
                self.extend(lambda extension: extension.update(self.state))
        elif kind == _NUMERIC:
            channel = self._numeric[body[0]]
            values = np.frombuffer(body, dtype=float, count=channel.size, offset=1)
            self._add(channel.topic, t, f"{head},{channel.render(values)}}}")
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
        if self.extension is not None:
            self.state.base_position, self.state.base_quaternion, self.state.contacts = v[:3].copy(), v[3:7].copy(), contacts.copy()
        k += 1 + n_contacts
        faults = bytes(body[k : k + fault_bytes]).decode() if fault_bytes else "[]"
        flags = "[" + ",".join("true" if c else "false" for c in contacts.tolist()) + "]"
        return f'{sample},{self._estimate.render(v[:3], v[3:7], v[7:10], v[10:13])},"contacts":{flags},"faults":{faults}'

    def extend(self, call: Any) -> None:
        """Write the messages ``call(extension)`` returns. An extension that fails is dropped, said in
        ``/events``: the run's own channels do not depend on it."""
        if self.extension is None:
            return
        try:
            messages = list(call(self.extension))
        except Exception as error:  # noqa: BLE001 - a broken viewer must not cost the log
            extension, self.extension = self.extension, None
            detail = json.dumps({"error": f"{type(error).__name__}: {error}"})
            self._add("/events", self.state.t, f'{{"cycle":0,"t":{self.state.t!r},"event":"log_extension_failed","detail":{detail}}}',
                      flush=True)
            try:
                extension.close()
            except Exception:  # noqa: BLE001
                pass
            return
        for topic, t, payload in messages:
            self._add(topic, t, payload)

    def finish(self) -> None:
        try:
            if self.extension is not None:
                self.extension.close()
        finally:
            try:
                self._writer.finish()
            finally:
                self._file.close()


def _read_text(body: memoryview, k: int) -> tuple[str, int]:
    n = body[k]
    return bytes(body[k + 1 : k + 1 + n]).decode(), k + 1 + n


def _serve(sock: socket.socket, parent_end: socket.socket, path: Path, joint_names: Sequence[str], metadata: Mapping[str, Any],
           chunk_size: int, cpus: list[int] | None, extension: LogExtension | None = None,
           channels: Sequence[NumericChannel] = ()) -> None:  # fmt: skip
    """The logger process: write records until told to close, or until the control process is gone."""
    parent_end.close()
    try:
        os.nice(10)  # the control loop first: a logger behind by a few cycles loses nothing (backlog)
        if cpus:
            os.sched_setaffinity(0, cpus)
    except (OSError, AttributeError):
        pass
    try:
        sink = _McapSink(path, joint_names, metadata, chunk_size, extension, channels)
    except OSError as error:
        sock.send(f"cannot write the run log {path}: {error}".encode())
        return
    status = b"ok"
    try:
        sink.extend(lambda extension: extension.open())
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


__all__: list[str] = []  # the logger process, started by RunLogWriter
