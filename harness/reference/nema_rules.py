"""Where our controller and SUMO's NEMA controller part, and who is right: the rules that judge a difference.

Rules of this file
------------------
- A rule is a statement of how an actuated controller must behave, quoted from a source nobody here
  wrote: NTCIP 1202 v02's object definitions (NEMA TS 2 by their references), a vendor's note, or a
  line of SUMO's ``NEMAController.cpp`` where that line is what the other side did. Each rule is
  checked on what a controller *showed* (its colour changes) and the calls it read, never on its
  internal state, and never against what our controller does: the same check runs on both sides.
- A rule that a side breaks makes that side wrong at that point. A *both defensible* class is a
  behaviour that the sources leave to the controller's settings: neither side breaks a rule.
- Only the first difference of a sequence is judged: from there the two controllers serve different
  phases, and later differences follow from it.

Theory of operation
-------------------
:func:`classify` finds the first change only one side makes (:class:`Comparison.first_difference`)
and collects, on both sides, the greens that end around it (:class:`Ending`: the green, its yellow
onset and where its ring went next). Each ending is checked against the rules in the order of
:data:`CLASSES`; the first rule broken names the class and the side that broke it. When no ending
breaks a rule, the greens one side kept past the other side's legitimate end are checked (a green held
past its maximum). A difference no rule explains is ``UNEXPLAINED``: the test suite asks for none.

Tick conventions are those of :mod:`harness.reference.nema`: a change at tick ``k`` is made by the
step that read the calls placed before it (``called[k]``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

from emulator.model.controller import tenths
from emulator.model.coordination import Plan
from hils.protocol.config import ForceOff, IntersectionConfig


class Color(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED = "red"


@dataclass(frozen=True, slots=True, order=True)
class ColorChange:
    """A phase starts showing a colour at a tick."""

    tick: int
    phase: int
    color: Color

    def __str__(self) -> str:
        return f"{self.tick / 10:.1f}s {self.phase} {self.color}"


Timeline = tuple[ColorChange, ...]

NTCIP_MIN_GREEN = ("NTCIP 1202 v02 phaseMinimumGreen: \"The first timed portion of the Green interval\" (a "
                   "green is held at least its minimum)")
NTCIP_PASSAGE = ("NTCIP 1202 v02 phasePassage: \"The phase shall remain in the extensible portion of the Green "
                 "interval as long as the passage timer is not timed out. The timing of this portion of the green "
                 "interval shall be reset with each subsequent vehicle actuation\"")
NTCIP_MAXIMUM = ("NTCIP 1202 v02 phaseMaximum1: \"the maximum length of time this phase may be held Green in the "
                 "presence of a serviceable conflicting call. In the absence of a serviceable conflicting call the "
                 "Maximum Green timer shall be held reset\"")
NTCIP_SEQUENCE = ("NTCIP 1202 v02 sequenceData: \"The order of phase numbers determines the phase sequence for "
                  "the ring\"")
TECNOTE_3013 = ("Naztec TecNote 3013: \"Any controller can 'back into' a protected left-turn phase when the cross "
                "street phases and the opposing left-turn are skipped\"; NTCIP 1202 v02 phaseOptions bit 14 "
                "(Conditional Service, optional): serves \"a preceding actuated vehicle phase when sufficient time "
                "remains before max time out of the phase(s) not prepared to terminate\"")
NTCIP_PHASE_NEXT = ("NTCIP 1202 v02 phaseStatusGroupPhaseNexts: the next phase \"shall be determined at the end of "
                    "the green interval of the terminating phase\"; SUMO's own NEMAPhase::trySwitch lets a later "
                    "call change the decision \"only if the new transition is on the same side of a barrier\"")
NTCIP_SPLIT = ("NTCIP 1202 v02 splitTime: \"The time in seconds the splitPhase is allowed to receive (i.e. before a "
               "Force Off is applied)\"; coordForceMode fixed: \"each non-coord phase will be forced at a fixed "
               "position in the cycle\"")
NTCIP_GAP_DISABLE = ("NTCIP 1202 v02 phaseOptions bit 11 (Simultaneous Gap Disable, optional): \"disables a gapped "
                     "out phase from reverting to the extensible portion\"; phasePassage: the extensible portion "
                     "\"shall be reset with each subsequent vehicle actuation\"")


class Right(StrEnum):
    """Who is right in a class: the side that keeps the rule, or both."""

    KEEPER = "the side that keeps the rule"
    BOTH = "both defensible"


@dataclass(frozen=True, slots=True)
class DifferenceClass:
    """One kind of first difference: the rule, who is right and the source that decides it."""

    name: str
    rule: str
    right: Right
    source: str

    def __str__(self) -> str:
        return self.name


ENDED_BEFORE_MIN = DifferenceClass(
    "green ended before its minimum", "a green ends before its minimum green has elapsed", Right.KEEPER,
    NTCIP_MIN_GREEN)
ENDED_WHILE_EXTENDING = DifferenceClass(
    "green ended while its call extended it",
    "a green ends while its own call is on, before its maximum timed from a serviceable conflicting call, and "
    "without having gapped out in the presence of one", Right.KEEPER, f"{NTCIP_PASSAGE}; {NTCIP_MAXIMUM}")
RE_EXTENDED = DifferenceClass(
    "gapped-out green re-extended by its returning call",
    "a green that gapped out after its minimum gets its call back: one side ends it (the gap-out held: the call "
    "came back just then, or a conflicting call has waited since the gap-out), the other extends it again",
    Right.BOTH, NTCIP_GAP_DISABLE)
SKIPPED = DifferenceClass(
    "called phase skipped to cross the barrier",
    "a ring crosses the barrier while a phase after its own, before the barrier, is called", Right.KEEPER,
    NTCIP_SEQUENCE)
BACKED_WITH_CALL_ACROSS = DifferenceClass(
    "backed into an earlier phase with a call across the barrier",
    "a ring backs into an earlier phase of its barrier group while a phase across the barrier is called",
    Right.KEEPER, TECNOTE_3013)
PULLED_ACROSS = DifferenceClass(
    "clearing ring pulled across the barrier",
    "a ring that began its yellow alone (toward a phase on its side of the barrier) enters a phase across it",
    Right.KEEPER, NTCIP_PHASE_NEXT)
HELD_PAST_MAXIMUM = DifferenceClass(
    "green held past its maximum",
    "a green stays on after its maximum, timed from a serviceable conflicting call, where the other side ends it "
    "and its ring goes on (within its group, or across the barrier with the other ring)", Right.KEEPER,
    NTCIP_MAXIMUM)
ENTERED_PAST_FORCE_OFF = DifferenceClass(
    "phase entered too late to serve its minimum before its force-off",
    "while a pattern runs, a non-coordinated phase starts green where its minimum green no longer ends by its "
    "force-off point in the cycle", Right.KEEPER, NTCIP_SPLIT)
COORD_WAITS_FOR_OTHER_RING = DifferenceClass(
    "coordinated phase held for the other ring",
    "a coordinated phase past its yield point, with a call on a phase of its own barrier group in that phase's "
    "permissive period, ends on one side while the other ring's green goes on, and waits for the other ring on "
    "the other side", Right.BOTH,
    "NTCIP 1202 v02 phaseConcurrency: phases of different rings in one group \"may run concurrently\" (rings "
    "time independently between barriers); SUMO's PhaseTransitionLogic::fromCoord: \"Determine if the other "
    "phase is also ready to switch\" before leaving the coordinated phase")
PERMISSIVE_PERIOD = DifferenceClass(
    "coordinated phase left or kept outside a permissive period",
    "a coordinated phase past its yield point ends on one side and goes on on the other, neither because of the "
    "rules above: one side gives the phase it leaves for a (sequential) permissive period, the other does not",
    Right.BOTH,
    "permissive periods are a controller setting NTCIP 1202 does not define; SUMO's PhaseTransitionLogic::fromCoord "
    "applies them to TS2 only: \"Dr. Wang had the Type-170 code setup in a way that it could transition whenever\"")
UNEXPLAINED = DifferenceClass("unexplained", "no rule explains the difference", Right.BOTH, "")

#: The classes in the order their rules are checked.
CLASSES: tuple[DifferenceClass, ...] = (ENDED_BEFORE_MIN, ENDED_WHILE_EXTENDING, PULLED_ACROSS, SKIPPED,
                                        BACKED_WITH_CALL_ACROSS, ENTERED_PAST_FORCE_OFF, COORD_WAITS_FOR_OTHER_RING,
                                        PERMISSIVE_PERIOD, HELD_PAST_MAXIMUM, RE_EXTENDED)


class Side(StrEnum):
    OURS = "ours"
    SUMO = "SUMO"


@dataclass(frozen=True, slots=True)
class Ending:
    """A green that ends on one side: its phase, green and yellow onsets, and the ring's next green."""

    side: Side
    phase: int
    green: int
    yellow: int
    next: int | None  # the phase the ring shows green next (None: not within the sequence)
    next_green: int | None
    alone: bool  # no phase of the other ring began a yellow at the same tick


