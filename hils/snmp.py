"""The SNMP transport: NTCIP GET over UDP with gufo-snmp, SET (and SNMPv1 GET) with pysnmp's asyncio API.

Implements :class:`hils.transport.Transport` for wall-clock runs. Every request
becomes an asyncio task on the :class:`hils.clock.WallClockDriver`'s loop and
completes its SimPy event through :meth:`WallClockDriver.deliver`, so SimPy is
touched from the loop's thread only.

Rules of this module:

- SNMPv2c GETs (the poller's hot path) go through gufo-snmp, whose BER codec
  is compiled: a GET costs the client a few tens of microseconds instead of
  pysnmp's two milliseconds. gufo-snmp keeps one request in flight per
  socket, so the transport keeps a pool of sessions: a GET takes an idle one
  or opens another, and a session whose request timed out is dropped (a late
  answer must not be read as the next request's). SNMPv1 GETs stay with
  pysnmp: gufo-snmp reports a v1 noSuchName as an empty answer, without the
  error index.
- One pysnmp ``SnmpEngine`` and one UDP target for the whole run, created once.
- Several objects per PDU: the poller's reds, yellows and greens in one GET,
  a phase call's groups in one SET (INTEGER values).
- No retries: one datagram per request, and no answer within ``tau_udp``
  fails the event with :class:`CommunicationTimeout`. The deadline is our own
  asyncio timer started when :meth:`get`/:meth:`set` is called; pysnmp's own
  timeout is set later than it, because pysnmp checks timeouts on a 0.1 s tick
  and could fire up to one tick early.
- A refusal (error-status, or a v2c varbind exception) fails the event with
  :class:`hils.ntcip.SnmpError`; values come back as ``int`` or ``bytes``.
- Varbinds are built once per distinct request and reused: pysnmp resolves an
  ``ObjectType`` against its MIB view on first use (about 0.14 ms a varbind)
  and skips that for an object it has already resolved.
"""

from __future__ import annotations

import asyncio
import operator
import socket
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any
from urllib.parse import unquote, urlsplit

import simpy
from gufo.snmp import SnmpError as GufoError
from gufo.snmp import SnmpVersion as GufoVersion
from gufo.snmp.aio.client import SnmpSession
from pyasn1.type import univ
from pysnmp.hlapi.v3arch.asyncio import (
    CommunityData,
    ContextData,
    EndOfMibView,
    Integer32,
    NoSuchInstance,
    NoSuchObject,
    ObjectIdentity,
    ObjectType,
    SnmpEngine,
    UdpTransportTarget,
    get_cmd,
    set_cmd,
)
from pysnmp.proto import errind

from hils.clock import WallClockDriver
from hils.ntcip import ErrorStatus, Oid, SnmpError, oid_str
from hils.transport import CommunicationTimeout, TransportError, Value, VarBind

__all__ = ["SnmpTarget", "SnmpTransport", "SnmpVersion"]

DEFAULT_PORT = 161
DEFAULT_COMMUNITY = "public"

# pysnmp's own timeout is only a backstop behind our deadline (see module doc).
_PYSNMP_TIMEOUT_MARGIN = 1.0
# Distinct requests whose varbinds are kept; a run uses a handful (poll, calls).
_VARBIND_CACHE_SIZE = 1024
_EXCEPTION_VALUES = (NoSuchObject, NoSuchInstance, EndOfMibView)


class SnmpVersion(Enum):
    """SNMP versions with community security; the value is how a target URL spells it."""

    V1 = "1"
    V2C = "2c"

    @property
    def mp_model(self) -> int:
        """pysnmp's message processing model number (``CommunityData(mpModel=...)``)."""
        return 0 if self is SnmpVersion.V1 else 1


_QUERY_KEYS = ("community", "version")


