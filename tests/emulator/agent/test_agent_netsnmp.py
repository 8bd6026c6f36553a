"""The emulator's SNMP agent against an independent client: net-snmp's snmpget, snmpset and snmpwalk.

`hils emulator serve` runs as a subprocess on a free port (``--port 0``; the
port is read from the line it prints when ready) and the Debian ``snmp``
package's tools talk to it, numerically (``-On``), without retries. Edge cases
that net-snmp's tools cannot produce (garbage, huge GETBULKs, a ticker held up)
are sent from Python with messages built by pysnmp's protocol API.
"""

from __future__ import annotations

import asyncio
import itertools
import random
import re
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pyasn1.codec.ber import decoder, encoder
from pysnmp.proto import api

from emulator.agent.mib import MibView
from emulator.agent.serve import WallClockTicker
from emulator.agent.snmp import DEFAULT_MAX_MESSAGE_SIZE, DropReason, RequestKind, SnmpAgent
from emulator.model.controller import Controller
from harness.bench.processes import Served, start_emulator, tool
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import (
    ASC,
    COORD_FORCE_MODE,
    COORD_PATTERN_STATUS,
    LOCAL_FREE_STATUS,
    MAX_OVERLAPS,
    MAX_PHASE_GROUPS,
    MAX_PHASES,
    MAX_PREEMPTS,
    OVERLAP_STATUS_TABLE,
    OVERLAP_TABLE,
    PATTERN_TABLE,
    PREEMPT_CONTROL_STATE,
    PREEMPT_TABLE,
    SHORT_ALARM_STATUS,
    SPLIT_TABLE,
    SYSTEM_PATTERN_CONTROL,
    UNIT_BACKUP_TIME,
    ControlColumn,
    ErrorStatus,
    LocalFreeStatus,
    Oid,
    OverlapColumn,
    OverlapStatusColumn,
    PatternColumn,
    PhaseColumn,
    PhaseOption,
    PreemptColumn,
    PreemptState,
    ShortAlarm,
    SplitColumn,
    StatusColumn,
    control_oid,
    oid_str,
    parse_oid,
    phase_oid,
    status_oid,
)
from hils.shell.transport import Latency
from hils.sim.network import data_path

pytestmark = pytest.mark.wallclock

A = oid_str(ASC)
VEH_CALL_1 = oid_str(control_oid(ControlColumn.VEH_CALL, 1))
GREENS_1 = oid_str(status_oid(StatusColumn.GREENS, 1))
YELLOWS_1 = oid_str(status_oid(StatusColumn.YELLOWS, 1))
REDS_1 = oid_str(status_oid(StatusColumn.REDS, 1))
BACKUP_TIME = oid_str(UNIT_BACKUP_TIME.instance())
MAX_PHASES_0 = oid_str(MAX_PHASES.instance())
UNKNOWN = A + ".99.0"
# Everything a SET could change: the control objects of group 1, unitBackupTime, systemPatternControl.
WRITABLE = [oid_str(control_oid(c, 1)) for c in ControlColumn] + [BACKUP_TIME,
                                                                   oid_str(SYSTEM_PATTERN_CONTROL.instance())]
PHASES_2_6 = 0b00100010  # 34
PHASES_4_8 = 0b10001000  # 136


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """One agent shared by the tests that leave its signal state alone."""
    served = start_emulator(tmp_path_factory.mktemp("agent") / "serve.log")
    yield served
    served.stop()


