"""Properties of the manager's state machine, driven directly (it is pure: no SimPy).

Hypothesis plays the shell and the world: it starts the machine (start-up reads that get no answer, a
refusal, or a read), converts random action values (valid and invalid) through the converters of the
shipped config at the manager's sequence position, sends polls and settles them in any order (answered,
failed, late, or from before a halt), fires the timers the manager asked for in random order (and stale
tokens), answers, refuses or loses the SETs it asked for, times simulation steps (drift), asks for
read-backs and answers them, asks for recovery and answers its re-read, switches the keepalive and
closes the run, with time never going back; some polls read a preempt in service, and any poll that reads none
reports the preemption over. Every effect the manager returns is checked against the
rules of the paper as it comes out: what may be sent in which state, retries, the gating of the
keepalive and of the read-back, failed polls counted in a row, start-up attempts, drift counting,
recovery and its timer, the close and the sequence position; and preemption: PREEMPTED entered from any
commanding state when a poll reads a preempt in service, nothing but the keepalive of no call sent in it, every
action refused as preempted, no TIMEOUT but for failures of the run's own side, and IDLE again as soon as a poll
reads the preemption over.
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass
from typing import Any

import hypothesis.strategies as st
import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis.stateful import RuleBasedStateMachine, initialize, precondition, rule

from hils.control.actions import PAPER_ACTION_TYPES, ActionConverter, ActionError, ActionType, Command, PreemptedError
from hils.control.manager import CLEAR_ATTEMPTS, Ev, Manager, Mode, State, graph
from hils.control.manager_io import (
    AgentOverdue,
    AnotherManager,
    CallsFound,
    CallsWatched,
    CloseDone,
    CloseRequested,
    CommandEnded,
    CommandRequested,
    ControllerRead,
    ControllerUnreachable,
    ControllerUnreadable,
    ControlsRead,
    ControlsReset,
    Dispatch,
    DriftSeen,
    Dropped,
    Effect,
    Event,
    HaltPolling,
    KeepaliveSwitched,
    Note,
    OrderChanged,
    PollAnswered,
    PollFailed,
    PollFailureSeen,
    PreemptBegan,
    PreemptEnded,
    Purpose,
    ReadbackDue,
    ReadController,
    ReadControls,
    Recovered,
    RecoveryRequested,
    RecoveryStarted,
    Refused,
    ResumePolling,
    RetryStartup,
    ScheduleBegan,
    ScheduleEnded,
    ScheduleRequested,
    SendCall,
    SendControls,
    SetAnswered,
    SetFailed,
    ShowSignal,
    Started,
    StartTimer,
    StartupDone,
    StartupLost,
    StartupRefused,
    StepTimed,
    TimeoutEntered,
    TimeoutReason,
    TimerExpired,
    TimerKind,
    Verified,
    WatchCalls,
)
from hils.control.phase_control import Control
from hils.protocol.config import load
from hils.protocol.ntcip import CONTROL_TABLE, ControlColumn, SignalState

CONFIG = load()
PHASES = CONFIG.phase_numbers
TAU_TRANS = CONFIG.middleware.tau_trans
N_TIMEOUT = CONFIG.middleware.n_timeout
RECOVER_AFTER = 5.0
WATCH, WATCH_PERIOD = 20.0, 0.1
DISPATCHED_OUTCOMES = {"verified", "served", "timeout", "preempted"}

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
RUNNING = (Mode.IDLE, Mode.IN_TRANSITION, Mode.SERVING, Mode.SCHEDULED)  # commanding
WORKING = (*RUNNING, Mode.PREEMPTED)  # polling, keepalive, drift, read-back
DOWN = (Mode.TIMEOUT, Mode.RECOVERING)
PREEMPTS = st.frozensets(st.integers(1, 4), min_size=1, max_size=2)


def shown(greens: frozenset[int]) -> SignalState:
    return SignalState(frozenset(PHASES) - greens, frozenset(), greens)


def manager(recover_after: float | None = RECOVER_AFTER, keepalive_period: float | None = None) -> Manager:
    return Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT, n_timeout=N_TIMEOUT,
                   keepalive_period=(CONFIG.middleware.keepalive_period or 0.0) if keepalive_period is None
                   else keepalive_period, recover_after=recover_after, watch=WATCH, watch_period=WATCH_PERIOD)


@dataclass
class Outstanding:
    """A SET the manager asked for, whose answer the world has not given yet."""

    purpose: Purpose
    command_id: int | None
    phases: frozenset[int]


@dataclass
class InFlight:
    """A poll sent, not settled yet: its id and the polling period it went out in."""

    poll_id: int
    epoch: int


class ManagerMachine(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.manager = manager()
        self.converters = {t: ActionConverter(CONFIG, t) for t in PAPER_ACTION_TYPES}
        self.t = 0.0
        self.actions = 0
        self.polls = 0
        self.in_flight: list[InFlight] = []
        self.epoch = 0  # one more at every HaltPolling, as the poller's polling periods
        self.newest = 0  # the newest poll answered and applied
        self.failed_ids: set[int] = set()  # the polls of this polling period that failed
        self.timers: list[tuple[float, TimerKind, int]] = []  # started, not yet fired
        self.fired: set[int] = set()
        self.keepalive_token: int | None = None  # the latest keepalive timer armed
        self.recover_token: int | None = None  # the latest recovery timer armed
        self.sets: list[Outstanding] = []
        self.last_set = -math.inf
        self.sets_sent = 0  # VehCall SETs sent
        self.set_unsure = False  # a SET failed since the last was sent: what the controller holds is unsure
        self.readback: tuple[int, bool] = (-1, False)  # SETs sent when the read-back went out; could it judge?
        self.found: tuple[float, frozenset[int]] | None = None  # someone's calls the start-up found
        self.drifted = 0  # consecutive drifted steps while working, as the paper counts them
        self.dispatched: dict[int, Command] = {}
        self.dispatched_at: dict[int, float] = {}
        self.ended: dict[int, str] = {}
        self.keeps: set[int] = set()
        self.open: int | None = None  # the dispatched command not yet ended
        self.read_pending = False  # the recovery asked to re-read the controller
        self.clears_lost = 0  # clearing SETs (after the close) whose datagram got no answer
        self.close_done = 0
        self.read_greens: frozenset[int] = frozenset()
        self.shown: frozenset[int] = frozenset()
        self.preempted_at = 0.0  # when the manager last entered PREEMPTED
        self.consistent = True  # False once a check failed: the trackers no longer match the manager

    # --- the shell -----------------------------------------------------------------------------

    def _tick(self, dt: float) -> float:
        assert dt >= 0.0
        self.t += dt
        return self.t

    def feed(self, ev: Event) -> list[Effect]:
        m = self.manager
        self.consistent = False
        before, open_before, position_before, call_before = m.mode, self.open, m.position, m.call
        sent_before, running_before, sets_sent_before = dict(m.sent), m.running, self.sets_sent
        effects = m.handle(ev)
        after = m.mode

        # Where the machine may go.
        if before in DOWN and after not in (*DOWN, Mode.CLOSED):
            assert before is Mode.RECOVERING and isinstance(ev, SetAnswered) and ev.purpose is Purpose.RECOVERY, (
                f"left TIMEOUT on {ev}")
        if before is Mode.STARTING and after is Mode.IDLE:
            assert isinstance(ev, Started) and effects[-1] == StartupDone()
        if after is Mode.STARTING:
            assert before is Mode.STARTING, "nothing goes back to the start-up"
        if before is Mode.CLOSED:
            # Closed, only this happens: a command is dropped, a clear that got no answer is sent again, the
            # close ends, the start-up (if it was still going) ends.
            assert after is Mode.CLOSED and all(isinstance(e, Dropped | SendCall | SendControls | CloseDone
                                                           | StartupDone) for e in effects), f"closed, yet {effects}"
            if isinstance(ev, SetFailed) and ev.purpose is Purpose.CLEAR:
                self.clears_lost += ev.lost
                again = ev.lost and self.clears_lost < CLEAR_ATTEMPTS
                assert effects == ([self.let_go(Purpose.CLEAR)] if again else [CloseDone(ev.error)]), (
                    "a lost clear is sent again, CLEAR_ATTEMPTS times in all; then the close is over")
            if isinstance(ev, SetAnswered) and ev.purpose is Purpose.CLEAR:
                assert effects == [CloseDone()]
        if isinstance(ev, CommandRequested | ScheduleRequested) and before is Mode.PREEMPTED:
            (refused,) = effects
            assert isinstance(refused, Refused) and refused.action_id == ev.action_id
            assert isinstance(refused.error, PreemptedError) and refused.error.reason == "preempted"
            assert after is Mode.PREEMPTED
        elif (isinstance(ev, CommandRequested) and before is not Mode.IDLE) or (
                isinstance(ev, ScheduleRequested) and before not in (Mode.IDLE, Mode.SCHEDULED)):
            assert effects == [Dropped(ev.action_id, before.log_name)]
        assert (m.refusal() is not None) == (after is Mode.PREEMPTED), "refused exactly while PREEMPTED"
        if isinstance(ev, CloseRequested) and before is not Mode.CLOSED:
            assert after is Mode.CLOSED and effects[0] == HaltPolling()
            if self.last_set > -math.inf:
                assert effects[-1] == self.let_go(Purpose.CLEAR), "closing clears the call"
            else:
                assert effects == [HaltPolling(), CloseDone()], "nothing was SET, nothing to clear"

        # Start-up: attempts without answer are counted; the n_timeout-th is a communication TIMEOUT.
        if isinstance(ev, StartupLost) and before is not Mode.CLOSED:
            attempt = m.startup_attempts
            assert effects[0] == PollFailureSeen(0, f"start-up read: {ev.error}", attempt)
            if attempt < N_TIMEOUT:
                assert effects[1:] == [RetryStartup()] and after is before
            else:
                assert ControllerUnreachable(N_TIMEOUT) in effects and effects[-1] == StartupDone()
                assert after is (Mode.TIMEOUT if before is Mode.STARTING else before)
        if isinstance(ev, StartupRefused) and before is not Mode.CLOSED:
            assert effects[0] == Note(f"start-up: {ev.detail}") and effects[-1] == StartupDone()
            assert after is (Mode.TIMEOUT if before is Mode.STARTING else before)

        # Polls: answers applied in poll order, results from before a halt ignored, failures counted in a row.
        if isinstance(ev, PollAnswered | PollFailed) and ev.epoch != self.epoch:
            assert effects == [] and after is before, "a poll sent before the halt changed something"
        elif isinstance(ev, PollAnswered):
            assert before in WORKING, f"a poll of this period answered in {before.name}"
            if ev.poll_id < self.newest:
                assert effects == [] and after is before, "a late answer changed something"
            else:
                # logged whatever it shows when it is the first answer after failed polls (in poll order)
                after_failures = any(self.newest < i < ev.poll_id for i in self.failed_ids)
                assert effects[0] == ShowSignal(ev.poll_id, ev.state, after_failures)
                self.newest = ev.poll_id
                self.shown = ev.state.greens
                # A preempt in service is PREEMPTED from any commanding state; a poll reading none ends it.
                assert (after is Mode.PREEMPTED) == bool(ev.preempts), f"{before.name} -> {after.name} on {ev}"
                if before is not Mode.PREEMPTED and ev.preempts:
                    assert PreemptBegan(ev.preempts, open_before) in effects
                    assert m.preempts == ev.preempts and m.preempted_since == ev.t
                    withdrawn = self.let_go(Purpose.WITHDRAW) in effects
                    # (under phase control, less the force-offs this very poll saw spent: the controller reset them)
                    spent = {e.change.order.phase for e in effects
                             if isinstance(e, OrderChanged) and e.change.after.name == "SPENT"}
                    held = (any(p - spent if c is ControlColumn.FORCE_OFF else p for c, p in sent_before.items())
                            if m.phase_control else bool(call_before))
                    assert withdrawn == held, "the interrupted call is withdrawn (when there is one)"
                elif before is Mode.PREEMPTED and not ev.preempts:
                    assert effects[1:] == [PreemptEnded(ev.t - self.preempted_at, ev.state.greens)]
                    assert after is Mode.IDLE
        elif isinstance(ev, PollFailed):
            # n_timeout polls of consecutive ids that all failed, in poll order, whatever order they settled in.
            assert before in WORKING, f"a poll of this period failed in {before.name}"
            self.failed_ids.add(ev.poll_id)
            ids = sorted(self.failed_ids)
            blocks, start = [], 0
            for i in range(1, len(ids) + 1):
                if i == len(ids) or ids[i] != ids[i - 1] + 1:
                    blocks.append(ids[start:i])
                    start = i
            run = next(len(b) for b in blocks if ev.poll_id in b)
            assert effects[0] == PollFailureSeen(ev.poll_id, ev.error, run)
            if run >= N_TIMEOUT:
                assert after is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.COMMUNICATION
            else:
                assert effects == [effects[0]] and after is before
        if isinstance(ev, ReadbackDue):
            failing = any(i > self.newest for i in self.failed_ids)
            expected = [ReadControls()] if before in WORKING and not failing else []
            assert effects == expected, "the read-back goes out while working and no poll fails, and only then"
            if effects:
                self.readback = (self.sets_sent, not self.sets and not self.set_unsure)
        if isinstance(ev, SetFailed):
            self.set_unsure = True
        # Someone's calls found at start-up are watched, unless gone; calls that change are another manager.
        if isinstance(ev, CallsFound) and before is Mode.STARTING:
            assert effects[-1:] == ([WatchCalls(WATCH_PERIOD)] if ev.calls else [])
            self.found = (ev.t, ev.calls)
        if isinstance(ev, CallsWatched) and before is Mode.STARTING:
            since, found = self.found
            if ev.calls != found:
                assert after is Mode.TIMEOUT and isinstance(effects[0], AnotherManager)
                assert effects[-1] == StartupDone() and m.timeout_reason is TimeoutReason.FOREIGN_CONTROL
                assert not any(isinstance(e, SendCall | SendControls) for e in effects), (
                    "nothing is SET on someone's controller")
            else:
                assert after is Mode.STARTING
                assert effects == ([] if ev.t - since >= WATCH else [WatchCalls(WATCH_PERIOD)])

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
                    assert not m.phase_control, "a phase-control run SETs the control objects, never VehCall alone"
                    self._check_send(ev, before, phases, purpose, command_id)
                case SendControls(controls, purpose):
                    assert m.phase_control, "a run of phase commands SETs VehCall alone"
                    self._check_controls(ev, before, after, dict(controls), purpose, effects, sent_before)
                case ScheduleBegan(action_id, schedule):
                    assert isinstance(ev, ScheduleRequested) and (action_id, schedule) == (ev.action_id, ev.schedule)
                    assert before in (Mode.IDLE, Mode.SCHEDULED) and schedule.orders and m.running is not None
                case ScheduleEnded(reason):
                    assert running_before is not None and m.running is not running_before
                    assert reason == {ScheduleRequested: "replaced" if getattr(ev, "schedule", None) and
                                      ev.schedule.orders else "cleared", CloseRequested: "closed",
                                      PollAnswered: "preempted", TimerExpired: "done"}[type(ev)]
                case OrderChanged(change):
                    assert change.before is not change.after
                    if change.after.name == "SPENT":
                        assert change.order.phase not in m.sent[ControlColumn.FORCE_OFF], "the controller reset it"
                case ControlsReset():
                    assert isinstance(ev, ControlsRead | ControllerRead) and m.phase_control
                    assert isinstance(ev, ControlsRead) or ev.backup_mode
                case StartTimer(kind, delay, token):
                    assert token not in self.fired and all(token != t for _, _, t in self.timers)
                    if kind is TimerKind.KEEPALIVE:
                        assert delay == m.keepalive_period > 0
                        self.keepalive_token = token
                    elif kind is TimerKind.RECOVER:
                        assert delay == RECOVER_AFTER and after is Mode.TIMEOUT
                        assert any(isinstance(e, TimeoutEntered) for e in effects) or isinstance(
                            ev, ControllerUnreadable | SetFailed), "the recovery timer starts on entering TIMEOUT"
                        self.recover_token = token
                    elif kind is TimerKind.TRANSITION:
                        assert delay == TAU_TRANS and isinstance(ev, CommandRequested)
                    elif kind is TimerKind.CONTROL:
                        assert delay >= 0 and token == m._control_token and m.running is not None
                        assert isinstance(ev, ScheduleRequested | TimerExpired)
                    else:
                        command = self.dispatched[self.open]
                        assert isinstance(ev, PollAnswered) and set(command.phases) <= ev.state.greens
                        assert command.green is not None and delay == command.green
                    self.timers.append((ev.t + delay, kind, token))
                case Verified(command_id, command, poll_id, hold):
                    assert command_id == self.open and command == self.dispatched[command_id]
                    assert isinstance(ev, PollAnswered) and poll_id == ev.poll_id
                    assert set(command.phases) <= ev.state.greens
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
                    if outcome == "preempted":
                        assert isinstance(ev, PollAnswered) and ev.preempts and after is Mode.PREEMPTED
                    elif outcome == "verified":
                        assert green is None and isinstance(ev, PollAnswered)
                    elif outcome == "served":
                        assert green is not None and isinstance(ev, TimerExpired) and ev.kind is TimerKind.DURATION
                    assert math.isclose(hold, ev.t - self.dispatched_at[command_id]) and hold >= 0
                    self.ended[command_id] = outcome
                    self.open = None
                case Dropped(action_id, state):
                    assert isinstance(ev, CommandRequested | ScheduleRequested) and action_id == ev.action_id
                    assert state == before.log_name and before is not Mode.IDLE
                case TimeoutEntered(reason, _detail, command_id):
                    assert after is Mode.TIMEOUT and before in (Mode.STARTING, *WORKING)
                    assert command_id == open_before
                    assert HaltPolling() in effects, "polling halts in TIMEOUT"
                    if isinstance(ev, PollFailed | StartupLost | StartupRefused):
                        assert reason is TimeoutReason.COMMUNICATION
                    elif isinstance(ev, StepTimed):
                        assert reason is TimeoutReason.DRIFT and self.drifted + 1 == N_DRIFT
                    elif isinstance(ev, ControlsRead | CallsWatched):
                        assert reason is TimeoutReason.FOREIGN_CONTROL
                    elif isinstance(ev, AgentOverdue):
                        assert reason is TimeoutReason.AGENT
                    else:
                        assert isinstance(ev, TimerExpired) and ev.kind is TimerKind.TRANSITION
                        assert reason is TimeoutReason.TRANSITION
                case DriftSeen(step, took, consecutive):
                    assert isinstance(ev, StepTimed) and took > step and before in (Mode.STARTING, *WORKING)
                    assert consecutive == self.drifted + 1
                case RecoveryStarted() | ReadController():
                    assert before is Mode.TIMEOUT and after is Mode.RECOVERING
                    by_timer = isinstance(ev, TimerExpired) and ev.kind is TimerKind.RECOVER
                    assert isinstance(ev, RecoveryRequested) or (by_timer and ev.token == self.recover_token)
                    self.read_pending = True
                case Recovered(greens):
                    assert before is Mode.RECOVERING and after in (Mode.IDLE, Mode.SCHEDULED)
                    assert ResumePolling() in effects
                    assert greens == self.read_greens, "recovered to what the re-read showed"
                case HaltPolling():
                    self.epoch += 1
                    self.in_flight = []  # whatever was sent: its result is from before the halt
                case PreemptBegan():
                    assert before in RUNNING and after is Mode.PREEMPTED
                    self.preempted_at = ev.t
                case PreemptEnded() | Refused():
                    pass  # checked above with the poll and the command that made them
                case CloseDone():
                    self.close_done += 1
                    assert self.close_done == 1, "the close ended twice"
                case (ResumePolling() | Note() | ShowSignal() | PollFailureSeen() | ReadControls() | RetryStartup()
                      | StartupDone() | ControllerUnreachable() | WatchCalls() | AnotherManager()):
                    pass
                case _:
                    raise AssertionError(f"unknown effect {eff!r}")

        # A control object the run never sets found set while working is a TIMEOUT; so is VehCall other than the
        # call last SET, read when no SET of the run could race with the read; else nothing happens.
        if isinstance(ev, ControlsRead) and m.phase_control:
            self._check_read_back(ev, before, after, effects, sent_before, sets_sent_before)
        elif isinstance(ev, ControlsRead):
            sent_then, clean = self.readback
            foreign = any(phases for _name, phases in ev.held) or (
                ev.veh_call is not None and clean and sent_then == self.sets_sent and ev.veh_call != m.call)
            if before in WORKING and foreign:
                assert after is Mode.TIMEOUT and any(isinstance(e, TimeoutEntered) for e in effects)
            else:
                assert after is before and effects == []
        # Drift is counted while the machine works and only then; an on-time step resets the count.
        if isinstance(ev, StepTimed) and before in (Mode.STARTING, *WORKING):
            self.drifted = self.drifted + 1 if ev.took > ev.step else 0
        if isinstance(ev, SetAnswered) and before is Mode.RECOVERING and ev.purpose is Purpose.RECOVERY:
            self.drifted = 0
            self.failed_ids.clear()
        if after in (Mode.IDLE, Mode.SCHEDULED) and before is Mode.RECOVERING:
            assert m.drifted_in_a_row == 0 and not m.polls_failing
        if (before is Mode.RECOVERING and isinstance(ev, ControllerRead)) or any(
                isinstance(e, PreemptEnded) for e in effects):
            shows = ev.greens if isinstance(ev, ControllerRead) else ev.state.greens
            expected = next((i for i, pair in enumerate(CONFIG.sequence) if set(pair) <= shows), position_before)
            assert m.position == expected, "recovery and the end of preemption align the position with the greens"
        elif not any(isinstance(e, Dispatch) for e in effects) and not isinstance(ev, Started):
            assert m.position == position_before, ("only a dispatch, the start-up, a recovery or the end of preemption "
                                                   "moves the position")

        assert (self.open is not None) == (after in (Mode.IN_TRANSITION, Mode.SERVING)) or after is Mode.CLOSED
        assert (m.pending is None) == (self.open is None)
        assert m.state is after.paper
        assert after is not Mode.PREEMPTED or m.call == frozenset(), "no call stands while preempted"
        if m.phase_control:
            self._check_held(before, after, ev)
        assert len(self.dispatched) - len(self.ended) <= 1
        assert m.poll_epoch == self.epoch
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
            assert before in WORKING, f"keepalive in {before.name}"
            assert isinstance(ev, TimerExpired) and ev.token == self.keepalive_token
            assert m.keepalive_on and phases == m.call
            assert ev.t - self.last_set >= m.keepalive_period - 1e-9, "keepalive before a period without a SET"
        elif purpose is Purpose.RECOVERY:
            assert before is Mode.RECOVERING and isinstance(ev, ControllerRead) and phases == ev.greens
        elif purpose is Purpose.WITHDRAW:
            assert before in RUNNING and isinstance(ev, PollAnswered) and ev.preempts and phases == frozenset()
        else:
            assert isinstance(ev, CloseRequested | SetFailed) and phases == frozenset()
            assert isinstance(ev, CloseRequested) or (ev.purpose is Purpose.CLEAR and ev.lost)
        if purpose is not Purpose.RECOVERY:
            assert before in WORKING or purpose is Purpose.CLEAR, f"{purpose} SET in {before.name}"
        if before is Mode.PREEMPTED:  # no command ever: the keepalive of no call, and the close's clear
            assert purpose in (Purpose.KEEPALIVE, Purpose.CLEAR) and phases == frozenset(), f"{purpose} SET preempted"
        self._sent(ev, purpose, command_id, phases)

    def _sent(self, ev: Event, purpose: Purpose, command_id: int | None, phases: frozenset[int]) -> None:
        self.last_set = ev.t
        self.sets_sent += 1
        self.set_unsure = False
        self.sets.append(Outstanding(purpose, command_id, phases))

    def let_go(self, purpose: Purpose) -> SendCall | SendControls:
        """The SET that lets go of what the run holds: VehCall at 0, or, under phase control, all six objects."""
        if self.manager.phase_control:
            return SendControls(tuple((c, frozenset()) for c in ControlColumn), purpose)
        return SendCall(frozenset(), purpose)

    def _check_controls(self, ev: Event, before: Mode, after: Mode, controls: dict[ControlColumn, frozenset[int]],
                        purpose: Purpose, effects: list[Effect], sent_before: dict[ControlColumn, frozenset[int]],
                        ) -> None:
        """A SET of the control objects (phase control): only where, when and what the rules allow."""
        m = self.manager
        for phases in controls.values():
            assert phases <= set(PHASES), f"a SET of unknown phases {controls}"
        assert m.keepalive_period == 0 or purpose is Purpose.CLEAR or any(
            isinstance(e, StartTimer) and e.kind is TimerKind.KEEPALIVE for e in effects), (
            "every SET but the close's restarts the keepalive: the backup timer never runs out while at work")
        everything = set(controls) == set(ControlColumn)
        if purpose is Purpose.SCHEDULE:
            assert (before in (Mode.IDLE, Mode.SCHEDULED) and isinstance(ev, ScheduleRequested | TimerExpired)) or (
                before is Mode.RECOVERING and isinstance(ev, SetAnswered) and after is Mode.SCHEDULED)
            assert all(controls[c] != sent_before[c] for c in controls), "only the objects that change are SET"
        elif purpose is Purpose.KEEPALIVE:
            assert before in WORKING and isinstance(ev, TimerExpired) and ev.token == self.keepalive_token
            assert m.keepalive_on and ev.t - self.last_set >= m.keepalive_period - 1e-9
            assert ControlColumn.FORCE_OFF not in controls and ControlColumn.VEH_CALL in controls
            assert controls == {c: p for c, p in sent_before.items() if c in controls}, "SET again as they stand"
            assert all(controls[c] for c in controls if c is not ControlColumn.VEH_CALL)
        elif purpose is Purpose.RECOVERY:
            assert before is Mode.RECOVERING and isinstance(ev, ControllerRead) and everything
        elif purpose is Purpose.REESTABLISH:
            assert before in WORKING and isinstance(ev, ControlsRead) and everything
            assert any(isinstance(e, ControlsReset) for e in effects)
        elif purpose is Purpose.RELEASE:
            assert after is Mode.TIMEOUT and before is not Mode.TIMEOUT and everything
            assert not any(controls.values()) and any(sent_before.values()), "let go, when holding anything"
        elif purpose is Purpose.WITHDRAW:
            assert isinstance(ev, PollAnswered) and ev.preempts and after is Mode.PREEMPTED
            assert everything and not any(controls.values())
        else:
            assert purpose is Purpose.CLEAR and everything and not any(controls.values())
            assert isinstance(ev, CloseRequested) or (isinstance(ev, SetFailed) and ev.purpose is Purpose.CLEAR)
        self._sent(ev, purpose, None, controls.get(ControlColumn.VEH_CALL, frozenset()))

    def _check_held(self, before: Mode, after: Mode, ev: Event) -> None:
        """Phase control: what the run holds is what the running schedule asks, while it commands, and nothing
        while it does not; and never what a schedule may not ask."""
        m = self.manager
        held = m.sent
        asked = m.running.image() if m.running is not None else {c: frozenset() for c in ControlColumn}
        if after in (Mode.IDLE, Mode.SCHEDULED):
            assert held == asked, f"holds {held}, the schedule asks {asked}"
            assert (after is Mode.SCHEDULED) == (m.running is not None)
        if after in (Mode.PREEMPTED, Mode.TIMEOUT):
            assert not any(held.values()), f"{after.name} and still holding {held}"
        if after in WORKING and m.backup_time and m.keepalive_on and any(held.values()):
            # MMITSS re-sends every active command each (backup time - 1) s; ours is due no later
            due = [d for d, _kind, token in self.timers if token == self.keepalive_token]
            assert due and due[0] <= self.last_set + m.backup_time - 1 + 1e-9, (
                f"holding {held}, last SET at {self.last_set}, backup time {m.backup_time} s, keepalive due {due}")
        c = ControlColumn
        for a, b in ((c.HOLD, c.FORCE_OFF), (c.VEH_CALL, c.PHASE_OMIT), (c.PED_CALL, c.PED_OMIT),
                     (c.HOLD, c.PHASE_OMIT)):
            assert not held[a] & held[b], f"{a.name} and {b.name} on {sorted(held[a] & held[b])}"
        assert not any(set(ring) <= held[c.PHASE_OMIT] for ring in CONFIG.rings), "a whole ring omitted"
        if isinstance(ev, ScheduleRequested) and before in (Mode.IDLE, Mode.SCHEDULED):
            assert after is (Mode.SCHEDULED if ev.schedule.orders else Mode.IDLE)

    # --- rules ---------------------------------------------------------------------------------

    @initialize(greens=GREENS, backup=BACKUP, lost=st.integers(0, N_TIMEOUT), refused=st.integers(0, 7),
                meanwhile=st.lists(st.sampled_from(["on_time", "drifted", "drift_limit", "keepalive", "recovery",
                                                    "command", "stale_timer", "close"]), max_size=3),
                found=st.sampled_from([frozenset(), frozenset(), frozenset({2, 6})]),
                watched=st.lists(st.sampled_from([frozenset({2, 6}), frozenset({2, 6}), frozenset({4, 8})]),
                                 max_size=4))
    def start(self, greens: frozenset[int], backup: int, lost: int, refused: int, meanwhile: list[str],
              found: frozenset[int], watched: list[frozenset[int]]) -> None:
        # Mostly a read after a few attempts without answer; sometimes no answer at all, a refusal, and the run
        # going on while the controller is read (its steps drifting into a TIMEOUT, even a close).
        for what in meanwhile:
            t = self._tick(0.25)
            if what in ("on_time", "drifted"):
                self.feed(StepTimed(t, STEP, 1.0 if what == "drifted" else 0.1))
            elif what == "drift_limit":
                for _ in range(N_DRIFT):
                    self.feed(StepTimed(self._tick(0.25), STEP, 1.0))
            elif what == "keepalive":
                self.feed(KeepaliveSwitched(t, True))
            elif what == "recovery":
                self.feed(RecoveryRequested(t))
            elif what == "command":
                self.feed(CommandRequested(t, 0, Command((2, 6), keep=True), frozenset()))
            elif what == "stale_timer":
                self.feed(TimerExpired(t, TimerKind.TRANSITION, -1))
            else:
                self.feed(CloseRequested(t))
        for _ in range(lost):
            self.feed(StartupLost(self._tick(1.0), "CommunicationTimeout: no answer within 1.0 s"))
        if lost == N_TIMEOUT:
            return
        if refused == 0:
            self.feed(StartupRefused(self._tick(0.002), "the controller refuses to be written (noAccess)"))
            return
        effects = self.feed(CallsFound(self._tick(0.006), found))
        for calls in watched:
            if not any(isinstance(e, WatchCalls) for e in effects):
                break
            effects = self.feed(CallsWatched(self._tick(WATCH / 3), calls))
        if any(isinstance(e, StartupDone) for e in effects):
            return  # another manager: the run refuses to start
        self.feed(Started(self._tick(0.0135), greens, backup))
        self.shown = greens

    @rule(data=st.data(), action_type=st.sampled_from(PAPER_ACTION_TYPES), dt=DT)
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

    def _send_poll(self) -> InFlight | None:
        """A poll goes out, as the poller sends one per period while polling is not halted."""
        if self.manager.mode not in WORKING:
            return None
        self.polls += 1
        poll = InFlight(self.polls, self.epoch)
        self.in_flight.append(poll)
        return poll

    @rule(dt=DT, greens=GREENS, with_pending=st.booleans())
    def observe(self, dt: float, greens: frozenset[int], with_pending: bool) -> None:
        """A poll answered at once (the usual case)."""
        poll = self._send_poll()
        if poll is None:
            return
        self.in_flight.remove(poll)
        if with_pending and self.open is not None:
            greens |= set(self.dispatched[self.open].phases)
        self.feed(PollAnswered(self._tick(dt), poll.poll_id, poll.epoch, shown(greens)))

    @rule(dt=DT, greens=GREENS, preempts=PREEMPTS)
    def observe_preempted(self, dt: float, greens: frozenset[int], preempts: frozenset[int]) -> None:
        """A poll answered at once reading a preempt in service (a lower-numbered one may take over)."""
        poll = self._send_poll()
        if poll is None:
            return
        self.in_flight.remove(poll)
        effects = self.feed(PollAnswered(self._tick(dt), poll.poll_id, poll.epoch, shown(greens), preempts))
        assert not any(isinstance(e, SendCall | SendControls) and e.purpose is not Purpose.WITHDRAW for e in effects)

    @precondition(lambda self: self.open is not None)
    @rule(dt=DT, greens=GREENS)
    def observe_commanded(self, dt: float, greens: frozenset[int]) -> None:
        # The controller showing what was asked, as it usually does: gives verification a chance
        # against the transition timer that timer_fires may pick first.
        self.observe(dt, greens, with_pending=True)

    @rule(polls=st.integers(1, 8))
    def polls_go_out(self, polls: int) -> None:
        """Polls on their way, overlapping (their fates come in any order: poll_settles)."""
        for _ in range(polls):
            self._send_poll()

    @precondition(lambda self: self.in_flight)
    @rule(data=st.data(), dt=DT, fate=st.sampled_from(["answered", "failed", "failed", "failed"]), greens=GREENS)
    def poll_settles(self, data: st.DataObject, dt: float, fate: str, greens: frozenset[int]) -> None:
        poll = self.in_flight.pop(data.draw(st.integers(0, len(self.in_flight) - 1), label="poll"))
        t = self._tick(dt)
        if fate == "answered":
            self.feed(PollAnswered(t, poll.poll_id, poll.epoch, shown(greens)))
        else:
            self.feed(PollFailed(t, poll.poll_id, poll.epoch, "CommunicationTimeout",
                                 "CommunicationTimeout: no answer within 1.0 s"))

    @rule(dt=DT, answered=st.booleans(), greens=GREENS)
    def poll_from_before_a_halt_settles(self, dt: float, answered: bool, greens: frozenset[int]) -> None:
        t, epoch = self._tick(dt), self.epoch - 1
        self.polls += 1
        if answered:
            self.feed(PollAnswered(t, self.polls, epoch, shown(greens)))
        else:
            self.feed(PollFailed(t, self.polls, epoch, "CommunicationTimeout", "lost"))

    @precondition(lambda self: self.timers)
    @rule(data=st.data())
    def timer_fires(self, data: st.DataObject) -> None:
        due, kind, token = self.timers.pop(data.draw(st.integers(0, len(self.timers) - 1), label="timer"))
        self.t = max(self.t, due)
        m = self.manager
        if kind is TimerKind.KEEPALIVE:
            live = token == self.keepalive_token
        elif kind is TimerKind.CONTROL:
            live = token == m._control_token and m.running is not None
        elif kind is TimerKind.RECOVER:
            live = token == self.recover_token and m.mode is Mode.TIMEOUT
        else:
            live = m.pending is not None and m.pending.token == token
        mode = m.mode
        stale = m.stale(kind, token)  # the shell feeds no expiry the manager calls stale: it must change nothing
        assert stale or live, "the manager calls live a timer that is not"
        effects = self.feed(TimerExpired(self.t, kind, token))
        self.fired.add(token)
        if not live or stale:
            assert effects == [] and m.mode is mode, "a stale timer had an effect"
        if kind is TimerKind.RECOVER and live:
            assert effects == [RecoveryStarted(), ReadController()] and m.mode is Mode.RECOVERING

    @precondition(lambda self: self.sets)
    @rule(data=st.data(), dt=DT, fate=st.sampled_from(["answered", "lost", "refused"]))
    def set_returns(self, data: st.DataObject, dt: float, fate: str) -> None:
        done = self.sets.pop(data.draw(st.integers(0, len(self.sets) - 1), label="set"))
        t = self._tick(dt)
        if fate == "answered":
            self.feed(SetAnswered(t, done.purpose, done.command_id))
        else:
            effects = self.feed(SetFailed(t, done.purpose, done.command_id, lost=fate == "lost", error=fate))
            if fate == "refused":
                assert not any(isinstance(e, SendCall | SendControls) for e in effects), (
                    "a refused SET is never retried")

    @rule(dt=DT, drifted=st.booleans())
    def step_timed(self, dt: float, drifted: bool) -> None:
        m, took = self.manager, STEP * (1.5 if drifted else 0.5)
        noticed = m.notices(STEP, took)
        before = (m.mode, m.drifted_in_a_row)
        effects = self.feed(StepTimed(self._tick(dt), STEP, took))
        if not noticed:  # the shell does not report such a step: it must change nothing
            assert effects == [] and (m.mode, m.drifted_in_a_row) == before

    @precondition(lambda self: self.read_pending)
    @rule(dt=DT, greens=GREENS, readable=st.booleans(), backup_mode=st.booleans())
    def controller_answers_the_recovery(self, dt: float, greens: frozenset[int], readable: bool,
                                        backup_mode: bool) -> None:
        self.read_pending = False
        t = self._tick(dt)
        if readable:
            self.shown = self.read_greens = greens
            self.feed(self._read(t, greens, backup_mode))
        else:
            self.feed(ControllerUnreadable(t, "no answer"))

    def _read(self, t: float, greens: frozenset[int], backup_mode: bool) -> ControllerRead:
        """The recovery's re-read, as the middleware reports it (the signal state alone, for phase commands)."""
        return ControllerRead(t, greens)

    # Recovery requests, keepalive switching, read-backs and stale timers share one rule, so that they
    # come rarely enough for commands to run their course in between.
    @rule(data=st.data(), dt=DT,
          what=st.sampled_from(["recovery", "recovery", "keepalive_switch", "stale_timer", "readback",
                                "controls_read", "controls_read", "agent_overdue"]))
    def disturbance(self, data: st.DataObject, dt: float, what: str) -> None:
        t = self._tick(dt)
        mode = self.manager.mode
        if what == "recovery":
            effects = self.feed(RecoveryRequested(t))
            if mode is not Mode.TIMEOUT:
                assert self.manager.mode is mode and not any(isinstance(e, SendCall | SendControls) for e in effects)
        elif what == "readback":
            self.feed(ReadbackDue(t))
        elif what == "agent_overdue":
            effects = self.feed(AgentOverdue(t, 10.0))
            if mode in WORKING:
                assert self.manager.mode is Mode.TIMEOUT and self.manager.timeout_reason is TimeoutReason.AGENT
            else:
                assert effects == [] and self.manager.mode is mode
        elif what == "controls_read":
            names = ("phaseControlGroupPhaseOmit", "phaseControlGroupPedOmit", "phaseControlGroupHold",
                     "phaseControlGroupForceOff", "phaseControlGroupPedCall")
            # Mostly clear (as a run sees them), sometimes one set by someone else.
            foreign = data.draw(st.sampled_from([frozenset()] * 3 + [frozenset({p}) for p in PHASES]), label="held")
            which = data.draw(st.sampled_from(names), label="object")
            # VehCall: not read, the run's call, or someone else's
            veh_call = data.draw(st.sampled_from([None, self.manager.call, self.manager.call,
                                                  frozenset({4, 8}), frozenset()]), label="veh_call")
            self.feed(ControlsRead(t, tuple((n, foreign if n == which else frozenset()) for n in names), veh_call))
        elif what == "keepalive_switch":
            on = data.draw(st.booleans(), label="on")
            assert self.feed(KeepaliveSwitched(t, on)) == []
            assert self.manager.keepalive_on is on
        else:
            kind = data.draw(st.sampled_from(TimerKind), label="kind")
            token = data.draw(st.integers(-3, 0), label="token")
            assert self.manager.stale(kind, token)
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
        # A communication failure ends whatever is pending, so every dispatched command has now ended exactly once.
        while self.manager.mode in WORKING:
            poll = self._send_poll()
            self.in_flight.remove(poll)
            self.feed(PollFailed(self._tick(0.1), poll.poll_id, poll.epoch, "CommunicationTimeout", "lost"))
        if self.manager.mode is not Mode.CLOSED:
            assert set(self.ended) == set(self.dispatched)
        assert set(self.ended.values()) <= DISPATCHED_OUTCOMES


