"""The Testbed: the one way to assemble a run and drive it, from Python or from the CLI.

A :class:`Testbed` owns the run's one SimPy environment, the clock that drives it, the transport
to the controller, the middleware (whose manager is the state machine), the traffic simulation and
the event log. Everything else is a client of it: ``hils run``, the fault harness, the benchmarks,
the tests and your own code::

    from hils import Testbed

    with Testbed(action_type="selection", sumo=True, seed=1) as tb:
        obs = tb.reset()
        for _ in range(30):
            obs, info = tb.step((2, 6))   # runs to the next decision point

Rules of this module
--------------------
- This is the only place that creates the SimPy environment of a run.
- Virtual time and wall-clock time go through the same code: only the clock (``_advance``) and the
  transport differ. ``target="virtual"`` (the default) is the in-process emulator, found through
  the ``hils.targets`` entry point so that ``hils`` never imports it; ``target="snmp://..."`` is a
  real controller, or ``hils emulator serve``, at wall-clock time; a callable target is a factory
  ``(env, config, seed=...) -> target`` whose target has a ``transport``, or a ``surface`` (with
  ``get_latency`` and ``set_latency``) that an in-process transport reaches (the fault harness puts
  its faults there).
- A decision point is the end of the control interval for selection and switch actions, the end of
  the served green for duration actions, and, earlier, the manager entering TIMEOUT or the end of
  the run's ``duration``.
- Every way a run ends goes through :meth:`Testbed.finish`: the calls placed are cleared,
  ``run_ended`` is logged with its reason and the log is closed. :meth:`Testbed.run` finishes the run
  before it re-raises whatever ended it (an agent's exception, Ctrl-C, SIGTERM, an error).
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import math
import signal
import time
from collections.abc import Callable, Generator, Mapping
from importlib.metadata import entry_points
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import simpy

from hils import config as config_mod
from hils.actions import ActionError, ActionType
from hils.agents import CONTROLLER_AGENTS, Agent, Observation, controller_config, load_agent
from hils.config import IntersectionConfig
from hils.detectors import DetectorFeed
from hils.errors import UserError
from hils.events import EventLog, Kind, TaggedLog
from hils.events import read as read_events
from hils.hires import Event
from hils.junction import Junction
from hils.manager import CLEAR_ATTEMPTS, State
from hils.middleware import Middleware, Submission
from hils.ntcip import SignalState
from hils.preflight import ControllerCheckFailed
from hils.scenario import Scenario, load_scenario
from hils.summary import Tally
from hils.sumo_net import TLS_ID
from hils.transport import LocalTransport, Transport

log = logging.getLogger(__name__)

StepCost = Callable[[Callable[[], Any]], float]
TargetFactory = Callable[..., Any]

#: Agents used when none is named: with traffic to observe, and without (no SUMO).
DEFAULT_AGENTS = {ActionType.SELECTION: "max-pressure", ActionType.SWITCH: "fixed-cycle",
                  ActionType.DURATION: "queue-proportional"}
BLIND_AGENTS = {ActionType.SELECTION: "random", ActionType.SWITCH: "fixed-cycle", ActionType.DURATION: "random"}

VIRTUAL = "virtual"


class Simulation(Protocol):
    """What the run steps: SUMO, or nothing (:class:`NoSimulation`)."""

    def apply(self, state: SignalState) -> None: ...

    def step(self) -> Any: ...

    def advance(self, steps: int) -> None:
        """``steps`` steps at once, with nothing shown changing between them (as many :meth:`step` calls)."""

    def traffic_state(self) -> Any: ...

    def queues(self) -> Mapping[int, int]: ...


class NoSimulation:
    """Stands in for SUMO in middleware-only runs: steps cost nothing and there is no traffic."""

    def apply(self, state: SignalState) -> None:
        """No lights to set."""

    def step(self) -> None:
        """No traffic to move."""

    def advance(self, steps: int) -> None:
        """No traffic to move."""

    def traffic_state(self) -> None:
        return None

    def queues(self) -> Mapping[int, int]:
        return {}


class RunInterrupted(Exception):
    """The run was stopped from outside (Ctrl-C or SIGTERM); ``reason`` is what ``run_ended`` logs."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class AgentFailed(Exception):
    """The agent's ``act()`` raised; the original exception is the cause."""


class NotStarted(RuntimeError):
    """A Testbed used before :meth:`Testbed.reset` or after :meth:`Testbed.close`."""


class SeveralControllers(UserError, ValueError):
    """A run of several controllers asked for the one controller (name a traffic light instead)."""


def modeled_cost(step: Callable[[], Any]) -> float:
    """Virtual time: a step costs no simulated time (faults may model otherwise)."""
    step()
    return 0.0


