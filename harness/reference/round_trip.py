"""The round trip of `hils replay`: logs the emulator makes under random configs, inferred and replayed in virtual
time; a benchmark that prints the share of configs replayed at >= 99 % (and writes it under reports/).

A config is the shipped four-leg (:file:`hils/data/four_leg.toml`: 8 phases, 2 rings, 2 barriers, a detector and a
push button per phase) with walks on its throughs and, drawn from a seed (:func:`random_config`), what the
controller model has today and a log shows the effects of: the passage time, max or min recall on some phases,
a detector delay, extension or carryover on some detectors, dual entry on some throughs, conditional service or
Naztec's backing (``backup_prevent = false``) on some phases, pedestrian recycle on some throughs, the leading left of
ring 1 lagging (ring order 2, 1, 3, 4), and coordination on the shipped plan (70 s) at any offset (an offset not at the
lead green: the local zero anywhere in the cycle). The log (:func:`emulator_log`) is the model's own under random
detector and push-button inputs, then a minute without.
:func:`round_trip` infers a config from the log (:func:`harness.reference.field_log.infer`), replays the log's
inputs into the model under it (:mod:`harness.reference.replay_virtual`) and gives the whole-log match
(:mod:`harness.reference.replay_match`).

``python -m harness.reference.round_trip --configs 50`` prints each config's match and features, for a config below
99 % the first of its log's events the replay missed (:func:`first_miss`: where the replay parts from the log, where
to look for what the inference got wrong), and the share at >= 99 %, and writes ``reports/replay/round_trip.json``.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from harness.reference import field_log, replay_virtual
from harness.reference.hires_file import FieldLogError, Row
from harness.reference.replay_match import JUDGED, Logged, match_table, overall
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import EventCode as E

BASE = Path(config_mod.__file__).parents[1] / "data" / "four_leg.toml"
PLAN = """
[coordination]
pattern = 1
force_off = "fixed"
offset_reference = "lead_green"
correction = "shortway"

[[coordination.patterns]]
number = 1
cycle = 70
offset = {offset}
coord_phases = [2, 6]
splits = {{ 1 = 14, 2 = 28, 3 = 12, 4 = 16, 5 = 12, 6 = 30, 7 = 13, 8 = 15 }}
"""


#: Detector timers drawn (s): delays short enough that the round trip's actuations (0.7 s on average) often last them.
TIMERS = {"delay": (0.3, 0.5, 1.0), "extend": (0.5, 1.0, 2.0), "carryover": (0.5, 1.0)}


@dataclass(frozen=True, slots=True)
class Drawn:
    """A random config's text and the features drawn into it."""

    toml: str
    features: tuple[str, ...]


def random_config(rng: random.Random, *, recalls: Sequence[str] = ("min", "max"), dual_entry: bool = True,
                  lag: bool = True, coordination: bool = True, sequencing: bool = True,
                  detector_timers: bool = True) -> Drawn:
    """The four-leg with walks on its throughs and features drawn from ``rng`` (see the header); ``recalls``,
    ``dual_entry``, ``lag``, ``coordination``, ``sequencing`` (backing options, pedestrian recycle) and
    ``detector_timers`` say which may be drawn."""
    text = BASE.read_text()
    features = []
    passage = rng.choice((1.0, 1.5, 2.0, 3.0))
    text = text.replace("[timing]            # shared by every phase, as in the paper",
                        f"[timing]\npassage = {passage}")
    features.append(f"passage {passage:g}")
    for p in range(1, 9):
        options = ["walk = 4, ped_clear = 5"] if p % 2 == 0 else []
        if recalls and rng.random() < 0.15:
            kind = rng.choice(tuple(recalls))
            options.append(f'recall = "{kind}"')
            features.append(f"{kind} recall {p}")
        if dual_entry and p % 2 == 0 and rng.random() < 0.1:
            options.append("dual_entry = true")
            features.append(f"dual entry {p}")
        if sequencing and rng.random() < 0.1:
            option = rng.choice(("conditional_service = true", "backup_prevent = false"))
            options.append(option)
            features.append(f"{'conditional service' if option.startswith('conditional') else 'backing'} {p}")
        if sequencing and p % 2 == 0 and rng.random() < 0.15:
            options.append("ped_recycle = true")
            features.append(f"ped recycle {p}")
        if options:
            text = text.replace(f"\n{p} = {{ approach", f"\n{p} = {{ {', '.join(options)}, approach", 1)
    if lag and rng.random() < 0.5:
        text = text.replace("rings = [[1, 2, 3, 4], [5, 6, 7, 8]]", "rings = [[2, 1, 3, 4], [5, 6, 7, 8]]")
        features.append("1 lags 2")
    text = text[:text.index("[coordination]")]
    if detector_timers:
        table = []
        for p in range(1, 9):
            timers = {name: rng.choice(values) for name, values in TIMERS.items() if rng.random() < 0.15}
            table.append(f"{p} = {{ phase = {p}" + "".join(f", {k} = {v:g}" for k, v in timers.items()) + " }")
            features += [f"{k} {v:g} s on {p}" for k, v in timers.items()]
        text += "[detectors]\n" + "\n".join(table) + "\n\n"
    if coordination and rng.random() < 0.5:
        offset = rng.randrange(70)
        text += PLAN.format(offset=offset)
        features.append(f"coordinated, offset {offset}")
    return Drawn(text, tuple(features))


