"""The emulator reached in process, for virtual-time runs.

:class:`VirtualTarget` puts a controller model on the run's SimPy environment
(ticking every 0.1 s), behind its call-processing and status-update delays
(:mod:`emulator.delays`), and hands the middleware a :class:`hils.transport.LocalTransport`
to its MIB view. It is what `hils run` uses when no --target is given (found
through the ``hils.targets`` entry point, so the middleware never imports it).
"""

from __future__ import annotations

import random

import simpy

from emulator.controller import TICK, Controller
from emulator.delays import DelayedController
from emulator.mib import MibView
from hils.config import IntersectionConfig
from hils.transport import Latency, LocalTransport


class VirtualTarget:
    """Controller model + its delays + MIB view + in-process transport on one environment.

    ``controller`` is the model itself (its lamps, for monitors); ``unit`` is what the agent talks to."""

    def __init__(self, env: simpy.Environment, config: IntersectionConfig, *, seed: int = 0,
                 get_latency: Latency | None = None, set_latency: Latency | None = None,
                 loss: float = 0.0) -> None:
        self.env = env
        self.controller = Controller(config)
        self.unit = DelayedController(self.controller, config.emulator)
        self.mib = MibView(self.unit)
        self.transport = LocalTransport(env, self.mib, tau_udp=config.middleware.tau_udp,
                                        get_latency=get_latency, set_latency=set_latency, loss=loss, seed=seed)
        # The controller powered up at some instant of its own: its tick grid has a phase, drawn from
        # the seed, against the middleware's poll and decision times.
        self.tick_phase = random.Random(f"tick-phase-{seed}").uniform(0.0, TICK)
        self.process = env.process(self.unit.process(env, self.tick_phase))
