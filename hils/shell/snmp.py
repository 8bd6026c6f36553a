"""The SNMP transport: NTCIP GET over UDP with gufo-snmp, SET (and SNMPv1 GET) with pysnmp's asyncio API.

Implements :class:`hils.shell.transport.Transport` for wall-clock runs. Every request
becomes an asyncio task on the :class:`hils.shell.clock.WallClockDriver`'s loop and
completes its SimPy event through :meth:`WallClockDriver.deliver`, so SimPy is
touched from the loop's thread only.

Rules of this module:

- SNMPv2c GETs (the poller's hot path) go through gufo-snmp, whose BER codec
  is compiled: a poll costs the client about 0.1 ms of CPU, event loop and
  driver included, instead of about 2 ms through pysnmp. gufo-snmp keeps one request in flight per
  socket, so the transport keeps a pool of sessions: a GET takes an idle one
  or opens another, and a session whose request timed out is dropped (a late
  answer must not be read as the next request's). SNMPv1 GETs stay with
  pysnmp: gufo-snmp reports a v1 noSuchName as an empty answer, without the
  error index.
- One pysnmp ``SnmpEngine`` per run (per wall-clock driver and SNMPv3 user), shared by the transports of
  all its controllers and created once: an engine costs ~50 ms to build and loads its MIB modules
  again on its first SET, which, once per controller, stalled the loop of a corridor's start-up.
  One UDP target per transport, also created once.
- SNMPv3 (USM, authNoPriv or authPriv with HMAC-SHA-96 and AES-128): gufo-snmp
  for GETs (each session discovers the agent's engine first), pysnmp's
  ``UsmUserData`` for SETs. Keys missing from the target URL come from the
  environment variables ``HILS_SNMP_AUTH_KEY`` and ``HILS_SNMP_PRIV_KEY``.
  A target is refused when pysnmp cannot secure its level here (:func:`hils.protocol.usm.services_missing`).
- A v3 exchange the agent refuses fails with :class:`SecurityRefused` naming the usmStats counter of
  its Report (:class:`hils.protocol.usm.UsmFailure`): wrong digest, decryption error, unknown user, time
  window, security level. gufo-snmp says only that a Report came, so its session is dropped and the
  GET is sent once more through pysnmp, which reads the Report (or, the session having gone stale,
  gets the answer).
- Several objects per PDU: the poller's reds, yellows and greens in one GET,
  a phase call's groups in one SET (INTEGER values).
- No retries: one datagram per request, and no answer within ``tau_udp``
  fails the event with :class:`CommunicationTimeout`. The deadline is our own
  asyncio timer started when :meth:`get`/:meth:`set` is called; the libraries'
  own timeouts are set later than it (pysnmp checks timeouts on a 0.1 s tick
  and could fire up to one tick early).
- A refusal (error-status, or a v2c varbind exception) fails the event with
  :class:`hils.protocol.ntcip.SnmpError`; values come back as ``int`` or ``bytes``.
  Through gufo-snmp a missing object is NO_SUCH_NAME at its index, and any
  other error-status of a GET a :class:`TransportError` naming it (gufo-snmp
  does not report the status as a number).
- Varbinds are built once per distinct request and reused: pysnmp resolves an
  ``ObjectType`` against its MIB view on first use (about 0.14 ms a varbind)
  and skips that for an object it has already resolved.
"""

from __future__ import annotations

import asyncio
import operator
import os
import re
import socket
import weakref
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any
from urllib.parse import unquote, urlsplit

import simpy
from gufo.snmp import Aes128Key, Sha1Key, SnmpAuthError, User
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
    UsmUserData,
    get_cmd,
    set_cmd,
    usmAesCfb128Protocol,
    usmHMACSHAAuthProtocol,
)
from pysnmp.proto import errind

from hils.protocol.ntcip import AUTH_KEY_ENV, PRIV_KEY_ENV, ErrorStatus, Oid, SnmpError, oid_str
from hils.protocol.usm import UsmFailure, services_missing
from hils.shell.clock import WallClockDriver
from hils.shell.transport import CommunicationTimeout, SecurityRefused, TransportError, Value, VarBind

