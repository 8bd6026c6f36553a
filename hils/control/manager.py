"""The manager: the middleware's whole state machine, pure.

Rules of this file
------------------
- Everything that affects the state machine lives here (h11's rule): whether a command is sent or
  dropped, verification, timers, the retry of an unanswered command SET, the gating of the
  keepalive and of the read-back, the counting of failed polls and of start-up attempts, drift
  counting, recovery and its timer, closing, and the position in the cyclic sequence. Every TIMEOUT is
  decided here. The shell (:mod:`hils.shell.middleware`) only carries out the effects returned and feeds back
  what happened: it never counts, retries or gates.
- No clock, no I/O, no SimPy. Every input is an event object that carries the time it happened;
  every output is an effect object (their vocabulary: :mod:`hils.control.manager_io`).
- ``_TRANSITIONS`` maps each (state, event kind) to the next state and the handler that produces the
  effects, one row per line, so the whole graph can be read (and drawn: ``python -m hils.control.manager``
  prints it) off the table. An event is first given its kind by ``_classify``: the guard of each kind
  (:class:`Ev`) is a condition on the event and the machine's data, evaluated without changing
  anything. A (state, kind) pair not in the table is an error naming both. Handlers never choose the
  next state.
- Timers are identified by a token. A timer that was superseded or belongs to an older command has
  a stale token: its expiry is classified STALE_TIMER and changes nothing (:meth:`Manager.stale` says so
  before the shell makes the event: most timers go stale, a keepalive at every SET, a transition timer at
  every verified command, and the shell need not feed an expiry that does nothing). Poll results carry the
  polling period they were sent in (``epoch``, one more at every halt): a result from before the last
  halt is STALE_POLL and changes nothing.

Theory of operation
-------------------
States (:class:`Mode`), with the paper's names (:class:`State`) that the log and reports keep:

- STARTING (paper IDLE): the controller is being read for the first time. A read that gets no answer
  is made again, up to n_timeout attempts in all (one lost datagram at start-up is no reason to halt);
  the last unanswered one, or a refusal, is a communication TIMEOUT. Calls found on the controller are
  watched before anything is SET (unless the run takes over): VehCall read again every ``watch_period``
  for ``watch`` seconds; calls that change meanwhile mean another manager drives the controller, a
  FOREIGN_CONTROL TIMEOUT in which the run refuses to start (it has SET nothing). The read done: IDLE.
- IDLE (paper IDLE): a command may be sent. A command that asks to keep what is shown (switch 0,
  or selection of the pair already green) completes at once (KEEP). Any other is dispatched: the
  shell SETs VehCall to the commanded phases, the transition timer (tau_trans) starts, and the
  manager goes IN_TRANSITION.
- IN_TRANSITION (paper ON_HOLD): waits for a poll whose greens hold the commanded phases. That
  verifies the transition: a plain command returns to IDLE; a duration command goes SERVING
  and its green timer starts from the verifying poll. A command SET that got no answer
  (lost, not refused) is SET again while the transition is awaited; tau_trans still bounds the wait.
  If the transition timer expires first: TIMEOUT.
- SERVING (paper ON_HOLD): the prescribed green is being served; back to IDLE when it has passed.
- SCHEDULED (paper IDLE: the next action is taken, and replaces it): a phase-control schedule runs (see Phase
  control below); IDLE again when it is done or cleared.
- PREEMPTED (its own name, ``preempted``): the controller serves a preempt (a poll read a preemptState in
  service: entry, track clearance, dwell, linked or exit; see Preemption below). Entered from IDLE,
  IN_TRANSITION or SERVING; left for IDLE when a poll reads no preempt in service.
- TIMEOUT (paper TIMEOUT): entered on a transition not seen within tau_trans, a communication
  failure (n_timeout consecutive failed polls, below), n_drift consecutive drifted steps, a
  control object changed by someone else (FOREIGN_CONTROL, below), or an agent that gave no action
  within the control interval of its decision point (AGENT: at the wall clock an agent thinks in a
  thread of its own, and the run goes on meanwhile). Polling halts; commands,
  keepalives and read-backs are not sent. A recovery request, or the recovery timer (``recover_after``
  seconds after entering TIMEOUT, when set), re-reads the controller (RECOVERING).
- RECOVERING (paper TIMEOUT): the controller was re-read; the call is SET to the pair it shows (so
  no transition follows that nobody commanded) and the sequence position follows it. When that SET
  is answered: IDLE, polling resumes and the drift and failure counts restart. A failed read or SET:
  TIMEOUT, and the recovery timer starts again.
- CLOSED: the run has ended; the calls are cleared and nothing else is sent. A clearing SET whose
  datagram got no answer is sent again, up to CLEAR_ATTEMPTS in all: calls left on a controller stay
  until its backup time drops them, so one lost datagram is no reason to leave them. The close is
  done (:class:`CloseDone`) when a clear is answered, when the last one fails, or at once when the run
  never SET a call.

Polls. The poller sends one GET per period and reports each one's fate (:class:`PollAnswered`,
:class:`PollFailed`), in whatever order they settle. Answers are applied in poll order: one older
than the newest applied is late and discarded. A communication failure is n_timeout consecutive failed
polls, as the paper defines it, counted in poll order: n_timeout polls of consecutive ids that all failed,
whenever each failure became known. A failure overtaken by the answer of a later poll still belongs to its
run (an outage shorter than tau_udp is n_timeout lost polls like any other: its failures come in after
the first answer beyond it); a poll answered breaks the run it falls in. With overlapping polls a dead
link is therefore seen about (n_timeout - 1) periods + tau_udp after it dies. While a poll newer than
the newest answered one has failed, the read-back waits (the failed polls speak for the link).

The control objects are ours while we run. The shell reads them back at a low rate when the
manager says so (:class:`ReadbackDue` -> :class:`ReadControls` -> :class:`ControlsRead`). In IDLE,
IN_TRANSITION, SERVING and PREEMPTED, any of PhaseOmit, PedOmit, Hold, ForceOff or PedCall set is a control
object changed by someone else (the run never sets them): TIMEOUT (FOREIGN_CONTROL). VehCall is ours,
re-SET by every command and keepalive: a read of it is judged only when it cannot race with a SET of
ours (none in flight when the read was sent, none sent before its answer, the last one answered), and
then VehCall other than the call last SET is a change by someone else: TIMEOUT (FOREIGN_CONTROL). The
recovery's SET and the close's clear set every control object.

Preemption. A preempt is the controller's own operation (a train, a fire truck), not a failure of the run:
the middleware watches and never fights it. A poll that reads a preempt in service ends the command pending, if
any (:class:`CommandEnded` ``preempted``: the controller leaves the commanded phases for the preempt's, and no
transition TIMEOUT follows, its timers being stale from then on), withdraws the call (VehCall SET to no phase,
``withdraw``, unless it holds none) and enters PREEMPTED. The interrupted command is dropped, not re-issued:
the traffic it was chosen for has changed by the end of the preemption, and a controller returning from a
preempt serves its exit phases, which is what a field engineer expects to see; a call left standing would
instead move the controller on from the exit phases the moment it returns, with nobody deciding it. In
PREEMPTED no call is placed: every action is refused with :class:`hils.control.actions.PreemptedError`
(:class:`Refused`), and :meth:`Manager.refusal` says so before anything is handed over, so that a run of
several controllers sends none of a step's actions when one of them is refused. The keepalive goes on: it
re-SETs the (empty) call, which changes nothing the controller does, while a backup timer that ran out would
drop the controller to backup mode, where NTCIP 1202 resets preemptControlState ("The device shall reset this
object to ZERO when in BACKUP Mode"). Failed polls, drift, an overdue agent and control objects set by someone
else are TIMEOUTs as anywhere at work: a preempt explains the signals leaving the commanded phases, nothing
else. The first poll that reads no preempt in service ends it (:class:`PreemptEnded`): the sequence position
follows the greens shown (the exit phases), the manager is IDLE and the agent's next action is a command again.

Phase control (``phase_control``: the run's action type is ``control``). The agent hands schedules of holds,
force-offs, omits and calls per phase (:mod:`hils.control.phase_control`, which checks them and keeps the life cycle
of each order: waiting, armed, acting, spent, ended, lapsed). The run owns all six phaseControlGroup objects, and
``sent`` is what each holds by the run. In IDLE or SCHEDULED a schedule replaces the one running (MMITSS's way: what
both ask stays set, in one SET of the objects that change) and the machine is SCHEDULED; a schedule without orders
clears everything (IDLE). At each instant of the running schedule (the control timer) its orders end, then start,
and the objects whose phases that changes are SET (purpose ``schedule``); after its last instant the schedule is
done (IDLE). A step, whose orders have no end, runs until the next action replaces it. Every poll tells the orders
what shows green: a hold or force-off on a phase not green is armed, and acts when its phase shows green; a force-off
whose green ended is spent (the controller reset its bit: ``sent`` drops it, nothing is SET). The keepalive SETs
again every object that holds phases but ForceOff, and VehCall. The read-back judges all six objects when no SET of
the run could race it: phases the run did not SET are FOREIGN_CONTROL; phases it SET that are gone (ForceOff aside)
mean the controller lost them (CONTROLS_LOST: the six SET again, ``reestablish``). Every way out of commanding lets
go of them: entering TIMEOUT SETs all six to 0 (``release``: nobody manages them now, and a hold left on would keep
its green); in TIMEOUT the schedule's orders go on and nothing is sent; the recovery re-reads the controller, says
when it reports backupMode (its backup timer ran out and reset every object: :class:`ControlsReset`), and SETs all
six to what the running schedule asks then (SCHEDULED, or IDLE when none runs). A preempt ends the schedule and
SETs all six to 0 (``withdraw``); the close ends it and clears all six. In PREEMPTED a schedule is refused; in
STARTING, TIMEOUT, RECOVERING and CLOSED it is dropped.

Commands arriving anywhere but IDLE and PREEMPTED are dropped. Every dispatched command ends exactly once
(:class:`CommandEnded`: verified, served, timeout or preempted), except the one pending when the run closes.
The keepalive re-SETs the call when no SET has gone out for a keepalive period (a third of the
controller's backup time, or the config's, whichever is shorter), except in TIMEOUT, RECOVERING and
CLOSED (in PREEMPTED too: see Preemption), or while switched off. An empty call is re-SET too: the start-up SET
put the controller under system control, and a run that has placed no call yet (an agent keeping the start-up
pair, the actuated baseline) keeps it there rather than let the backup timer drop it to backup mode.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, auto

from hils.control.actions import ActionError, Command, PreemptedError
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
from hils.control.phase_control import Change, OrderState, Running, no_controls
from hils.protocol.config import Pair
from hils.protocol.ntcip import CONTROL_TABLE, ControlColumn, SignalState

__all__ = ["CLEAR_ATTEMPTS", "Ev", "Manager", "Mode", "Pending", "State", "graph"]


class _Singletons(Enum):
    """An enum hashed by identity (its members are singletons): the transition table and the paper's names are looked
    up by these at every event, and Enum's own ``__hash__`` is a Python call hashing the member's name."""

    __hash__ = object.__hash__


class State(_Singletons):
    """The paper's names of the manager's states, kept by the log, the reports and the public API; and PREEMPTED,
    which the paper's lab controller never was."""

    IDLE = "idle"
    ON_HOLD = "on_hold"
    TIMEOUT = "timeout"
    PREEMPTED = "preempted"


