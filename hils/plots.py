"""Plots of a run: the signal timeline of every phase, and queues over time."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hils.config import IntersectionConfig
from hils.events import Kind

COLORS = {"G": "#2ca02c", "Y": "#ffbf00", "r": "#d62728"}


def pyplot() -> Any:
    """matplotlib's pyplot on the file-only Agg backend, imported when a picture is first drawn: a
    command that draws nothing (``hils --help``, a benchmark) does not pay for it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def signal_intervals(records: Sequence[dict[str, Any]], phases: Sequence[int], start: float, end: float
                     ) -> dict[int, list[tuple[float, float, str]]]:
    """Per phase, (from, to, indication) spans as the polls saw them within [start, end], merged
    so that a span lasts as long as the indication does."""
    spans: dict[int, list[tuple[float, float, str]]] = {p: [] for p in phases}
    polls = [r for r in records if r["kind"] == Kind.POLL and r["t"] <= end]
    for a, b in zip(polls, [*polls[1:], None], strict=True):
        t0, t1 = a["t"], (b["t"] if b else end)
        if t1 < start:
            continue
        for p in phases:
            ind = "G" if p in a["greens"] else "Y" if p in a["yellows"] else "r"
            row = spans[p]
            if row and row[-1][2] == ind:
                row[-1] = (row[-1][0], min(t1, end), ind)
            else:
                row.append((max(t0, start), min(t1, end), ind))
    return spans


def signal_timeline(records: Sequence[dict[str, Any]], config: IntersectionConfig, path: Path, *,
                    start: float = 0.0, end: float = 120.0, title: str | None = None) -> Path:
    phases = list(config.phase_numbers)
    spans = signal_intervals(records, phases, start, end)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(11, 0.45 * len(phases) + 1.6))
    for row, p in enumerate(phases):
        ax.broken_barh([(t0, t1 - t0) for t0, t1, _ in spans[p]], (row - 0.4, 0.8),
                       facecolors=[COLORS[ind] for _, _, ind in spans[p]], linewidth=0)
    for r in records:
        if r["kind"] == Kind.COMMAND_DISPATCHED and start <= r["t"] <= end:
            ax.axvline(r["t"], color="black", linewidth=0.8, linestyle="--")
    ax.set_yticks(range(len(phases)), [f"phase {p}" for p in phases])
    ax.invert_yaxis()
    ax.set_xlim(start, end)
    ax.set_xlabel("simulation time (s); dashed: command dispatched")
    ax.set_title(title or f"Signal timeline, {config.name}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def queues(samples: Sequence[tuple[float, Mapping[str, int]]], path: Path, *, title: str = "Queues",
           bin_s: float = 60.0) -> Path:
    """Longest queue per approach in each ``bin_s`` window: samples every few seconds are too
    jagged to read, and the longest queue is what a traffic engineer looks for."""
    names = sorted({k for _, q in samples for k in q})
    bins: dict[int, dict[str, int]] = {}
    for t, q in samples:
        row = bins.setdefault(int(t // bin_s), {})
        for name in names:
            row[name] = max(row.get(name, 0), q.get(name, 0))
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(11, 3.6))
    starts = sorted(bins)
    for name in names:
        ax.step([b * bin_s / 60.0 for b in starts], [bins[b][name] for b in starts], where="post", label=name,
                linewidth=1.4)
    ax.set_xlabel("simulation time (min)")
    ax.set_ylabel(f"longest queue per {bin_s:g} s (veh)")
    ax.set_title(title)
    if names:
        ax.legend(ncol=len(names), fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
