"""The robot's locomotion service handed over and back: a small client of Unitree's motion switcher
over DDS RPC, and the RPC endpoint the DDS emulator serves it with.

Protocol, as Unitree's public SDK (unitree_sdk2 / unitree_sdk2_python: the motion switcher client
and the ``unitree_api`` IDL) speaks it; giwbc's own implementation:

* Topics ``rt/api/motion_switcher/request`` (type ``unitree_api::msg::dds_::Request_``) and
  ``rt/api/motion_switcher/response`` (``Response_``): :mod:`giwbc.hal.dds.api_idl`.
* A request carries an identity (``id`` chosen by the client, echoed in the response; ``api_id``
  the call), a lease (0: none), a policy (priority 0, ``noreply`` false), ``parameter`` a JSON
  string; the response's ``status.code`` is 0 when done, its ``data`` a JSON string.
* API ids: 1001 CheckMode (``{}`` → ``{"form": ..., "name": ...}``; an empty ``name``: no service
  commands the motors), 1002 SelectMode (``{"name": ...}``), 1003 ReleaseMode (``{}``). The SDK's
  own programs call ReleaseMode then CheckMode again, once a second, until ``name`` is empty.

:class:`MotionSwitcherClient` does that with a bounded wait: :meth:`~MotionSwitcherClient.release`
retries until the mode is gone or ``timeout`` passes (a :class:`~giwbc.errors.DdsLinkError`, one
line, naming the mode and the last answer), :meth:`~MotionSwitcherClient.select` gives the robot
back to the mode released. It opens its own participant with giwbc's Cyclone configuration
(:func:`~giwbc.hal.dds.config.cyclone_config`: the plan's interface pinned; loopback in rehearsals).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Any

from giwbc.errors import DdsLinkError, HardwareConfigError
from giwbc.hal.dds.config import check_domain, check_interface, cyclone_config

SERVICE = "motion_switcher"
REQUEST_TOPIC = f"rt/api/{SERVICE}/request"
RESPONSE_TOPIC = f"rt/api/{SERVICE}/response"
CHECK_MODE, SELECT_MODE, RELEASE_MODE = 1001, 1002, 1003
API_NAMES = {CHECK_MODE: "CheckMode", SELECT_MODE: "SelectMode", RELEASE_MODE: "ReleaseMode"}
# The SDK's RPC status codes giwbc names (0: done).
RPC_OK = 0
RPC_ERR_CLIENT_API_TIMEOUT = 3104  # no response within the client's timeout
RPC_ERR_CLIENT_API_NOT_MATCH = 3105  # a response to another call
RPC_ERR_SERVER_INTERNAL = 3202


@dataclass(frozen=True)
class Mode:
    """The motion switcher's answer to CheckMode: ``name`` empty when no service commands the motors."""

    form: str
    name: str

    @property
    def active(self) -> bool:
        return bool(self.name)

    def __str__(self) -> str:
        return repr(self.name) if self.name else "none"


