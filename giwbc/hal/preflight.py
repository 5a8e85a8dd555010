"""SocketCAN pre-flight: are the plan's CAN interfaces there, up, at the plan's bitrate, with
automatic bus-off recovery and a transmit queue that holds one cycle's burst?

Read before any motor is enabled (``giwbc deploy`` on SocketCAN buses, ``giwbc motors check``).
The link facts come from ``ip -details -json link show`` (iproute2; the JSON keys are those its
``ip/iplink_can.c`` prints: ``linkinfo.info_kind`` ``can`` / ``vcan``, ``info_data.state``,
``restart_ms``, ``bittiming.bitrate``, ``berr_counter``), or from ``/sys/class/net`` where ``ip``
is missing (no bitrate there: that check then says so). Each problem comes with the exact
``ip link`` commands that fix it, in the order they must run (bitrate and restart-ms can only
change while the interface is down).

Why each check:

- **exists / up**: a missing adapter (USB unplugged, driver not loaded) or a down interface makes
  every send fail; better said before than as 29 stale motors.
- **bitrate**: a node at another bitrate sees only error frames, and drives the bus error-passive.
- **restart-ms**: without it a bus-off (a short, a missing terminator, a babbling node) stops the
  interface for good until someone runs ``ip link set ... type can restart``; with it the kernel
  recovers and the safety supervisor sees a stall instead of a dead bus.
- **txqueuelen**: each cycle the host writes one frame per motor back to back; a queue shorter
  than that burst makes sends fail with ENOBUFS, i.e. dropped commands every cycle.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from giwbc.errors import HardwareConfigError
from giwbc.hal.hardware import BusConfig, HardwarePlan

DEFAULT_RESTART_MS = 100
MIN_TXQUEUELEN = 32
ERROR, WARNING = "error", "warning"


@dataclass(frozen=True)
class LinkInfo:
    """What the kernel says about one network interface."""

    name: str
    up: bool  # administratively up (flag UP)
    operstate: str
    kind: str | None  # linkinfo.info_kind: "can", "vcan", ... (None: not reported)
    link_type: str | None  # "can" for CAN and vCAN
    txqlen: int | None
    bitrate: int | None = None
    restart_ms: int | None = None
    can_state: str | None = None  # ERROR-ACTIVE, ERROR-WARNING, ERROR-PASSIVE, BUS-OFF, STOPPED
    berr_tx: int | None = None
    berr_rx: int | None = None


@dataclass(frozen=True)
class Finding:
    """One problem with one bus's interface, and the commands that fix it."""

    bus: str
    interface: str
    severity: str  # "error": do not enable motors; "warning": look at it
    problem: str
    fix: tuple[str, ...] = ()

    def __str__(self) -> str:
        out = f"[{self.severity}] bus {self.bus!r} ({self.interface}): {self.problem}"
        return out + "".join(f"\n    {c}" for c in self.fix)


@dataclass(frozen=True)
class PreflightReport:
    """Findings for every SocketCAN bus of a plan; ``checked`` / ``skipped`` list bus names."""

    findings: tuple[Finding, ...]
    checked: tuple[str, ...]
    skipped: tuple[str, ...] = ()
    fix_commands: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        return not any(f.severity == ERROR for f in self.findings)

    def __str__(self) -> str:
        head = f"SocketCAN pre-flight: {len(self.checked)} interface(s) checked"
        if self.skipped:
            head += f", {len(self.skipped)} bus(es) not on SocketCAN ({', '.join(self.skipped)})"
        if not self.findings:
            return head + ": all ready"
        lines = [head + ":"] + [str(f) for f in self.findings]
        if self.fix_commands:
            lines += ["all fixes, in order:"] + [f"    {c}" for c in self.fix_commands]
        return "\n".join(lines)


