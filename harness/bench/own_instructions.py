"""hils' own work in instructions, which a busy machine does not change: RESCO grid4x4's sixteen controllers without
SUMO (the random agent at every decision, measure off as the environments run), under valgrind's callgrind.

``python harness/bench/own_instructions.py [--tree TREE] [--seconds 600] [--warm 60]`` runs the probe for ``seconds``
and for ``warm`` simulated seconds, each in a fresh process (``PYTHONHASHSEED=0``, address randomisation off), with
the code of ``TREE`` (default: the tree this file is in; another worktree or clone for the code before a change), and
prints the instructions of the difference: what ``seconds - warm`` simulated seconds cost, start-up counted out, and
per controller-hour. It is run by path, so that it runs the code of a tree that does not hold it.

``--env`` runs instead what ``hils bench resco`` runs on its hils side: an episode of the PettingZoo environment on
grid4x4, SUMO in the process, a seeded random policy. SUMO's instructions are among those counted; two trees that give
the same signals give SUMO the same work, so the difference between them is hils' own.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[2]
CONTROLLERS = 16
PROBE = """
import sys
from hils import Testbed
with Testbed(scenario="resco:grid4x4", sumo=False, agent="random", seed=0, duration=float(sys.argv[1]),
             measure=False) as tb:
    tb.reset_all()
    tb.run()
"""

ENV_PROBE = """
import sys
import hils.envs
env = hils.envs.parallel_env(scenario="resco:grid4x4", action_type="selection", episode_length=float(sys.argv[1]))
env.reset(seed=0)
for agent in env.possible_agents:
    env.action_space(agent).seed(0)
while env.agents:
    env.step({agent: env.action_space(agent).sample() for agent in env.agents})
env.close()
"""


def instructions(tree: Path, seconds: float, probe: str = PROBE) -> int:
    """Instructions of one probe process of ``seconds`` simulated seconds, as callgrind counts them."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONHASHSEED": "0"}
    command = ["setarch", platform.machine(), "-R", "valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
               sys.executable, "-c", probe, str(seconds)]
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True, check=False)
    found = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        raise SystemExit(f"own_instructions: valgrind failed ({done.returncode}): {done.stderr.strip()[-300:]}")
    return int(found[1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python harness/bench/own_instructions.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", type=Path, default=HERE, help="the tree whose code runs (default: this one)")
    parser.add_argument("--seconds", type=float, default=600.0, help="simulated seconds of the measured run (600)")
    parser.add_argument("--warm", type=float, default=60.0, help="simulated seconds of the start-up run (60)")
    parser.add_argument("--env", action="store_true",
                        help="run the PettingZoo environment's episode with SUMO, as hils bench resco does")
    args = parser.parse_args(argv)
    tree = args.tree.resolve()
    probe = ENV_PROBE if args.env else PROBE
    long, short = instructions(tree, args.seconds, probe), instructions(tree, args.warm, probe)
    hours = (args.seconds - args.warm) * CONTROLLERS / 3600.0
    print(f"{tree}: {long:,} instructions for {args.seconds:g} s, {short:,} for {args.warm:g} s: "
          f"{long - short:,} for {args.seconds - args.warm:g} s of {CONTROLLERS} controllers, "
          f"{(long - short) / hours:,.0f} per controller-hour")
    return 0


if __name__ == "__main__":
    sys.exit(main())
