"""Declarative fault scenarios: loading and refusing files, judging runs, and the shipped suite via the CLI."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest
import simpy

from harness.faults.inject import FaultTarget, IndicationMonitor
from harness.faults.judge import evaluate
from harness.faults.reader import default_suite, load_fault_scenario, parse_fault_scenario
from harness.faults.runner import run_fault_scenario
from harness.faults.table import FaultScenarioError
from hils.cli.main import main
from hils.protocol.ntcip import ControlColumn, UnitControlStatus, UnitFlashStatus
from hils.run.testbed import run_spec
from hils.shell.events import Kind
from hils.shell.events import read as read_events
from hils.sim.network import TLS_ID

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


SEEDS = (1, 1001, 2002)


@pytest.mark.slow
def test_the_shipped_suite_passes_at_every_seed_through_the_cli(tmp_path, capsys):
    """Every scenario's expectations hold at three seeds (its faults', emulator's and agent's draws replaced),
    burst-loss's too: each burst of lost polls is a TIMEOUT however the polls' answers and failures interleave."""
    code = main(["faults", "run", "--seeds", ",".join(map(str, SEEDS)), "--out", str(tmp_path),
                 "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "scenario" in out and "seed" in out and "detection s" in out and "faults fired" in out
    report = json.loads((tmp_path / "faults.json").read_text())
    runs = {(s["scenario"], s["seed"]) for s in report["scenarios"]}
    names = {name for name, _ in runs}
    assert runs == {(name, seed) for name in names for seed in SEEDS}
    assert report["failed"] == 0 and report["passed"] == len(runs) and len(names) >= 18
    assert {"paper-communication-failure", "paper-transition-timeout", "paper-drift", "burst-loss"} <= names
    for s in report["scenarios"]:
        assert s["faults"] and all(f["fired"] > 0 for f in s["faults"]), s["scenario"]
    bursts = [s for s in report["scenarios"] if s["scenario"] == "burst-loss"]
    for s in bursts:
        lost = s["faults"][0]["details"]["requests_lost"]
        assert len(s["timeouts"]) >= lost // 8 - 3 > 5, (s["seed"], len(s["timeouts"]), lost)
    md = (tmp_path / "faults.md").read_text()
    assert "| paper-drift | 1001 | PASS |" in md and "## burst-loss (seed 2002): PASS" in md
    # A scenario of several controllers reports each intersection's outcome.
    link = next(s for s in report["scenarios"] if s["scenario"] == "corridor-link-down" and s["seed"] == 1)
    assert [(o["intersection"], o["timeouts"]) for o in link["intersections"]] == [
        ("J1", []), ("J2", ["communication"]), ("J3", []), ("J4", [])]
    assert "| corridor-link-down | 1 | PASS | 1.400 | 0.010 | 1 at J2 | j2-link-down at J2 x" in md
    assert "| J2 | PASS | j2-link-down | communication | 1.400 | 0.010 | 3 | 36.6 (10.0-46.7) |" in md


@pytest.mark.parametrize(("name", "reason", "detection"), [
    ("paper-communication-failure", "communication", 1.4),  # 5th lost poll: 4 periods + tau_udp
    ("paper-transition-timeout", "transition", 10.0),  # tau_trans after the dispatch
    ("paper-drift", "drift", 1.0),  # the 5th consecutive slow step of 0.25 s
])
def test_the_papers_three_errors_are_reproduced_with_its_parameters(name, reason, detection):
    scenario = load_fault_scenario(SUITE / f"{name}.toml")
    params = scenario.config.middleware
    assert (params.poll_hz, params.tau_udp, params.tau_trans, params.n_timeout, params.n_drift) == (10, 1, 10, 5, 5)
    result = run_fault_scenario(scenario)
    assert result.passed, [c.message for c in result.failures]
    assert [e.reason for e in result.episodes] == [reason]
    assert result.detection_s == pytest.approx(detection, abs=0.01)


def test_a_wrong_expectation_fails_saying_which_and_what_happened(tmp_path):
    path = tmp_path / "wrong.toml"
    path.write_text(LINK_DOWN.replace("detect_within = 5.2", "detect_within = 1.0"))
    result = run_fault_scenario(load_fault_scenario(path))
    assert not result.passed
    (failure,) = result.failures
    assert failure.expectation == "detect_within"
    assert "TIMEOUT within 1 s after fault 'link-down' first fired" in failure.message
    assert re.search(r"got TIMEOUT \(communication\) at 21\.4\d\d s, 1\.400 s after", failure.message)


def test_a_scenario_expecting_no_timeout_fails_when_one_happens(tmp_path, capsys):
    path = tmp_path / "ride.toml"
    path.write_text(LINK_DOWN.split("[expect]")[0] + '[expect]\ntimeout = "none"\n')
    code = main(["faults", "run", str(path), "--out", str(tmp_path / "rep"), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 1
    assert re.search(r"FAIL ride \(seed \d+\): timeout: expected no TIMEOUT; got TIMEOUT: communication at "
                     r"21\.4\d\d s", out)
    assert json.loads((tmp_path / "rep" / "faults.json").read_text())["failed"] == 1


def test_a_fault_that_never_fires_fails_the_scenario(tmp_path):
    path = tmp_path / "late.toml"
    path.write_text(LINK_DOWN.replace("start = 20.0\nend = 35.0", "start = 90.0").split("[expect]")[0])
    result = run_fault_scenario(load_fault_scenario(path))
    (failure,) = result.failures
    assert failure.expectation == "fault link-down fired"
    assert "never fired" in failure.message


def test_the_implicit_checks_catch_a_conflicting_command_and_a_lost_record():
    scenario = parse_fault_scenario(LINK_DOWN, "link.toml")
    faults = scenario.build_faults()
    base = run_fault_scenario(scenario)
    assert base.passed
    # Judge doctored records of a fresh run: one SET of conflicting phases, one record missing.
    monitors = []

    def factory(env, config, *, seed, fast_path, hires):
        target = FaultTarget(env, config, seed=seed, faults=faults, fast_path=fast_path, hires=hires)
        monitors.append(IndicationMonitor(env, target.controller, config))
        return target

    records = run_spec(scenario.spec(), target=factory).records
    sent = next(i for i, r in enumerate(records) if r["kind"] == Kind.SET_SENT)
    records[sent] = {**records[sent], "phases": frozenset({1, 7})}
    del records[sent + 1]
    result = evaluate(scenario, records, faults, {TLS_ID: monitors[0]})
    failed = {c.expectation: c.message for c in result.failures}
    assert set(failed) == {"no_conflicting_command", "log_complete"}
    assert "phases [1, 7]" in failed["no_conflicting_command"]
    assert "seq not gapless" in failed["log_complete"]


def test_the_judge_names_an_overlap_shown_beside_a_phase_it_conflicts_with(city_config):
    scenario = parse_fault_scenario(LINK_DOWN, "link.toml")
    faults = scenario.build_faults()

    def factory(env, config, *, seed, fast_path, hires):
        return FaultTarget(env, config, seed=seed, faults=faults, fast_path=fast_path, hires=hires)

    records = run_spec(scenario.spec(), target=factory).records
    # A controller showing the city's right-turn overlap A (with 8 and 5) beside 6, which runs beside neither.
    env = simpy.Environment()
    shown = SimpleNamespace(greens=frozenset({2, 6}), yellows=frozenset(), overlap_greens=frozenset({1}),
                            overlap_yellows=frozenset(), flash_status=UnitFlashStatus.NOT_FLASH,
                            control_status=UnitControlStatus.SYSTEM_CONTROL,
                            control={c: frozenset() for c in ControlColumn})
    monitor = IndicationMonitor(env, shown, city_config)
    env.run(until=0.2)
    result = evaluate(scenario, records, faults, {TLS_ID: monitor})
    failed = {c.expectation: c.message for c in result.failures}
    assert set(failed) == {"no_conflicting_indication"}
    assert "got: overlap A and phase 6 at 0.050 s; overlap A and phase 6 at 0.150 s" in failed[
        "no_conflicting_indication"]


def test_a_scenario_is_reproducible_from_its_seed():
    short = parse_fault_scenario((SUITE / "loss-all-datagrams-hour.toml").read_text().replace("3600.0", "300.0"))

    def trace():
        result = run_fault_scenario(short)
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
    (lambda t: t.replace("seed = 1", 'seed = 1\naction_type = "control"\n[[schedule]]\ncommandType = "hold"\n'
                                       'commandPhase = 2\ncommandStartTime = 0\ncommandEndTime = 9\n[[schedule]]\n'
                                       'commandType = "forceoff"\ncommandPhase = 2\ncommandStartTime = 5\n'
                                       'commandEndTime = 6\n'), "schedule", "phase 2 is held and forced off at once"),
    (lambda t: t.replace("recover_within = 0.1", "recover_within = 0.1\nheld_as_scheduled_from = 5.0"),
     "expect.held_as_scheduled_from", "needs a [[schedule]]"),
    (lambda t: t.replace('type = "drop"', 'type = "preempt"\nhold = 5.0').replace("end = 35.0", ""),
     "faults[0].preempt", "is 1, which the config 'paper four-leg intersection' has not; allowed: its [preempts] "
     "(none)"),
])
def test_a_bad_scenario_file_is_refused_naming_the_file_and_the_key(tmp_path, edit, key, message):
    path = tmp_path / "bad.toml"
    path.write_text(edit(LINK_DOWN))
    with pytest.raises(FaultScenarioError) as err:
        load_fault_scenario(path)
    assert err.value.source == str(path)
    assert err.value.field == key
    assert message in str(err.value)


def test_the_cli_refuses_a_bad_file_with_its_name_and_key(tmp_path, capsys):
    path = tmp_path / "typo.toml"
    path.write_text(LINK_DOWN.replace("seed = 1", "sede = 1"))
    assert main(["faults", "run", str(path), "--out", str(tmp_path), "--no-progress"]) == 2
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
    assert load_fault_scenario(path).config.middleware.n_timeout == 3
    path.write_text('config = "missing.toml"\n' + LINK_DOWN)
    with pytest.raises(FaultScenarioError, match="config") as err:
        load_fault_scenario(path)
    assert err.value.source == str(path) and "missing.toml" in str(err.value)


def test_the_suite_is_found_beside_the_harness_package():
    assert Path(__file__).resolve().parents[3] / "fault_scenarios" == SUITE
    assert SUITE.is_dir()


# --- scenarios of several controllers ---------------------------------------------------------------------------

CORRIDOR_LINK_DOWN = (SUITE / "corridor-link-down.toml").read_text()
OTHERS = ("J1", "J3", "J4")


@pytest.mark.parametrize(("name", "reason"), [
    ("corridor-link-down", "communication"),
    ("corridor-controller-reboot", "communication"),
    ("corridor-stuck-controller", "transition"),
])
def test_a_fault_on_one_corridor_controller_times_out_that_one_alone(name, reason):
    result = run_fault_scenario(load_fault_scenario(SUITE / f"{name}.toml"))
    assert result.passed, [(c.label, c.message) for c in result.failures]
    assert [(e.intersection, e.reason) for e in result.episodes] == [("J2", reason)]
    assert all(e.recovered is not None for e in result.episodes)
    outcomes = {o.intersection: o for o in result.outcomes}
    assert list(outcomes) == ["J1", "J2", "J3", "J4"]
    for tls in OTHERS:
        assert outcomes[tls].episodes == () and outcomes[tls].faults == ()
        assert {c.expectation for c in result.checks if c.intersection == tls} >= {"timeout", "verified_every"}
    assert {c.intersection for c in result.checks} == {"J1", "J2", "J3", "J4"}


def _verified(records, tls):
    return [(r["t"], tuple(r["command"])) for r in records
            if r["kind"] == Kind.TRANSITION_VERIFIED and r["intersection"] == tls]


def test_while_one_corridor_link_is_down_the_others_go_on_verifying_the_same_transitions(tmp_path):
    faulted, baseline = tmp_path / "faulted.jsonl", tmp_path / "baseline.jsonl"
    assert run_fault_scenario(parse_fault_scenario(CORRIDOR_LINK_DOWN), log_path=faulted).passed
    # The same run with J2's link whole: the fault's window opens after the run has ended.
    run_fault_scenario(parse_fault_scenario(CORRIDOR_LINK_DOWN.replace("start = 20.0\nend = 35.0", "start = 100.0")),
                 log_path=baseline)
    records, clean = list(read_events(faulted)), list(read_events(baseline))
    assert {r["intersection"] for r in records if r["kind"] in (Kind.TIMEOUT_ENTERED, Kind.POLL_FAILED)} == {"J2"}
    assert not [r for r in clean if r["kind"] == Kind.TIMEOUT_ENTERED]
    for tls in OTHERS:
        verified = _verified(records, tls)
        # Throughout the fault's window [20, 35) s: no stretch longer than the fixed cycle's own without one.
        times = [20.0, *(t for t, _ in verified if 20.0 < t < 35.0), 35.0]
        assert len(times) > 2 and max(b - a for a, b in itertools.pairwise(times)) < 15.2, (tls, verified)
        # The same pairs, in the same order, as with J2's link whole (J2's TIMEOUT is a decision point of the
        # run, so the others' later decisions come 1.4 s later than without it).
        assert [c for _, c in verified] == [c for _, c in _verified(clean, tls)], tls
    assert not [t for t, _ in _verified(records, "J2") if 20.0 <= t < 35.0]
    assert len(_verified(records, "J2")) < len(_verified(clean, "J2"))


def test_a_corridor_fault_on_the_wrong_controller_fails_at_both_intersections(tmp_path, capsys):
    path = tmp_path / "moved.toml"
    path.write_text(CORRIDOR_LINK_DOWN.replace('intersection = "J2"', 'intersection = "J3"'))
    assert main(["faults", "run", str(path), "--out", str(tmp_path / "rep"), "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert re.search(r"FAIL moved \(seed 1\): \[J3\] timeout: expected no TIMEOUT; got TIMEOUT: communication "
                     r"at 21\.4\d\d s", out)
    assert re.search(r"FAIL moved \(seed 1\): \[J3\] verified_every: expected a transition verified at least every "
                     r"16 s \(3 verified\); got 36\.\d{3} s without one", out)
    assert "FAIL moved (seed 1): [J2] timeout: expected TIMEOUT because of communication; got: none" in out
    report = json.loads((tmp_path / "rep" / "faults.json").read_text())["scenarios"][0]
    assert [(o["intersection"], o["passed"], o["timeouts"]) for o in report["intersections"]] == [
        ("J1", True, []), ("J2", False, []), ("J3", False, ["communication"]), ("J4", True, [])]
    md = (tmp_path / "rep" / "faults.md").read_text()
    assert "| J3 | FAIL | j2-link-down | communication |" in md


def test_agent_faults_act_on_their_intersection_and_slow_steps_on_every_one():
    scenario = parse_fault_scenario("""
