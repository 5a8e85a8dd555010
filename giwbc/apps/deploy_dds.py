"""``giwbc deploy --transport dds``: a G1 driven over Unitree's low-level DDS interface
(:mod:`giwbc.hal.dds`), or rehearsed on the DDS emulator (:mod:`giwbc.emulation.dds_emulator`).

Kept apart from :mod:`giwbc.apps.deploy_run` so the procedure there only branches: which plan
file a transport reads (:func:`default_hardware`), the plan matching the transport asked
(:func:`check_transport`), and the robot (and emulator) of a DDS plan (:func:`open_dds`). The
DDS rows of the fault table (:data:`DDS_FAULT_CASES`, ``--fault dds_...``) run against the
emulator.

Rehearsals stay on the machine: the emulator and the host meet on the loopback interface only
(Cyclone configured with ``lo`` alone, unicast discovery) and on a domain of the run's own
(:func:`~giwbc.emulation.dds_emulator.emulation_domain`), never the plan's robot network.

The robot's own locomotion service (``--release-service`` / ``--restore-service``): released
through Unitree's motion switcher (:mod:`giwbc.hal.dds.motion_switcher`) before the robot is
opened, so before any motor is enabled (not released within ``service_timeout``: DeployError,
one line); the released mode selected again once the robot is closed with its motors off. With
``--emulate`` the emulator plays that service (mode :data:`EMULATED_SERVICE`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from giwbc.emulation import EmulatorConfig, FaultInjection
from giwbc.emulation.dds_emulator import DdsEmulatorProcess, DdsFault
from giwbc.errors import DdsLinkError, DeployError, HardwareConfigError
from giwbc.hal.dds.motion_switcher import Mode, MotionSwitcherClient
from giwbc.hal.dds.plan import DdsPlan
from giwbc.hal.dds.robot import DdsRobot
from giwbc.hal.hardware import load_hardware
from giwbc.hal.safety import FaultKind

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

TRANSPORTS = ("can", "dds")
PLAN_FILES = {"can": "hardware.toml", "dds": "hardware_dds.toml"}
EMULATED_SERVICE = "ai"  # the mode the emulated G1's locomotion service runs in until released (a name, as CheckMode reports one)


@dataclass(frozen=True)
class DdsFaultCase:
    """One DDS row of the fault table: what is injected (``at`` seconds after the start-up) and the fault that must stop the run."""

    kind: str
    expected: FaultKind
    description: str
    dds: str | None = None  # a DdsFault kind
    motor: str | None = None  # a FaultInjection kind (the emulator's firmware)

    def injections(self, at: float) -> tuple[Any, ...]:
        if self.dds is not None:
            return (DdsFault(self.dds, start=at),)
        return (FaultInjection(self.motor or "error", joints=("left_knee_joint",), start=at),)


DDS_FAULT_CASES: dict[str, DdsFaultCase] = {c.kind: c for c in (
    DdsFaultCase("dds_stale_state", FaultKind.MISSING_REPLIES, "the robot republishes one state (its tick stops)", dds="stale_state"),
    DdsFaultCase("dds_silent", FaultKind.MISSING_REPLIES, "the robot stops publishing rt/lowstate", dds="silent"),
    DdsFaultCase("dds_dropped_commands", FaultKind.MOTOR_DISABLED, "the robot drops every rt/lowcmd: its motors time out", dds="drop_commands"),
    DdsFaultCase("dds_crc_errors", FaultKind.CORRUPT_FRAMES, "rt/lowstate arrives with a bad CRC", dds="corrupt"),
    DdsFaultCase("dds_motor_error", FaultKind.MOTOR_ERROR, "the left knee reports an error flag", motor="error"),
    DdsFaultCase("dds_late_subscriber", FaultKind.DRIVER_ERROR, "the robot's reader of rt/lowcmd goes away", dds="late_subscriber"),
    DdsFaultCase("dds_service_active", FaultKind.DRIVER_ERROR, "the robot's locomotion service publishes rt/lowcmd too", dds="service_active"),
)}  # fmt: skip


def default_hardware(description: RobotDescription, transport: str) -> Path:
    """The robot folder's plan for ``transport``."""
    return description.folder / PLAN_FILES[transport]


def check_transport(plan: Any, transport: str, hardware: Path) -> None:
    """The plan is one of ``transport``; DeployError (one line) naming the fix otherwise."""
    dds = isinstance(plan, DdsPlan)
    if dds and transport != "dds":
        raise DeployError(f"{hardware}: a DDS plan ([transport] kind = \"dds\"): run it with --transport dds")
    if not dds and transport == "dds":
        raise DeployError(f"{hardware}: a CAN plan ([[buses]], [[motors]]); --transport dds needs a DDS plan "
                          f"([transport] kind = \"dds\", e.g. robots/g1/{PLAN_FILES['dds']})")  # fmt: skip


# The injected faults that mean something behind DDS: the firmware's and physics' (the emulator's
# CAN-frame faults and the host's bus-driver faults act on CAN buses a DDS robot does not have).
DDS_MOTOR_FAULTS = frozenset({"error", "overheat", "push", "encoder"})
DDS_HOST_FAULTS = frozenset({"policy_nan", "controller_nan", "controller_raise", "qp_infeasible", "keyboard_interrupt", "sigint", "sigterm",
                             "sighup"})  # fmt: skip