def run(program: str, version: str, community: str, port: int, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([tool(program), f"-v{version}", "-c", community, "-On", "-t", "1", "-r", "0",
                           f"127.0.0.1:{port}", *args], capture_output=True, text=True, timeout=20)


def values(output: str) -> dict[str, str]:
    """OID (without the leading dot) -> value text, from net-snmp's ``-On`` output."""
    out = {}
    for line in output.splitlines():
        if line.startswith(".") and " = " in line:
            oid, value = line[1:].split(" = ", 1)
            out[oid] = value
    return out


def get(port: int, *oids: str, version: str = "2c") -> dict[str, str]:
    done = run("snmpget", version, "public", port, *oids)
    assert done.returncode == 0, done.stderr
    return values(done.stdout)


def integers(port: int, *oids: str) -> list[int]:
    got = get(port, *oids)
    return [int(got[oid].removeprefix("INTEGER: ")) for oid in oids]


# --- SNMP messages built with pysnmp, for what net-snmp's tools do not send ---------------------

def request(version: int, community: str, kind: RequestKind, oids: list[Oid], *,
            non_repeaters: int = 0, max_repetitions: int = 10, request_id: int = 1) -> bytes:
    module = api.PROTOCOL_MODULES[version]
    pdu_class = {RequestKind.GET: module.GetRequestPDU, RequestKind.GET_NEXT: module.GetNextRequestPDU,
                 RequestKind.GET_BULK: getattr(module, "GetBulkRequestPDU", None)}[kind]
    pdu = pdu_class()
    if kind is RequestKind.GET_BULK:
        module.apiBulkPDU.set_defaults(pdu)
        module.apiBulkPDU.set_non_repeaters(pdu, non_repeaters)
        module.apiBulkPDU.set_max_repetitions(pdu, max_repetitions)
    else:
        module.apiPDU.set_defaults(pdu)
    module.apiPDU.set_request_id(pdu, request_id)
    module.apiPDU.set_varbinds(pdu, [(oid, module.null) for oid in oids])
    message = module.Message()
    module.apiMessage.set_defaults(message)
    module.apiMessage.set_community(message, community)
    module.apiMessage.set_pdu(message, pdu)
    return encoder.encode(message)


@dataclass(frozen=True)
class Answer:
    request_id: int
    status: ErrorStatus
    index: int
    varbinds: list[tuple[Oid, Any]]


def parse(datagram: bytes) -> Answer:
    module = api.PROTOCOL_MODULES[int(api.decodeMessageVersion(datagram))]
    message, rest = decoder.decode(datagram, asn1Spec=module.Message())
    assert not rest
    pdu = module.apiMessage.get_pdu(message)
    return Answer(int(module.apiPDU.get_request_id(pdu)), ErrorStatus(int(module.apiPDU.get_error_status(pdu))),
                  int(module.apiPDU.get_error_index(pdu)),
                  [(tuple(oid), value) for oid, value in module.apiPDU.get_varbinds(pdu)])


def udp_exchange(port: int, datagram: bytes, timeout: float = 2.0) -> bytes:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout)
        sock.sendto(datagram, ("127.0.0.1", port))
        return sock.recv(65535)


# --- reading ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("version", ["1", "2c"])
def test_configured_objects_read_back(server: Served, version: str, paper_config: IntersectionConfig) -> None:
    rings = [phase_oid(PhaseColumn.RING, p) for p in range(1, 9)]
    timing = [oid_str(phase_oid(c, 1)) for c in (PhaseColumn.MINIMUM_GREEN, PhaseColumn.MAXIMUM1,
                                                 PhaseColumn.YELLOW_CHANGE, PhaseColumn.RED_CLEAR)]
    got = get(server.port, MAX_PHASES_0, oid_str(MAX_PHASE_GROUPS.instance()), *timing, *map(oid_str, rings),
              REDS_1, YELLOWS_1, GREENS_1, oid_str(phase_oid(PhaseColumn.CONCURRENCY, 1)), version=version)
    assert got[MAX_PHASES_0] == "INTEGER: 8"
    assert got[oid_str(MAX_PHASE_GROUPS.instance())] == "INTEGER: 1"
    assert [got[oid] for oid in timing] == ["INTEGER: 3", "INTEGER: 20", "INTEGER: 30", "INTEGER: 20"]
    assert [got[oid_str(oid)] for oid in rings] == [f"INTEGER: {paper_config.ring_of(p)}" for p in range(1, 9)]
    assert [paper_config.ring_of(p) for p in range(1, 9)] == [1, 1, 1, 1, 2, 2, 2, 2]
    # At power-up phases 2 and 6 rest in green (bits 1 and 5), every other phase shows red.
    assert got[GREENS_1] == f"INTEGER: {PHASES_2_6}"
    assert got[YELLOWS_1] == "INTEGER: 0"
    assert got[REDS_1] == f"INTEGER: {0xFF & ~PHASES_2_6}"
    assert got[oid_str(phase_oid(PhaseColumn.CONCURRENCY, 1))] == "Hex-STRING: 05 06 "


