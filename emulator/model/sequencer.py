"""The sequencer: which phase each ring serves next, the barrier, backing and conditional service, dual entry, the
committed next phase.

Rules of this file
------------------
- The sequencer chooses; the rings time (:mod:`emulator.model.ring`). It moves a ring only through the
  controller's ``move`` (which takes the ring's table, :meth:`emulator.model.ring.Ring.move`): a green ends
  only by :meth:`Sequencer.commit` committing the ring's next phase (or none), and a ring leaves DWELL only by
  :meth:`Sequencer.start` starting its committed phase.
- Every answer that depends on a running pattern comes from the coordinator's part in the rings
  (:mod:`emulator.model.coordinated`), which gives the free answer when none runs.
- It reads the inputs of the tick (:class:`emulator.model.inputs.Inputs`, the demand) as the controller hands
  them; its own state is the barrier group being served and what it worked out before the rings timed.

Theory of operation
-------------------
Both rings work inside one barrier group (``group``) at a time, so any two phases they show are concurrent by
the ring-and-barrier structure. A green is *ready to end* when it has timed its minimum (and Walk plus
pedestrian clearance if it served a walk), is not held, and has gapped out, maxed out or been forced off
(:meth:`Sequencer.ending`). A green without anywhere to go rests in green, maxed out or not.

A ready ring *wishes* for the nearest phase with demand in its ring order after its own (1, 2, 3, 4, 1, ...).
Within the barrier group it goes there at once when that is forward. Backing into an earlier phase of the group
while the other ring still times is an option, never the default: NTCIP 1202 gives it as phaseOptions bit 14,
"Conditional Service Enable - in multi-ring configurations when set to 1 causes a gapped/maxed phase to
conditionally service a preceding actuated vehicle phase when sufficient time remains before max time out of the
phase(s) not prepared to terminate. Support is optional" (its default, like every phaseOptions bit's, is clear),
and the field logs replayed for issue 35 never show a ring backing. So a ring backs from a phase with
``conditional_service`` once its green is ready to end and every other ring's green not ready to end has time
left before its maximum for the clearance and the earlier phase's minimum (:meth:`_conditional`). Naztec's
controllers back by default, "into a protected left-turn phase when the cross street phases and the opposing
left-turn are skipped" (Naztec TecNote 3013), unless their Backup Prevent is set: ``backup_prevent = false``
gives that, backing only while no demand waits across the barrier; ``backup_prevent`` is true by default. A
backing refused counts as a wish beyond the barrier (the phase waits for the group's next visit, or, with
nothing across, both rings clear and restart the group for it); when both rings are ready and one wishes
beyond, the other does not back either (crossing goes first). While a pattern runs, no ring backs while
``backup_prevent`` makes another restart the group, even before that one is ready: backed into its
coordinated phase, it would rest there to its yield point and hold the restart for a cycle (:meth:`_beyond`
says why). A wish beyond the barrier is served only when every ring is ready (or idle in red) and wishes
beyond or nowhere: then all rings clear together into the new group, a ring without demand there taking its
``dual_entry`` phase if it has one and resting in red otherwise. Until then the ring wishing across keeps its
green (it waits at the barrier).

The next phase is *committed at the start of yellow* (shown in phaseStatusGroupPhaseNexts from then). With
``next_phase_lock = "green_end"`` (the default; NTCIP 1202: PhaseNext "shall be determined at the end of the
green interval of the terminating phase") a call arriving during the clearance does not redirect it. With
``"red_end"`` (controllers that lock their detectors at the start of red, SUMO issue 9989) a call during the
yellow or red clearance redirects the ring to the nearest phase with demand on the committed phase's side of
the barrier. A committed phase that loses its call during the clearance is still served (its minimum green,
then it ends as usual): NEMA TS 2 commits Phase Next at the end of the green, and SUMO's NEMA controller,
validated against Econolite SIL, does the same (NEMAController.cpp, NEMAPhase::exit enters
``lastTransitionDecision`` at the end of red without re-checking its call). A committed phase that is
*omitted* during the clearance is dropped: the ring ends its clearance in red with nothing committed and
chooses again at the next tick, because phaseControlGroupPhaseOmit (NTCIP 1202) says an omitted phase is not
serviced. A committed phase starts when its ring's clearance is over, no other ring still shows a phase of
another barrier group (both rings enter a new group together) and its red revert since its own last yellow
has passed. Omitted phases never start; ForceOff bits clear themselves when that phase's green ends.

An overlap that will still show green or yellow after this tick (its own trailing green, yellow and red
after its parents ended, or a green whose included next was taken away) holds back a committed phase that
conflicts with it until it has cleared, as controllers do when their overlap clearance locks the next phase;
a minus-green-yellow overlap's modifier waits for it likewise (:meth:`emulator.model.overlaps.Overlaps.blocks`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, MutableMapping, Sequence
from typing import TYPE_CHECKING

from emulator.model.coordinated import Coordinated
from emulator.model.inputs import Inputs
from emulator.model.overlaps import Overlaps, Phases
from emulator.model.preemption import Preemptor
from emulator.model.ring import DWELL, END, GREEN, RED_CLEAR, START, TIMED, Ring, Termination, Timing
from hils.protocol.config import IntersectionConfig, NextPhaseLock
from hils.protocol.ntcip import ControlColumn

if TYPE_CHECKING:
    from emulator.model.preempted import Preempted

# The control objects read every tick, bound once (as ring.py binds the intervals).
FORCE_OFF, PHASE_OMIT = ControlColumn.FORCE_OFF, ControlColumn.PHASE_OMIT
FORCED_OFF = Termination.FORCE_OFF

#: How the sequencer moves a ring: the controller's move (the ring's table, and what the other units do then).
Move = Callable[..., None]


class Sequencer:
    """The ring sequence of one controller: the barrier group served, the decisions of each tick."""

    def __init__(self, config: IntersectionConfig, rings: Sequence[Ring], timing: Mapping[int, Timing],
                 control: MutableMapping[ControlColumn, frozenset[int]], coordinated: Coordinated,
                 preemptor: Preemptor, overlaps: Overlaps, move: Move) -> None:
        self.config = config
        self.rings = rings
        self.timing = timing
        self.control = control
        self.coordinated = coordinated
        self.preemptor = preemptor
        self.overlaps = overlaps
        self.move = move
        self._barrier = {p: config.barrier_of(p) for p in config.phases}
        self._order = {p: ring.index(p) for ring in config.rings for p in ring}
        self._ring_of = {p: config.ring_of(p) for p in config.phases}
        # The phases of each barrier group and of each ring, as sets: the tick's questions about demand are set
        # operations on them.
        self._group_phases = [frozenset(p for p in config.phases if self._barrier[p] == g)
                              for g in range(len(config.barriers))]
        self._ring_phases = {n: frozenset(order) for n, order in enumerate(config.rings, start=1)}
        # Where a ring looks for its next phase (:meth:`wish`): from its phase (None: the first of its order) on, in
        # ring order, each phase with the one before it; resting in red, its own phase last.
        self._ahead = {(p, dwell): tuple((order[(i + k - 1) % len(order)], order[(i + k) % len(order)])
                                         for k in range(1, len(order) + dwell))
                       for order in config.rings for i, p in enumerate(order) for dwell in (False, True)}
        self._ahead |= {(None, n, dwell): self._ahead[order[0], dwell]
                        for n, order in enumerate(config.rings, start=1) for dwell in (False, True)}
        self._red_end = config.next_phase_lock is NextPhaseLock.RED_END
        self._gap_disable = frozenset(p for p, ph in config.phases.items() if ph.simultaneous_gap_disable)
        # The backings conditional service may allow (:meth:`_conditional`): from a phase with the option into an
        # earlier phase of its ring and barrier group.
        self._conditional_pairs = tuple((p, q) for order in config.rings for i, p in enumerate(order)
                                        if config.phases[p].conditional_service
                                        for q in order[:i] if self._barrier[q] == self._barrier[p])
        self.reset()

    def reset(self) -> None:
        self.group = 0
        self.waiting_across = False  # demand on a phase of another barrier group, this tick
        self.restarting = False  # a pattern runs and a ring must restart its group through the barrier, this tick

    def barrier_of(self, phase: int) -> int:
        return self._barrier[phase]

    # --- before the rings time ---------------------------------------------------------------------------

    def prepare(self, demand: frozenset[int], inputs: Inputs) -> None:
        """What the tick's decisions read before the rings time: demand across the barrier, a group restart."""
        if not self.coordinated.running:  # free: any demand across counts, and no group restarts for a pattern
            self.waiting_across, self.restarting = not demand <= self._group_phases[self.group], False
            return
        self.waiting_across = self.waits_across(demand, inputs)
        self.restarting = any(self._restarts(r, demand, inputs) for r in self.rings)

    def waits_across(self, demand: frozenset[int], inputs: Inputs) -> bool:
        """Demand waits across the barrier (which forbids backing); while a pattern runs only demand that can still
        be served in this cycle counts (a phase past its permissive period is skipped anyway), measured as its own
        ring measures it (:meth:`serviceable`)."""
        group = self._group_phases[self.group]
        return any(q not in group
                   and self.coordinated.fits(self.rings, self.rings[self._ring_of[q] - 1], q, demand, inputs)
                   for q in demand)

    def _restarts(self, r: Ring, demand: frozenset[int], inputs: Inputs) -> bool:
        """``r``'s next service is a backing that ``backup_prevent`` on its phase forbids: the ring will restart its
        barrier group through the barrier (see :meth:`_beyond`)."""
        if r.phase is None or not self.config.phases[r.phase].backup_prevent or not (
                r.interval is GREEN or (r.interval is DWELL and r.target is None)):
            return False
        q = self.wish(r, demand, inputs)
        return (q is not None and self._backing(r, q)
                and not (self.config.phases[r.phase].conditional_service and self._conditional(r, q)))

    def redirect(self, r: Ring, demand: frozenset[int], inputs: Inputs) -> None:
        """``red_end`` lock: a ring in its clearance takes the nearest phase with demand after its own on the
        committed phase's side of the barrier (SUMO's ``NEMAPhase::trySwitch`` lets a later call override the
        decision "only if the new transition is on the same side of a barrier"); without one it keeps it."""
        r.target = self._redirected(r, demand, inputs)

    def _redirected(self, r: Ring, demand: frozenset[int], inputs: Inputs) -> int:
        """The phase :meth:`redirect` commits ``r`` to."""
        side = self._barrier[r.target]
        n, i = len(r.order), self._order[r.phase]
        for k in range(1, n):
            q = r.order[(i + k) % n]
            if (self._barrier[q] == side and self.serviceable(r, q, demand, inputs)
                    and (side != self.group or not self._beyond(q))):
                return q
        return r.target

    def time(self, demand: frozenset[int], inputs: Inputs, tick: int) -> None:
        """One tick of the rings' timers (a green's with the demand conflicting with it); a clearance that has run
        its length moves on (a red clearance a preempt's entry cut to nothing ends on the tick it starts)."""
        for r in self.rings:
            interval = r.interval
            if interval is GREEN:
                max_recall = r.phase in inputs.extending
                r.time_green(extending=r.phase in inputs.calls or max_recall, conflict=self.conflicting(r, demand),
                             max_recall=max_recall, gap_disable=r.phase in self._gap_disable)
            elif interval is not DWELL and r.time_clearance(tick):
                self.move(r, TIMED)
                if r.interval is RED_CLEAR and r.length == 0:
                    self.move(r, TIMED)

    # --- what a ring may do ------------------------------------------------------------------------------

    def _backing(self, r: Ring, q: int) -> bool:
        """Serving ``q`` next would back ``r`` up: ``q`` comes before the ring's phase in their barrier group."""
        p = r.phase
        return p is not None and self._barrier[p] == self._barrier[q] and self._order[q] < self._order[p]

    def _beyond(self, q: int) -> bool:
        """True when a phase with demand cannot be served in this visit of the barrier group: it lies across
        the barrier, or its ring would have to back into it while demand waits across the barrier, from a
        phase with ``backup_prevent``, or (a pattern running) while another ring restarts the group.

        The last case keeps the coordinated phases served. A ring that ``backup_prevent`` keeps from backing
        restarts its group through the barrier, which takes every ring: Naztec TecNote 3013 gives the option's
        purpose, to "insure that the controller never 'backs into' a protected left-turn phase", so it holds under
        coordination too. Had the other ring backed meanwhile into its coordinated phase, that phase would rest
        to its yield point a cycle later and hold the restarting ring at the barrier until then, its own
        coordinated phase unserved for that cycle. No source found (NTCIP 1202 defines no backup prevent; SUMO's
        NEMA controller has none) says what a controller does here; this choice keeps coordination's promise,
        every coordinated phase served every cycle, and in free mode (where a backed phase ends by its maximum)
        nothing changes."""
        if self._barrier[q] != self.group:
            return True
        r = self.rings[self._ring_of[q] - 1]
        if not self._backing(r, q):
            return False
        option = self.config.phases[r.phase]
        if option.conditional_service and self._conditional(r, q):
            return False
        return self.waiting_across or option.backup_prevent or self.restarting

    def _conditional(self, r: Ring, q: int) -> bool:
        """``r`` may back into ``q`` as conditional service (NTCIP 1202 phaseOptions bit 14): its green has gapped
        or maxed out, and every green of another ring "not prepared to terminate" has time left before its maximum
        for ``r``'s clearance and ``q``'s minimum. With none of them (every other ring ready, or in its clearance) the
        condition holds: nothing times out on the way. While a pattern runs the force-off points replace the
        maximum, and :meth:`serviceable` has already asked that ``q`` fits before its own."""
        if not self._prepared(r):
            return False
        timing = self.timing
        needed = timing[r.phase].yellow + timing[r.phase].red_clear + timing[q].min_green
        return self.coordinated.running or all(o.maximum - o.max_ticks >= needed for o in self.rings
                                               if o is not r and o.interval is GREEN and not self._prepared(o))

    def _prepared(self, r: Ring) -> bool:
        """``r`` shows a green "prepared to terminate": past its minimum, gapped or maxed out (or forced off)."""
        return r.interval is GREEN and r.ticks >= r.minimum and self.coordinated.ending(r) is not None

    def conflicting(self, r: Ring, demand: frozenset[int]) -> bool:
        """Demand conflicts with ``r``'s green: in its own ring, or beyond this visit of the barrier group."""
        p, ring, group = r.phase, self._ring_phases[r.number], self._group_phases[self.group]
        for q in demand:  # noqa: SIM110 - asked of every green at every step: a loop costs less than any() of a generator
            # demand of another ring in this group is beyond this visit only where that ring may not back
            if q != p and (q in ring or q not in group or self._beyond(q)):
                return True
        return False

    def ending(self, r: Ring, inputs: Inputs) -> Termination | None:
        """Why the ring's green may end now (None: it may not); a force-off before a gap-out before a max-out."""
        if r.interval is not GREEN or r.ticks < r.minimum or r.phase in inputs.holds:
            return None
        if r.phase in self.control[FORCE_OFF]:
            return FORCED_OFF
        return self.coordinated.ending(r)

    def wish(self, r: Ring, demand: frozenset[int], inputs: Inputs) -> int | None:
        """The nearest phase with demand after the ring's own, in ring order (a ring resting in red may re-serve
        its own phase, last in the order); a ring showing its coordinated phase leaves it only in the next phase's
        permissive period (:meth:`emulator.model.coordinated.Coordinated.stays`)."""
        dwell = r.interval is DWELL
        ahead = self._ahead[r.phase, dwell] if r.phase is not None else self._ahead[None, r.number, dwell]
        running = self.coordinated.running
        for prior, q in ahead:
            if q in demand and (not running or self.coordinated.fits(self.rings, r, q, demand, inputs)):
                if running and self.coordinated.stays(r, prior):
                    return None  # outside q's permissive period the coordinated phase stays
                return q
        return None

    def serviceable(self, r: Ring, q: int, demand: frozenset[int], inputs: Inputs) -> bool:
        """``q`` has demand and fits what the running pattern leaves (:meth:`Coordinated.fits`)."""
        return q in demand and self.coordinated.fits(self.rings, r, q, demand, inputs)

    # --- after the rings timed -----------------------------------------------------------------------------

    def decide(self, demand: frozenset[int], inputs: Inputs, omitted: frozenset[int] = frozenset()) -> None:
        """Commit the next phase of every ready ring that may go: within the group at once, across the barrier
        when every ring is ready for it (``omitted``: phases never entered, besides PhaseOmit's, as a preempt's dwell
        omits those that may not cycle)."""
        commits, across = self._choices(demand, inputs)
        for r, q in commits:
            self.commit(r, q, inputs)
        if across:
            self._cross(across, demand, inputs, omitted)

    def _choices(self, demand: frozenset[int], inputs: Inputs) -> tuple[list[tuple[Ring, int]], dict[int, int]]:
        """What :meth:`decide` does: the commits within the group, or else the wishes beyond it when every ring may
        cross (empty: the ring wishing across waits at the barrier). A commit within the group keeps its ring from
        crossing, so the two never come together."""
        ready = {}  # a green that may end now, or a ring resting in red with nothing committed
        for r in self.rings:
            ready[r.number] = r.target is None if r.interval is DWELL else self.ending(r, inputs) is not None
        if True not in ready.values():
            return [], {}  # most ticks: every ring is timing
        wish, across = {}, {}
        for r in self.rings:
            if ready[r.number]:
                q = wish[r.number] = self.wish(r, demand, inputs)
                if q is not None and self._beyond(q):
                    across[r.number] = q
        all_ready = False not in ready.values()
        commits = []
        for r in self.rings:
            q = wish.get(r.number)
            if q is None or r.number in across:
                continue
            if r.interval is GREEN and self._order[q] < self._order[r.phase] and all_ready and across:
                wish[r.number] = None  # both rings could cross: crossing goes before backing
                continue
            commits.append((r, q))
        if commits or not across or not all(ready[r.number] and (wish[r.number] is None or r.number in across)
                                            for r in self.rings):
            return commits, {}
        return [], across

    def _cross(self, across: dict[int, int], demand: frozenset[int], inputs: Inputs, omitted: frozenset[int]) -> None:
        """Every ring clears into the next barrier group a wish lies in (``omitted``: as :meth:`decide` says)."""
        # Cross to the nearest group (cyclically) that a wish lies in; restart the group only when every
        # wish beyond it is a backing that backup_prevent forbids (crossing serves those on the way back).
        groups = {self._barrier[q] for q in across.values()}
        n = len(self.config.barriers)
        self.group = next(g for g in ((self.group + k) % n for k in range(1, n + 1)) if g in groups)
        for r in self.rings:
            target = across.get(r.number)
            if target is None or self._barrier[target] != self.group:
                # Nearest demand of the ring in the new group; a restarted group serves its own phase again.
                target = next((q for q in r.order if self._barrier[q] == self.group
                               and self.serviceable(r, q, demand, inputs)), None)
            if target is None:
                omit = self.control[PHASE_OMIT] | omitted
                target = next((q for q in r.order if self._barrier[q] == self.group
                               and self.config.phases[q].dual_entry and q not in omit), None)
            self.commit(r, target, inputs)

    def commit(self, r: Ring, target: int | None, inputs: Inputs) -> None:
        """Commit the ring's next phase: a green ends (yellow starts), a resting red ring takes it."""
        r.target = target
        if r.interval is GREEN:
            reason = self.ending(r, inputs)
            self.control[FORCE_OFF] -= {r.phase}
            self.move(r, END, reason=reason)

    def start(self, tick: int) -> None:
        """Each ring resting in red starts its committed phase when it may."""
        for r in self.rings:
            if r.interval is not DWELL or r.target is None or not self._starts(r, tick):
                continue
            t = r.target
            if t in self.control[PHASE_OMIT] and self.preemptor.serving is None:
                r.target = None  # omitted during the clearance: not serviced, choose again (a preempt overrides omits)
                continue
            r.phase, r.target = t, None
            self.move(r, START)

    def _starts(self, r: Ring, tick: int, phases: Phases | None = None) -> bool:
        """``r``, resting in red with a committed phase, starts it at ``tick`` (or drops it, omitted): its
        clearance is over, no other ring still shows a phase of another barrier group (both rings enter a new
        group together), its red revert has passed and no overlap it waits for still shows after this tick
        (``phases``: what the phases show as the overlaps step; by default, what they show now)."""
        t = r.target
        if t in self.control[PHASE_OMIT] and self.preemptor.serving is None:
            return True
        if r.reverting(t, tick, self.timing[t]):
            return False
        side = self._barrier[t]
        for o in self.rings:
            if o is not r and o.interval is not DWELL and self._barrier[o.phase] != side:
                return False
        # an overlap it waits for still shows (or clears) after this tick
        return not (self.config.overlaps and self.overlaps.blocks(t, Phases.of(self.rings) if phases is None
                                                                  else phases))

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def deadline(self, tick: int, demand: frozenset[int], inputs: Inputs, phases: Phases | None,
                 preempted: Preempted) -> int | None:
        """Ticks to the next step at which the sequencer or a ring acts, inputs and ``demand`` staying as they are
        (None: none ahead); ``phases``: what the phases show at the next tick if no ring moves (None: no overlaps
        to ask).

        1 when the next step decides something: a green's timers start or stop running or the conflicting demand it
        registered changes, a ``red_end`` call redirects a clearing ring, a ready ring commits its wish or the
        rings cross the barrier (:meth:`_choices`; in a preempt's dwell with cycling phases too, on their demand),
        or a committed phase starts (:meth:`_starts`). Each question is the step's own, asked now: until a counter
        reaches a threshold (the rest of the answer) it answers the same at every tick. The thresholds: each ring's
        timers as the pattern and a preempt being served set them too, and what conditional service compares
        (:meth:`_conditional_thresholds`). A green's minimum matters only with conflicting demand (registered by the
        last step, and constant in quiet time): without any, the ready green has nowhere to go and no ring waits
        across the barrier for it. While a pattern runs or a preempt is served it may be what ends it, and with
        conditional service it makes a green "prepared to terminate"."""
        serving = self.preemptor.serving is not None
        cycling = preempted.cycling(demand) if serving else None
        if cycling is not None:
            demand = cycling[0]  # a preempt's dwell with cycling phases: the rings cycle as the sequencer runs them
        minimums = self.coordinated.running or serving or bool(self._conditional_pairs)
        ahead: list[int] = self._conditional_thresholds()
        for r in self.rings:
            ahead += r.thresholds(tick, self.timing, minimum=minimums or r.conflict)
            if minimums and r.interval is GREEN:
                ahead += self.coordinated.thresholds(r) + preempted.thresholds(r)
        least = min(ahead, default=None)
        if least == 1:
            return 1  # a real step anyway: no question needs asking
        redirecting = self._red_end and not serving
        self.prepare(demand, inputs)  # what the next step reads first, as it will read it
        for r in self.rings:
            interval = r.interval
            if interval is GREEN:
                max_recall = r.phase in inputs.extending
                if not r.steady(extending=r.phase in inputs.calls or max_recall,
                                conflict=self.conflicting(r, demand), max_recall=max_recall):
                    return 1
            elif interval is DWELL:
                if r.target is not None and self._starts(r, tick + 1, phases):
                    return 1
            elif redirecting and r.target is not None and self._redirected(r, demand, inputs) != r.target:
                return 1
        if (not serving or cycling is not None) and any(self._choices(demand, inputs)):
            return 1
        return least

    def _conditional_thresholds(self) -> list[int]:
        """Ticks from now to each reading of a running maximum timer at which its green stops leaving the time a
        conditional service asks (:meth:`_conditional`: a clearance and the earlier phase's minimum); a green's
        minimum, which makes it "prepared to terminate", is a threshold too while any phase has the option."""
        if not self._conditional_pairs:
            return []
        timing = self.timing
        needs = {timing[p].yellow + timing[p].red_clear + timing[q].min_green for p, q in self._conditional_pairs}
        return [o.maximum - n + 1 - o.max_ticks for o in self.rings if o.interval is GREEN and o.max_ticks
                for n in needs if o.max_ticks <= o.maximum - n]
