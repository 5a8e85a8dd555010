"""The control loop's few-call forms of the CAN codec against the general ones, on the G1's plan
(Damiao and CubeMars replies mixed over 10 buses): the steady reply decode (a batch whose ids,
lengths and byte 0 repeat the last one's) against a fresh decoder's full decode, and the block
command encoder against the per-field one, on random input."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.hal.frames import frames_of
from giwbc.hal.hardware import load_hardware
from giwbc.hal.protocols import CORRUPT, REPLY, CommandValueError
from giwbc.hal.protocols.mit import MitReplyDecoder
from giwbc.hal.protocols.multibus import MultiBusCodec

FIELDS = ("verdict", "index", "motor_id", "state", "temperature", "rotor_temperature", "error_code", "voltage", "status")


@pytest.fixture(scope="module")
def protocols(g1):
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    return [bus.make_protocol() for bus in plan.buses]


def _replies(protocols, rng):
    """One reply per motor in plan order, random states, temperatures and error codes; the bus of each."""
    frames, bus = [], []
    for b, protocol in enumerate(protocols):
        for motor in protocol.motors:
            r = motor.model
            cubemars = protocol._variants[protocol.index[motor.can_id]].name == "cubemars"
            frames.append(protocol.encode_reply(
                motor.can_id, rng.uniform(r.position.min, r.position.max), rng.uniform(r.velocity.min, r.velocity.max),
                rng.uniform(r.torque.min, r.torque.max), temperature=float(rng.integers(20, 90)),
                rotor_temperature=float(rng.integers(20, 90)), error_code=int(rng.integers(0, 8)) if cubemars else 0,
                status=int(rng.choice([0, 1, 8, 12])) if not cubemars else None))  # fmt: skip
            bus.append(b)
    return frames_of(frames), np.array(bus)


def _assert_same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_steady_decode_equals_a_fresh_decoder(protocols):
    rng = np.random.default_rng(7)
    warm = MitReplyDecoder(protocols)
    batch, bus = _replies(protocols, rng)
    warm.decode(bus, batch)  # keeps the steady key
    for _ in range(20):
        fresh, _ = _replies(protocols, rng)
        batch["data"][:, 1:] = fresh["data"][:, 1:]  # same ids, lengths and byte 0; new payloads
        assert warm._steady is not None
        steady = warm.decode(bus, batch)
        _assert_same(steady, MitReplyDecoder(protocols).decode(bus, batch))
        assert (steady.verdict == REPLY).all()


def test_steady_decode_falls_back_on_what_the_key_does_not_cover(protocols):
    rng = np.random.default_rng(8)
    warm = MitReplyDecoder(protocols)
    batch, bus = _replies(protocols, rng)
    warm.decode(bus, batch)
    cubemars = [k for k, (b, m) in enumerate((b, m) for b, p in enumerate(protocols) for m in p.motors)
                if protocols[b]._variants[protocols[b].index[m.can_id]].name == "cubemars"]  # fmt: skip
    assert cubemars, "the G1 plan has CubeMars wrist motors"
    batch["data"][cubemars[0], 7] = 200  # an undefined CubeMars error byte: corrupt
    steady = warm.decode(bus, batch)
    _assert_same(steady, MitReplyDecoder(protocols).decode(bus, batch))
    assert steady.verdict[cubemars[0]] == CORRUPT
    other = batch.copy()
    other["data"][3, 0] ^= 0x01  # byte 0 names another motor (or none): the key differs, full decode
    _assert_same(warm.decode(bus, other), MitReplyDecoder(protocols).decode(bus, other))
    swapped = bus.copy()
    swapped[[0, -1]] = swapped[[-1, 0]]  # the same frames on other buses
    _assert_same(warm.decode(swapped, batch), MitReplyDecoder(protocols).decode(swapped, batch))


def test_steady_kernel_compiled_equals_its_python(protocols):
    """giwbc.hal.kernels.steady_replies compiled against its plain Python function, bit for bit, on
    random payloads (every field), a changed key byte or bus (refused), an undefined CubeMars error
    byte (refused) and a batch of another length (refused)."""
    from giwbc.hal.kernels import KEY_BYTES, steady_replies
    from giwbc.util.jit import reference

    rng = np.random.default_rng(10)
    warm = MitReplyDecoder(protocols)
    batch, bus = _replies(protocols, rng)
    warm.decode(bus, batch)
    constants = warm._steady[0]
    m = len(batch)
    cubemars = np.flatnonzero(constants[6])
    assert len(cubemars)

    def run(kernel, octets, on):
        values, extra, error = np.full((m, 3), np.nan), np.full((3, m), np.nan), np.full(m, -7, dtype=np.int64)
        ok = kernel(octets, on, *constants, values, extra, error)
        return ok, values, extra, error

    def same(octets, on):
        a, b = run(steady_replies, octets, on), run(reference(steady_replies), octets, on)
        assert a[0] == b[0]
        if a[0]:
            for x, y in zip(a[1:], b[1:]):
                np.testing.assert_array_equal(x, y)
        return a

    for _ in range(30):
        octets = batch.view(np.uint8).reshape(m, 16).copy()
        octets[:, 9:14] = rng.integers(0, 256, size=(m, 5))  # random position, velocity, torque counts
        octets[:, 14] = rng.integers(0, 256, m)
        octets[:, 15] = np.where(np.isin(np.arange(m), cubemars), rng.integers(0, 8, m), rng.integers(0, 256, m))
        ok, values, extra, error = same(octets, bus)
        assert ok and np.isfinite(values).all()
        decoded = MitReplyDecoder(protocols).decode(bus, octets.view(batch.dtype).reshape(m))
        np.testing.assert_array_equal(values, decoded.state)
        np.testing.assert_array_equal(extra[0], decoded.temperature)
        np.testing.assert_array_equal(extra[1], decoded.rotor_temperature)
        np.testing.assert_array_equal(extra[2], decoded.voltage)
        np.testing.assert_array_equal(error, decoded.error_code)
        changed = octets.copy()
        changed[rng.integers(m), KEY_BYTES[rng.integers(len(KEY_BYTES))]] ^= 1 << int(rng.integers(8))
        assert not same(changed, bus)[0]
        moved = bus.copy()
        moved[rng.integers(m)] += 1
        assert not same(octets, moved)[0]
        undefined = octets.copy()
        undefined[rng.choice(cubemars), 15] = 200
        assert not same(undefined, bus)[0]
        assert not same(octets[:-1], bus[:-1])[0]


def test_no_kernel_compiles_in_a_cycle(protocols):
    """The decoder's construction compiles (or loads) the steady kernel for every type a cycle
    passes it: frames read from a socket (a read-only view of the bytes, np.frombuffer) and frames
    built in memory, on read-only or writable bus indices. A compile inside a cycle stalls the loop
    for up to a second (the watchdog stopped a first run for it)."""
    from giwbc.hal.kernels import steady_replies

    decoder = MitReplyDecoder(protocols)
    known = set(steady_replies.signatures)
    batch, bus = _replies(protocols, np.random.default_rng(12))
    from_socket = np.frombuffer(batch.tobytes(), dtype=batch.dtype)
    assert not from_socket.flags.writeable
    frozen_bus = bus.copy()
    frozen_bus.flags.writeable = False
    decoder.decode(bus, batch)  # keeps the steady key
    for frames in (batch, from_socket):
        for on in (bus, frozen_bus):
            decoded = decoder.decode(on, frames)
            _assert_same(decoded, MitReplyDecoder(protocols).decode(bus, batch))
    assert set(steady_replies.signatures) == known


def test_steady_joint_state_equals_the_general_update(g1):
    """giwbc.hal.kernels.joint_state_of_replies (CanRobot's steady cycle: every motor once, in plan
    order), compiled and as plain Python, against the general path's numpy on random replies: the
    same q, dq, tau (MotorGroup.states_to_joint), temperatures (the coil's where not NaN) and error
    codes, bit for bit."""
    from giwbc.hal.kernels import joint_state_of_replies
    from giwbc.hal.motor import MotorGroup
    from giwbc.util.jit import reference

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    motors = [m for bus in plan.buses for m in bus.motors]
    group = MotorGroup(motors)
    joint = np.array([g1.joint_names.index(m.joint) for m in motors], dtype=np.int64)
    rng = np.random.default_rng(11)
    m, n = len(motors), g1.dofs
    for _ in range(20):
        state = rng.uniform(-50, 50, (m, 3))
        rotor = np.where(rng.random(m) < 0.5, np.nan, rng.uniform(20, 90, m))
        reported = rng.uniform(20, 90, m)
        error = rng.integers(-1, 8, m)
        expected = np.zeros((3, n))
        expected[:, joint] = group.states_to_joint(state).T
        expected_temperature = np.full(n, np.nan)
        expected_temperature[joint] = np.where(np.isnan(rotor), reported, rotor)
        expected_error = np.full(n, -1)
        expected_error[joint] = error
        for kernel in (joint_state_of_replies, reference(joint_state_of_replies)):
            out, temperature, codes = np.zeros((3, n)), np.full(n, np.nan), np.full(n, -1, dtype=np.int64)
            kernel(state, group._state_scale, group._state_offset, joint, rotor, reported, error, out, temperature, codes)
            np.testing.assert_array_equal(out, expected)
            np.testing.assert_array_equal(temperature, expected_temperature)
            np.testing.assert_array_equal(codes, expected_error)


def test_block_encoder_equals_the_field_encoder(protocols):
    rng = np.random.default_rng(9)
    codec = MultiBusCodec(protocols)
    n = len(codec.motors)
    lo, hi = codec._encoder._lo.T, codec._encoder._hi.T
    for _ in range(20):
        rows = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), size=(5, n))  # some beyond the ranges: clamped
        rows[:, rng.integers(0, n, 3)] = lo[:, :3]  # exact range ends
        reference, clamped = codec.encode_commands(*rows)
        block, block_clamped = codec.encode_rows(rows.copy())
        np.testing.assert_array_equal(block.view(np.uint8), reference.view(np.uint8))
        np.testing.assert_array_equal(block_clamped, clamped)
        assert clamped.any() and not clamped.all()
    rows[2, 4] = np.nan
    with pytest.raises(CommandValueError, match="NaN"):
        codec.encode_rows(rows)


def test_held_command_kernel_equals_the_block_encoder(g1, protocols):
    """giwbc.hal.kernels.held_commands (the held command's frames in one compiled call), compiled and
    as plain Python, against MotorGroup.commands_to_motor + MultiBusCodec.encode_rows on random joint
    rows, some beyond the motors' ranges: the same frames byte for byte, the same clamp mask; a NaN
    is refused (-1), so the general encoder names it."""
    from giwbc.hal.kernels import held_commands
    from giwbc.hal.motor import MotorGroup
    from giwbc.hal.protocols.mit import _LEVELS_F
    from giwbc.util.jit import reference

    codec = MultiBusCodec(protocols)
    group = MotorGroup(codec.motors)
    joint = np.array([g1.joint_names.index(m.joint) for m in codec.motors], dtype=np.int64)
    encoder, n = codec._encoder, len(codec.motors)
    rng = np.random.default_rng(13)
    for _ in range(20):
        held = np.vstack([rng.uniform(-4, 4, g1.dofs), rng.uniform(-60, 60, g1.dofs), rng.uniform(0, 700, g1.dofs),
                          rng.uniform(0, 12, g1.dofs), rng.uniform(-400, 400, g1.dofs)])  # fmt: skip
        expected, expected_clamped = codec.encode_rows(group.commands_to_motor(held.take(joint, axis=1)))
        assert expected_clamped.any() and not expected_clamped.all()
        batch, clamped, count = codec.encode_held(held, joint, group._command_scale, group._command_offset)
        np.testing.assert_array_equal(batch.view(np.uint8), expected.view(np.uint8))
        np.testing.assert_array_equal(clamped, expected_clamped)
        assert count == int(expected_clamped.sum())
        out, mask = np.zeros((n, 16), dtype=np.uint8), np.zeros((n, 5), dtype=bool)
        args = (held, joint, group._command_scale, group._command_offset, encoder._lo_rows, encoder._hi_rows, encoder._span_rows, _LEVELS_F,
                codec._template_octets)  # fmt: skip
        assert reference(held_commands)(*args, out, mask) == count
        np.testing.assert_array_equal(out, expected.view(np.uint8).reshape(n, 16))
        np.testing.assert_array_equal(mask, expected_clamped)
    held[3, joint[5]] = np.nan
    assert held_commands(*args, out, mask) == -1  # (args holds this held)
    assert codec.encode_held(held, joint, group._command_scale, group._command_offset) is None


def test_the_held_command_encodes_as_any_command_does(g1):
    """CanRobot encodes set_joint_impedance's checked rows directly; a command set any other way
    (the same values in new arrays) goes the general way: the same frames, the same clamps."""
    import socket

    from giwbc.hal.bus import CanBusLink
    from giwbc.hal.can_robot import CanRobot
    from giwbc.hal.unix_bus import UnixCanBus
    from giwbc.robot.interface import ImpedanceCommand

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    ends = [socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET) for _ in plan.buses]
    links = [CanBusLink(UnixCanBus(f"held-{bus.name}", _socket=host), bus.make_protocol(), name=bus.name)
             for bus, (host, _) in zip(plan.buses, ends)]  # fmt: skip
    robot = CanRobot(g1, plan, links=links, wait_for_replies=False)
    try:
        rng = np.random.default_rng(3)
        n = g1.dofs
        for _ in range(10):
            command = ImpedanceCommand(rng.uniform(-3, 3, n), rng.uniform(-40, 40, n), rng.uniform(0, 600, n), rng.uniform(0, 10, n),
                                       rng.uniform(-300, 300, n))  # fmt: skip
            robot.set_joint_impedance(command)
            assert robot._held_rows() is not None
            before = robot.clamp_counts.copy()
            held, held_clamped = robot._frames("command")
            held_counts = robot.clamp_counts.copy()
            c = robot.command
            robot.command = ImpedanceCommand(*(np.array(v) for v in (c.q_ref, c.v_ref, c.kp, c.kd, c.tau_ff)))
            assert robot._held_rows() is None
            general, general_clamped = robot._frames("command")
            np.testing.assert_array_equal(held.view(np.uint8), general.view(np.uint8))
            assert held_clamped == general_clamped > 0
            np.testing.assert_array_equal(robot.clamp_counts - held_counts, held_counts - before)  # the same fields clamped
    finally:
        robot.close()
        for _, motor in ends:
            motor.close()


def _random_reports(g1, rng, cycles: int, buses: int):
    """Cycle reports and measurements, mostly quiet, with each anomaly the safety check looks at
    now and then: an error code, a disabled motor, heat, corrupt frames, silence, a joint beyond its
    soft limits (NaN too), fast joints, strong torques, a stale IMU, bus-off."""
    from giwbc.hal.can_robot import CycleReport
    from giwbc.robot.interface import ImuReading

    n = g1.dofs
    lo, hi = g1.position_limits
    q0 = g1.default_configuration()[7:]
    for k in range(cycles):
        q = q0 + rng.normal(0, 0.01, n)
        dq, tau = rng.normal(0, 1.0, n), rng.normal(0, 5.0, n)
        error, status = np.zeros(n, dtype=np.int64), np.ones(n, dtype=np.int64)
        temperature = np.where(rng.random(n) < 0.3, np.nan, rng.uniform(30, 60, n))
        corrupt, stale, missing = np.zeros(buses, dtype=np.int64), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool)
        bus_errors, bus_sent = np.zeros(buses, dtype=np.int64), np.full(buses, 3, dtype=np.int64)
        j = int(rng.integers(n))
        anomaly = int(rng.integers(24))
        if anomaly == 0:
            error[j] = 3
        elif anomaly == 1:
            status[j] = 0
        elif anomaly == 2:
            temperature[j] = 120.0
        elif anomaly == 3:
            corrupt[int(rng.integers(buses))] = int(rng.integers(1, 4))
        elif anomaly == 4:
            stale[j] = int(rng.integers(1, 6))
            missing[j] = True
        elif anomaly == 5:
            q[j] = hi[j] + 0.1 if np.isfinite(hi[j]) else 1e3
        elif anomaly == 6:
            q[j] = np.nan
        elif anomaly == 7:
            dq[j] = 1e3
        elif anomaly == 8:
            tau[j] = 1e4
        elif anomaly == 9:
            bus_errors[0], bus_sent[0] = 1, 0
        imu = None if anomaly == 10 else ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]), 0.002 * k)
        report = CycleReport(k, 0.002 * k, "command", missing, stale, error, temperature, 0, corrupt, 0, 0, 0, anomaly != 11, 0.0, 0.0,
                             None if anomaly == 12 else status, bus_sent, bus_errors, (None,) * buses)  # fmt: skip
        for a in (q, dq, tau):
            a.flags.writeable = False  # as a CAN robot's measured views
        yield report, q, dq, tau, imu


def test_safety_quiet_path_equals_the_full_check(g1, monkeypatch):
    """SafetySupervisor.check with its compiled quiet path (giwbc.hal.kernels.quiet_joints) against
    the same check forced down its full path, over one random sequence of cycles with every anomaly
    it tests: the same faults (kind, message, joints, in order) every cycle and the same history
    (armed limits, torque counts, corrupt window, IMU staleness, bus-off counts). The kernel's plain
    Python function answers as the compiled one; no cycle compiles it."""
    import giwbc.hal.safety as safety
    from giwbc.hal.kernels import quiet_joints
    from giwbc.util.jit import reference

    config = safety.SafetyConfig(max_missing_cycles=3, torque_cycles=2, bus_off_cycles=2, max_corrupt_frames=4, corrupt_window=10)
    buses = 10
    names = tuple(f"can{b}" for b in range(buses))
    fast = safety.SafetySupervisor(g1, config, n_buses=buses, bus_names=names)
    signatures = len(quiet_joints.signatures)
    full = safety.SafetySupervisor(g1, config, n_buses=buses, bus_names=names)
    python = safety.SafetySupervisor(g1, config, n_buses=buses, bus_names=names)
    rng = np.random.default_rng(5)
    quiet = 0
    for report, q, dq, tau, imu in _random_reports(g1, rng, 600, buses):
        expected_full = None
        with monkeypatch.context() as m:
            m.setattr(safety, "quiet_joints", lambda *args: False)
            expected_full = full.check(report, q, dq, tau, imu)
        got = fast.check(report, q, dq, tau, imu)
        with monkeypatch.context() as m:
            m.setattr(safety, "quiet_joints", reference(quiet_joints))
            got_python = python.check(report, q, dq, tau, imu)
        quiet += not got
        for faults in (got, got_python):
            assert [(f.kind, f.message, f.joints) for f in faults] == [(f.kind, f.message, f.joints) for f in expected_full]
        for s in (fast, python):
            for name in ("_armed_limits", "_torque_over", "_corrupt", "_corrupt_total", "_bus_down"):
                np.testing.assert_array_equal(getattr(s, name), getattr(full, name))
            assert s._imu_stale == full._imu_stale and s._down_any == full._down_any
    assert 300 < quiet < 600  # both paths taken, many times
    assert len(quiet_joints.signatures) == signatures  # warmed up at construction for read-only measurements