@pytest.mark.parametrize(("program", "version", "options"), [
    ("snmpwalk", "1", ()),  # GETNEXT
    ("snmpwalk", "2c", ()),  # GETNEXT
    ("snmpbulkwalk", "2c", ("-Cr7",)),  # GETBULK, 7 per answer: rows end mid-table
])
def test_walk_lists_every_object_in_order(server: Served, paper_config: IntersectionConfig, program: str,
                                          version: str, options: tuple[str, ...]) -> None:
    done = run(program, version, "public", server.port, *options, A)
    assert done.returncode == 0, done.stderr
    walked = [parse_oid(oid) for oid in values(done.stdout)]
    expected = MibView(Controller(paper_config)).oids
    assert len(walked) == len(expected) > 100
    assert walked == expected
    assert all(a < b for a, b in itertools.pairwise(walked))


def test_get_of_missing_objects_v2c_gives_exception_values(server: Served) -> None:
    missing_instance = oid_str(phase_oid(PhaseColumn.MINIMUM_GREEN, 9))
    got = get(server.port, UNKNOWN, missing_instance, MAX_PHASES_0)
    assert got == {UNKNOWN: "No Such Object available on this agent at this OID",
                   missing_instance: "No Such Instance currently exists at this OID",
                   MAX_PHASES_0: "INTEGER: 8"}


def test_get_of_a_missing_object_v1_is_no_such_name_at_its_index(server: Served) -> None:
    done = run("snmpget", "1", "public", server.port, MAX_PHASES_0, UNKNOWN)
    assert "Reason: (noSuchName) There is no such variable name in this MIB." in done.stderr
    assert f"Failed object: .{UNKNOWN}" in done.stderr
    # snmpget drops the failed varbind and asks again: the error index pointed at the right one.
    assert values(done.stdout) == {MAX_PHASES_0: "INTEGER: 8"}


def test_walk_of_the_phase_table_gives_every_column_and_the_options(server: Served) -> None:
    table = oid_str(phase_oid(PhaseColumn.WALK, 1))[: -len(".2.1")]  # phaseEntry
    done = run("snmpwalk", "2c", "public", server.port, table)
    assert done.returncode == 0, done.stderr
    got = values(done.stdout)
    columns = sorted({int(oid.split(".")[-2]) for oid in got})
    # phaseNumber, the index, first; 13, 15 and 17 the gap reduction's time before reduction, time to reduce and
    # minimum gap
    assert columns == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 13, 15, 17, 20, 21, 22, 23]
    assert len(got) == 17 * 8
    options = int(PhaseOption.ENABLED | PhaseOption.SIMULTANEOUS_GAP_DISABLE)
    assert {got[oid_str(phase_oid(PhaseColumn.OPTIONS, p))] for p in range(1, 9)} == {f"INTEGER: {options}"}
    assert got[oid_str(phase_oid(PhaseColumn.PASSAGE, 4))] == "INTEGER: 0"
    assert got[oid_str(phase_oid(PhaseColumn.WALK, 4))] == "INTEGER: 0"
    # no gap reduction configured: the minimum gap is the passage
    assert got[oid_str(phase_oid(PhaseColumn.MINIMUM_GAP, 4))] == got[oid_str(phase_oid(PhaseColumn.PASSAGE, 4))]


