"""Compiled kernels of the CAN cycle's steady path (issue 37): a steady reply batch's key check and
payload arithmetic in one call, over the frames' raw bytes.

In the steady state every cycle's replies repeat the last batch's ids, lengths, byte 0 and buses;
:class:`~giwbc.hal.protocols.mit.MitReplyDecoder` keeps what follows from those and decodes only
the payloads. Done in numpy that is about twenty small-array calls per cycle (the key's two
comparisons, the bit fields, the temperatures), each paying numpy's per-call overhead; here it is
one loop over the frames. Same IEEE operations as the numpy form (an exact integer times a float64
scale plus an offset: no fused multiply-add, numba without ``fastmath``), so every field is equal
bit for bit; ``tests/test_hal_cycle_paths.py`` compares the compiled kernel, its plain Python
function (:func:`giwbc.util.jit.reference`) and the full decode on random batches.
"""

from __future__ import annotations

import numpy as np

from giwbc.util.jit import compiled

__all__ = ["KEY_BYTES", "held_commands", "joint_state_of_replies", "quiet_joints", "steady_key", "steady_replies", "warm_up"]

# A frame's key (struct can_frame bytes): the 32-bit can_id (flags included), the length, and the
# payload's byte 0 (frame byte 8).
KEY_BYTES = (0, 1, 2, 3, 4, 8)


def steady_key(octets: np.ndarray) -> np.ndarray:
    """The key bytes of frames given as their ``(M, 16)`` raw bytes: ``(M, 6)`` uint8."""
    return np.ascontiguousarray(octets[:, KEY_BYTES])


@compiled
def steady_replies(
    octets: np.ndarray,
    bus: np.ndarray,
    key_bus: np.ndarray,
    key: np.ndarray,
    scale: np.ndarray,
    low: np.ndarray,
    fields: np.ndarray,
    error: np.ndarray,
    cubemars: np.ndarray,
    limit: np.ndarray,
    values: np.ndarray,
    extra: np.ndarray,
    error_out: np.ndarray,
) -> bool:
    """Decode the replies ``octets`` (``(M, 16)`` uint8, ``struct can_frame`` each) that arrived on
    ``bus`` when their buses and key bytes (:data:`KEY_BYTES`) equal ``key_bus`` and ``key`` (those
    of the kept batch): ``values[k]`` = position, velocity, torque counts × ``scale[k]`` +
    ``low[k]``; ``extra[0, k]`` = byte 6 + ``fields[0, k]`` (temperature), ``extra[1, k]`` = byte 7
    + ``fields[1, k]`` (rotor temperature), ``extra[2, k]`` = byte 6 × ``fields[2, k]`` (volts);
    ``error_out[k]`` = byte 7 where ``cubemars[k]``, else ``error[k]``. False (outputs undefined)
    when the key differs or a CubeMars reply's byte 7 is above ``limit[k]`` (an undefined error code:
    corrupt): then the full decode decides."""
    m = octets.shape[0]
    if bus.shape[0] != m or key_bus.shape[0] != m or key.shape[0] != m:
        return False
    for k in range(m):
        if bus[k] != key_bus[k]:
            return False
        o = octets[k]
        q = key[k]
        if o[0] != q[0] or o[1] != q[1] or o[2] != q[2] or o[3] != q[3] or o[4] != q[4] or o[8] != q[5]:
            return False
    for k in range(m):
        o = octets[k]
        b4 = int(o[12])
        d6 = int(o[14])
        d7 = int(o[15])
        if cubemars[k]:
            if d7 > limit[k]:
                return False
            error_out[k] = d7
        else:
            error_out[k] = error[k]
        position = (int(o[9]) << 8) | int(o[10])
        velocity = (int(o[11]) << 4) | (b4 >> 4)
        torque = ((b4 & 0xF) << 8) | int(o[13])
        values[k, 0] = float(position) * scale[k, 0] + low[k, 0]
        values[k, 1] = float(velocity) * scale[k, 1] + low[k, 1]
        values[k, 2] = float(torque) * scale[k, 2] + low[k, 2]
        extra[0, k] = float(d6) + fields[0, k]
        extra[1, k] = float(d7) + fields[1, k]
        extra[2, k] = float(d6) * fields[2, k]
    return True


@compiled
def joint_state_of_replies(
    state: np.ndarray,
    scale: np.ndarray,
    offset: np.ndarray,
    joint: np.ndarray,
    rotor: np.ndarray,
    reported: np.ndarray,
    error: np.ndarray,
    joint_state: np.ndarray,
    temperature: np.ndarray,
    joint_error: np.ndarray,
) -> None:
    """One reply per motor, in plan order: motor ``k``'s (position, velocity, torque) ``state[k]``
    to its joint ``joint[k]``'s column of ``joint_state`` (rows q, dq, tau) as ``state × scale +
    offset`` (two roundings, as ``state *= scale; state += offset``), its temperature (the coil's
    ``rotor[k]`` where reported, else ``reported[k]``) and its error code."""
    for k in range(state.shape[0]):
        j = joint[k]
        for i in range(3):
            joint_state[i, j] = state[k, i] * scale[k, i] + offset[k, i]
        r = rotor[k]
        temperature[j] = reported[k] if r != r else r
        joint_error[j] = error[k]


