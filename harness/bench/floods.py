"""Hostile datagrams for the wire benchmark and the tests, and a process that floods an agent with them.

- :func:`wrong_community`: a large SNMPv2c GET with a community no agent here accepts.
- :func:`v3_get`: an SNMPv3 GET in plaintext, its security header as given: with this agent's engine ID (learnt
  by :func:`discover_engine_id`, as any manager learns it, RFC 3414 4), an empty user name and no authentication
  it is the request that passed pysnmp's checks and left per-message state behind that never expired.
- :func:`flooding`: another process makes one datagram (:func:`large_wrong_community`,
  :func:`v3_without_user`: it discovers the engine ID itself, as an attacker would) and sends it at a steady
  rate until the block ends, so that the sender's work does not share the measured process's interpreter.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import socket
import time
from collections.abc import Callable, Iterator

from pyasn1.codec.ber import decoder, encoder
from pysnmp.proto import api
from pysnmp.proto.mpmod.rfc3412 import SNMPv3Message
from pysnmp.proto.secmod.rfc3414.service import UsmSecurityParameters

from hils.protocol.ntcip import MAX_PHASES, signal_oids

#: msgFlags (RFC 3412 6.4): reportable, with authentication, with privacy.
REPORTABLE, AUTH, PRIV = 0x04, 0x01, 0x02


def wrong_community(size: int) -> bytes:
    """An SNMPv2c GET of ``size`` bytes or a little more with a community no agent here accepts."""
    v2c = api.v2c
    pdu = v2c.GetRequestPDU()
    v2c.apiPDU.set_defaults(pdu)
    v2c.apiPDU.set_varbinds(pdu, [(oid, v2c.Null("")) for oid in signal_oids(1)] * (size // 60))
    message = v2c.Message()
    v2c.apiMessage.set_defaults(message)
    v2c.apiMessage.set_community(message, "not-a-community")
    v2c.apiMessage.set_pdu(message, pdu)
    return encoder.encode(message)


def v3_get(engine_id: bytes, user: bytes = b"", flags: int = REPORTABLE, digest: bytes = b"", boots: int = 0,
           engine_time: int = 0, message_id: int = 1) -> bytes:
    """An SNMPv3 GET of maxPhases with this USM header and a plaintext scoped PDU (nothing is signed: ``digest``
    is put as it is)."""
    pdu = api.v2c.GetRequestPDU()
    api.v2c.apiPDU.set_defaults(pdu)
    api.v2c.apiPDU.set_request_id(pdu, message_id)
    api.v2c.apiPDU.set_varbinds(pdu, [(MAX_PHASES.instance(), api.v2c.Null(""))])
    security = UsmSecurityParameters()
    security["msgAuthoritativeEngineId"] = engine_id
    security["msgAuthoritativeEngineBoots"] = boots
    security["msgAuthoritativeEngineTime"] = engine_time
    security["msgUserName"] = user
    security["msgAuthenticationParameters"] = digest
    security["msgPrivacyParameters"] = b""
    message = SNMPv3Message()
    message["msgVersion"] = 3
    header = message["msgGlobalData"]
    header["msgID"] = message_id
    header["msgMaxSize"] = 65507
    header["msgFlags"] = bytes([flags])
    header["msgSecurityModel"] = 3
    message["msgSecurityParameters"] = encoder.encode(security)
    scoped = message["msgData"]["plaintext"]
    scoped["contextEngineId"] = engine_id
    scoped["contextName"] = b""
    scoped["data"]["get-request"] = pdu
    return encoder.encode(message)


def discover_engine_id(address: tuple[str, int], timeout: float = 2.0) -> bytes:
    """The agent's engine ID, from the Report to a discovery request (empty engine ID and user name)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout)
        sock.sendto(v3_get(b""), address)
        answer, _ = sock.recvfrom(65535)
    message, _ = decoder.decode(answer, asn1Spec=SNMPv3Message())
    security, _ = decoder.decode(bytes(message["msgSecurityParameters"]), asn1Spec=UsmSecurityParameters())
    return bytes(security["msgAuthoritativeEngineId"])


def large_wrong_community(_address: tuple[str, int]) -> bytes:
    """60 KB with a wrong community (what the wire benchmark first flooded with)."""
    return wrong_community(60_000)


def v3_without_user(address: tuple[str, int]) -> bytes:
    """A GET with the agent's engine ID, no user name, noAuthNoPriv: it passed pysnmp's USM unauthenticated."""
    return v3_get(discover_engine_id(address))


Datagram = Callable[[tuple[str, int]], bytes]


def _send(address: tuple[str, int], make: Datagram, per_second: int) -> None:
    """Send ``make(address)`` ``per_second`` times a second, in bursts every 10 ms, until terminated."""
    datagram = make(address)
    burst = max(1, per_second // 100)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        start, sent = time.monotonic(), 0
        while True:
            for _ in range(burst):
                # A full socket buffer means the agent falls behind: the flood goes on.
                with contextlib.suppress(OSError):
                    sock.sendto(datagram, address)
            sent += burst
            time.sleep(max(0.0, start + sent / per_second - time.monotonic()))


@contextlib.contextmanager
def flooding(address: tuple[str, int], make: Datagram, per_second: int) -> Iterator[None]:
    """``make(address)`` sent to ``address`` ``per_second`` times a second by another process while the block runs
    (``make``: a function of this module, or any other the process can import)."""
    sender = multiprocessing.get_context("spawn").Process(target=_send, args=(address, make, per_second),
                                                          daemon=True)
    sender.start()
    try:
        yield
    finally:
        sender.terminate()
        sender.join(5)
