"""The emulator as a Signal-Replay bench: a hi-res log's inputs replayed into `hils emulator serve`, its record
compared with the log's.

Signal-Replay (``signal_replay`` on PyPI, unmodified) does what it does with a bench controller: it resets the
controller's detector inputs, waits for the cycle position of the log's start when the signal is coordinated,
SETs the log's vehicle and pedestrian detector (and preempt) inputs over NTCIP at their times
(``vehicleDetectorControlGroupActuation``, ``pedestrianDetectorControlGroupActuation``, ``preemptControlState``),
collects the bench's events from its MaxTime event-log endpoint, and scores the bench's phase and overlap events
against the log's (its ``match_percentage``, a dynamic-time-warping match of the events grouped by time). This
module serves the emulator for it (:func:`harness.bench.processes.start_emulator`, ``--http``), runs it, and adds a
table of its own: per event type and phase, how many of the log's events the bench logged within a tolerance
(:func:`match_table`), so a difference can be read where it is.

Times: the served controllers keep the host's clock, and Signal-Replay starts a coordinated replay at the cycle
position the log started at (``cycle_length``), so the bench's cycle is where the log's was as long as whole
days are whole cycles (86,400 s a multiple of the cycle). A free log is aligned to the second
(``cycle_length=1``): the inputs land on the tenth of a second they were logged at. The SET of an input is sent
:data:`LATENCY_S` before it is due (Signal-Replay's ``replay_latency_offset_seconds``): the emulator answers at
once and reads its inputs at the next tick.
"""

from __future__ import annotations

import argparse
import csv
import logging
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

from harness.reference.hires_file import Row
from hils.protocol import config as config_mod
from hils.protocol.hires import Event, EventCode
from hils.shell.asclog import collect

log = logging.getLogger(__name__)

E = EventCode
LATENCY_S = 0.05
#: The events the bench is judged on: Signal-Replay's COMPARISON_EVENT_IDS (phase, pedestrian, overlap, preempt)
#: and what else a controller decides (gap/max/force-off, min complete, barrier) besides calls.
JUDGED = (E.PHASE_BEGIN_GREEN, E.PHASE_MIN_COMPLETE, E.PHASE_GAP_OUT, E.PHASE_MAX_OUT, E.PHASE_FORCE_OFF,
          E.PHASE_GREEN_TERMINATION, E.PHASE_END_YELLOW, E.PHASE_END_RED_CLEARANCE, E.PED_BEGIN_WALK,
          E.PED_BEGIN_CLEARANCE, E.PED_BEGIN_SOLID_DONT_WALK, E.BARRIER_TERMINATION, E.OVERLAP_BEGIN_GREEN,
          E.OVERLAP_BEGIN_YELLOW, E.OVERLAP_OFF, E.OVERLAP_DARK, E.PREEMPT_ENTRY_STARTED, E.PREEMPT_BEGIN_EXIT)


@dataclass(frozen=True, slots=True)
class MatchRow:
    """One event type of one phase (or overlap, barrier...): the log's count, the bench's, and how many of the log's
    the bench logged within the tolerance."""

    code: int
    parameter: int
    field: int
    bench: int
    matched: int

    @property
    def share(self) -> float | None:
        return None if not self.field else round(100 * self.matched / self.field, 1)


@dataclass
class Replayed:
    """What one replay gave: Signal-Replay's own match, the bench's events and the table."""

    signal_replay_match: float
    shift: timedelta  # bench time minus log time
    field: list[Row]
    bench: list[Event]
    table: list[MatchRow]

    def overall(self) -> float | None:
        n = sum(r.field for r in self.table)
        return None if not n else round(100 * sum(r.matched for r in self.table) / n, 1)