@dataclass(frozen=True, slots=True)
class Judgement:
    """The first difference of a sequence: its tick, class and the side that broke the class's rule."""

    tick: int
    kind: DifferenceClass
    breaker: Side | None  # None for both-defensible and unexplained differences
    phase: int | None

    def __str__(self) -> str:
        who = f", broken by {self.breaker}" if self.breaker else ""
        return f"{self.tick / 10:.1f}s {self.kind}{who} (phase {self.phase})"


class Rules:
    """The rules on one config and one sequence of calls (``called[k]``: the calls the step ending at ``k`` read)."""

    def __init__(self, config: IntersectionConfig, called: Sequence[frozenset[int]], plan: Plan | None = None) -> None:
        self.config = config
        self.called = called
        self.plan = plan
        self.ring = {p: config.ring_of(p) for p in config.phases}
        self.side = {p: config.barrier_of(p) for p in config.phases}
        self.order = {p: ring.index(p) for ring in config.rings for p in ring}
        self.min = {p: tenths(ph.min_green) for p, ph in config.phases.items()}
        self.max = {p: tenths(ph.max_green) for p, ph in config.phases.items()}

    def calls(self, k: int) -> frozenset[int]:
        return self.called[min(max(k, 0), len(self.called) - 1)]

    def conflicting(self, p: int, k: int) -> bool:
        """A serviceable conflicting call on ``p`` at tick ``k``: a call on a phase that may not show with it."""
        return any(q != p and (self.ring[q] == self.ring[p] or self.side[q] != self.side[p]) for q in self.calls(k))

    def local(self, k: int) -> int:
        """The running pattern's cycle position at tick ``k`` (in step with the system: the sequences keep their
        power-up pattern)."""
        return (k - self.plan.offset) % self.plan.cycle

    def serviceable(self, q: int, k: int, clearance: int) -> bool:
        """``q`` is called at ``k`` and, while a pattern runs, can still be served to its minimum after
        ``clearance`` ticks before its force-off point (a phase that cannot is skipped: splitTime)."""
        return q in self.calls(k) and (self.plan is None or self.plan.fits(q, self.local(k), clearance))

    def maxed(self, p: int, green: int, end: int) -> bool:
        """The green of ``p`` from ``green`` reached its limit by ``end``: its maximum (a conflicting call for max
        ticks); while a pattern runs, its force-off point (a coordinated phase: its yield point), which replaces
        the maximum."""
        if self.plan is not None:
            if p not in self.plan.coord.values() and not self.plan.in_window(p, self.local(green)):
                return True  # started past its force-off point: forced off at its minimum
            return self._passes(p, green, end)
        for run, k in enumerate(range(end, green, -1), start=1):
            if not self.conflicting(p, k):
                return False
            if run >= self.max[p] - 1:
                return True
        return False

    def _passes(self, p: int, green: int, end: int) -> bool:
        """The green from ``green`` to ``end`` reached ``p``'s force-off point (or outlasted its split, floating)."""
        plan = self.plan
        to_point = (plan.force_off[p] - self.local(green)) % plan.cycle
        floating = self.config.coordination.force_off is ForceOff.FLOATING and p not in plan.coord.values()
        limit = plan.split[p] - plan.clearance[p] if floating else plan.cycle
        return end - green >= min(to_point, limit) - 1

    # --- the rules, each on one ending ---------------------------------------------------------

    def ended_before_min(self, e: Ending) -> bool:
        return e.green > 0 and e.yellow - e.green < self.min[e.phase] - 1

    def returning(self, e: Ending) -> bool:
        """The green's call came back just before it ended, after a gap-out past its minimum."""
        p, since = e.phase, e.green + self.min[e.phase]
        return p in self.calls(e.yellow) and any(p not in self.calls(k) for k in range(max(since, e.yellow - 2),
                                                                                      e.yellow))

    def latched(self, e: Ending) -> bool:
        """The green gapped out past its minimum while a serviceable conflicting call waited, which kept waiting
        until it ended (NEMA's simultaneous gap disable holds such a gap-out)."""
        p = e.phase
        return any(p not in self.calls(k) and all(self.conflicting(p, j) for j in range(k, e.yellow + 1))
                   for k in range(e.green + self.min[p], e.yellow))

    def ready(self, p: int, green: int, k: int) -> bool:
        """The green of ``p`` from ``green`` may end at tick ``k``: past its minimum, and gapped out or maxed out."""
        return k - green >= self.min[p] - 1 and (p not in self.calls(k) or self.maxed(p, green, k))

    def ended_while_extending(self, e: Ending) -> bool:
        return (e.phase in self.calls(e.yellow) and not self.maxed(e.phase, e.green, e.yellow)
                and not self.latched(e) and not self.returning(e))

    def clearance(self, p: int) -> int:
        ph = self.config.phases[p]
        return tenths(ph.yellow) + tenths(ph.red_clear)

    def skipped(self, e: Ending) -> bool:
        p = e.phase
        return (e.next is not None and self.side[e.next] != self.side[p]
                and any(self.ring[x] == self.ring[p] and self.side[x] == self.side[p] and self.order[x] > self.order[p]
                        and self.serviceable(x, e.yellow, self.clearance(p)) for x in self.config.phases))

    def backed_with_call_across(self, e: Ending) -> bool:
        p = e.phase
        return (e.next is not None and self.side[e.next] == self.side[p] and self.order[e.next] < self.order[p]
                and any(self.side[x] != self.side[p] and self.serviceable(x, e.yellow, self.clearance(p))
                        for x in self.config.phases))

    def entered_past_force_off(self, e: Ending) -> bool:
        plan, q = self.plan, e.next
        if plan is None or q is None or q in plan.coord.values():
            return False
        return not plan.fits(q, self.local(e.next_green), 0)

    def pulled_across(self, e: Ending) -> bool:
        return e.alone and e.next is not None and self.side[e.next] != self.side[e.phase]


