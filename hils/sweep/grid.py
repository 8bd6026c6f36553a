"""Sweeps: a grid of agents x seeds x scenarios, each cell one `hils run`, on a process pool or on Ray.

Rules of this module
--------------------
- One code path: every cell runs through :func:`run_cell`, the same function in a pool worker or in a
  Ray task. It runs `hils run` with the cell's arguments into the cell's own run folder (the layout
  `hils run --out` gives: events.jsonl, summary.json, plots, and the console in console.txt) and
  returns what that summary says.
- Every cell runs in a fresh process of its own, never after another cell in one: a libsumo run
  depends on what its process did before (:mod:`hils.sim.sumo`), and a cell must give what `hils run`
  gives it.
- A cell that fails is a row with its error; the sweep goes on and its table keeps every cell.
- Results come back in grid order, whatever order the workers finish in, so a sweep's table is
  reproducible from its seeds (virtual time), whichever backend ran it.
- The backends are an existing engine each: :mod:`concurrent.futures` processes (spawned, one SUMO
  per process) on one machine, Ray (`pip install 'hils[ray]'`) beyond it. Ray is imported only when
  asked for.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import multiprocessing
import os
import re
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from hils.agents.builtin import BUILTIN
from hils.control.actions import ActionType
from hils.protocol.errors import UserError
from hils.protocol.resco import NAMES as RESCO_NAMES
from hils.protocol.scenario import RESCO_PREFIX, SCENARIOS, SUFFIX
from hils.report import jsonout

__all__ = [
    "ATSPM_FIGURES", "COLUMNS", "SHIPPED", "Cell", "CellResult", "Progress", "SweepError", "figures", "grid",
    "native_action_type", "parse_seeds", "render", "rows", "run_cell", "run_grid", "scenario_arguments",
    "write_table",
]

#: The ATSPM figures of a run's record a sweep's table and `hils compare` carry (``atspm_<name>``).
ATSPM_FIGURES = ("split_failures", "percent_on_green", "max_outs", "force_offs")

#: The shipped scenarios of one light: `hils run` arguments that select them (the four-leg is the default run).
SHIPPED = ("four_leg", "four_phase")
#: Scenarios of several lights, run with `hils run --scenario`: the shipped ones and RESCO's (resco:NAME).
NETWORKS = tuple(s for s in SCENARIOS if s not in SHIPPED)
_ALLOWED = (f"{', '.join(SHIPPED + NETWORKS)}, {', '.join(RESCO_PREFIX + n for n in RESCO_NAMES)}, a .scenario.toml "
            "file or CONFIG.toml[@SCENARIO.sumocfg]")


class SweepError(UserError):
    """A sweep that cannot run as asked: a bad grid or an unavailable backend."""


@dataclass(frozen=True, slots=True)
class Cell:
    """One run of the grid."""

    agent: str
    seed: int
    scenario: str = "four_leg"
    action_type: str = "selection"
    duration: float = 3600.0

    @property
    def name(self) -> str:
        """The cell's run folder name: readable and unique within the grid."""
        agent = re.sub(r"[^A-Za-z0-9_.-]+", "_", self.agent)
        scenario = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(self.scenario.split("@")[0]).stem)
        return f"{scenario}-{self.action_type}-{agent}-seed{self.seed}"


@dataclass(frozen=True, slots=True)
class CellResult:
    """What one cell gave: its folder, whether it ran, and the figures of its summary."""

    cell: Cell
    folder: str
    ok: bool
    error: str | None = None
    figures: dict[str, Any] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)


def scenario_arguments(scenario: str) -> list[str]:
    """`hils run` arguments of a scenario: a shipped name, resco:NAME, a .scenario.toml file, or
    CONFIG.toml[@SCENARIO.sumocfg]."""
    if scenario == "four_leg":
        return []
    if scenario in SHIPPED:
        data = resources.files("hils.data")
        return ["--config", str(data / f"{scenario}.toml"), "--sumocfg", str(data / f"{scenario}.sumocfg")]
    if scenario in NETWORKS or scenario.endswith(SUFFIX) or (
            scenario.startswith(RESCO_PREFIX) and scenario.removeprefix(RESCO_PREFIX) in RESCO_NAMES):
        return ["--scenario", scenario]
    config, _, sumocfg = scenario.partition("@")
    if not config.endswith(".toml") or config.endswith(SUFFIX):
        raise SweepError(f"scenario {scenario!r}: allowed: {_ALLOWED}")
    return ["--config", config, *(["--sumocfg", sumocfg] if sumocfg else [])]


