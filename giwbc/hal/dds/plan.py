"""A robot driven over Unitree's low-level DDS interface: its plan (``[transport] kind = "dds"``).

Schema (``robots/g1/hardware_dds.toml``)::

    [transport]
    kind = "dds"            # the plan's transport (a CAN plan has [[buses]] instead)
    interface = "eth0"      # the network interface the robot is reached on (its 192.168.123.0/24)
    domain = 0              # DDS domain id, 0..232 (Unitree's robots: 0)
    mode_pr = 0             # LowCmd_.mode_pr: 0 = PR (ankle pitch/roll joints, the URDF's), 1 = AB (the ankle motors)
    state_timeout = 3.0     # s to wait for the robot's first rt/lowstate before refusing to start

    [imu]
    source = "dds"          # the LowState_'s imu_state (the pelvis IMU)

    [joints]                # the motor slot (index into motor_cmd / motor_state, 0..34) of each joint
    left_hip_pitch_joint = 0
    ...

Joints are mapped by name: the plan must name exactly the robot's joints, each slot once.
Every problem is one :class:`~giwbc.errors.HardwareConfigError` line naming the file and the entry.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from giwbc.errors import HardwareConfigError
from giwbc.hal.dds.config import check_domain, check_interface
from giwbc.hal.dds.layout import MOTORS
from giwbc.util.toml import TomlPlace

TRANSPORTS = ("can", "dds")
DDS_BUS = "dds"  # the name the supervisor and the summaries give the DDS link (one "bus": rt/lowcmd out, rt/lowstate in)


@dataclass(frozen=True)
class DdsImu:
    """The IMU of a DDS robot: the one in its ``LowState_`` (``source = "dds"``)."""

    source: str = "dds"
    device: str | None = None
    bus: str | None = None


@dataclass(frozen=True)
class DdsLink:
    """The DDS link as the supervisor and summaries see it: one "bus" carrying every motor."""

    name: str
    motors: tuple[str, ...]  # joint names, plan order


@dataclass(frozen=True)
class DdsPlan:
    """A validated DDS plan: interface, domain, the motor slot of each joint (plan order)."""

    source: str
    control_rate: float
    interface: str
    domain: int
    slots: Mapping[str, int]
    mode_pr: int = 0
    state_timeout: float = 3.0
    imu: DdsImu = DdsImu()
    transport: str = "dds"

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.slots)

    @property
    def buses(self) -> tuple[DdsLink, ...]:
        return (DdsLink(DDS_BUS, self.joints),)

    @property
    def motors(self) -> tuple[str, ...]:
        return self.joints

    @property
    def loads(self) -> Mapping[str, Any]:
        return MappingProxyType({})

    def motor(self, joint: str) -> tuple[DdsLink, int]:
        """The link and the motor slot driving ``joint``."""
        if joint not in self.slots:
            raise KeyError(f"{self.source}: no motor slot for joint {joint!r}")
        return self.buses[0], self.slots[joint]

    def slot_array(self, joint_names: Sequence[str]) -> list[int]:
        """The slot of each of ``joint_names`` (the robot's order), after :meth:`validate_joints`."""
        self.validate_joints(joint_names)
        return [self.slots[j] for j in joint_names]

    def validate_joints(self, joint_names: Sequence[str]) -> None:
        names = list(joint_names)
        missing = [j for j in names if j not in self.slots]
        extra = [j for j in self.slots if j not in set(names)]
        problems = ([f"no motor slot for robot joint(s) {missing}"] if missing else []) + (
            [f"slots for joint(s) the robot does not have: {extra}"] if extra else [])  # fmt: skip
        if problems:
            raise HardwareConfigError(f"{self.source}: " + "; ".join(problems))

    def with_interface(self, interface: str, domain: int | None = None) -> DdsPlan:
        """The same plan on another interface (and domain): the emulator's loopback."""
        from dataclasses import replace

        return replace(self, interface=check_interface(interface, self.source),
                       domain=self.domain if domain is None else check_domain(domain, self.source))  # fmt: skip


_TRANSPORT_KEYS = {"kind", "interface", "domain", "mode_pr", "state_timeout"}


def parse_dds_plan(data: Mapping[str, Any], control_rate: float, source: str) -> DdsPlan:
    """The :class:`DdsPlan` of a parsed TOML document whose ``[transport]`` says ``kind = "dds"``."""
    at = TomlPlace(source, HardwareConfigError)
    at.check_keys(data, {"transport", "imu", "joints", "description"}, ("transport", "joints"))
    t = data["transport"]
    if not isinstance(t, Mapping):
        raise at.fail("[transport] must be a table")
    where = TomlPlace(f"{source}: transport", HardwareConfigError)
    where.check_keys(t, _TRANSPORT_KEYS, ("kind", "interface", "domain"))
    kind = t["kind"]
    if kind != "dds":
        raise where.fail(f"kind must be one of {', '.join(TRANSPORTS)} (\"can\": describe [[buses]] and [[motors]] instead), got {kind!r}")
    if not (math.isfinite(control_rate) and control_rate > 0):
        raise at.fail(f"control rate must be > 0 Hz, got {control_rate}")
    interface = check_interface(t["interface"], f"{source}: transport")
    domain = check_domain(t["domain"], f"{source}: transport")
    mode_pr = t.get("mode_pr", 0)
    if mode_pr not in (0, 1) or isinstance(mode_pr, bool):
        raise where.fail(f"mode_pr must be 0 (PR: ankle pitch/roll joints) or 1 (AB: the ankle motors), got {mode_pr!r}")
    timeout = where.number(t, "state_timeout", 3.0)
    if not 0 < timeout <= 60:
        raise where.fail(f"state_timeout must be in (0, 60] s, got {timeout}")
    imu = data.get("imu", {"source": "dds"})
    if not isinstance(imu, Mapping) or set(imu) != {"source"} or imu["source"] != "dds":
        raise TomlPlace(f"{source}: imu", HardwareConfigError).fail(
            f"a DDS robot's IMU is the one in its rt/lowstate: [imu] source = \"dds\" and nothing else, got {dict(imu) if isinstance(imu, Mapping) else imu!r}"
        )
    joints = data["joints"]
    if not isinstance(joints, Mapping) or not joints:
        raise at.fail("[joints] must be a table of joint = motor slot (0..34)")
    seen: dict[int, str] = {}
    for joint, slot in joints.items():
        if isinstance(slot, bool) or not isinstance(slot, int) or not 0 <= slot < MOTORS:
            raise TomlPlace(f"{source}: joints", HardwareConfigError).fail(f"{joint}: motor slot must be an integer from 0 to {MOTORS - 1}, got {slot!r}")
        if slot in seen:
            raise TomlPlace(f"{source}: joints", HardwareConfigError).fail(f"{joint}: motor slot {slot} is already {seen[slot]!r}'s")
        seen[slot] = joint
    return DdsPlan(source, float(control_rate), interface, domain, MappingProxyType(dict(joints)), int(mode_pr), float(timeout))


__all__ = ["DDS_BUS", "TRANSPORTS", "DdsImu", "DdsLink", "DdsPlan", "parse_dds_plan"]
