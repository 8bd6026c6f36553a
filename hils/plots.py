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


def run_end(records: Sequence[dict[str, Any]]) -> float:
    """Simulated time at which the run ended (its last record when it has no RUN_ENDED)."""
    ended = [r["t"] for r in records if r["kind"] == Kind.RUN_ENDED]
    return ended[-1] if ended else (records[-1]["t"] if records else 0.0)


def timeline_window(records: Sequence[dict[str, Any]], start: float, end: float) -> tuple[float, float]:
    """The asked window cut to the run: never past its end; a window that starts after the end
    shows the run's last stretch of the same length instead."""
    last = run_end(records)
    if start >= last:
        start = max(0.0, last - (end - start))
    return start, min(end, last)


def phase_rows(config: IntersectionConfig) -> list[tuple[int, int, int]]:
    """(phase, ring, barrier) in the order a timing diagram shows them: ring by ring, each in its
    service order, so the barrier groups of the two rings line up."""
    rows = []
    for ring_index, ring in enumerate(config.rings, start=1):
        for p in ring:
            rows.append((p, ring_index, config.barrier_of(p) + 1))
    return rows


def movement_label(config: IntersectionConfig, phase: int) -> str:
    ph = config.phases[phase]
    movement = " ".join(x for x in (ph.approach, ph.turn) if x)
    return f"{phase}  {movement}" if movement else f"phase {phase}"


def signal_timeline(records: Sequence[dict[str, Any]], config: IntersectionConfig, path: Path, *,
                    start: float = 0.0, end: float = 120.0, title: str | None = None) -> Path:
    """Green, yellow and red of every phase over [start, end] cut to the run, one row per phase
    grouped by ring (solid separators) and barrier (dotted), labelled with its movement."""
    start, end = timeline_window(records, start, end)
    rows = phase_rows(config)
    phases = [p for p, _, _ in rows]
    spans = signal_intervals(records, phases, start, end)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(11, 0.45 * len(phases) + 1.9))
    for row, p in enumerate(phases):
        ax.broken_barh([(t0, t1 - t0) for t0, t1, _ in spans[p]], (row - 0.4, 0.8),
                       facecolors=[COLORS[ind] for _, _, ind in spans[p]], linewidth=0)
    for r in records:
        if r["kind"] == Kind.COMMAND_DISPATCHED and start <= r["t"] <= end:
            ax.axvline(r["t"], color="black", linewidth=0.8, linestyle="--")
    for row in range(1, len(rows)):
        (_, ring_a, barrier_a), (_, ring_b, barrier_b) = rows[row - 1], rows[row]
        if ring_a != ring_b:
            ax.axhline(row - 0.5, color="black", linewidth=1.6)
        elif barrier_a != barrier_b:
            ax.axhline(row - 0.5, color="black", linewidth=0.9, linestyle=":")
    groups: dict[tuple[int, int], list[int]] = {}
    for row, (_, ring, barrier) in enumerate(rows):
        groups.setdefault((ring, barrier), []).append(row)
    for (ring, barrier), members in groups.items():
        ax.text(1.01, 1 - (sum(members) / len(members) + 0.5) / len(rows), f"ring {ring}\nbarrier {barrier}",
                transform=ax.transAxes, va="center", fontsize="small")
    ax.set_yticks(range(len(phases)), [movement_label(config, p) for p in phases])
    ax.set_ylim(len(phases) - 0.5, -0.5)
    ax.set_xlim(start, end)
    ax.set_xlabel("simulation time (s); dashed: command dispatched; green, yellow, red as polled")
    ax.set_title(title or f"Signal timeline, {config.name}: {start:.0f} to {end:.0f} s of a "
                          f"{run_end(records):.0f} s run")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def queue_bins(samples: Sequence[tuple[float, Mapping[str, int]]], bin_s: float
               ) -> tuple[list[float], dict[str, list[int]]]:
    """Edges and per-approach longest queue of ``bin_s`` bins over the samples. A last bin
    shorter than ``bin_s`` joins the one before it: a maximum over a few samples would read as
    a queue that suddenly vanished."""
    if not samples:
        return [], {}
    names = sorted({k for _, q in samples for k in q})
    t_end = samples[-1][0]
    count = max(1, int(t_end // bin_s))
    edges = [b * bin_s for b in range(count)] + [t_end]
    tops = {name: [0] * count for name in names}
    for t, q in samples:
        b = min(int(t // bin_s), count - 1)
        for name in names:
            tops[name][b] = max(tops[name][b], q.get(name, 0))
    return edges, tops


def queues(samples: Sequence[tuple[float, Mapping[str, int]]], path: Path, *, title: str = "Queues",
           bin_s: float = 60.0, spillback: Mapping[str, Sequence[float]] | None = None) -> Path:
    """Longest queue per approach in each ``bin_s`` window: samples every few seconds are too
    jagged to read, and the longest queue is what a traffic engineer looks for. ``spillback``
    gives, per approach, times at which one of its lanes was full; the bins holding them are
    marked: the queue reached back beyond the modelled lanes."""
    spillback = spillback or {}
    edges, tops = queue_bins(samples, bin_s)
    plt = pyplot()
    from matplotlib.transforms import offset_copy

    fig, ax = plt.subplots(figsize=(11, 3.8))
    minutes = [e / 60.0 for e in edges]
    spilled = False
    for index, (name, values) in enumerate(tops.items()):
        line = ax.stairs(values, minutes, label=name, linewidth=1.4, baseline=None)
        full = sorted({min(int(t // bin_s), len(values) - 1) for t in spillback.get(name, ())})
        if full:
            spilled = True
            # above the bin's queue, stacked 7 points apart so that approaches do not hide each other
            ax.plot([(minutes[b] + minutes[b + 1]) / 2 for b in full], [values[b] for b in full], linestyle="none",
                    marker="^", color=line.get_edgecolor(), markersize=6, clip_on=False,
                    transform=offset_copy(ax.transData, fig=fig, y=6 + 7 * index, units="points"))
    if spillback:
        ax.text(0.0, -0.28, "triangles: a lane of the approach was full (spillback: the queue reaches back "
                "beyond the network)" if spilled else "no lane was full (no spillback)",
                transform=ax.transAxes, fontsize="small")
    ax.set_xlabel("simulation time (min)")
    ax.set_ylabel(f"longest queue per {bin_s:g} s (veh)")
    highest = max((v for values in tops.values() for v in values), default=0)
    ax.set_ylim(0, max(1.0, highest) * (1.3 if spilled else 1.08))  # room for the stacked spillback marks
    ax.set_title(title)
    if tops:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", title="approach")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