def grid(agents: Sequence[str], seeds: Sequence[int], scenarios: Sequence[str] = ("four_leg",), *,
         action_type: str | None = None, duration: float = 3600.0) -> list[Cell]:
    """Every combination, scenario-major then agent then seed; without ``action_type``, each agent's own."""
    if not agents or not seeds or not scenarios:
        raise SweepError("a sweep needs at least one agent, one seed and one scenario")
    for scenario in scenarios:
        scenario_arguments(scenario)
    return [Cell(a, s, sc, action_type or native_action_type(a), duration)
            for sc in scenarios for a in agents for s in seeds]


def native_action_type(agent: str) -> str:
    """The action type a built-in agent issues (selection for one that takes any, and for user agents)."""
    own = getattr(BUILTIN.get(agent), "action_type", None)
    return own.value if isinstance(own, ActionType) else ActionType.SELECTION.value


def run_cell(cell: Cell, root: str) -> CellResult:
    """Run one cell as `hils run` would, into ``root/<cell name>``; never raises for a failed run."""
    from hils.cli.main import main  # here, not at import: a Ray worker imports this module first

    folder = Path(root) / cell.name
    folder.mkdir(parents=True, exist_ok=True)
    argv = ["--quiet", "run", "--no-progress", "--out", str(folder), "--agent", cell.agent, "--seed", str(cell.seed),
            "--action-type", cell.action_type, "--duration", f"{cell.duration:g}", *scenario_arguments(cell.scenario)]
    console = io.StringIO()
    try:
        with contextlib.redirect_stdout(console), contextlib.redirect_stderr(console):
            code = main(argv)
    except Exception as exc:  # a cell's crash is its row, not the sweep's end
        code, console = 1, io.StringIO(console.getvalue() + f"\n{type(exc).__name__}: {exc}\n")
    (folder / "console.txt").write_text(console.getvalue(), encoding="utf-8")
    summary_path = folder / "summary.json"
    if code != 0 or not summary_path.exists():
        last = [line for line in console.getvalue().splitlines() if line.strip()][-1:] or [f"exit status {code}"]
        return CellResult(cell, str(folder), False, last[0])
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    return CellResult(cell, str(folder), True, None, figures(summary), summary)


def figures(summary: dict[str, Any]) -> dict[str, Any]:
    """The per-run figures a sweep's table shows, from one summary.json."""
    traffic = summary.get("traffic") or {}
    queues = traffic.get("max_queue") or {}
    resco = traffic.get("resco") or {}
    controls = list((summary.get("intersections") or {"": summary}).values())
    atspm = (summary.get("record") or {}).get("atspm") or {}
    return {
        "resco_delay_s": resco.get("delay_s"),
        "resco_trip_time_s": resco.get("trip_time_s"),
        "resco_waiting_time_s": resco.get("waiting_time_s"),
        "resco_queue": resco.get("queue"),
        "mean_delay_s": traffic.get("mean_delay"),
        "arrived": traffic.get("arrived"),
        "departed": traffic.get("departed"),
        "waiting_to_enter": traffic.get("waiting_to_enter"),
        "max_queue": max(queues.values()) if queues else None,
        # per approach only for a light alone: a network's dozens of approaches make no table
        **({f"max_queue_{a}": q for a, q in sorted(queues.items())} if "intersections" not in summary else {}),
        "timeouts": sum(sum((c.get("timeouts") or {}).values()) for c in controls),
        "wall_s": summary.get("wall_time_s"),
        # ATSPM measures of the controllers' own hi-res logs (hils.report.record), as a DOT states a signal's
        # performance
        **{f"atspm_{name}": atspm.get(name) for name in ATSPM_FIGURES},
    }


Progress = Callable[[CellResult], None]


def run_grid(cells: Sequence[Cell], root: str | Path, *, workers: int | None = None, ray: str | None = None,
             progress: Progress | None = None) -> list[CellResult]:
    """Run every cell, on a local process pool (``workers``, default: the CPUs) or on Ray (``ray``:
    "auto", "local" or a cluster address); the results in the order of ``cells``."""
    root = str(Path(root).resolve())
    Path(root).mkdir(parents=True, exist_ok=True)
    done: dict[int, CellResult] = {}

    def finished(i: int, result: CellResult) -> None:
        done[i] = result
        if progress is not None:
            progress(result)

    if ray is not None:
        _on_ray(cells, root, ray, finished)
    else:
        n = min(len(cells), workers or os.cpu_count() or 1)
        # Spawned workers (a fork of a process that loaded libsumo is not a clean SUMO), each for one cell only
        # (max_tasks_per_child=1): a libsumo run depends on what its process did before (hils.sim.sumo says how).
        # Cells run one after another in one worker drifted from `hils run` (cologne1, coordinated, seed 0, 600 s:
        # RESCO delay 25.009 s against 24.983 s), and a table changed with the order the workers took the cells in.
        with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"), max_tasks_per_child=1) as pool:
            futures = {pool.submit(run_cell, cell, root): i for i, cell in enumerate(cells)}
            for future in as_completed(futures):
                finished(futures[future], future.result())
    return [done[i] for i in range(len(cells))]