ManagerMachine.TestCase.settings = settings(max_examples=200, stateful_step_count=60, deadline=None,
                                            suppress_health_check=[HealthCheck.too_slow])
TestManagerMachine = ManagerMachine.TestCase


# --- phase control: the same machine driven by schedules ------------------------------------------------------------

_TIME = st.one_of(st.sampled_from([0.0, 0.0, 0.05, 1.0, 2.0, 5.0, 11.0, 24.0]), st.floats(0.0, 40.0))
_LENGTH = st.one_of(st.sampled_from([1.0, 5.0, 20.0, 60.0]), st.floats(-1.0, 30.0))
_COMMAND = st.builds(
    lambda kind, phase, start, length: {"commandType": kind, "commandPhase": phase, "commandStartTime": start,
                                        "commandEndTime": start + length},
    st.sampled_from([c.value for c in Control]), st.sampled_from([*PHASES, *PHASES, *PHASES, 9]), _TIME, _LENGTH)
SCHEDULES = st.one_of(
    st.lists(_COMMAND, min_size=1, max_size=5).map(lambda cmds: {"MsgType": "Schedule", "Schedule": cmds}),
    st.lists(_COMMAND, max_size=3),
    st.dictionaries(st.sampled_from([c.value for c in Control]), st.lists(st.sampled_from(PHASES), max_size=2),
                    min_size=1, max_size=3),
    st.sampled_from(["clear", {"MsgType": "Schedule", "Schedule": "Clear"}, 1.5, None, {"MsgType": "Status"}]),
)


