"""Comparing agents: the figures of several agents over several seeds, each with its 95 % confidence interval.

The runs are a sweep (:mod:`hils.sweep.grid`: one `hils run` per agent and seed, in parallel processes or on
Ray); this module only aggregates them. Per scenario, agent and figure: the mean over the seeds and the half width
of its 95 % confidence interval, Student's t with n - 1 degrees of freedom (seeds are independent runs of
the same demand; with one seed there is no interval and the table says so).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hils.report import atspm
from hils.report.plots import pyplot
from hils.sweep.grid import ATSPM_FIGURES, CellResult

#: The widest a table is drawn (a terminal's usual width): its columns wrap into blocks beyond.
WIDTH = 120

#: Two-sided 95 % quantiles of Student's t by degrees of freedom (1..30); beyond, the normal's 1.96.
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)

#: The figures compared, with how the plot names them: RESCO's four (as RL papers report them, from SUMO's
#: tripinfo: :mod:`hils.sim.resco_metrics`), then hils' own, then ATSPM's (from the controllers' own hi-res logs,
#: :mod:`hils.report.atspm`: as a DOT states a signal's performance; split failures and arrivals on green need the
#: controller to read its detectors).
FIGURES = {
    "resco_delay_s": "RESCO delay (s)",
    "resco_trip_time_s": "RESCO trip time (s)",
    "resco_waiting_time_s": "RESCO waiting time (s)",
    "resco_queue": "RESCO queue (vehicles)",
    "mean_delay_s": "mean delay (s)",
    "arrived": "throughput (vehicles arrived)",
    "waiting_to_enter": "waiting to enter (vehicles)",
    "max_queue": "max queue (vehicles)",
    "atspm_split_failures": "ATSPM split failures",
    "atspm_percent_on_green": "ATSPM arrivals on green (%)",
    "atspm_max_outs": "ATSPM max-outs",
    "atspm_force_offs": "ATSPM force-offs",
}
_LABELS = {"resco_delay_s": "RESCO delay s", "resco_trip_time_s": "trip time s", "resco_waiting_time_s": "waiting s",
           "resco_queue": "RESCO queue", "mean_delay_s": "mean delay s", "arrived": "arrived",
           "waiting_to_enter": "waiting to enter", "max_queue": "max queue", "atspm_split_failures": "split failures",
           "atspm_percent_on_green": "% on green", "atspm_max_outs": "max-outs", "atspm_force_offs": "force-offs"}


@dataclass(frozen=True, slots=True)
class Estimate:
    """A figure over seeds: mean, 95 % CI half width (None with fewer than two values), and n."""

    mean: float | None
    half_width: float | None
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> Estimate:
        import numpy as np  # here: `hils` registers this command at every start

        a = np.asarray([v for v in values if v is not None], dtype=float)
        if a.size == 0:
            return cls(None, None, 0)
        if a.size == 1:
            return cls(float(a[0]), None, 1)
        t = _T95[a.size - 2] if a.size - 1 <= len(_T95) else 1.96
        return cls(float(a.mean()), float(t * a.std(ddof=1) / math.sqrt(a.size)), int(a.size))

    def text(self, digits: int = 1) -> str:
        if self.mean is None:
            return "-"
        return f"{self.mean:.{digits}f}" + ("" if self.half_width is None else f" ± {self.half_width:.{digits}f}")


Table = dict[str, dict[str, Estimate]]


def aggregate(results: Sequence[CellResult]) -> dict[str, Table]:
    """Per scenario, per agent (each in the order first seen), per figure, including each approach's max queue
    (a scenario of one light)."""
    by_cell: dict[str, dict[str, list[CellResult]]] = {}
    for r in results:
        by_cell.setdefault(r.cell.scenario, {}).setdefault(r.cell.agent, []).append(r)
    out: dict[str, Table] = {}
    for scenario, by_agent in by_cell.items():
        runs = [r for agent_runs in by_agent.values() for r in agent_runs]
        approaches = sorted({k for r in runs for k in r.figures if k.startswith("max_queue_")})
        out[scenario] = {agent: {name: Estimate.of([r.figures.get(name) for r in agent_runs if r.ok])
                                 for name in (*FIGURES, *approaches)} for agent, agent_runs in by_agent.items()}
    return out


@dataclass(frozen=True, slots=True)
class Runs:
    """An agent's runs in one scenario: how many there were and how many failed."""

    total: int
    failed: int

    @property
    def ok(self) -> int:
        return self.total - self.failed


def runs(results: Sequence[CellResult]) -> dict[str, dict[str, Runs]]:
    """Per scenario, per agent: its runs, to tell an agent whose runs failed from a figure nobody measured."""
    out: dict[str, dict[str, Runs]] = {}
    for r in results:
        by_agent = out.setdefault(r.cell.scenario, {})
        before = by_agent.get(r.cell.agent, Runs(0, 0))
        by_agent[r.cell.agent] = Runs(before.total + 1, before.failed + (0 if r.ok else 1))
    return out


