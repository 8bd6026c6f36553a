"""Phase control at the wall clock: MMITSS's own schedule run against `hils emulator serve` (real UDP) by
`hils run --schedule`, the phase sequence read by net-snmp beside what the schedule asks and beside the same
schedule in virtual time (from SETTLED s after the receipt on: before, the served controller's first green depends
on where it was in its cycle when the run took it, the virtual one's on its power-up).

The emulator is served with ``examples/mmitss/four_leg_min_recall.toml`` (every phase on minimum recall, the
controller with traffic everywhere that MMITSS's schedules assume). While `hils run` drives it, net-snmp's
``snmpget`` (a client independent of hils) reads phaseStatusGroupGreens and the Hold, PhaseOmit and VehCall objects
every ``period`` s. The greens it saw are cut into intervals, counted from the schedule's receipt (the run's
``schedule_started`` record; both sides stamp ``time.monotonic_ns()``); each hold of the schedule is judged kept (its
phase green from the hold's start, or from when it came green, to the hold's end) and each green start is matched
with the virtual-time run's. ``python -m harness.bench.phase_control_wire`` prints the table and writes
``phase_control_wire.json`` under ``reports/runs/<time>-phase-control-wire/`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from harness.bench.processes import start_emulator, tool
from hils.agents.builtin import ScheduleAgent
from hils.control import phase_control
from hils.control.phase_control import Control, Schedule
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn, StatusColumn, control_oid, groups_to_phases, oid_str, status_oid
from hils.report import outfiles
from hils.run.testbed import Testbed
from hils.shell.events import Kind, read

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "mmitss"
CONFIG = EXAMPLES / "four_leg_min_recall.toml"
SCHEDULE = EXAMPLES / "schedule_ev.json"
#: Seconds from the schedule's receipt after which the wall-clock greens are matched with virtual time's: the end of
#: schedule_ev.json's first hold (4 and 7 to 24 s), which both runs leave at the same moment.
SETTLED = 24.0
#: What net-snmp reads each time: the greens, and three of the objects the run SETs (group 1: phases 1-8).
READ = (("greens", status_oid(StatusColumn.GREENS, 1)), ("hold", control_oid(ControlColumn.HOLD, 1)),
        ("omit", control_oid(ControlColumn.PHASE_OMIT, 1)), ("veh_call", control_oid(ControlColumn.VEH_CALL, 1)))


@dataclass(frozen=True)
class Green:
    """Phases green together from ``start`` to ``end`` (s from the schedule's receipt)."""

    phases: tuple[int, ...]
    start: float
    end: float


@dataclass(frozen=True)
class HoldKept:
    """A hold of the schedule, and whether its phase stayed green from the hold's start (or from when it came green
    within it) to its end, as net-snmp saw it."""

    phase: int
    start: float
    end: float
    green_from: float | None  # when its phase showed green within the hold (None: never)
    kept: bool


def greens_in(samples: list[tuple[float, frozenset[int]]], until: float) -> list[Green]:
    """The intervals of one set of greens, from (time, greens) samples in time order (an empty set: no green)."""
    out: list[Green] = []
    for (t, greens), t_next in zip(samples, [*(t for t, _ in samples[1:]), until], strict=True):
        if out and out[-1].phases == tuple(sorted(greens)):
            out[-1] = Green(out[-1].phases, out[-1].start, t_next)
        elif greens:
            out.append(Green(tuple(sorted(greens)), t, t_next))
    return out


def holds_kept(schedule: Schedule, greens: list[Green], slack: float) -> list[HoldKept]:
    """Each hold judged on the greens seen: green through to its end (within ``slack`` s, the reading period)."""
    out = []
    for o in schedule.orders:
        if o.control is not Control.HOLD:
            continue
        start, end = o.start / 10, o.end / 10
        spans = [g for g in greens if o.phase in g.phases and g.end > start and g.start < end]
        first = spans[0] if spans else None
        kept = first is not None and first.end >= end - slack
        out.append(HoldKept(o.phase, start, end, None if first is None else max(first.start, start), kept))
    return out


def virtual_greens(config: IntersectionConfig, schedule: Schedule, duration: float, log: Path) -> list[Green]:
    """The same schedule in virtual time: its green intervals from the run's polls."""
    with Testbed(config, action_type="control", agent=ScheduleAgent(schedule), duration=duration,
                 log_path=log) as tb:
        tb.reset()
        tb.run()
    records = list(read(log))
    received = next(r["t"] for r in records if r["kind"] == Kind.SCHEDULE_STARTED)
    polls = [(r["t"] - received, frozenset(r["greens"])) for r in records if r["kind"] == Kind.POLL]
    return greens_in(polls, duration - received)


def measure(duration: float, period: float, out: Path, schedule_path: Path = SCHEDULE,
            config_path: Path = CONFIG) -> dict[str, object]:
    """Serve, run the schedule at the wall clock, read it with net-snmp; the figures as a JSON-able dict."""
    config = config_mod.load(config_path)
    schedule = phase_control.load(schedule_path, config)
    out.mkdir(parents=True, exist_ok=True)
    served = start_emulator(out / "serve.log", "--config", str(config_path))
    snmpget = tool("snmpget")
    samples: list[tuple[int, dict[str, frozenset[int]]]] = []
    try:
        url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
        run = subprocess.Popen([sys.executable, "-m", "hils", "run", "--config", str(config_path), "--schedule",
                                str(schedule_path), "--target", url, "--no-sumo", "--duration", str(duration),
                                "--out", str(out / "run"), "--no-progress"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        while run.poll() is None:
            at = time.monotonic_ns()
            got = subprocess.run([snmpget, "-v2c", "-c", "public", "-On", "-Oqv", "-t", "1", "-r", "0",
                                  f"127.0.0.1:{served.port}", *(oid_str(oid) for _, oid in READ)],
                                 capture_output=True, text=True, check=False)
            values = got.stdout.split()
            if got.returncode == 0 and len(values) == len(READ):
                samples.append((at, {name: groups_to_phases([int(v)]) for (name, _), v in zip(READ, values,
                                                                                               strict=True)}))
            time.sleep(max(0.0, period - (time.monotonic_ns() - at) / 1e9))
        printed = run.stdout.read() if run.stdout else ""
        if run.returncode != 0:
            raise RuntimeError(f"hils run ended with {run.returncode}:\n{printed}")
    finally:
        served.proc.terminate()
        served.proc.wait()
    records = list(read(out / "run" / "events.jsonl"))
    received_ns = next(r["wall_ns"] for r in records if r["kind"] == Kind.SCHEDULE_STARTED)
    seen = [((at - received_ns) / 1e9, s) for at, s in samples if at >= received_ns]
    span = schedule.span or duration
    wall = greens_in([(t, s["greens"]) for t, s in seen], seen[-1][0] if seen else 0.0)
    virtual = virtual_greens(config, schedule, duration, out / "virtual.jsonl")
    last = seen[-1][0] if seen else 0.0
    holds = [h for h in holds_kept(schedule, [g for g in wall if g.start < span], slack=2 * period) if h.end < last]
    # The first greens depend on where the served controller was in its cycle when the run took it (it cycles on
    # its recalls from the moment it is served), the virtual run's on its power-up: matched from SETTLED s on.
    matched = [(v, min(wall, key=lambda w, v=v: abs(w.start - v.start), default=None)) for v in virtual
               if SETTLED <= v.start < last - 1.0]
    offsets = [w.start - v.start for v, w in matched if w is not None and w.phases == v.phases]
    omits_held = sum(1 for t, s in seen if 1.0 < t < span and s["omit"] == schedule.at(int(t * 10))[
        ControlColumn.PHASE_OMIT])
    return {
        "schedule": str(schedule_path.name), "config": config.name, "duration_s": duration, "period_s": period,
        "reads": len(samples), "reads_in_schedule": sum(1 for t, _ in seen if t < span),
        "wall_greens": [asdict(g) for g in wall], "virtual_greens": [asdict(g) for g in virtual],
        "holds": [asdict(h) for h in holds], "holds_kept": sum(h.kept for h in holds), "holds_judged": len(holds),
        "green_starts_matched": len(offsets), "green_starts_virtual": len(matched),
        "green_start_offset_s": {"min": min(offsets, default=None), "max": max(offsets, default=None)},
        "omit_reads_as_scheduled": omits_held,
        "omit_reads": sum(1 for t, _ in seen if 1.0 < t < span),
    }


def render(fig: dict[str, object]) -> str:
    lines = [f"{fig['schedule']} on {fig['config']} at the wall clock, read by net-snmp every {fig['period_s']:g} s "
             f"({fig['reads']} reads)", "", "green (net-snmp, s from receipt)   virtual time              asked"]
    virtual = fig["virtual_greens"]
    holds = fig["holds"]
    for i, g in enumerate(fig["wall_greens"]):
        v = virtual[i] if i < len(virtual) else None
        asked = ", ".join(f"hold {h['phase']} {h['start']:g}-{h['end']:g}" for h in holds
                          if h["phase"] in g["phases"] and h["start"] < g["end"] and h["end"] > g["start"])
        vtext = f"{v['phases']} {v['start']:6.1f}-{v['end']:6.1f}" if v else ""
        lines.append(f"{g['phases']!s:8} {g['start']:6.1f}-{g['end']:6.1f}             {vtext:26}{asked}")
    off = fig["green_start_offset_s"]
    lines += ["", f"holds kept: {fig['holds_kept']} of {fig['holds_judged']}",
              f"green starts matching virtual time: {fig['green_starts_matched']} of {fig['green_starts_virtual']}"
              + (f" (offset {off['min']:+.2f} to {off['max']:+.2f} s)" if off["min"] is not None else ""),
              f"PhaseOmit read as the schedule asks: {fig['omit_reads_as_scheduled']} of {fig['omit_reads']} reads"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m harness.bench.phase_control_wire", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=140.0, metavar="S",
                   help="wall-clock seconds of the run (140: MMITSS's schedule_ev.json lasts 133.5 s)")
    p.add_argument("--period", type=float, default=0.2, metavar="S", help="seconds between net-snmp reads (0.2)")
    p.add_argument("--schedule", type=Path, default=SCHEDULE, metavar="FILE", help="MMITSS schedule JSON")
    p.add_argument("--out", type=Path, metavar="DIR", help="default: reports/runs/<time>-phase-control-wire/")
    args = p.parse_args(argv)
    out = args.out or outfiles.fresh_folder("phase-control-wire")
    fig = measure(args.duration, args.period, out, args.schedule)
    (out / "phase_control_wire.json").write_text(json.dumps(fig, indent=1) + "\n")
    print(render(fig))
    print(f"\nwritten: {out / 'phase_control_wire.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