__all__ = ["AUTH_KEY_ENV", "PRIV_KEY_ENV", "AuthProtocol", "PrivProtocol", "SnmpTarget", "SnmpTransport", "SnmpVersion"]

DEFAULT_PORT = 161
DEFAULT_COMMUNITY = "public"

# The libraries' own timeouts are only a backstop behind our deadline (see module doc).
_LIBRARY_TIMEOUT_MARGIN = 1.0
# Distinct requests whose varbinds are kept; a run uses a handful (poll, calls).
_VARBIND_CACHE_SIZE = 1024
_EXCEPTION_VALUES = (NoSuchObject, NoSuchInstance, EndOfMibView)
# pysnmp's indications of a message this end could not secure (its ciphers missing, say).
_LOCAL_SECURITY_FAILURES = (errind.EncryptionError, errind.AuthenticationError, errind.UnsupportedAuthProtocol,
                            errind.UnsupportedPrivProtocol, errind.NoEncryption, errind.NoAuthentication)


class SnmpVersion(Enum):
    """SNMP versions; the value is how a target URL spells it."""

    V1 = "1"
    V2C = "2c"
    V3 = "3"

    @property
    def mp_model(self) -> int:
        """pysnmp's message processing model number (``CommunityData(mpModel=...)``)."""
        return {SnmpVersion.V1: 0, SnmpVersion.V2C: 1, SnmpVersion.V3: 3}[self]


class AuthProtocol(Enum):
    """SNMPv3 authentication (USM, RFC 3414); the value is how a target URL spells it."""

    SHA = "SHA"  # HMAC-SHA-96


class PrivProtocol(Enum):
    """SNMPv3 privacy (USM, RFC 3826); the value is how a target URL spells it."""

    AES = "AES"  # AES-128 in CFB mode


#: RFC 3414 (11.2) asks for pass phrases of at least 8 characters; net-snmp refuses shorter ones.
MIN_KEY_LENGTH = 8

_COMMUNITY_KEYS = ("community", "version")
_V3_KEYS = ("version", "user", "auth", "auth_key", "priv", "priv_key")
_QUERY_KEYS = tuple(dict.fromkeys(_COMMUNITY_KEYS + _V3_KEYS))
_KEYS_IN_URL = re.compile(r"\b(auth_key|priv_key)=[^&#]*")


def url_shown(url: str) -> str:
    """How messages and logs quote a target URL: without its keys (``auth_key=...``)."""
    return _KEYS_IN_URL.sub(r"\1=...", url)


_FORM = ("snmp://HOST[:PORT][?community=NAME&version=1|2c] or "
         "snmp://HOST[:PORT]?version=3&user=U&auth=SHA[&auth_key=K][&priv=AES[&priv_key=K]]")


