"""The controller's record and the inputs field tools send, over the wire: `hils emulator serve --http` read by
Signal-Replay's own collector as it reads an Intelight MaxTime, and vehicle detector, push-button and preempt
inputs SET by net-snmp's snmpset as Signal-Replay sends them."""

from __future__ import annotations

import socket
import time
from datetime import datetime, timedelta
from pathlib import Path

import pytest
from signal_replay import collector

from hils.protocol.hires import EventCode
from hils.protocol.ntcip import (
    DETECTOR_ACTUATION,
    PED_DETECTOR_ACTUATION,
    PREEMPT_CONTROL_STATE,
    STATUS_TABLE,
    StatusColumn,
    oid_str,
)
from hils.shell import asclog
from tests.emulator.agent.test_agent_netsnmp import run

pytestmark = pytest.mark.wallclock

E = EventCode


def wait_for(condition: object, seconds: float = 5.0) -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, "not seen in time"
        time.sleep(0.1)


def test_signal_replays_collector_reads_the_served_log_in_host_time(served: object) -> None:
    frame = collector.fetch_output_data("127.0.0.1", served.http_ports[0])
    assert list(frame.columns) == ["TimeStamp", "EventTypeID", "Parameter"]
    first = frame.iloc[0]
    # The controller powered up on the host's clock: its first events (the start-up greens) are stamped now-ish.
    assert abs((datetime.now() - first.TimeStamp.to_pydatetime()).total_seconds()) < 60
    assert {(int(r.EventTypeID), int(r.Parameter)) for r in frame.itertuples()
            if r.TimeStamp == first.TimeStamp} >= {(E.PHASE_BEGIN_GREEN, 2), (E.PHASE_BEGIN_GREEN, 6)}
    later = collector.fetch_output_data("127.0.0.1", served.http_ports[0], since=datetime.now() + timedelta(hours=1))
    assert later.empty  # since: from that time on


def test_detector_and_push_button_sets_reach_the_log(served: object) -> None:
    url = f"http://127.0.0.1:{served.http_ports[0]}"
    since = datetime.now() - timedelta(seconds=1)
    done = run("snmpset", "1", "private", served.port, oid_str(PED_DETECTOR_ACTUATION.instance(1)), "i", "8")
    assert done.returncode == 0, done.stderr  # push button 4 (bit 3 of group 1)
    done = run("snmpset", "1", "private", served.port, oid_str(DETECTOR_ACTUATION.instance(1)), "i", "128")
    assert done.returncode == 0, done.stderr  # vehicle detector 8

    def seen() -> set[tuple[int, int]]:
        return {(e.code, e.parameter) for e in asclog.collect(url, since)}

    wait_for(lambda: {(E.PED_DETECTOR_ON, 4), (E.PED_CALL_REGISTERED, 4), (E.DETECTOR_ON, 8),
                      (E.PHASE_CALL_REGISTERED, 8)} <= seen())
    peds = run("snmpget", "2c", "public", served.port, oid_str(STATUS_TABLE[StatusColumn.PED_CALLS].instance(1)))
    assert peds.stdout.strip().endswith("INTEGER: 8")  # the controller holds the pedestrian call of phase 4
    for obj in (PED_DETECTOR_ACTUATION, DETECTOR_ACTUATION):
        assert run("snmpset", "1", "private", served.port, oid_str(obj.instance(1)), "i", "0").returncode == 0
    wait_for(lambda: {(E.PED_DETECTOR_OFF, 4), (E.DETECTOR_OFF, 8)} <= seen())


@pytest.mark.parametrize("obj", [PED_DETECTOR_ACTUATION, DETECTOR_ACTUATION])
def test_a_detector_group_that_does_not_exist_is_no_such_name(served: object, obj: object) -> None:
    """Signal-Replay resets groups 1, 2, ... of each kind and stops at the first noSuchName (eight detectors of
    each kind here: one group)."""
    done = run("snmpset", "1", "private", served.port, oid_str(obj.instance(2)), "i", "0")
    assert done.returncode != 0 and "noSuchName" in done.stderr + done.stdout


