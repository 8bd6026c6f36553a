"""What `hils replay` costs and what a broken log does to it: benchmarks that print figures.

- ``orders``: the seconds :func:`harness.reference.field_log.infer` takes on a synthetic log whose rings each
  serve N phases in one barrier group (every phase of a ring follows the one before it, ring 2 half a phase behind
  ring 1 so that the group is one), for N from 8 to 16: the service order of a ring is what grows with N.
- ``mutations``: a catalogue of single-field mutations of two real logs (the ``atspm`` package's field log and the
  emulator's own pretimed log, ``hils run --agent fixed-time --no-sumo``), each given to
  ``hils replay LOG --infer-only`` in a process of its own; an outcome is a config (exit 0: the validator took it),
  a refusal of the log (exit 2, one line), a refusal of the inferred config (exit 2, one line naming
  ``inferred.toml``), a crash (a traceback or another exit) or a hang (no answer within the timeout).

- ``day``: what a day of a busy coordinated log costs `hils replay` in virtual time, stage by stage (reading the
  file, inferring the config, replaying the inputs into the model, matching): the ``atspm`` package's two hours
  (controller 1136) laid end to end twelve times, from midnight (445,824 events), in a process of its own.
- ``compare LOG...``: each log's config inferred by the tree in ``--tree`` and by this one, and the lines of the
  two ``inferred.toml`` that differ.

All take ``--tree DIR``: run the hils source tree in DIR instead of this one (for the figures before a change:
``git archive main | tar -x -C DIR``). Results go to ``--out`` (default: a new temporary folder), as JSON.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import pandas as pd

from hils.protocol.hires import EventCode

E = EventCode
START = datetime(2024, 4, 15, 12)
#: Green, yellow and red clearance of every phase of the synthetic log, in tenths.
GREEN, YELLOW, RED = 100, 30, 20


def nema_numbers(ring: int, n: int) -> list[int]:
    """The first ``n`` phase numbers of ``ring`` in NEMA's numbering (ring 1: 1-4, 9-12, ...; ring 2: 5-8, ...)."""
    return [p for p in range(1, 8 * n + 1) if (p - 1) % 8 // 4 == ring - 1][:n]


def synthetic(phases_per_ring: int, cycles: int = 10) -> pd.DataFrame:
    """An ATSPM-layout log of two rings that each serve ``phases_per_ring`` phases in order, one barrier group."""
    rows: list[tuple[datetime, int, int]] = []
    span = GREEN + YELLOW + RED
    for ring, lag in ((1, 0), (2, span // 2)):
        for k in range(cycles * phases_per_ring):
            p = nema_numbers(ring, phases_per_ring)[k % phases_per_ring]
            t0 = lag + k * span
            for code, at in ((E.PHASE_ON, 0), (E.PHASE_BEGIN_GREEN, 0), (E.PHASE_MIN_COMPLETE, 50),
                             (E.PHASE_BEGIN_YELLOW, GREEN), (E.PHASE_END_YELLOW, GREEN + YELLOW),
                             (E.PHASE_BEGIN_RED_CLEARANCE, GREEN + YELLOW), (E.PHASE_END_RED_CLEARANCE, span),
                             (E.PHASE_INACTIVE, span)):
                rows.append((START + timedelta(seconds=(t0 + at) / 10), int(code), p))
    rows.sort()
    return pd.DataFrame({"TimeStamp": [r[0] for r in rows], "DeviceId": 1, "EventId": [r[1] for r in rows],
                         "Parameter": [r[2] for r in rows]})


def _env(tree: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree.resolve())
    return env


# The reader was field_log.load before it had a module of its own: a tree of either age reads the log.
_TIMED = """
import sys, time
from harness.reference import field_log
try:
    from harness.reference.hires_file import load
except ImportError:
    load = field_log.load
rows = load(sys.argv[1])
t = time.perf_counter()
field_log.infer(rows, "synthetic")
print(time.perf_counter() - t)
"""


# Each stage of `hils replay` on one log, timed (a tree of before the replay in virtual time has no such stages).
_STAGES = """
import json, sys, time
from harness.reference import field_log, hires_file, replay_match, replay_virtual
seconds = {}
t = time.perf_counter()
rows = hires_file.load(sys.argv[1]); seconds["read"] = time.perf_counter() - t; t = time.perf_counter()
config = field_log.infer(rows).config(); seconds["infer"] = time.perf_counter() - t; t = time.perf_counter()
ran = replay_virtual.run(rows, config); seconds["replay"] = time.perf_counter() - t; t = time.perf_counter()
table = replay_match.match_table(rows, ran.events)
replay_match.green_table(rows, ran.events); seconds["match"] = time.perf_counter() - t
print(json.dumps({"seconds": seconds, "events": len(rows), "match": replay_match.overall(table)}))
"""


def day_log(path: Path) -> Path:
    """A day of the atspm package's field log: its two hours laid end to end twelve times from midnight."""
    import atspm

    sample = pd.read_parquet(Path(atspm.__file__).parent / "data" / "sample_raw_data.parquet")
    first = sample.TimeStamp.min()
    parts = [sample.assign(TimeStamp=sample.TimeStamp - first + first.normalize() + pd.Timedelta(hours=2 * k))
             for k in range(12)]
    pd.concat(parts, ignore_index=True).to_parquet(path)
    return path


def day(out: Path, tree: Path | None, timeout: float) -> list[dict[str, object]]:
    """Seconds per stage of a replay of a day of log (see the module's header)."""
    log = day_log(out / "day.parquet")
    done = subprocess.run([sys.executable, "-c", _STAGES, str(log)], env=_env(tree), capture_output=True, text=True,
                          timeout=timeout, check=True)
    result = json.loads(done.stdout.splitlines()[-1])
    total = sum(result["seconds"].values())
    print(f"a day of log ({result['events']:,} events; whole-log match {result['match']} %): "
          + ", ".join(f"{k} {v:.1f} s" for k, v in result["seconds"].items()) + f"; total {total:.1f} s", flush=True)
    return [result | {"total": total}]


def orders(phases: Sequence[int], out: Path, tree: Path | None, timeout: float) -> list[dict[str, object]]:
    """Seconds to infer each synthetic log's config (None: not done within ``timeout``)."""
    results = []
    for n in phases:
        path = out / f"synthetic_{n}.parquet"
        synthetic(n).to_parquet(path)
        try:
            done = subprocess.run([sys.executable, "-c", _TIMED, str(path)], env=_env(tree), capture_output=True,
                                  text=True, timeout=timeout, check=True)
            seconds: float | None = round(float(done.stdout.split()[-1]), 3)
        except subprocess.TimeoutExpired:
            seconds = None
        results.append({"phases_per_ring": n, "seconds": seconds})
        print(f"{n:>3} phases per ring: " + (f"{seconds:.3f} s" if seconds is not None else f"> {timeout:g} s"),
              flush=True)
    return results


# --- the mutation catalogue ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Mutation:
    """One change to one field of one row of a base log (or, for ``crafted``, a small log made to break a rule)."""

    name: str
    family: str
    change: Callable[[pd.DataFrame], pd.DataFrame | None]  # None: the base log has no such row
    parquet: bool = False  # written as parquet (a typed column holding a null), not as CSV text


def _cell(code: int, column: str, value: object, nth: int = 5) -> Callable[[pd.DataFrame], pd.DataFrame | None]:
    """Set ``column`` of the ``nth`` row with EventId ``code`` to ``value``."""
    def change(frame: pd.DataFrame) -> pd.DataFrame | None:
        index = frame.index[frame.EventId.astype(str) == str(code)]
        if not len(index):
            return None
        out = frame.copy()
        out.loc[index[min(nth, len(index) - 1)], column] = value
        return out
    return change


def _same_time_as_previous(code: int, parameter: int, after_s: float = 0.0
                           ) -> Callable[[pd.DataFrame], pd.DataFrame]:
    """Move the third ``code``/``parameter`` event to ``after_s`` after the second."""
    def change(frame: pd.DataFrame) -> pd.DataFrame:
        index = frame.index[(frame.EventId.astype(str) == str(code)) & (frame.Parameter.astype(str) == str(parameter))]
        out = frame.copy()
        then = pd.Timestamp(out.loc[index[1], "TimeStamp"]) + pd.Timedelta(seconds=after_s)
        out.loc[index[2], "TimeStamp"] = then.isoformat(sep=" ", timespec="milliseconds")
        return out
    return change


def _shifted(code: int, seconds: float, nth: int = 5) -> Callable[[pd.DataFrame], pd.DataFrame]:
    def change(frame: pd.DataFrame) -> pd.DataFrame:
        index = frame.index[frame.EventId.astype(str) == str(code)]
        out = frame.copy()
        then = pd.Timestamp(out.loc[index[nth], "TimeStamp"]) + pd.Timedelta(seconds=seconds)
        out.loc[index[nth], "TimeStamp"] = then.isoformat(sep=" ", timespec="milliseconds")
        return out
    return change


def _null(column: str, code: int) -> Callable[[pd.DataFrame], pd.DataFrame]:
    """A typed column with one null (what a parquet writer gives for a missing value)."""
    def change(frame: pd.DataFrame) -> pd.DataFrame:
        out = frame.copy()
        out["TimeStamp"] = pd.to_datetime(out.TimeStamp)
        for c in ("DeviceId", "EventId", "Parameter"):
            out[c] = pd.to_numeric(out[c]).astype("Int64")
        index = out.index[out.EventId == code]
        out.loc[index[5], column] = None
        return out
    return change


def _many_lone_phases(frame: pd.DataFrame) -> pd.DataFrame:
    """64 phases that never run beside another: each barrier group needs an unused number for the other ring."""
    rows = []
    for k in range(2 * 64):
        p, t0 = k % 64 + 1, START + timedelta(seconds=15 * k)
        rows += [(t0, int(E.PHASE_BEGIN_GREEN), p), (t0 + timedelta(seconds=10), int(E.PHASE_BEGIN_YELLOW), p),
                 (t0 + timedelta(seconds=13), int(E.PHASE_END_YELLOW), p),
                 (t0 + timedelta(seconds=15), int(E.PHASE_END_RED_CLEARANCE), p)]
    return pd.DataFrame({"TimeStamp": [r[0].isoformat(sep=" ") for r in rows], "DeviceId": "1",
                         "EventId": [str(r[1]) for r in rows], "Parameter": [str(r[2]) for r in rows]})


def _thirteen_phase_ring(frame: pd.DataFrame) -> pd.DataFrame:
    return synthetic(13).astype(str)


def _local_zeros_a_tick_apart(frame: pd.DataFrame) -> pd.DataFrame:
    """Every local zero 0.1 s after the one before (a cycle of 0 s)."""
    out = frame.copy()
    zeros = out.index[(out.EventId == str(int(E.COORD_CYCLE_STATE_CHANGE))) & (out.Parameter == "5")]
    first = pd.Timestamp(out.loc[zeros[0], "TimeStamp"])
    for k, i in enumerate(zeros):
        out.loc[i, "TimeStamp"] = (first + pd.Timedelta(seconds=k / 10)).isoformat(sep=" ", timespec="milliseconds")
    return out


def catalogue(base: str) -> list[Mutation]:
    """The mutations of one base log (``field`` or ``emulator``), by family."""
    green, yellow = int(E.PHASE_BEGIN_GREEN), int(E.PHASE_BEGIN_YELLOW)
    out = [Mutation(f"TimeStamp={v!r}", "a timestamp that is not one", _cell(green, "TimeStamp", v))
           for v in ("", "not a time", "2024-02-30 12:00:00", "2024-04-15 25:00:00", "2024-04-15T12:00:00+02:00",
                     "9999-12-31 23:59:59.9", "1600-01-01 00:00:00", "1713182400", "12:00:00")]
    out += [Mutation(f"EventId={v!r}", "an EventId that is not one", _cell(green, "EventId", v))
            for v in ("", "x", "1.5", "-1", "99999999999", "1e3", "NaN")]
    out += [Mutation(f"Parameter={v!r} of a begin green", "a phase number that is not one",
                     _cell(green, "Parameter", v)) for v in ("", "x", "-2", "0", "256", "99999999999", "2.5")]
    out += [Mutation(f"Parameter={v!r} of a begin yellow", "a phase number that is not one",
                     _cell(yellow, "Parameter", v)) for v in ("0", "300")]
    out += [Mutation(f"DeviceId={v!r}", "a DeviceId that is not one", _cell(green, "DeviceId", v)) for v in ("", "x")]
    out += [Mutation(f"{what}: TimeStamp one hour {'later' if s > 0 else 'earlier'}", "an event out of place",
                     _shifted(code, s)) for code, what in ((yellow, "begin yellow"), (green, "begin green"))
            for s in (3600.0, -3600.0)]
    out += [Mutation("begin green EventId=8", "an event out of place", _cell(green, "EventId", "8")),
            Mutation("begin yellow EventId=1", "an event out of place", _cell(yellow, "EventId", "1")),
            Mutation("begin green Parameter=9 (a new phase)", "an event out of place", _cell(green, "Parameter", "9")),
            Mutation("begin green Parameter=4 (another phase)", "an event out of place",
                     _cell(green, "Parameter", "4"))]
    zero = int(E.COORD_CYCLE_STATE_CHANGE)
    out += [Mutation("local zero at the time of the one before", "two local zeros at the same time",
                     _same_time_as_previous(zero, 5)),
            Mutation("local zero 0.1 s after the one before", "two local zeros at the same time",
                     _same_time_as_previous(zero, 5, 0.1)),
            Mutation("local zero 300 s after the one before", "two local zeros at the same time",
                     _same_time_as_previous(zero, 5, 300.0))]
    out += [Mutation(f"yield point Parameter={v}", "a coordination event out of range",
                     _cell(int(E.COORD_YIELD_POINT), "Parameter", v, nth=1)) for v in ("4", "0", "300")]
    out += [Mutation(f"force-off Parameter={v}", "a coordination event out of range",
                     _cell(int(E.PHASE_FORCE_OFF), "Parameter", v)) for v in ("4", "0", "300")]
    out += [Mutation(f"walk Parameter={v}", "a pedestrian event out of range",
                     _cell(int(E.PED_BEGIN_WALK), "Parameter", v, nth=1)) for v in ("0", "300")]
    if base == "field":  # overlaps, detectors and push buttons in the log: their numbers
        out += [Mutation(f"overlap begin green Parameter={v}", "overlap numbers out of range",
                         _cell(int(E.OVERLAP_BEGIN_GREEN), "Parameter", v)) for v in ("0", "17", "255", "-1", "1000")]
        out += [Mutation(f"overlap begin yellow Parameter={v}", "overlap numbers out of range",
                         _cell(int(E.OVERLAP_BEGIN_YELLOW), "Parameter", v)) for v in ("0", "-1")]
        out += [Mutation(f"detector on Parameter={v}", "detector numbers out of range",
                         _cell(int(E.DETECTOR_ON), "Parameter", v)) for v in ("0", "65", "300", "-5")]
        out += [Mutation(f"push button Parameter={v}", "detector numbers out of range",
                         _cell(int(E.PED_DETECTOR_ON), "Parameter", v, nth=1)) for v in ("0", "65")]
    else:  # the pretimed log has none: one of its plan events (cycle 70 s, offset 0) becomes one
        for code, name, family in ((int(E.OVERLAP_BEGIN_GREEN), "overlap begin green", "overlap"),
                                   (int(E.DETECTOR_ON), "detector on", "detector"),
                                   (int(E.PED_DETECTOR_ON), "push button", "detector")):
            out += [Mutation(f"cycle length event becomes {name} (number 70)", f"{family} numbers out of range",
                             _cell(int(E.CYCLE_LENGTH_CHANGE), "EventId", str(code), nth=0)),
                    Mutation(f"offset event becomes {name} (number 0)", f"{family} numbers out of range",
                             _cell(int(E.OFFSET_LENGTH_CHANGE), "EventId", str(code), nth=0))]
        out += [Mutation("begin green becomes overlap begin green", "overlap numbers out of range",
                         _cell(green, "EventId", str(int(E.OVERLAP_BEGIN_GREEN))))]
    out += [Mutation(f"{column} null", "a null in a typed column", _null(column, green), parquet=True)
            for column in ("TimeStamp", "EventId", "Parameter", "DeviceId")]
    return out


#: Logs made to break one rule each (from the emulator's log where they change it).
CRAFTED = [Mutation("64 phases that never run together", "no free phase number", _many_lone_phases),
           Mutation("13 phases in one ring's barrier group", "a ring of many phases", _thirteen_phase_ring),
           Mutation("every local zero 0.1 s after the one before", "two local zeros at the same time",
                    _local_zeros_a_tick_apart),
           Mutation("no events (the header alone)", "an empty log", lambda frame: frame.head(0))]


def base_logs(folder: Path) -> dict[str, pd.DataFrame]:
    """The field log (the atspm package's) and the emulator's own pretimed log, as text columns."""
    import atspm

    field = pd.read_parquet(Path(atspm.__file__).parent / "data" / "sample_raw_data.parquet")
    run = folder / "fixed_time_run"
    subprocess.run([sys.executable, "-m", "hils", "run", "--agent", "fixed-time", "--no-sumo", "--duration", "1800",
                    "--out", str(run), "--no-progress"], check=True, capture_output=True, cwd=folder)
    emulator = pd.read_parquet(run / "hires.parquet")
    return {name: _as_text(frame) for name, frame in (("field", field), ("emulator", emulator))}


def _as_text(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.astype(str)
    out["TimeStamp"] = [t.isoformat(sep=" ", timespec="milliseconds") for t in pd.to_datetime(frame.TimeStamp)]
    return out


def classify(returncode: int | None, stderr: str) -> str:
    """config, log refused, config refused, crash or hang (see the module's header)."""
    if returncode is None:
        return "hang"
    lines = [line for line in stderr.splitlines() if line.strip() and " INFO " not in line]
    if returncode == 0:
        return "config"
    if returncode == 2 and len(lines) == 1 and lines[0].startswith("hils: ") and "Traceback" not in stderr:
        return "config refused" if "inferred.toml" in lines[0] else "log refused"
    return "crash"


def mutations(out: Path, tree: Path | None, timeout: float) -> list[dict[str, object]]:
    """Each mutated log through ``hils replay --infer-only``; prints a line per log and the counts."""
    bases = base_logs(out)
    cases = [(base, m) for base in bases for m in catalogue(base)] + [("emulator", m) for m in CRAFTED]
    results = []
    for base, m in cases:
        mutated = m.change(bases[base])
        if mutated is None:
            continue
        i = len(results) + 1
        path = out / "logs" / f"{i:03d}.{'parquet' if m.parquet else 'csv'}"
        path.parent.mkdir(exist_ok=True)
        if m.parquet:
            mutated.to_parquet(path)
        else:
            mutated.to_csv(path, index=False)
        started = time.perf_counter()
        try:
            done = subprocess.run([sys.executable, "-m", "hils", "replay", str(path), "--infer-only", "--out",
                                   str(out / "inferred" / f"{i:03d}")], env=_env(tree), capture_output=True,
                                  text=True, timeout=timeout, cwd=out)
            outcome, said = classify(done.returncode, done.stderr), done.stderr.strip().splitlines()
        except subprocess.TimeoutExpired:
            outcome, said = "hang", []
        seconds = round(time.perf_counter() - started, 2)
        last = said[-1] if said else ""
        results.append({"case": i, "base": base, "family": m.family, "mutation": m.name, "outcome": outcome,
                        "seconds": seconds, "said": last[:300]})
        print(f"{i:>4} {base:<9} {m.name[:48]:<48} {outcome:<15} {last[:110]}", flush=True)
    counts = Counter(str(r["outcome"]) for r in results)
    print("\n" + ", ".join(f"{k}: {counts[k]}" for k in ("config", "log refused", "config refused", "crash", "hang"))
          + f"\ncrash or hang: {counts['crash'] + counts['hang']} of {len(results)}; neither a config nor a refusal of "
          f"the log (crash, hang, or its own config refused): "
          f"{counts['crash'] + counts['hang'] + counts['config refused']} of {len(results)}")
    return results


def compare(logs: Sequence[Path], out: Path, tree: Path | None, timeout: float) -> list[dict[str, object]]:
    """Each log's config inferred by the tree in ``tree`` and by this one: exit codes and the lines that differ."""
    results = []
    for k, log in enumerate(logs, start=1):
        toml, codes = {}, {}
        for side, source in (("tree", tree), ("this", None)):
            folder = out / f"{k:02d}_{log.stem}" / side
            try:
                done = subprocess.run([sys.executable, "-m", "hils", "replay", str(log.resolve()), "--infer-only",
                                       "--out", str(folder)], env=_env(source), capture_output=True, text=True,
                                      timeout=timeout, cwd=out)
                codes[side] = classify(done.returncode, done.stderr)
            except subprocess.TimeoutExpired:
                codes[side] = "hang"
            written = folder / "inferred.toml"
            toml[side] = written.read_text().splitlines() if written.exists() else []
        differ = [line for line in difflib.unified_diff(toml["tree"], toml["this"], lineterm="", n=0)
                  if line[:1] in "+-" and not line.startswith(("+++", "---"))]
        results.append({"log": str(log), "tree": codes["tree"], "this": codes["this"], "differ": differ})
        print(f"{log}: {codes['tree']} -> {codes['this']}; " + (f"{len(differ)} lines differ" if differ
                                                                 else "same config"), flush=True)
        for line in differ:
            print(f"    {line}")
    return results


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.reference.replay_bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("orders", "mutations", "compare", "day"))
    parser.add_argument("logs", nargs="*", type=Path, metavar="LOG", help="for compare: the logs to infer configs of")
    parser.add_argument("--tree", type=Path, metavar="DIR", help="run the hils source tree in DIR (default: this one)")
    parser.add_argument("--out", type=Path, metavar="DIR", help="where logs and results go (default: a new folder)")
    parser.add_argument("--phases", default="8-16", metavar="A-B", help="phases per ring, for orders (8-16)")
    parser.add_argument("--timeout", type=float, default=60.0, metavar="S",
                        help="seconds before a run counts as a hang (60)")
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix=f"hils-replay-{args.what}-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.what == "orders":
        lo, _, hi = args.phases.partition("-")
        results = orders(range(int(lo), int(hi or lo) + 1), out, args.tree, args.timeout)
    elif args.what == "mutations":
        results = mutations(out, args.tree, args.timeout)
    elif args.what == "day":
        results = day(out, args.tree, max(args.timeout, 1200.0))
    else:
        results = compare(args.logs, out, args.tree, args.timeout)
    (out / f"{args.what}.json").write_text(json.dumps({"tree": str(args.tree or "this"), "results": results},
                                                      indent=1, default=str))
    print(f"Results in {out / f'{args.what}.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
