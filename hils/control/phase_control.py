"""Phase control: holds, force-offs, vehicle and pedestrian omits and calls per phase, as a schedule.

The fourth way an agent commands (:attr:`hils.control.actions.ActionType.CONTROL`), the way the systems that drive
field controllers do: MMITSS (``mmitss/mmitss-az``, ``src/mrp/traffic-controller-interface/``) takes a JSON
schedule of ``hold``, ``forceoff``, ``omit_veh``, ``omit_ped``, ``call_veh`` and ``call_ped`` commands per phase
with start and end times in seconds from its receipt; CARMA Streets (``tsc_client_service``) omits every phase but
its target and holds the target. Each command is one bit of one of NTCIP 1202's six phaseControlGroup objects
(:class:`hils.protocol.ntcip.ControlColumn`), and "When a bit = 1, the device shall activate the System Phase
Hold [Force Off, Phase Omit, Ped Omit] control for that phase" or "place a call for vehicle [ped] service on that
phase" (NTCIP 1202 v03, 5.2.5.2 to 5.2.5.7).

Rules of this file
------------------
- Pure: no clock, no I/O. Times are integer tenths of a second from the schedule's receipt (the controller's
  tick; MMITSS rounds its times to 0.1 s likewise), never floats compared.
- :func:`parse` is the one door in: whatever form an action takes, it comes out a checked :class:`Schedule` or
  a typed :class:`hils.control.actions.ActionError` whose ``reason`` names the rule broken; a refused schedule
  reaches nobody, so nothing is sent for it.
- What an order does from moment to moment (armed, acting, spent, lapsed) is the life-cycle table
  ``_ORDER_TRANSITIONS`` below, one row per line, driven by the manager (:mod:`hils.control.manager`) through
  :class:`Running`; nothing else moves an order.

The forms an action may take
----------------------------
- MMITSS's schedule message, as MMITSS sends it: ``{"MsgType": "Schedule", "Schedule": [{"commandPhase": 2,
  "commandType": "hold", "commandStartTime": 0.0, "commandEndTime": 24.0}, ...]}``, or just its list of commands.
  Its clear message (``"Schedule": "Clear"``), or the word ``"clear"``, is the empty schedule: it ends the one
  running and clears every control object.
- A step: a mapping from command type to phases, ``{"hold": [2, 6], "omit_veh": [1, 3, 4, 5, 7, 8]}``, acting
  from now until the next action replaces it (CARMA Streets' way; the environments' ``MultiBinary`` action).
- A :class:`Schedule` built in Python (:meth:`Schedule.of`).

The rules a schedule is checked by (each refusal's ``reason``)
--------------------------------------------------------------
- ``unknown_phase``: every phase is one of the intersection's.
- ``schedule_time``: times are finite, not negative, and an order ends after it starts. An order that starts and
  ends at the same tenth is dropped, as MMITSS drops it (its own example schedule holds two such), and said so.
- ``hold_and_force_off``: no phase is held and forced off at once. One keeps its green, the other ends it; NTCIP
  1202 does not say which wins, so a schedule asking both asks nothing a controller will do the same way twice.
- ``call_of_omitted_phase``: no phase is called and omitted at once (vehicle call with vehicle omit, pedestrian
  call with pedestrian omit): the omit says the phase is not to be serviced, the call that it is.
- ``hold_of_omitted_phase``: no phase is held and omitted at once.
- ``ring_omitted``: never is every phase of a ring omitted. A NEMA ring always times one of its phases; with all
  of them omitted it has none to go to, and the phase it times (the omit does not end a green) stays on for as
  long as the omit lasts, whatever else the schedule asks.

What the other commands mean, accepted as they are
--------------------------------------------------
- A hold on a phase that is not green is *armed*: it holds nothing and calls nothing until its phase next shows
  green, then keeps that green until released: phaseControlGroupHold activates "the System Phase Hold control for
  that phase" (NTCIP 1202 v03), a hold of the green, and places no call (VehCall does). (The NEMA TS 2 text of the
  Hold input was not among the stored references: this rests on the NTCIP text.) MMITSS holds the next phase before
  it starts so; a hold whose phase never shows green in its window *lapsed*.
- A force-off ends its phase's green once the minimum has been served, and only to serve a conflicting call: with
  no conflicting call the green rests, as a NEMA green with nowhere to go does. Its bit stays set until that green
  ends ("When the phase green terminates, the associated bit shall be reset to 0", 5.2.5.5): the order is then
  *spent*, and is neither set nor sent again in its window (set again, it would end the phase's next green at its
  minimum). A force-off whose green did not end in its window (no conflicting call) *lapsed*.
- Several orders of one type on one phase overlapping are one: the bit is set while any of them is on. (MMITSS
  groups commands that start together and ends the group at the earliest end of its members; its own
  ``test/schedule1.json`` calls phase 2 from 0 to 68 s and from 0 to 168 s, which it thereby ends at 68 s.)
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum, StrEnum, auto
from pathlib import Path
from typing import Any

from hils.control.errors import (
    ActionError,
    ActionTypeError,
    CallOmittedError,
    HoldForceOffError,
    HoldOmittedError,
    RingOmittedError,
    ScheduleTimeError,
    UnknownPhaseError,
)
from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.ntcip import ControlColumn

__all__ = [
    "Control", "Controls", "Order", "OrderState", "Running", "Schedule", "ScheduleFileError", "load", "no_controls",
    "parse",
]


class Control(StrEnum):
    """A command type, by MMITSS's name, and the phaseControlGroup object it sets (:attr:`column`)."""

    HOLD = "hold"
    FORCE_OFF = "forceoff"
    OMIT_VEH = "omit_veh"
    OMIT_PED = "omit_ped"
    CALL_VEH = "call_veh"
    CALL_PED = "call_ped"

    @property
    def column(self) -> ControlColumn:
        return _COLUMN[self]


