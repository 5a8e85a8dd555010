"""Channels derived from the control loop's records inside the logger process.

The loop hands over raw records only; a :class:`LogExtension` (e.g. the robot's 3D scene for
Foxglove: link transforms from forward kinematics, contact forces) turns the robot's state at the
end of each logged cycle into more messages, in the logger process, off the loop's thread and CPU,
at whatever reduced rate it likes. It may also stream them elsewhere (a live viewer).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

Message = tuple[str, float, str]  # (topic, robot time s, JSON text)


@dataclass
class RobotState:
    """What the logger knows of the robot at the end of a cycle (None: not logged yet)."""

    t: float = 0.0
    q: np.ndarray | None = None  # measured joint positions, in the log's joint order
    tau: np.ndarray | None = None  # measured joint torques
    base_position: np.ndarray | None = None  # the estimate, world frame
    base_quaternion: np.ndarray | None = None  # x, y, z, w
    contacts: np.ndarray | None = None  # contact flags, in the description's contact order
    contact_forces: np.ndarray | None = None  # (contacts, 3) world-frame forces where known (a simulator)


class LogExtension(Protocol):
    """Extra channels of a run log; every method runs in the logger process."""

    def schemas(self) -> Mapping[str, Mapping[str, Any]]:
        """``topic -> JSON schema`` of each extra channel (the schema's ``title`` names it)."""
        ...

    def open(self) -> Sequence[Message]:
        """Start (e.g. a live server); the first messages (e.g. the robot description)."""
        ...

    def update(self, state: RobotState) -> Sequence[Message]:
        """The messages for this cycle's state (none at cycles a reduced rate skips)."""
        ...

    def close(self) -> None:
        """Stop what :meth:`open` started."""
        ...


__all__ = ["LogExtension", "Message", "RobotState"]
