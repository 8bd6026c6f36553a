"""The manager: the middleware's whole state machine, pure.

Rules of this file
------------------
- Everything that affects the state machine lives here (h11's rule): whether a command is sent or
  dropped, verification, timers, the retry of an unanswered command SET, the gating of the
  keepalive, drift counting, recovery, closing, and the position in the cyclic sequence. The shell
  (:mod:`hils.middleware`) only carries out the effects returned and feeds back what happened.
- No clock, no I/O, no SimPy. Every input is an event object that carries the time it happened;
  every output is an effect object.
- ``_TRANSITIONS`` maps each (state, event kind) to the next state and the handler that produces
  the effects, so the whole graph can be read (and drawn) off the table. An event is first given
  its kind by ``_classify`` (which only looks, never changes anything); a (state, kind) pair not in
  the table is an error naming both. Handlers never choose the next state.
- Timers are identified by a token. A timer that was superseded or belongs to an older command has
  a stale token: its expiry is classified STALE_TIMER and changes nothing.

Theory of operation
-------------------
States (:class:`Mode`), with the paper's names (:class:`State`) that the log and reports keep:

- IDLE (paper IDLE): a command may be sent. A command that asks to keep what is shown (switch 0,
  or selection of the pair already green) completes at once (KEEP). Any other is dispatched: the
  shell SETs VehCall to the commanded phases, the transition timer (tau_trans) starts, and the
  manager goes IN_TRANSITION.
- IN_TRANSITION (paper ON_HOLD): waits for an observation whose greens hold the commanded phases.
  That verifies the transition: a plain command returns to IDLE; a duration command goes SERVING
  and its green timer starts from the verifying observation. A command SET that got no answer
  (lost, not refused) is SET again while the transition is awaited; tau_trans still bounds the wait.
  If the transition timer expires first: TIMEOUT.
- SERVING (paper ON_HOLD): the prescribed green is being served; back to IDLE when it has passed.
- TIMEOUT (paper TIMEOUT): entered on a transition not seen within tau_trans, a communication
  failure (n_timeout consecutive failed polls, reported by the poller), n_drift consecutive
  drifted steps, or a control object changed by someone else (FOREIGN_CONTROL, below). Polling
  halts; commands and keepalives are not sent. A recovery request re-reads the controller
  (RECOVERING).
- RECOVERING (paper TIMEOUT): the controller was re-read; the call is SET to the pair it shows (so
  no transition follows that nobody commanded) and the sequence position follows it. When that SET
  is answered: IDLE, polling resumes and the drift count restarts. A failed read or SET: TIMEOUT.
- CLOSED: the run has ended; the calls are cleared and nothing else is sent. A clearing SET whose
  datagram got no answer is sent again, up to CLEAR_ATTEMPTS in all: calls left on a controller stay
  until its backup time drops them, so one lost datagram is no reason to leave them.

The control objects are ours while we run. The shell reads them back at a low rate
(:class:`ControlsRead`). In IDLE, IN_TRANSITION and SERVING, any of PhaseOmit, PedOmit, Hold,
ForceOff or PedCall set is a control object changed by someone else (the run never sets them):
TIMEOUT (FOREIGN_CONTROL). VehCall is not judged: it is ours, re-SET by every command and
keepalive, and a read of it races with our own SETs in flight. The recovery's SET and the
close's clear set every control object.

Commands arriving anywhere but IDLE are dropped. Every dispatched command ends exactly once
(:class:`CommandEnded`: verified, served or timeout), except the one pending when the run closes.
The keepalive re-SETs the call when no SET has gone out for a keepalive period (a third of the
controller's backup time, or the config's, whichever is shorter), except in TIMEOUT, RECOVERING and
CLOSED, or while switched off. An empty call is re-SET too: the start-up SET put the controller under
system control, and a run that has placed no call yet (an agent keeping the start-up pair, the actuated
baseline) keeps it there rather than let the backup timer drop it to backup mode.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, StrEnum, auto

from hils.actions import Command
from hils.config import Pair


class State(Enum):
    """The paper's names of the manager's states, kept by the log, the reports and the public API."""

    IDLE = "idle"
    ON_HOLD = "on_hold"
    TIMEOUT = "timeout"


class Mode(Enum):
    """The states of the machine."""

    IDLE = "idle"
    IN_TRANSITION = "in_transition"
    SERVING = "serving"
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


_PAPER = {Mode.IDLE: State.IDLE, Mode.IN_TRANSITION: State.ON_HOLD, Mode.SERVING: State.ON_HOLD,
          Mode.TIMEOUT: State.TIMEOUT, Mode.RECOVERING: State.TIMEOUT, Mode.CLOSED: None}


class TimeoutReason(StrEnum):
    COMMUNICATION = "communication"
    TRANSITION = "transition"
    DRIFT = "drift"
    FOREIGN_CONTROL = "foreign_control"


class TimerKind(StrEnum):
    TRANSITION = "transition"
    DURATION = "duration"
    KEEPALIVE = "keepalive"


class Purpose(StrEnum):
    """Why a SET of VehCall was sent."""

    COMMAND = "command"
    RETRY = "retry"
    KEEPALIVE = "keepalive"
    RECOVERY = "recovery"
    CLEAR = "clear"


# --- input events -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Started:
    """The start-up read: what the controller shows and its backup time (0: none)."""

    t: float
    greens: frozenset[int]
    backup_time: int


@dataclass(frozen=True, slots=True)
class CommandRequested:
    t: float
    action_id: int
    command: Command
    shown: frozenset[int]  # the greens shown when the command was requested (the signal cache's)


@dataclass(frozen=True, slots=True)
class SignalObserved:
    t: float
    greens: frozenset[int]
    poll_id: int


@dataclass(frozen=True, slots=True)
class TimerExpired:
    t: float
    kind: TimerKind
    token: int


@dataclass(frozen=True, slots=True)
class FailureDetected:
    t: float
    reason: TimeoutReason
    detail: str = ""


@dataclass(frozen=True, slots=True)
class StepTimed:
    """One simulation step of length ``step`` cost ``took`` seconds (wall clock, or modeled)."""

    t: float
    step: float
    took: float


@dataclass(frozen=True, slots=True)
class SetAnswered:
    t: float
    purpose: Purpose
    command_id: int | None


@dataclass(frozen=True, slots=True)
class SetFailed:
    t: float
    purpose: Purpose
    command_id: int | None
    lost: bool  # no answer at all (the SET may never have arrived), as opposed to a refusal


@dataclass(frozen=True, slots=True)
class RecoveryRequested:
    t: float


@dataclass(frozen=True, slots=True)
class ControllerRead:
    """The recovery's re-read of the controller succeeded."""

    t: float
    greens: frozenset[int]


