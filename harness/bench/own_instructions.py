"""hils' own work in instructions, which a busy machine does not change: RESCO grid4x4's sixteen controllers without
SUMO (the random agent at every decision, measure off as the environments run), under valgrind's callgrind.

``python harness/bench/own_instructions.py [--tree TREE] [--seconds 600] [--warm 60]`` runs the probe for ``seconds``
and for ``warm`` simulated seconds, each in a fresh process (``PYTHONHASHSEED=0``, address randomisation off), with
the code of ``TREE`` (default: the tree this file is in; another worktree or clone for the code before a change), and
prints the instructions of the difference: what ``seconds - warm`` simulated seconds cost, start-up counted out, and
per controller-hour. It is run by path, so that it runs the code of a tree that does not hold it.
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


def instructions(tree: Path, seconds: float) -> int:
    """Instructions of one probe process of ``seconds`` simulated seconds, as callgrind counts them."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONHASHSEED": "0"}
    command = ["setarch", platform.machine(), "-R", "valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
               sys.executable, "-c", PROBE, str(seconds)]
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
    args = parser.parse_args(argv)
    tree = args.tree.resolve()
    long, short = instructions(tree, args.seconds), instructions(tree, args.warm)
    hours = (args.seconds - args.warm) * CONTROLLERS / 3600.0
    print(f"{tree}: {long:,} instructions for {args.seconds:g} s, {short:,} for {args.warm:g} s: "
          f"{long - short:,} for {args.seconds - args.warm:g} s of {CONTROLLERS} controllers, "
          f"{(long - short) / hours:,.0f} per controller-hour")
    return 0


if __name__ == "__main__":
    sys.exit(main())