def unmeasured(results: Sequence[CellResult]) -> dict[str, dict[str, str]]:
    """Per scenario, why a figure no run gave was not measured (by figure): the ATSPM measures without the atspm
    package, split failures and arrivals on green where no controller read its detectors."""
    out: dict[str, dict[str, str]] = {}
    for r in results:
        missing = ((r.summary.get("record") or {}).get("atspm") or {}).get("missing")
        if r.ok:
            out[r.cell.scenario] = ({f"atspm_{name}": missing for name in ATSPM_FIGURES} if missing else
                                    {"atspm_split_failures": atspm.NO_DETECTORS,
                                     "atspm_percent_on_green": atspm.NO_DETECTORS})
    return out


def render(table: Table, runs: dict[str, Runs], *, unmeasured: dict[str, str] | None = None,
           width: int = WIDTH) -> str:
    """The table as text: a row per agent (``failed`` in every column of an agent none of whose runs finished), its
    columns wrapped into blocks of at most ``width`` characters, each repeating the agent; a figure no run gave is
    left out and said once, with why (``unmeasured``, by figure); then what the intervals are over, naming each
    agent that has fewer runs than seeds behind its figures."""
    names = list(next(iter(table.values())))
    shown = [n for n in names if any(row[n].n for row in table.values())] or names[:1]
    cells = {agent: {n: row[n].text() if runs[agent].ok else "failed" for n in shown} for agent, row in table.items()}
    agent_width = max(len("agent"), *(len(a) for a in table))
    widths = {n: max(len(_label(n)), *(len(row[n]) for row in cells.values())) for n in shown}
    blocks: list[list[str]] = [[]]
    for n in shown:
        if blocks[-1] and agent_width + sum(2 + widths[m] for m in (*blocks[-1], n)) > width:
            blocks.append([])
        blocks[-1].append(n)
    lines: list[str] = []
    for k, block in enumerate(blocks):
        head = f"{'agent':<{agent_width}}" + "".join(f"  {_label(n):>{widths[n]}}" for n in block)
        lines += [""] * (k > 0) + [head, "-" * len(head)]
        lines += [f"{agent:<{agent_width}}" + "".join(f"  {row[n]:>{widths[n]}}" for n in block)
                  for agent, row in cells.items()]
    why = unmeasured or {}
    left_out: dict[str, list[str]] = {}
    for n in names:
        if n not in shown:
            left_out.setdefault(why.get(n, "no run gave it"), []).append(_label(n))
    lines += [textwrap.fill(f"not measured, left out: {', '.join(labels)}: {reason}", width, subsequent_indent="  ")
              for reason, labels in left_out.items()]
    seeds = max(r.total for r in runs.values())
    short = [f"{agent}: {r.failed} of {r.total} runs failed" for agent, r in runs.items() if r.failed]
    lines.append(f"mean ± half width of the 95 % confidence interval over {seeds} seeds (Student's t)"
                 + (f"; {', '.join(short)}, see the sweep table" if short else ""))
    return "\n".join(lines)


def _label(name: str) -> str:
    return name.replace("max_queue_", "queue ") if name.startswith("max_queue_") else _LABELS[name]


def plot(table: Table, path: Path, title: str, runs: dict[str, Runs]) -> None:
    """One panel per figure (RESCO's four on top, hils' in the middle, ATSPM's below): a bar per agent with its 95 %
    confidence interval; an agent whose runs all failed is marked so, a figure no run gave "not measured"."""
    plt = pyplot()
    agents = list(table)
    columns = len(FIGURES) // 3
    fig, axes = plt.subplots(3, columns, figsize=(3.2 * columns, 10.8))
    for ax, (name, label) in zip(axes.flat, FIGURES.items(), strict=True):
        means = [table[a][name].mean or 0.0 for a in agents]
        errors = [table[a][name].half_width or 0.0 for a in agents]
        measured = [a for a in agents if table[a][name].n]
        ax.bar(range(len(agents)), means, yerr=errors, capsize=4, color="#4c78a8")
        for i, agent in enumerate(agents):
            if not runs[agent].ok:
                ax.text(i, 0, "runs\nfailed", ha="center", va="bottom", fontsize=7, color="#b22222")
            elif measured and not table[agent][name].n:  # an ATSPM detector measure where no detector was read
                ax.text(i, 0, "not\nmeasured", ha="center", va="bottom", fontsize=7, color="#555")
        ax.set_xticks(range(len(agents)), agents, rotation=30, ha="right", fontsize=8)
        ax.set_title(label, fontsize=9)
        if any(means):
            ax.set_ylim(bottom=0)
        else:
            ax.set_ylim(0, 1)  # not matplotlib's tiny range around zero
            said = ("not measured" if not measured else
                    "0 for every agent" if len(measured) == len(agents) else "0 where measured")
            ax.text(0.5, 0.5, said, transform=ax.transAxes, ha="center", fontsize=9, color="#555")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
