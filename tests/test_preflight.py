"""SocketCAN pre-flight: parsing `ip -details -json link show`, verdicts with their fix commands,
and (where the kernel has AF_CAN and a vcan interface) the socketcan path over a real socket.

``fixtures/ip_link_can.json``: the ``lo`` entry is this machine's iproute2 6.1 output; the CAN
entries follow the keys iproute2 prints for CAN links (ip/iplink_can.c: ``info_data.state``,
``berr_counter``, ``restart_ms``, ``bittiming``, ``bittiming_const``, ``clock``) for a gs_usb
adapter in the states a bring-up meets: ready, wrong bitrate without restart-ms and a short
queue, down and never configured, bus-off, error-passive; and a ``vcan``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import can
import numpy as np
import pytest

from giwbc.hal.frames import frame_port, frames
from giwbc.hal.hardware import parse_hardware
from giwbc.hal.preflight import ERROR, WARNING, LinkInfo, parse_ip_links, preflight, read_links, read_sysfs_link

FIXTURE = Path(__file__).parent / "fixtures" / "ip_link_can.json"


def plan_for(channels: list[str], motors_per_bus: int = 3, interface: str = "socketcan"):
    buses = "".join(
        f'\n[[buses]]\nname = "b{k}"\ninterface = "{interface}"\nchannel = "{c}"\nbitrate = 1000000\nhost_id = 0\n'
        for k, c in enumerate(channels)
    )
    motors = "".join(
        f'\n[[motors]]\nbus = "b{k}"\nid = {j + 1}\njoint = "j{k}_{j}"\nmodel = "DM4310"\n'
        for k in range(len(channels))
        for j in range(motors_per_bus)
    )
    return parse_hardware(buses + motors + '\n[imu]\nsource = "emulated"\n', 500.0)


def test_parser_reads_every_field_of_the_fixture() -> None:
    links = parse_ip_links(FIXTURE.read_text())
    assert set(links) == {"lo", "can0", "can1", "can2", "can3", "can4", "vcan0"}
    c0 = links["can0"]
    assert (c0.up, c0.kind, c0.link_type, c0.txqlen, c0.bitrate, c0.restart_ms, c0.can_state) == (
        True, "can", "can", 128, 1000000, 100, "ERROR-ACTIVE",
    )
    assert (links["can1"].bitrate, links["can1"].restart_ms, links["can1"].txqlen) == (500000, 0, 2)
    c2 = links["can2"]
    assert (c2.up, c2.operstate, c2.bitrate, c2.can_state) == (False, "DOWN", None, "STOPPED")
    assert (links["can3"].can_state, links["can3"].berr_tx) == ("BUS-OFF", 248)
    assert (links["vcan0"].kind, links["vcan0"].link_type, links["vcan0"].bitrate) == ("vcan", "can", None)
    assert (links["lo"].kind, links["lo"].link_type) == (None, "loopback")


def test_parser_reads_this_machines_real_ip_output() -> None:
    done = subprocess.run(["ip", "-details", "-json", "link", "show"], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"`ip -details -json link show` failed here: {done.stderr.strip()}")
    links = parse_ip_links(done.stdout)
    assert "lo" in links and links["lo"].up and links["lo"].link_type == "loopback"


def test_verdicts_and_exact_fix_commands() -> None:
    links = parse_ip_links(FIXTURE.read_text())
    report = preflight(plan_for(["can0", "can1", "can2", "can3", "can4", "can9"]), links)
    by_bus: dict[str, list] = {}
    for f in report.findings:
        by_bus.setdefault(f.interface, []).append(f)
    assert "can0" not in by_bus  # ready
    # can1: wrong bitrate, no restart-ms (one down/set/up sequence fixes both), queue of 2 < 3
    c1 = by_bus["can1"]
    assert [f.severity for f in c1] == [ERROR, ERROR, ERROR]
    assert "bitrate 500000 bit/s, the plan says 1000000" in c1[0].problem
    assert c1[0].fix == (
        "sudo ip link set can1 down",
        "sudo ip link set can1 type can bitrate 1000000 restart-ms 100",
        "sudo ip link set can1 up",
    )
    assert c1[2].problem == "txqueuelen 2 is shorter than one cycle's burst of 3 frames"
    assert c1[2].fix == ("sudo ip link set can1 txqueuelen 32",)
    # can2: down and never configured
    assert by_bus["can2"][0].fix[1] == "sudo ip link set can2 type can bitrate 1000000 restart-ms 100"
    assert "bitrate not set" in by_bus["can2"][0].problem
    # can3: bus-off without automatic restart
    c3 = [f.problem for f in by_bus["can3"]]
    assert any("restart-ms is not set" in p for p in c3) and any("BUS-OFF" in p for p in c3)
    # can4: error-passive is a warning with the error counters
    (w,) = by_bus["can4"]
    assert w.severity == WARNING and "ERROR-PASSIVE (error counters tx 136, rx 0)" in w.problem
    # can9: missing
    assert by_bus["can9"][0].severity == ERROR and "does not exist" in by_bus["can9"][0].problem
    assert not report.ok
    # the combined fix list runs each command once, in order
    assert report.fix_commands[:4] == (
        "sudo ip link set can1 down",
        "sudo ip link set can1 type can bitrate 1000000 restart-ms 100",
        "sudo ip link set can1 up",
        "sudo ip link set can1 txqueuelen 32",
    )
    assert len(set(report.fix_commands)) == len(report.fix_commands)
    text = str(report)
    assert "all fixes, in order:" in text and "can9" in text


def test_ready_interfaces_pass_and_other_interfaces_are_skipped() -> None:
    links = parse_ip_links(FIXTURE.read_text())
    ok = preflight(plan_for(["can0"]), links)
    assert ok.ok and ok.findings == () and "all ready" in str(ok)
    virtual = preflight(plan_for(["can0"], interface="virtual"), links)
    assert virtual.ok and virtual.checked == () and virtual.skipped == ("b0",)


def test_burst_longer_than_queue() -> None:
    link = LinkInfo("can0", True, "UP", "can", "can", txqlen=4, bitrate=1000000, restart_ms=100, can_state="ERROR-ACTIVE")
    report = preflight(plan_for(["can0"], motors_per_bus=6), {"can0": link})
    (f,) = report.findings
    assert f.problem == "txqueuelen 4 is shorter than one cycle's burst of 6 frames"
    assert f.fix == ("sudo ip link set can0 txqueuelen 32",)


def test_vcan_is_refused_unless_allowed() -> None:
    links = parse_ip_links(FIXTURE.read_text())
    plan = plan_for(["vcan0"])
    assert not preflight(plan, links).ok
    assert preflight(plan, links, allow_virtual=True).ok


def test_sysfs_fallback(tmp_path: Path) -> None:
    d = tmp_path / "can0"
    d.mkdir()
    for name, value in (("flags", "0x40081"), ("type", "280"), ("tx_queue_len", "10"), ("operstate", "up")):
        (d / name).write_text(value + "\n")
    link = read_sysfs_link("can0", tmp_path)
    assert link == LinkInfo("can0", True, "UP", None, "can", 10)
    assert read_sysfs_link("can7", tmp_path) is None
    report = preflight(plan_for(["can0"]), {"can0": link})
    assert report.ok and [f.severity for f in report.findings] == [WARNING]


def test_read_links_runs_ip_and_keeps_the_named_interfaces() -> None:
    calls = []

    def run(cmd, **kw):
        calls.append(cmd)
        return SimpleNamespace(returncode=0, stdout=FIXTURE.read_text(), stderr="")

    links = read_links(["can0", "can7"], run=run)
    if not calls:
        pytest.skip("no `ip` on this machine: read_links used /sys/class/net")
    assert calls == [["ip", "-details", "-json", "link", "show"]]
    assert set(links) == {"can0"}


# ----------------------------------------------------------------------------- a real socket
def _vcan_or_skip() -> str:
    if not hasattr(socket, "AF_CAN"):
        pytest.skip("this Python has no socket.AF_CAN")
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as e:
        pytest.skip(f"the kernel has no AF_CAN sockets here ({e.strerror}); the vcan test needs the can and vcan modules")
    name = os.environ.get("GIWBC_VCAN", "vcan0")
    if not Path(f"/sys/class/net/{name}").exists():
        pytest.skip(f"no {name} interface (create it: sudo modprobe vcan && sudo ip link add dev {name} type vcan "
                    f"&& sudo ip link set {name} up; or set GIWBC_VCAN)")
    return name


def test_socketcan_batched_frames_over_a_vcan_interface() -> None:
    name = _vcan_or_skip()
    report = preflight(plan_for([name]).with_interface("socketcan"), allow_virtual=True)
    assert report.ok, str(report)
    tx = can.Bus(interface="socketcan", channel=name)
    rx = can.Bus(interface="socketcan", channel=name)
    try:
        ptx, prx = frame_port(tx), frame_port(rx)
        assert type(ptx).__name__ == "SocketPort"  # the batched path, not python-can's per-message one
        batch = frames(np.arange(1, 30), np.arange(29 * 8).reshape(29, 8) % 256)
        assert ptx.send(batch, time.perf_counter() + 0.5).sent == 29
        got = prx.receive(time.perf_counter() + 0.5, 29).frames
        np.testing.assert_array_equal(np.asarray(got["can_id"]), batch["can_id"])
        np.testing.assert_array_equal(np.asarray(got["data"]), batch["data"])
    finally:
        tx.shutdown()
        rx.shutdown()