def test_the_coordination_objects_walk_and_set_within_ntcip_ranges(tmp_path: Path) -> None:
    """The coord node (A.4) of the shipped four-leg: its pattern 1 and split table 1 walked by snmpwalk;
    systemPatternControl starts the pattern, out-of-range values are refused."""
    served = start_emulator(tmp_path / "serve.log")
    try:
        coord = A + ".4"
        done = run("snmpwalk", "2c", "public", served.port, coord)
        assert done.returncode == 0, done.stderr
        got = values(done.stdout)
        cycle, split_2 = oid_str(PATTERN_TABLE[PatternColumn.CYCLE_TIME].instance(1)), SPLIT_TABLE[SplitColumn.TIME]
        assert got[cycle] == "INTEGER: 70" and got[oid_str(split_2.instance(1, 2))] == "INTEGER: 28"
        assert got[oid_str(SPLIT_TABLE[SplitColumn.COORD_PHASE].instance(1, 6))] == "INTEGER: 1"
        assert got[oid_str(COORD_FORCE_MODE.instance())] == "INTEGER: 3"  # fixed
        assert got[oid_str(COORD_PATTERN_STATUS.instance())] == "INTEGER: 254"  # free at power-up
        assert len([o for o in got if o.startswith(oid_str(SPLIT_TABLE[SplitColumn.NUMBER].prefix))]) == 8
        done = run("snmpset", "2c", "private", served.port, oid_str(SYSTEM_PATTERN_CONTROL.instance()), "i", "1")
        assert done.returncode == 0, done.stderr
        status = [oid_str(o.instance()) for o in (COORD_PATTERN_STATUS, LOCAL_FREE_STATUS)]
        assert integers(served.port, *status) == [1, int(LocalFreeStatus.NOT_FREE)]
        for oid, value in ((cycle, "256"), (oid_str(COORD_FORCE_MODE.instance()), "4")):
            done = run("snmpset", "2c", "private", served.port, oid, "i", value)
            assert "wrongValue" in done.stderr, done.stderr
        done = run("snmpset", "2c", "private", served.port, oid_str(COORD_FORCE_MODE.instance()), "i", "2")
        assert done.returncode == 0 and integers(served.port, oid_str(COORD_FORCE_MODE.instance())) == [2]
    finally:
        served.stop()


def test_the_overlap_objects_walk_and_the_trailing_times_set_within_ntcip_ranges(tmp_path: Path) -> None:
    """The overlap node (A.9) of the city four-leg walked by snmpwalk: its table (types, included and modifier
    phases) and its status with 2+6 green at start-up; a trailing yellow below NEMA's 3.0 s is refused."""
    served = start_emulator(tmp_path / "serve.log", "--config", str(data_path("four_leg_city.toml")))
    try:
        done = run("snmpwalk", "2c", "public", served.port, A + ".9")
        assert done.returncode == 0, done.stderr
        got = values(done.stdout)
        assert got[oid_str(MAX_OVERLAPS.instance())] == "INTEGER: 8"
        types = [got[oid_str(OVERLAP_TABLE[OverlapColumn.TYPE].instance(n))] for n in range(1, 9)]
        assert types == ["INTEGER: 2"] * 4 + ["INTEGER: 1"] * 4  # normal right turns, fya (other) lefts
        assert got[oid_str(OVERLAP_TABLE[OverlapColumn.INCLUDED_PHASES].instance(1))] == 'Hex-STRING: 08 05 '
        # The node ends the MIB: the walk's last answer is endOfMibView.
        assert done.stdout.rstrip().endswith("No more variables left in this MIB View (It is past the end of the "
                                             "MIB tree)")
        # C (6, 3) and D (2, 7) green with 2+6; E and F flash beside them (their yellow bit).
        status = [oid_str(OVERLAP_STATUS_TABLE[col].instance(1)) for col in
                  (OverlapStatusColumn.REDS, OverlapStatusColumn.YELLOWS, OverlapStatusColumn.GREENS)]
        assert integers(served.port, *status) == [195, 48, 12]
        trail_yellow = oid_str(OVERLAP_TABLE[OverlapColumn.TRAIL_YELLOW].instance(1))
        done = run("snmpset", "2c", "private", served.port, trail_yellow, "i", "29")
        assert "wrongValue" in done.stderr, done.stderr
        done = run("snmpset", "2c", "private", served.port, trail_yellow, "i", "40")
        assert done.returncode == 0 and integers(served.port, trail_yellow) == [40]
    finally:
        served.stop()