@dataclass(frozen=True, slots=True)
class ControllerUnreadable:
    t: float
    error: str


@dataclass(frozen=True, slots=True)
class ControlsRead:
    """The read-back of the control objects the run never sets (all but VehCall): the phases each holds."""

    t: float
    held: tuple[tuple[str, frozenset[int]], ...]  # (name, phases): PhaseOmit, PedOmit, Hold, ForceOff, PedCall


@dataclass(frozen=True, slots=True)
class KeepaliveSwitched:
    t: float
    on: bool


@dataclass(frozen=True, slots=True)
class CloseRequested:
    t: float


Event = (Started | CommandRequested | SignalObserved | TimerExpired | FailureDetected | StepTimed | SetAnswered
         | SetFailed | RecoveryRequested | ControllerRead | ControllerUnreadable | KeepaliveSwitched | CloseRequested
         | ControlsRead)

# --- effects --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Dispatch:
    """A command leaves for the controller (logged as dispatched; its SET follows)."""

    command_id: int
    action_id: int
    command: Command


@dataclass(frozen=True, slots=True)
class SendCall:
    """SET VehCall to ``phases``."""

    phases: frozenset[int]
    purpose: Purpose
    command_id: int | None = None


@dataclass(frozen=True, slots=True)
class StartTimer:
    kind: TimerKind
    delay: float
    token: int


@dataclass(frozen=True, slots=True)
class Dropped:
    action_id: int
    state: str  # the log name of the state that dropped it


@dataclass(frozen=True, slots=True)
class Verified:
    command_id: int
    command: Command
    poll_id: int
    hold: float  # seconds from dispatch to the verifying observation


@dataclass(frozen=True, slots=True)
class CommandEnded:
    command_id: int
    outcome: str  # verified | served | timeout | keep
    hold: float  # seconds from dispatch (0 for a keep)


@dataclass(frozen=True, slots=True)
class TimeoutEntered:
    reason: TimeoutReason
    detail: str
    command_id: int | None