def split_faults(faults: tuple[Any, ...], dds: bool = True) -> tuple[tuple[Any, ...], tuple[DdsFault, ...]]:
    """(the firmware's and the host's faults, the DDS emulator's); a fault the transport cannot
    carry is a DeployError (one line)."""
    mine = tuple(f for f in faults if isinstance(f, DdsFault))
    others = tuple(f for f in faults if not isinstance(f, DdsFault))
    if not dds and mine:
        raise DeployError(f"DDS faults ({', '.join(f.kind for f in mine)}) need --transport dds")
    if dds:
        can_only = sorted({f.kind for f in others} - DDS_MOTOR_FAULTS - DDS_HOST_FAULTS)
        if can_only:
            raise DeployError(f"fault(s) {', '.join(can_only)} act on CAN buses; over DDS inject {', '.join(DDS_FAULT_CASES)} "
                              f"or {', '.join(sorted(DDS_MOTOR_FAULTS | DDS_HOST_FAULTS))}")  # fmt: skip
    return others, mine


def open_dds(plan: DdsPlan, description: RobotDescription, options: Any, config: EmulatorConfig | None, dds_faults: tuple[DdsFault, ...],
             say: Callable[[str], None], plant: Any = None) -> tuple[DdsRobot, DdsEmulatorProcess | None]:  # fmt: skip
    """The DDS robot of ``plan`` (on the emulator in its own process with ``options.emulate``, stepping
    ``plant``: a :func:`giwbc.plants.resolve_plant` spec, None for the description's model)."""
    if options.imu is not None:
        raise DeployError("--imu chooses the IMU a CAN rehearsal imitates; a DDS robot's IMU is the one in its rt/lowstate")
    if dds_faults and not options.emulate:
        raise DeployError("injected faults are for rehearsals: they need --emulate")
    emulator = None
    if options.emulate:
        if options.emulator_mode != "process":
            raise DeployError("the DDS emulator runs in its own process, as the robot does: --transport dds --emulate --emulator process")
        try:
            motors = load_hardware(description.folder / PLAN_FILES["can"], options.control_rate, joint_names=description.joint_names,
                                   interface="virtual")  # fmt: skip
        except HardwareConfigError as error:
            raise DeployError(f"the DDS emulator's motor models: {error}") from error
        service = EMULATED_SERVICE if options.release_service else None
        emulator = DdsEmulatorProcess(plan, motors, description, config, faults=dds_faults, service=service,
                                      plant=plant)
        plan = emulator.host_plan()
        say(f"emulated G1 behind DDS in its own process (domain {plan.domain} on loopback, rt/lowcmd / rt/lowstate"
            + (f"; its locomotion service runs mode {service!r})" if service else ")"))
    switcher, released = None, Mode("", "")
    try:
        if options.release_service:
            switcher, released = release_service(plan, options.service_timeout, say)
            if not (options.restore_service and released.active):
                switcher.close()
        robot = DdsRobot(description, plan)
    except (HardwareConfigError, DdsLinkError) as error:
        if switcher is not None:
            switcher.close()
        if emulator is not None:
            emulator.close()
        raise DeployError(str(error)) from error
    if switcher is not None and options.restore_service and released.active:
        robot.after_close = lambda: restore_service(robot, switcher, released, options.service_timeout, say)
    elif options.restore_service:
        say("--restore-service: no mode was active before the run; nothing to restore")
    say(f"DDS: robot on domain {plan.domain} over {plan.interface!r}, first rt/lowstate tick {int(robot.state.tick[0])}, "
        f"{robot.transport.matched_readers()} reader(s) of rt/lowcmd")  # fmt: skip
    return robot, emulator


def release_service(plan: DdsPlan, timeout: float, say: Callable[[str], None]) -> tuple[MotionSwitcherClient, Mode]:
    """The motion switcher's client on the plan's domain and interface, after releasing the active
    mode within ``timeout`` s (DdsLinkError otherwise), and the mode it released."""
    switcher = MotionSwitcherClient(plan.domain, plan.interface, source=f"{plan.source}: releasing the robot's locomotion service")
    try:
        released = switcher.release(timeout)
    except BaseException:
        switcher.close()
        raise
    say(f"motion switcher: {'mode ' + str(released) + ' released' if released.active else 'no mode active'} "
        f"({', '.join(f'{name} {code}' for name, code in switcher.calls)})")  # fmt: skip
    return switcher, released


def restore_service(robot: DdsRobot, switcher: MotionSwitcherClient, mode: Mode, timeout: float, say: Callable[[str], None]) -> None:
    """Select ``mode`` again (the robot closed); only with its motors off (zero gain, mode 0 sent)."""
    try:
        if robot.enabled:
            say(f"motion switcher: mode {mode} NOT restored: the motors were not confirmed off; restore it by hand")
            return
        switcher.select(mode.name, timeout)
        say(f"motion switcher: mode {mode} selected again (the robot's own service commands it now)")
    except DdsLinkError as error:
        say(f"motion switcher: mode {mode} NOT restored: {error}")
    finally:
        switcher.close()


__all__ = ["DDS_FAULT_CASES", "EMULATED_SERVICE", "PLAN_FILES", "TRANSPORTS", "DdsFaultCase", "check_transport", "default_hardware", "open_dds", "release_service", "restore_service", "split_faults"]
