"""Detectors: SUMO's stop-bar presence actuates the controller's detectors over NTCIP, and the controller runs
fully actuated on them (`--agent actuated`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from harness.bench.processes import start_emulator
from hils.protocol.config import ConfigError, IntersectionConfig, parse
from hils.protocol.ntcip import (
    DETECTOR_ACTUATION,
    DETECTOR_STATUS_ACTIVE,
    MAX_VEHICLE_DETECTOR_STATUS_GROUPS,
    MAX_VEHICLE_DETECTORS,
    VEHICLE_DETECTOR_CALL_PHASE,
    VEHICLE_DETECTOR_DELAY,
    VEHICLE_DETECTOR_EXTEND,
    StatusColumn,
    oid_str,
    status_oid,
)
from hils.shell.events import Kind, read
from tests.hils.shell.test_preflight import snmp


def test_an_actuated_detector_calls_its_phase_and_holds_its_green(paper_config: IntersectionConfig) -> None:
    c = Controller(paper_config)
    mib = MibView(c)
    assert mib.get_many([VEHICLE_DETECTOR_CALL_PHASE.instance(4)]) == (4,)  # detector n calls phase n
    mib.set_many([(DETECTOR_ACTUATION.instance(1), 0b1000)])  # detector 4 actuated
    assert mib.get_many([DETECTOR_STATUS_ACTIVE.instance(1), status_oid(StatusColumn.VEH_CALLS, 1)]) == (0b1000, 0b1000)
    for _ in range(100):
        c.step()
    assert 4 in c.greens
    c.set_actuations({2, 4})  # a vehicle on phase 2's loop while 4's stays actuated: 4 extends to its maximum
    served = 0
    while 4 in c.greens:
        c.step()
        served += 1
    assert served == 10 * paper_config.phases[4].max_green  # the maximum times from the conflicting call
    c.set_actuations(set())
    assert c.calls == frozenset()  # non-locking: the call goes with the vehicle


def test_128_detectors_are_served_in_16_status_groups(paper_toml: str) -> None:
    config = parse(paper_toml + "\n[detectors]\n4 = 4\n66 = 2\n128 = 6\n", "det.toml")
    c = Controller(config)
    mib = MibView(c)
    assert mib.get_many([MAX_VEHICLE_DETECTORS.instance(), MAX_VEHICLE_DETECTOR_STATUS_GROUPS.instance(),
                         VEHICLE_DETECTOR_CALL_PHASE.instance(128)]) == (128, 16, 6)
    mib.set_many([(DETECTOR_ACTUATION.instance(16), 0b1000_0000), (DETECTOR_ACTUATION.instance(9), 0b10)])
    assert c.actuations == frozenset({128, 66})
    assert mib.get_many([DETECTOR_STATUS_ACTIVE.instance(16), DETECTOR_STATUS_ACTIVE.instance(9)]) == (0b1000_0000, 2)
    c.step()
    assert c.calls == frozenset({2, 6})


def test_detector_objects_through_net_snmp(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        actuation, active = oid_str(DETECTOR_ACTUATION.instance(1)), oid_str(DETECTOR_STATUS_ACTIVE.instance(1))
        snmp("snmpset", served.port, actuation, "i", str(0b100))
        assert snmp("snmpget", served.port, active).strip().endswith("INTEGER: 4")
        table = snmp("snmpwalk", served.port, oid_str(VEHICLE_DETECTOR_CALL_PHASE.prefix))
        assert [line.rsplit(" ", 1)[-1] for line in table.strip().splitlines()] == [str(p) for p in range(1, 9)]
    finally:
        served.stop()


def test_detector_delay_and_extend_through_net_snmp(tmp_path: Path, paper_toml: str) -> None:
    config = tmp_path / "timed.toml"
    config.write_text(paper_toml + "\n[detectors]\n4 = { phase = 4, delay = 3.0, extend = 1.5 }\n")
    served = start_emulator(tmp_path / "serve.log", "--config", str(config))
    try:
        delay, extend = oid_str(VEHICLE_DETECTOR_DELAY.instance(4)), oid_str(VEHICLE_DETECTOR_EXTEND.instance(4))
        got = snmp("snmpget", served.port, delay, extend).strip().splitlines()
        assert [line.rsplit(" ", 1)[-1] for line in got] == ["30", "15"]  # tenths of a second
        snmp("snmpset", served.port, delay, "i", "55")
        assert snmp("snmpget", served.port, delay).strip().endswith("INTEGER: 55")
        table = snmp("snmpwalk", served.port, oid_str(VEHICLE_DETECTOR_EXTEND.prefix))
        assert [line.rsplit(" ", 1)[-1] for line in table.strip().splitlines()] == ["0", "0", "0", "15"]
    finally:
        served.stop()


@pytest.fixture(scope="module")
def actuated_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("actuated") / "run"
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--agent", "actuated", "--duration", "900",
                           "--no-progress", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "detector actuations  phase 1 " in done.stdout
    return out


def test_the_actuated_controller_serves_every_approach_with_greens_that_follow_demand(actuated_run: Path) -> None:
    records = list(read(actuated_run / "events.jsonl"))
    # The middleware only observes: no command was SET, the controller ran on its detectors.
    assert {r["purpose"] for r in records if r["kind"] == Kind.SET_SENT} <= {"startup", "keepalive", "clear"}
    assert any(r["kind"] == Kind.DETECTORS for r in records)
    greens: dict[int, list[float]] = {}
    started: dict[int, float] = {}
    shown: set[int] = set()
    for r in records:
        if r["kind"] == Kind.POLL:  # one record per change of the state seen
            now = set(r["greens"])
            started.update({p: r["t"] for p in now - shown})
            for p in shown - now:
                greens.setdefault(p, []).append(r["t"] - started[p])
            shown = now
    assert set(greens) == set(range(1, 9)), "every phase was served"
    for p in (2, 4, 6, 8):  # throughs: gapped out short and extended long, as demand came
        assert min(greens[p]) < 6.0 and max(greens[p]) > 9.0, (p, greens[p])
    summary = json.loads((actuated_run / "summary.json").read_text())
    assert set(summary["detector_actuations"]) == {str(p) for p in range(1, 9)}
    assert all(n > 0 for n in summary["detector_actuations"].values())
    assert summary["traffic"]["waiting_to_enter"] == 0


def test_the_detectors_table_maps_detectors_to_phases_and_is_read_over_ntcip(paper_toml: str) -> None:
    config = parse(paper_toml + "\n[detectors]\n1 = 2\n9 = 2\n4 = 4\n", "det.toml")
    assert config.detectors == {1: 2, 9: 2, 4: 4}
    mib = MibView(Controller(config))
    assert mib.get_many([VEHICLE_DETECTOR_CALL_PHASE.instance(9), MAX_VEHICLE_DETECTORS.instance()]) == (2, 9)
    mib.set_many([(DETECTOR_ACTUATION.instance(2), 0b1)])  # detector 9, in the second group of eight
    assert mib.controller.calls == frozenset({2})


@pytest.mark.parametrize(("table", "field", "allowed"), [
    ("[detectors]\n129 = 2", "detectors.129", "allowed: detector numbers 1-128"),
    ("[detectors]\n3 = 12", "detectors.3", "allowed: the configured phases 1, 2, 3, 4, 5, 6, 7, 8"),
    ("detectors = 3", "detectors", "must be a table"),
])
def test_a_bad_detectors_table_is_refused_naming_file_field_and_what_is_allowed(paper_toml: str, table: str,
                                                                               field: str, allowed: str) -> None:
    with pytest.raises(ConfigError) as info:
        # A table goes at the end; a plain key at the top, where it is not inside another table.
        parse(paper_toml + "\n" + table + "\n" if table.startswith("[") else table + "\n" + paper_toml, "det.toml")
    assert info.value.source == "det.toml" and info.value.field == field and allowed in info.value.message


PER_LANE = """
[detectors]
1 = 1
2 = { phase = 2, lane = "E2C_0" }
10 = { phase = 2, lane = "E2C_1" }
3 = 3
4 = 4
5 = 5
6 = 6
7 = 7
8 = 8
"""


def test_loops_per_lane_actuate_their_own_detector(paper_toml: str, tmp_path: Path) -> None:
    config = tmp_path / "lanes.toml"
    config.write_text(paper_toml + PER_LANE)
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--agent", "actuated", "--config", str(config),
                           "--duration", "300", "--no-progress", "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    active = [set(r["active"]) for r in read(tmp_path / "run" / "events.jsonl") if r["kind"] == Kind.DETECTORS]
    # The two through lanes of phase 2 have their own loops: each is seen actuated without the other.
    assert any(2 in a and 10 not in a for a in active) and any(10 in a and 2 not in a for a in active)


def test_a_loop_on_a_lane_its_phase_does_not_have_is_refused_in_one_line(paper_toml: str, tmp_path: Path) -> None:
    config = tmp_path / "wrong.toml"
    config.write_text(paper_toml + PER_LANE.replace('lane = "E2C_1"', 'lane = "N2C_0"'))
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--agent", "actuated", "--config", str(config),
                           "--duration", "60", "--no-progress", "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "detectors.10: lane 'N2C_0' is not an approach lane of phase 2; allowed: E2C_0, E2C_1" in done.stderr
    assert "Traceback" not in done.stderr