def test_the_preempt_objects_walk_and_a_preempt_is_called_with_snmpset(tmp_path: Path) -> None:
    """The preempt node (A.6) of the city four-leg walked by snmpwalk; preemptControlState.1 SET to 1 with snmpset
    calls it: shortAlarmStatus shows the preempt input, preemptState its entry, then its dwell in 2+5."""
    served = start_emulator(tmp_path / "serve.log", "--config", str(data_path("four_leg_city.toml")))
    try:
        done = run("snmpwalk", "2c", "public", served.port, A + ".6")
        assert done.returncode == 0, done.stderr
        got = values(done.stdout)
        state = oid_str(PREEMPT_TABLE[PreemptColumn.STATE].instance(1))
        assert got[oid_str(MAX_PREEMPTS.instance())] == "INTEGER: 1"
        assert got[oid_str(PREEMPT_TABLE[PreemptColumn.DWELL_PHASE].instance(1))] == "Hex-STRING: 02 05 "
        assert got[state] == f"INTEGER: {int(PreemptState.NOT_ACTIVE)}"
        control = oid_str(PREEMPT_CONTROL_STATE.instance(1))
        assert got[control] == "INTEGER: 0"
        done = run("snmpset", "2c", "private", served.port, control, "i", "2")
        assert "wrongValue" in done.stderr, done.stderr
        done = run("snmpset", "2c", "private", served.port, control, "i", "1")
        assert done.returncode == 0, done.stderr
        alarm = oid_str(SHORT_ALARM_STATUS.instance())
        assert integers(served.port, alarm)[0] & ShortAlarm.PREEMPT
        deadline = time.monotonic() + 15
        while integers(served.port, state) != [int(PreemptState.DWELL)]:
            assert time.monotonic() < deadline, "no dwell within 15 s"
            time.sleep(0.2)
        assert integers(served.port, GREENS_1) == [0b00010010]  # 2 and 5
    finally:
        served.stop()


def test_a_phase_timing_set_is_range_checked_and_read_back(server: Served) -> None:
    minimum = oid_str(phase_oid(PhaseColumn.MINIMUM_GREEN, 7))
    yellow = oid_str(phase_oid(PhaseColumn.YELLOW_CHANGE, 7))
    done = run("snmpset", "2c", "private", server.port, yellow, "i", "29")
    assert "wrongValue" in done.stderr and integers(server.port, yellow) == [30]
    done = run("snmpset", "2c", "private", server.port, minimum, "i", "5")
    assert done.returncode == 0, done.stderr
    assert integers(server.port, minimum) == [5]
    done = run("snmpset", "2c", "private", server.port, minimum, "i", "3")  # as the other tests expect it
    assert done.returncode == 0, done.stderr


# --- writing -------------------------------------------------------------------------------------

def test_set_applies_in_both_versions(server: Served) -> None:
    done = run("snmpset", "1", "private", server.port, BACKUP_TIME, "i", "45")
    assert done.returncode == 0, done.stderr
    assert values(done.stdout) == {BACKUP_TIME: "INTEGER: 45"}
    assert integers(server.port, BACKUP_TIME) == [45]
    done = run("snmpset", "2c", "private", server.port, BACKUP_TIME, "i", "30")
    assert done.returncode == 0, done.stderr
    assert integers(server.port, BACKUP_TIME) == [30]


REFUSED = [
    # version, community, varbinds, net-snmp's reason, the failed object
    ("2c", "public", [(VEH_CALL_1, "i", "136")], "noAccess", VEH_CALL_1),
    ("1", "public", [(VEH_CALL_1, "i", "136")], "(noSuchName)", VEH_CALL_1),
    ("2c", "private", [(MAX_PHASES_0, "i", "4")], "notWritable", MAX_PHASES_0),
    ("1", "private", [(MAX_PHASES_0, "i", "4")], "(noSuchName)", MAX_PHASES_0),
    ("2c", "private", [(UNKNOWN, "i", "1")], "notWritable", UNKNOWN),
    ("1", "private", [(UNKNOWN, "i", "1")], "(noSuchName)", UNKNOWN),
    ("2c", "private", [(oid_str(control_oid(ControlColumn.VEH_CALL, 2)), "i", "1")], "noCreation",
     oid_str(control_oid(ControlColumn.VEH_CALL, 2))),
    ("2c", "private", [(VEH_CALL_1, "i", "256")], "wrongValue", VEH_CALL_1),
    ("2c", "private", [(VEH_CALL_1, "i", "-1")], "wrongValue", VEH_CALL_1),
    ("1", "private", [(VEH_CALL_1, "i", "256")], "(badValue)", VEH_CALL_1),
    ("2c", "private", [(VEH_CALL_1, "s", "x")], "wrongType", VEH_CALL_1),
    ("2c", "private", [(VEH_CALL_1, "u", "136")], "wrongType", VEH_CALL_1),  # Gauge32 is no INTEGER
    ("1", "private", [(VEH_CALL_1, "s", "x")], "(badValue)", VEH_CALL_1),
    # The first varbind alone would be fine: a refused SET applies none of its varbinds.
    ("2c", "private", [(BACKUP_TIME, "i", "40"), (VEH_CALL_1, "i", "300")], "wrongValue", VEH_CALL_1),
    ("1", "private", [(VEH_CALL_1, "i", "136"), (MAX_PHASES_0, "i", "3")], "(noSuchName)", MAX_PHASES_0),
]