@compiled
def held_commands(
    held: np.ndarray,
    joint: np.ndarray,
    scale: np.ndarray,
    offset: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    span: np.ndarray,
    levels: np.ndarray,
    template: np.ndarray,
    out: np.ndarray,
    clamped: np.ndarray,
) -> int:
    """MIT command frames of the joint-side ``(5, dofs)`` rows ``held`` (q, dq, kp, kd, tau), motor
    ``k`` driving joint ``joint[k]``: each field to the motor side (``x × scale + offset``), clamped
    to ``[lo, hi]`` (``clamped[k, i]`` says whether it was), quantized as
    :meth:`~giwbc.hal.protocols.mit.MitCommandEncoder.encode_rows` does (``ceil((x − lo) × levels /
    span − 0.5)``) and packed big-endian in bytes 8..15 of ``out[k]`` (``(N, 16)`` uint8), whose
    bytes 0..7 are ``template[k]``'s. Returns how many fields were clamped, or -1 at a NaN (outputs
    undefined: the general encoder names it)."""
    n = joint.shape[0]
    count = 0
    for k in range(n):
        j = joint[k]
        word = np.uint64(0)
        for i in range(5):
            x = held[i, j] * scale[i, k] + offset[i, k]
            if x != x:
                return -1
            low = lo[i, k]
            high = hi[i, k]
            below = x < low
            above = x > high
            clamped[k, i] = below or above
            if below or above:
                count += 1
            if below:
                x = low
            if above:
                x = high
            x -= low
            x *= levels[i]
            x /= span[i, k]
            x -= 0.5
            word |= np.uint64(np.ceil(x)) << np.uint64(48 - 12 * i)
        for b in range(8):
            out[k, b] = template[k, b]
            out[k, 8 + b] = np.uint8((word >> np.uint64(56 - 8 * b)) & np.uint64(0xFF))
    return count


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`steady_replies` for every argument type the
    decoder passes (C-contiguous arrays; the frames and the buses writable or read-only: frames read
    from a socket are a read-only view of its bytes), so a first compile never lands inside a
    control cycle (a reply decoder's construction calls it, before any bus is read)."""
    one = np.zeros(1, dtype=np.int64)
    for frozen_octets in (False, True):
        for frozen_bus in (False, True):
            octets = np.zeros((1, 16), dtype=np.uint8)
            bus = one.copy()
            octets.flags.writeable = not frozen_octets
            bus.flags.writeable = not frozen_bus
            steady_replies(octets, bus, one, steady_key(octets), np.ones((1, 3)), np.zeros((1, 3)), np.zeros((3, 1)), one,
                           np.zeros(1, dtype=bool), one, np.empty((1, 3)), np.empty((3, 1)), np.empty(1, dtype=np.int64))  # fmt: skip


@compiled
def quiet_joints(
    error_code: np.ndarray,
    status: np.ndarray,
    has_status: bool,
    temperature: np.ndarray,
    max_temperature: float,
    corrupt: np.ndarray,
    corrupt_total: np.ndarray,
    stale: np.ndarray,
    max_missing: int,
    q: np.ndarray,
    soft_lower: np.ndarray,
    soft_upper: np.ndarray,
    armed: np.ndarray,
    missing: np.ndarray,
    dq: np.ndarray,
    velocity_limit: np.ndarray,
    tau: np.ndarray,
    torque_limit: np.ndarray,
    torque_over: np.ndarray,
) -> bool:
    """The safety check's per-joint and per-bus tests in one loop
    (:meth:`~giwbc.hal.safety.SafetySupervisor.check`): arms the soft limits of the joints inside
    them (``armed``, as the check does), then True when nothing else would need a look: no error
    code, no motor reporting state 0 (``has_status``), no temperature above the limit, no corrupt
    frame this cycle or in the window, no joint silent for ``max_missing`` cycles, no armed joint
    measured outside its soft limits, no velocity or torque beyond its limit and no torque count
    running. False: the check's full path decides (and arms the same joints again: idempotent).
    The comparisons are numpy's (a NaN compares False)."""
    n = q.shape[0]
    for j in range(n):
        if q[j] >= soft_lower[j] and q[j] <= soft_upper[j]:
            armed[j] = True
    for b in range(corrupt.shape[0]):
        if corrupt[b] != 0:
            return False
    for b in range(corrupt_total.shape[0]):
        if corrupt_total[b] != 0:
            return False
    for j in range(n):
        if error_code[j] > 0 or temperature[j] > max_temperature or stale[j] >= max_missing or torque_over[j] != 0:
            return False
        if has_status and status[j] == 0:
            return False
        if armed[j] and not (q[j] >= soft_lower[j] and q[j] <= soft_upper[j]) and not missing[j]:
            return False
        if abs(dq[j]) > velocity_limit[j] or abs(tau[j]) > torque_limit[j]:
            return False
    return True


def warm_up_quiet_joints(n: int, buses: int) -> None:
    """Compile (or load from numba's cache) :func:`quiet_joints` for the arrays a cycle passes it:
    the measurements writable or read-only (a CAN robot's ``measured`` are read-only views), so no
    first compile lands inside a control cycle."""
    ints, floats, flags = np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n, dtype=bool)
    for frozen in (False, True):
        q, dq, tau = np.zeros(n), np.zeros(n), np.zeros(n)
        for a in (q, dq, tau):
            a.flags.writeable = not frozen
        quiet_joints(ints, ints, True, floats, 1.0, np.zeros(buses, dtype=np.int64), np.zeros(buses, dtype=np.int64), ints, 1,
                     q, floats, floats, flags.copy(), flags, dq, floats, tau, floats, ints)  # fmt: skip
