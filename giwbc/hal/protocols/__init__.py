"""Actuator protocols: one module per protocol, all implementing :class:`ActuatorProtocol`."""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

from giwbc.hal.protocols.base import (
    ActuatorProtocol,
    CanFrame,
    CanProtocolError,
    CommandBatch,
    CommandValueError,
    CORRUPT,
    ERROR_FRAME,
    REPLY,
    UNKNOWN,
    CorruptFrameError,
    DecodedReplies,
    EncodedCommand,
    FrameLengthError,
    FrameTraffic,
    MotorCommand,
    MotorReply,
    ProtocolConfigError,
    UnknownMotorError,
)
from giwbc.hal.protocols.mit import REPLY_VARIANTS, MitProtocol, MitReplyDecoder, pack_command

PROTOCOLS: Mapping[str, type[ActuatorProtocol]] = MappingProxyType({MitProtocol.name: MitProtocol})
"""Protocol classes by the name used in hardware.toml (``protocol = "mit"``)."""


def protocol_class(name: str) -> type[ActuatorProtocol]:
    """The protocol called ``name``; ``ValueError`` naming the known ones otherwise."""
    try:
        return PROTOCOLS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown actuator protocol {name!r}; known: {', '.join(PROTOCOLS)}") from None


__all__ = [
    "PROTOCOLS",
    "REPLY_VARIANTS",
    "ActuatorProtocol",
    "CanFrame",
    "CanProtocolError",
    "CommandBatch",
    "CommandValueError",
    "CORRUPT",
    "ERROR_FRAME",
    "REPLY",
    "UNKNOWN",
    "CorruptFrameError",
    "DecodedReplies",
    "EncodedCommand",
    "FrameLengthError",
    "FrameTraffic",
    "MitProtocol",
    "MitReplyDecoder",
    "MotorCommand",
    "MotorReply",
    "ProtocolConfigError",
    "UnknownMotorError",
    "pack_command",
    "protocol_class",
]