_CHECKS: dict[DifferenceClass, Callable[[Rules, Ending], bool]] = {
    ENDED_BEFORE_MIN: Rules.ended_before_min,
    ENDED_WHILE_EXTENDING: Rules.ended_while_extending,
    PULLED_ACROSS: Rules.pulled_across,
    SKIPPED: Rules.skipped,
    BACKED_WITH_CALL_ACROSS: Rules.backed_with_call_across,
    ENTERED_PAST_FORCE_OFF: Rules.entered_past_force_off,
}


def endings(config: IntersectionConfig, timeline: Timeline, side: Side) -> list[Ending]:
    """Every green of ``timeline`` that ends, with where its ring went next."""
    ring = {p: config.ring_of(p) for p in config.phases}
    yellows: dict[int, list[int]] = {}
    for c in timeline:
        if c.color is Color.YELLOW:
            yellows.setdefault(c.tick, []).append(c.phase)
    out = []
    green: dict[int, int] = {}
    for i, c in enumerate(timeline):
        if c.color is Color.GREEN:
            green[c.phase] = c.tick
        elif c.color is Color.YELLOW:
            r = ring[c.phase]
            after = next((d for d in timeline[i + 1:] if d.color is Color.GREEN and ring[d.phase] == r), None)
            others = [q for k in (c.tick - 1, c.tick, c.tick + 1) for q in yellows.get(k, ()) if ring[q] != r]
            out.append(Ending(side, c.phase, green.get(c.phase, 0), c.tick, after and after.phase,
                              after and after.tick, not others))
    return out


