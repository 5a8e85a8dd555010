"""Cyclone DDS's configuration for giwbc: the network interface and the domain pinned by the plan.

Cyclone reads its configuration from XML (``CYCLONEDDS_URI`` or a ``Domain``'s config); giwbc
never relies on the environment's: :func:`cyclone_config` builds the XML for one domain and one
interface and the transport passes it to the domain it creates, so a test or the emulator cannot
wander onto the machine's other networks.

On loopback (``lo``) Linux does not deliver multicast unless the interface has the MULTICAST flag
(it usually does not), so discovery on ``lo`` is unicast: multicast off and the peers listed
(``127.0.0.1``; Cyclone then probes the participant ports of that address). On the robot's
interface (``eth0``, ``enp3s0``, the one on 192.168.123.0/24 for a G1) multicast discovery is
what Unitree's robot uses, and is left on.
"""

from __future__ import annotations

import re
from xml.sax.saxutils import quoteattr

from giwbc.errors import HardwareConfigError

LOOPBACK = "lo"
MAX_DOMAIN = 232  # DDS domain ids 0..232 (RTPS port mapping, the standard's limit)
_INTERFACE = re.compile(r"^[A-Za-z0-9_.:-]{1,15}$")  # a Linux interface name (IFNAMSIZ - 1)


def check_domain(domain: object, source: str = "dds") -> int:
    """The domain id as an int; HardwareConfigError naming ``source`` for anything but 0..232."""
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= MAX_DOMAIN:
        raise HardwareConfigError(f"{source}: DDS domain id must be an integer from 0 to {MAX_DOMAIN}, got {domain!r}")
    return domain


def check_interface(interface: object, source: str = "dds") -> str:
    """The network interface's name; HardwareConfigError naming ``source`` for one no Linux interface can have."""
    if not isinstance(interface, str) or not _INTERFACE.match(interface):
        raise HardwareConfigError(f"{source}: network interface must be a Linux interface name (e.g. \"eth0\", \"lo\"), got {interface!r}")
    return interface


def cyclone_config(domain: int, interface: str, *, max_participants: int = 20) -> str:
    """The Cyclone DDS XML for ``domain`` on ``interface`` only (module docstring)."""
    check_domain(domain)
    check_interface(interface)
    loopback = interface == LOOPBACK
    discovery = (
        "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        f"<MaxAutoParticipantIndex>{int(max_participants)}</MaxAutoParticipantIndex>"
        "<Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>"
        if loopback else ""
    )
    multicast = "<AllowMulticast>false</AllowMulticast>" if loopback else ""
    return (
        f"<CycloneDDS><Domain id=\"{int(domain)}\"><General><Interfaces><NetworkInterface name={quoteattr(interface)}/>"
        f"</Interfaces>{multicast}</General>{discovery}</Domain></CycloneDDS>"
    )


__all__ = ["LOOPBACK", "MAX_DOMAIN", "check_domain", "check_interface", "cyclone_config"]
