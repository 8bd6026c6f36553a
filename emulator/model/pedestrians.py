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
PedOmit (and an omitted phase) stops new calls latching; a walk being timed completes.
"""

from __future__ import annotations

from collections.abc import Mapping

from emulator.model import inputs as reading
from emulator.model.coordinated import Coordinated
from emulator.model.inputs import Inputs
from emulator.model.ring import Timing


class PedCalls:
    """One controller's latched pedestrian calls."""

    def __init__(self, timing: Mapping[int, Timing], coordinated: Coordinated) -> None:
        self.timing = timing
        self.coordinated = coordinated
        self.reset()

    def reset(self) -> None:
        """Power-up: no call latched."""
        self.calls: frozenset[int] = frozenset()
        # The last answers of latched() and demand() and what they were asked with: the step and quiet time ask the
        # same questions of the same (immutable) sets, mostly.
        self._latched: tuple[tuple, frozenset[int]] = ((None, None, None), frozenset())
        self._demand: tuple[tuple, frozenset[int]] = ((None, None), frozenset())

    def latch(self, greens: frozenset[int], inputs: Inputs) -> frozenset[int]:
        """This tick's calls latch (``greens``: the phases showing green); the demand they make with the inputs."""
        calls = self._latch(greens, inputs)
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
        change only with the inputs and the greens."""
        return 1 if self._latch(greens, inputs) != self.calls else None

    def _latch(self, greens: frozenset[int], inputs: Inputs) -> frozenset[int]:
        asked, answer = self._latched
        if asked[0] is not self.calls or asked[1] is not greens or asked[2] is not inputs:
            answer = reading.latched(self.calls, greens, inputs)
            self._latched = (self.calls, greens, inputs), answer
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