def replay(rows: Sequence[Row], config: Path, work: Path, *, device: str = "field", tolerance_s: float = 1.0,
           settle_s: float = 2.0, warm_up_s: float = 0.0) -> Replayed:
    """Serve the emulator with ``config``, let it run ``warm_up_s`` (to rest in its start-up state, as the log's
    controller did before its first input), let Signal-Replay replay ``rows`` into it and compare (see the header)."""
    import pandas as pd
    import signal_replay as sr

    from harness.bench.processes import start_emulator

    cfg = config_mod.load(config)
    plan = cfg.coordination.patterns.get(cfg.coordination.pattern) if isinstance(cfg.coordination.pattern, int) \
        else None
    cycle = plan.cycle if plan is not None else 1
    if plan is not None and 86_400 % cycle:
        log.warning("cycle %d s does not divide a day: the bench's cycle position is off by the days between the "
                    "log and today modulo the cycle", cycle)
    frame = pd.DataFrame({"TimeStamp": [r.time for r in rows], "DeviceId": device, "EventId": [r.code for r in rows],
                          "Parameter": [r.parameter for r in rows]})
    work.mkdir(parents=True, exist_ok=True)
    served = start_emulator(work / "serve.log", "--config", str(config), http=True)
    try:
        since = datetime.now()
        time.sleep(warm_up_s)
        sim = sr.ATCSimulation(
            signals=[sr.SignalConfig(device, "127.0.0.1", udp_port=served.port, http_port=served.http_ports[0],
                                     cycle_length=cycle, replay_latency_offset_seconds=LATENCY_S,
                                     snmp_community="private")],
            events=frame, replays=1, post_replay_settle_seconds=settle_s, final_collection_poll_seconds=1,
            final_collection_timeout_seconds=60, work_dir=work / "signal_replay", stop_on_conflict=False)
        result = sim.run()
        bench = collect(f"http://127.0.0.1:{served.http_ports[0]}", since)
    finally:
        served.stop()
    matches = [c.match_percentage for c in result.comparisons if c.run_a == "input"]
    shift = input_shift(rows, bench)
    return Replayed(matches[0] if matches else float("nan"), shift, list(rows), bench,
                    match_table(rows, bench, shift, tolerance_s))


def input_shift(rows: Sequence[Row], bench: Sequence[Event]) -> timedelta:
    """Bench time minus log time: the most frequent offset between the log's detector-on events and the bench's of
    the same detector (the replayed inputs)."""
    theirs: dict[int, list[datetime]] = defaultdict(list)
    for e in bench:
        if e.code == E.DETECTOR_ON:
            theirs[e.parameter].append(e.time)
    first = {d: times[0] for d, times in theirs.items()}
    offsets: Counter[timedelta] = Counter()
    for r in rows:
        if r.code == E.DETECTOR_ON and r.parameter in first:
            for t in theirs[r.parameter][:50]:
                offsets[t - r.time] += 1
    if not offsets:
        raise ValueError("the bench logged none of the log's detector inputs: nothing was replayed")
    return offsets.most_common(1)[0][0]


def match_table(rows: Iterable[Row], bench: Iterable[Event], shift: timedelta, tolerance_s: float = 1.0,
                codes: Sequence[int] = JUDGED) -> list[MatchRow]:
    """Per event type and parameter over the bench's span: the log's events, the bench's, and how many of the log's
    have a bench event of the same type and parameter within ``tolerance_s`` (each bench event matched once)."""
    bench = list(bench)
    if not bench:
        return []
    lo, hi = bench[0].time - shift, bench[-1].time - shift
    mine: dict[tuple[int, int], list[datetime]] = defaultdict(list)
    theirs: dict[tuple[int, int], list[datetime]] = defaultdict(list)
    for r in rows:
        if r.code in codes and lo <= r.time <= hi:
            mine[(r.code, r.parameter)].append(r.time)
    for e in bench:
        if e.code in codes:
            theirs[(e.code, e.parameter)].append(e.time - shift)
    tolerance = timedelta(seconds=tolerance_s)
    out = []
    for key in sorted(set(mine) | set(theirs)):
        free = sorted(theirs.get(key, []))
        matched = 0
        for t in sorted(mine.get(key, [])):
            near = [u for u in free if abs(u - t) <= tolerance]
            if near:
                free.remove(min(near, key=lambda u: abs(u - t)))
                matched += 1
        out.append(MatchRow(key[0], key[1], len(mine.get(key, [])), len(theirs.get(key, [])), matched))
    return out


