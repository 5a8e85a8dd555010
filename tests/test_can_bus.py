"""CanBusLink over python-can's in-process ``virtual`` interface, and the bus capacity planner."""

from __future__ import annotations

import itertools
import time

import can
import pytest

from giwbc.hal.bus import (
    BusCapacityError,
    BusPlanSpec,
    CanBusLink,
    bus_load,
    check_capacity,
    frame_bits,
    plan_bus_loads,
)
from giwbc.hal.motor import MOTOR_PRESETS, MotorConfig
from giwbc.hal.protocols import FrameTraffic, MitProtocol

_channels = itertools.count()
MARGIN = 0.05  # s, generous: receive must return by deadline + MARGIN


def make_protocol() -> MitProtocol:
    ak, dm = MOTOR_PRESETS["AK70-10"], MOTOR_PRESETS["DM4310"]
    return MitProtocol([MotorConfig(1, ak, "a"), MotorConfig(2, ak, "b"), MotorConfig(3, dm, "c")])


@pytest.fixture
def buses():
    """(host side, motor side) virtual buses on a channel of their own."""
    ch = f"giwbc-test-{next(_channels)}-{time.monotonic_ns()}"
    host = can.Bus(interface="virtual", channel=ch)
    motors = can.Bus(interface="virtual", channel=ch)
    yield host, motors
    host.shutdown()
    motors.shutdown()


def reply_msg(p: MitProtocol, motor_id: int, position: float = 0.5) -> can.Message:
    f = p.encode_reply(motor_id, position, -1.0, 0.25)
    return can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False)


def test_send_batch_reaches_the_motors(buses):
    host, motors = buses
    p = make_protocol()
    link = CanBusLink(host, p, name="can0")
    batch = p.encode_commands([0.1, 0.2, 0.3], 0.0, 10.0, 0.5, [1.0, -1.0, 0.0])
    assert link.send(batch, deadline=time.perf_counter() + 0.5) == 3
    got = [motors.recv(timeout=0.5) for _ in range(3)]
    assert [m.arbitration_id for m in got] == [1, 2, 3]
    assert [bytes(m.data) for m in got] == [f.data for f in batch.frames()]
    assert not any(m.is_extended_id for m in got)
    c = link.counters
    assert (c.sent, c.dropped, c.retries, c.bus_errors) == (3, 0, 0, 0)


def test_receive_returns_all_replies_early(buses):
    host, motors = buses
    p = make_protocol()
    link = CanBusLink(host, p)
    for mid in (3, 1, 2):
        motors.send(reply_msg(p, mid, position=0.1 * mid))
    t0 = time.perf_counter()
    res = link.receive(deadline=t0 + 2.0)
    assert time.perf_counter() - t0 < 1.0  # returned once all three had replied
    assert res.complete and res.missing == ()
    assert sorted(res.replies) == [1, 2, 3]
    assert res.replies[2].position == pytest.approx(0.2, abs=2e-4)
    assert res.replies[3].temperature == 25.0 and res.replies[3].status == 1  # Damiao variant
    assert res.counters.received == 3 and res.counters.unknown == 0


def test_receive_keeps_latest_reply_per_motor(buses):
    host, motors = buses
    p = make_protocol()
    link = CanBusLink(host, p)
    motors.send(reply_msg(p, 1, position=0.1))
    motors.send(reply_msg(p, 1, position=0.7))
    res = link.receive(deadline=time.perf_counter() + 0.1, expect=())
    assert res.replies[1].position == pytest.approx(0.7, abs=2e-4)
    assert res.counters.received == 2
    assert res.missing == ()


