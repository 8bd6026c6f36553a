"""SNMP messages read and written by hand: the one place the agent touches BER itself.

Rules of this file
------------------
- Three things only, all for speed; everything else is pyasn1's (through
  pysnmp) in :mod:`emulator.agent.snmp`:
  1. the message header (outer SEQUENCE, version INTEGER and, for SNMPv1/v2c,
     the community OCTET STRING), read before anything else is decoded;
  2. the fast path of the poller's request: an SNMPv1/v2c GetRequest read
     whole, and its answer (a Response with INTEGER and OCTET STRING values,
     no error) written;
  3. what an SNMPv3 message says of its security (:func:`read_usm`: flags,
     security model, engine ID, user name, where its digest lies), read before
     pysnmp decodes it, so that the agent can turn away what USM would refuse
     at a few bytes' cost instead of pysnmp's half millisecond.
- Reading the header costs a few bytes of work whatever the datagram's size,
  so the agent checks version and community before it decodes the rest, and a
  stream of large datagrams with a wrong community costs it next to nothing.
- Anything that is not a definite-length BER header of that shape raises
  :class:`HeaderError`; the outer SEQUENCE must end exactly at the end of the
  datagram (no truncated message, no trailing bytes). :func:`read_get` returns
  None for anything but a plain GetRequest: the agent then takes its general
  path, which decides what to answer or drop.
- What a request carries and an answer repeats (version, community, request-id,
  names) is copied byte for byte, never decoded and encoded again.

An SNMPv1/v2c message is ``SEQUENCE { version INTEGER, community OCTET STRING,
pdu }`` (RFC 1157, RFC 1901); an SNMPv3 one is ``SEQUENCE { version INTEGER,
msgGlobalData SEQUENCE { msgID, msgMaxSize INTEGER, msgFlags OCTET STRING,
msgSecurityModel INTEGER }, msgSecurityParameters OCTET STRING, msgData }``
(RFC 3412 6), its header the version only; with USM the security parameters
wrap ``SEQUENCE { engineID OCTET STRING, boots INTEGER, time INTEGER, userName
OCTET STRING, authenticationParameters OCTET STRING, privacyParameters OCTET
STRING }`` (RFC 3414 2.4).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

_SEQUENCE = 0x30
_INTEGER = 0x02
_OCTET_STRING = 0x04
_NULL = 0x05
_OID = 0x06
_GET_REQUEST = 0xA0
_RESPONSE = 0xA2
_NO_ERROR = b"\x02\x01\x00"  # error-status and error-index 0
#: SNMP version numbers with a community after them (v1 is 0, v2c is 1).
COMMUNITY_VERSIONS = frozenset({0, 1})


class HeaderError(ValueError):
    """The datagram does not start like an SNMP message."""


@dataclass(frozen=True, slots=True)
class Header:
    version: int  # the message's version field: 0 (v1), 1 (v2c), 3 (v3) or anything a sender put there
    community: bytes | None  # None for versions without a community
    end: int = field(default=0, compare=False)  # where the community ends (the PDU starts)


@dataclass(frozen=True, slots=True)
class UsmHeader:
    """What an SNMPv3 message says of its security, read without decoding (or decrypting) the rest."""

    flags: int  # msgFlags: bit 0 authentication, bit 1 privacy, bit 2 reportable
    security_model: int  # 3 is USM
    engine_id: bytes  # msgAuthoritativeEngineID: empty when the sender discovers it
    user: bytes  # msgUserName
    digest: slice  # where msgAuthenticationParameters lies in the datagram


def read_usm(datagram: bytes) -> UsmHeader:
    """The security header of an SNMPv3 message; :class:`HeaderError` if it is not one to the user name."""
    end, pos = _element(datagram, 0, _SEQUENCE, "message")
    if end != len(datagram):
        raise HeaderError(f"the message SEQUENCE ends at byte {end} of {len(datagram)}")
    pos, _ = _element(datagram, pos, _INTEGER, "version")
    global_end, pos = _element(datagram, pos, _SEQUENCE, "msgGlobalData")
    pos, _ = _element(datagram, pos, _INTEGER, "msgID")
    pos, _ = _element(datagram, pos, _INTEGER, "msgMaxSize")
    flags_end, flags_at = _element(datagram, pos, _OCTET_STRING, "msgFlags")
    if flags_end - flags_at != 1:
        raise HeaderError(f"msgFlags of {flags_end - flags_at} bytes, not 1")
    model_end, model_at = _element(datagram, flags_end, _INTEGER, "msgSecurityModel")
    if model_end != global_end or not 1 <= model_end - model_at <= 4:
        raise HeaderError("msgGlobalData does not end with a msgSecurityModel INTEGER")
    params_end, pos = _element(datagram, global_end, _OCTET_STRING, "msgSecurityParameters")
    usm_end, pos = _element(datagram, pos, _SEQUENCE, "UsmSecurityParameters")
    if usm_end != params_end:
        raise HeaderError("msgSecurityParameters hold more than one SEQUENCE")
    engine_end, engine_at = _element(datagram, pos, _OCTET_STRING, "msgAuthoritativeEngineID")
    pos, _ = _element(datagram, engine_end, _INTEGER, "msgAuthoritativeEngineBoots")
    pos, _ = _element(datagram, pos, _INTEGER, "msgAuthoritativeEngineTime")
    user_end, user_at = _element(datagram, pos, _OCTET_STRING, "msgUserName")
    digest_end, digest_at = _element(datagram, user_end, _OCTET_STRING, "msgAuthenticationParameters")
    return UsmHeader(datagram[flags_at], int.from_bytes(datagram[model_at:model_end], "big", signed=True),
                     bytes(datagram[engine_at:engine_end]), bytes(datagram[user_at:user_end]),
                     slice(digest_at, digest_end))


def read_header(datagram: bytes) -> Header:
    """The version and community of an SNMP message, from its first bytes only."""
    end, pos = _element(datagram, 0, _SEQUENCE, "message")
    if end != len(datagram):
        raise HeaderError(f"the message SEQUENCE ends at byte {end} of {len(datagram)}")
    version_end, pos = _element(datagram, pos, _INTEGER, "version")
    if not 1 <= version_end - pos <= 4:
        raise HeaderError(f"a version INTEGER of {version_end - pos} bytes")
    version = int.from_bytes(datagram[pos:version_end], "big", signed=True)
    if version not in COMMUNITY_VERSIONS:
        return Header(version, None)
    community_end, pos = _element(datagram, version_end, _OCTET_STRING, "community")
    return Header(version, bytes(datagram[pos:community_end]), community_end)


@dataclass(frozen=True, slots=True)
class GetRequest:
    """A plain SNMPv1/v2c GetRequest, with the bytes its answer repeats."""

    header: bytes  # version and community elements, as received
    request_id: bytes  # the request-id element, as received
    oids: tuple[tuple[int, ...], ...]
    names: tuple[bytes, ...]  # each OID element, as received


def read_get(datagram: bytes, header: Header) -> GetRequest | None:
    """The GetRequest after ``header``, or None if the PDU is anything else or not read simply."""
    try:
        pdu_end, pos = _element(datagram, header.end, _GET_REQUEST, "PDU")
        if pdu_end != len(datagram):
            return None
        id_end, _ = _element(datagram, pos, _INTEGER, "request-id")
        request_id = bytes(datagram[pos:id_end])
        pos, _ = _element(datagram, id_end, _INTEGER, "error-status")
        pos, _ = _element(datagram, pos, _INTEGER, "error-index")
        list_end, pos = _element(datagram, pos, _SEQUENCE, "varbind list")
        oids, names = [], []
        while pos < list_end:
            varbind_end, inner = _element(datagram, pos, _SEQUENCE, "varbind")
            name_end, arcs = _element(datagram, inner, _OID, "name")
            value_end, _ = _element(datagram, name_end, _NULL, "value")
            if value_end != varbind_end:
                return None
            oids.append(_decode_oid(datagram[arcs:name_end]))
            names.append(bytes(datagram[inner:name_end]))
            pos = varbind_end
    except HeaderError:
        return None
    if pos != list_end or list_end != pdu_end or not oids:
        return None
    return GetRequest(bytes(datagram[2 + _length_size(datagram[1]):header.end]), request_id, tuple(oids),
                      tuple(names))


def encode_response(request: GetRequest, values: Sequence[int | bytes]) -> bytes:
    """The Response to ``request`` with these values (INTEGER for int, OCTET STRING for bytes), no error."""
    varbinds = b"".join(_tlv(_SEQUENCE, name + _value(value)) for name, value in zip(request.names, values,
                                                                                    strict=True))
    pdu = _tlv(_RESPONSE, request.request_id + _NO_ERROR + _NO_ERROR + _tlv(_SEQUENCE, varbinds))
    return _tlv(_SEQUENCE, request.header + pdu)


def _value(value: int | bytes) -> bytes:
    if isinstance(value, bytes):
        return _tlv(_OCTET_STRING, value)
    # The fewest octets of two's complement (X.690 8.3.2).
    size = (value if value >= 0 else ~value).bit_length() // 8 + 1
    return _tlv(_INTEGER, value.to_bytes(size, "big", signed=True))


def _tlv(tag: int, contents: bytes) -> bytes:
    n = len(contents)
    if n < 0x80:
        return bytes((tag, n)) + contents
    size = (n.bit_length() + 7) // 8
    return bytes((tag, 0x80 | size)) + n.to_bytes(size, "big") + contents


def _length_size(first: int) -> int:
    return 0 if first < 0x80 else first & 0x7F


def _decode_oid(data: bytes) -> tuple[int, ...]:
    arcs: list[int] = []
    value = 0
    for byte in data:
        value = (value << 7) | (byte & 0x7F)
        if not byte & 0x80:
            arcs.append(value)
            value = 0
    if not arcs or data[-1] & 0x80:
        raise HeaderError("an OBJECT IDENTIFIER is cut short")
    first = arcs[0]
    head = (first // 40, first % 40) if first < 80 else (2, first - 80)
    return (*head, *arcs[1:])


def _element(data: bytes, pos: int, tag: int, what: str) -> tuple[int, int]:
    """(end, start of contents) of the element at ``pos``, which must carry ``tag`` and fit in ``data``."""
    if pos + 2 > len(data):
        raise HeaderError(f"the {what} is cut short at byte {pos}")
    if data[pos] != tag:
        raise HeaderError(f"the {what} has tag 0x{data[pos]:02x}, not 0x{tag:02x}")
    first = data[pos + 1]
    pos += 2
    if first < 0x80:
        length = first
    else:
        count = first & 0x7F
        # 0x80 is the indefinite form (not allowed in SNMP); more than 4 length bytes is no UDP datagram.
        if not 1 <= count <= 4 or pos + count > len(data):
            raise HeaderError(f"the {what} has a length of form 0x{first:02x}")
        length = int.from_bytes(data[pos:pos + count], "big")
        pos += count
    if pos + length > len(data):
        raise HeaderError(f"the {what} needs {length} bytes, {len(data) - pos} are left")
    return pos + length, pos
