"""A run: agent, middleware, simulation stepping and target wired on one SimPy environment.

:class:`Run` sets the processes up on an environment it is given and does not
know which clock drives it. :func:`run_virtual` drives it in virtual time
against the in-process emulator (or any target factory); the wall-clock runner
in :mod:`hils.wire` drives the same object against an SNMP target.
"""

from __future__ import annotations

import gc
import logging
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass
from functools import cached_property
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

import simpy

from hils.actions import ActionType
from hils.agents import Agent, Observation, load_agent
from hils.config import IntersectionConfig
from hils.events import EventLog, Kind
from hils.events import read as read_events
from hils.manager import State
from hils.middleware import Middleware
from hils.ntcip import SignalState
from hils.transport import Transport

log = logging.getLogger(__name__)

StepCost = Callable[[Callable[[], Any]], float]

#: Agents used when none is named: with traffic to observe, and without (--no-sumo).
DEFAULT_AGENTS = {ActionType.SELECTION: "max-pressure", ActionType.SWITCH: "fixed-cycle",
                  ActionType.DURATION: "queue-proportional"}
BLIND_AGENTS = {ActionType.SELECTION: "random", ActionType.SWITCH: "fixed-cycle", ActionType.DURATION: "random"}


class Simulation(Protocol):
    """What the run steps: SUMO, or nothing (:class:`NoSimulation`)."""

    def apply(self, state: SignalState) -> None: ...

    def step(self) -> Any: ...

    def traffic_state(self) -> Any: ...


class NoSimulation:
    """Stands in for SUMO in middleware-only runs: steps cost nothing and there is no traffic."""

    def apply(self, state: SignalState) -> None:
        """No lights to set."""

    def step(self) -> None:
        """No traffic to move."""

    def traffic_state(self) -> None:
        return None


def modeled_cost(step: Callable[[], Any]) -> float:
    """Virtual time: a step costs no simulated time (faults may model otherwise)."""
    step()
    return 0.0


def measured_cost(step: Callable[[], Any]) -> float:
    """Wall-clock time: a step costs the wall time it took."""
    t0 = time.perf_counter()
    step()
    return time.perf_counter() - t0


@dataclass(frozen=True)
class RunSpec:
    config: IntersectionConfig
    action_type: ActionType = ActionType.SELECTION
    agent: str | None = None  # built-in name or package.module:Class; None = the default of the action type
    duration: float = 3600.0
    seed: int = 0
    log_path: Path | None = None
    recover_after: float | None = 5.0  # call recover() this long after entering TIMEOUT; None: never

    sumo: bool = False  # whether a traffic simulation runs (decides the default agent)

    @property
    def agent_spec(self) -> str:
        return self.agent or (DEFAULT_AGENTS if self.sumo else BLIND_AGENTS)[self.action_type]