@dataclass(frozen=True, slots=True)
class SnmpTarget:
    """Where the controller answers and how to speak to it: ``snmp://HOST[:PORT][?community=C&version=1|2c]``."""

    host: str
    port: int = DEFAULT_PORT
    community: str = DEFAULT_COMMUNITY
    version: SnmpVersion = SnmpVersion.V2C

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("SNMP target needs a host")
        if not 1 <= self.port <= 65535:
            raise ValueError(f"SNMP target port {self.port} is outside 1..65535")

    @classmethod
    def parse(cls, url: str) -> SnmpTarget:
        """Parse a target URL; a ValueError says what is wrong and what is allowed."""
        form = "snmp://HOST[:PORT][?community=NAME&version=1|2c]"
        parts = urlsplit(url.strip())
        if parts.scheme != "snmp":
            raise ValueError(f"SNMP target {url!r} must start with snmp:// (form: {form})")
        if parts.username is not None or parts.password is not None:
            raise ValueError(f"SNMP target {url!r}: give the community as ?community=NAME, not before the host")
        if parts.path not in ("", "/") or parts.fragment:
            raise ValueError(f"SNMP target {url!r} has a path or fragment; the form is {form}")
        host = parts.hostname
        if not host:
            raise ValueError(f"SNMP target {url!r} has no host (form: {form})")
        if ":" in host:
            raise ValueError(f"SNMP target {url!r}: IPv6 addresses are not supported; give an IPv4 address or a name")
        try:
            port = parts.port
        except ValueError:
            raise ValueError(f"SNMP target {url!r}: the port must be a number in 1..65535") from None
        options = _parse_query(url, parts.query)
        version_text = options.get("version", SnmpVersion.V2C.value).lower()
        try:
            version = SnmpVersion(version_text)
        except ValueError:
            allowed = ", ".join(v.value for v in SnmpVersion)
            raise ValueError(f"SNMP target {url!r}: version {version_text!r} is not one of {allowed}") from None
        community = options.get("community", DEFAULT_COMMUNITY)
        if not community:
            raise ValueError(f"SNMP target {url!r}: the community is empty")
        return cls(host, DEFAULT_PORT if port is None else port, community, version)


def _parse_query(url: str, query: str) -> dict[str, str]:
    options: dict[str, str] = {}
    for item in filter(None, query.split("&")):
        key, sep, value = item.partition("=")
        key = unquote(key)
        if not sep:
            raise ValueError(f"SNMP target {url!r}: query item {item!r} is not KEY=VALUE")
        if key not in _QUERY_KEYS:
            raise ValueError(f"SNMP target {url!r}: unknown option {key!r}; allowed: {', '.join(_QUERY_KEYS)}")
        if key in options:
            raise ValueError(f"SNMP target {url!r}: option {key!r} is given twice")
        options[key] = unquote(value)
    return options


class _ResolvedUdpTarget(UdpTransportTarget):
    """A UDP target for an address resolved beforehand.

    The stock ``create()`` resolves through ``loop.getaddrinfo``, i.e. on a
    thread of the loop's executor; resolving once in the constructor keeps
    the run thread-free and reports a bad host name before the run starts.
    """

    async def _resolve_address(self, address: tuple[str, int]) -> tuple[str, int]:
        return address


