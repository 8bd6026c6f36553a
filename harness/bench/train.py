"""`hils bench train`: training throughput, hils beside sumo-rl, on PyTorch's CPU build.

Two trainings, each once per side and seed, alternately, every run in a fresh process (:mod:`harness.bench.seeds`):

- Stable-Baselines3 PPO on sumo-rl's single intersection (its ``nets/single-intersection``, its own demand): sumo-rl's
  ``SumoEnvironment`` beside ``hils.sumo_rl.SumoEnvironment``, the same arguments (:data:`SINGLE`: a decision every
  5 s, yellow 3 s, as sumo-rl's own side-by-side code in ``examples/`` gives them, since hils refuses sumo-rl's
  default 2 s yellow) and the same PPO settings (:data:`SB3_PPO`), for the same number of environment steps;
- RLlib PPO on RESCO's grid4x4 as sumo-rl gives it (``grid4x4(parallel=True)``: PettingZoo's parallel API, 16
  lights, a decision every 5 s), one policy shared by the sixteen lights, RLlib's ``ParallelPettingZooEnv`` around
  either side's environment, sampled and learnt in the one process (no env runner of its own, no learner actor), for
  the same iterations of the same batch.

Both sides run SUMO through libsumo (sumo-rl as :mod:`harness.reference.sumo_rl_peer` starts it) at SUMO's 1 s step,
with sumo-rl's default observation and reward, so the spaces and networks of the policies are the same. Each run's
wall time of training (``learn`` / the ``train()`` iterations, not the imports and the build before) is split into
SUMO's steps, the environment's own work (its ``step`` and ``reset`` less SUMO's) and the learner's (the rest:
rollouts' inference, PPO's updates, the libraries' glue); each run states its CPU seconds and the machine's load, since
several people share a machine and a figure taken under load is lower. torch runs ``--torch-threads`` threads (1:
the networks are small, and a second thread only competes for a shared core).

sumo-rl 1.4.5's PettingZoo wrapper does not start with pettingzoo 1.27: :func:`harness.reference.sumo_rl_peer.
sumo_rl_pettingzoo` gives it the class under the name it calls, and nothing else changes. The training libraries are
the ``rl`` extra; sumo-rl the ``bench`` extra.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from types import MappingProxyType
from typing import Any

from harness.bench.seeds import Spread, alternate, ratios, time_sumo_steps
from hils.protocol.resco import networks_dir

#: sumo-rl's SumoEnvironment arguments of the single-intersection training, on both sides.
SINGLE = MappingProxyType({"single_agent": True, "delta_time": 5, "yellow_time": 3, "min_green": 5, "max_green": 50,
                           "num_seconds": 3600, "sumo_warnings": False})
#: Stable-Baselines3 PPO's settings, on both sides: a rollout of 256 steps, 10 epochs of minibatches of 64.
SB3_PPO = MappingProxyType({"n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 3e-4})
#: RLlib PPO's settings on grid4x4, on both sides (its batch in environment steps is ``--batch``; minibatches of 128
#: or the whole batch if smaller: :func:`minibatch`).
RLLIB_PPO = MappingProxyType({"minibatch_size": 128, "num_epochs": 5, "lr": 3e-4})
#: The grid's options beside RESCO's network, demand and hour, on both sides: sumo-rl's defaults but the yellow.
GRID = MappingProxyType({"yellow_time": 3, "sumo_warnings": False})
SIDES = ("hils", "sumo_rl")
LABELS = MappingProxyType({"hils": "hils", "sumo_rl": "sumo-rl"})

#: The environment's step and reset of the run in this process: calls, agent steps, wall and CPU seconds.
_ENV = {"steps": 0, "agent_steps": 0, "seconds": 0.0, "cpu_s": 0.0}


def _restart_count() -> None:
    _ENV.update(steps=0, agent_steps=0, seconds=0.0, cpu_s=0.0)


def single_intersection_files() -> dict[str, str]:
    """sumo-rl's single-intersection network and demand, from the installed sumo-rl."""
    folder = networks_dir().parent / "single-intersection"
    return {"net_file": str(folder / "single-intersection.net.xml"),
            "route_file": str(folder / "single-intersection.rou.xml")}


