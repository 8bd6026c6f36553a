"""`hils bench env`: the gymnasium environment's speed beside sumo-rl's, on the same network and demand.

Both environments run the shipped four-leg network and its routes with a 0.25 s SUMO step, a decision
every 10 s and a seeded random policy, for one simulated hour per episode: one episode of each per seed
(seeds 0-7 by default), each in a fresh process (one libsumo per process), alternately
(:mod:`harness.bench.seeds`); medians and spread over the seeds, and hils' ratio to sumo-rl seed by seed.
What differs, on purpose, is the controller: hils' emulator enforces minimum green, yellow and red clearance itself
(10 Hz polls, NTCIP objects, the manager), while sumo-rl switches SUMO's program directly and inserts a
yellow of its own without an all-red. sumo-rl gets the shipped config's yellow and minimum green (3 s
each), converted to its unit: it counts both in SUMO steps (one per ``simulationStep``) although its docs
say seconds, so at a 0.25 s step a "3" is 0.75 s; that unconverted run is measured too, for the record.
The two still serve different signal sequences (hils adds the 2 s all-red and decides among the config's
pairs) and the same demand becomes different traffic, which SUMO takes longer or shorter to step: each
side's vehicles inserted and arrived are reported beside its time, and its time is split into SUMO's steps
and the environment's own work (controller, middleware, observations), the part an environment is
answerable for. With the same clearances on both sides, hils' controller is also run without its red clearance
(``hils_no_all_red``: sumo-rl's yellow and no all-red), and compared with sumo-rl.
sumo-rl is the `bench` extra (`pip install 'hils[bench]'`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from functools import partial
from importlib import resources
from typing import Any

from harness.bench.seeds import alternate, compare_episodes, episode_figures, time_sumo_steps, worker_usage

EPISODE_S = 3600.0
SUMO_STEP = 0.25
DECISION_S = 10.0
TIMINGS = ("yellow", "min_green", "max_green")


def hils_episode(seed: int, duration: float = EPISODE_S, all_red: bool = True, sumo_worker: bool = False
                 ) -> dict[str, Any]:
    """One episode of `hils/Intersection-v1` (selection) with a random policy. ``all_red=False``: the shipped config
    with no red clearance, the clearances sumo-rl gives (a yellow, no all-red). ``sumo_worker``: SUMO in a worker
    process (both processes' CPU counted) instead of the environment's (its default)."""
    import gymnasium as gym

    import hils.envs  # noqa: F401  (registers the environment)

    sumo_s = time_sumo_steps()
    env = gym.make("hils/Intersection-v1", action_type="selection", sumo_step=SUMO_STEP,
                   control_interval=DECISION_S, episode_length=duration, sumo_worker=sumo_worker,
                   **({} if all_red else {"config": without_red_clearance()}))
    worker = env.unwrapped.testbed.sumo_process
    steps, wall, cpu, (worker_cpu, worker_sumo) = _random_episode(env, seed, lambda: worker_usage(worker))
    traffic = env.unwrapped.testbed.traffic
    env.close()
    return {"steps": steps, "wall_s": wall, "cpu_s": cpu + worker_cpu, "sumo_s": sumo_s[0] + worker_sumo,
            "inserted": traffic.departed, "arrived": traffic.arrived, "load": os.getloadavg()[0]}


def sumo_rl_episode(seed: int, duration: float = EPISODE_S, converted: bool = True) -> dict[str, Any]:
    """One episode of sumo-rl's single-agent SumoEnvironment with a random policy, through libsumo.

    ``converted``: the config's timings in sumo-rl's unit (:func:`sumo_rl_timing`); else the same numbers
    as seconds would be written, which sumo-rl takes as steps (a 0.75 s yellow at 0.25 s steps)."""
    from harness.reference.sumo_rl_peer import sumo_rl as sumo_rl_module

    sumo_rl = sumo_rl_module()
    sumo_s = time_sumo_steps()

    data = resources.files("hils.data")
    env = sumo_rl.SumoEnvironment(net_file=str(data / "four_leg.net.xml"), route_file=str(data / "four_leg.rou.xml"),
                                  use_gui=False, num_seconds=int(duration), delta_time=int(DECISION_S),
                                  single_agent=True, sumo_seed=seed, sumo_warnings=False,
                                  additional_sumo_cmd=f"--step-length {SUMO_STEP}")
    # Set after construction: its constructor compares the yellow, in steps, with delta_time, in seconds.
    env.yellow_time, env.min_green, env.max_green = sumo_rl_timing() if converted else _config_timing()
    steps, wall, cpu, _ = _random_episode(env, seed)
    stats = env.sumo.simulation
    inserted = int(stats.getParameter("", "stats.vehicles.inserted"))
    running = int(stats.getParameter("", "stats.vehicles.running"))
    env.close()
    return {"steps": steps, "wall_s": wall, "cpu_s": cpu, "sumo_s": sumo_s[0], "inserted": inserted,
            "arrived": inserted - running, "load": os.getloadavg()[0]}


def without_red_clearance() -> Any:
    """The shipped config, every phase's red clearance 0 s: the same clearances as sumo-rl's (its yellow, no
    all-red)."""
    from dataclasses import replace

    from hils.protocol.config import load

    cfg = load()
    return replace(cfg, phases={n: replace(p, red_clear=0.0) for n, p in cfg.phases.items()})


def sumo_rl_timing() -> tuple[int, int, int]:
    """The shipped config's yellow, minimum and maximum green in sumo-rl's unit: SUMO steps, since its
    TrafficSignal counts a yellow and a minimum green by calls of ``update()``, one per step."""
    yellow, min_green, max_green = (round(s / SUMO_STEP) for s in _config_timing())
    return yellow, min_green, max_green


def _config_timing() -> tuple[float, float, float]:
    """The shipped config's yellow, minimum and maximum green in seconds (every phase has the same)."""
    from hils.protocol.config import load

    phase = load().phases[2]
    return phase.yellow, phase.min_green, phase.max_green


def _random_episode(env: Any, seed: int, worker: Callable[[], tuple[float, float]] = lambda: (0.0, 0.0)
                    ) -> tuple[int, float, float, tuple[float, float]]:
    """Reset with ``seed`` and step a seeded random policy to the episode's end: (steps, wall seconds, CPU seconds of
    the process, and what ``worker()`` moved by meanwhile: a SUMO worker's CPU and steps, :func:`worker_usage`)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    steps, done, started, cpu = 0, False, time.perf_counter(), time.process_time()
    before = worker()
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps, done = steps + 1, terminated or truncated
    after = worker()
    return (steps, time.perf_counter() - started, time.process_time() - cpu,
            (after[0] - before[0], after[1] - before[1]))


def measure_env(seeds: Sequence[int], duration: float = EPISODE_S, *, progress: bool = True) -> dict[str, Any]:
    """One episode of each side per seed, alternately, each in a fresh process (:mod:`harness.bench.seeds`): every
    run, each side's figures over the seeds, and hils' per-seed ratios to each sumo-rl side."""
    runs = alternate(seeds, {"hils": partial(hils_episode, duration=duration),
                             "hils_worker": partial(hils_episode, duration=duration, sumo_worker=True),
                             "hils_no_all_red": partial(hils_episode, duration=duration, all_red=False),
                             "sumo_rl": partial(sumo_rl_episode, duration=duration),
                             "sumo_rl_unconverted": partial(sumo_rl_episode, duration=duration, converted=False)},
                     progress=progress)
    sides = {side: episode_figures(by_seed, duration) for side, by_seed in runs.items()}
    return {"episode_s": duration, "sumo_step_s": SUMO_STEP, "decision_s": DECISION_S, "policy": "random (seeded)",
            "seeds": list(seeds), "config_timing_s": dict(zip(TIMINGS, _config_timing(), strict=True)),
            "sumo_rl_timing_steps": dict(zip(TIMINGS, sumo_rl_timing(), strict=True)),
            "runs": runs, "sides": sides,
            "hils_to_sumo_rl": compare_episodes(sides["hils"], sides["sumo_rl"]),
            "hils_worker_to_sumo_rl": compare_episodes(sides["hils_worker"], sides["sumo_rl"]),
            "same_clearances": compare_episodes(sides["hils_no_all_red"], sides["sumo_rl"]),
            "hils_to_sumo_rl_unconverted": compare_episodes(sides["hils"], sides["sumo_rl_unconverted"])}
