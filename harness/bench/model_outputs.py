"""Before and after, byte for byte: the outputs of the runs the controller model decides, from any source tree.

A change meant to leave behaviour as it was (a refactor of the controller, a faster path) is proven so by running
the same runs on the tree before it and on the tree after it and comparing every output. Each run is a process of
its own started with ``PYTHONPATH=TREE`` (so the tree's ``hils``, ``emulator`` and ``harness`` are the ones
imported), in the same scratch folder both times (paths written into outputs agree), and only through what both
trees offer: the ``hils`` command and the public ``Testbed`` and PettingZoo API. What the wall clock stamps is taken
out, as tests/hils/run/same_seed.py takes it out; everything else is kept and compared as bytes:

- each event log (JSON Lines) less every record's ``wall_ns``;
- each summary.json and faults.json less the figures measured on the wall clock (wall time, internal latencies);
- each hi-res log (hires.parquet) as CSV, each hi-res journal and every other CSV as written;
- every SVG picture (matplotlib's ids salted and its date fixed, so that two runs draw the same bytes).

The runs: the default hour (``hils run``), the corridor hour, the city four-leg hour under its coordinated plan, a
preempted run (the city four-leg, actuated, three ambulances from the east), RESCO grid4x4 and cologne8 for 300 s
with max-pressure and with the actuated baseline, the fault suite at seeds 1, 1001 and 2002, and a seeded PettingZoo
episode of the corridor.

Usage::

    python -m harness.bench.model_outputs run --tree /work/main --out /tmp/before
    python -m harness.bench.model_outputs run --out /tmp/after          # this tree
    python -m harness.bench.model_outputs compare /tmp/before /tmp/after
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

WALL_CLOCK_FIGURES = frozenset({"wall_ns", "wall_time_s", "internal_latency_ms", "wall_s", "elapsed_s"})
HERE = Path(__file__).resolve().parents[2]

# In-process runs, as a user of the public API writes them; each writes its outputs into the folder argv[1].
PREEMPTED = """
import json, sys
from pathlib import Path
import libsumo
from hils import Testbed
from hils.protocol.config import load
from hils.sim.network import data_path
from hils.report import jsonout, summary

def ambulances(tb):
    libsumo.route.add("east_west", ["E2C", "C2W"])
    libsumo.vehicletype.copy("DEFAULT_VEHTYPE", "ambulance")
    for depart in (20, 200, 420):
        libsumo.vehicle.add(f"ambulance{depart}", "east_west", typeID="ambulance", depart=str(depart))

out = Path(sys.argv[1])
with Testbed(load(data_path("four_leg_city.toml")), agent="actuated", sumo=True, seed=4, duration=600.0,
             on_reset=ambulances) as tb:
    tb.reset()
    tb.run()
s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()}, traffic=tb.traffic,
                      wall_s=tb.wall_s)
(out / "summary.json").write_text(jsonout.dumps(s))
with (out / "events.jsonl").open("w") as f:
    for r in tb.records:
        f.write(jsonout.dumps(r, indent=None) + "\\n")
(out / "hires.json").write_text(jsonout.dumps({str(k): v for k, v in tb.hires().items()}))
"""

PETTINGZOO = """
import json, sys
from pathlib import Path
import numpy as np
import hils.envs
from hils.report import jsonout

out = Path(sys.argv[1])
env = hils.envs.parallel_env("corridor")
steps = []
observations, infos = env.reset(seed=7)
rng = np.random.default_rng(7)
for agent in env.possible_agents:
    env.action_space(agent).seed(7)
for _ in range(40):
    if not env.agents:
        break
    actions = {a: env.action_space(a).sample() for a in env.agents if infos[a].get("due", True)}
    observations, rewards, terminations, truncations, infos = env.step(actions)
    steps.append({"actions": {a: np.asarray(v).tolist() for a, v in actions.items()},
                  "observations": {a: np.asarray(v).tolist() for a, v in observations.items()},
                  "rewards": rewards, "truncations": truncations,
                  "infos": {a: {k: v for k, v in i.items() if not k.startswith("wall")} for a, i in infos.items()}})
tb = env.testbed
with (out / "events.jsonl").open("w") as f:
    for r in tb.records:
        f.write(jsonout.dumps(r, indent=None) + "\\n")
