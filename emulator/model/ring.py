"""A ring's timer: the intervals one ring times and the timers a NEMA phase runs in them.

Rules of this file
------------------
- A ring's interval changes only by ``_NEXT`` below, ``(interval, event) -> interval``, through
  :meth:`Ring.move`; an event with no entry is an error (:class:`RingError`) that names the ring, its
  interval and the event.
- Time is an integer count of ticks (tenths of a second), as in a real controller; no float time is
  compared anywhere in here.
- An interval takes its lengths when it starts (``Timing`` copied into the ring), so a SET of the phase
  table acts from the next interval on.
- The ring times; it never chooses. Which phase is next, when a green may end and when a committed phase
  may start are the sequencer's (:mod:`emulator.model.sequencer`); what a pattern or a preempt asks of a
  ring is theirs (:mod:`emulator.model.coordinated`, :mod:`emulator.model.preempted`). They move a ring
  only by the events of the table.

Theory of operation
-------------------
Each ring times one phase at a time through GREEN, YELLOW and RED_CLEAR, then DWELLs at red until its
committed next phase may start (``START``). A yellow and a red clearance run their length (``TIMED``); a
red clearance cut to nothing (a preempt's entry may) ends on the tick it starts. A green ends only when the
sequencer commits the ring's next phase (``END``). At power-up (and at the end of the start-up flash) a
phase with a start-up interval (NTCIP 1202 phaseStartup) starts in it from red.

The timers of a green, set when it starts:

- *Minimum*: the phase's minimum green, or its Walk plus pedestrian clearance when the green serves a walk
  (the walk and the pedestrian clearance are timed from the start of the green, or from the tick a recycled
  walk starts within it: :meth:`Ring.recycle`).
- *Passage* (gap): ticks since the green's own vehicle call was last present (a call, or max recall,
  restarts it every tick); it has gapped out when it reaches the *allowable gap*: the phase's passage time, or
  with gap reduction (volume density) less: NTCIP 1202 phaseTimeBeforeReduction, "The Time Before Reduction
  period shall begin when the phase is Green and there is a serviceable conflicting call. If the serviceable
  conflicting call is removed before completion of this time (or time to reduce), the timer shall reset. Upon
  completion of the TBR period ... the linear reduction of the allowable gap from the Passage Time shall
  begin"; phaseTimeToReduce "shall control the rate of reduction of the allowable gap between the Passage Time
  and Minimum Gap setting", and past phaseMinimumGap "the allowable gap shall remain fixed" (:meth:`Ring.allowed`;
  phaseCarsBeforeReduction and phaseReduceBy are not modelled).
- *Maximum 1 or 2*: Maximum2 when ringControlGroupMax2 selects it for the ring. It times while
  *conflicting demand* waits (demand in its own ring or across the barrier), and on max recall from the
  start of the green, as NTCIP 1202 phaseMaximum1's timer is "held reset unless Max Vehicle Recall is
  enabled for this phase" (:func:`maximum_runs`).
- *Simultaneous gap disable*: once a ready, gapped-out green sees conflicting demand it stays gapped out
  until it ends, when its phase has ``simultaneous_gap_disable`` (the default; NTCIP 1202 phaseOptions bit
  11: it "disables a gapped out phase from reverting to the extensible portion"): a call coming back does
  not re-extend it. Without it, a call coming back while it waits (at the barrier for the other ring)
  extends it again.

The timers of the clearance: the yellow change and the red clearance (each the lesser of the phase's and
a preempt's cap, when a preempt's entry or track clearance ends the green), and the *red revert*: the
tick each phase of the ring last ended its yellow (``yellow_end``), before which plus the phase's red
revert time it may not start again.

Deadlines. Between two events a ring only counts. :meth:`Ring.thresholds` lists how many ticks from now
each of its timers reaches its next threshold, as the controller's quiet time asks it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from hils.protocol.config import Phase
from hils.protocol.ntcip import PHASE_TABLE, PhaseColumn, PhaseStartup


class Interval(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED_CLEAR = "red_clear"
    DWELL = "dwell"


# The members bound once: Python 3.11's EnumType has a __getattr__, which makes every ``Interval.GREEN`` a lookup
# about ten times slower than a global's, and the step reads them many times a tick.
GREEN, YELLOW, RED_CLEAR, DWELL = Interval.GREEN, Interval.YELLOW, Interval.RED_CLEAR, Interval.DWELL


class Event(StrEnum):
    """What moves a ring from one interval to the next (see ``_NEXT``)."""

    START = "its committed phase may start"
    END = "the sequencer ended its green"
    TIMED = "its interval has run its length"
    STARTUP_GREEN = "power-up: the phase starts in green"
    STARTUP_YELLOW = "power-up: the phase starts in its yellow change"
    STARTUP_RED = "power-up: the phase starts in its red clearance"


START, END, TIMED = Event.START, Event.END, Event.TIMED  # bound once, as the intervals are


_NEXT: dict[tuple[Interval, Event], Interval] = {
    (DWELL, Event.START): GREEN,
    (GREEN, Event.END): YELLOW,
    (YELLOW, Event.TIMED): RED_CLEAR,
    (RED_CLEAR, Event.TIMED): DWELL,
    (DWELL, Event.STARTUP_GREEN): GREEN,
    (DWELL, Event.STARTUP_YELLOW): YELLOW,
    (DWELL, Event.STARTUP_RED): RED_CLEAR,
}

CLEARANCE = (YELLOW, RED_CLEAR)

#: The event that starts a phase in its start-up interval (phaseStartup), for the options that start one.
STARTUP = {
    PhaseStartup.GREEN_WALK: Event.STARTUP_GREEN,
    PhaseStartup.GREEN_NO_WALK: Event.STARTUP_GREEN,
    PhaseStartup.YELLOW_CHANGE: Event.STARTUP_YELLOW,
    PhaseStartup.RED_CLEAR: Event.STARTUP_RED,
}


def tenths(seconds: float) -> int:
    return round(seconds * 10)


class Termination(StrEnum):
    """Why a green ended (the hi-res log's gap-out, max-out and force-off events)."""

    GAP_OUT = "gap_out"
    MAX_OUT = "max_out"
    FORCE_OFF = "force_off"  # the coordinator's force-off point (or floating split), or phaseControlGroupForceOff
    YIELD = "yield"  # a coordinated phase ending after its yield point


@dataclass(frozen=True, slots=True)
class Change:
    """One interval change, for timelines and logs (a yellow says why its green ended)."""

    tick: int
    ring: int
    phase: int | None
    interval: Interval
    reason: Termination | None = None


class RingError(RuntimeError):
    """An event the ring's table has no entry for in the interval it is in."""


@dataclass(slots=True)
class Timing:
    """One phase's timings in ticks; mutable so the phase table can be retimed over SNMP."""

    min_green: int
    max1: int
    max2: int
    passage: int
    walk: int
    ped_clear: int
    yellow: int
    red_clear: int
    red_revert: int
    time_before_reduction: int = 0
    time_to_reduce: int = 0
    min_gap: int = 0  # the gap is reduced only to a minimum gap below the passage

    @classmethod
    def of(cls, ph: Phase) -> Timing:
        return cls(tenths(ph.min_green), tenths(ph.max_green), tenths(ph.maximum2), tenths(ph.passage),
                   tenths(ph.walk), tenths(ph.ped_clear), tenths(ph.yellow), tenths(ph.red_clear),
                   tenths(ph.red_revert), tenths(ph.time_before_reduction), tenths(ph.time_to_reduce),
                   tenths(ph.passage if ph.min_gap is None else ph.min_gap))


#: The phase-table column (NTCIP 1202 phaseTable) that carries each timing, and the ticks one unit of its value is.
TIMING_COLUMNS: dict[PhaseColumn, tuple[str, int]] = {
    PhaseColumn.WALK: ("walk", 10),
    PhaseColumn.PEDESTRIAN_CLEAR: ("ped_clear", 10),
    PhaseColumn.MINIMUM_GREEN: ("min_green", 10),
    PhaseColumn.PASSAGE: ("passage", 1),
    PhaseColumn.MAXIMUM1: ("max1", 10),
    PhaseColumn.MAXIMUM2: ("max2", 10),
    PhaseColumn.YELLOW_CHANGE: ("yellow", 1),
    PhaseColumn.RED_CLEAR: ("red_clear", 1),
    PhaseColumn.RED_REVERT: ("red_revert", 1),
    PhaseColumn.TIME_BEFORE_REDUCTION: ("time_before_reduction", 10),
    PhaseColumn.TIME_TO_REDUCE: ("time_to_reduce", 10),
    PhaseColumn.MINIMUM_GAP: ("min_gap", 1),
}


#: The ticks a SET of each timing may give: the values its phase-table object holds, in whole units of it.
#: phaseYellowChange's starts at 3.0 s: its MIB SYNTAX is INTEGER (0..255), but its description gives "NEMA TS 2 range:
#: 3-25.5 sec", and a controller may hold the narrower range (:data:`hils.protocol.ntcip.PHASE_TABLE` does).
SETTABLE: dict[str, range] = {name: range(PHASE_TABLE[column].low * unit, PHASE_TABLE[column].high * unit + 1, unit)
                              for column, (name, unit) in TIMING_COLUMNS.items()}


def maximum_runs(conflict: bool, max_recall: bool) -> bool:
    """The green's maximum timer (Maximum 1 or 2) times this tick: with conflicting demand, or always under max
    recall. NTCIP 1202 phaseMaximum1 (phaseMaximum2 alike): "This time setting shall determine the maximum
    length of time this phase may be held in Green in the presence of a serviceable conflicting call. In the
    absence of a serviceable conflicting call the Maximum Green timer shall be held reset unless Max Vehicle
    Recall is enabled for this phase." So a max-recalled green times out its maximum and rests there: a
    conflicting call then ends it at once. While a pattern runs the maximum is inhibited
    (:meth:`emulator.model.coordinated.Coordinated.ending`)."""
    return conflict or max_recall


@dataclass(slots=True)
class Ring:
    """The timer of one ring (mutable: the controller's working memory)."""

    number: int
    order: tuple[int, ...]
    phase: int | None = None  # the phase timing now, or last timed while in DWELL
    interval: Interval = DWELL
    ticks: int = 0  # ticks completed in the current interval
    length: int = 0  # ticks the current yellow / red clearance lasts, fixed when it starts
    minimum: int = 0  # ticks the current green lasts at least (minimum green, or walk + ped clear)
    maximum: int = 0  # max-out ticks of the current green (Maximum1 or Maximum2)
    passage: int = 0  # passage ticks of the current green
    reduction: tuple[int, int, int] | None = None  # the green's time before reduction, time to reduce, minimum gap
    reducing: int = 0  # ticks of serviceable conflicting demand in a row during this green (the TBR timer on)
    walk: int = 0  # the green's tick its walk ends (0: no walk); from its start, or a recycled walk's start
    ped_clear: int = 0
    walk_start: int = 0  # the green's tick its walk began (pedestrian recycle starts one within the green)
    max_ticks: int = 0  # the maximum timer: ticks of conflicting demand (or of max recall) during this green
    conflict: bool = False  # conflicting demand registered at the green's last tick (the max timer may run without)
    gap: int = 0  # ticks since the green's own vehicle call was last present
    gapped: bool = False  # gapped out with conflicting demand: latched until the green ends (simultaneous gap disable)
    target: int | None = None  # the committed next phase (PhaseNext), from the start of yellow
    yellow_end: dict[int, int] = field(default_factory=dict)  # red revert: the tick each phase last ended its yellow

    def move(self, event: Event, timing: Timing, *, walk: Callable[[int], bool], max2: bool,
             caps: tuple[int, int] | None) -> Interval:
        """Take ``event``: the next interval by ``_NEXT``, its timers started from ``timing`` (the ring's phase's):
        a green serving a walk when ``walk`` says so for its phase (asked only as a green starts), timing Maximum 2
        with ``max2``; a clearance the lesser of its length and a preempt's ``caps`` (yellow, red clearance)."""
        to = _NEXT.get((self.interval, event))
        if to is None:
            raise RingError(f"ring {self.number}: no transition from {self.interval} on {event.name} ({event})")
        self.interval, self.ticks, self.max_ticks, self.conflict, self.gap, self.gapped = to, 0, 0, False, 0, False
        self.reducing = 0
        if to is GREEN:
            self.walk, self.ped_clear = (timing.walk, timing.ped_clear) if walk(self.phase) else (0, 0)
            self.walk_start = 0
            self.minimum = max(timing.min_green, self.walk + self.ped_clear)
            self.maximum = timing.max2 if max2 else timing.max1
            self.passage = timing.passage
            self.reduction = None if timing.min_gap >= timing.passage else (
                timing.time_before_reduction, timing.time_to_reduce, timing.min_gap)
        else:
            self.length = timing.yellow if to is YELLOW else timing.red_clear if to is RED_CLEAR else 0
            if caps is not None and to in CLEARANCE:
                self.length = min(self.length, caps[to is RED_CLEAR])
        return to

    def time_green(self, *, extending: bool, conflict: bool, max_recall: bool, gap_disable: bool) -> None:
        """One tick of a green: its passage timer restarts while ``extending`` (called, or on max recall), its
        maximum timer runs (:func:`maximum_runs`), and a gap-out with ``conflict`` latches with ``gap_disable``."""
        self.ticks += 1
        self.gap = 0 if extending else self.gap + 1
        self.conflict = conflict
        self.max_ticks = self.max_ticks + 1 if maximum_runs(conflict, max_recall) else 0
        self.reducing = self.reducing + 1 if conflict else 0
        if not conflict:
            self.gapped = False
        elif self.ticks >= self.minimum and self.gap > 0 and self.gap >= self.allowed() and gap_disable:
            self.gapped = True

    def recycle(self, timing: Timing) -> None:
        """A walk starts within the running green (pedestrian recycle, :mod:`emulator.model.pedestrians`): it and
        its pedestrian clearance are timed from this tick, and the green lasts at least to their end."""
        self.walk_start = self.ticks
        self.walk, self.ped_clear = self.ticks + timing.walk, timing.ped_clear
        self.minimum = max(self.minimum, self.walk + self.ped_clear)

    def time_clearance(self, tick: int) -> bool:
        """One tick of a yellow or red clearance: True when it has run its length (a yellow's end is kept for the
        red revert)."""
        self.ticks += 1
        if self.ticks < self.length:
            return False
        if self.interval is YELLOW:
            self.yellow_end[self.phase] = tick
        return True

    def allowed(self, later: int = 0) -> int:
        """The allowable gap (ticks) ``later`` ticks from now if the conflicting demand stays: the passage, reduced
        linearly to the minimum gap over the time to reduce once the time before reduction has run."""
        if self.reduction is None:
            return self.passage
        before, to_reduce, least = self.reduction
        into = self.reducing + later - before if self.reducing else 0
        if into <= 0:
            return self.passage
        if into >= to_reduce:
            return least
        return max(least, self.passage - (self.passage - least) * into // to_reduce)

    @property
    def gapped_out(self) -> bool:
        return self.gapped or (self.gap > 0 and self.gap >= self.allowed())

    @property
    def maxed_out(self) -> bool:
        return self.max_ticks >= self.maximum

    def reverting(self, phase: int, tick: int, timing: Timing) -> bool:
        """``phase`` (of this ring) is still in its red revert: its last yellow ended less than its red revert ago."""
        revert = self.yellow_end.get(phase)
        return revert is not None and tick - revert < timing.red_revert

    def clearance_left(self, timing: Timing | None) -> int:
        """Ticks until this ring has cleared its phase (a green's whole yellow and red clearance)."""
        if self.interval is GREEN:
            return timing.yellow + timing.red_clear
        if self.interval is YELLOW:
            return self.length - self.ticks + timing.red_clear
        if self.interval is RED_CLEAR:
            return self.length - self.ticks
        return 0

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------------

    def thresholds(self, tick: int, timing: dict[int, Timing], *, minimum: bool) -> list[int]:
        """Ticks from now to each next threshold of the ring's timers (those a step compares): a clearance's
        end, the red revert of a committed phase waiting in red, and a green's walk, pedestrian clearance,
        passage and maximum (a running timer only) and its minimum when ``minimum`` says it matters."""
        interval = self.interval
        if interval is GREEN:
            ticks, walked = self.ticks, self.walk + self.ped_clear
            ahead = []  # appended one by one: a comprehension costs more than the two or three tests
            if minimum and ticks < self.minimum:
                ahead.append(self.minimum - ticks)
            if ticks < self.walk:
                ahead.append(self.walk - ticks)
            if ticks < walked:
                ahead.append(walked - ticks)
            if self.gap and self.gap < self.allowed():
                ahead.append(self._gap_out_in())
            if self.max_ticks and self.max_ticks < self.maximum:
                ahead.append(self.maximum - self.max_ticks)
            return ahead
        if interval is DWELL:
            revert = None if self.target is None else self.yellow_end.get(self.target)
            if revert is not None and tick < revert + timing[self.target].red_revert:
                return [revert + timing[self.target].red_revert - tick]
            return []
        return [max(1, self.length - self.ticks)]  # a clearance a preempt's entry cut below its ticks ends at once

    def _gap_out_in(self) -> int:
        """Ticks until the running gap timer reaches the allowable gap (which the reduction may lower meanwhile)."""
        ahead = self.passage - self.gap
        if self.reduction is None or not self.reducing:
            return ahead
        return next(k for k in range(1, ahead + 1) if self.gap + k >= self.allowed(k))

    def steady(self, *, extending: bool, conflict: bool, max_recall: bool) -> bool:
        """A green's timers run at the next tick as :meth:`skip` runs them, with these inputs: its passage timer
        keeps running or keeps being restarted, its maximum timer keeps running or held reset, and the conflicting
        demand it registered stays."""
        return ((self.gap == 0) == extending and self.conflict == conflict
                and (self.max_ticks > 0) == maximum_runs(conflict, max_recall)
                and (self.reduction is None or (self.reducing > 0) == conflict))


def skip(rings: Iterable[Ring], n: int) -> None:
    """``n`` quiet ticks of ``rings``: each interval and each green's running timers count (a running gap or maximum
    timer is above zero in quiet time: an extending green resets its gap every tick, a maximum timer held reset is
    0). One call for the rings: quiet time skips at every read and write of the controller."""
    for r in rings:
        if r.interval is not DWELL:
            r.ticks += n
        if r.gap:
            r.gap += n
        if r.max_ticks:
            r.max_ticks += n
        if r.reducing:
            r.reducing += n