scenario = "corridor"
action_type = "switch"
duration = 30.0
seed = 1

[[faults]]
name = "too-far"
type = "bad_actions"
intersection = "J3"
action = "out_of_range"
start = 5.0
count = 2

[[faults]]
name = "slow-sumo"
type = "slow_steps"
start = 20.0
count = 5
consecutive = 5
cost = 0.4

[expect]
timeout = "drift"
timeouts = 1
detect_within = 1.01
refused = 0

[expect.J3]
timeout = "drift"
refused = 2
refused_reason = "wrong_type"
""")
    result = run_fault_scenario(scenario)
    assert result.passed, [(c.label, c.message) for c in result.failures]
    assert [(e.intersection, e.reason) for e in result.episodes] == [(tls, "drift") for tls in scenario.intersections]
    assert {o.intersection: o.faults for o in result.outcomes}["J3"] == ("too-far", "slow-sumo")
    assert [f.intersection for f in result.faults] == ["J3", None]


CORRIDOR_MINIMAL = """
scenario = "corridor"
duration = 60.0

[[faults]]
name = "link"
type = "drop"
intersection = "J2"
start = 20.0

[[faults]]
name = "other"
type = "stuck"
intersection = "J3"
start = 20.0

[expect.J2]
timeout = "communication"
"""


@pytest.mark.parametrize(("edit", "key", "message"), [
    (lambda t: t.replace('intersection = "J2"\n', ""), "faults[0].intersection",
     "is required with several controllers; allowed: J1, J2, J3, J4"),
    (lambda t: t.replace('intersection = "J2"', 'intersection = "J9"'), "faults[0].intersection",
     "is 'J9'; allowed: J1, J2, J3, J4"),
    (lambda t: t + '\n[[faults]]\ntype = "slow_steps"\nintersection = "J2"\ncount = 1\ncost = 1.0\n',
     "faults[2].intersection", "not allowed: slow_steps acts on the one simulation"),
    (lambda t: t + '\n[expect.J9]\ntimeout = "none"\n', "expect.J9", "unknown key; allowed: timeout, "),
    (lambda t: t.replace("[expect.J2]", "[expect]\nJ2 = 3\n[expect.J1]"), "expect.J2", "must be a table"),
    (lambda t: t + 'timout = "none"\n', "expect.J2.timout", "unknown key"),
    (lambda t: t + "recovered_greens = [2, 9]\n", "expect.J2.recovered_greens", "has 9; allowed: 1, 2, 3"),
    (lambda t: t + 'recovered_greens = "startup"\n', "expect.J2.recovered_greens", "list of phase numbers"),
    (lambda t: t + 'after_fault = "other"\n', "expect.J2.after_fault", "is 'other'; allowed: link"),
    (lambda t: t.replace('timeout = "communication"', "recovered_greens = [2, 6]"),
     "expect.J2.recovered_greens", "needs expect.timeout"),
    (lambda t: t + "verified_every = 0\n", "expect.J2.verified_every", "allowed: > 0"),
    (lambda t: 'config = "x.toml"\n' + t, "scenario", "not both"),
    (lambda t: t.replace('"corridor"', '"corridr"'), "scenario", "no shipped scenario of that name"),
    (lambda t: t.replace('"corridor"', '"missing.scenario.toml"'), "scenario", "missing.scenario.toml"),
])
def test_a_bad_scenario_of_several_controllers_is_refused_naming_the_file_and_the_key(tmp_path, edit, key, message):
    path = tmp_path / "bad.toml"
    path.write_text(edit(CORRIDOR_MINIMAL))
    with pytest.raises(FaultScenarioError) as err:
        load_fault_scenario(path)
    assert (err.value.source, err.value.field) == (str(path), key)
    assert message in str(err.value)


def test_a_scenario_of_several_controllers_takes_the_middleware_overrides_in_each(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(CORRIDOR_MINIMAL + "\n[middleware]\nn_timeout = 3\n")
    scenario = load_fault_scenario(path)
    assert scenario.several and list(scenario.intersections) == ["J1", "J2", "J3", "J4"]
    assert {cfg.middleware.n_timeout for cfg in scenario.intersections.values()} == {3}
    assert scenario.network.intersections == scenario.intersections  # what the run is built from
    assert (scenario.expectations("J2").timeout, scenario.expectations("J1").timeout) == (("communication",), ("none",))


def test_a_scenario_of_several_controllers_is_read_from_a_file_beside_the_fault_scenario(tmp_path):
    data = Path(__file__).resolve().parents[3] / "hils" / "data"
    (tmp_path / "pair.scenario.toml").write_text(
        f'sumocfg = "{data / "corridor.sumocfg"}"\n[intersections]\n'
        f'A = "{data / "corridor_arterial.toml"}"\nB = "{data / "corridor_crossroad.toml"}"\n')
    path = tmp_path / "s.toml"
    path.write_text(CORRIDOR_MINIMAL.replace('"corridor"', '"pair.scenario.toml"').replace('"J2"', '"A"').replace(
        '"J3"', '"B"').replace("[expect.J2]", "[expect.A]"))
    scenario = load_fault_scenario(path)
    assert list(scenario.intersections) == ["A", "B"]
    assert [f.intersection for f in scenario.faults] == ["A", "B"]
    assert scenario.expectations("A").timeout == ("communication",)
    assert "faults: drop at A, stuck at B" in scenario.summary()


def test_a_preempt_during_a_commanded_transition_is_judged_preempted_and_its_breaches_fail():
    scenario = load_fault_scenario(SUITE / "controller-preempted-mid-transition.toml")
    faults = scenario.build_faults()
    monitors = []

    def factory(env, config, *, seed, fast_path, hires):
        target = FaultTarget(env, config, seed=seed, faults=faults, fast_path=fast_path, hires=hires)
        monitors.append(IndicationMonitor(env, target.controller, config))
        return target

    def configure(tb):
        for fault in faults:
            fault.on_run(tb, tb.intersection)

    records = run_spec(scenario.spec(), target=factory, configure=configure).records
    result = evaluate(scenario, records, faults, {TLS_ID: monitors[0]})
    assert result.passed, [c.message for c in result.failures]
    (began,) = [r for r in records if r["kind"] == Kind.PREEMPT_BEGIN]
    assert began["command_id"] is not None, "the preempt came during a commanded transition"
    # A command sent while preempted, and a preemption that never ends, each fail the check, saying what happened.
    at = next(i for i, r in enumerate(records) if r["kind"] == Kind.PREEMPT_BEGIN)
    sent = {**records[at + 1], "kind": Kind.SET_SENT.value, "purpose": "command", "phases": [1, 5], "command_id": 9}
    doctored = [*records[:at + 1], sent, *(r for r in records[at + 1:] if r["kind"] != Kind.PREEMPT_END)]
    failed = {c.expectation: c.message for c in evaluate(scenario, doctored, faults, {TLS_ID: monitors[0]}).failures}
    assert "preemptions" in failed
    assert re.search(r"the preemption at 20\.\d+ s never ended; the preemption at 20\.\d+ s sent command SET at",
                     failed["preemptions"])


def test_a_schedule_through_a_link_outage_is_re_established_after_the_backup_reset():
    scenario = load_fault_scenario(SUITE / "schedule-through-link-outage.toml")
    result = run_fault_scenario(scenario)
    assert result.passed, [f.message for f in result.failures]


def test_a_schedule_not_re_established_after_the_backup_reset_fails(monkeypatch):
    """Planted: the recovery SETs every object to 0 and nothing after (re-establishing broken): the scenario fails."""
    from hils.control import manager as manager_mod
    from hils.control.phase_control import no_controls

    real_set, real_recovered = manager_mod.Manager._recovery_set, manager_mod.Manager._recovered

    def recovery_set_nothing(self, ev, out):
        self._sync(ev.greens)
        self._recovering_greens = ev.greens
        self._send_controls(no_controls(), manager_mod.Purpose.RECOVERY, ev.t, out)

    def recovered_without_changes(self, ev, out):
        running, self.running = self.running, None
        real_recovered(self, ev, out)
        self.running = running

    for key, (target, handler) in list(manager_mod._TRANSITIONS.items()):
        planted = {real_set: recovery_set_nothing, real_recovered: recovered_without_changes}.get(handler)
        if planted is not None:
            monkeypatch.setitem(manager_mod._TRANSITIONS, key, (target, planted))
    result = run_fault_scenario(load_fault_scenario(SUITE / "schedule-through-link-outage.toml"))
    assert "held_as_scheduled_from" in [f.expectation for f in result.failures]