def classify(config: IntersectionConfig, called: Sequence[frozenset[int]], ours: Timeline, reference: Timeline,
             tick: int, tolerance: int = 1, plan: Plan | None = None) -> Judgement:
    """The class of the first difference (at ``tick``) between ``ours`` and SUMO's ``reference``; ``plan``: the
    pattern both run (its force-off points, which SUMO lays out the same way: a sequence with every phase
    called agrees change for change)."""
    rules = Rules(config, called, plan)
    near = [e for timeline, side in ((reference, Side.SUMO), (ours, Side.OURS))
            for e in endings(config, timeline, side)
            if e.yellow - tolerance <= tick <= (e.next_green if e.next_green is not None else e.yellow) + tolerance]
    for kind, check in _CHECKS.items():
        for e in near:
            if check(rules, e):
                return Judgement(tick, kind, None if kind.right is Right.BOTH else e.side, e.phase)
    for e in near:  # an end on one side that the other side did not make
        other = Side.OURS if e.side is Side.SUMO else Side.SUMO
        kept = reference if other is Side.SUMO else ours
        if any(c.phase == e.phase and c.color is Color.YELLOW and abs(c.tick - e.yellow) <= tolerance for c in kept):
            continue
        plan = rules.plan
        if (plan is not None and e.phase in plan.coord.values() and e.alone and e.next is not None
                and rules.side[e.next] == rules.side[e.phase]):
            return Judgement(tick, COORD_WAITS_FOR_OTHER_RING, None, e.phase)
        if plan is not None and e.phase in plan.coord.values():
            return Judgement(tick, PERMISSIVE_PERIOD, None, e.phase)
        if rules.maxed(e.phase, e.green, e.yellow) and _could_go_on(rules, e, kept):
            return Judgement(tick, HELD_PAST_MAXIMUM, other, e.phase)
        if rules.returning(e) or (e.phase in rules.calls(e.yellow) and rules.latched(e)):
            return Judgement(tick, RE_EXTENDED, None, e.phase)
    return Judgement(tick, UNEXPLAINED, None, None)


def _could_go_on(rules: Rules, e: Ending, kept: Timeline) -> bool:
    """Where ``kept`` still shows ``e``'s green, its ring had somewhere to go: the next phase is on its side of the
    barrier, or the other ring's green there may end too (a ring waits at the barrier only for a green that may
    not)."""
    if e.next is not None and rules.side[e.next] == rules.side[e.phase]:
        return True
    shown: dict[int, int] = {}  # the other ring's greens on the keeping side, and when they began
    for c in kept:
        if c.tick > e.yellow:
            break
        if rules.ring[c.phase] != rules.ring[e.phase]:
            if c.color is Color.GREEN:
                shown[c.phase] = c.tick
            else:
                shown.pop(c.phase, None)
    return all(rules.ready(o, green, e.yellow) for o, green in shown.items())
