"""The emulator reached in process, for virtual-time runs.

:class:`VirtualTarget` puts a controller model on the run's SimPy environment (ticking every
0.1 s) behind its call-processing and status-update delays (:mod:`emulator.delays`), and
offers its MIB view as the object surface the middleware's in-process transport reaches,
with the latencies a controller's answers take. It is what a virtual-time Testbed uses (found
through the ``hils.targets`` entry point, so the middleware never imports it); the Testbed builds
the transport, so this package needs nothing of the middleware.
"""

from __future__ import annotations

import random

import simpy

from emulator.controller import TICK, Controller
from emulator.delays import DelayedController
from emulator.mib import MibView
from hils.config import IntersectionConfig
from hils.ntcip import Latency

#: Modeled answer times of the in-process controller: a GET of the signal state, and a SET (the
#: paper measured 7.5 ms for a SET to a Cobalt).
GET_LATENCY = Latency(0.002)
SET_LATENCY = Latency(0.0075)


class VirtualTarget:
    """Controller model + its delays + MIB view on one environment; the MIB view is the transport's surface.

    ``controller`` is the model itself (its lamps, for monitors); ``unit`` is what the agent talks to."""

    def __init__(self, env: simpy.Environment, config: IntersectionConfig, *, seed: int = 0) -> None:
        self.env = env
        self.controller = Controller(config)
        self.unit = DelayedController(self.controller, config.emulator)
        self.mib = MibView(self.unit)
        self.surface = self.mib
        self.get_latency = GET_LATENCY
        self.set_latency = SET_LATENCY
        # The controller powered up at some instant of its own: its tick grid has a phase, drawn from
        # the seed, against the middleware's poll and decision times.
        self.tick_phase = random.Random(f"tick-phase-{seed}").uniform(0.0, TICK)
        self.process = env.process(self.unit.process(env, self.tick_phase))