@pytest.mark.parametrize(("version", "community", "varbinds", "reason", "failed"), REFUSED,
                         ids=[f"v{v}-{c}-{r.strip('()')}-{len(vb)}vb" for v, c, vb, r, _ in REFUSED])
def test_refused_set_reports_and_changes_nothing(server: Served, version: str, community: str,
                                                 varbinds: list[tuple[str, str, str]], reason: str,
                                                 failed: str) -> None:
    before = get(server.port, *WRITABLE)
    done = run("snmpset", version, community, server.port, *(part for vb in varbinds for part in vb))
    assert done.returncode != 0
    assert re.search(rf"^Reason: {re.escape(reason)}( |$)", done.stderr, re.MULTILINE), done.stderr
    assert f"Failed object: .{failed}\n" in done.stderr
    assert get(server.port, *WRITABLE) == before  # nothing changed, and the agent still answers


# --- the model ticks at wall-clock time --------------------------------------------------------------

def test_vehicle_call_moves_greens_through_yellow_in_wall_clock_time(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        assert integers(served.port, GREENS_1) == [PHASES_2_6]
        done = run("snmpset", "2c", "private", served.port, VEH_CALL_1, "i", str(PHASES_4_8))
        set_at = time.monotonic()
        assert done.returncode == 0, done.stderr
        seen: list[tuple[float, int, int]] = []  # (time, yellows, greens)
        while time.monotonic() < set_at + 10:
            yellows, greens = integers(served.port, YELLOWS_1, GREENS_1)
            seen.append((time.monotonic(), yellows, greens))
            if greens == PHASES_4_8:
                break
            time.sleep(0.03)
    finally:
        served.stop()
    assert {(y, g) for _, y, g in seen} <= {(0, PHASES_2_6), (PHASES_2_6, 0), (0, 0), (0, PHASES_4_8)}
    assert any(y == PHASES_2_6 for _, y, _ in seen), "yellows {2, 6} never seen"
    green_at = next(t for t, _, g in seen if g == PHASES_4_8)
    yellow_at = next(t for t, y, _ in seen if y == PHASES_2_6)
    # Greens {2, 6} end once their 3 s minimum green (timed from power-up) is over, then 3 s yellow
    # and 2 s red clearance: the wall clock, not the request rate, paces the model.
    expected = max(set_at, served.ready_at + 3.0) + 5.0
    assert abs(green_at - expected) < 0.5, (green_at - set_at, expected - set_at)
    assert 4.6 < green_at - yellow_at < 5.5
    assert green_at - set_at < 8.5


def test_ticker_catches_up_on_missed_ticks_and_counts_them(paper_config: IntersectionConfig) -> None:
    controller = Controller(paper_config)
    ticker = WallClockTicker(controller)

    async def scenario() -> None:
        task = asyncio.create_task(ticker.run())
        await asyncio.sleep(0.25)
        time.sleep(0.45)  # hold the loop up, as a long request or a GC pause would
        await asyncio.sleep(0.12)
        task.cancel()

    started = time.monotonic()
    asyncio.run(scenario())
    elapsed = time.monotonic() - started
    assert controller.tick == ticker.stats.ticks
    assert int(elapsed / 0.1) - 1 <= ticker.stats.ticks <= int(elapsed / 0.1)
    assert ticker.stats.late >= 3  # the ticks due while the loop was held up ran up to 0.4 s late
    assert ticker.stats.max_lateness > 0.3


# --- what gets no answer -------------------------------------------------------------------------------

def test_foreign_datagrams_are_dropped_counted_and_the_agent_keeps_answering(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log", "--latency-ms", "30", "--jitter-ms", "5", verbose=True)
    valid = request(api.SNMP_VERSION_2C, "public", RequestKind.GET, [MAX_PHASES.instance()])
    response = api.v2c.Message()
    api.v2c.apiMessage.set_defaults(response)
    api.v2c.apiMessage.set_pdu(response, api.v2c.apiPDU.get_response(
        api.v2c.apiMessage.get_pdu(decoder.decode(valid, asn1Spec=api.v2c.Message())[0])))
    foreign = {
        DropReason.MALFORMED: [random.Random(7).randbytes(60), b"", valid[:-4], valid + b"\x00\x00",
                               b"\x30\x03\x02\x01\x00"],
        DropReason.NOT_A_REQUEST: [encoder.encode(response)],
    }
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for datagram in (d for ds in foreign.values() for d in ds):
                sock.sendto(datagram, ("127.0.0.1", served.port))
            sock.settimeout(0.3)
            with pytest.raises(TimeoutError):
                sock.recv(65535)
        # A real SNMPv3 discovery request, and a GET with a community the agent does not know.
        v3 = subprocess.run([tool("snmpget"), "-v3", "-l", "noAuthNoPriv", "-u", "nobody", "-On", "-t", "0.5",
                             "-r", "0", f"127.0.0.1:{served.port}", MAX_PHASES_0], capture_output=True, text=True)
        assert "Timeout" in v3.stderr
        wrong = run("snmpget", "2c", "secret", served.port, MAX_PHASES_0)
        assert "Timeout: No Response" in wrong.stderr
        assert get(served.port, MAX_PHASES_0) == {MAX_PHASES_0: "INTEGER: 8"}
        # The answers wait 25..35 ms each, concurrently: ten at once take about one delay, not ten.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(2)
            started = time.monotonic()
            for i in range(10):
                sock.sendto(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, [MAX_PHASES.instance()],
                                    request_id=i), ("127.0.0.1", served.port))
            ids = {parse(sock.recv(65535)).request_id for _ in range(10)}
            elapsed = time.monotonic() - started
        assert ids == set(range(10))
        assert 0.025 <= elapsed < 0.15
    finally:
        code, out = served.stop(signal.SIGINT)
    assert code == 0
    summary = out.strip().splitlines()[-1]
    dropped = len(foreign[DropReason.MALFORMED]) + len(foreign[DropReason.NOT_A_REQUEST]) + 2
    assert f"dropped {dropped} datagrams (malformed 5, unsupported version 1, unknown community 1, " \
           f"not a request 1)" in summary
    assert re.search(r"served 11 requests \(get 11\), 0 answered with an error", summary), summary
    assert served.log.read_text().count("emulator.agent.snmp: dropped a ") == dropped


def test_sigterm_stops_cleanly_with_a_summary(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log", "--ro-community", "ro", "--rw-community", "rw")
    assert run("snmpset", "2c", "rw", served.port, VEH_CALL_1, "i", "1").returncode == 0
    assert run("snmpset", "2c", "ro", served.port, VEH_CALL_1, "i", "2").returncode != 0
    code, out = served.stop(signal.SIGTERM)
    assert code == 0
    assert re.search(r"^served 2 requests \(set 2\), 1 answered with an error; dropped 0 datagrams \(none\); "
                     r"\d+ ticks, \d+ late", out, re.MULTILINE), out
    log = served.log.read_text()
    assert "SET from 127.0.0.1:" in log
    assert "phaseControlGroupVehCall.1 = 1 -> applied" in log
    assert "phaseControlGroupVehCall.1 = 2 -> refused (no_access)" in log


# --- edge cases, in process ----------------------------------------------------------------------------

@pytest.fixture
def agent(paper_config: IntersectionConfig) -> SnmpAgent:
    return SnmpAgent(MibView(Controller(paper_config)))


def test_answers_too_large_are_too_big_and_bulk_answers_are_cut_short(agent: SnmpAgent) -> None:
    everything = agent.view.oids
    # The most objects one request may name: their answer is larger than the request.
    fitting = max(n for n in range(1, len(everything))
                  if len(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, everything[:n]))
                  <= DEFAULT_MAX_MESSAGE_SIZE)
    answer = parse(agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, everything[:fitting])))
    assert (answer.status, answer.index, answer.varbinds) == (ErrorStatus.TOO_BIG, 0, [])
    # SNMPv1 echoes the request's varbinds (RFC 1157 4.1.2): no larger than the request, so within the maximum.
    v1_request = request(api.SNMP_VERSION_1, "public", RequestKind.GET, everything[:fitting])
    v1_datagram = agent.respond(v1_request)
    assert v1_datagram is not None and len(v1_datagram) <= DEFAULT_MAX_MESSAGE_SIZE
    v1 = parse(v1_datagram)
    assert (v1.status, v1.index, [oid for oid, _ in v1.varbinds]) == (ErrorStatus.TOO_BIG, 0,
                                                                       list(everything[:fitting]))
    # A request beyond the maximum is dropped unread.
    assert agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET, everything)) is None
    assert agent.stats.dropped == {DropReason.TOO_LARGE: 1}
    datagram = agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET_BULK, [ASC],
                                     max_repetitions=2**31 - 1))
    assert datagram is not None
    bulk = parse(datagram)
    assert len(datagram) <= DEFAULT_MAX_MESSAGE_SIZE
    assert bulk.status is ErrorStatus.NO_ERROR
    assert 40 < len(bulk.varbinds) < len(everything)
    assert [oid for oid, _ in bulk.varbinds] == everything[:len(bulk.varbinds)]


