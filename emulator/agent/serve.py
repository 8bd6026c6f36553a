"""Serving the emulator at wall-clock time: controllers tick every 0.1 s while their SNMP agents answer.

One process serves one or more controllers, each its own model, MIB view and
agent on its own UDP port (consecutive ports from the first, or each a free
one). All run on one asyncio loop and no thread: one ticker sleeps until each
tick's deadline and steps every controller, the agents answer datagrams
between ticks. A request therefore always sees its controller between two
whole ticks, and a SET takes effect after the controller's call-processing
delay, counted from the next tick; status answers lag by the status-update
delay (:mod:`emulator.model.delays`, the same model as in virtual time).

Deadlines are computed from the start time (``start + k * period``), never by
adding periods up, so they do not drift. When the loop was held up past one or
more deadlines the missed ticks are all run at once (the model stays in step
with the wall clock), and a tick run more than ``late_after`` past its
deadline is counted as late.

The controllers' clocks are the host's: tick 0 falls on a tenth of a second of
the host's time and each controller's clock starts at that local time, as a
real controller's clock is set to local time. Their hi-res logs
(:mod:`emulator.model.datalogger`) are therefore stamped in the host's local time, and
a field tool that aligns a replay with the time of day (Signal-Replay's cycle
alignment) finds the coordinated cycle where the time of day puts it. With
``http`` each controller also serves its log as an Intelight MaxTime does
(:mod:`emulator.agent.asclog`), on consecutive TCP ports, on the same loop: a
few events per turn of it, so that serving a log never holds a tick up. With ``spat`` each controller sends its
10 Hz SPaT packet (:mod:`emulator.agent.spat_udp`) once its ticks due have run, to consecutive UDP ports; with
``j2735`` its J2735 SPaT (:mod:`emulator.agent.j2735`) likewise.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import json
import logging
import math
import signal
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from enum import Enum
from pathlib import Path
from typing import TextIO

from emulator.agent import j2735, spat_udp
from emulator.agent.asclog import AsclogServer, Connections, HttpStats
from emulator.agent.mib import MibView
from emulator.agent.snmp import AgentStats, DropReason, ReportBudget, RequestKind, SnmpAgent, V3User
from emulator.agent.spat_udp import SpatSender
from emulator.model.controller import TICK, Change, Controller
from emulator.model.datalogger import DataLogger
from emulator.model.delays import DelayedController
from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.ntcip import Latency, Version
from hils.protocol.timegrid import Grid

log = logging.getLogger(__name__)

NO_LATENCY = Latency(0.0)
MAX_PORT = 65535


class ServeError(UserError, ValueError):
    """Serving options that cannot be used together; says what is allowed."""


class BindError(OSError):
    """A controller's UDP port (or the TCP port of its event log) could not be bound (in use, not permitted, no such
    address)."""

    def __init__(self, host: str, port: int, cause: OSError, protocol: str = "udp") -> None:
        super().__init__(cause.errno, cause.strerror or str(cause))
        self.host = host
        self.port = port
        self.protocol = protocol

    def __str__(self) -> str:
        return f"cannot bind {self.protocol}:{self.host}:{self.port}: {self.strerror}"


@dataclass(slots=True)
class TickStats:
    """Counters of a ticker (mutable: updated every tick)."""

    ticks: int = 0
    late: int = 0
    max_lateness: float = 0.0  # seconds


class WallClockTicker:
    """Steps controllers at the wall-clock deadlines of their common 0.1 s tick, on the running loop.

    One ticker steps every controller of the process, each once per deadline and in order: one timer
    instead of one per controller, and the models stay in step with each other. Lateness is counted
    per deadline."""

    def __init__(self, *controllers: Controller | DelayedController, period: float = TICK,
                 late_after: float = TICK / 2, observe: Callable[[float], None] | None = None,
                 origin: float | None = None, after: Sequence[Callable[[], None]] = ()) -> None:
        self.controllers = controllers
        self.after = after  # called once the ticks due have run: what is sent each tick (SPaT) reads them
        self.period = period
        self.late_after = late_after
        self.observe = observe  # gets each tick's lateness (s), for benchmarks
        self.origin = origin  # the host's time (time.time()) of tick 0; None: when run() starts
        self.stats = TickStats()

    async def run(self) -> None:
        """Tick until cancelled."""
        loop = asyncio.get_running_loop()
        grid = Grid(loop.time() + (0.0 if self.origin is None else self.origin - time.time()), self.period)
        k = 1
        while True:
            await asyncio.sleep(grid.delay(k, loop.time()))
            now = loop.time()
            while grid.at(k) <= now:
                lateness = now - grid.at(k)
                for controller in self.controllers:
                    controller.step()
                self.stats.ticks += 1
                self.stats.max_lateness = max(self.stats.max_lateness, lateness)
                if self.observe is not None:
                    self.observe(lateness)
                if lateness > self.late_after:
                    self.stats.late += 1
                    log.debug("tick %d ran %.1f ms late", k, lateness * 1e3)
                k += 1
            for call in self.after:
                call()


@dataclass(frozen=True, slots=True)
class ServeOptions:
    host: str = "127.0.0.1"
    port: int = 1161  # of the first controller, the others on the next ports; 0: each on a free port
    ro_community: str = "public"
    rw_community: str = "private"
    latency: Latency = NO_LATENCY
    seed: int | None = None
    trace: Path | None = None  # JSON Lines of every interval change, stamped with time.monotonic_ns(); one controller
    v3_user: V3User | None = None  # the SNMPv3 user accepted besides the communities; None: v1/v2c only
    http: int | None = None  # TCP port of the first controller's MaxTime event-log endpoint; None: no endpoint
    log_events: int = 100_000  # the hi-res events each controller keeps (its last ones, as a controller's ring buffer)
    ntcip: Version | None = None  # the edition of NTCIP 1202 served; None: each config's [emulator] ntcip
    spat: tuple[str, int] | None = None  # where the first controller's 10 Hz SPaT packet goes, the others to the
    # next ports; None: not sent
    j2735: tuple[str, int] | None = None  # likewise its J2735 SPaT (UPER MessageFrame)


@dataclass(frozen=True, slots=True)
class ServeSummary:
    """What one serving session did, for the closing line."""

    traffic: AgentStats  # the agents' counters at the end, summed over the controllers
    ticks: TickStats
    controllers: int = 1
    http: HttpStats | None = None  # the event-log endpoints' counters, summed; None: not served

    def describe(self) -> str:
        def parts(counts: Counter, kinds: type[Enum]) -> str:
            return ", ".join(f"{k.value} {counts[k]}" for k in kinds if counts[k]) or "none"

        t, k = self.traffic, self.ticks
        reports = (f", {t.reports.total()} SNMPv3 reports ("
                   + ", ".join(f"{failure.value} {n}" for failure, n in t.reports.most_common()) + ")"
                   if t.reports else "")
        by = f" by {self.controllers} controllers" if self.controllers > 1 else ""
        http = f"; {self.http.describe()}" if self.http is not None else ""
        return (f"served {t.answered} requests{by} ({parts(t.requests, RequestKind)}), {t.errors} answered with an "
                f"error{reports}; dropped {t.total_dropped} datagrams ({parts(t.dropped, DropReason)}){http}; "
                f"{k.ticks} ticks, {k.late} late (max {k.max_lateness * 1e3:.1f} ms)")


class ServedController:
    """One controller model behind its delays, its MIB view and the SNMP agent over it."""

    def __init__(self, config: IntersectionConfig, options: ServeOptions, trace: TextIO | None = None,
                 reports: ReportBudget | None = None, start: datetime | None = None,
                 connections: Connections | None = None) -> None:
        self.config = config
        self._trace = trace
        self.controller = Controller(config, on_change=self._on_change, start=start)
        self.log = DataLogger(self.controller, capacity=options.log_events)
        self.asclog = AsclogServer(self.log.snapshot, connections)
        self.unit = DelayedController(self.controller, config.emulator)
        self.view = MibView(self.unit, options.ntcip)
        self.agent = SnmpAgent(self.view, ro_community=options.ro_community, rw_community=options.rw_community,
                               latency=options.latency, seed=options.seed, v3_user=options.v3_user, reports=reports)

    def _on_change(self, change: Change) -> None:
        log.debug("tick %d: ring %d phase %s %s", change.tick, change.ring, change.phase, change.interval.value)
        if self._trace is not None:
            # Monotonic nanoseconds are comparable with the middleware's event log stamps
            # (same clock, other process): what the wire benchmark measures lags from.
            self._trace.write(json.dumps({"wall_ns": time.monotonic_ns(), "tick": change.tick, "ring": change.ring,
                                          "phase": change.phase, "interval": change.interval.value}) + "\n")


def serve_ports(first: int, count: int) -> list[int]:
    """The UDP ports of ``count`` controllers from ``first`` on (0: each a free port)."""
    if count < 1:
        raise ServeError(f"--count {count}: no controller to serve; allowed: 1 or more")
    if first == 0:
        return [0] * count
    if not 0 < first <= MAX_PORT - count + 1:
        raise ServeError(f"--port {first} with --count {count} needs ports {first}..{first + count - 1}; allowed: "
                         f"--port 1..{MAX_PORT - count + 1}, or 0 (each controller on a free port)")
    return list(range(first, first + count))


class EmulatorServer:
    """Controllers served side by side (see :class:`ServedController`) and the one wall-clock ticker of them all."""

    def __init__(self, configs: Sequence[IntersectionConfig], options: ServeOptions | None = None) -> None:
        self.options = options or ServeOptions()
        self.ports = serve_ports(self.options.port, len(configs))
        if self.options.trace is not None and len(configs) > 1:
            raise ServeError(f"--trace records one controller, not {len(configs)}; allowed: --trace with --count 1")
        self._trace = self.options.trace.open("w", buffering=1) if self.options.trace else None
        self.http_ports = None if self.options.http is None else serve_ports(self.options.http, len(configs))
        self.addresses: list[tuple[str, int]] = []  # of the agents, once started
        self.http_addresses: list[tuple[str, int]] = []
        # The controllers' clocks are the host's, as a real controller's is set: tick 0 at the next tenth of a
        # second of the host's time, so their logs' timestamps are the host's local time too.
        tenths = math.ceil(time.time() * 10)
        start = datetime.fromtimestamp(tenths // 10) + timedelta(microseconds=tenths % 10 * 100_000)
        # The agents share the process's loop, so they share one budget of SNMPv3 Reports too, and the event-log
        # endpoints one of connections and render turns.
        reports = ReportBudget()
        connections = Connections()
        self.controllers = tuple(ServedController(config, self.options, self._trace, reports, start, connections)
                                 for config in configs)
        self.spat = self._senders("--spat", self.options.spat, lambda i: spat_udp.encode)
        self.j2735 = self._senders("--j2735", self.options.j2735,
                                   lambda i: lambda c, sent: j2735.encode(c, sent, intersection=i + 1))
        self.ticker = WallClockTicker(*(served.unit for served in self.controllers), origin=tenths / 10,
                                      after=[sender.send for sender in (*self.spat, *self.j2735)])
        self._ticking: asyncio.Task[None] | None = None

    def _senders(self, option: str, address: tuple[str, int] | None,
                 encoder: Callable[[int], Callable[[Controller, int], bytes]]) -> list[SpatSender]:
        """One SPaT sender per controller, to consecutive ports from ``address`` (None: none), each encoding with
        ``encoder(i)`` for the i-th controller; sent while spatOptions bit 0 ("Enabled SPAT") is set."""
        if address is None:
            return []
        host, first = address
        n = len(self.controllers)
        if first + n - 1 > MAX_PORT:
            raise ServeError(f"{option} {host}:{first} for {n} controllers needs ports up to {first + n - 1}; "
                             f"allowed: PORT 1..{MAX_PORT - n + 1}")
        return [SpatSender(served.controller, host, first + i, lambda view=served.view: view.spat_options & 1 == 1,
                           encoder(i)) for i, served in enumerate(self.controllers)]

    async def start(self) -> list[tuple[str, int]]:
        """Bind every agent and start ticking; returns the bound addresses, in order."""
        for served, port in zip(self.controllers, self.ports, strict=True):
            try:
                self.addresses.append(await served.agent.start(self.options.host, port))
            except OSError as exc:
                self._close()
                raise BindError(self.options.host, port, exc) from exc
        for served, port in zip(self.controllers, self.http_ports or (), strict=False):
            try:
                self.http_addresses.append(await served.asclog.start(self.options.host, port))
            except OSError as exc:
                self._close()
                raise BindError(self.options.host, port, exc, "tcp") from exc
        for sender in (*self.spat, *self.j2735):
            try:
                await sender.start()
            except OSError as exc:
                self._close()
                raise BindError(*sender.address, exc, "udp (SPaT)") from exc
        self._ticking = asyncio.create_task(self.ticker.run(), name="controller-tick")
        return list(self.addresses)

    @property
    def ticking(self) -> asyncio.Task[None]:
        if self._ticking is None:
            raise RuntimeError("the server is not started")
        return self._ticking

    def _close(self) -> None:
        for served in self.controllers:
            served.agent.close()
            served.asclog.close()
        for sender in (*self.spat, *self.j2735):
            sender.close()
        if self._trace is not None:
            self._trace.close()

    async def stop(self) -> ServeSummary:
        """Stop answering and ticking; raises what ended the ticker if it failed."""
        self._close()
        try:
            await asyncio.gather(*(served.asclog.wait_closed() for served in self.controllers))
        finally:  # whatever a client's connection ended in, the controllers stop ticking
            if self._ticking is not None:
                self._ticking.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await self._ticking
        return self.summary()

    def summary(self) -> ServeSummary:
        http = None
        if self.http_ports is not None:
            http = HttpStats()
            for served in self.controllers:
                http.add(served.asclog.stats)
        return ServeSummary(_total(served.agent.stats for served in self.controllers), copy.copy(self.ticker.stats),
                            len(self.controllers), http)


def _total(stats: Iterable[AgentStats]) -> AgentStats:
    """The sum of agents' counters (a new object: the agents keep counting)."""
    out = AgentStats()
    for st in stats:
        out.requests.update(st.requests)
        out.dropped.update(st.dropped)
        out.errors += st.errors
        out.reports.update(st.reports)
    return out


async def serve_until_signalled(configs: Sequence[IntersectionConfig], options: ServeOptions,
                                on_ready: Callable[[EmulatorServer, list[tuple[str, int]]], None]) -> ServeSummary:
    """Serve until SIGINT or SIGTERM; ``on_ready`` gets the server and its agents' addresses once requests are
    answered."""
    server = EmulatorServer(configs, options)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        on_ready(server, await server.start())
        stopping = asyncio.create_task(stop.wait())
        await asyncio.wait({stopping, server.ticking}, return_when=asyncio.FIRST_COMPLETED)
        stopping.cancel()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    # The ticker ends on its own only when the model fails; stop() then raises that failure.
    return await server.stop()
