"""When each signal next changes: the controller's timing, as a signal phase and timing (SPaT) message gives it.

Rules of this file
------------------
- It reads the units and never acts: :func:`announce`, asked between two ticks, gives per phase and overlap its
  indication and, in ticks from now, the earliest tick it can change, the latest and the likely one.
- The *earliest* is firm whatever the inputs do from now on (calls, holds, force-offs, omits, detectors, patterns,
  preempts, the backup timer): only a power cycle, a retiming of the phase table (it acts from the phase's next
  interval) or a fault the monitor finds can break it.
- The *latest* is firm while the inputs stand as they are when it is announced (no SET, detector or push button
  changes them): then the controller's own timers decide, as a real controller's SPaT assumes when it announces
  a green's maximum. An input may move it (a hold keeps a green, a call withdrawn lets it rest), and the next
  announcement says so. It is None where nothing bounds the change as things stand: a green held; a green with no
  conflicting demand (it rests); a coordinated phase (it rests to its yield point and leaves it only in a
  permissive period); a ring whose next service is not known yet (it waits at the barrier for a ring that serves
  another phase first, or that may still back into an earlier phase by conditional service); a preempt called or
  served (its track and dwell phases stay green as its input says); a transition to a new offset or pattern under
  way; the backup time passing with a control object set, a
  time-of-day change, or a detector's delay, extension or carryover running out, before the bound; a red phase an
  overlap or an omit may hold back.
- Where no bound can be known it is None, as SAE J2735's TimeMark has "unknown" (36001 on the wire).
- A property test holds it to the truth: over random configs and inputs every change of a signal happens after
  every earliest announced since its last change, and by every latest announced since its last change and the
  last input (tests/emulator/model/test_spat.py).

Theory of operation
-------------------
SAE J2735's SPaT gives, per signal group, its movement state and TimeChangeDetails: minEndTime (the earliest the
state can end), maxEndTime (the latest) and likelyTime, in tenths of a second of the hour; NTCIP 1202 v03 counts
the controller's time in that base (ascCurrentTick, 0-36000). Here they are ticks from now; the field side adds
the clock.

The earliest, from the model's rules:

- *A green* ends no sooner than its minimum (the sequencer ends a green only once it has timed it), or, when a
  preempt is configured, the least that preempt's entry may cut it to (the lesser of the phase's and the
  preempt's minimum green) or, for a track phase, its track green.
- *A yellow* ends after its length, or sooner when a preempt's entry or track clearance caps it.
- *A red phase* turns green no sooner than its ring has ended what it shows and cleared it (the next yellow and red
  clearance, each at the least a preempt may cap it to); a ring resting in red may start it at the next tick.

The latest, from the units' timers (:meth:`emulator.model.sequencer.Sequencer.ending` says when a green is ready
to end, :meth:`~emulator.model.sequencer.Sequencer.decide` where it goes):

- *A green* is ready to end by its minimum and then, free, its maximum timer (Maximum 1 or 2, as the green
  started with it), which runs while conflicting demand waits (NTCIP 1202 phaseMaximum1: "the maximum length of
  time this phase may be held in Green in the presence of a serviceable conflicting call"); under a pattern, its
  force-off point (the local timer passing it, one tick a tick while no transition runs) or its floating limit;
  a ForceOff bit makes it ready at its minimum. A ready green whose ring goes on within the barrier group ends at
  once; one whose ring goes across ends when every ring is ready to cross (the latest of their ready times).
- *A yellow* ends after its length (nothing lengthens it).
- *A red phase* committed as its ring's next starts once that ring and every ring across the barrier have cleared
  and its red revert has passed; free, a phase its ring will commit when its green ends (its wish, the demand
  standing) likewise after that green's latest end and its yellow and red clearance.
- *In flash* every signal is red: the start-up flash ends at a known tick (a phase with a lit start-up interval
  changes then); a monitor's flash lasts until a power cycle (no change announced: earliest None).
- *An overlap* follows its parents (:mod:`emulator.model.overlaps`): a normal overlap's green ends once every green
  parent has ended and its trailing green has run, its yellow with its parents' yellows, and it turns green with
  its first parent; its latest is its one green parent's when its parents are all of one ring and that ring goes
  to a phase it does not include. Its own trailing yellow ends after its length; a delayed green starts its delay
  later and ends with it, and the delay's end is a latest only from an included phase whose green is sure to
  outlast it (released sooner, the overlap stays red); a transit bar's green (flashing through its phase's yellow)
  has no latest end. A minus-green-yellow overlap's modifiers and a flashing yellow arrow's permissive phase may
  change it at the next tick.

The likely time is the latest where one is known: what the timers give when the demand stands (an actuated
green maxes out, a forced green ends at its force-off point); a gap in traffic ends a green sooner. Where no latest
is known, a green whose maximum timer runs is likely to end at its maximum; anything else has no likely time.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

from emulator.model import inputs as reading
from emulator.model.overlaps import TRAILING, Show
from emulator.model.ring import DWELL, GREEN, RED_CLEAR, STARTUP, YELLOW, Event, Ring
from hils.protocol.config import NextPhaseLock, Overlap, OverlapKind
from hils.protocol.ntcip import ControlColumn, PreemptState, UnitFlashStatus

if TYPE_CHECKING:
    from emulator.model.controller import Controller


#: The start-up intervals a phase leaves the start-up flash lit in (a red clearance shows red: no change).
_STARTS_LIT = frozenset(k for k, event in STARTUP.items() if event is not Event.STARTUP_RED)


class Indication(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED = "red"


@dataclass(frozen=True, slots=True)
class SignalTiming:
    """One signal's indication and the ticks from now of its next change: earliest (None: none coming), latest
    and likely (None: unknown); and the ticks since its indication began (None: unknown), SPaT's startTime."""

    kind: str  # "phase" or "overlap"
    number: int
    indication: Indication
    earliest: int | None
    latest: int | None
    likely: int | None
    started: int | None = None