class RpcEndpoint:
    """One DDS participant with a service's two RPC topics on ``domain`` over ``interface``: the
    client's side (writes requests, reads responses) or, ``server``, the service's (the emulator).
    Writer reliable (it matches any reader), reader best effort (it matches any writer), XCDR1."""

    def __init__(self, domain: int, interface: str, *, server: bool = False, depth: int = 16, source: str = "dds") -> None:
        self.participant: Any = None
        self._domain: Any = None
        check_domain(domain, source)
        check_interface(interface, source)
        from giwbc.hal.dds.transport import _cyclone

        _cyclone()
        from cyclonedds.core import DDSException, Policy, Qos
        from cyclonedds.domain import Domain, DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from giwbc.hal.dds.api_idl import Request_, Response_

        xcdr1 = Policy.DataRepresentation(use_cdrv0_representation=True)
        common = (Policy.History.KeepLast(depth), Policy.Durability.Volatile, xcdr1)
        try:
            try:
                self._domain = Domain(domain, cyclone_config(domain, interface))
            except DDSException:  # this process already has the domain (the robot's transport): its configuration stands
                self._domain = None
            self.participant = DomainParticipant(domain)
            request = Topic(self.participant, REQUEST_TOPIC, Request_)
            response = Topic(self.participant, RESPONSE_TOPIC, Response_)
            out, into = (response, request) if server else (request, response)
            self.writer = DataWriter(self.participant, out, qos=Qos(Policy.Reliability.Reliable(100_000_000), *common))
            self.reader = DataReader(self.participant, into, qos=Qos(Policy.Reliability.BestEffort, *common))
        except DDSException as error:
            self.close()
            raise HardwareConfigError(f"{source}: cannot open the motion switcher's DDS topics on domain {domain} over {interface!r} "
                                      f"({error})") from None  # fmt: skip
        self._kind = Response_ if not server else Request_

    def take(self, limit: int = 16) -> list[Any]:
        """The messages waiting (requests on the server's side, responses on the client's), oldest first."""
        if self.reader is None:
            return []
        return [m for m in self.reader.take(limit) if isinstance(m, self._kind)]

    def write(self, message: Any) -> None:
        self.writer.write(message)

    def matched(self) -> tuple[int, int]:
        """(readers of what this side writes, writers of what it reads) that discovery matched."""
        return len(self.writer.get_matched_subscriptions()), len(self.reader.get_matched_publications())

    def close(self) -> None:
        """Delete the participant (and the domain when this endpoint created it); idempotent."""
        participant, self.participant = self.participant, None
        if participant is not None:
            self.writer = self.reader = None
            participant.__del__()
        domain, self._domain = self._domain, None
        if domain is not None:
            domain.__del__()


def request(identity: int, api_id: int, parameter: dict[str, Any] | str, *, lease: int = 0, priority: int = 0) -> Any:
    """A ``Request_`` as Unitree's SDK sends it (no binary, a reply wanted)."""
    from giwbc.hal.dds.api_idl import Request_, RequestHeader_, RequestIdentity_, RequestLease_, RequestPolicy_

    text = parameter if isinstance(parameter, str) else json.dumps(parameter)
    header = RequestHeader_(RequestIdentity_(identity, api_id), RequestLease_(lease), RequestPolicy_(priority, False))
    return Request_(header, text, [])


def response(to: Any, code: int, data: dict[str, Any] | str = "") -> Any:
    """The ``Response_`` to request ``to`` (its identity echoed)."""
    from giwbc.hal.dds.api_idl import RequestIdentity_, Response_, ResponseHeader_, ResponseStatus_

    identity = to.header.identity
    text = data if isinstance(data, str) else json.dumps(data)
    return Response_(ResponseHeader_(RequestIdentity_(identity.id, identity.api_id), ResponseStatus_(code)), text, [])


