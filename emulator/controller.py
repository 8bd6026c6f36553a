"""A dual-ring NEMA TS2 actuated controller in free mode, ticking every 0.1 s.

Rules of this file
------------------
- Time is an integer count of ticks (tenths of a second), as in a real controller; no float time
  is compared anywhere in here.
- :meth:`Controller.step` is the only thing that advances timing. It reads the control objects
  (calls, holds, force-offs, omits) as they are at that tick.
- A ring's timed intervals follow ``_NEXT`` (yellow, then red clearance) and nothing else; a ring
  leaves GREEN only by ``_clear`` (the start of its yellow, where its next phase is committed) and
  starts a phase only by ``_start``. The decisions of a tick are made in ``_decide`` from the rings'
  readiness and wishes, in the order of the rules below.

Theory of operation
-------------------
Each ring times one phase at a time: GREEN, YELLOW, RED_CLEAR; a ring whose committed next phase
lies across the barrier then WAITs in red for the other ring; a ring with nothing to serve in the
barrier group DWELLs in red. Both rings always work inside one barrier group, so any two phases they
show are concurrent by the ring-and-barrier structure. The rules, per tick (aligned with SUMO's NEMA
controller, which its authors validated against Econolite software-in-the-loop; see
docs/nema_differences.md for where and why we differ):

1. Timing a green. Conflicting demand for a green is a call on another phase of its ring or on any
   phase across the barrier; Maximum1 times only while it exists (max-out). The phase's own call
   extends the green by its passage time after the call was last seen (gap-out when it has not been
   seen for ``passage``; a middleware's presence call is a constant actuation). A green that has
   timed its minimum and gapped out while conflicting demand exists stays gapped out (its call
   coming back does not extend it again) until it ends or the conflicting demand goes away.
2. A green is ready to end when it is not held and has timed its minimum, and it gapped out, maxed
   out or is forced off (ForceOff acts only while conflicting demand exists).
3. A ready ring wishes for the nearest called phase after its own in ring order (cyclically), its
   own excluded. A phase with ``backup_prevent`` is not backed into (served from a later phase of
   its barrier group): the ring reaches it through a barrier cycle, as if it lay across the barrier
   (both rings clear and re-enter the group), and for the other ring that call is conflicting
   demand, as a call across the barrier is.
4. A wish within the barrier group is served at once: the ring clears (yellow, red clearance) and
   enters the wished phase; backing into an earlier phase of the group waits while both rings are
   ready and one of them wishes across the barrier (the crossing goes first).
5. Barrier crossing. While a ring wishes across the barrier, it keeps its green (waits at the
   barrier) until every ring is ready, with a wish across or none; then all rings clear together
   and, when every one has finished its red clearance, enter the other group together. A ring with
   no call there serves its ``dual_entry`` phase of that group, if it has one, else it dwells in red.
6. Without a wish a ready green rests in green. A ring that dwells starts a called phase of the
   group at once. With no green and nothing called anywhere the controller rests in red.

The next phase of a ring is decided at the start of its yellow (PhaseNext, reported from then) and
a call that appears during the clearance does not redirect it. A committed next phase whose call
drops during the clearance is served anyway, for its minimum green (as SUMO's NEMA controller does:
NEMAController.cpp, NEMAPhase::exit enters the last transition decision at the end of red without
re-checking its call; NEMA TS2 commits PhaseNext at the end of green). A committed next phase that is
omitted during the clearance is not served (an omitted phase "shall not be serviced", NTCIP 1202
phaseControlGroupPhaseOmit): at the end of the clearance the ring decides again among the calls it
may serve, or dwells.

Recalls: ``min`` and ``max`` recall call the phase whenever it is not green (``max`` also keeps
calling it while green, so it extends to its maximum); ``soft`` recall calls it only while no other
phase is called. Omitted phases never start. ForceOff bits clear themselves when that phase's green
ends. unitBackupTime is armed by the first SET of a control object; when it passes without another,
the controller reports backupMode and clears every control object. A conflict monitor, like an MMU,
checks every change that no two phases showing green or yellow are incompatible under the
configured matrix; if they are, the controller goes to flash (all red) and stops timing.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import Enum

import simpy

from hils.config import IntersectionConfig, Recall
from hils.ntcip import ControlColumn, PhaseStartup, UnitControlStatus, UnitFlashStatus

log = logging.getLogger(__name__)

TICK = 0.1  # seconds per controller tick


class Interval(Enum):
    GREEN = "green"
    YELLOW = "yellow"
    RED_CLEAR = "red_clear"
    WAIT = "wait"  # red, clearance done, waiting for the other ring to cross the barrier together
    DWELL = "dwell"  # red, nothing to serve in this barrier group


# What a timed clearance interval becomes when it has run its length.
_NEXT: dict[Interval, Interval] = {
    Interval.YELLOW: Interval.RED_CLEAR,
    Interval.RED_CLEAR: Interval.WAIT,
}

_STARTUP_INTERVAL = {
    PhaseStartup.GREEN_WALK: Interval.GREEN,
    PhaseStartup.GREEN_NO_WALK: Interval.GREEN,
    PhaseStartup.YELLOW_CHANGE: Interval.YELLOW,
    PhaseStartup.RED_CLEAR: Interval.RED_CLEAR,
}


def tenths(seconds: float) -> int:
    return round(seconds * 10)


@dataclass(slots=True)
class Ring:
    """Timing state of one ring (mutable: the controller's working memory)."""

    number: int
    order: tuple[int, ...]
    phase: int | None = None  # the phase timing now, or last timed while in WAIT or DWELL
    interval: Interval = Interval.DWELL
    ticks: int = 0  # ticks completed in the current interval
    max_ticks: int = 0  # ticks of conflicting demand during this green
    since_call: int = 0  # ticks since the green's own call was last seen
    gapped_out: bool = False  # rule 1: gapped out under conflicting demand, until it ends or the demand goes
    target: int | None = None  # the next phase, committed at the start of yellow


@dataclass(frozen=True, slots=True)
class Change:
    """One interval change, for timelines and logs."""

    tick: int
    ring: int
    phase: int | None
    interval: Interval


class Controller:
    """The controller model: state, control objects and the tick."""

    def __init__(self, config: IntersectionConfig, *, on_change: Callable[[Change], None] | None = None) -> None:
        self.config = config
        self.on_change = on_change
        phases = config.phases
        self._min = {p: tenths(ph.min_green) for p, ph in phases.items()}
        self._max = {p: tenths(ph.max_green) for p, ph in phases.items()}
        self._passage = {p: max(1, tenths(ph.passage)) for p, ph in phases.items()}
        self._length = {p: {Interval.YELLOW: tenths(ph.yellow), Interval.RED_CLEAR: tenths(ph.red_clear)}
                        for p, ph in phases.items()}
        self._barrier = {p: config.barrier_of(p) for p in phases}
        self._order = {p: ring.index(p) for ring in config.rings for p in ring}
        self._ring_of = {p: ph.ring for p, ph in phases.items()}
        self._recall = {p: ph.recall for p, ph in phases.items() if ph.recall is not Recall.NONE}
        self._dual_entry = {(ph.ring, self._barrier[p]): p for p, ph in phases.items() if ph.dual_entry}
        self._backup_prevent = frozenset(p for p, ph in phases.items() if ph.backup_prevent)
        self.backup_time = config.middleware.backup_time
        self.pattern = 254  # free
        self.reset()

    # --- lifecycle -------------------------------------------------------------------------------

    def reset(self) -> None:
        """Power-up: start-up intervals, control objects cleared, not under system control."""
        self.tick = 0
        self.control: dict[ControlColumn, frozenset[int]] = {c: frozenset() for c in ControlColumn}
        self.control_status = UnitControlStatus.OTHER
        self.flash_status = UnitFlashStatus.NOT_FLASH
        self._changed = True
        self._quiet: tuple[frozenset[int], ...] | None = None
        self._since_set: int | None = None  # ticks since the last control SET; None = backup timer disarmed
        self.rings = [Ring(i + 1, order) for i, order in enumerate(self.config.rings)]
        started = [p for p, ph in self.config.phases.items() if ph.startup in _STARTUP_INTERVAL]
        self.group = self._barrier[started[0]] if started else 0
        for p in started:
            ring = self.rings[self._ring_of[p] - 1]
            ring.phase, ring.interval = p, _STARTUP_INTERVAL[self.config.phases[p].startup]
        self._crossing_to: int | None = None  # the barrier group every ring is clearing toward
        self._refresh_status()

    def process(self, env: simpy.Environment, phase: float = 0.0):
        """SimPy process ticking the controller every 0.1 s, without accumulating float error.

        ``phase`` (0 <= phase < 0.1 s) shifts the tick grid: a real controller's ticks keep their
        own phase relative to whoever talks to it."""
        start = env.now + phase
        while True:
            due = start + (self.tick + 1) * TICK
            yield env.timeout(max(0.0, due - env.now))
            self.step()

    # --- control objects -----------------------------------------------------------------------------

    def set_control(self, column: ControlColumn, phases: Iterable[int]) -> None:
        """A SET of one control object: replaces its phases and restarts the backup timer."""
        self.control[column] = frozenset(phases)
        self._since_set = 0
        if self.control_status is not UnitControlStatus.SYSTEM_CONTROL:
            self.control_status = UnitControlStatus.SYSTEM_CONTROL

    @property
    def calls(self) -> frozenset[int]:
        """Vehicle calls the controller acts on: called or recalled, configured and not omitted."""
        omitted = self.control[ControlColumn.PHASE_OMIT]
        called = self.control[ControlColumn.VEH_CALL].intersection(self.config.phases) - omitted
        if self._recall:
            greens = self.greens
            hard = {p for p, r in self._recall.items()
                    if r is Recall.MAX or (r is Recall.MIN and p not in greens)} - omitted
            called |= hard
            if not called:  # soft recall: only while nothing else is called
                called = frozenset(p for p, r in self._recall.items()
                                   if r is Recall.SOFT and p not in greens) - omitted
        return frozenset(called)

    # --- status --------------------------------------------------------------------------------------

    @property
    def flashing(self) -> bool:
        return self.flash_status is not UnitFlashStatus.NOT_FLASH

    def _refresh_status(self) -> None:
        greens, yellows, ons = set(), set(), set()
        if not self.flashing:
            for r in self.rings:
                if r.interval is Interval.GREEN:
                    greens.add(r.phase)
                elif r.interval is Interval.YELLOW:
                    yellows.add(r.phase)
                if r.interval in (Interval.GREEN, Interval.YELLOW, Interval.RED_CLEAR):
                    ons.add(r.phase)
        self.greens = frozenset(greens)
        self.yellows = frozenset(yellows)
        self.phase_ons = frozenset(ons)
        self.reds = frozenset(self.config.phases) - self.greens - self.yellows

    @property
    def phase_nexts(self) -> frozenset[int]:
        """The phase each clearing (or waiting) ring has committed to serve next."""
        if self.flashing:
            return frozenset()  # a flashing controller times nothing, so nothing comes next
        return frozenset(r.target for r in self.rings
                         if r.target is not None and r.interval in (Interval.YELLOW, Interval.RED_CLEAR,
                                                                    Interval.WAIT))

    # --- the tick ------------------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one tick (0.1 s)."""
        self.tick += 1
        self._backup_timer()
        if self.flashing:
            return
        calls = self.calls
        inputs = (calls, self.control[ControlColumn.HOLD], self.control[ControlColumn.FORCE_OFF])
        if inputs == self._quiet:
            # Nothing is timing and the inputs are as they were: only the greens' counters move.
            for r in self.rings:
                if r.interval is Interval.GREEN:
                    r.ticks += 1
                    if r.phase not in calls:
                        r.since_call += 1
            return
        for r in self.rings:
            self._time(r, calls)
        if self._crossing_to is not None and all(r.interval in (Interval.WAIT, Interval.DWELL) for r in self.rings):
            self._enter_group()
        self._decide(calls)
        changed, self._changed = self._changed, False
        if changed:
            self._refresh_status()
            self._monitor()
        resting = all((r.interval is Interval.GREEN and not r.max_ticks and not self._ready(r, calls))
                      or (r.interval is Interval.DWELL and not calls) for r in self.rings)
        self._quiet = inputs if resting and not changed else None

    def _backup_timer(self) -> None:
        if self._since_set is None or self.backup_time == 0:
            return
        self._since_set += 1
        if self._since_set >= self.backup_time * 10:
            log.warning("backup time %d s passed without a control SET: backup mode, control objects cleared",
                        self.backup_time)
            self.control = {c: frozenset() for c in ControlColumn}
            self.control_status = UnitControlStatus.BACKUP_MODE
            self._since_set = None

    def _conflicting(self, r: Ring, calls: frozenset[int]) -> bool:
        p = r.phase
        return any(q != p and (self._ring_of[q] == r.number or self._barrier[q] != self._barrier[p]
                               or self._needs_cycle(q)) for q in calls)

    def _needs_cycle(self, q: int) -> bool:
        """A backup-prevented phase behind its ring's current phase in this group: served after a barrier cycle."""
        if q not in self._backup_prevent or self._barrier[q] != self.group:
            return False
        current = self.rings[self._ring_of[q] - 1].phase
        return (current is not None and self._barrier[current] == self.group
                and self._order[q] < self._order[current])

    def _time(self, r: Ring, calls: frozenset[int]) -> None:
        """Rule 1, and the clearance intervals."""
        if r.interval in (Interval.WAIT, Interval.DWELL):
            return
        r.ticks += 1
        p = r.phase
        if r.interval is Interval.GREEN:
            r.since_call = 0 if p in calls else r.since_call + 1
            if self._conflicting(r, calls):
                r.max_ticks += 1
                if r.ticks >= self._min[p] and r.since_call >= self._passage[p]:
                    r.gapped_out = True
            else:
                r.max_ticks, r.gapped_out = 0, False
        elif r.ticks >= self._length[p][r.interval]:
            self._enter(r, _NEXT[r.interval])
            if r.interval is Interval.WAIT:
                self._end_clearance(r, calls)

    def _end_clearance(self, r: Ring, calls: frozenset[int]) -> None:
        """At the end of red: enter the committed phase if it is in this group, else wait at the barrier."""
        target = r.target
        if target is not None and target in self.control[ControlColumn.PHASE_OMIT]:
            target = r.target = None  # omitted during the clearance: decide again
        if self._crossing_to is not None:
            return  # a crossing is under way: wait for every ring to finish its clearance
        if target is not None and self._barrier[target] == self.group:
            self._start(r, target)
        else:
            self._enter(r, Interval.DWELL)  # nothing committed here

    def _ready(self, r: Ring, calls: frozenset[int]) -> bool:
        """Rule 2."""
        if r.interval is not Interval.GREEN:
            return r.interval is Interval.DWELL
        p = r.phase
        if p in self.control[ControlColumn.HOLD] or r.ticks < self._min[p]:
            return False
        forced = p in self.control[ControlColumn.FORCE_OFF] and self._conflicting(r, calls)
        return r.gapped_out or r.since_call >= self._passage[p] or r.max_ticks >= self._max[p] or forced

    def _wish(self, r: Ring, calls: frozenset[int]) -> int | None:
        """Rule 3: the nearest called phase after the ring's own, in ring order."""
        order = r.order
        here = self._order[r.phase] if r.phase is not None else -1
        for k in range(1, len(order) + (r.interval is Interval.DWELL)):
            q = order[(here + k) % len(order)]
            if q in calls and (q != r.phase or r.interval is Interval.DWELL):
                return q
        return None

    def _decide(self, calls: frozenset[int]) -> None:
        """Rules 3 to 6 for this tick."""
        if not calls or self._crossing_to is not None:
            return
        ready = {r.number: self._ready(r, calls) for r in self.rings}
        wishes = {r.number: self._wish(r, calls) for r in self.rings if ready[r.number]}
        across = {n: q for n, q in wishes.items() if q is not None and (self._crosses(q) or self._needs_cycle(q))}
        all_ready = all(ready.values())
        # Rules 4 and 6: within the group.
        for r in self.rings:
            q = wishes.get(r.number)
            if q is None or r.number in across:
                continue
            backing = r.phase is not None and self._order[q] < self._order[r.phase]
            if backing and across and all_ready:
                wishes[r.number] = None  # the crossing goes first; the ring comes back to it after
                continue
            if r.interval is Interval.DWELL:
                self._start(r, q)
            else:
                self._clear(r, q)
        # Rule 5: crossing, once every ring is ready with a wish across or none.
        if across and all(ready[r.number] and (wishes.get(r.number) is None or r.number in across)
                          for r in self.rings):
            # The next barrier group in sequence that a ring wishes to enter; the same group again
            # (a barrier cycle) when only backup-prevented phases are wished for.
            wished = {self._barrier[q] for q in across.values()}
            n = len(self.config.barriers)
            group = next(g for g in ((self.group + k) % n for k in range(1, n + 1)) if g in wished)
            self._crossing_to = group
            for r in self.rings:
                wish = across.get(r.number)
                target = wish if wish is not None and self._barrier[wish] == group else self._dual_entry.get(
                    (r.number, group))
                if r.interval is Interval.GREEN:
                    self._clear(r, target)
                else:
                    r.target = target
                    self._enter(r, Interval.WAIT)
            if all(r.interval is Interval.WAIT for r in self.rings):
                self._enter_group()

    def _crosses(self, q: int) -> bool:
        return self._barrier[q] != self.group

    def _enter_group(self) -> None:
        """Every ring has finished its clearance: enter the new group's committed phases together."""
        self.group, self._crossing_to = self._crossing_to, None
        for r in self.rings:
            target = r.target
            if target is not None and target in self.control[ControlColumn.PHASE_OMIT]:
                target = None  # omitted during the clearance: the ring decides again from red
            if target is not None:
                self._start(r, target)
            elif r.interval is not Interval.DWELL:
                r.target = None
                self._enter(r, Interval.DWELL)

    def _clear(self, r: Ring, target: int | None) -> None:
        """End a green: yellow now, the next phase committed (PhaseNext) from now on."""
        self.control[ControlColumn.FORCE_OFF] -= {r.phase}
        r.target = target
        self._enter(r, Interval.YELLOW)

    def _start(self, r: Ring, phase: int) -> None:
        r.phase, r.target = phase, None
        r.since_call = 0
        self._enter(r, Interval.GREEN)

    def _enter(self, r: Ring, interval: Interval) -> None:
        r.interval, r.ticks, r.max_ticks, r.gapped_out = interval, 0, 0, False
        self._changed = True
        if self.on_change is not None:
            self.on_change(Change(self.tick, r.number, r.phase, interval))

    def _monitor(self) -> None:
        shown = sorted(self.greens | self.yellows)
        for i, a in enumerate(shown):
            for b in shown[i + 1:]:
                if not self.config.compatible(a, b):
                    log.error("conflict monitor: phases %d and %d shown together at tick %d: flash", a, b, self.tick)
                    self.flash_status = UnitFlashStatus.MMU
                    self._refresh_status()
                    return
