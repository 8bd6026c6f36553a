"""Train PPO on the virtual intersection, save it, measure its mean delay against max-pressure, then run the same
policy against the served emulator.

Needs the ``rl`` extra (Stable-Baselines3 on the CPU build of PyTorch)::

    pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu   # the CPU build (docs/rl.md)
    pip install -e '.[rl]'
    python examples/train_ppo.py --timesteps 20000

Training runs in virtual time (as fast as SUMO steps), with ``--workers`` SUMOs in parallel
(Stable-Baselines3's SubprocVecEnv, one SUMO per process). The model is saved to ``--save``
(``PPO.load(PATH)`` restores it). The measured episode runs with ``measure=True``: the episode's
figures are then in ``env.unwrapped.testbed.traffic`` (``mean_delay``, and RESCO's in ``.resco``),
beside max-pressure's on the same seed. Evaluation at the wall clock builds the same environment with
``target="snmp://..."``: the policy's actions go over SNMP to ``hils emulator serve`` (started
here), as they would to a real controller.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import gymnasium
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import SubprocVecEnv

import hils.envs
from hils import Testbed

ENV_ID = hils.envs.ENV_ID


def env_factory(**kwargs: object) -> Callable[[], gymnasium.Env]:
    return lambda: gymnasium.make(ENV_ID, **kwargs)


def serve_emulator() -> tuple[subprocess.Popen[str], str]:
    """Start ``hils emulator serve`` on a free port; returns it and its snmp:// URL."""
    proc = subprocess.Popen([sys.executable, "-m", "hils", "emulator", "serve", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()  # "serving NAME on udp:127.0.0.1:PORT (ro=... rw=... ntcip=...)"
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


def mean_delays(model: PPO, options: dict, seconds: float, seed: int) -> tuple[float, float]:
    """Mean delay (s) of one measured episode under the policy, and under max-pressure on the same seed."""
    env = gymnasium.make(ENV_ID, **{**options, "episode_length": seconds, "measure": True})
    evaluate(model, env, seed)
    env.close()
    policy = env.unwrapped.testbed.traffic.mean_delay
    with Testbed(sumo=True, agent="max-pressure", duration=seconds, seed=seed) as tb:
        tb.reset()
        tb.run()
    return policy, tb.traffic.mean_delay


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=20_000, help="PPO training steps (decisions)")
    parser.add_argument("--workers", type=int, default=2, help="parallel SUMOs during training")
    parser.add_argument("--episode-length", type=float, default=600.0, help="simulated seconds per training episode")
    parser.add_argument("--eval-seconds", type=float, default=120.0, help="wall-clock seconds of the evaluation")
    parser.add_argument("--measure-seconds", type=float, default=3600.0, help="simulated s of the measured episode")
    parser.add_argument("--save", type=Path, default=Path("reports/rl/ppo_intersection.zip"), help="the model file")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    options = {"action_type": "selection", "reward": "queue", "episode_length": args.episode_length}
    train_env = SubprocVecEnv([env_factory(**options) for _ in range(args.workers)])
    model = PPO("MlpPolicy", train_env, n_steps=64, batch_size=64, seed=args.seed, verbose=1)
    model.learn(total_timesteps=args.timesteps)
    train_env.close()
    args.save.parent.mkdir(parents=True, exist_ok=True)
    model.save(args.save)
    print(f"model saved to {args.save}")

    policy, baseline = mean_delays(model, options, args.measure_seconds, args.seed + 1)
    print(f"mean delay over {args.measure_seconds:g} s: PPO {policy:.1f} s, max-pressure {baseline:.1f} s")

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