class MotionSwitcherClient:
    """The motion switcher's client (module docstring). ``timeout``: seconds one call waits for
    its response (``resend``: the request repeated this often meanwhile); ``discovery``: seconds to
    wait for the service's endpoints to match."""

    def __init__(self, domain: int, interface: str, *, timeout: float = 1.0, discovery: float = 2.0, resend: float = 0.1,
                 source: str = "dds") -> None:  # fmt: skip
        self.where = f"{source}: DDS domain {domain} on {interface!r}"
        self.timeout = float(timeout)
        self.resend = float(resend)
        self.endpoint = RpcEndpoint(domain, interface, source=source)
        self._next_id = time.monotonic_ns()  # request ids: unique within this client, as the SDK's (monotonic ns)
        self.calls: list[tuple[str, int]] = []  # (API name, status code) of each call, in order
        end = time.monotonic() + discovery
        while min(self.endpoint.matched()) < 1 and time.monotonic() < end:
            time.sleep(0.01)
        if self.endpoint.matched()[0] == 0:
            self.close()
            raise DdsLinkError(f"{self.where}: no motion switcher service: nobody reads {REQUEST_TOPIC} within {discovery:g} s")

    def call(self, api_id: int, parameter: dict[str, Any]) -> tuple[int, str]:
        """(status code, response data) of one call; :data:`RPC_ERR_CLIENT_API_TIMEOUT` when no response came in time.

        The request goes out again (a new id) every ``resend`` s until one is answered: discovery
        matches each side on its own clock, and a request written before the service's reader knew
        this writer is dropped there. The three calls are idempotent, so a repeat does no harm."""
        end = time.monotonic() + self.timeout
        sent: set[int] = set()
        code, data, due = RPC_ERR_CLIENT_API_TIMEOUT, "", 0.0
        while time.monotonic() < end:
            if time.monotonic() >= due:
                self._next_id += 1
                sent.add(self._next_id)
                self.endpoint.write(request(self._next_id, api_id, parameter))
                due = time.monotonic() + self.resend
            got = [r for r in self.endpoint.take() if r.header.identity.id in sent]
            if got:
                answer = got[0]
                code = RPC_ERR_CLIENT_API_NOT_MATCH if answer.header.identity.api_id != api_id else answer.header.status.code
                data = answer.data
                break
            time.sleep(0.002)
        self.calls.append((API_NAMES.get(api_id, str(api_id)), code))
        return code, data

    def _answer(self, api_id: int, parameter: dict[str, Any]) -> str:
        code, data = self.call(api_id, parameter)
        name = API_NAMES[api_id]
        if code == RPC_ERR_CLIENT_API_TIMEOUT:
            raise DdsLinkError(f"{self.where}: the motion switcher did not answer {name} within {self.timeout:g} s")
        if code != RPC_OK:
            raise DdsLinkError(f"{self.where}: the motion switcher refused {name} (status code {code})")
        return data

    def check_mode(self) -> Mode:
        """The active mode (CheckMode)."""
        data = self._answer(CHECK_MODE, {})
        try:
            fields = json.loads(data)
            return Mode(str(fields.get("form", "")), str(fields.get("name", "")))
        except (ValueError, AttributeError):
            raise DdsLinkError(f"{self.where}: the motion switcher's CheckMode answer is not a JSON object: {data[:80]!r}") from None

    def release(self, timeout: float = 5.0, interval: float = 0.2) -> Mode:
        """Release the active mode (ReleaseMode, then CheckMode, every ``interval`` s until no mode
        is active or ``timeout`` s passed: DdsLinkError). Returns the mode that was active."""
        previous = self.check_mode()
        end = time.monotonic() + timeout
        mode, attempts, code = previous, 0, RPC_OK
        while mode.active:
            if time.monotonic() > end:
                raise DdsLinkError(f"{self.where}: the robot's service {mode} is still active after {attempts} ReleaseMode in {timeout:g} s "
                                   f"(last status code {code}); release it by hand first (README: the G1 over DDS)")  # fmt: skip
            code = self.call(RELEASE_MODE, {})[0]
            attempts += 1
            time.sleep(min(interval, max(0.0, end - time.monotonic())))  # the service needs a moment to stop
            mode = self.check_mode()
        return previous

    def select(self, name: str, timeout: float = 5.0) -> Mode:
        """Select mode ``name`` (SelectMode) and wait up to ``timeout`` s until CheckMode reports it."""
        self._answer(SELECT_MODE, {"name": name})
        end = time.monotonic() + timeout
        mode = self.check_mode()
        while mode.name != name:
            if time.monotonic() > end:
                raise DdsLinkError(f"{self.where}: SelectMode {name!r} accepted but CheckMode reports {mode} after {timeout:g} s")
            time.sleep(0.05)
            mode = self.check_mode()
        return mode

    def close(self) -> None:
        self.endpoint.close()

    def __enter__(self) -> MotionSwitcherClient:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


__all__ = [
    "API_NAMES", "CHECK_MODE", "RELEASE_MODE", "REQUEST_TOPIC", "RESPONSE_TOPIC", "RPC_ERR_CLIENT_API_NOT_MATCH", "RPC_ERR_CLIENT_API_TIMEOUT",
    "RPC_ERR_SERVER_INTERNAL", "RPC_OK", "SELECT_MODE", "SERVICE", "Mode", "MotionSwitcherClient", "RpcEndpoint", "request", "response",
]  # fmt: skip
