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
- One intersection is the case N = 1: the run holds a mapping of :class:`hils.run.intersection.Intersection`
  and every step of it (assembly, stepping, observing, finishing) goes over that mapping; the single-light
  API is a view of the one-intersection case.
- Virtual time and wall-clock time go through the same code: only the clock (:mod:`hils.shell.clock`, whose
  ``advance`` is the one place time moves) and the transport differ. ``target="virtual"`` (the default) is
  the in-process emulator, found through the ``hils.shell.targets`` entry point so that ``hils`` never imports it;
  ``target="snmp://..."`` is a real controller, or ``hils emulator serve``, at wall-clock time; a callable
  target is a factory ``(env, config, *, seed, fast_path, hires) -> target`` whose target has a ``transport``, or
  a ``surface`` (with ``get_latency`` and ``set_latency``) that an in-process transport reaches (the fault
  harness puts its faults there); ``hires`` says whether the run keeps the controller's hi-res record
  (:attr:`Testbed.keeps_hires`).
- Virtual time's fast path is switched by the run's ``fast_path`` flag alone (:mod:`hils.shell.fastpath`).
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
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import simpy

from hils.agents.builtin import DETECTOR_AGENTS, Agent, Observation, check_plans, controller_config, load_agent
from hils.control.actions import ActionError, ActionType, PreemptedError
from hils.control.manager import CLEAR_ATTEMPTS, State
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import AgentFailed, RunInterrupted, UserError, described
from hils.protocol.hires import Event
from hils.protocol.scenario import Scenario, labels, load_scenario
from hils.protocol.spat import MovementTiming
from hils.report.summary import Tally
from hils.run.detectors import DetectorFeed
from hils.run.intersection import Intersection
from hils.run.simulation import NoSimulation, Simulation, steps
from hils.shell.clock import Answer, Clock, VirtualClock, WallClockDriver
from hils.shell.events import EventLog, Kind, LogWriteError, TaggedLog
from hils.shell.events import read as read_events
from hils.shell.fastpath import StepCost, modeled_cost
from hils.shell.hiresjournal import HiresJournal
from hils.shell.middleware import Middleware, Received, Submission
from hils.shell.preflight import ControllerCheckFailed
from hils.shell.targets import VIRTUAL, TargetFactory, check_target, connect, target_specs
from hils.shell.transport import Transport
from hils.sim.network import TLS_ID

if TYPE_CHECKING:
    from hils.sim.worker import SumoProcess

__all__ = [
    "BLIND_AGENTS", "DEFAULT_AGENTS", "AgentFailed", "NotStarted", "RunInterrupted", "RunResult", "RunSpec",
    "SeveralIntersections", "Testbed", "run_spec",
]

log = logging.getLogger(__name__)


#: Agents used when none is named: with traffic to observe, and without (no SUMO).
DEFAULT_AGENTS = {ActionType.SELECTION: "max-pressure", ActionType.SWITCH: "fixed-cycle",
                  ActionType.DURATION: "queue-proportional", ActionType.CONTROL: "omit-hold"}
BLIND_AGENTS = {ActionType.SELECTION: "random", ActionType.SWITCH: "fixed-cycle", ActionType.DURATION: "random",
                ActionType.CONTROL: "omit-hold"}



class NotStarted(RuntimeError):
    """A Testbed used before :meth:`Testbed.reset` or after :meth:`Testbed.close`."""


class SeveralIntersections(UserError, ValueError):
    """A run of several intersections asked for its one intersection (name one instead)."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What a run is, as the CLI and the harness describe it (see :class:`Testbed` for the fields)."""

    config: IntersectionConfig
    action_type: ActionType = ActionType.SELECTION
    agent: str | None = None  # built-in name or package.module:Class; None = the default of the action type
    duration: float = 3600.0
    seed: int = 0
    log_path: Path | None = None
    recover_after: float | None = 5.0  # recover this long after entering TIMEOUT; None: never
    sumo: bool = False  # whether a traffic simulation runs (decides the default agent)
    fast_path: bool = True  # virtual time leaves out what cannot change a result (hils.shell.fastpath)

    @property
    def agent_spec(self) -> str:
        return self.agent or (DEFAULT_AGENTS if self.sumo else BLIND_AGENTS)[self.action_type]


