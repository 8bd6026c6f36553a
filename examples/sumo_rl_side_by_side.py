"""One piece of sumo-rl code, run on sumo-rl and on hils (``docs/sumo-rl.md``): only the module differs.

    python examples/sumo_rl_side_by_side.py [--seconds 3600] [--seeds 0-2]

The same single-agent loop, a fixed cycle (each green phase for six decisions, 30 s, then the next), on sumo-rl's
single-intersection network, its own demand, with the same options (yellow 3 s: hils refuses sumo-rl's default of
2 s, below NTCIP 1202's least). sumo-rl switches SUMO's light itself (through TraCI, as it runs by default); hils
shows what a NEMA controller derived from the light's program shows, commanded through the middleware. The table
gives, per side and seed, the decisions, the means over the episode's steps of sumo-rl's ``system_mean_waiting_time``
and ``system_total_stopped``, and the reward summed (sumo-rl's default, ``diff-waiting-time``). (Speed is measured
by ``hils bench``, against sumo-rl through libsumo; sumo-rl here runs as it does by default, through TraCI.)
"""

from __future__ import annotations

import argparse
import os
from types import ModuleType
from typing import Any

import sumo

from hils.protocol.resco import networks_dir

NETS = networks_dir().parent  # the installed sumo-rl's networks
OPTIONS = {"net_file": str(NETS / "single-intersection" / "single-intersection.net.xml"),
           "route_file": str(NETS / "single-intersection" / "single-intersection.rou.xml"),
           "single_agent": True, "delta_time": 5, "yellow_time": 3, "min_green": 5, "max_green": 50,
           "sumo_warnings": False, "additional_sumo_cmd": "--no-step-log"}


def episode(sumo_rl: ModuleType, seed: int, seconds: int) -> dict[str, Any]:
    """The fixed cycle for ``seconds`` on ``sumo_rl``'s SumoEnvironment: the code a sumo-rl user writes."""
    env = sumo_rl.SumoEnvironment(**OPTIONS, num_seconds=seconds, sumo_seed=seed)
    env.reset()
    decisions, waiting, stopped, reward, done = 0, 0.0, 0, 0.0, False
    while not done:
        action = (decisions // 6) % env.action_space.n
        _, r, terminated, truncated, info = env.step(action)
        decisions, reward = decisions + 1, reward + r
        waiting, stopped = waiting + info["system_mean_waiting_time"], stopped + info["system_total_stopped"]
        done = terminated or truncated
    env.close()
    return {"decisions": decisions, "waiting": waiting / decisions, "stopped": stopped / decisions, "reward": reward}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=3600, help="simulated seconds per episode (3600)")
    parser.add_argument("--seeds", default="0-2", help="SUMO seeds, FIRST-LAST (0-2)")
    args = parser.parse_args()
    first, _, last = args.seeds.partition("-")
    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)  # sumo-rl looks for SUMO's tools there
    import sumo_rl  # sumo-rl itself: SUMO through TraCI

    import hils.sumo_rl

    print(f"{'side':<8} {'seed':>4} {'decisions':>9} {'mean waiting (s)':>16} {'stopped':>7} {'reward':>8}")
    for seed in range(int(first), int(last or first) + 1):
        for side, module in (("sumo-rl", sumo_rl), ("hils", hils.sumo_rl)):
            row = episode(module, seed, args.seconds)
            print(f"{side:<8} {seed:>4} {row['decisions']:>9} {row['waiting']:>16.2f} {row['stopped']:>7.1f} "
                  f"{row['reward']:>8.2f}")


if __name__ == "__main__":
    main()