def announce(c: Controller) -> tuple[SignalTiming, ...]:
    """Every phase's and overlap's timing, as the controller stands between two ticks."""
    if c.flashing:
        return _flash(c)
    bounds = _Bounds(c)
    phases = {p: bounds.phase(p) for p in sorted(c.config.phases)}
    overlaps = [bounds.overlap(n, phases) for n in sorted(c.config.overlaps)]
    return (*phases.values(), *overlaps)


def _flash(c: Controller) -> tuple[SignalTiming, ...]:
    """In flash every signal is red: the start-up flash ends at a known tick, when the phases with a start-up
    interval start in it (the others stay red: no change announced for them); a monitor's flash lasts until a
    power cycle."""
    until = max(1, c.startup_flash * 10 - c.tick) if c.flash_status is UnitFlashStatus.STARTUP else None
    starting = {p for p, ph in c.config.phases.items() if ph.startup in _STARTS_LIT}
    since = c.tick if until is not None else None  # the start-up flash began at power-up
    out = [SignalTiming("phase", p, Indication.RED, until, until if p in starting else None, until, since)
           for p in sorted(c.config.phases)]
    out += [SignalTiming("overlap", n, Indication.RED, until, None, until, since) for n in sorted(c.config.overlaps)]
    return tuple(out)


def _followed(o: Overlap) -> tuple[int, ...]:
    """The phases an overlap follows: its included phases; a flashing yellow arrow's permissive (modifier) phases
    too (:mod:`emulator.model.overlaps`, ``Cond.CLEARING``)."""
    return o.included + o.modifiers if o.kind is OverlapKind.FYA else o.included


def _apart(c: Controller, included: tuple[int, ...], g: int) -> bool:
    """No included phase but ``g`` may show green or yellow while ``g``'s ring ends and clears it: each is of ``g``'s
    ring or of another barrier group (which starts only once every ring has cleared)."""
    ring, seq = c.config.ring_of(g), c.sequencer
    return all(q == g or c.config.ring_of(q) == ring or seq.barrier_of(q) != seq.barrier_of(g) for q in included)


