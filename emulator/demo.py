"""`hils emulator demo`: the controller model in virtual time, with a few calls, as a timeline."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import simpy

from emulator.controller import Controller
from hils.config import IntersectionConfig
from hils.ntcip import ControlColumn


@dataclass(frozen=True, slots=True)
class Row:
    """The signal display from one tick on: which phases show green, yellow and red."""

    t: float
    greens: frozenset[int]
    yellows: frozenset[int]
    reds: frozenset[int]
    nexts: frozenset[int] = frozenset()  # PhaseNext: committed at the start of yellow


DEFAULT_CALLS: tuple[tuple[float, tuple[int, ...]], ...] = (
    (2.0, (3, 7)),   # side-street lefts: crosses the barrier from the start-up [2,6]
    (14.0, (4, 8)),  # side-street throughs: same barrier group
    (26.0, (1, 5)),  # main-street lefts: back across the barrier
    (40.0, (1, 6)),  # a lead-lag pair: only ring 2 changes
)


def run(config: IntersectionConfig, calls: Iterable[tuple[float, Iterable[int]]] = DEFAULT_CALLS,
        duration: float = 60.0) -> list[Row]:
    """Run the model for ``duration`` s, SET VehCall at the given times; return the display changes."""
    env = simpy.Environment()
    controller = Controller(config)
    rows = [Row(0.0, controller.greens, controller.yellows, controller.reds, controller.phase_nexts)]

    def ticking():
        for _ in controller.process(env):
            yield _
            last = rows[-1]
            if (controller.greens, controller.yellows, controller.phase_nexts) != (last.greens, last.yellows,
                                                                                     last.nexts):
                rows.append(Row(round(controller.tick / 10, 1), controller.greens, controller.yellows,
                                controller.reds, controller.phase_nexts))

    def caller():
        for at, phases in sorted(calls):
            yield env.timeout(at - env.now)
            controller.set_control(ControlColumn.VEH_CALL, phases)

    env.process(ticking())
    env.process(caller())
    env.run(until=duration)
    return rows


def render(rows: list[Row], config: IntersectionConfig) -> str:
    phases = config.phase_numbers
    head = "     t (s)  " + " ".join(f"{p:>2}" for p in phases) + "   green    yellow   next"
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = " ".join(f"{'G' if p in r.greens else 'Y' if p in r.yellows else 'r':>2}" for p in phases)
        lines.append(f"{r.t:10.1f}  {cells}   {_fmt(r.greens):8} {_fmt(r.yellows):8} {_fmt(r.nexts)}")
    return "\n".join(lines)


def _fmt(phases: frozenset[int]) -> str:
    return "[" + ",".join(map(str, sorted(phases))) + "]" if phases else "-"