def measured_cost(step: Callable[[], Any]) -> float:
    """Wall-clock time: a step costs the wall time it took."""
    t0 = time.perf_counter()
    step()
    return time.perf_counter() - t0


def virtual_target_factory() -> TargetFactory:
    """The in-process emulator, found through the ``hils.targets`` entry point."""
    found = [ep for ep in entry_points(group="hils.targets") if ep.name == VIRTUAL]
    if not found:
        raise RuntimeError("no virtual target installed: the emulator package is needed for virtual-time runs "
                           "(or give target='snmp://HOST:PORT')")
    return found[0].load()


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What a run is, as the CLI and the harness describe it (see :class:`Testbed` for the fields)."""

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


class Testbed:
    __test__ = False  # pytest: a class named Test* here is not a test
    """A run of one intersection's controller, or of a scenario's several: controllers (virtual or real),
    middleware, optional SUMO, event log.

    ``config``: an :class:`IntersectionConfig`, a TOML path, or None for the shipped four-leg; or, instead,
    ``scenario``: a shipped scenario's name (``corridor``, ``grid4x4``), a ``.scenario.toml`` path or a
    :class:`hils.scenario.Scenario`, one controller per traffic light, all in this one run (:attr:`junctions`).
    ``action_type``: selection, switch or duration. ``target``: ``"virtual"``, an ``snmp://`` URL or a target
    factory; with several controllers, a mapping from each traffic light to its own (a scenario at wall clock
    needs a URL for every light). ``sumo``: True to run the SUMO scenario (started at each reset), or a
    simulation object the caller started; ``sumo_config``: the ``.sumocfg`` SUMO starts with (default: the
    scenario's, or the shipped four-leg). ``seed``: every virtual-time run is reproducible from it.
    ``agent``: what :meth:`run` uses when given none (a built-in name, ``package.module:Class`` or an
    instance; with several controllers each gets its own of a named agent). ``duration``: simulated seconds
    after which the run is done (None: no end). ``log_path``: the JSON Lines event log (None: kept in memory
    only). ``recover_after``: seconds in TIMEOUT before recover() is called (None: never).
    ``on_reset(testbed, target)`` runs after assembly, before anything starts: the fault harness wraps parts
    of the run there (``target``: the single controller's, or None with several). ``measure``: False skips
    what only the end-of-run summary and the queue plot need (per-vehicle delays, queue and spillback samples,
    ``queues`` records), as environments do for speed.

    With one controller the Testbed is that controller's: :meth:`step`, :meth:`observe`, :attr:`middleware`,
    :attr:`config`. With several, :meth:`step_all` and :meth:`observe_all` take and give one value per
    traffic light, and :attr:`junctions` holds each controller's parts.
    """

    def __init__(self, config: IntersectionConfig | str | Path | None = None, *,
                 action_type: ActionType | str = ActionType.SELECTION,
                 target: str | TargetFactory | Mapping[str, str | TargetFactory] = VIRTUAL,
                 sumo: bool | Simulation = False, seed: int = 0, agent: str | Agent | None = None,
                 duration: float | None = None, log_path: str | Path | None = None,
                 recover_after: float | None = 5.0,
                 on_reset: Callable[[Testbed, Any], None] | None = None,
                 sumo_config: str | Path | None = None, detectors: bool | None = None,
                 scenario: str | Path | Scenario | None = None, measure: bool = True) -> None:
        if scenario is not None and config is not None:
            raise ValueError("give a config (one intersection) or a scenario (its intersections), not both")
        self.scenario = _scenario(scenario)
        if self.scenario is not None:
            self.configs = {tls: controller_config(agent, c) for tls, c in self.scenario.intersections.items()}
            sumo_config = sumo_config if sumo_config is not None else self.scenario.sumo_config
        else:
            cfg = config if isinstance(config, IntersectionConfig) else config_mod.load(config)
            self.configs = {TLS_ID: controller_config(agent, cfg)}
        self.config = next(iter(self.configs.values()))
        self.action_type = ActionType(action_type)
        self._targets = _target_specs(target, self.configs)
        # Each wall-clock target parsed and its host resolved once, here: a bad one is refused before anything
        # starts, naming its light.
        self._wall_targets = {tls: _check_target(url, f"{tls}: " if self.several else "")
                              for tls, url in self._targets.items() if isinstance(url, str) and url != VIRTUAL}
        if duration is not None and not duration > 0:
            raise ValueError(f"duration must be positive seconds or None, got {duration!r}")
        self._sumo_spec = sumo
        self.sumo_config = sumo_config
        self.seed = seed
        self._agent_spec = agent
        # Detector actuations from SUMO feed the controller when asked, and by default for the agents that leave
        # the controller to its own operation (actuated, coordinated).
        self.detectors = agent in CONTROLLER_AGENTS if detectors is None else detectors
        self.duration = duration
        self.log_path = Path(log_path) if log_path is not None else None
        self.recover_after = recover_after
        self.on_reset = on_reset
        self.measure = measure
        self.spec = RunSpec(self.config, self.action_type, agent if isinstance(agent, str) else None,
                            math.inf if duration is None else duration, seed, self.log_path, recover_after,
                            sumo=bool(sumo))
        self.env: simpy.Environment | None = None
        self.junctions: dict[str, Junction] = {}
        self.events: EventLog | None = None
        self.tally = Tally()
        self.simulation: Simulation = NoSimulation()
        self.step_cost: StepCost = modeled_cost
        self.ended = False
        self.end_reason: str | None = None
        self.traffic: Any = None  # the simulation's end-of-run summary, once finished
        self.wall_s = 0.0
        self._driver: Any = None
        self._owns_sumo = False
        self._wall_t0 = 0.0

    # --- properties ---------------------------------------------------------------------------

    @property
    def mode(self) -> str:
        """``virtual`` or ``wall-clock``."""
        return "wall-clock" if self._wall_targets else VIRTUAL

    @property
    def several(self) -> bool:
        """True for a run of more than one controller (a corridor, a grid)."""
        return len(self.configs) > 1

    @property
    def junction(self) -> Junction:
        """The run's one controller (a run of several: :attr:`junctions`)."""
        if self.several:
            raise SeveralControllers(f"this run has {len(self.configs)} controllers ({', '.join(self.configs)}): "
                                     "use testbed.junctions[TLS], step_all() and observe_all()")
        if not self.junctions:
            raise NotStarted("the Testbed is not started: call reset() first")
        return next(iter(self.junctions.values()))

    @property
    def middleware(self) -> Middleware | None:
        return self.junction.middleware if self.junctions else None

    @property
    def transport(self) -> Transport | None:
        return self.junction.transport if self.junctions else None

    @property
    def target(self) -> Any:
        return self.junction.target if self.junctions else None

    @property
    def agent(self) -> Agent | None:
        return self.junction.agent if self.junctions else None

    @agent.setter
    def agent(self, agent: Agent | None) -> None:
        self.junction.agent = agent

    @property
    def traffic_samples(self) -> list[tuple[float, dict[str, int]]]:
        return self.junction.traffic_samples if self.junctions else []

    @property
    def now(self) -> float:
        return self._env.now

    @property
    def state(self) -> State:
        """The manager's state."""
        return self._mw.state

    @property
    def done(self) -> bool:
        """True once the run has ended or its ``duration`` has passed."""
        return self.ended or (self.duration is not None and self._env.now >= self.duration - 1e-9)

    @property
    def records(self) -> list[dict[str, Any]]:
        """The event log's records (read back from the file when the log is not kept in memory)."""
        log_ = self.events
        if log_ is None:
            return []
        return log_.records if log_.keep else list(read_events(log_.path))

    def hires(self) -> dict[str, list[Event]]:
        """Each controller's own hi-res event log, where the run can read it: the in-process emulator's (a target
        with a ``hires()`` method, see :mod:`hils.hires`). A controller reached at the wall clock keeps its own,
        which a field tool collects from it (:func:`hils.hires.collect` for a MaxTime endpoint)."""
        return {tls: j.target.hires() for tls, j in self.junctions.items()
                if callable(getattr(j.target, "hires", None))}

    @property
    def driver(self) -> Any:
        """Wall-clock runs: the :class:`hils.clock.WallClockDriver` (its ``loop`` is the run's asyncio loop,
        where servers of the run such as the dashboard run as tasks); None in virtual time."""
        return self._driver

    @property
    def lateness(self) -> Any:
        """Wall-clock runs: the driver's lateness summary; None in virtual time."""
        return None if self._driver is None else self._driver.lateness.summary()

    # --- life cycle -----------------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> Observation | dict[str, Observation]:
        """Start (or restart, with a new seed) the run; returns the first observation (one per traffic light
        in a run of several)."""
        if self.env is not None:
            self.close()
        if seed is not None:
            self.seed = seed
            self.spec = dataclasses.replace(self.spec, seed=seed)
        self._wall_t0 = time.perf_counter()
        self.ended, self.end_reason, self.traffic = False, None, None
        env = self.env = simpy.Environment()
        self._assemble_clock(env)
        # A run that writes its log to a file does not also keep it in memory: a long run's records
        # would grow the heap that every full garbage collection walks, in the middle of the hot path.
        self.events = EventLog(self.log_path, keep=self.log_path is None)
        self.tally = Tally()  # the summary's figures, kept as the run goes: its end re-reads nothing
        self.events.subscribe(self.tally)
        self.junctions = {tls: self._assemble_junction(env, tls, index) for index, tls in enumerate(self.configs)}
        self._assemble_simulation()
        for j in self.junctions.values():
            j.agent = self._load_agent(j.config)
        if self.on_reset is not None:
            self.on_reset(self, None if self.several else self.junction.target)
        self._start()
        self._advance(None, *(j.middleware.ready for j in self.junctions.values()), every=True)
        self._check_controllers()
        return self.observe_all() if self.several else self.observe()

    def _check_controllers(self) -> None:
        """The start-up checks: refuse a controller unfit for a run (one line each), warn about the rest."""
        refusals = [(j.id, line) for j in self.junctions.values() for line in j.refusals()]
        if refusals:
            self.finish("error")
            raise ControllerCheckFailed("; ".join(f"{tls}: {line}" if self.several else line
                                                  for tls, line in refusals))

    def _assemble_clock(self, env: simpy.Environment) -> None:
        if self.mode == VIRTUAL:
            self.step_cost = modeled_cost
            self._driver = None
            return
        from hils.clock import WallClockDriver

        driver = self._driver = WallClockDriver(env)

        def wall_cost(step: Callable[[], Any]) -> float:
            # What a step cost at the wall clock: its own time plus how late it started.
            return max(0.0, driver.sim_now() - env.now) + measured_cost(step)

        self.step_cost = wall_cost

    def _assemble_junction(self, env: simpy.Environment, tls: str, index: int) -> Junction:
        cfg, spec = self.configs[tls], self._targets[tls]
        # Every controller of a run has its own seeded draws (its tick phase, its latencies).
        seed = self.seed if not self.several else self.seed * 1009 + index
        community = None
        if self.mode == VIRTUAL:
            factory = virtual_target_factory() if spec == VIRTUAL else spec
            target = factory(env, cfg, seed=seed)
            # A target brings its transport, or an object surface that an in-process transport reaches.
            transport = getattr(target, "transport", None) or LocalTransport(
                env, target.surface, tau_udp=cfg.middleware.tau_udp, get_latency=target.get_latency,
                set_latency=target.set_latency, seed=seed, change_feed=getattr(target, "change_feed", None))
            where = "the in-process emulator"
        else:
            from hils.snmp import SnmpTransport

            target, address = self._wall_targets[tls]
            transport = SnmpTransport(env, self._driver, target, tau_udp=cfg.middleware.tau_udp, address=address)
            where, community = f"{target.host}:{target.port}", getattr(target, "community", None)
        events = TaggedLog(self.events, tls) if self.several else self.events
        # One controller's tally is the run's; each of several has its own, handed its intersection's records.
        tally = self.tally
        if self.several:
            tally = Tally(tls)
            self.events.subscribe(tally, intersection=tls)
        middleware = Middleware(env, transport, cfg, self.action_type, events, where=where, community=community)
        return Junction(tls, cfg, target, transport, middleware, events, tally)

    def _assemble_simulation(self) -> None:
        sumo = self._sumo_spec
        self._owns_sumo = False
        if sumo is True:
            from hils.sumo import SumoSimulation

            # SUMO's tripinfo (RESCO's figures) goes beside the event log
            tripinfo = self.log_path.with_name("tripinfo.xml") if self.log_path is not None else None
            sim = SumoSimulation(seed=self.seed, end=self.duration, sumo_config=self.sumo_config, lights=self.configs,
                                 measure=self.measure, links=self.scenario.links if self.scenario else None,
                                 tripinfo=tripinfo)
            sim.start()  # a SUMO that fails to start (e.g. a network the config does not fit) closes itself
            self.simulation = sim
            self._owns_sumo = True
        elif sumo is False:
            self.simulation = NoSimulation()
        else:
            self.simulation = sumo
        if isinstance(self.simulation, NoSimulation):
            return
        for j in self.junctions.values():
            # One light: the simulation itself (a wrapper the caller hands in works); several: each its own.
            j.view = self.simulation.lights[j.id] if self.several else self.simulation

    def _load_agent(self, config: IntersectionConfig) -> Agent | None:
        spec = self._agent_spec
        if spec is None or isinstance(spec, str):
            return load_agent(self.spec.agent_spec, config, self.action_type, self.seed)
        if self.several:
            raise SeveralControllers("an agent object drives one controller: name a built-in agent or "
                                     "package.module:Class, and each controller gets its own")
        return spec

    def _start(self) -> None:
        # Everything loaded so far (SUMO, numpy, the config) lives for the whole run: keep it out of
        # the collector's way so that collections during the run stay short.
        gc.freeze()
        for j in self.junctions.values():
            zones = any(p.approach is not None for p in j.config.preempts.values())
            if (self.detectors or zones) and j.view is not None:
                # Built before the run starts: a detector on a lane its phase does not have is refused now.
                pm = j.view.phase_map
                j.detector_feed = DetectorFeed(j.transport, j.config, j.events,
                                               {p: pm.incoming_lanes(p) for p in pm.phases}, detectors=self.detectors,
                                               preempt_calls=j.view.preempt_calls if zones else None)
        cfg = self.config
        fields = ({"scenario": self.scenario.name, "source": self.scenario.source, "intersections": list(self.configs)}
                  if self.several else
                  {"config": cfg.name, "source": cfg.source})
        self.events.emit(Kind.RUN_STARTED, **fields, seed=self.seed, mode=self.mode,
                         action_type=self.action_type.value, agent=_agent_name(self._agent_spec, self.spec),
                         duration=self.duration)
        ended = lambda: self.ended  # noqa: E731 - the junctions' processes ask it as the run goes
        # Several controllers start spread over one poll period, so that their polls, keepalives and read-backs
        # go out spread over it too, as a central system staggers them: 64 controllers polled at one instant
        # are a burst that makes the last answers of each round several milliseconds late at the wall clock.
        spread = self.config.middleware.poll_period / len(self.junctions)
        for index, j in enumerate(self.junctions.values()):
            j.middleware.start(after=index * spread)
            if self.recover_after is not None:
                self.env.process(j.auto_recover(self.recover_after, ended))
            if j.view is not None and self.measure:
                self.env.process(j.sample_traffic(ended))
        self.env.process(self._simulation_loop())

    def _poll_counts(self) -> dict[str, Any]:
        if not self.junctions:
            return {}  # the run ended while it was being assembled
        if self.several:
            return {tls: j.middleware.poller.counts for tls, j in self.junctions.items()}
        return self.junction.middleware.poller.counts

    def finish(self, reason: str | None = None) -> None:
        """End the run: clear the calls placed, log ``run_ended`` with ``reason``, close the log.

        ``reason`` defaults to ``duration`` once the duration has passed, else ``closed``.
        Idempotent; bounded in wall-clock time (a clearing SET answers or fails within tau_udp, and one that
        gets no answer is sent again, :data:`hils.manager.CLEAR_ATTEMPTS` times in all)."""
        if self.env is None or self.ended:
            return
        if reason is None:
            reason = "duration" if self.done else "closed"
        self.ended = True
        self.end_reason = reason

        def ending() -> Generator[simpy.Event, Any, None]:
            yield simpy.AllOf(self.env, [j.middleware.close() for j in self.junctions.values()])
            self.events.emit(Kind.RUN_ENDED, reason=reason, polls=self._poll_counts())
            self.events.close()

        done = self.env.process(ending())
        tau_udp = max(cfg.middleware.tau_udp for cfg in self.configs.values())
        try:
            self._advance(self.env.now + CLEAR_ATTEMPTS * tau_udp + 1.0, done)
            if self._driver is not None:
                self._advance(self.env.now + 0.05)  # let answers already on their way land before closing
        except RunInterrupted:
            log.warning("interrupted again while clearing the calls; they may stay until the backup time")
        finally:
            if not done.triggered:
                self.events.emit(Kind.RUN_ENDED, reason=reason, polls=self._poll_counts())
                self.events.close()
            self.wall_s = time.perf_counter() - self._wall_t0
            self._collect_traffic()

    def _collect_traffic(self) -> None:
        summary = getattr(self.simulation, "summary", None)
        if summary is not None and getattr(self.simulation, "running", False):
            # the run's own SUMO ends here, so that its tripinfo (RESCO's figures) is complete
            self.traffic = self.simulation.finish() if self._owns_sumo else summary()

    def close(self) -> None:
        """Finish the run if it is still going, then release the transports, the clock and SUMO."""
        if self.env is None:
            return
        try:
            self.finish()
        finally:
            for j in self.junctions.values():
                j.transport.close()
            if self._driver is not None:
                self._driver.close()
            if self._owns_sumo:
                self.simulation.close()
            self.env = None

    def __enter__(self) -> Testbed:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self.env is not None and not self.ended:
            self.finish(_reason_of(exc) if exc is not None else None)
        self.close()

    # --- stepping ---------------------------------------------------------------------------------

    def observe(self) -> Observation:
        """What the agent sees now."""
        self._started()
        return self.junction.observe()

    def observe_all(self) -> dict[str, Observation]:
        """What each traffic light's agent sees now."""
        self._started()
        return {tls: j.observe() for tls, j in self.junctions.items()}

    def step(self, action: Any) -> tuple[Observation, dict[str, Any]]:
        """Submit ``action`` and run to the next decision point; returns the observation and an info mapping.

        An action that cannot be served is refused with a typed :class:`hils.actions.ActionError`
        (logged; nothing is sent, no time passes). ``info`` says what happened: ``action_id``,
        ``dropped`` (the manager was not IDLE), ``state``, ``timeout`` (the manager entered TIMEOUT
        during the step) and ``timeout_reason``, ``ended`` (the run's duration has passed)."""
        self._check_running()
        observations, infos = self.step_all({self.junction.id: action})
        return observations[self.junction.id], infos[self.junction.id]

    def step_all(self, actions: Mapping[str, Any]) -> tuple[dict[str, Observation], dict[str, dict[str, Any]]]:
        """One action per traffic light, then run to the next decision point of any of them; returns the
        observation and the info (as :meth:`step`'s, with ``due``) of each.

        Each controller keeps its own decision schedule: only the lights that are ``due`` (at their decision
        point now, as the last step's infos said; every light after :meth:`reset`) act; the action of a light
        that is not due, left out or None is not taken (``acted`` False), and its schedule runs on. Every
        action taken is converted before any is submitted: one that cannot be served raises its
        :class:`hils.actions.ActionError` and nothing is sent to any controller."""
        self._check_running()
        unknown = sorted(set(actions) - set(self.junctions))
        if unknown:
            raise KeyError(f"no traffic light {', '.join(unknown)} in this run; it has {', '.join(self.junctions)}")
        chosen = {tls: value for tls, value in actions.items() if value is not None and self.junctions[tls].due}
        if len(chosen) > 1:  # all or none: a refused action leaves the others unsent
            for tls, value in chosen.items():
                try:
                    self.junctions[tls].middleware.check(value)
                except ActionError:
                    chosen = {tls: value}  # submitted alone: logged as received and refused, nothing sent
                    break
        submitted = {tls: self.junctions[tls].middleware.submit(value) for tls, value in chosen.items()}
        for tls, done in submitted.items():
            if done.error is not None:
                if self.several:
                    done.error.add_note(f"the action of traffic light {tls}; nothing was sent to any controller")
                raise done.error
        return self._to_decision(submitted)

    def wait(self) -> tuple[Observation, dict[str, Any]]:
        """Run to the next decision point without acting (e.g. after a refused action)."""
        self._check_running()
        observations, infos = self._to_decision({})
        return observations[self.junction.id], infos[self.junction.id]

    def run_for(self, seconds: float) -> Observation | dict[str, Observation]:
        """Let ``seconds`` of run time pass without acting; returns the observation then."""
        self._check_running()
        self._advance(self._env.now + seconds)
        return self.observe_all() if self.several else self.observe()

    def recover(self, tls: str | None = None) -> bool:
        """Recover from TIMEOUT now (the controller of traffic light ``tls`` in a run of several): re-read the
        controller and return to IDLE; False if it failed."""
        self._check_running()
        junction = self.junctions[tls] if tls is not None else self.junction
        proc = junction.middleware.recover()
        self._advance(None, proc)
        return bool(proc.value)

    def run(self, agent: Agent | None = None, progress: Callable[[float], None] | None = None) -> str:
        """Let the agents (``agent``, or the Testbed's: one per traffic light) act at every decision point until
        the run is done.

        Returns the end reason (``duration``). Whatever else ends the run (an agent raising:
        :class:`AgentFailed`; Ctrl-C or SIGTERM: :class:`RunInterrupted` or KeyboardInterrupt; an
        error) first finishes the run cleanly, then propagates."""
        if self.env is None:
            self.reset()
        agents = {tls: agent or j.agent for tls, j in self.junctions.items()}
        if any(a is None for a in agents.values()):
            raise NotStarted("no agent: pass one to run() or to the Testbed")
        observations = self.observe_all()
        try:
            while not self.done:
                actions = {}
                for tls, a in agents.items():
                    if not self.junctions[tls].due:
                        continue  # its own decision point has not come: it is not asked
                    try:
                        actions[tls] = a.act(observations[tls])
                    except Exception as exc:
                        raise AgentFailed(f"the agent's act() raised {type(exc).__name__}: {exc}") from exc
                try:
                    # None: no action this time, the controller runs on its own until the next decision.
                    observations, _ = self.step_all(actions)
                except ActionError:
                    # refused and logged: the agents are asked again at the next decision
                    observations, _ = self.step_all({})
                if progress is not None:
                    progress(self._env.now)
        except BaseException as exc:
            self.finish(_reason_of(exc))
            raise
        self.finish("duration")
        return "duration"

    def _to_decision(self, submitted: Mapping[str, Submission]
                     ) -> tuple[dict[str, Observation], dict[str, dict[str, Any]]]:
        self._started()
        timeouts = {tls: j.middleware.entering(State.TIMEOUT) for tls, j in self.junctions.items()}
        for j in self.junctions.values():
            if j.due:
                j.schedule(self.action_type)  # asked now: its next decision point starts from here
        deadlines = [j.deadline for j in self.junctions.values() if j.deadline is not None]
        if self.duration is not None:
            deadlines.append(self.duration)
        self._advance(min(deadlines, default=None), *(ev for j in self.junctions.values() for ev in j.waits))
        infos = {}
        for tls, j in self.junctions.items():
            j.due = j.at_decision()
            done = submitted.get(tls)
            infos[tls] = j.info(done.action_id if done else None, done is not None,
                                done.dropped if done else False, timeouts[tls].triggered) | {
                "ended": self.done, "due": j.due}
        return self.observe_all(), infos

    # --- the clock ----------------------------------------------------------------------------------

    def _advance(self, until: float | None, *events: simpy.Event, every: bool = False) -> None:
        """Run the environment until one of ``events`` (all of them with ``every``) has been processed, or to
        ``until``.

        The one place time moves. ``until`` follows SimPy's ``run(until=t)`` rule in both clocks:
        events due exactly at ``t`` stay queued, so an agent deciding at ``t`` acts before them."""
        env = self._env
        if every and events:
            events = (simpy.AllOf(env, events),)
        if any(ev.processed for ev in events) or (until is not None and until <= env.now):
            return
        virtual = self._driver is None
        if virtual and until is not None:
            events = (*events, _deadline(env, until))
        stop = simpy.core.StopSimulation.callback if virtual else self._stop_driver
        for ev in events:
            ev.callbacks.append(stop)
        try:
            if virtual:
                env.run()  # until one of the events stops it
            else:
                self._driver.run_sync(until=until)
        finally:
            for ev in events:
                if ev.callbacks is not None and stop in ev.callbacks:
                    ev.callbacks.remove(stop)
        driver = self._driver
        if driver is not None and driver.signalled is not None:
            signalled, driver.signalled = driver.signalled, None
            raise RunInterrupted("interrupted" if signalled == signal.SIGINT else "terminated")

    def _stop_driver(self, _event: simpy.Event) -> None:
        self._driver.stop()

    # --- processes ---------------------------------------------------------------------------------

    def _simulation_loop(self) -> Generator[simpy.Event, Any, None]:
        env = self._env
        step = self.config.middleware.sumo_step
        sim = self.simulation
        lights = [(j.view, j.middleware.cache) for j in self.junctions.values() if j.view is not None]
        feeds = [(j.view, j.detector_feed) for j in self.junctions.values() if j.detector_feed is not None]
        middlewares = [j.middleware for j in self.junctions.values()]
        k = 0
        start = env.now

        def show() -> None:
            for view, cache in lights:
                if cache.snapshot is not None:
                    view.apply(cache.snapshot.state)

        def one_step() -> None:
            show()
            sim.step()
            for view, feed in feeds:
                feed.feed(view.present())

        # Steps that cost no time and act on nothing but SUMO (virtual time, no fault on their cost, no detectors
        # SETting the controller) run back to back while nothing else is due before the next one: what they
        # do and see is the same, without a trip through the event queue for each, and SUMO makes the step due
        # and those after it in one call (nothing can change what it shows until the next event).
        back_to_back = self.step_cost is modeled_cost and not feeds
        while not self.ended:
            if back_to_back:
                show()
                n = 1 + _steps_before(env.peek(), start, k + 1, step)
                sim.advance(n)
                took = 0.0
            else:
                n, took = 1, self.step_cost(one_step)
            for mw in middlewares:
                mw.observe_step(step, took)
            k += n
            yield env.timeout(max(0.0, start + k * step - env.now))

    # --- helpers ----------------------------------------------------------------------------------------

    @property
    def _env(self) -> simpy.Environment:
        self._started()
        return self.env

    def _started(self) -> None:
        if self.env is None:
            raise NotStarted("the Testbed is not started: call reset() first")

    @property
    def _mw(self) -> Middleware:
        self._started()
        return self.junction.middleware

    def _check_running(self) -> None:
        self._started()
        if self.ended:
            raise NotStarted(f"the run has ended ({self.end_reason}): call reset() to start another")


#: Steps run back to back at most when no other event is queued (one simulated hour at 0.25 s).
_MAX_STRETCH = 14400


def _steps_before(until: float, start: float, k: int, step: float) -> int:
    """How many steps of the grid ``start + j * step``, from j = k on, start before ``until``."""
    if math.isinf(until):
        return _MAX_STRETCH  # nothing else will ever happen: step on, a stretch at a time
    j = max(k, math.ceil((until - start) / step))
    # the grid's own float comparison decides, however the division rounded
    while j > k and start + (j - 1) * step >= until:
        j -= 1
    while start + j * step < until:
        j += 1
    return j - k


def _deadline(env: simpy.Environment, at: float) -> simpy.Event:
    """An event due at ``at`` that runs before every other event due then, as ``env.run(until=at)``'s own.

    Built as SimPy builds that one; unlike it, a deadline that another event beat to the stop is left
    without callbacks, so it cannot stop a later run."""
    event = simpy.Event(env)
    event._ok, event._value = True, None
    env.schedule(event, simpy.core.URGENT, at - env.now)
    return event


class TargetError(UserError, ValueError):
    """A target that is neither ``virtual`` nor a usable ``snmp://`` URL."""


def _scenario(scenario: str | Path | Scenario | None) -> Scenario | None:
    if scenario is None or isinstance(scenario, Scenario):
        return scenario
    return load_scenario(scenario)


def _target_specs(target: str | TargetFactory | Mapping[str, str | TargetFactory],
                  configs: Mapping[str, IntersectionConfig]) -> dict[str, str | TargetFactory]:
    """Each traffic light's target: one for all, or a mapping naming every light; all in virtual time (the
    emulator, a factory) or all at the wall clock (URLs), since a run has one clock."""
    if isinstance(target, Mapping):
        missing, unknown = sorted(set(configs) - set(target)), sorted(set(target) - set(configs))
        if missing or unknown:
            raise TargetError(f"targets: {'no target for ' + ', '.join(missing) if missing else ''}"
                              f"{'; ' if missing and unknown else ''}"
                              f"{'no traffic light ' + ', '.join(unknown) if unknown else ''}; allowed: one "
                              f"target per traffic light of the run ({', '.join(configs)})")
        specs = {tls: target[tls] for tls in configs}
    else:
        if isinstance(target, str) and target != VIRTUAL and len(configs) > 1:
            raise TargetError(f"target {target!r}: a run of {len(configs)} controllers needs one target per traffic "
                              f"light ({', '.join(configs)}): a mapping, or a TOML file of TLS = URL lines")
        specs = dict.fromkeys(configs, target)
    urls = [spec for spec in specs.values() if isinstance(spec, str) and spec != VIRTUAL]
    if urls and len(urls) != len(specs):
        raise TargetError("targets: either every controller is reached at the wall clock (snmp:// URLs) or none "
                          "is (virtual): a run has one clock")
    return specs


def _check_target(url: str, light: str) -> tuple[Any, tuple[str, int]]:
    """The :class:`hils.snmp.SnmpTarget` of ``url`` and its host's address; a URL that is not one, or whose host
    does not resolve, is refused (``light``: how the message names the traffic light, in a run of several)."""
    if not url.startswith("snmp://"):
        raise TargetError(f"{light}target {url!r}: allowed: 'virtual' or "
                          "snmp://HOST[:PORT][?community=NAME&version=1|2c]")
    from hils.snmp import SnmpTarget, resolve
    from hils.transport import TransportError

    try:
        target = SnmpTarget.parse(url)
        return target, resolve(target)
    except ValueError as exc:
        raise TargetError(f"{light}{exc}") from None
    except TransportError as exc:
        raise TargetError(f"{light}target {url!r}: {exc}; allowed: a host name this machine resolves, or an "
                          "IPv4 address") from None


def _agent_name(given: str | Agent | None, spec: RunSpec) -> str:
    """How the log names the agent: its spec, or the class of an agent object handed in."""
    return spec.agent_spec if given is None or isinstance(given, str) else type(given).__name__


def _reason_of(exc: BaseException) -> str:
    """The ``run_ended`` reason for what ended a run."""
    if isinstance(exc, RunInterrupted):
        return exc.reason
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, AgentFailed):
        return "agent_error"
    return "error"


@dataclasses.dataclass
class RunResult:
    """A finished run: the Testbed (its records, traffic summary, lateness) and the wall time."""

    testbed: Testbed
    target: Any
    wall_s: float
    end_reason: str

    @property
    def records(self) -> list[dict[str, Any]]:
        return self.testbed.records

    @property
    def lateness(self) -> Any:
        return self.testbed.lateness


def run_spec(spec: RunSpec, *, target: str | TargetFactory = VIRTUAL, simulation: Simulation | None = None,
             configure: Callable[[Testbed, Any], None] | None = None,
             progress: Callable[[float], None] | None = None) -> RunResult:
    """Build a Testbed from ``spec``, run its agent for ``spec.duration`` s and close it.

    ``simulation``: a simulation the caller started (and closes); default: SUMO when ``spec.sumo``."""
    tb = Testbed(spec.config, action_type=spec.action_type, target=target,
                 sumo=simulation if simulation is not None else spec.sumo, seed=spec.seed, agent=spec.agent,
                 duration=spec.duration, log_path=spec.log_path, recover_after=spec.recover_after,
                 on_reset=configure)
    with tb:
        tb.reset()
        reason = tb.run(progress=progress)
        return RunResult(tb, tb.target, tb.wall_s, reason)