@dataclass(frozen=True, slots=True)
class DriftSeen:
    step: float
    took: float
    consecutive: int


@dataclass(frozen=True, slots=True)
class HaltPolling:
    pass


@dataclass(frozen=True, slots=True)
class ResumePolling:
    pass


@dataclass(frozen=True, slots=True)
class ReadController:
    """Re-read the controller's signal state (recovery); answer with ControllerRead or ControllerUnreadable."""


@dataclass(frozen=True, slots=True)
class RecoveryStarted:
    pass


@dataclass(frozen=True, slots=True)
class Recovered:
    greens: frozenset[int]


@dataclass(frozen=True, slots=True)
class Note:
    message: str


Effect = (Dispatch | SendCall | StartTimer | Dropped | Verified | CommandEnded | TimeoutEntered | DriftSeen
          | HaltPolling | ResumePolling | ReadController | RecoveryStarted | Recovered | Note)


@dataclass(frozen=True, slots=True)
class Pending:
    """The command in transition or being served: what it is, when it was sent, its live timer token."""

    command_id: int
    command: Command
    since: float
    token: int


class Ev(Enum):
    """The kinds an input event is classified into; the table is written in these."""

    STARTED = auto()
    COMMAND = auto()
    KEEP = auto()
    VERIFIED = auto()
    VERIFIED_DURATION = auto()
    OBSERVED = auto()
    TRANSITION_EXPIRED = auto()
    DURATION_ELAPSED = auto()
    KEEPALIVE_DUE = auto()
    STALE_TIMER = auto()
    FAILURE = auto()
    ON_TIME = auto()
    DRIFTED = auto()
    DRIFT_LIMIT = auto()
    COMMAND_SET_LOST = auto()
    CLEAR_LOST = auto()
    RECOVERY_SET_ANSWERED = auto()
    RECOVERY_SET_FAILED = auto()
    SET_RESULT = auto()
    RECOVERY_REQUESTED = auto()
    CONTROLLER_READ = auto()
    CONTROLLER_UNREADABLE = auto()
    KEEPALIVE_SWITCHED = auto()
    CLOSE = auto()
    CONTROLS_OURS = auto()
    FOREIGN_CONTROL = auto()


#: How many times in all the closing clear is sent while its datagrams get no answer (see CLOSED).
CLEAR_ATTEMPTS = 3