class PhaseControlMachine(ManagerMachine):
    """The manager of a phase-control run (:mod:`hils.control.phase_control`) driven as the other machine is, with
    schedules, steps and clears (valid and not) for actions, recovery re-reads that find the controller in backup
    mode, and read-backs of all six control objects as the run SET them, with phases lost or added. On top of every
    check of the other machine: what the run holds is what the running schedule asks while it commands (IDLE,
    SCHEDULED) and nothing while it does not (PREEMPTED, TIMEOUT); never a phase held and forced off, called and
    omitted, held and omitted, nor a whole ring omitted; only the objects that change are SET; the keepalive SETs
    them again as they stand (ForceOff aside) and every SET but the close's restarts it; a read-back that finds the
    run's phases gone SETs all six again; every exit lets go of all six."""

    def __init__(self) -> None:
        super().__init__()
        self.manager = Manager(TAU_TRANS, sequence=CONFIG.sequence, n_drift=N_DRIFT, n_timeout=N_TIMEOUT,
                               keepalive_period=CONFIG.middleware.keepalive_period or 0.0,
                               recover_after=RECOVER_AFTER, watch=WATCH, watch_period=WATCH_PERIOD, phase_control=True)
        self.converter = ActionConverter(CONFIG, ActionType.CONTROL)

    def _act(self, data: st.DataObject, action_type: ActionType, dt: float) -> None:
        value = data.draw(SCHEDULES, label="schedule")
        try:
            schedule = self.converter.convert(value)
        except ActionError:
            return  # nothing reaches the manager
        self.actions += 1
        self.feed(ScheduleRequested(self._tick(dt), self.actions, schedule))

    def _read(self, t: float, greens: frozenset[int], backup_mode: bool) -> ControllerRead:
        held = {c: frozenset() for c in ControlColumn} if backup_mode else dict(self.manager.sent)
        return ControllerRead(t, greens, held, backup_mode)

    @precondition(lambda self: self.manager.running is not None and self.manager._control_token is not None)
    @rule()
    def next_instant(self) -> None:
        """The running schedule's next instant comes (its control timer fires), before anything else happens."""
        m = self.manager
        due, kind, token = next(t for t in self.timers if t[2] == m._control_token)
        self.timers.remove((due, kind, token))
        self.t = max(self.t, due)
        self.fired.add(token)
        self.feed(TimerExpired(self.t, kind, token))

    @rule(data=st.data(), dt=DT, change=st.sampled_from(["same", "same", "lost", "added"]))
    def controls_read_back(self, data: st.DataObject, dt: float, change: str) -> None:
        """A read-back of all six objects, answered before anything else happens: as the run SET them, or with a
        phase lost (the controller reset them) or added (someone else's)."""
        t = self._tick(dt)
        if data.draw(st.booleans(), label="answered first"):  # every SET answered: the read can be judged
            while self.sets:
                done = self.sets.pop(0)
                self.feed(SetAnswered(t, done.purpose, done.command_id))
        self.feed(ReadbackDue(t))
        held = dict(self.manager.sent)
        column = data.draw(st.sampled_from(list(ControlColumn)), label="object")
        phase = data.draw(st.sampled_from(PHASES), label="phase")
        held[column] = held[column] - {phase} if change == "lost" else held[column] | {phase} if change == "added" \
            else held[column]
        names = {CONTROL_TABLE[c].name: c for c in ControlColumn}
        read = tuple((name, held[c]) for name, c in names.items() if c is not ControlColumn.VEH_CALL)
        self.feed(ControlsRead(self._tick(0.005), read, held[ControlColumn.VEH_CALL]))

    @precondition(lambda self: self.manager.mode is Mode.TIMEOUT)
    @rule(dt=DT, greens=GREENS, backup_mode=st.booleans())
    def recovery_round(self, dt: float, greens: frozenset[int], backup_mode: bool) -> None:
        """A recovery that goes through at once: asked, the controller re-read (in backup mode or not), its SET
        answered."""
        t = self._tick(dt)
        self.feed(RecoveryRequested(t))
        self.read_pending = False
        self.shown = self.read_greens = greens
        self.feed(self._read(self._tick(0.01), greens, backup_mode))
        done = next(o for o in reversed(self.sets) if o.purpose is Purpose.RECOVERY)
        self.sets.remove(done)
        self.feed(SetAnswered(self._tick(0.01), done.purpose, done.command_id))

    def _check_read_back(self, ev: ControlsRead, before: Mode, after: Mode, effects: list[Effect],
                         sent_before: dict[ControlColumn, frozenset[int]], sets_sent_before: int) -> None:
        sent_then, clean = self.readback
        read = {**{c: p for name, p in ev.held for c in ControlColumn if CONTROL_TABLE[c].name == name},
                ControlColumn.VEH_CALL: ev.veh_call}
        # (judged as the read came in: the TIMEOUT it may cause SETs the objects to 0 after)
        judged = clean and sent_then == sets_sent_before and ev.veh_call is not None
        foreign = judged and any(read[c] - sent_before[c] for c in ControlColumn)
        lost = judged and any(sent_before[c] - read[c] for c in ControlColumn if c is not ControlColumn.FORCE_OFF)
        if before not in WORKING or not (foreign or lost):
            assert effects == [] and after is before, "a read-back that cannot be judged, or finds all as SET"
        elif foreign:
            assert after is Mode.TIMEOUT and m_reason(self.manager) is TimeoutReason.FOREIGN_CONTROL
        else:
            assert after is before and isinstance(effects[0], ControlsReset)
            (again,) = [e for e in effects if isinstance(e, SendControls)]
            assert again.purpose is Purpose.REESTABLISH


