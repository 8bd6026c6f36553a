"""The two ATSPM charts of a controller's hi-res log: the Purdue coordination diagram and the split monitor.

Both are drawn from the log's own events (no other source), one panel per phase, as UDOT's ATSPM draws them,
in SVG written directly like the run folder's other pictures (:mod:`hils.report.plots`: no plotting library, drawn
in milliseconds, opened by any browser):

- **Purdue coordination diagram** (Day, Bullock et al., Purdue University): each cycle of a phase runs from
  the start of its red (end of yellow, event 9) to the next; the x axis is the time of day, the y axis the
  time in the cycle. Green points mark where the green began (event 1), yellow points where it ended
  (event 8); every vehicle detector actuation of the phase (event 82) is a black dot where it fell in its
  cycle, so a platoon arriving on green shows as dots between the green and yellow lines.
- **Split monitor**: each service of a phase, its split (green, yellow and red clearance: begin green to
  the phase going inactive) over the time of day, coloured by how the green ended (gap-out, max-out,
  force-off, or none: a coordinated phase yielding or a green with nowhere to go), with the programmed
  split of the pattern running (events 134-149) as a dashed line.

A coordinated phase (one with yield point events, 151) says so in its panel's title. The time of day reads as a
clock does.

Each is drawn where it says something the run's other pictures do not: the coordination diagram for the phases whose
detectors the controller read (its arrivals are its point), the split monitor where the controller chose its splits
itself, running a plan or timing its greens on its detectors. A controller that only served the middleware's calls
has neither (every split is the agent's, in the signal timeline): :data:`NOTHING_TO_DRAW`. A legend names only what
its chart shows.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path

from hils.protocol.config import FREE, IntersectionConfig
from hils.protocol.hires import Event, EventCode, split_code
from hils.report.plots import Chart, Svg, clock_ticks

E = EventCode
TERMINATIONS = {E.PHASE_GAP_OUT: ("gap-out", "#2ca02c"), E.PHASE_MAX_OUT: ("max-out", "#d62728"),
                E.PHASE_FORCE_OFF: ("force-off", "#1f77b4"), None: ("none (yield, rest)", "#7f7f7f")}
GREEN, YELLOW = "#2ca02c", "#e6a800"
DASHED = "dashed"  # a legend entry drawn as the programmed split's dashed line
_PANEL_W, _PANEL_H, _LEFT, _TOP, _GAP = 520.0, 190.0, 70.0, 70.0, 95.0

Panel = Callable[[Svg, Chart], None]

#: Why a controller's log gives no chart (the run's summary says it).
NOTHING_TO_DRAW = ("no coordination diagram or split monitor: the controller ran no plan and read no detector, it "
                   "served the middleware's calls alone (the agent's splits are in signal_timeline.svg)")


def _hours(t: datetime, day0: datetime) -> float:
    return (t - day0).total_seconds() / 3600


def _coordinated(events: Sequence[Event]) -> set[int]:
    return {e.parameter for e in events if e.code == E.COORD_YIELD_POINT}


def _draw(path: Path, title: str, legend: Sequence[tuple[str, str]], day0: datetime, y_label: str,
          panels: Sequence[tuple[str, tuple[float, float], tuple[float, float], Panel]]) -> Path:
    """Panels two by two, each with its axes over the time of day (hours after ``day0``'s midnight, read as a clock);
    a legend of (label, colour) under the title (a dashed line where the colour is ``dashed``)."""
    columns = 1 if len(panels) == 1 else 2
    rows = (len(panels) + columns - 1) // columns
    svg = Svg(_LEFT + columns * (_PANEL_W + _LEFT), _TOP + rows * (_PANEL_H + _GAP))
    svg.title(title, 24)
    x = _LEFT
    for label, color in legend:
        if color == DASHED:
            svg.line(x - 6, 46, x + 4, 46, color="#555555", dash="5 3")
        else:
            svg.dots([(x, 46)], color, radius=4)
        svg.text(x + 8, 50, label, size=12)
        x += 24 + 7 * len(label)
    for k, (name, xs, ys, draw) in enumerate(panels):
        left = _LEFT + (k % columns) * (_PANEL_W + _LEFT)
        top = _TOP + (k // columns) * (_PANEL_H + _GAP) + 18
        chart = Chart(left, top, _PANEL_W, _PANEL_H, xs, ys)
        svg.text(left + _PANEL_W / 2, top - 6, name, size=13, anchor="middle")
        draw(svg, chart)
        chart.axes(svg, f"time of day, {day0:%Y-%m-%d}", y_label=y_label, x_ticks=clock_ticks(*xs))
    return svg.write(path)


def coordination_diagram(events: Sequence[Event], config: IntersectionConfig, path: Path, title: str) -> bool:
    """Draw the Purdue coordination diagram of every phase whose detectors the log shows actuated to ``path`` (SVG);
    False when no such phase has a whole cycle to show."""
    actuated = {e.parameter for e in events if e.code == E.DETECTOR_ON}
    detectors: dict[int, set[int]] = {}
    for d, phase in config.detectors.items():
        if d in actuated:
            detectors.setdefault(phase, set()).add(d)
    day0 = datetime.combine(events[0].time.date(), datetime.min.time()) if events else datetime.min
    coordinated = _coordinated(events)
    panels = []
    for phase in sorted(p for p in detectors if p):
        reds = [e.time for e in events if e.code == E.PHASE_END_YELLOW and e.parameter == phase]
        if len(reds) < 2:
            continue
        marks: dict[str, list[tuple[float, float]]] = {"green": [], "yellow": [], "arrival": []}
        kinds = {E.PHASE_BEGIN_GREEN: "green", E.PHASE_BEGIN_YELLOW: "yellow"}
        k = 0
        for e in events:
            if not reds[0] <= e.time < reds[-1]:
                continue
            while e.time >= reds[k + 1]:
                k += 1
            kind = kinds.get(e.code) if e.parameter == phase else None
            if e.code == E.DETECTOR_ON and e.parameter in detectors[phase]:
                kind = "arrival"
            if kind is not None:
                marks[kind].append((_hours(e.time, day0), (e.time - reds[k]).total_seconds()))
        longest = max((b - a).total_seconds() for a, b in itertools.pairwise(reds))

        def draw(svg: Svg, chart: Chart, marks: dict[str, list[tuple[float, float]]] = marks) -> None:
            svg.dots([(chart.x(x), chart.y(y)) for x, y in marks["arrival"]], "black", radius=1.3)
            for kind, color in (("green", GREEN), ("yellow", YELLOW)):
                points = [(chart.x(x), chart.y(y)) for x, y in marks[kind]]
                svg.polyline(points, color)
                svg.dots(points, color, radius=2.2)

        span = (_hours(reds[0], day0), _hours(reds[-1], day0))
        panels.append((f"phase {phase}" + (" (coordinated)" if phase in coordinated else ""), span,
                       (0.0, longest * 1.05), draw))
    if not panels:
        return False
    _draw(path, f"Purdue coordination diagram, {title}", [("begin green", GREEN), ("begin yellow", YELLOW),
                                                         ("detector on (arrival)", "black")],
          day0, "time in cycle (s)", panels)
    return True


def _services(events: Sequence[Event], phase: int) -> list[tuple[datetime, float, int | None]]:
    """Each service of ``phase``: when its green began, its split (s) and the termination event that ended it."""
    out, start, reason = [], None, None
    for e in events:
        if e.parameter != phase:
            continue
        if e.code == E.PHASE_BEGIN_GREEN:
            start, reason = e.time, None
        elif e.code in TERMINATIONS and start is not None:
            reason = e.code
        elif e.code == E.PHASE_INACTIVE and start is not None:
            out.append((start, (e.time - start).total_seconds(), reason))
            start = None
    return out


def _programmed(events: Sequence[Event], phase: int) -> list[tuple[datetime, float | None]]:
    """The programmed split of ``phase`` over time: each split change (None when the pattern goes free)."""
    out: list[tuple[datetime, float | None]] = []
    for e in events:
        if e.code == split_code(phase):
            out.append((e.time, float(e.parameter)))
        elif e.code == E.COORD_PATTERN_CHANGE and e.parameter == 254:
            out.append((e.time, None))
    return out


def chose_its_splits(events: Sequence[Event]) -> bool:
    """The controller chose its splits itself: it ran a plan (a pattern other than free) or read its detectors."""
    return any(e.code == E.DETECTOR_ON or (e.code == E.COORD_PATTERN_CHANGE and e.parameter != FREE) for e in events)


def split_monitor(events: Sequence[Event], config: IntersectionConfig, path: Path, title: str) -> bool:
    """Draw the split monitor of every phase served to ``path`` (SVG); False when no phase was served, or when the
    controller did not choose its splits itself (a controller on the middleware's calls alone)."""
    if not events or not chose_its_splits(events):
        return False
    day0 = datetime.combine(events[0].time.date(), datetime.min.time())
    span = (_hours(events[0].time, day0), _hours(events[-1].time, day0))
    coordinated = _coordinated(events)
    panels = []
    ended: set[int | None] = set()  # how greens ended, and whether a split was programmed: what the legend names
    planned = False
    for phase in config.phase_numbers:
        services = _services(events, phase)
        if not services:
            continue
        plan = _programmed(events, phase)
        ended |= {r for _, _, r in services}
        planned |= any(s is not None for _, s in plan)
        top = max([s for _, s, _ in services] + [s for _, s in plan if s is not None])

        def draw(svg: Svg, chart: Chart, services: list = services, plan: list = plan) -> None:
            # Each split holds until the next change, the last one to the end of the log (a log collected after
            # the controller powered up may hold no pattern event: no split known, no line).
            for (t0, split), (t1, _) in itertools.pairwise([*plan, (events[-1].time, None)]):
                if split is not None:
                    svg.line(chart.x(_hours(t0, day0)), chart.y(split), chart.x(_hours(t1, day0)), chart.y(split),
                             color="#555555", dash="5 3")
            for reason, (_, color) in TERMINATIONS.items():
                svg.dots([(chart.x(_hours(t, day0)), chart.y(s)) for t, s, r in services if r == reason], color,
                         radius=2.4)

        panels.append((f"phase {phase}" + (" (coordinated)" if phase in coordinated else ""), span,
                       (0.0, top * 1.15), draw))
    if not panels:
        return False
    legend = [(label, color) for reason, (label, color) in TERMINATIONS.items() if reason in ended]
    # a log collected after the controller powered up may hold no pattern event: what was programmed is unknown
    unknown = "" if any(e.code == E.COORD_PATTERN_CHANGE for e in events) else (
        "; no pattern event in the log: programmed split unknown")
    _draw(path, f"Split monitor, {title}: each service's split by how its green ended{unknown}",
          legend + [("programmed split", DASHED)] * planned, day0, "split (s)", panels)
    return True


#: A chart of a controller's log: ``(events, config, path, title)``, drawn to ``path``; False when it has nothing
#: to show (then no file is written).
Draw = Callable[[Sequence[Event], IntersectionConfig, Path, str], bool]

#: The charts of each controller's log, by the name of their file.
CHARTS: dict[str, Draw] = {"coordination_diagram.svg": coordination_diagram, "split_monitor.svg": split_monitor}
