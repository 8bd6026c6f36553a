"""`hils sweep` and `hils compare`: many runs at once, on a local process pool or on Ray."""

from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path
from typing import Any

from hils.control.actions import ActionType
from hils.report import jsonout, outfiles
from hils.sweep import compare
from hils.sweep import grid as sweep

SWEEP_HELP = """\
Run a grid of agents x seeds x scenarios, each cell one `hils run` (virtual time, SUMO) in its own run
folder, and gather their figures in one table (sweep.csv, sweep.json and the console).

Cells run in parallel on a local process pool (--workers, default: the CPUs), or on Ray when one machine
is not enough (pip install 'hils[ray]'; --ray local starts one here, --ray auto joins the running
cluster, or give its address). A cell that fails is a row with its error; the others go on.

Example: hils sweep --agents max-pressure,webster,random --seeds 0-4 --duration 1800
"""

COMPARE_HELP = """\
Compare agents over several seeds: each agent runs once per seed and scenario (a sweep, in parallel
processes), and a table per scenario gives each figure's mean with the half width of its 95 % confidence
interval over the seeds (Student's t): RESCO's average delay, trip time, waiting time and queue (as RL
papers report them, from SUMO's tripinfo), then hils' mean delay, throughput, vehicles waiting to enter,
max queue (and per approach, for one light). Writes compare.md, compare.json and a plot per scenario
(compare.png for one) beside the sweep's table and run folders.

Examples: hils compare --agents max-pressure,webster --seeds 0-4
          hils compare --scenarios resco:cologne8 --agents max-pressure,actuated,coordinated,fixed-time --seeds 0-4
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="a grid of agents x seeds x scenarios on a process pool or Ray",
                       description=SWEEP_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    _grid_options(p)
    p.set_defaults(func=sweep_command)
    p = sub.add_parser("compare", help="agents over seeds: a table with 95 %% confidence intervals, and a plot",
                       description=COMPARE_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    _grid_options(p)
    p.set_defaults(func=compare_command)


def _grid_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--agents", required=True, metavar="A,B,...",
                   help="built-in agent names (random, fixed-cycle, max-pressure, queue-proportional, webster, "
                        "actuated, coordinated, fixed-time) or package.module:Class, comma-separated")
    p.add_argument("--seeds", default="0-2", metavar="0-4|0,3,7", help="seeds (0-2)")
    p.add_argument("--scenarios", "--scenario", default="four_leg", metavar="S,...",
                   help=f"comma-separated: {sweep._ALLOWED} (four_leg)")
    p.add_argument("--action-type", choices=[t.value for t in ActionType],
                   help="the action design every agent uses (default: each agent's own, e.g. webster duration, "
                        "max-pressure selection)")
    p.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds per run (3600)")
    p.add_argument("--workers", type=int, metavar="N", help="local processes (default: the CPUs)")
    p.add_argument("--ray", metavar="local|auto|ADDRESS", help="run the cells on Ray instead of local processes")
    p.add_argument("--out", type=Path, metavar="DIR", help="folder of the table and the run folders "
                                                           "(default: a new reports/runs/<time>-<command>/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _run(args: argparse.Namespace, scenarios: list[str], kind: str) -> tuple[list[sweep.CellResult], Path]:
    if not args.duration > 0:
        raise sweep.SweepError(f"--duration must be positive seconds, got {args.duration:g}")
    if args.workers is not None and args.workers < 1:
        raise sweep.SweepError(f"--workers must be at least 1, got {args.workers}")
    agents = [a.strip() for a in args.agents.split(",") if a.strip()]
    cells = sweep.grid(agents, sweep.parse_seeds(args.seeds), scenarios, action_type=args.action_type,
                       duration=args.duration)
    out = outfiles.given_folder(args.out) if args.out is not None else outfiles.fresh_folder(kind)
    where = f"Ray ({args.ray})" if args.ray else f"local processes ({args.workers or 'one per CPU'})"
    print(f"{len(cells)} runs of {args.duration:g} simulated s on {where}; run folders in {out}/")
    bar = _bar(len(cells)) if not args.no_progress else None
    try:
        results = sweep.run_grid(cells, out, workers=args.workers, ray=args.ray,
                                 progress=(lambda r: bar.update(1)) if bar else None)
    finally:
        if bar is not None:
            bar.close()
    sweep.write_table(results, out)
    return results, out


def _bar(total: int) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, unit="run")


def _scenarios(args: argparse.Namespace) -> list[str]:
    return [s.strip() for s in args.scenarios.split(",") if s.strip()]


def sweep_command(args: argparse.Namespace) -> int:
    results, out = _run(args, _scenarios(args), "sweep")
    print(sweep.render(results))
    print(f"Table in {out}/sweep.csv and sweep.json")
    return 0 if all(r.ok for r in results) else 1


def compare_command(args: argparse.Namespace) -> int:
    scenarios = _scenarios(args)
    results, out = _run(args, scenarios, "compare")
    tables, runs, unmeasured = compare.aggregate(results), compare.runs(results), compare.unmeasured(results)
    markdown, plots = [], []
    terminal = shutil.get_terminal_size((compare.WIDTH, 24)).columns  # the table wraps its columns to fit
    for scenario, table in tables.items():
        why = unmeasured.get(scenario)
        print(f"{scenario}, {args.duration:g} simulated s per run\n"
              f"{compare.render(table, runs[scenario], unmeasured=why, width=terminal)}\n")
        text = compare.render(table, runs[scenario], unmeasured=why)
        plot = "compare.png" if len(tables) == 1 else f"compare-{re.sub(r'[^A-Za-z0-9_.-]+', '_', scenario)}.png"
        compare.plot(table, out / plot, f"{scenario}: mean over seeds with 95 % CI ({args.duration:g} s)",
                     runs[scenario])
        markdown.append(f"## {scenario}, {args.duration:g} s\n\n```\n{text}\n```\n\n![{scenario}]({plot})\n")
        plots.append(plot)
    for r in results:
        if not r.ok:
            print(f"FAILED {r.cell.scenario} {r.cell.agent} seed {r.cell.seed}: {r.error} "
                  f"(see {r.folder}/console.txt)")
    (out / "compare.md").write_text("# hils compare\n\n" + "\n".join(markdown), encoding="utf-8")
    (out / "compare.json").write_text(jsonout.dumps({
        scenario: {agent: {name: {"mean": e.mean, "ci95_half_width": e.half_width, "n": e.n} for name, e in row.items()}
                   for agent, row in table.items()} for scenario, table in tables.items()}) + "\n", encoding="utf-8")
    print(f"Outputs in {out}/: compare.md, compare.json, {', '.join(plots)}, sweep.csv and one run folder per run")
    return 0 if all(r.ok for r in results) else 1