def m_reason(m: Manager) -> TimeoutReason | None:
    return m.timeout_reason


PhaseControlMachine.TestCase.settings = settings(max_examples=200, stateful_step_count=60, deadline=None,
                                                 suppress_health_check=[HealthCheck.too_slow])
TestPhaseControlMachine = PhaseControlMachine.TestCase


def started(greens: frozenset[int] = frozenset({2, 6}), backup: int = 0, **options: Any) -> Manager:
    m = manager(**options)
    m.handle(Started(0.0, greens, backup))
    return m


def answered(m: Manager, t: float, poll_id: int, greens: frozenset[int]) -> list[Effect]:
    return m.handle(PollAnswered(t, poll_id, m.poll_epoch, shown(greens)))


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
    assert answered(m, 3.0, 2, frozenset()) == [ShowSignal(2, shown(frozenset()))]
    assert m.handle(CommandRequested(4.0, 2, cmd, frozenset())) == [Dropped(2, "on_hold")]
    effects = answered(m, 6.2, 3, frozenset({3, 7}))
    assert effects[1] == Verified(1, cmd, 3, effects[1].hold) and math.isclose(effects[1].hold, 5.2)
    assert effects[2].kind is TimerKind.DURATION and effects[2].delay == 11.5
    assert m.mode is Mode.SERVING and m.state is State.ON_HOLD
    assert m.handle(TimerExpired(11.0, TimerKind.TRANSITION, transition_token)) == [], "stale by now"
    effects = m.handle(TimerExpired(17.7, TimerKind.DURATION, effects[2].token))
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
    m = started(recover_after=None)
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


