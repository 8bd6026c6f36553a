"""Where our controller and SUMO's NEMA controller part, and who is right: the rules that judge a difference.

Rules of this file
------------------
- A rule is a statement of how an actuated controller must behave, quoted from a source nobody here
  wrote: NTCIP 1202 v03's object definitions (the MIB text in ``ntcip_mib/``, NEMA TS 2 by their
  references; a test finds every NTCIP quote there word for word), a vendor's note, or a line of SUMO's
  ``NEMAController.cpp`` where that line is what the other side did. Each rule is checked on what a
  controller *showed* (its colour changes) and the calls it read, never on its internal state, and never
  against what our controller does: the same check runs on both sides.
- Every difference gets one of three verdicts (:class:`Verdict`): SUMO departs from a quoted rule; a
  setting both may take (the standard leaves the behaviour to a controller setting, and the side that
  showed it is one that has the setting: :class:`Settings`); the model's fault (our controller breaks a
  rule, or no rule explains the difference: nothing excuses the model but a rule).
- Every divergence is judged, not only the first: after a difference the two controllers serve different
  phases until they show the same colours again (a resync, :meth:`harness.reference.nema.Comparison.divergences`);
  the next difference after it is judged afresh. Besides, every green our controller ends is audited on its
  own (:func:`audit`), whether or not SUMO differs there: a fault both sides share is still a fault.

Theory of operation
-------------------
:func:`classify` takes the tick where a divergence starts and collects, on both sides, the greens that end
around it (:class:`Ending`: the green, its yellow onset, where its ring went next and the other ring's greens
beside it). Each ending is checked against the rules in the order of :data:`CLASSES`; the first rule broken
names the class and the side that broke it. When no ending breaks a rule, the greens one side kept past the
other side's end are checked (a green held past its maximum; a gapped-out green whose call came back). A
difference no rule explains is ``UNEXPLAINED``, the model's fault: the test suite asks for none.
:func:`audit` runs the same rules, and the held-past-maximum rule on its own, on every green our timeline ends.

Tick conventions are those of :mod:`harness.reference.nema`: a change at tick ``k`` is made by the
step that read the calls placed before it (``called[k]``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
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

NTCIP = "NTCIP 1202 v03"  # the MIB text of harness/reference/ntcip_mib, where every quote of it is found


@dataclass(frozen=True, slots=True)
class Quote:
    """A passage of a source, word for word (``text``), where it stands (``where``), and what it says here."""

    where: str
    text: str
    note: str = ""

    def __str__(self) -> str:
        return f'{self.where}: "{self.text}"' + (f" ({self.note})" if self.note else "")


MIN_GREEN = Quote(f"{NTCIP} phaseMinimumGreen", "The first timed portion of the Green interval",
                  "a green is held at least its minimum")
PASSAGE = Quote(f"{NTCIP} phasePassage", "The phase shall remain in the extensible portion of the Green interval "
                "as long as the passage timer is not timed out. The timing of this portion of the green interval "
                "shall be reset with each subsequent vehicle actuation")
MAXIMUM = Quote(f"{NTCIP} phaseMaximum1", "the maximum length of time this phase may be held in Green in the "
                "presence of a serviceable conflicting call. In the absence of a serviceable conflicting call the "
                "Maximum Green timer shall be held reset")
SEQUENCE = Quote(f"{NTCIP} sequenceData", "The order of phase numbers determines the phase sequence for the ring")
BACK_INTO = Quote("Naztec TecNote 3013", "Any controller can 'back into' a protected left-turn phase when the cross "
                  "street phases and the opposing left-turn are skipped")
CONDITIONAL_SERVICE_BIT = Quote(
    f"{NTCIP} phaseOptions bit 14, Conditional Service Enable", "in multi-ring configurations when set to 1 causes a "
    "gapped/maxed phase to conditionally service a preceding actuated vehicle phase when sufficient time remains "
    "before max time out of the phase(s) not prepared to terminate. Support is optional")
PHASE_NEXT = Quote(f"{NTCIP} phaseStatusGroupPhaseNexts", "The phase next to be serviced shall be determined at the "
                   "end of the green interval of the terminating phase")
SUMO_TRY_SWITCH = Quote("SUMO NEMAController.cpp, NEMAPhase::trySwitch",
                        "only if the new transition is on the same side of a barrier",
                        "a later call may change the decision")
SPLIT = Quote(f"{NTCIP} splitTime", "The time in seconds the splitPhase is allowed to receive (i.e. before a Force "
              "Off is applied)")
FIXED_FORCE_OFF = Quote(f"{NTCIP} coordForceMode", "fixed: each non-coord phase will be forced at a fixed position in "
                        "the cycle")
GAP_DISABLE = Quote(f"{NTCIP} phaseOptions bit 11, Simultaneous Gap Disable", "in multi-ring configurations when set "
                    "to 1 disables a gapped out phase from reverting to the extensible portion. Support is optional")
CONCURRENCY = Quote(f"{NTCIP} phaseConcurrency", "may run concurrently",
                    "phases of different rings in one group; rings time independently between barriers")
SUMO_FROM_COORD = Quote("SUMO NEMAController.cpp, PhaseTransitionLogic::fromCoord",
                        "Determine if the other phase is also ready to switch",
                        "before leaving the coordinated phase")
SUMO_TYPE_170 = Quote("SUMO NEMAController.cpp, PhaseTransitionLogic::fromCoord",
                      "Dr. Wang had the Type-170 code setup in a way that it could transition whenever",
                      "permissive periods, which NTCIP 1202 does not define, apply to TS2 only")


class Right(StrEnum):
    """Who is right in a class: the side that keeps the rule, or either (a setting both may take)."""

    KEEPER = "the side that keeps the rule"
    SETTING = "a setting both may take"


class Verdict(StrEnum):
    """The three counts of the differential."""

    REFERENCE = "SUMO departs from a quoted rule"
    SETTING = "a setting both may take"
    MODEL = "the model's fault"


@dataclass(frozen=True, slots=True)
class DifferenceClass:
    """One kind of difference: the rule, who is right and the sources that decide it."""

    name: str
    rule: str
    right: Right
    quotes: tuple[Quote, ...]

    @property
    def source(self) -> str:
        return "; ".join(map(str, self.quotes))

    def __str__(self) -> str:
        return self.name


ENDED_BEFORE_MIN = DifferenceClass(
    "green ended before its minimum", "a green ends before its minimum green has elapsed", Right.KEEPER,
    (MIN_GREEN,))
ENDED_WHILE_EXTENDING = DifferenceClass(
    "green ended while its call extended it",
    "a green ends while its own call is on, before its maximum timed from a serviceable conflicting call, and "
    "without having gapped out past its minimum (a gap-out held when the call comes back is simultaneous gap "
    "disable, a setting)", Right.KEEPER, (PASSAGE, MAXIMUM))
RE_EXTENDED = DifferenceClass(
    "gapped-out green re-extended by its returning call",
    "a green that gapped out after its minimum gets its call back while it still shows: one side ends it (the "
    "gap-out held), the other extends it again, however long after the gap-out the call returns", Right.SETTING,
    (GAP_DISABLE, PASSAGE))
SKIPPED = DifferenceClass(
    "called phase skipped to cross the barrier",
    "a ring crosses the barrier while a phase after its own, before the barrier, is called", Right.KEEPER,
    (SEQUENCE,))
BACKED_WITH_CALL_ACROSS = DifferenceClass(
    "backed into an earlier phase with a call across the barrier, not as conditional service",
    "a ring backs into an earlier phase of its barrier group while a phase across the barrier is called, and the "
    "backing is not conditional service: the side is not set to give it, or the other ring's green that is not "
    "ready to end has too little time left before its maximum for the clearance and the earlier phase's minimum",
    Right.KEEPER, (BACK_INTO, CONDITIONAL_SERVICE_BIT))
CONDITIONAL_SERVICE = DifferenceClass(
    "conditional service: backed into an earlier phase with a call across the barrier",
    "a ring whose green gapped or maxed out backs into an earlier phase of its barrier group while a phase across the "
    "barrier is called, on a side set to give conditional service, with the clearance and the earlier phase's "
    "minimum ending before the maximum of every green of the other ring that is not ready to end (not beside "
    "greens all ready to end: they cross first)", Right.SETTING,
    (CONDITIONAL_SERVICE_BIT,))
PULLED_ACROSS = DifferenceClass(
    "clearing ring pulled across the barrier",
    "a ring that began its yellow alone (toward a phase on its side of the barrier) enters a phase across it",
    Right.KEEPER, (PHASE_NEXT, SUMO_TRY_SWITCH))
HELD_PAST_MAXIMUM = DifferenceClass(
    "green held past its maximum",
    "a green stays on after its maximum, timed from a serviceable conflicting call, while its ring could go on "
    "(within its group, or across the barrier with the other ring, whose greens may end too)", Right.KEEPER,
    (MAXIMUM,))
ENTERED_PAST_FORCE_OFF = DifferenceClass(
    "phase entered too late to serve its minimum before its force-off",
    "while a pattern runs, a non-coordinated phase starts green where its minimum green no longer ends by its "
    "force-off point in the cycle", Right.KEEPER, (SPLIT, FIXED_FORCE_OFF))
COORD_WAITS_FOR_OTHER_RING = DifferenceClass(
    "coordinated phase held for the other ring",
    "a coordinated phase past its yield point, with a call on a phase of its own barrier group in that phase's "
    "permissive period, ends on one side while the other ring's green goes on, and waits for the other ring on "
    "the other side", Right.SETTING, (CONCURRENCY, SUMO_FROM_COORD))
PERMISSIVE_PERIOD = DifferenceClass(
    "coordinated phase left or kept outside a permissive period",
    "a coordinated phase past its yield point ends on one side and goes on on the other, neither because of the "
    "rules above: one side gives the phase it leaves for a (sequential) permissive period, the other does not",
    Right.SETTING, (SUMO_TYPE_170,))
UNEXPLAINED = DifferenceClass("unexplained", "no rule explains the difference", Right.KEEPER, ())

#: The classes in the order their rules are checked.
CLASSES: tuple[DifferenceClass, ...] = (ENDED_BEFORE_MIN, ENDED_WHILE_EXTENDING, PULLED_ACROSS, SKIPPED,
                                        BACKED_WITH_CALL_ACROSS, CONDITIONAL_SERVICE, ENTERED_PAST_FORCE_OFF,
                                        COORD_WAITS_FOR_OTHER_RING, PERMISSIVE_PERIOD, HELD_PAST_MAXIMUM, RE_EXTENDED)


class Side(StrEnum):
    OURS = "ours"
    SUMO = "SUMO"


@dataclass(frozen=True, slots=True)
class Settings:
    """What a side is set to do where the standard leaves the choice to a setting."""

    conditional_service: bool  # NTCIP 1202 phaseOptions bit 14


def settings_of(config: IntersectionConfig) -> Mapping[Side, Settings]:
    """What each side is set to do: ours as ``config`` sets its phases (``conditional_service``: phaseOptions bit 14;
    the differential sets it as SUMO has it, :func:`harness.reference.nema.sumo_options`); SUMO's
    ``PhaseTransitionLogic::fromBarrier`` checks only its own ring's calls across the barrier before backing, which is
    conditional service always on."""
    return {Side.OURS: Settings(conditional_service=any(ph.conditional_service for ph in config.phases.values())),
            Side.SUMO: Settings(conditional_service=True)}


@dataclass(frozen=True, slots=True)
class Ending:
    """A green that ends on one side: its phase, green and yellow onsets, the ring's next green, and the greens
    the other ring showed at the yellow (phase, green onset)."""

    side: Side
    phase: int
    green: int
    yellow: int
    next: int | None  # the phase the ring shows green next (None: not within the sequence)
    next_green: int | None
    alone: bool  # no phase of the other ring began a yellow at the same tick
    beside: tuple[tuple[int, int], ...] = ()


@dataclass(frozen=True, slots=True)
class Judgement:
    """A judged difference: its tick, class and the side that broke the class's rule."""

    tick: int
    kind: DifferenceClass
    breaker: Side | None  # None for a setting and for an unexplained difference
    phase: int | None

    @property
    def verdict(self) -> Verdict:
        if self.kind is UNEXPLAINED or self.breaker is Side.OURS:
            return Verdict.MODEL
        return Verdict.SETTING if self.kind.right is Right.SETTING else Verdict.REFERENCE

    def __str__(self) -> str:
        who = f", broken by {self.breaker}" if self.breaker else ""
        return f"{self.tick / 10:.1f}s {self.kind}{who} (phase {self.phase}): {self.verdict}"


