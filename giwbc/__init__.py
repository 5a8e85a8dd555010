"""giwbc: floating-base robots from reinforcement learning in simulation to a real robot on a CAN bus."""

__version__ = "0.1.0"

from giwbc.numerics import pin_kernels

pin_kernels()  # before anything loads numpy: the same floating-point kernels on every x86-64 machine (giwbc.numerics)

from giwbc import envs as envs  # noqa: E402  registers the giwbc/... gymnasium ids (imports gymnasium only)