def _on_ray(cells: Sequence[Cell], root: str, address: str, finished: Callable[[int, CellResult], None]) -> None:
    try:
        import ray
    except ImportError:
        raise SweepError("--ray needs Ray: pip install 'hils[ray]'") from None
    started = not ray.is_initialized()
    if started:
        # "local" starts a Ray instance for this sweep; "auto" joins the running cluster.
        ray.init(address=None if address == "local" else address, include_dashboard=False,
                 log_to_driver=False, configure_logging=False)
    try:
        remote = ray.remote(max_calls=1)(run_cell)  # a worker process for each cell, as on the local pool
        pending = {remote.remote(cell, root): i for i, cell in enumerate(cells)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                finished(pending.pop(ref), ray.get(ref))
    finally:
        if started:
            ray.shutdown()


# --- the table -------------------------------------------------------------------------------------

COLUMNS = ("scenario", "action_type", "agent", "seed", "ok", "resco_delay_s", "resco_trip_time_s",
           "resco_waiting_time_s", "resco_queue", "mean_delay_s", "arrived", "waiting_to_enter", "max_queue",
           "timeouts", "wall_s", "folder", "error")


def rows(results: Iterable[CellResult]) -> list[dict[str, Any]]:
    return [{**{k: v for k, v in asdict(r.cell).items() if k != "duration"}, "ok": r.ok, **r.figures,
             "folder": r.folder, "error": r.error} for r in results]


def write_table(results: Sequence[CellResult], root: str | Path) -> tuple[Path, Path]:
    """sweep.csv (the columns of :data:`COLUMNS` and every per-approach queue) and sweep.json."""
    table = rows(results)
    extra = sorted({k for row in table for k in row} - set(COLUMNS))
    csv_path, json_path = Path(root) / "sweep.csv", Path(root) / "sweep.json"
    with csv_path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, [*COLUMNS, *extra])
        writer.writeheader()
        writer.writerows(table)
    json_path.write_text(jsonout.dumps({"cells": table}) + "\n", encoding="utf-8")
    return csv_path, json_path


def render(results: Sequence[CellResult]) -> str:
    """The console table: one line per cell."""
    width = max(12, *(len(Path(r.cell.scenario).stem) for r in results))
    head = f"{'scenario':<{width}} {'agent':<20} {'seed':>4}  {'RESCO delay s':>13} {'mean delay s':>12} " \
           f"{'arrived':>8} {'waiting':>8} {'max queue':>9} {'timeouts':>8}"
    lines = [head, "-" * len(head)]
    for r in results:
        c, f = r.cell, r.figures
        if not r.ok:
            lines.append(f"{Path(c.scenario).stem:<{width}} {c.agent:<20} {c.seed:>4}  FAILED: {r.error}")
            continue
        lines.append(f"{Path(c.scenario).stem:<{width}} {c.agent:<20} {c.seed:>4}  {_s(f['resco_delay_s']):>13} "
                     f"{_s(f['mean_delay_s']):>12} {_n(f['arrived']):>8} {_n(f['waiting_to_enter']):>8} "
                     f"{_n(f['max_queue']):>9} {_n(f['timeouts']):>8}")
    return "\n".join(lines)


def _s(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def _n(x: Any) -> str:
    return "-" if x is None else str(x)


def parse_seeds(text: str) -> list[int]:
    """``0-4`` or ``0,3,7`` (or a mix)."""
    out: list[int] = []
    for part in text.split(","):
        a, sep, b = part.strip().partition("-")
        try:
            out += list(range(int(a), int(b) + 1)) if sep else [int(a)]
        except ValueError:
            raise SweepError(f"--seeds {text!r}: allowed: integers and ranges, e.g. 0-4 or 0,3,7") from None
    if not out:
        raise SweepError(f"--seeds {text!r} names no seed")
    return out