def test_getbulk_non_repeaters_and_end_of_mib(agent: SnmpAgent) -> None:
    oids = agent.view.oids
    answer = parse(agent.respond(request(api.SNMP_VERSION_2C, "public", RequestKind.GET_BULK,
                                         [ASC, oids[-1], oids[-3]], non_repeaters=1, max_repetitions=5)))
    # One non-repeater, then rows of two; the third row is past the end in both columns and is the last.
    assert [oid for oid, _ in answer.varbinds] == [oids[0], oids[-1], oids[-2], oids[-1], oids[-1], oids[-1],
                                                    oids[-1]]
    ended = [value.tagSet == api.v2c.EndOfMibView.tagSet for _, value in answer.varbinds]
    assert ended == [False, True, False, True, False, True, True]


def test_getnext_past_the_end_in_v1_is_no_such_name(agent: SnmpAgent) -> None:
    last = agent.view.oids[-1]
    answer = parse(agent.respond(request(api.SNMP_VERSION_1, "public", RequestKind.GET_NEXT, [ASC, last])))
    assert (answer.status, answer.index) == (ErrorStatus.NO_SUCH_NAME, 2)
    assert [oid for oid, _ in answer.varbinds] == [ASC, last]  # v1 errors echo the request's varbinds


def test_drop_counter_is_readable_from_python(paper_config: IntersectionConfig) -> None:
    agent = SnmpAgent(MibView(Controller(paper_config)), ro_community="ro", rw_community="rw",
                      latency=Latency(0.002, 0.001), seed=1)

    async def exchange() -> list[bytes]:
        host, port = await agent.start("127.0.0.1", 0)
        loop = asyncio.get_running_loop()
        answers: asyncio.Queue[bytes] = asyncio.Queue()

        class Client(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: Any) -> None:
                answers.put_nowait(data)

        transport, _ = await loop.create_datagram_endpoint(Client, remote_addr=(host, port))
        for datagram in (b"\xff" * 10, request(api.SNMP_VERSION_1, "public", RequestKind.GET, [ASC]),
                         request(api.SNMP_VERSION_1, "ro", RequestKind.GET, [MAX_PHASES.instance()])):
            transport.sendto(datagram)
        got = [await asyncio.wait_for(answers.get(), 2)]
        transport.close()
        agent.close()
        return got

    [answer] = asyncio.run(exchange())
    assert parse(answer).varbinds[0][1] == 8
    assert agent.stats.dropped == {DropReason.MALFORMED: 1, DropReason.COMMUNITY: 1}
    assert agent.stats.total_dropped == 2
    assert agent.stats.answered == 1