@dataclass(frozen=True, slots=True)
class SnmpTarget:
    """Where the controller answers and how to speak to it (URL forms in :meth:`parse`).

    SNMPv1/v2c use ``community``; SNMPv3 uses the user-based security model with ``user``,
    authentication (``auth``, ``auth_key``) and optionally privacy (``priv``, ``priv_key``):
    authNoPriv or authPriv, and has no community (``""``). Keys are pass phrases; they never appear in
    the repr.
    """

    host: str
    port: int = DEFAULT_PORT
    community: str = DEFAULT_COMMUNITY
    version: SnmpVersion = SnmpVersion.V2C
    user: str = ""
    auth: AuthProtocol | None = None
    auth_key: str = field(default="", repr=False)
    priv: PrivProtocol | None = None
    priv_key: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("SNMP target needs a host")
        if not 1 <= self.port <= 65535:
            raise ValueError(f"SNMP target port {self.port} is outside 1..65535")
        if self.version is SnmpVersion.V3:
            # Messages name a community only where there is one (start-up advice, snmpset hints).
            object.__setattr__(self, "community", "")
            if not self.user:
                raise ValueError("an SNMPv3 target needs a user")
            if self.auth is None:
                raise ValueError("an SNMPv3 target needs auth=SHA (authNoPriv or authPriv; noAuthNoPriv is not "
                                 "supported)")
            for name, protocol, key in (("auth", self.auth, self.auth_key), ("priv", self.priv, self.priv_key)):
                if protocol is not None and len(key) < MIN_KEY_LENGTH:
                    raise ValueError(f"SNMPv3 {name}_key must have at least {MIN_KEY_LENGTH} characters")
        elif self.user or self.auth or self.priv:
            raise ValueError("user, auth and priv are SNMPv3 options; add version=3")

    @property
    def security_level(self) -> str:
        """The SNMPv3 security level, as net-snmp's ``-l`` spells it."""
        return "authPriv" if self.priv is not None else "authNoPriv"

    @classmethod
    def parse(cls, url: str, environ: Mapping[str, str] | None = None) -> SnmpTarget:
        """Parse a target URL; a ValueError says what is wrong and what is allowed.

        SNMPv3 keys missing from the URL are taken from ``environ`` (the process environment by
        default): :data:`AUTH_KEY_ENV` and :data:`PRIV_KEY_ENV`.
        """
        env = os.environ if environ is None else environ
        shown = url_shown(url)
        parts = urlsplit(url.strip())
        if parts.scheme != "snmp":
            raise ValueError(f"SNMP target {shown!r} must start with snmp:// (form: {_FORM})")
        if parts.username is not None or parts.password is not None:
            raise ValueError(f"SNMP target {shown!r}: give the community as ?community=NAME, not before the host")
        if parts.path not in ("", "/") or parts.fragment:
            raise ValueError(f"SNMP target {shown!r} has a path or fragment; the form is {_FORM}")
        host = parts.hostname
        if not host:
            raise ValueError(f"SNMP target {shown!r} has no host (form: {_FORM})")
        if ":" in host:
            raise ValueError(f"SNMP target {shown!r}: IPv6 addresses are not supported; give an IPv4 address or a name")
        try:
            port = parts.port
        except ValueError:
            raise ValueError(f"SNMP target {shown!r}: the port must be a number in 1..65535") from None
        port = DEFAULT_PORT if port is None else port
        options = _parse_query(shown, parts.query)
        version_text = options.get("version", SnmpVersion.V2C.value).lower()
        try:
            version = SnmpVersion(version_text)
        except ValueError:
            allowed = ", ".join(v.value for v in SnmpVersion)
            raise ValueError(f"SNMP target {shown!r}: version {version_text!r} is not one of {allowed}") from None
        allowed_keys = _V3_KEYS if version is SnmpVersion.V3 else _COMMUNITY_KEYS
        for key in options:
            if key not in allowed_keys:
                raise ValueError(f"SNMP target {shown!r}: option {key!r} does not go with version {version.value}; "
                                 f"allowed: {', '.join(allowed_keys)}")
        if version is not SnmpVersion.V3:
            community = options.get("community", DEFAULT_COMMUNITY)
            if not community:
                raise ValueError(f"SNMP target {shown!r}: the community is empty")
            return cls(host, port, community, version)
        auth = _protocol(shown, "auth", options.get("auth"), AuthProtocol)
        priv = _protocol(shown, "priv", options.get("priv"), PrivProtocol)
        for name, protocol, kind in (("auth", auth, AuthProtocol), ("priv", priv, PrivProtocol)):
            if f"{name}_key" in options and protocol is None:
                raise ValueError(f"SNMP target {shown!r}: {name}_key without {name}: add {name}="
                                 f"{'|'.join(p.value for p in kind)}, or leave the key out")
        auth_key = options.get("auth_key") or env.get(AUTH_KEY_ENV, "") if auth else ""
        priv_key = options.get("priv_key") or env.get(PRIV_KEY_ENV, "") if priv else ""
        for name, protocol, key, variable in (("auth", auth, auth_key, AUTH_KEY_ENV),
                                              ("priv", priv, priv_key, PRIV_KEY_ENV)):
            if protocol is not None and not key:
                raise ValueError(f"SNMP target {shown!r}: {name}={protocol.value} needs a key: give {name}_key=K "
                                 f"or set {variable}")
        try:
            target = cls(host, port, version=version, user=options.get("user", ""), auth=auth, auth_key=auth_key,
                         priv=priv, priv_key=priv_key)
        except ValueError as exc:
            raise ValueError(f"SNMP target {shown!r}: {exc}") from None
        missing = services_missing(privacy=priv is not None)
        if missing:
            raise ValueError(f"SNMP target {shown!r}: {missing}")
        return target


