"""Properties of the manager's state machine, driven directly (it is pure: no SimPy).

Hypothesis plays the shell: it converts random action values (valid and invalid)
through the converters of the shipped config, feeds random signal observations,
fires the timers the manager asked for in random order (and stale tokens),
reports communication and drift failures and completes recoveries, with time
never going back. Every effect the manager returns is checked against the
rules of the paper as it comes out.
"""

from __future__ import annotations

import math
from typing import Any

import hypothesis.strategies as st
import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis.stateful import RuleBasedStateMachine, initialize, precondition, rule

from hils.actions import ActionConverter, ActionError, ActionType, Command
from hils.config import load
from hils.manager import (
    CommandEnded,
    CommandRequested,
    Dispatch,
    Dropped,
    Effect,
    Event,
    FailureDetected,
    Manager,
    Recovered,
    RecoveryCompleted,
    SignalObserved,
    StartTimer,
    State,
    TimeoutEntered,
    TimeoutReason,
    TimerExpired,
    TimerKind,
    Verified,
)

CONFIG = load()
PHASES = CONFIG.phase_numbers
TAU_TRANS = CONFIG.middleware.tau_trans
DISPATCHED_OUTCOMES = {"verified", "served", "timeout"}

# --- action values, each tagged with whether the converter must accept it --------------------


def _selection_valid(a: int, b: int) -> bool:
    return frozenset((a, b)) in {frozenset(p) for p in CONFIG.pairs}


_shapes = st.sampled_from([tuple, list, lambda v: np.array(v, dtype=np.int64), lambda v: tuple(map(np.int32, v)),
                          lambda v: np.array(v, dtype=np.float32)])
_any_pair = st.tuples(st.integers(-1, 10), st.integers(-1, 10), _shapes).map(
    lambda t: (t[2]((t[0], t[1])), _selection_valid(t[0], t[1])))
_good_pair = st.tuples(st.sampled_from(CONFIG.pairs), st.booleans(), _shapes).map(
    lambda t: (t[2](t[0][::-1] if t[1] else t[0]), True))
_bad_selection_type = st.sampled_from(["15", None, 3, 1.5, (1, 5, 2), [1.5, 5.0], [True, 5], b"\x01\x05", (1,),
                                      {1, 5}, {1: 5}])
SELECTION = st.one_of(_good_pair, _any_pair, _bad_selection_type.map(lambda v: (v, False)))

SWITCH = st.one_of(
    st.sampled_from([0, 1, np.int64(0), np.int64(1), np.uint8(1), 0.0, 1.0, np.float32(1.0), np.array(0),
                     np.array([1])]).map(lambda v: (v, True)),
    st.one_of(st.sampled_from([True, False, 0.5, "1", None, [1], 2**80]),
              st.integers(max_value=-1), st.integers(min_value=2)).map(lambda v: (v, False)),
)

DURATION = st.one_of(
    st.floats(0.0, 1.0).map(lambda v: (v, True)),
    st.floats(0.0, 1.0, width=32).map(lambda v: (np.float32(v), True)),
    st.sampled_from([0, 1, np.int64(1), np.float64(0.5)]).map(lambda v: (v, True)),
    st.one_of(st.floats(max_value=-1e-9), st.floats(min_value=1.0, exclude_min=True),
              st.sampled_from([math.nan, math.inf, -math.inf, np.float32("nan"), "0.5", True, False, None, [0.5]]),
              ).map(lambda v: (v, False)),
)

VALUES = {ActionType.SELECTION: SELECTION, ActionType.SWITCH: SWITCH, ActionType.DURATION: DURATION}

DT = st.one_of(st.just(0.0), st.floats(0.0, 15.0))
GREENS = st.frozensets(st.sampled_from(PHASES), max_size=4)