def test_n_timeout_failed_polls_in_a_row_are_a_communication_timeout() -> None:
    m = started(recover_after=None)
    assert answered(m, 0.1, 1, frozenset({2, 6}))[0] == ShowSignal(1, shown(frozenset({2, 6})))
    for i in range(2, 2 + N_TIMEOUT - 1):
        effects = m.handle(PollFailed(i * 0.1 + 1.0, i, 0, "CommunicationTimeout", "lost"))
        assert effects == [PollFailureSeen(i, "lost", i - 1)]
    # an answer breaks the run (and is logged: the state is known again)
    assert answered(m, 2.0, 7, frozenset({2, 6}))[0] == ShowSignal(7, shown(frozenset({2, 6})), after_failures=True)
    assert not m.polls_failing
    for i in range(8, 8 + N_TIMEOUT):
        effects = m.handle(PollFailed(i * 0.1 + 1.0, i, 0, "SnmpError", "genErr"))
    assert [type(e) for e in effects] == [PollFailureSeen, TimeoutEntered, HaltPolling]
    assert effects[1].detail == f"{N_TIMEOUT} consecutive polls failed (last: SnmpError)"
    assert m.mode is Mode.TIMEOUT and m.poll_epoch == 1
    assert m.handle(PollFailed(3.0, 13, 0, "CommunicationTimeout", "lost")) == [], "sent before the halt"
    assert (m.polls_answered, m.polls_failed, m.polls_late) == (2, 2 * N_TIMEOUT - 1, 0)