def _protocol(url: str, name: str, text: str | None, kind: type[AuthProtocol] | type[PrivProtocol]) -> Any:
    if text is None:
        return None
    try:
        return kind(text.upper())
    except ValueError:
        allowed = ", ".join(p.value for p in kind)
        raise ValueError(f"SNMP target {url!r}: {name} {text!r} is not supported; allowed: {allowed}") from None


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
                 tau_udp: float = 1.0, address: tuple[str, int] | None = None) -> None:
        """``address``: the target's, as :func:`resolve` gave it to a caller that checked the target first
        (None: resolved here)."""
        if driver.env is not env:
            raise ValueError("the driver must step the transport's environment")
        if not tau_udp > 0:
            raise ValueError(f"tau_udp must be positive, got {tau_udp}")
        self.env = env
        self.driver = driver
        self.target = target
        self.tau_udp = tau_udp
        self._address = address or resolve(target)
        # Taken now rather than on the first request: building one takes ~50 ms, which
        # would otherwise stall the loop in the middle of a run.
        self._engine = _ENGINES.take(driver, _credentials(target))
        self._auth = _pysnmp_auth(target)
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
        if not key:
            raise ValueError("a GET needs at least one OID")
        if self.target.version is not SnmpVersion.V1:
            names = self._get_names.get(key)
            if names is None:
                names = _remember(self._get_names, key, tuple(oid_str(oid) for oid in key))
            return self._submit(self._gufo_get, key, names)
        return self._submit(self._pysnmp, get_cmd, self._varbinds(key), _decode_values)

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
        _ENGINES.give_back(self.driver, _credentials(self.target))

    def _varbinds(self, key: tuple[Oid, ...]) -> tuple[ObjectType, ...]:
        """pysnmp's varbinds of a GET of ``key``, built once."""
        varbinds = self._get_varbinds.get(key)
        if varbinds is None:
            varbinds = _remember(self._get_varbinds, key, tuple(ObjectType(ObjectIdentity(oid)) for oid in key))
        return varbinds

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

    async def _gufo_get(self, key: tuple[Oid, ...], names: tuple[str, ...]) -> tuple[Value, ...]:
        session = self._sessions.pop() if self._sessions else await self._new_session()
        try:
            answer = await session.get_many(names)
        except SnmpAuthError:
            # A Report (SNMPv3): gufo-snmp does not say which, pysnmp does. The session stays dropped: if
            # it had only gone stale (the agent restarted), the next one discovers the agent afresh.
            return await self._pysnmp(get_cmd, self._varbinds(key), _decode_values)
        except GufoError as exc:
            # An answer came (an error status): the session is clean for the next request.
            self._sessions.append(session)
            raise TransportError(f"SNMP GET refused: {exc!r}") from None
        self._sessions.append(session)
        return _gufo_values(names, answer)

    async def _new_session(self) -> SnmpSession:
        host, port = self._address
        target = self.target
        timeout = self.tau_udp + _LIBRARY_TIMEOUT_MARGIN
        if target.version is not SnmpVersion.V3:
            return SnmpSession(host, port, community=target.community, version=GufoVersion.v2c, timeout=timeout,
                               allow_bulk=False)
        user = User(target.user, auth_key=Sha1Key(target.auth_key.encode()),
                    priv_key=Aes128Key(target.priv_key.encode()) if target.priv is not None else None)
        session = SnmpSession(host, port, user=user, version=GufoVersion.v3, timeout=timeout, allow_bulk=False)
        # USM discovery (RFC 3414 4): the agent's engine id, boots and time, under the request's deadline.
        await session.refresh()
        return session

    async def _pysnmp(self, command: Callable[..., Awaitable[Any]], varbinds: tuple[ObjectType, ...],
                      decode: Callable[[Sequence[Any]], Any]) -> Any:
        udp = self._udp or await self._open()
        indication, status, index, answer = await command(
            self._engine, self._auth, udp, self._context, *varbinds, lookupMib=False)
        if indication and not isinstance(indication, errind.RequestTimedOut):
            self._refused(indication)
        return _check_answer(indication, status, index, answer, len(varbinds), decode)

    def _refused(self, indication: Any) -> None:
        """Raise :class:`SecurityRefused` if pysnmp's ``indication`` is a USM refusal or this end cannot secure
        the message; return for anything else."""
        target = self.target
        failure = UsmFailure.of(indication)
        if failure is not None:
            raise SecurityRefused(f"{target.host}:{target.port} refused SNMPv3 user {target.user!r} at "
                                  f"{target.security_level}: {failure}")
        if isinstance(indication, _LOCAL_SECURITY_FAILURES):
            raise SecurityRefused(services_missing(privacy=target.priv is not None)
                                  or f"SNMPv3 security failed: {indication}")

    async def _open(self) -> _ResolvedUdpTarget:
        # create() does not suspend (the address is already resolved), so no
        # other request can interleave here and open a second target.
        udp = await _ResolvedUdpTarget.create(self._address, timeout=self.tau_udp + _LIBRARY_TIMEOUT_MARGIN,
                                              retries=0)
        self._udp = udp
        return udp


