"""One side of `hils bench overhead --instructions`, run alone in a process under callgrind.

``python -m harness.bench.overhead_probe hils SECONDS CHANGES`` runs the full loop (the benchmark's run: four-leg,
max-pressure, SUMO, event log to a file) and writes the signal states it showed, step by step, to CHANGES;
``python -m harness.bench.overhead_probe floor SECONDS CHANGES`` replays them on bare libsumo. The benchmark runs
each for the asked duration and for a few seconds, under ``valgrind --tool=callgrind``: the difference of
the two instruction counts is what the simulated time cost, with the process's start-up (imports, SUMO's
start) counted out. Instructions, unlike seconds, do not change with what else the machine is doing.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from harness.bench.overhead import _replay, record_full_loop
from hils.protocol import config as config_mod


def main(argv: list[str]) -> int:
    side, seconds, changes = argv[0], float(argv[1]), Path(argv[2])
    cfg = config_mod.load()
    if side == "hils":
        _wall, shown, _traffic = record_full_loop(cfg, 0, seconds)
        changes.write_text(json.dumps(shown), encoding="utf-8")
    else:
        _replay(cfg, 0, seconds, [tuple(c) for c in json.loads(changes.read_text(encoding="utf-8"))])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
