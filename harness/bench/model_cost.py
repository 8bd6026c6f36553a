"""What the controller model costs: its instructions per controller-hour, counted by callgrind on a replay.

A run's controllers are driven by their inputs (control SETs, detectors) and by the clock (steps, quiet time
skipped). ``record`` runs RESCO grid4x4 (max-pressure, SUMO, seed 0) and writes every call the run made on each
controller from outside, in order (a call the controller makes on itself inside another, a step's own skip of a
quiet tick, the replay makes again by making the outer one); ``count`` replays them on fresh controllers (with
their data loggers, as the run had them), in a process of its own under ``valgrind --tool=callgrind`` twice, once
making the calls and once only reading them, so that the difference is the model's own work: start-up, SUMO and
the middleware counted out. Instructions, unlike seconds, do not change with what else the machine is doing. The
recording is the tree's own (a faster model may be asked fewer times), the traffic the same: a run whose outputs
are identical (:mod:`harness.bench.model_outputs`).

Usage (``PYTHONHASHSEED=0``; ``PYTHONPATH`` picks the tree measured)::

    python harness/bench/model_cost.py record calls.pickle --duration 300
    python harness/bench/model_cost.py count calls.pickle
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

#: The controller's methods a run calls: the inputs, the clock and quiet time.
CALLS = ("set_control", "set_timing", "set_backup_time", "set_pattern_control", "set_preempt_control", "set_max2",
         "set_actuations", "set_ped_actuations", "reset", "step", "skip", "quiet_ticks", "advance")


def record(out: Path, duration: float, scenario: str) -> None:
    from emulator.model.controller import Controller
    from hils.protocol.config import IntersectionConfig
    from hils.run.testbed import Testbed

    configs: list[IntersectionConfig] = []
    calls: list[tuple[int, str, tuple]] = []
    units: dict[int, int] = {}
    made_units: list[Controller] = []
    made = Controller.__init__

    def init(self, config, **kw):
        units[id(self)] = len(configs)
        configs.append(config)
        made_units.append(self)
        made(self, config, **kw)

    inside: set[int] = set()  # the controllers in one of these calls now: what it calls itself is not recorded

    def wrap(name: str):
        method = getattr(Controller, name)

        def recorded(self, *args):
            if id(self) not in units or id(self) in inside:
                return method(self, *args)  # a call the replay makes again by making the outer one
            calls.append((units[id(self)], name, args))
            inside.add(id(self))
            try:
                return method(self, *args)
            finally:
                inside.discard(id(self))
        return recorded

    Controller.__init__ = init
    for name in CALLS:
        setattr(Controller, name, wrap(name))
    with Testbed(scenario=scenario, sumo=True, seed=0, duration=duration) as tb:
        tb.run()
    with out.open("wb") as f:
        pickle.dump({"scenario": scenario, "duration": duration, "configs": configs, "calls": calls,
                     "logger": any(u.recorder is not None for u in made_units)}, f)
    print(f"{len(configs)} controllers, {len(calls)} calls over {duration:g} s of {scenario}")


def replay(path: Path, act: bool) -> None:
    from emulator.model.controller import Controller
    from emulator.model.datalogger import DataLogger

    with path.open("rb") as f:
        doc = pickle.load(f)
    units = [Controller(config) for config in doc["configs"]]
    if doc["logger"]:
        for unit in units:
            DataLogger(unit)
    for unit, name, args in doc["calls"]:
        if act:
            getattr(units[unit], name)(*args)


def count(path: Path) -> None:
    counted = {}
    for act in (True, False):
        done = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable,
                               __file__, "replay", str(path), *(["--act"] if act else [])],
                              capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"})
        line = next(x for x in done.stderr.splitlines() if "Collected" in x)
        counted[act] = int(line.split()[-1])
    with path.open("rb") as f:
        doc = pickle.load(f)
    hours = len(doc["configs"]) * doc["duration"] / 3600
    model = counted[True] - counted[False]
    what = "controller model" + (" with its data logger" if doc["logger"] else "")
    print(f"{what}: {model / 1e6:,.1f} M instructions over {hours:g} controller-hours ({doc['scenario']}, "
          f"{doc['duration']:g} s): {model / hours / 1e6:,.1f} M per controller-hour")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python harness/bench/model_cost.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    recording = commands.add_parser("record", help="run the scenario and write its controllers' calls")
    recording.add_argument("calls", type=Path)
    recording.add_argument("--duration", type=float, default=300.0, help="simulated seconds (300)")
    recording.add_argument("--scenario", default="resco:grid4x4", help="scenario (resco:grid4x4)")
    counting = commands.add_parser("count", help="count the replay's instructions under callgrind")
    counting.add_argument("calls", type=Path)
    replaying = commands.add_parser("replay", help="replay the calls (what count runs under callgrind)")
    replaying.add_argument("calls", type=Path)
    replaying.add_argument("--act", action="store_true", help="make the calls (without: only read them)")
    args = parser.parse_args(argv)
    if args.command == "record":
        record(args.calls, args.duration, args.scenario)
    elif args.command == "count":
        count(args.calls)
    else:
        replay(args.calls, args.act)
    return 0


if __name__ == "__main__":
    sys.exit(main())
