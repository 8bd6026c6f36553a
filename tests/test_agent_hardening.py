"""The agent's defences: the hand-read message header checked against net-snmp's own datagrams,
and datagrams with a wrong community or beyond the maximum size dropped before pyasn1 sees them."""

from __future__ import annotations

import socket
import subprocess

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyasn1.codec.ber import decoder
from pysnmp.proto import api
from test_agent_netsnmp import parse, request

from emulator import agent as agent_mod
from emulator.agent import DEFAULT_MAX_MESSAGE_SIZE, DropReason, RequestKind, SnmpAgent
from emulator.ber import Header, HeaderError, read_header
from emulator.controller import Controller
from emulator.mib import MibView
from harness.processes import tool
from hils import config as config_mod
from hils.ntcip import MAX_PHASES


def captured(*args: str) -> bytes:
    """The first datagram net-snmp's snmpget sends for ``args``, caught on a socket that never answers."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(5)
        port = sock.getsockname()[1]
        proc = subprocess.Popen([tool("snmpget"), *args, "-t", "0.3", "-r", "0", "-On", f"127.0.0.1:{port}",
                                 ".1.3.6.1.4.1.1206.4.2.1.1.1.0"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            return sock.recv(65535)
        finally:
            proc.wait(timeout=5)


@pytest.mark.parametrize(("args", "expected"), [
    (["-v1", "-c", "public"], Header(0, b"public")),
    (["-v2c", "-c", "a much longer community name" * 6], Header(1, b"a much longer community name" * 6)),
    (["-v3", "-l", "noAuthNoPriv", "-u", "someone"], Header(3, None)),
])
def test_header_of_net_snmp_requests(args: list[str], expected: Header) -> None:
    datagram = captured(*args)
    assert read_header(datagram) == expected
    # pyasn1 reads the same version from the whole message.
    assert int(api.decodeMessageVersion(datagram)) == expected.version
    if expected.community is not None:
        module = api.PROTOCOL_MODULES[expected.version]
        message, _ = decoder.decode(datagram, asn1Spec=module.Message())
        assert bytes(module.apiMessage.get_community(message)) == expected.community


@pytest.mark.parametrize("datagram", [
    b"", b"\x30", b"\x30\x00", b"\x30\x80\x02\x01\x01\x04\x00\x00\x00",  # empty, cut, empty SEQUENCE, indefinite
    b"\x31\x05\x02\x01\x01\x04\x00",  # a SET, not a SEQUENCE
    b"\x30\x05\x02\x01\x01\x04\x01",  # the community runs past the end
    b"\x30\x05\x02\x01\x01\x04\x00\xff",  # a byte after the message
    b"\x30\x08\x02\x06\x00\x00\x00\x00\x00\x01",  # a six-byte version
    b"\x30\x85\x00\x00\x00\x00\x05",  # five length bytes
])
def test_header_errors(datagram: bytes) -> None:
    with pytest.raises(HeaderError):
        read_header(datagram)


def test_header_leaves_what_follows_the_community_alone() -> None:
    assert read_header(b"\x30\x06\x02\x01\x01\x04\x00\xff") == Header(1, b"")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64))
def test_header_reader_never_fails_otherwise(datagram: bytes) -> None:
    try:
        header = read_header(datagram)
    except HeaderError:
        return
    assert header.community is None or len(header.community) < len(datagram)


@pytest.fixture
def agent() -> SnmpAgent:
    return SnmpAgent(MibView(Controller(config_mod.load())))


def test_wrong_community_and_oversized_datagrams_are_dropped_before_decoding(agent: SnmpAgent,
                                                                            monkeypatch) -> None:
    decoded: list[bytes] = []
    real = decoder.decode

    def spy(substrate, *args, **kwargs):
        decoded.append(bytes(substrate))
        return real(substrate, *args, **kwargs)

    monkeypatch.setattr(agent_mod.decoder, "decode", spy)
    oids = [MAX_PHASES.instance()] * 2
    wrong = request(api.SNMP_VERSION_2C, "secret", RequestKind.GET, oids)
    # 60 KB: a valid header with a wrong community, and one with the right community.
    padding = [MAX_PHASES.instance()] * 4000
    big_wrong = request(api.SNMP_VERSION_2C, "secret", RequestKind.GET, padding)
    big_right = request(api.SNMP_VERSION_2C, "public", RequestKind.GET, padding)
    assert len(big_wrong) > 50_000
    for datagram in (wrong, big_wrong, big_right):
        assert agent.respond(datagram) is None
    assert decoded == []
    assert agent.stats.dropped == {DropReason.COMMUNITY: 1, DropReason.TOO_LARGE: 2}
    # A request with the right community is decoded and answered.
    answer = agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, oids))
    assert answer is not None and len(decoded) == 1
    assert [value for _, value in parse(answer).varbinds] == [8, 8]


def test_maximum_message_size_is_the_agents_own() -> None:
    small = SnmpAgent(MibView(Controller(config_mod.load())), max_message_size=100)
    oids = [MAX_PHASES.instance()] * 6
    datagram = request(api.SNMP_VERSION_2C, "public", RequestKind.GET, oids)
    assert len(datagram) > 100
    assert small.respond(datagram) is None
    assert small.stats.dropped == {DropReason.TOO_LARGE: 1}
    assert len(datagram) < DEFAULT_MAX_MESSAGE_SIZE
