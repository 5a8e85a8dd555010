"""Hardware plan of a robot: CAN buses, the motors on them, the IMU source (``hardware.toml``).

Schema::

    [[buses]]                      # one per CAN interface
    name = "can0"                  # referenced by motors
    interface = "socketcan"        # python-can interface (tests and dry runs override: "virtual")
    channel = "can0"
    bitrate = 1000000
    max_load = 0.8                 # optional, nominal utilisation limit (default 0.8)
    protocol = "mit"               # optional, default "mit"
    host_id = 0                    # optional (MIT): the id the motors reply with (their master
                                   # id); only frames with it are replies. Without it replies are
                                   # told by length and byte 0 alone, and some foreign frames
                                   # pass for replies (a Damiao bus: byte 0 has a 4-bit id)

    [[motors]]
    bus = "can0"
    id = 1                         # CAN id, unique per bus
    joint = "left_hip_pitch_joint" # unique
    model = "DM10010"              # a preset of giwbc.hal.motor.MOTOR_PRESETS
    sign = 1                       # optional, +1 / -1
    zero_offset = 0.0              # optional, rad, joint angle at which the motor reads 0
    gear_ratio = 1.0               # optional, motor rad per joint rad
    reply = "damiao"               # optional, reply variant (default: the model's)
    torque = 150.0                 # optional overrides of the model's ranges: x, [min, max] or
                                   # {min = .., max = ..} for position, velocity, kp, kd, torque

    [imu]
    source = "emulated"            # or "serial": an Xsens MTi (device = "/dev/ttyUSB0",
                                   # baudrate = 921600), see giwbc.hal.xsens
                                   # or "can": bus = "can4", rate = 500.0 and [[imu.frames]]
                                   # (ids, byte layout, scales), see giwbc.hal.can_imu

A file with a ``[transport]`` table (``kind = "dds"``) is a robot on Unitree's low-level DDS
interface instead: :func:`load_hardware` returns a :class:`giwbc.hal.dds.plan.DdsPlan`.

Validation names the file and the problem: unknown keys, unknown bus, duplicate CAN id on a bus,
duplicate joint, unknown model preset, bad ranges, ambiguous replies, and buses over capacity at
the control rate. :func:`validate_joints` checks the plan against the robot's joint names (and
optionally effort limits) handed in by the caller.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import can

from giwbc.hal.bus import DEFAULT_MAX_LOAD, BusCapacityError, BusLoad, BusPlanSpec, CanBusLink, plan_bus_loads
from giwbc.hal.can_imu import CanImuLayout, parse_can_imu_layout
from giwbc.hal.motor import RANGE_FIELDS, MotorConfig, motor_preset
from giwbc.hal.protocols import ActuatorProtocol, ProtocolConfigError, protocol_class
from giwbc.errors import HardwareConfigError
from giwbc.util.toml import TomlPlace, parse_toml

IMU_SOURCES = ("emulated", "serial", "can")


@dataclass(frozen=True)
class BusConfig:
    """One CAN bus and its motors, in file order."""

    name: str
    interface: str
    channel: str | int
    bitrate: int
    max_load: float = DEFAULT_MAX_LOAD
    protocol: str = "mit"
    motors: tuple[MotorConfig, ...] = ()
    host_id: int | None = None

    def make_protocol(self, **kwargs: Any) -> ActuatorProtocol:
        """The protocol instance for this bus's motors (with the bus's ``host_id``, if any)."""
        if self.host_id is not None:
            kwargs.setdefault("host_id", self.host_id)
        return protocol_class(self.protocol)(self.motors, **kwargs)

    def open(self, **kwargs: Any) -> can.BusABC:
        """Open the python-can bus (``kwargs`` go to ``can.Bus``)."""
        return can.Bus(interface=self.interface, channel=self.channel, bitrate=self.bitrate, **kwargs)

    def open_link(self, **kwargs: Any) -> CanBusLink:
        """Open the bus and wrap it in a :class:`CanBusLink` (``kwargs`` go to the link)."""
        return CanBusLink(self.open(), self.make_protocol(), name=self.name, **kwargs)


@dataclass(frozen=True)
class ImuConfig:
    """Where the IMU comes from: ``emulated``, a ``serial`` device, or frames on a ``can`` bus."""

    source: str
    device: str | None = None
    baudrate: int | None = None
    bus: str | None = None
    layout: CanImuLayout | None = None

    @property
    def can_id(self) -> int | None:
        """The first frame id of a CAN IMU (None otherwise)."""
        return self.layout.frames[0].can_id if self.layout is not None else None


@dataclass(frozen=True)
class HardwarePlan:
    """A validated hardware plan; ``loads`` are the bus loads at ``control_rate``."""

    source: str
    control_rate: float
    buses: tuple[BusConfig, ...]
    imu: ImuConfig
    loads: Mapping[str, BusLoad]

    @property
    def motors(self) -> tuple[MotorConfig, ...]:
        return tuple(m for b in self.buses for m in b.motors)

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(m.joint for m in self.motors)

    def bus(self, name: str) -> BusConfig:
        for b in self.buses:
            if b.name == name:
                return b
        raise KeyError(f"{self.source}: no bus {name!r}")

    def motor(self, joint: str) -> tuple[BusConfig, MotorConfig]:
        """The bus and motor driving ``joint``."""
        for b in self.buses:
            for m in b.motors:
                if m.joint == joint:
                    return b, m
        raise KeyError(f"{self.source}: no motor drives joint {joint!r}")

    def routing(self, joint_names: Sequence[str]) -> tuple[tuple[str, int], ...]:
        """For each robot joint (in the robot's order): (bus name, index of its motor on that bus)."""
        validate_joints(self, joint_names)
        where = {m.joint: (b.name, i) for b in self.buses for i, m in enumerate(b.motors)}
        return tuple(where[j] for j in joint_names)

    def with_imu(self, imu: ImuConfig) -> HardwarePlan:
        """The same plan with another IMU source (bus loads and CAN ids checked again)."""
        return replace(self, imu=imu, loads=MappingProxyType(_loads(self.source, self.buses, imu, self.control_rate)))

    def with_interface(self, interface: str) -> HardwarePlan:
        """The same plan with every bus on another python-can interface (e.g. ``"virtual"``)."""
        return replace(self, buses=tuple(replace(b, interface=interface) for b in self.buses))


# ----------------------------------------------------------------------------- loading
def load_hardware(
    path: str | Path,
    control_rate: float = 500.0,
    *,
    joint_names: Sequence[str] | None = None,
    effort_limits: Mapping[str, float] | None = None,
    interface: str | None = None,
    allow_dds: bool = False,
) -> HardwarePlan:
    """Read and validate ``hardware.toml``; also :func:`validate_joints` when ``joint_names`` is given.

    ``interface`` replaces every bus's python-can interface (``"virtual"`` for tests, dry runs).
    ``allow_dds``: a DDS plan is returned (a :class:`giwbc.hal.dds.plan.DdsPlan`) instead of refused
    in one line (callers that drive CAN buses leave it off).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise HardwareConfigError(f"{p}: cannot read hardware file: {e.strerror or e}") from e
    except UnicodeDecodeError as e:  # a binary or corrupted file
        raise HardwareConfigError(f"{p}: not a UTF-8 text hardware file: {e}") from e
    return parse_hardware(
        text, control_rate, source=str(p), joint_names=joint_names, effort_limits=effort_limits, interface=interface, allow_dds=allow_dds
    )


def parse_hardware(
    text: str,
    control_rate: float = 500.0,
    *,
    source: str = "<hardware.toml>",
    joint_names: Sequence[str] | None = None,
    effort_limits: Mapping[str, float] | None = None,
    interface: str | None = None,
    allow_dds: bool = False,
) -> HardwarePlan:
    """:func:`load_hardware` for TOML text; ``source`` names it in error messages."""
    data = parse_toml(text, source, HardwareConfigError)
    if "transport" in data:  # a robot on Unitree's low-level DDS interface (giwbc.hal.dds.plan), not on CAN buses
        from giwbc.hal.dds.plan import parse_dds_plan

        if not allow_dds:
            raise HardwareConfigError(f"{source}: a DDS plan ([transport]), not CAN buses: this command drives CAN buses "
                                      "(giwbc deploy --transport dds runs a DDS plan)")  # fmt: skip

        dds = parse_dds_plan(data, float(control_rate), source)
        if joint_names is not None:
            dds.validate_joints(joint_names)
        return dds  # type: ignore[return-value]
    plan = _build(data, float(control_rate), source, interface)
    if joint_names is not None:
        validate_joints(plan, joint_names, effort_limits)
    return plan


def validate_joints(
    plan: HardwarePlan, joint_names: Sequence[str], effort_limits: Mapping[str, float] | None = None
) -> None:
    """The plan drives exactly the robot's joints; with ``effort_limits`` (N m per joint), each
    motor's torque range covers its joint's limit. HardwareConfigError otherwise."""
    names = list(joint_names)
    dup = sorted({j for j in names if names.count(j) > 1})
    if dup:
        raise HardwareConfigError(f"{plan.source}: the robot's joint list repeats {dup}")
    have = set(plan.joints)
    missing = [j for j in names if j not in have]
    extra = [j for j in plan.joints if j not in set(names)]
    problems = []
    if missing:
        problems.append(f"no motor for robot joint(s) {missing}")
    if extra:
        problems.append(f"motors for joint(s) the robot does not have: {extra}")
    if problems:
        raise HardwareConfigError(f"{plan.source}: " + "; ".join(problems))
    for joint, limit in (effort_limits or {}).items():
        if joint not in have:
            continue
        _, m = plan.motor(joint)
        if m.joint_effort_limit < limit:
            raise HardwareConfigError(
                f"{plan.source}: joint {joint!r}: motor {m.model.name} (torque range {m.model.torque.min:g}.."
                f"{m.model.torque.max:g} N m, gear {m.gear_ratio:g}) covers only {m.joint_effort_limit:g} N m "
                f"at the joint, below its effort limit {limit:g} N m"
            )


# ----------------------------------------------------------------------------- internals
_BUS_KEYS = {"name", "interface", "channel", "bitrate", "max_load", "protocol", "host_id"}
_MOTOR_KEYS = {"bus", "id", "joint", "model", "sign", "zero_offset", "gear_ratio", "reply", *RANGE_FIELDS}
_TOP_KEYS = {"buses", "motors", "imu", "description"}


def _at(source: str, where: str = "") -> TomlPlace:
    """Where a problem is (the file ``source``, the table ``where``): its errors are HardwareConfigError."""
    return TomlPlace(f"{source}: {where}" if where else source, HardwareConfigError)


def _build(data: Mapping[str, Any], control_rate: float, source: str, interface: str | None) -> HardwarePlan:
    _at(source).check_keys(data, _TOP_KEYS, ("buses", "motors", "imu"))
    if not (math.isfinite(control_rate) and control_rate > 0):
        raise _at(source).fail(f"control rate must be > 0 Hz, got {control_rate}")
    raw_buses, raw_motors = data["buses"], data["motors"]
    if not isinstance(raw_buses, list) or not raw_buses:
        raise _at(source, "buses").fail("need at least one [[buses]] table")
    if not isinstance(raw_motors, list):
        raise _at(source, "motors").fail("must be an array of [[motors]] tables")

    buses: dict[str, dict[str, Any]] = {}
    for k, b in enumerate(raw_buses):
        where = f"buses[{k}]"
        _at(source, where).check_keys(b, _BUS_KEYS, ("name", "interface", "channel", "bitrate"))
        name = _at(source, where).string(b, "name")
        where = f"bus {name!r}"
        if name in buses:
            raise _at(source, where).fail("duplicate bus name")
        bitrate = _at(source, where).integer(b, "bitrate")
        if not 0 < bitrate <= 1_000_000:
            raise _at(source, where).fail(f"bitrate must be in 1..1000000 bit/s (classic CAN), got {bitrate}")
        max_load = _at(source, where).number(b, "max_load", DEFAULT_MAX_LOAD)
        if not 0 < max_load <= 1:
            raise _at(source, where).fail(f"max_load must be in (0, 1], got {max_load}")
        protocol = b.get("protocol", "mit")
        try:
            protocol_class(protocol)
        except ValueError as e:
            raise _at(source, where).fail(str(e)) from None
        host_id = _at(source, where).integer(b, "host_id") if "host_id" in b else None
        if host_id is not None and not 0 <= host_id <= 0x7FF:
            raise _at(source, where).fail(f"host_id must be a standard 11-bit id (0..0x7FF), got {host_id}")
        buses[name] = dict(
            host_id=host_id,
            name=name,
            interface=interface or _at(source, where).string(b, "interface"),
            channel=_channel(source, where, b["channel"]),
            bitrate=bitrate,
            max_load=max_load,
            protocol=protocol,
            motors=[],
        )

    joints: dict[str, str] = {}
    for k, m in enumerate(raw_motors):
        where = f"motors[{k}]"
        _at(source, where).check_keys(m, _MOTOR_KEYS, ("bus", "id", "joint", "model"))
        joint = _at(source, where).string(m, "joint")
        where = f"motors[{k}] (joint {joint!r})"
        if joint in joints:
            raise _at(source, where).fail(f"duplicate joint, already driven by a motor on bus {joints[joint]!r}")
        bus_name = _at(source, where).string(m, "bus")
        if bus_name not in buses:
            raise _at(source, where).fail(f"unknown bus {bus_name!r}; buses: {', '.join(buses)}")
        can_id = _at(source, where).integer(m, "id")
        on_bus = buses[bus_name]["motors"]
        clash = next((o for o in on_bus if o.can_id == can_id), None)
        if clash is not None:
            raise _at(source, where).fail(f"duplicate CAN id {can_id} on bus {bus_name!r} (also {clash.joint!r})")
        try:
            model = motor_preset(_at(source, where).string(m, "model"))
            overrides = {f: m[f] for f in RANGE_FIELDS if f in m}
            if overrides:
                model = model.with_overrides(**overrides)
            sign = m.get("sign", 1)
            motor = MotorConfig(
                can_id=can_id,
                model=model,
                joint=joint,
                sign=sign,
                zero_offset=_at(source, where).number(m, "zero_offset", 0.0),
                gear_ratio=_at(source, where).number(m, "gear_ratio", 1.0),
                reply=m.get("reply"),
            )
        except ValueError as e:
            if isinstance(e, HardwareConfigError):
                raise
            raise _at(source, where).fail(str(e)) from None
        on_bus.append(motor)
        joints[joint] = bus_name

    configs = []
    for b in buses.values():
        cfg = BusConfig(**{**b, "motors": tuple(b["motors"])})
        try:
            cfg.make_protocol()  # validates ids, reply variants and reply demultiplexing
        except ProtocolConfigError as e:
            raise _at(source, f"bus {cfg.name!r}").fail(str(e)) from None
        configs.append(cfg)

    imu = _imu(source, data["imu"], buses)
    return HardwarePlan(source, control_rate, tuple(configs), imu, MappingProxyType(_loads(source, configs, imu, control_rate)))


def _loads(source: str, configs: Sequence[BusConfig], imu: ImuConfig, control_rate: float) -> dict[str, BusLoad]:
    """Bus loads at ``control_rate`` (a CAN IMU's frames on its bus included); the IMU's frame ids
    must not be a motor's id or the motors' reply id on that bus."""
    extra = {}
    if imu.layout is not None:  # the CAN IMU's frames share its bus with the motors
        extra[imu.bus] = (imu.layout.bits_per_cycle(control_rate), imu.layout.bits_per_cycle(control_rate, worst_case=True))
    specs = [
        BusPlanSpec(
            c.name, c.bitrate, tuple(protocol_class(c.protocol).traffic(m) for m in c.motors), c.max_load,
            extra.get(c.name, (0, 0)),
        )
        for c in configs
    ]
    try:
        loads = plan_bus_loads(specs, control_rate)
    except BusCapacityError as e:
        raise _at(source, "").fail(str(e)) from e
    if imu.layout is not None:
        bus_cfg = next((c for c in configs if c.name == imu.bus), None)
        if bus_cfg is None:
            raise _at(source, "imu").fail(f"unknown bus {imu.bus!r}; buses: {', '.join(c.name for c in configs)}")
        taken = {m.can_id: f"motor {m.joint!r}" for m in bus_cfg.motors}
        if bus_cfg.host_id is not None:
            taken[bus_cfg.host_id] = "the motors' reply id (host_id)"
        for fr in imu.layout.frames:
            if not fr.extended and fr.can_id in taken:
                raise _at(source, "imu").fail(f"CAN id {fr.can_id} is {taken[fr.can_id]}'s id on bus {imu.bus!r}")
    return loads


def _channel(source: str, where: str, v: Any) -> str | int:
    if isinstance(v, bool) or not isinstance(v, (str, int)) or v == "":
        raise _at(source, where).fail(f"channel must be a non-empty string or an integer, got {v!r}")
    return v


def _imu(source: str, t: Any, buses: Mapping[str, Any]) -> ImuConfig:
    where = "imu"
    _at(source, where).check_keys(t, {"source", "device", "baudrate", "bus", "id", "rate", "frames"}, ("source",))
    kind = t["source"]
    if kind not in IMU_SOURCES:
        raise _at(source, where).fail(f"source must be one of {', '.join(IMU_SOURCES)}, got {kind!r}")
    if kind == "can" and "id" in t:
        raise _at(source, where).fail("a CAN IMU is described by rate and [[imu.frames]] (id and fields of each frame), not one id")
    allowed = {"emulated": {"source"}, "serial": {"source", "device", "baudrate"}, "can": {"source", "bus", "rate", "frames"}}[kind]
    required = {"emulated": (), "serial": ("device",), "can": ("bus", "rate", "frames")}[kind]
    _at(source, f"imu (source {kind!r})").check_keys(t, allowed, required)
    if kind == "emulated":
        return ImuConfig("emulated")
    if kind == "serial":
        device = _at(source, where).string(t, "device")
        baud = None
        if "baudrate" in t:
            baud = _at(source, where).integer(t, "baudrate")
            if baud <= 0:
                raise _at(source, where).fail(f"baudrate must be > 0, got {baud}")
        return ImuConfig("serial", device=device, baudrate=baud)
    bus = _at(source, where).string(t, "bus")
    if bus not in buses:
        raise _at(source, where).fail(f"unknown bus {bus!r}; buses: {', '.join(buses)}")
    return ImuConfig("can", bus=bus, layout=parse_can_imu_layout(t, source))
