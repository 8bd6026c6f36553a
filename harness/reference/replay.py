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

Times: the served controllers keep the host's clock (their cycles counted from the host's midnight), and Signal-Replay
starts a coordinated replay when the time since the log's start is a whole number of cycles past its ``cycle_offset``
(signal_replay 1.0.1, ``_wait_until_next_cycle``). Where whole days are not whole cycles (86,400 s not a multiple of the
cycle, 75 s for instance) the days between the config's day (its ``[emulator] start``: the log's first day for a written
config, whose cycle positions count from its midnight on) and the bench's are not whole cycles either: that remainder is
given as the ``cycle_offset`` (:func:`day_shift`), so the bench's cycle is where the log's was. A free log is aligned to
the second (``cycle_length=1``): the inputs land on the tenth of a second they were logged at. The SET of an input is
sent :data:`LATENCY_S` before it is due (Signal-Replay's ``replay_latency_offset_seconds``): the emulator answers at
once and reads its inputs at the next tick.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date, datetime, timedelta
from pathlib import Path

from harness.reference.hires_file import Row
from harness.reference.replay_match import Equivalence, GreenRow, MatchRow, green_table, match_table, overall
from hils.protocol import config as config_mod
from hils.protocol.hires import Event, EventCode
from hils.shell.asclog import collect

log = logging.getLogger(__name__)

E = EventCode
LATENCY_S = 0.05
#: What Signal-Replay's own score is when it is 0.0 (signal_replay 1.0.1; issue 35).
THROWN_OUT = ("every chunk thrown out by its phase-call similarity check: it keeps only its comparison event types "
              "of the field log, so the field side has no phase calls (43/44) to be similar to; not a measure of the "
              "bench")


@dataclass
class Replayed:
    """What one Signal-Replay bench run gave: Signal-Replay's own match, the bench's events and the tables."""

    signal_replay_match: float
    shift: timedelta  # bench time minus log time
    field: list[Row]
    bench: list[Event]
    table: list[MatchRow]
    green: list[GreenRow]

    def overall(self) -> float | None:
        return overall(self.table)


def replay(rows: Sequence[Row], config: Path, work: Path, *, device: str = "field", tolerance_s: float = 1.0,
           settle_s: float = 2.0, warm_up_s: float = 0.0, equivalences: Sequence[Equivalence] = ()) -> Replayed:
    """Serve the emulator with ``config``, let it run ``warm_up_s`` (to rest in its start-up state, as the log's
    controller did before its first input), let Signal-Replay replay ``rows`` into it and compare (see the header),
    through the declared logging variants ``equivalences``."""
    import pandas as pd
    import signal_replay as sr

    from harness.bench.processes import start_emulator

    cfg = config_mod.load(config)
    plan = cfg.coordination.patterns.get(cfg.coordination.pattern) if isinstance(cfg.coordination.pattern, int) \
        else None
    cycle = plan.cycle if plan is not None else 1
    frame = pd.DataFrame({"TimeStamp": [r.time for r in rows], "DeviceId": device, "EventId": [r.code for r in rows],
                          "Parameter": [r.parameter for r in rows]})
    work.mkdir(parents=True, exist_ok=True)
    served = start_emulator(work / "serve.log", "--config", str(config), http=True)
    try:
        since = datetime.now()
        offset = day_shift(cfg.emulator.start.date(), since.date(), cycle)
        if offset:
            log.info("cycle %d s does not divide a day: Signal-Replay starts %d s into the cycle (the %d days since "
                     "the config's day)", cycle, offset, (since.date() - cfg.emulator.start.date()).days)
        time.sleep(warm_up_s)
        sim = sr.ATCSimulation(
            signals=[sr.SignalConfig(device, "127.0.0.1", udp_port=served.port, http_port=served.http_ports[0],
                                     cycle_length=cycle, cycle_offset=offset, replay_latency_offset_seconds=LATENCY_S,
                                     snmp_community="private")],
            events=frame, replays=1, post_replay_settle_seconds=settle_s, final_collection_poll_seconds=1,
            final_collection_timeout_seconds=60, work_dir=work / "signal_replay", stop_on_conflict=False)
        result = sim.run()
        bench = collect(f"http://127.0.0.1:{served.http_ports[0]}", since)
    finally:
        served.stop()
    matches = [c.match_percentage for c in result.comparisons if c.run_a == "input"]
    shift = input_shift(rows, bench)
    span = (bench[0].time - shift, bench[-1].time - shift) if bench else None
    return Replayed(matches[0] if matches else float("nan"), shift, list(rows), bench,
                    match_table(rows, bench, shift, tolerance_s, span=span, equivalences=equivalences),
                    green_table(rows, bench, shift, tolerance_s))


def day_shift(log_day: date, bench_day: date, cycle: int) -> int:
    """Seconds past a whole number of cycles Signal-Replay waits from the log's start (its ``cycle_offset``) so that
    the bench, counting its cycles from ``bench_day``'s midnight, is where the log's controller was, counting from
    ``log_day``'s: the days between them modulo the cycle (0 when the cycle divides a day)."""
    return (bench_day - log_day).days * 86_400 % cycle


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


def signal_replay_score(match: float) -> str:
    """Signal-Replay's own score, said as what it is."""
    said = f"{match:.1f} %"
    return f"{said} ({THROWN_OUT})" if match == 0.0 else said


# --- `hils replay` -------------------------------------------------------------------------------------------

#: The vendor whose logging variants apply, by the log file's suffix (a vendor's own form says whose it is).
VENDOR_BY_SUFFIX = {".dat": "Econolite", ".datz": "Econolite", ".xml": "MaxTime"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="replay a controller's hi-res log into the emulator (virtual time) and compare",
        description="Write a config for the controller of a hi-res log (phases, rings, clearances, minimums, "
                    "detectors, push buttons, the coordination plan: from the log's own events, saying what it had to "
                    "guess), run the log's detector, push-button and preempt inputs into the emulator's controller "
                    "model in virtual time (each on the tick it was logged at; two hours of a busy coordinated log in "
                    "about 10 s), and report how many of the log's events the emulator logged within 1 s: over the "
                    "whole log, per green (re-anchored at each field green: how it ended) and per event type and "
                    "phase. --bench signal-replay replays through Signal-Replay at the wall clock instead (pip install "
                    "'hils[test]' brings signal_replay).")
    p.add_argument("log", metavar="LOG",
                   help="hi-res log: ATSPM layout (.parquet or .csv), Econolite .dat/.datZ or MaxTime asclog .xml")
    p.add_argument("--device", metavar="ID", help="the controller's DeviceId when an ATSPM log holds several")
    p.add_argument("--config", metavar="FILE", type=Path,
                   help="the emulator's config (default: written from the log into OUT/inferred.toml)")
    p.add_argument("--start", metavar="TIME", type=datetime.fromisoformat,
                   help="replay from this time of the log (ISO, e.g. 2024-04-15T12:30:00; default: its start)")
    p.add_argument("--minutes", type=float, metavar="M", help="replay this many minutes (default: to the log's end)")
    p.add_argument("--bench", choices=("virtual", "signal-replay"), default="virtual",
                   help="virtual: the emulator's model in process, in virtual time (default); signal-replay: "
                        "Signal-Replay replays the log into `hils emulator serve` in real time")
    p.add_argument("--vendor", choices=sorted(set(VENDOR_BY_SUFFIX.values())),
                   help="whose logging variants to count as equivalent (default: from the file: .dat Econolite, "
                        ".xml MaxTime; an ATSPM file: none); whatever the vendor, an overlap the log shows dark while "
                        "its phases are green has its dark counted as its begin green")
    p.add_argument("--infer-only", action="store_true", help="write the config and stop")
    p.add_argument("--out", metavar="DIR", type=Path, help="output folder (default: a new temporary one)")
    p.set_defaults(func=_command)


def _command(args: argparse.Namespace) -> int:
    from harness.reference import field_log, hires_file, replay_match, replay_virtual
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
    if not rows:
        raise FieldLogError(f"{args.log}: no events from {start} on; allowed: --start and --minutes within the log "
                            f"({every[0].time} to {every[-1].time})")
    minutes = (rows[-1].time - rows[0].time).total_seconds() / 60
    vendor = args.vendor or VENDOR_BY_SUFFIX.get(Path(args.log).suffix.lower())
    equivalences = replay_match.for_log(vendor, field_log.dark_at_green(rows))
    if args.bench == "signal-replay":
        print(f"Replaying {len(rows)} events ({minutes:.1f} minutes, in real time) into the emulator with "
              "Signal-Replay...", flush=True)
        replayed = replay(rows, config, out, equivalences=equivalences)
        table, green = replayed.table, replayed.green
        headline = (f"Signal-Replay's match (its DTW of phase and overlap events): "
                    f"{signal_replay_score(replayed.signal_replay_match)}\n"
                    f"events of the log found in the bench's log within 1 s (bench clock {replayed.shift} after the "
                    f"log's, over the bench's span): {replayed.overall()} %")
    else:
        print(f"Replaying {len(rows)} events ({minutes:.1f} minutes) into the emulator in virtual time...", flush=True)
        wall = time.perf_counter()
        ran = replay_virtual.run(rows, config_mod.load(config))
        wall = time.perf_counter() - wall
        table = replay_match.match_table(rows, ran.events, equivalences=equivalences)
        green = replay_match.green_table(rows, ran.events)
        headline = (f"{ran.inputs} inputs replayed in {wall:.1f} s of wall time\n"
                    f"events of the log found in the emulator's log within 1 s, over the whole log: "
                    f"{replayed_share(table)}")
        (out / "bench.csv").write_text("TimeStamp,EventId,Parameter\n" + "".join(
            f"{e.time.isoformat(sep=' ', timespec='milliseconds')[:-2]},{e.code},{e.parameter}\n" for e in ran.events))
    print(headline)
    print(replay_match.render_equivalences(equivalences))
    print(replay_match.render(table, green, equivalences))
    replay_match.write_table(table, out / "match.csv", equivalences)
    outputs = ["inferred.toml"] if args.config is None else []
    outputs += ["match.csv", "signal_replay/" if args.bench == "signal-replay" else "bench.csv"]
    print(f"Outputs in {out}/: {', '.join(outputs)}")
    return 0


def replayed_share(table: Sequence[MatchRow]) -> str:
    n, share = sum(r.field for r in table), overall(table)
    return f"{share} % of {n}" if share is not None else f"none to judge ({n} judged events in the log)"
