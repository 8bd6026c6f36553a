"""Overlaps: signal outputs driven by their included (parent) phases, ticking with the controller.

Rules of this file
------------------
- An overlap's display changes only by ``_NEXT`` below: per display, the first condition that holds gives the
  next display (the same one: it stays). :meth:`Overlaps.step` evaluates them once per controller tick, after
  the rings have timed, from what the phases show then.
- Time is integer ticks, as in the controller; only the overlap's own trailing intervals count ticks.
- An overlap turns green only from red, from its trailing green, (a flashing yellow arrow) from flashing or (a
  transit bar) from its flashing green: never from a yellow.

Theory of operation
-------------------
NTCIP 1202 v02 overlapType (A.9.2.1.2) defines the two standard types:

    normal: "The overlap output shall be green in the following situations: (1) when an overlap included
    phase is green. (2) when an overlap included phase is yellow (or red clearance) and an overlap included
    phase is next. The overlap output shall be yellow when an included phase is yellow and an overlap included
    phase is not next. The overlap output shall be red whenever the overlap green and yellow are not ON."

    minusGreenYellow: green as normal "and an overlap modifier phase is NOT green"; yellow "when an overlap
    included phase is yellow and an overlap modifier phase is NOT yellow and an overlap included phase is not
    next".

"Next" is read per ring: a phase clearing (or dwelling in red) whose ring has committed an included phase
(phaseStatusGroupPhaseNexts) keeps a green overlap green, which is the standard's "the CU is cycling between
included phases" (overlapIncludedPhases); it never starts a green before an included phase shows one. An
overlap that was held red by its modifier does not turn yellow when its included phase clears: a yellow
follows a green.

Never green to red. The standard's rules read alone allow two displays no signal may show, and a signal
monitor faults a channel that skips its yellow (NEMA TS 2's MMU: "Minimum Yellow Change Interval"
monitoring). Where they would, the overlap times a yellow of its own (overlapTrailYellow, 3.0 s at least)
and its trailing red, and the phase that ends its green waits for that clearance, as a conflicting phase
waits for a trailing overlap (:meth:`Overlaps.blocks`):

- A minus-green-yellow overlap whose modifier is to start beside a green included phase: read literally, it
  goes from green to red the tick the modifier turns green. Here it clears once the modifier is committed
  next (phaseStatusGroupPhaseNexts), and the modifier waits for it; it stays red while the modifier is green.
- A green overlap whose included phase's clearance loses its included next (a ``red_end`` redirect or a
  preempt commits another phase): it times its own yellow. It follows its parent's yellow only from that
  yellow's first tick, so that yellow is never a remnant of the parent's.

overlapTrailGreen: "When this value is greater than zero and the overlap green would normally terminate, the
overlap green shall be extended by this additional time", followed by the overlap's own overlapTrailYellow and
overlapTrailRed. A trailing overlap shows beyond its parents, so a phase that conflicts with it (see
:meth:`hils.protocol.config.IntersectionConfig.overlap_allows`) may not start until it has cleared: the default of
controllers whose "Lock Inhibit" is off, which "insures that the overlap clearance has completed before the
next eligible phase is serviced" (Naztec overlap programming, MM 1-5-1). Without a trailing green the overlap
clears with its parent's yellow and is red during its parent's red clearance.

A transit bar (``transit``) is NTCIP 1202 v03's transit-2: "The overlap output drives a 2-section bar signal for
transit vehicles using overlap green (vertical bar) and red (horizontal bar) outputs. The overlap output shall be
green ... when an overlap included phase is green. The overlap output shall be flashing green when an overlap
included phase is yellow and an overlap included phase is not next. The overlap output shall be red whenever an
overlap included phase is red." It has no yellow lamp, so it goes from (flashing) green to red, the one overlap
that does (a log shows it: MaxTime 1015's overlaps A and B log begin green, 61, then red, 64, never a yellow); its
flashing green is its green output, flashing, and the monitor does not time a yellow on its channel (an MMU's
"Minimum Yellow Change Disable" jumper for that channel, Reno A&E MMU2-1600GE operations manual). It has neither
modifiers nor a trailing green.

A delayed green (``delay_green``): the overlap stays red so long after an included phase's green starts, then turns
green if an included phase still holds it (it goes back to red at once otherwise), as a controller holds a signal
"gaining ROW ... at red ... for the delay period" (Siemens T400 facilities manual, 8.3 phase delays; Naztec's
overlaps have their "FYA Delay Time"). MaxTime 1015's log shows one: its overlaps G and H begin green 3.0 s after
phases 4 and 8, 17 times in 18. No NTCIP 1202 object carries it. While it delays, the overlap is red but not at
rest: a phase that conflicts with it waits, as for a trailing overlap.

The flashing yellow arrow (``fya``) is not in NTCIP 1202 v02 (a vendor's overlapType other(1) there); its
v03 objects were found in no source we could read, so its status is served with the v02 objects: the arrow's
yellow lamp sets the overlap's yellow bit, steady or flashing. It follows the practice the sources agree on:
the arrow is green with its protected (included) phases, flashes while a modifier phase is green -- the
permissive phase is "tied to the opposing through movement" (UDOT's traffic-signal guidelines), "NOT the
straight ahead phase for the same approach" -- and shows a steady yellow arrow when the protected phase
clears or when the opposing through clears, red otherwise. From flashing it may go straight to the green
arrow when the protected phase starts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum, StrEnum

from emulator.model.ring import GREEN, YELLOW, Ring
from hils.protocol.config import IntersectionConfig, Overlap, OverlapKind


class Show(StrEnum):
    """What an overlap displays; the TRAIL_ intervals are its own, timed after its parents ended."""

    RED = "red"
    GREEN = "green"
    YELLOW = "yellow"  # clearing with a parent's yellow
    FLASHING = "flashing"  # a flashing yellow arrow's permissive indication
    FLASHING_GREEN = "flashing_green"  # a transit bar's green, flashing while its included phase clears
    TRAIL_GREEN = "trail_green"
    TRAIL_YELLOW = "trail_yellow"
    TRAIL_RED = "trail_red"
    DELAYED = "delayed"  # red, timing the delay of its green (delay_green)


class Cond(Enum):
    """What decides an overlap's next display (see ``_NEXT``)."""

    HELD = "its included phases hold it green (and no modifier of a minus-green-yellow overlap is green or next)"
    DELAYS = "its included phases hold it green and it has a delayed green"
    RELEASED = "its included phases no longer hold it green"
    FLASH = "a flashing yellow arrow's permissive (modifier) phase is green"
    MODIFIED = "a minus-green-yellow overlap's modifier phase is green or committed next"
    TRAILS = "it has a trailing green (a transit bar has none)"
    BAR_CLEARING = "it is a transit bar and one of its included phases is yellow"
    BAR = "it is a transit bar (it has no yellow lamp)"
    CLEARS = "the yellow of a phase it follows starts now (and no modifier of a minus-green-yellow overlap is yellow)"
    CLEARING = "a phase it follows is yellow (and no modifier of a minus-green-yellow overlap is)"
    TIMED = "its trailing interval has run its length"
    ALWAYS = "otherwise"


