"""The DDS transport: one domain participant on the plan's interface and domain, a writer and a
reader, exchanging serialized messages as bytes (no per-message Python objects).

:class:`DdsTransport` creates the domain with giwbc's own configuration
(:func:`~giwbc.hal.dds.config.cyclone_config`: the interface pinned), the topics with the
``unitree_hg`` types (:mod:`giwbc.hal.dds.idl`, XCDR1 as Unitree's robot speaks it), a best-effort
volatile writer on ``publish`` and reader on ``subscribe`` (a late state is worth nothing: the
newest one counts; the reader keeps the last ``depth`` so each one is checked and counted). :meth:`write` hands Cyclone the bytes the caller built in place;
:meth:`take` returns the bytes waiting, oldest first. :meth:`matched_readers` /
:meth:`writers` count the peers discovery matched (a robot that does not listen, or a second
writer on the command topic: the robot's own locomotion service).

Errors: cyclonedds missing, an interface Cyclone cannot use, a domain it cannot create: one
:class:`~giwbc.errors.HardwareConfigError` line each.
"""

from __future__ import annotations

import socket
import time
from typing import Any

from giwbc.errors import HardwareConfigError
from giwbc.hal.dds.config import check_domain, check_interface, cyclone_config

LOWCMD_TOPIC = "rt/lowcmd"
LOWSTATE_TOPIC = "rt/lowstate"
_ANY = 0xFFFFFFFF  # sample, view and instance state: any (take every sample)


def _cyclone() -> Any:
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError as error:
        raise HardwareConfigError(f"the DDS transport needs cyclonedds: pip install 'giwbc[dds]' ({error})") from None
    import cyclonedds

    return cyclonedds


class DdsTransport:
    """A participant on ``domain`` over ``interface`` writing ``publish`` and reading ``subscribe``
    (topic names; their types from :data:`TYPES`). ``listen``: also read the ``publish`` topic
    (another participant's messages there: the robot's locomotion service still commanding it).
    ``subscribe`` None: no reader (a second writer only: the emulated locomotion service).
    ``local`` False: the reader ignores this process's other participants (the emulator's own
    locomotion service is not a command to its firmware)."""

    def __init__(self, domain: int, interface: str, *, publish: str, subscribe: str | None, depth: int = 8, listen: bool = False,
                 source: str = "dds", local: bool = True) -> None:  # fmt: skip
        self.participant: Any = None
        check_domain(domain, source)
        check_interface(interface, source)
        cyclonedds = _cyclone()
        from cyclonedds._clayer import ddspy_take, ddspy_write
        from cyclonedds.core import DDSException, Policy, Qos
        from cyclonedds.domain import Domain, DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from giwbc.hal.dds.idl import LowCmd_, LowState_

        types = {LOWCMD_TOPIC: LowCmd_, LOWSTATE_TOPIC: LowState_}
        for name in (publish, subscribe or publish):
            if name not in types:
                raise HardwareConfigError(f"{source}: unknown DDS topic {name!r}; giwbc speaks {', '.join(types)}")
        known = [name for _, name in socket.if_nameindex()]
        if interface not in known:
            raise HardwareConfigError(f"{source}: network interface {interface!r} does not exist on this machine (interfaces: {', '.join(known)})")
        self.domain, self.interface = domain, interface
        self._write, self._take = ddspy_write, ddspy_take
        qos = Qos(
            Policy.Reliability.BestEffort, Policy.History.KeepLast(depth), Policy.Durability.Volatile,
            Policy.DataRepresentation(use_cdrv0_representation=True),
        )  # fmt: skip
        try:
            try:
                self._domain = Domain(domain, cyclone_config(domain, interface))
            except DDSException:  # this process already created the domain (a second participant): it has its configuration
                self._domain = None
            self.participant = DomainParticipant(domain)
            published = Topic(self.participant, publish, types[publish])
            self.writer = DataWriter(self.participant, published, qos=qos)
            reader_qos = qos if local else Qos(*qos, Policy.IgnoreLocal.Process)
            self.reader = None if subscribe is None else DataReader(self.participant, Topic(self.participant, subscribe, types[subscribe]),
                                                                    qos=reader_qos)  # fmt: skip
            # Another participant's messages on the published topic (never our own: IgnoreLocal).
            self.listener = DataReader(self.participant, published, qos=Qos(*qos, Policy.IgnoreLocal.Participant)) if listen else None
        except DDSException as error:
            raise HardwareConfigError(
                f"{source}: cannot open DDS domain {domain} on interface {interface!r} ({error}); is the interface up and is it this "
                "machine's (ip addr)?"
            ) from None
        self._cyclonedds = cyclonedds
        self.written = 0
        self.taken = 0
        self.write_errors = 0

    def write(self, data: bytes) -> bool:
        """Publish one serialized message (header included, a multiple of 4 bytes); False when DDS refused it."""
        if self._write(self.writer._ref, data) < 0:
            self.write_errors += 1
            return False
        self.written += 1
        return True

    def take(self, limit: int = 64, reader: Any = None) -> list[bytes]:
        """The serialized messages waiting (at most ``limit``), oldest first (on ``reader``, default the subscribed topic's)."""
        reader = reader or self.reader
        if reader is None:
            return []
        got = self._take(reader._ref, _ANY, limit)
        if isinstance(got, int):
            return []
        out = [data for data, info in got if info.valid_data]
        if reader is self.reader:
            self.taken += len(out)
        return out

    def foreign(self, limit: int = 64) -> int:
        """How many messages another participant published on our topic since the last call (``listen``)."""
        return 0 if self.listener is None else len(self.take(limit, self.listener))

    def matched_readers(self) -> int:
        """Readers of the published topic that discovery matched (the robot listening)."""
        return len(self.writer.get_matched_subscriptions())

    def writers(self) -> int:
        """Writers of the subscribed topic that discovery matched."""
        return 0 if self.reader is None else len(self.reader.get_matched_publications())

    def wait_matched(self, timeout: float, readers: int = 1) -> bool:
        """Wait up to ``timeout`` s until at least ``readers`` readers of the published topic match."""
        end = time.monotonic() + timeout
        while self.matched_readers() < readers:
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True

    def drop_reader(self) -> None:
        """Delete the reader of the subscribed topic (discovery tells the writers: they lose a match)."""
        if self.reader is not None:
            self.reader.__del__()  # cyclonedds deletes the C entity here (idempotent)
            self.reader = None

    def close(self) -> None:
        """Delete the participant (and with it the writer and readers); idempotent."""
        participant = getattr(self, "participant", None)
        if participant is not None:
            self.participant = None
            self.writer = self.reader = self.listener = None
            participant.__del__()
        domain, self._domain = getattr(self, "_domain", None), None
        if domain is not None:
            # The last entity gone, Cyclone stops its threads: a process forked later (the emulator)
            # does not inherit a domain whose threads did not come along.
            domain.__del__()


__all__ = ["LOWCMD_TOPIC", "LOWSTATE_TOPIC", "DdsTransport"]
