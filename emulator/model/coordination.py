"""The coordinator of an actuated controller: which pattern runs, the local cycle timer, its force-offs.

Rules of this file
------------------
- Time is integer ticks (0.1 s), as in the controller. The controller's clock counts ticks from midnight
  of the simulated day (power-up is 00:00:00 of day 0); it keeps counting across power cycles, as a
  controller's real-time clock does.
- The coordinator decides *when* (which pattern, where in the cycle, which force-off points the timer
  passed this tick); the controller (:mod:`emulator.model.controller`) decides *what the rings do*. The
  coordinator never looks at rings, the controller never computes a cycle position.
- :meth:`Coordinator.step` is the only thing that moves the local cycle timer; :meth:`Coordinator.skip`
  moves it over quiet ticks, which :meth:`Coordinator.deadline` vouches pass no mark.
- A pattern's timings are copied into a :class:`Plan` when the pattern starts; a SET of the pattern or
  split table (NTCIP) takes effect at the next local cycle zero, as a pattern change does.

Theory of operation
-------------------
*Which pattern runs.* NTCIP 1202 systemPatternControl is the system's command: 1-253 a pattern, 254
free, 0 standby ("the system relinquishes control": the local plan runs), 255 flash (not modelled:
"If an unsupported / invalid pattern is called, Free shall be the operational mode"). The local plan
is the config's power-up ``pattern`` until the time-of-day ``schedule`` changes it, at each entry's
time. A called pattern that is not defined, or whose timings do not fit (splits not adding up to the
cycle, a split shorter than its phase's minimum service, an offset past the cycle), runs Free, and
localFreeStatus says why, as NTCIP's patternCycleTime, patternOffsetTime and splitTime require. From
free, a pattern starts at once with the local timer on the system's sync; from a pattern, a new one
(or new timings) starts at the next local zero.

*The local cycle.* A :class:`Plan` lays each ring's splits end to end in ring order, each split
holding its phase's green and then its yellow and red clearance, so a phase's *force-off point* is its
split's start plus its split minus its clearance. The local zero is the start of the earliest
coordinated phase's green (``offset_reference = "lead_green"``, NEMA TS 2) or the start of its yellow
(``"yellow"``, as 170 controllers count). In sync, the local timer is the system's: ``(clock - offset)
mod cycle`` (patternOffsetTime: "the local time zero shall lag the system time zero ... for this
pattern"). Positions are relative to each ring's *yield point*, its coordinated phase's force-off:
a phase *fits* while the ring can still reach it, serve its minimum and clear before its force-off
point.

*Offset correction* (coordCorrectionMode). When the local timer is off the system's (a pattern changed
its offset or cycle), ``dwell`` holds the timer just before the earliest coordinated yield point until
it is in step (the coordinated phases dwell in green); ``add`` holds there too, at most a fifth of the
cycle per cycle; ``shortway`` adds that way or subtracts (the timer jumps forward at the start of the
coordinated splits, shortening the coordinated greens, never below their minimum), whichever reaches
the sync in fewer cycles, at most a fifth of the cycle per cycle. The bound on the cycles a correction takes is
:meth:`Plan.correction_cycles`.

*Quiet time.* Between two real steps the timer only counts; anything discrete happens at a *mark*
(a split start, a force-off point, a fit threshold, the local zero, a second of the status objects) or
at a schedule time. While a correction is under way every tick is a real step.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from hils.protocol.config import FREE, Coordination, Correction, ForceOff, IntersectionConfig, OffsetReference, Pattern
from hils.protocol.ntcip import CoordCorrectionMode as CorrectionMode
from hils.protocol.ntcip import CoordForceMode as ForceMode
from hils.protocol.ntcip import LocalFreeStatus, SplitMode

DAY = 864_000  # ticks in a day
CORRECTION_SHARE = 5  # add and shortway change a cycle by at most cycle / 5


_CORRECTIONS = {Correction.DWELL: CorrectionMode.DWELL, Correction.SHORTWAY: CorrectionMode.SHORTWAY,
                Correction.ADD: CorrectionMode.ADD_ONLY}
_FORCES = {ForceOff.FLOATING: ForceMode.FLOATING, ForceOff.FIXED: ForceMode.FIXED}


@dataclass(slots=True)
class PatternRow:
    """One row of the pattern table as the NTCIP database holds it (seconds), writable over SNMP."""

    cycle: int
    offset: int
    split: int  # patternSplitNumber
    sequence: int = 1


@dataclass(slots=True)
class SplitRow:
    """One phase of one split table (seconds), writable over SNMP."""

    time: int
    mode: SplitMode = SplitMode.NONE
    coord: bool = False


@dataclass(frozen=True)
class Plan:
    """A pattern laid out on the local cycle, in ticks: what the coordinator and the rings time against."""

    number: int
    cycle: int
    offset: int
    coord: Mapping[int, int]  # ring -> its coordinated phase
    split: Mapping[int, int]
    start: Mapping[int, int]  # cycle position of each phase's split start
    force_off: Mapping[int, int]  # cycle position where each phase's green must end
    min_green: Mapping[int, int]
    walk_service: Mapping[int, int]  # the least a green serving a walk lasts: minimum green, or walk + ped clear
    clearance: Mapping[int, int]
    ring_of: Mapping[int, int]
    modes: Mapping[int, SplitMode]
    hold: int  # where add and dwell hold the timer: the tick before the earliest coordinated yield point
    jump: int  # where shortway subtracts: the start of the earliest coordinated split
    add_cap: int  # ticks add and shortway may lengthen one cycle by
    subtract_cap: int  # ticks shortway may shorten one cycle by (the coordinated greens keep their minimum)

    def position(self, phase: int, local: int) -> int:
        """Ticks from ``phase``'s ring's yield point to ``local`` (0 at the yield point)."""
        return (local - self.force_off[self.coord[self.ring_of[phase]]]) % self.cycle

    def reach(self, phase: int) -> int:
        """Ticks from its ring's yield point to ``phase``'s force-off point (the cycle for the coordinated phase)."""
        return (self.force_off[phase] - self.force_off[self.coord[self.ring_of[phase]]]) % self.cycle or self.cycle

    def fits(self, phase: int, local: int, clearance: int, *, walk: bool = False) -> bool:
        """``phase`` can still start after ``clearance`` ticks, serve its minimum (with ``walk``, its walk and
        pedestrian clearance too) and reach its force-off point in this cycle (the coordinated phase always fits:
        it is where the ring returns)."""
        if phase in self.coord.values():
            return True
        least = self.walk_service[phase] if walk else self.min_green[phase]
        return self.position(phase, local) + clearance + least <= self.reach(phase)

    def permitted(self, prior: int, local: int) -> bool:
        """The permissive period of the phase after ``prior`` (leaving its ring's coordinated phase) is open:
        ``prior`` can no longer be served to its minimum before its force-off point, and that point passed less
        than the coordinated phase's minimum green ago. For the first phase after the coordinated phase (``prior``
        the coordinated phase) that is the coordinated minimum green after the yield point."""
        coord = self.coord[self.ring_of[prior]]
        since = (local - self.force_off[prior]) % self.cycle
        if since < self.min_green[coord]:
            return True
        return prior != coord and since > self.cycle - self.min_green[prior] - self.clearance[coord]

    def held(self, coord: int, local: int) -> bool:
        """``local`` lies in coordinated phase ``coord``'s own split, before its yield point."""
        green = (self.force_off[coord] - self.start[coord]) % self.cycle
        return self.position(coord, local) >= self.cycle - green

    def in_window(self, phase: int, local: int) -> bool:
        """``local`` lies before ``phase``'s force-off point in this cycle (after its ring's yield point)."""
        return self.position(phase, local) < self.reach(phase)

    def correction_cycles(self, lag: int, correction: CorrectionMode) -> int:
        """The most cycles reaching the system's sync from ``lag`` ticks ahead of it takes (0 when in sync)."""
        if lag == 0:
            return 0
        if correction is CorrectionMode.DWELL:
            return 1
        cycles = math.ceil(lag / self.add_cap)
        if correction is CorrectionMode.SHORTWAY and self.subtract_cap:
            cycles = min(cycles, math.ceil((self.cycle - lag) / self.subtract_cap))
        return cycles

    def marks(self) -> frozenset[int]:
        """Cycle positions where something discrete may happen: split starts, force-off points, the thresholds
        where a phase stops fitting (after any clearance), the local zero, the correction points, every second."""
        out = {0, self.hold, self.jump, *self.start.values(), *self.force_off.values(), *range(0, self.cycle, 10)}
        clearances = {0, *self.clearance.values()}
        for c in self.coord.values():  # where permissive periods open and close
            for p in self.split:
                if self.ring_of[p] == self.ring_of[c]:
                    out |= {(self.force_off[p] + self.min_green[c] + k) % self.cycle for k in (0, 1)}
                    out |= {(self.force_off[p] - self.min_green[p] - self.clearance[c] + k) % self.cycle
                            for k in (0, 1)}
        for c in clearances:
            out |= self.unfit(c)
        return frozenset(out)

    def unfit(self, clearance: int) -> set[int]:
        """Cycle positions where a phase stops fitting (:meth:`fits`, with or without its walk) after
        ``clearance`` ticks."""
        out = set()
        for p in self.split:
            if p not in self.coord.values():
                y = self.force_off[self.coord[self.ring_of[p]]]
                out |= {(y + self.reach(p) - least - clearance + 1) % self.cycle
                        for least in (self.min_green[p], self.walk_service[p])}
        return out


