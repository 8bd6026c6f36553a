"""The served event log never costs a tick or an SNMP answer, and no client holds it: `hils emulator serve --http`
under looping and never-reading clients from another process (issue 33, item 5), with a log as large as the
controller keeps (100,000 events, 8.5 MB of XML); a client that reads nothing is dropped, the connections are
limited, and a request with bare LF line endings is answered at once (item 12)."""

from __future__ import annotations

import asyncio
import socket
import statistics
import time
import urllib.request

import pytest
from pyasn1.codec.ber import encoder
from pysnmp.proto import api

from emulator.agent.asclog import MAX_CONNECTIONS, AsclogServer, Dropped
from emulator.agent.serve import EmulatorServer, ServedController, ServeOptions
from harness.bench.floods import LOG_REQUEST, fetching_logs, fill_log
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import ASCLOG_PATH, asclog_xml
from hils.protocol.ntcip import MAX_PHASES

pytestmark = pytest.mark.wallclock

FULL = 100_000  # events: the served log's default capacity


def maxphases_get() -> bytes:
    message = api.v2c.Message()
    api.v2c.apiMessage.set_defaults(message)
    api.v2c.apiMessage.set_community(message, "public")
    pdu = api.v2c.GetRequestPDU()
    api.v2c.apiPDU.set_defaults(pdu)
    api.v2c.apiPDU.set_varbinds(pdu, [(MAX_PHASES.instance(), api.v2c.Null(""))])
    api.v2c.apiMessage.set_pdu(message, pdu)
    return encoder.encode(message)


async def served_under_log_flood(config: IntersectionConfig, whole: int, never_read: int,
                                 seconds: float) -> tuple[list[float], list[float]]:
    """Tick lateness and SNMP GET round trips (s) of a served controller with a full log while another process
    asks for the log with ``whole`` clients reading every answer and ``never_read`` reading none."""
    server = EmulatorServer([config], ServeOptions(port=0, http=0, log_events=FULL))
    fill_log(server.controllers[0], FULL)
    [address] = await server.start()
    await asyncio.sleep(0.3)  # the ticks stepped to fill the log are caught up with first
    lateness: list[float] = []
    server.ticker.observe = lateness.append
    loop = asyncio.get_running_loop()
    rtts: list[float] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe, \
            fetching_logs(server.http_addresses[0], whole, never_read):
        probe.setblocking(False)
        get = maxphases_get()
        deadline = loop.time() + seconds
        while loop.time() < deadline:
            sent = loop.time()
            await loop.sock_sendto(probe, get, address)
            try:
                async with asyncio.timeout(5.0):
                    await loop.sock_recvfrom(probe, 65535)
                rtts.append(loop.time() - sent)
            except TimeoutError:
                rtts.append(float("inf"))
            await asyncio.sleep(0.1)
    await server.stop()
    return lateness, rtts


def test_looping_and_never_reading_clients_cost_no_tick_and_no_snmp_answer(paper_config) -> None:
    """Within the middleware's GET timeout (tau_udp: a later answer is a communication failure), every tick and
    every answer; at the median, a few milliseconds. Before: each request rendered the whole log on the loop
    (0.7 s here): this test measured the tick 1.09 s late at the median, 3.4 s at most, and GETs went unanswered
    for seconds."""
    tau_udp = paper_config.middleware.tau_udp
    lateness, rtts = asyncio.run(served_under_log_flood(paper_config, whole=6, never_read=40, seconds=5.0))
    late = f"tick lateness median {statistics.median(lateness):.3f} s, max {max(lateness):.3f} s"
    assert len(lateness) > 30
    assert statistics.median(lateness) < 0.02 and max(lateness) < tau_udp, late
    answers = f"{len(rtts)} GETs, round trip median {statistics.median(rtts):.3f} s, max {max(rtts):.3f} s"
    assert len(rtts) > 20 and statistics.median(rtts) < 0.02 and max(rtts) < tau_udp, answers


def logged(config: IntersectionConfig, events: int) -> ServedController:
    served = ServedController(config, ServeOptions(log_events=FULL))
    fill_log(served, events)
    return served


async def _read_all(sock: socket.socket) -> bytes:
    loop = asyncio.get_running_loop()
    out = b""
    try:
        while chunk := await loop.sock_recv(sock, 1 << 16):
            out += chunk
    except ConnectionResetError:
        pass
    return out


def test_a_client_that_reads_nothing_is_dropped_after_the_write_timeout(paper_config) -> None:
    """Before: the server waited on such a client for ever, its whole answer buffered."""
    full_log = logged(paper_config, FULL)

    async def scenario() -> tuple[bytes, float, AsclogServer]:
        server = AsclogServer(full_log.log.snapshot, write_timeout=0.5)
        address = await server.start("127.0.0.1", 0)
        loop = asyncio.get_running_loop()
        with socket.socket() as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.setblocking(False)
            await loop.sock_connect(sock, address)
            await loop.sock_sendall(sock, LOG_REQUEST)
            start = loop.time()
            while not server.stats.dropped:
                await asyncio.sleep(0.05)
                assert loop.time() - start < 5, "never dropped"
            dropped_after = loop.time() - start
            body = await _read_all(sock)
        server.close()
        return body, dropped_after, server

    body, dropped_after, server = asyncio.run(scenario())
    assert 0.5 <= dropped_after < 2.0
    assert server.stats.dropped == {Dropped.NOT_READING: 1}
    assert body.startswith(b"HTTP/1.1 200 OK\r\n") and b"Transfer-Encoding: chunked" in body
    assert not body.endswith(b"0\r\n\r\n")  # cut short, and the client can tell: no last chunk
    assert len(body) < 2_000_000  # of 8.5 MB: what the kernel and the transport held, not the whole answer


