"""The two ATSPM charts of a controller's hi-res log: the Purdue coordination diagram and the split monitor.

Both are drawn from the log's own events (no other source), one panel per phase, the way UDOT's ATSPM
draws them:

- **Purdue coordination diagram** (Day, Bullock et al., Purdue University): each cycle of a phase runs from
  the start of its red (end of yellow, event 9) to the next; the x axis is the time of day, the y axis the
  time in the cycle. Green points mark where the green began (event 1), yellow points where it ended
  (event 8); every vehicle detector actuation of the phase (event 82) is a black dot where it fell in its
  cycle, so a platoon arriving on green shows as dots between the green and yellow lines.
- **Split monitor**: each service of a phase, its split (green, yellow and red clearance: begin green to
  the end of its red clearance) over the time of day, coloured by how the green ended (gap-out, max-out,
  force-off, or none: a coordinated phase yielding or a green with nowhere to go), with the programmed
  split of the pattern running (events 134-149) as a line.

A coordinated phase (one with yield point events, 151) says so in its panel's title.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path

from hils.config import IntersectionConfig
from hils.hires import Event, EventCode
from hils.plots import pyplot

E = EventCode
TERMINATION_COLORS = {E.PHASE_GAP_OUT: ("gap-out", "#2ca02c"), E.PHASE_MAX_OUT: ("max-out", "#d62728"),
                      E.PHASE_FORCE_OFF: ("force-off", "#1f77b4"), None: ("none (yield, rest)", "#7f7f7f")}


def _hours(t: datetime, day0: datetime) -> float:
    return (t - day0).total_seconds() / 3600


def _grid(n: int) -> tuple[int, int]:
    cols = 2 if n > 1 else 1
    return (n + cols - 1) // cols, cols


def _coordinated(events: Sequence[Event]) -> set[int]:
    return {e.parameter for e in events if e.code == E.COORD_YIELD_POINT}


def _axis_hours(ax: object, day0: datetime) -> None:
    ax.set_xlabel(f"time of day (h), {day0:%Y-%m-%d}")


def coordination_diagram(events: Sequence[Event], config: IntersectionConfig, path: Path, title: str) -> bool:
    """Draw the Purdue coordination diagram of every phase with detectors to ``path`` (PNG); False when no phase
    has a whole cycle to show."""
    detectors: dict[int, set[int]] = {}
    for d, phase in config.detectors.items():
        detectors.setdefault(phase, set()).add(d)
    panels = []
    for phase in sorted(detectors):
        reds = [e.time for e in events if e.code == E.PHASE_END_YELLOW and e.parameter == phase]
        if len(reds) >= 2:
            panels.append((phase, reds))
    if not panels:
        return False
    day0 = datetime.combine(events[0].time.date(), datetime.min.time())
    coordinated = _coordinated(events)
    plt = pyplot()
    rows, cols = _grid(len(panels))
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 2.9 * rows), squeeze=False)
    for ax, (phase, reds) in zip(axes.flat, panels, strict=False):
        marks: dict[str, tuple[list[float], list[float]]] = {"green": ([], []), "yellow": ([], []), "arrival": ([], [])}
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
                xs, ys = marks[kind]
                xs.append(_hours(e.time, day0))
                ys.append((e.time - reds[k]).total_seconds())
        ax.scatter(*marks["arrival"], s=3, color="black", label="detector on (arrival)", zorder=2)
        ax.plot(*marks["green"], color="#2ca02c", marker="o", markersize=2.5, linewidth=1, label="begin green")
        ax.plot(*marks["yellow"], color="#e6a800", marker="o", markersize=2.5, linewidth=1, label="begin yellow")
        ax.set_title(f"phase {phase}" + (" (coordinated)" if phase in coordinated else ""), fontsize=9)
        ax.set_ylabel("time in cycle (s) from start of red", fontsize=8)
        _axis_hours(ax, day0)
        ax.set_ylim(bottom=0)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Purdue coordination diagram, {title}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def _services(events: Sequence[Event], phase: int) -> list[tuple[datetime, float, int | None]]:
    """Each service of ``phase``: when its green began, its split (s) and the termination event that ended it."""
    out, start, reason = [], None, None
    for e in events:
        if e.parameter != phase:
            continue
        if e.code == E.PHASE_BEGIN_GREEN:
            start, reason = e.time, None
        elif e.code in TERMINATION_COLORS and start is not None:
            reason = e.code
        elif e.code == E.PHASE_INACTIVE and start is not None:
            out.append((start, (e.time - start).total_seconds(), reason))
            start = None
    return out


def _programmed(events: Sequence[Event], phase: int) -> list[tuple[datetime, float | None]]:
    """The programmed split of ``phase`` over time: each split change (None when the pattern goes free)."""
    out: list[tuple[datetime, float | None]] = []
    code = E.SPLIT_1_CHANGE + phase - 1
    for e in events:
        if e.code == code:
            out.append((e.time, float(e.parameter)))
        elif e.code == E.COORD_PATTERN_CHANGE and e.parameter == 254:
            out.append((e.time, None))
    return out


def split_monitor(events: Sequence[Event], config: IntersectionConfig, path: Path, title: str) -> bool:
    """Draw the split monitor of every phase served to ``path`` (PNG); False when no phase was served."""
    panels = [(p, s) for p in config.phase_numbers if (s := _services(events, p))]
    if not panels:
        return False
    day0 = datetime.combine(events[0].time.date(), datetime.min.time())
    end = _hours(events[-1].time, day0)
    coordinated = _coordinated(events)
    plt = pyplot()
    rows, cols = _grid(len(panels))
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 2.7 * rows), squeeze=False)
    for ax, (phase, services) in zip(axes.flat, panels, strict=False):
        for reason, (label, color) in TERMINATION_COLORS.items():
            mine = [(_hours(t, day0), s) for t, s, r in services if r == reason]
            if mine:
                ax.scatter(*zip(*mine, strict=True), s=8, color=color, label=label)
        plan = _programmed(events, phase)
        for (t0, split), nxt in zip(plan, [*plan[1:], None], strict=True):
            if split is not None:
                t1 = end if nxt is None else _hours(nxt[0], day0)
                ax.hlines(split, _hours(t0, day0), t1, colors="#555555", linestyles="dashed", linewidth=1,
                          label="programmed split")
        ax.set_title(f"phase {phase}" + (" (coordinated)" if phase in coordinated else ""), fontsize=9)
        ax.set_ylabel("split (s)", fontsize=8)
        _axis_hours(ax, day0)
        top = max([s for _, s, _ in services] + [s for _, s in plan if s is not None])
        ax.set_ylim(0, top * 1.15)
        handles, labels = ax.get_legend_handles_labels()
        unique = dict(zip(labels, handles, strict=True))
        ax.legend(unique.values(), unique.keys(), fontsize=7, loc="upper right")
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"Split monitor, {title}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def draw(logs: Mapping[str, Sequence[Event]], configs: Mapping[str, IntersectionConfig],
         folders: Mapping[str, Path], names: Mapping[str, str]) -> list[Path]:
    """Both charts of each controller's log in its folder; the files written."""
    written = []
    for tls, events in logs.items():
        if not events:
            continue
        for name, chart in (("coordination_diagram.png", coordination_diagram), ("split_monitor.png", split_monitor)):
            path = folders[tls] / name
            if chart(events, configs[tls], path, names[tls]):
                written.append(path)
    return written
