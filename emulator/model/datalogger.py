"""The controller's data logger: its high-resolution event log, in the Indiana enumerations.

Rules of this file
------------------
- The logger watches and never acts. The controller tells it each interval change with the reason a green
  ended (:meth:`DataLogger.changed`), the end of each step (:meth:`DataLogger.stepped`) and a power cycle
  (:meth:`DataLogger.powered_up`); everything else it reads off the controller after the step. Nothing
  here changes the controller.
- An event's time is the controller's clock (the coordinator's: local time in ticks since midnight of the
  day the unit first powered up, counting on through power cycles) at the tick that made it. So the log is
  the same in virtual time and at the wall clock, and the same whether quiet ticks are stepped or skipped:
  a skipped stretch changes nothing discrete, and every threshold the log reports (walk, pedestrian clearance,
  the coordinator's marks) is a real step, but for a green's minimum that changes nothing else: the controller
  takes no step for the logger, which logs such a minimum at its own tick when it next hears from the
  controller or is read (:meth:`DataLogger._minimums`), so a reader of a controller skipping quiet ticks
  brings it to the present first, as :meth:`emulator.inprocess.VirtualTarget.hires` does.
- The events of one tick are kept in (code, parameter) order, as field logs list them; ticks in time order.
- The list of events is never changed in place but by appending: dropping the oldest makes a new list. So a
  :class:`Snapshot` (the list and its length then) is taken in O(log n) and stays the log as it stood while
  the controller logs on: the served event log (:mod:`emulator.agent.asclog`) streams from one between ticks.

Theory of operation
-------------------
What is logged, and from what (codes: :class:`hils.protocol.hires.EventCode`):

=========================================  ======================================================================
events                                     from
=========================================  ======================================================================
0, 1 phase on, begin green                 the change into green
7, 8 and 4/5/6 green termination, yellow   the change into yellow, with why the green ended (gap-out, max-out,
                                           force-off: the coordinator's or phaseControlGroupForceOff; a
                                           coordinated phase ending at its yield point is forced off there, as
                                           field controllers log it; none when it ends later)
9, 10 end yellow, begin red clearance      the change into red clearance (10 only when it has a length: "Set
                                           only if phase red clearance is served")
11, 12 end red clearance, phase inactive   the change to rest in red (the ring no longer times the phase)
2 phase check                              conflicting demand registered against the green ("Set when a
                                           conflicting call is registered against the active phase"; at the
                                           latest on the tick the green ends, as field logs show it); under max
                                           recall the max timer runs from the green's start without it
3 min complete                             the green's minimum (with walk and pedestrian clearance) timed
31 barrier termination                     a green starting in another barrier group than the last one;
                                           parameter: the group that ended (1 = the first), as field logs show
21, 22, 23 walk, flashing and solid DW     the walk and pedestrian clearance intervals of a green
43, 44 phase call registered, dropped      the vehicle calls the controller acts on (phaseStatusGroupVehCalls),
                                           not on a phase with a minimum or maximum recall
45 pedestrian call registered              a pedestrian call latched, not on a phase with pedestrian recall
41/42, 46/47, 48/49 hold, omit, ped omit   the hold, omit (with the running pattern's split-mode omits) and
                                           pedestrian omit objects as the controller applies them
81, 82 / 89, 90 detector off, on           the vehicle and pedestrian detector inputs as the controller reads them
61-65, 32/33 overlaps                      each overlap's display (:mod:`emulator.model.overlaps`) as it changes:
                                           begin green, trailing green, yellow (its parent's or its own trailing one),
                                           trailing red, off (red); a flashing yellow arrow's flashing begins and
                                           ends the permissive (32, 33), numbered as the overlap (1 = A)
102, 104 preempt input on, off             preemptControlState as the controller reads it
105, 106, 107, 110, 111 preemption         a preempt's service (:mod:`emulator.model.preemption`, preemptState) entering
                                           entry, track clearance, dwell, maximum presence, exit
131-149 pattern, cycle, offset, splits     a pattern starting (or laid out anew); 131 also when going free (254)
150 cycle state                            its changes (free, in step, add, subtract, dwell) and each local zero
151 yield point                            each coordinated phase's yield point
155, 173 unit control and flash status     their NTCIP values, on change
182, 184 power failure, restored           a power cycle (184 alone at the first power-up)
=========================================  ======================================================================

At power-up the log records the state the unit starts in (the phases starting in green, yellow or red
clearance, the pattern) as events of that tick, so a log read from its start tells the whole story.
Without a ``capacity`` the log keeps every event of the unit's life (a run hands it over at its end); with
one it keeps the last ``capacity`` events, as a real controller keeps a ring buffer of its last events
(MaxTime's holds about 10,000): a served controller's memory stays bounded however long it runs. Given a sink
(:meth:`DataLogger.write_to`), the logger also hands it each tick's events as the tick logs them, so that a run
can write them through (:mod:`hils.shell.hiresjournal`) and keep them if it dies before its end.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from types import SimpleNamespace

from emulator.model.controller import Controller, Inputs, Termination
from emulator.model.coordination import Coordinator, Plan
from emulator.model.overlaps import Show
from emulator.model.ring import DWELL, GREEN, RED_CLEAR, YELLOW, Ring
from hils.protocol.config import Recall
from hils.protocol.hires import MAX_PARAMETER, CycleState, Event, EventCode, split_code
from hils.protocol.ntcip import ControlColumn, CoordCorrectionMode, PreemptState, UnitControlStatus, UnitFlashStatus

# The codes as plain ints: the logger names a few at every interval change, and Python 3.11's EnumType.__getattr__
# makes each EventCode.X lookup about ten times a plain attribute's.
E = SimpleNamespace(**{code.name: int(code) for code in EventCode})

_TERMINATIONS = {Termination.GAP_OUT: E.PHASE_GAP_OUT, Termination.MAX_OUT: E.PHASE_MAX_OUT,
                 Termination.FORCE_OFF: E.PHASE_FORCE_OFF}
# Bound once, likewise: the logger reads them at every step or interval change.
STARTUP_FLASH = UnitFlashStatus.STARTUP
YIELD = Termination.YIELD
CYCLE_FREE, IN_STEP, DWELLING = CycleState.FREE, CycleState.IN_STEP, CycleState.TRANSITION_DWELL
SUBTRACTING, ADDING = CycleState.TRANSITION_SUBTRACT, CycleState.TRANSITION_ADD
# What an overlap logs as it enters a display (Show.GREEN from a trailing green: it stays green, nothing).
_OVERLAP = {Show.GREEN: E.OVERLAP_BEGIN_GREEN, Show.TRAIL_GREEN: E.OVERLAP_BEGIN_TRAILING_GREEN,
            Show.YELLOW: E.OVERLAP_BEGIN_YELLOW, Show.TRAIL_YELLOW: E.OVERLAP_BEGIN_YELLOW,
            Show.TRAIL_RED: E.OVERLAP_BEGIN_RED_CLEARANCE, Show.RED: E.OVERLAP_OFF,
            Show.FLASHING: E.FYA_BEGIN_PERMISSIVE}
_GREENS = (Show.TRAIL_GREEN, Show.FLASHING_GREEN)
_SILENT = (Show.FLASHING_GREEN, Show.DELAYED)
# What a preempt logs as its service enters a state (NTCIP preemptState).
_PREEMPT = {PreemptState.ENTRY_STARTED: E.PREEMPT_ENTRY_STARTED,
            PreemptState.TRACK_SERVICE: E.PREEMPT_BEGIN_TRACK_CLEARANCE, PreemptState.DWELL: E.PREEMPT_BEGIN_DWELL,
            PreemptState.MAX_PRESENCE: E.PREEMPT_MAX_PRESENCE_EXCEEDED, PreemptState.EXIT_STARTED: E.PREEMPT_BEGIN_EXIT}
# The on/off events of a set of numbers that the controller reads after each step.
_ON_OFF = {
    "calls": (E.PHASE_CALL_REGISTERED, E.PHASE_CALL_DROPPED),
    "holds": (E.PHASE_HOLD_ACTIVE, E.PHASE_HOLD_RELEASED),
    "omits": (E.PHASE_OMIT_ON, E.PHASE_OMIT_OFF),
    "ped_omits": (E.PED_OMIT_ON, E.PED_OMIT_OFF),
    "detectors": (E.DETECTOR_ON, E.DETECTOR_OFF),
    "ped_detectors": (E.PED_DETECTOR_ON, E.PED_DETECTOR_OFF),
    "preempts": (E.PREEMPT_CALL_INPUT_ON, E.PREEMPT_CALL_INPUT_OFF),
}


@dataclass(frozen=True, slots=True)
class Snapshot:
    """Events ``start`` to ``stop`` of a log's list of records, which only grows past ``stop``: a fixed view."""

    records: list[tuple[int, int, int]]  # (clock tick, code, parameter), the logger's list when it was taken
    start: int
    stop: int
    day0: datetime

    def __len__(self) -> int:
        return self.stop - self.start

    def events(self, first: int = 0, count: int | None = None) -> list[Event]:
        """``count`` events (all: None) from the ``first`` of the view on."""
        lo = self.start + first
        hi = self.stop if count is None else min(self.stop, lo + count)
        return [Event(_local_time(self.day0, c), code, p) for c, code, p in self.records[lo:hi]]


