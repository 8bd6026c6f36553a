"""Plots of a run: the signal timeline of every phase, and queues over time.

A run folder's two pictures are SVG written here directly: drawn in milliseconds with nothing to
import, sharp at any zoom, and opened by any browser. Other commands draw with matplotlib
(:func:`pyplot`), imported only when they draw.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Any

from hils.protocol.config import IntersectionConfig
from hils.protocol.resco import light_of, titled
from hils.protocol.scenario import described
from hils.report.outfiles import write_whole
from hils.shell.events import Kind, signal_known

#: An indication nobody verified: polls failing, or halted in TIMEOUT (see :func:`hils.shell.events.signal_known`).
NO_DATA = "-"
COLORS = {"G": "#2ca02c", "Y": "#ffbf00", "r": "#d62728", NO_DATA: "#d9d9d9"}
PREEMPTED = "#7b3294"  # the controller served a preempt: its own operation, not the agent's


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
    so that a span lasts as long as the indication does; :data:`NO_DATA` while the state was not
    verified (from a failed poll with no newer answer, or a TIMEOUT, to the next answer), never the
    last state seen."""
    changes: list[tuple[float, dict[int, str] | None]] = []  # (t, indication per phase, None: no data)
    shown: dict[int, str] | None = None
    for r in records:
        if r["t"] > end:
            break
        known = signal_known(r)
        if known is None:
            continue
        if r["kind"] == Kind.POLL:
            shown = {p: "G" if p in r["greens"] else "Y" if p in r["yellows"] else "r" for p in phases}
        changes.append((r["t"], shown if known else None))
    spans: dict[int, list[tuple[float, float, str]]] = {p: [] for p in phases}
    for (t0, at), (t1, _) in zip(changes, [*changes[1:], (end, None)], strict=True):
        if t1 < start:
            continue
        for p in phases:
            ind = NO_DATA if at is None else at[p]
            row = spans[p]
            if row and row[-1][2] == ind:
                row[-1] = (row[-1][0], min(t1, end), ind)
            else:
                row.append((max(t0, start), min(t1, end), ind))
    return spans


def preempted_spans(episodes: Sequence[Mapping[str, Any]], start: float, end: float
                    ) -> list[tuple[float, float, tuple[int, ...]]]:
    """(from, to, preempts) of every PREEMPTED episode (:attr:`hils.report.summary.Tally.preemptions`) that overlaps
    [start, end], cut to it; one still on (no duration yet) lasts to ``end``."""
    spans = [(e["t"], end if e["duration_s"] is None else e["t"] + e["duration_s"], tuple(e["preempts"]))
             for e in episodes]
    return [(max(t0, start), min(t1, end), n) for t0, t1, n in spans if t1 > start and t0 < end]


def run_end(records: Sequence[dict[str, Any]]) -> float:
    """Simulated time at which the run ended (its last record when it has no RUN_ENDED)."""
    ended = [r["t"] for r in records if r["kind"] == Kind.RUN_ENDED]
    return ended[-1] if ended else (records[-1]["t"] if records else 0.0)


