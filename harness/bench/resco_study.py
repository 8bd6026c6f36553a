"""The RESCO study: how much of max-pressure's gain over fixed-time survives a real controller.

``python -m harness.bench.resco_study --seeds 0-4`` runs, on every RESCO scenario, max-pressure and fixed-time under
sumo-rl's direct switching and under hils' emulated NEMA controllers (same network, same demand, same seeds),
and writes (to the published ``reports/resco/`` with ``--publish``; else to ``--out`` or a new folder:
:mod:`harness.published`) ``results.json`` (every run's RESCO figures and the aggregates) and ``README.md``
(method, what differs between the sides and why, the tables with 95 % confidence intervals, the gains).

Rules of this module
--------------------
- A *cell* is one run: scenario x agent x side x seed (:class:`Cell`). Each runs in a fresh process (a pool of
  ``--workers``, one task per process: libsumo holds one simulation per process) and leaves one small JSON file,
  ``cells/SCENARIO/SIDE-AGENT-seedN.json``, with its figures, its wall time, the commit it ran at and the machine.
  A cell whose file exists for the same run is not run again: the same duration and the same code
  (:func:`code_digest`: hils', the emulator's and the peer's files, sumo-rl's and SUMO's versions). The study
  resumes where it stopped and grows with new seeds or scenarios; a change of the code runs every cell again (a
  cell kept from other code would mix two controllers in one table); ``--force`` runs every asked cell again. A
  cell that fails leaves no file (it is run at the next call) and the study says which, and exits with status 1.
- hils' side is one `hils run` per cell (:func:`hils.sweep.grid.run_cell`, as `hils compare` runs it); sumo-rl's side
  is :func:`harness.reference.sumo_rl_peer.episode` (how it runs and what is matched: that module's header). Both give
  RESCO's four figures from SUMO's tripinfo and the queue sampled at every decision, by
  :mod:`hils.sim.resco_metrics`.
- The figures are the mean over the seeds with the half width of its 95 % confidence interval (Student's t,
  :class:`hils.sweep.compare.Estimate`). A gain is computed seed by seed (fixed-time's delay minus max-pressure's at the
  same seed, on the same side) and estimated the same way; what survives is the ratio of hils' mean gain to
  sumo-rl's, where sumo-rl's is a gain (positive): where max-pressure does worse than fixed-time under sumo-rl,
  there is nothing to survive and the study says so.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from harness import published
from harness.bench import machine
from harness.bench.seeds import seeds_text
from hils.protocol.errors import UserError
from hils.report import jsonout
from hils.sweep.compare import Estimate

__all__ = ["AGENTS", "FIGURES", "SIDES", "Cell", "aggregate", "cells", "main", "render_readme", "run_cell"]

#: The two agents, as hils names them (hils.agents.builtin): fixed-time is the fixed-cycle agent.
AGENTS = ("max-pressure", "fixed-cycle")
#: The sides: sumo-rl switching SUMO's lights itself, hils' controllers.
SIDES = ("sumo_rl", "hils")
SIDE_LABELS = {"sumo_rl": "sumo-rl", "hils": "hils"}
AGENT_LABELS = {"max-pressure": "max-pressure", "fixed-cycle": "fixed-time"}
#: RESCO's figures, from SUMO's tripinfo (hils.sim.resco_metrics), and how the tables name them.
FIGURES = {"delay_s": "delay s", "trip_time_s": "trip time s", "waiting_time_s": "waiting s", "queue": "queue"}


@dataclass(frozen=True, slots=True)
class Cell:
    """One run of the study."""

    scenario: str
    agent: str
    side: str
    seed: int
    duration: float = 3600.0

    def path(self, root: Path) -> Path:
        return root / "cells" / self.scenario / f"{self.side}-{self.agent}-seed{self.seed}.json"


def cells(scenarios: Sequence[str], agents: Sequence[str], seeds: Sequence[int], duration: float) -> list[Cell]:
    """Every cell, scenario after scenario, agent after agent, seed after seed, the two sides side by side."""
    return [Cell(scenario, agent, side, seed, duration)
            for scenario in scenarios for agent in agents for seed in seeds for side in SIDES]


def run_cell(cell: Cell) -> dict[str, Any]:
    """Run one cell (in a fresh process): its RESCO figures, vehicles counted, wall seconds, and on hils' side the
    TIMEOUTs its controllers entered."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hils-resco-study-") as tmp:
        if cell.side == "hils":
            from hils.sweep.grid import Cell as RunCell
            from hils.sweep.grid import native_action_type
            from hils.sweep.grid import run_cell as run_hils

            result = run_hils(RunCell(cell.agent, cell.seed, f"resco:{cell.scenario}", native_action_type(cell.agent),
                                      cell.duration), tmp)
            if not result.ok:
                raise RuntimeError(f"hils run failed: {result.error}")
            resco = {k: v for k, v in result.summary["traffic"]["resco"].items() if k != "notes"}
            extra = {"timeouts": result.figures["timeouts"]}
        else:
            from harness.reference.sumo_rl_peer import episode

            run = episode(cell.seed, scenario=cell.scenario, duration=cell.duration, agent=cell.agent,
                          tripinfo=Path(tmp) / "tripinfo.xml")
            resco = {k: v for k, v in asdict(run["resco"]).items() if k != "notes"}
            extra = {}
    return {"cell": asdict(cell), "code": code_digest(), "resco": resco, **extra,
            "wall_s": time.perf_counter() - started, "commit": _commit(), "machine": machine.describe()}


