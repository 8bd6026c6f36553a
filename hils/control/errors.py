"""The typed errors an action is refused with: each says what was wrong and what is allowed, and its ``reason``
names the rule (the event log's ``action_refused`` and the fault suite's ``refused_reason`` keep it). A refused
action reaches no manager: nothing is sent for it."""

from __future__ import annotations

__all__ = [
    "ActionError",
    "ActionTypeError",
    "CallOmittedError",
    "ConflictError",
    "DurationRangeError",
    "HoldForceOffError",
    "HoldOmittedError",
    "NotInActionSetError",
    "PreemptedError",
    "RingOmittedError",
    "ScheduleConflictError",
    "ScheduleTimeError",
    "UnknownPhaseError",
]


class ActionError(ValueError):
    """An action that cannot be converted; nothing is sent for it."""

    reason = "invalid"


class ActionTypeError(ActionError, TypeError):
    reason = "wrong_type"


class UnknownPhaseError(ActionError):
    reason = "unknown_phase"


class ConflictError(ActionError):
    reason = "conflict"


class NotInActionSetError(ActionError):
    reason = "not_in_action_set"


class DurationRangeError(ActionError):
    reason = "duration_out_of_range"


class PreemptedError(ActionError):
    """A valid action that arrived while the controller serves a preempt: the preempt drives the signals, so the
    middleware commands nothing until the controller reports it over (the manager's PREEMPTED)."""

    reason = "preempted"


class ScheduleConflictError(ActionError):
    """A schedule that asks two things of one phase at once, or leaves a ring nothing to serve."""


class HoldForceOffError(ScheduleConflictError):
    reason = "hold_and_force_off"


class CallOmittedError(ScheduleConflictError):
    reason = "call_of_omitted_phase"


class HoldOmittedError(ScheduleConflictError):
    reason = "hold_of_omitted_phase"


class RingOmittedError(ScheduleConflictError):
    reason = "ring_omitted"


class ScheduleTimeError(ActionError):
    reason = "schedule_time"
