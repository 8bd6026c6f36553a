"""sumo-rl on RESCO's scenarios, matched to hils' controllers: the peer of `hils bench resco` and of the RESCO study.

How the peer runs
-----------------
sumo-rl 1.4.5's PettingZoo environments (``sumo_rl.env``, ``sumo_rl.parallel_env``, RESCO's in
``sumo_rl.environment.resco_envs``) do not start with the pettingzoo 1.27 that hils installs: their AEC wrapper
calls ``pettingzoo.utils.agent_selector(agents)``, which that release turned into a module (the class is now
``AgentSelector``): "'module' object is not callable". Under the wrapper is sumo-rl's own multi-agent
environment, ``SumoEnvironment(single_agent=False)``: one dict of actions (one per light) per call of ``step``,
which applies those of the lights due and steps SUMO to the next decision, exactly what the parallel wrapper
does once it has gathered every agent's action. That environment runs here, unmodified, through libsumo
(``LIBSUMO_AS_TRACI``), with sumo-rl's default observation, reward and info.

Matched to hils (what the comparison holds equal)
-------------------------------------------------
- Network, demand, begin: the ``.net.xml`` and ``.rou.xml`` of the scenario's ``.sumocfg`` (the files of
  sumo-rl's own RESCO environments), from RESCO's start time (cologne 25200 s, ingolstadt 57600 s), for the
  episode's simulated seconds.
- SUMO: 0.25 s steps, the episode's seed, no teleporting (``--time-to-teleport -1``: sumo-rl's default and
  hils'), ``--end`` and, when measured, the tripinfo options of hils' SumoSimulation (:data:`TRIPINFO_OPTIONS`).
- Decisions every RESCO ``step_length``: the derived config's control interval (10 s; 5 s on arterial4x4).
- Yellow and minimum green per light from the light's derived config (:mod:`hils.protocol.resco`), in sumo-rl's unit:
  SUMO
  steps, since its TrafficSignal counts both in calls of ``update()``, one per SUMO step, although its docs say
  seconds. A light's yellow is its phases' (one value per light in every RESCO network; the longest if not). Its
  minimum green is set before every decision to that of the stage shown: the longer of the two phases' that
  serve it in hils' controller (:meth:`Light.min_green_steps`).
- Stages: sumo-rl's actions are its green phases of the light's first program ('y' nowhere, not all 'r' and
  's'); those that are also RESCO's stages ('g' or 'G' somewhere, on a link that controls a connection) are, in
  program order, the derived config's sequence (:class:`Light`). One phase of one ingolstadt21 light
  (cluster_1427494838_273472399, "GGrrrrrrrr": green only on links that control no connection) is a stage of
  neither RESCO nor hils: it stays in sumo-rl's action space, and the agents of this module never choose it.
- Agents: max-pressure and fixed-time are hils' own classes (:mod:`hils.agents.builtin`), asked as in a hils run:
  max-pressure sees each phase's movement (halting vehicles on its incoming lanes minus on its outgoing lanes, the
  lanes of hils' phase map) and the pair shown, and picks a pair, shown here as its stage; fixed-time
  (``fixed-cycle``) asks to advance at every decision, here to the next stage of the config's sequence.

What differs (the controller, on purpose)
-----------------------------------------
sumo-rl switches SUMO's light itself: at a decision for another stage the links that lose their green show 'y'
for the yellow, then the new stage's greens all at once. No all-red (hils' controller times the program's, or one
0.1 s tick where it has none), no ring-and-barrier (hils ends each ring's phase at its own minimum green and
crosses a barrier when both rings are ready), a decision acts on the step it is made (hils' middleware SETs the
call and verifies it by 10 Hz polls; the controller acts on its 0.1 s tick).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType, ModuleType
from typing import Any

from hils.protocol.config import IntersectionConfig, Pair

__all__ = ["HOW_IT_RUNS", "TRIPINFO_OPTIONS", "Light", "episode", "sumo_rl", "sumo_rl_pettingzoo"]

#: How the peer runs, for consoles and reports.
HOW_IT_RUNS = ("sumo-rl's SumoEnvironment(single_agent=False) stepped directly through libsumo (its PettingZoo "
               "wrapper calls pettingzoo's agent_selector, which pettingzoo 1.27 renamed AgentSelector, and does not "
               "start); yellow and minimum green per light from hils' derived config, in SUMO steps")
#: SUMO's tripinfo options of a measured run, as hils' SumoSimulation gives them (RESCO's figures read it).
TRIPINFO_OPTIONS = ("--tripinfo-output.write-unfinished", "true", "--tripinfo-output.write-undeparted", "true")
SUMO_STEP = 0.25


def sumo_rl() -> ModuleType:
    """sumo-rl, running through libsumo.

    sumo-rl reads ``LIBSUMO_AS_TRACI`` when it is imported and then calls ``traci``, which that variable makes
    libsumo only if set before traci's first import; libsumo itself imports traci (its helper modules), as does
    any part of hils that touches SUMO. So sumo-rl is imported here with ``traci`` being libsumo, as the variable
    would have made it, whatever was imported before."""
    if "sumo_rl" in sys.modules:
        return sys.modules["sumo_rl"]
    import sumo

    from hils.sim.quiet_libsumo import libsumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    os.environ["LIBSUMO_AS_TRACI"] = "1"
    traci = sys.modules.get("traci")
    sys.modules["traci"] = libsumo
    try:
        import sumo_rl as module
    finally:
        if traci is not None:
            sys.modules["traci"] = traci
        else:
            del sys.modules["traci"]
    return module


def sumo_rl_pettingzoo() -> ModuleType:
    """sumo-rl (:func:`sumo_rl`) with its PettingZoo environments started: its AEC wrapper calls
    ``agent_selector(agents)``, the name it imports from ``pettingzoo.utils``, which pettingzoo 1.27 made a module; it
    is given the class that module holds (``AgentSelector``, the same methods), and nothing else of sumo-rl changes.
    For training, whose libraries take PettingZoo environments (RLlib's ``ParallelPettingZooEnv``)."""
    module = sumo_rl()
    from pettingzoo.utils import AgentSelector

    env_module = sys.modules["sumo_rl.environment.env"]
    if not callable(env_module.agent_selector):
        env_module.agent_selector = AgentSelector
    return module


def steps(seconds: float) -> int:
    """Seconds in sumo-rl's unit for yellow and minimum green: SUMO steps."""
    return round(seconds / SUMO_STEP)


@dataclass(frozen=True)
class Light:
    """One light as both sides number its stages: sumo-rl's action (its green phase's index) of each stage of the
    derived config's sequence, and the timings sumo-rl is given."""

    tls: str
    config: IntersectionConfig
    sequence: tuple[int, ...]  # sumo-rl's action showing each stage of config.sequence, in its order
    yellow_steps: int

    @classmethod
    def of(cls, tls: str, config: IntersectionConfig, greens: Sequence[str], connected: Sequence[int]) -> Light:
        """``greens``: the states of sumo-rl's green phases (its ``TrafficSignal.green_phases``), in order;
        ``connected``: the link indices that control a connection."""
        stages = [i for i, state in enumerate(greens) if any(state[k] in "Gg" for k in connected)]
        if len(stages) != len(config.sequence):
            raise ValueError(f"light {tls}: sumo-rl has {len(stages)} green phases green on a connection, the derived "
                             f"config {len(config.sequence)} stages: they cannot be matched")
        return cls(tls, config, tuple(stages), steps(max(p.yellow for p in config.phases.values())))

    @property
    def action_of_pair(self) -> Mapping[Pair, int]:
        """sumo-rl's action showing each pair (its first stage)."""
        out: dict[Pair, int] = {}
        for pair, action in zip(self.config.sequence, self.sequence, strict=True):
            out.setdefault(pair, action)
        return MappingProxyType(out)

    def pair_of(self, action: int) -> Pair | None:
        """The pair a sumo-rl action shows (None for a phase that is no stage)."""
        return self.config.sequence[self.sequence.index(action)] if action in self.sequence else None

    def min_green_steps(self, action: int) -> int:
        """The minimum green of the stage ``action`` shows: the longer of its pair's phases' (the light's longest
        for a phase that is no stage)."""
        pair = self.pair_of(action)
        phases = self.config.phases
        return steps(max(phases[p].min_green for p in pair) if pair else max(p.min_green for p in phases.values()))


@dataclass(frozen=True, slots=True)
class Movements:
    """What hils' max-pressure agent reads of the traffic state: each phase's movement."""

    movements: Mapping[int, Any]


class _AgentBridge:
    """A hils agent (selection or switch) deciding one sumo-rl light: it observes as in a hils run and its action is
    shown as sumo-rl's action."""

    def __init__(self, light: Light, agent: Any, lanes: Mapping[int, tuple[tuple[str, ...], tuple[str, ...]]]) -> None:
        from hils.control.actions import ActionType

        self.light, self.agent, self.lanes = light, agent, lanes
        self.selects = agent.action_type is ActionType.SELECTION
        self.position = 0  # in the config's sequence, for switch actions

    def act(self, t: float, shown: int) -> int:
        from hils.agents.builtin import Observation
        from hils.protocol.ntcip import SignalState
        from hils.sim.quiet_libsumo import libsumo
        from hils.sim.sumo import MovementState

        halting = libsumo.lane.getLastStepHaltingNumber
        movements = {p: MovementState(p, sum(map(halting, inc)), sum(map(halting, out)))
                     for p, (inc, out) in self.lanes.items()}
        pair = self.light.pair_of(shown)
        phases = frozenset(self.light.config.phases)
        greens = frozenset(pair or ())
        signal = SignalState(phases - greens, frozenset(), greens)
        action = self.agent.act(Observation(t, signal, Movements(movements), state=None))
        if self.selects:
            return self.light.action_of_pair[tuple(action)]
        if action == 1:
            self.position = (self.position + 1) % len(self.light.sequence)
        return self.light.sequence[self.position]


Policy = Callable[[float, Mapping[str, int]], dict[str, int]]


def episode(seed: int, *, scenario: str, duration: float, agent: str = "random",
            tripinfo: str | Path | None = None) -> dict[str, Any]:
    """One episode of sumo-rl's multi-agent SumoEnvironment on RESCO's ``scenario`` (matched to hils: see the module
    header), decided by ``agent`` (``random``: each light's action space, seeded; or a hils agent, ``max-pressure``
    or ``fixed-cycle``). Returns decisions, wall seconds from reset to the episode's end, of them SUMO's steps,
    vehicles inserted and arrived; with ``tripinfo``, also RESCO's figures (from SUMO's tripinfo written there, and
    the queue sampled at every decision)."""
    from harness.bench.seeds import time_sumo_steps
    from hils.protocol import resco
    from hils.sim.sumo import _console

    module = sumo_rl()
    sumo_s = time_sumo_steps()
    scenario_ = resco.load(scenario)
    configs = scenario_.intersections
    first = next(iter(configs.values()))
    begin, interval = resco.MAPS[scenario].start, first.middleware.control_interval
    net, routes = _files(scenario_.sumo_config)
    options = ["--step-length", repr(SUMO_STEP), "--end", repr(begin + duration), "--no-step-log", "true"]
    if tripinfo is not None:
        options += ["--tripinfo-output", str(tripinfo), *TRIPINFO_OPTIONS]
    # Its constructor starts SUMO on the network alone, without --no-warnings: SUMO's console is kept quiet as hils'.
    with _console(quiet=True):
        env = module.SumoEnvironment(net_file=str(net), route_file=str(routes), begin_time=int(begin),
                                     num_seconds=int(duration), delta_time=int(interval), single_agent=False,
                                     sumo_seed=seed, sumo_warnings=False, additional_sumo_cmd=" ".join(options))
    started, cpu = time.perf_counter(), time.process_time()
    env.reset(seed=seed)
    lights = _lights(env, configs)
    maps = _phase_maps(lights, scenario_) if agent != "random" or tripinfo is not None else {}
    decide = _policy(env, lights, maps, agent, seed)
    queue = _queue_tracker(lights, maps) if tripinfo is not None else None
    decisions, done = 0, False
    while not done:
        for tls, ts in env.traffic_signals.items():
            ts.min_green = lights[tls].min_green_steps(ts.green_phase)
        *_, dones, _ = env.step(decide(env.sim_step, {tls: ts.green_phase for tls, ts in env.traffic_signals.items()}))
        if queue is not None:
            queue.sample()
        decisions, done = decisions + 1, dones["__all__"]
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    stats = env.sumo.simulation
    inserted = int(stats.getParameter("", "stats.vehicles.inserted"))
    running = int(stats.getParameter("", "stats.vehicles.running"))
    env.close()
    out = {"steps": decisions, "wall_s": wall, "cpu_s": cpu, "sumo_s": sumo_s[0], "inserted": inserted,
           "arrived": inserted - running}
    if tripinfo is not None:
        from hils.sim.resco_metrics import metrics, read_tripinfo

        out["resco"] = metrics(read_tripinfo(tripinfo), queue)
    return out


def _files(sumocfg: Path) -> tuple[Path, Path]:
    """The network and route file a RESCO ``.sumocfg`` names."""
    import xml.etree.ElementTree as ET

    inputs = ET.parse(sumocfg).getroot().find("input")
    net, routes = (inputs.find(tag).get("value") for tag in ("net-file", "route-files"))
    return sumocfg.parent / net, sumocfg.parent / routes


def _lights(env: Any, configs: Mapping[str, IntersectionConfig]) -> dict[str, Light]:
    """Every light matched (:class:`Light`), and given its yellow: sumo-rl has just started SUMO (reset)."""
    trafficlight = env.sumo.trafficlight
    lights = {}
    for tls, ts in env.traffic_signals.items():
        connected = [k for k, links in enumerate(trafficlight.getControlledLinks(tls)) if links]
        light = lights[tls] = Light.of(tls, configs[tls], [p.state for p in ts.green_phases], connected)
        ts.yellow_time = light.yellow_steps
    return lights


def _phase_maps(lights: Mapping[str, Light], scenario: Any) -> dict[str, Any]:
    """hils' phase map of every light, on the running simulation's links."""
    from hils.sim.network import derive_phase_map, read_net
    from hils.sim.quiet_libsumo import libsumo

    net = read_net(libsumo.simulation.getOption("net-file"))
    return {tls: derive_phase_map(light.config, net, libsumo.trafficlight.getControlledLinks(tls), tls,
                                  scenario.links.get(tls)) for tls, light in lights.items()}


def _policy(env: Any, lights: Mapping[str, Light], maps: Mapping[str, Any], agent: str, seed: int) -> Policy:
    """What decides every light at a decision: ``(time, each light's action shown) -> each light's action``."""
    if agent == "random":
        for tls in lights:
            env.action_spaces(tls).seed(seed)
        return lambda t, shown: {tls: int(env.action_spaces(tls).sample()) for tls in shown}
    from hils.agents.builtin import load_agent
    from hils.sweep.grid import native_action_type

    bridges = {}
    for tls, light in lights.items():
        hils_agent = load_agent(agent, light.config, native_action_type(agent), seed)
        lanes = {p: (maps[tls].incoming_lanes(p), maps[tls].outgoing_lanes(p)) for p in light.config.phase_numbers}
        bridges[tls] = _AgentBridge(light, hils_agent, lanes)
    return lambda t, shown: {tls: bridges[tls].act(t, action) for tls, action in shown.items()}


def _queue_tracker(lights: Mapping[str, Light], maps: Mapping[str, Any]) -> Any:
    """RESCO's queue over every light's incoming lanes (those of hils' phase map, as a hils run samples them)."""
    from hils.sim.quiet_libsumo import libsumo
    from hils.sim.resco_metrics import QueueTracker

    incoming = {tls: tuple(dict.fromkeys(lane for p in light.config.phase_numbers
                                         for lane in maps[tls].incoming_lanes(p))) for tls, light in lights.items()}
    return QueueTracker(incoming, {lane: libsumo.lane.getLength(lane) for lanes in incoming.values() for lane in lanes})