def sumo_environment(side: str) -> Callable[..., Any]:
    """The ``SumoEnvironment`` class of ``side``: hils' or sumo-rl's (through libsumo)."""
    if side == "hils":
        from hils.sumo_rl import SumoEnvironment

        return SumoEnvironment
    from harness.reference.sumo_rl_peer import sumo_rl

    return sumo_rl().SumoEnvironment


def grid4x4(side: str, seed: int) -> Any:
    """RESCO's grid4x4 as ``side``'s ``grid4x4(parallel=True)`` gives it: a PettingZoo parallel environment."""
    if side == "hils":
        from hils import sumo_rl as module
    else:
        from harness.reference.sumo_rl_peer import sumo_rl_pettingzoo

        module = sumo_rl_pettingzoo()
    return module.grid4x4(parallel=True, sumo_seed=seed, **GRID)


def timed(env: Any) -> Any:
    """``env`` with its ``step`` and ``reset`` timed into this process's totals (calls, agent steps, wall and CPU
    seconds)."""
    step, reset = env.step, env.reset

    def timed_step(action: Any) -> Any:
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return step(action)
        finally:
            _ENV["seconds"] += time.perf_counter() - t0
            _ENV["cpu_s"] += time.process_time() - c0
            _ENV["steps"] += 1
            _ENV["agent_steps"] += len(action) if isinstance(action, Mapping) else 1

    def timed_reset(*args: Any, **kwargs: Any) -> Any:
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return reset(*args, **kwargs)
        finally:
            _ENV["seconds"] += time.perf_counter() - t0
            _ENV["cpu_s"] += time.process_time() - c0

    env.step, env.reset = timed_step, timed_reset
    return env


def _threads(n: int) -> None:
    import torch

    torch.set_num_threads(n)