@dataclass(slots=True)
class _Green:
    """What the logger remembers of the green a ring is timing (mutable: updated as it runs)."""

    phase: int
    start: int  # clock tick it began
    minimum: int  # ticks of its minimum
    min_logged: bool = False
    checking: bool = False  # conflicting demand registered (the max timer runs, unless max recall ran it before)


@dataclass(slots=True)
class _Seen:
    """What the controller showed after the last step (mutable: the logger's memory of it)."""

    inputs: Inputs | None = None  # the controller's inputs the sets were read from
    sets: dict[str, frozenset[int]] = field(default_factory=lambda: dict.fromkeys(_ON_OFF, frozenset()))
    ped_calls: frozenset[int] = frozenset()
    walks: frozenset[int] = frozenset()
    clears: frozenset[int] = frozenset()
    flash: UnitFlashStatus | None = None
    control: UnitControlStatus | None = None
    pattern: int | None = None
    plan: Plan | None = None
    state: CycleState | None = None
    overlaps: dict[int, Show] = field(default_factory=dict)
    preempts: dict[int, PreemptState] = field(default_factory=dict)


class DataLogger:
    """The hi-res event log of one controller, attached to it as its recorder."""

    def __init__(self, controller: Controller, capacity: int | None = None) -> None:
        self.controller = controller
        self.capacity = capacity
        self.day0: datetime = controller.day0
        self._log: list[tuple[int, int, int]] = []  # (clock tick, code, parameter)
        self._tick: list[tuple[int, int, int]] = []  # events of the tick being stepped, as the log keeps them
        self._greens: dict[int, _Green] = {}  # ring number -> its green
        self._red_served: dict[int, bool] = {}  # ring number -> its red clearance has a length
        self._group: int | None = None  # barrier group of the last green started
        self._seen = _Seen()
        self._sink: Callable[[Sequence[Event]], None] | None = None
        self._co = controller.coordinator  # its clock is the log's
        self._next_minimum: float = math.inf  # the clock tick of the earliest minimum not logged yet
        cfg = controller.config
        self._barrier = {p: cfg.barrier_of(p) for p in cfg.phases}
        self._no_call_events = frozenset(p for p, ph in cfg.phases.items() if ph.recall in (Recall.MIN, Recall.MAX))
        self._no_ped_events = frozenset(p for p, ph in cfg.phases.items() if ph.recall is Recall.PED)
        controller.recorder = self
        self._power_up(first=True)

    # --- reading the log -------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._log)

    def time(self, clock: int) -> datetime:
        """The local time of a clock tick."""
        return _local_time(self.day0, clock)

    def events(self, since: datetime | None = None) -> list[Event]:
        """The log in time order; from ``since`` on (inclusive) when given."""
        return self.snapshot(since).events()

    def snapshot(self, since: datetime | None = None) -> Snapshot:
        """The log as it stands, from ``since`` on (inclusive) when given; O(log n), nothing copied."""
        self._minimums(before=self._co.clock + 1)
        start = 0
        if since is not None:
            clock = -(-(since - self.day0) // timedelta(microseconds=100_000))  # the first tick at or after since
            start = bisect.bisect_left(self._log, clock, key=lambda e: e[0])
        return Snapshot(self._log, start, len(self._log), self.day0)

    def write_to(self, sink: Callable[[Sequence[Event]], None]) -> None:
        """Hand ``sink`` the log so far, then each tick's events as the tick logs them."""
        sink(self.events())
        self._sink = sink

    # --- what the controller tells -------------------------------------------------------------------------

    def changed(self, r: Ring, reason: Termination | None) -> None:
        clock = self._co.clock
        if self._next_minimum < clock:
            self._minimums(before=clock)
        p, interval = r.phase, r.interval
        if interval is GREEN:
            group = self._barrier[p]
            if self._group is not None and group != self._group:
                self._tick.append((clock, E.BARRIER_TERMINATION, self._group + 1))
            self._group = group
            self._greens[r.number] = _Green(p, clock, r.minimum)
            self._next_minimum = min(self._next_minimum, clock + r.minimum)
            self._tick.append((clock, E.PHASE_ON, p))
            self._tick.append((clock, E.PHASE_BEGIN_GREEN, p))
        elif interval is YELLOW:
            green = self._greens.pop(r.number, None)
            if green is not None:
                self._min_complete(green, clock)
                if not green.checking:  # the conflicting call came on the tick that ends the green
                    self._tick.append((clock, E.PHASE_CHECK, p))
            if reason in _TERMINATIONS:
                self._tick.append((clock, _TERMINATIONS[reason], p))
            elif reason is YIELD and self._at_force_off(p):
                self._tick.append((clock, E.PHASE_FORCE_OFF, p))
            self._tick.append((clock, E.PHASE_GREEN_TERMINATION, p))
            self._tick.append((clock, E.PHASE_BEGIN_YELLOW, p))
        elif interval is RED_CLEAR:
            self._tick.append((clock, E.PHASE_END_YELLOW, p))
            self._red_served[r.number] = r.length > 0
            if r.length:
                self._tick.append((clock, E.PHASE_BEGIN_RED_CLEARANCE, p))
        else:  # rests in red: its red clearance (if served) is over and the ring no longer times the phase
            if self._red_served.pop(r.number, False):
                self._tick.append((clock, E.PHASE_END_RED_CLEARANCE, p))
            self._tick.append((clock, E.PHASE_INACTIVE, p))

    def stepped(self) -> None:
        c = self.controller
        clock = self._co.clock
        if self._next_minimum < clock:
            self._minimums(before=clock)
        for number, green in self._greens.items():
            if clock >= self._next_minimum:
                self._min_complete(green, clock)
            checking = c.rings[number - 1].conflict
            if checking and not green.checking:
                self._tick.append((clock, E.PHASE_CHECK, green.phase))
            green.checking = checking
        if self._seen.flash is STARTUP_FLASH and not c.flashing:
            self._intervals()  # start-up flash over: the start-up intervals begin
        self._read()
        self._flush()

    def pending(self) -> int | None:
        """The clock tick of the next green's minimum the logger has yet to log (None: none): one timed in quiet
        ticks is logged when the logger next hears from the controller or is read, or by :meth:`log_until`."""
        due = min((g.start + g.minimum for g in self._greens.values() if not g.min_logged), default=None)
        self._next_minimum = math.inf if due is None else due
        return due

    def log_until(self, clock: int) -> None:
        """The controller's clock has reached ``clock`` (though it counts the quiet ticks up to it only when next
        read or written): the greens' minimums timed by then are logged, at their ticks."""
        self._minimums(before=clock + 1)

    def powered_up(self) -> None:
        self._minimums(before=self._co.clock + 1)
        self._power_up(first=False)


    # --- internals -----------------------------------------------------------------------------------------------

    def _minimums(self, *, before: int) -> None:
        """Each green's minimum timed at a clock tick before ``before`` and not logged yet, logged at its tick: the
        controller skips quiet ticks without telling the logger, so a minimum that changed nothing else is logged
        when the logger next hears from the controller or is read (at the latest)."""
        if self._next_minimum >= before:
            return
        due = sorted((g.start + g.minimum, g.phase, g) for g in self._greens.values()
                     if not g.min_logged and g.start + g.minimum < before)
        for clock, group in itertools.groupby(due, key=lambda d: d[0]):
            for _, phase, green in group:
                green.min_logged = True
                self._tick.append((clock, E.PHASE_MIN_COMPLETE, phase))
            self._flush()
        self._next_minimum = min((g.start + g.minimum for g in self._greens.values() if not g.min_logged),
                                 default=math.inf)

    def _flush(self) -> None:
        """The events of the tick being stepped (or of a minimum's tick) go to the log."""
        if not self._tick:
            return  # most steps log nothing
        logged = sorted(set(self._tick))
        self._log += logged
        self._tick.clear()
        if self._sink is not None:
            at = self.time(logged[0][0])
            self._sink([Event(at, code, p) for _, code, p in logged])
        if self.capacity is not None and len(self._log) > self.capacity + self.capacity // 4:
            self._log = self._log[len(self._log) - self.capacity:]  # the oldest go, a quarter at a time

    def _power_up(self, *, first: bool) -> None:
        clock = self._co.clock
        if not first:
            self._tick.append((clock, E.POWER_FAILURE, 1))
        self._tick.append((clock, E.POWER_RESTORED, 1))
        self._greens.clear()
        self._red_served.clear()
        self._group = None
        if not self.controller.flashing:
            self._intervals()
        self._read()
        self._flush()

    def _intervals(self) -> None:
        """The intervals the rings start in (power-up and the end of start-up flash start them unannounced)."""
        clock = self._co.clock
        for ring in self.controller.rings:
            if ring.interval is GREEN:
                self.changed(ring, None)
            elif ring.interval is not DWELL:
                if ring.interval is RED_CLEAR:
                    self._red_served[ring.number] = ring.length > 0
                begins = E.PHASE_BEGIN_YELLOW if ring.interval is YELLOW else E.PHASE_BEGIN_RED_CLEARANCE
                self._tick.append((clock, E.PHASE_ON, ring.phase))
                self._tick.append((clock, begins, ring.phase))

    def _at_force_off(self, phase: int) -> bool:
        """The coordinator's force-off point of ``phase`` passed this tick (a coordinated phase's yield point)."""
        co = self.controller.coordinator
        return co.plan is not None and co.plan.force_off.get(phase) in co.passed

    def _min_complete(self, green: _Green, clock: int) -> None:
        if not green.min_logged and clock >= green.start + green.minimum:
            green.min_logged = True
            self._tick.append((clock, E.PHASE_MIN_COMPLETE, green.phase))
            self._next_minimum = min((g.start + g.minimum for g in self._greens.values() if not g.min_logged),
                                     default=math.inf)

    def _read(self) -> None:
        """Events of what the controller shows now against what it showed after the last step."""
        c, seen, clock = self.controller, self._seen, self._co.clock
        inputs = c.inputs
        if inputs is not seen.inputs:  # these change only with the inputs: a write, a new pattern
            seen.inputs = inputs
            now = {
                "calls": c.calls - self._no_call_events,
                "holds": inputs.holds,
                "omits": inputs.omits,
                "ped_omits": c.control[ControlColumn.PED_OMIT],
                "detectors": c.actuations,
                "ped_detectors": c.ped_actuations,
                "preempts": c.preemptor.control,
            }
            for name, numbers in now.items():
                before = seen.sets[name]
                if numbers != before:
                    on, off = _ON_OFF[name]
                    for n in numbers - before:
                        self._tick.append((clock, on, n))
                    for n in before - numbers:
                        self._tick.append((clock, off, n))
            seen.sets = now
        # The controller keeps each of these sets (and dicts) while it holds the same numbers, but the walks and
        # pedestrian clearances, which each status image holds anew: most steps change none of them.
        if c.peds.calls is not seen.ped_calls:
            for p in c.peds.calls - seen.ped_calls - self._no_ped_events:
                self._tick.append((clock, E.PED_CALL_REGISTERED, p))
            seen.ped_calls = c.peds.calls
        if c.walks != seen.walks or c.ped_clears != seen.clears:
            for p in c.walks - seen.walks:
                self._tick.append((clock, E.PED_BEGIN_WALK, p))
            for p in c.ped_clears - seen.clears:
                self._tick.append((clock, E.PED_BEGIN_CLEARANCE, p))
            for p in (seen.walks | seen.clears) - c.walks - c.ped_clears:
                self._tick.append((clock, E.PED_BEGIN_SOLID_DONT_WALK, p))
            seen.walks, seen.clears = c.walks, c.ped_clears
        if c.overlaps.shown != seen.overlaps:
            for n, shown in c.overlaps.shown.items():
                before = seen.overlaps.get(n, Show.RED)
                if shown is before:
                    continue
                if before is Show.FLASHING:
                    self._tick.append((clock, E.FYA_END_PERMISSIVE, n))
                # A green that goes on (from a trailing green, a transit bar's flashing green) is no new green; a
                # flashing green is its green lamp, a delayed green's red is red: no event of their own.
                goes_on = shown is Show.GREEN and before in _GREENS
                if not (shown in _SILENT or goes_on or (shown is Show.RED and before is Show.DELAYED)):
                    self._tick.append((clock, _OVERLAP[shown], n))
            seen.overlaps = dict(c.overlaps.shown)
        if c.preemptor.states != seen.preempts:
            for n, state in c.preemptor.states.items():
                if state is not seen.preempts.get(n, PreemptState.NOT_ACTIVE) and state in _PREEMPT:
                    self._tick.append((clock, _PREEMPT[state], n))
            seen.preempts = dict(c.preemptor.states)
        if c.flash_status is not seen.flash:
            seen.flash = c.flash_status
            self._tick.append((clock, E.UNIT_FLASH_STATUS_CHANGE, int(seen.flash)))
        if c.control_status is not seen.control:
            seen.control = c.control_status
            self._tick.append((clock, E.UNIT_CONTROL_STATUS_CHANGE, int(seen.control)))
        self._coordination()

    def _coordination(self) -> None:
        co, seen = self._co, self._seen
        clock = co.clock
        plan = co.plan
        if plan is None and seen.state is CYCLE_FREE:
            return  # free, as it was
        if co.running != seen.pattern or plan is not seen.plan:
            seen.pattern, seen.plan = co.running, plan
            self._tick.append((clock, E.COORD_PATTERN_CHANGE, co.running))
            if plan is not None:
                self._tick.append((clock, E.CYCLE_LENGTH_CHANGE, min(plan.cycle // 10, MAX_PARAMETER)))
                self._tick.append((clock, E.OFFSET_LENGTH_CHANGE, min(plan.offset // 10, MAX_PARAMETER)))
                for phase, split in plan.split.items():
                    self._tick.append((clock, split_code(phase), min(split // 10, MAX_PARAMETER)))
        state = _cycle_state(co)
        if state is not seen.state:
            seen.state = state
            self._tick.append((clock, E.COORD_CYCLE_STATE_CHANGE, state))
        if plan is None or not co.passed:
            return
        if 0 in co.passed:
            self._tick.append((clock, E.COORD_CYCLE_STATE_CHANGE, CycleState.LOCAL_ZERO))
        for phase in plan.coord.values():
            if plan.force_off[phase] in co.passed:
                self._tick.append((clock, E.COORD_YIELD_POINT, phase))


def _local_time(day0: datetime, clock: int) -> datetime:
    """The local time of a clock tick counted from midnight of ``day0``."""
    return day0 + timedelta(microseconds=clock * 100_000)


def _cycle_state(co: Coordinator) -> CycleState:
    """The coordinator's state as event 150 names it: free, in step, or the correction under way."""
    if co.plan is None:
        return CYCLE_FREE
    if not co.lag:
        return IN_STEP
    if co.correction is CoordCorrectionMode.DWELL:
        return DWELLING
    return SUBTRACTING if co.subtracting else ADDING
