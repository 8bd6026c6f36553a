"""Every output a user reads, from one tree of the code: what a speed change must leave equal, file for file.

``python harness/bench/outputs.py write DIR [--tree TREE]`` runs a fixed set of runs with the code of ``TREE``
(default: the tree this file is in; another clone or worktree, read only, for the code before a change), each in a
fresh process, and writes their outputs under DIR with ``manifest.json``: every file's SHA-256 after taking out what
the wall clock stamps (an event record's ``wall_ns``; the summary's wall time and internal latencies,
:mod:`tests.hils.run.same_seed`'s rule; a fault report's wall seconds; SUMO's date in its outputs' header) and
where the tree and the outputs lie. ``python harness/bench/outputs.py compare A B``
says how many outputs the two manifests hold and names every one that differs or is missing from either (the paths of
the Python environment it runs in taken out too: both sides are written by one).

It is run by path, not as a module, so that it runs the code of a tree that does not hold it.

The runs: the default hour (four-leg, max-pressure), the corridor, the coordinated four-leg city hour and that config
actuated, RESCO grid4x4 and cologne8 (300 s, max-pressure and actuated), the fault suite at seeds 1, 1001 and 2002
(every scenario's event log, a preempted controller among them), and seeded episodes of the PettingZoo environment on
RESCO grid4x4 and of the gymnasium one (every observation, reward, termination and info, and the event log).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[2]

#: name -> arguments of `hils run` (each run a fresh process, its folder under DIR/name).
RUNS: dict[str, list[str]] = {
    "default-hour": [],
    "corridor": ["--scenario", "corridor", "--duration", "900"],
    "city-coordinated": ["--config", "hils/data/four_leg_city.toml", "--agent", "coordinated"],
    "city-actuated": ["--config", "hils/data/four_leg_city.toml", "--agent", "actuated", "--duration", "900"],
    **{f"{name}-{agent}": ["--scenario", f"resco:{name}", "--agent", agent, "--duration", "300"]
       for name in ("grid4x4", "cologne8") for agent in ("max-pressure", "actuated")},
}
FAULT_SEEDS = "1,1001,2002"
TREE_FILE = "tree.txt"  # the tree whose code wrote the outputs

#: An episode of an environment, as a program run in the tree: it prints one JSON document of everything it gave.
EPISODES = {
    "pettingzoo-grid4x4": """
import hils.envs
env = hils.envs.parallel_env(scenario="resco:grid4x4", action_type="selection", episode_length=600.0)
out = []
obs, infos = env.reset(seed=3)
for agent in env.possible_agents:
    env.action_space(agent).seed(3)
out.append([obs, infos])
while env.agents:
    out.append(env.step({agent: env.action_space(agent).sample() for agent in env.agents}))
records = env.testbed.records
env.close()
""",
    "gymnasium-four-leg": """
import gymnasium as gym
import hils.envs
env = gym.make("hils/Intersection-v1", action_type="selection", episode_length=900.0)
out = []
obs, info = env.reset(seed=5)
env.action_space.seed(5)
out.append([obs, info])
done = False
while not done:
    step = env.step(env.action_space.sample())
    out.append(step)
    done = step[2] or step[3]
records = env.unwrapped.testbed.records
env.close()
""",
}
DUMP = """
import json, sys
import numpy as np
def plain(v):
    if isinstance(v, np.ndarray):
        return {"dtype": str(v.dtype), "shape": list(v.shape), "values": v.tolist()}
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, (set, frozenset)):
        return sorted(v)
    return repr(v)
print(json.dumps({"steps": out, "records": [{k: v for k, v in r.items() if k != "wall_ns"} for r in records]},
                 default=plain, sort_keys=True))
