"""The first bytes of an SNMP message, read by hand: the one place the agent looks at BER itself.

Rules of this file
------------------
- Only the message header is read here: the outer SEQUENCE, the version
  INTEGER and (SNMPv1/v2c) the community OCTET STRING. Everything after the
  community is left to pyasn1, and nothing is ever encoded here.
- Reading costs a few bytes of work whatever the datagram's size, so the
  agent can check version and community before it decodes the rest, and a
  stream of large datagrams with a wrong community costs it next to nothing.
- Anything that is not a definite-length BER header of that shape raises
  :class:`HeaderError`; the outer SEQUENCE must end exactly at the end of the
  datagram (no truncated message, no trailing bytes).

An SNMPv1/v2c message is ``SEQUENCE { version INTEGER, community OCTET STRING,
pdu }`` (RFC 1157, RFC 1901); an SNMPv3 one is ``SEQUENCE { version INTEGER,
msgGlobalData SEQUENCE, ... }`` (RFC 3412): its header is the version only.
"""

from __future__ import annotations

from dataclasses import dataclass

_SEQUENCE = 0x30
_INTEGER = 0x02
_OCTET_STRING = 0x04
#: SNMP version numbers with a community after them (v1 is 0, v2c is 1).
COMMUNITY_VERSIONS = frozenset({0, 1})


class HeaderError(ValueError):
    """The datagram does not start like an SNMP message."""


@dataclass(frozen=True, slots=True)
class Header:
    version: int  # the message's version field: 0 (v1), 1 (v2c), 3 (v3) or anything a sender put there
    community: bytes | None  # None for versions without a community


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
    return Header(version, bytes(datagram[pos:community_end]))


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