_COLUMN = {Control.HOLD: ControlColumn.HOLD, Control.FORCE_OFF: ControlColumn.FORCE_OFF,
           Control.OMIT_VEH: ControlColumn.PHASE_OMIT, Control.OMIT_PED: ControlColumn.PED_OMIT,
           Control.CALL_VEH: ControlColumn.VEH_CALL, Control.CALL_PED: ControlColumn.PED_CALL}

#: The commands whose meaning depends on whether their phase shows green (the others act from their start).
GREEN_BOUND = frozenset({Control.HOLD, Control.FORCE_OFF})

#: The six control objects as phase sets, in the table's column order: what a SET writes, what a read gives.
Controls = Mapping[ControlColumn, frozenset[int]]


def no_controls() -> dict[ControlColumn, frozenset[int]]:
    """Every control object at 0."""
    return {c: frozenset() for c in ControlColumn}


class ScheduleFileError(UserError, ValueError):
    """A schedule file that cannot be used: names the file and what is wrong in it."""


@dataclass(frozen=True, slots=True)
class Order:
    """One command: ``control`` on ``phase`` from tenth ``start`` to tenth ``end`` (exclusive; None: until the next
    action replaces it), counted from the schedule's receipt."""

    control: Control
    phase: int
    start: int
    end: int | None

    def on_at(self, tenth: int) -> bool:
        return self.start <= tenth and (self.end is None or tenth < self.end)

    def overlaps(self, other: Order) -> bool:
        return ((other.end is None or self.start < other.end)
                and (self.end is None or other.start < self.end))

    def __str__(self) -> str:
        until = "on" if self.end is None else f"{self.end / 10:g} s"
        return f"{self.control.value} {self.phase} ({self.start / 10:g} s to {until})"