class Mode(_Singletons):
    """The states of the machine."""

    STARTING = "starting"
    IDLE = "idle"
    IN_TRANSITION = "in_transition"
    SERVING = "serving"
    SCHEDULED = "scheduled"
    PREEMPTED = "preempted"
    TIMEOUT = "timeout"
    RECOVERING = "recovering"
    CLOSED = "closed"

    @property
    def paper(self) -> State | None:
        """The paper's name of this state (None once closed)."""
        return _PAPER[self]

    @property
    def log_name(self) -> str:
        paper = self.paper
        return self.value if paper is None else paper.value


_PAPER = {Mode.STARTING: State.IDLE, Mode.IDLE: State.IDLE, Mode.IN_TRANSITION: State.ON_HOLD,
          Mode.SERVING: State.ON_HOLD, Mode.SCHEDULED: State.IDLE, Mode.PREEMPTED: State.PREEMPTED,
          Mode.TIMEOUT: State.TIMEOUT, Mode.RECOVERING: State.TIMEOUT, Mode.CLOSED: None}


@dataclass(frozen=True, slots=True)
class Pending:
    """The command in transition or being served: what it is, when it was sent, its live timer token."""

    command_id: int
    command: Command
    since: float
    token: int


class Ev(_Singletons):
    """The kinds an input event is classified into; the table is written in these. Each says its guard."""

    STARTED = auto()  # Started
    STARTUP_RETRY = auto()  # StartupLost, fewer than n_timeout attempts so far
    STARTUP_UNREACHABLE = auto()  # StartupLost, the n_timeout-th attempt
    STARTUP_REFUSED = auto()  # StartupRefused
    CALLS_WATCHED = auto()  # CallsFound with calls the run does not take over, or CallsWatched the same, watch not over
    CALLS_LEFT = auto()  # CallsFound without calls (or taken over), or CallsWatched the same when the watch is over
    CALLS_CHANGED = auto()  # CallsWatched other than the calls found
    COMMAND = auto()  # CommandRequested that asks for a transition
    KEEP = auto()  # CommandRequested that keeps what is shown (switch 0, the pair already green)
    VERIFIED = auto()  # PollAnswered in IN_TRANSITION showing the commanded phases green (a plain command)
    VERIFIED_DURATION = auto()  # the same, for a duration command
    PREEMPT_BEGAN = auto()  # PollAnswered, not in PREEMPTED, reading a preempt in service
    PREEMPT_ENDED = auto()  # PollAnswered in PREEMPTED reading none in service
    OBSERVED = auto()  # any other PollAnswered of this polling period, not older than the newest applied
    LATE_POLL = auto()  # PollAnswered older than the newest applied
    STALE_POLL = auto()  # PollAnswered or PollFailed sent before the last halt
    POLL_FAILED = auto()  # PollFailed that makes no run of n_timeout in a row, in poll order
    POLLS_FAILED = auto()  # PollFailed that makes a run of n_timeout in a row, in poll order
    TRANSITION_EXPIRED = auto()  # TimerExpired: the pending command's transition timer
    DURATION_ELAPSED = auto()  # TimerExpired: the pending command's green timer
    KEEPALIVE_DUE = auto()  # TimerExpired: the live keepalive timer
    RECOVERY_DUE = auto()  # TimerExpired: the live recovery timer
    STALE_TIMER = auto()  # TimerExpired with any other token
    ON_TIME = auto()  # StepTimed within its step
    DRIFTED = auto()  # StepTimed over its step, fewer than n_drift in a row
    DRIFT_LIMIT = auto()  # StepTimed over its step, the n_drift-th in a row
    COMMAND_SET_LOST = auto()  # SetFailed, lost, of the pending command's SET in IN_TRANSITION
    CLEAR_ANSWERED = auto()  # SetAnswered of a clear
    CLEAR_LOST = auto()  # SetFailed, lost, of a clear, fewer than CLEAR_ATTEMPTS sent
    CLEAR_FAILED = auto()  # SetFailed of a clear: refused, or the last attempt lost
    RECOVERY_SET_ANSWERED = auto()  # SetAnswered of the recovery SET
    RECOVERY_SET_FAILED = auto()  # SetFailed of the recovery SET
    SET_RESULT = auto()  # any other SetAnswered or SetFailed
    RECOVERY_REQUESTED = auto()  # RecoveryRequested
    CONTROLLER_READ = auto()  # ControllerRead
    CONTROLLER_UNREADABLE = auto()  # ControllerUnreadable
    READBACK = auto()  # ReadbackDue, no poll failing
    READBACK_WAITS = auto()  # ReadbackDue while a poll newer than the newest answered one has failed
    CONTROLS_OURS = auto()  # ControlsRead, nothing set
    FOREIGN_CONTROL = auto()  # ControlsRead, something set
    AGENT_OVERDUE = auto()  # AgentOverdue
    KEEPALIVE_SWITCHED = auto()  # KeepaliveSwitched
    CLOSE = auto()  # CloseRequested
    SCHEDULE = auto()  # ScheduleRequested with orders
    SCHEDULE_CLEAR = auto()  # ScheduleRequested without any: clear everything
    CONTROL_DUE = auto()  # TimerExpired: the live control timer, an instant of the running schedule, not its last
    SCHEDULE_DONE = auto()  # TimerExpired: the live control timer, the running schedule's last instant
    CONTROLS_LOST = auto()  # ControlsRead, phase control, judged: nothing foreign, but a control object the run SET
    #                         (a force-off aside: it resets itself) no longer holds all its phases
    RECOVERED_TO_SCHEDULE = auto()  # SetAnswered of the recovery SET while a schedule runs