# ----------------------------------------------------------------------------- reading links
def parse_ip_links(text: str) -> dict[str, LinkInfo]:
    """The interfaces in the output of ``ip -details -json link show`` (one interface or all)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise HardwareConfigError(f"cannot parse `ip -details -json link show` output: {e}") from e
    if not isinstance(data, list):
        raise HardwareConfigError("`ip -details -json link show` output is not a JSON array")
    out: dict[str, LinkInfo] = {}
    for link in data:
        if not isinstance(link, Mapping) or "ifname" not in link:
            continue
        info = link.get("linkinfo") or {}
        kind = info.get("info_kind")
        d = info.get("info_data") or {}
        bt = d.get("bittiming") or {}
        berr = d.get("berr_counter") or {}
        out[link["ifname"]] = LinkInfo(
            name=link["ifname"],
            up="UP" in (link.get("flags") or ()),
            operstate=str(link.get("operstate", "UNKNOWN")),
            kind=kind,
            link_type=link.get("link_type"),
            txqlen=_opt_int(link.get("txqlen")),
            bitrate=_opt_int(bt.get("bitrate")),
            restart_ms=_opt_int(d.get("restart_ms")),
            can_state=d.get("state"),
            berr_tx=_opt_int(berr.get("tx")),
            berr_rx=_opt_int(berr.get("rx")),
        )
    return out


def _opt_int(v: Any) -> int | None:
    return int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def read_sysfs_link(name: str, root: Path = Path("/sys/class/net")) -> LinkInfo | None:
    """A link from ``/sys/class/net/<name>`` (no bitrate, restart-ms or CAN state there)."""
    d = root / name
    if not d.is_dir():
        return None

    def read(f: str) -> str | None:
        try:
            return (d / f).read_text().strip()
        except OSError:
            return None

    flags = read("flags")
    link_type = read("type")  # ARPHRD_CAN = 280
    txq = read("tx_queue_len")
    return LinkInfo(
        name=name,
        up=bool(int(flags, 16) & 0x1) if flags else False,
        operstate=(read("operstate") or "unknown").upper(),
        kind=None,
        link_type="can" if link_type == "280" else link_type,
        txqlen=int(txq) if txq and txq.isdigit() else None,
    )


def read_links(names: Sequence[str], run: Callable[..., Any] = subprocess.run) -> dict[str, LinkInfo]:
    """The named interfaces that exist, from ``ip`` (or ``/sys/class/net`` without it)."""
    if shutil.which("ip") is not None:
        done = run(["ip", "-details", "-json", "link", "show"], capture_output=True, text=True, timeout=10, check=False)
        if done.returncode == 0:
            links = parse_ip_links(done.stdout)
            return {n: links[n] for n in names if n in links}
    return {n: link for n in names if (link := read_sysfs_link(n)) is not None}


# ----------------------------------------------------------------------------- verdicts
def cycle_burst(plan: HardwarePlan, bus: BusConfig) -> int:
    """Frames the host writes to ``bus`` back to back each control cycle (one per motor)."""
    return len(bus.motors)


def check_bus(
    bus: BusConfig,
    link: LinkInfo | None,
    burst: int,
    *,
    restart_ms: int = DEFAULT_RESTART_MS,
    allow_virtual: bool = False,
) -> list[Finding]:
    """The findings for one bus given what the kernel says about its interface."""
    name = str(bus.channel)
    sudo = "sudo ip link set"
    if link is None:
        return [
            Finding(
                bus.name, name, ERROR,
                "interface does not exist (adapter unplugged, driver not loaded, or another name: see `ip -br link show type can`)",
                (f"sudo ip link add dev {name} type vcan   # only for a dry run without hardware",) if allow_virtual else (),
            )
        ]
    if link.link_type not in (None, "can"):
        return [Finding(bus.name, name, ERROR, f"not a CAN interface (link type {link.link_type!r})")]
    txq_need = max(burst, 1)
    txq_fix = f"{sudo} {name} txqueuelen {max(2 * txq_need, MIN_TXQUEUELEN)}"
    if link.kind == "vcan":
        findings = [] if allow_virtual else [Finding(bus.name, name, ERROR, "a virtual CAN interface (vcan): no motor can answer on it")]
        if not link.up:
            findings.append(Finding(bus.name, name, ERROR, "interface is down", (f"{sudo} {name} up",)))
        return findings
    down_settings: dict[str, str] = {}  # settings that change only while the interface is down
    problems: list[str] = []
    findings: list[Finding] = []
    if link.kind == "can" and link.bitrate != bus.bitrate:
        have = "not set" if link.bitrate is None else f"{link.bitrate} bit/s"
        problems.append(f"bitrate {have}, the plan says {bus.bitrate} bit/s")
        down_settings["bitrate"] = str(bus.bitrate)
    if link.kind == "can" and not link.restart_ms:
        problems.append("restart-ms is not set: a bus-off would stop this bus until a manual restart")
        down_settings["restart-ms"] = str(restart_ms)
    if link.kind is None:
        findings.append(Finding(bus.name, name, WARNING, "bitrate and restart-ms unknown (`ip` not available): check them by hand"))
    if down_settings:
        settings = " ".join(f"{k} {v}" for k, v in down_settings.items())
        fix = (f"{sudo} {name} down", f"{sudo} {name} type can {settings}", f"{sudo} {name} up")
        findings += [Finding(bus.name, name, ERROR, p, fix) for p in problems]
    elif not link.up:
        findings.append(Finding(bus.name, name, ERROR, "interface is down", (f"{sudo} {name} up",)))
    if link.txqlen is not None and link.txqlen < txq_need:
        findings.append(
            Finding(bus.name, name, ERROR, f"txqueuelen {link.txqlen} is shorter than one cycle's burst of {burst} frames", (txq_fix,))
        )
    if link.up and link.can_state == "BUS-OFF":
        findings.append(
            Finding(
                bus.name, name, ERROR, "controller is BUS-OFF: check wiring, 120 ohm termination at both ends, power",
                (f"{sudo} {name} type can restart",),
            )
        )
    elif link.up and link.can_state in ("ERROR-PASSIVE", "ERROR-WARNING"):
        counters = f" (error counters tx {link.berr_tx}, rx {link.berr_rx})" if link.berr_tx is not None else ""
        findings.append(
            Finding(
                bus.name, name, WARNING,
                f"controller is {link.can_state}{counters}: errors on the bus (termination, wiring, a node at another bitrate)",
            )
        )
    return findings


def preflight(
    plan: HardwarePlan,
    links: Mapping[str, LinkInfo] | None = None,
    *,
    restart_ms: int = DEFAULT_RESTART_MS,
    allow_virtual: bool = False,
) -> PreflightReport:
    """Check every ``socketcan`` bus of ``plan`` (``links``: from :func:`read_links` when None).
    Other python-can interfaces (``virtual``, ``giwbc-unix``, vendor adapters) are skipped."""
    can_buses = [b for b in plan.buses if b.interface == "socketcan"]
    skipped = tuple(b.name for b in plan.buses if b.interface != "socketcan")
    if links is None:
        links = read_links([str(b.channel) for b in can_buses]) if can_buses else {}
    findings: list[Finding] = []
    for b in can_buses:
        findings += check_bus(b, links.get(str(b.channel)), cycle_burst(plan, b), restart_ms=restart_ms, allow_virtual=allow_virtual)
    fixes: list[str] = []
    for f in findings:
        for c in f.fix:
            if c not in fixes:
                fixes.append(c)
    return PreflightReport(tuple(findings), tuple(b.name for b in can_buses), skipped, tuple(fixes))


__all__ = [
    "DEFAULT_RESTART_MS",
    "Finding",
    "LinkInfo",
    "PreflightReport",
    "check_bus",
    "cycle_burst",
    "parse_ip_links",
    "preflight",
    "read_links",
    "read_sysfs_link",
]
