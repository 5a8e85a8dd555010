"""Tasks: the robot-agnostic logic of learning problems (action → references, observation, reward)."""

from giwbc.tasks.balance import BalanceRewards, G1Balance, ResidualScales
from giwbc.tasks.cartpole import CartPoleBalance, CartPoleSwingUp, CartPoleTask
from giwbc.tasks.floating_base import FloatingBaseTask
from giwbc.tasks.standing import StandingTask
from giwbc.tasks.task import ActionBlock, InvalidActionError, ResidualLayout, Task

__all__ = [
    "ActionBlock",
    "BalanceRewards",
    "G1Balance",
    "ResidualScales",
    "CartPoleBalance",
    "CartPoleSwingUp",
    "CartPoleTask",
    "FloatingBaseTask",
    "InvalidActionError",
    "ResidualLayout",
    "StandingTask",
    "Task",
]