def test_failures_are_counted_in_poll_order_whatever_overtook_them() -> None:
    """An outage shorter than tau_udp: polls 2..9 lost, poll 10 answered before their failures come in (each
    fails tau_udp after it went out). In poll order they are eight failed polls in a row: a TIMEOUT at the
    fifth, poll 6's failure; the answer of poll 10 does not hide the run."""
    m = started(recover_after=None)
    answered(m, 0.1, 1, frozenset({2, 6}))
    answered(m, 1.002, 10, frozenset({2, 6}))
    for i in range(2, 6):
        assert m.handle(PollFailed(0.1 * i + 1.0, i, 0, "CommunicationTimeout", "lost")) == [
            PollFailureSeen(i, "lost", i - 1)]
    effects = m.handle(PollFailed(1.6, 6, 0, "CommunicationTimeout", "lost"))
    assert [type(e) for e in effects] == [PollFailureSeen, TimeoutEntered, HaltPolling] and effects[0].consecutive == 5
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.COMMUNICATION
    # Out of order, too: a run is made whole by the failure that joins its two halves.
    joined = started(recover_after=None)
    for i in (1, 2, 4, 5):
        assert joined.handle(PollFailed(1.0, i, 0, "CommunicationTimeout", "lost"))[0].consecutive in (1, 2)
    effects = joined.handle(PollFailed(1.1, 3, 0, "CommunicationTimeout", "lost"))
    assert effects[0].consecutive == 5 and joined.mode is Mode.TIMEOUT


