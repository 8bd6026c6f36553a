"""`hils bench env`: the gymnasium environment's speed beside sumo-rl's, on the same network and demand.

Both environments run the shipped four-leg network and its routes with a 0.25 s SUMO step, a decision
every 10 s and a seeded random policy, for one simulated hour per episode, each in a fresh process (one
libsumo per process), alternately and several times; the medians are compared. What differs, on
purpose, is the controller: hils' emulator enforces minimum green, yellow and red clearance itself
(10 Hz polls, NTCIP objects, the manager), while sumo-rl switches SUMO's program directly and inserts a
yellow of its own without an all-red. sumo-rl gets the shipped config's yellow and minimum green (3 s
each), converted to its unit: it counts both in SUMO steps (one per ``simulationStep``) although its docs
say seconds, so at a 0.25 s step a "3" is 0.75 s; that unconverted run is measured too, for the record.
The two still serve different signal sequences (hils adds the 2 s all-red and decides among the config's
pairs) and the same demand becomes different traffic, which SUMO takes longer or shorter to step: each
side's vehicles inserted and arrived are reported beside its time, and its time is split into SUMO's steps
and the environment's own work (controller, middleware, observations), the part an environment is
answerable for.
sumo-rl is the `bench` extra (`pip install 'hils[bench]'`).
"""

from __future__ import annotations

import contextlib
import io
import os
import statistics
import sys
import time
from importlib import resources
from typing import Any

from harness.processes import in_fresh_process

EPISODE_S = 3600.0
SUMO_STEP = 0.25
DECISION_S = 10.0
TIMINGS = ("yellow", "min_green", "max_green")


def hils_episode(seed: int, duration: float = EPISODE_S) -> dict[str, Any]:
    """One episode of `hils/Intersection-v0` (selection) with a random policy."""
    import gymnasium as gym

    import hils  # noqa: F401  (registers the environment)

    sumo_s = _time_sumo_steps()
    env = gym.make("hils/Intersection-v0", action_type="selection", sumo_step=SUMO_STEP,
                   control_interval=DECISION_S, episode_length=duration)
    steps, wall = _random_episode(env, seed)
    traffic = env.unwrapped.testbed.traffic
    env.close()
    return {"steps": steps, "wall_s": wall, "sumo_s": sumo_s[0], "inserted": traffic.departed,
            "arrived": traffic.arrived}


def sumo_rl_episode(seed: int, duration: float = EPISODE_S, converted: bool = True) -> dict[str, Any]:
    """One episode of sumo-rl's single-agent SumoEnvironment with a random policy, through libsumo.

    ``converted``: the config's timings in sumo-rl's unit (:func:`sumo_rl_timing`); else the same numbers
    as seconds would be written, which sumo-rl takes as steps (a 0.75 s yellow at 0.25 s steps)."""
    import sumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    os.environ["LIBSUMO_AS_TRACI"] = "1"
    with contextlib.redirect_stdout(io.StringIO()):  # traci's "Using libsumo as traci as requested ..."
        import sumo_rl

    sumo_s = _time_sumo_steps()  # after sumo_rl's import: it must find libsumo as traci untouched

    data = resources.files("hils.data")
    env = sumo_rl.SumoEnvironment(net_file=str(data / "four_leg.net.xml"), route_file=str(data / "four_leg.rou.xml"),
                                  use_gui=False, num_seconds=int(duration), delta_time=int(DECISION_S),
                                  single_agent=True, sumo_seed=seed, sumo_warnings=False,
                                  additional_sumo_cmd=f"--step-length {SUMO_STEP}")
    # Set after construction: its constructor compares the yellow, in steps, with delta_time, in seconds.
    env.yellow_time, env.min_green, env.max_green = sumo_rl_timing() if converted else _config_timing()
    steps, wall = _random_episode(env, seed)
    stats = env.sumo.simulation
    inserted = int(stats.getParameter("", "stats.vehicles.inserted"))
    running = int(stats.getParameter("", "stats.vehicles.running"))
    env.close()
    return {"steps": steps, "wall_s": wall, "sumo_s": sumo_s[0], "inserted": inserted, "arrived": inserted - running}