_NEXT: dict[Show, tuple[tuple[Cond, Show], ...]] = {
    Show.RED: ((Cond.DELAYS, Show.DELAYED), (Cond.HELD, Show.GREEN), (Cond.FLASH, Show.FLASHING),
               (Cond.ALWAYS, Show.RED)),
    Show.DELAYED: ((Cond.RELEASED, Show.RED), (Cond.TIMED, Show.GREEN), (Cond.ALWAYS, Show.DELAYED)),
    Show.GREEN: ((Cond.HELD, Show.GREEN), (Cond.MODIFIED, Show.TRAIL_YELLOW), (Cond.TRAILS, Show.TRAIL_GREEN),
                 (Cond.BAR_CLEARING, Show.FLASHING_GREEN), (Cond.BAR, Show.RED), (Cond.CLEARS, Show.YELLOW),
                 (Cond.ALWAYS, Show.TRAIL_YELLOW)),
    Show.FLASHING_GREEN: ((Cond.HELD, Show.GREEN), (Cond.CLEARING, Show.FLASHING_GREEN), (Cond.ALWAYS, Show.RED)),
    Show.FLASHING: ((Cond.HELD, Show.GREEN), (Cond.FLASH, Show.FLASHING), (Cond.CLEARING, Show.YELLOW),
                    (Cond.ALWAYS, Show.RED)),
    Show.YELLOW: ((Cond.CLEARING, Show.YELLOW), (Cond.ALWAYS, Show.RED)),
    Show.TRAIL_GREEN: ((Cond.HELD, Show.GREEN), (Cond.MODIFIED, Show.TRAIL_YELLOW), (Cond.TIMED, Show.TRAIL_YELLOW),
                       (Cond.ALWAYS, Show.TRAIL_GREEN)),
    Show.TRAIL_YELLOW: ((Cond.TIMED, Show.TRAIL_RED), (Cond.ALWAYS, Show.TRAIL_YELLOW)),
    Show.TRAIL_RED: ((Cond.TIMED, Show.RED), (Cond.ALWAYS, Show.TRAIL_RED)),
}

