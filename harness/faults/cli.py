"""`hils faults ...`: run and list the fault scenarios.

``hils faults run [PATH ...]`` runs every scenario (default: the shipped suite
in ``fault_scenarios/``), prints a results table, writes ``faults.md`` and
``faults.json`` to its output folder (:mod:`harness.published`: ``--publish`` rebuilds
the published ``reports/faults.md``, the shipped suite at :data:`PUBLISHED_SEEDS`) and
exits 1 if any expectation failed.
``hils faults list [PATH ...]`` prints one line per scenario. ``hils faults
proxy`` relays UDP to an SNMP agent with faults on a schedule (:mod:`harness.faults.proxy`).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from harness import published
from harness.bench.seeds import seeds_text
from harness.faults.judge import FaultScenarioResult
from harness.faults.proxy import register_proxy
from harness.faults.reader import FaultScenario, default_suite, discover, load_fault_scenario
from harness.faults.runner import run_fault_scenario
from hils.protocol.errors import UserError
from hils.report import jsonout
from hils.report.outfiles import write_whole
from hils.sweep.grid import SweepError, parse_seeds

RUN_HELP = """\
Run fault scenarios in virtual time and check their expected outcomes.

Each scenario (a TOML file) runs the middleware against the emulator with faults
injected on a timeline: lost, late or refused datagrams, a stuck or rebooting
controller, slow simulation steps, a misbehaving agent, a suppressed keepalive.
A scenario may run several controllers (scenario = "corridor") with a fault on
one of them; each intersection is then judged on its own.
Besides its own expectations every scenario checks that each of its faults fired,
that nothing conflicting was ever sent or shown, and that the event log is whole.
With --seeds every scenario runs once per seed (its own seed replaced: the
emulator's draws, the faults' and the agent's), and is reported per seed: an
expectation must hold at every seed.

Outputs: faults.md and faults.json in a new reports/runs/<time>-faults/ (or --out);
--publish rebuilds the published reports/faults.md and faults.json instead, from the
shipped suite at seeds 1,1001,2002 unless --seeds says otherwise.

Exit status: 0 if every expectation held, 1 if any failed, 2 if a scenario file
is invalid.
"""

#: The seeds of the published report (reports/faults.md): every scenario must hold at each of them.
PUBLISHED_SEEDS = (1, 1001, 2002)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("faults", help="fault-injection scenarios (CI suites)",
                            description="Fault-injection scenarios: the paper's error-handling experiments and more.")
    commands = parser.add_subparsers(dest="faults_command", metavar="COMMAND", required=True)

    run = commands.add_parser("run", help="run scenarios and report", description=RUN_HELP,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("paths", nargs="*", metavar="PATH",
                     help="scenario files or directories of them (default: the shipped suite)")
    run.add_argument("--log-dir", type=Path, metavar="DIR",
                     help="also write each scenario's JSON Lines event log to DIR/<scenario>.jsonl")
    run.add_argument("--seeds", type=_seeds, metavar="SEEDS",
                     help="run every scenario at each of these seeds, e.g. 1,1001,2002 or 0-4 (default: the "
                          "scenario's own)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    published.options(run, "faults", ".")
    run.set_defaults(func=_run)

    listing = commands.add_parser("list", help="list scenarios, one line each",
                                  description="List fault scenarios, one line each.")
    listing.add_argument("paths", nargs="*", metavar="PATH",
                         help="scenario files or directories of them (default: the shipped suite)")
    listing.set_defaults(func=_list)

    register_proxy(commands)


def _scenarios(paths: Sequence[str]) -> list[FaultScenario]:
    if not paths:
        suite = default_suite()
        if not suite.is_dir():
            raise SystemExit(f"hils faults: the shipped suite is not at {suite}; give scenario files or directories")
        paths = [str(suite)]
    files = discover(paths)
    if not files:
        raise SystemExit(f"hils faults: no scenario files (*.toml) in {', '.join(paths)}")
    return [load_fault_scenario(f) for f in files]


def _list(args: argparse.Namespace) -> int:
    scenarios = _scenarios(args.paths)
    width = max(len(s.name) for s in scenarios)
    for s in scenarios:
        print(f"{s.name:<{width}}  {s.summary()}")
    return 0


def _seeds(text: str) -> list[int]:
    try:
        return parse_seeds(text)
    except SweepError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _run(args: argparse.Namespace) -> int:
    if args.publish and args.paths:
        raise UserError("--publish rebuilds the published report of the shipped suite; give no PATH (or --out DIR "
                        "for a report of these scenarios)")
    seeds = args.seeds or (list(PUBLISHED_SEEDS) if args.publish else None)
    scenarios = _scenarios(args.paths)
    out = published.folder(args)
    if seeds:
        scenarios = [dataclasses.replace(s, seed=seed) for s in scenarios for seed in seeds]
    t0 = time.perf_counter()
    results: list[FaultScenarioResult] = []
    # Faults make the controller model warn (backup mode after a suppressed keepalive, say): that is
    # the scenario working, and the report tells it. Only errors (an MMU trip) stay on the console.
    logging.getLogger("emulator").setLevel(max(logging.ERROR, logging.getLogger().level))
    with tqdm(scenarios, unit="scenario", disable=args.no_progress or args.quiet, file=sys.stderr) as bar:
        for scenario in bar:
            bar.set_postfix_str(f"{scenario.name} seed {scenario.seed}")
            name = f"{scenario.name}-seed{scenario.seed}" if seeds else scenario.name
            log_path = None if args.log_dir is None else args.log_dir / f"{name}.jsonl"
            results.append(run_fault_scenario(scenario, log_path=log_path))
    wall = time.perf_counter() - t0
    print(render_table(results))
    for r in results:
        for c in r.failures:
            print(f"FAIL {r.scenario.name} (seed {r.scenario.seed}): {c.label}: expected {c.message}")
    failed = sum(not r.passed for r in results)
    print(f"{len(results) - failed} of {len(results)} scenario runs passed in {wall:.1f} s")
    command = " ".join(["hils faults run", *args.paths, *([f"--seeds {seeds_text(seeds)}"] if seeds else []),
                        *(["--publish"] if args.publish else [])])
    md, js = write_reports(results, out, wall, command)
    print(f"reports: {md} {js}")
    return 1 if failed else 0


def _seconds(t: float | None) -> str:
    return "-" if t is None else f"{t:.3f}"


def _rows(results: Sequence[FaultScenarioResult]) -> list[list[str]]:
    return [[r.scenario.name, str(r.scenario.seed), "PASS" if r.passed else "FAIL", _seconds(r.detection_s),
             _seconds(r.recovery_s), r.timeouts_text(), r.fired_text(), f"{r.wall_s:.2f}"] for r in results]


HEADER = ["scenario", "seed", "result", "detection s", "recovery s", "timeouts", "faults fired", "wall s"]


def render_table(results: Sequence[FaultScenarioResult]) -> str:
    rows = [HEADER, *_rows(results)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(HEADER))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def render_markdown(results: Sequence[FaultScenarioResult], wall_s: float, command: str) -> str:
    """The report of a suite's runs, ``command`` the command line that made it."""
    failed = sum(not r.passed for r in results)
    out = [
        "# Fault scenarios",
        "",
        f"{len(results) - failed} of {len(results)} scenario runs passed; the suite took {wall_s:.1f} s of wall time "
        f"for {sum(r.scenario.duration for r in results):g} s of virtual time. Generated by `{command}`.",
        "",
        "Detection: seconds from the fault's first firing (or, where stated, from the dispatch of the command "
        "that timed out) to TIMEOUT. Recovery: the slowest TIMEOUT's seconds from the `recover()` call that "
        "succeeded back to IDLE. Faults fired: how often each fault actually acted. A scenario of several "
        "controllers is judged at each intersection; its row gives the slowest detection and recovery, and its "
        "section a table of every intersection's outcome.",
        "",
        "| " + " | ".join(HEADER) + " |",
        "|" + "|".join("---" for _ in HEADER) + "|",
    ]
    out += ["| " + " | ".join(row) + " |" for row in _rows(results)]
    for r in results:
        s = r.scenario
        out += ["", f"## {s.name} (seed {s.seed}): {'PASS' if r.passed else 'FAIL'}", "", s.description or "", "",
                f"`{_display(s.source)}`: {s.action_type.value} actions, agent {s.agent or 'default'}, "
                f"{s.duration:g} s, seed {s.seed}"
                + (f", controllers {', '.join(s.intersections)}." if s.several else "."), ""]
        if s.several:
            out += [*_intersection_table(r), ""]
        for f in r.faults:
            details = "".join(f", {k} {v}" for k, v in f.details.items())
            first = "" if f.first_fired is None else f", first at {f.first_fired:.3f} s"
            where = "" if f.intersection is None else f" at {f.intersection}"
            out.append(f"- fault `{f.name}`{where} ({f.description}): fired {f.fired} times{first}{details}")
        for e in r.episodes:
            rec = "never recovered" if e.recovered is None else (
                f"recover() at {e.recovery_called:.3f} s, IDLE at {e.recovered:.3f} s")
            where = "" if e.intersection is None else f" at {e.intersection}"
            out.append(f"- TIMEOUT{where} ({e.reason}) at {e.entered:.3f} s; {rec}"
                       + (f" ({e.failed_recoveries} recover() calls failed before)" if e.failed_recoveries else ""))
        for c in r.checks:
            out.append(f"- {'ok' if c.ok else '**FAILED**'} {c.label}: {c.message}")
    return "\n".join(out) + "\n"


def _intersection_table(result: FaultScenarioResult) -> list[str]:
    """One row per intersection of a run of several controllers: what acted on it and how it fared."""
    header = ["intersection", "result", "faults", "timeouts", "detection s", "recovery s", "transitions verified",
              "longest without one s"]
    rows = []
    for o in result.outcomes:
        start, end = o.longest_unverified
        rows.append([o.intersection, "PASS" if result.passed_at(o.intersection) else "FAIL",
                     ", ".join(o.faults) or "-", ", ".join(e.reason for e in o.episodes) or "none",
                     _seconds(o.detection_s), _seconds(o.recovery_s), str(o.verified),
                     f"{end - start:.1f} ({start:.1f}-{end:.1f})"])
    return ["| " + " | ".join(row) + " |" for row in (header, ["---"] * len(header), *rows)]


def _display(source: str) -> str:
    """A scenario's path relative to the working directory when it is below it."""
    path = Path(source).resolve()
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else source


def write_reports(results: Sequence[FaultScenarioResult], report_dir: Path, wall_s: float, command: str
                  ) -> tuple[Path, Path]:
    """faults.md and faults.json in ``report_dir`` (made before the runs)."""
    md = report_dir / "faults.md"
    js = report_dir / "faults.json"
    write_whole(md, render_markdown(results, wall_s, command))  # a full disk leaves the report as it was
    doc = {
        "passed": sum(r.passed for r in results),
        "failed": sum(not r.passed for r in results),
        "wall_s": round(wall_s, 3),
        "scenarios": [r.to_json() for r in results],
    }
    write_whole(js, jsonout.dumps(doc) + "\n")
    return md, js
