"""Properties of the manager's state machine, driven directly (it is pure: no SimPy).

Hypothesis plays the shell and the world: it converts random action values (valid and invalid)
through the converters of the shipped config at the manager's sequence position, feeds random
signal observations, fires the timers the manager asked for in random order (and stale tokens),
answers, refuses or loses the SETs it asked for, times simulation steps (drift), reports
communication failures, asks for recovery and answers its re-read, switches the keepalive and
closes the run, with time never going back. Every effect the manager returns is checked against
the rules of the paper as it comes out: what may be sent in which state, retries, the gating of
the keepalive, drift counting, recovery and the sequence position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import hypothesis.strategies as st
import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis.stateful import RuleBasedStateMachine, initialize, precondition, rule

from hils.actions import ActionConverter, ActionError, ActionType, Command
from hils.config import load
from hils.manager import (
    CLEAR_ATTEMPTS,
    CloseRequested,
    CommandEnded,
    CommandRequested,
    ControllerRead,
    ControllerUnreadable,
    ControlsRead,
    Dispatch,
    DriftSeen,
    Dropped,
    Effect,
    Event,
    FailureDetected,
    HaltPolling,
    KeepaliveSwitched,
    Manager,
    Mode,
    Note,
    Purpose,
    ReadController,
    Recovered,
    RecoveryRequested,
    RecoveryStarted,
    ResumePolling,
    SendCall,
    SetAnswered,
    SetFailed,
    SignalObserved,
    Started,
    StartTimer,
    State,
    StepTimed,
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
N_DRIFT = CONFIG.middleware.n_drift
STEP = CONFIG.middleware.sumo_step
BACKUP = st.sampled_from([0, 6, 30, 300])
RUNNING = (Mode.IDLE, Mode.IN_TRANSITION, Mode.SERVING)


@dataclass
class Outstanding:
    """A SET the manager asked for, whose answer the world has not given yet."""

    purpose: Purpose
    command_id: int | None
    phases: frozenset[int]


class ManagerMachine(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.manager = Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT,
                               keepalive_period=CONFIG.middleware.keepalive_period or 0.0)
        self.converters = {t: ActionConverter(CONFIG, t) for t in ActionType}
        self.t = 0.0
        self.actions = 0
        self.polls = 0
        self.timers: list[tuple[float, TimerKind, int]] = []  # started, not yet fired
        self.fired: set[int] = set()
        self.keepalive_token: int | None = None  # the latest keepalive timer armed
        self.sets: list[Outstanding] = []
        self.last_set = -math.inf
        self.drifted = 0  # consecutive drifted steps while running, as the paper counts them
        self.dispatched: dict[int, Command] = {}
        self.dispatched_at: dict[int, float] = {}
        self.ended: dict[int, str] = {}
        self.keeps: set[int] = set()
        self.open: int | None = None  # the dispatched command not yet ended
        self.read_pending = False  # the recovery asked to re-read the controller
        self.clears_lost = 0  # clearing SETs (after the close) whose datagram got no answer
        self.read_greens: frozenset[int] = frozenset()
        self.consistent = True  # False once a check failed: the trackers no longer match the manager

    # --- the shell -----------------------------------------------------------------------------

    def _tick(self, dt: float) -> float:
        assert dt >= 0.0
        self.t += dt
        return self.t

    def feed(self, ev: Event) -> list[Effect]:
        m = self.manager
        self.consistent = False
        before, open_before, position_before = m.mode, self.open, m.position
        effects = m.handle(ev)
        after = m.mode

        # Where the machine may go.
        if before in (Mode.TIMEOUT, Mode.RECOVERING) and after not in (Mode.TIMEOUT, Mode.RECOVERING, Mode.CLOSED):
            assert before is Mode.RECOVERING and isinstance(ev, SetAnswered) and ev.purpose is Purpose.RECOVERY, (
                f"left TIMEOUT on {ev}")
        if before is Mode.CLOSED:
            # Closed, only two things happen: a command is dropped, a clear that got no answer is sent again.
            assert after is Mode.CLOSED and all(isinstance(e, Dropped | SendCall) for e in effects), (
                f"closed, yet {effects}")
            if isinstance(ev, SetFailed) and ev.purpose is Purpose.CLEAR and ev.lost:
                self.clears_lost += 1
                assert effects == ([SendCall(frozenset(), Purpose.CLEAR)] if self.clears_lost < CLEAR_ATTEMPTS
                                   else []), "a lost clear is sent again, CLEAR_ATTEMPTS times in all"
        if isinstance(ev, CommandRequested) and before is not Mode.IDLE:
            assert effects == [Dropped(ev.action_id, before.log_name)]
        if isinstance(ev, FailureDetected) and before in RUNNING:
            assert after is Mode.TIMEOUT
        if isinstance(ev, CloseRequested) and before is not Mode.CLOSED:
            assert after is Mode.CLOSED
            if self.last_set > -math.inf:
                assert effects[-1] == SendCall(frozenset(), Purpose.CLEAR), "closing clears the call"
            else:
                assert effects == [HaltPolling()], "nothing was SET, nothing to clear"

        sent = [e for e in effects if isinstance(e, SendCall)]
        for eff in effects:
            match eff:
                case Dispatch(command_id, action_id, command):
                    assert before is Mode.IDLE, f"dispatched while {before.name}"
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
                    assert SendCall(frozenset(command.phases), Purpose.COMMAND, command_id) in sent
                    assert m.position == CONFIG.sequence.index(command.phases), "the position follows the command"
                    self.dispatched[command_id] = command
                    self.dispatched_at[command_id] = ev.t
                    self.open = command_id
                case SendCall(phases, purpose, command_id):
                    self._check_send(ev, before, phases, purpose, command_id)
                case StartTimer(kind, delay, token):
                    assert token not in self.fired and all(token != t for _, _, t in self.timers)
                    if kind is TimerKind.KEEPALIVE:
                        assert delay == m.keepalive_period > 0
                        self.keepalive_token = token
                    elif kind is TimerKind.TRANSITION:
                        assert delay == TAU_TRANS and isinstance(ev, CommandRequested)
                    else:
                        command = self.dispatched[self.open]
                        assert isinstance(ev, SignalObserved) and set(command.phases) <= ev.greens
                        assert command.green is not None and delay == command.green
                    self.timers.append((ev.t + delay, kind, token))
                case Verified(command_id, command, poll_id, hold):
                    assert command_id == self.open and command == self.dispatched[command_id]
                    assert isinstance(ev, SignalObserved) and poll_id == ev.poll_id
                    assert set(command.phases) <= ev.greens
                    assert math.isclose(hold, ev.t - self.dispatched_at[command_id]) and hold >= 0
                case CommandEnded(command_id, outcome, hold):
                    if outcome == "keep":
                        assert before is Mode.IDLE and isinstance(ev, CommandRequested)
                        assert ev.command.keep or set(ev.command.phases) <= ev.shown
                        assert ev.command.green is None and hold == 0.0
                        assert command_id not in self.dispatched and command_id not in self.keeps
                        self.keeps.add(command_id)
                        continue
                    assert outcome in DISPATCHED_OUTCOMES
                    assert command_id == self.open, "ended a command that is not pending"
                    assert command_id not in self.ended, "a command ended twice"
                    green = self.dispatched[command_id].green
                    if outcome == "verified":
                        assert green is None and isinstance(ev, SignalObserved)
                    elif outcome == "served":
                        assert green is not None and isinstance(ev, TimerExpired) and ev.kind is TimerKind.DURATION
                    assert math.isclose(hold, ev.t - self.dispatched_at[command_id]) and hold >= 0
                    self.ended[command_id] = outcome
                    self.open = None
                case Dropped(action_id, state):
                    assert isinstance(ev, CommandRequested) and action_id == ev.action_id
                    assert state == before.log_name and before is not Mode.IDLE
                case TimeoutEntered(reason, _detail, command_id):
                    assert after is Mode.TIMEOUT and before in RUNNING
                    assert command_id == open_before
                    assert HaltPolling() in effects, "polling halts in TIMEOUT"
                    if isinstance(ev, FailureDetected):
                        assert reason is ev.reason
                    elif isinstance(ev, StepTimed):
                        assert reason is TimeoutReason.DRIFT and self.drifted + 1 == N_DRIFT
                    elif isinstance(ev, ControlsRead):
                        assert reason is TimeoutReason.FOREIGN_CONTROL
                    else:
                        assert isinstance(ev, TimerExpired) and ev.kind is TimerKind.TRANSITION
                        assert reason is TimeoutReason.TRANSITION
                case DriftSeen(step, took, consecutive):
                    assert isinstance(ev, StepTimed) and took > step and before in RUNNING
                    assert consecutive == self.drifted + 1
                case RecoveryStarted() | ReadController():
                    assert before is Mode.TIMEOUT and isinstance(ev, RecoveryRequested) and after is Mode.RECOVERING
                    self.read_pending = True
                case Recovered(greens):
                    assert before is Mode.RECOVERING and after is Mode.IDLE and ResumePolling() in effects
                    assert greens == self.read_greens, "recovered to what the re-read showed"
                case HaltPolling() | ResumePolling() | Note():
                    pass
                case _:
                    raise AssertionError(f"unknown effect {eff!r}")

        # A control object the run never sets, found set while running, is a TIMEOUT; else nothing happens.
        if isinstance(ev, ControlsRead):
            foreign = any(phases for _name, phases in ev.held)
            if before in RUNNING and foreign:
                assert after is Mode.TIMEOUT and any(isinstance(e, TimeoutEntered) for e in effects)
            else:
                assert after is before and effects == []
        # Drift is counted while running and only then; an on-time step resets the count.
        if isinstance(ev, StepTimed) and before in RUNNING:
            self.drifted = self.drifted + 1 if ev.took > ev.step else 0
        if isinstance(ev, SetAnswered) and before is Mode.RECOVERING and ev.purpose is Purpose.RECOVERY:
            self.drifted = 0
        if after is Mode.IDLE and before is Mode.RECOVERING:
            assert m.drifted_in_a_row == 0
        if isinstance(ev, ControllerRead) and before is Mode.RECOVERING:
            expected = next((i for i, pair in enumerate(CONFIG.sequence) if set(pair) <= ev.greens), position_before)
            assert m.position == expected, "recovery aligns the position with what the controller shows"
        elif not any(isinstance(e, Dispatch) for e in effects) and not isinstance(ev, Started):
            assert m.position == position_before, "only a dispatch, the start-up or a recovery moves the position"

        assert (self.open is not None) == (after in (Mode.IN_TRANSITION, Mode.SERVING)) or after is Mode.CLOSED
        assert (m.pending is None) == (self.open is None)
        assert m.state is after.paper
        assert len(self.dispatched) - len(self.ended) <= 1
        self.consistent = True
        return effects

    def _check_send(self, ev: Event, before: Mode, phases: frozenset[int], purpose: Purpose,
                    command_id: int | None) -> None:
        m = self.manager
        for p in phases:
            assert p in CONFIG.phases
        if purpose in (Purpose.COMMAND, Purpose.RETRY):
            assert len(phases) == 2 and CONFIG.compatible(*phases)
        # A keepalive repeats the call as it stands; a recovery SETs what the controller shows.
        if purpose is Purpose.COMMAND:
            assert before is Mode.IDLE and isinstance(ev, CommandRequested)
        elif purpose is Purpose.RETRY:
            assert before is Mode.IN_TRANSITION and isinstance(ev, SetFailed) and ev.lost
            assert ev.command_id == command_id == self.open
            assert phases == frozenset(self.dispatched[self.open].phases)
        elif purpose is Purpose.KEEPALIVE:
            assert before in RUNNING, f"keepalive in {before.name}"
            assert isinstance(ev, TimerExpired) and ev.token == self.keepalive_token
            assert m.keepalive_on and phases == m.call
            assert ev.t - self.last_set >= m.keepalive_period - 1e-9, "keepalive before a period without a SET"
        elif purpose is Purpose.RECOVERY:
            assert before is Mode.RECOVERING and isinstance(ev, ControllerRead) and phases == ev.greens
        else:
            assert isinstance(ev, CloseRequested | SetFailed) and phases == frozenset()
            assert isinstance(ev, CloseRequested) or (ev.purpose is Purpose.CLEAR and ev.lost)
        if purpose is not Purpose.RECOVERY:
            assert before in (*RUNNING,) or purpose is Purpose.CLEAR, f"{purpose} SET in {before.name}"
        self.last_set = ev.t
        self.sets.append(Outstanding(purpose, command_id, phases))

    # --- rules ---------------------------------------------------------------------------------

    @initialize(greens=GREENS, backup=BACKUP)
    def start(self, greens: frozenset[int], backup: int) -> None:
        self.feed(Started(self.t, greens, backup))
        self.polls += 1
        self.feed(SignalObserved(self.t, greens, self.polls))
        self.shown = greens

    @rule(data=st.data(), action_type=st.sampled_from(ActionType), dt=DT)
    def act(self, data: st.DataObject, action_type: ActionType, dt: float) -> None:
        self._act(data, action_type, dt)

    @rule(data=st.data(), dt=DT)
    def act_duration(self, data: st.DataObject, dt: float) -> None:
        # Duration commands take the longest path (transition, then serving): give them more turns.
        self._act(data, ActionType.DURATION, dt)

    def _act(self, data: st.DataObject, action_type: ActionType, dt: float) -> None:
        value, valid = data.draw(VALUES[action_type], label="value")
        try:
            command = self.converters[action_type].convert(value, self.manager.position)
        except ActionError:
            assert not valid, f"valid {action_type.value} value {value!r} refused"
            return  # nothing reaches the manager
        assert valid, f"invalid {action_type.value} value {value!r} accepted as {command}"
        self.actions += 1
        self.feed(CommandRequested(self._tick(dt), self.actions, command, self.shown))

    @rule(dt=DT, greens=GREENS, with_pending=st.booleans())
    def observe(self, dt: float, greens: frozenset[int], with_pending: bool) -> None:
        if with_pending and self.open is not None:
            greens |= set(self.dispatched[self.open].phases)
        self.polls += 1
        self.shown = greens
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
        live = token == self.keepalive_token if kind is TimerKind.KEEPALIVE else (
            self.manager.pending is not None and self.manager.pending.token == token)
        mode = self.manager.mode
        effects = self.feed(TimerExpired(self.t, kind, token))
        self.fired.add(token)
        if not live:
            assert effects == [] and self.manager.mode is mode, "a stale timer had an effect"

    @precondition(lambda self: self.sets)
    @rule(data=st.data(), dt=DT, fate=st.sampled_from(["answered", "lost", "refused"]))
    def set_returns(self, data: st.DataObject, dt: float, fate: str) -> None:
        done = self.sets.pop(data.draw(st.integers(0, len(self.sets) - 1), label="set"))
        t = self._tick(dt)
        if fate == "answered":
            self.feed(SetAnswered(t, done.purpose, done.command_id))
        else:
            effects = self.feed(SetFailed(t, done.purpose, done.command_id, lost=fate == "lost"))
            if fate == "refused":
                assert not any(isinstance(e, SendCall) for e in effects), "a refused SET is never retried"

    @rule(dt=DT, drifted=st.booleans())
    def step_timed(self, dt: float, drifted: bool) -> None:
        m, took = self.manager, STEP * (1.5 if drifted else 0.5)
        noticed = m.notices(STEP, took)
        before = (m.mode, m.drifted_in_a_row)
        effects = self.feed(StepTimed(self._tick(dt), STEP, took))
        if not noticed:  # the shell does not report such a step: it must change nothing
            assert effects == [] and (m.mode, m.drifted_in_a_row) == before

    @precondition(lambda self: self.read_pending)
    @rule(dt=DT, greens=GREENS, readable=st.booleans())
    def controller_answers_the_recovery(self, dt: float, greens: frozenset[int], readable: bool) -> None:
        self.read_pending = False
        t = self._tick(dt)
        if readable:
            self.shown = self.read_greens = greens
            self.feed(ControllerRead(t, greens))
        else:
            self.feed(ControllerUnreadable(t, "no answer"))

    # Failures, recovery requests, keepalive switching and stale timers share one rule, so that they
    # come rarely enough for commands to run their course in between.
    @rule(data=st.data(), dt=DT,
          what=st.sampled_from(["failure", "recovery", "recovery", "keepalive_switch", "stale_timer", "controls_read",
                                "controls_read"]))
    def disturbance(self, data: st.DataObject, dt: float, what: str) -> None:
        t = self._tick(dt)
        mode = self.manager.mode
        if what == "failure":
            reason = data.draw(st.sampled_from([TimeoutReason.COMMUNICATION, TimeoutReason.TRANSITION]), label="why")
            self.feed(FailureDetected(t, reason, data.draw(st.text(max_size=5), label="detail")))
        elif what == "recovery":
            effects = self.feed(RecoveryRequested(t))
            if mode is not Mode.TIMEOUT:
                assert self.manager.mode is mode and not any(isinstance(e, SendCall) for e in effects)
        elif what == "controls_read":
            names = ("phaseControlGroupPhaseOmit", "phaseControlGroupPedOmit", "phaseControlGroupHold",
                     "phaseControlGroupForceOff", "phaseControlGroupPedCall")
            # Mostly clear (as a run sees them), sometimes one set by someone else.
            foreign = data.draw(st.sampled_from([frozenset()] * 3 + [frozenset({p}) for p in PHASES]), label="held")
            which = data.draw(st.sampled_from(names), label="object")
            self.feed(ControlsRead(t, tuple((n, foreign if n == which else frozenset()) for n in names)))
        elif what == "keepalive_switch":
            on = data.draw(st.booleans(), label="on")
            assert self.feed(KeepaliveSwitched(t, on)) == []
            assert self.manager.keepalive_on is on
        else:
            kind = data.draw(st.sampled_from(TimerKind), label="kind")
            token = data.draw(st.integers(-3, 0), label="token")
            assert self.feed(TimerExpired(t, kind, token)) == []
            assert self.manager.mode is mode

    @precondition(lambda self: self.manager.mode is not Mode.CLOSED)
    @rule(dt=DT)
    def close_sometimes(self, dt: float) -> None:
        # Rare: a closed machine only drops; give it a chance to show that.
        if dt > 14.0:
            self.feed(CloseRequested(self._tick(dt)))

    def teardown(self) -> None:
        if not self.consistent:
            return  # a rule failed: report that failure, not one that follows from it
        # A failure ends whatever is pending, so every dispatched command has now ended exactly once.
        if self.manager.mode in RUNNING:
            self.feed(FailureDetected(self.t + 1.0, TimeoutReason.COMMUNICATION))
        if self.manager.mode is not Mode.CLOSED:
            assert set(self.ended) == set(self.dispatched)
        assert set(self.ended.values()) <= DISPATCHED_OUTCOMES


ManagerMachine.TestCase.settings = settings(max_examples=200, stateful_step_count=60, deadline=None,
                                            suppress_health_check=[HealthCheck.too_slow])
TestManagerMachine = ManagerMachine.TestCase


def started(greens: frozenset[int] = frozenset({2, 6}), backup: int = 0) -> Manager:
    m = Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT,
                keepalive_period=CONFIG.middleware.keepalive_period or 0.0)
    m.handle(Started(0.0, greens, backup))
    return m


def test_a_full_duration_cycle_by_hand() -> None:
    """The path the random machine must be able to take: dispatch, verify, serve."""
    conv = ActionConverter(CONFIG, ActionType.DURATION)
    m = started()
    assert m.position == CONFIG.sequence.index((2, 6))
    cmd = conv.convert(0.5, m.position)
    effects: list[Any] = m.handle(CommandRequested(1.0, 1, cmd, frozenset({2, 6})))
    assert effects[0] == Dispatch(1, 1, Command((3, 7), green=11.5))
    assert effects[1] == SendCall(frozenset({3, 7}), Purpose.COMMAND, 1)
    assert effects[-1].kind is TimerKind.TRANSITION and effects[-1].delay == TAU_TRANS
    assert m.mode is Mode.IN_TRANSITION and m.state is State.ON_HOLD
    transition_token = effects[-1].token
    assert m.handle(SignalObserved(3.0, frozenset(), 2)) == []
    assert m.handle(CommandRequested(4.0, 2, cmd, frozenset())) == [Dropped(2, "on_hold")]
    effects = m.handle(SignalObserved(6.2, frozenset({3, 7}), 3))
    assert effects[0] == Verified(1, cmd, 3, effects[0].hold) and math.isclose(effects[0].hold, 5.2)
    assert effects[1].kind is TimerKind.DURATION and effects[1].delay == 11.5
    assert m.mode is Mode.SERVING and m.state is State.ON_HOLD
    assert m.handle(TimerExpired(11.0, TimerKind.TRANSITION, transition_token)) == [], "stale by now"
    effects = m.handle(TimerExpired(17.7, TimerKind.DURATION, effects[1].token))
    assert len(effects) == 1 and effects[0].command_id == 1 and effects[0].outcome == "served"
    assert math.isclose(effects[0].hold, 16.7)
    assert m.mode is Mode.IDLE and m.pending is None


def test_a_lost_command_set_is_retried_a_refused_one_is_not() -> None:
    m = started()
    m.handle(CommandRequested(0.0, 1, Command((3, 7)), frozenset({2, 6})))
    effects = m.handle(SetFailed(1.0, Purpose.COMMAND, 1, lost=True))
    assert effects[0] == SendCall(frozenset({3, 7}), Purpose.RETRY, 1)
    assert [type(e) for e in effects[1:]] == [StartTimer], "the retry re-arms the keepalive"
    assert m.handle(SetFailed(2.0, Purpose.RETRY, 1, lost=False)) == []
    assert m.handle(SetFailed(2.5, Purpose.KEEPALIVE, None, lost=True)) == []


def test_drift_enters_timeout_at_the_nth_consecutive_slow_step_and_recovery_restarts_the_count() -> None:
    m = started()
    for i in range(N_DRIFT - 1):
        assert m.handle(StepTimed(i, STEP, 1.0)) == [DriftSeen(STEP, 1.0, i + 1)]
    assert m.handle(StepTimed(5.0, STEP, 0.1)) == []
    assert m.drifted_in_a_row == 0
    for i in range(N_DRIFT):
        effects = m.handle(StepTimed(6.0 + i, STEP, 1.0))
    assert [type(e) for e in effects] == [DriftSeen, TimeoutEntered, HaltPolling]
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.DRIFT
    assert m.handle(StepTimed(20.0, STEP, 1.0)) == [], "drift is not counted in TIMEOUT"
    assert m.handle(RecoveryRequested(21.0)) == [RecoveryStarted(), ReadController()]
    effects = m.handle(ControllerRead(21.1, frozenset({4, 8})))
    assert effects[0] == SendCall(frozenset({4, 8}), Purpose.RECOVERY) and m.position == 3
    assert m.mode is Mode.RECOVERING and m.state is State.TIMEOUT
    assert m.handle(SetAnswered(21.2, Purpose.RECOVERY, None)) == [Recovered(frozenset({4, 8})), ResumePolling()]
    assert m.mode is Mode.IDLE and m.drifted_in_a_row == 0 and m.timeout_reason is None


def test_a_start_up_read_ending_after_a_drift_timeout_or_a_close_changes_no_state() -> None:
    """At the wall clock a large grid's steps can drift while its controllers still start: the start-up read
    then ends in TIMEOUT (or, after Ctrl-C, in CLOSED). What it read is kept; the recovery resumes from it."""
    m = Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT, keepalive_period=10.0)
    for i in range(N_DRIFT):
        m.handle(StepTimed(i * STEP, STEP, 1.0))
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.DRIFT
    effects = m.handle(Started(2.0, frozenset({4, 8}), 30))
    assert m.mode is Mode.TIMEOUT and m.position == CONFIG.sequence.index((4, 8))
    assert not any(isinstance(e, SendCall) for e in effects), "nothing is sent in TIMEOUT"
    assert m.handle(RecoveryRequested(3.0)) == [RecoveryStarted(), ReadController()]
    effects = m.handle(Started(3.1, frozenset({4, 8}), 30))
    assert m.mode is Mode.RECOVERING and not any(isinstance(e, SendCall) for e in effects)
    closed = Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT, keepalive_period=10.0)
    closed.handle(CloseRequested(0.5))
    assert closed.handle(Started(1.0, frozenset({2, 6}), 30)) == [] and closed.mode is Mode.CLOSED


def test_keepalive_is_gated_in_timeout_and_off_and_resumes_after_recovery() -> None:
    m = started(backup=30)
    assert m.keepalive_period == 10.0
    effects = m.handle(CommandRequested(0.0, 1, Command((3, 7)), frozenset({2, 6})))
    token = next(e.token for e in effects if isinstance(e, StartTimer) and e.kind is TimerKind.KEEPALIVE)
    m.handle(SignalObserved(6.0, frozenset({3, 7}), 1))
    effects = m.handle(TimerExpired(10.0, TimerKind.KEEPALIVE, token))
    assert effects[0] == SendCall(frozenset({3, 7}), Purpose.KEEPALIVE)
    token = effects[1].token
    m.handle(KeepaliveSwitched(12.0, False))
    effects = m.handle(TimerExpired(20.0, TimerKind.KEEPALIVE, token))
    assert [type(e) for e in effects] == [StartTimer], "switched off: no SET, the timer runs on"
    m.handle(KeepaliveSwitched(21.0, True))
    m.handle(FailureDetected(25.0, TimeoutReason.COMMUNICATION))
    assert m.handle(TimerExpired(30.0, TimerKind.KEEPALIVE, effects[0].token)) == [], "gated in TIMEOUT"
    m.handle(RecoveryRequested(31.0))
    effects = m.handle(ControllerRead(31.1, frozenset({3, 7})))
    assert any(isinstance(e, StartTimer) and e.kind is TimerKind.KEEPALIVE for e in effects), "the recovery re-arms"


def test_close_clears_the_call_and_then_nothing_is_sent() -> None:
    m = started(backup=30)
    m.handle(CommandRequested(0.0, 1, Command((3, 7)), frozenset({2, 6})))
    assert m.handle(CloseRequested(1.0)) == [HaltPolling(), SendCall(frozenset(), Purpose.CLEAR)]
    for ev in (CommandRequested(2.0, 2, Command((4, 8)), frozenset()), TimerExpired(10.0, TimerKind.KEEPALIVE, 1),
               FailureDetected(11.0, TimeoutReason.COMMUNICATION), RecoveryRequested(12.0)):
        assert not any(isinstance(e, SendCall) for e in m.handle(ev))
    assert m.mode is Mode.CLOSED and m.state is None


def test_every_state_names_its_paper_state_and_the_table_covers_every_event() -> None:
    from hils.manager import _TRANSITIONS, Ev

    assert {mode.paper for mode in Mode} == {*State, None}
    plain = {Ev.STARTED, Ev.COMMAND, Ev.KEEP, Ev.VERIFIED, Ev.VERIFIED_DURATION, Ev.TRANSITION_EXPIRED,
             Ev.DURATION_ELAPSED, Ev.COMMAND_SET_LOST, Ev.CONTROLLER_READ, Ev.CONTROLLER_UNREADABLE,
             Ev.RECOVERY_SET_ANSWERED, Ev.RECOVERY_SET_FAILED, Ev.CLEAR_LOST}
    for mode in Mode:
        for ev in Ev:
            if ev not in plain:
                assert (mode, ev) in _TRANSITIONS, f"{ev.name} can reach {mode.name} but has no entry"