class _OneIntersection:
    """The single-light API: a thin view of a run of one intersection (:class:`Testbed`'s general API takes and
    gives one value per intersection; in a run of several, these raise :class:`SeveralIntersections`)."""

    configs: dict[str, IntersectionConfig]
    intersections: dict[str, Intersection]
    reset_all: Callable[..., dict[str, Observation]]
    step_all: Callable[..., tuple[dict[str, Observation], dict[str, dict[str, Any]]]]

    @property
    def config(self) -> IntersectionConfig:
        """The intersection's config."""
        return self.configs[self._only()]

    @property
    def intersection(self) -> Intersection:
        """The run's intersection (its parts stay after the run is closed)."""
        name = self._only()
        if name not in self.intersections:
            raise NotStarted("the Testbed is not started: call reset() first")
        return self.intersections[name]

    @property
    def middleware(self) -> Middleware:
        return self.intersection.middleware

    @property
    def transport(self) -> Transport:
        return self.intersection.transport

    @property
    def target(self) -> Any:
        return self.intersection.target

    @property
    def agent(self) -> Agent | None:
        return self.intersection.agent

    @agent.setter
    def agent(self, agent: Agent | None) -> None:
        self.intersection.agent = agent

    @property
    def traffic_samples(self) -> list[tuple[float, dict[str, int]]]:
        return self.intersection.traffic_samples

    @property
    def state(self) -> State:
        """The manager's state."""
        return self.intersection.middleware.state

    def reset(self, seed: int | None = None) -> Observation:
        """Start (or restart, with a new seed) the run; returns the first observation."""
        name = self._only()
        return self.reset_all(seed)[name]

    def observe(self) -> Observation:
        """What the agent sees now."""
        return self.intersection.observe()

    def step(self, action: Any) -> tuple[Observation, dict[str, Any]]:
        """Submit ``action`` and run to the next decision point; returns the observation and an info mapping.

        An action that cannot be served is refused with a typed :class:`hils.control.actions.ActionError`
        (logged; nothing is sent, no time passes), :class:`hils.control.actions.PreemptedError` while the
        controller serves a preempt. ``info`` says what happened: ``action_id``, ``acted``, ``dropped`` (the
        manager was not IDLE), ``refused`` (why :meth:`step_all` refused it, else None), ``state`` (idle, on_hold,
        timeout or preempted), ``timeout`` (the manager entered TIMEOUT during the step) and ``timeout_reason``,
        ``ended`` (the run's duration has passed)."""
        name = self._only()
        observations, infos = self._to_decision(self._submit({name: action}, preempted_raises=True))
        return observations[name], infos[name]

    def wait(self) -> tuple[Observation, dict[str, Any]]:
        """Run to the next decision point without acting (e.g. after a refused action)."""
        name = self._only()
        observations, infos = self.step_all({})
        return observations[name], infos[name]

    def _only(self) -> str:
        """The name of the run's one intersection; a run of several has none."""
        if len(self.configs) > 1:
            raise SeveralIntersections(f"this run has {len(self.configs)} intersections ({', '.join(self.configs)}): "
                                       "use reset_all(), step_all(), observe_all() and testbed.intersections[NAME]")
        return next(iter(self.configs))


