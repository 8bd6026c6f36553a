"""The manager: a pure state machine for phase commands, transitions and errors.

Rules of this file
------------------
- No clock, no I/O, no SimPy. Every input is an event object that carries the
  time it happened; every output is an effect object that the thin SimPy
  shell in :mod:`hils.middleware` carries out (send a SET, start a timer, log).
- Every transition is listed in ``_TRANSITIONS``: a (state, event type) pair
  not in the table is an error, so a new event or state cannot slip through
  unhandled. The handlers return the next state; nothing else assigns it.
- Timers are identified by a token. The shell feeds back :class:`TimerExpired`
  with that token; a timer that was cancelled or belongs to an older command
  has a stale token and is ignored.

Theory of operation
-------------------
IDLE: a command may be sent. A converted command arrives as
:class:`CommandRequested`. If it asks to keep the pair already shown (switch 0,
or selection of the pair already green), it completes at once. Otherwise the
manager dispatches it (the shell SETs VehCall to the commanded phases), starts
the transition timer (tau_trans) and goes ON_HOLD.

ON_HOLD has two stages. In TRANSITION it waits for a signal observation whose
greens include the commanded phases; that observation verifies the transition.
A plain command then returns to IDLE; a duration command moves to SERVING and
starts a timer for its green time, measured from the verifying observation,
and returns to IDLE when it expires. If the transition timer expires first,
the manager enters TIMEOUT. Commands arriving while ON_HOLD are dropped.

TIMEOUT: entered on a transition not seen within tau_trans, on a communication
failure (n_timeout consecutive failed polls, reported by the poller) or on
n_drift consecutive drifted steps. The shell halts polling and command sending.
Commands are dropped. Only :class:`RecoveryCompleted` (after ``recover()`` has
re-read the controller) leaves it, for IDLE.

Every dispatched command ends exactly once: :class:`CommandEnded` with outcome
``verified``, ``served`` (duration) or ``timeout``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, StrEnum

from hils.actions import Command


class State(Enum):
    IDLE = "idle"
    ON_HOLD = "on_hold"
    TIMEOUT = "timeout"


class Stage(Enum):
    """What an ON_HOLD command waits for."""

    TRANSITION = "transition"  # the commanded phases to show green
    SERVING = "serving"  # the prescribed green time to pass (duration actions)


class TimeoutReason(StrEnum):
    COMMUNICATION = "communication"
    TRANSITION = "transition"
    DRIFT = "drift"


class TimerKind(StrEnum):
    TRANSITION = "transition"
    DURATION = "duration"


# --- input events ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CommandRequested:
    t: float
    action_id: int
    command: Command


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
class RecoveryCompleted:
    t: float
    greens: frozenset[int]


Event = CommandRequested | SignalObserved | TimerExpired | FailureDetected | RecoveryCompleted

# --- effects --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Dispatch:
    command_id: int
    action_id: int
    command: Command


@dataclass(frozen=True, slots=True)
class StartTimer:
    kind: TimerKind
    delay: float
    token: int


@dataclass(frozen=True, slots=True)
class Dropped:
    action_id: int
    state: State


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
class Recovered:
    greens: frozenset[int]


Effect = Dispatch | StartTimer | Dropped | Verified | CommandEnded | TimeoutEntered | Recovered


@dataclass(frozen=True, slots=True)
class Pending:
    """The command ON_HOLD: what it is, when it was sent, which timer token is live."""

    command_id: int
    command: Command
    since: float
    stage: Stage
    token: int


class Manager:
    """The state machine. Feed events to :meth:`handle`; it returns the effects to carry out."""

    def __init__(self, tau_trans: float) -> None:
        self.tau_trans = tau_trans
        self.state = State.IDLE
        self.pending: Pending | None = None
        self.greens: frozenset[int] = frozenset()
        self.timeout_reason: TimeoutReason | None = None
        self._next_command = 0
        self._next_token = 0

    def handle(self, event: Event) -> list[Effect]:
        handler = _TRANSITIONS.get((self.state, type(event)))
        if handler is None:
            raise RuntimeError(f"no transition for {type(event).__name__} in {self.state.name}")
        effects: list[Effect] = []
        self.state = handler(self, event, effects)
        return effects

    # --- handlers: each returns the next state ------------------------------------------------

    def _request(self, ev: CommandRequested, out: list[Effect]) -> State:
        cmd = ev.command
        if cmd.green is None and (cmd.keep or set(cmd.phases) <= self.greens):
            out.append(CommandEnded(self._new_command(), "keep", 0.0))
            return State.IDLE
        command_id = self._new_command()
        token = self._new_token()
        self.pending = Pending(command_id, cmd, ev.t, Stage.TRANSITION, token)
        out.append(Dispatch(command_id, ev.action_id, cmd))
        out.append(StartTimer(TimerKind.TRANSITION, self.tau_trans, token))
        return State.ON_HOLD

    def _drop(self, ev: CommandRequested, out: list[Effect]) -> State:
        out.append(Dropped(ev.action_id, self.state))
        return self.state

    def _observe(self, ev: SignalObserved, out: list[Effect]) -> State:
        self.greens = ev.greens
        return self.state

    def _verify(self, ev: SignalObserved, out: list[Effect]) -> State:
        self.greens = ev.greens
        p = self.pending
        if p.stage is not Stage.TRANSITION or not set(p.command.phases) <= ev.greens:
            return State.ON_HOLD
        hold = ev.t - p.since
        out.append(Verified(p.command_id, p.command, ev.poll_id, hold))
        if p.command.green is None:
            out.append(CommandEnded(p.command_id, "verified", hold))
            self.pending = None
            return State.IDLE
        token = self._new_token()
        self.pending = Pending(p.command_id, p.command, p.since, Stage.SERVING, token)
        out.append(StartTimer(TimerKind.DURATION, p.command.green, token))
        return State.ON_HOLD

    def _timer(self, ev: TimerExpired, out: list[Effect]) -> State:
        p = self.pending
        if p is None or ev.token != p.token:
            return self.state
        if ev.kind is TimerKind.DURATION:
            out.append(CommandEnded(p.command_id, "served", ev.t - p.since))
            self.pending = None
            return State.IDLE
        return self._enter_timeout(FailureDetected(ev.t, TimeoutReason.TRANSITION,
                                                   f"phases {list(p.command.phases)} not green "
                                                   f"after {ev.t - p.since:.3f} s"), out)

    def _stale_timer(self, ev: TimerExpired, out: list[Effect]) -> State:
        return self.state

    def _enter_timeout(self, ev: FailureDetected, out: list[Effect]) -> State:
        p = self.pending
        if p is not None:
            out.append(CommandEnded(p.command_id, "timeout", ev.t - p.since))
            self.pending = None
        self.timeout_reason = ev.reason
        out.append(TimeoutEntered(ev.reason, ev.detail, p.command_id if p else None))
        return State.TIMEOUT

    def _already_timed_out(self, ev: FailureDetected, out: list[Effect]) -> State:
        return State.TIMEOUT

    def _recovered(self, ev: RecoveryCompleted, out: list[Effect]) -> State:
        self.greens = ev.greens
        self.timeout_reason = None
        out.append(Recovered(ev.greens))
        return State.IDLE

    def _not_in_timeout(self, ev: RecoveryCompleted, out: list[Effect]) -> State:
        self.greens = ev.greens
        return self.state

    # --- helpers ----------------------------------------------------------------------------

    def _new_command(self) -> int:
        self._next_command += 1
        return self._next_command

    def _new_token(self) -> int:
        self._next_token += 1
        return self._next_token


_Handler = Callable[[Manager, Event, list[Effect]], State]

# The whole state machine: (state, event type) -> handler returning the next state.
_TRANSITIONS: dict[tuple[State, type], _Handler] = {
    (State.IDLE, CommandRequested): Manager._request,
    (State.ON_HOLD, CommandRequested): Manager._drop,
    (State.TIMEOUT, CommandRequested): Manager._drop,
    (State.IDLE, SignalObserved): Manager._observe,
    (State.ON_HOLD, SignalObserved): Manager._verify,
    (State.TIMEOUT, SignalObserved): Manager._observe,
    (State.IDLE, TimerExpired): Manager._stale_timer,
    (State.ON_HOLD, TimerExpired): Manager._timer,
    (State.TIMEOUT, TimerExpired): Manager._stale_timer,
    (State.IDLE, FailureDetected): Manager._enter_timeout,
    (State.ON_HOLD, FailureDetected): Manager._enter_timeout,
    (State.TIMEOUT, FailureDetected): Manager._already_timed_out,
    (State.IDLE, RecoveryCompleted): Manager._not_in_timeout,
    (State.ON_HOLD, RecoveryCompleted): Manager._not_in_timeout,
    (State.TIMEOUT, RecoveryCompleted): Manager._recovered,
}