def test_the_streamed_log_is_the_whole_log_for_http_1_1_and_1_0(paper_config) -> None:
    """Chunk by chunk, the same bytes as the log rendered at once (here 2,000 events: 32 chunks)."""
    some_log = logged(paper_config, 2000)

    async def scenario() -> tuple[bytes, bytes]:
        server = AsclogServer(some_log.log.snapshot)
        host, port = await server.start("127.0.0.1", 0)
        url = f"http://{host}:{port}{ASCLOG_PATH}"
        chunked = await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=30).read())
        loop = asyncio.get_running_loop()
        with socket.socket() as sock:
            sock.setblocking(False)
            await loop.sock_connect(sock, (host, port))
            await loop.sock_sendall(sock, f"GET {ASCLOG_PATH} HTTP/1.0\r\n\r\n".encode())
            plain = await _read_all(sock)
        server.close()
        return chunked, plain

    chunked, plain = asyncio.run(scenario())
    whole = asclog_xml(some_log.log.events())
    assert chunked == whole
    head, body = plain.split(b"\r\n\r\n", 1)
    assert b"Transfer-Encoding" not in head and b"Content-Length" not in head  # delimited by the close
    assert body == whole


def test_connections_beyond_the_limit_get_503_at_once(served: object) -> None:
    """Before: every connection was served, each holding its whole answer."""
    address = ("127.0.0.1", served.http_ports[0])
    idle = [socket.create_connection(address, timeout=5) for _ in range(MAX_CONNECTIONS)]
    try:
        time.sleep(0.2)  # accepted and counted
        with socket.create_connection(address, timeout=5) as extra:
            start = time.monotonic()
            extra.sendall(LOG_REQUEST)
            answer = extra.recv(4096)
            waited = time.monotonic() - start
    finally:
        for sock in idle:
            sock.close()
    assert answer.startswith(b"HTTP/1.1 503 Service Unavailable\r\n") and b"Retry-After: 1\r\n" in answer
    assert waited < 1.0
    time.sleep(0.2)
    with urllib.request.urlopen(f"http://{address[0]}:{address[1]}{ASCLOG_PATH}", timeout=5) as again:
        assert again.status == 200  # the idle ones closed: served again


@pytest.mark.parametrize("request_", [
    f"GET {ASCLOG_PATH} HTTP/1.1\nHost: x\n\n".encode(),
    f"\r\nGET {ASCLOG_PATH} HTTP/1.1\r\nHost: x\n\r\n".encode(),
])
def test_bare_lf_line_endings_are_read_at_once(served: object, request_: bytes) -> None:
    """RFC 9112 section 2.2: "a recipient MAY recognize a single LF as a line terminator". Before: the request
    waited 5 s for a CRLF CRLF that never came, then got 400."""
    with socket.create_connection(("127.0.0.1", served.http_ports[0]), timeout=5) as sock:
        start = time.monotonic()
        sock.sendall(request_)
        first = sock.recv(4096)
        waited = time.monotonic() - start
    assert first.startswith(b"HTTP/1.1 200 OK\r\n") and waited < 1.0


def test_a_bare_cr_is_refused_at_once(served: object) -> None:
    """RFC 9112 section 2.2: a bare CR makes the element invalid."""
    with socket.create_connection(("127.0.0.1", served.http_ports[0]), timeout=5) as sock:
        start = time.monotonic()
        sock.sendall(f"GET {ASCLOG_PATH} HTTP/1.1\rHost: x\r\n\r\n".encode())
        first = sock.recv(4096)
        waited = time.monotonic() - start
    assert first.startswith(b"HTTP/1.1 400 Bad Request\r\n") and b"CR" in first and waited < 1.0


def test_the_closing_line_counts_the_event_log_requests(tmp_path) -> None:
    from harness.bench.processes import start_emulator

    server = start_emulator(tmp_path / "serve.log", http=True)
    address = ("127.0.0.1", server.http_ports[0])
    with urllib.request.urlopen(f"http://{address[0]}:{address[1]}{ASCLOG_PATH}", timeout=5) as answer:
        answer.read()
    with socket.create_connection(address, timeout=5) as sock:
        sock.sendall(b"GET /elsewhere HTTP/1.1\r\n\r\n")
        sock.recv(4096)
    code, out = server.stop()
    assert code == 0
    assert "event log: answered 2 requests (200 1, 404 1); dropped 0 connections" in out


def test_the_wire_bench_measures_the_tick_under_the_event_log_flood() -> None:
    """`hils bench wire`'s figures for the event-log flood: requests answered, refused beyond the connection limit,
    and the tick's lateness beside it."""
    from harness.bench.commands import LOG_EVENTS, LogFlood, measure_tick_lateness_under_flood

    figures = measure_tick_lateness_under_flood(2.0, [LogFlood("event_log", whole=2, never_read=MAX_CONNECTIONS)])
    flood = figures["floods"]["event_log"]
    assert figures["log_events"] == LOG_EVENTS and flood["whole"] == 2
    assert flood["answered"] >= 1 and flood["refused_busy"] >= 1, flood
    assert flood["n"] >= 15 and figures["quiet"]["n"] >= 15
    assert flood["p50"] < 20.0, flood
