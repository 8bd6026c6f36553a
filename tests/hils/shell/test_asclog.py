"""Collecting a controller's log from whatever answers at its event-log endpoint: bounded in time and size, every
failure one line, and a run's other outputs written all the same.

A hostile endpoint here is a local TCP server that answers one way each: a body dripped 1 KB every 0.5 s, headers
dripped, a body without end, a body cut short of its Content-Length, a status line that is not HTTP, values no
ATSPM reader takes, and a good log that, collected long after the controller powered up, holds no pattern event.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from hils.protocol.hires import Event, EventCode, asclog_xml
from hils.run.testbed import Testbed
from hils.shell.asclog import Bounds, CollectError, collect

E = EventCode
HEAD = b"HTTP/1.1 200 OK\r\nContent-Type: application/xml\r\n"


def _log_without_a_pattern() -> bytes:
    """Ten minutes of an actuated controller's log (its detectors on SUMO's traffic) from its second minute on:
    services and detector events, no pattern event (131-149)."""
    with Testbed(agent="actuated", sumo=True, duration=660.0) as tb:
        tb.reset()
        tb.run()
        (events,) = tb.hires().values()
    start = events[0].time + timedelta(seconds=60)
    kept = [e for e in events if e.time >= start]
    assert not any(E.COORD_PATTERN_CHANGE <= e.code <= 149 for e in kept)
    assert any(e.code == E.PHASE_INACTIVE for e in kept) and any(e.code == E.DETECTOR_ON for e in kept)
    return asclog_xml(kept)


def _drip(conn: socket.socket) -> None:
    conn.sendall(HEAD + b"Content-Length: 10000000\r\n\r\n")
    while True:
        conn.sendall(b" " * 1024)
        time.sleep(0.5)


def _drip_headers(conn: socket.socket) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\n")
    while True:
        conn.sendall(b"X-A: b\r\n")
        time.sleep(0.5)


def _endless(conn: socket.socket) -> None:
    conn.sendall(HEAD + b"\r\n<EventResponses>\n")
    row = b'<Event ID="1" TimeStamp="04-15-2024 12:00:00.1" EventTypeID="82" Parameter="3"/>\n' * 1000
    while True:
        conn.sendall(row)


def _cut_short(conn: socket.socket) -> None:
    conn.sendall(HEAD + b"Content-Length: 100000\r\n\r\n<EventResponses>\n<Event ID=\"1\" Time")


def _garbage(conn: socket.socket) -> None:
    conn.sendall(b"\x16\x03\x01 not HTTP at all\r\n\r\n")


def _too_large_values(conn: socket.socket) -> None:
    body = (b'<EventResponses><Event ID="1" TimeStamp="04-15-2024 12:00:00.1" EventTypeID="1" Parameter="2"/>'
            b'<Event ID="2" TimeStamp="04-15-2024 12:00:00.2" EventTypeID="70000" Parameter="99999999999"/>'
            b'</EventResponses>')
    conn.sendall(HEAD + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)


def _closes(conn: socket.socket) -> None:
    """Hangs up without a word."""


def _busy(conn: socket.socket) -> None:
    conn.sendall(b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\nContent-Length: 0\r\n\r\n")


def _answer(body: bytes) -> Callable[[socket.socket], None]:
    def answer(conn: socket.socket) -> None:
        conn.sendall(HEAD + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)

    return answer


class Hostile:
    """A local endpoint answering every request with ``behaviour(connection)``, then closing it."""

    def __init__(self, behaviour: Callable[[socket.socket], None]) -> None:
        self.behaviour = behaviour
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.server.getsockname()[1]}"
        self.requests = 0
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return  # closed
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn: socket.socket) -> None:
        self.requests += 1
        with conn:
            try:
                conn.recv(65536)  # the request
                self.behaviour(conn)
            except OSError:
                pass  # the collector hung up: what a bounded collector does

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.server.shutdown(socket.SHUT_RDWR)  # wakes the thread waiting in accept()
        self.server.close()


@pytest.fixture
def hostile() -> Iterator[Callable[[Callable[[socket.socket], None]], Hostile]]:
    servers: list[Hostile] = []

    def start(behaviour: Callable[[socket.socket], None]) -> Hostile:
        servers.append(Hostile(behaviour))
        return servers[-1]

    yield start
    for s in servers:
        s.close()


BOUNDS = Bounds(seconds=2.0, max_bytes=2**20, read_timeout=1.0)

CASES = {
    "drip": (_drip, "not collected within 2 s"),
    "dripped headers": (_drip_headers, "not collected within 2 s"),
    "endless body": (_endless, "the log is larger than the 1 MB allowed"),
    "cut short": (_cut_short, "the answer ended early"),
    "garbage status line": (_garbage, "not an HTTP answer"),
    "values too large": (_too_large_values, "EventTypeID 70000; allowed: 0 to 32767"),
    "closes at once": (_closes, "the endpoint closed the connection without an answer"),
    "always busy": (_busy, "the endpoint stayed busy (HTTP 503) for 2 s"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_hostile_endpoint_is_one_line_within_the_bounds(hostile, case: str) -> None:
    behaviour, why = CASES[case]
    server = hostile(behaviour)
    t0 = time.monotonic()
    with pytest.raises(CollectError) as caught:
        collect(server.url, datetime(2024, 4, 15, 12), BOUNDS)
    took = time.monotonic() - t0
    assert why in str(caught.value) and "\n" not in str(caught.value)
    assert took < BOUNDS.seconds + 5, f"took {took:.1f} s"  # the deadline, and a loaded machine's slack


def test_a_busy_endpoint_is_asked_again_after_its_retry_after(hostile) -> None:
    # `hils emulator serve --http` answers 503 (Retry-After: 1) beyond its connection limit: come back, in bounds.
    event = Event(datetime(2024, 4, 15, 12, 0, 0), E.PHASE_BEGIN_GREEN, 2)
    answers = iter([_busy, _answer(asclog_xml([event]))])
    server = hostile(lambda conn: next(answers)(conn))
    assert collect(server.url, None, Bounds(seconds=5.0, max_bytes=2**20, read_timeout=1.0)) == [event]
    assert server.requests == 2


def test_a_silent_endpoint_times_out_on_its_read_timeout(hostile) -> None:
    server = hostile(lambda conn: time.sleep(30))
    t0 = time.monotonic()
    with pytest.raises(CollectError, match="no answer within 1 s"):
        collect(server.url, None, BOUNDS)
    assert time.monotonic() - t0 < BOUNDS.read_timeout + 1.5


def test_an_endpoint_nobody_listens_on_says_so() -> None:
    with socket.socket() as unused:
        unused.bind(("127.0.0.1", 0))  # a port of ours, not listening
        with pytest.raises(CollectError, match="Connection refused"):
            collect(f"http://127.0.0.1:{unused.getsockname()[1]}", None, BOUNDS)


def test_a_good_log_reads_back_in_time_order(hostile) -> None:
    later, earlier = (Event(datetime(2024, 4, 15, 12, 0, 1), E.DETECTOR_ON, 3),
                      Event(datetime(2024, 4, 15, 12, 0, 0), E.PHASE_BEGIN_GREEN, 2))
    server = hostile(_answer(asclog_xml([later, earlier])))
    assert collect(server.url, None, BOUNDS) == [earlier, later]


# --- a wall-clock run, with its log collected from each ---------------------------------------------------------


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    from harness.bench.processes import start_emulator

    server = start_emulator(tmp_path_factory.mktemp("serve") / "serve.log")
    try:
        yield server
    finally:
        server.stop()


@pytest.mark.wallclock
@pytest.mark.parametrize("case", ["no pattern event", *CASES])
def test_a_run_whose_log_cannot_be_collected_still_writes_every_other_output(
        tmp_path: Path, served, hostile, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    from hils.cli.main import main

    behaviour, why = CASES.get(case, (None, None))
    server = hostile(behaviour or _answer(_log_without_a_pattern()))
    out = tmp_path / "run"
    code = main(["run", "--no-sumo", "--no-progress", "--duration", "2", "--out", str(out),
                 "--target", f"snmp://127.0.0.1:{served.port}?community=private&version=2c",
                 "--asclog", server.url, "--asclog-timeout", "2", "--asclog-max-mb", "1"])
    console = capsys.readouterr().out
    assert code == 0, console
    s = json.loads((out / "summary.json").read_text())
    assert s["outputs"]["failed"] == {} and s["outputs"]["finished"]
    for name in ("events.jsonl", "summary.json", "signal_timeline.svg"):
        assert name in s["outputs"]["written"] and (out / name).stat().st_size > 0, name
    record = s["record"]
    if why is None:  # collected: its record and charts, the split monitor without a programmed split
        assert record["file"] == "hires.parquet" and (out / "split_monitor.svg").exists()
        assert "programmed split unknown" in (out / "split_monitor.svg").read_text()
        return
    line = f"could not collect the controller's log from {server.url}/v1/asclog/xml/full?since="
    assert record["missing"].startswith(line) and why in record["missing"] and "\n" not in record["missing"]
    assert f"Hi-res log: {line}" in console
    assert "file" not in record and not (out / "hires.parquet").exists()