class Testbed(_OneIntersection):
    """A run: controllers (virtual or real), the middleware of each, optional SUMO, the event log.

    ``config``: an :class:`IntersectionConfig`, a TOML path, or None for the shipped four-leg; or, instead,
    ``scenario``: a shipped scenario's name (``corridor``, ``grid4x4``), a ``.scenario.toml`` path or a
    :class:`hils.protocol.scenario.Scenario`, one controller per intersection (traffic light), all in this one run.
    ``action_type``: selection, switch or duration. ``target``: ``"virtual"``, an ``snmp://`` URL or a target
    factory; with several intersections, a mapping from each one's name to its own (a scenario at wall clock
    needs a URL for every intersection). ``sumo``: True to run the SUMO scenario (started at each reset), or a
    simulation object the caller started (with a ``lights`` mapping); ``sumo_config``: the ``.sumocfg`` SUMO
    starts with (default: the scenario's, or the shipped four-leg). ``seed``: every virtual-time run is
    reproducible from it, in a process of its own (a SUMO run may also depend on the runs before it in one
    process: :mod:`hils.sim.sumo`). ``agent``: what :meth:`run` uses when given none (a built-in name,
    ``package.module:Class`` or an instance; with several intersections each gets its own of a named agent).
    ``duration``: simulated seconds after which the run is done (None: no end). ``log_path``: the JSON Lines event
    log (None: kept in memory only). ``hires_path``: the hi-res journal, where the controllers held in process write
    their hi-res events through as they log them (:mod:`hils.shell.hiresjournal`; None: none). ``recover_after``:
    seconds in TIMEOUT before the manager recovers by itself (None: never). ``on_reset(testbed)`` runs after
    assembly, before anything starts: the fault harness wraps parts of the run there. ``detectors``: SUMO's stop-bar
    loops actuate the controllers' detectors (default: for the actuated agent). ``measure``: False skips what only
    the end-of-run summary, the queue plot and the controllers' hi-res record need (per-vehicle delays, queue and
    spillback samples, ``queues`` records; the data logger of each controller held in process, unless a
    ``hires_path`` journal is asked for: :attr:`keeps_hires`), as environments do for speed; every other record
    of the run stays the same. ``fast_path``: leave out in virtual time what cannot change a result
    (:mod:`hils.shell.fastpath`); False runs the reference (every controller tick, every poll, every SUMO step).
    ``take_over``: drive a controller on which someone else's calls are found without first watching them for
    another manager (a run that finds them changing refuses to start); their calls are cleared. ``sumo_worker``: SUMO
    steps in a worker process of its own (:mod:`hils.sim.worker`), beside this one's work, in virtual time: the same
    run on two cores; the process lives until :meth:`close`, each reset a fresh SUMO in it.

    The general API takes and gives one value per intersection, by name: :meth:`reset_all`, :meth:`step_all`,
    :meth:`observe_all`, :attr:`intersections`. A run of one intersection also has the single view of it:
    :meth:`reset`, :meth:`step`, :meth:`wait`, :meth:`observe`, :attr:`intersection`, :attr:`middleware`,
    :attr:`config`... (in a run of several these raise :class:`SeveralIntersections`).
    """

    __test__ = False  # pytest: a class named Test* here is not a test

    def __init__(self, config: IntersectionConfig | str | Path | None = None, *,
                 action_type: ActionType | str = ActionType.SELECTION,
                 target: str | TargetFactory | Mapping[str, str | TargetFactory] = VIRTUAL,
                 sumo: bool | Simulation = False, seed: int = 0, agent: str | Agent | None = None,
                 duration: float | None = None, log_path: str | Path | None = None,
                 hires_path: str | Path | None = None, recover_after: float | None = 5.0,
                 on_reset: Callable[[Testbed], None] | None = None,
                 sumo_config: str | Path | None = None, detectors: bool | None = None,
                 scenario: str | Path | Scenario | None = None, measure: bool = True, fast_path: bool = True,
                 take_over: bool = False, sumo_worker: bool = False) -> None:
        if scenario is not None and config is not None:
            raise ValueError("give a config (one intersection) or a scenario (its intersections), not both")
        self.scenario = _scenario(scenario)
        if self.scenario is not None:
            check_plans(agent, self.scenario.name, self.scenario.intersections)
            self.configs = {tls: controller_config(agent, c) for tls, c in self.scenario.intersections.items()}
            sumo_config = sumo_config if sumo_config is not None else self.scenario.sumo_config
        else:
            cfg = config if isinstance(config, IntersectionConfig) else config_mod.load(config)
            self.configs = {TLS_ID: controller_config(agent, cfg)}
        self.labels = labels(list(self.configs))
        first = next(iter(self.configs.values()))
        self.action_type = ActionType(action_type)
        self._targets = target_specs(target, self.configs)
        # Each wall-clock target parsed and its host resolved once, here: a bad one is refused before anything
        # starts, naming its intersection.
        self._wall_targets = {name: check_target(url, self.labels[name])
                              for name, url in self._targets.items() if isinstance(url, str) and url != VIRTUAL}
        if duration is not None and not duration > 0:
            raise ValueError(f"duration must be positive seconds or None, got {duration!r}")
        if agent is not None and not isinstance(agent, str) and len(self.configs) > 1:
            raise SeveralIntersections("an agent object drives one controller: name a built-in agent or "
                                       "package.module:Class, and each intersection gets its own")
        self._sumo_spec = sumo
        self.sumo_config = sumo_config
        self.seed = seed
        self._agent_spec = agent
        self.fast_path = fast_path
        self.take_over = take_over
        # Detector actuations from SUMO feed the controller when asked, and by default for the agents that leave
        # the controller to its own operation on them (actuated, coordinated; fixed-time's pretimed plan needs none).
        self.detectors = agent in DETECTOR_AGENTS if detectors is None else detectors
        self.duration = duration
        self.log_path = Path(log_path) if log_path is not None else None
        self.hires_path = Path(hires_path) if hires_path is not None else None
        self.journal: HiresJournal | None = None
        self.recover_after = recover_after
        self.on_reset = on_reset
        self.measure = measure
        self.spec = RunSpec(first, self.action_type, agent if isinstance(agent, str) else None,
                            math.inf if duration is None else duration, seed, self.log_path, recover_after,
                            sumo=bool(sumo), fast_path=fast_path)
        self.env: simpy.Environment | None = None
        self.intersections: dict[str, Intersection] = {}
        self.events: EventLog | None = None
        self.simulation: Simulation = NoSimulation()
        self.clock: Clock | None = None
        self.step_cost: StepCost = modeled_cost
        self.ended = False
        self.end_reason: str | None = None
        self.traffic: Any = None  # the simulation's end-of-run summary, once finished
        self.wall_s = 0.0
        self._driver: Any = None
        self._owns_sumo = False
        self._wall_t0 = 0.0
        if sumo_worker and self._wall_targets:
            raise ValueError("sumo_worker: SUMO steps in a worker process in virtual time only; at the wall clock a "
                             "step's cost is measured where SUMO steps")
        self.sumo_process: SumoProcess | None = None
        if sumo_worker and sumo is True:
            from hils.sim.worker import SumoProcess

            # spawned now, so that it boots while the run is assembled; its SUMO starts at each reset
            self.sumo_process = SumoProcess()

    # --- properties ---------------------------------------------------------------------------

    @property
    def mode(self) -> str:
        """``virtual`` or ``wall-clock``."""
        return "wall-clock" if self._wall_targets else VIRTUAL

    @property
    def now(self) -> float:
        return self._env.now

    @property
    def done(self) -> bool:
        """True once the run has ended or its ``duration`` has passed."""
        return self.ended or (self.duration is not None and self._env.now >= self.duration - 1e-9)

    @property
    def keeps_hires(self) -> bool:
        """The run keeps its controllers' hi-res record: it measures, or writes the hi-res journal. Without, the
        controllers held in process run no data logger (their targets are made with ``hires=False``): none of its
        work on every step, none of the steps it alone needs, and :meth:`hires` has nothing to give."""
        return self.measure or self.hires_path is not None

    @property
    def records(self) -> list[dict[str, Any]]:
        """The event log's records (read back from the file when the log is not kept in memory)."""
        log_ = self.events
        if log_ is None:
            return []
        return log_.records if log_.keep else list(read_events(log_.path))

    def hires(self) -> dict[str, list[Event]]:
        """Each controller's own hi-res event log, where the run can read it: the in-process emulator's (a target
        with a ``hires()`` method, see :mod:`hils.protocol.hires`). A controller reached at the wall clock keeps its
        own, which a field tool collects from it (:func:`hils.shell.asclog.collect` for a MaxTime endpoint). Empty
        in a run that keeps no hi-res record (:attr:`keeps_hires`)."""
        if not self.keeps_hires:
            return {}
        return {name: i.target.hires() for name, i in self.intersections.items()
                if callable(getattr(i.target, "hires", None))}

    def spat(self) -> dict[str, tuple[MovementTiming, ...]]:
        """Each controller's signal phase and timing now, where the run can read it: the in-process emulator's (a
        target with a ``spat()`` method): per phase and overlap its indication and the earliest, latest and likely
        time of its next change in the run's seconds (:class:`hils.protocol.spat.MovementTiming`). A controller
        reached over SNMP has no per-phase timing object in NTCIP 1202 (docs/spat.md): it is left out."""
        self._started()
        return {name: i.target.spat() for name, i in self.intersections.items()
                if callable(getattr(i.target, "spat", None))}

    def j2735(self) -> dict[str, bytes]:
        """Each controller's SPaT now as SAE J2735 sends it, where the run can read it (the in-process emulator's):
        a UPER MessageFrame (messageId 19) with startTime, minEndTime, maxEndTime and likelyTime per signal group
        (phase p is group p, overlap n group 16 + n), the intersections numbered 1, 2, ... in the run's order
        (docs/spat.md). Needs pycrate (``pip install 'hils[j2735]'``)."""
        self._started()
        readers = [(name, i.target) for name, i in self.intersections.items()
                   if callable(getattr(i.target, "j2735", None))]
        return {name: target.j2735(intersection=k + 1) for k, (name, target) in enumerate(readers)}

    @property
    def driver(self) -> Any:
        """Wall-clock runs: the :class:`hils.shell.clock.WallClockDriver` (its ``loop`` is the run's asyncio loop,
        where servers of the run such as the dashboard run as tasks); None in virtual time."""
        return self._driver

    @property
    def lateness(self) -> Any:
        """Wall-clock runs: the driver's lateness summary; None in virtual time."""
        return None if self._driver is None else self._driver.lateness.summary()

    # --- life cycle -----------------------------------------------------------------------------

    def reset_all(self, seed: int | None = None) -> dict[str, Observation]:
        """Start (or restart, with a new seed) the run; returns the first observation of each intersection."""
        if self.env is not None:
            self._close_run()
        if seed is not None:
            self.seed = seed
            self.spec = dataclasses.replace(self.spec, seed=seed)
        self._wall_t0 = time.perf_counter()
        self.ended, self.end_reason, self.traffic = False, None, None
        # A run that writes its log to a file does not also keep it in memory: a long run's records
        # would grow the heap that every full garbage collection walks, in the middle of the hot path.
        # Opened first: a log that cannot be written stops the run before anything is assembled.
        self.events = EventLog(self.log_path, keep=self.log_path is None)
        self.events.on_failure = self._log_failed
        env = self.env = simpy.Environment()
        self._assemble_clock(env)
        self.intersections = {name: self._assemble_intersection(env, name, index)
                              for index, name in enumerate(self.configs)}
        self._assemble_simulation()
        self._assemble_journal()
        for i in self.intersections.values():
            i.agent = self._load_agent(i.config)
        if self.on_reset is not None:
            self.on_reset(self)
        self._start()
        self._advance(None, *(i.middleware.ready for i in self.intersections.values()), every=True)
        self._check_controllers()
        return self.observe_all()

    def _log_failed(self, failure: LogWriteError) -> None:
        """The log's file stopped taking records: the run ends as an error at its next event, and finish() clears
        the calls all the same (the clearing SET never waits on the log). During finish() the run is ending."""
        if not self.ended:
            self.env.event().fail(failure)  # raised by the environment's next step, between two events

    def _check_controllers(self) -> None:
        """The start-up checks: refuse a controller unfit for a run (one line each), warn about the rest."""
        refusals = [i.named(line) for i in self.intersections.values() for line in i.refusals()]
        if refusals:
            self.finish("error")
            raise ControllerCheckFailed("; ".join(refusals))

    def _assemble_clock(self, env: simpy.Environment) -> None:
        self._driver = WallClockDriver(env) if self._wall_targets else None
        self.clock = self._driver or VirtualClock(env)
        self.step_cost = self.clock.step_cost  # a fault may wrap it (on_reset)

    def _assemble_intersection(self, env: simpy.Environment, name: str, index: int) -> Intersection:
        cfg, spec, label = self.configs[name], self._targets[name], self.labels[name]
        # Every controller of a run of several has its own seeded draws (its tick phase, its latencies); a lone
        # one draws from the run's seed itself.
        seed = self.seed if label is None else self.seed * 1009 + index
        target, transport, foresight, where, community = connect(
            env, cfg, spec, self._wall_targets.get(name), self._driver, seed=seed, fast_path=self.fast_path,
            hires=self.keeps_hires)
        events = TaggedLog(self.events, label) if label is not None else self.events
        # The summary's figures, kept as the run goes (its end re-reads nothing): each intersection's tally is handed
        # its own records and the run's (a lone one's, every record).
        tally = Tally(label)
        self.events.subscribe(tally, intersection=label)
        middleware = Middleware(env, transport, cfg, self.action_type, events, where=where, community=community,
                                recover_after=self.recover_after, foresight=foresight if self.fast_path else None,
                                take_over=self.take_over)
        return Intersection(name, label, cfg, target, transport, middleware, events, tally)
    @property
    def devices(self) -> dict[str, int]:
        """The ``DeviceId`` of each controller in its hi-res record: 1, 2, ... in the run's order."""
        return {name: n for n, name in enumerate(self.configs, start=1)}

    def _assemble_journal(self) -> None:
        """Each controller held in process writes its hi-res events through to the journal (a target with a
        ``hires_to()`` method); no journal when none is, or none is asked for."""
        self.journal = None
        held = {name: i.target.hires_to for name, i in self.intersections.items()
                if callable(getattr(i.target, "hires_to", None))}
        if self.hires_path is None or not held:
            return
        try:
            self.journal = HiresJournal(self.hires_path)
        except OSError as exc:
            log.warning("no hi-res journal %s: %s; the run's record is kept in memory until its end", self.hires_path,
                        exc.strerror or exc)
            return
        for name, hires_to in held.items():
            hires_to(self.journal.device(self.devices[name]))

    def _assemble_simulation(self) -> None:
        sumo = self._sumo_spec
        self._owns_sumo = False
        if sumo is True:
            from hils.sim.sumo import SumoSimulation
            from hils.sim.worker import SumoWorker

            # SUMO's tripinfo (RESCO's figures) goes beside the event log
            tripinfo = self.log_path.with_name("tripinfo.xml") if self.log_path is not None else None
            options = dict(seed=self.seed, end=self.duration, sumo_config=self.sumo_config, lights=self.configs,
                           measure=self.measure, links=self.scenario.links if self.scenario else None,
                           tripinfo=tripinfo)
            sim = SumoSimulation(**options) if self.sumo_process is None else SumoWorker(self.sumo_process, **options)
            sim.start()  # a SUMO that fails to start (e.g. a network the config does not fit) closes itself
            self.simulation = sim
            self._owns_sumo = True
        elif sumo is False:
            self.simulation = NoSimulation()
        else:
            self.simulation = sumo
        for i in self.intersections.values():
            i.signals = self.simulation.lights.get(i.name)

    def _load_agent(self, config: IntersectionConfig) -> Agent | None:
        spec = self._agent_spec
        if spec is None or isinstance(spec, str):
            return load_agent(self.spec.agent_spec, config, self.action_type, self.seed)
        return spec

    def _start(self) -> None:
        if not callable(getattr(self.step_cost, "free_until", None)):
            raise TypeError(f"step_cost {self.step_cost!r} is not a hils.shell.fastpath.StepCost (a cost function with "
                            "free_until): wrap a plain cost function with hils.shell.fastpath.every_step")
        # Everything loaded so far (SUMO, numpy, the config) lives for the whole run: keep it out of
        # the collector's way so that collections during the run stay short.
        gc.freeze()
        for i in self.intersections.values():
            zones = any(p.approach is not None for p in i.config.preempts.values())
            if (self.detectors or zones) and i.signals is not None:
                # Built before the run starts: a detector on a lane its phase does not have is refused now.
                pm = i.signals.phase_map
                i.detector_feed = DetectorFeed(i.transport, i.config, i.events,
                                               {p: pm.incoming_lanes(p) for p in pm.phases}, detectors=self.detectors,
                                               preempt_calls=i.signals.preempt_calls if zones else None)
        self.events.emit(Kind.RUN_STARTED, **self._what_runs(), seed=self.seed, mode=self.mode,
                         action_type=self.action_type.value, agent=_agent_name(self._agent_spec, self.spec),
                         duration=self.duration)
        ended = lambda: self.ended  # noqa: E731 - the intersections' processes ask it as the run goes
        # The controllers start spread over one poll period, so that their polls, keepalives and read-backs go
        # out spread over it too, as a central system staggers them: 64 controllers polled at one instant are a
        # burst that makes the last answers of each round several milliseconds late at the wall clock.
        spread = self.spec.config.middleware.poll_period / len(self.intersections)
        for index, i in enumerate(self.intersections.values()):
            i.middleware.start(after=index * spread)
            if i.signals is not None and self.measure:
                self.env.process(i.sample_traffic(ended))
        self.env.process(steps(self.env, self.simulation, list(self.intersections.values()),
                                self.spec.config.middleware.sumo_step, self.step_cost,
                                fast_path=self.fast_path, ended=ended))

    def _what_runs(self) -> dict[str, Any]:
        """``run_started``'s account of what runs: the intersection's config, or the scenario and its names."""
        if self.labels[next(iter(self.configs))] is None:
            return {"config": self.spec.config.name, "source": self.spec.config.source}
        return {"scenario": self.scenario.name, "source": self.scenario.source, "intersections": list(self.configs)}

    def _poll_counts(self) -> dict[str, Any]:
        """``run_ended``'s poll counts: the intersection's, or each one's by name."""
        counts = {i.label: i.middleware.poll_counts for i in self.intersections.values()}
        return counts.get(None, counts)

    def finish(self, reason: str | None = None) -> None:
        """End the run: clear the calls placed, log ``run_ended`` with ``reason``, close the log.

        ``reason`` defaults to ``duration`` once the duration has passed, else ``closed``.
        Idempotent; bounded in wall-clock time (a clearing SET answers or fails within tau_udp, and one that
        gets no answer is sent again, :data:`hils.control.manager.CLEAR_ATTEMPTS` times in all)."""
        if self.env is None or self.ended:
            return
        if reason is None:
            reason = "duration" if self.done else "closed"
        self.ended = True
        self.end_reason = reason

        def ending() -> Generator[simpy.Event, Any, None]:
            yield simpy.AllOf(self.env, [i.middleware.close() for i in self.intersections.values()])
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
            if self.journal is not None:
                self.hires()  # reading each log brings it to the present: the journal gets every event up to the end
                self.journal.close()
            self.wall_s = time.perf_counter() - self._wall_t0
            self._collect_traffic()

    def _collect_traffic(self) -> None:
        summary = getattr(self.simulation, "summary", None)
        if summary is not None and getattr(self.simulation, "running", False):
            # the run's own SUMO ends here, so that its tripinfo (RESCO's figures) is complete
            self.traffic = self.simulation.finish() if self._owns_sumo else summary()

    def close(self) -> None:
        """Finish the run if it is still going, then release the transports, the clock, SUMO and its worker."""
        try:
            self._close_run()
        finally:
            if self.sumo_process is not None:
                self.sumo_process.close()

    def _close_run(self) -> None:
        if self.env is None:
            return
        try:
            self.finish()
        finally:
            for i in self.intersections.values():
                i.transport.close()
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
            self.finish(reason_of(exc) if exc is not None else None)
        self.close()

    # --- stepping ---------------------------------------------------------------------------------

    def observe_all(self) -> dict[str, Observation]:
        """What each intersection's agent sees now."""
        self._started()
        return {name: i.observe() for name, i in self.intersections.items()}

    def step_all(self, actions: Mapping[str, Any]) -> tuple[dict[str, Observation], dict[str, dict[str, Any]]]:
        """One action per intersection, then run to the next decision point of any of them; returns the
        observation and the info (as :meth:`step`'s, with ``due`` and ``acted``) of each.

        Each intersection keeps its own decision schedule: only those that are ``due`` (at their decision point
        now, as the last step's infos said; every one after :meth:`reset_all`) act; the action of one that is
        not due, left out or None is not taken (``acted`` False), and its schedule runs on. Every action taken
        is converted before any is submitted: one that cannot be served raises its
        :class:`hils.control.actions.ActionError` and nothing is sent to any controller. The action of an
        intersection whose controller serves a preempt is the exception: the agent did nothing wrong and the
        others act, so it is refused alone (logged, nothing sent to it, ``acted`` False, ``refused`` saying why)
        and the step goes on."""
        return self._to_decision(self._submit(actions, preempted_raises=False))

    def _submit(self, actions: Mapping[str, Any], *, preempted_raises: bool) -> dict[str, Submission]:
        """The actions of the intersections that are due, converted, then handed to their middlewares (see
        :meth:`step_all`); ``preempted_raises``: a :class:`PreemptedError` raises as any refusal does (a run of
        one, stepped by :meth:`step`: no time passes)."""
        self._check_running()
        unknown = sorted(set(actions) - set(self.intersections))
        if unknown:
            raise KeyError(f"no intersection {', '.join(unknown)} in this run; it has "
                           f"{', '.join(self.intersections)}")
        received: dict[str, Received] = {}
        refused = None
        for name, value in actions.items():
            intersection = self.intersections[name]
            if value is not None and intersection.due:
                r = received[name] = intersection.middleware.receive(value)
                if r.error is not None and refused is None and (
                        preempted_raises or not isinstance(r.error, PreemptedError)):
                    refused = name
        if refused is not None:  # all or none: submitted alone, logged as received and refused, nothing sent
            received = {refused: received[refused]}
        submitted = {name: self.intersections[name].middleware.submit(r) for name, r in received.items()}
        if refused is not None:
            error = submitted[refused].error
            if self.intersections[refused].label is not None:
                error.add_note(f"the action of intersection {refused}; nothing was sent to any controller")
            raise error
        return submitted

    def run_for(self, seconds: float) -> None:
        """Let ``seconds`` of run time pass without acting."""
        self._check_running()
        self._advance(self._env.now + seconds)

    def recover(self, name: str | None = None) -> bool:
        """Recover from TIMEOUT now (the controller of intersection ``name``; None: the run's one): re-read the
        controller and return to IDLE; False if it failed."""
        self._check_running()
        intersection = self.intersections[name] if name is not None else self.intersection
        proc = intersection.middleware.recover()
        self._advance(None, proc)
        return bool(proc.value)

    def run(self, agent: Agent | None = None, progress: Callable[[float], None] | None = None) -> str:
        """Let the agents (``agent``, or the Testbed's: one per intersection) act at every decision point until
        the run is done.

        The agents are asked through the clock (:meth:`hils.shell.clock.Clock.ask`): at the wall clock each thinks in
        a thread of its own while the run goes on, an answer later than a SUMO step is logged (``agent_late``),
        and none within the control interval is a TIMEOUT (``agent``); its answer, when it comes, is discarded
        and the agent is asked again at the next decision point after it.

        Returns the end reason (``duration``). Whatever else ends the run (an agent raising:
        :class:`AgentFailed`; Ctrl-C or SIGTERM: :class:`RunInterrupted` or KeyboardInterrupt; an
        error) first finishes the run cleanly, then propagates."""
        if self.env is None:
            self.reset_all()
        agents = {name: agent or i.agent for name, i in self.intersections.items()}
        if any(a is None for a in agents.values()):
            raise NotStarted("no agent: pass one to run() or to the Testbed")
        observations = self.observe_all()
        asked: dict[str, Answer] = {}  # agents thinking (at the wall clock: still, after their decision's time)
        try:
            while not self.done:
                for name, a in agents.items():
                    if self.intersections[name].due and name not in asked:
                        asked[name] = self.clock.ask(a.act, observations[name])
                try:
                    # None: no action this time, the controller runs on its own until the next decision.
                    observations, _ = self.step_all(self._answers(asked))
                except ActionError:
                    # refused and logged: the agents are asked again at the next decision
                    observations, _ = self.step_all({})
                if progress is not None:
                    progress(self._env.now)
        except BaseException as exc:
            self.finish(reason_of(exc))
            raise
        self.finish("duration")
        return "duration"

    def _answers(self, asked: dict[str, Answer]) -> dict[str, Any]:
        """The actions of the agents asked: waits (at the wall clock) until each has answered or its control
        interval has passed; an agent that has not answered by then is overdue (a TIMEOUT) and keeps thinking."""
        waiting = [a for a in asked.values() if not a.done and not a.overdue]
        if waiting:
            deadline = min(a.asked_at + self.intersections[name].config.middleware.control_interval
                           for name, a in asked.items() if a in waiting)
            self._advance(deadline, *(a.event for a in waiting), every=True)
        actions = {}
        for name, answer in list(asked.items()):
            intersection = self.intersections[name]
            params = intersection.config.middleware
            if not answer.done:
                if not answer.overdue and self._env.now >= answer.asked_at + params.control_interval - 1e-9:
                    answer.overdue = True
                    intersection.middleware.agent_overdue(self._env.now - answer.asked_at)
                continue
            del asked[name]
            if answer.error is not None:
                raise AgentFailed(f"the agent's act() raised {described(answer.error)}") from answer.error
            took = answer.answered_at - answer.asked_at
            if took > params.sumo_step:
                intersection.events.emit(Kind.AGENT_LATE, took_s=took, discarded=answer.overdue)
                log.warning("%s", intersection.named(f"the agent answered after {took:.1f} s"
                                                     + (": beyond the control interval, its action is discarded"
                                                        if answer.overdue else "")))
            if not answer.overdue:
                actions[name] = answer.value
        return actions

    def _to_decision(self, submitted: Mapping[str, Submission]
                     ) -> tuple[dict[str, Observation], dict[str, dict[str, Any]]]:
        self._started()
        timeouts = {name: i.middleware.entering(State.TIMEOUT) for name, i in self.intersections.items()}
        for i in self.intersections.values():
            if i.due:
                i.schedule(self.action_type)  # asked now: its next decision point starts from here
        deadlines = [i.deadline for i in self.intersections.values() if i.deadline is not None]
        if self.duration is not None:
            deadlines.append(self.duration)
        self._advance(min(deadlines, default=None), *(ev for i in self.intersections.values() for ev in i.waits))
        infos = {}
        for name, i in self.intersections.items():
            i.due = i.at_decision()
            done = submitted.get(name)
            infos[name] = i.info(done.action_id if done else None, done is not None and done.error is None,
                                 done.dropped if done else False, timeouts[name].triggered) | {
                "refused": None if done is None or done.error is None else str(done.error),
                "ended": self.done, "due": i.due}
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
        signalled = self.clock.advance(until, events)
        if signalled is not None:
            raise RunInterrupted("interrupted" if signalled == signal.SIGINT else "terminated")

    # --- processes ---------------------------------------------------------------------------------

    # --- helpers ----------------------------------------------------------------------------------------

    @property
    def _env(self) -> simpy.Environment:
        self._started()
        return self.env

    def _started(self) -> None:
        if self.env is None:
            raise NotStarted("the Testbed is not started: call reset() first")

    def _check_running(self) -> None:
        self._started()
        if self.ended:
            raise NotStarted(f"the run has ended ({self.end_reason}): call reset() to start another")


def _scenario(scenario: str | Path | Scenario | None) -> Scenario | None:
    if scenario is None or isinstance(scenario, Scenario):
        return scenario
    return load_scenario(scenario)


def _agent_name(given: str | Agent | None, spec: RunSpec) -> str:
    """How the log names the agent: its spec, or the class of an agent object handed in."""
    return spec.agent_spec if given is None or isinstance(given, str) else type(given).__name__


def reason_of(exc: BaseException) -> str:
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
             configure: Callable[[Testbed], None] | None = None,
             progress: Callable[[float], None] | None = None) -> RunResult:
    """Build a Testbed from ``spec``, run its agent for ``spec.duration`` s and close it.

    ``simulation``: a simulation the caller started (and closes); default: SUMO when ``spec.sumo``."""
    tb = Testbed(spec.config, action_type=spec.action_type, target=target,
                 sumo=simulation if simulation is not None else spec.sumo, seed=spec.seed, agent=spec.agent,
                 duration=spec.duration, log_path=spec.log_path, recover_after=spec.recover_after,
                 on_reset=configure, fast_path=spec.fast_path)
    with tb:
        tb.reset()
        reason = tb.run(progress=progress)
        return RunResult(tb, tb.target, tb.wall_s, reason)
