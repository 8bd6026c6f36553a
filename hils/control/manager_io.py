"""The manager's vocabulary: the events it is fed and the effects it returns (:mod:`hils.control.manager`).

Every input is a frozen event carrying the time it happened; every output is a frozen effect the shell
(:mod:`hils.shell.middleware`) carries out. Nothing here decides anything.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from hils.control.actions import ActionError, Command
from hils.control.phase_control import Change, Controls, Schedule
from hils.protocol.ntcip import ControlColumn, SignalState

__all__ = [
    "AgentOverdue",
    "AnotherManager",
    "CallsFound",
    "CallsWatched",
    "CloseDone",
    "CloseRequested",
    "CommandEnded",
    "CommandRequested",
    "ControllerRead",
    "ControllerUnreachable",
    "ControllerUnreadable",
    "ControlsRead",
    "ControlsReset",
    "Dispatch",
    "DriftSeen",
    "Dropped",
    "Effect",
    "Event",
    "HaltPolling",
    "KeepaliveSwitched",
    "Note",
    "OrderChanged",
    "PollAnswered",
    "PollFailed",
    "PollFailureSeen",
    "PreemptBegan",
    "PreemptEnded",
    "Purpose",
    "ReadController",
    "ReadControls",
    "ReadbackDue",
    "Recovered",
    "RecoveryRequested",
    "RecoveryStarted",
    "Refused",
    "ResumePolling",
    "RetryStartup",
    "ScheduleBegan",
    "ScheduleEnded",
    "ScheduleRequested",
    "SendCall",
    "SendControls",
    "SetAnswered",
    "SetFailed",
    "ShowSignal",
    "StartTimer",
    "Started",
    "StartupDone",
    "StartupLost",
    "StartupRefused",
    "StepTimed",
    "TimeoutEntered",
    "TimeoutReason",
    "TimerExpired",
    "TimerKind",
    "Verified",
    "WatchCalls",
]


class TimeoutReason(StrEnum):
    COMMUNICATION = "communication"
    TRANSITION = "transition"
    DRIFT = "drift"
    FOREIGN_CONTROL = "foreign_control"
    AGENT = "agent"


class TimerKind(StrEnum):
    TRANSITION = "transition"
    DURATION = "duration"
    KEEPALIVE = "keepalive"
    RECOVER = "recover"
    CONTROL = "control"  # the running schedule's next instant (an order starts or ends)


class Purpose(StrEnum):
    """Why a SET of the control objects (VehCall alone, in a run of phase commands) was sent."""

    COMMAND = "command"
    RETRY = "retry"
    KEEPALIVE = "keepalive"
    RECOVERY = "recovery"
    WITHDRAW = "withdraw"  # a preempt began: the call of the command it interrupted goes (phase control: all six)
    CLEAR = "clear"
    SCHEDULE = "schedule"  # phase control: what the schedule asks changed (an order started or ended, a new one)
    REESTABLISH = "reestablish"  # phase control: the controller lost the run's control objects; all six SET again
    RELEASE = "release"  # phase control: entering TIMEOUT, the run lets go of every control object


# --- input events -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Started:
    """The start-up read: what the controller shows and its backup time (0: none)."""

    t: float
    greens: frozenset[int]
    backup_time: int


@dataclass(frozen=True, slots=True)
class StartupLost:
    """A start-up read or write that got no answer (``error``: what the transport said)."""

    t: float
    error: str


@dataclass(frozen=True, slots=True)
class StartupRefused:
    """The controller refused the start-up read or write (``detail``: the refusal, for the user)."""

    t: float
    detail: str


@dataclass(frozen=True, slots=True)
class CommandRequested:
    t: float
    action_id: int
    command: Command
    shown: frozenset[int]  # the greens shown when the command was requested (the signal cache's)


@dataclass(frozen=True, slots=True)
class ScheduleRequested:
    """A phase-control action, converted: the schedule to carry out from ``t`` (empty: clear everything)."""

    t: float
    action_id: int
    schedule: Schedule


@dataclass(frozen=True, slots=True)
class PollAnswered:
    """Poll ``poll_id``, sent in polling period ``epoch``, read ``state`` and the preempts in service (by number)."""

    t: float
    poll_id: int
    epoch: int
    state: SignalState
    preempts: frozenset[int] = frozenset()


@dataclass(frozen=True, slots=True)
class PollFailed:
    """Poll ``poll_id``, sent in polling period ``epoch``, got no usable answer (``kind``: the error's type)."""

    t: float
    poll_id: int
    epoch: int
    kind: str
    error: str


@dataclass(frozen=True, slots=True)
class TimerExpired:
    t: float
    kind: TimerKind
    token: int


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
    error: str = ""


@dataclass(frozen=True, slots=True)
class RecoveryRequested:
    t: float


@dataclass(frozen=True, slots=True)
class ControllerRead:
    """The recovery's re-read of the controller succeeded; in a phase-control run it read the control objects and
    whether the controller reports backupMode (unitControlStatus) too."""

    t: float
    greens: frozenset[int]
    controls: Controls | None = None
    backup_mode: bool = False


@dataclass(frozen=True, slots=True)
class ControllerUnreadable:
    t: float
    error: str


@dataclass(frozen=True, slots=True)
class ReadbackDue:
    """The read-back's time has come: the manager says whether to read the control objects."""

    t: float


@dataclass(frozen=True, slots=True)
class ControlsRead:
    """The read-back of the control objects: the phases each of those the run never sets holds, and VehCall."""

    t: float
    held: tuple[tuple[str, frozenset[int]], ...]  # (name, phases): PhaseOmit, PedOmit, Hold, ForceOff, PedCall
    veh_call: frozenset[int] | None = None  # VehCall as read (None: not read)


@dataclass(frozen=True, slots=True)
class CallsFound:
    """The start-up read found VehCall holding ``calls`` (someone else's, the run has SET nothing yet)."""

    t: float
    calls: frozenset[int]


@dataclass(frozen=True, slots=True)
class CallsWatched:
    """VehCall read again while the start-up watches for another manager."""

    t: float
    calls: frozenset[int]


@dataclass(frozen=True, slots=True)
class AgentOverdue:
    """The agent asked at a decision point has given no action within the control interval (``waited`` s)."""

    t: float
    waited: float


@dataclass(frozen=True, slots=True)
class KeepaliveSwitched:
    t: float
    on: bool


@dataclass(frozen=True, slots=True)
class CloseRequested:
    t: float


Event = (Started | StartupLost | StartupRefused | CallsFound | CallsWatched | CommandRequested | PollAnswered
         | PollFailed | TimerExpired | StepTimed | SetAnswered | SetFailed | RecoveryRequested | ControllerRead
         | ControllerUnreadable | ReadbackDue | ControlsRead | AgentOverdue | KeepaliveSwitched | CloseRequested
         | ScheduleRequested)

# --- effects --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RetryStartup:
    """Read the controller for the start-up again."""


@dataclass(frozen=True, slots=True)
class StartupDone:
    """The start-up is over (read, or given up): start polling and reading back."""


@dataclass(frozen=True, slots=True)
class WatchCalls:
    """Read VehCall again in ``delay`` s (answer with CallsWatched): is someone else changing it?"""

    delay: float


@dataclass(frozen=True, slots=True)
class AnotherManager:
    """Someone else changed VehCall while the start-up watched: another manager drives the controller."""

    detail: str


@dataclass(frozen=True, slots=True)
class ControllerUnreachable:
    """No start-up read got an answer in ``attempts`` tries."""

    attempts: int


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
class SendControls:
    """SET these control objects (phase control), each to its phases, in one request."""

    controls: tuple[tuple[ControlColumn, frozenset[int]], ...]
    purpose: Purpose

    @property
    def columns(self) -> dict[ControlColumn, frozenset[int]]:
        return dict(self.controls)


@dataclass(frozen=True, slots=True)
class ScheduleBegan:
    """The schedule of action ``action_id`` runs from now."""

    action_id: int
    schedule: Schedule


@dataclass(frozen=True, slots=True)
class ScheduleEnded:
    """The running schedule is over: ``done`` (its last order ended), ``replaced``, ``cleared`` (by the next action),
    ``preempted`` or ``closed``."""

    reason: str


@dataclass(frozen=True, slots=True)
class OrderChanged:
    """An order of the running schedule moved in its life cycle (:mod:`hils.control.phase_control`)."""

    change: Change


@dataclass(frozen=True, slots=True)
class ControlsReset:
    """The controller no longer holds the control objects the run SET (its backup timer ran out, or someone cleared
    them): they are SET again."""

    detail: str


@dataclass(frozen=True, slots=True)
class StartTimer:
    kind: TimerKind
    delay: float
    token: int


@dataclass(frozen=True, slots=True)
class Refused:
    """A command refused (``error``: the typed error to hand the agent); nothing is sent for it."""

    action_id: int
    error: ActionError


@dataclass(frozen=True, slots=True)
class PreemptBegan:
    """The controller serves ``preempts``; ``command_id``: the command that ended because of it (None: none)."""

    preempts: frozenset[int]
    command_id: int | None


@dataclass(frozen=True, slots=True)
class PreemptEnded:
    """The controller reports its preemption over after ``duration`` s, showing ``greens``."""

    duration: float
    greens: frozenset[int]


@dataclass(frozen=True, slots=True)
class Dropped:
    action_id: int
    state: str  # the log name of the state that dropped it


@dataclass(frozen=True, slots=True)
class ShowSignal:
    """What poll ``poll_id`` read is the signal state now (the cache, SUMO, the agents); ``after_failures``: the
    first answer after failed polls (the state is known again)."""

    poll_id: int
    state: SignalState
    after_failures: bool = False


@dataclass(frozen=True, slots=True)
class PollFailureSeen:
    """A failed poll (0: a start-up read), and the failed polls in a row it makes."""

    poll_id: int
    error: str
    consecutive: int


@dataclass(frozen=True, slots=True)
class Verified:
    command_id: int
    command: Command
    poll_id: int
    hold: float  # seconds from dispatch to the verifying poll


@dataclass(frozen=True, slots=True)
class CommandEnded:
    command_id: int
    outcome: str  # verified | served | timeout | preempted | keep
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
class ReadControls:
    """Read the control objects back now; answer with ControlsRead (a read that fails is let go)."""


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
class CloseDone:
    """The close is over; ``error`` says why the calls could not be cleared ('' when they were, or none)."""

    error: str = ""


@dataclass(frozen=True, slots=True)
class Note:
    message: str


Effect = (RetryStartup | StartupDone | WatchCalls | AnotherManager | ControllerUnreachable | Dispatch | SendCall |
          StartTimer | Refused | Dropped | ShowSignal | PollFailureSeen | Verified | CommandEnded | TimeoutEntered |
          DriftSeen | HaltPolling | ResumePolling | ReadControls | ReadController | RecoveryStarted | Recovered |
          CloseDone | Note | PreemptBegan | PreemptEnded | SendControls | ScheduleBegan | ScheduleEnded | OrderChanged
          | ControlsReset)
