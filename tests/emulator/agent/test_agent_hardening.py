"""The agent's defences: the hand-read message header checked against net-snmp's own datagrams,
and datagrams with a wrong community or beyond the maximum size dropped before pyasn1 sees them."""

from __future__ import annotations

import re
import socket
import subprocess

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyasn1.codec.ber import decoder, encoder
from pysnmp.proto import api

from emulator.agent import snmp as agent_mod
from emulator.agent.ber import Header, HeaderError, encode_response, read_get, read_header
from emulator.agent.mib import MibView
from emulator.agent.snmp import DEFAULT_MAX_MESSAGE_SIZE, DropReason, RequestKind, SnmpAgent
from emulator.model.controller import Controller
from harness.bench.processes import start_emulator, tool
from hils.protocol import config as config_mod
from hils.protocol.ntcip import MAX_PHASES, oid_str, signal_oids
from tests.emulator.agent.test_agent_netsnmp import parse, request

pytestmark = pytest.mark.wallclock


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
    # With the right community, a plain GET is answered on the fast path, anything else through pyasn1.
    answer = agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, oids))
    assert answer is not None and decoded == []
    assert [value for _, value in parse(answer).varbinds] == [8, 8]
    assert agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET_NEXT, oids)) is not None
    assert decoded


def test_maximum_message_size_is_the_agents_own() -> None:
    small = SnmpAgent(MibView(Controller(config_mod.load())), max_message_size=100)
    oids = [MAX_PHASES.instance()] * 6
    datagram = request(api.SNMP_VERSION_2C, "public", RequestKind.GET, oids)
    assert len(datagram) > 100
    assert small.respond(datagram) is None
    assert small.stats.dropped == {DropReason.TOO_LARGE: 1}
    assert len(datagram) < DEFAULT_MAX_MESSAGE_SIZE


# --- the GET fast path: byte for byte what pyasn1 writes -------------------------------------------

oid_arcs = st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=12)
# NTCIP objects hold no negative numbers; pyasn1 pads some negative ones (-128 as ff 80) where X.690
# asks for the fewest octets, so byte-identity is checked on what the MIB holds.
values = st.lists(st.one_of(st.integers(0, 2**31 - 1), st.binary(max_size=300)), min_size=1, max_size=8)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([api.SNMP_VERSION_1, api.SNMP_VERSION_2C]), st.integers(-(2**31), 2**31 - 1),
       st.binary(min_size=1, max_size=200), st.data())
def test_fast_get_reads_and_writes_as_pyasn1_does(version: int, request_id: int, community: bytes, data) -> None:
    answers = data.draw(values)
    oids = [(1, 3, 6, *data.draw(oid_arcs)) for _ in answers]
    module = api.PROTOCOL_MODULES[version]
    pdu = module.GetRequestPDU()
    module.apiPDU.set_defaults(pdu)
    module.apiPDU.set_request_id(pdu, request_id)
    module.apiPDU.set_varbinds(pdu, [(oid, module.null) for oid in oids])
    message = module.Message()
    module.apiMessage.set_defaults(message)
    module.apiMessage.set_community(message, community)
    module.apiMessage.set_pdu(message, pdu)
    datagram = encoder.encode(message)
    header = read_header(datagram)
    get = read_get(datagram, header)
    assert get is not None and get.oids == tuple(oids)
    response = module.apiMessage.get_response(message)
    module.apiPDU.set_varbinds(module.apiMessage.get_pdu(response),
                               [(oid, module.OctetString(v) if isinstance(v, bytes) else module.Integer(v))
                                for oid, v in zip(oids, answers, strict=True)])
    ours = encode_response(get, answers)
    decoded, rest = decoder.decode(ours, asn1Spec=module.Message())
    assert not rest and decoded == response
    # Byte for byte too, but for negative INTEGERs such as -128, which pyasn1 writes in one octet
    # more than X.690 8.3.2 allows (0xff80); ours are minimal, as net-snmp's.
    if all(isinstance(v, bytes) or v >= 0 for v in answers):
        assert ours == encoder.encode(response)


def test_only_plain_gets_take_the_fast_path(agent: SnmpAgent) -> None:
    oids = [MAX_PHASES.instance()]
    for kind in (RequestKind.GET_NEXT, RequestKind.GET_BULK):
        datagram = request(api.SNMP_VERSION_2C, "public", kind, oids)
        assert read_get(datagram, read_header(datagram)) is None
    # A GET of a missing object is answered by the general path, with its exception value.
    missing = (*MAX_PHASES.instance()[:-1], 99)
    answer = parse(agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, [*oids, missing])))
    assert answer.varbinds[0][1] == 8
    assert answer.varbinds[1][1].tagSet == api.v2c.NoSuchInstance.tagSet


def test_served_gets_read_by_net_snmp_on_the_fast_path(tmp_path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        for version in ("1", "2c"):
            out = subprocess.run([tool("snmpget"), f"-v{version}", "-c", "public", "-On", "-t", "1", "-r", "0",
                                  f"127.0.0.1:{served.port}", *(f".{oid_str(oid)}" for oid in signal_oids(1)),
                                  f".{oid_str(MAX_PHASES.instance())}"], capture_output=True, text=True, timeout=10)
            assert out.returncode == 0, out.stderr
            lines = out.stdout.strip().splitlines()
            assert len(lines) == 4
            assert all(re.fullmatch(r"\.[\d.]+ = INTEGER: \d+", line) for line in lines), lines
            assert lines[3].endswith("INTEGER: 8")
    finally:
        code, out = served.stop()
    assert code == 0
    assert "served 2 requests (get 2)" in out
