"""The middleware against the emulator in virtual time: an hour per action type, the paper's three errors."""

from __future__ import annotations

import math

import pytest

from harness.faults.inject import FaultTarget, StuckController, Window
from hils.control.actions import PAPER_ACTION_TYPES, ActionType
from hils.protocol import config as config_mod
from hils.protocol.ntcip import ControlColumn
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind
from hils.shell.fastpath import every_step

CFG = config_mod.load()
CLEARANCE = 5.0  # yellow 3 s + red clearance 2 s, every phase of the paper's intersection
POLL = 1.0 / CFG.middleware.poll_hz
GET_LATENCY = 0.002  # LocalTransport's default modeled GET response time
TICK = 0.1
# The emulator's own latency (calibrated on the paper's Cobalt): its call processing and status update.
CONTROLLER_LATENCY = (CFG.emulator.call_processing_ticks + CFG.emulator.status_update_ticks) * TICK


def _kinds(records, kind):
    return [r for r in records if r["kind"] == kind]



@pytest.mark.parametrize("action_type", PAPER_ACTION_TYPES)
def test_one_hour_every_transition_verified_within_clearance_plus_one_poll(action_type):
    result = run_spec(RunSpec(CFG, action_type, duration=3600.0, seed=3))
    records = result.records
    dispatched = _kinds(records, Kind.COMMAND_DISPATCHED)
    verified = _kinds(records, Kind.TRANSITION_VERIFIED)
    assert len(dispatched) > 150
    # The last command may still be in transition when the hour ends.
    assert len(verified) >= len(dispatched) - 1
    assert not _kinds(records, Kind.TIMEOUT_ENTERED)
    assert result.target.controller.flash_status.name == "NOT_FLASH"
    for r in _kinds(records, Kind.COMMAND_DISPATCHED):
        a, b = r["command"]
        assert CFG.compatible(a, b)
    # A hold is what is left of the previous green's minimum, then the clearance and the controller's
    # own latency, plus up to one controller tick to notice the call, one poll period and the GET's
    # response time. The previous green began within one poll (and a GET) before it was verified; the
    # start-up green at t = 0.
    min_green = CFG.phases[1].min_green
    verified_at = {r["command_id"]: r["t"] for r in verified}
    green_began = 0.0
    for cmd in dispatched:
        if cmd["command_id"] not in verified_at:
            continue
        hold = verified_at[cmd["command_id"]] - cmd["t"]
        early = max(0.0, green_began - POLL - GET_LATENCY + min_green - cmd["t"])
        late = max(0.0, green_began + min_green - cmd["t"])
        low = CLEARANCE + CONTROLLER_LATENCY + early
        assert low - 1e-6 <= hold <= low - early + late + TICK + POLL + GET_LATENCY + 1e-6, cmd
        green_began = verified_at[cmd["command_id"]]
    # Calls cleared at the end of the run (in the controller's database; its phase logic follows a tick later).
    assert result.target.unit.control[ControlColumn.VEH_CALL] == frozenset()


def test_one_hour_of_phase_control_steps_serves_every_target_and_clears_all_six_objects():
    """The omit-hold agent (CARMA Streets' way) for an hour: each step's target pair shows green, nothing times out,
    and the run's end leaves every control object at 0."""
    result = run_spec(RunSpec(CFG, ActionType.CONTROL, duration=3600.0, seed=3))
    records = result.records
    steps = _kinds(records, Kind.SCHEDULE_STARTED)
    assert len(steps) >= 300 and not _kinds(records, Kind.TIMEOUT_ENTERED)
    shown = {tuple(r["greens"]) for r in _kinds(records, Kind.POLL)}
    assert {(1, 5), (2, 6), (3, 7), (4, 8)} <= shown, "every pair of the sequence served"
    assert result.target.controller.flash_status.name == "NOT_FLASH"
    assert not any(result.target.unit.control.values())




