"""Quiet time: the ticks that change nothing but counters, told by the units' deadlines, and skipped at once.

Rules of this file
------------------
- It decides nothing of the controller's operation: it only says which of the next ticks are quiet
  (:meth:`QuietTime.ticks`), and the controller skips those (:meth:`emulator.model.controller.Controller.skip`)
  instead of stepping them. Skipping a quiet tick and stepping it leave the controller in the same state: a
  property test steps one controller every tick and advances its twin over the same stretches
  (tests/emulator/model/test_controller_events.py).
- The quiet time is the least of the units' deadlines, and nothing else. Every unit reports its own: the ticks
  until the next step at which it acts, given the inputs as they are. The backup timer, the start-up flash, the
  coordinator, the pedestrian calls, the preemptor and its part in the rings, the overlaps and, through the
  sequencer, every ring's timers with what a pattern or a preempt sets them and every decision the sequencer
  takes.
- Any input (a SET, a detector, a retiming, a power cycle) makes the next step a real one
  (:meth:`QuietTime.touched`): the deadlines are asked again after it.

Theory of operation
-------------------
A step's discrete effects (intervals, targets, the gap latch, the status, latched pedestrian calls, the control
objects, flash and control status, the preempts' states) depend on the inputs, on the discrete state and on a
few comparisons of counters with thresholds (minimum, walk, pedestrian clearance, passage, maximum, clearance
lengths, red revert, backup time, start-up flash, the coordinator's marks, the preempts' timers). So a unit asked
right after a step can tell when it next acts: at the next step if one of its questions (is this green ready
and does its ring wish a phase, may this committed phase start, does this call latch, ...) is answered yes now,
otherwise not before a counter reaches its next threshold. The least answer over the units is the next real step.

In quiet time a gap counter that runs is above zero (an extending green resets it every tick), a max-out counter
that runs is above zero (it is held at zero without conflicting demand unless the phase is on max recall, and its
first tick of a green is a real step) and the conflicting demand a green registered (``Ring.conflict``) stays as
it is, which is all skipping needs to know. A green's minimum is a threshold only while it has conflicting demand
(or a pattern runs, or a preempt is served): without any, a ready green has nowhere to go, even one that max
recall has maxed out. The data logger logs that minimum at its tick all the same, without a step
(:mod:`emulator.model.datalogger`).

The units are asked once per quiet stretch: quiet ticks only count, so the tick their least deadline falls on
stays where it was until the next real step or input.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from emulator.model import ring
from emulator.model.overlaps import Phases
from hils.protocol.ntcip import UnitFlashStatus

if TYPE_CHECKING:
    from emulator.model.controller import Controller


class QuietTime:
    """What one controller knows of its quiet time: whether an input came, and the next tick that is not quiet."""

    def __init__(self, controller: Controller) -> None:
        self.c = controller
        self.touched()

    def touched(self) -> None:
        """An input came (or the unit powered up): the next step is a real one."""
        self.fresh = True  # an input came since the last real step
        self.next_real: float | None = None  # the tick of the next real step, once asked (inf: none)
        self.units: float | None = None  # the tick the units but the backup timer next act at, once asked (inf: never)

    def written(self) -> None:
        """A write that changed no input a step reads (a repeated control SET): the backup timer restarted, so its
        deadline alone moved (later); the other units' stand."""
        if self.units is not None:
            self.next_real = self._with_backup(self.units)

    def stepped(self) -> None:
        """A real step ran: the deadlines are asked anew."""
        self.fresh = False
        self.next_real = self.units = None

    def proven(self) -> bool:
        """The next tick is one :meth:`ticks` proved quiet."""
        return self.next_real is not None and self.c.tick + 1 < self.next_real

    def ticks(self) -> int | None:
        """How many steps from now the next one that may change anything is, inputs staying as they are: 1 after an
        input, None when no step will, otherwise the least of the units' deadlines."""
        if self.fresh:
            return 1
        c = self.c
        if self.next_real is None:
            ahead = self._units()
            self.units = math.inf if ahead is None else c.tick + ahead
            self.next_real = self._with_backup(self.units)
        return None if self.next_real is math.inf else self.next_real - c.tick

    def _with_backup(self, units: float) -> float:
        backup = self.c.backup.deadline()
        return units if backup is None else min(units, self.c.tick + backup)

    def skip(self, n: int) -> None:
        """Advance ``n`` quiet ticks at once: every unit that times counts them, nothing else moves."""
        if n <= 0:
            return
        c = self.c
        c.tick += n
        c.coordinator.skip(n)
        c.backup.skip(n)
        if c.flashing:
            return
        if c.config.overlaps:
            c.overlaps.skip(n)
        if c.detectors.timers:
            c.detectors.skip(n)
        if c.config.preempts:
            c.preemptor.skip(n)
        ring.skip(c.rings, n)

    def _units(self) -> int | None:
        """The least deadline of the units but the backup timer (None: none will act). The sequencer, the costliest
        to ask, is asked last, and not when another unit acts at the next step."""
        c = self.c
        ahead = [c.coordinator.deadline()]
        if c.flashing:
            if c.flash_status is UnitFlashStatus.STARTUP and c.tick < c.startup_flash * 10:
                ahead.append(c.startup_flash * 10 - c.tick)
            return _least(ahead)
        inputs = c.inputs
        ahead.append(c.peds.deadline(c.greens, inputs))
        phases = Phases.of(c.rings, later=True) if c.config.overlaps else None
        if c.detectors.timers:
            ahead.append(c.detectors.deadline(c.actuations, c.greens))
        if c.config.preempts:
            ahead += (c.preemptor.deadline(), c.preempting.deadline(c.sequencer))
        if phases is not None:
            ahead.append(c.overlaps.deadline(phases))
        if 1 in ahead:
            return 1
        ahead.append(c.sequencer.deadline(c.tick, c.peds.demand(inputs), inputs, phases, c.preempting))
        return _least(ahead)


def _least(deadlines: list[int | None]) -> int | None:
    least = None
    for d in deadlines:
        if d is not None and (least is None or d < least):
            least = d
    return least