"""

WALL_CLOCK_FIGURES = frozenset({"wall_time_s", "internal_latency_ms", "wall_s"})


def _python(tree: Path, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONHASHSEED": "0"}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, check=False)


def write(out: Path, tree: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    failed = []
    for name, args in RUNS.items():
        print(f"run {name}", flush=True)
        done = _python(tree, ["-m", "hils", "run", *args, "--no-progress", "--out", str(out / name)], tree)
        if done.returncode != 0:
            failed.append(f"{name}: {done.stderr.strip()[-400:]}")
    print("faults", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        done = _python(tree, ["-m", "hils", "faults", "run", "--seeds", FAULT_SEEDS, "--no-progress",
                              "--log-dir", str(out / "faults" / "logs"), "--out", str(out / "faults")], Path(tmp))
    if done.returncode not in (0, 1):
        failed.append(f"faults: {done.stderr.strip()[-400:]}")
    for name, program in EPISODES.items():
        print(f"episode {name}", flush=True)
        done = _python(tree, ["-c", program + DUMP], tree)
        if done.returncode != 0:
            failed.append(f"{name}: {done.stderr.strip()[-400:]}")
            continue
        (out / f"{name}.json").write_text(done.stdout, encoding="utf-8")
    (out / TREE_FILE).write_text(str(tree), encoding="utf-8")
    manifest = digests(out)
    print(f"{len(manifest)} outputs in {out}")
    for line in failed:
        print(f"FAILED {line}", file=sys.stderr)
    return 1 if failed else 0


def digests(out: Path) -> dict[str, str]:
    """Every output's SHA-256 (by its path under ``out``), written to ``out/manifest.json`` too."""
    tree = (out / TREE_FILE).read_text(encoding="utf-8")
    # the environment's packages (RESCO's networks among them) first: it may lie inside a tree, and both sides ran it
    places = {sys.prefix: "PYTHON", tree: "TREE", str(out): "OUT"}
    manifest = {str(p.relative_to(out)): _digest(p, places) for p in sorted(out.rglob("*"))
                if p.is_file() and p.name not in ("manifest.json", TREE_FILE)}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True), encoding="utf-8")
    return manifest


def _digest(path: Path, places: dict[str, str]) -> str:
    """The file's SHA-256 after taking out what the wall clock stamps and where the tree and the outputs lie (a
    config's source path, SUMO's header)."""
    data = path.read_bytes()
    for place, name in places.items():
        data = data.replace(place.encode(), name.encode())
    if path.suffix == ".xml":  # SUMO's header comment: when it was generated
        data = b"\n".join(line for line in data.splitlines() if not line.startswith(b"<!-- generated on"))
    if path.suffix == ".jsonl":
        # the keys in the order they were written: the order is the file's too
        data = b"".join(json.dumps({k: v for k, v in json.loads(line).items() if k != "wall_ns"}).encode() + b"\n"
                        for line in data.splitlines() if line.strip())
    elif path.suffix == ".json":
        data = json.dumps(_without_wall(json.loads(data))).encode()
    elif path.suffix == ".md" and path.parent.name == "faults":  # its table's last column is each run's wall time
        data = b"\n".join(line.rstrip(b"|").rsplit(b"|", 1)[0] if line.startswith(b"|") else line
                          for line in data.splitlines() if b"of wall time" not in line)
    return hashlib.sha256(data).hexdigest()


def _without_wall(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_wall(v) for k, v in value.items() if k not in WALL_CLOCK_FIGURES}
    if isinstance(value, list):
        return [_without_wall(v) for v in value]
    return value


def compare(a: Path, b: Path) -> int:
    first, second = digests(a.resolve()), digests(b.resolve())
    differ = sorted(k for k in first.keys() & second.keys() if first[k] != second[k])
    only = sorted(first.keys() ^ second.keys())
    same = len(first.keys() & second.keys()) - len(differ)
    print(f"{same} of {len(first.keys() | second.keys())} outputs identical")
    for k in differ:
        print(f"differs: {k}")
    for k in only:
        print(f"only in {'the first' if k in first else 'the second'}: {k}")
    return 0 if not differ and not only else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python harness/bench/outputs.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    w = sub.add_parser("write", help="run everything with one tree's code, write the outputs and their manifest")
    w.add_argument("out", type=Path)
    w.add_argument("--tree", type=Path, default=HERE, help="the tree whose code runs (default: this one)")
    c = sub.add_parser("compare", help="compare two folders written by `write`")
    c.add_argument("first", type=Path)
    c.add_argument("second", type=Path)
    args = parser.parse_args(argv)
    if args.command == "write":
        return write(args.out.resolve(), args.tree.resolve())
    return compare(args.first, args.second)


if __name__ == "__main__":
    sys.exit(main())
