"""The served emulator against the NTCIP 1202 v03 MIB, object by object, with net-snmp over real UDP: every object
it answers is known to the MIB, of its type and within its syntax; every read-only object refuses a SET; every
writable INTEGER takes a SET at its range's edges and refuses one past them with wrongValue. What departs from v03
does so for a listed reason (v02's definition, a declared sub-range, a column taken from the config)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from emulator.agent.mib import NOT_WRITABLE_HERE
from harness.reference import mib_conformance
from harness.reference.mib_conformance import NetSnmp, Verdict, check, served_emulator
from hils.sim.network import data_path

pytestmark = pytest.mark.wallclock


@pytest.fixture(scope="module")
def city() -> Iterator[NetSnmp]:
    """The four-leg as a city runs it: coordination patterns, eight overlaps, a preempt."""
    with served_emulator(str(data_path("four_leg_city.toml"))) as agent:
        yield agent


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
    assert {"maxOverlaps", "overlapTrailGreen", "preemptDelay", "patternCycleTime", "splitTime"} <= served
    # The walk still answers after every SET was put back.
    assert check(city, sets=False).instances == report.instances


def test_a_controller_with_phases_left_out_serves_every_row_its_max_counts() -> None:
    with served_emulator(str(data_path("four_phase.toml"))) as agent:
        report = check(agent, sets=True)
    assert [f.line() for f in report.findings if f.verdict is Verdict.FINDING] == []


def test_a_target_that_is_no_snmp_url_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        mib_conformance.main(["--target", "http://127.0.0.1:161"])
    assert info.value.code == 2
    assert "must start with snmp://" in capsys.readouterr().err