def sb3_run(seed: int, *, side: str, timesteps: int, threads: int = 1) -> dict[str, Any]:
    """Stable-Baselines3 PPO learning ``timesteps`` steps of ``side``'s single-intersection environment."""
    from stable_baselines3 import PPO

    _threads(threads)
    _restart_count()
    sumo_s = time_sumo_steps()
    env = timed(sumo_environment(side)(**single_intersection_files(), **SINGLE, sumo_seed=seed))
    model = PPO("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **SB3_PPO)
    cpu, started = time.process_time(), time.perf_counter()
    model.learn(total_timesteps=timesteps)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    env.close()
    return _run(model.num_timesteps, wall, cpu, sumo_s[0])


def _grid_env(config: dict[str, Any]) -> Any:
    """RLlib's environment creator (a module's function: RLlib pickles it): ``side``'s grid4x4, timed."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    return ParallelPettingZooEnv(timed(grid4x4(config["side"], config["seed"])))


def rllib_run(seed: int, *, side: str, iterations: int, batch: int, threads: int = 1) -> dict[str, Any]:
    """RLlib PPO, one policy shared by grid4x4's sixteen lights, ``iterations`` training iterations of ``batch``
    environment steps on ``side``'s environment, sampled and learnt in this process."""
    import ray
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.tune.registry import register_env

    # Ray's notices about itself (its token authentication, its new API stack, its own PPO module's deprecated
    # constructor) say nothing about the figures: errors only (RLlib gives its loggers a level of their own).
    for name in ("ray", "ray.rllib"):
        logging.getLogger(name).setLevel(logging.ERROR)
    _threads(threads)
    sumo_s = time_sumo_steps()
    ray.init(num_cpus=1, include_dashboard=False, configure_logging=False, log_to_driver=False)
    register_env("hils_bench_train", _grid_env)
    config = (PPOConfig()
              .api_stack(enable_rl_module_and_learner=True, enable_env_runner_and_connector_v2=True)
              .environment("hils_bench_train", env_config={"side": side, "seed": seed})
              .env_runners(num_env_runners=0)
              .multi_agent(policies={"shared"}, policy_mapping_fn=lambda *_, **__: "shared")
              .training(train_batch_size_per_learner=batch, **{**RLLIB_PPO, "minibatch_size": minibatch(batch)})
              .debugging(seed=seed, log_level="ERROR"))
    algo = config.build_algo()
    try:
        cpu, started, sumo_before = time.process_time(), time.perf_counter(), sumo_s[0]
        _restart_count()  # building the algorithm reset the environment once
        for _ in range(iterations):
            algo.train()
        wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    finally:
        algo.stop()
        ray.shutdown()
    return _run(_ENV["steps"], wall, cpu, sumo_s[0] - sumo_before)


def minibatch(batch: int) -> int:
    """RLlib PPO's minibatch for a batch of ``batch`` steps: PPO refuses one larger than the batch."""
    return min(RLLIB_PPO["minibatch_size"], batch)


def _run(steps: int, wall: float, cpu: float, sumo: float) -> dict[str, Any]:
    """One run's figures: environment steps (and agent steps); wall and CPU seconds of training (the CPU this process
    took: the sampling and the learning, not Ray's own daemons), of the wall time SUMO's, the environment's own and
    the learner's, of the CPU time the environment's (SUMO's included); the machine's load (1 min) at its end."""
    return {"steps": steps, "agent_steps": _ENV["agent_steps"], "wall_s": wall, "cpu_s": cpu, "sumo_s": sumo,
            "env_own_s": _ENV["seconds"] - sumo, "learner_s": wall - _ENV["seconds"], "env_cpu_s": _ENV["cpu_s"],
            "load_1min": os.getloadavg()[0]}


#: Each side's figures over the seeds: (console title, digits) of each.
FIGURES = MappingProxyType({
    "steps_per_s": ("steps/s", 1), "steps_per_cpu_s": ("steps/CPU s", 1), "sumo_share": ("wall: SUMO", 2),
    "env_own_share": ("env's own", 2), "learner_share": ("learner", 2), "env_cpu_ms": ("CPU ms/step: env", 2),
    "learner_cpu_ms": ("learner", 2), "cpu_per_wall": ("CPU/wall", 2), "load_1min": ("load (1 min)", 1)})
#: The figures whose ratio hils / sumo-rl is taken seed by seed.
COMPARED = ("steps_per_s", "steps_per_cpu_s", "env_cpu_ms", "learner_cpu_ms")


def figures(runs: Mapping[int, Mapping[str, Any]]) -> dict[str, Any]:
    """One side's runs, per seed and over the seeds (:class:`Spread`): environment steps per second of training's
    wall time and of its CPU time, the shares of the wall time (SUMO, the environment's own work, the learner), the
    CPU milliseconds per environment step of the environment (SUMO's included) and of the learner (the rest), CPU
    seconds per wall second and the load. The learner's CPU per step is a check: the same networks learn from either
    side's steps, so it should come out the same on both."""
    per_seed = {seed: {"steps_per_s": r["steps"] / r["wall_s"], "steps_per_cpu_s": r["steps"] / r["cpu_s"],
                       "sumo_share": r["sumo_s"] / r["wall_s"], "env_own_share": r["env_own_s"] / r["wall_s"],
                       "learner_share": r["learner_s"] / r["wall_s"], "env_cpu_ms": 1e3 * r["env_cpu_s"] / r["steps"],
                       "learner_cpu_ms": 1e3 * (r["cpu_s"] - r["env_cpu_s"]) / r["steps"],
                       "cpu_per_wall": r["cpu_s"] / r["wall_s"], "load_1min": r["load_1min"]}
                for seed, r in runs.items()}
    return {"per_seed": per_seed, **{f: Spread.of([v[f] for v in per_seed.values()]).as_dict() for f in FIGURES}}


def _compare(runs: Mapping[str, Mapping[int, Mapping[str, Any]]]) -> dict[str, Any]:
    """Both sides' :func:`figures` and hils' ratio to sumo-rl seed by seed (steps per second and per CPU second, the
    environment's and the learner's CPU per step)."""
    sides = {side: figures(by_seed) for side, by_seed in runs.items()}
    hils, peer = sides["hils"]["per_seed"], sides["sumo_rl"]["per_seed"]
    return {"runs": runs, "sides": sides, "hils_to_sumo_rl": {
        f: ratios({s: v[f] for s, v in hils.items()}, {s: v[f] for s, v in peer.items()}).as_dict() for f in COMPARED}}


def measure_train(seeds: Sequence[int], *, timesteps: int, iterations: int, batch: int, threads: int = 1,
                  parts: Sequence[str] = ("sb3", "rllib"), progress: bool = True) -> dict[str, Any]:
    """The trainings of ``parts`` (``sb3``, ``rllib``), each side once per seed, alternately, in fresh processes."""
    out: dict[str, Any] = {"seeds": list(seeds), "torch_threads": threads, "versions": versions()}
    if "sb3" in parts:
        runs = alternate(seeds, {side: partial(sb3_run, side=side, timesteps=timesteps, threads=threads)
                                 for side in SIDES}, progress=progress)
        out["sb3"] = {"environment": "sumo-rl's single-intersection", "options": dict(SINGLE), "ppo": dict(SB3_PPO),
                      "timesteps": timesteps, **_compare(runs)}
    if "rllib" in parts:
        runs = alternate(seeds, {side: partial(rllib_run, side=side, iterations=iterations, batch=batch,
                                               threads=threads) for side in SIDES}, progress=progress)
        out["rllib"] = {"environment": "RESCO's grid4x4 as sumo-rl gives it (16 lights, PettingZoo parallel)",
                        "options": dict(GRID),
                        "ppo": {**RLLIB_PPO, "minibatch_size": minibatch(batch), "train_batch_size_per_learner": batch},
                        "iterations": iterations, **_compare(runs)}
    return out


def table(sides: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Console lines: per side (its label, its :func:`figures`) median [min-max] over the seeds."""
    cells = {label: [Spread(**f[k]).text(d) for k, (_, d) in FIGURES.items()] for label, f in sides.items()}
    titles = [title for title, _ in FIGURES.values()]
    widths = [2 + max(len(titles[i]), *(len(row[i]) for row in cells.values())) for i in range(len(titles))]
    return ["  " + f"{'':10}" + "".join(f"{t:>{w}}" for t, w in zip(titles, widths, strict=True)),
            *("  " + f"{label:10}" + "".join(f"{c:>{w}}" for c, w in zip(row, widths, strict=True))
              for label, row in cells.items())]


def missing_libraries(parts: Sequence[str]) -> list[str]:
    """What the trainings of ``parts`` need and this environment lacks (by the name pip installs it under)."""
    import importlib.util

    needed = {"torch": "torch", "sumo_rl": "sumo-rl"}
    if "sb3" in parts:
        needed["stable_baselines3"] = "stable-baselines3"
    if "rllib" in parts:
        needed["tree"] = "ray[rllib]"  # dm_tree: RLlib's own dependency, absent where ray alone is installed
        needed["ray"] = "ray[rllib]"
    return sorted({pip for module, pip in needed.items() if importlib.util.find_spec(module) is None})


def versions() -> dict[str, str]:
    """The versions of what the trainings run on."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("torch", "stable-baselines3", "ray", "gymnasium", "pettingzoo", "sumo-rl", "libsumo"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out
