"""The emulator reached in process, for virtual-time runs.

:class:`VirtualTarget` puts a controller model on the run's SimPy environment (ticking every
0.1 s) behind its call-processing and status-update delays (:mod:`emulator.model.delays`), and
offers its MIB view as the object surface the middleware's in-process transport reaches,
with the latencies a controller's answers take. It is what a virtual-time Testbed uses (found
through the ``hils.shell.targets`` entry point, so the middleware never imports it); the Testbed builds
the transport, so this package needs nothing of the middleware.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Generator, Sequence
from typing import Any

import simpy

from emulator.agent import j2735
from emulator.agent.mib import MibView
from emulator.model.controller import TICK, Controller
from emulator.model.datalogger import DataLogger
from emulator.model.delays import DelayedController
from emulator.model.event_clock import ClockedSurface, EventClock
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import Event
from hils.protocol.ntcip import Latency
from hils.protocol.spat import MovementTiming
from hils.protocol.timegrid import Grid

#: Modeled answer times of the in-process controller: a GET of the signal state, and a SET (the
#: paper measured 7.5 ms for a SET to a Cobalt).
GET_LATENCY = Latency(0.002)
SET_LATENCY = Latency(0.0075)


class VirtualTarget:
    """Controller model + its delays + MIB view on one environment; the MIB view is the transport's surface.

    ``controller`` is the model itself (its lamps, for monitors); ``unit`` is what the agent talks to;
    ``log`` its data logger, whose hi-res event log :meth:`hires` hands the run, and :meth:`hires_to` hands a sink
    as it is logged (the optional methods of a target through which a Testbed keeps the controller's own record).
    With ``hires=False`` (a run that keeps no hi-res record) the controller has no data logger (``log`` is None):
    the logger's work on every step and the ticks stepped for it alone (a green's minimum, logged at its tick) are
    left out, and nothing else changes, since the logger never acts.
    On virtual time's fast path (``fast_path``, the run's flag: :mod:`hils.shell.fastpath`) the unit's ticks run
    event by event (:mod:`emulator.model.event_clock`), and the clock is the change feed that lets the poller skip
    polls that cannot see a change. Without it is the reference the fast path is tested against: every tick
    stepped by a SimPy process, no change feed, so every poll is sent.
    """

    def __init__(self, env: simpy.Environment, config: IntersectionConfig, *, seed: int = 0,
                 fast_path: bool = True, hires: bool = True) -> None:
        self.env = env
        self.controller = Controller(config)
        self.log = DataLogger(self.controller) if hires else None
        self.unit = DelayedController(self.controller, config.emulator)
        self.mib = MibView(self.unit)
        self.get_latency = GET_LATENCY
        self.set_latency = SET_LATENCY
        # The controller powered up at some instant of its own: its tick grid has a phase, drawn from
        # the seed, against the middleware's poll and decision times.
        self.tick_phase = random.Random(f"tick-phase-{seed}").uniform(0.0, TICK)
        self._ticks = Grid(env.now + self.tick_phase, TICK)  # the controller's tick count k is reached at at(k)
        self.clock: EventClock | None = None
        self._ticking: simpy.Process | None = None
        self._j2735_sent = 0
        if fast_path:
            self.clock = EventClock(env, self.unit, self.tick_phase)
            self.surface: MibView | ClockedSurface = ClockedSurface(self.mib, self.clock)
        else:
            self.surface = self.mib
            self._ticking = env.process(self.unit.process(env, self.tick_phase))

    def hires(self) -> list[Event]:
        """The controller's hi-res event log so far, the controller brought to the present first (on the fast path
        quiet ticks are counted only when something reads or writes the controller, and a minimum timed in them is
        logged then, at its tick)."""
        log = self._logger()
        if self.clock is not None:
            self.clock.catch_up()
        return log.events()

    def spat(self) -> tuple[MovementTiming, ...]:
        """Each phase's and overlap's indication and the times of its next change, in the run's seconds: the
        controller's own announcement (:meth:`emulator.model.controller.Controller.spat`), brought to the present
        first (on the fast path quiet ticks are counted only when something reads or writes the controller)."""
        if self.clock is not None:
            self.clock.catch_up()
        tick = self.controller.tick

        def at(ticks: int | None) -> float | None:
            return None if ticks is None else self._ticks.at(tick + ticks)

        return tuple(MovementTiming(s.kind, s.number, s.indication.value, at(s.earliest), at(s.latest), at(s.likely))
                     for s in self.controller.spat())

    def j2735(self, intersection: int = 1) -> bytes:
        """The controller's SPaT now as a J2735 message (UPER MessageFrame: :func:`emulator.agent.j2735.encode`),
        numbered ``intersection``; its revision counts the messages asked for."""
        if self.clock is not None:
            self.clock.catch_up()
        message = j2735.encode(self.controller, self._j2735_sent, intersection=intersection)
        self._j2735_sent += 1
        return message

    def hires_to(self, sink: Callable[[Sequence[Event]], None]) -> None:
        """Hand ``sink`` the hi-res log so far, then each tick's events as they are logged (the other optional
        method of a target: a Testbed writes them through, :mod:`hils.shell.hiresjournal`)."""
        log = self._logger()
        log.write_to(sink)
        if self.clock is not None:
            self.env.process(self._minimums(log, self.clock))

    def _minimums(self, log: DataLogger, clock: EventClock) -> Generator[simpy.Event, Any, None]:
        """On the fast path the controller takes no step where a green's minimum changes nothing else, and its logger
        logs such a minimum when it next hears from it: for a sink written through (a journal, kept if the run dies)
        each is logged at its own time all the same, the controller left untouched."""
        c = self.controller
        while True:
            due = log.pending()
            if due is None:
                yield clock.changed()  # a green starts (or the unit powers up) only where what it answers changes
                continue
            # the logger's clock counts with the controller's ticks
            reached = self.env.timeout(clock.delay(due - c.coordinator.clock))
            yield reached | clock.changed()
            if reached.processed:
                log.log_until(due)

    def _logger(self) -> DataLogger:
        if self.log is None:
            raise RuntimeError("this controller keeps no hi-res log: it was built with hires=False (a Testbed does so "
                               "with measure=False and no hires_path)")
        return self.log

    @property
    def change_feed(self) -> EventClock | None:
        """What the in-process transport offers its poller (None for the ticked reference)."""
        return self.clock

    def power_cycle(self) -> None:
        """Power the controller down and up: reset it and start its tick grid from now."""
        if self.clock is not None:
            self.clock.power_cycle()
            return
        self._ticking.defused = True  # the interrupted tick process ends here on purpose
        self._ticking.interrupt("power cycle")
        self.unit.reset()
        self._ticking = self.env.process(self.unit.process(self.env))