(out / "episode.json").write_text(jsonout.dumps(steps))
(out / "hires.json").write_text(jsonout.dumps({str(k): v for k, v in tb.hires().items()}))
env.close()
"""


def cli(*arguments: str) -> Callable[[Path, Path], list[str]]:
    """A ``hils run`` of these arguments into the scratch folder."""
    def command(tree: Path, scratch: Path) -> list[str]:
        return [sys.executable, "-m", "hils", "run", "--no-progress", "--seed", "0", "--out", str(scratch),
                *(str(tree / a) if a.startswith("hils/data/") else a for a in arguments)]
    return command


def script(code: str) -> Callable[[Path, Path], list[str]]:
    def command(tree: Path, scratch: Path) -> list[str]:
        return [sys.executable, "-c", code, str(scratch)]
    return command


def faults(tree: Path, scratch: Path) -> list[str]:
    return [sys.executable, "-m", "hils", "faults", "run", "--no-progress", "--seeds", "1,1001,2002", "--out",
            str(scratch), "--log-dir", str(scratch / "logs"), str(tree / "fault_scenarios")]


CASES: dict[str, Callable[[Path, Path], list[str]]] = {
    "default-hour": cli(),
    "corridor-hour": cli("--scenario", "corridor"),
    "city-coordinated-hour": cli("--config", "hils/data/four_leg_city.toml", "--agent", "coordinated"),
    "preempted": script(PREEMPTED),
    "grid4x4-max-pressure": cli("--scenario", "resco:grid4x4", "--duration", "300"),
    "grid4x4-actuated": cli("--scenario", "resco:grid4x4", "--agent", "actuated", "--duration", "300"),
    "cologne8-max-pressure": cli("--scenario", "resco:cologne8", "--duration", "300"),
    "cologne8-actuated": cli("--scenario", "resco:cologne8", "--agent", "actuated", "--duration", "300"),
    "faults": faults,
    "pettingzoo": script(PETTINGZOO),
}


def without_wall_clock(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: without_wall_clock(v) for k, v in value.items() if k not in WALL_CLOCK_FIGURES}
    if isinstance(value, list):
        return [without_wall_clock(v) for v in value]
    return value


def normalise(source: Path, target: Path, tree: Path) -> list[Path]:
    """The outputs of one run, as compared, from its folder into ``target``; the files written. The environment's
    path (where RESCO's networks are installed) is written ``VENV``, the tree's own (a fault scenario's) ``TREE``."""
    written = []
    for path in sorted(p for p in source.rglob("*") if p.is_file()):
        out = target / path.relative_to(source)
        out.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix in (".jsonl", ".json"):
            text = path.read_text(encoding="utf-8").replace(sys.prefix, "VENV").replace(str(tree), "TREE")
            if path.suffix == ".jsonl":
                text = "".join(json.dumps(without_wall_clock(json.loads(line))) + "\n" for line in text.splitlines())
            else:
                text = json.dumps(without_wall_clock(json.loads(text)), indent=1)
            out.write_text(text, encoding="utf-8")
        elif path.suffix == ".parquet":
            import pyarrow.parquet as pq

            out = out.with_suffix(".parquet.csv")
            pq.read_table(path).to_pandas().to_csv(out, index=False)
        elif path.suffix in (".csv", ".svg", ".toml"):
            shutil.copyfile(path, out)
        else:
            continue  # a picture or report made of the figures above (faults.md: wall times; png: renderer bytes)
        written.append(out)
    return written


def run(tree: Path, out: Path, cases: Sequence[str]) -> None:
    scratch = Path(tempfile.gettempdir()) / "hils-model-outputs"
    config = scratch / "mplconfig"
    config.mkdir(parents=True, exist_ok=True)
    (config / "matplotlibrc").write_text("svg.hashsalt: hils\n")
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONHASHSEED": "0", "MPLCONFIGDIR": str(config),
           "SOURCE_DATE_EPOCH": "0", "PYTHONPYCACHEPREFIX": str(scratch / "pycache" / tree.name)}
    for case in cases:
        folder = scratch / "run" / case
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        started = time.monotonic()
        done = subprocess.run(CASES[case](tree, folder), env=env, cwd=scratch, capture_output=True, text=True)
        if done.returncode not in (0, 1) or not any(folder.iterdir()):
            sys.exit(f"{case}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
        shutil.rmtree(out / case, ignore_errors=True)
        files = normalise(folder, out / case, tree)
        print(f"{case}: {len(files)} outputs in {time.monotonic() - started:.0f} s (exit {done.returncode})",
              flush=True)


def compare(before: Path, after: Path) -> int:
    names = sorted({p.relative_to(before) for p in before.rglob("*") if p.is_file()}
                   | {p.relative_to(after) for p in after.rglob("*") if p.is_file()})
    differ = [n for n in names if not ((before / n).is_file() and (after / n).is_file()
                                       and filecmp.cmp(before / n, after / n, shallow=False))]
    for n in differ:
        print(f"differs: {n}")
    print(f"{len(names) - len(differ)} of {len(names)} outputs identical")
    return 1 if differ else 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.bench.model_outputs", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    runs = commands.add_parser("run", help="run the cases on a tree and keep their outputs, normalised")
    runs.add_argument("--tree", type=Path, default=HERE, help="source tree to run (default: this one)")
    runs.add_argument("--out", type=Path, required=True, help="folder of the normalised outputs")
    runs.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of: {', '.join(CASES)}")
    compared = commands.add_parser("compare", help="compare two folders of outputs byte for byte")
    compared.add_argument("before", type=Path)
    compared.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    if args.command == "compare":
        return compare(args.before, args.after)
    unknown = set(args.cases.split(",")) - set(CASES)
    if unknown:
        parser.error(f"--cases: unknown {', '.join(sorted(unknown))}; allowed: {', '.join(CASES)}")
    run(args.tree.resolve(), args.out.resolve(), args.cases.split(","))
    return 0


if __name__ == "__main__":
    sys.exit(main())