def test_loss_of_n_timeout_polls_enters_timeout_and_recovery_resumes_service():
    def configure(run):
        def outage():
            yield run.env.timeout(100.0)
            run.transport.loss = 1.0
            yield run.env.timeout(7.0)
            run.transport.loss = 0.0
        run.env.process(outage())

    result = run_spec(RunSpec(CFG, ActionType.SWITCH, duration=300.0, seed=1, recover_after=5.0),
                         configure=configure)
    records = result.records
    (timeout,) = _kinds(records, Kind.TIMEOUT_ENTERED)
    assert timeout["reason"] == "communication"
    failed = [r for r in _kinds(records, Kind.POLL_FAILED) if r["t"] <= timeout["t"]]
    assert [r["consecutive"] for r in failed[-CFG.middleware.n_timeout:]] == [1, 2, 3, 4, 5]
    # n_timeout polls on the poll grid, each failing tau_udp after it went out: detection (n_timeout - 1)
    # periods + tau_udp after the first lost poll, which goes out within one period of the loss.
    n = CFG.middleware.n_timeout
    assert 100.0 + (n - 1) * POLL + CFG.middleware.tau_udp <= timeout["t"]
    assert timeout["t"] <= 100.0 + n * POLL + CFG.middleware.tau_udp + 1e-6
    # Polling and command sending halt during TIMEOUT.
    polls_during = [r for r in records if r["kind"] in (Kind.POLL, Kind.POLL_FAILED, Kind.SET_SENT)
                    and timeout["t"] < r["t"] < timeout["t"] + 5.0]
    assert polls_during == []
    (recovered,) = _kinds(records, Kind.RECOVERED)
    # The first recovery attempt comes recover_after (5 s) later; while the outage lasts it fails and is retried.
    assert timeout["t"] + 5.0 <= recovered["t"] <= 107.0 + 5.0 + 2 * CFG.middleware.tau_udp
    after = [r for r in _kinds(records, Kind.TRANSITION_VERIFIED) if r["t"] > recovered["t"]]
    assert len(after) > 10


def test_transition_never_seen_enters_timeout_after_tau_trans():
    # From 50 s the controller acknowledges calls and ignores them: a transition that never comes.
    stuck = StuckController("stuck", window=Window(50.0, math.inf))
    result = run_spec(RunSpec(CFG, ActionType.SWITCH, duration=120.0, seed=1, recover_after=None),
                      target=lambda env, cfg, **run: FaultTarget(env, cfg, **run, faults=[stuck]))
    records = result.records
    (timeout,) = _kinds(records, Kind.TIMEOUT_ENTERED)
    assert timeout["reason"] == "transition"
    cmd = next(r for r in _kinds(records, Kind.COMMAND_DISPATCHED) if r["command_id"] == timeout["command_id"])
    assert timeout["t"] - cmd["t"] == pytest.approx(CFG.middleware.tau_trans)
    ended = [r for r in _kinds(records, Kind.HOLD_RELEASED) if r["command_id"] == cmd["command_id"]]
    assert [r["reason"] for r in ended] == ["timeout"]
    # Without recovery the manager stays in TIMEOUT: later actions are dropped, nothing is sent.
    later = [r for r in records if r["t"] > timeout["t"]]
    assert {r["kind"] for r in later} <= {Kind.ACTION_RECEIVED, Kind.ACTION_CONVERTED, Kind.ACTION_DROPPED,
                                          Kind.SET_SENT, Kind.SET_ANSWERED, Kind.RUN_ENDED, Kind.DRIFT}
    assert all(r["purpose"] == "clear" for r in later if r["kind"] == Kind.SET_SENT)
    assert _kinds(later, Kind.ACTION_DROPPED)


def test_n_drift_consecutive_slow_steps_enter_timeout_and_isolated_ones_do_not():
    step = CFG.middleware.sumo_step

    def slow_steps(slow):
        def configure(run):
            count = iter(range(10**9))

            def cost(fn):
                fn()
                return 2 * step if next(count) in slow else 0.0
            run.step_cost = every_step(cost)
        return configure

    isolated = run_spec(RunSpec(CFG, ActionType.SWITCH, duration=60.0, seed=1),
                           configure=slow_steps({40, 42, 44, 46, 48, 50, 52, 54}))
    assert len(_kinds(isolated.records, Kind.DRIFT)) == 8
    assert not _kinds(isolated.records, Kind.TIMEOUT_ENTERED)

    five = run_spec(RunSpec(CFG, ActionType.SWITCH, duration=60.0, seed=1),
                       configure=slow_steps({40, 41, 42, 43, 44}))
    (timeout,) = _kinds(five.records, Kind.TIMEOUT_ENTERED)
    assert timeout["reason"] == "drift"
    assert timeout["t"] == pytest.approx(44 * step)
    (recovered,) = _kinds(five.records, Kind.RECOVERED)
    assert any(r["t"] > recovered["t"] for r in _kinds(five.records, Kind.TRANSITION_VERIFIED))


def test_same_seed_same_log_apart_from_wall_clock():
    def strip(records):
        return [{k: v for k, v in r.items() if k != "wall_ns"} for r in records]

    a = run_spec(RunSpec(CFG, ActionType.SELECTION, duration=600.0, seed=7))
    b = run_spec(RunSpec(CFG, ActionType.SELECTION, duration=600.0, seed=7))
    c = run_spec(RunSpec(CFG, ActionType.SELECTION, duration=600.0, seed=8))
    assert strip(a.records) == strip(b.records)
    assert strip(a.records) != strip(c.records)
