"""`hils bench resco`: hils' PettingZoo environment beside sumo-rl's on RESCO's networks, every light a controller.

Per scenario and seed, one episode of each side, each in a fresh process, alternately (:mod:`harness.bench.seeds`):

- hils: ``hils.envs.parallel_env(scenario="resco:NAME")``, every light an emulated NEMA controller derived from
  its SUMO program, driven through the middleware (virtual time, ``measure`` off as for training);
- hils with a SUMO worker: the same with ``sumo_worker=True``, SUMO stepped in a worker process
  (:mod:`hils.sim.worker`): its CPU time is both processes', its SUMO part the worker's steps, its own work the rest
  of the wall time (what SUMO's steps did not hide);
- sumo-rl: its multi-agent ``SumoEnvironment`` on the same network and demand, matched to hils' decisions and
  timings, run as :mod:`harness.reference.sumo_rl_peer` says (its PettingZoo wrapper does not start with pettingzoo
  1.27).

Both at 0.25 s SUMO steps, a decision every RESCO step_length (10 s, 5 s on arterial4x4), a seeded random policy
(each light's own action space), one simulated hour from RESCO's begin. Each side's wall time from reset to the
episode's end is split into SUMO's steps (libsumo's ``simulationStep``, timed on both) and the environment's own
work, per simulated hour and, for the own work, per simulated controller-hour; vehicles inserted and arrived are
shown, since the same demand under other signals is other traffic that SUMO steps at its own cost; and the machine's
load (one minute's average) at each episode's end, since a busy machine moves wall time much more than CPU time.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from functools import partial
from typing import Any

from harness.bench.seeds import alternate, compare_episodes, episode_figures, time_sumo_steps, worker_usage
from harness.reference.sumo_rl_peer import HOW_IT_RUNS
from harness.reference.sumo_rl_peer import episode as sumo_rl_episode

EPISODE_S = 3600.0
DEFAULT_SCENARIOS = ("grid4x4", "cologne8")


def hils_episode(seed: int, *, scenario: str, duration: float = EPISODE_S, sumo_worker: bool = False
                 ) -> dict[str, Any]:
    """One episode of hils' PettingZoo environment on RESCO's ``scenario`` with a seeded random policy, SUMO in this
    process (the environment's default) or in a worker process."""
    import hils.envs

    sumo_s = time_sumo_steps()
    env = hils.envs.parallel_env(scenario=f"resco:{scenario}", action_type="selection", episode_length=duration,
                                 sumo_worker=sumo_worker)
    worker = env.testbed.sumo_process
    started, cpu = time.perf_counter(), time.process_time()
    # the worker boots beside the environment's construction: what it took before the episode is not counted, as
    # this process's imports are not
    worker_cpu, worker_sumo = worker_usage(worker)
    env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    steps = 0
    while env.agents:
        env.step({agent: env.action_space(agent).sample() for agent in env.agents})
        steps += 1
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    cpu_now, sumo_now = worker_usage(worker)
    cpu, sumo_s[0] = cpu + cpu_now - worker_cpu, sumo_s[0] + sumo_now - worker_sumo
    traffic = env.testbed.traffic
    env.close()
    return {"steps": steps, "wall_s": wall, "cpu_s": cpu, "sumo_s": sumo_s[0], "inserted": traffic.departed,
            "arrived": traffic.arrived, "load": os.getloadavg()[0]}


def sumo_rl_side(seed: int, *, scenario: str, duration: float = EPISODE_S) -> dict[str, Any]:
    """One episode of sumo-rl's side (:func:`harness.reference.sumo_rl_peer.episode`) and the load at its end."""
    return {**sumo_rl_episode(seed, scenario=scenario, duration=duration), "load": os.getloadavg()[0]}


def measure_resco(scenarios: Sequence[str], seeds: Sequence[int], duration: float = EPISODE_S, *,
                  progress: bool = True) -> dict[str, Any]:
    """Per scenario: every run, each side's figures over the seeds, and hils' ratio to sumo-rl seed by seed."""
    from hils.protocol import resco

    out: dict[str, Any] = {"episode_s": duration, "sumo_step_s": 0.25, "policy": "random (seeded)",
                           "seeds": list(seeds), "peer": HOW_IT_RUNS, "scenarios": {}}
    for name in scenarios:
        controllers = len(resco.load(name).intersections)
        runs = alternate(seeds, {"hils": partial(hils_episode, scenario=name, duration=duration),
                                 "hils_worker": partial(hils_episode, scenario=name, duration=duration,
                                                        sumo_worker=True),
                                 "sumo_rl": partial(sumo_rl_side, scenario=name, duration=duration)},
                         progress=progress)
        sides = {side: episode_figures(by_seed, duration, controllers) for side, by_seed in runs.items()}
        out["scenarios"][name] = {"controllers": controllers, "decision_s": resco.MAPS[name].decision_interval,
                                  "runs": runs, "sides": sides,
                                  "hils_to_sumo_rl": compare_episodes(sides["hils"], sides["sumo_rl"]),
                                  "hils_worker_to_sumo_rl": compare_episodes(sides["hils_worker"], sides["sumo_rl"])}
    return out
