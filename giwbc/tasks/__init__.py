"""Tasks: the robot-agnostic logic of learning problems (action → references, observation, reward)."""

from giwbc.tasks.cartpole import CartPoleBalance, CartPoleSwingUp, CartPoleTask
from giwbc.tasks.standing import StandingTask
from giwbc.tasks.task import ActionBlock, InvalidActionError, ResidualLayout, Task

_BALANCE = ("BalanceRewards", "G1Balance", "ResidualScales")


def __getattr__(name: str) -> object:
    """The G1 balance task on first use (it imports Pinocchio and the WBC)."""
    if name in _BALANCE:
        from giwbc.tasks import balance

        return getattr(balance, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ActionBlock",
    "BalanceRewards",
    "G1Balance",
    "ResidualScales",
    "CartPoleBalance",
    "CartPoleSwingUp",
    "CartPoleTask",
    "InvalidActionError",
    "ResidualLayout",
    "StandingTask",
    "Task",
]