def sumo_rl_timing() -> tuple[int, int, int]:
    """The shipped config's yellow, minimum and maximum green in sumo-rl's unit: SUMO steps, since its
    TrafficSignal counts a yellow and a minimum green by calls of ``update()``, one per step."""
    yellow, min_green, max_green = (round(s / SUMO_STEP) for s in _config_timing())
    return yellow, min_green, max_green


def _config_timing() -> tuple[float, float, float]:
    """The shipped config's yellow, minimum and maximum green in seconds (every phase has the same)."""
    from hils.config import load

    phase = load().phases[2]
    return phase.yellow, phase.min_green, phase.max_green


def _time_sumo_steps() -> list[float]:
    """From now on in this (fresh) process, the wall seconds libsumo's simulationStep takes are summed into the
    list returned: both environments step SUMO through it, so what is left of an episode's wall time is the
    environment's own work, whatever traffic its signals made."""
    from hils.sumo import libsumo  # imported quietly there

    total = [0.0]
    step = libsumo.simulationStep

    def timed(*args: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return step(*args)
        finally:
            total[0] += time.perf_counter() - t0

    # sumo-rl reaches libsumo through traci, which (LIBSUMO_AS_TRACI) holds libsumo's functions as its own.
    for module in (libsumo, sys.modules.get("traci")):
        if module is not None and getattr(module, "simulationStep", None) is step:
            module.simulationStep = timed
    return total


def _random_episode(env: Any, seed: int) -> tuple[int, float]:
    """Reset with ``seed`` and step a seeded random policy to the episode's end: (steps, wall seconds)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    steps, done, started = 0, False, time.perf_counter()
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps, done = steps + 1, terminated or truncated
    return steps, time.perf_counter() - started


def measure_env(repeat: int = 3, seed: int = 0, duration: float = EPISODE_S) -> dict[str, Any]:
    """Alternating episodes of each; per side every run and the medians."""
    runs: dict[str, list[dict[str, Any]]] = {"hils": [], "sumo_rl": [], "sumo_rl_unconverted": []}
    for _ in range(repeat):
        runs["hils"].append(in_fresh_process(hils_episode, seed, duration))
        runs["sumo_rl"].append(in_fresh_process(sumo_rl_episode, seed, duration))
        runs["sumo_rl_unconverted"].append(in_fresh_process(sumo_rl_episode, seed, duration, False))
    out: dict[str, Any] = {"episode_s": duration, "sumo_step_s": SUMO_STEP, "decision_s": DECISION_S,
                           "policy": "random (seeded)", "repeat": repeat,
                           "config_timing_s": dict(zip(TIMINGS, _config_timing(), strict=True)),
                           "sumo_rl_timing_steps": dict(zip(TIMINGS, sumo_rl_timing(), strict=True)),
                           "runs": runs}
    for side, rs in runs.items():
        wall = statistics.median(r["wall_s"] for r in rs)
        steps = rs[0]["steps"]
        own = statistics.median(r["wall_s"] - r["sumo_s"] for r in rs)
        out[side] = {"steps": steps, "wall_median_s": wall, "steps_per_s": steps / wall,
                     "wall_per_sim_hour_s": wall * 3600.0 / duration,
                     "sumo_per_sim_hour_s": statistics.median(r["sumo_s"] for r in rs) * 3600.0 / duration,
                     "own_per_sim_hour_s": own * 3600.0 / duration,
                     "inserted": rs[0]["inserted"], "arrived": rs[0]["arrived"]}
    out["speed_ratio_hils_to_sumo_rl"] = out["hils"]["steps_per_s"] / out["sumo_rl"]["steps_per_s"]
    out["speed_ratio_hils_to_sumo_rl_unconverted"] = (out["hils"]["steps_per_s"]
                                                      / out["sumo_rl_unconverted"]["steps_per_s"])
    out["own_work_ratio_sumo_rl_to_hils"] = out["sumo_rl"]["own_per_sim_hour_s"] / out["hils"]["own_per_sim_hour_s"]
    return out
