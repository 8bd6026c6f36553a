"""When each signal next changes: the controller's timing, as a signal phase and timing (SPaT) message gives it.

Rules of this file
------------------
- It reads the units and never acts: :func:`announce`, asked between two ticks, gives per phase and overlap its
  indication and, in ticks from now, the earliest tick it can change, the latest and the likely one.
- A bound is given only where the model's own rules make it firm, whatever the inputs do from now on (calls,
  holds, force-offs, omits, detectors, patterns, preempts, the backup timer): only a power cycle, a retiming of
  the phase table (it acts from the phase's next interval) or a fault the monitor finds can break it. Where no
  bound can be known it is None, as SAE J2735's TimeMark has "unknown" (36001 on the wire).
- A property test holds it to the truth: over random configs and inputs every change of a signal happens within
  every bound announced since its last change (tests/emulator/model/test_spat.py).

Theory of operation
-------------------
SAE J2735's SPaT gives, per signal group, its movement state and TimeChangeDetails: minEndTime (the earliest the
state can end), maxEndTime (the latest) and likelyTime, in tenths of a second of the hour; NTCIP 1202 v03 counts
the controller's time in that base (ascCurrentTick, 0-36000). Here they are ticks from now; the field side adds
the clock. The NTCIP 1202 v03 MIB text kept in harness/reference/ntcip_mib/ has no per-phase timing object: SPaT
output is built on these figures.

The bounds, from the model's rules:

- *A green* ends no sooner than its minimum (the sequencer ends a green only once it has timed it), or, when a
  preempt is configured, the least that preempt's entry may cut it to (the lesser of the phase's and the
  preempt's minimum green) or, for a track phase, its track green. It has no latest: a hold, a call coming back or
  no conflicting demand keeps it. Its likely end is its maximum while the maximum timer runs.
- *A yellow* ends after its length, or sooner when a preempt's entry or track clearance caps it; nothing lengthens
  it, so its latest is its length.
- *A red phase* turns green no sooner than its ring has ended what it shows and cleared it (the next yellow and red
  clearance, each at the least a preempt may cap it to); a ring resting in red may start it at the next tick. Its
  latest is unknown (the other ring at the barrier, red revert, demand).
- *In flash* every signal is red: the start-up flash ends at a known tick; a monitor's flash lasts until a power
  cycle (no change announced: earliest None).
- *An overlap* follows its parents and its trailing intervals: its next change may come at the next tick, its
  latest is unknown.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

from emulator.model.ring import DWELL, GREEN, YELLOW, Ring
from hils.protocol.ntcip import UnitFlashStatus

if TYPE_CHECKING:
    from emulator.model.controller import Controller


class Indication(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED = "red"


@dataclass(frozen=True, slots=True)
class SignalTiming:
    """One signal's indication and the ticks from now of its next change: earliest (None: none coming), latest
    and likely (None: unknown)."""

    kind: str  # "phase" or "overlap"
    number: int
    indication: Indication
    earliest: int | None
    latest: int | None
    likely: int | None


def announce(c: Controller) -> tuple[SignalTiming, ...]:
    """Every phase's and overlap's timing, as the controller stands between two ticks."""
    if c.flashing:
        until = c.startup_flash * 10 - c.tick if c.flash_status is UnitFlashStatus.STARTUP else None
        until = None if until is None else max(1, until)
        return tuple(SignalTiming(kind, n, Indication.RED, until, None, until)
                     for kind, numbers in (("phase", c.config.phases), ("overlap", c.config.overlaps))
                     for n in sorted(numbers))
    bounds = _Bounds(c)
    out = []
    for p in sorted(c.config.phases):
        r = c.rings[c.config.ring_of(p) - 1]
        if r.phase == p and r.interval is GREEN:
            earliest = bounds.green_end(r)
            likely = max(earliest, r.maximum - r.max_ticks) if r.max_ticks else None
            out.append(SignalTiming("phase", p, Indication.GREEN, earliest, None, likely))
        elif r.phase == p and r.interval is YELLOW:
            left = max(1, r.length - r.ticks)
            out.append(SignalTiming("phase", p, Indication.YELLOW, bounds.clearance_end(r), left, left))
        else:
            out.append(SignalTiming("phase", p, Indication.RED, bounds.cleared(r), None, None))
    for n in sorted(c.config.overlaps):
        shown = (Indication.GREEN if n in c.overlap_greens else Indication.YELLOW if n in c.overlap_yellows
                 else Indication.RED)
        out.append(SignalTiming("overlap", n, shown, 1, None, None))
    return tuple(out)


class _Bounds:
    """The least a preempt may cut each timer to, for one announcement."""

    def __init__(self, c: Controller) -> None:
        self.c = c
        timings = list(c.preemptor.timing.values())
        self.min_green = min((tm.min_green for tm in timings), default=None)
        self.yellow = min((min(tm.enter_yellow, tm.track_yellow) for tm in timings), default=None)
        self.red = min((min(tm.enter_red, tm.track_red) for tm in timings), default=None)
        self.track = {}
        for n, tm in c.preemptor.timing.items():
            for q in c.config.preempts[n].track_phases if tm.track_green else ():
                self.track[q] = min(self.track.get(q, tm.track_green), tm.track_green)

    def green_end(self, r: Ring) -> int:
        """Ticks from now to the soonest the ring's green may end (its yellow shows)."""
        floor = r.minimum
        if self.min_green is not None:
            floor = min(floor, self.c.timing[r.phase].min_green, self.min_green)
        floor = min(floor, self.track.get(r.phase, floor))
        return max(1, floor - r.ticks)

    def clearance_end(self, r: Ring) -> int:
        """Ticks from now to the soonest the ring's running clearance interval may end."""
        cap = self.yellow if r.interval is YELLOW else self.red
        length = r.length if cap is None else min(r.length, cap)
        return max(1, length - r.ticks)

    def _least(self, length: int, cap: int | None) -> int:
        return length if cap is None else min(length, cap)

    def cleared(self, r: Ring) -> int:
        """Ticks from now to the soonest the ring may start a phase: what it shows ended and cleared."""
        if r.interval is DWELL:
            return 1
        timing = self.c.timing[r.phase]
        red = self._least(timing.red_clear, self.red)
        if r.interval is GREEN:
            return self.green_end(r) + max(1, self._least(timing.yellow, self.yellow)) + red
        if r.interval is YELLOW:
            return self.clearance_end(r) + red
        return self.clearance_end(r)