#: How many times in all the closing clear is sent while its datagrams get no answer (see CLOSED).
CLEAR_ATTEMPTS = 3

#: Failed poll ids kept at most (a poll settles within tau_udp, a few dozen periods at most).
_FAILED_KEPT = 4096


class Manager:
    """The state machine. Feed events to :meth:`handle`; it returns the effects to carry out.

    ``n_timeout``: failed polls in a row (and start-up reads without answer) that are a communication
    failure. ``recover_after``: seconds in TIMEOUT before the manager recovers by itself (None: never).
    ``watch``, ``watch_period``: how long and how often the start-up watches calls found on the controller;
    ``take_over``: take the controller without watching (another manager's calls are cleared).
    ``phase_control``: the run commands by phase control (schedules of holds, force-offs, omits and calls) rather
    than by phase commands (VehCall alone)."""

    def __init__(self, tau_trans: float, *, sequence: tuple[Pair, ...] = (), n_drift: int = 5, n_timeout: int = 5,
                 keepalive_period: float = 0.0, recover_after: float | None = None, watch: float = 20.0,
                 watch_period: float = 0.1, take_over: bool = False, phase_control: bool = False) -> None:
        self.tau_trans = tau_trans
        self.sequence = sequence
        self.n_drift = n_drift
        self.n_timeout = n_timeout
        self.keepalive_period = keepalive_period  # 0: no keepalive
        self.recover_after = recover_after
        self.watch = watch
        self.watch_period = watch_period
        self.take_over = take_over
        self.phase_control = phase_control
        self.mode = Mode.STARTING
        self.pending: Pending | None = None
        self.timeout_reason: TimeoutReason | None = None
        self.position = -1  # index in the sequence of the pair last commanded or shown; -1: none yet
        self.sent = no_controls()  # each control object as last SET (a force-off the controller reset: without it)
        self.greens: frozenset[int] = frozenset()  # the greens last shown (a poll, the start-up or recovery read)
        self.running: Running | None = None  # the schedule being carried out (phase control)
        self.backup_time = 0  # the controller's unitBackupTime, as the start-up read it
        self.last_set = float("-inf")
        self.keepalive_on = True
        self.drifted_in_a_row = 0
        self.startup_attempts = 0  # start-up reads that got no answer
        self.poll_epoch = 0  # polling periods so far: one more at every halt
        self.newest_poll = 0  # the newest poll whose answer was applied
        self.newest_failed = 0  # the newest poll that failed
        self._failed: set[int] = set()  # the polls of this polling period that failed (the recent ones), by id
        self.polls_answered = 0
        self.polls_failed = 0
        self.polls_late = 0
        self.clears_sent = 0
        self._found: tuple[float, frozenset[int]] | None = None  # when the start-up found someone's calls, which
        self._sets_sent = 0  # VehCall SETs sent, and not yet answered or failed
        self._sets_pending = 0
        self._set_failed = False  # a SET failed since the last one was sent: what the controller holds is unsure
        self._readback: tuple[int, bool] = (-1, False)  # SETs sent when the read-back went out; could it judge?
        self._recovering_greens: frozenset[int] = frozenset()  # what the recovery's re-read showed
        self.preempts: frozenset[int] = frozenset()  # the preempts in service, as last read (in PREEMPTED)
        self.preempted_since = 0.0  # when the poll that entered PREEMPTED was answered
        self._next_command = 0
        self._next_token = 0
        self._keepalive_token: int | None = None
        self._recover_token: int | None = None
        self._control_token: int | None = None  # the control timer of the running schedule's next instant

    @property
    def call(self) -> frozenset[int]:
        """VehCall as last SET."""
        return self.sent[ControlColumn.VEH_CALL]

    @property
    def state(self) -> State | None:
        """The paper's name of the current state."""
        return self.mode.paper

    def notices(self, step: float, took: float) -> bool:
        """Whether a step that took ``took`` s would change anything: a drifted one, or one on time that
        ends a run of drifted ones. (The shell reports only those: four steps a second are timed, and an
        on-time step after an on-time step is ON_TIME with nothing to reset.)"""
        return took > step or self.drifted_in_a_row > 0

    def counts_only(self, state: SignalState) -> bool:
        """Whether an answer showing ``state`` again (the newest applied) would only be counted: no verification, no
        preemption, no state left; looks, never changes. The fast path leaves such a poll unsent after a SET of ours
        (:mod:`hils.shell.fastpath`, rule 2). Only a state that commands counts an answer alone, and there the newest
        answer read no preempt in service (it would have entered PREEMPTED): the probe reads none either."""
        probe = PollAnswered(0.0, self.newest_poll + 1, self.poll_epoch, state, frozenset())
        entry = _TRANSITIONS.get((self.mode, self._classify(probe)))
        return entry is not None and entry == (self.mode, Manager._answered)

    def refusal(self) -> ActionError | None:
        """The typed error a command (or schedule) handed over now would be refused with (None: it would not be);
        looks, never changes. Only PREEMPTED refuses: elsewhere a command is sent, kept or dropped."""
        if self.mode is not Mode.PREEMPTED:
            return None
        return PreemptedError(f"the controller serves preempt {', '.join(map(str, sorted(self.preempts)))} (since "
                              f"{self.preempted_since:.1f} s): nothing is commanded until it reports the preemption "
                              "over")

    def stale(self, kind: TimerKind, token: int) -> bool:
        """True when the expiry of timer ``token`` of ``kind`` would be STALE_TIMER now (it changes nothing, in
        every state); looks, never changes."""
        if kind is TimerKind.CONTROL:
            return token != self._control_token or self.running is None
        if kind is TimerKind.KEEPALIVE:
            return token != self._keepalive_token
        if kind is TimerKind.RECOVER:
            return token != self._recover_token
        return self.pending is None or token != self.pending.token

    def handle(self, event: Event) -> list[Effect]:
        kind = self._classify(event)
        entry = _TRANSITIONS.get((self.mode, kind))
        if entry is None:
            raise RuntimeError(f"no transition for {type(event).__name__} ({kind.name}) in {self.mode.name}")
        target, handler = entry
        effects: list[Effect] = []
        if handler is not None:
            handler(self, event, effects)
        self.mode = target
        return effects

    # --- classification: the guards; looks, never changes ------------------------------------------

    def _classify(self, ev: Event) -> Ev:
        match ev:
            case CommandRequested(command=cmd, shown=shown):
                keep = cmd.green is None and (cmd.keep or set(cmd.phases) <= shown)
                return Ev.KEEP if keep else Ev.COMMAND
            case PollAnswered(poll_id=poll_id, epoch=epoch, state=state, preempts=preempts):
                if epoch != self.poll_epoch:
                    return Ev.STALE_POLL
                if poll_id < self.newest_poll:
                    return Ev.LATE_POLL
                if self.mode is Mode.PREEMPTED:
                    return Ev.OBSERVED if preempts else Ev.PREEMPT_ENDED
                if preempts:
                    return Ev.PREEMPT_BEGAN
                p = self.pending
                if self.mode is Mode.IN_TRANSITION and p is not None and set(p.command.phases) <= state.greens:
                    return Ev.VERIFIED if p.command.green is None else Ev.VERIFIED_DURATION
                return Ev.OBSERVED
            case PollFailed(poll_id=poll_id, epoch=epoch):
                if epoch != self.poll_epoch:
                    return Ev.STALE_POLL
                return Ev.POLLS_FAILED if self._run_with(poll_id) >= self.n_timeout else Ev.POLL_FAILED
            case StartupLost():
                return Ev.STARTUP_UNREACHABLE if self.startup_attempts + 1 >= self.n_timeout else Ev.STARTUP_RETRY
            case CallsFound(calls=calls):
                return Ev.CALLS_WATCHED if calls and not self.take_over else Ev.CALLS_LEFT
            case CallsWatched(t=t, calls=calls):
                since, found = self._found
                if calls != found:
                    return Ev.CALLS_CHANGED
                return Ev.CALLS_LEFT if t - since >= self.watch else Ev.CALLS_WATCHED
            case ScheduleRequested(schedule=schedule):
                return Ev.SCHEDULE if schedule.orders else Ev.SCHEDULE_CLEAR
            case TimerExpired(kind=kind, token=token) if self.stale(kind, token):
                return Ev.STALE_TIMER
            case TimerExpired(kind=TimerKind.CONTROL):
                schedule = self.running.schedule
                last = not schedule.open and self.running.next_instant == schedule.instants[-1]
                return Ev.SCHEDULE_DONE if last else Ev.CONTROL_DUE
            case TimerExpired(kind=kind):
                if kind is TimerKind.KEEPALIVE:
                    return Ev.KEEPALIVE_DUE
                if kind is TimerKind.RECOVER:
                    return Ev.RECOVERY_DUE
                return Ev.TRANSITION_EXPIRED if kind is TimerKind.TRANSITION else Ev.DURATION_ELAPSED
            case StepTimed(step=step, took=took):
                if took <= step:
                    return Ev.ON_TIME
                return Ev.DRIFT_LIMIT if self.drifted_in_a_row + 1 >= self.n_drift else Ev.DRIFTED
            case SetAnswered(purpose=Purpose.RECOVERY):
                return Ev.RECOVERY_SET_ANSWERED if self.running is None else Ev.RECOVERED_TO_SCHEDULE
            case SetAnswered(purpose=purpose):
                return Ev.CLEAR_ANSWERED if purpose is Purpose.CLEAR else Ev.SET_RESULT
            case SetFailed(purpose=purpose, command_id=command_id, lost=lost):
                if purpose is Purpose.RECOVERY:
                    return Ev.RECOVERY_SET_FAILED
                if purpose is Purpose.CLEAR:
                    return Ev.CLEAR_LOST if lost and self.clears_sent < CLEAR_ATTEMPTS else Ev.CLEAR_FAILED
                p = self.pending
                if (lost and purpose in (Purpose.COMMAND, Purpose.RETRY) and self.mode is Mode.IN_TRANSITION
                        and p is not None and p.command_id == command_id):
                    return Ev.COMMAND_SET_LOST
                return Ev.SET_RESULT
            case ReadbackDue():
                return Ev.READBACK_WAITS if self.polls_failing else Ev.READBACK
            case ControlsRead():
                if self._foreign(ev):
                    return Ev.FOREIGN_CONTROL
                return Ev.CONTROLS_LOST if self._lost(ev) else Ev.CONTROLS_OURS
        return _PLAIN_KINDS[type(ev)]

    @property
    def polls_failing(self) -> bool:
        """True while a poll newer than the newest answered one has failed."""
        return self.newest_failed > self.newest_poll

    def _run_with(self, poll_id: int) -> int:
        """The failed polls of consecutive ids, in poll order, that poll ``poll_id`` failing makes (itself too)."""
        failed, below, above = self._failed, 0, 0
        while poll_id - below - 1 in failed:
            below += 1
        while poll_id + above + 1 in failed:
            above += 1
        return below + 1 + above

    def _foreign(self, ev: ControlsRead) -> str:
        """What of the read-back is not ours ('' when all of it is)."""
        if self.phase_control:
            read = self._judged(ev)
            return "; ".join(f"{CONTROL_TABLE[c].name} on phases {sorted(read[c] - self.sent[c])} (the run's: "
                             f"{sorted(self.sent[c])})" for c in ControlColumn if read and read[c] - self.sent[c])
        found = [f"{name} on phases {sorted(phases)}" for name, phases in ev.held if phases]
        sent_then, judged = self._readback
        if ev.veh_call is not None and judged and sent_then == self._sets_sent and ev.veh_call != self.call:
            found.append(f"phaseControlGroupVehCall on phases {sorted(ev.veh_call)} (the run's call: "
                         f"{sorted(self.call)})")
        return "; ".join(found)

    def _lost(self, ev: ControlsRead) -> str:
        """Phase control: what the run SET that the read-back no longer finds ('' when nothing). A force-off is
        not lost when its bit is gone: "When the phase green terminates, the associated bit shall be reset to 0"
        (NTCIP 1202, phaseControlGroupForceOff)."""
        read = self._judged(ev) if self.phase_control else None
        return "; ".join(f"{CONTROL_TABLE[c].name} lost phases {sorted(self.sent[c] - read[c])}"
                         for c in ControlColumn if read and c is not ControlColumn.FORCE_OFF and self.sent[c] - read[c])

    def _judged(self, ev: ControlsRead) -> dict[ControlColumn, frozenset[int]] | None:
        """Phase control: the six objects as read back, when no SET of the run could race the read (none sent
        between the read and its answer, every one answered); None when the read cannot be judged. Every object may
        be the run's, so a racing read tells nothing of whose it is."""
        sent_then, clean = self._readback
        if ev.veh_call is None or not clean or sent_then != self._sets_sent:
            return None
        return {**{_BY_NAME[name]: phases for name, phases in ev.held}, ControlColumn.VEH_CALL: ev.veh_call}

    def _call_known(self) -> bool:
        """True when the controller holds the call last SET for sure: every SET answered, the last one too."""
        return self._sets_pending == 0 and not self._set_failed

    # --- handlers: effects only ------------------------------------------------------------------

    def _started(self, ev: Started, out: list[Effect]) -> None:
        self._sync(ev.greens)
        self.greens = ev.greens
        self.backup_time = ev.backup_time
        if ev.backup_time:
            limit = ev.backup_time / 3.0  # the controller's own backup time rules
            self.keepalive_period = min(self.keepalive_period, limit) if self.keepalive_period else limit
        self._arm_keepalive(out)
        out.append(StartupDone())

    def _retry_startup(self, ev: StartupLost, out: list[Effect]) -> None:
        self.startup_attempts += 1
        out.append(PollFailureSeen(0, f"start-up read: {ev.error}", self.startup_attempts))
        out.append(RetryStartup())

    def _unreachable(self, ev: StartupLost, out: list[Effect]) -> None:
        self._last_attempt(ev, out)
        self._enter_timeout(ev.t, TimeoutReason.COMMUNICATION, f"controller unreachable at start-up: {ev.error}", out)
        out.append(StartupDone())

    def _give_up_startup(self, ev: StartupLost, out: list[Effect]) -> None:
        self._last_attempt(ev, out)
        out.append(StartupDone())

    def _last_attempt(self, ev: StartupLost, out: list[Effect]) -> None:
        self.startup_attempts += 1
        out.append(PollFailureSeen(0, f"start-up read: {ev.error}", self.startup_attempts))
        out.append(ControllerUnreachable(self.startup_attempts))

    def _refused(self, ev: StartupRefused, out: list[Effect]) -> None:
        out.append(Note(f"start-up: {ev.detail}"))
        self._enter_timeout(ev.t, TimeoutReason.COMMUNICATION, ev.detail, out)
        out.append(StartupDone())

    def _note_refusal(self, ev: StartupRefused, out: list[Effect]) -> None:
        out.append(Note(f"start-up: {ev.detail}"))
        out.append(StartupDone())

    def _end_startup(self, ev: Started | StartupLost | StartupRefused | CallsFound | CallsWatched,
                     out: list[Effect]) -> None:
        out.append(StartupDone())

    def _watch_calls(self, ev: CallsFound | CallsWatched, out: list[Effect]) -> None:
        if isinstance(ev, CallsFound):
            self._found = (ev.t, ev.calls)
            out.append(Note(f"start-up: VehCall holds phases {sorted(ev.calls)} placed by someone else: watching "
                            f"them for {self.watch:g} s before taking the controller"))
        out.append(WatchCalls(self.watch_period))

    def _another_manager(self, ev: CallsWatched, out: list[Effect]) -> None:
        since, found = self._found
        detail = (f"another manager drives the controller: its VehCall went from phases {sorted(found)} to "
                  f"{sorted(ev.calls)} while the run watched for {ev.t - since:.1f} s")
        out.append(AnotherManager(detail))
        self._enter_timeout(ev.t, TimeoutReason.FOREIGN_CONTROL, detail, out)
        out.append(StartupDone())

    def _dispatch(self, ev: CommandRequested, out: list[Effect]) -> None:
        command_id = self._new_command()
        token = self._new_token()
        cmd = ev.command
        self.pending = Pending(command_id, cmd, ev.t, token)
        if cmd.phases in self.sequence:
            self.position = self.sequence.index(cmd.phases)
        out.append(Dispatch(command_id, ev.action_id, cmd))
        self._send(frozenset(cmd.phases), Purpose.COMMAND, command_id, ev.t, out)
        out.append(StartTimer(TimerKind.TRANSITION, self.tau_trans, token))

    def _keep(self, ev: CommandRequested, out: list[Effect]) -> None:
        out.append(CommandEnded(self._new_command(), "keep", 0.0))

    def _drop(self, ev: CommandRequested, out: list[Effect]) -> None:
        out.append(Dropped(ev.action_id, self.mode.log_name))

    def _refuse(self, ev: CommandRequested, out: list[Effect]) -> None:
        out.append(Refused(ev.action_id, self.refusal()))

    def _preempt_began(self, ev: PollAnswered, out: list[Effect]) -> None:
        self._answered(ev, out)
        p = self.pending
        if p is not None:  # the controller leaves the commanded phases for the preempt's: no TIMEOUT will follow
            out.append(CommandEnded(p.command_id, "preempted", ev.t - p.since))
            self.pending = None
        self.preempts = ev.preempts
        self.preempted_since = ev.t
        out.append(PreemptBegan(ev.preempts, p.command_id if p else None))
        if self.phase_control:
            self._end_schedule("preempted", out)
            self._let_go(Purpose.WITHDRAW, ev.t, out)
        elif self.call:
            self._send(frozenset(), Purpose.WITHDRAW, None, ev.t, out)

    def _still_preempted(self, ev: PollAnswered, out: list[Effect]) -> None:
        self._answered(ev, out)
        self.preempts = ev.preempts  # a lower-numbered preempt may have taken over

    def _preempt_over(self, ev: PollAnswered, out: list[Effect]) -> None:
        self._answered(ev, out)
        greens = ev.state.greens
        out.append(PreemptEnded(ev.t - self.preempted_since, greens))
        self.preempts = frozenset()
        self._sync(greens)

    def _answered(self, ev: PollAnswered, out: list[Effect]) -> None:
        # the first answer after failed polls, in poll order: one failed between the state shown and this one
        after_failures = self.polls_failing and any(self.newest_poll < i < ev.poll_id for i in self._failed)
        self.newest_poll = ev.poll_id
        self.polls_answered += 1
        self.greens = ev.state.greens
        out.append(ShowSignal(ev.poll_id, ev.state, after_failures))
        if self.running is not None:
            self._orders_changed(self.running.seen(self.greens), out)

    def _late(self, ev: PollAnswered, out: list[Effect]) -> None:
        self.polls_late += 1

    def _verified(self, ev: PollAnswered, out: list[Effect]) -> None:
        self._answered(ev, out)
        p = self.pending
        hold = ev.t - p.since
        out.append(Verified(p.command_id, p.command, ev.poll_id, hold))
        out.append(CommandEnded(p.command_id, "verified", hold))
        self.pending = None

    def _serve(self, ev: PollAnswered, out: list[Effect]) -> None:
        self._answered(ev, out)
        p = self.pending
        out.append(Verified(p.command_id, p.command, ev.poll_id, ev.t - p.since))
        token = self._new_token()
        self.pending = Pending(p.command_id, p.command, p.since, token)
        out.append(StartTimer(TimerKind.DURATION, p.command.green, token))

    def _poll_failed(self, ev: PollFailed, out: list[Effect]) -> None:
        self.polls_failed += 1
        run = self._run_with(ev.poll_id)
        self._failed.add(ev.poll_id)
        self.newest_failed = max(self.newest_failed, ev.poll_id)
        if len(self._failed) > _FAILED_KEPT:  # polls settle within tau_udp: older failures are in no run to come
            self._failed = {i for i in self._failed if i > self.newest_failed - _FAILED_KEPT // 2}
        out.append(PollFailureSeen(ev.poll_id, ev.error, run))

    def _polls_failed(self, ev: PollFailed, out: list[Effect]) -> None:
        self._poll_failed(ev, out)
        self._enter_timeout(ev.t, TimeoutReason.COMMUNICATION,
                            f"{self.n_timeout} consecutive polls failed (last: {ev.kind})", out)

    def _served(self, ev: TimerExpired, out: list[Effect]) -> None:
        p = self.pending
        out.append(CommandEnded(p.command_id, "served", ev.t - p.since))
        self.pending = None

    def _retry(self, ev: SetFailed, out: list[Effect]) -> None:
        # The SET is idempotent; tau_trans still bounds the wait, and each try takes tau_udp.
        self._settled(ev, out)
        p = self.pending
        self._send(frozenset(p.command.phases), Purpose.RETRY, p.command_id, ev.t, out)

    def _keepalive(self, ev: TimerExpired, out: list[Effect]) -> None:
        # Any SET of a control object restarts the controller's backup timer: refresh only when no
        # SET went out for a whole period (a later SET re-armed the timer, so this one is stale).
        if self.keepalive_on and self.phase_control:
            # Any SET of a control object restarts the backup timer (NTCIP 1202, unitBackupTime): the objects that
            # hold phases are SET again as they stand, a force-off aside (it resets itself when its green ends, and
            # set again after a green ended unseen it would end the phase's next green), and VehCall always.
            kept = {c: p for c, p in self.sent.items() if (p and c is not ControlColumn.FORCE_OFF)
                    or c is ControlColumn.VEH_CALL}
            self._send_controls(kept, Purpose.KEEPALIVE, ev.t, out)
        elif self.keepalive_on:
            self._send(self.call, Purpose.KEEPALIVE, None, ev.t, out)
        else:
            self._arm_keepalive(out)

    def _switch_keepalive(self, ev: KeepaliveSwitched, out: list[Effect]) -> None:
        self.keepalive_on = ev.on

    def _transition_timeout(self, ev: TimerExpired, out: list[Effect]) -> None:
        p = self.pending
        self._enter_timeout(ev.t, TimeoutReason.TRANSITION,
                            f"phases {list(p.command.phases)} not green after {ev.t - p.since:.3f} s", out)

    def _on_time(self, ev: StepTimed, out: list[Effect]) -> None:
        self.drifted_in_a_row = 0

    def _drifted(self, ev: StepTimed, out: list[Effect]) -> None:
        self.drifted_in_a_row += 1
        out.append(DriftSeen(ev.step, ev.took, self.drifted_in_a_row))

    def _drift_limit(self, ev: StepTimed, out: list[Effect]) -> None:
        self._drifted(ev, out)
        self._enter_timeout(ev.t, TimeoutReason.DRIFT,
                            f"{self.n_drift} consecutive steps took longer than {ev.step} s", out)

    def _nothing_to_recover(self, ev: RecoveryRequested, out: list[Effect]) -> None:
        # Re-SETting the call to the greens shown would cancel a command in transition.
        out.append(Note(f"recover() in {self.mode.log_name}: nothing to recover"))

    def _read_controller(self, ev: RecoveryRequested | TimerExpired, out: list[Effect]) -> None:
        self._recover_token = None
        out.append(RecoveryStarted())
        out.append(ReadController())

    def _recovery_set(self, ev: ControllerRead, out: list[Effect]) -> None:
        self._sync(ev.greens)
        self.greens = ev.greens
        self._recovering_greens = ev.greens
        if not self.phase_control:
            self._send(ev.greens, Purpose.RECOVERY, None, ev.t, out)
            return
        # Phase control: every object SET to what the schedule asks now (what someone else set goes too).
        if ev.backup_mode:
            out.append(ControlsReset(f"the controller reports backupMode: no control object was SET within its "
                                     f"backup time ({self.backup_time} s), and it reset every one; SET again as the "
                                     "schedule asks now"))
        self._send_controls(self._asked(), Purpose.RECOVERY, ev.t, out)

    def _recovered(self, ev: SetAnswered, out: list[Effect]) -> None:
        self._settled(ev, out)
        self.timeout_reason = None
        self.drifted_in_a_row = 0
        self._failed.clear()
        self.newest_failed = 0
        out.append(Recovered(self._recovering_greens))
        out.append(ResumePolling())
        if self.running is not None:  # an order started or ended while the recovery SET was on its way
            self._send_changes(Purpose.SCHEDULE, ev.t, out)

    def _recovery_failed(self, ev: ControllerUnreadable | SetFailed, out: list[Effect]) -> None:
        if isinstance(ev, SetFailed):
            self._settled(ev, out)
            if self.phase_control and ev.lost:  # it may have landed: in TIMEOUT the run holds nothing
                self._let_go(Purpose.RELEASE, ev.t, out)
            elif self.phase_control:  # refused: an SNMP SET applies whole or not at all, so nothing of it landed
                self.sent = no_controls()
        what = ev.error if isinstance(ev, ControllerUnreadable) else "the recovery SET got no answer"
        out.append(Note(f"recovery failed, still in TIMEOUT: {what}"))
        self._arm_recovery(out)

    def _read_controls(self, ev: ReadbackDue, out: list[Effect]) -> None:
        self._readback = (self._sets_sent, self._call_known())
        out.append(ReadControls())

    def _settled(self, ev: SetAnswered | SetFailed, out: list[Effect]) -> None:
        """A SET of VehCall answered or failed (a lost request may not have reached the controller, a lost answer
        may have)."""
        self._sets_pending -= 1
        if isinstance(ev, SetFailed):
            self._set_failed = True

    def _agent_overdue(self, ev: AgentOverdue, out: list[Effect]) -> None:
        self._enter_timeout(ev.t, TimeoutReason.AGENT,
                            f"the agent gave no action within the control interval ({ev.waited:g} s)", out)

    def _foreign_control(self, ev: ControlsRead, out: list[Effect]) -> None:
        self._enter_timeout(ev.t, TimeoutReason.FOREIGN_CONTROL, f"set by someone else: {self._foreign(ev)}", out)

    def _close(self, ev: CloseRequested, out: list[Effect]) -> None:
        self._halt(out)
        self._keepalive_token = None
        self._recover_token = None
        self._end_schedule("closed", out)
        if self.last_set > float("-inf"):  # a run that never SET a call has none to clear
            self._clear(ev.t, out)
        else:
            out.append(CloseDone())

    def _clear_again(self, ev: SetFailed, out: list[Effect]) -> None:
        self._settled(ev, out)
        self._clear(ev.t, out)

    def _cleared(self, ev: SetAnswered, out: list[Effect]) -> None:
        self._settled(ev, out)
        out.append(CloseDone())

    def _not_cleared(self, ev: SetFailed, out: list[Effect]) -> None:
        self._settled(ev, out)
        out.append(CloseDone(ev.error or "the clearing SET failed"))

    def _clear(self, t: float, out: list[Effect]) -> None:
        self.clears_sent += 1
        if self.phase_control:
            self._send_controls(no_controls(), Purpose.CLEAR, t, out)
        else:
            self._send(frozenset(), Purpose.CLEAR, None, t, out)

    # --- phase control ----------------------------------------------------------------------------------

    def _schedule(self, ev: ScheduleRequested, out: list[Effect]) -> None:
        self._end_schedule("replaced" if ev.schedule.orders else "cleared", out)
        if ev.schedule.orders:
            self.running = Running(ev.schedule, ev.t)
            out.append(ScheduleBegan(ev.action_id, ev.schedule))
            if self.running.next_instant == 0:
                self._orders_changed(self.running.pass_instant(self.greens), out)
        self._send_changes(Purpose.SCHEDULE, ev.t, out)
        self._arm_control(ev.t, out)

    def _control_due(self, ev: TimerExpired, out: list[Effect]) -> None:
        self._orders_changed(self.running.pass_instant(self.greens), out)
        self._send_changes(Purpose.SCHEDULE, ev.t, out)
        self._arm_control(ev.t, out)

    def _schedule_done(self, ev: TimerExpired, out: list[Effect]) -> None:
        self._orders_changed(self.running.pass_instant(self.greens), out)
        self._end_schedule("done", out)
        self._send_changes(Purpose.SCHEDULE, ev.t, out)

    def _control_due_halted(self, ev: TimerExpired, out: list[Effect]) -> None:
        # Nothing is sent while halted: the orders go on, and the recovery SETs what they ask then.
        self._orders_changed(self.running.pass_instant(self.greens), out)
        self._arm_control(ev.t, out)

    def _schedule_done_halted(self, ev: TimerExpired, out: list[Effect]) -> None:
        self._orders_changed(self.running.pass_instant(self.greens), out)
        self._end_schedule("done", out)

    def _reestablish(self, ev: ControlsRead, out: list[Effect]) -> None:
        out.append(ControlsReset(f"the controller no longer holds what the run SET ({self._lost(ev)}); SET again as "
                                 "the schedule asks now"))
        self._send_controls(self._asked(), Purpose.REESTABLISH, ev.t, out)

    def _end_schedule(self, reason: str, out: list[Effect]) -> None:
        if self.running is None:
            return
        self._orders_changed(self.running.cancel(), out)
        self.running = None
        self._control_token = None
        out.append(ScheduleEnded(reason))

    def _orders_changed(self, changes: list[Change], out: list[Effect]) -> None:
        for change in changes:
            out.append(OrderChanged(change))
            if change.after is OrderState.SPENT:
                # "When the phase green terminates, the associated bit shall be reset to 0": the controller did it.
                self.sent[ControlColumn.FORCE_OFF] -= {change.order.phase}

    def _asked(self) -> dict[ControlColumn, frozenset[int]]:
        """What the control objects hold by the running schedule now (all at 0 when none runs)."""
        return self.running.image() if self.running is not None else no_controls()

    def _send_changes(self, purpose: Purpose, t: float, out: list[Effect]) -> None:
        """SET the control objects whose phases the running schedule now asks other than as last SET."""
        changed = {c: p for c, p in self._asked().items() if p != self.sent[c]}
        if changed:
            self._send_controls(changed, purpose, t, out)

    def _let_go(self, purpose: Purpose, t: float, out: list[Effect]) -> None:
        """Every control object at 0, when any holds phases by the run."""
        if any(self.sent.values()):
            self._send_controls(no_controls(), purpose, t, out)

    def _arm_control(self, t: float, out: list[Effect]) -> None:
        running = self.running
        nxt = running.next_instant if running is not None else None
        if nxt is None:
            self._control_token = None
            return
        self._control_token = self._new_token()
        out.append(StartTimer(TimerKind.CONTROL, max(0.0, running.received + nxt / 10 - t), self._control_token))

    def _send_controls(self, controls: dict[ControlColumn, frozenset[int]], purpose: Purpose, t: float,
                       out: list[Effect]) -> None:
        self.sent.update(controls)
        self.last_set = t
        self._sets_sent += 1
        self._sets_pending += 1
        self._set_failed = False
        out.append(SendControls(tuple((c, controls[c]) for c in ControlColumn if c in controls), purpose))
        if purpose is not Purpose.CLEAR:
            self._arm_keepalive(out)

    # --- helpers ---------------------------------------------------------------------------------------

    def _enter_timeout(self, t: float, reason: TimeoutReason, detail: str, out: list[Effect]) -> None:
        p = self.pending
        if p is not None:
            out.append(CommandEnded(p.command_id, "timeout", t - p.since))
            self.pending = None
        self.timeout_reason = reason
        out.append(TimeoutEntered(reason, detail, p.command_id if p else None))
        self._halt(out)
        if self.phase_control:  # nobody manages the control objects now: a hold left on would keep its green
            self._let_go(Purpose.RELEASE, t, out)
        self._arm_recovery(out)

    def _halt(self, out: list[Effect]) -> None:
        self.poll_epoch += 1  # results of polls sent until now are stale
        out.append(HaltPolling())

    def _arm_recovery(self, out: list[Effect]) -> None:
        if self.recover_after is not None:
            self._recover_token = self._new_token()
            out.append(StartTimer(TimerKind.RECOVER, self.recover_after, self._recover_token))

    def _send(self, phases: frozenset[int], purpose: Purpose, command_id: int | None, t: float,
              out: list[Effect]) -> None:
        self.sent[ControlColumn.VEH_CALL] = phases
        self.last_set = t
        self._sets_sent += 1
        self._sets_pending += 1
        self._set_failed = False
        out.append(SendCall(phases, purpose, command_id))
        if purpose is not Purpose.CLEAR:
            self._arm_keepalive(out)

    def _arm_keepalive(self, out: list[Effect]) -> None:
        if self.keepalive_period:
            self._keepalive_token = self._new_token()
            out.append(StartTimer(TimerKind.KEEPALIVE, self.keepalive_period, self._keepalive_token))

    def _sync(self, greens: frozenset[int]) -> None:
        """Align the sequence position with the pair the controller shows (start-up, recovery)."""
        for i, pair in enumerate(self.sequence):
            if set(pair) <= greens:
                self.position = i
                return

    def _new_command(self) -> int:
        self._next_command += 1
        return self._next_command

    def _new_token(self) -> int:
        self._next_token += 1
        return self._next_token


_BY_NAME = {CONTROL_TABLE[c].name: c for c in ControlColumn}

_PLAIN_KINDS: dict[type, Ev] = {
    Started: Ev.STARTED, StartupRefused: Ev.STARTUP_REFUSED, RecoveryRequested: Ev.RECOVERY_REQUESTED,
    ControllerRead: Ev.CONTROLLER_READ, ControllerUnreadable: Ev.CONTROLLER_UNREADABLE,
    KeepaliveSwitched: Ev.KEEPALIVE_SWITCHED, CloseRequested: Ev.CLOSE, AgentOverdue: Ev.AGENT_OVERDUE,
}

_Handler = Callable[[Manager, Event, list[Effect]], None] | None
M = Mode
H = Manager

# The states of a machine commanding; at work (keepalive, drift, polls, read-back), PREEMPTED too; halted.
_RUNNING = (M.IDLE, M.IN_TRANSITION, M.SERVING, M.SCHEDULED)
_WORKING = (*_RUNNING, M.PREEMPTED)
_DOWN = (M.TIMEOUT, M.RECOVERING)

# The whole state machine, one row per line: (state, event kind) -> (next state, handler producing the effects).
# A line over several states (a named tuple of them) writes the same row for each.
_TRANSITIONS: dict[tuple[Mode, Ev], tuple[Mode, _Handler]] = {
    # --- start-up ---------------------------------------------------------------------------------------
    (M.STARTING, Ev.STARTED): (M.IDLE, H._started),
    (M.STARTING, Ev.STARTUP_RETRY): (M.STARTING, H._retry_startup),
    (M.STARTING, Ev.STARTUP_UNREACHABLE): (M.TIMEOUT, H._unreachable),
    (M.STARTING, Ev.STARTUP_REFUSED): (M.TIMEOUT, H._refused),
    (M.STARTING, Ev.CALLS_WATCHED): (M.STARTING, H._watch_calls),
    (M.STARTING, Ev.CALLS_LEFT): (M.STARTING, None),  # nobody changed them: the start-up goes on and clears them
    (M.STARTING, Ev.CALLS_CHANGED): (M.TIMEOUT, H._another_manager),
    # The start-up read can end after the run has already timed out (steps of a large grid drifting while its
    # controllers start at the wall clock) or closed: what it read is kept, the state stays.
    **{(s, Ev.STARTED): (s, H._started) for s in _DOWN},
    **{(s, Ev.STARTUP_RETRY): (s, H._retry_startup) for s in _DOWN},
    **{(s, Ev.STARTUP_UNREACHABLE): (s, H._give_up_startup) for s in _DOWN},
    **{(s, Ev.STARTUP_REFUSED): (s, H._note_refusal) for s in _DOWN},
    (M.CLOSED, Ev.STARTED): (M.CLOSED, H._end_startup),
    (M.CLOSED, Ev.STARTUP_RETRY): (M.CLOSED, H._end_startup),  # closed: no more attempts
    (M.CLOSED, Ev.STARTUP_UNREACHABLE): (M.CLOSED, H._end_startup),
    (M.CLOSED, Ev.STARTUP_REFUSED): (M.CLOSED, H._end_startup),
    **{(s, Ev.CALLS_WATCHED): (s, None) for s in _DOWN},  # timed out while reading: no watch, the start-up goes on
    **{(s, Ev.CALLS_LEFT): (s, None) for s in _DOWN},
    **{(s, Ev.CALLS_CHANGED): (s, None) for s in _DOWN},
    (M.CLOSED, Ev.CALLS_WATCHED): (M.CLOSED, H._end_startup),
    (M.CLOSED, Ev.CALLS_LEFT): (M.CLOSED, H._end_startup),
    (M.CLOSED, Ev.CALLS_CHANGED): (M.CLOSED, H._end_startup),
    # --- commands ---------------------------------------------------------------------------------------
    (M.IDLE, Ev.COMMAND): (M.IN_TRANSITION, H._dispatch),
    (M.IDLE, Ev.KEEP): (M.IDLE, H._keep),
    **{(s, Ev.COMMAND): (s, H._drop) for s in (M.STARTING, M.IN_TRANSITION, M.SERVING, *_DOWN, M.CLOSED)},
    **{(s, Ev.KEEP): (s, H._drop) for s in (M.STARTING, M.IN_TRANSITION, M.SERVING, *_DOWN, M.CLOSED)},
    # (a run commands by phase commands or by phase control, never both: SCHEDULED sees no command, IN_TRANSITION
    # and SERVING no schedule)
    (M.PREEMPTED, Ev.COMMAND): (M.PREEMPTED, H._refuse),
    (M.PREEMPTED, Ev.KEEP): (M.PREEMPTED, H._refuse),
    (M.IN_TRANSITION, Ev.COMMAND_SET_LOST): (M.IN_TRANSITION, H._retry),
    (M.IN_TRANSITION, Ev.TRANSITION_EXPIRED): (M.TIMEOUT, H._transition_timeout),
    (M.SERVING, Ev.DURATION_ELAPSED): (M.IDLE, H._served),
    (M.CLOSED, Ev.TRANSITION_EXPIRED): (M.CLOSED, None),  # the command pending at the close stays open
    (M.CLOSED, Ev.DURATION_ELAPSED): (M.CLOSED, None),
    # --- phase control: a schedule replaces the one running; a step (orders without end) runs until replaced --
    (M.IDLE, Ev.SCHEDULE): (M.SCHEDULED, H._schedule),
    (M.SCHEDULED, Ev.SCHEDULE): (M.SCHEDULED, H._schedule),
    (M.IDLE, Ev.SCHEDULE_CLEAR): (M.IDLE, H._schedule),
    (M.SCHEDULED, Ev.SCHEDULE_CLEAR): (M.IDLE, H._schedule),
    (M.PREEMPTED, Ev.SCHEDULE): (M.PREEMPTED, H._refuse),
    (M.PREEMPTED, Ev.SCHEDULE_CLEAR): (M.PREEMPTED, H._refuse),
    **{(s, Ev.SCHEDULE): (s, H._drop) for s in (M.STARTING, *_DOWN, M.CLOSED)},
    **{(s, Ev.SCHEDULE_CLEAR): (s, H._drop) for s in (M.STARTING, *_DOWN, M.CLOSED)},
    (M.SCHEDULED, Ev.CONTROL_DUE): (M.SCHEDULED, H._control_due),
    (M.SCHEDULED, Ev.SCHEDULE_DONE): (M.IDLE, H._schedule_done),
    **{(s, Ev.CONTROL_DUE): (s, H._control_due_halted) for s in _DOWN},  # the orders go on; nothing is sent
    **{(s, Ev.SCHEDULE_DONE): (s, H._schedule_done_halted) for s in _DOWN},
    **{(s, Ev.CONTROLS_LOST): (s, H._reestablish) for s in _WORKING},
    **{(s, Ev.CONTROLS_LOST): (s, None) for s in (*_DOWN, M.CLOSED)},  # halted: the recovery SETs them all
    # --- polls (halted in TIMEOUT, RECOVERING and CLOSED: every result there is from before the halt) ----
    (M.IN_TRANSITION, Ev.VERIFIED): (M.IDLE, H._verified),
    (M.IN_TRANSITION, Ev.VERIFIED_DURATION): (M.SERVING, H._serve),
    **{(s, Ev.OBSERVED): (s, H._answered) for s in _RUNNING},
    **{(s, Ev.LATE_POLL): (s, H._late) for s in _WORKING},
    **{(s, Ev.POLL_FAILED): (s, H._poll_failed) for s in _WORKING},
    **{(s, Ev.POLLS_FAILED): (M.TIMEOUT, H._polls_failed) for s in _WORKING},  # preempted or not
    **{(s, Ev.STALE_POLL): (s, None) for s in (*_WORKING, *_DOWN, M.CLOSED)},
    # --- preemption: the controller's own operation -----------------------------------------------------
    **{(s, Ev.PREEMPT_BEGAN): (M.PREEMPTED, H._preempt_began) for s in _RUNNING},
    (M.PREEMPTED, Ev.OBSERVED): (M.PREEMPTED, H._still_preempted),
    (M.PREEMPTED, Ev.PREEMPT_ENDED): (M.IDLE, H._preempt_over),
    # --- timers -----------------------------------------------------------------------------------------
    **{(s, Ev.KEEPALIVE_DUE): (s, H._keepalive) for s in _WORKING},
    **{(s, Ev.KEEPALIVE_DUE): (s, None) for s in _DOWN},  # gated; the recovery SET re-arms it
    (M.TIMEOUT, Ev.RECOVERY_DUE): (M.RECOVERING, H._read_controller),
    **{(s, Ev.STALE_TIMER): (s, None) for s in Mode},
    # --- simulation steps (drift is counted while the machine works) ---------------------------------
    **{(s, Ev.ON_TIME): (s, H._on_time) for s in (M.STARTING, *_WORKING)},
    **{(s, Ev.DRIFTED): (s, H._drifted) for s in (M.STARTING, *_WORKING)},
    **{(s, Ev.DRIFT_LIMIT): (M.TIMEOUT, H._drift_limit) for s in (M.STARTING, *_WORKING)},
    **{(s, Ev.ON_TIME): (s, None) for s in (*_DOWN, M.CLOSED)},
    **{(s, Ev.DRIFTED): (s, None) for s in (*_DOWN, M.CLOSED)},
    **{(s, Ev.DRIFT_LIMIT): (s, None) for s in (*_DOWN, M.CLOSED)},
    # --- SET answers ------------------------------------------------------------------------------------
    **{(s, Ev.SET_RESULT): (s, H._settled) for s in Mode},
    (M.RECOVERING, Ev.RECOVERY_SET_ANSWERED): (M.IDLE, H._recovered),
    (M.RECOVERING, Ev.RECOVERED_TO_SCHEDULE): (M.SCHEDULED, H._recovered),
    (M.RECOVERING, Ev.RECOVERY_SET_FAILED): (M.TIMEOUT, H._recovery_failed),
    (M.CLOSED, Ev.RECOVERY_SET_ANSWERED): (M.CLOSED, H._settled),  # a recovery overtaken by the close
    (M.CLOSED, Ev.RECOVERY_SET_FAILED): (M.CLOSED, H._settled),
    (M.CLOSED, Ev.CLEAR_ANSWERED): (M.CLOSED, H._cleared),
    (M.CLOSED, Ev.CLEAR_LOST): (M.CLOSED, H._clear_again),
    (M.CLOSED, Ev.CLEAR_FAILED): (M.CLOSED, H._not_cleared),
    # --- recovery ---------------------------------------------------------------------------------------
    **{(s, Ev.RECOVERY_REQUESTED): (s, H._nothing_to_recover) for s in (M.STARTING, *_WORKING)},
    (M.TIMEOUT, Ev.RECOVERY_REQUESTED): (M.RECOVERING, H._read_controller),
    (M.RECOVERING, Ev.RECOVERY_REQUESTED): (M.RECOVERING, None),  # one recovery at a time
    (M.CLOSED, Ev.RECOVERY_REQUESTED): (M.CLOSED, None),
    (M.RECOVERING, Ev.CONTROLLER_READ): (M.RECOVERING, H._recovery_set),
    (M.RECOVERING, Ev.CONTROLLER_UNREADABLE): (M.TIMEOUT, H._recovery_failed),
    (M.CLOSED, Ev.CONTROLLER_READ): (M.CLOSED, None),
    (M.CLOSED, Ev.CONTROLLER_UNREADABLE): (M.CLOSED, None),
    # --- the read-back of the control objects ---------------------------------------------------------
    **{(s, Ev.READBACK): (s, H._read_controls) for s in _WORKING},
    **{(s, Ev.READBACK_WAITS): (s, None) for s in _WORKING},  # polls are failing: the poll count speaks
    **{(s, Ev.READBACK): (s, None) for s in (*_DOWN, M.CLOSED)},  # in TIMEOUT only recovery sends
    **{(s, Ev.READBACK_WAITS): (s, None) for s in (*_DOWN, M.CLOSED)},
    **{(s, Ev.FOREIGN_CONTROL): (M.TIMEOUT, H._foreign_control) for s in _WORKING},
    **{(s, Ev.FOREIGN_CONTROL): (s, None) for s in (*_DOWN, M.CLOSED)},  # halted: the recovery clears them
    **{(s, Ev.CONTROLS_OURS): (s, None) for s in (*_WORKING, *_DOWN, M.CLOSED)},
    # --- the agent ------------------------------------------------------------------------------------
    **{(s, Ev.AGENT_OVERDUE): (M.TIMEOUT, H._agent_overdue) for s in _WORKING},
    **{(s, Ev.AGENT_OVERDUE): (s, None) for s in (*_DOWN, M.CLOSED)},  # already halted, or over
    # --- the keepalive switch and the close ---------------------------------------------------------
    **{(s, Ev.KEEPALIVE_SWITCHED): (s, H._switch_keepalive) for s in Mode},
    **{(s, Ev.CLOSE): (M.CLOSED, H._close) for s in (M.STARTING, *_WORKING, *_DOWN)},
    (M.CLOSED, Ev.CLOSE): (M.CLOSED, None),
}


def graph() -> list[tuple[Mode, Ev, Mode]]:
    """Every edge of the state graph that changes the state, as (from, event kind, to), read off the table."""
    return sorted(((s, ev, to) for (s, ev), (to, _handler) in _TRANSITIONS.items() if to is not s),
                  key=lambda e: (list(Mode).index(e[0]), e[1].value))


def _dot() -> str:
    """The state graph in Graphviz's dot language (``python -m hils.control.manager | dot -Tsvg``)."""
    lines = ["digraph manager {", "  rankdir=LR;"]
    lines += [f'  {a.name} -> {b.name} [label="{ev.name.lower()}"];' for a, ev, b in graph()]
    return "\n".join([*lines, "}"])


if __name__ == "__main__":
    sys.stdout.write(_dot() + "\n")