class Rules:
    """The rules on one config and one sequence of calls (``called[k]``: the calls the step ending at ``k`` read)."""

    def __init__(self, config: IntersectionConfig, called: Sequence[frozenset[int]], plan: Plan | None = None,
                 settings: Mapping[Side, Settings] | None = None) -> None:
        self.config = config
        self.called = called
        self.plan = plan
        self.settings = settings_of(config) if settings is None else settings
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

    def conflict_run(self, p: int, green: int, end: int) -> int:
        """Ticks up to ``end`` (back to ``green``) that a serviceable conflicting call on ``p`` has waited without a
        break: how long ``p``'s maximum has timed."""
        run = 0
        for k in range(end, green, -1):
            if not self.conflicting(p, k):
                break
            run += 1
        return run

    def maxed(self, p: int, green: int, end: int, slack: int = 1) -> bool:
        """The green of ``p`` from ``green`` reached its limit by ``end``, give or take ``slack`` ticks (a side may
        end it a tick early): its maximum (a conflicting call for max ticks); while a pattern runs, its force-off
        point (a coordinated phase: its yield point), which replaces the maximum."""
        if self.plan is not None:
            if p not in self.plan.coord.values() and not self.plan.in_window(p, self.local(green)):
                return True  # started past its force-off point: forced off at its minimum
            return self._passes(p, green, end, slack)
        return self.conflict_run(p, green, end) >= self.max[p] - slack

    def _passes(self, p: int, green: int, end: int, slack: int) -> bool:
        """The green from ``green`` to ``end`` reached ``p``'s force-off point (or outlasted its split, floating)."""
        plan = self.plan
        to_point = (plan.force_off[p] - self.local(green)) % plan.cycle
        floating = self.config.coordination.force_off is ForceOff.FLOATING and p not in plan.coord.values()
        limit = plan.split[p] - plan.clearance[p] if floating else plan.cycle
        return end - green >= min(to_point, limit) - slack

    def time_left(self, p: int, green: int, k: int) -> int:
        """Ticks from ``k`` until the green of ``p`` from ``green`` reaches its maximum (its force-off or yield
        point while a pattern runs)."""
        if self.plan is not None:
            return (self.plan.force_off[p] - self.local(k)) % self.plan.cycle
        return self.max[p] - 1 - self.conflict_run(p, green, k)

    # --- the rules, each on one ending ---------------------------------------------------------

    def ended_before_min(self, e: Ending) -> bool:
        return e.green > 0 and e.yellow - e.green < self.min[e.phase] - 1

    def gapped(self, e: Ending) -> bool:
        """The green gapped out past its minimum (its call off) before it ended: with simultaneous gap disable the
        gap-out holds, whenever the call comes back."""
        return any(e.phase not in self.calls(k) for k in range(e.green + self.min[e.phase] - 1, e.yellow))

    def ready(self, p: int, green: int, k: int, slack: int = 1) -> bool:
        """The green of ``p`` from ``green`` may end at tick ``k``: past its minimum, and gapped out or maxed out."""
        return k - green >= self.min[p] - slack and (p not in self.calls(k) or self.maxed(p, green, k, slack))

    def ended_while_extending(self, e: Ending) -> bool:
        return e.phase in self.calls(e.yellow) and not self.maxed(e.phase, e.green, e.yellow) and not self.gapped(e)

    def clearance(self, p: int) -> int:
        ph = self.config.phases[p]
        return tenths(ph.yellow) + tenths(ph.red_clear)

    def skipped(self, e: Ending) -> bool:
        p = e.phase
        return (e.next is not None and self.side[e.next] != self.side[p]
                and any(self.ring[x] == self.ring[p] and self.side[x] == self.side[p] and self.order[x] > self.order[p]
                        and self.serviceable(x, e.yellow, self.clearance(p)) for x in self.config.phases))

    def backs(self, e: Ending) -> bool:
        """The ring of ``e`` went on to an earlier phase of its barrier group."""
        p = e.phase
        return e.next is not None and self.side[e.next] == self.side[p] and self.order[e.next] < self.order[p]

    def backs_with_call_across(self, e: Ending) -> bool:
        p = e.phase
        return self.backs(e) and any(self.side[x] != self.side[p] and self.serviceable(x, e.yellow, self.clearance(p))
                                     for x in self.config.phases)

    def conditional_service(self, e: Ending) -> bool:
        """The backing of ``e`` is conditional service as phaseOptions bit 14 words it: its side is set to give it,
        its green had gapped or maxed out, and every green of the other ring not prepared to terminate has time left
        before its maximum for ``e``'s clearance and the earlier phase's minimum. With no such green nothing times
        out on the way, but with a call across the barrier two greens ready to end cross it instead (a ring already
        clearing toward a phase of the group does not)."""
        if not self.settings[e.side].conditional_service or not (self.ready(e.phase, e.green, e.yellow)
                                                                    or self.gapped(e)):
            return False  # not gapped (or held gapped out, simultaneous gap disable) nor maxed out
        holding = [(o, green) for o, green in e.beside if not self.ready(o, green, e.yellow)]
        if not holding:  # the other ring's greens cross with it, unless one goes on within the group
            crossing = e.beside and not any(self.forward(o, e.yellow) for o, _ in e.beside)
            return not (crossing and self.backs_with_call_across(e))
        return self.time_for(e.phase, e.next, holding, e.yellow)

    def time_for(self, p: int, q: int, holding: Sequence[tuple[int, int]], k: int) -> bool:
        """At ``k`` each green of ``holding`` (phase, green onset) has time left before its maximum for ``p``'s
        clearance and ``q``'s minimum."""
        needed = self.clearance(p) + self.min[q]
        return all(self.time_left(o, green, k) >= needed for o, green in holding)

    def forward(self, o: int, k: int) -> bool:
        """At ``k`` the ring of ``o`` has a called phase after ``o`` in its barrier group to go on to."""
        return any(self.ring[x] == self.ring[o] and self.side[x] == self.side[o] and self.order[x] > self.order[o]
                   and self.serviceable(x, k, self.clearance(o)) for x in self.config.phases)

    def backed_with_call_across(self, e: Ending) -> bool:
        return self.backs_with_call_across(e) and not self.conditional_service(e)

    def backed_conditionally(self, e: Ending) -> bool:
        """A backing a setting gives: with a call across, as conditional service words it; with none, from a green
        that gapped or maxed out, by a side that backs at all (conditional service, or Naztec's backing, which asks
        no time of the other ring)."""
        if self.backs_with_call_across(e):
            return self.conditional_service(e)
        return (self.backs(e) and self.settings[e.side].conditional_service
                and self.ready(e.phase, e.green, e.yellow))

    def entered_past_force_off(self, e: Ending) -> bool:
        plan, q = self.plan, e.next
        if plan is None or q is None or q in plan.coord.values():
            return False
        return not plan.fits(q, self.local(e.next_green), 0)

    def pulled_across(self, e: Ending) -> bool:
        return e.alone and e.next is not None and self.side[e.next] != self.side[e.phase]

    def regapped(self, e: Ending, kept: Timeline) -> bool:
        """The green of ``e`` gapped out past its minimum (its call off) and its call came back later while
        ``kept`` still showed that green: one side held the gap-out, the other could re-extend."""
        p = e.phase
        until = next((c.tick for c in kept if c.phase == p and c.color is Color.YELLOW and c.tick > e.green), None)
        if until is None:
            until = len(self.called) - 1
        gap = next((k for k in range(e.green + self.min[p] - 1, e.yellow + 1) if p not in self.calls(k)), None)
        return gap is not None and any(p in self.calls(k) for k in range(gap + 1, until + 1))

    def goes_on(self, p: int, k: int, across: bool, shown: Mapping[int, int] | None = None) -> bool:
        """At tick ``k`` the ring of ``p`` (in our config) has a called phase of its group to go to after ``p``: a
        later one, or an earlier one while nothing waits ``across`` the barrier where ``p`` backs: Naztec's backing
        (``backup_prevent`` off), or conditional service with the time it asks of the other ring's greens
        (``shown``: phase -> green onset) not ready to end."""
        ph = self.config.phases[p]
        holding = [(o, green) for o, green in (shown or {}).items() if not self.ready(o, green, k, slack=0)]

        def backs(q: int) -> bool:
            return not across and (not ph.backup_prevent or (ph.conditional_service
                                                             and self.time_for(p, q, holding, k)))

        return any(q != p and self.ring[q] == self.ring[p] and self.side[q] == self.side[p]
                   and self.serviceable(q, k, self.clearance(p)) and (self.order[q] > self.order[p] or backs(q))
                   for q in self.ring)

    def could_leave(self, e: Ending, k: int, shown: Mapping[int, int]) -> bool:
        """At tick ``k`` the ring of ``e`` had somewhere to go: a called phase of its group, or across the barrier
        with every green of the other ring (``shown``: phase -> green onset) ready to end and going nowhere in the
        group either. With the other ring in its clearance it cannot tell, and says no."""
        p = e.phase
        across = any(self.side[x] != self.side[p] and self.serviceable(x, k, self.clearance(p)) for x in self.ring)
        if self.goes_on(p, k, across, shown):
            return True
        return across and bool(shown) and all(self.ready(o, green, k, slack=0) and not self.goes_on(o, k, across)
                                              for o, green in shown.items())

    def held_past_maximum(self, e: Ending, timeline: Timeline, tolerance: int) -> bool:
        """The green of ``e`` stayed on more than ``tolerance`` ticks after a tick at which it had maxed out (been
        forced off), to the tick, and its ring could leave it. A coordinated phase is left out: where it may end is
        a permissive period, a setting."""
        if self.plan is not None and e.phase in self.plan.coord.values():
            return False
        other = [c for c in timeline if self.ring[c.phase] != self.ring[e.phase] and c.tick < e.yellow]
        shown: dict[int, int] = {}
        i = 0
        for k in range(e.green + self.min[e.phase] - 1, e.yellow - tolerance):
            while i < len(other) and other[i].tick <= k:
                c = other[i]
                if c.color is Color.GREEN:
                    shown[c.phase] = c.tick
                else:
                    shown.pop(c.phase, None)
                i += 1
            if self.maxed(e.phase, e.green, k, slack=0) and self.could_leave(e, k, shown):
                return True
        return False