_GREEN = frozenset({Show.GREEN, Show.TRAIL_GREEN, Show.FLASHING_GREEN})
_YELLOW = frozenset({Show.YELLOW, Show.TRAIL_YELLOW, Show.FLASHING})
#: Displays that outlast the overlap's parents: a phase conflicting with the overlap waits for them to end.
TRAILING = frozenset({Show.TRAIL_GREEN, Show.TRAIL_YELLOW, Show.TRAIL_RED})
#: Displays the overlap times with its own timer: the trailing ones and a delayed green's red.
TIMED = TRAILING | {Show.DELAYED}


@dataclass(frozen=True, slots=True)
class Phases:
    """What the phases show as the overlaps step: each ring's phase once it has timed this tick."""

    greens: frozenset[int]
    yellows: frozenset[int]
    starting: frozenset[int]  # phases whose yellow starts this tick
    nexts: Mapping[int, int | None]  # each phase clearing or resting in red: its ring's committed next phase
    committed: frozenset[int]  # every ring's committed next phase (phaseStatusGroupPhaseNexts)

    @classmethod
    def of(cls, rings: Sequence[Ring], *, later: bool = False) -> Phases:
        """What ``rings`` show now; ``later``: at a later tick if none of them moves (no yellow starts then)."""
        return cls(
            greens=frozenset(r.phase for r in rings if r.interval is GREEN),
            yellows=frozenset(r.phase for r in rings if r.interval is YELLOW),
            starting=frozenset() if later else frozenset(r.phase for r in rings
                                                         if r.interval is YELLOW and r.ticks == 0),
            nexts={r.phase: r.target for r in rings if r.interval is not GREEN and r.phase is not None},
            committed=frozenset(r.target for r in rings if r.target is not None))


@dataclass(slots=True)
class OverlapTiming:
    """An overlap's trailing times in ticks; mutable so the overlap table can be retimed over SNMP."""

    trail_green: int
    trail_yellow: int
    trail_red: int
    delay_green: int

    @classmethod
    def of(cls, o: Overlap) -> OverlapTiming:
        return cls(o.trail_green * 10, round(o.trail_yellow * 10), round(o.trail_red * 10), round(o.delay_green * 10))