class ManagerMachine(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.manager = Manager(TAU_TRANS)
        self.converters = {t: ActionConverter(CONFIG, t) for t in ActionType}
        self.t = 0.0
        self.actions = 0
        self.polls = 0
        self.timers: list[tuple[float, TimerKind, int]] = []  # started, not yet fired
        self.fired: set[int] = set()
        self.dispatched: dict[int, Command] = {}
        self.dispatched_at: dict[int, float] = {}
        self.ended: dict[int, str] = {}
        self.keeps: set[int] = set()
        self.open: int | None = None  # the dispatched command not yet ended
        self.consistent = True  # False once a check failed: the trackers no longer match the manager

    # --- the shell -----------------------------------------------------------------------------

    def _tick(self, dt: float) -> float:
        assert dt >= 0.0
        self.t += dt
        return self.t

    def feed(self, ev: Event) -> list[Effect]:
        m = self.manager
        self.consistent = False
        before, open_before, greens_before = m.state, self.open, m.greens
        effects = m.handle(ev)
        after = m.state

        if before is State.TIMEOUT and after is not State.TIMEOUT:
            assert isinstance(ev, RecoveryCompleted), f"left TIMEOUT on {ev}"
        if isinstance(ev, RecoveryCompleted) and before is State.TIMEOUT:
            assert after is State.IDLE
            assert effects == [Recovered(ev.greens)]
        if isinstance(ev, CommandRequested) and before is not State.IDLE:
            assert effects == [Dropped(ev.action_id, before)]
        if isinstance(ev, FailureDetected):
            assert after is State.TIMEOUT
        if isinstance(ev, SignalObserved):
            assert m.greens == ev.greens

        for eff in effects:
            match eff:
                case Dispatch(command_id, action_id, command):
                    assert before is State.IDLE, f"dispatched while {before.name}"
                    assert isinstance(ev, CommandRequested)
                    assert (action_id, command) == (ev.action_id, ev.command)
                    a, b = command.phases
                    assert a != b and CONFIG.compatible(a, b), f"conflicting pair {command.phases} dispatched"
                    assert command.phases in CONFIG.pairs
                    assert not command.keep
                    assert self.open is None, "a second command pending"
                    assert command_id not in self.dispatched and command_id not in self.keeps
                    if command.green is not None:
                        g_min, g_max = self.converters[ActionType.DURATION].green_range(command.phases)
                        assert g_min - 1e-9 <= command.green <= g_max + 1e-9
                    self.dispatched[command_id] = command
                    self.dispatched_at[command_id] = ev.t
                    self.open = command_id
                case StartTimer(kind, delay, token):
                    assert self.open is not None
                    command = self.dispatched[self.open]
                    if kind is TimerKind.TRANSITION:
                        assert delay == TAU_TRANS
                        assert isinstance(ev, CommandRequested)
                    else:
                        assert isinstance(ev, SignalObserved) and set(command.phases) <= ev.greens
                        assert command.green is not None and delay == command.green
                    assert token not in self.fired and all(token != t for _, _, t in self.timers)
                    self.timers.append((ev.t + delay, kind, token))
                case Verified(command_id, command, poll_id, hold):
                    assert command_id == self.open and command == self.dispatched[command_id]
                    assert isinstance(ev, SignalObserved) and poll_id == ev.poll_id
                    assert set(command.phases) <= ev.greens
                    assert math.isclose(hold, ev.t - self.dispatched_at[command_id]) and hold >= 0
                case CommandEnded(command_id, outcome, hold):
                    if outcome == "keep":
                        assert before is State.IDLE and isinstance(ev, CommandRequested)
                        assert ev.command.keep or set(ev.command.phases) <= greens_before
                        assert ev.command.green is None
                        assert command_id not in self.dispatched and command_id not in self.keeps
                        assert hold == 0.0
                        self.keeps.add(command_id)
                        continue
                    assert outcome in DISPATCHED_OUTCOMES
                    assert command_id == self.open, "ended a command that is not pending"
                    assert command_id not in self.ended, "a command ended twice"
                    green = self.dispatched[command_id].green
                    if outcome == "verified":
                        assert green is None and isinstance(ev, SignalObserved)
                    elif outcome == "served":
                        assert green is not None and isinstance(ev, TimerExpired)
                        assert ev.kind is TimerKind.DURATION
                    assert math.isclose(hold, ev.t - self.dispatched_at[command_id]) and hold >= 0
                    self.ended[command_id] = outcome
                    self.open = None
                case Dropped(action_id, state):
                    assert isinstance(ev, CommandRequested) and action_id == ev.action_id
                    assert state is before and before in (State.ON_HOLD, State.TIMEOUT)
                case TimeoutEntered(reason, _detail, command_id):
                    assert after is State.TIMEOUT
                    assert command_id == open_before
                    if isinstance(ev, FailureDetected):
                        assert reason is ev.reason
                    else:
                        assert isinstance(ev, TimerExpired) and ev.kind is TimerKind.TRANSITION
                        assert reason is TimeoutReason.TRANSITION
                case Recovered(greens):
                    assert before is State.TIMEOUT and greens == ev.greens
                case _:
                    raise AssertionError(f"unknown effect {eff!r}")

        assert (self.open is not None) == (after is State.ON_HOLD)
        assert (m.pending is None) == (self.open is None)
        if m.pending is not None:
            assert m.pending.command_id == self.open
        assert len(self.dispatched) - len(self.ended) <= 1
        self.consistent = True
        return effects

    # --- rules ---------------------------------------------------------------------------------

    @initialize(greens=GREENS)
    def start(self, greens: frozenset[int]) -> None:
        self.polls += 1
        self.feed(SignalObserved(self.t, greens, self.polls))
        for conv in self.converters.values():
            conv.sync(greens)

    @rule(data=st.data(), action_type=st.sampled_from(ActionType), dt=DT)
    def act(self, data: st.DataObject, action_type: ActionType, dt: float) -> None:
        self._act(data, action_type, dt)

    @rule(data=st.data(), dt=DT)
    def act_duration(self, data: st.DataObject, dt: float) -> None:
        # Duration commands take the longest path (transition, then serving): give them more turns.
        self._act(data, ActionType.DURATION, dt)

    def _act(self, data: st.DataObject, action_type: ActionType, dt: float) -> None:
        value, valid = data.draw(VALUES[action_type], label="value")
        conv = self.converters[action_type]
        try:
            command = conv.convert(value)
        except ActionError:
            assert not valid, f"valid {action_type.value} value {value!r} refused"
            return  # nothing reaches the manager
        assert valid, f"invalid {action_type.value} value {value!r} accepted as {command}"
        self.actions += 1
        effects = self.feed(CommandRequested(self._tick(dt), self.actions, command))
        if any(isinstance(e, Dispatch) for e in effects):
            conv.commit(command)  # as the shell does

    @rule(dt=DT, greens=GREENS, with_pending=st.booleans())
    def observe(self, dt: float, greens: frozenset[int], with_pending: bool) -> None:
        if with_pending and self.open is not None:
            greens |= set(self.dispatched[self.open].phases)
        self.polls += 1
        self.feed(SignalObserved(self._tick(dt), greens, self.polls))

    @precondition(lambda self: self.open is not None)
    @rule(dt=DT, greens=GREENS)
    def observe_commanded(self, dt: float, greens: frozenset[int]) -> None:
        # The controller showing what was asked, as it usually does: gives verification a chance
        # against the transition timer that timer_fires may pick first.
        self.observe(dt, greens, with_pending=True)

    @precondition(lambda self: self.timers)
    @rule(data=st.data())
    def timer_fires(self, data: st.DataObject) -> None:
        due, kind, token = self.timers.pop(data.draw(st.integers(0, len(self.timers) - 1), label="timer"))
        self.t = max(self.t, due)
        pending = self.manager.pending
        state = self.manager.state
        effects = self.feed(TimerExpired(self.t, kind, token))
        self.fired.add(token)
        if pending is None or pending.token != token:
            assert effects == [] and self.manager.state is state, "a stale timer had an effect"

    @precondition(lambda self: self.manager.state is State.TIMEOUT)
    @rule(dt=DT, greens=GREENS)
    def recover(self, dt: float, greens: frozenset[int]) -> None:
        assert self.feed(RecoveryCompleted(self._tick(dt), greens)) == [Recovered(greens)]
        for conv in self.converters.values():
            conv.sync(greens)  # as the shell does after re-reading the controller

    # Failures, recoveries (in any state) and stale timers share one rule, so that they come
    # rarely enough for commands to run their course in between.
    @rule(data=st.data(), dt=DT, what=st.sampled_from(["failure", "recovery", "stale_timer"]))
    def disturbance(self, data: st.DataObject, dt: float, what: str) -> None:
        t = self._tick(dt)
        state = self.manager.state
        if what == "failure":
            reason = data.draw(st.sampled_from(TimeoutReason), label="reason")
            self.feed(FailureDetected(t, reason, data.draw(st.text(max_size=5), label="detail")))
        elif what == "recovery":
            greens = data.draw(GREENS, label="greens")
            effects = self.feed(RecoveryCompleted(t, greens))
            if state is not State.TIMEOUT:
                assert effects == [] and self.manager.state is state
            else:
                for conv in self.converters.values():
                    conv.sync(greens)
        else:
            kind = data.draw(st.sampled_from(TimerKind), label="kind")
            token = data.draw(st.one_of(st.integers(-3, 0), st.sampled_from(sorted(self.fired) or [0])),
                              label="token")
            assert self.feed(TimerExpired(t, kind, token)) == []
            assert self.manager.state is state

    def teardown(self) -> None:
        if not self.consistent:
            return  # a rule failed: report that failure, not one that follows from it
        # A failure ends whatever is pending, so every dispatched command has now ended exactly once.
        if self.manager.state is not State.TIMEOUT:
            self.feed(FailureDetected(self.t + 1.0, TimeoutReason.COMMUNICATION))
        assert set(self.ended) == set(self.dispatched)
        assert set(self.ended.values()) <= DISPATCHED_OUTCOMES


ManagerMachine.TestCase.settings = settings(max_examples=200, stateful_step_count=60, deadline=None,
                                            suppress_health_check=[HealthCheck.too_slow])
TestManagerMachine = ManagerMachine.TestCase


def test_a_full_duration_cycle_by_hand() -> None:
    """The path the random machine must be able to take: dispatch, verify, serve."""
    conv = ActionConverter(CONFIG, ActionType.DURATION)
    conv.sync(frozenset({2, 6}))
    m = Manager(TAU_TRANS)
    m.handle(SignalObserved(0.0, frozenset({2, 6}), 1))
    cmd = conv.convert(0.5)
    effects: list[Any] = m.handle(CommandRequested(1.0, 1, cmd))
    assert effects == [Dispatch(1, 1, Command((3, 7), green=11.5)), StartTimer(TimerKind.TRANSITION, TAU_TRANS, 1)]
    assert m.handle(SignalObserved(3.0, frozenset(), 2)) == []
    assert m.handle(CommandRequested(4.0, 2, cmd)) == [Dropped(2, State.ON_HOLD)]
    effects = m.handle(SignalObserved(6.2, frozenset({3, 7}), 3))
    assert effects[0] == Verified(1, cmd, 3, effects[0].hold)
    assert math.isclose(effects[0].hold, 5.2)
    assert effects[1] == StartTimer(TimerKind.DURATION, 11.5, 2)
    assert m.handle(TimerExpired(11.0, TimerKind.TRANSITION, 1)) == [], "the transition timer is stale by now"
    effects = m.handle(TimerExpired(17.7, TimerKind.DURATION, 2))
    assert len(effects) == 1 and effects[0].command_id == 1 and effects[0].outcome == "served"
    assert math.isclose(effects[0].hold, 16.7)
    assert m.state is State.IDLE and m.pending is None


def test_transition_not_seen_within_tau_trans_times_out_and_only_recovery_leaves() -> None:
    m = Manager(TAU_TRANS)
    m.handle(SignalObserved(0.0, frozenset({2, 6}), 1))
    m.handle(CommandRequested(0.0, 1, Command((4, 8))))
    effects = m.handle(TimerExpired(10.0, TimerKind.TRANSITION, 1))
    assert [type(e) for e in effects] == [CommandEnded, TimeoutEntered]
    assert effects[0].outcome == "timeout"
    assert effects[1].reason is TimeoutReason.TRANSITION and effects[1].command_id == 1
    assert m.state is State.TIMEOUT and m.timeout_reason is TimeoutReason.TRANSITION
    for ev in (SignalObserved(11.0, frozenset({4, 8}), 2), FailureDetected(12.0, TimeoutReason.DRIFT),
               CommandRequested(13.0, 2, Command((1, 5)))):
        m.handle(ev)
        assert m.state is State.TIMEOUT
    assert m.handle(RecoveryCompleted(14.0, frozenset({4, 8}))) == [Recovered(frozenset({4, 8}))]
    assert m.state is State.IDLE and m.timeout_reason is None
    assert m.handle(CommandRequested(15.0, 3, Command((4, 8))))[0].outcome == "keep"