class Run:
    """One run's processes on a given environment and transport."""

    def __init__(self, spec: RunSpec, env: simpy.Environment, transport: Transport, *,
                 simulation: Simulation | None = None, step_cost: StepCost = modeled_cost,
                 agent: Agent | None = None, mode: str = "virtual") -> None:
        self.spec = spec
        self.env = env
        # A run that writes its log to a file does not also keep it in memory: a long run's records
        # would grow the heap that every full garbage collection walks, in the middle of the hot path.
        self.events = EventLog(spec.log_path, keep=spec.log_path is None)
        self.middleware = Middleware(env, transport, spec.config, spec.action_type, self.events)
        self.agent = agent or load_agent(spec.agent_spec, spec.config, spec.action_type, spec.seed)
        self.simulation = simulation or NoSimulation()
        self.step_cost = step_cost
        self.mode = mode
        self.ended = False
        self.traffic_samples: list[tuple[float, dict[str, int]]] = []

    def start(self) -> None:
        # Everything loaded so far (SUMO, numpy, the config) lives for the whole run: keep it out of
        # the collector's way so that collections during the run stay short.
        gc.freeze()
        cfg = self.spec.config
        self.events.emit(Kind.RUN_STARTED, config=cfg.name, source=cfg.source, seed=self.spec.seed, mode=self.mode,
                         action_type=self.spec.action_type.value, agent=self.spec.agent_spec,
                         duration=self.spec.duration)
        self.middleware.start()
        self.env.process(self._agent_loop())
        self.env.process(self._simulation_loop())
        if self.spec.recover_after is not None:
            self.env.process(self._auto_recover())
        if not isinstance(self.simulation, NoSimulation):
            self.env.process(self._sample_traffic())

    def finish(self, reason: str = "duration") -> simpy.Process:
        """Clear the calls, then log the end of the run."""
        def ending():
            self.ended = True
            self.middleware.keepalive_enabled = False
            self.middleware.poller.halt()
            yield self.middleware.close()
            self.events.emit(Kind.RUN_ENDED, reason=reason)
            self.events.close()
        return self.env.process(ending())

    def _observation(self) -> Observation:
        converter = self.middleware.converter
        return Observation(self.env.now, self.middleware.cache.state, self.simulation.traffic_state(),
                           converter.next_pair)

    def _agent_loop(self) -> Generator[simpy.Event, Any, None]:
        mw = self.middleware
        yield mw.ready
        interval = self.spec.config.middleware.control_interval
        step = self.spec.config.middleware.sumo_step
        duration_actions = self.spec.action_type is ActionType.DURATION
        while not self.ended:
            if duration_actions:
                # Ask again only once the prescribed green has been served (the manager is IDLE).
                yield mw.wait_idle()
                if self.ended:
                    return
            mw.submit(self.agent.act(self._observation()))
            if not duration_actions:
                yield self.env.timeout(interval)
            elif mw.state is State.IDLE:
                yield self.env.timeout(step)  # refused or kept: do not ask again at the same instant

    def _simulation_loop(self) -> Generator[simpy.Event, Any, None]:
        step = self.spec.config.middleware.sumo_step
        sim = self.simulation
        cache = self.middleware.cache
        k = 0
        start = self.env.now

        def one_step() -> None:
            if cache.snapshot is not None:
                sim.apply(cache.snapshot.state)
            sim.step()

        while not self.ended:
            took = self.step_cost(one_step)
            self.middleware.observe_step(step, took)
            k += 1
            yield self.env.timeout(max(0.0, start + k * step - self.env.now))

    def _sample_traffic(self, period: float = 5.0) -> Generator[simpy.Event, Any, None]:
        """Queue per approach every ``period`` s, for the queue plot."""
        phases = self.spec.config.phases
        while True:
            yield self.env.timeout(period)
            traffic = self.simulation.traffic_state()
            per_approach: dict[str, int] = {}
            for p, m in traffic.movements.items():
                name = phases[p].approach or f"phase {p}"
                per_approach[name] = per_approach.get(name, 0) + m.upstream_queue
            self.traffic_samples.append((self.env.now, per_approach))

    def _auto_recover(self) -> Generator[simpy.Event, Any, None]:
        mw = self.middleware
        while True:
            yield mw.wait_for(State.TIMEOUT)
            yield self.env.timeout(self.spec.recover_after)
            while mw.timeout_flag:
                ok = yield mw.recover()
                if not ok:
                    yield self.env.timeout(self.spec.recover_after)


TargetFactory = Callable[..., Any]


def virtual_target_factory() -> TargetFactory:
    """The in-process emulator, found through the ``hils.targets`` entry point."""
    found = [ep for ep in entry_points(group="hils.targets") if ep.name == "virtual"]
    if not found:
        raise RuntimeError("no virtual target installed: the emulator package is needed for virtual-time runs "
                           "(or give --target snmp://HOST:PORT)")
    return found[0].load()


@dataclass
class RunResult:
    run: Run
    target: Any
    wall_s: float
    lateness: Any = None  # wall-clock runs: the driver's lateness summary

    @cached_property
    def records(self) -> list[dict[str, Any]]:
        log = self.run.events
        return log.records if log.keep else list(read_events(log.path))


def run_virtual(spec: RunSpec, *, target_factory: TargetFactory | None = None,
                simulation: Simulation | None = None, progress: Callable[[float], None] | None = None,
                chunk: float = 60.0, configure: Callable[[Run, Any], None] | None = None) -> RunResult:
    """Run in virtual time for ``spec.duration`` s; deterministic for a given seed."""
    t0 = time.perf_counter()
    env = simpy.Environment()
    factory = target_factory or virtual_target_factory()
    target = factory(env, spec.config, seed=spec.seed)
    run = Run(spec, env, target.transport, simulation=simulation)
    if configure is not None:
        configure(run, target)
    run.start()
    t = 0.0
    while t < spec.duration:
        t = min(spec.duration, t + chunk)
        env.run(until=t)
        if progress is not None:
            progress(t)
    ending = run.finish()
    env.run(until=ending)
    return RunResult(run, target, time.perf_counter() - t0)