def test_vehcall_changed_by_someone_else_is_foreign_control_when_no_set_of_ours_races_the_read() -> None:
    names = ("phaseControlGroupPhaseOmit", "phaseControlGroupPedOmit", "phaseControlGroupHold",
             "phaseControlGroupForceOff", "phaseControlGroupPedCall")
    clear = tuple((n, frozenset()) for n in names)
    m = started(recover_after=None)
    m.handle(CommandRequested(1.0, 1, Command((3, 7)), frozenset({2, 6})))
    assert m.handle(ReadbackDue(1.5)) == [ReadControls()]
    # The command's SET is still in flight: whatever the read shows, it is not judged.
    assert m.handle(ControlsRead(1.52, clear, frozenset({4, 8}))) == []
    m.handle(SetAnswered(1.6, Purpose.COMMAND, 1))
    m.handle(ReadbackDue(3.5))
    assert m.handle(ControlsRead(3.52, clear, frozenset({3, 7}))) == [], "the run's own call"
    m.handle(ReadbackDue(5.5))
    effects = m.handle(ControlsRead(5.52, clear, frozenset({4, 8})))
    assert [type(e) for e in effects] == [CommandEnded, TimeoutEntered, HaltPolling]
    assert effects[1].reason is TimeoutReason.FOREIGN_CONTROL
    assert effects[1].detail == ("set by someone else: phaseControlGroupVehCall on phases [4, 8] (the run's call: "
                                 "[3, 7])")
    # A SET of ours sent between the read and its answer, or one that failed: the read cannot be judged.
    racing = started(recover_after=None)
    racing.handle(ReadbackDue(2.0))
    racing.handle(CommandRequested(2.01, 1, Command((3, 7)), frozenset({2, 6})))
    racing.handle(SetAnswered(2.02, Purpose.COMMAND, 1))
    assert racing.handle(ControlsRead(2.03, clear, frozenset())) == []
    refused = started(recover_after=None)
    refused.handle(CommandRequested(2.0, 1, Command((3, 7)), frozenset({2, 6})))
    refused.handle(SetFailed(2.01, Purpose.COMMAND, 1, lost=False, error="genErr"))
    refused.handle(ReadbackDue(4.0))
    assert refused.handle(ControlsRead(4.02, clear, frozenset())) == [], "the controller may hold either call"


def test_calls_found_at_start_up_are_watched_and_calls_that_change_refuse_the_run() -> None:
    m = manager()
    effects = m.handle(CallsFound(0.01, frozenset({2, 6})))
    assert isinstance(effects[0], Note) and effects[-1] == WatchCalls(WATCH_PERIOD)
    assert m.handle(CallsWatched(0.11, frozenset({2, 6}))) == [WatchCalls(WATCH_PERIOD)]
    effects = m.handle(CallsWatched(3.21, frozenset({4, 8})))
    assert isinstance(effects[0], AnotherManager) and "from phases [2, 6] to [4, 8]" in effects[0].detail
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.FOREIGN_CONTROL
    assert effects[-1] == StartupDone() and m.last_set == -math.inf, "nothing was SET: the close clears nothing"
    assert m.handle(CloseRequested(4.0)) == [HaltPolling(), CloseDone()]
    left = manager()
    left.handle(CallsFound(0.0, frozenset({2, 6})))
    assert left.handle(CallsWatched(WATCH, frozenset({2, 6}))) == [] and left.mode is Mode.STARTING, (
        "calls that did not change in the watch are taken as left: the start-up goes on and clears them")
    taking = Manager(TAU_TRANS, take_over=True)
    assert taking.handle(CallsFound(0.0, frozenset({2, 6}))) == [] and taking.mode is Mode.STARTING
    assert manager().handle(CallsFound(0.0, frozenset())) == [], "no calls: nothing to watch"


def test_a_late_answer_is_counted_and_not_applied() -> None:
    m = started()
    answered(m, 0.3, 3, frozenset({2, 6}))
    assert answered(m, 0.35, 2, frozenset({4, 8})) == [] and m.polls_late == 1 and m.newest_poll == 3


def test_start_up_reads_without_answer_are_made_again_then_a_communication_timeout() -> None:
    m = manager()
    for attempt in range(1, N_TIMEOUT):
        effects = m.handle(StartupLost(attempt * 1.0, "CommunicationTimeout: no answer"))
        assert effects == [PollFailureSeen(0, "start-up read: CommunicationTimeout: no answer", attempt),
                           RetryStartup()]
        assert m.mode is Mode.STARTING and m.state is State.IDLE
    effects = m.handle(StartupLost(N_TIMEOUT * 1.0, "CommunicationTimeout: no answer"))
    assert [type(e) for e in effects] == [PollFailureSeen, ControllerUnreachable, TimeoutEntered, HaltPolling,
                                          StartTimer, StartupDone]
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.COMMUNICATION
    refused = manager(recover_after=None)
    effects = refused.handle(StartupRefused(0.1, "the community can read but not write"))
    assert effects == [Note("start-up: the community can read but not write"),
                       TimeoutEntered(TimeoutReason.COMMUNICATION, "the community can read but not write", None),
                       HaltPolling(), StartupDone()]


def test_the_recovery_timer_recovers_after_recover_after_and_again_after_a_failed_recovery() -> None:
    m = started()
    effects = m.handle(StepTimed(0.0, STEP, 1.0))
    for i in range(1, N_DRIFT):
        effects = m.handle(StepTimed(i * STEP, STEP, 1.0))
    timer = effects[-1]
    assert timer.kind is TimerKind.RECOVER and timer.delay == RECOVER_AFTER
    assert m.handle(TimerExpired(6.0, TimerKind.RECOVER, timer.token)) == [RecoveryStarted(), ReadController()]
    effects = m.handle(ControllerUnreadable(6.1, "no answer"))
    again = effects[-1]
    assert m.mode is Mode.TIMEOUT and again.kind is TimerKind.RECOVER and again.token != timer.token
    assert m.handle(TimerExpired(7.0, TimerKind.RECOVER, timer.token)) == [], "the first timer is spent"
    m.handle(RecoveryRequested(8.0))  # recovered by hand meanwhile
    m.handle(ControllerRead(8.1, frozenset({2, 6})))
    m.handle(SetAnswered(8.2, Purpose.RECOVERY, None))
    assert m.mode is Mode.IDLE
    assert m.handle(TimerExpired(11.1, TimerKind.RECOVER, again.token)) == [] and m.mode is Mode.IDLE


def test_the_read_back_waits_while_polls_fail_and_in_timeout() -> None:
    m = started(recover_after=None)
    assert m.handle(ReadbackDue(2.0)) == [ReadControls()]
    m.handle(PollFailed(2.1, 1, 0, "CommunicationTimeout", "lost"))
    assert m.handle(ReadbackDue(4.0)) == []
    answered(m, 4.1, 2, frozenset({2, 6}))
    assert m.handle(ReadbackDue(6.0)) == [ReadControls()]
    for i in range(3, 3 + N_DRIFT):
        m.handle(StepTimed(i, STEP, 1.0))
    assert m.mode is Mode.TIMEOUT and m.handle(ReadbackDue(10.0)) == []


def test_a_start_up_read_ending_after_a_drift_timeout_or_a_close_changes_no_state() -> None:
    """At the wall clock a large grid's steps can drift while its controllers still start: the start-up read
    then ends in TIMEOUT (or, after Ctrl-C, in CLOSED). What it read is kept; the recovery resumes from it."""
    m = manager(recover_after=None, keepalive_period=10.0)
    for i in range(N_DRIFT):
        m.handle(StepTimed(i * STEP, STEP, 1.0))
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.DRIFT
    effects = m.handle(Started(2.0, frozenset({4, 8}), 30))
    assert m.mode is Mode.TIMEOUT and m.position == CONFIG.sequence.index((4, 8))
    assert not any(isinstance(e, SendCall) for e in effects), "nothing is sent in TIMEOUT"
    assert effects[-1] == StartupDone()
    assert m.handle(RecoveryRequested(3.0)) == [RecoveryStarted(), ReadController()]
    effects = m.handle(Started(3.1, frozenset({4, 8}), 30))
    assert m.mode is Mode.RECOVERING and not any(isinstance(e, SendCall) for e in effects)
    closed = manager(keepalive_period=10.0)
    assert closed.handle(CloseRequested(0.5)) == [HaltPolling(), CloseDone()]
    assert closed.handle(Started(1.0, frozenset({2, 6}), 30)) == [StartupDone()] and closed.mode is Mode.CLOSED