def test_error_unknown_corrupt_and_remote_frames_are_counted(buses):
    host, motors = buses
    p = make_protocol()
    link = CanBusLink(host, p)
    motors.send(can.Message(is_error_frame=True, arbitration_id=0x20000080, data=bytes(8)))
    motors.send(can.Message(arbitration_id=0, is_extended_id=False, data=bytes.fromhex("77 00 00 00 00 00 00 00")))
    motors.send(can.Message(arbitration_id=0x1234, is_extended_id=True, data=bytes(8)))
    motors.send(can.Message(arbitration_id=1, is_extended_id=False, is_remote_frame=True, dlc=8))
    # 6 bytes from motor 1, whose AK70-10 (CubeMars variant) replies with 8: corrupt
    motors.send(can.Message(arbitration_id=0, is_extended_id=False, data=bytes.fromhex("01 00 00 00 00 00")))
    motors.send(reply_msg(p, 2))
    res = link.receive(deadline=time.perf_counter() + 0.2, expect=[2])
    c = res.counters
    assert (c.errors, c.unknown, c.corrupt, c.received) == (1, 3, 1, 1)
    assert list(res.replies) == [2]


def test_receive_returns_at_deadline_when_silent(buses):
    host, _ = buses
    link = CanBusLink(host, make_protocol())
    t0 = time.perf_counter()
    res = link.receive(deadline=t0 + 0.1)
    elapsed = time.perf_counter() - t0
    assert 0.1 - 0.005 <= elapsed <= 0.1 + MARGIN
    assert res.replies == {} and res.missing == (1, 2, 3) and not res.complete
    t0 = time.perf_counter()
    link.receive(deadline=t0 - 1.0)  # already past: returns at once
    assert time.perf_counter() - t0 < MARGIN


def test_full_transmit_queue_drops_without_crashing():
    ch = f"giwbc-test-full-{time.monotonic_ns()}"
    host = can.Bus(interface="virtual", channel=ch)
    tiny = can.Bus(interface="virtual", channel=ch, rx_queue_size=2)  # fills after 2 frames
    try:
        p = make_protocol()
        link = CanBusLink(host, p, send_timeout=1e-3, max_retries=1)
        frames = p.encode_commands(0, 0, 0, 0, 0).frames() + [p.enter_motor_mode(1)] * 2
        t0 = time.perf_counter()
        assert link.send(frames, deadline=t0 + 0.5) == 2
        assert time.perf_counter() - t0 < 0.1  # 3 frames x 2 attempts x 1 ms, not the 0.5 s deadline
        c = link.counters
        assert (c.sent, c.dropped, c.retries, c.bus_errors) == (2, 3, 3, 6)
    finally:
        host.shutdown()
        tiny.shutdown()


class FlakyBus(can.BusABC):
    """A bus whose send fails the first ``failures`` times and whose recv can raise."""

    def __init__(self, failures: int = 0, recv_raises: bool = False) -> None:
        super().__init__(channel="flaky")
        self.failures = failures
        self.recv_raises = recv_raises
        self.sent: list[can.Message] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.failures > 0:
            self.failures -= 1
            raise can.CanOperationError("Transmit buffer full")
        self.sent.append(msg)

    def _recv_internal(self, timeout):
        if self.recv_raises:
            raise can.CanOperationError("bus off")
        time.sleep(timeout or 0)
        return None, False


def test_send_retry_policy_is_bounded():
    p = make_protocol()
    link = CanBusLink(FlakyBus(failures=1), p, max_retries=2)
    assert link.send(p.encode_commands(0, 0, 0, 0, 0)) == 3
    c = link.counters
    assert (c.sent, c.dropped, c.retries, c.bus_errors) == (3, 0, 1, 1)

    link = CanBusLink(FlakyBus(failures=10**6), p, max_retries=2)
    assert link.send(p.encode_commands(0, 0, 0, 0, 0)) == 0
    c = link.counters
    assert (c.sent, c.dropped, c.retries, c.bus_errors) == (0, 3, 6, 9)


def test_send_after_deadline_drops_everything():
    p = make_protocol()
    bus = FlakyBus()
    link = CanBusLink(bus, p)
    assert link.send(p.encode_commands(0, 0, 0, 0, 0), deadline=time.perf_counter() - 1e-3) == 0
    assert link.counters.dropped == 3 and bus.sent == []