class _SharedEngines:
    """pysnmp engines shared by the transports of one run (one wall-clock driver), each closed when its last
    transport closes; a run dropped half assembled takes its engines with it (the drivers are weak keys).

    Controllers of one credentials share an engine (pysnmp keeps a target's community or USM user in
    its engine's configuration; two SNMPv3 users of one name and different keys cannot share one)."""

    @dataclass
    class _Shared:
        engine: SnmpEngine
        users: int = 0  # transports using it

    def __init__(self) -> None:
        self._runs: weakref.WeakKeyDictionary[WallClockDriver, dict[tuple[str, ...], _SharedEngines._Shared]] = (
            weakref.WeakKeyDictionary())

    def take(self, driver: WallClockDriver, credentials: tuple[str, ...]) -> SnmpEngine:
        engines = self._runs.setdefault(driver, {})
        if credentials not in engines:
            engines[credentials] = self._Shared(SnmpEngine())
        shared = engines[credentials]
        shared.users += 1
        return shared.engine

    def give_back(self, driver: WallClockDriver, credentials: tuple[str, ...]) -> None:
        engines = self._runs[driver]
        shared = engines[credentials]
        shared.users -= 1
        if not shared.users:
            del engines[credentials]
            shared.engine.close_dispatcher()


_ENGINES = _SharedEngines()


def _credentials(target: SnmpTarget) -> tuple[str, ...]:
    """What decides whether two targets' SETs can share an engine (communities differ by index in one)."""
    if target.version is not SnmpVersion.V3:
        return ()
    return (target.user, target.auth_key, target.priv_key or "")


def resolve(target: SnmpTarget) -> tuple[str, int]:
    """The IPv4 address and port of the target's host; a host this machine cannot resolve is a
    :class:`TransportError` naming it."""
    try:
        infos = socket.getaddrinfo(target.host, target.port, socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    except socket.gaierror as exc:
        raise TransportError(f"cannot resolve SNMP target host {target.host!r}: {exc.strerror}") from None
    host, port = infos[0][4][:2]
    return host, port


def _pysnmp_auth(target: SnmpTarget) -> CommunityData | UsmUserData:
    if target.version is not SnmpVersion.V3:
        return CommunityData(target.community, mpModel=target.version.mp_model)
    if target.priv is None:
        return UsmUserData(target.user, authKey=target.auth_key, authProtocol=usmHMACSHAAuthProtocol)
    return UsmUserData(target.user, authKey=target.auth_key, privKey=target.priv_key,
                       authProtocol=usmHMACSHAAuthProtocol, privProtocol=usmAesCfb128Protocol)


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