def code_digest() -> str:
    """What a run's figures depend on besides its cell: every file of hils and of the emulator (code and data), the
    peer's module, and the versions of sumo-rl and SUMO."""
    import hashlib
    import importlib.metadata

    import emulator
    import hils

    digest = hashlib.sha256()
    roots = [Path(hils.__file__).parent, Path(emulator.__file__).parent]
    files = [(root.name, f) for root in roots for f in sorted(root.rglob("*"))
             if f.is_file() and "__pycache__" not in f.parts]
    files.append(("harness", Path(__file__).parents[1] / "reference" / "sumo_rl_peer.py"))
    for top, f in files:
        digest.update(f"{top}/{f.name}\0".encode())
        digest.update(f.read_bytes())
    for dist in ("sumo-rl", "eclipse-sumo", "libsumo"):
        digest.update(f"{dist}=={importlib.metadata.version(dist)}\0".encode())
    return digest.hexdigest()[:16]


def _commit() -> str | None:
    """The commit the code ran at (None outside a git checkout)."""
    done = subprocess.run(["git", "-C", str(Path(__file__).parent), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True, check=False)
    return done.stdout.strip() or None


def run(todo: Sequence[Cell], root: Path, *, workers: int, force: bool = False, progress: bool = True
        ) -> tuple[list[dict[str, Any]], dict[Cell, str]]:
    """Every cell of ``todo``: read from its file when it ran before with the same duration and code (unless
    ``force``), else run in a fresh process and written. Returns the results in the order of ``todo`` and the
    failures."""
    from tqdm import tqdm

    done: dict[Cell, dict[str, Any]] = {}
    pending = []
    code = code_digest()
    for cell in todo:
        cached = _cached(cell, root, code) if not force else None
        if cached is not None:
            done[cell] = cached
        else:
            pending.append(cell)
    failed: dict[Cell, str] = {}
    if pending:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(workers, len(pending)), mp_context=context, max_tasks_per_child=1) as pool, \
                tqdm(total=len(pending), unit="run", disable=None if progress else True, file=sys.stderr) as bar:
            futures = {pool.submit(run_cell, cell): cell for cell in pending}
            for future in as_completed(futures):
                cell = futures[future]
                try:
                    done[cell] = future.result()
                except Exception as exc:  # a cell's failure is reported, the study goes on
                    failed[cell] = f"{type(exc).__name__}: {exc}"
                else:
                    path = cell.path(root)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_text(jsonout.dumps(done[cell]) + "\n", encoding="utf-8")
                bar.update()
    return [done[c] for c in todo if c in done], failed


def _cached(cell: Cell, root: Path, code: str) -> dict[str, Any] | None:
    path = cell.path(root)
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None  # unreadable: run it again
    return result if result.get("cell") == asdict(cell) and result.get("code") == code else None


# --- aggregates ------------------------------------------------------------------------------------


