"""Serving the emulator at wall-clock time: the controller ticks every 0.1 s while the SNMP agent answers.

Both run on one asyncio loop and no thread: the ticker sleeps until each
tick's deadline and steps the controller, the agent answers datagrams between
ticks. A request therefore always sees the controller between two whole ticks,
and a SET takes effect after the controller's call-processing delay, counted
from the next tick; status answers lag by the status-update delay
(:mod:`emulator.delays`, the same model as in virtual time).

Deadlines are computed from the start time (``start + k * period``), never by
adding periods up, so they do not drift. When the loop was held up past one or
more deadlines the missed ticks are all run at once (the model stays in step
with the wall clock), and a tick run more than ``late_after`` past its
deadline is counted as late.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import json
import logging
import signal
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from emulator.agent import AgentStats, DropReason, RequestKind, SnmpAgent, V3User
from emulator.controller import TICK, Change, Controller
from emulator.delays import DelayedController
from emulator.mib import MibView
from hils.config import IntersectionConfig
from hils.ntcip import Latency

log = logging.getLogger(__name__)

NO_LATENCY = Latency(0.0)


@dataclass(slots=True)
class TickStats:
    """Counters of a ticker (mutable: updated every tick)."""

    ticks: int = 0
    late: int = 0
    max_lateness: float = 0.0  # seconds


class WallClockTicker:
    """Steps a controller at the wall-clock deadlines of its 0.1 s tick, on the running loop."""

    def __init__(self, controller: Controller | DelayedController, *, period: float = TICK,
                 late_after: float = TICK / 2, observe: Callable[[float], None] | None = None) -> None:
        self.controller = controller
        self.period = period
        self.late_after = late_after
        self.observe = observe  # gets each tick's lateness (s), for benchmarks
        self.stats = TickStats()

    async def run(self) -> None:
        """Tick until cancelled."""
        loop = asyncio.get_running_loop()
        start = loop.time()
        k = 1
        while True:
            await asyncio.sleep(max(0.0, start + k * self.period - loop.time()))
            now = loop.time()
            while start + k * self.period <= now:
                lateness = now - (start + k * self.period)
                self.controller.step()
                self.stats.ticks += 1
                self.stats.max_lateness = max(self.stats.max_lateness, lateness)
                if self.observe is not None:
                    self.observe(lateness)
                if lateness > self.late_after:
                    self.stats.late += 1
                    log.debug("tick %d ran %.1f ms late", self.controller.tick, lateness * 1e3)
                k += 1


@dataclass(frozen=True, slots=True)
class ServeOptions:
    host: str = "127.0.0.1"
    port: int = 1161
    ro_community: str = "public"
    rw_community: str = "private"
    latency: Latency = NO_LATENCY
    seed: int | None = None
    trace: Path | None = None  # JSON Lines of every interval change, stamped with time.monotonic_ns()
    v3_user: V3User | None = None  # the SNMPv3 user accepted besides the communities; None: v1/v2c only


@dataclass(frozen=True, slots=True)
class ServeSummary:
    """What one serving session did, for the closing line."""

    traffic: AgentStats  # a copy of the agent's counters at the end
    ticks: TickStats

    def describe(self) -> str:
        def parts(counts: Counter, kinds: type[Enum]) -> str:
            return ", ".join(f"{k.value} {counts[k]}" for k in kinds if counts[k]) or "none"

        t, k = self.traffic, self.ticks
        reports = f", {t.reports} SNMPv3 reports" if t.reports else ""
        return (f"served {t.answered} requests ({parts(t.requests, RequestKind)}), {t.errors} answered with an "
                f"error{reports}; dropped {t.total_dropped} datagrams ({parts(t.dropped, DropReason)}); "
                f"{k.ticks} ticks, {k.late} late (max {k.max_lateness * 1e3:.1f} ms)")


class EmulatorServer:
    """A controller model behind its delays, its MIB view, the SNMP agent over it and the wall-clock ticker."""

    def __init__(self, config: IntersectionConfig, options: ServeOptions | None = None) -> None:
        self.config = config
        self.options = options or ServeOptions()
        self._trace = self.options.trace.open("w", buffering=1) if self.options.trace else None
        self.controller = Controller(config, on_change=self._on_change)
        self.unit = DelayedController(self.controller, config.emulator)
        self.view = MibView(self.unit)
        self.agent = SnmpAgent(self.view, ro_community=self.options.ro_community,
                               rw_community=self.options.rw_community, latency=self.options.latency,
                               seed=self.options.seed, v3_user=self.options.v3_user)
        self.ticker = WallClockTicker(self.unit)
        self._ticking: asyncio.Task[None] | None = None

    async def start(self) -> tuple[str, int]:
        """Bind the agent and start ticking; returns the bound address."""
        address = await self.agent.start(self.options.host, self.options.port)
        self._ticking = asyncio.create_task(self.ticker.run(), name="controller-tick")
        return address

    @property
    def ticking(self) -> asyncio.Task[None]:
        if self._ticking is None:
            raise RuntimeError("the server is not started")
        return self._ticking

    def _on_change(self, change: Change) -> None:
        log.debug("tick %d: ring %d phase %s %s", change.tick, change.ring, change.phase, change.interval.value)
        if self._trace is not None:
            # Monotonic nanoseconds are comparable with the middleware's event log stamps
            # (same clock, other process): what the wire benchmark measures lags from.
            self._trace.write(json.dumps({"wall_ns": time.monotonic_ns(), "tick": change.tick, "ring": change.ring,
                                          "phase": change.phase, "interval": change.interval.value}) + "\n")

    async def stop(self) -> ServeSummary:
        """Stop answering and ticking; raises what ended the ticker if it failed."""
        self.agent.close()
        if self._trace is not None:
            self._trace.close()
        if self._ticking is not None:
            self._ticking.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticking
        return self.summary()

    def summary(self) -> ServeSummary:
        return ServeSummary(copy.deepcopy(self.agent.stats), copy.copy(self.ticker.stats))


async def serve_until_signalled(config: IntersectionConfig, options: ServeOptions,
                                on_ready: Callable[[tuple[str, int]], None]) -> ServeSummary:
    """Serve until SIGINT or SIGTERM; ``on_ready`` gets the bound address once requests are answered."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    server = EmulatorServer(config, options)
    try:
        on_ready(await server.start())
        stopping = asyncio.create_task(stop.wait())
        await asyncio.wait({stopping, server.ticking}, return_when=asyncio.FIRST_COMPLETED)
        stopping.cancel()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    # The ticker ends on its own only when the model fails; stop() then raises that failure.
    return await server.stop()
