"""The middleware's behaviour in virtual time against the in-process emulator."""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import pairwise
from typing import Any

import pytest
import simpy

from emulator.inprocess import VirtualTarget
from emulator.model.inputs import Reader
from hils.control.actions import ActionType
from hils.control.manager import CLEAR_ATTEMPTS, State
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn, UnitControlStatus, control_oid
from hils.run.testbed import RunSpec, Testbed, run_spec
from hils.shell.events import Kind
from hils.shell.middleware import READBACK_PERIOD
from hils.shell.transport import CommunicationTimeout, LocalTransport


class Rig:
    """A Testbed against the in-process emulator, started and settled, driven action by action."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.SELECTION,
                 *, start_at: float = 5.0) -> None:
        self.tb = Testbed(config, action_type=action_type, seed=0, recover_after=None)
        self.tb.reset()
        self.env, self.target, self.log, self.mw = self.tb.env, self.tb.target, self.tb.events, self.tb.middleware
        # By start_at the start-up pair (2, 6) has served its minimum green, so transitions take
        # exactly yellow + red clearance.
        self.tb.run_for(start_at - self.env.now)

    def submit(self, value: Any) -> int:
        """Hand an action to the middleware at once (no decision point); returns its action id."""
        return self.mw.submit(value).action_id

    def run(self, seconds: float) -> None:
        self.tb.run_for(seconds)

    @property
    def controller(self) -> Any:
        return self.target.controller

    @property
    def veh_call(self) -> frozenset[int]:
        # As the NTCIP database holds it: the phase logic takes a SET one tick of call processing later.
        return self.target.unit.control[ControlColumn.VEH_CALL]

    def sets(self, purpose: str | None = None) -> list[dict[str, Any]]:
        """The SETs since start-up (whose one SET clears the control objects)."""
        return [r for r in self.log.of(Kind.SET_SENT)
                if r["purpose"] != "startup" and (purpose is None or r["purpose"] == purpose)]

    def kinds(self, kind: Kind) -> list[dict[str, Any]]:
        return self.log.of(kind)


@pytest.mark.parametrize(("action_type", "value", "error", "reason"), [
    (ActionType.SELECTION, (1, 2), "ConflictError", "conflict"),
    (ActionType.SELECTION, (1, 9), "UnknownPhaseError", "unknown_phase"),
    (ActionType.SELECTION, (1, 6), "NotInActionSetError", "not_in_action_set"),
    (ActionType.SELECTION, "15", "ActionTypeError", "wrong_type"),
    (ActionType.SWITCH, 2, "ActionTypeError", "wrong_type"),
    (ActionType.DURATION, float("nan"), "DurationRangeError", "duration_out_of_range"),
    (ActionType.DURATION, 1.1, "DurationRangeError", "duration_out_of_range"),
])
def test_refused_action_is_logged_and_nothing_is_sent(paper_config, action_type, value, error, reason) -> None:
    rig = Rig(paper_config, action_type)
    action_id = rig.submit(value)
    rig.run(30.0)
    (refused,) = rig.kinds(Kind.ACTION_REFUSED)
    assert refused["action_id"] == action_id
    assert (refused["error"], refused["reason"]) == (error, reason)
    assert refused["message"]
    # Nothing of the refused action was sent: only the start-up SET, and the keepalive holding the empty call.
    assert {r["purpose"] for r in rig.sets()} <= {"keepalive"} and all(not r["phases"] for r in rig.sets())
    assert rig.target.mib.set_count == 1 + len(rig.sets())
    assert rig.veh_call == frozenset()
    assert rig.kinds(Kind.ACTION_CONVERTED) == rig.kinds(Kind.COMMAND_DISPATCHED) == []
    assert rig.mw.state is State.IDLE
    assert rig.controller.greens == frozenset({2, 6})


def test_a_valid_action_after_a_refused_one_is_served(paper_config) -> None:
    rig = Rig(paper_config)
    rig.submit((1, 7))
    rig.submit((4, 8))
    rig.run(8.0)
    assert [r["phases"] for r in rig.sets("command")] == [frozenset({4, 8})]
    assert rig.veh_call == frozenset({4, 8})
    assert rig.controller.greens == frozenset({4, 8})


def test_actions_while_on_hold_are_dropped(paper_config) -> None:
    rig = Rig(paper_config)
    first = rig.submit((3, 7))
    assert rig.mw.state is State.ON_HOLD
    rig.run(1.0)
    second = rig.submit((4, 8))
    third = rig.submit((1, 5))
    rig.run(10.0)
    dropped = rig.kinds(Kind.ACTION_DROPPED)
    assert [(r["action_id"], r["state"]) for r in dropped] == [(second, "on_hold"), (third, "on_hold")]
    assert [r["action_id"] for r in rig.kinds(Kind.COMMAND_DISPATCHED)] == [first]
    assert [r["phases"] for r in rig.sets("command")] == [frozenset({3, 7})]
    assert rig.veh_call == frozenset({3, 7})
    assert rig.controller.greens == frozenset({3, 7})
    assert rig.mw.state is State.IDLE


def test_actions_while_in_timeout_are_dropped(paper_config) -> None:
    rig = Rig(paper_config)
    step = paper_config.middleware.sumo_step
    for _ in range(paper_config.middleware.n_drift):
        rig.mw.observe_step(step, step * 2)
    assert rig.mw.state is State.TIMEOUT
    action_id = rig.submit((3, 7))
    rig.run(5.0)
    assert [(r["action_id"], r["state"]) for r in rig.kinds(Kind.ACTION_DROPPED)] == [(action_id, "timeout")]
    assert rig.sets() == []
    assert rig.veh_call == frozenset()


@pytest.mark.parametrize(("action_type", "value"), [(ActionType.SWITCH, 0), (ActionType.SELECTION, (2, 6)),
                                                    (ActionType.SELECTION, [6, 2])])
def test_keep_completes_at_once_without_a_set(paper_config, action_type, value) -> None:
    rig = Rig(paper_config, action_type)
    rig.submit(value)
    (released,) = rig.kinds(Kind.HOLD_RELEASED)
    assert released["reason"] == "keep" and released["hold_s"] == 0.0
    assert released["t"] == rig.env.now
    assert rig.mw.state is State.IDLE
    rig.run(1.0)
    assert rig.sets() == [] and rig.target.mib.set_count == 1
    assert rig.kinds(Kind.COMMAND_DISPATCHED) == []
    assert [r["to"] for r in rig.kinds(Kind.STATE)] == []


def test_switch_advances_the_controller_around_the_sequence(paper_config) -> None:
    rig = Rig(paper_config, ActionType.SWITCH)
    shown = []
    for _ in range(5):
        rig.submit(1)
        rig.run(10.0)
        shown.append(rig.controller.greens)
    assert shown == [frozenset(p) for p in [(3, 7), (4, 8), (1, 5), (2, 6), (3, 7)]]
    assert [r["reason"] for r in rig.kinds(Kind.HOLD_RELEASED)] == ["verified"] * 5


@pytest.mark.parametrize(("x", "green"), [(0.0, 3.0), (0.5, 11.5), (1.0, 20.0)])
def test_duration_holds_for_transition_plus_prescribed_green(paper_config, x, green) -> None:
    rig = Rig(paper_config, ActionType.DURATION)
    rig.submit(x)
    dispatched_t = rig.env.now
    rig.run(1.0)
    assert rig.mw.state is State.ON_HOLD
    rig.env.run(until=rig.mw.wait_idle())
    (dispatched,) = rig.kinds(Kind.COMMAND_DISPATCHED)
    assert dispatched["command"] == (3, 7) and math.isclose(dispatched["green"], green)
    (verified,) = rig.kinds(Kind.TRANSITION_VERIFIED)
    (released,) = rig.kinds(Kind.HOLD_RELEASED)
    assert released["reason"] == "served"
    assert math.isclose(released["t"] - verified["t"], green, abs_tol=1e-9)
    transition = verified["t"] - dispatched_t
    # Clearance and the controller's call processing, after up to one tick until the tick that reads the
    # call, then up to one poll period to see the green and the GET's answer time (2 ms).
    call_processing = paper_config.emulator.call_processing_ticks * 0.1
    assert 5.0 + call_processing <= transition <= 5.0 + call_processing + 0.1 + 0.1 + 0.002 + 1e-9
    assert math.isclose(released["hold_s"], transition + green, abs_tol=1e-9)
    assert rig.controller.greens == frozenset({3, 7}), "the pair must still be green when its time is served"


def test_duration_agent_is_asked_again_only_when_the_green_is_served(paper_config) -> None:
    spec = RunSpec(paper_config, ActionType.DURATION, agent="random", duration=120.0, seed=4)
    records = run_spec(spec).records
    asked = [r["t"] for r in records if r["kind"] == "action_received"]
    served = [r["t"] for r in records if r["kind"] == "hold_released"]
    assert len(asked) >= 4
    assert not [r for r in records if r["kind"] == "action_dropped"]
    # Every action after the first comes at the instant the previous green was served.
    assert all(any(math.isclose(a, s) for s in served) for a in asked[1:])


@pytest.mark.parametrize("keepalive", [True, False])
def test_keepalive_keeps_the_controller_out_of_backup_mode(paper_config, keepalive: bool) -> None:
    config = paper_config.with_middleware(backup_time=6)
    rig = Rig(config, ActionType.SWITCH)
    rig.mw.keepalive_enabled = keepalive
    held = len(rig.sets("keepalive"))  # before any command, the keepalive holds the empty call
    rig.submit(1)
    statuses = []
    for _ in range(120):
        rig.run(1.0)
        statuses.append(rig.controller.control_status)
    command_sets = rig.sets("command")
    assert len(command_sets) == 1
    if keepalive:
        assert UnitControlStatus.BACKUP_MODE not in statuses
        assert set(statuses) == {UnitControlStatus.SYSTEM_CONTROL}
        assert rig.veh_call == frozenset({3, 7})
        times = [r["t"] for r in rig.sets()]
        assert all(b - a <= 6 / 3 + 1e-6 for a, b in pairwise(times))
        assert all(r["phases"] == frozenset({3, 7}) for r in rig.sets("keepalive")[held:])
    else:
        assert len(rig.sets("keepalive")) == held
        first = statuses.index(UnitControlStatus.BACKUP_MODE)
        # The SET at 5 s reaches the phase logic at the tick after next (call processing), a little after
        # 5.1 s; backup_time later is just after 11 s, first seen by the sample at 12 s.
        assert first == 6, "backup mode must come backup_time after the last SET took effect"
        assert rig.veh_call == frozenset()


def test_calls_are_cleared_at_the_end_of_a_run(paper_config) -> None:
    result = run_spec(RunSpec(paper_config, ActionType.SELECTION, agent="random", duration=60.0, seed=3))
    # In the controller's database at the end; its phase logic takes it a tick of call processing later.
    assert result.target.unit.control[ControlColumn.VEH_CALL] == frozenset()
    records = result.records
    sets = [r for r in records if r["kind"] == "set_sent"]
    assert any(r["purpose"] == "command" for r in sets)
    assert sets[-1]["purpose"] == "clear" and sets[-1]["phases"] == frozenset()
    assert [r["kind"] for r in records[-2:]] == ["set_answered", "run_ended"]


@pytest.mark.parametrize("lost", [1, 2, CLEAR_ATTEMPTS])
def test_a_closing_clear_that_gets_no_answer_is_sent_again(paper_config, lost: int, caplog) -> None:
    """One lost datagram is no reason to leave the calls on the controller until its backup time; a dead link
    still ends the run, after CLEAR_ATTEMPTS x tau_udp at most."""
    with Testbed(paper_config, action_type="switch", duration=30.0) as tb:
        tb.reset()
        while not tb.done:
            tb.step(1)  # steps leave the calls placed: only finish() clears them
        transport, env = tb.intersection.transport, tb.env
        real_set, dropped = transport.set, []

        def set_losing_the_first_clears(varbinds):
            if len(dropped) < lost and all(value == 0 for _oid, value in varbinds):
                dropped.append(env.now)
                event = env.event()
                env.timeout(transport.tau_udp).callbacks.append(
                    lambda _: event.fail(CommunicationTimeout("no answer (dropped by the test)")))
                return event
            return real_set(varbinds)

        transport.set = set_losing_the_first_clears
        assert tb.target.unit.control[ControlColumn.VEH_CALL] != frozenset()
        tb.finish()
    clears = [(r["kind"], r["t"]) for r in tb.records if r.get("purpose") == "clear"]
    attempts = min(lost + 1, CLEAR_ATTEMPTS)
    assert [k for k, _ in clears] == ["set_sent", "set_failed"] * lost + ["set_sent", "set_answered"] * (
        attempts - lost)
    assert clears[-1][1] - clears[0][1] <= attempts * paper_config.middleware.tau_udp + 1e-9
    cleared = tb.target.unit.control[ControlColumn.VEH_CALL] == frozenset()
    assert cleared is (lost < CLEAR_ATTEMPTS)
    assert ("could not clear the calls" in caplog.text) is (lost == CLEAR_ATTEMPTS)


def test_recover_in_idle_changes_nothing(paper_config) -> None:
    rig = Rig(paper_config, ActionType.SWITCH)
    rig.submit(1)
    rig.run(8.0)
    position = rig.mw.manager.position
    sets = len(rig.sets())
    assert rig.env.run(until=rig.mw.recover()) is True
    rig.run(1.0)
    assert rig.mw.state is State.IDLE
    assert rig.kinds(Kind.RECOVERED) == [] and rig.kinds(Kind.TIMEOUT_ENTERED) == []
    assert len(rig.sets()) == sets
    assert rig.mw.manager.position == position
    rig.submit(1)
    rig.run(8.0)
    assert rig.controller.greens == frozenset({4, 8})


def test_recover_while_on_hold_does_not_disturb_the_transition(paper_config) -> None:
    rig = Rig(paper_config, ActionType.SWITCH)
    rig.submit(1)
    rig.run(1.0)
    assert rig.mw.state is State.ON_HOLD
    rig.env.run(until=rig.mw.recover())
    rig.run(8.0)
    assert rig.kinds(Kind.TIMEOUT_ENTERED) == []
    assert [r["reason"] for r in rig.kinds(Kind.HOLD_RELEASED)] == ["verified"]
    assert rig.veh_call == frozenset({3, 7})
    assert rig.controller.greens == frozenset({3, 7})
    assert rig.mw.manager.position == paper_config.sequence.index((3, 7))


def test_transition_not_shown_within_tau_trans_enters_timeout_and_recovery_resumes(paper_config,
                                                                                     monkeypatch) -> None:
    rig = Rig(paper_config)
    # The controller takes the call for 3 and 7 and will not serve it (an omit would be a foreign control).
    read = Reader.read
    monkeypatch.setattr(Reader, "read", lambda *a: replace(inputs := read(*a), calls=inputs.calls - {3, 7}))
    rig.submit((3, 7))
    rig.run(paper_config.middleware.tau_trans + 1.0)
    assert rig.mw.state is State.TIMEOUT
    (entered,) = rig.kinds(Kind.TIMEOUT_ENTERED)
    assert entered["reason"] == "transition" and entered["command_id"] == 1
    assert math.isclose(entered["t"] - rig.kinds(Kind.COMMAND_DISPATCHED)[0]["t"], paper_config.middleware.tau_trans)
    assert [r["reason"] for r in rig.kinds(Kind.HOLD_RELEASED)] == ["timeout"]
    assert rig.mw.poller.halted

    assert rig.env.run(until=rig.mw.recover()) is True
    assert rig.mw.state is State.IDLE and not rig.mw.poller.halted
    (recovered,) = rig.kinds(Kind.RECOVERED)
    assert recovered["greens"] == rig.controller.greens == frozenset({2, 6})
    # Recovery aligns the call with what the controller shows, so the stale call is gone.
    assert rig.sets("recovery")[-1]["phases"] == frozenset({2, 6})
    assert rig.veh_call == frozenset({2, 6})
    rig.run(0.3)  # the recovery's SET reaches the phase logic after the controller's call processing
    monkeypatch.undo()
    rig.run(8.0)
    assert rig.controller.greens == frozenset({2, 6})
    rig.submit((4, 8))
    rig.run(8.0)
    assert rig.controller.greens == frozenset({4, 8})
    assert [r["reason"] for r in rig.kinds(Kind.HOLD_RELEASED)] == ["timeout", "verified"]


@pytest.mark.parametrize("column", [c for c in ControlColumn if c is not ControlColumn.VEH_CALL])
def test_a_control_object_set_by_someone_else_is_a_timeout_and_recovery_clears_it(paper_config, column) -> None:
    rig = Rig(paper_config)
    rig.run(3.0)
    assert rig.kinds(Kind.TIMEOUT_ENTERED) == []  # our own call is not foreign
    rig.target.surface.set_many([(control_oid(column, 1), 0b1000)])  # another manager's SET: phase 4
    set_at = rig.env.now
    rig.run(READBACK_PERIOD + 0.1)
    (entered,) = rig.kinds(Kind.TIMEOUT_ENTERED)
    assert entered["reason"] == "foreign_control" and set_at < entered["t"] <= set_at + READBACK_PERIOD + 0.05
    name = "phaseControlGroup" + column.name.title().replace("_", "")
    assert entered["detail"] == f"set by someone else: {name} on phases [4]"
    assert rig.env.run(until=rig.mw.recover()) is True
    assert rig.target.unit.control[column] == frozenset(), "the recovery SET takes every control object back"
    rig.run(2 * READBACK_PERIOD)
    assert len(rig.kinds(Kind.TIMEOUT_ENTERED)) == 1 and rig.mw.state is State.IDLE


def test_drift_needs_n_drift_consecutive_steps(paper_config) -> None:
    rig = Rig(paper_config)
    step = paper_config.middleware.sumo_step
    n = paper_config.middleware.n_drift
    for _ in range(n - 1):
        rig.mw.observe_step(step, step * 1.5)
    rig.mw.observe_step(step, step * 0.5)
    for _ in range(n - 1):
        rig.mw.observe_step(step, step * 1.5)
    assert rig.mw.state is State.IDLE
    rig.mw.observe_step(step, step * 1.5)
    assert rig.mw.state is State.TIMEOUT
    (entered,) = rig.kinds(Kind.TIMEOUT_ENTERED)
    assert entered["reason"] == "drift"
    assert [r["consecutive"] for r in rig.kinds(Kind.DRIFT)] == [1, 2, 3, 4, 1, 2, 3, 4, 5]


def test_a_command_for_a_pair_already_green_is_verified_by_the_next_poll(paper_config) -> None:
    rig = Rig(paper_config, ActionType.DURATION)
    # A stale sequence position (as after a recovery that read the controller mid-transition)
    # makes the next pair the one already green: no poll will show a change.
    rig.mw.manager.position = paper_config.sequence.index((1, 5))
    rig.submit(0.0)
    (dispatched,) = rig.kinds(Kind.COMMAND_DISPATCHED)
    assert dispatched["command"] == (2, 6)
    rig.run(4.0)
    (verified,) = rig.kinds(Kind.TRANSITION_VERIFIED)
    assert verified["hold_s"] <= 0.1 + 1e-9
    assert rig.kinds(Kind.TIMEOUT_ENTERED) == []
    assert [r["reason"] for r in rig.kinds(Kind.HOLD_RELEASED)] == ["served"]


def test_no_backup_time_anywhere_means_no_keepalive_and_no_stall(paper_config) -> None:
    cfg = paper_config.with_middleware(backup_time=0)
    tb = Testbed(cfg, action_type="switch", on_reset=lambda tb: setattr(tb.target.controller, "backup_time", 0))
    tb.reset()
    tb.run_for(1.0)
    tb.middleware.submit(1)
    tb.run_for(120.0)  # would never get here if the keepalive spun at one instant
    assert tb.middleware.keepalive_period == 0.0  # 0: no keepalive
    assert [r["purpose"] for r in tb.events.of(Kind.SET_SENT)] == ["startup", "command"]


class _FirstSetLost:
    """Loses the first command SET: it never reaches the controller and fails after tau_udp."""

    def __init__(self, inner, tau_udp: float) -> None:
        self.inner, self.env, self.tau_udp, self.sets = inner, inner.env, tau_udp, 0

    def get(self, oids):
        return self.inner.get(oids)

    def set(self, varbinds):
        self.sets += 1
        if self.sets != 2:  # the first is the start-up SET of the control objects; lose the command's
            return self.inner.set(varbinds)
        failed = self.env.event()
        self.env.timeout(self.tau_udp).callbacks.append(
            lambda _: failed.fail(CommunicationTimeout("lost")))
        return failed

    def close(self) -> None:
        self.inner.close()


def test_a_command_set_without_answer_is_sent_again_and_the_transition_completes(paper_config) -> None:
    tau_udp = paper_config.middleware.tau_udp

    def target(env: simpy.Environment, config: IntersectionConfig, *, seed: int, fast_path: bool,
               hires: bool) -> VirtualTarget:
        base = VirtualTarget(env, config, seed=seed, fast_path=fast_path, hires=hires)
        base.transport = _FirstSetLost(LocalTransport(env, base.surface, tau_udp=tau_udp,
                                                      get_latency=base.get_latency, set_latency=base.set_latency),
                                       tau_udp)
        return base

    tb = Testbed(paper_config, action_type="switch", target=target)
    tb.reset()
    tb.run_for(5.0 - tb.now)
    tb.middleware.submit(1)
    tb.run_for(15.0)
    log = tb.events
    sent = [(r["purpose"], r["t"]) for r in log.of(Kind.SET_SENT) if r["purpose"] not in ("keepalive", "startup")]
    assert [p for p, _ in sent] == ["command", "retry"]
    assert sent[1][1] - sent[0][1] == pytest.approx(paper_config.middleware.tau_udp)
    (verified,) = log.of(Kind.TRANSITION_VERIFIED)
    # The retry's transition: clearance plus the controller's call processing, within a tick and a poll.
    call_processing = paper_config.emulator.call_processing_ticks * 0.1
    assert verified["hold_s"] == pytest.approx(paper_config.middleware.tau_udp + 5.0 + call_processing, abs=0.2)
    assert not log.of(Kind.TIMEOUT_ENTERED)


def test_a_run_that_has_placed_no_call_keeps_the_controller_under_system_control(paper_config) -> None:
    """An agent keeping the start-up pair (or the actuated baseline) places no call: the keepalive holds the
    empty call, so the controller never drops to backup mode behind the run's back."""
    rig = Rig(paper_config.with_middleware(backup_time=6), ActionType.SWITCH)
    statuses = []
    for _ in range(30):
        rig.run(1.0)
        statuses.append(rig.controller.control_status)
    assert set(statuses) == {UnitControlStatus.SYSTEM_CONTROL}
    held = rig.sets("keepalive")
    assert len(held) >= 30 // 2 - 1 and all(r["phases"] == frozenset() for r in held)