_CHECKS: dict[DifferenceClass, Callable[[Rules, Ending], bool]] = {
    ENDED_BEFORE_MIN: Rules.ended_before_min,
    ENDED_WHILE_EXTENDING: Rules.ended_while_extending,
    PULLED_ACROSS: Rules.pulled_across,
    SKIPPED: Rules.skipped,
    BACKED_WITH_CALL_ACROSS: Rules.backed_with_call_across,
    CONDITIONAL_SERVICE: Rules.backed_conditionally,
    ENTERED_PAST_FORCE_OFF: Rules.entered_past_force_off,
}


def endings(config: IntersectionConfig, timeline: Timeline, side: Side) -> list[Ending]:
    """Every green of ``timeline`` that ends, with where its ring went next and the other ring's greens beside it."""
    ring = {p: config.ring_of(p) for p in config.phases}
    yellows: dict[int, list[int]] = {}
    for c in timeline:
        if c.color is Color.YELLOW:
            yellows.setdefault(c.tick, []).append(c.phase)
    out = []
    green: dict[int, int] = {}
    shown: dict[int, int] = {}
    for i, c in enumerate(timeline):
        if c.color is Color.GREEN:
            green[c.phase] = shown[c.phase] = c.tick
        elif c.color is Color.YELLOW:
            shown.pop(c.phase, None)
            r = ring[c.phase]
            after = next((d for d in timeline[i + 1:] if d.color is Color.GREEN and ring[d.phase] == r), None)
            others = [q for k in (c.tick - 1, c.tick, c.tick + 1) for q in yellows.get(k, ()) if ring[q] != r]
            beside = tuple((q, t) for q, t in shown.items() if ring[q] != r)
            out.append(Ending(side, c.phase, green.get(c.phase, 0), c.tick, after and after.phase,
                              after and after.tick, not others, beside))
    return out


