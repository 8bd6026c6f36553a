"""A dual-ring NEMA actuated controller in free mode, ticking every 0.1 s.

Rules of this file
------------------
- Time is an integer count of ticks (tenths of a second), as in a real
  controller; no float time is compared anywhere in here.
- :meth:`Controller.step` is the only thing that advances timing. It reads the
  control objects (calls, holds, force-offs, omits) as they are at that tick.
- Interval changes of a ring follow ``_NEXT`` below and nothing else; a ring
  leaves DWELL only by starting a phase (``_start``), which happens only inside
  the current barrier group or when both rings cross a barrier together.

Theory of operation
-------------------
Each ring times one phase at a time through GREEN, YELLOW and RED_CLEAR, then
DWELLs at red until it may start another phase. Both rings always work inside
the same barrier group, so any two phases they show are concurrent by the
ring-and-barrier structure.

A green ends only when it has timed its minimum and a *conflicting demand*
waits: a call on another phase of its own ring, or a call that cannot be served
in the current visit of the barrier group (a phase beyond the barrier, or one
its ring has already passed in sequence). Without such demand the phase rests
in green. With demand it ends at once if its own phase has no call (gap out),
at Maximum1 timed from the moment the conflicting demand appeared (max out), or
when its ForceOff bit is set; Hold keeps it green regardless. A ring in DWELL
starts the next called phase of its ring, in sequence order, later than the one
it last served in this group visit. When both rings dwell, they cross together
into the next barrier group (cyclically) that holds a call, or restart the
current group if that is the only one with calls; without calls anywhere the
controller rests in red.

Omitted phases never start. ForceOff bits clear themselves when that phase's
green ends. unitBackupTime is armed by the first SET of a control object; when
it passes without another, the controller reports backupMode and clears every
control object. A conflict monitor, like an MMU, checks every tick that no two
phases showing green or yellow are incompatible under the configured matrix;
if they are, the controller goes to flash (all red) and stops timing.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import Enum

import simpy

from hils.config import IntersectionConfig
from hils.ntcip import ControlColumn, PhaseStartup, UnitControlStatus, UnitFlashStatus

log = logging.getLogger(__name__)

TICK = 0.1  # seconds per controller tick


class Interval(Enum):
    GREEN = "green"
    YELLOW = "yellow"
    RED_CLEAR = "red_clear"
    DWELL = "dwell"


# What a timed interval becomes when it has run its length.
_NEXT: dict[Interval, Interval] = {
    Interval.YELLOW: Interval.RED_CLEAR,
    Interval.RED_CLEAR: Interval.DWELL,
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
    phase: int | None = None  # the phase timing now, or last timed while in DWELL
    interval: Interval = Interval.DWELL
    ticks: int = 0  # ticks completed in the current interval
    max_ticks: int = 0  # ticks of conflicting demand during this green
    last: int | None = None  # last phase started in the current barrier group visit


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
        self._min = {p: tenths(ph.min_green) for p, ph in config.phases.items()}
        self._max = {p: tenths(ph.max_green) for p, ph in config.phases.items()}
        self._length = {p: {Interval.YELLOW: tenths(ph.yellow), Interval.RED_CLEAR: tenths(ph.red_clear)}
                        for p, ph in config.phases.items()}
        self._barrier = {p: config.barrier_of(p) for p in config.phases}
        self._order = {p: ring.index(p) for ring in config.rings for p in ring}
        self.backup_time = config.middleware.backup_time
        self.pattern = 254  # free
        self.reset()

    # --- lifecycle -------------------------------------------------------------------

    def reset(self) -> None:
        """Power-up: start-up intervals, control objects cleared, not under system control."""
        self.tick = 0
        self.control: dict[ControlColumn, frozenset[int]] = {c: frozenset() for c in ControlColumn}
        self.control_status = UnitControlStatus.OTHER
        self.flash_status = UnitFlashStatus.NOT_FLASH
        self._calls_key: tuple[frozenset[int], frozenset[int]] | None = None
        self._calls: frozenset[int] = frozenset()
        self._changed = True
        self._quiet: tuple[frozenset[int], ...] | None = None
        self._since_set: int | None = None  # ticks since the last control SET; None = backup timer disarmed
        self.rings = [Ring(i + 1, order) for i, order in enumerate(self.config.rings)]
        started = [p for p, ph in self.config.phases.items() if ph.startup in _STARTUP_INTERVAL]
        self.group = self._barrier[started[0]] if started else 0
        for p in started:
            ring = self.rings[self.config.ring_of(p) - 1]
            ring.phase, ring.last, ring.interval = p, p, _STARTUP_INTERVAL[self.config.phases[p].startup]
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

    # --- control objects ----------------------------------------------------------------

    def set_control(self, column: ControlColumn, phases: Iterable[int]) -> None:
        """A SET of one control object: replaces its phases and restarts the backup timer."""
        self.control[column] = frozenset(phases)
        self._since_set = 0
        if self.control_status is not UnitControlStatus.SYSTEM_CONTROL:
            self.control_status = UnitControlStatus.SYSTEM_CONTROL

    @property
    def calls(self) -> frozenset[int]:
        """Vehicle calls the controller acts on: called, configured and not omitted."""
        return self.control[ControlColumn.VEH_CALL].intersection(self.config.phases) - self.control[
            ControlColumn.PHASE_OMIT]

    # --- status -------------------------------------------------------------------------

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
                if r.interval is not Interval.DWELL:
                    ons.add(r.phase)
        self.greens = frozenset(greens)
        self.yellows = frozenset(yellows)
        self.phase_ons = frozenset(ons)
        self.reds = frozenset(self.config.phases) - self.greens - self.yellows

    @property
    def phase_nexts(self) -> frozenset[int]:
        """The phase each clearing ring will serve next, as the calls stand now."""
        if self.flashing:
            return frozenset()  # a flashing controller times nothing, so nothing comes next
        calls = self.calls
        out = set()
        for r in self.rings:
            if r.interval in (Interval.YELLOW, Interval.RED_CLEAR):
                nxt = self._candidate(r, calls) or next(
                    (p for g in self._groups_after() for p in r.order if self._barrier[p] == g and p in calls), None)
                if nxt is not None:
                    out.add(nxt)
        return frozenset(out)

    # --- the tick -------------------------------------------------------------------------

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
            return
        blocked = self._blocked(calls)
        for r in self.rings:
            self._time(r, calls, blocked)
        for r in self.rings:
            if r.interval is Interval.DWELL and (p := self._candidate(r, calls)) is not None:
                self._start(r, p)
        if all(r.interval is Interval.DWELL for r in self.rings):
            self._cross(calls)
        changed, self._changed = self._changed, False
        if changed:
            self._refresh_status()
            self._monitor()
        # Quiet: every ring rests (green without conflicting demand, or dwelling with nothing to start).
        resting = all(r.interval is Interval.DWELL or (r.interval is Interval.GREEN and not r.max_ticks)
                      for r in self.rings)
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

    def _blocked(self, calls: frozenset[int]) -> set[int]:
        """Calls that cannot be served in this visit of the barrier group."""
        out = set()
        for q in calls:
            ring = self.rings[self.config.ring_of(q) - 1]
            if self._barrier[q] != self.group:
                out.add(q)
            elif ring.interval is Interval.GREEN and ring.phase == q:
                continue
            elif ring.last is not None and self._order[q] <= self._order[ring.last]:
                out.add(q)
        return out

    def _time(self, r: Ring, calls: frozenset[int], blocked: set[int]) -> None:
        if r.interval is Interval.DWELL:
            return
        r.ticks += 1
        p = r.phase
        if r.interval is Interval.GREEN:
            conflict = any(q != p and (q in blocked or self.config.ring_of(q) == r.number) for q in calls)
            r.max_ticks = r.max_ticks + 1 if conflict else 0
            if conflict and r.ticks >= self._min[p] and p not in self.control[ControlColumn.HOLD] and (
                    p not in calls or r.max_ticks >= self._max[p] or p in self.control[ControlColumn.FORCE_OFF]):
                self.control[ControlColumn.FORCE_OFF] -= {p}
                self._enter(r, Interval.YELLOW)
        elif r.ticks >= self._length[p][r.interval]:
            self._enter(r, _NEXT[r.interval])

    def _enter(self, r: Ring, interval: Interval) -> None:
        r.interval, r.ticks, r.max_ticks = interval, 0, 0
        self._changed = True
        if self.on_change is not None:
            self.on_change(Change(self.tick, r.number, r.phase, interval))

    def _candidate(self, r: Ring, calls: frozenset[int]) -> int | None:
        """Next called phase of the ring in this group visit, later in sequence than the last one."""
        after = -1 if r.last is None else self._order[r.last]
        return next((p for p in r.order if p in calls and self._barrier[p] == self.group
                     and self._order[p] > after), None)

    def _start(self, r: Ring, phase: int) -> None:
        r.phase = r.last = phase
        self._enter(r, Interval.GREEN)

    def _groups_after(self) -> list[int]:
        n = len(self.config.barriers)
        return [(self.group + k) % n for k in range(1, n + 1)]

    def _cross(self, calls: frozenset[int]) -> None:
        target = next((g for g in self._groups_after() if any(self._barrier[q] == g for q in calls)), None)
        if target is None:
            return
        self.group = target
        for r in self.rings:
            r.last = None
            if (p := self._candidate(r, calls)) is not None:
                self._start(r, p)

    def _monitor(self) -> None:
        shown = sorted(self.greens | self.yellows)
        for i, a in enumerate(shown):
            for b in shown[i + 1:]:
                if not self.config.compatible(a, b):
                    log.error("conflict monitor: phases %d and %d shown together at tick %d: flash", a, b, self.tick)
                    self.flash_status = UnitFlashStatus.MMU
                    self._refresh_status()
                    return
