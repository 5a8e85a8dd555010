"""Unitree's CRC32 of a low-level message (the ``crc`` field of ``LowCmd_`` and ``LowState_``).

As Unitree's SDK documents and computes it (``crc32_core``): the message's C struct (natural
alignment, :data:`~giwbc.hal.dds.layout.LOWCMD_C`) read as little-endian 32-bit words, all but the
last one (the ``crc`` itself), each word fed most significant bit first through CRC-32 with the
polynomial 0x04C11DB7, initial value 0xFFFFFFFF, no reflection and no final XOR (CRC-32/MPEG-2).

:func:`unitree_crc` computes it with :func:`zlib.crc32` (the same polynomial, bit-reflected): the
words' bytes in big-endian order with each byte's bits reversed, then the result's 32 bits reversed
and inverted; a few microseconds for a 2 kB state instead of ~1 ms for a Python bit loop.
:func:`crc32_reference` is the documented bit loop, for tests.
"""

from __future__ import annotations

import zlib

import numpy as np

_REVERSED = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))  # each byte's bits reversed (a bytes.translate table)
POLYNOMIAL = 0x04C11DB7


def _reverse32(value: int) -> int:
    """The 32 bits of ``value`` in reverse order."""
    return int.from_bytes(value.to_bytes(4, "little").translate(_REVERSED), "big")


def unitree_crc(c_struct: np.ndarray | bytes) -> int:
    """The CRC of a message given as its C struct bytes (the last 4 bytes, the crc field, excluded)."""
    raw = np.frombuffer(c_struct, dtype=np.uint8) if isinstance(c_struct, (bytes, bytearray, memoryview)) else c_struct
    n = (len(raw) // 4 - 1) * 4
    words = raw[:n].view("<u4").byteswap()  # each word's bytes most significant first
    crc = zlib.crc32(words.tobytes().translate(_REVERSED))
    return _reverse32(crc ^ 0xFFFFFFFF)


def crc32_reference(words: list[int]) -> int:
    """The documented algorithm over 32-bit ``words``, one bit at a time (slow; tests)."""
    crc = 0xFFFFFFFF
    for word in words:
        for bit in range(31, -1, -1):
            top = crc & 0x80000000
            crc = (crc << 1) & 0xFFFFFFFF
            if top ^ (((word >> bit) & 1) << 31):
                crc ^= POLYNOMIAL
    return crc


__all__ = ["POLYNOMIAL", "crc32_reference", "unitree_crc"]