def named(label: str | None, config: IntersectionConfig) -> str:
    """How a picture's title names an intersection: its label in a run of several and its config's name, once where
    the name already begins with the label (a RESCO light's derived config: "A0, dual-ring from its SUMO program");
    in a run of a scenario's one light, the scenario and the light (as the console's summary does)."""
    light = light_of(config.source) if not label else None
    if light is not None:
        return titled(*light)
    if not label or described(label, config) != config.name:
        return config.name
    return f"{label} ({config.name})"


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
                    start: float = 0.0, end: float = 120.0, label: str | None = None,
                    preemptions: Sequence[Mapping[str, Any]] = ()) -> Path:
    """Green, yellow and red of every phase over [start, end] cut to the run, one row per phase
    grouped by ring (solid separators) and barrier (dotted), labelled with its movement (SVG). ``label`` names
    the intersection in the title (default: its config's name); ``preemptions`` (the run's
    :attr:`hils.report.summary.Tally.preemptions`) are marked above the rows."""
    start, end = timeline_window(records, start, end)
    rows = phase_rows(config)
    phases = [p for p, _, _ in rows]
    spans = signal_intervals(records, phases, start, end)
    preempted = preempted_spans(preemptions, start, end)
    row_h, left, top, width = 40.0, 150.0, 58.0 if preempted else 40.0, 780.0
    chart = Chart(left, top, width, row_h * len(rows), (start, end))
    svg = Svg(left + width + 90.0, top + chart.height + 60.0)
    svg.title(f"Signal timeline, {label or config.name}: {start:.0f} to {end:.0f} s of a {run_end(records):.0f} s run",
              22)
    for row, p in enumerate(phases):
        y = top + row * row_h
        for t0, t1, ind in spans[p]:
            x0, x1 = chart.x(t0), chart.x(t1)
            if ind == NO_DATA:
                svg.rect(x0, y + 4, x1 - x0, row_h - 8, svg.hatch())
                if x1 - x0 >= 48:
                    svg.text((x0 + x1) / 2, y + row_h / 2 + 4, "no data", size=11, anchor="middle")
            else:
                svg.rect(x0, y + 4, x1 - x0, row_h - 8, COLORS[ind])
        svg.text(left - 8, y + row_h / 2 + 4, movement_label(config, p), anchor="end")
    for r in records:
        if r["kind"] == Kind.COMMAND_DISPATCHED and start <= r["t"] <= end:
            svg.line(chart.x(r["t"]), top, chart.x(r["t"]), top + chart.height, dash="4 3", width=0.8)
    for t0, t1, numbers in preempted:  # a bar above the rows and its bounds across them
        x0, x1 = chart.x(t0), chart.x(t1)
        svg.rect(x0, top - 10, x1 - x0, 7, PREEMPTED)
        svg.text(x0, top - 14, f"preempt {', '.join(map(str, numbers))}", size=11)
        for x in (x0, x1):
            svg.line(x, top - 10, x, top + chart.height, color=PREEMPTED, dash="2 2", width=1.2)
    for row in range(1, len(rows)):
        (_, ring_a, barrier_a), (_, ring_b, barrier_b) = rows[row - 1], rows[row]
        y = top + row * row_h
        if ring_a != ring_b:
            svg.line(left, y, left + width, y, width=1.8)
        elif barrier_a != barrier_b:
            svg.line(left, y, left + width, y, dash="1 2", width=1.0)
    groups: dict[tuple[int, int], list[int]] = {}
    for row, (_, ring, barrier) in enumerate(rows):
        groups.setdefault((ring, barrier), []).append(row)
    for (ring, barrier), members in groups.items():
        y = top + (sum(members) / len(members) + 0.5) * row_h
        svg.text(left + width + 8, y - 3, f"ring {ring}", size=11)
        svg.text(left + width + 8, y + 11, f"barrier {barrier}", size=11)
    # the caption names what the picture shows: a stretch without data narrower than a pixel (the few ms between
    # the close's clear and the run's end) is not there to see
    unverified = any(ind == NO_DATA and chart.x(t1) - chart.x(t0) >= 1.0 for row in spans.values()
                     for t0, t1, ind in row)
    chart.axes(svg, "simulation time (s); dashed: command dispatched; colours as polled"
               + ("; hatched: no data (polls failing or halted in TIMEOUT)" if unverified else "")
               + ("; purple: controller preempted" if preempted else ""))
    return svg.write(path)


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
           bin_s: float = 60.0, spillback: Mapping[str, Sequence[float]] | None = None,
           legend: str = "approach") -> Path:
    """Longest queue per ``legend`` (approach) in each ``bin_s`` window (SVG): samples every few seconds are too
    jagged to read, and the longest queue is what a traffic engineer looks for. ``spillback``
    gives, per approach, times at which one of its lanes was full; the bins holding them are
    marked: the queue reached back beyond the modelled lanes."""
    spillback = spillback or {}
    edges, tops = queue_bins(samples, bin_s)
    minutes = [e / 60.0 for e in edges]
    highest = max((v for values in tops.values() for v in values), default=0)
    full = {name: sorted({min(int(t // bin_s), len(values) - 1) for t in spillback.get(name, ())})
            for name, values in tops.items()}
    spilled = any(full.values())
    left, top, width, height = 60.0, 40.0, 800.0, 230.0
    chart = Chart(left, top, width, height, (minutes[0], minutes[-1]) if minutes else (0.0, 1.0),
                  (0.0, max(1.0, highest) * (1.3 if spilled else 1.08)))  # room for the stacked spillback marks
    svg = Svg(left + width + 120.0, top + height + (80.0 if spillback else 55.0))
    svg.title(title, 22)
    svg.text(left + width + 14, top + 8, legend, size=12)
    for index, (name, values) in enumerate(tops.items()):
        color = PALETTE[index % len(PALETTE)]
        points = [(chart.x(minutes[b + k]), chart.y(v)) for b, v in enumerate(values) for k in (0, 1)]
        svg.polyline(points, color)
        for b in full[name]:
            # above the bin's queue, stacked 7 points apart so that approaches do not hide each other
            x, y = chart.x((minutes[b] + minutes[b + 1]) / 2), chart.y(values[b]) - 8 - 7 * index
            svg.polyline([(x - 4, y + 3), (x + 4, y + 3), (x, y - 4), (x - 4, y + 3)], color, fill=color)
        y = top + 26 + 18 * index
        svg.line(left + width + 14, y - 4, left + width + 34, y - 4, color=color, width=2.0)
        svg.text(left + width + 40, y, name, size=12)
    chart.axes(svg, "simulation time (min)", y_label=f"longest queue per {bin_s:g} s (veh)")
    if spillback:
        svg.text(left, top + height + 70, "triangles: a lane of the approach was full (spillback: the queue reaches "
                 "back beyond the network)" if spilled else "no lane was full (no spillback)", size=11)
    return svg.write(path)


# --- a few SVG primitives: the run folder's pictures need no plotting library ------------------------------

#: Line colours of the queue plot (matplotlib's tab20, so they read like the other pictures of hils; the
#: grid's sixteen intersections each get their own).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94")


#: The mean advance of a title's characters in DejaVu Sans, in em (its digits 0.64, lower case ~0.6, space 0.32).
_EM_WIDTH = 0.6


class Svg:
    """An SVG document built element by element."""

    def __init__(self, width: float, height: float) -> None:
        self.width, self.height = width, height
        self.parts: list[str] = []
        self.defs: list[str] = []

    def hatch(self) -> str:
        """The fill of a stretch without data: grey diagonal hatching (defined once per picture)."""
        if not self.defs:
            self.defs.append('<pattern id="no-data" width="7" height="7" patternUnits="userSpaceOnUse" '
                             'patternTransform="rotate(45)"><rect width="7" height="7" fill="#f0f0f0"/>'
                             '<line x1="0" y1="0" x2="0" y2="7" stroke="#9a9a9a" stroke-width="2.5"/></pattern>')
        return "url(#no-data)"

    def rect(self, x: float, y: float, w: float, h: float, fill: str) -> None:
        self.parts.append(f'<rect x="{x:.2f}" y="{y:.2f}" width="{max(w, 0.0):.2f}" height="{h:.2f}" '
                          f'fill="{fill}"/>')

    def line(self, x1: float, y1: float, x2: float, y2: float, *, color: str = "black", width: float = 1.0,
             dash: str | None = None) -> None:
        dashed = f' stroke-dasharray="{dash}"' if dash else ""
        self.parts.append(f'<line x1="{x1:.2f}" y1="{y1:.2f}" x2="{x2:.2f}" y2="{y2:.2f}" stroke="{color}" '
                          f'stroke-width="{width}"{dashed}/>')

    def polyline(self, points: Sequence[tuple[float, float]], color: str, *, fill: str = "none") -> None:
        coords = " ".join(f"{x:.2f},{y:.2f}" for x, y in points)
        self.parts.append(f'<polyline points="{coords}" fill="{fill}" stroke="{color}" stroke-width="1.6"/>')

    def dots(self, points: Sequence[tuple[float, float]], color: str, *, radius: float = 1.5) -> None:
        self.parts.extend(f'<circle cx="{x:.2f}" cy="{y:.2f}" r="{radius}" fill="{color}"/>' for x, y in points)

    def text(self, x: float, y: float, text: str, *, size: float = 12, anchor: str = "start",
             rotate: bool = False) -> None:
        turn = f' transform="rotate(-90 {x:.2f} {y:.2f})"' if rotate else ""
        self.parts.append(f'<text x="{x:.2f}" y="{y:.2f}" font-size="{size}" text-anchor="{anchor}"{turn}>'
                          f"{escape(text)}</text>")

    def title(self, text: str, y: float, *, size: float = 15) -> None:
        """The picture's title, centred, its font made smaller where it would run past the edges (RESCO names a light
        by a cluster id of up to 45 characters)."""
        fits = (self.width - 20) / (_EM_WIDTH * max(len(text), 1))
        self.text(self.width / 2, y, text, size=round(min(size, fits), 1), anchor="middle")

    def write(self, path: Path) -> Path:
        """Write the picture whole (a file that cannot take all of it is removed: no half picture is left)."""
        w, h = f"{self.width:.0f}", f"{self.height:.0f}"
        write_whole(path, f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" '
                    'font-family="DejaVu Sans, Helvetica, Arial, sans-serif">\n'
                    + (f"<defs>{''.join(self.defs)}</defs>\n" if self.defs else "")
                    + '<rect width="100%" height="100%" fill="white"/>\n' + "\n".join(self.parts) + "\n</svg>\n")
        return path


@dataclass(frozen=True)
class Chart:
    """A plotting area: data coordinates to SVG coordinates, and its axes with round ticks."""

    left: float
    top: float
    width: float
    height: float
    xs: tuple[float, float]
    ys: tuple[float, float] | None = None  # None: rows, no y axis

    def x(self, value: float) -> float:
        lo, hi = self.xs
        return self.left + (value - lo) / ((hi - lo) or 1.0) * self.width

    def y(self, value: float) -> float:
        lo, hi = self.ys or (0.0, 1.0)
        return self.top + self.height - (value - lo) / ((hi - lo) or 1.0) * self.height

    def axes(self, svg: Svg, x_label: str, *, y_label: str | None = None,
             x_ticks: Sequence[tuple[float, str]] | None = None) -> None:
        """The frame, round ticks on both axes (``x_ticks``: the x axis's own, as (value, label)) and the labels."""
        bottom = self.top + self.height
        svg.parts.append(f'<rect x="{self.left:.2f}" y="{self.top:.2f}" width="{self.width:.2f}" '
                         f'height="{self.height:.2f}" fill="none" stroke="black"/>')
        for value, label in x_ticks if x_ticks is not None else [(v, f"{v:g}") for v in ticks(*self.xs)]:
            svg.line(self.x(value), bottom, self.x(value), bottom + 5)
            svg.text(self.x(value), bottom + 19, label, anchor="middle")
        svg.text(self.left + self.width / 2, bottom + 38, x_label, anchor="middle")
        if self.ys is not None:
            for value in ticks(*self.ys):
                svg.line(self.left - 5, self.y(value), self.left, self.y(value))
                svg.text(self.left - 8, self.y(value) + 4, f"{value:g}", anchor="end")
            if y_label:
                svg.text(self.left - 38, self.top + self.height / 2, y_label, anchor="middle", rotate=True)


def ticks(lo: float, hi: float, most: int = 10) -> list[float]:
    """Round tick values (1, 2 or 5 times a power of ten apart) covering [lo, hi], at most ``most``."""
    span = hi - lo
    if span <= 0:
        return [lo]
    step = next(m * 10.0 ** e for e in range(math.floor(math.log10(span / most)), 99) for m in (1, 2, 5)
                if span / (m * 10.0 ** e) <= most)
    first = math.ceil(lo / step - 1e-9)
    return [round(k * step, 10) for k in range(first, math.floor(hi / step + 1e-9) + 1)]


#: Steps between the ticks of a time of day, in seconds: round on a clock's face.
_CLOCK_STEPS = (1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200)


def clock_ticks(lo: float, hi: float, most: int = 8) -> list[tuple[float, str]]:
    """Ticks at round times of day over [lo, hi] hours after midnight, at most ``most``, labelled as a clock reads
    (``07:15``; ``07:15:30`` where they are under a minute apart)."""
    span = (hi - lo) * 3600
    step = next((s for s in _CLOCK_STEPS if span / s <= most), _CLOCK_STEPS[-1])
    first, last = math.ceil(lo * 3600 / step - 1e-9), math.floor(hi * 3600 / step + 1e-9)
    out = []
    for k in range(first, last + 1):
        seconds = k * step
        hours, rest = divmod(seconds, 3600)
        clock = f"{hours % 24:02d}:{rest // 60:02d}" + (f":{rest % 60:02d}" if step < 60 else "")
        out.append((seconds / 3600, clock))
    return out