def test_keepalive_is_gated_in_timeout_and_off_and_resumes_after_recovery() -> None:
    m = started(backup=30, recover_after=None)
    assert m.keepalive_period == 10.0
    effects = m.handle(CommandRequested(0.0, 1, Command((3, 7)), frozenset({2, 6})))
    token = next(e.token for e in effects if isinstance(e, StartTimer) and e.kind is TimerKind.KEEPALIVE)
    answered(m, 6.0, 1, frozenset({3, 7}))
    effects = m.handle(TimerExpired(10.0, TimerKind.KEEPALIVE, token))
    assert effects[0] == SendCall(frozenset({3, 7}), Purpose.KEEPALIVE)
    token = effects[1].token
    m.handle(KeepaliveSwitched(12.0, False))
    effects = m.handle(TimerExpired(20.0, TimerKind.KEEPALIVE, token))
    assert [type(e) for e in effects] == [StartTimer], "switched off: no SET, the timer runs on"
    m.handle(KeepaliveSwitched(21.0, True))
    for i in range(2, 2 + N_TIMEOUT):
        m.handle(PollFailed(25.0, i, 0, "CommunicationTimeout", "lost"))
    assert m.mode is Mode.TIMEOUT
    assert m.handle(TimerExpired(30.0, TimerKind.KEEPALIVE, effects[0].token)) == [], "gated in TIMEOUT"
    m.handle(RecoveryRequested(31.0))
    effects = m.handle(ControllerRead(31.1, frozenset({3, 7})))
    assert any(isinstance(e, StartTimer) and e.kind is TimerKind.KEEPALIVE for e in effects), "the recovery re-arms"


def test_close_clears_the_call_and_then_nothing_is_sent() -> None:
    m = started(backup=30)
    m.handle(CommandRequested(0.0, 1, Command((3, 7)), frozenset({2, 6})))
    assert m.handle(CloseRequested(1.0)) == [HaltPolling(), SendCall(frozenset(), Purpose.CLEAR)]
    for ev in (CommandRequested(2.0, 2, Command((4, 8)), frozenset()), TimerExpired(10.0, TimerKind.KEEPALIVE, 1),
               PollFailed(11.0, 9, 0, "CommunicationTimeout", "lost"), RecoveryRequested(12.0)):
        assert not any(isinstance(e, SendCall) for e in m.handle(ev))
    assert m.handle(SetAnswered(12.5, Purpose.CLEAR, None)) == [CloseDone()]
    assert m.mode is Mode.CLOSED and m.state is None


def test_every_state_names_its_paper_state_and_the_graph_reads_off_the_table() -> None:
    from hils.control.manager import _TRANSITIONS

    assert {mode.paper for mode in Mode} == {*State, None}
    assert {ev for _s, ev in _TRANSITIONS} == set(Ev), "every kind of event has a row somewhere"
    edges = graph()
    reachable, frontier = {Mode.STARTING}, [Mode.STARTING]
    while frontier:
        here = frontier.pop()
        for a, _ev, b in edges:
            if a is here and b not in reachable:
                reachable.add(b)
                frontier.append(b)
    assert reachable == set(Mode), "every state is reached from the start-up"
    assert not any(a is Mode.CLOSED for a, _ev, _b in edges), "nothing leaves CLOSED"
    assert {b for a, _ev, b in edges if a is Mode.TIMEOUT} == {Mode.RECOVERING, Mode.CLOSED}
    assert {(a, b) for a, ev, b in edges if a is Mode.RECOVERING and b is Mode.IDLE} == {
        (Mode.RECOVERING, Mode.IDLE)} and [ev for a, ev, b in edges if b is Mode.IDLE and a is Mode.RECOVERING] == [
        Ev.RECOVERY_SET_ANSWERED], "TIMEOUT is left only through an answered recovery SET"
    dot = subprocess.run([sys.executable, "-m", "hils.control.manager"], capture_output=True, text=True,
                         check=True).stdout
    assert dot.startswith("digraph manager {") and "TIMEOUT -> RECOVERING" in dot
    assert dot.count(" -> ") == len(edges)


def test_a_preempt_ends_the_transition_without_a_timeout_and_only_a_failure_of_the_run_times_out_in_it() -> None:
    m = started(backup=30, recover_after=None)
    effects = m.handle(CommandRequested(1.0, 1, Command((3, 7)), frozenset({2, 6})))
    transition = next(e for e in effects if isinstance(e, StartTimer) and e.kind is TimerKind.TRANSITION)
    preempted = PollAnswered(1.5, 1, 0, shown(frozenset()), frozenset({1}))
    effects = m.handle(preempted)
    assert effects[1:4] == [CommandEnded(1, "preempted", 0.5), PreemptBegan(frozenset({1}), 1),
                            SendCall(frozenset(), Purpose.WITHDRAW)]
    assert m.mode is Mode.PREEMPTED and m.state is State.PREEMPTED and m.pending is None
    assert m.handle(TimerExpired(11.0, TimerKind.TRANSITION, transition.token)) == [], "no transition TIMEOUT"
    (refused,) = m.handle(CommandRequested(12.0, 2, Command((4, 8)), frozenset({2, 5})))
    assert isinstance(refused.error, PreemptedError) and "preempt 1 (since 1.5 s)" in str(refused.error)
    # A lower-numbered preempt taking over is still the one preemption; the end is the exit phases shown.
    m.handle(PollAnswered(13.0, 2, 0, shown(frozenset({2, 5})), frozenset({1, 2})))
    assert m.mode is Mode.PREEMPTED and m.preempts == frozenset({1, 2})
    assert answered(m, 31.5, 3, frozenset({2, 6}))[1:] == [PreemptEnded(30.0, frozenset({2, 6}))]
    assert m.mode is Mode.IDLE and m.position == CONFIG.sequence.index((2, 6)) and m.refusal() is None
    # Polls failing while preempted are a communication failure as anywhere.
    m.handle(PollAnswered(32.0, 4, 0, shown(frozenset({2, 5})), frozenset({1})))
    for i in range(5, 5 + N_TIMEOUT):
        effects = m.handle(PollFailed(33.0 + i, i, 0, "CommunicationTimeout", "lost"))
    assert m.mode is Mode.TIMEOUT and m.timeout_reason is TimeoutReason.COMMUNICATION


def test_a_refused_recovery_set_under_phase_control_sends_nothing_and_holds_nothing() -> None:
    """An SNMP SET applies whole or not at all: a refused recovery SET landed nothing, so the manager, back in
    TIMEOUT, holds nothing and sends no release (a lost one may have landed: it is released)."""
    for lost in (False, True):
        m = Manager(TAU_TRANS, sequence=CONFIG.sequence, recover_after=None, phase_control=True)
        m.handle(Started(0.0, frozenset({2, 6}), 30))
        schedule = ActionConverter(CONFIG, ActionType.CONTROL).convert({"hold": [2, 6], "call_veh": [2, 6]})
        m.handle(ScheduleRequested(1.0, 1, schedule))
        m.handle(SetAnswered(1.01, Purpose.SCHEDULE, None))
        m.handle(AgentOverdue(2.0, 10.0))
        assert m.mode is Mode.TIMEOUT
        m.handle(SetFailed(2.1, Purpose.RELEASE, None, lost=True, error="lost"))
        m.handle(RecoveryRequested(3.0))
        effects = m.handle(ControllerRead(3.1, frozenset({2, 6}), None, False))
        assert any(isinstance(e, SendControls) and e.purpose is Purpose.RECOVERY for e in effects)
        effects = m.handle(SetFailed(3.2, Purpose.RECOVERY, None, lost=lost, error="lost" if lost else "genErr"))
        assert m.mode is Mode.TIMEOUT
        released = [e for e in effects if isinstance(e, SendControls)]
        assert released == ([SendControls(tuple((c, frozenset()) for c in ControlColumn), Purpose.RELEASE)]
                            if lost else []), "a refused SET is never followed by another"
        assert not any(m.sent.values()), "in TIMEOUT the run holds nothing"
