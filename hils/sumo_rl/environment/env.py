"""sumo-rl's environments on hils: ``SumoEnvironment`` (gymnasium, one light or a dict of them), ``env`` (PettingZoo
AEC) and ``parallel_env`` (PettingZoo parallel), each light a NEMA controller that the middleware commands.

``from hils.sumo_rl import SumoEnvironment`` in place of ``from sumo_rl import SumoEnvironment`` runs sumo-rl code on
hils: the constructor takes sumo-rl's arguments, ``reset``, ``step``, ``close``, ``save_csv``, ``encode`` and the spaces
answer as sumo-rl's do, with sumo-rl's observations, rewards and info. What differs, by design, is the light: it shows
what a controller derived from its SUMO program shows (:mod:`hils.sumo_rl.lights`), which enforces minimum green,
yellow and red clearance itself, and an action is a call the middleware places with it.

Rules of this module
--------------------
- One run per episode on one :class:`hils.Testbed` (the only place a run is assembled): every light of the network an
  intersection of the run, with its own controller (the emulator in virtual time, or a real one at the wall clock with
  ``target={light: "snmp://..."}``), middleware and decision schedule; SUMO is the run's simulation, started at every
  reset with sumo-rl's options (its seed, ``--max-depart-delay``, ``--waiting-time-memory``, ``--time-to-teleport``,
  ``additional_sumo_cmd``) and closed at the next reset or :meth:`SumoEnvironment.close`.
- A decision every ``delta_time`` s, for every light at once, from the first whole SUMO step after the controllers
  were read (the run starts with the controllers' start-up read; its first SUMO step is taken at once): observations
  are of SUMO's state at the decision's time, and ``info["step"]`` is that time. An episode is ``num_seconds`` s of
  simulation from ``begin_time``; its last decision may come less than ``delta_time`` after the one before.
- ``step(action)`` takes the actions of the lights at a decision point (all of them, as in sumo-rl, where every light
  has the same ``delta_time``), hands them to the run and runs to the next decision point. An action the middleware
  cannot take now (a transition to the last pair asked for still under way) is dropped and logged; what became of
  each light's action is in :attr:`SumoEnvironment.controller_infos` (``acted``, ``dropped``, ``refused``,
  ``timeout``...), outside sumo-rl's ``info``, whose keys stay sumo-rl's.
- ``fixed_ts=True`` runs each controller's timing plan from its program (pretimed, RESCO's fixed-time baseline),
  and no action is taken; a light whose program gives no legal plan is refused, saying why.
- sumo-rl's ``sumo_seed="random"`` draws each episode's seed from the environment's RNG (seeded by ``reset(seed=...)``):
  the same seed gives the same run.
- ``out_csv_name``: the info of every step of an episode, written as sumo-rl writes it, to
  ``{out_csv_name}_conn{label}_ep{episode}.csv`` at the next reset or by :meth:`SumoEnvironment.save_csv`.

This follows sumo-rl's ``sumo_rl/environment/env.py``
(MIT License, Copyright (c) 2018 Lucas Alegre: its notice is in :mod:`hils.sumo_rl`).
"""

from __future__ import annotations

import csv
import logging
import math
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.utils import EzPickle, seeding
from pettingzoo import AECEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_wrapper_fn

from hils.control.actions import ActionType
from hils.envs.intersection import EnvOptionError, episode_seed
from hils.protocol.config import Pair
from hils.run.testbed import Testbed
from hils.shell.targets import VIRTUAL
from hils.sim.network import scenario_config
from hils.sim.quiet_libsumo import libsumo
from hils.sim.sumo import SumoSimulation, statistic
from hils.sumo_rl.environment.observations import DefaultObservationFunction, ObservationFunction
from hils.sumo_rl.environment.traffic_signal import TrafficSignal
from hils.sumo_rl.lights import Timings, derive

try:
    from pettingzoo.utils import AgentSelector  # pettingzoo 1.25+
except ImportError:  # pettingzoo 1.24: the class had the module's name
    from pettingzoo.utils import agent_selector as AgentSelector  # noqa: N812

__all__ = ["SumoEnvironment", "SumoEnvironmentPZ", "env", "parallel_env"]

log = logging.getLogger(__name__)

#: SUMO's step when ``additional_sumo_cmd`` sets none (SUMO's own default, which sumo-rl runs with).
STEP_LENGTH = 1.0