def render(replayed: Replayed, tolerance_s: float = 1.0) -> str:
    """The table as text: per event type and phase, the log's events found by the bench."""
    names = {int(c): c.name.lower().replace("_", " ") for c in E}
    lines = [f"Signal-Replay's match (its DTW of phase and overlap events): {replayed.signal_replay_match:.1f} %",
             f"events of the log found in the bench's log within {tolerance_s:g} s (bench clock {replayed.shift} "
             f"after the log's): {replayed.overall()} %", "",
             f"{'event':<34}{'no.':>4}{'log':>7}{'bench':>7}{'found':>7}{'share':>8}"]
    for r in replayed.table:
        share = "-" if r.share is None else f"{r.share:.1f} %"
        lines.append(f"{names.get(r.code, str(r.code)):<34}{r.parameter:>4}{r.field:>7}{r.bench:>7}{r.matched:>7}"
                     f"{share:>8}")
    return "\n".join(lines)


def write_table(replayed: Replayed, path: Path) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["EventId", "Parameter", "log", "bench", "found", "share_percent"])
        out.writerows((r.code, r.parameter, r.field, r.bench, r.matched, r.share) for r in replayed.table)


# --- `hils replay` -------------------------------------------------------------------------------------------


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="replay a controller's hi-res log into the emulator with Signal-Replay and compare",
        description="Write a config for the controller of an ATSPM-layout hi-res log (phases, rings, clearances, "
                    "minimums, detectors, push buttons, the coordination plan: from the log's own events, saying what "
                    "it had to guess), serve the emulator with it, let Signal-Replay replay the log's detector and "
                    "pedestrian inputs into it in real time, and report Signal-Replay's match and, per event type and "
                    "phase, how many of the log's events the emulator logged too (pip install 'hils[test]' brings "
                    "signal_replay).")
    p.add_argument("log", metavar="LOG", help="hi-res log in the ATSPM layout (.parquet or .csv)")
    p.add_argument("--device", metavar="ID", help="the controller's DeviceId when the log holds several")
    p.add_argument("--config", metavar="FILE", type=Path,
                   help="the emulator's config (default: written from the log into OUT/inferred.toml)")
    p.add_argument("--start", metavar="TIME", type=datetime.fromisoformat,
                   help="replay from this time of the log (ISO, e.g. 2024-04-15T12:30:00; default: its start)")
    p.add_argument("--minutes", type=float, metavar="M", help="replay this many minutes (default: to the log's end)")
    p.add_argument("--infer-only", action="store_true", help="write the config and stop")
    p.add_argument("--out", metavar="DIR", type=Path, help="output folder (default: a new temporary one)")
    p.set_defaults(func=_command)


def _command(args: argparse.Namespace) -> int:
    from harness.reference import field_log, hires_file
    from harness.reference.hires_file import FieldLogError

    every = hires_file.load(args.log, args.device)
    config = args.config
    if config is None:
        try:
            inferred = field_log.infer(every, name=f"{Path(args.log).stem} {args.device or ''}".strip())
        except FieldLogError as exc:
            raise FieldLogError(f"{args.log}: {exc}") from None
    out = args.out or Path(tempfile.mkdtemp(prefix="hils-replay-"))
    out.mkdir(parents=True, exist_ok=True)
    if config is None:
        config = out / "inferred.toml"
        config.write_text(inferred.toml)
        print(f"Config written to {config}\nRead from the log:\n  " + "\n  ".join(inferred.read)
              + "\nGuessed:\n  " + "\n  ".join(inferred.guessed))
        inferred.config()  # refused here, naming the field, if what was inferred does not make a config
    if args.infer_only:
        return 0
    start = args.start or every[0].time
    end = start + timedelta(minutes=args.minutes) if args.minutes else None
    rows = [r for r in every if r.time >= start and (end is None or r.time < end)]
    minutes = (rows[-1].time - rows[0].time).total_seconds() / 60 if rows else 0
    print(f"Replaying {len(rows)} events ({minutes:.1f} minutes, in real time) into the emulator...", flush=True)
    replayed = replay(rows, config, out)
    print(render(replayed))
    write_table(replayed, out / "match.csv")
    print(f"Outputs in {out}/: {'inferred.toml, ' if args.config is None else ''}match.csv, signal_replay/")
    return 0
