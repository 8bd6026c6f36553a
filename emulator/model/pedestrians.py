"""The pedestrian calls: latched until a green serves their walk.

Rules of this file
------------------
- The latched calls change only here: :meth:`PedCalls.latch` once per tick before the rings time, and
  :meth:`PedCalls.serve` as a green starts. The set is replaced, never changed in place, and kept as it is while it
  holds the same calls (the data logger compares it by identity every tick).
- What latches is :func:`emulator.model.inputs.latched`; whether a walk fits a running pattern is the
  coordinator's part in the rings (:meth:`emulator.model.coordinated.Coordinated.walk_fits`).

Theory of operation
-------------------
A pedestrian call (phaseControlGroupPedCall, pedestrian recall, the pattern's pedestrian recall, a push button)
latches on a phase not showing green and stays until a green of its phase serves a walk. A green serves one when
it starts with the call latched, the phase has a walk time and, while a pattern runs, the walk and the pedestrian
clearance end by the phase's force-off point; a call the green does not serve stays latched for the next cycle.
PedOmit (and an omitted phase) stops new calls latching; a walk being timed completes. A push button latches
nothing on its phase while that phase times its walk (:func:`emulator.model.inputs.latched`).

*Pedestrian recycle* (``ped_recycle``, per phase; off by default). NTCIP 1202 words the pedestrian service of a
phase's own green as recyclable: Ped Recall "shall function in the same manner as an external pedestrian call
except that it shall not recycle the pedestrian service until a conflicting phase is serviced" (phaseOptions bit
8), so an external call may recycle it; controllers give it as an option (Intelight MaxTime's field log of issue
35 shows 7 of 27 walks starting within a green already running, 0.2 s after the push). Where the phase has it, a
call latched while its green runs and times no walk or pedestrian clearance (a push button latches then,
:func:`emulator.model.inputs.latched`) starts a walk within that green at once (:meth:`PedCalls.recycle`), the green
lasting to the end of its pedestrian clearance, when that end comes before the green's maximum would (free: its
maximum timer, running or not, has the walk and clearance left) or, while a pattern runs, by the phase's force-off
point. Otherwise the call stays latched for the next green, as without the option. A preempt being served recycles
nothing (its entry ends walks).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from emulator.model import inputs as reading
from emulator.model.coordinated import Coordinated
from emulator.model.inputs import Inputs
from emulator.model.ring import GREEN, Ring, Timing


class PedCalls:
    """One controller's latched pedestrian calls."""

    def __init__(self, timing: Mapping[int, Timing], coordinated: Coordinated, recycling: frozenset[int],
                 rings: Sequence[Ring]) -> None:
        self.timing = timing
        self.coordinated = coordinated
        self.recycling = recycling  # the phases with pedestrian recycle
        self.rings = rings  # the controller's, to see which phases time their walk
        self.reset()

    def reset(self) -> None:
        """Power-up: no call latched."""
        self.calls: frozenset[int] = frozenset()
        # The last answers of latched() and demand() and what they were asked with: the step and quiet time ask the
        # same questions of the same (immutable) sets, mostly.
        self._latched: tuple[tuple, frozenset[int]] = ((None, None, None, None), frozenset())
        self._demand: tuple[tuple, frozenset[int]] = ((None, None), frozenset())

    def latch(self, greens: frozenset[int], inputs: Inputs) -> frozenset[int]:
        """This tick's calls latch (``greens``: the phases showing green); the demand they make with the inputs."""
        calls = self.latched(greens, inputs)
        if calls != self.calls:
            self.calls = calls
        return self.demand(inputs)

    def demand(self, inputs: Inputs) -> frozenset[int]:
        """The demand the latched calls make with the inputs (:func:`emulator.model.inputs.demand`)."""
        asked, answer = self._demand
        if asked[0] is not inputs or asked[1] is not self.calls:
            answer = reading.demand(inputs, self.calls)
            self._demand = (inputs, self.calls), answer
        return answer

    def deadline(self, greens: frozenset[int], inputs: Inputs) -> int | None:
        """1 when the next tick latches a call (``greens``: the phases showing green then), else None: the calls
        change only with the inputs and the greens.

        Pedestrian recycle needs no deadline of its own: every real step checks it after the rings timed, and what it
        waits for turns true only at a real step. A latched call waits for its green's walk and pedestrian clearance
        to end (a threshold its ring reports) and for the walk to fit: free, by the green's maximum, which only
        draws nearer (or starts again, at the step its conflicting demand goes); under a pattern, by the phase's
        force-off point, which only draws nearer until its ring's yield point passes (one of the coordinator's
        marks); during a preempt none recycles, and its end is the preemptor's step."""
        return 1 if self.latched(greens, inputs) != self.calls else None

    def walking(self) -> frozenset[int]:
        """The phases timing their walk now."""
        return frozenset(r.phase for r in self.rings if r.interval is GREEN and r.ticks < r.walk)

    def latched(self, greens: frozenset[int], inputs: Inputs) -> frozenset[int]:
        """The calls the next latch leaves (``greens``: the phases showing green), changing nothing
        (:func:`emulator.model.inputs.latched`, a push button latching nothing on a phase timing its walk)."""
        asked, answer = self._latched
        walking = self.walking() if inputs.pushed else frozenset()
        if asked[0] is not self.calls or asked[1] is not greens or asked[2] is not inputs or asked[3] != walking:
            answer = reading.latched(self.calls, greens, inputs, walking)
            self._latched = (self.calls, greens, inputs, walking), answer
        return answer

    def serve(self, phase: int) -> bool:
        """A green of ``phase`` starts: True when it serves a walk; the call is answered (cleared) unless it waits
        for a walk that did not fit."""
        if phase not in self.calls:
            return False  # the calls stay the very set they were: what reads them sees no change
        called = self.timing[phase].walk > 0
        served = called and self.coordinated.walk_fits(phase)
        if served or not called:
            self.calls -= {phase}
        return served

    def recycle(self, rings: Iterable[Ring]) -> None:
        """Pedestrian recycle: a call latched on a phase with ``ped_recycle`` whose green runs, timing no walk or
        pedestrian clearance, starts a walk within that green when it fits; the call is answered."""
        for r in rings:
            p = r.phase
            if r.interval is GREEN and p in self.calls and p in self.recycling and self._recycles(r):
                r.recycle(self.timing[p])
                self.calls -= {p}

    def _recycles(self, r: Ring) -> bool:
        """A walk may start now within ``r``'s green: none is timed, and it and its clearance end before the green's
        maximum would (free) or by the phase's force-off point (a pattern running)."""
        t = self.timing[r.phase]
        if t.walk == 0 or r.ticks < r.walk + r.ped_clear:
            return False
        if self.coordinated.running:
            return self.coordinated.walk_fits(r.phase)
        return r.maximum - r.max_ticks >= t.walk + t.ped_clear