@dataclass(frozen=True)
class Schedule:
    """A checked schedule: its orders, in the order given, and what was dropped from it (orders that start and end
    at the same tenth, as MMITSS drops them). Empty: clear everything."""

    orders: tuple[Order, ...] = ()
    dropped: tuple[str, ...] = ()
    sources: tuple[str, ...] = ()  # where each order came from (``Schedule[3]``), when read from a message or list
    instants: tuple[int, ...] = field(init=False)  # every tenth at which an order starts or ends, sorted

    def __post_init__(self) -> None:
        times = {o.start for o in self.orders} | {o.end for o in self.orders if o.end is not None}
        object.__setattr__(self, "instants", tuple(sorted(times)))

    @classmethod
    def of(cls, orders: Iterable[tuple[Control | str, int, float, float | None]]) -> Schedule:
        """A schedule from ``(control, phase, start_s, end_s)`` tuples (``end_s`` None: until replaced); unchecked
        until :func:`parse` checks it against an intersection."""
        return cls(tuple(Order(Control(c), int(p), _tenths(s, "start"), None if e is None else _tenths(e, "end"))
                         for c, p, s, e in orders))

    @property
    def open(self) -> bool:
        """Some order runs until the next action replaces it (a step)."""
        return any(o.end is None for o in self.orders)

    @property
    def span(self) -> float | None:
        """Seconds from receipt to the last end (None for a step)."""
        return None if self.open else max((o.end for o in self.orders), default=0) / 10

    def at(self, tenth: int) -> dict[ControlColumn, frozenset[int]]:
        """What every control object holds at ``tenth`` by this schedule alone (no order spent)."""
        out: dict[ControlColumn, set[int]] = {c: set() for c in ControlColumn}
        for o in self.orders:
            if o.on_at(tenth):
                out[o.control.column].add(o.phase)
        return {c: frozenset(p) for c, p in out.items()}

    def as_rows(self) -> list[list[Any]]:
        """The orders as the log keeps them: ``[type, phase, start_s, end_s or None]``."""
        return [[o.control.value, o.phase, o.start / 10, None if o.end is None else o.end / 10] for o in self.orders]


# --- parsing ------------------------------------------------------------------------------------------------------

_MMITSS_KEYS = ("commandPhase", "commandType", "commandStartTime", "commandEndTime")
_ALLOWED = (f"allowed: MMITSS's schedule message {{'MsgType': 'Schedule', 'Schedule': [{{'commandPhase': 2, "
            f"'commandType': 'hold', 'commandStartTime': 0.0, 'commandEndTime': 24.0}}, ...]}} or its list of "
            f"commands, its clear message or 'clear', a step {{'hold': [2, 6], 'omit_veh': [3, 7], ...}}, or a "
            f"Schedule; command types: {', '.join(c.value for c in Control)}")


def parse(value: object, config: IntersectionConfig) -> Schedule:
    """The checked schedule an action value asks for, or the typed error of the first rule it breaks."""
    if isinstance(value, Schedule):
        schedule = value
    elif isinstance(value, str):
        if value.strip().lower() != "clear":
            raise ActionTypeError(f"phase control takes a schedule, got {_short(value)}; {_ALLOWED}")
        schedule = Schedule()
    elif isinstance(value, Mapping) and "MsgType" in value:
        schedule = _message(value)
    elif isinstance(value, Mapping):
        schedule = _step(value)
    elif isinstance(value, Sequence) and not isinstance(value, bytes | bytearray):
        schedule = _commands(value)
    else:
        raise ActionTypeError(f"phase control takes a schedule, got {_short(value)}; {_ALLOWED}")
    check(schedule, config)
    return schedule


def load(path: str | Path, config: IntersectionConfig) -> Schedule:
    """A schedule file (MMITSS's JSON message or command list), checked; a :class:`ScheduleFileError` names the
    file and what is wrong in it."""
    p = Path(path)
    try:
        raw = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ScheduleFileError(f"schedule {p}: cannot be read ({exc.strerror})") from None
    except ValueError as exc:
        raise ScheduleFileError(f"schedule {p}: is not JSON ({exc})") from None
    try:
        return parse(raw, config)
    except ActionError as exc:
        raise ScheduleFileError(f"schedule {p}: {exc}") from None


def _message(value: Mapping[str, Any]) -> Schedule:
    if value.get("MsgType") != "Schedule":
        raise ActionTypeError(f"MsgType is {_short(value.get('MsgType'))}; allowed: 'Schedule'")
    body = value.get("Schedule")
    if isinstance(body, str) and body.strip().lower() == "clear":
        return Schedule()
    if not isinstance(body, Sequence) or isinstance(body, str | bytes):
        raise ActionTypeError(f"Schedule is {_short(body)}; allowed: a list of commands or 'Clear'")
    return _commands(body)


