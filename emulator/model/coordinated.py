"""The coordinator's part in the rings: force-off and yield latches, floating limits, what fits before a force-off.

Rules of this file
------------------
- The coordinator (:mod:`emulator.model.coordination`) decides *when*: which pattern runs, where in the cycle,
  which points the local timer passed this tick. This unit turns that into what each ring may do; the rings
  (:mod:`emulator.model.ring`) and the sequencer (:mod:`emulator.model.sequencer`) ask it and never read a
  cycle position themselves. Every question here has the free answer when no pattern runs.
- Its latches move only in :meth:`Coordinated.step` (once per tick, after the coordinator stepped, before the
  rings time) and :meth:`Coordinated.entered` (a ring entered an interval); time is integer ticks.

Theory of operation
-------------------
While a pattern runs, a green that is not a coordinated phase ends at its phase's *force-off point*: it is
*forced* once the local timer passes that point or when it starts past it (``forced``), and with floating
force-offs (coordForceMode) it may last its split less its clearance at most (``limit``). Coordination
inhibits the maximum: the force-off points limit a green, which may still gap out before. A coordinated
phase ends only after its ring's *yield point* passed since it last ended (``yielded``), never gapped or
maxed out.

A ring leaves its coordinated phase for a phase only in that phase's permissive period
(:meth:`emulator.model.coordination.Plan.permitted`: sequential periods, as SUMO's
``PhaseTransitionLogic::fromCoord``, written to match Econolite software-in-the-loop, SUMO pull request
10082). A phase with demand is served only if it still fits before its force-off point once its ring has
cleared, and with it every ring showing a phase of another barrier group (rings cross a barrier together);
a phase that does not fit is skipped: its time goes to the phases after it.

The walk is served only if it and the pedestrian clearance end by the phase's force-off point; otherwise the
call stays latched for the next cycle, and a phase wanted by its pedestrian call alone is skipped. A
controller without stop-in-walk keeps to its splits, and stop-in-walk "will allow an occasional pedestrian
call to push the controller out of coordination" (Naztec, Coordination Modes+, MM->2->1).

Deadlines. While a pattern runs a green's minimum and its floating limit are thresholds of the rings
(:meth:`Coordinated.thresholds`); the coordinator's own marks are its ``deadline``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from emulator.model.coordination import Coordinator
from emulator.model.inputs import Inputs
from emulator.model.ring import DWELL, GREEN, YELLOW, Ring, Termination, Timing
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import CoordForceMode

# Bound once, as ring.py binds the intervals: the sequencer asks why a green may end many times a tick.
YIELD, GAP_OUT, FORCE_OFF, MAX_OUT = Termination.YIELD, Termination.GAP_OUT, Termination.FORCE_OFF, Termination.MAX_OUT


class Coordinated:
    """The rings under the running pattern: each ring's latches, and the pattern's answers to the sequencer."""

    def __init__(self, config: IntersectionConfig, coordinator: Coordinator, timing: Mapping[int, Timing]) -> None:
        self.coordinator = coordinator
        self.timing = timing
        self._barrier = {p: config.barrier_of(p) for p in config.phases}
        self._numbers = range(1, len(config.rings) + 1)
        self.reset()

    def reset(self) -> None:
        """Power-up: no latch set, no pattern placed yet."""
        # Per ring: its green passed its force-off point or started past it; the green ticks a floating force-off
        # allows (0: none); its yield point passed since its coordinated phase last ended.
        self.forced = dict.fromkeys(self._numbers, False)
        self.limit = dict.fromkeys(self._numbers, 0)
        self.yielded = dict.fromkeys(self._numbers, False)
        self._placed = None  # the plan the latches were placed under

    @property
    def running(self) -> bool:
        """A pattern runs."""
        return self.coordinator.plan is not None

    def step(self, rings: Sequence[Ring]) -> None:
        """After the coordinator's tick: the latches follow the points it passed; a new pattern places every ring."""
        co = self.coordinator
        plan = co.plan
        if plan is not self._placed:  # a pattern started (or the unit powered up in one): where is each ring?
            self._placed = plan
            for r in rings:
                self.yielded[r.number] = plan is not None and not plan.held(plan.coord[r.number], co.timer)
                self._place(r)
            return
        if plan is None:
            return
        for r in rings:
            if plan.force_off[plan.coord[r.number]] in co.passed:
                self.yielded[r.number] = True
            if (r.interval is GREEN and r.phase not in plan.coord.values()
                    and plan.force_off[r.phase] in co.passed):
                self.forced[r.number] = True

    def entered(self, r: Ring) -> None:
        """``r`` entered an interval: a coordinated phase's yellow waits for the next yield point, a green is placed."""
        plan = self.coordinator.plan
        if plan is not None and r.phase == plan.coord[r.number] and r.interval is YELLOW:
            self.yielded[r.number] = False
        if r.interval is GREEN:
            self._place(r)

    def _place(self, r: Ring) -> None:
        """A green starts (or a pattern starts under it): its force-off latch and floating limit."""
        plan, co = self.coordinator.plan, self.coordinator
        if plan is None or r.interval is not GREEN or r.phase in plan.coord.values():
            self.forced[r.number], self.limit[r.number] = False, 0
            return
        self.forced[r.number] = not plan.in_window(r.phase, co.timer)
        floating = co.force_mode is CoordForceMode.FLOATING
        self.limit[r.number] = plan.split[r.phase] - plan.clearance[r.phase] if floating else 0

    # --- what the rings ask --------------------------------------------------------------------------

    def ending(self, r: Ring) -> Termination | None:
        """Why a green past its minimum, neither held nor forced off by the control objects, may end: free, a
        gap-out before a max-out; while a pattern runs, a coordinated phase at its yield point, another by a
        gap-out or its force-off (the maximum inhibited)."""
        plan = self.coordinator.plan
        if plan is not None and r.phase == plan.coord[r.number]:
            # a coordinated phase ends only after its yield point, never gapped or maxed out
            return YIELD if self.yielded[r.number] else None
        if r.gapped_out:
            return GAP_OUT
        if plan is not None:  # coordination inhibits the maximum: the force-off points limit a green
            limit = self.limit[r.number]
            return FORCE_OFF if self.forced[r.number] or (limit > 0 and r.ticks >= limit) else None
        return MAX_OUT if r.maxed_out else None

    def stays(self, r: Ring, prior: int) -> bool:
        """``r`` shows its coordinated phase in green and may not leave it for the phase after ``prior``: that
        phase's permissive period is closed."""
        plan = self.coordinator.plan
        return (plan is not None and r.interval is GREEN and r.phase == plan.coord[r.number]
                and not plan.permitted(prior, self.coordinator.timer))

    def fits(self, rings: Sequence[Ring], r: Ring, q: int, demand: frozenset[int], inputs: Inputs) -> bool:
        """Phase ``q`` (with demand) still fits before its force-off point once ``r`` has cleared, and with it
        every ring showing a phase of another barrier group than ``q``'s; always, free."""
        plan = self.coordinator.plan
        if plan is None:
            return True
        side = self._barrier[q]
        timing = self.timing
        clear = max(o.clearance_left(None if o.phase is None else timing[o.phase]) for o in rings
                    if o is r or (o.interval is not DWELL and self._barrier[o.phase] != side))
        # wanted for a vehicle, not only for its pedestrian call (soft recall counts as demand counts it: when
        # nothing else wants service)
        vehicle = (q in inputs.calls and q not in inputs.omits) or q in inputs.recalled or (
            q in inputs.soft and demand <= inputs.soft)
        return plan.fits(q, self.coordinator.timer, clear, walk=not vehicle and timing[q].walk > 0)

    def walk_fits(self, phase: int) -> bool:
        """A green of ``phase`` starting now may serve its walk: no pattern runs, or its walk and pedestrian
        clearance end by its force-off point."""
        plan = self.coordinator.plan
        return plan is None or plan.fits(phase, self.coordinator.timer, 0, walk=True)

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def thresholds(self, r: Ring) -> list[int]:
        """Ticks from now to the floating limit of ``r``'s green, if it has one still ahead, and to each point where a
        phase stops fitting after the clearance of ``r``'s green (:meth:`fits`) as its phase's timing is now: a SET of
        the phase table may have moved it off the clearances the plan was laid out with, which the coordinator's own
        marks hold (:meth:`emulator.model.coordination.Plan.marks`)."""
        if r.interval is not GREEN:
            return []
        limit = self.limit[r.number]
        ahead = [limit - r.ticks] if r.ticks < limit else []
        plan = self.coordinator.plan
        if plan is not None:
            timing = self.timing[r.phase]
            clearance = timing.yellow + timing.red_clear
            if clearance not in plan.clearance.values():
                ahead.append(self.coordinator.until(plan.unfit(clearance)))
        return ahead