class Overlaps:
    """The overlaps of one controller: their displays, trailing timers and status sets."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.config = config
        self.timing = {n: OverlapTiming.of(o) for n, o in config.overlaps.items()}
        #: Per overlap, the phases that may not start while it shows: those that may not be lit beside it (what
        #: the monitor checks), and a minus-green-yellow overlap's modifiers (it clears before they start: see
        #: "Never green to red").
        conflicting = config.permissives.overlaps
        self.waiting = {n: conflicting[n] | frozenset(o.modifiers if o.kind is OverlapKind.MINUS_GREEN_YELLOW
                                                      else ()) for n, o in config.overlaps.items()}
        self.reset()

    def reset(self) -> None:
        """Power-up (and flash): every overlap red."""
        self.shown = {n: Show.RED for n in self.config.overlaps}
        self.ticks = {n: 0 for n in self.config.overlaps}

    @property
    def greens(self) -> frozenset[int]:
        return frozenset(n for n, s in self.shown.items() if s in _GREEN)

    @property
    def yellows(self) -> frozenset[int]:
        return frozenset(n for n, s in self.shown.items() if s in _YELLOW)

    @property
    def reds(self) -> frozenset[int]:
        return frozenset(self.shown) - self.greens - self.yellows

    @property
    def flashing(self) -> frozenset[int]:
        return frozenset(n for n, s in self.shown.items() if s is Show.FLASHING)

    def discrete(self) -> tuple[Show, ...]:
        return tuple(self.shown.values())

    def blocks(self, phase: int, phases: Phases) -> bool:
        """``phase`` may not start this tick: an overlap it waits for will not show red after this tick's step.
        Asked before the overlaps step, with what the phases show then: starting ``phase`` cannot hold such an
        overlap green (it is none of its parents), so the answer stands once the phase has started."""
        return any(phase in self.waiting[n] and self._after(n, phases)[0] is not Show.RED for n in self.shown)

    def step(self, phases: Phases) -> None:
        """One tick, after the rings have timed: each overlap follows what the phases show now."""
        for n, s in self.shown.items():
            to, ticks = self._after(n, phases)
            self.shown[n], self.ticks[n] = to, ticks if to is s else 0

    def _after(self, n: int, phases: Phases) -> tuple[Show, int]:
        """What overlap ``n`` shows once this tick's step has run, and the ticks its trailing interval then has
        timed (one more than now)."""
        s = self.shown[n]
        ticks = self.ticks[n] + (s in TIMED)
        to = next(to for cond, to in _NEXT[s] if self._holds(cond, n, phases, ticks))
        # A trailing red of no length is no interval at all: the overlap is red at once.
        return (Show.RED if to is Show.TRAIL_RED and self.timing[n].trail_red == 0 else to), ticks

    def _holds(self, cond: Cond, n: int, phases: Phases, ticks: int) -> bool:
        o = self.config.overlaps[n]
        minus = o.kind is OverlapKind.MINUS_GREEN_YELLOW
        greens, yellows = phases.greens, phases.yellows
        if cond is Cond.HELD:
            # Cycling between included phases keeps a green; it does not start one (a ring resting in red that
            # commits its own included phase again shows nothing green yet).
            nexts = phases.nexts
            cycling = self.shown[n] in _GREEN and any(p in o.included and nexts.get(p) in o.included for p in nexts)
            return (cycling or not greens.isdisjoint(o.included)) and not self._holds(Cond.MODIFIED, n, phases, ticks)
        if cond is Cond.DELAYS:
            return self.timing[n].delay_green > 0 and self._holds(Cond.HELD, n, phases, ticks)
        if cond is Cond.RELEASED:
            return not self._holds(Cond.HELD, n, phases, ticks)
        if cond is Cond.FLASH:
            return o.kind is OverlapKind.FYA and not greens.isdisjoint(o.modifiers)
        if cond is Cond.MODIFIED:
            return minus and not (greens | phases.committed).isdisjoint(o.modifiers)
        if cond is Cond.TRAILS:
            return self.timing[n].trail_green > 0 and o.kind is not OverlapKind.TRANSIT
        if cond is Cond.BAR:
            return o.kind is OverlapKind.TRANSIT
        if cond is Cond.BAR_CLEARING:
            # "flashing green when an overlap included phase is yellow and an overlap included phase is not next"
            return o.kind is OverlapKind.TRANSIT and not phases.yellows.isdisjoint(o.included)
        if cond in (Cond.CLEARS, Cond.CLEARING):
            followed = o.included + o.modifiers if o.kind is OverlapKind.FYA else o.included
            clearing = phases.starting if cond is Cond.CLEARS else yellows
            return not clearing.isdisjoint(followed) and not (minus and not yellows.isdisjoint(o.modifiers))
        if cond is Cond.TIMED:
            return ticks >= self._length(n, self.shown[n])
        return True

    def _length(self, n: int, s: Show) -> int:
        tm = self.timing[n]
        return {Show.TRAIL_GREEN: tm.trail_green, Show.TRAIL_YELLOW: tm.trail_yellow, Show.TRAIL_RED: tm.trail_red,
                Show.DELAYED: tm.delay_green}[s]

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def deadline(self, phases: Phases) -> int | None:
        """Steps until an overlap's display changes, the phases showing ``phases`` (None: none will): 1 when one
        follows them at the next step, else when a trailing interval ends."""
        ahead = []
        for n, s in self.shown.items():
            if self._after(n, phases)[0] is not s:
                return 1
            if s in TIMED:
                ahead.append(self._length(n, s) - self.ticks[n])
        return min(ahead, default=None)

    def skip(self, n: int) -> None:
        for k, s in self.shown.items():
            if s in TIMED:
                self.ticks[k] += n
