"""The run log written by a logger process: every record round-trips into the MCAP file, a crashed
control process still leaves a finished file with its faults, Ctrl-C does not stop the logger, a
stalled logger costs records (counted and noted) but never blocks the loop, and a logger that
cannot write is a clear error."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from types import SimpleNamespace

import numpy as np
import pytest

from giwbc.runlog import SCHEMAS, RunLogWriter, read_log
from giwbc.hal.safety import Fault, FaultKind
from giwbc.robot.interface import ImuReading

JOINTS = ("a", "b", "c")


def estimate(contacts=(True, False), faults=()):
    base = SimpleNamespace(position=[1.0, 2.0, 0.75], quaternion=[0, 0, 0, 1], linear_velocity=[0.1, 0, 0], angular_velocity=[0, 0, 0.2])
    return SimpleNamespace(base=base, contacts=np.array(contacts), faults=SimpleNamespace(ok=not faults, reasons=list(faults)))


def test_every_record_round_trips(tmp_path):
    path = tmp_path / "run.mcap"
    imu = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.0, 9.81]), 0.004)
    with RunLogWriter(path, JOINTS, {"robot": "test", "rates": [500, 50]}) as log:
        for cycle in range(3):
            t = 0.002 * cycle
            log.commands(cycle, t, "running", "command", [0.1, 0.2, 1 / 3], [0, 0, 0], [40, 40, 40], [1, 1, 1], [0.5, np.nan, -2])
            log.replies(cycle, t, [0.1, 0.2, 0.3], [0, 0.01, 0], [1, 2, 3], [30, np.nan, 31], [0, -1, 2], [False, True, False], 1, 2, 3)
            log.estimator(cycle, t, imu if cycle else None, estimate(faults=("stale_imu: no new sample",)) if cycle == 2 else None)
            log.timing(cycle, t, cycle, 1.5, None if cycle == 0 else 2000.2, 600.0, 80.0, 90.0, cycle == 2)
            log.flush()
        log.fault(Fault(FaultKind.MISSING_REPLIES, "motor b is silent", 2, 0.004, ("b",)))
        log.event(2, 0.004, "phase", {"phase": "damping", "array": np.arange(2)})
    assert log.counts == {"/commands": 3, "/replies": 3, "/estimator": 3, "/timing": 3, "/faults": 1, "/events": 1}
    run = read_log(path)
    assert run.joint_names == JOINTS and run.metadata["robot"] == "test" and run.metadata["rates"] == [500, 50]
    assert set(run.schemas) == set(SCHEMAS)
    commands = run.topic("/commands")
    assert [c["cycle"] for c in commands] == [0, 1, 2] and commands[1]["phase"] == "running" and commands[1]["kind"] == "command"
    assert commands[0]["q_ref"] == [0.1, 0.2, 0.333333] and commands[0]["tau_ff"] == [0.5, None, -2]
    replies = run.topic("/replies")[0]
    assert replies["temperature"] == [30, None, 31] and replies["error_code"] == [0, -1, 2] and replies["missing"] == [1]
    assert (replies["late"], replies["corrupt"], replies["unknown"]) == (1, 2, 3)
    est = run.topic("/estimator")
    assert est[0]["imu_quaternion"] is None and est[0]["position"] is None
    assert est[1]["imu_angular_velocity"] == [0.1, -0.2, 0.3] and est[1]["imu_time"] == 0.004
    assert est[2]["position"] == [1, 2, 0.75] and est[2]["contacts"] == [True, False] and est[2]["faults"] == ["stale_imu"]
    timing = run.topic("/timing")
    assert timing[0]["period_us"] is None and timing[2]["period_us"] == 2000.2 and timing[2]["overrun"] is True
    assert run.faults[0]["kind"] == "missing_replies" and run.faults[0]["joints"] == ["b"]
    assert run.events[0]["detail"] == {"phase": "damping", "array": [0, 1]}


def _child(script: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(script), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_crashed_control_process_leaves_a_finished_log_with_its_faults(tmp_path):
    path = tmp_path / "crash.mcap"
    proc = _child(
        """
        import os, sys
        from giwbc.runlog import RunLogWriter
        from giwbc.hal.safety import Fault, FaultKind
        log = RunLogWriter(sys.argv[1], ["a"])
        for cycle in range(100):
            log.commands(cycle, cycle * 0.002, "running", "command", [0], [0], [1], [0], [0])
            log.flush()
        log.fault(Fault(FaultKind.FALL, "base tilt 1.2 rad", 99, 0.198))
        print(log.pid, flush=True)
        os._exit(3)  # no close(): the control process dies
        """,
        str(path),
    )
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 3, err
    logger = int(out.strip())
    deadline = time.monotonic() + 30
    while _alive(logger) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(logger)
    run = read_log(path)  # a finished file: the summary is there (a torn one would be read sequentially)
    assert len(run.topic("/commands")) == 100
    assert run.faults[0]["kind"] == "fall" and "tilt" in run.faults[0]["message"]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead for our purpose
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_ctrl_c_stops_the_run_not_its_logger(tmp_path):
    log = RunLogWriter(tmp_path / "sigint.mcap", JOINTS)
    try:
        os.kill(log.pid, signal.SIGINT)
        os.kill(log.pid, signal.SIGTERM)
        time.sleep(0.2)
        log.commands(0, 0.0, "running", "command", *[np.zeros(3)] * 5)
        log.flush()
    finally:
        log.close()
    assert len(read_log(log.path).topic("/commands")) == 1


def test_a_stalled_logger_costs_records_but_never_blocks_the_loop(tmp_path):
    joints = [f"j{k}" for k in range(300)]  # 12 kB a record: the socket's buffer fills within the run
    log = RunLogWriter(tmp_path / "stalled.mcap", joints, backlog=4)
    os.kill(log.pid, signal.SIGSTOP)
    try:
        slowest = 0.0
        for cycle in range(3000):
            t0 = time.perf_counter()
            log.commands(cycle, cycle * 0.002, "running", "command", *[np.full(300, cycle, dtype=float)] * 5)
            log.flush()
            slowest = max(slowest, time.perf_counter() - t0)
        assert slowest < 0.05  # never waited for the logger
        assert log.dropped > 0
    finally:
        os.kill(log.pid, signal.SIGCONT)
        log.close()
    run = read_log(log.path)
    kept = [c["cycle"] for c in run.topic("/commands")]
    assert len(kept) + log.dropped == 3000
    assert kept == sorted(kept) and kept[-1] == 2999  # the oldest went; order kept
    assert any(e["event"] == "log_dropped" and e["detail"]["records"] == log.dropped for e in run.events)


def test_a_logger_that_cannot_write_is_a_clear_error(tmp_path):
    (tmp_path / "taken").mkdir()
    log = RunLogWriter(tmp_path / "taken", JOINTS)  # a directory: the logger cannot open it
    deadline = time.monotonic() + 30
    with pytest.raises(OSError, match="taken"):
        while time.monotonic() < deadline:  # the logger is gone: handing records over fails
            log.commands(0, 0.0, "running", "command", *[np.zeros(3)] * 5)
            log.flush()
            time.sleep(0.01)
    with pytest.raises(OSError, match="cannot write the run log"):
        log.close()


def test_the_logger_runs_where_it_is_told_and_below_the_loop(tmp_path):
    cpu = min(os.sched_getaffinity(0))
    log = RunLogWriter(tmp_path / "placed.mcap", JOINTS, cpus=[cpu])
    try:
        deadline = time.monotonic() + 10
        while os.sched_getaffinity(log.pid) != {cpu} and time.monotonic() < deadline:
            time.sleep(0.01)  # the child sets it up as it starts
        assert os.sched_getaffinity(log.pid) == {cpu}
        assert os.getpriority(os.PRIO_PROCESS, log.pid) >= os.getpriority(os.PRIO_PROCESS, 0) + 10 or os.getpriority(os.PRIO_PROCESS, log.pid) == 19
    finally:
        log.close()


def test_numeric_channels_round_trip_with_their_names_and_schema(tmp_path):
    from giwbc.runlog import Field, NumericChannel

    channel = NumericChannel("/gait", "test.Gait", (
        Field("phase", kind="label", labels=("stand", "swing")), Field("steps", kind="integer"), Field("dcm", 2), Field("time"),
    ))  # fmt: skip
    rows = [[1.0, 3.0, 0.25, -1 / 3, 0.5], [0.0, 4.0, np.nan, 0.1, np.inf], [7.0, 5.0, 0.0, 0.0, 1.0]]  # label 7: out of range
    with RunLogWriter(tmp_path / "gait.mcap", JOINTS, channels=[channel]) as log:
        for cycle, row in enumerate(rows):
            log.channel("/gait", cycle, 0.002 * cycle, np.array(row))
            log.flush()
        with pytest.raises(ValueError, match="need 5 values"):
            log.channel("/gait", 3, 0.006, np.zeros(4))
        with pytest.raises(ValueError, match="no numeric channel"):
            log.channel("/other", 3, 0.006, np.zeros(5))
    assert log.counts["/gait"] == 3
    run = read_log(log.path)
    gait = run.topic("/gait")
    assert [g["phase"] for g in gait] == ["swing", "stand", None] and [g["steps"] for g in gait] == [3, 4, 5]
    assert gait[0]["dcm"] == [0.25, -0.333333] and gait[1]["dcm"] == [None, 0.1] and gait[1]["time"] is None
    assert [c["phase"] for c in run.changes("/gait", ("phase",))] == ["swing", "stand", None]
    schema = run.schemas["/gait"]
    assert schema["title"] == "test.Gait" and set(schema["required"]) >= {"cycle", "t", "phase", "steps", "dcm", "time"}
    jsonschema = pytest.importorskip("jsonschema")
    for message in gait:
        jsonschema.Draft202012Validator(schema).validate(message)
    with pytest.raises(ValueError, match="own"):
        NumericChannel("/commands", "clash", (Field("x"),))
    with pytest.raises(ValueError, match="labels"):
        Field("phase", kind="label")