class Manager:
    """The state machine. Feed events to :meth:`handle`; it returns the effects to carry out."""

    def __init__(self, tau_trans: float, *, sequence: tuple[Pair, ...] = (), n_drift: int = 5,
                 keepalive_period: float = 0.0) -> None:
        self.tau_trans = tau_trans
        self.sequence = sequence
        self.n_drift = n_drift
        self.keepalive_period = keepalive_period  # 0: no keepalive
        self.mode = Mode.IDLE
        self.pending: Pending | None = None
        self.timeout_reason: TimeoutReason | None = None
        self.position = -1  # index in the sequence of the pair last commanded or shown; -1: none yet
        self.call: frozenset[int] = frozenset()  # VehCall as last SET
        self.last_set = float("-inf")
        self.keepalive_on = True
        self.drifted_in_a_row = 0
        self.clears_sent = 0
        self._recovering_greens: frozenset[int] = frozenset()  # what the recovery's re-read showed
        self._next_command = 0
        self._next_token = 0
        self._keepalive_token: int | None = None

    @property
    def state(self) -> State | None:
        """The paper's name of the current state."""
        return self.mode.paper

    def notices(self, step: float, took: float) -> bool:
        """Whether a step that took ``took`` s would change anything: a drifted one, or one on time that
        ends a run of drifted ones. (The shell reports only those: four steps a second are timed, and an
        on-time step after an on-time step is ON_TIME with nothing to reset.)"""
        return took > step or self.drifted_in_a_row > 0

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

    # --- classification: looks, never changes ----------------------------------------------------

    def _classify(self, ev: Event) -> Ev:
        match ev:
            case CommandRequested(command=cmd, shown=shown):
                keep = cmd.green is None and (cmd.keep or set(cmd.phases) <= shown)
                return Ev.KEEP if keep else Ev.COMMAND
            case SignalObserved(greens=greens):
                p = self.pending
                if self.mode is Mode.IN_TRANSITION and p is not None and set(p.command.phases) <= greens:
                    return Ev.VERIFIED if p.command.green is None else Ev.VERIFIED_DURATION
                return Ev.OBSERVED
            case TimerExpired(kind=kind, token=token):
                if kind is TimerKind.KEEPALIVE:
                    return Ev.KEEPALIVE_DUE if token == self._keepalive_token else Ev.STALE_TIMER
                if self.pending is None or token != self.pending.token:
                    return Ev.STALE_TIMER
                return Ev.TRANSITION_EXPIRED if kind is TimerKind.TRANSITION else Ev.DURATION_ELAPSED
            case StepTimed(step=step, took=took):
                if took <= step:
                    return Ev.ON_TIME
                return Ev.DRIFT_LIMIT if self.drifted_in_a_row + 1 >= self.n_drift else Ev.DRIFTED
            case SetAnswered(purpose=purpose):
                return Ev.RECOVERY_SET_ANSWERED if purpose is Purpose.RECOVERY else Ev.SET_RESULT
            case SetFailed(purpose=purpose, command_id=command_id, lost=lost):
                if purpose is Purpose.RECOVERY:
                    return Ev.RECOVERY_SET_FAILED
                p = self.pending
                if (lost and purpose in (Purpose.COMMAND, Purpose.RETRY) and self.mode is Mode.IN_TRANSITION
                        and p is not None and p.command_id == command_id):
                    return Ev.COMMAND_SET_LOST
                if lost and purpose is Purpose.CLEAR and self.clears_sent < CLEAR_ATTEMPTS:
                    return Ev.CLEAR_LOST
                return Ev.SET_RESULT
            case ControlsRead():
                return Ev.FOREIGN_CONTROL if self._foreign(ev) else Ev.CONTROLS_OURS
        return _PLAIN_KINDS[type(ev)]

    def _foreign(self, ev: ControlsRead) -> str:
        """What of the read-back is not ours ('' when all of it is)."""
        return "; ".join(f"{name} on phases {sorted(phases)}" for name, phases in ev.held if phases)

    # --- handlers: effects only ------------------------------------------------------------------

    def _started(self, ev: Started, out: list[Effect]) -> None:
        self._sync(ev.greens)
        if ev.backup_time:
            limit = ev.backup_time / 3.0  # the controller's own backup time rules
            self.keepalive_period = min(self.keepalive_period, limit) if self.keepalive_period else limit
        self._arm_keepalive(out)

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

    def _verified(self, ev: SignalObserved, out: list[Effect]) -> None:
        p = self.pending
        hold = ev.t - p.since
        out.append(Verified(p.command_id, p.command, ev.poll_id, hold))
        out.append(CommandEnded(p.command_id, "verified", hold))
        self.pending = None

    def _serve(self, ev: SignalObserved, out: list[Effect]) -> None:
        p = self.pending
        out.append(Verified(p.command_id, p.command, ev.poll_id, ev.t - p.since))
        token = self._new_token()
        self.pending = Pending(p.command_id, p.command, p.since, token)
        out.append(StartTimer(TimerKind.DURATION, p.command.green, token))

    def _served(self, ev: TimerExpired, out: list[Effect]) -> None:
        p = self.pending
        out.append(CommandEnded(p.command_id, "served", ev.t - p.since))
        self.pending = None

    def _retry(self, ev: SetFailed, out: list[Effect]) -> None:
        # The SET is idempotent; tau_trans still bounds the wait, and each try takes tau_udp.
        p = self.pending
        self._send(frozenset(p.command.phases), Purpose.RETRY, p.command_id, ev.t, out)

    def _keepalive(self, ev: TimerExpired, out: list[Effect]) -> None:
        # Any SET of a control object restarts the controller's backup timer: refresh only when no
        # SET went out for a whole period (a later SET re-armed the timer, so this one is stale).
        if self.keepalive_on:
            self._send(self.call, Purpose.KEEPALIVE, None, ev.t, out)
        else:
            self._arm_keepalive(out)

    def _switch_keepalive(self, ev: KeepaliveSwitched, out: list[Effect]) -> None:
        self.keepalive_on = ev.on

    def _transition_timeout(self, ev: TimerExpired, out: list[Effect]) -> None:
        p = self.pending
        self._enter_timeout(ev.t, TimeoutReason.TRANSITION,
                            f"phases {list(p.command.phases)} not green after {ev.t - p.since:.3f} s", out)

    def _failure(self, ev: FailureDetected, out: list[Effect]) -> None:
        self._enter_timeout(ev.t, ev.reason, ev.detail, out)

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

    def _read_controller(self, ev: RecoveryRequested, out: list[Effect]) -> None:
        out.append(RecoveryStarted())
        out.append(ReadController())

    def _recovery_set(self, ev: ControllerRead, out: list[Effect]) -> None:
        self._sync(ev.greens)
        self._recovering_greens = ev.greens
        self._send(ev.greens, Purpose.RECOVERY, None, ev.t, out)

    def _recovered(self, ev: SetAnswered, out: list[Effect]) -> None:
        self.timeout_reason = None
        self.drifted_in_a_row = 0
        out.append(Recovered(self._recovering_greens))
        out.append(ResumePolling())

    def _recovery_failed(self, ev: ControllerUnreadable | SetFailed, out: list[Effect]) -> None:
        what = ev.error if isinstance(ev, ControllerUnreadable) else "the recovery SET got no answer"
        out.append(Note(f"recovery failed, still in TIMEOUT: {what}"))

    def _foreign_control(self, ev: ControlsRead, out: list[Effect]) -> None:
        self._enter_timeout(ev.t, TimeoutReason.FOREIGN_CONTROL, f"set by someone else: {self._foreign(ev)}", out)

    def _close(self, ev: CloseRequested, out: list[Effect]) -> None:
        out.append(HaltPolling())
        if self.last_set > float("-inf"):  # a run that never SET a call has none to clear
            self._clear(ev.t, out)
        self._keepalive_token = None

    def _clear_again(self, ev: SetFailed, out: list[Effect]) -> None:
        self._clear(ev.t, out)

    def _clear(self, t: float, out: list[Effect]) -> None:
        self.clears_sent += 1
        self._send(frozenset(), Purpose.CLEAR, None, t, out)

    # --- helpers ---------------------------------------------------------------------------------------

    def _enter_timeout(self, t: float, reason: TimeoutReason, detail: str, out: list[Effect]) -> None:
        p = self.pending
        if p is not None:
            out.append(CommandEnded(p.command_id, "timeout", t - p.since))
            self.pending = None
        self.timeout_reason = reason
        out.append(TimeoutEntered(reason, detail, p.command_id if p else None))
        out.append(HaltPolling())

    def _send(self, phases: frozenset[int], purpose: Purpose, command_id: int | None, t: float,
              out: list[Effect]) -> None:
        self.call = phases
        self.last_set = t
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


