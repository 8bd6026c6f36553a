"""`hils bench env`: the gymnasium environment's speed beside sumo-rl's, on the same network and demand.

Both environments run the shipped four-leg network and its routes with a 0.25 s SUMO step, a decision
every 10 s and a seeded random policy, for one simulated hour per episode, each in a fresh process (one
libsumo per process), alternately and several times; the medians are compared. What differs, on
purpose, is the controller: hils' emulator enforces minimum green, yellow and red clearance itself
(10 Hz polls, NTCIP objects, the manager), while sumo-rl switches SUMO's program directly and inserts a
yellow of its own without an all-red. So the two serve different signal sequences and the same demand
becomes different traffic: each side's vehicles inserted and arrived are reported beside its time.
sumo-rl is the `bench` extra (`pip install 'hils[bench]'`).
"""

from __future__ import annotations

import multiprocessing
import os
import statistics
import time
from collections.abc import Callable
from importlib import resources
from typing import Any

EPISODE_S = 3600.0
SUMO_STEP = 0.25
DECISION_S = 10.0


def hils_episode(seed: int, duration: float = EPISODE_S) -> dict[str, Any]:
    """One episode of `hils/Intersection-v0` (selection) with a random policy."""
    import gymnasium as gym

    import hils  # noqa: F401  (registers the environment)

    env = gym.make("hils/Intersection-v0", action_type="selection", sumo_step=SUMO_STEP,
                   control_interval=DECISION_S, episode_length=duration)
    steps, wall = _random_episode(env, seed)
    traffic = env.unwrapped.testbed.traffic
    env.close()
    return {"steps": steps, "wall_s": wall, "inserted": traffic.departed, "arrived": traffic.arrived}


def sumo_rl_episode(seed: int, duration: float = EPISODE_S) -> dict[str, Any]:
    """One episode of sumo-rl's single-agent SumoEnvironment with a random policy, through libsumo."""
    import sumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    os.environ["LIBSUMO_AS_TRACI"] = "1"
    import sumo_rl

    data = resources.files("hils.data")
    env = sumo_rl.SumoEnvironment(net_file=str(data / "four_leg.net.xml"), route_file=str(data / "four_leg.rou.xml"),
                                  use_gui=False, num_seconds=int(duration), delta_time=int(DECISION_S), yellow_time=3,
                                  min_green=3, max_green=20, single_agent=True, sumo_seed=seed, sumo_warnings=False,
                                  additional_sumo_cmd=f"--step-length {SUMO_STEP}")
    steps, wall = _random_episode(env, seed)
    stats = env.sumo.simulation
    inserted = int(stats.getParameter("", "stats.vehicles.inserted"))
    running = int(stats.getParameter("", "stats.vehicles.running"))
    env.close()
    return {"steps": steps, "wall_s": wall, "inserted": inserted, "arrived": inserted - running}


def _random_episode(env: Any, seed: int) -> tuple[int, float]:
    """Reset with ``seed`` and step a seeded random policy to the episode's end: (steps, wall seconds)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    steps, done, started = 0, False, time.perf_counter()
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps, done = steps + 1, terminated or truncated
    return steps, time.perf_counter() - started


def _in_fresh_process(fn: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any]:
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, args)


def measure_env(repeat: int = 3, seed: int = 0, duration: float = EPISODE_S) -> dict[str, Any]:
    """Alternating episodes of each; per side every run and the medians."""
    runs: dict[str, list[dict[str, Any]]] = {"hils": [], "sumo_rl": []}
    for _ in range(repeat):
        runs["hils"].append(_in_fresh_process(hils_episode, seed, duration))
        runs["sumo_rl"].append(_in_fresh_process(sumo_rl_episode, seed, duration))
    out: dict[str, Any] = {"episode_s": duration, "sumo_step_s": SUMO_STEP, "decision_s": DECISION_S,
                           "policy": "random (seeded)", "repeat": repeat, "runs": runs}
    for side, rs in runs.items():
        wall = statistics.median(r["wall_s"] for r in rs)
        steps = rs[0]["steps"]
        out[side] = {"steps": steps, "wall_median_s": wall, "steps_per_s": steps / wall,
                     "wall_per_sim_hour_s": wall * 3600.0 / duration,
                     "inserted": rs[0]["inserted"], "arrived": rs[0]["arrived"]}
    out["speed_ratio_hils_to_sumo_rl"] = out["hils"]["steps_per_s"] / out["sumo_rl"]["steps_per_s"]
    return out