def env(**kwargs: Any) -> AECEnv:
    """A PettingZoo AEC environment: :class:`SumoEnvironmentPZ` (sumo-rl's arguments), its actions checked."""
    aec = SumoEnvironmentPZ(**kwargs)
    return wrappers.OrderEnforcingWrapper(wrappers.AssertOutOfBoundsWrapper(aec))


parallel_env = parallel_wrapper_fn(env)


class SumoEnvironment(gym.Env):
    """sumo-rl's ``SumoEnvironment`` on NEMA controllers (see the module header).

    sumo-rl's arguments, as it documents them, with what each does here:

    - ``net_file``, ``route_file`` (several: comma-separated): any network; every traffic light gets a controller
      derived from its first program (:mod:`hils.sumo_rl.lights`).
    - ``delta_time`` (5): seconds between decisions, the controllers' control interval; it must exceed every light's
      clearance (yellow plus red clearance).
    - ``yellow_time`` (3; sumo-rl's default of 2 s is below NTCIP 1202's 3 s and refused), ``min_green`` (5),
      ``max_green`` (50): every phase's yellow change, minimum green and maximum green in its controller. The
      controller enforces them; max green times only against a conflicting call, which the middleware places only
      for the pair asked for, so it seldom ends a green (sumo-rl ignores it). ``enforce_max_green``: as sumo-rl.
    - ``begin_time``, ``num_seconds``, ``max_depart_delay``, ``waiting_time_memory``, ``time_to_teleport``,
      ``sumo_seed``, ``additional_sumo_cmd``: SUMO's, as sumo-rl passes them (``--step-length`` in
      ``additional_sumo_cmd`` sets the run's SUMO step; 1 s without it, as in sumo-rl).
    - ``single_agent``, ``reward_fn``, ``reward_weights``, ``observation_class``, ``add_system_info``,
      ``add_per_agent_info``, ``out_csv_name``, ``fixed_ts``: as sumo-rl (``fixed_ts``: each controller's timing plan).
    - ``sumo_warnings``: False keeps SUMO's console quiet. ``use_gui`` runs without a GUI (libsumo has none; a
      warning says so); ``render_mode`` other than None is refused (there is nothing to render), and
      ``virtual_display`` is kept for sumo-rl's callers only.

    hils' own, keyword only: ``target`` (``"virtual"``, or a mapping from every light to its ``snmp://`` URL: real
    controllers at the wall clock) and ``log_path`` (the run's event log, overwritten every episode; None: kept in
    memory).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    CONNECTION_LABEL = 0  # numbers the environments of a process, as sumo-rl's CSV names do

    def __init__(self, net_file: str, route_file: str, out_csv_name: str | None = None, use_gui: bool = False,
                 virtual_display: tuple[int, int] = (3200, 1800), begin_time: int = 0, num_seconds: int = 20000,
                 max_depart_delay: int = -1, waiting_time_memory: int = 1000, time_to_teleport: int = -1,
                 delta_time: int = 5, yellow_time: float = 3, min_green: int = 5, max_green: int = 50,
                 enforce_max_green: bool = False, single_agent: bool = False,
                 reward_fn: str | Callable | dict | list = "diff-waiting-time",
                 reward_weights: list[float] | None = None,
                 observation_class: type[ObservationFunction] = DefaultObservationFunction,
                 add_system_info: bool = True, add_per_agent_info: bool = True, sumo_seed: str | int = "random",
                 fixed_ts: bool = False, sumo_warnings: bool = True, additional_sumo_cmd: str | None = None,
                 render_mode: str | None = None, *, target: str | Mapping[str, str] = VIRTUAL,
                 log_path: str | Path | None = None) -> None:
        if render_mode is not None:
            raise EnvOptionError(f"render_mode {render_mode!r}: hils runs SUMO in process through libsumo, which has "
                                 "no GUI to render; allowed: None")
        if use_gui:
            log.warning("use_gui: hils runs SUMO in process through libsumo, which has no GUI; running without one")
        self.render_mode = None
        self.virtual_display = virtual_display
        self._net, self._route = str(net_file), str(route_file)
        self.use_gui = use_gui
        self.begin_time = begin_time
        self.delta_time = delta_time
        self.max_depart_delay = max_depart_delay
        self.waiting_time_memory = waiting_time_memory
        self.time_to_teleport = time_to_teleport
        self.min_green = min_green
        self.max_green = max_green
        self.enforce_max_green = enforce_max_green
        self.yellow_time = yellow_time
        self.single_agent = single_agent
        self.reward_fn = reward_fn
        self.reward_weights = reward_weights
        self.sumo_seed = sumo_seed
        self.fixed_ts = fixed_ts
        self.sumo_warnings = sumo_warnings
        self.additional_sumo_cmd = additional_sumo_cmd
        self.add_system_info = add_system_info
        self.add_per_agent_info = add_per_agent_info
        self.observation_class = observation_class
        self.label = str(SumoEnvironment.CONNECTION_LABEL)
        SumoEnvironment.CONNECTION_LABEL += 1
        self.sumo: Any = None  # libsumo while an episode runs, as sumo-rl's connection

        sumo_args, step_length = _sumo_options(additional_sumo_cmd, quiet=not sumo_warnings)
        self._scenario_dir = tempfile.TemporaryDirectory(prefix="hils-sumo-rl-")
        sumocfg = scenario_config(net=net_file, routes=str(route_file).split(","), directory=self._scenario_dir.name,
                                  begin=float(begin_time))
        self.scenario, self.lights = derive(net_file, sumocfg, Timings(
            delta_time, yellow_time, min_green, max_green, begin_time, num_seconds, step_length))
        self.ts_ids = list(self.lights)
        self.sim_max_time = begin_time + num_seconds
        self._simulation = SumoSimulation(
            sumo_config=sumocfg, lights=self.scenario.intersections, links=self.scenario.links, end=num_seconds,
            step_length=step_length, time_to_teleport=float(time_to_teleport), quiet=not sumo_warnings, measure=False,
            extra_args=["--max-depart-delay", str(max_depart_delay), "--waiting-time-memory",
                        str(waiting_time_memory), *sumo_args])
        self.testbed = Testbed(scenario=self.scenario, action_type=ActionType.SELECTION, target=target,
                               sumo=self._simulation, duration=float(num_seconds),
                               agent="fixed-time" if fixed_ts else None, log_path=log_path, measure=False)
        self._reward_fns = reward_fn if isinstance(reward_fn, dict) else dict.fromkeys(self.ts_ids, reward_fn)
        missing = [ts for ts in self.ts_ids if ts not in self._reward_fns]
        if missing:
            raise EnvOptionError(f"reward_fn: a dict with no reward for traffic light(s) {', '.join(missing)}; "
                                 f"allowed: one for every light ({', '.join(self.ts_ids)})")
        self.vehicles: dict[str, dict[str, float]] = {}
        self._build_traffic_signals()

        self.reward_range = (-float("inf"), float("inf"))
        self.episode = 0
        self.episode_done = False
        self.metrics: list[dict[str, Any]] = []
        self.out_csv_name = out_csv_name
        self.observations: dict[str, np.ndarray | None] = dict.fromkeys(self.ts_ids)
        self.rewards: dict[str, Any] = dict.fromkeys(self.ts_ids)
        #: what the run made of each light's last action (the Testbed's step info: acted, dropped, refused, timeout...)
        self.controller_infos: dict[str, dict[str, Any]] = {}

    def _build_traffic_signals(self) -> None:
        self.traffic_signals = {
            ts: TrafficSignal(self, ts, self.delta_time, self.yellow_time, self.min_green, self.max_green,
                              self.enforce_max_green, self.begin_time, self._reward_fns[ts], self.reward_weights,
                              libsumo)
            for ts in self.ts_ids
        }

    # --- the episode -------------------------------------------------------------------------------------

    def reset(self, seed: int | None = None, **kwargs: Any) -> Any:
        """Start an episode (closing the one before and writing its CSV); the first observations (single agent:
        the first light's, with the info)."""
        super().reset(seed=seed, **kwargs)
        if self.episode != 0:
            self.close()
            self.save_csv(self.out_csv_name, self.episode)
        self.episode += 1
        self.metrics = []
        if seed is not None:
            self.sumo_seed = seed
        run_seed = episode_seed(None if self.sumo_seed == "random" else int(self.sumo_seed), self.np_random)
        self._simulation.seed = run_seed
        self._simulation.start()
        self.sumo = libsumo
        tb = self.testbed
        try:
            tb.reset_all(seed=run_seed)
            step = self._simulation.step_length
            tb.run_for(math.ceil(tb.now / step - 1e-9) * step - tb.now)  # to SUMO's time: observations are of now
        except BaseException:
            self.close()
            raise
        self._build_traffic_signals()
        for ts, signal in self.traffic_signals.items():
            signal.drive(tb.intersections[ts])
        self.vehicles = {}
        self.episode_done = False
        self.controller_infos = {}
        if self.single_agent:
            return self._compute_observations()[self.ts_ids[0]], self._compute_info()
        return self._compute_observations()

    @property
    def sim_step(self) -> float:
        """SUMO's current time (s)."""
        return self._simulation.time

    def step(self, action: dict | int | None) -> tuple:
        """Take the action(s) of the lights at a decision point and run to the next one.

        ``action``: single agent, the first light's green phase index; otherwise a dict of them by light. None or
        ``{}`` (or ``fixed_ts``) takes none. Returns ``(obs, reward, terminated, truncated, info)`` for a single
        agent and ``(observations, rewards, dones, info)`` otherwise, as sumo-rl does."""
        empty = action is None or (isinstance(action, Mapping) and not action)
        self._run_steps({} if self.fixed_ts or empty else self._apply_actions(action))
        observations = self._compute_observations()
        rewards = self._compute_rewards()
        dones = self._compute_dones()
        truncated = dones["__all__"]  # an episode ends when its time is up; no state is terminal
        info = self._compute_info()
        if self.single_agent:
            return observations[self.ts_ids[0]], rewards[self.ts_ids[0]], False, truncated, info
        return observations, rewards, dones, info

    def _apply_actions(self, actions: Any) -> dict[str, Pair | None]:
        """The pair each light at a decision point asks its controller for (None: none)."""
        if self.single_agent:
            actions = {self.ts_ids[0]: actions}
        unknown = [str(ts) for ts in actions if ts not in self.traffic_signals]
        if unknown:
            raise EnvOptionError(f"actions for {', '.join(unknown)}: no such traffic light; allowed: "
                                 f"{', '.join(self.ts_ids)}")
        return {ts: self.traffic_signals[ts].set_next_phase(a) for ts, a in actions.items()
                if self.traffic_signals[ts].time_to_act}

    def _run_steps(self, calls: Mapping[str, Pair | None]) -> None:
        """Run to the next decision point with ``calls`` placed; the run ends with the episode."""
        tb = self.testbed
        _, self.controller_infos = tb.step_all(calls)
        for signal in self.traffic_signals.values():
            signal.settle()
        self.episode_done = tb.done
        if tb.done:
            tb.finish()

    def _compute_dones(self) -> dict[str, bool]:
        dones = dict.fromkeys(self.ts_ids, False)
        dones["__all__"] = self.episode_done
        return dones

    def _acting(self) -> list[str]:
        return [ts for ts in self.ts_ids if self.traffic_signals[ts].time_to_act or self.fixed_ts]

    def _compute_observations(self) -> dict[str, np.ndarray]:
        acting = self._acting()
        self.observations.update({ts: self.traffic_signals[ts].compute_observation() for ts in acting})
        return {ts: self.observations[ts].copy() for ts in acting}

    def _compute_rewards(self) -> dict[str, Any]:
        acting = self._acting()
        self.rewards.update({ts: self.traffic_signals[ts].compute_reward() for ts in acting})
        return {ts: self.rewards[ts] for ts in acting}

    def _compute_info(self) -> dict[str, Any]:
        info: dict[str, Any] = {"step": self.sim_step}
        if self.add_system_info:
            info.update(self._get_system_info())
        if self.add_per_agent_info:
            info.update(self._get_per_agent_info())
        self.metrics.append(info.copy())
        return info

    def _get_system_info(self) -> dict[str, Any]:
        vehicle = libsumo.vehicle
        vehicles = vehicle.getIDList()
        speeds = [vehicle.getSpeed(v) for v in vehicles]
        waiting_times = [vehicle.getWaitingTime(v) for v in vehicles]
        # SUMO's running counts since the episode's start (sumo-rl adds up each step's arrivals and departures; the
        # run steps SUMO several steps per call where nothing else is due)
        departed = int(statistic("stats.vehicles.inserted"))
        return {
            "system_total_running": len(vehicles),
            "system_total_backlogged": len(libsumo.simulation.getPendingVehicles()),
            "system_total_stopped": sum(int(speed < 0.1) for speed in speeds),  # SUMO's halting: below 0.1 m/s
            "system_total_arrived": departed - int(statistic("stats.vehicles.running")),
            "system_total_departed": departed,
            "system_total_teleported": int(statistic("stats.teleports.total")),
            "system_total_waiting_time": float(sum(waiting_times)),
            "system_mean_waiting_time": float(np.mean(waiting_times)) if vehicles else 0.0,
            "system_mean_speed": float(np.mean(speeds)) if vehicles else 0.0,
        }

    def _get_per_agent_info(self) -> dict[str, Any]:
        signals = [self.traffic_signals[ts] for ts in self.ts_ids]
        stopped = [ts.get_total_queued() for ts in signals]
        waiting = [sum(ts.get_accumulated_waiting_time_per_lane()) for ts in signals]
        info: dict[str, Any] = {}
        for ts, s, w in zip(signals, stopped, waiting, strict=True):
            info[f"{ts.id}_stopped"] = s
            info[f"{ts.id}_accumulated_waiting_time"] = w
            info[f"{ts.id}_average_speed"] = ts.get_average_speed()
        info["agents_total_stopped"] = sum(stopped)
        info["agents_total_accumulated_waiting_time"] = sum(waiting)
        return info

    # --- spaces (the first light's: a single agent's) -----------------------------------------------------

    @property
    def observation_space(self) -> gym.spaces.Space:
        return self.traffic_signals[self.ts_ids[0]].observation_space

    @property
    def action_space(self) -> gym.spaces.Discrete:
        return self.traffic_signals[self.ts_ids[0]].action_space

    @property
    def reward_space(self) -> gym.spaces.Box:
        return self.traffic_signals[self.ts_ids[0]].reward_space

    @property
    def reward_dim(self) -> int:
        return self.traffic_signals[self.ts_ids[0]].reward_dim

    def observation_spaces(self, ts_id: str) -> gym.spaces.Space:
        """The observation space of light ``ts_id``."""
        return self.traffic_signals[ts_id].observation_space

    def action_spaces(self, ts_id: str) -> gym.spaces.Discrete:
        """The action space of light ``ts_id``."""
        return self.traffic_signals[ts_id].action_space

    # --- closing and output ----------------------------------------------------------------------------

    def close(self) -> None:
        """End the episode's run (its calls cleared) and SUMO; a later :meth:`reset` starts another."""
        self.testbed.close()
        self._simulation.close()
        self.sumo = None

    def __del__(self) -> None:
        if "testbed" in self.__dict__:  # not when the constructor refused its arguments
            self.close()

    def render(self) -> None:
        """Nothing to render (libsumo has no GUI; ``render_mode`` is None)."""

    def save_csv(self, out_csv_name: str | None, episode: int) -> None:
        """Write the info of every step of the episode to ``{out_csv_name}_conn{label}_ep{episode}.csv`` (nothing
        when ``out_csv_name`` is None)."""
        if out_csv_name is None or not self.metrics:
            return
        path = Path(f"{out_csv_name}_conn{self.label}_ep{episode}.csv")
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("w", newline="", encoding="utf-8") as out:
            writer = csv.DictWriter(out, fieldnames=list(self.metrics[0]))
            writer.writeheader()
            writer.writerows(self.metrics)

    # --- a discrete state, for tabular agents ------------------------------------------------------------

    def encode(self, state: np.ndarray, ts_id: str) -> tuple:
        """The observation of light ``ts_id`` as a hashable state: its green phase, the min-green flag and each
        density and queue in tenths (0-9)."""
        n = self.traffic_signals[ts_id].num_green_phases
        phase = int(np.flatnonzero(state[:n] == 1)[0])
        return (phase, state[n], *(self._discretize_density(d) for d in state[n + 1:]))

    def _discretize_density(self, density: float) -> int:
        return min(int(density * 10), 9)


#: SUMO options the environment gives SUMO itself, and the argument that sets each (None: the network is the run's).
_GIVEN = {"--seed": "sumo_seed", "--end": "num_seconds", "-e": "num_seconds", "--begin": "begin_time",
          "-b": "begin_time", "--time-to-teleport": "time_to_teleport", "--max-depart-delay": "max_depart_delay",
          "--waiting-time-memory": "waiting_time_memory", "--net-file": "net_file", "-n": "net_file",
          "--route-files": "route_file", "-r": "route_file", "--configuration-file": None, "-c": None}
#: SUMO flags the run always sets (no step log; no warnings when quiet): left out where a command repeats them.
_SET_ANYWAY = ("--no-step-log", "--no-warnings")


def _sumo_options(additional: str | None, quiet: bool) -> tuple[list[str], float]:
    """``additional_sumo_cmd`` as SUMO options, less its ``--step-length`` (the run's SUMO step, which the run gives
    SUMO itself) and the flags the run sets anyway, with that step (:data:`STEP_LENGTH` without one). An option the
    environment sets from one of its arguments is refused (SUMO refuses an option given twice)."""
    words = additional.split() if additional else []
    step = STEP_LENGTH
    out: list[str] = []
    rest = iter(words)
    for word in rest:
        name, equals, value = word.partition("=")
        if name in _GIVEN:
            argument = _GIVEN[name]
            raise EnvOptionError(f"additional_sumo_cmd: {name}: the environment gives SUMO this option itself"
                                 + (f"; allowed: its {argument} argument" if argument else "; allowed: leave it out"))
        if name in _SET_ANYWAY and (name == "--no-step-log" or quiet):
            continue
        if name != "--step-length":
            out.append(word)
            continue
        value = value if equals else next(rest, "")
        try:
            step = float(value)
        except ValueError:
            raise EnvOptionError(f"additional_sumo_cmd: --step-length {value!r}: allowed: seconds, e.g. "
                                 "--step-length 1") from None
    return out, step


class SumoEnvironmentPZ(AECEnv, EzPickle):
    """sumo-rl's PettingZoo AEC environment: every light an agent, acting in turn; the run moves when the last has
    acted. Takes :class:`SumoEnvironment`'s arguments."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "name": "sumo_rl_v0", "is_parallelizable": True}

    def __init__(self, **kwargs: Any) -> None:
        EzPickle.__init__(self, **kwargs)
        self._kwargs = kwargs
        self.seed()
        self.env = SumoEnvironment(**self._kwargs)
        self.render_mode = self.env.render_mode
        self.agents = list(self.env.ts_ids)
        self.possible_agents = list(self.env.ts_ids)
        self._agent_selector = AgentSelector(self.agents)
        self.agent_selection = self._agent_selector.reset()
        self.action_spaces = {a: self.env.action_spaces(a) for a in self.agents}
        self.observation_spaces = {a: self.env.observation_spaces(a) for a in self.agents}
        self.rewards = dict.fromkeys(self.agents, 0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, dict[str, Any]] = {a: {} for a in self.agents}
        self._actions: dict[str, Any] = {}

    def seed(self, seed: int | None = None) -> None:
        """Seed the wrapper's own RNG (the episodes are seeded through :meth:`reset`)."""
        self.randomizer, seed = seeding.np_random(seed)

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        self.env.reset(seed=seed, options=options)
        self.agents = self.possible_agents[:]
        self.agent_selection = self._agent_selector.reset()
        self.rewards = dict.fromkeys(self.agents, 0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self._actions = {}
        self.compute_info()

    def compute_info(self) -> None:
        """Each agent's info: the system's figures and its own (the keys its name begins)."""
        infos = self.env._compute_info()
        self.infos = {a: {k: v for k, v in infos.items() if k.startswith((f"{a}_", "system"))} for a in self.agents}

    def observation_space(self, agent: str) -> gym.spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gym.spaces.Space:
        return self.action_spaces[agent]

    def observe(self, agent: str) -> np.ndarray:
        return self.env.observations[agent].copy()

    def close(self) -> None:
        self.env.close()

    def render(self) -> None:
        return self.env.render()

    def save_csv(self, out_csv_name: str | None, episode: int) -> None:
        self.env.save_csv(out_csv_name, episode)

    def step(self, action: Any) -> None:
        if self.truncations[self.agent_selection] or self.terminations[self.agent_selection]:
            return self._was_dead_step(action)
        agent = self.agent_selection
        if not self.action_spaces[agent].contains(action):
            raise EnvOptionError(f"action {action!r} for agent {agent}: allowed: an integer in "
                                 f"[0, {self.action_spaces[agent].n})")
        if not self.env.fixed_ts:
            self._actions[agent] = action
        if self._agent_selector.is_last():
            self.env._run_steps(self.env._apply_actions(self._actions))
            self._actions = {}
            self.env._compute_observations()
            self.rewards = self.env._compute_rewards()
            self.compute_info()
        else:
            self._clear_rewards()
        done = self.env._compute_dones()["__all__"]
        self.truncations = dict.fromkeys(self.agents, done)
        self.agent_selection = self._agent_selector.next()
        self._cumulative_rewards[agent] = 0
        self._accumulate_rewards()
        return None
