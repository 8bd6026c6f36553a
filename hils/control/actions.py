"""Agent actions, their conversion to one unified phase command, and conflict detection.

The three action designs of the paper all become a :class:`Command`: the phase
of each ring, plus a green time for phase duration. The fourth way to command,
phase control (holds, force-offs, omits and calls per phase, as a schedule or
step by step), becomes a checked :class:`hils.control.phase_control.Schedule`.
Anything that cannot be served safely is refused here with a typed
:class:`ActionError` (:mod:`hils.control.errors`) whose message says what was
wrong and what is allowed; a refused action never reaches the manager, so
nothing is sent for it.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from enum import StrEnum

from hils.control import phase_control
from hils.control.errors import (
    ActionError,
    ActionTypeError,
    ConflictError,
    DurationRangeError,
    NotInActionSetError,
    PreemptedError,
    UnknownPhaseError,
)
from hils.control.phase_control import Schedule
from hils.protocol.config import IntersectionConfig, Pair
from hils.protocol.conflict import first_conflict

__all__ = [
    "PAPER_ACTION_TYPES", "ActionConverter", "ActionError", "ActionType", "ActionTypeError", "Command", "ConflictError",
    "ConflictMatrix", "DurationRangeError", "NotInActionSetError", "PreemptedError", "UnknownPhaseError",
]


class ActionType(StrEnum):
    SELECTION = "selection"  # a compatible pair from the configured set (acyclic)
    SWITCH = "switch"  # 0 keep the current pair, 1 advance in the cyclic sequence
    DURATION = "duration"  # x in [0, 1]: green time of the next pair in the sequence
    CONTROL = "control"  # phase control: holds, force-offs, omits and calls per phase (hils.control.phase_control)


#: The paper's three action designs, each converted to a phase command (a pair); phase control is the fourth way.
PAPER_ACTION_TYPES = (ActionType.SELECTION, ActionType.SWITCH, ActionType.DURATION)


@dataclass(frozen=True, slots=True)
class Command:
    """The unified phase command sent to the controller."""

    phases: Pair  # (ring 1 phase, ring 2 phase)
    green: float | None = None  # seconds of green to serve (duration actions only)
    keep: bool = False  # the agent asked to stay: completes without a transition


def _short(value: object) -> str:
    """repr() of an action value, cut short: a refusal message stays one readable line."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class ConflictMatrix:
    """Which phases may show green together: the config's matrix, derived from
    the ring-and-barrier structure unless the config overrides it, read through
    the one conflict check (:func:`hils.protocol.conflict.first_conflict`)."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.phases = config.phase_numbers
        self._permissives = config.permissives

    def conflict(self, a: int, b: int) -> bool:
        return first_conflict(self._permissives, (a, b)) is not None

    def as_rows(self) -> list[list[int]]:
        """The conflict matrix (1 = conflict) over the phases in number order, diagonal 0."""
        return [[int(a != b and self.conflict(a, b)) for b in self.phases] for a in self.phases]


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _unwrap(value: object) -> object:
    """The number inside what RL libraries hand over: a numpy 0-d array or a one-element array."""
    shape = getattr(value, "shape", None)
    if shape is not None and hasattr(value, "item") and (shape == () or shape == (1,)):
        return value.reshape(()).item() if shape else value.item()
    return value


def _integral(value: object) -> int | None:
    """An integer value given as an int or as a float with an integral value (numpy's too); else None."""
    value = _unwrap(value)
    if isinstance(value, bool) or (getattr(value, "dtype", None) is not None and value.dtype.kind == "b"):
        return None
    if _is_int(value):
        return int(value)
    if isinstance(value, numbers.Real):
        x = float(value)
        if math.isfinite(x) and x == int(x):
            return int(x)
    return None


class ActionConverter:
    """Converts one action type to commands. Switch and duration actions depend on the position in the
    cyclic sequence (the index of the pair last commanded or shown, -1 before any): the manager keeps
    it and passes it in, so the converter holds no state of the run."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType) -> None:
        self.config = config
        self.action_type = ActionType(action_type)
        self.matrix = ConflictMatrix(config)
        self.sequence = config.sequence
        self._pairs = frozenset(config.pairs)
        self._convert = {
            ActionType.SELECTION: self._selection,
            ActionType.SWITCH: self._switch,
            ActionType.DURATION: self._duration,
            ActionType.CONTROL: self._control,
        }[self.action_type]

    def convert(self, value: object, position: int = -1) -> Command | Schedule:
        """The command for an action value at sequence ``position`` (a checked schedule for phase control), or an
        :class:`ActionError`."""
        return self._convert(value, position)

    def pair_after(self, position: int) -> Pair:
        """The pair a switch (1) or duration action serves next from ``position``."""
        return self.sequence[(position + 1) % len(self.sequence)]

    def pair_at(self, position: int) -> Pair | None:
        return self.sequence[position] if position >= 0 else None

    def _selection(self, value: object, position: int) -> Command:
        # A pair is ordered: a set or a mapping is not one, whatever its size.
        ordered = not isinstance(value, (str, bytes, set, frozenset, dict)) and hasattr(value, "__len__")
        numbers_ = [_integral(p) for p in value] if ordered and len(value) == 2 else None
        if numbers_ is None or None in numbers_:
            raise ActionTypeError(f"phase selection takes a pair of phase numbers, got {_short(value)}; "
                                  f"allowed: one of {list(self.config.pairs)}")
        a, b = numbers_
        for p in (a, b):
            if p not in self.config.phases:
                raise UnknownPhaseError(f"unknown phase {_short(p)} in {_short([a, b])}; "
                                        f"allowed phases: {list(self.matrix.phases)}")
        if a == b or self.matrix.conflict(a, b):
            raise ConflictError(f"phases {a} and {b} conflict and are never commanded together; "
                                f"allowed: one of {list(self.config.pairs)}")
        pair = (a, b) if self.config.ring_of(a) == 1 else (b, a)
        if pair not in self._pairs:
            raise NotInActionSetError(f"pair {list(pair)} is not in the configured set of pairs; "
                                      f"allowed: one of {list(self.config.pairs)}")
        return Command(pair)

    def _switch(self, value: object, position: int) -> Command:
        number = None if isinstance(value, (list, tuple)) else _integral(value)
        if number not in (0, 1):
            raise ActionTypeError(f"phase switch takes 0 (keep) or 1 (advance), got {_short(value)}")
        current = self.pair_at(position)
        if number == 0:
            return Command(current or self.pair_after(position), keep=current is not None)
        return Command(self.pair_after(position))

    def _duration(self, value: object, position: int) -> Command:
        number = _unwrap(value)
        if isinstance(number, bool) or not isinstance(number, numbers.Real):
            raise ActionTypeError(f"phase duration takes a number x in [0, 1], got {_short(value)}")
        try:
            x = float(number)
        except OverflowError:
            raise DurationRangeError(f"phase duration x = {_short(value)} is outside [0, 1]") from None
        if math.isnan(x) or not 0.0 <= x <= 1.0:
            raise DurationRangeError(f"phase duration x = {x} is outside [0, 1]; allowed: 0 <= x <= 1 "
                                     "(0 = minimum green, 1 = maximum green)")
        pair = self.pair_after(position)
        g_min, g_max = self.green_range(pair)
        return Command(pair, green=g_min + x * (g_max - g_min))

    def _control(self, value: object, position: int) -> Schedule:
        return phase_control.parse(value, self.config)

    def green_range(self, pair: Pair) -> tuple[float, float]:
        """Green-time bounds of a pair: the larger minimum and the smaller maximum of its phases
        (never below that minimum), so the green is valid for both."""
        g_min = max(self.config.phases[p].min_green for p in pair)
        g_max = max(g_min, min(self.config.phases[p].max_green for p in pair))
        return g_min, g_max
