"""Train a shared PPO policy with RLlib on a RESCO scenario's PettingZoo environment, then measure it on RESCO's
average delay against max-pressure, and save it.

Needs the ``rl`` and ``resco`` extras (RLlib, the CPU build of PyTorch, sumo-rl's networks)::

    pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu   # the CPU build (docs/rl.md)
    pip install -e '.[rl,resco]'
    python examples/train_rllib_resco.py --scenario resco:grid4x4 --iterations 20
    python examples/train_rllib_resco.py --address auto ...     # on a running Ray cluster (ray start --head ...)

Every traffic light is an agent of ``hils.envs.parallel_env`` (a NEMA controller each, emulated in virtual
time); the lights whose observation and action spaces are the same share one policy (all sixteen of grid4x4;
cologne8's lights fall into a few groups). Training episodes are ``--episode-length`` simulated seconds from
the scenario's begin. The evaluation runs one episode of ``--eval-length`` seconds with ``measure=True`` and
reads RESCO's figures from ``env.testbed.traffic.resco`` (SUMO's tripinfo), then runs max-pressure on the same
seed through the Testbed, and prints both. The trained policy is saved with RLlib's ``save_to_path`` under
``--out``; ``Algorithm.from_checkpoint(PATH)`` restores it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import ray
import torch
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

import hils.envs
from hils import Testbed


def make_env(config: dict[str, Any]) -> ParallelPettingZooEnv:
    return ParallelPettingZooEnv(hils.envs.parallel_env(**config))


def policy_groups(env: Any) -> dict[str, str]:
    """Each light's policy: one per distinct (observation, action) space, shared by every light that has it."""
    groups: dict[tuple, str] = {}
    out = {}
    for agent in env.possible_agents:
        key = (env.observation_space(agent).shape, env.action_space(agent).n)
        out[agent] = groups.setdefault(key, f"shared{len(groups)}")
    return out


def evaluate(modules: dict[str, Any], env_config: dict[str, Any], mapping: dict[str, str], seed: int) -> Any:
    """One measured episode with the trained policies (greedy actions); returns RESCO's figures of it."""
    env = hils.envs.parallel_env(**{**env_config, "measure": True})
    observations, _ = env.reset(seed=seed)
    while env.agents:
        actions = {}
        for agent, obs in observations.items():
            batch = {"obs": torch.as_tensor(np.asarray(obs)[None], dtype=torch.float32)}
            logits = modules[mapping[agent]].forward_inference(batch)["action_dist_inputs"]
            actions[agent] = int(torch.argmax(logits, dim=-1)[0])
        observations, *_ = env.step(actions)
    env.close()
    return env.testbed.traffic.resco


def max_pressure(scenario: str, seconds: float, seed: int) -> Any:
    with Testbed(scenario=scenario, sumo=True, agent="max-pressure", duration=seconds, seed=seed) as tb:
        tb.reset_all()
        tb.run()
    return tb.traffic.resco


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="resco:grid4x4", help="a RESCO scenario (resco:NAME) or any hils "
                                                                     "scenario (resco:grid4x4)")
    parser.add_argument("--iterations", type=int, default=20, help="PPO training iterations (20)")
    parser.add_argument("--episode-length", type=float, default=900.0, help="simulated s per training episode (900)")
    parser.add_argument("--eval-length", type=float, default=3600.0, help="simulated s of the evaluation (3600, "
                                                                          "RESCO's hour)")
    parser.add_argument("--workers", type=int, default=0, help="RLlib env runners, one SUMO each (0: the driver)")
    parser.add_argument("--batch", type=int, default=400, help="environment steps per training batch (400)")
    parser.add_argument("--address", default=None, help="Ray cluster to join (auto: the running one); default: "
                                                        "a local Ray instance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("reports/rl/rllib_resco"), help="where the policy is saved")
    args = parser.parse_args(argv)

    ray.init(address=args.address, include_dashboard=False, configure_logging=False, log_to_driver=False)
    env_config = {"scenario": args.scenario, "action_type": "selection", "reward": "queue",
                  "episode_length": args.episode_length}
    register_env("hils_resco", make_env)
    probe = hils.envs.parallel_env(**env_config)
    mapping = policy_groups(probe)
    probe.close()
    config = (PPOConfig()
              .environment("hils_resco", env_config=env_config)
              .env_runners(num_env_runners=args.workers)
              .multi_agent(policies=set(mapping.values()),
                           policy_mapping_fn=lambda agent_id, *_, **__: mapping[agent_id])
              .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={p: RLModuleSpec()
                                                                            for p in set(mapping.values())}))
              .training(train_batch_size_per_learner=args.batch, minibatch_size=min(128, args.batch),
                        num_epochs=5, lr=3e-4)
              .debugging(seed=args.seed))
    algo = config.build_algo()
    try:
        for i in range(1, args.iterations + 1):
            result = algo.train()
            episode = result.get("env_runners", {}).get("episode_return_mean")
            print(f"iteration {i}: mean episode return {episode if episode is None else round(episode, 1)}",
                  flush=True)
        saved = algo.save_to_path(str(args.out.resolve()))
        print(f"policy saved in {saved} ({len(set(mapping.values()))} shared policies for {len(mapping)} lights)")
        modules = {pid: algo.get_module(pid) for pid in set(mapping.values())}
    finally:
        algo.stop()  # closes its environments: one SUMO per process
        ray.shutdown()
    trained = evaluate(modules, {**env_config, "episode_length": args.eval_length}, mapping, args.seed + 1000)
    baseline = max_pressure(args.scenario, args.eval_length, args.seed + 1000)
    print(f"RESCO's average delay over {args.eval_length:g} s, seed {args.seed + 1000}: PPO {trained.delay_s:.1f} s, "
          f"max-pressure {baseline.delay_s:.1f} s (trip time {trained.trip_time_s:.1f} vs "
          f"{baseline.trip_time_s:.1f} s, queue {trained.queue:.2f} vs {baseline.queue:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
