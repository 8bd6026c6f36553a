"""Declarative fault scenarios: loading and refusing files, judging runs, and the shipped suite via the CLI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from harness.faults import FaultTarget, IndicationMonitor
from harness.scenarios import ScenarioError, default_suite, evaluate, load_scenario, parse_scenario, run_scenario
from hils.cli import main
from hils.events import Kind
from hils.testbed import run_spec

SUITE = default_suite()

LINK_DOWN = """
description = "link down"
duration = 60.0
seed = 1

[[faults]]
name = "link-down"
type = "drop"
start = 20.0
end = 35.0

[expect]
timeout = "communication"
detect_within = 5.2
recover_within = 0.1
"""


def test_the_shipped_suite_passes_through_the_cli(tmp_path, capsys):
    code = main(["faults", "run", "--report-dir", str(tmp_path), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "scenario" in out and "detection s" in out and "faults fired" in out
    report = json.loads((tmp_path / "faults.json").read_text())
    names = {s["scenario"] for s in report["scenarios"]}
    assert report["failed"] == 0 and report["passed"] == len(names) >= 18
    assert {"paper-communication-failure", "paper-transition-timeout", "paper-drift"} <= names
    for s in report["scenarios"]:
        assert s["faults"] and all(f["fired"] > 0 for f in s["faults"]), s["scenario"]
    md = (tmp_path / "faults.md").read_text()
    assert "| paper-drift | PASS |" in md


@pytest.mark.parametrize(("name", "reason", "detection"), [
    ("paper-communication-failure", "communication", 1.4),  # 5th lost poll: 4 periods + tau_udp
    ("paper-transition-timeout", "transition", 10.0),  # tau_trans after the dispatch
    ("paper-drift", "drift", 1.0),  # the 5th consecutive slow step of 0.25 s
])
def test_the_papers_three_errors_are_reproduced_with_its_parameters(name, reason, detection):
    scenario = load_scenario(SUITE / f"{name}.toml")
    params = scenario.config.middleware
    assert (params.poll_hz, params.tau_udp, params.tau_trans, params.n_timeout, params.n_drift) == (10, 1, 10, 5, 5)
    result = run_scenario(scenario)
    assert result.passed, [c.message for c in result.failures]
    assert [e.reason for e in result.episodes] == [reason]
    assert result.detection_s == pytest.approx(detection, abs=0.01)


def test_a_wrong_expectation_fails_saying_which_and_what_happened(tmp_path):
    path = tmp_path / "wrong.toml"
    path.write_text(LINK_DOWN.replace("detect_within = 5.2", "detect_within = 1.0"))
    result = run_scenario(load_scenario(path))
    assert not result.passed
    (failure,) = result.failures
    assert failure.expectation == "detect_within"
    assert "TIMEOUT within 1 s after fault 'link-down' first fired" in failure.message
    assert re.search(r"got TIMEOUT \(communication\) at 21\.4\d\d s, 1\.400 s after", failure.message)


def test_a_scenario_expecting_no_timeout_fails_when_one_happens(tmp_path, capsys):
    path = tmp_path / "ride.toml"
    path.write_text(LINK_DOWN.split("[expect]")[0] + '[expect]\ntimeout = "none"\n')
    code = main(["faults", "run", str(path), "--report-dir", str(tmp_path / "rep"), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 1
    assert re.search(r"FAIL ride: timeout: expected no TIMEOUT; got TIMEOUT: communication at 21\.4\d\d s", out)
    assert json.loads((tmp_path / "rep" / "faults.json").read_text())["failed"] == 1


def test_a_fault_that_never_fires_fails_the_scenario(tmp_path):
    path = tmp_path / "late.toml"
    path.write_text(LINK_DOWN.replace("start = 20.0\nend = 35.0", "start = 90.0").split("[expect]")[0])
    result = run_scenario(load_scenario(path))
    (failure,) = result.failures
    assert failure.expectation == "fault link-down fired"
    assert "never fired" in failure.message


def test_the_implicit_checks_catch_a_conflicting_command_and_a_lost_record():
    scenario = parse_scenario(LINK_DOWN, "link.toml")
    faults = scenario.build_faults()
    base = run_scenario(scenario)
    assert base.passed
    # Judge doctored records of a fresh run: one SET of conflicting phases, one record missing.
    monitors = []

    def factory(env, config, seed=0):
        target = FaultTarget(env, config, seed=seed, faults=faults)
        monitors.append(IndicationMonitor(env, target.controller, config))
        return target

    records = run_spec(scenario.spec(), target=factory).records
    sent = next(i for i, r in enumerate(records) if r["kind"] == Kind.SET_SENT)
    records[sent] = {**records[sent], "phases": frozenset({1, 7})}
    del records[sent + 1]
    result = evaluate(scenario, records, faults, monitors[0])
    failed = {c.expectation: c.message for c in result.failures}
    assert set(failed) == {"no_conflicting_command", "log_complete"}
    assert "phases [1, 7]" in failed["no_conflicting_command"]
    assert "seq not gapless" in failed["log_complete"]


def test_a_scenario_is_reproducible_from_its_seed():
    short = parse_scenario((SUITE / "loss-all-datagrams-hour.toml").read_text().replace("3600.0", "300.0"))

    def trace():
        result = run_scenario(short)
        return [(e.reason, e.entered) for e in result.episodes], [f.fired for f in result.faults]

    assert trace() == trace()


@pytest.mark.parametrize(("edit", "key", "message"), [
    (lambda t: "speed = 3\n" + t, "speed", "unknown key"),
    (lambda t: t.replace('type = "drop"', 'type = "drop"\nprobabilty = 0.5'), "faults[0].probabilty", "unknown key"),
    (lambda t: t.replace('type = "drop"', 'type = "drop"\nprobability = 2'), "faults[0].probability",
     "allowed: > 0 and <= 1"),
    (lambda t: t.replace('type = "drop"', 'type = "lose"'), "faults[0].type", "allowed: drop, delay"),
    (lambda t: t.replace("end = 35.0", "end = 10.0"), "faults[0].end", "allowed: > start"),
    (lambda t: t.replace("duration = 60.0", 'duration = "long"'), "duration", "must be a finite number"),
    (lambda t: t.replace('timeout = "communication"', 'timeout = "sometimes"'), "expect.timeout",
     "allowed: none, any, communication"),
    (lambda t: t.replace("recover_within = 0.1", "recover_in = 0.1"), "expect.recover_in", "unknown key"),
    (lambda t: t + '\n[middleware]\nn_timeout = 0\n', "middleware.n_timeout", "allowed: >= 1"),
    (lambda t: t + '\n[middleware]\nn_timout = 5\n', "middleware.n_timout", "unknown key"),
    (lambda t: t.replace('type = "drop"', 'type = "bad_actions"\naction = "conflict"').replace(
        "seed = 1", 'seed = 1\naction_type = "duration"'), "faults[0].action", "a duration agent cannot issue"),
    (lambda t: t.replace('type = "drop"', 'type = "snmp_error"\nstatus = "oops"'), "faults[0].status",
     "unknown SNMP error status"),
])
def test_a_bad_scenario_file_is_refused_naming_the_file_and_the_key(tmp_path, edit, key, message):
    path = tmp_path / "bad.toml"
    path.write_text(edit(LINK_DOWN))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.source == str(path)
    assert err.value.field == key
    assert message in str(err.value)


def test_the_cli_refuses_a_bad_file_with_its_name_and_key(tmp_path, capsys):
    path = tmp_path / "typo.toml"
    path.write_text(LINK_DOWN.replace("seed = 1", "sede = 1"))
    assert main(["faults", "run", str(path), "--report-dir", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "sede" in err and "unknown key" in err


def test_faults_list_prints_one_line_per_scenario(capsys):
    assert main(["faults", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    files = sorted(SUITE.glob("*.toml"))
    assert len(lines) == len(files)
    assert [line.split()[0] for line in lines] == [f.stem for f in files]


def test_a_config_path_is_resolved_beside_the_scenario(tmp_path, paper_toml):
    (tmp_path / "slow.toml").write_text(paper_toml.replace("n_timeout = 5 ", "n_timeout = 3 "))
    path = tmp_path / "s.toml"
    path.write_text('config = "slow.toml"\n' + LINK_DOWN)
    assert load_scenario(path).config.middleware.n_timeout == 3
    path.write_text('config = "missing.toml"\n' + LINK_DOWN)
    with pytest.raises(ScenarioError, match="config") as err:
        load_scenario(path)
    assert err.value.source == str(path) and "missing.toml" in str(err.value)


def test_the_suite_is_found_beside_the_harness_package():
    assert Path(__file__).resolve().parents[1] / "harness" / "fault_scenarios" == SUITE
    assert SUITE.is_dir()