def emulator_log(cfg: IntersectionConfig, seconds: int, seed: int, start: datetime = datetime(2024, 5, 1, 7),
                 arrivals: float = 0.012) -> list[Row]:
    """The emulator's own log under ``cfg``: ``seconds`` of random vehicle detector and push-button inputs on the
    detectors the config has (a vehicle arriving at each detector with probability ``arrivals`` a tick), then a
    minute without any."""
    c = Controller(cfg, start=start)
    log = DataLogger(c)
    rng = random.Random(seed)
    on: set[int] = set()
    pushed: set[int] = set()
    for k in range((seconds + 60) * 10):
        if k < seconds * 10:
            on = {d for d in cfg.detectors
                  if (d in on and rng.random() > 0.15) or (d not in on and rng.random() < arrivals)}
            pushed = {d for d in cfg.ped_detectors if (d in pushed and rng.random() > 0.3) or rng.random() < 0.003}
        else:
            on, pushed = set(), set()
        c.set_actuations(on)
        c.set_ped_actuations(pushed)
        c.step()
    return [Row(e.time, e.code, e.parameter) for e in log.events()]


@dataclass(frozen=True, slots=True)
class Trip:
    """A round trip's whole-log match (None: the log was refused) and, below 100 %, the first of the log's judged
    events the replay missed, said as where to look."""

    share: float | None
    first_miss: str = ""


def round_trip(drawn: Drawn, seconds: int, seed: int) -> Trip:
    """The whole-log match of the emulator's log under ``drawn`` replayed into the config inferred from it."""
    rows = emulator_log(config_mod.parse(drawn.toml, "round_trip.toml"), seconds, seed)
    try:
        inferred = field_log.infer(rows).config()
    except FieldLogError as e:
        return Trip(None, str(e))
    ran = replay_virtual.run(rows, inferred)
    return Trip(overall(match_table(rows, ran.events)), first_miss(rows, ran.events))


def first_miss(rows: Sequence[Row], bench: Sequence[Logged]) -> str:
    """The earliest judged event of ``rows`` that ``bench`` did not log within 1 s (each bench event matched once,
    nearest first, as :func:`harness.reference.replay_match.match_table` matches), with what the bench logged of that
    type and parameter nearest to it; empty when there is none. A replay parts from its log there first."""
    free: dict[tuple[int, int], list] = {}
    for e in bench:
        if e.code in JUDGED:
            free.setdefault((e.code, e.parameter), []).append(e.time)
    tolerance = timedelta(seconds=1)
    for r in sorted((r for r in rows if r.code in JUDGED), key=lambda r: r.time):
        pool = free.get((r.code, r.parameter), [])
        near = [k for k, t in enumerate(pool) if abs(t - r.time) <= tolerance]
        if near:
            del pool[min(near, key=lambda k: abs(pool[k] - r.time))]
            continue
        nearest = min(pool, key=lambda t: abs(t - r.time), default=None)
        said = "none" if nearest is None else f"{(nearest - r.time).total_seconds():+.1f} s"
        return (f"first missed: event {r.code} ({E(r.code).name.lower().replace('_', ' ')}) of {r.parameter} at "
                f"{(r.time - rows[0].time).total_seconds():.1f} s (the replay's nearest: {said})")
    return ""


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.reference.round_trip", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", type=int, default=50, help="random configs (50)")
    parser.add_argument("--seconds", type=int, default=600, help="seconds of random inputs per log (600)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the configs drawn (1)")
    parser.add_argument("--out", type=Path, default=Path("reports/replay"), help="folder of round_trip.json")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    results = []
    wall = time.perf_counter()
    for k in range(args.configs):
        drawn = random_config(rng)
        trip = round_trip(drawn, args.seconds, seed=k)
        share = trip.share
        results.append({"match_percent": share, "features": list(drawn.features), "first_miss": trip.first_miss})
        print(f"{k + 1:>4}/{args.configs}  {'refused' if share is None else f'{share:5.1f} %'}  "
              f"{', '.join(drawn.features)}" + (f"\n{'':>12}{trip.first_miss}" if share is None or share < 99 else ""),
              flush=True)
    good = sum(1 for r in results if r["match_percent"] is not None and r["match_percent"] >= 99)
    print(f"replayed at >= 99 %: {good} of {args.configs} configs ({100 * good / args.configs:.0f} %), "
          f"{time.perf_counter() - wall:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "round_trip.json").write_text(json.dumps({"seed": args.seed, "seconds": args.seconds,
                                                          "at_least_99": good, "configs": args.configs,
                                                          "results": results}, indent=1))
    print(f"Results in {args.out / 'round_trip.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