def aggregate(results: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Per scenario: per agent and side, each figure over the seeds; per side, max-pressure's gain over fixed-time
    in delay (seconds and share of fixed-time's, seed by seed); per agent, hils' delay minus sumo-rl's (seed by
    seed); and the share of sumo-rl's mean gain that survives on hils."""
    by: dict[str, dict[tuple[str, str], dict[int, Mapping[str, Any]]]] = {}
    for r in results:
        c = r["cell"]
        by.setdefault(c["scenario"], {}).setdefault((c["agent"], c["side"]), {})[c["seed"]] = r["resco"]
    out: dict[str, Any] = {}
    for scenario, runs in by.items():
        figures = {f"{agent}/{side}": {name: _estimate(v.get(name) for v in seeds.values()) for name in FIGURES}
                   for (agent, side), seeds in runs.items()}
        gains = {}
        for side in SIDES:
            mp, ft = runs.get(("max-pressure", side), {}), runs.get(("fixed-cycle", side), {})
            common = sorted(set(mp) & set(ft))
            gains[side] = {"delay_s": _estimate(ft[s]["delay_s"] - mp[s]["delay_s"] for s in common),
                           "share": _estimate(1 - mp[s]["delay_s"] / ft[s]["delay_s"] for s in common)}
        costs = {}
        for agent in AGENTS:
            h, p = runs.get((agent, "hils"), {}), runs.get((agent, "sumo_rl"), {})
            common = sorted(set(h) & set(p))
            costs[agent] = _estimate(h[s]["delay_s"] - p[s]["delay_s"] for s in common)
        peer, ours = gains["sumo_rl"]["delay_s"], gains["hils"]["delay_s"]
        gained = peer["mean"] is not None and peer["mean"] > 0 and ours["mean"] is not None
        survives = ours["mean"] / peer["mean"] if gained else None
        out[scenario] = {"figures": figures, "gain": gains, "hils_minus_sumo_rl_delay_s": costs,
                         "gain_surviving": survives,
                         "seeds": sorted({s for seeds in runs.values() for s in seeds})}
    return out


def _estimate(values: Iterable[float | None]) -> dict[str, Any]:
    return asdict(Estimate.of([v for v in values if v is not None]))


def _text(e: Mapping[str, Any], digits: int = 1, scale: float = 1.0) -> str:
    """An estimate as the tables print it, ``mean ± half width``, both scaled (a negative scale turns the sign)."""
    mean, half = e["mean"], e["half_width"]
    return Estimate(None if mean is None else mean * scale, None if half is None else abs(half * scale),
                    e["n"]).text(digits)


# --- the README ------------------------------------------------------------------------------------

_METHOD = """\
# RESCO on real controllers: how much of max-pressure's gain survives

RL signal-control papers compare agents on RESCO (Ault & Sharon, NeurIPS 2021 datasets and benchmarks track),
usually through sumo-rl, which switches SUMO's lights itself: it shows the chosen stage at once after a yellow of
its own, with no all-red and no controller between the agent and the lights. A real signal controller serves a
call only within its rules: each phase's minimum green, its yellow and red clearance, the ring-and-barrier
structure (two rings, crossing a barrier together). This study measures what that does to a benchmark result:
max-pressure's gain over fixed-time on every RESCO scenario, under sumo-rl's direct switching and under hils'
emulated NEMA controllers (NTCIP 1202, driven phase by phase through hils' middleware in virtual time), on the
same network, demand and seeds.

## Method

- **Scenarios**: RESCO's eight ({scenarios}), read from sumo-rl {sumo_rl} (`sumo_rl/nets/RESCO`), each from its
  begin time (cologne 25200 s, ingolstadt 57600 s) for {duration} simulated seconds, as RESCO evaluates.
- **Seeds**: {seeds} (SUMO's `--seed`; the demand is the scenario's route file on both sides).
- **Agents**, one definition for both sides (hils' own classes, `hils/agents/builtin.py`, asked the same way on each
  side):
  - *max-pressure* (Varaiya 2013): at every decision, the stage whose two phases' movements have the largest
    summed pressure (halting vehicles on the movement's incoming lanes minus on its outgoing lanes; ties keep the
    stage shown, then the first in the program's order);
  - *fixed-time* (hils' `fixed-cycle`): at every decision, advance to the next stage of the program's order.
  Decisions every RESCO step length: 10 s (5 s on arterial4x4).
- **sumo-rl's side**: sumo-rl's `SumoEnvironment(single_agent=False)` stepped directly (its PettingZoo wrapper
  does not start with pettingzoo 1.27: `agent_selector` is now `AgentSelector`), through libsumo, 0.25 s SUMO
  steps. Its actions are the program's green phases, matched one to one to the stages hils' controllers serve.
  Each light is given the yellow and minimum green of hils' derived config for it, in sumo-rl's unit (SUMO steps:
  its TrafficSignal counts both in `update()` calls, one per step); the minimum green of the stage being shown,
  before every decision.
- **hils' side**: `hils run --scenario resco:NAME --agent AGENT` (one emulated NEMA controller per light, its
  config derived from the light's SUMO program: `hils/protocol/resco.py`), virtual time, 0.25 s SUMO steps, 10 Hz polls.
- **Figures**: RESCO's, from SUMO's own tripinfo as RESCO's code computes them (`hils/sim/resco_metrics.py` quotes
  it), the same code on both sides: *delay* is timeLoss + departDelay over every vehicle due by the end (arrived,
  still running, never entered); *trip time* and *waiting time* the mean duration and waitingTime of the vehicles
  that entered; *queue* the vehicles stopped within 200 m of a light on its incoming lanes, per decision step,
  averaged over the lights and the steps. Each figure is the mean over the seeds ± the half width of its 95 %
  confidence interval (Student's t, n - 1 degrees of freedom).
- **Gain**: fixed-time's delay minus max-pressure's, seed by seed on one side (and as a share of fixed-time's),
  estimated the same way; *surviving* is hils' mean gain over sumo-rl's.

## What differs between the two sides, and why

The network, demand, seeds, step length, decision times, agents, yellow and minimum green are the same. The
controller is not, on purpose: that is the question.

- **All-red**: sumo-rl inserts none; hils' controller times each phase's red clearance after its yellow (the
  program's all-red where it has one, else 0.1 s, one controller tick: the least a NEMA config allows).
- **Ring and barrier**: sumo-rl shows a stage whole, at once; hils' controller ends each ring's phase at its own
  minimum green and crosses a barrier only when both rings are ready, so a stage change can take longer than
  yellow plus all-red.
- **Control path**: sumo-rl sets SUMO's state on the step it decides; hils' middleware SETs the phases' calls over
  NTCIP (modeled latency), the controller acts on its 0.1 s tick, and the manager verifies the transition by 10 Hz
  polls before it takes the next decision (a decision that comes while a transition is unverified is dropped, as
  the paper's middleware prescribes).
- **What the agent sees**: the same pressure definition on both sides; hils' agent reads it through the testbed's
  observation, sumo-rl's from libsumo at the same decision times.
- One ingolstadt21 light (cluster_1427494838_273472399) has a program phase that is green only on links that
  control no connection: it is an action in sumo-rl's space, a stage of neither RESCO nor hils, and neither agent
  chooses it.

## Reproduce

```sh
pip install -e '.[resco]'
python -m harness.bench.resco_study --seeds {seeds} --duration {duration_arg} --publish  # resumes: reads back its cells
```

Each run (cell) is one fresh process; its figures go to `cells/SCENARIO/SIDE-AGENT-seedN.json` as it finishes, so
a study that stops resumes where it stopped, and more seeds or scenarios add cells (`--force` runs them again).
{timing}
"""


def render_readme(table: Mapping[str, Any], meta: Mapping[str, Any]) -> str:
    """The study's README from its aggregates (:func:`aggregate`) and what it ran (seeds, duration, versions)."""
    text = _METHOD.format(**meta)
    lines = [text, "## Results", "",
             "RESCO's figures, mean ± 95 % confidence half width over the seeds (n per cell in the last column)."]
    if any(f["delay_s"]["n"] < 2 for s in table.values() for f in s["figures"].values()):
        lines.append("Where n is 1 there is no interval: the figure is one run, and every comparison below is as "
                     "uncertain as that.")
    lines.append("")
    lines += ["| scenario | agent | side | " + " | ".join(FIGURES.values()) + " | n |",
              "|---|---|---|" + "---:|" * len(FIGURES) + "---:|"]
    for scenario, s in table.items():
        for agent in AGENTS:
            for side in SIDES:
                f = s["figures"].get(f"{agent}/{side}")
                if f is None:
                    continue
                digits = {"queue": 2}
                lines.append(f"| {scenario} | {AGENT_LABELS[agent]} | {SIDE_LABELS[side]} | "
                             + " | ".join(_text(f[name], digits.get(name, 1)) for name in FIGURES)
                             + f" | {f['delay_s']['n']} |")
    lines += ["", "### Max-pressure's gain over fixed-time (RESCO delay), and how much of it survives", "",
              "| scenario | gain, sumo-rl (s) | gain, hils (s) | gain, sumo-rl (%) | gain, hils (%) | surviving "
              "| hils - sumo-rl, max-pressure (s) | hils - sumo-rl, fixed-time (s) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for scenario, s in table.items():
        g, c = s["gain"], s["hils_minus_sumo_rl_delay_s"]
        survives = "-" if s["gain_surviving"] is None else f"{s['gain_surviving']:.0%}"
        lines.append(f"| {scenario} | {_text(g['sumo_rl']['delay_s'])} | {_text(g['hils']['delay_s'])} | "
                     f"{_text(g['sumo_rl']['share'], 0, 100)} | {_text(g['hils']['share'], 0, 100)} | {survives} | "
                     f"{_text(c['max-pressure'])} | {_text(c['fixed-cycle'])} |")
    lines += ["", "*surviving*: hils' mean gain over sumo-rl's (none where sumo-rl's is no gain). A gain below zero: "
              "max-pressure's delay above fixed-time's. The last two columns: what a real controller costs "
              "each agent in RESCO delay (hils' minus sumo-rl's, seed by seed).", ""]
    lines += _findings(table)
    return "\n".join(lines).rstrip() + "\n"


def _findings(table: Mapping[str, Any]) -> list[str]:
    """Sentences a reader can quote, one per scenario, from the figures."""
    out = ["## In one sentence per scenario", ""]
    for scenario, s in table.items():
        g = s["gain"]
        if g["sumo_rl"]["delay_s"]["mean"] is None or g["hils"]["delay_s"]["mean"] is None:
            out.append(f"- {scenario}: incomplete (a side or an agent has no run).")
            continue
        peer, ours = (_effect(g[side]) for side in SIDES)
        if peer[0] == ours[0]:  # the same verb: said once
            said = f"{peer[0]} {peer[1]} under sumo-rl's switching and {ours[1]} under hils' NEMA controllers"
        else:
            said = f"{' '.join(peer)} under sumo-rl's switching but {' '.join(ours)} under hils' NEMA controllers"
        if s["gain_surviving"] is not None:
            tail = f": {s['gain_surviving']:.0%} of the gain survives."
        else:
            tail = ": with no gain under sumo-rl, there is none to survive."
        out.append(f"- {scenario}: max-pressure {said}{tail}")
    return out


def _effect(gain: Mapping[str, Any]) -> tuple[str, str]:
    """A gain in words: a cut in RESCO's delay, or (below zero) an addition to it; the verb and the amount."""
    delay, share = gain["delay_s"], gain["share"]
    if delay["mean"] >= 0:
        return "cuts RESCO's delay", f"by {_text(delay)} s ({_text(share, 0, 100)} %)"
    return "adds to RESCO's delay", f"{_text(delay, 1, -1)} s (+{_text(share, 0, -100)} % of fixed-time's)"


def _meta(results: Sequence[Mapping[str, Any]], seeds: Sequence[int], duration: float,
          scenarios: Sequence[str]) -> dict[str, Any]:
    import importlib.metadata

    from hils.protocol import resco

    chosen = "" if list(scenarios) == list(resco.NAMES) else f" --scenarios {','.join(scenarios)}"
    return {"scenarios": ", ".join(scenarios), "sumo_rl": importlib.metadata.version("sumo-rl"),
            "duration": f"{duration:g}", "seeds": seeds_text(seeds),
            "duration_arg": f"{duration:g}{chosen}", "timing": _timing(results)}


def _timing(results: Sequence[Mapping[str, Any]]) -> str:
    """How long the runs took: per scenario and side, the median seconds of one run, and the total."""
    if not results:
        return ""
    walls: dict[str, dict[str, list[float]]] = {}
    for r in results:
        walls.setdefault(r["cell"]["scenario"], {}).setdefault(r["cell"]["side"], []).append(r["wall_s"])
    commits = sorted({r.get("commit") or "?" for r in results})
    first = results[0]["machine"]
    total = sum(r["wall_s"] for r in results)
    lines = [f"The {len(results)} runs of this report took {total / 60:.0f} min of run time in all, each on one core "
             f"of {first['cpu']} ({first['cores']} cores; `--workers` runs that many at once), at commit"
             f"{'s' if len(commits) > 1 else ''} {', '.join(commits)}; one run, median seconds (start-up, the "
             "simulated time, and RESCO's figures from the tripinfo):", "",
             "| scenario | " + " | ".join(SIDE_LABELS[s] for s in SIDES) + " |", "|---|" + "---:|" * len(SIDES)]
    for scenario, by_side in walls.items():
        lines.append(f"| {scenario} | " + " | ".join(f"{statistics.median(by_side[s]):.0f}" if s in by_side else "-"
                                                     for s in SIDES) + " |")
    return "\n".join(lines)


# --- the command -----------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    from hils.protocol import resco
    from hils.sweep.grid import SweepError, parse_seeds

    parser = argparse.ArgumentParser(
        prog="python -m harness.bench.resco_study",
        description="Max-pressure and fixed-time on RESCO's scenarios under sumo-rl's direct switching and under "
                    "hils' NEMA controllers (same network, demand and seeds): RESCO's figures with 95 %% confidence "
                    "intervals, max-pressure's gain on each side and how much of it survives, written to "
                    "OUT/results.json and OUT/README.md (OUT: --out DIR, the published reports/resco/ with "
                    "--publish, else a new reports/runs/<time>-resco-study/). Every run is a fresh process whose "
                    "figures are kept in OUT/cells/: a second call with the same OUT resumes (cells already run are "
                    "read back). Needs sumo-rl: pip install 'hils[resco]'.")
    parser.add_argument("--scenarios", default="all", metavar="NAME,...|all",
                        help=f"RESCO scenarios (all: {','.join(resco.NAMES)})")
    parser.add_argument("--seeds", default="0-4", metavar="LIST", help="seeds, e.g. 0-4 or 0,3,7 (0-4)")
    parser.add_argument("--duration", type=float, default=3600.0, metavar="S",
                        help="simulated seconds from each scenario's begin (3600, as RESCO evaluates)")
    parser.add_argument("--workers", type=int, default=multiprocessing.cpu_count(), metavar="N",
                        help="runs at once, each in its own process (the CPUs)")
    published.options(parser, "resco-study", "resco")
    parser.add_argument("--force", action="store_true", help="run every cell again, even those already run")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    names = list(resco.NAMES) if args.scenarios == "all" else [n.strip().removeprefix("resco:")
                                                                for n in args.scenarios.split(",")]
    unknown = [n for n in names if n not in resco.NAMES]
    if unknown:
        parser.error(f"--scenarios: {', '.join(unknown)}: allowed: all, or some of {','.join(resco.NAMES)}")
    try:
        seeds = parse_seeds(args.seeds)
    except SweepError as exc:
        parser.error(str(exc))
    if not args.duration > 0 or args.workers < 1:
        parser.error("--duration: allowed: positive seconds; --workers: 1 or more")
    try:
        out = published.folder(args)
    except UserError as exc:
        parser.error(str(exc))
    todo = cells(names, AGENTS, seeds, args.duration)
    results, failed = run(todo, out, workers=args.workers, force=args.force, progress=not args.no_progress)
    table = aggregate(results)
    meta = _meta(results, seeds, args.duration, names)
    (out / "results.json").write_text(jsonout.dumps({
        "seeds": seeds, "duration_s": args.duration, "scenarios": names, "agents": list(AGENTS),
        "sides": list(SIDES), "aggregates": table, "runs": results,
        "failed": [{"cell": asdict(c), "error": e} for c, e in failed.items()]}) + "\n", encoding="utf-8")
    (out / "README.md").write_text(render_readme(table, meta), encoding="utf-8")
    print(render_console(table))
    print(f"written: {out / 'results.json'}, {out / 'README.md'} ({len(results)} runs, "
          f"{len(todo) - len(results)} missing)")
    for cell, error in failed.items():
        print(f"failed: {cell.scenario} {cell.agent} {SIDE_LABELS[cell.side]} seed {cell.seed}: {error}",
              file=sys.stderr)
    return 1 if failed else 0


def render_console(table: Mapping[str, Any]) -> str:
    """RESCO delay per scenario, agent and side, and the gain surviving."""
    head = f"{'scenario':<13} {'agent':<13} {'sumo-rl delay s':>16} {'hils delay s':>16}"
    lines = [head, "-" * len(head)]
    for scenario, s in table.items():
        for agent in AGENTS:
            cells_ = [s["figures"].get(f"{agent}/{side}") for side in SIDES]
            lines.append(f"{scenario:<13} {AGENT_LABELS[agent]:<13} "
                         + " ".join(f"{_text(c['delay_s']) if c else '-':>16}" for c in cells_))
        survives = "-" if s["gain_surviving"] is None else f"{s['gain_surviving']:.0%}"
        lines.append(f"{'':<13} gain surviving on hils: {survives}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