def lay_out(number: int, row: PatternRow, splits: Mapping[int, SplitRow], config: IntersectionConfig,
            reference: OffsetReference) -> Plan | LocalFreeStatus:
    """The plan of pattern ``number``, or the localFreeStatus that says why it cannot run (NTCIP: Free)."""
    phases = config.phases
    if row.cycle == 0 or row.sequence != 1 or any(p not in splits for p in phases):
        return LocalFreeStatus.BAD_PLAN
    if row.offset >= row.cycle:
        return LocalFreeStatus.INVALID_OFFSET  # patternOffsetTime: "equal to or greater than ... Free"
    coord = {phases[p].ring: p for p in phases if splits[p].coord}
    if sorted(coord) != list(range(1, len(config.rings) + 1)) or sum(splits[p].coord for p in phases) != len(coord) \
            or len({config.barrier_of(p) for p in coord.values()}) != 1:
        return LocalFreeStatus.BAD_PLAN
    tick = 10
    need = {p: round((ph.min_green + ph.yellow + ph.red_clear) * tick) for p, ph in phases.items()}
    if any(splits[p].time * tick < need[p] for p in phases):
        return LocalFreeStatus.BAD_CYCLE_TIME  # splitTime: "NOT adequate to service the minimum ... Free"
    for ring in config.rings:
        if sum(splits[p].time for p in ring) != row.cycle:
            return LocalFreeStatus.SPLIT_OVERRUN
    for group in config.barriers:
        if len({sum(splits[p].time for p in ring if p in group) for ring in config.rings}) > 1:
            return LocalFreeStatus.SPLIT_OVERRUN  # the rings would reach the barrier at different times
    cycle = row.cycle * tick
    clearance = {p: round(ph.clearance * tick) for p, ph in phases.items()}
    raw_start: dict[int, int] = {}
    for ring in config.rings:
        at = 0
        for p in ring:
            raw_start[p] = at
            at += splits[p].time * tick
    raw_force = {p: raw_start[p] + splits[p].time * tick - clearance[p] for p in phases}
    zero = min((raw_start if reference is OffsetReference.LEAD_GREEN else raw_force)[c] for c in coord.values())
    start = {p: (raw_start[p] - zero) % cycle for p in phases}
    force = {p: (raw_force[p] - zero) % cycle for p in phases}
    min_green = {p: round(ph.min_green * tick) for p, ph in phases.items()}
    walk_service = {p: max(min_green[p], round((ph.walk + ph.ped_clear) * tick) if ph.walk else 0)
                    for p, ph in phases.items()}
    greens = [(force[c] - start[c]) % cycle for c in coord.values()]
    return Plan(number, cycle, row.offset * tick, coord, {p: splits[p].time * tick for p in phases}, start, force,
                min_green, walk_service, clearance, {p: ph.ring for p, ph in phases.items()},
                {p: splits[p].mode for p in phases},
                hold=(min(force[c] for c in coord.values()) - 1) % cycle,
                jump=min(start[c] for c in coord.values()), add_cap=cycle // CORRECTION_SHARE,
                subtract_cap=max(0, min(min(greens) - max(min_green[c] for c in coord.values()),
                                        cycle // CORRECTION_SHARE)))


@dataclass
class Coordinator:
    """The unit's coordination: its NTCIP tables, the command, the local plan and the running pattern."""

    config: IntersectionConfig
    clock: int = 0  # ticks since midnight of day 0
    command: int = 0  # systemPatternControl
    patterns: dict[int, PatternRow] = field(default_factory=dict)
    splits: dict[int, dict[int, SplitRow]] = field(default_factory=dict)
    force_mode: ForceMode = ForceMode.FIXED
    correction: CorrectionMode = CorrectionMode.SHORTWAY

    def __post_init__(self) -> None:
        c: Coordination = self.config.coordination
        self.reference = c.offset_reference
        self.force_mode = _FORCES[c.force_off]
        self.correction = _CORRECTIONS[c.correction]
        # The tables hold a row for every pattern number up to the highest configured, and at least one
        # (maxPatterns is 1..253 and counts the patternTable's rows); one not configured has a cycle of 0 (no
        # pattern: calling it runs Free) until a SET defines it.
        for n in range(1, max(c.patterns, default=1) + 1):
            pattern = c.patterns.get(n)
            self.patterns[n] = PatternRow(pattern.cycle, pattern.offset, n) if pattern else PatternRow(0, 0, n)
            self.splits[n] = (_split_rows(pattern) if pattern
                              else {p: SplitRow(0) for p in self.config.phases})
        self.reset()

    def reset(self) -> None:
        """Power-up: the local plan is the config's power-up pattern; the clock keeps running."""
        self.local = self.config.coordination.pattern
        self.plan: Plan | None = None
        self.free_status = LocalFreeStatus.COORD_FREE
        self.timer = 0  # the local cycle timer (ticks), when a pattern runs
        self.passed: frozenset[int] = frozenset()  # cycle positions the timer passed in the last step
        self.budget = 0  # correction ticks left in this cycle
        self.replan = False  # a table SET: lay the running pattern out again at the next local zero
        self._start_called()

    # --- the command, the tables ------------------------------------------------------------------

    @property
    def called(self) -> int:
        """The pattern called now: the system's command, or the local plan in standby."""
        if self.command == 0:
            return self.local
        return self.command if self.command <= FREE else FREE

    @property
    def running(self) -> int:
        """coordPatternStatus: the pattern running, or 254 free."""
        return self.plan.number if self.plan else FREE

    @property
    def cycle_status(self) -> int:
        """coordCycleStatus, seconds: the local cycle counting down from the cycle to zero (0 when free)."""
        return (self.plan.cycle - self.timer) // 10 if self.plan else 0

    @property
    def sync_status(self) -> int:
        """coordSyncStatus, seconds: the time since the system reference point (0 when free)."""
        return self.sync // 10

    def set_command(self, value: int) -> None:
        """A SET of systemPatternControl."""
        self.command = value
        if self.plan is None or self.called == FREE:
            self._start_called()

    def tables_changed(self) -> None:
        """A SET of the pattern or split table, or of coordForceMode/coordCorrectionMode: the running pattern is
        laid out again at its next local zero (a pattern not running yet uses the new values when it starts)."""
        if self.plan is not None:
            self.replan = True

    # --- the tick ----------------------------------------------------------------------------------

    @property
    def sync(self) -> int:
        """The system's position in the running pattern's cycle (coordSyncStatus, in ticks)."""
        return (self.clock - self.plan.offset) % self.plan.cycle if self.plan else 0

    @property
    def lag(self) -> int:
        """Ticks the local timer is ahead of the system's (0: in sync)."""
        return (self.timer - self.sync) % self.plan.cycle if self.plan else 0

    def step(self) -> None:
        """One tick: the clock, the time-of-day plan, the local timer and the points it passed."""
        lag = self.lag if self.plan is not None else 0  # before the clock moves: the timer moves with it when in step
        self.clock += 1
        for entry in self.config.coordination.schedule:
            if self.clock % DAY == entry.start * 10:
                self.local = entry.pattern
        if (self.called != self.running or self.replan) and (self.plan is None or self.called == FREE):
            self._start_called()
            self.passed = frozenset()
            return
        plan = self.plan
        if plan is None:
            self.passed = frozenset()
            return
        before = self.timer
        adding = lag and (self.correction is CorrectionMode.DWELL or not self._subtracting(plan, lag))
        if adding and before == plan.hold and (self.budget > 0 or self.correction is CorrectionMode.DWELL):
            self.budget -= 1
            self.passed = frozenset()
            return
        self.timer = (before + 1) % plan.cycle
        if lag and not adding and self.timer == plan.jump and self.budget > 0:
            d = min(plan.cycle - lag, self.budget)
            self.budget -= d
            self.timer = (self.timer + d) % plan.cycle
        steps = (self.timer - before) % plan.cycle
        self.passed = frozenset((before + k) % plan.cycle for k in range(1, steps + 1))
        if 0 in self.passed:
            self._new_cycle()

    @property
    def subtracting(self) -> bool:
        """A correction under way shortens cycles (shortway, when going back is the short way)."""
        return self.plan is not None and bool(self.lag) and self._subtracting(self.plan, self.lag)

    def _subtracting(self, plan: Plan, lag: int) -> bool:
        """Shortway subtracts when that reaches the sync in fewer cycles than adding (its cap is the smaller one:
        the coordinated greens keep their minimum)."""
        return (self.correction is CorrectionMode.SHORTWAY and plan.subtract_cap > 0
                and math.ceil((plan.cycle - lag) / plan.subtract_cap) < math.ceil(lag / plan.add_cap))

    def _new_cycle(self) -> None:
        if self.called != self.running or self.replan:
            self._start_called(timer=0)
        plan = self.plan
        if plan is not None:
            lag = self.lag
            self.budget = plan.subtract_cap if lag and self._subtracting(plan, lag) else plan.add_cap

    def _start_called(self, timer: int | None = None) -> None:
        """Run the called pattern now: on the system's sync, or from ``timer`` (a change at the local zero)."""
        self.replan = False
        called = self.called
        if called == FREE:
            self.plan = None
            self.free_status = (LocalFreeStatus.COMMAND_FREE if self.command == FREE
                                else LocalFreeStatus.OTHER if self.command > FREE else LocalFreeStatus.COORD_FREE)
            return
        row = self.patterns.get(called)
        splits = self.splits.get(row.split) if row else None
        plan = lay_out(called, row, splits, self.config, self.reference) if row and splits else LocalFreeStatus.BAD_PLAN
        if isinstance(plan, LocalFreeStatus):
            self.plan, self.free_status = None, plan
            return
        self.plan, self.free_status = plan, LocalFreeStatus.NOT_FREE
        self.timer = (self.clock - plan.offset) % plan.cycle if timer is None else timer
        lag = self.lag
        self.budget = plan.subtract_cap if lag and self._subtracting(plan, lag) else plan.add_cap

    # --- quiet time ---------------------------------------------------------------------------------

    def deadline(self) -> int | None:
        """Steps until the next one at which anything discrete may happen here (None: never, inputs kept)."""
        plan = self.plan
        if plan is not None and self.lag:
            return 1
        ahead = self.until_schedule() if self.config.coordination.schedule else None
        if plan is not None:
            mark = self.until(plan.marks())
            ahead = mark if ahead is None else min(ahead, mark)
        return ahead

    def until(self, marks: Iterable[int]) -> int:
        """Ticks until the local timer next reaches one of ``marks`` (cycle positions of the running plan)."""
        cycle, timer = self.plan.cycle, self.timer
        return min((m - timer - 1) % cycle + 1 for m in marks)

    def until_schedule(self) -> int:
        """Ticks until the next time-of-day change of the local plan (a schedule configured)."""
        now = self.clock % DAY
        return min((e.start * 10 - now - 1) % DAY + 1 for e in self.config.coordination.schedule)

    def skip(self, n: int) -> None:
        """``n`` quiet ticks at once (fewer than :meth:`deadline`)."""
        self.clock += n
        if self.plan is not None:
            self.timer = (self.timer + n) % self.plan.cycle

    # --- what the rings ask --------------------------------------------------------------------------

    def recalled(self) -> frozenset[int]:
        """Phases with demand from the running pattern: the coordinated phases, and split-mode recalls."""
        plan = self.plan
        if plan is None:
            return frozenset()
        modes = {SplitMode.MIN_RECALL, SplitMode.MAX_RECALL, SplitMode.PED_RECALL, SplitMode.MAX_AND_PED_RECALL}
        return frozenset(plan.coord.values()) | {p for p, m in plan.modes.items() if m in modes}

    def omitted(self) -> frozenset[int]:
        plan = self.plan
        return frozenset(p for p, m in plan.modes.items() if m is SplitMode.OMITTED) if plan else frozenset()

    def max_recalled(self) -> frozenset[int]:
        plan = self.plan
        return frozenset(p for p, m in plan.modes.items()
                         if m in (SplitMode.MAX_RECALL, SplitMode.MAX_AND_PED_RECALL)) if plan else frozenset()

    def ped_recalled(self) -> frozenset[int]:
        plan = self.plan
        return frozenset(p for p, m in plan.modes.items()
                         if m in (SplitMode.PED_RECALL, SplitMode.MAX_AND_PED_RECALL)) if plan else frozenset()


def _split_rows(pattern: Pattern) -> dict[int, SplitRow]:
    return {p: SplitRow(t, pattern.modes.get(p, SplitMode.NONE), p in pattern.coord_phases)
            for p, t in pattern.splits.items()}
