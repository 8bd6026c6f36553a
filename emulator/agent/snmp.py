"""The emulator's SNMP agent: a live controller's NTCIP 1202 objects over SNMPv1, v2c and v3 on UDP.

Rules of this file
------------------
- pysnmp is the SNMP implementation: messages are decoded and built with its
  protocol API (``pysnmp.proto.api``) and pyasn1's BER codec. Nothing here
  writes BER by hand; only the message header is read by hand, in
  :mod:`emulator.agent.ber`.
- The agent is a plain asyncio datagram endpoint rather than a pysnmp
  ``SnmpEngine`` with MIB instrumentation: that keeps the error mapping per
  version, the dropping of foreign datagrams and the per-request latency in
  this file, exact and testable.
- SNMPv3 (one USM user, HMAC-SHA-96 with or without AES-128) goes through
  pysnmp's own message processing and user-based security (:class:`_Usm`):
  nothing of v3 is decoded here. Its PDUs are SNMPv2 PDUs and are answered
  by the same handlers as v2c; discovery, a request below the user's security
  level and authentication failures get pysnmp's Reports (a request below the
  level that pysnmp lets through all the same is dropped).
- pysnmp is handed only what it can answer cheaply or must: a message is
  screened first on its security header (:func:`emulator.agent.ber.read_usm`, a few
  microseconds, where pysnmp takes half a millisecond or more). An authentic
  message of the user at its level (its HMAC checked here against the user's
  key) goes through; one that draws a Report (discovery, an unknown user, a
  lower level, a wrong digest) goes through only within a :class:`ReportBudget`
  shared by the process's agents; the rest is dropped at once: a foreign engine
  ID (pysnmp would keep going and end in an error), or the agent's engine ID
  with no user name (no step of RFC 3414 sends that, and pysnmp lets it through
  as an unauthenticated request).
- No per-request state outlives its datagram: pysnmp keeps a state per message
  in its message processing and USM caches until the answer is sent, and never
  frees the state of a message nobody answers (USM's cache has no expiry, the
  other one expires on a timer this agent has no use for); both are emptied
  after every datagram. A flood of refused messages therefore costs no memory.
- A refused SNMPv3 request is logged as a warning with its reason (the usmStats
  counter of the Report, or why it was dropped), at once for the first of its
  kind and then at most once per :data:`WARN_EVERY` seconds with the count of
  those left out, so that a flood does not flood the log.
- :meth:`SnmpAgent.respond` turns one datagram into one answer (or None for a
  dropped datagram) synchronously and without I/O; it applies a SET to the MIB
  view at once. Only the endpoint sends, on an asyncio timer at the arrival
  time plus the modeled latency, so a slow answer never holds up the next
  request.

Theory of operation
-------------------
A datagram is checked in order of cost, so that hostile traffic costs little:
its length against ``max_message_size`` (nothing read), then its version and
community from the first bytes (:func:`emulator.agent.ber.read_header`), and only
then is the whole message decoded by pyasn1. A datagram longer than the
maximum, not a well-formed SNMPv1/v2c message (garbage, truncated, trailing
bytes, SNMPv3 when no v3 user is configured), that names neither community, or that carries no request PDU
(a response, trap or report) is dropped and counted per :class:`DropReason`,
as RFC 3416 and RFC 1157 ask for authentication failures and parse errors.
Everything else gets exactly one response, never longer than
``max_message_size``: a request is no longer than that, so the SNMPv1 tooBig
answer that echoes its varbinds fits too.

The MIB view (:class:`emulator.agent.mib.MibView`) refuses with four statuses; the
agent refines them into SNMPv2 terms (RFC 3416 section 4.2.5), then maps them
to SNMPv1 with RFC 3584 section 4.4 for v1 requests:

=====================================  =============================  ===========
case                                   SNMPv2c                        SNMPv1
=====================================  =============================  ===========
SET with the read-only community       noAccess, index 1              noSuchName
SET of a read-only object              notWritable                    noSuchName
SET of an unknown name                 notWritable                    noSuchName
SET of a missing row of a writable     noCreation                     noSuchName
column (e.g. a phase group past max)
SET value of a non-INTEGER type        wrongType                      badValue
SET value out of the object's range    wrongValue                     badValue
GET of an unknown object               noSuchObject varbind           noSuchName
GET of a missing instance              noSuchInstance varbind         noSuchName
GETNEXT/GETBULK past the last object   endOfMibView varbind           noSuchName
answer larger than max_message_size    tooBig, no varbinds            tooBig
=====================================  =============================  ===========

Where net-snmp's own snmpd meets the same case (read-only community, read-only
or unknown object, wrong type, missing object or instance) it answers the same,
in both versions. A refused SET changes nothing: the view validates every
varbind before applying any.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import logging
import random
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from types import ModuleType
from typing import Any

from pyasn1.codec.ber import decoder, encoder
from pyasn1.type import univ
from pysnmp.carrier.asyncio.dgram import udp
from pysnmp.entity import config
from pysnmp.entity.engine import SnmpEngine
from pysnmp.error import PySnmpError
from pysnmp.proto import api, rfc1905
from pysnmp.proto.mpmod.cache import Cache as MessageStates
from pysnmp.proto.secmod.cache import Cache as SecurityStates
from pysnmp.proto.secmod.rfc3414 import localkey

from emulator.agent.ber import Header, HeaderError, UsmHeader, encode_response, read_get, read_header, read_usm
from emulator.agent.mib import MibView, Value
from hils.protocol.ntcip import Access, ErrorStatus, Latency, Oid, SnmpError, object_for, oid_str
from hils.protocol.usm import UsmFailure

log = logging.getLogger(__name__)

#: The version field of an SNMPv3 message (RFC 3412); pysnmp's message processing model number too.
SNMP_VERSION_3 = 3
# Length fields of an SNMPv3 answer may take a few more bytes than its request's.
_V3_LENGTH_MARGIN = 8
#: Seconds between two ticks of USM's timer (see :meth:`_Usm.tick`).
USM_TICK = 1.0
#: The security model number of USM (RFC 3411).
USM_MODEL = 3
# msgFlags' two low bits (RFC 3412 6.4) -> securityLevel (RFC 3411): noAuthNoPriv 1, authNoPriv 2, authPriv 3.
_LEVELS = {0: 1, 1: 2, 3: 3}
#: SNMPv3 Reports a process's agents may send per second, and at once (see :class:`ReportBudget`).
REPORTS_PER_S = 100.0
REPORT_BURST = 100
#: Seconds between two warnings of one kind of refused SNMPv3 request.
WARN_EVERY = 10.0
# The dispatcher wants a transport address to answer to; ours answers the datagram's sender itself.
_NOWHERE = ("0.0.0.0", 0)

#: Largest answer sent: one Ethernet frame of UDP payload, so answers are never fragmented.
DEFAULT_MAX_MESSAGE_SIZE = 1472

# RFC 3584 section 4.4: how an SNMPv2 error status reads to an SNMPv1 manager.
_V1_STATUS: dict[ErrorStatus, ErrorStatus] = {
    ErrorStatus.NO_ERROR: ErrorStatus.NO_ERROR,
    ErrorStatus.TOO_BIG: ErrorStatus.TOO_BIG,
    ErrorStatus.NO_SUCH_NAME: ErrorStatus.NO_SUCH_NAME,
    ErrorStatus.BAD_VALUE: ErrorStatus.BAD_VALUE,
    ErrorStatus.READ_ONLY: ErrorStatus.READ_ONLY,
    ErrorStatus.GEN_ERR: ErrorStatus.GEN_ERR,
    ErrorStatus.WRONG_VALUE: ErrorStatus.BAD_VALUE,
    ErrorStatus.WRONG_ENCODING: ErrorStatus.BAD_VALUE,
    ErrorStatus.WRONG_TYPE: ErrorStatus.BAD_VALUE,
    ErrorStatus.WRONG_LENGTH: ErrorStatus.BAD_VALUE,
    ErrorStatus.INCONSISTENT_VALUE: ErrorStatus.BAD_VALUE,
    ErrorStatus.NO_ACCESS: ErrorStatus.NO_SUCH_NAME,
    ErrorStatus.NOT_WRITABLE: ErrorStatus.NO_SUCH_NAME,
    ErrorStatus.NO_CREATION: ErrorStatus.NO_SUCH_NAME,
    ErrorStatus.INCONSISTENT_NAME: ErrorStatus.NO_SUCH_NAME,
    ErrorStatus.RESOURCE_UNAVAILABLE: ErrorStatus.GEN_ERR,
    ErrorStatus.COMMIT_FAILED: ErrorStatus.GEN_ERR,
    ErrorStatus.UNDO_FAILED: ErrorStatus.GEN_ERR,
    ErrorStatus.AUTHORIZATION_ERROR: ErrorStatus.NO_SUCH_NAME,
}


class DropReason(Enum):
    """Why a datagram got no answer."""

    TOO_LARGE = "too large"  # longer than the maximum message size: dropped unread
    MALFORMED = "malformed"  # not a complete BER-encoded SNMP message
    VERSION = "unsupported version"  # SNMPv3 or an unknown version number
    COMMUNITY = "unknown community"
    NOT_A_REQUEST = "not a request"  # a response, trap, inform or report PDU
    AUTHENTICATION = "refused by USM"  # SNMPv3 below the user's security level, or USM dropped it silently
    ENGINE_ID = "foreign SNMPv3 engine ID"  # neither empty (discovery) nor this agent's
    NO_USER = "SNMPv3 without a user name"  # with this agent's engine ID: no step of RFC 3414 sends that
    REPORTS_SPENT = "SNMPv3 Reports over their rate"  # would have drawn a Report, with the budget spent


class RequestKind(Enum):
    GET = "get"
    GET_NEXT = "getnext"
    GET_BULK = "getbulk"
    SET = "set"


class Missing(Enum):
    """SNMPv2 exception values of a varbind; each one is a noSuchName error in SNMPv1."""

    NO_SUCH_OBJECT = "noSuchObject"
    NO_SUCH_INSTANCE = "noSuchInstance"
    END_OF_MIB_VIEW = "endOfMibView"


_MISSING_VALUES = {
    Missing.NO_SUCH_OBJECT: rfc1905.noSuchObject,
    Missing.NO_SUCH_INSTANCE: rfc1905.noSuchInstance,
    Missing.END_OF_MIB_VIEW: rfc1905.endOfMibView,
}


@dataclass(slots=True)
class AgentStats:
    """Traffic counters of one agent (mutable: updated as datagrams arrive)."""

    requests: Counter[RequestKind] = field(default_factory=Counter)
    errors: int = 0  # answers with a non-zero error status
    dropped: Counter[DropReason] = field(default_factory=Counter)
    reports: Counter[UsmFailure] = field(default_factory=Counter)  # SNMPv3 Reports sent, by the counter they name

    @property
    def answered(self) -> int:
        return sum(self.requests.values())

    @property
    def total_dropped(self) -> int:
        return sum(self.dropped.values())


class _Drop(Exception):
    def __init__(self, reason: DropReason, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


class ReportBudget:
    """How many SNMPv3 Reports may still be sent: a token bucket of ``burst`` tokens refilled at ``per_second``.

    A message that draws a Report costs pysnmp about a millisecond; a stream of them would take the loop
    from the controller's tick. One budget serves every agent of a process (they share its loop)."""

    def __init__(self, per_second: float = REPORTS_PER_S, burst: int = REPORT_BURST,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.per_second = per_second
        self.burst = burst
        self._clock = clock
        self._tokens = float(burst)
        self._at = clock()

    def take(self) -> bool:
        """Spend one Report if one is left."""
        now = self._clock()
        self._tokens = min(float(self.burst), self._tokens + (now - self._at) * self.per_second)
        self._at = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


class _Warnings:
    """Warnings of one kind at once, then at most one per ``every`` seconds with how many were left out."""

    def __init__(self, every: float = WARN_EVERY, clock: Callable[[], float] = time.monotonic) -> None:
        self.every = every
        self._clock = clock
        self._last: dict[Any, float] = {}
        self._left_out: Counter[Any] = Counter()

    def warn(self, kind: Any, message: str) -> None:
        now = self._clock()
        last = self._last.get(kind)
        if last is not None and now - last < self.every:
            self._left_out[kind] += 1
            return
        self._last[kind] = now
        left_out = self._left_out.pop(kind, 0)
        log.warning("%s%s", message, f" ({left_out} more like it in the last {now - last:.0f} s)" if left_out else "")


@dataclass(frozen=True, slots=True)
class _Request:
    version: int
    module: ModuleType  # pysnmp.proto.api.v1 or v2c
    message: Any
    pdu: Any
    oids: tuple[Oid, ...]
    values: tuple[Any, ...]  # the request's varbind values, pyasn1 objects
    writable: bool  # came with the read-write community
    usm: _UsmRequest | None = None  # how to answer an SNMPv3 request; None for v1/v2c


# One varbind of an answer: a value of the view, or an SNMPv2 exception value.
_Result = tuple[Oid, Value | Missing]


class SnmpAgent:
    """SNMPv1/v2c (and, with ``v3_user``, SNMPv3) command responder over one MIB view, on the running loop."""

    def __init__(self, view: MibView, *, ro_community: str = "public", rw_community: str = "private",
                 latency: Latency | None = None, seed: int | None = None,
                 max_message_size: int = DEFAULT_MAX_MESSAGE_SIZE, v3_user: V3User | None = None,
                 reports: ReportBudget | None = None) -> None:
        """``reports``: the budget of SNMPv3 Reports, shared with the process's other agents (None: its own)."""
        if ro_community == rw_community:
            raise ValueError("the read-only and read-write communities must differ")
        self.view = view
        self._usm = _Usm(v3_user, reports or ReportBudget()) if v3_user is not None else None
        self._warnings = _Warnings()
        self.communities = {ro_community.encode(): False, rw_community.encode(): True}
        self.latency = latency or Latency(0.0)
        self.max_message_size = max_message_size
        self.stats = AgentStats()
        self._rng = random.Random(seed)
        self._transport: asyncio.DatagramTransport | None = None
        v1, v2c = api.v1, api.v2c
        self._handlers: dict[int, dict[Any, Callable[[_Request, str], bytes]]] = {
            api.SNMP_VERSION_1: {v1.GetRequestPDU.tagSet: self._get, v1.GetNextRequestPDU.tagSet: self._get_next,
                                 v1.SetRequestPDU.tagSet: self._set},
            api.SNMP_VERSION_2C: {v2c.GetRequestPDU.tagSet: self._get, v2c.GetNextRequestPDU.tagSet: self._get_next,
                                  v2c.GetBulkRequestPDU.tagSet: self._get_bulk, v2c.SetRequestPDU.tagSet: self._set},
        }
        # SNMPv3 carries SNMPv2 PDUs (RFC 3416) and answers as v2c does.
        self._handlers[SNMP_VERSION_3] = self._handlers[api.SNMP_VERSION_2C]

    # --- serving ----------------------------------------------------------------------------

    async def start(self, host: str = "127.0.0.1", port: int = 1161) -> tuple[str, int]:
        """Bind the UDP socket (port 0 picks a free one) and answer from now on; returns the bound address."""
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(lambda: _Endpoint(self), local_addr=(host, port))
        if self._usm is not None:
            self._usm_tick()
        return self.address

    def _usm_tick(self) -> None:
        if self._usm is not None and self._transport is not None and not self._transport.is_closing():
            self._usm.tick()
            asyncio.get_running_loop().call_later(USM_TICK, self._usm_tick)

    @property
    def address(self) -> tuple[str, int]:
        if self._transport is None:
            raise RuntimeError("the agent is not started")
        host, port = self._transport.get_extra_info("sockname")[:2]
        return host, port

    def close(self) -> None:
        """Stop answering; answers still waiting out their latency are not sent."""
        if self._transport is not None:
            self._transport.close()

    def _send_later(self, answer: bytes, addr: tuple[str, int], arrived: float) -> None:
        """Send at ``arrived`` (loop time) plus the drawn latency: the decoding time is part of it."""
        loop = asyncio.get_running_loop()
        due = arrived + self.latency.draw(self._rng)
        if due <= loop.time():
            self._sendto(answer, addr)
        else:
            loop.call_at(due, self._sendto, answer, addr)

    def _sendto(self, answer: bytes, addr: tuple[str, int]) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.sendto(answer, addr)

    # --- one datagram -------------------------------------------------------------------------

    def respond(self, datagram: bytes, source: str = "") -> bytes | None:
        """The encoded answer to one datagram, or None when it is dropped (and counted)."""
        try:
            header, writable = self._screen(datagram)
            if header.community is None:
                return self._respond_v3(datagram, source)
            answer = self._fast_get(datagram, header)
            if answer is not None:
                return answer
            request = self._decode_message(datagram, header.version, api.PROTOCOL_MODULES[header.version], writable)
        except _Drop as drop:
            self.stats.dropped[drop.reason] += 1
            log.debug("dropped a %d-byte datagram from %s: %s (%s)", len(datagram), source or "?",
                      drop.reason.value, str(drop)[:200])
            return None
        handler = self._handlers[request.version].get(request.pdu.tagSet)
        if handler is None:
            self.stats.dropped[DropReason.NOT_A_REQUEST] += 1
            log.debug("dropped a %s PDU from %s", type(request.pdu).__name__, source or "?")
            return None
        return handler(request, source)

    def _screen(self, datagram: bytes) -> tuple[Header, bool]:
        """The header of a datagram worth decoding, and whether its community may write."""
        if len(datagram) > self.max_message_size:
            raise _Drop(DropReason.TOO_LARGE, f"{len(datagram)} bytes, more than {self.max_message_size}")
        try:
            header = read_header(datagram)
        except HeaderError as exc:
            raise _Drop(DropReason.MALFORMED, str(exc)) from None
        if header.community is None:
            if header.version != SNMP_VERSION_3 or self._usm is None:
                raise _Drop(DropReason.VERSION, f"SNMP version number {header.version}")
            return header, True
        writable = self.communities.get(header.community)
        if writable is None:
            raise _Drop(DropReason.COMMUNITY, f"community {header.community!r}")
        return header, writable

    def _respond_v3(self, datagram: bytes, source: str) -> bytes | None:
        """An SNMPv3 message through pysnmp's message processing and USM: a discovery or an
        authentication failure gets pysnmp's Report, a request at the user's level our answer."""
        usm = self._usm
        assert usm is not None
        try:
            header = read_usm(datagram)
        except HeaderError as exc:
            raise _Drop(DropReason.MALFORMED, f"SNMPv3: {exc}") from None
        who = f"SNMPv3 request from {source or '?'} as user {header.user.decode(errors='replace')!r}"
        try:
            usm.admit(header, datagram)
            reports, received = usm.receive(datagram)
            if received is None:
                failure = usm.failure
                if not reports:
                    raise _Drop(DropReason.AUTHENTICATION, f"{failure or 'refused by the user-based security model'}"
                                                           ", no Report asked for")
                if failure is not None:
                    self.stats.reports[failure] += 1
                    if failure is not UsmFailure.UNKNOWN_ENGINE_ID:  # discovery: how every manager starts
                        self._warnings.warn(failure, f"{who} refused, answered with a Report: {failure}")
                return reports[0]
            pdu = received.pdu
            handler = self._handlers[SNMP_VERSION_3].get(pdu.tagSet)
            if handler is None:
                raise _Drop(DropReason.NOT_A_REQUEST, f"a {type(pdu).__name__} PDU")
            varbinds = api.v2c.apiPDU.get_varbinds(pdu)
            # The user may write: like the read-write community, it is the middleware's.
            request = _Request(SNMP_VERSION_3, api.v2c, None, pdu, tuple(tuple(oid) for oid, _ in varbinds),
                               tuple(value for _, value in varbinds), True, received)
            handler(request, source)
            return received.finish()
        except _Drop as drop:
            self._warnings.warn(drop.reason, f"{who} dropped ({drop.reason.value}): {drop}")
            raise
        finally:
            usm.forget()

    def _fast_get(self, datagram: bytes, header: Header) -> bytes | None:
        """The answer to a plain GET of objects that all exist, written by hand; None leaves the
        datagram to the general path (any other PDU, a missing object, an answer too large)."""
        request = read_get(datagram, header)
        if request is None or not all(oid in self.view for oid in request.oids):
            return None
        answer = encode_response(request, [self.view.get(oid) for oid in request.oids])
        if len(answer) > self.max_message_size:
            return None
        self.stats.requests[RequestKind.GET] += 1
        return answer

    @staticmethod
    def _decode_message(datagram: bytes, version: int, module: ModuleType, writable: bool) -> _Request:
        # pyasn1 fails on hostile input with more than its own exception types (a TypeError
        # for some garbage), and any failure here only means "not a message we can read".
        try:
            message, rest = decoder.decode(datagram, asn1Spec=module.Message())
            pdu = module.apiMessage.get_pdu(message)
            varbinds = module.apiPDU.get_varbinds(pdu)
            oids = tuple(tuple(oid) for oid, _ in varbinds)
        except Exception as exc:
            raise _Drop(DropReason.MALFORMED, str(exc)) from None
        if rest:
            raise _Drop(DropReason.MALFORMED, f"{len(rest)} bytes after the message")
        return _Request(version, module, message, pdu, oids, tuple(v for _, v in varbinds), writable)

    # --- the requests -------------------------------------------------------------------------

    def _get(self, req: _Request, source: str) -> bytes:
        self.stats.requests[RequestKind.GET] += 1
        return self._read_answer(req, [(oid, self._read(oid)) for oid in req.oids])

    def _get_next(self, req: _Request, source: str) -> bytes:
        self.stats.requests[RequestKind.GET_NEXT] += 1
        return self._read_answer(req, [self._next(oid) for oid in req.oids])

    def _get_bulk(self, req: _Request, source: str) -> bytes:
        self.stats.requests[RequestKind.GET_BULK] += 1
        module = req.module
        n = min(int(module.apiBulkPDU.get_non_repeaters(req.pdu)), len(req.oids))
        repetitions = int(module.apiBulkPDU.get_max_repetitions(req.pdu))
        results = [self._next(oid) for oid in req.oids[:n]]
        cursor = list(req.oids[n:])
        # Rows stop once every column is past the end or once more varbinds than could ever
        # fit are collected (each encodes to 8 bytes or more): an answer is bounded whatever
        # max-repetitions asks for.
        for _ in range(repetitions):
            if not cursor or len(results) * 8 > self.max_message_size:
                break
            row = [self._next(oid) for oid in cursor]
            results += row
            if all(value is Missing.END_OF_MIB_VIEW for _, value in row):
                break
            cursor = [oid for oid, _ in row]
        # RFC 3416 4.2.3: a GETBULK answer too large is cut short rather than refused.
        varbinds = [(oid, _asn1(module, value)) for oid, value in results]
        answer = self._encode(req, ErrorStatus.NO_ERROR, 0, varbinds)
        while len(answer) > self.max_message_size:
            varbinds = varbinds[:min(len(varbinds) - 1, len(varbinds) * self.max_message_size // len(answer))]
            answer = self._encode(req, ErrorStatus.NO_ERROR, 0, varbinds)
        return answer

    def _set(self, req: _Request, source: str) -> bytes:
        self.stats.requests[RequestKind.SET] += 1
        varbinds = [(oid, _python_value(value)) for oid, value in zip(req.oids, req.values, strict=True)]
        status, index = ErrorStatus.NO_ERROR, 0
        if not req.writable:
            # RFC 3416 4.2.5 (1): no name is in the read-only community's write view.
            if varbinds:
                status, index = ErrorStatus.NO_ACCESS, 1
        else:
            try:
                self.view.set_many(varbinds)
            except SnmpError as exc:
                status, index = self._set_status(exc, req.oids), exc.index
        log.info("SET from %s: %s -> %s", source or "?",
                 ", ".join(f"{_name(oid)} = {_show(value)}" for oid, value in zip(req.oids, req.values, strict=True)),
                 _outcome(status, req))
        return self._answer(req, status, index, list(zip(req.oids, req.values, strict=True)))

    # --- the view -----------------------------------------------------------------------------

    def _read(self, oid: Oid) -> Value | Missing:
        if oid in self.view:
            return self.view.get(oid)
        return Missing.NO_SUCH_INSTANCE if self.view.definition(oid) is not None else Missing.NO_SUCH_OBJECT

    def _next(self, oid: Oid) -> _Result:
        following = self.view.next_oid(oid)
        if following is None:
            return oid, Missing.END_OF_MIB_VIEW
        return following, self.view.get(following)

    def _set_status(self, exc: SnmpError, oids: Sequence[Oid]) -> ErrorStatus:
        """The SNMPv2 status of a refused SET (RFC 3416 4.2.5)."""
        if exc.status is not ErrorStatus.NO_SUCH_NAME:
            return exc.status
        obj = self.view.definition(oids[exc.index - 1])
        # A missing row of a writable column "could not ever be created" (noCreation); any other
        # unknown name has nothing writable under it (notWritable).
        return ErrorStatus.NO_CREATION if obj is not None and obj.access is Access.READ_WRITE \
            else ErrorStatus.NOT_WRITABLE

    # --- answers ------------------------------------------------------------------------------

    def _read_answer(self, req: _Request, results: list[_Result]) -> bytes:
        if req.version == api.SNMP_VERSION_1:
            missing = [i for i, (_, value) in enumerate(results, start=1) if isinstance(value, Missing)]
            if missing:
                return self._answer(req, ErrorStatus.NO_SUCH_NAME, missing[0],
                                    list(zip(req.oids, req.values, strict=True)))
        return self._answer(req, ErrorStatus.NO_ERROR, 0, [(oid, _asn1(req.module, v)) for oid, v in results])

    def _answer(self, req: _Request, status: ErrorStatus, index: int, varbinds: list[tuple[Oid, Any]]) -> bytes:
        if req.version == api.SNMP_VERSION_1:
            status = _V1_STATUS[status]
        answer = self._encode(req, status, index, varbinds)
        if len(answer) > self.max_message_size:
            # RFC 3416 4.2.1 answers tooBig without varbinds; RFC 1157 4.1.2 echoes the request's.
            echo = list(zip(req.oids, req.values, strict=True)) if req.version == api.SNMP_VERSION_1 else []
            status, index = ErrorStatus.TOO_BIG, 0
            answer = self._encode(req, status, index, echo)
        if status is not ErrorStatus.NO_ERROR:
            self.stats.errors += 1
        return answer

    @staticmethod
    def _encode(req: _Request, status: ErrorStatus, index: int, varbinds: list[tuple[Oid, Any]]) -> bytes:
        if req.usm is not None:
            return req.usm.answer(status, index, varbinds)
        module = req.module
        message = module.apiMessage.get_response(req.message)
        pdu = module.apiMessage.get_pdu(message)
        module.apiPDU.set_error_status(pdu, int(status))
        module.apiPDU.set_error_index(pdu, index)
        module.apiPDU.set_varbinds(pdu, varbinds)
        return encoder.encode(message)


@dataclass(frozen=True, slots=True)
class V3User:
    """The SNMPv3 user the agent accepts: HMAC-SHA-96 authentication, and AES-128 privacy with a
    ``priv_key`` (authPriv) or none without (authNoPriv). Keys are pass phrases (RFC 3414 A.2)."""

    name: str
    auth_key: str = field(repr=False)
    priv_key: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("the SNMPv3 user needs a name")
        for what, key in (("auth", self.auth_key), ("priv", self.priv_key)):
            if (key or what == "auth") and len(key) < 8:
                raise ValueError(f"the SNMPv3 {what} key must have at least 8 characters (RFC 3414)")

    @property
    def security_level(self) -> int:
        """The lowest level accepted (RFC 3411 securityLevel: 2 authNoPriv, 3 authPriv)."""
        return 3 if self.priv_key else 2


@dataclass(slots=True)
class _UsmRequest:
    """One SNMPv3 request as pysnmp's dispatcher handed it over, and how to send its answer.

    pysnmp secures and encodes an answer once per request (it releases the request's state as it
    does), while the handlers may encode several candidates to fit ``max_message_size``. So
    :meth:`answer` keeps the latest candidate and returns a stand-in of its size (the request's
    own security overhead plus the answer PDU, and a margin for length fields); :meth:`finish`
    has pysnmp encode the candidate the handler settled on.
    """

    usm: _Usm
    context: tuple[Any, ...]  # the dispatcher's arguments before the PDU
    pdu: Any
    tail: tuple[Any, ...]  # maxSizeResponseScopedPDU, stateReference
    overhead: int  # bytes of the request's message around its PDU
    candidate: Any = None

    def answer(self, status: ErrorStatus, index: int, varbinds: list[tuple[Oid, Any]]) -> bytes:
        response = api.v2c.apiPDU.get_response(self.pdu)
        api.v2c.apiPDU.set_error_status(response, int(status))
        api.v2c.apiPDU.set_error_index(response, index)
        api.v2c.apiPDU.set_varbinds(response, varbinds)
        self.candidate = response
        return bytes(self.overhead + len(encoder.encode(response)) + _V3_LENGTH_MARGIN)

    def finish(self) -> bytes:
        return self.usm.encode(self.context, self.candidate, self.tail)


class _Usm:
    """pysnmp's SNMPv3 message processing and user-based security (RFC 3412, 3414, 3826), used without
    its transport and MIB instrumentation: a datagram goes in, Reports and requests come out, and an
    answer PDU goes back in to be secured and encoded."""

    def __init__(self, user: V3User, budget: ReportBudget) -> None:
        self.user = user
        self.budget = budget
        self.engine = SnmpEngine()
        priv = config.USM_PRIV_CFB128_AES if user.priv_key else config.USM_PRIV_NONE
        config.add_v3_user(self.engine, user.name, config.USM_AUTH_HMAC96_SHA, user.auth_key, priv,
                           user.priv_key or None)
        self.engine_id = self.engine.snmpEngineID.asOctets()
        self._name = user.name.encode()
        # The user's key localized to this engine (RFC 3414 A.2.2), as pysnmp keeps it for its own check.
        self._auth_key = localkey.password_to_key_sha(univ.OctetString(user.auth_key),
                                                      self.engine.snmpEngineID).asOctets()
        # The dispatcher only ever calls send_message on its transport: collect what it sends.
        self.engine.transport_dispatcher = self  # type: ignore[assignment]
        self._sent: list[bytes] = []
        self._received: list[_UsmRequest] = []
        self._datagram = b""
        self.failure: UsmFailure | None = None  # why USM refused the last datagram, if it did
        self.engine.message_dispatcher.register_context_engine_id(
            b"", (rfc1905.GetRequestPDU.tagSet, rfc1905.GetNextRequestPDU.tagSet, rfc1905.GetBulkRequestPDU.tagSet,
                  rfc1905.SetRequestPDU.tagSet), self._process_pdu)
        self.engine.observer.register_observer(self._refused, "rfc3412.prepareDataElements:sm-failure")

    def admit(self, header: UsmHeader, datagram: bytes) -> None:
        """Raise :class:`_Drop` unless pysnmp should see this message (see the rules of this file)."""
        level = _LEVELS.get(header.flags & 3)
        if header.security_model != USM_MODEL or level is None:
            raise _Drop(DropReason.AUTHENTICATION, f"security model {header.security_model} and msgFlags "
                                                   f"0x{header.flags:02x}: only USM, and privacy with authentication")
        if header.engine_id == self.engine_id:
            if not header.user:
                raise _Drop(DropReason.NO_USER, "no user name with this agent's engine ID")
            if header.user == self._name and level >= self.user.security_level and self._authentic(header, datagram):
                return
        elif header.engine_id:
            raise _Drop(DropReason.ENGINE_ID, f"engine ID {header.engine_id.hex()}, this agent's is "
                                              f"{self.engine_id.hex()}: the manager must discover it again")
        if not self.budget.take():
            raise _Drop(DropReason.REPORTS_SPENT, f"more than {self.budget.per_second:g} a second would draw a Report "
                                                  "(discovery, unknown user, wrong level or digest)")

    def _authentic(self, header: UsmHeader, datagram: bytes) -> bool:
        """Whether the message's HMAC-SHA-96 is the user's (RFC 3414 6.3.2): computed over the message with its
        digest zeroed."""
        digest = datagram[header.digest]
        if len(digest) != 12:
            return False
        zeroed = datagram[:header.digest.start] + bytes(12) + datagram[header.digest.stop:]
        return hmac.compare_digest(hmac.new(self._auth_key, zeroed, hashlib.sha1).digest()[:12], digest)

    def receive(self, datagram: bytes) -> tuple[list[bytes], _UsmRequest | None]:
        """The Reports pysnmp sent for ``datagram`` and the request it carried at the user's level, if any."""
        self._sent, self._received, self._datagram, self.failure = [], [], datagram, None
        try:
            self.engine.message_dispatcher.receive_message(self.engine, udp.DOMAIN_NAME, _NOWHERE, datagram)
        except Exception as exc:
            raise _Drop(DropReason.MALFORMED, f"SNMPv3: {exc}") from None
        request = self._received[0] if self._received else None
        if request is not None and (request.context[0] != SNMP_VERSION_3
                                    or int(request.context[3]) < self.user.security_level):
            raise _Drop(DropReason.AUTHENTICATION, f"security level {int(request.context[3])}, the user needs "
                                                   f"{self.user.security_level}")
        return self._sent, request

    def encode(self, context: tuple[Any, ...], pdu: Any, tail: tuple[Any, ...]) -> bytes:
        self._sent = []
        try:
            self.engine.message_dispatcher.return_response_pdu(self.engine, *context, pdu, *tail, {})
        except PySnmpError as exc:
            raise _Drop(DropReason.AUTHENTICATION, f"SNMPv3 answer not sent: {exc}") from None
        return self._sent[0]

    # --- what pysnmp asks of a transport dispatcher --------------------------------------------

    def send_message(self, message: bytes, _domain: Any, _address: Any) -> None:
        self._sent.append(bytes(message))

    @staticmethod
    def get_timer_resolution() -> float:
        """Seconds per :meth:`tick`: USM keeps each peer's time line for 300 of them."""
        return USM_TICK

    def tick(self) -> None:
        """Expire USM's time lines as a dispatcher's timer would (pysnmp keeps one entry per message until then)."""
        for model in self.engine.security_models.values():
            model.receive_timer_tick(self.engine, 0)

    def forget(self) -> None:
        """Drop every per-message state pysnmp kept: an answer is encoded within its datagram's turn, so none is
        needed afterwards, and pysnmp never frees that of a message nobody answers."""
        self.engine.message_processing_subsystems[SNMP_VERSION_3]._cache = MessageStates()
        self.engine.security_models[USM_MODEL]._cache = SecurityStates()

    def _refused(self, _engine: Any, _point: str, variables: dict[str, Any], _context: Any) -> None:
        self.failure = UsmFailure.of(variables["statusInformation"].get("errorIndication"))

    def _process_pdu(self, _engine: Any, *args: Any) -> None:
        # (mpModel, securityModel, securityName, securityLevel, contextEngineId, contextName, pduVersion,
        #  PDU, maxSizeResponseScopedPDU, stateReference), RFC 3412 4.2.2.1.3.
        self._received.append(_UsmRequest(self, args[:7], args[7], args[8:],
                                          len(self._datagram) - len(encoder.encode(args[7]))))


class _Endpoint(asyncio.DatagramProtocol):
    def __init__(self, agent: SnmpAgent) -> None:
        self.agent = agent

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        arrived = asyncio.get_running_loop().time()
        answer = self.agent.respond(data, f"{addr[0]}:{addr[1]}")
        if answer is not None:
            self.agent._send_later(answer, addr, arrived)

    def error_received(self, exc: Exception) -> None:
        # An ICMP error for an earlier answer (the manager went away): nothing to do for us.
        log.debug("UDP error: %s", exc)


def _asn1(module: ModuleType, value: Value | Missing) -> Any:
    if isinstance(value, Missing):
        return _MISSING_VALUES[value]
    return module.OctetString(value) if isinstance(value, bytes) else module.Integer(value)


def _python_value(value: Any) -> Value:
    """A SET value as the view takes it: int for an SNMP INTEGER, bytes for anything else.

    Gauge32, Counter32, TimeTicks and the like are integers in pyasn1 but not
    INTEGERs in SNMP: only the tag tells. Every non-INTEGER reaches the view as
    bytes so the view refuses it as WRONG_TYPE in its own validation order.
    """
    if value.tagSet == univ.Integer.tagSet:
        return int(value)
    if value.tagSet == univ.OctetString.tagSet:
        return value.asOctets()
    return encoder.encode(value)


def _name(oid: Oid) -> str:
    obj = object_for(oid)
    if obj is None:
        return oid_str(oid)
    return f"{obj.name}.{oid_str(oid[len(obj.prefix):])}"


def _show(value: Any) -> str:
    shown = value.prettyPrint()
    return shown if value.tagSet == univ.Integer.tagSet else f"{type(value).__name__}({shown})"


def _outcome(status: ErrorStatus, req: _Request) -> str:
    if status is ErrorStatus.NO_ERROR:
        return "applied"
    v1 = _V1_STATUS[status]
    as_v1 = f", {v1.name.lower()} in SNMPv1" if req.version == api.SNMP_VERSION_1 and v1 is not status else ""
    return f"refused ({status.name.lower()}{as_v1})"
