"""Every motor of several buses in one call: a robot's commands as one batch of frames, and the
replies of all its buses decoded at once.

A control cycle encodes a command for every motor and decodes a reply from every motor, spread over
several buses (the G1: 29 motors on 10). Per bus, a vectorized call costs about as much for 3
motors as for 30 (numpy's per-call overhead), so :class:`MultiBusCodec` does each in one call for
all buses when they all speak MIT mode, and falls back to each bus's protocol otherwise.

Motors are numbered in bus order, then each bus's motor order (a hardware plan's motor order).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from giwbc.hal.frames import frames, frames_of
from giwbc.hal.protocols.base import ActuatorProtocol, DecodedReplies
from giwbc.hal.kernels import held_commands
from giwbc.hal.protocols.mit import _LEVELS_F as _LEVELS
from giwbc.hal.protocols.mit import MitCommandEncoder, MitProtocol, MitReplyDecoder

SPECIAL_FRAMES = ("enter", "exit", "zero")
_LITTLE_ENDIAN = sys.byteorder == "little"  # encode_rows writes payloads as native 64-bit words


class MultiBusCodec:
    """Commands and replies of the motors of ``protocols`` (one protocol per bus), all at once."""

    def __init__(self, protocols: Sequence[ActuatorProtocol]) -> None:
        self.protocols = tuple(protocols)
        sizes = [len(p.motors) for p in self.protocols]
        self.bounds = np.cumsum([0, *sizes])
        self.motors = tuple(m for p in self.protocols for m in p.motors)
        self._can_ids = np.array([m.can_id for m in self.motors], dtype=np.int64)
        self._mit = all(type(p) is MitProtocol for p in self.protocols)
        self._encoder: MitCommandEncoder | None = None
        self._decoder: MitReplyDecoder | None = None
        if self._mit:
            # Command payloads do not depend on CAN ids: one encoder over every motor (any number of
            # them: ids are per bus) encodes them in one call.
            self._encoder = MitCommandEncoder(self.motors)
            self._decoder = MitReplyDecoder(self.protocols)  # type: ignore[arg-type]
            self._template = frames(self._can_ids, np.zeros((len(self.motors), 8), dtype=np.uint8))
            self._template_octets = self._template.view(np.uint8).reshape(len(self.motors), 16)
        self._special: dict[str, NDArray[Any]] = {}

    def encode_commands(self, position: Any, velocity: Any, kp: Any, kd: Any, torque: Any) -> tuple[NDArray[Any], NDArray[np.bool_]]:
        """Command frames for every motor (arrays in motor order, motor side) and which of their
        fields (position, velocity, kp, kd, torque) were clamped to the motors' ranges."""
        if self._encoder is not None:
            data, clamped = self._encoder.encode(position, velocity, kp, kd, torque)
            out = self._template.copy()
            out["data"] = data
            return out, clamped
        parts, clamped = [], []
        values = [np.broadcast_to(np.asarray(v, dtype=float), (len(self.motors),)) for v in (position, velocity, kp, kd, torque)]
        for p, a, b in zip(self.protocols, self.bounds[:-1], self.bounds[1:]):
            batch = p.encode_commands(*(v[a:b] for v in values))
            parts.append(frames(batch.arbitration_ids, batch.data, extended=batch.is_extended_id))
            clamped.append(batch.clamped)
        return np.concatenate(parts), np.vstack(clamped)

    def encode_rows(self, rows: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[np.bool_]] | None:
        """:meth:`encode_commands` of a ``(5, N)`` motor-side float block (overwritten), in the
        control loop's few calls; None when the buses do not all speak MIT mode (then call
        :meth:`encode_commands`)."""
        if self._encoder is None or not _LITTLE_ENDIAN:
            return None
        words, clamped = self._encoder.encode_rows(rows)
        out = self._template.copy()
        out.view(np.uint64).reshape(-1, 2)[:, 1] = words.byteswap()  # the payload, big-endian, in bytes 8..15 of each frame
        return out, clamped

    def encode_held(self, held: NDArray[np.float64], joint: NDArray[np.int64], scale: NDArray[np.float64],
                    offset: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[np.bool_], int] | None:  # fmt: skip
        """:meth:`encode_rows` of the joint-side ``(5, dofs)`` rows ``held`` taken at ``joint`` (one
        column per motor) and brought to the motor side as ``held × scale + offset``, in one compiled
        call (:func:`~giwbc.hal.kernels.held_commands`): the frames, the clamp mask and how many
        fields were clamped; None when the buses do not all speak MIT mode or a field is NaN (then
        take the general path, which names it)."""
        encoder = self._encoder
        if encoder is None:
            return None
        n = len(self.motors)
        out = np.empty(n, dtype=self._template.dtype)
        clamped = np.empty((n, 5), dtype=bool)
        count = held_commands(held, joint, scale, offset, encoder._lo_rows, encoder._hi_rows, encoder._span_rows, _LEVELS,
                              self._template_octets, out.view(np.uint8).reshape(n, 16), clamped)  # fmt: skip
        if count < 0:
            return None
        return out, clamped, count

    def special_frames(self, kind: str) -> NDArray[Any]:
        """The ``enter`` (motor mode), ``exit`` or ``zero`` frame of every motor."""
        if kind not in SPECIAL_FRAMES:
            raise ValueError(f"special frames are {SPECIAL_FRAMES}, got {kind!r}")
        if kind not in self._special:
            make = {"enter": "enter_motor_mode", "exit": "exit_motor_mode", "zero": "set_zero"}[kind]
            self._special[kind] = frames_of([getattr(p, make)(m.can_id) for p in self.protocols for m in p.motors])
        return self._special[kind]

    def decode_replies(self, bus: Any, batch: NDArray[Any]) -> DecodedReplies:
        """Decode ``batch``; ``bus[k]`` is the index of the bus frame ``k`` arrived on. Rows stay in
        input order; ``index`` is the motor's number across all buses."""
        bus = np.asarray(bus, dtype=np.int64).reshape(len(batch))
        if self._decoder is not None:
            return self._decoder.decode(bus, batch)
        order = np.argsort(bus, kind="stable")
        parts = [p.decode_frames(batch[bus == b]) for b, p in enumerate(self.protocols)]
        grouped = DecodedReplies.concatenate(parts, self.bounds[:-1].tolist())
        inverse = np.empty_like(order)
        inverse[order] = np.arange(order.size)
        return grouped.take(inverse)


__all__ = ["SPECIAL_FRAMES", "MultiBusCodec"]