_PLAIN_KINDS: dict[type, Ev] = {
    Started: Ev.STARTED, FailureDetected: Ev.FAILURE, RecoveryRequested: Ev.RECOVERY_REQUESTED,
    ControllerRead: Ev.CONTROLLER_READ, ControllerUnreadable: Ev.CONTROLLER_UNREADABLE,
    KeepaliveSwitched: Ev.KEEPALIVE_SWITCHED, CloseRequested: Ev.CLOSE,
}

_Handler = Callable[[Manager, Event, list[Effect]], None] | None
M = Mode

# Every state: events that change nothing, or that every state handles alike.
_EVERYWHERE: dict[Ev, _Handler] = {
    Ev.STALE_TIMER: None, Ev.SET_RESULT: None, Ev.KEEPALIVE_SWITCHED: Manager._switch_keepalive,
    Ev.CONTROLS_OURS: None,
}
# The states in which the machine works normally (commands, keepalive, drift).
_RUNNING = (M.IDLE, M.IN_TRANSITION, M.SERVING)
_DOWN = (M.TIMEOUT, M.RECOVERING)

# The whole state machine: (state, event kind) -> (next state, handler producing the effects).
_TRANSITIONS: dict[tuple[Mode, Ev], tuple[Mode, _Handler]] = {
    (M.IDLE, Ev.STARTED): (M.IDLE, Manager._started),
    # The start-up read can end after the run has already timed out (steps of a large grid drifting while
    # its controllers start at the wall clock) or closed: what it read is kept, the state stays.
    (M.TIMEOUT, Ev.STARTED): (M.TIMEOUT, Manager._started),
    (M.RECOVERING, Ev.STARTED): (M.RECOVERING, Manager._started),
    (M.CLOSED, Ev.STARTED): (M.CLOSED, None),
    (M.IDLE, Ev.COMMAND): (M.IN_TRANSITION, Manager._dispatch),
    (M.IDLE, Ev.KEEP): (M.IDLE, Manager._keep),
    (M.IN_TRANSITION, Ev.VERIFIED): (M.IDLE, Manager._verified),
    (M.IN_TRANSITION, Ev.VERIFIED_DURATION): (M.SERVING, Manager._serve),
    (M.IN_TRANSITION, Ev.TRANSITION_EXPIRED): (M.TIMEOUT, Manager._transition_timeout),
    (M.IN_TRANSITION, Ev.COMMAND_SET_LOST): (M.IN_TRANSITION, Manager._retry),
    (M.SERVING, Ev.DURATION_ELAPSED): (M.IDLE, Manager._served),
    (M.TIMEOUT, Ev.RECOVERY_REQUESTED): (M.RECOVERING, Manager._read_controller),
    (M.RECOVERING, Ev.RECOVERY_REQUESTED): (M.RECOVERING, None),  # one recovery at a time
    (M.RECOVERING, Ev.CONTROLLER_READ): (M.RECOVERING, Manager._recovery_set),
    (M.RECOVERING, Ev.CONTROLLER_UNREADABLE): (M.TIMEOUT, Manager._recovery_failed),
    (M.RECOVERING, Ev.RECOVERY_SET_ANSWERED): (M.IDLE, Manager._recovered),
    (M.RECOVERING, Ev.RECOVERY_SET_FAILED): (M.TIMEOUT, Manager._recovery_failed),
    **{(s, ev): (s, handler) for s in (*_RUNNING, *_DOWN, M.CLOSED) for ev, handler in _EVERYWHERE.items()},
    **{(s, ev): (s, Manager._drop) for s in (M.IN_TRANSITION, M.SERVING, *_DOWN, M.CLOSED)
       for ev in (Ev.COMMAND, Ev.KEEP)},
    **{(s, Ev.OBSERVED): (s, None) for s in (*_RUNNING, *_DOWN, M.CLOSED)},
    **{(s, Ev.KEEPALIVE_DUE): (s, Manager._keepalive) for s in _RUNNING},
    **{(s, Ev.KEEPALIVE_DUE): (s, None) for s in (*_DOWN, M.CLOSED)},  # gated; the recovery SET re-arms it
    **{(s, Ev.FAILURE): (M.TIMEOUT, Manager._failure) for s in _RUNNING},
    **{(s, Ev.FAILURE): (s, None) for s in (*_DOWN, M.CLOSED)},
    **{(s, Ev.ON_TIME): (s, Manager._on_time) for s in _RUNNING},
    **{(s, Ev.DRIFTED): (s, Manager._drifted) for s in _RUNNING},
    **{(s, Ev.DRIFT_LIMIT): (M.TIMEOUT, Manager._drift_limit) for s in _RUNNING},
    **{(s, ev): (s, None) for s in (*_DOWN, M.CLOSED) for ev in (Ev.ON_TIME, Ev.DRIFTED, Ev.DRIFT_LIMIT)},
    **{(s, Ev.RECOVERY_REQUESTED): (s, Manager._nothing_to_recover) for s in _RUNNING},
    **{(s, Ev.FOREIGN_CONTROL): (M.TIMEOUT, Manager._foreign_control) for s in _RUNNING},
    **{(s, Ev.FOREIGN_CONTROL): (s, None) for s in (*_DOWN, M.CLOSED)},  # halted: the recovery clears them
    **{(s, Ev.CLOSE): (M.CLOSED, Manager._close) for s in (*_RUNNING, *_DOWN)},
    **{(s, ev): (s, None) for s in (*_RUNNING, M.TIMEOUT, M.CLOSED)
       for ev in (Ev.RECOVERY_SET_ANSWERED, Ev.RECOVERY_SET_FAILED)},  # a recovery overtaken by a close
    (M.CLOSED, Ev.TRANSITION_EXPIRED): (M.CLOSED, None),  # the command pending at the close stays open
    (M.CLOSED, Ev.DURATION_ELAPSED): (M.CLOSED, None),
    (M.CLOSED, Ev.CONTROLLER_READ): (M.CLOSED, None),
    (M.CLOSED, Ev.CONTROLLER_UNREADABLE): (M.CLOSED, None),
    (M.CLOSED, Ev.CLOSE): (M.CLOSED, None),
    (M.CLOSED, Ev.CLEAR_LOST): (M.CLOSED, Manager._clear_again),
    (M.CLOSED, Ev.RECOVERY_REQUESTED): (M.CLOSED, None),
}
