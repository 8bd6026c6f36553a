"""The served emulator against the NTCIP 1202 v03 MIB, object by object, with net-snmp over real UDP: every object
it answers is known to the MIB, of its type and within its syntax; every read-only object refuses a SET; every
writable INTEGER takes a SET at its range's edges and refuses one past them with wrongValue. What departs from v03
does so for a listed reason (v02's definition, a declared sub-range, a column taken from the config)."""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterator

import pytest

from emulator.agent.mib import NOT_WRITABLE_HERE
from harness.bench.processes import tool
from harness.reference import mib_conformance
from harness.reference.mib_conformance import NetSnmp, Verdict, check, served_emulator
from hils.protocol.ntcip import PATTERN_TABLE, PREEMPT_STATUS, PatternColumn, Version, oid_str
from hils.sim.network import data_path

pytestmark = pytest.mark.wallclock


@pytest.fixture(scope="module")
def city() -> Iterator[NetSnmp]:
    """The four-leg as a city runs it: coordination patterns, eight overlaps, a preempt."""
    with served_emulator(str(data_path("four_leg_city.toml"))) as agent:
        yield agent


@pytest.fixture(scope="module")
def city_v03() -> Iterator[NetSnmp]:
    """The same controller served as NTCIP 1202 v03 (`hils emulator serve --ntcip v03`)."""
    with served_emulator(str(data_path("four_leg_city.toml")), Version.V03) as agent:
        yield agent


def _snmp(program: str, agent: NetSnmp, *args: str) -> str:
    """What net-snmp prints (stdout and stderr) for one request to the agent, SNMPv2c with the write community."""
    done = subprocess.run([tool(program), "-v2c", "-c", agent.write_community, "-On", "-t", "2", "-r", "1",
                           f"{agent.host}:{agent.port}", *args], capture_output=True, text=True, timeout=60)
    return done.stdout + done.stderr


def test_a_walk_alone_reports_no_finding(city: NetSnmp, capsys: pytest.CaptureFixture[str]) -> None:
    url = f"snmp://{city.host}:{city.port}?community={city.write_community}"
    assert mib_conformance.main(["--target", url]) == 0
    out = capsys.readouterr().out
    assert "437 accessible objects, 242 read-write" in out and "finding: 0" in out


def test_every_object_of_the_city_controller_is_as_the_mib_says(city: NetSnmp) -> None:
    report = check(city, sets=True)
    assert [f.line() for f in report.findings if f.verdict is Verdict.FINDING] == []
    by = {v: {f.name for f in report.findings if f.verdict is v and f.check == "set"} for v in Verdict}
    assert by[Verdict.V02] == {"patternSplitNumber"}  # read-write as v02 has it; v03 made it read-only
    assert by[Verdict.LIMITATION] == set(NOT_WRITABLE_HERE)
    served = {name for names in report.served.values() for name in names}
    assert {"maxOverlaps", "overlapTrailGreen", "preemptDelay", "patternCycleTime", "splitTime", "phaseNumber",
            "maxRings", "sequenceRingNumber", "maxChannels", "channelControlSource", "timebaseAscActionStatus",
            "vehicleDetectorControlGroupActuation"} <= served
    assert not {"preemptStatus", "maxPreemptGroups", "preemptStatusGroup"} & served  # v03 added them
    # The walk still answers after every SET was put back.
    assert check(city, sets=False).instances == report.instances


def test_served_as_v03_every_object_is_as_v03_defines_it(city_v03: NetSnmp) -> None:
    report = check(city_v03, sets=True, edition=Version.V03)
    assert [f.line() for f in report.findings if f.verdict is Verdict.FINDING] == []
    assert [f.line() for f in report.findings if f.verdict is Verdict.V02] == []  # patternSplitNumber as v03 has it
    assert {f.name for f in report.findings if f.verdict is Verdict.LIMITATION} == set(NOT_WRITABLE_HERE)
    served = {name for names in report.served.values() for name in names}
    assert {"preemptStatus", "maxPreemptGroups", "preemptStatusGroupNumber", "preemptStatusGroup"} <= served


def test_the_edition_decides_what_is_answered_and_what_is_written(city: NetSnmp, city_v03: NetSnmp) -> None:
    status = oid_str(PREEMPT_STATUS.instance())
    assert "No Such Object available on this agent at this OID" in _snmp("snmpget", city, status)
    # Served under v03: the preempt in service (0 none; the check's SETs of preemptControlState may have called it).
    assert re.fullmatch(rf"\.{re.escape(status)} = INTEGER: [01]\n", _snmp("snmpget", city_v03, status))
    split = oid_str(PATTERN_TABLE[PatternColumn.SPLIT_NUMBER].instance(1))
    assert f".{split} = INTEGER: 1" in _snmp("snmpset", city, split, "i", "1")  # read-write in v02
    assert "Reason: notWritable" in _snmp("snmpset", city_v03, split, "i", "1")  # read-only in v03


def test_an_agent_checked_as_the_edition_it_does_not_serve_has_findings(city_v03: NetSnmp,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    url = f"snmp://{city_v03.host}:{city_v03.port}?community={city_v03.write_community}"
    assert mib_conformance.main(["--target", url, "--ntcip", "v03"]) == 0
    assert "served as NTCIP 1202 v03" in capsys.readouterr().out
    assert mib_conformance.main(["--target", url, "--ntcip", "v02"]) == 1
    out = capsys.readouterr().out
    assert "preemptStatus" in out and "served under v02, which has no such object (v03 added it)" in out


def test_a_controller_with_phases_left_out_serves_every_row_its_max_counts() -> None:
    with served_emulator(str(data_path("four_phase.toml"))) as agent:
        report = check(agent, sets=True)
    assert [f.line() for f in report.findings if f.verdict is Verdict.FINDING] == []


def test_a_target_that_is_no_snmp_url_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        mib_conformance.main(["--target", "http://127.0.0.1:161"])
    assert info.value.code == 2
    assert "must start with snmp://" in capsys.readouterr().err