def _commands(items: Sequence[Any]) -> Schedule:
    orders, dropped, sources = [], [], []
    for i, item in enumerate(items):
        where = f"Schedule[{i}]"
        if not isinstance(item, Mapping):
            raise ActionTypeError(f"{where} is {_short(item)}; allowed: a command {{{', '.join(_MMITSS_KEYS)}}}")
        missing = [k for k in _MMITSS_KEYS if k not in item]
        if missing:
            raise ActionTypeError(f"{where} has no {', '.join(missing)}; a command has {', '.join(_MMITSS_KEYS)}")
        control = _control(item["commandType"], f"{where}.commandType")
        phase = _phase_number(item["commandPhase"], f"{where}.commandPhase")
        start = _tenths(item["commandStartTime"], f"{where}.commandStartTime")
        end = _tenths(item["commandEndTime"], f"{where}.commandEndTime")
        if end < start:
            raise ScheduleTimeError(f"{where} ends at {end / 10:g} s, before it starts at {start / 10:g} s; "
                                    "allowed: commandEndTime >= commandStartTime")
        order = Order(control, phase, start, end)
        if end == start:
            dropped.append(f"{where} ({order.control.value} {phase} at {start / 10:g} s) starts and ends at once")
        else:
            orders.append(order)
            sources.append(where)
    return Schedule(tuple(orders), tuple(dropped), tuple(sources))


def _step(value: Mapping[Any, Any]) -> Schedule:
    orders = []
    for key, phases in value.items():
        control = _control(key, f"step[{key!r}]")
        if isinstance(phases, str | bytes) or not isinstance(phases, Iterable):
            raise ActionTypeError(f"step[{key!r}] is {_short(phases)}; allowed: a list of phase numbers")
        for p in phases:
            orders.append(Order(control, _phase_number(p, f"step[{key!r}]"), 0, None))
    return Schedule(tuple(orders))


def _control(value: object, where: str) -> Control:
    try:
        return Control(value)
    except ValueError:
        raise ActionTypeError(f"{where} is {_short(value)}; allowed: "
                              f"{', '.join(c.value for c in Control)}") from None


def _phase_number(value: object, where: str) -> int:
    value = value.item() if hasattr(value, "item") and getattr(value, "shape", None) == () else value
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ActionTypeError(f"{where} is {_short(value)}; allowed: a phase number")
    return int(value)