class _Bounds:
    """The bounds of one announcement: the least a preempt may cut each timer to (the earliest), and where the
    inputs standing as they are make the controller's own timers decide (the latest)."""

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
        self.plan = c.coordinator.plan
        inputs = c.inputs
        self.inputs = inputs
        greens = frozenset(r.phase for r in c.rings if r.interval is GREEN)
        self.demand = reading.demand(inputs, c.peds.latched(greens, inputs))
        self.horizon = self._horizon()
        self.standing = self._standing()
        self.wish = {r.number: c.sequencer.wish(r, self.demand, inputs) for r in c.rings
                     if r.interval is GREEN or (r.interval is DWELL and r.target is None)} if self.standing else {}
        self.crossing = self._crossing() if self.standing else None
        self.ends = {r.number: self._end(r) for r in c.rings if r.interval is GREEN} if self.standing else {}

    # --- the earliest: firm whatever the inputs do -------------------------------------------------------

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

    # --- the latest: firm while the inputs stand --------------------------------------------------------

    def _horizon(self) -> int | None:
        """Ticks to the first thing the controller does by its own clock that may undo a latest: the backup time
        passing with a control object set (backup mode clears it: a call withdrawn lets a green rest), a
        time-of-day change of the local plan, a detector's timer changing what it recognizes (a delay running out
        places a call the standing demand lacks, an extension or carryover running out withdraws one)."""
        c = self.c
        ahead = []
        if c.detectors.timers:
            detectors = c.detectors.deadline(c.actuations, c.greens)
            if detectors is not None:
                ahead.append(detectors)
        backup = c.backup.deadline()
        if backup is not None and (any(c.control.values()) or c.coordinator.command):
            ahead.append(backup)
        if c.config.coordination.schedule:
            ahead.append(c.coordinator.until_schedule())
        return min(ahead, default=None)

    def _standing(self) -> bool:
        """A latest may be announced at all: no preempt called or served (it may keep a track or dwell phase
        green), no transition to a new offset under way (add, dwell and shortway move the force-off points), and
        in free operation the demand across the barrier as the last tick registered it (an input since is read
        at the next tick, whose announcement follows)."""
        c = self.c
        co, pe = c.coordinator, c.preemptor
        if co.called != co.running or co.replan:
            return False  # a pattern called (or retimed) starts at the next tick or the next local zero
        if pe.control or pe.serving is not None or any(s is not PreemptState.NOT_ACTIVE for s in pe.states.values()):
            return False
        if self.plan is not None:
            return not co.lag
        seq = c.sequencer
        return seq.waits_across(self.demand, self.inputs) == seq.waiting_across

    def _within(self, ticks: int | None) -> int | None:
        """``ticks``, unless the horizon comes first."""
        if ticks is None or (self.horizon is not None and ticks >= self.horizon):
            return None
        return ticks

    def _ready(self, r: Ring) -> int | None:
        """Ticks from now to the latest the ring's green is ready to end (:meth:`Sequencer.ending`), or None: held,
        or nothing bounds it (no conflicting demand in free operation; a coordinated phase, which rests to its
        yield point and leaves it only in a permissive period)."""
        c = self.c
        if r.phase in self.inputs.holds:
            return None
        least = max(1, r.minimum - r.ticks)
        if r.phase in c.control[ControlColumn.FORCE_OFF]:
            return least
        plan = self.plan
        if plan is None:
            # the maximum timer runs while conflicting demand waits, and times out at the maximum
            if not c.sequencer.conflicting(r, self.demand):
                return None
            return max(least, r.maximum - r.max_ticks)
        if r.phase in plan.coord.values():
            return None
        co, cd = c.coordinator, c.coordinated
        if cd.forced[r.number]:
            return least
        # the local timer passes the phase's force-off point, one tick a tick (no transition: see _standing)
        ahead = (plan.force_off[r.phase] - co.timer - 1) % plan.cycle + 1
        limit = cd.limit[r.number]
        if limit > 0:
            ahead = min(ahead, limit - r.ticks)
        return max(least, ahead)

    def _in_group(self, r: Ring) -> bool:
        """Whatever the ring wishes when its green is ready, it goes there at once, in its barrier group: free, its
        wish now (the demand standing, it stays) lies forward in the group; under a pattern, every phase from its
        own up to its coordinated phase does (the coordinated phase is always demand and always fits, so a wish
        that stops fitting falls on a later phase of the group)."""
        seq, q = self.c.sequencer, self.wish.get(r.number)
        if self.plan is None:
            if q is None or seq._beyond(q):
                return False
            # a backing waits while a ring wishes across: "crossing goes before backing" (Sequencer.decide)
            backing = r.order.index(q) < r.order.index(r.phase)
            return not backing or not any(w is not None and seq._beyond(w) for w in self.wish.values())
        coord = self.plan.coord[r.number]
        if coord in self.inputs.omits:
            return False  # not demand then: the ring's wish may fall across the barrier
        i, n = r.order.index(r.phase), len(r.order)
        ahead = [r.order[(i + k) % n] for k in range(1, n)]
        return coord in ahead and all(seq.barrier_of(q) == seq.group for q in ahead[:ahead.index(coord) + 1])

    def _crossing(self) -> int | None:
        """Ticks from now to the latest the rings cross the barrier together (:meth:`Sequencer.decide`): every ring
        ready and wishing across or nowhere, one wishing across. Known when each ring's green has a ready time and
        never wishes within the group (free: its wish now; under a pattern: its phase is the last of its group in
        its order), or the ring rests in red wanting nothing in the group (free)."""
        c, seq = self.c, self.c.sequencer
        times, across = [], False
        for o in c.rings:
            q = self.wish.get(o.number)
            if o.interval is GREEN:
                t = self._ready(o)
                if self.plan is None:
                    # a backing refused now may become conditional service once the green is ready to end
                    within = q is not None and (not seq._beyond(q) or (
                        c.config.phases[o.phase].conditional_service and seq._backing(o, q)))
                else:
                    nxt = o.order[(o.order.index(o.phase) + 1) % len(o.order)]
                    coord = self.plan.coord[o.number]
                    within = o.phase == coord or seq.barrier_of(coord) == seq.group or seq.barrier_of(nxt) == seq.group
                if t is None or within:
                    return None
                times.append(t)
            elif o.interval is DWELL and o.target is None and self.plan is None:
                if q is not None and not seq._beyond(q):
                    return None
            else:
                return None
            across |= q is not None and seq._beyond(q) if self.plan is None else True
        return max(times, default=None) if across else None

    def _end(self, r: Ring) -> int | None:
        """Ticks from now to the latest the ring's green ends (None: unbounded as things stand)."""
        if self._in_group(r):
            return self._within(self._ready(r))
        return self._within(self.crossing)

    def _start(self, p: int) -> int | None:
        """Ticks from now to the latest red phase ``p`` turns green: its ring has committed it (or, free, will
        commit it when its green ends), and the ring's clearance, the other rings' clearance across the barrier and
        the phase's red revert all end by then; None where an overlap may hold it back, it is omitted, or its ring's
        next service is not known."""
        c = self.c
        r = c.rings[c.config.ring_of(p) - 1]
        if not self.standing or p in self.inputs.omits:
            return None
        # the overlaps it waits for (Overlaps.blocks) must show red by then
        cleared = [self._overlap_red(n, p) for n in c.config.overlaps if p in c.overlaps.waiting[n]]
        if None in cleared:
            return None
        if self.plan is not None and c.config.next_phase_lock is NextPhaseLock.RED_END:
            return None  # a call in the clearance redirects the ring, to what still fits the pattern then
        timing = c.timing
        if r.target == p and r.interval in (YELLOW, RED_CLEAR, DWELL):
            seq = c.sequencer
            clear = [o.clearance_left(None if o.phase is None else timing[o.phase]) for o in c.rings
                     if o is r or (o.interval is not DWELL and seq.barrier_of(o.phase) != seq.barrier_of(p))]
            if any(o is not r and o.interval is GREEN and seq.barrier_of(o.phase) != seq.barrier_of(p)
                   for o in c.rings):
                return None  # a ring of the other group still green: the crossing is not yet committed
        elif r.interval is GREEN and self.plan is None and self.wish.get(r.number) == p:
            seq, end = c.sequencer, self.ends.get(r.number)
            crossing = seq._beyond(p)
            # crossing, the rings go to the other group of two: p is the ring's target there only if it lies there (a
            # backing refused while demand waits across is served at the group's next visit)
            if end is None or (crossing and (len(c.config.barriers) != 2 or seq.barrier_of(p) == seq.group)):
                return None
            # at the crossing every ring ends its green together; within the group only this one
            clear = [end + o.clearance_left(timing[o.phase]) for o in c.rings
                     if o is r or (crossing and o.interval is GREEN)]
        else:
            return None
        revert = r.yellow_end.get(p)
        if revert is not None:
            clear.append(revert + timing[p].red_revert - c.tick)
        return self._within(max(1, *clear, *cleared))

    def _overlap_red(self, n: int, p: int) -> int | None:
        """Ticks from now by which overlap ``n`` shows red (0: it does and stays so while ``p`` waits for it), from
        its trailing intervals or the one phase it follows that is lit; None: not known."""
        c, seq = self.c, self.c.sequencer
        show, ticks, trail, o = c.overlaps.shown[n], c.overlaps.ticks[n], c.overlaps.timing[n], c.config.overlaps[n]
        if show is Show.TRAIL_RED:
            return trail.trail_red - ticks
        if show is Show.TRAIL_YELLOW:
            return trail.trail_yellow - ticks + trail.trail_red
        if o.kind is OverlapKind.MINUS_GREEN_YELLOW or show is Show.TRAIL_GREEN or trail.trail_green:
            return None
        followed = _followed(o)
        ring = c.config.ring_of(p)
        # a phase it follows starting beside p (another ring, p's group) would light it first
        if not all(c.config.ring_of(q) == ring or seq.barrier_of(q) != seq.barrier_of(p) for q in followed):
            return None
        lit = [r for r in c.rings if r.phase in followed and r.interval in (GREEN, YELLOW)]
        if not lit:
            return 0 if show is Show.RED else None
        r = lit[0]
        if len(lit) > 1 or not _apart(self.c, followed, r.phase):
            return None
        if r.interval is YELLOW:
            return r.length - r.ticks  # it clears with that yellow
        end, q = self.ends.get(r.number), self.wish.get(r.number)
        if end is None or q is None or q in followed or self.plan is not None:
            return None
        return end + c.timing[r.phase].yellow

    # --- per signal ---------------------------------------------------------------------------------------

    def phase(self, p: int) -> SignalTiming:
        c = self.c
        r = c.rings[c.config.ring_of(p) - 1]
        if r.phase == p and r.interval is GREEN:
            earliest, latest = self.green_end(r), self.ends.get(r.number)
            likely = latest if latest is not None else max(earliest, r.maximum - r.max_ticks) if r.max_ticks else None
            return SignalTiming("phase", p, Indication.GREEN, earliest, latest, likely, r.ticks)
        if r.phase == p and r.interval is YELLOW:
            left = max(1, r.length - r.ticks)
            return SignalTiming("phase", p, Indication.YELLOW, self.clearance_end(r), left, left, r.ticks)
        latest = self._start(p)
        red_since = r.yellow_end.get(p)  # its red began as its last yellow ended (unknown if it never showed one)
        return SignalTiming("phase", p, Indication.RED, self.cleared(r), latest, latest,
                            None if red_since is None else c.tick - red_since)

    def overlap(self, n: int, phases: dict[int, SignalTiming]) -> SignalTiming:
        """An overlap's timing from the phases it follows (its own trailing intervals for any kind): green ends once
        every green included phase has ended (and its trailing green run); a flashing yellow arrow's flashing with
        its permissive phase's green and yellow; yellow once every yellow it follows has ended; red turns green (or
        flashing) with the first phase it follows that starts. A minus-green-yellow overlap's modifiers may change it
        at any tick: the next one is its earliest, its latest unknown."""
        c = self.c
        o, show, ticks = c.config.overlaps[n], c.overlaps.shown[n], c.overlaps.ticks[n]
        trail = c.overlaps.timing[n]
        shown = (Indication.GREEN if n in c.overlap_greens else Indication.YELLOW if n in c.overlap_yellows
                 else Indication.RED)
        earliest, latest = 1, None
        if show is Show.TRAIL_YELLOW:
            earliest = latest = max(1, trail.trail_yellow - ticks)
        elif o.kind is not OverlapKind.MINUS_GREEN_YELLOW:
            followed = _followed(o)
            if show is Show.GREEN:
                green = [phases[q] for q in o.included if phases[q].indication is Indication.GREEN]
                if green:
                    earliest = max(s.earliest for s in green) + trail.trail_green
                # a transit bar's green goes on, flashing, through its phase's yellow: its end is not the phase's
                if (len(green) == 1 and not trail.trail_green and o.kind is not OverlapKind.TRANSIT
                        and _apart(self.c, o.included, green[0].number) and self._leaves(o.included, green[0].number)):
                    latest = green[0].latest
            elif show is Show.FLASHING:
                # a flashing arrow (yellow) shows while its permissive phase is green, and clears with its yellow
                m = [phases[q] for q in o.modifiers if phases[q].indication is Indication.GREEN]
                if len(m) == 1 and _apart(self.c, followed, m[0].number):
                    yellow = c.timing[m[0].number].yellow
                    earliest = m[0].earliest + max(1, self._least(yellow, self.yellow))
                    latest = None if m[0].latest is None else m[0].latest + yellow
            elif show is Show.YELLOW:
                parents = [phases[q] for q in followed]
                yellow = [s for s in parents if s.indication is Indication.YELLOW]
                earliest = max((s.earliest for s in yellow), default=1)
                if len(yellow) == 1 and all(s.indication is not Indication.GREEN for s in parents) and _apart(
                        self.c, followed, yellow[0].number):
                    latest = yellow[0].latest
            elif show is Show.TRAIL_GREEN:
                earliest = max(1, trail.trail_green - ticks)
            elif show is Show.DELAYED:
                # red while its green's delay runs: green once it has run if an included phase still holds it then
                # (one that cannot end its green before); released by its phases sooner, it stays red
                earliest = max(1, trail.delay_green - ticks)
                held = any(phases[q].indication is Indication.GREEN and phases[q].earliest > earliest
                           for q in o.included)
                latest = earliest if held else None
            elif shown is Indication.RED:
                # from its trailing red it turns green only the tick after that has run (``_NEXT``)
                lit = trail.trail_red - ticks + 1 if show is Show.TRAIL_RED else 1
                parents = [phases[q] for q in followed]
                red = [s for s in parents if s.indication is Indication.RED]
                delay = trail.delay_green
                if any(s.indication is Indication.GREEN for s in parents):
                    earliest = latest = lit
                    # a delayed green: an included phase green still when its delay runs out holds it (else released)
                    if delay and not any(s.indication is Indication.GREEN and s.earliest > lit + delay
                                         for s in parents if s.number in o.included):
                        latest = None
                else:
                    earliest = max(lit, min((s.earliest for s in red), default=lit))
                    # a delayed green turns green by the delay's end after an included phase starts whose green
                    # outlasts the delay (a shorter one releases it, red on)
                    starts = [s.latest for s in red if s.latest is not None and (
                        not delay or s.number not in o.included or c.timing[s.number].min_green > delay)]
                    latest = max(lit, min(starts)) if starts else None
                if delay:
                    # an included phase's green starts its delay first; a flashing arrow's permissive phase does not
                    earliest += 0 if o.kind is OverlapKind.FYA else delay
                    latest = None if latest is None else latest + delay
        # only its own trailing intervals are timed: when a display it follows from its parents began is not kept
        return SignalTiming("overlap", n, shown, earliest, latest, latest, ticks if show in TRAILING else None)

    def _leaves(self, included: tuple[int, ...], g: int) -> bool:
        """The ring showing included phase ``g`` green goes to a phase not included when it ends (free: its wish, the
        demand standing), so the overlap is not held green through its included phases."""
        q = self.wish.get(self.c.config.ring_of(g))
        return self.plan is None and q is not None and q not in included


