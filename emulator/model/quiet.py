"""Quiet time: the ticks that change nothing but counters, told from the units' deadlines, and skipped at once.

Rules of this file
------------------
- It decides nothing of the controller's operation: it only says which of the next ticks are quiet
  (:meth:`QuietTime.ticks`), and the controller skips those (:meth:`emulator.model.controller.Controller.skip`)
  instead of stepping them. Skipping a quiet tick and stepping it leave the controller in the same state: a
  property test steps one controller every tick and advances its twin over the same stretches
  (tests/emulator/model/test_controller_events.py).
- Every unit reports its own deadline, the ticks until its timers reach their next threshold: the backup timer,
  the coordinator, the preemptor, the overlaps' trailing intervals, the detectors' delays and extensions and,
  through the sequencer, every ring's timers with what a pattern or a preempt sets them. The quiet time is the
  least of them.
- Any input (a SET, a detector, a retiming, a power cycle) makes the next step a real one
  (:meth:`QuietTime.touched`).

Theory of operation
-------------------
Most ticks change nothing but counters: a green resting on its call, a yellow timing its length. A tick's
discrete effects (intervals, targets, the gap latch, the status, latched pedestrian calls, the control objects,
flash and control status) depend on the inputs, on the discrete state and on a few comparisons of counters with
thresholds (minimum, walk, pedestrian clearance, passage, maximum, clearance lengths, red revert, backup time,
start-up flash). So once a step has changed nothing discrete, every following step with the same inputs changes
nothing either until a counter reaches its next threshold, the least of the units' deadlines. A step that did
change something is mostly followed by one that does not (a green or a clearance just started); where that is
short to prove (:meth:`emulator.model.sequencer.Sequencer.settles`), quiet time starts at once instead of after
that step.

In quiet time a gap counter that runs is above zero (an extending green resets it every tick), a max-out counter
that runs is above zero (it is held at zero without conflicting demand unless the phase is on max recall, and its
first tick of a green is a real step) and the conflicting demand a green registered (``Ring.conflict``) stays as
it is, which is all skipping needs to know. A green's minimum is a threshold only while it has conflicting demand
(or a pattern runs, or a preempt is served): without any, a ready green has nowhere to go, even one that max
recall has maxed out. The data logger still logs it at its tick, so with a recorder that tick is stepped for the
recorder alone (:meth:`QuietTime.proven` says it is quiet, and the controller skips it).

The units are asked once per quiet stretch: quiet ticks only count, so the ticks their deadlines fall on (and the
recorder's) stay where they were until the next real step or input, and a step for the recorder alone is
followed by the same answer without asking them again.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from emulator.model.ring import GREEN
from hils.protocol.ntcip import UnitFlashStatus

if TYPE_CHECKING:
    from emulator.model.controller import Controller


class QuietTime:
    """What one controller knows of its quiet time: whether it started, and the next tick that is not quiet."""

    def __init__(self, controller: Controller) -> None:
        self.c = controller
        self.touched()

    def touched(self) -> None:
        """An input came (or the unit powered up): the next step is a real one."""
        self.quiet = False  # the last step changed nothing discrete, and no input came since
        self.settled: tuple | None = None  # the discrete state the last step left, if nothing changed it since
        self.next_real: float | None = None  # ticks before this one change nothing (None: none proven)
        # The ticks the units' deadlines fall on, and those the recorder logs at, while quiet time lasts: quiet ticks
        # only count, so they stay where they were until the next real step or input.
        self._ahead: tuple[float, tuple[int, ...]] | None = None

    def written(self) -> None:
        """A write that changed no input a step reads (a repeated control SET): the discrete state is read anew, and
        the deadlines too (the backup timer restarted)."""
        self.settled = None
        self._ahead = None

    def proven(self) -> bool:
        """The next tick is one :meth:`ticks` proved quiet (stepped for a recorder alone)."""
        return self.next_real is not None and self.c.tick + 1 < self.next_real

    def stepped(self, before: tuple) -> None:
        """A real step ran from the discrete state ``before`` (:meth:`before`): quiet time starts if it changed
        nothing discrete, or if the sequencer proves the next step will change nothing."""
        c = self.c
        self.settled = self.discrete()
        self.quiet = self.settled == before or (not c.flashing and c.sequencer.settles(c.ped_calls, c.inputs))

    def before(self) -> tuple:
        """The discrete state a real step starts from."""
        self.next_real = None
        self._ahead = None
        return self.settled if self.settled is not None else self.discrete()

    def discrete(self) -> tuple:
        """Everything a step can change but counters."""
        c = self.c
        return (c.flash_status, c.control_status, c.ped_calls, c.status_version, tuple(c.control.values()),
                c.coordinator.discrete(), c.overlaps.discrete(), c.preemptor.discrete(), c.coordinated.discrete(),
                c.preempting.discrete(), c.sequencer.discrete())

    def ticks(self) -> int | None:
        """How many steps from now the next one that may change anything is, inputs staying as they are: 1 unless
        quiet time started and no input came since; None when no step will. Otherwise the least of the units'
        deadlines."""
        c = self.c
        if self._ahead is not None:
            self.next_real, logged = self._ahead
            due = min((t for t in logged if t > c.tick), default=self.next_real)
            return None if due is math.inf else min(due, self.next_real) - c.tick
        self.next_real = None
        if not self.quiet:
            return 1
        deadlines = [c.backup.deadline(), c.coordinator.deadline()]
        if c.flashing:
            if c.flash_status is UnitFlashStatus.STARTUP and c.tick < c.startup_flash * 10:
                deadlines.append(c.startup_flash * 10 - c.tick)
            return min((d for d in deadlines if d is not None), default=None)
        rings, logged = c.sequencer.deadline(c.tick, c.preempting, logging=c.recorder is not None)
        deadlines += [c.preemptor.deadline(), c.overlaps.deadline(), rings]
        if c.detectors.timers:
            deadlines.append(c.detectors.deadline(r.phase for r in c.rings if r.interval is GREEN))
        ahead = min((d for d in deadlines if d is not None), default=None)
        self.next_real = math.inf if ahead is None else c.tick + ahead
        self._ahead = self.next_real, tuple(c.tick + d for d in logged)
        return min((d for d in (ahead, *logged) if d is not None), default=None)