def classify(config: IntersectionConfig, called: Sequence[frozenset[int]], ours: Timeline, reference: Timeline,
             tick: int, tolerance: int = 1, plan: Plan | None = None,
             settings: Mapping[Side, Settings] | None = None) -> Judgement:
    """The class of the divergence starting at ``tick`` between ``ours`` and SUMO's ``reference``; ``plan``: the
    pattern both run (its force-off points, which SUMO lays out the same way: a sequence with every phase
    called agrees change for change)."""
    rules = Rules(config, called, plan, settings)
    near = [e for timeline, side in ((reference, Side.SUMO), (ours, Side.OURS))
            for e in endings(config, timeline, side)
            if e.yellow - tolerance <= tick <= (e.next_green if e.next_green is not None else e.yellow) + tolerance]
    for kind, check in _CHECKS.items():
        for e in near:
            if check(rules, e):
                return Judgement(tick, kind, None if kind.right is Right.SETTING else e.side, e.phase)
    for e in near:  # an end on one side that the other side did not make
        other = Side.OURS if e.side is Side.SUMO else Side.SUMO
        kept = reference if other is Side.SUMO else ours
        if any(c.phase == e.phase and c.color is Color.YELLOW and abs(c.tick - e.yellow) <= tolerance for c in kept):
            continue
        if (plan is not None and e.phase in plan.coord.values() and e.alone and e.next is not None
                and rules.side[e.next] == rules.side[e.phase]):
            return Judgement(tick, COORD_WAITS_FOR_OTHER_RING, None, e.phase)
        if plan is not None and e.phase in plan.coord.values():
            return Judgement(tick, PERMISSIVE_PERIOD, None, e.phase)
        if rules.maxed(e.phase, e.green, e.yellow) and _could_go_on(rules, e, kept):
            return Judgement(tick, HELD_PAST_MAXIMUM, other, e.phase)
        if rules.regapped(e, kept):
            return Judgement(tick, RE_EXTENDED, None, e.phase)
    return Judgement(tick, UNEXPLAINED, None, None)


def audit(config: IntersectionConfig, called: Sequence[frozenset[int]], ours: Timeline, tolerance: int = 1,
          plan: Plan | None = None, settings: Mapping[Side, Settings] | None = None) -> tuple[Judgement, ...]:
    """Every green ``ours`` ends, checked on its own against the rules a side keeps (those of the classes before
    the settings, and a green held past its maximum): the model's faults, whatever SUMO did there."""
    rules = Rules(config, called, plan, settings)
    faults = []
    for e in endings(config, ours, Side.OURS):
        kind = next((kind for kind, check in _CHECKS.items() if kind.right is Right.KEEPER and check(rules, e)), None)
        if kind is None and rules.held_past_maximum(e, ours, tolerance):
            kind = HELD_PAST_MAXIMUM
        if kind is not None:
            faults.append(Judgement(e.yellow, kind, Side.OURS, e.phase))
    return tuple(faults)


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
