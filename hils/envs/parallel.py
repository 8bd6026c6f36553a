"""A network of signalised intersections as a PettingZoo ``ParallelEnv``: one agent per traffic light.

``hils.envs.parallel_env(scenario="corridor", action_type=...)`` builds it on one :class:`hils.Testbed`
running a controller per traffic light of the scenario (the emulator in virtual time, or real ones at the
wall clock with ``target={tls: "snmp://..."}``). The agents are the traffic lights' SUMO ids, in the
scenario's order. Each agent's observation, action space and reward are the single-intersection
environment's (:mod:`hils.envs.intersection`, through the same :class:`IntersectionAdapter`).

Rules
-----
- Every intersection keeps its own decision schedule (selection and switch: the control interval;
  duration: the end of the green it serves). ``step(actions)`` takes the action of each agent whose
  intersection is at its decision point (``info["due"]`` of the last step; every agent after ``reset``),
  then runs to the next decision point of *any* intersection. The action of an agent that is not due, or
  left out, is not taken: its ``info["acted"]`` is False, and its controller runs on (duration: the green
  it was given is served whole, as the paper's ON_HOLD prescribes). Every live agent gets an observation
  and a reward at every step.
- An action outside the agent's space is refused with a typed error (:class:`EnvOptionError`, or the
  middleware's :class:`hils.control.actions.ActionError`) naming the agent; nothing is sent to any controller
  and no time passes. The action of an agent whose controller serves a preempt is not taken (the others'
  are): its ``info["acted"]`` is False, ``info["refused"]`` says why, and its observation's state is PREEMPTED.
- An episode is ``episode_length`` simulated seconds and is *truncated* for every agent at its end
  (``agents`` then empties); it is never *terminated*. A TIMEOUT of one controller shows in that agent's
  info (``timeout``, ``timeout_reason``, ``state``); the Testbed recovers it while the others run on.
- Seeding as the single environment: ``reset(seed=s)`` seeds SUMO and every controller; a reset without
  a seed draws the next one from the environment's RNG.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from hils.agents.builtin import Observation
from hils.control.actions import ActionType
from hils.envs.intersection import (
    EnvOptionError,
    IntersectionAdapter,
    Reward,
    action_type_of,
    episode_seed,
    reset_info,
    reward_of,
    with_timing,
)
from hils.protocol.scenario import Scenario, load_scenario
from hils.run.testbed import NotStarted, Testbed
from hils.shell.targets import VIRTUAL

__all__ = ["IntersectionsEnv", "Targets"]

Targets = str | Mapping[str, str]


class IntersectionsEnv(ParallelEnv[str, np.ndarray, Any]):
    """``hils.envs.parallel_env(scenario="corridor" | "grid4x4" | PATH, action_type=..., ...)``.

    ``scenario``: a shipped scenario's name, a ``.scenario.toml`` path or a :class:`hils.protocol.scenario.Scenario`.
    ``target``: ``"virtual"``, or a mapping from every traffic light to its ``snmp://`` URL (wall clock).
    ``sumo_step``, ``control_interval``: override every intersection's config. ``episode_length``:
    simulated seconds. ``reward``: a name of :data:`hils.envs.intersection.REWARDS` or a callable
    ``(previous, current) -> float``, applied to each agent's own observations. ``recover_after``: seconds
    in TIMEOUT before the Testbed recovers that controller. ``log_path``: the event log of each episode
    (overwritten; every record names its intersection). ``measure``: as the single environment's (off).
    ``sumo_worker``: as the single environment's (True: SUMO steps in a worker process; off by default).
    """

    metadata: ClassVar[dict[str, Any]] = {"name": "hils_intersections_v1", "render_modes": [],
                                          "is_parallelizable": True}
    render_mode = None

    def __init__(self, scenario: str | Path | Scenario = "corridor",
                 action_type: ActionType | str = ActionType.SELECTION, *, target: Targets = VIRTUAL,
                 sumo_step: float | None = None, control_interval: float | None = None,
                 episode_length: float = 3600.0, reward: str | Reward = "queue", recover_after: float = 5.0,
                 log_path: str | Path | None = None, measure: bool = False, sumo_worker: bool = False) -> None:
        self.action_type = action_type_of(action_type)
        self.reward_fn = reward_of(reward)
        loaded = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        configs = {tls: with_timing(cfg, sumo_step, control_interval) for tls, cfg in loaded.intersections.items()}
        self.scenario = dataclasses.replace(loaded, intersections=MappingProxyType(configs))
        self.testbed = Testbed(scenario=self.scenario, action_type=self.action_type, target=target, sumo=True,
                               duration=episode_length, recover_after=recover_after, log_path=log_path,
                               measure=measure, sumo_worker=sumo_worker)
        self.adapters = {tls: IntersectionAdapter(cfg, self.action_type) for tls, cfg in configs.items()}
        self.possible_agents: list[str] = list(configs)
        self.agents: list[str] = []
        self.observation_spaces: dict[str, spaces.Space] = {a: ad.observation_space for a, ad in self.adapters.items()}
        self.action_spaces: dict[str, spaces.Space] = {a: ad.action_space for a, ad in self.adapters.items()}
        self._np_random, _ = seeding.np_random()
        self._last: dict[str, Observation] = {}

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    # --- PettingZoo API -----------------------------------------------------------------------------

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._np_random, _ = seeding.np_random(seed)
        run_seed = episode_seed(seed, self._np_random)
        tb = self.testbed
        observations = tb.reset_all(seed=run_seed)
        for name, adapter in self.adapters.items():
            adapter.start(tb.intersections[name].middleware.cache, observations[name])
        self._last = observations
        self.agents = list(self.possible_agents)
        return ({tls: self.adapters[tls].vector(obs) for tls, obs in observations.items()},
                {tls: reset_info(obs, run_seed) for tls, obs in observations.items()})

    def step(self, actions: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool],
                                                       dict[str, bool], dict[str, dict[str, Any]]]:
        if not self.agents:
            raise NotStarted("the episode is over (or not started): call reset() first")
        unknown = sorted(set(actions) - set(self.agents))
        if unknown:
            raise EnvOptionError(f"actions for {', '.join(map(str, unknown))}: no such live agent; allowed: "
                                 f"{', '.join(self.agents)}")
        values = {}
        for tls, action in actions.items():
            try:
                values[tls] = self.adapters[tls].action(action)
            except EnvOptionError as exc:
                raise EnvOptionError(f"agent {tls}: {exc}") from None
        tb = self.testbed
        observations, infos = tb.step_all(values)  # a refused action raises, naming its light; nothing is sent
        rewards = {tls: float(self.reward_fn(self._last[tls], obs)) for tls, obs in observations.items()}
        self._last = observations
        truncated = tb.done
        if truncated:
            tb.finish()
            self.agents = []
        return ({tls: self.adapters[tls].vector(obs) for tls, obs in observations.items()}, rewards,
                dict.fromkeys(observations, False), dict.fromkeys(observations, truncated), infos)

    def close(self) -> None:
        self.testbed.close()
        self.agents = []