def _tenths(value: object, where: str) -> int:
    """Seconds as whole tenths, rounded as MMITSS rounds them (to 0.1 s)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise ScheduleTimeError(f"{where} is {_short(value)}; allowed: seconds, a finite number >= 0")
    if value < 0:
        raise ScheduleTimeError(f"{where} is {value}; allowed: seconds >= 0 (from the schedule's receipt)")
    return round(float(value) * 10)


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


# --- the rules ------------------------------------------------------------------------------------------------------

#: Two command types one phase may not have at once, and the error that says so.
_EXCLUSIVE = ((Control.HOLD, Control.FORCE_OFF, HoldForceOffError, "held and forced off"),
              (Control.CALL_VEH, Control.OMIT_VEH, CallOmittedError, "called and omitted"),
              (Control.CALL_PED, Control.OMIT_PED, CallOmittedError, "called for pedestrians and their walk omitted"),
              (Control.HOLD, Control.OMIT_VEH, HoldOmittedError, "held and omitted"))


def check(schedule: Schedule, config: IntersectionConfig) -> None:
    """Refuse a schedule that breaks a rule of the module header, with the error naming it."""
    allowed = list(config.phase_numbers)
    where = dict(zip(schedule.orders, schedule.sources, strict=False))

    def named(o: Order) -> str:
        return f"{where[o]}: {o}" if o in where else str(o)

    for o in schedule.orders:
        if o.phase not in config.phases:
            raise UnknownPhaseError(f"unknown phase {o.phase} in {named(o)}; allowed phases: {allowed}")
    by_phase: dict[int, list[Order]] = {}
    for o in schedule.orders:
        by_phase.setdefault(o.phase, []).append(o)
    for phase, orders in sorted(by_phase.items()):
        for a_type, b_type, error, what in _EXCLUSIVE:
            clash = next(((a, b) for a in orders if a.control is a_type for b in orders
                          if b.control is b_type and a.overlaps(b)), None)
            if clash is not None:
                a, b = clash
                raise error(f"phase {phase} is {what} at once ({named(a)}; {named(b)}): refused, nothing sent; "
                            "allowed: one of the two at a time")
    omits = [o for o in schedule.orders if o.control is Control.OMIT_VEH]
    for tenth in sorted({o.start for o in omits}):
        omitted = {o.phase for o in omits if o.on_at(tenth)}
        for number, ring in enumerate(config.rings, start=1):
            if set(ring) <= omitted:
                by = "; ".join(named(o) for o in omits if o.on_at(tenth) and o.phase in ring)
                raise RingOmittedError(f"every phase of ring {number} ({', '.join(map(str, ring))}) is omitted at "
                                       f"{tenth / 10:g} s ({by}): the ring would have no phase to serve; refused, "
                                       "nothing sent; allowed: at least one phase of each ring not omitted")


# --- the life of an order -----------------------------------------------------------------------------------------


class OrderState(Enum):
    WAITING = "waiting"  # accepted, its start not reached
    ARMED = "armed"  # on; a hold or force-off whose phase does not show green: it acts at that phase's next green
    ACTING = "acting"  # on and acting (a hold keeping its green, a force-off on its green, a call, an omit)
    SPENT = "spent"  # a force-off whose green ended: the controller reset its bit, and it is not set again
    ENDED = "ended"  # its window is over (or the schedule was replaced, or the run stopped commanding)
    LAPSED = "lapsed"  # its window is over and it never acted: a hold whose phase never showed green, a force-off
    #                   whose green did not end (no conflicting call)

    @property
    def on(self) -> bool:
        """Its bit is set while in this state."""
        return self in (OrderState.ARMED, OrderState.ACTING)


class Ov(Enum):
    """What happens to an order; the table is written in these. Each says its guard."""

    START = auto()  # its start: a call or an omit
    START_GREEN = auto()  # its start: a hold or force-off whose phase shows green
    START_RED = auto()  # its start: a hold or force-off whose phase does not show green
    GREEN = auto()  # a poll shows the phase of an ARMED hold or force-off green
    GREEN_ENDED = auto()  # a poll shows the phase of an ACTING force-off no longer green
    HOLD_LET_GO = auto()  # a poll shows the phase of an ACTING hold no longer green
    END = auto()  # its end, having acted
    END_LAPSED = auto()  # its end, never having acted
    CANCEL = auto()  # the schedule replaced or cleared, a preempt, the run's close


S = OrderState
_ORDER_TRANSITIONS: dict[tuple[OrderState, Ov], OrderState] = {
    (S.WAITING, Ov.START): S.ACTING,
    (S.WAITING, Ov.START_GREEN): S.ACTING,
    (S.WAITING, Ov.START_RED): S.ARMED,
    (S.ARMED, Ov.GREEN): S.ACTING,
    (S.ACTING, Ov.GREEN_ENDED): S.SPENT,  # "When the phase green terminates, the associated bit shall be reset to 0"
    (S.ACTING, Ov.HOLD_LET_GO): S.ARMED,  # the controller did not keep it (in backup mode, say): armed again
    (S.ARMED, Ov.END): S.ENDED,
    (S.ACTING, Ov.END): S.ENDED,
    (S.SPENT, Ov.END): S.ENDED,
    (S.ARMED, Ov.END_LAPSED): S.LAPSED,
    (S.ACTING, Ov.END_LAPSED): S.LAPSED,  # a force-off whose green rested: no conflicting call
    **{(s, Ov.CANCEL): S.ENDED for s in (S.WAITING, S.ARMED, S.ACTING, S.SPENT)},
}


@dataclass(frozen=True, slots=True)
class Change:
    """Order ``index`` of the running schedule went from ``before`` to ``after``."""

    index: int
    order: Order
    before: OrderState
    after: OrderState


class Running:
    """A schedule being carried out: the state of each of its orders, moved by the life-cycle table. The manager
    feeds it the schedule's instants and what the polls show; it answers with the changes, and says what the
    control objects hold by it (:meth:`image`)."""

    def __init__(self, schedule: Schedule, received: float) -> None:
        self.schedule = schedule
        self.received = received  # the run time the schedule's tenths count from
        self.states = [OrderState.WAITING] * len(schedule.orders)
        self._acted = [False] * len(schedule.orders)
        self._next = 0  # index into schedule.instants of the next instant to pass

    @property
    def next_instant(self) -> int | None:
        """The next tenth at which an order starts or ends (None: none is left)."""
        instants = self.schedule.instants
        return instants[self._next] if self._next < len(instants) else None

    @property
    def over(self) -> bool:
        """Every order has ended: nothing is left to do."""
        return all(s in (OrderState.ENDED, OrderState.LAPSED) for s in self.states)

    def image(self) -> dict[ControlColumn, frozenset[int]]:
        """What every control object holds by this schedule now: the phases of its orders that are on."""
        out: dict[ControlColumn, set[int]] = {c: set() for c in ControlColumn}
        for o, s in zip(self.schedule.orders, self.states, strict=True):
            if s.on:
                out[o.control.column].add(o.phase)
        return {c: frozenset(p) for c, p in out.items()}

    def pass_instant(self, greens: frozenset[int]) -> list[Change]:
        """The next instant has come: the orders ending then end, then those starting then start."""
        tenth = self.next_instant
        self._next += 1
        changes = []
        for i, o in enumerate(self.schedule.orders):
            if o.end == tenth and self.states[i] is not OrderState.WAITING:
                changes += self._move(i, Ov.END if self._took_effect(i) else Ov.END_LAPSED)
        for i, o in enumerate(self.schedule.orders):
            if o.start == tenth:
                if o.control not in GREEN_BOUND:
                    changes += self._move(i, Ov.START)
                else:
                    changes += self._move(i, Ov.START_GREEN if o.phase in greens else Ov.START_RED)
        return changes

    def _took_effect(self, i: int) -> bool:
        """A call or an omit acts while on; a hold once it kept its green; a force-off once its green ended."""
        control = self.schedule.orders[i].control
        if control is Control.FORCE_OFF:
            return self.states[i] is OrderState.SPENT
        return control is not Control.HOLD or self._acted[i]

    def seen(self, greens: frozenset[int]) -> list[Change]:
        """A poll shows ``greens``: armed holds and force-offs whose phase is green act; an acting force-off whose
        green ended is spent, an acting hold whose green ended is armed again."""
        changes = []
        for i, o in enumerate(self.schedule.orders):
            state = self.states[i]
            if o.control not in GREEN_BOUND or state not in (OrderState.ARMED, OrderState.ACTING):
                continue
            green = o.phase in greens
            if state is OrderState.ARMED and green:
                changes += self._move(i, Ov.GREEN)
            elif state is OrderState.ACTING and not green:
                changes += self._move(i, Ov.GREEN_ENDED if o.control is Control.FORCE_OFF else Ov.HOLD_LET_GO)
        return changes

    def cancel(self) -> list[Change]:
        """Every order not over ends now."""
        return [c for i, s in enumerate(self.states) if s in (OrderState.WAITING, OrderState.ARMED,
                                                               OrderState.ACTING, OrderState.SPENT)
                for c in self._move(i, Ov.CANCEL)]

    def _move(self, i: int, event: Ov) -> list[Change]:
        before = self.states[i]
        after = _ORDER_TRANSITIONS.get((before, event))
        if after is None:
            raise RuntimeError(f"no order transition for {event.name} in {before.name}")
        self.states[i] = after
        if after is OrderState.ACTING:
            self._acted[i] = True
        return [Change(i, self.schedule.orders[i], before, after)] if after is not before else []
