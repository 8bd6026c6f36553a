"""Hostile traffic for the wire benchmark and the tests: datagrams, event-log requests, and a process sending them.

- :func:`wrong_community`: a large SNMPv2c GET with a community no agent here accepts.
- :func:`v3_get`: an SNMPv3 GET in plaintext, its security header as given: with this agent's engine ID (learnt
  by :func:`discover_engine_id`, as any manager learns it, RFC 3414 4), an empty user name and no authentication
  it is the request that passed pysnmp's checks and left per-message state behind that never expired.
- :func:`flooding`: another process makes one datagram (:func:`large_wrong_community`,
  :func:`v3_without_user`: it discovers the engine ID itself, as an attacker would) and sends it at a steady
  rate until the block ends, so that the sender's work does not share the measured process's interpreter.
- :func:`fetching_logs`: another process asks a served controller's event log again and again, from clients that
  read each answer whole and from clients that never read one (each opened anew once the server drops or
  refuses it), until the block ends.
- :func:`fill_log`: a served controller's log made as large as a busy controller's after hours, before it is
  served, by its detectors chattering every tick.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from pyasn1.codec.ber import decoder, encoder
from pysnmp.proto import api
from pysnmp.proto.mpmod.rfc3412 import SNMPv3Message
from pysnmp.proto.secmod.rfc3414.service import UsmSecurityParameters

from hils.protocol.hires import ASCLOG_PATH
from hils.protocol.ntcip import MAX_PHASES, signal_oids

if TYPE_CHECKING:
    from emulator.agent.serve import ServedController

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


def flooding(address: tuple[str, int], make: Datagram, per_second: int) -> contextlib.AbstractContextManager[None]:
    """``make(address)`` sent to ``address`` ``per_second`` times a second by another process while the block runs
    (``make``: a function of this module, or any other the process can import)."""
    return _in_another_process(_send, address, make, per_second)


#: What a field collector sends for a controller's whole log.
LOG_REQUEST = f"GET {ASCLOG_PATH} HTTP/1.1\r\nHost: controller\r\n\r\n".encode()
_TCP_ESTABLISHED = 1  # tcpi_state, the first byte of Linux's struct tcp_info


def _fetch_whole_logs(address: tuple[str, int]) -> None:
    """Ask for the log and read the answer whole, again and again (a refused or failed request is asked again)."""
    while True:
        try:
            with socket.create_connection(address, timeout=30) as sock:
                sock.sendall(LOG_REQUEST)
                while sock.recv(1 << 16):
                    pass
        except OSError:
            time.sleep(0.05)


def _never_read_logs(address: tuple[str, int]) -> None:
    """Ask for the log and read nothing of the answer; once the server has closed the connection (dropped or
    refused it), ask again."""
    while True:
        with contextlib.suppress(OSError), socket.socket() as sock:
            # Before connecting, so that the window this client offers stays small.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.settimeout(5)
            sock.connect(address)
            sock.sendall(LOG_REQUEST)
            while sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0] == _TCP_ESTABLISHED:
                time.sleep(0.2)
        time.sleep(0.05)


def _fetch_logs(address: tuple[str, int], whole: int, never_read: int) -> None:
    clients = [threading.Thread(target=_fetch_whole_logs, args=(address,), daemon=True) for _ in range(whole)]
    clients += [threading.Thread(target=_never_read_logs, args=(address,), daemon=True) for _ in range(never_read)]
    for client in clients:
        client.start()
    threading.Event().wait()


def fetching_logs(address: tuple[str, int], whole: int, never_read: int) -> contextlib.AbstractContextManager[None]:
    """``whole`` clients asking for the event log at ``address`` (TCP) and reading each answer whole, again and
    again, and ``never_read`` clients asking for it and reading nothing, from another process while the block
    runs."""
    return _in_another_process(_fetch_logs, address, whole, never_read)


@contextlib.contextmanager
def _in_another_process(target: Callable[..., None], *args: object) -> Iterator[None]:
    """``target(*args)`` run by another process (spawned: nothing of this one's state) while the block runs."""
    sender = multiprocessing.get_context("spawn").Process(target=target, args=args, daemon=True)
    sender.start()
    try:
        yield
    finally:
        sender.terminate()
        sender.join(5)


def fill_log(served: ServedController, events: int) -> None:
    """Step ``served``'s controller with its vehicle detectors all on one tick and all off the next until its log
    holds ``events`` (or its capacity), before it is served: a log as large as a busy controller's after hours,
    in a second. Its clock runs ahead of the host's by the ticks stepped."""
    detectors = list(served.config.detectors)
    target = min(events, served.log.capacity or events)
    while len(served.log) < target:
        served.controller.set_actuations(() if served.controller.actuations else detectors)
        served.unit.step()