def http(port: int, request: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(request)
        out = b""
        while chunk := s.recv(65536):
            out += chunk
    return out


@pytest.mark.parametrize(("request_", "status"), [
    (b"GET /v1/asclog/xml/full?since=yesterday HTTP/1.1\r\nHost: x\r\n\r\n", b"400"),
    (b"GET /v1/other HTTP/1.1\r\n\r\n", b"404"),
    (b"POST /v1/asclog/xml/full HTTP/1.1\r\n\r\n", b"405"),
    (b"\x00\xff garbage\r\n\r\n", b"400"),
    (b"GET " + b"x" * 20000 + b" HTTP/1.1\r\n\r\n", b"400"),
])
def test_bad_requests_are_refused_and_the_log_keeps_answering(served: object, request_: bytes, status: bytes) -> None:
    port = served.http_ports[0]
    assert http(port, request_).split(b" ", 2)[1] == status
    assert http(port, b"GET /v1/asclog/xml/full HTTP/1.1\r\n\r\n").startswith(b"HTTP/1.1 200 OK")
    assert served.proc.poll() is None


def test_a_wall_clock_run_collects_the_controllers_log_into_its_folder(tmp_path: Path, served: object) -> None:
    import subprocess
    import sys

    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--duration", "4",
                           "--target", f"snmp://127.0.0.1:{served.port}?community=private&version=2c",
                           "--asclog", f"http://127.0.0.1:{served.http_ports[0]}", "--out", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Hi-res log:" in done.stdout and (out / "hires.parquet").exists()
    import pandas as pd
    frame = pd.read_parquet(out / "hires.parquet")
    # The run's own SETs put the controller under system control: its record says so, in the run's window.
    assert set(frame.DeviceId) == {1}
    assert ((frame.EventId == E.UNIT_CONTROL_STATUS_CHANGE) & (frame.Parameter == 2)).any()


def test_asclog_needs_a_wall_clock_run_of_one_controller(tmp_path: Path) -> None:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "hils", "run", "--no-sumo", "--duration", "1", "--asclog",
                           "http://127.0.0.1:1", "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--asclog" in done.stderr and "Traceback" not in done.stderr


def test_a_preempt_input_set_by_snmpset_reaches_the_log(tmp_path: Path) -> None:
    """Signal-Replay replays a log's preempt inputs (102/104) as preemptControlState SETs; a preempt that does not
    exist is noSuchName."""
    from harness.bench.processes import start_emulator

    city = Path(__file__).parents[3] / "hils/data/four_leg_city.toml"
    served = start_emulator(tmp_path / "serve.log", "--config", str(city), http=True)
    try:
        url = f"http://127.0.0.1:{served.http_ports[0]}"
        since = datetime.now() - timedelta(seconds=1)
        done = run("snmpset", "1", "private", served.port, oid_str(PREEMPT_CONTROL_STATE.instance(1)), "i", "1")
        assert done.returncode == 0, done.stderr
        wait_for(lambda: {(E.PREEMPT_CALL_INPUT_ON, 1), (E.PREEMPT_ENTRY_STARTED, 1)}
                 <= {(e.code, e.parameter) for e in asclog.collect(url, since)}, seconds=15)
        missing = run("snmpset", "1", "private", served.port, oid_str(PREEMPT_CONTROL_STATE.instance(2)), "i", "0")
        assert missing.returncode != 0 and "noSuchName" in missing.stderr + missing.stdout
        assert run("snmpset", "1", "private", served.port, oid_str(PREEMPT_CONTROL_STATE.instance(1)), "i",
                   "0").returncode == 0
        wait_for(lambda: (E.PREEMPT_CALL_INPUT_OFF, 1) in {(e.code, e.parameter) for e in asclog.collect(url, since)})
    finally:
        served.stop()