class SnmpTransport:
    """GET and SET of NTCIP objects to one SNMP agent, as SimPy events completed by the wall-clock driver."""

    def __init__(self, env: simpy.Environment, driver: WallClockDriver, target: SnmpTarget,
                 tau_udp: float = 1.0) -> None:
        if driver.env is not env:
            raise ValueError("the driver must step the transport's environment")
        if not tau_udp > 0:
            raise ValueError(f"tau_udp must be positive, got {tau_udp}")
        self.env = env
        self.driver = driver
        self.target = target
        self.tau_udp = tau_udp
        self._address = _resolve(target)
        # Built now rather than on the first request: it takes ~50 ms, which
        # would otherwise stall the loop in the middle of a run.
        self._engine = SnmpEngine()
        self._auth = CommunityData(target.community, mpModel=target.version.mp_model)
        self._context = ContextData()
        self._udp: _ResolvedUdpTarget | None = None
        self._get_names: dict[tuple[Oid, ...], tuple[str, ...]] = {}
        self._sessions: list[SnmpSession] = []
        self._get_varbinds: dict[tuple[Oid, ...], tuple[ObjectType, ...]] = {}
        self._set_varbinds: dict[tuple[VarBind, ...], tuple[ObjectType, ...]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._closed = False

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        """GET of several objects in one PDU; the event's value is a tuple of int/bytes in the same order."""
        key = tuple(tuple(oid) for oid in oids)
        if self.target.version is not SnmpVersion.V1:
            names = self._get_names.get(key)
            if names is None:
                if not key:
                    raise ValueError("a GET needs at least one OID")
                names = _remember(self._get_names, key, tuple(oid_str(oid) for oid in key))
            return self._submit(self._gufo_get, names)
        varbinds = self._get_varbinds.get(key)
        if varbinds is None:
            if not key:
                raise ValueError("a GET needs at least one OID")
            varbinds = _remember(self._get_varbinds, key, tuple(ObjectType(ObjectIdentity(oid)) for oid in key))
        return self._submit(self._pysnmp, get_cmd, varbinds, _decode_values)

    def set(self, varbinds: Sequence[VarBind]) -> simpy.Event:
        """SET of several INTEGER objects in one PDU; the event's value is None."""
        key = tuple((tuple(oid), value) for oid, value in varbinds)
        objects = self._set_varbinds.get(key)
        if objects is None:
            if not key:
                raise ValueError("a SET needs at least one varbind")
            objects = _remember(self._set_varbinds, key,
                                tuple(ObjectType(ObjectIdentity(oid), Integer32(_integer(oid, value)))
                                      for oid, value in key))
        return self._submit(self._pysnmp, set_cmd, objects, _no_value)

    def close(self) -> None:
        """Cancel requests in flight and release the sockets; their events never complete."""
        if self._closed:
            return
        self._closed = True
        for task in tuple(self._tasks):
            task.cancel()
        # gufo-snmp closes a session's socket when the session is dropped.
        self._sessions.clear()
        self._engine.close_dispatcher()

    def _submit(self, work: Callable[..., Awaitable[Any]], *args: Any) -> simpy.Event:
        if self._closed:
            raise RuntimeError("the SNMP transport is closed")
        loop = self.driver.loop
        event = self.env.event()
        task = loop.create_task(self._request(work(*args), event, loop.time() + self.tau_udp))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return event

    async def _request(self, work: Awaitable[Any], event: simpy.Event, deadline: float) -> None:
        try:
            async with asyncio.timeout_at(deadline):
                value = await work
        except TimeoutError:
            self.driver.deliver(event, exc=CommunicationTimeout(
                f"no answer from {self.target.host}:{self.target.port} within {self.tau_udp} s"))
        except (SnmpError, TransportError) as exc:
            self.driver.deliver(event, exc=exc)
        except Exception as exc:
            # Whatever the SNMP library raised, the SimPy side must see the request end.
            self.driver.deliver(event, exc=TransportError(f"SNMP request failed: {exc!r}"))
        else:
            self.driver.deliver(event, value)

    async def _gufo_get(self, names: tuple[str, ...]) -> tuple[Value, ...]:
        session = self._sessions.pop() if self._sessions else self._new_session()
        try:
            answer = await session.get_many(names)
        except GufoError as exc:
            # An answer came (an error status): the session is clean for the next request.
            self._sessions.append(session)
            raise TransportError(f"SNMP GET refused: {exc!r}") from None
        self._sessions.append(session)
        return _gufo_values(names, answer)

    def _new_session(self) -> SnmpSession:
        host, port = self._address
        # gufo's own timeout is a backstop behind our deadline, like pysnmp's.
        return SnmpSession(host, port, community=self.target.community, version=GufoVersion.v2c,
                           timeout=self.tau_udp + _PYSNMP_TIMEOUT_MARGIN, allow_bulk=False)

    async def _pysnmp(self, command: Callable[..., Awaitable[Any]], varbinds: tuple[ObjectType, ...],
                      decode: Callable[[Sequence[Any]], Any]) -> Any:
        udp = self._udp or await self._open()
        indication, status, index, answer = await command(
            self._engine, self._auth, udp, self._context, *varbinds, lookupMib=False)
        return _check_answer(indication, status, index, answer, len(varbinds), decode)

    async def _open(self) -> _ResolvedUdpTarget:
        # create() does not suspend (the address is already resolved), so no
        # other request can interleave here and open a second target.
        udp = await _ResolvedUdpTarget.create(self._address, timeout=self.tau_udp + _PYSNMP_TIMEOUT_MARGIN,
                                              retries=0)
        self._udp = udp
        return udp


def _resolve(target: SnmpTarget) -> tuple[str, int]:
    try:
        infos = socket.getaddrinfo(target.host, target.port, socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    except socket.gaierror as exc:
        raise TransportError(f"cannot resolve SNMP target host {target.host!r}: {exc.strerror}") from None
    host, port = infos[0][4][:2]
    return host, port


def _integer(oid: Oid, value: Any) -> int:
    # Any integer type (numpy's too) but bool, which is more likely a mistake than a 0/1 value.
    if isinstance(value, bool) or not hasattr(type(value), "__index__"):
        raise TypeError(f"SET of {oid_str(oid)}: only INTEGER values are sent, got {value!r}")
    number = operator.index(value)
    if not -(2**31) <= number < 2**31:
        raise ValueError(f"SET of {oid_str(oid)}: {number} does not fit an SNMP INTEGER (Integer32)")
    return number


def _remember(cache: dict, key: Any, value: Any) -> Any:
    if len(cache) >= _VARBIND_CACHE_SIZE:
        cache.clear()
    cache[key] = value
    return value


def _check_answer(indication: Any, status: Any, index: Any, answer: Sequence[Any], expected: int,
                  decode: Callable[[Sequence[Any]], Any]) -> Any:
    if indication:
        if isinstance(indication, errind.RequestTimedOut):
            raise CommunicationTimeout(str(indication))
        raise TransportError(f"SNMP engine error: {indication}")
    if status:
        code = int(status)
        try:
            error = ErrorStatus(code)
        except ValueError:
            raise TransportError(f"SNMP error-status {code} is not defined by RFC 3416") from None
        raise SnmpError(error, int(index))
    if len(answer) != expected:
        raise TransportError(f"SNMP answer has {len(answer)} varbinds for {expected} requested")
    return decode(answer)


def _decode_values(answer: Sequence[Any]) -> tuple[Value, ...]:
    values: list[Value] = []
    for i, (name, value) in enumerate(answer, 1):
        # The exception values derive from Null, and Null from OctetString: test them first.
        if isinstance(value, _EXCEPTION_VALUES):
            raise SnmpError(ErrorStatus.NO_SUCH_NAME, i, f"{type(value).__name__} at {name}")
        if isinstance(value, univ.Integer):
            values.append(int(value))
        elif isinstance(value, univ.OctetString) and not isinstance(value, univ.Null):
            values.append(bytes(value))
        else:
            raise TransportError(f"varbind {i} ({name}): {type(value).__name__} is neither INTEGER nor OCTET STRING")
    return tuple(values)


def _gufo_values(names: tuple[str, ...], answer: dict[str, Any]) -> tuple[Value, ...]:
    values: list[Value] = []
    for i, name in enumerate(names, 1):
        # gufo-snmp leaves out a varbind that came back noSuchObject or noSuchInstance.
        if name not in answer:
            raise SnmpError(ErrorStatus.NO_SUCH_NAME, i, f"no such object or instance at {name}")
        value = answer[name]
        if isinstance(value, bool) or not isinstance(value, int | bytes):
            raise TransportError(f"varbind {i} ({name}): {type(value).__name__} is neither INTEGER nor OCTET STRING")
        values.append(value)
    return tuple(values)


def _no_value(_answer: Sequence[Any]) -> None:
    return None
