"""Training on hils: Stable-Baselines3 PPO learns on ``hils.sumo_rl``'s single intersection (the smoke test of the
training bench, which CI runs: the test extra installs torch's CPU build and Stable-Baselines3), the bench's runs split
their time as they say, and sumo-rl's own PettingZoo environment starts for the bench's peer."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from pettingzoo.test import parallel_api_test
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

from harness.bench import commands as bench
from harness.bench.train import SB3_PPO, SINGLE, single_intersection_files
from harness.reference.sumo_rl_peer import sumo_rl_pettingzoo
from hils.sim.quiet_libsumo import libsumo
from hils.sumo_rl import SumoEnvironment
from hils.sumo_rl.environment import register
from tests.hils.sumo_rl.test_lights import files


def test_ppo_learns_on_the_single_intersection_and_its_policy_drives_the_controller() -> None:
    env = SumoEnvironment(**single_intersection_files(), **{**SINGLE, "num_seconds": 600}, sumo_seed=0)
    try:
        check_env(env, warn=True)  # Stable-Baselines3's own checker: spaces, reset, step, dtypes
        torch.set_num_threads(1)
        model = PPO("MlpPolicy", env, seed=0, device="cpu", **{**SB3_PPO, "n_steps": 128, "n_epochs": 2})
        before = [p.detach().clone() for p in model.policy.parameters()]
        model.learn(total_timesteps=256)
        assert model.num_timesteps == 256  # two rollouts of 128 decisions, each an environment step
        changed = [not torch.equal(a, b) for a, b in zip(before, model.policy.parameters(), strict=True)]
        assert all(changed)  # two updates moved every layer of the network: it learnt from what it saw
        assert np.isfinite(model.logger.name_to_value["train/value_loss"])
        obs, _ = env.reset(seed=1)
        light = env.ts_ids[0]
        acted, shown = 0, set()
        for _ in range(30):
            action, _ = model.predict(obs, deterministic=False)
            assert env.action_space.contains(action)
            obs, _, _, _, _ = env.step(action)
            acted += env.controller_infos[light]["acted"]
            shown.add(libsumo.trafficlight.getRedYellowGreenState(light))
        # the policy's actions reached the controller, which changed what SUMO shows (one green held shows one state)
        assert acted > 0 and len(shown) > 1
    finally:
        env.close()


def test_the_bench_trains_each_side_in_a_fresh_process_and_splits_its_wall_time(tmp_path: Path) -> None:
    out = tmp_path / "figures"
    done = subprocess.run([sys.executable, "-m", "hils", "bench", "train", "--parts", "sb3", "--seeds", "0",
                           "--timesteps", "256", "--out", str(out)], capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    doc = json.loads((out / "train.json").read_text())
    assert len(doc["machine"]["load"]) == 3 and "load" in done.stdout.splitlines()[0]
    f = doc["train"]
    assert f["seeds"] == [0] and "rllib" not in f and f["versions"]["torch"].startswith("2.13.0")
    runs = f["sb3"]["runs"]
    assert set(runs) == {"hils", "sumo_rl"}
    for run in (runs["hils"]["0"], runs["sumo_rl"]["0"]):
        assert run["steps"] == run["agent_steps"] == 256
        assert run["sumo_s"] > 0 and run["env_own_s"] > 0 and run["learner_s"] > 0
        assert run["sumo_s"] + run["env_own_s"] + run["learner_s"] == pytest.approx(run["wall_s"])
        assert run["cpu_s"] > 0
        assert 0 < run["env_cpu_s"] < run["cpu_s"]
    per_step = {}
    for side, by_seed in runs.items():
        run = by_seed["0"]
        per_step[side] = {time: run[time] / run["steps"] for time in ("wall_s", "cpu_s", "env_cpu_s")}
        per_step[side]["learner_cpu_s"] = (run["cpu_s"] - run["env_cpu_s"]) / run["steps"]
    # hils / sumo-rl seed by seed: of the rates (steps per second) the inverse of the times per step
    for figure, time, rate in (("steps_per_s", "wall_s", True), ("steps_per_cpu_s", "cpu_s", True),
                               ("env_cpu_ms", "env_cpu_s", False), ("learner_cpu_ms", "learner_cpu_s", False)):
        ratio = per_step["hils"][time] / per_step["sumo_rl"][time]
        assert f["sb3"]["hils_to_sumo_rl"][figure]["median"] == pytest.approx(1 / ratio if rate else ratio)
    assert "hils / sumo-rl, per seed: steps per second" in done.stdout


def test_sumo_rls_own_parallel_environment_starts_on_the_installed_pettingzoo() -> None:
    """sumo-rl 1.4.5's wrapper calls ``agent_selector(...)``, a module in pettingzoo 1.27: the peer gives it the
    class, and PettingZoo's own checker passes sumo-rl's parallel environment."""
    module = sumo_rl_pettingzoo()
    try:
        env = module.parallel_env(**files("2x2grid"), num_seconds=60, sumo_warnings=False, yellow_time=3)
        try:
            parallel_api_test(env, num_cycles=15)
        finally:
            env.close()
    finally:
        register()  # importing sumo-rl took gymnasium's sumo-rl-v0: given back to hils


def test_the_training_bench_takes_three_seeds_and_refuses_unknown_parts_in_one_line() -> None:
    parser = argparse.ArgumentParser()
    bench.register(parser.add_subparsers())
    args = parser.parse_args(["bench", "train"])
    assert args.seeds == [0, 1, 2] and args.parts == ["sb3", "rllib"] and args.torch_threads == 1
    done = subprocess.run([sys.executable, "-m", "hils", "bench", "train", "--parts", "sb3,dqn"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.splitlines()[-1] == ("hils bench train: error: argument --parts: 'sb3,dqn': allowed: sb3, "
                                            "rllib or sb3,rllib")
