"""Train PPO on the virtual intersection, then run the same policy against the served emulator.

Needs the ``rl`` extra (Stable-Baselines3; it brings PyTorch)::

    pip install -e '.[rl]'
    python examples/train_ppo.py --timesteps 20000

Training runs in virtual time (as fast as SUMO steps), with ``--workers`` SUMOs in parallel
(gymnasium's AsyncVectorEnv, one SUMO per process). Evaluation builds the same environment with
``target="snmp://..."``: the policy's actions go over SNMP to ``hils emulator serve`` (started
here) at the wall clock, as they would to a real controller.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Callable

import gymnasium
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import SubprocVecEnv

import hils.envs

ENV_ID = hils.envs.ENV_ID


def env_factory(**kwargs: object) -> Callable[[], gymnasium.Env]:
    return lambda: gymnasium.make(ENV_ID, **kwargs)


def serve_emulator() -> tuple[subprocess.Popen[str], str]:
    """Start ``hils emulator serve`` on a free port; returns it and its snmp:// URL."""
    proc = subprocess.Popen([sys.executable, "-m", "hils.cli", "emulator", "serve", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()  # "serving NAME on udp:127.0.0.1:PORT (ro=... rw=...)"
    port = line.split("udp:127.0.0.1:")[1].split()[0]
    return proc, f"snmp://127.0.0.1:{port}?community=private&version=2c"


def evaluate(model: PPO, env: gymnasium.Env, seed: int) -> tuple[float, int, int]:
    """One episode with the trained policy: total reward, decisions, timeouts."""
    obs, _ = env.reset(seed=seed)
    total, steps, timeouts, done = 0.0, 0, 0, False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        total, steps, timeouts = total + reward, steps + 1, timeouts + int(info["timeout"])
        done = terminated or truncated
    return total, steps, timeouts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=20_000, help="PPO training steps (decisions)")
    parser.add_argument("--workers", type=int, default=2, help="parallel SUMOs during training")
    parser.add_argument("--episode-length", type=float, default=600.0, help="simulated seconds per training episode")
    parser.add_argument("--eval-seconds", type=float, default=120.0, help="wall-clock seconds of the evaluation")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    options = {"action_type": "selection", "reward": "queue", "episode_length": args.episode_length}
    train_env = SubprocVecEnv([env_factory(**options) for _ in range(args.workers)])
    model = PPO("MlpPolicy", train_env, n_steps=64, batch_size=64, seed=args.seed, verbose=1)
    model.learn(total_timesteps=args.timesteps)
    train_env.close()

    virtual = gymnasium.make(ENV_ID, **{**options, "episode_length": args.eval_seconds})
    reward, steps, timeouts = evaluate(model, virtual, args.seed + 1)
    print(f"virtual time: reward {reward:.1f} over {steps} decisions, {timeouts} timeouts")
    virtual.close()

    proc, url = serve_emulator()
    try:
        real = gymnasium.make(ENV_ID, **{**options, "episode_length": args.eval_seconds, "target": url})
        reward, steps, timeouts = evaluate(model, real, args.seed + 1)
        print(f"wall clock against {url}: reward {reward:.1f} over {steps} decisions, {timeouts} timeouts")
        real.close()
    finally:
        proc.terminate()
        proc.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
