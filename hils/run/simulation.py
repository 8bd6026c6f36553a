"""The traffic simulation's side of a run: what the Testbed steps, and the process that steps it.

SUMO (:class:`hils.sim.sumo.SumoSimulation`) or nothing (:class:`NoSimulation`) is stepped on the run's grid of
``sumo_step`` seconds by one SimPy process (:func:`steps`): before each step every intersection's light is shown
what its signal cache holds (what the controller shows, never what an agent asked for), after it the detector
feeds hand SUMO's stop-bar presence to their controllers, and each middleware hears what the step cost (drift).
On virtual time's fast path (:mod:`hils.shell.fastpath`, rule 4) the steps that cost nothing and act on nothing but
SUMO run in one call while nothing else is due.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

import simpy

from hils.protocol.ntcip import SignalState
from hils.protocol.timegrid import Grid
from hils.shell.fastpath import StepCost, steps_before

if TYPE_CHECKING:
    from hils.run.intersection import Intersection

__all__ = ["NoSimulation", "Signals", "Simulation", "steps"]


class Signals(Protocol):
    """What the simulation shows for one intersection (:class:`hils.sim.sumo.Light`)."""

    def apply(self, state: SignalState) -> Any: ...

    def traffic_state(self) -> Any: ...

    def queues(self) -> Mapping[int, int]: ...


class Simulation(Protocol):
    """What the run steps: SUMO, or nothing (:class:`NoSimulation`); ``lights`` by intersection name."""

    lights: Mapping[str, Signals]

    def step(self) -> Any: ...

    def advance(self, steps: int) -> None:
        """``steps`` steps at once, with nothing shown changing between them (as many :meth:`step` calls)."""


class NoSimulation:
    """Stands in for SUMO in middleware-only runs: steps cost nothing and there is no traffic, nor lights."""

    lights: Mapping[str, Signals] = MappingProxyType({})

    def step(self) -> None:
        """No traffic to move."""

    def advance(self, steps: int) -> None:
        """No traffic to move."""


def steps(env: simpy.Environment, sim: Simulation, intersections: Sequence[Intersection], step: float,
          cost: StepCost, *, fast_path: bool, ended: Callable[[], bool]) -> Generator[simpy.Event, Any, None]:
    """The SimPy process that steps ``sim`` every ``step`` seconds until ``ended()``; ``cost`` says what a step
    cost (the run's clock, or a fault wrapped around it)."""
    lights = [(i.signals, i.middleware.cache) for i in intersections if i.signals is not None]
    feeds = [(i.signals, i.detector_feed) for i in intersections if i.detector_feed is not None]
    middlewares = [i.middleware for i in intersections]
    k = 0
    grid = Grid(env.now, step)

    def show() -> None:
        for signals, cache in lights:
            if cache.snapshot is not None:
                signals.apply(cache.snapshot.state)

    def one_step() -> None:
        show()
        sim.step()
        for signals, feed in feeds:
            feed.feed(signals.present())

    # The fast path (rule 4): steps that cost nothing and act on nothing but SUMO (no detectors SETting the
    # controller) run in one call while nothing else is due before the next one.
    stretches = fast_path and not feeds
    while not ended():
        free_until = cost.free_until(env.now) if stretches else env.now
        if free_until > env.now:
            show()
            n = 1 + steps_before(min(env.peek(), free_until), grid, k + 1)
            sim.advance(n)
            took = 0.0
        else:
            n, took = 1, cost(one_step)
        for mw in middlewares:
            mw.observe_step(step, took)
        k += n
        yield env.timeout(grid.delay(k, env.now))