def test_receive_driver_error_returns_early():
    link = CanBusLink(FlakyBus(recv_raises=True), make_protocol())
    t0 = time.perf_counter()
    res = link.receive(deadline=t0 + 1.0)
    assert time.perf_counter() - t0 < 0.5
    assert res.counters.bus_errors == 1 and res.missing == (1, 2, 3)


def test_exchange_sends_then_collects(buses):
    host, motors = buses
    p = make_protocol()
    link = CanBusLink(host, p)
    for mid in (1, 2, 3):
        motors.send(reply_msg(p, mid))
    res = link.exchange(p.encode_commands(0, 0, 0, 0, 0), deadline=time.perf_counter() + 0.5)
    assert res.complete and res.counters.sent == 3 and res.counters.received == 3
    assert [motors.recv(timeout=0.5).arbitration_id for _ in range(3)] == [1, 2, 3]


# ----------------------------------------------------------------------------- capacity
def test_frame_bits():
    assert frame_bits(8) == 111 and frame_bits(8, worst_case=True) == 135
    assert frame_bits(6) == 95 and frame_bits(6, worst_case=True) == 115
    assert frame_bits(0) == 47 and frame_bits(0, worst_case=True) == 55
    assert frame_bits(8, extended_id=True) == 131 and frame_bits(8, extended_id=True, worst_case=True) == 160
    with pytest.raises(ValueError):
        frame_bits(9)


def test_29_motors_on_one_bus_at_1khz_is_refused():
    load = bus_load(1_000_000, 29, 1000.0, name="can0")
    assert load.bits_nominal == 29 * 222 and load.bits_worst == 29 * 270
    assert load.nominal == pytest.approx(6.438) and load.worst_case == pytest.approx(7.83)
    with pytest.raises(BusCapacityError) as e:
        check_capacity(load)
    msg = str(e.value)
    assert "'can0'" in msg and "643.8%" in msg and "80%" in msg


def test_capacity_limits():
    # 3 motors at 1 kHz: 66.6 % nominal / 81 % worst -> fits; 4 motors: 88.8 % -> refused
    assert check_capacity(bus_load(1_000_000, 3, 1000.0)).nominal == pytest.approx(0.666)
    with pytest.raises(BusCapacityError, match="88.8%"):
        check_capacity(bus_load(1_000_000, 4, 1000.0))
    # nominal under a raised 90 % limit, but worst-case stuffing beyond 100 %: still refused
    with pytest.raises(BusCapacityError, match="108.0% worst-case"):
        check_capacity(bus_load(1_000_000, 4, 1000.0), max_load=0.9)
    # mixed reply lengths: (111 + 95) + (111 + 111) bits nominal, (135 + 115) + (135 + 135) worst
    load = bus_load(500_000, 2, 1000.0, reply_bytes=[6, 8])
    assert (load.bits_nominal, load.bits_worst) == (428, 520)
    with pytest.raises(BusCapacityError, match="104.0% worst-case"):
        check_capacity(load, max_load=0.9)
    assert check_capacity(bus_load(500_000, 2, 500.0, reply_bytes=[6, 8]), max_load=0.9).worst_case == 0.52
    with pytest.raises(ValueError):
        bus_load(1_000_000, 2, 1000.0, reply_bytes=[8])
    with pytest.raises(ValueError):
        bus_load(2_000_000, 2, 1000.0)


def test_planner_names_every_bus_over_capacity():
    t = (FrameTraffic(8, 8),)
    ok = BusPlanSpec("arm", 1_000_000, t * 2)
    with pytest.raises(BusCapacityError) as e:
        plan_bus_loads([ok, BusPlanSpec("leg", 1_000_000, t * 5), BusPlanSpec("waist", 500_000, t * 3)], 1000.0)
    msg = str(e.value)
    assert "'leg'" in msg and "111.0%" in msg and "'waist'" in msg and "133.2%" in msg and "'arm'" not in msg
    loads = plan_bus_loads([ok], 1000.0)
    assert loads["arm"].nominal == pytest.approx(0.444)
