"""`hils emulator demo`: the controller model in virtual time, with a few calls, as a timeline.

The timeline shows each phase as G (green), W (green with Walk), P (green with pedestrian clearance),
Y (yellow) or r (red), and the committed next phases (phaseStatusGroupPhaseNexts) during clearances.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

import simpy

from emulator.model.controller import Controller
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn


@dataclass(frozen=True, slots=True)
class Row:
    """The signal display from one tick on: which phases show green, yellow and red."""

    t: float
    greens: frozenset[int]
    yellows: frozenset[int]
    reds: frozenset[int]
    walks: frozenset[int] = frozenset()
    ped_clears: frozenset[int] = frozenset()
    nexts: frozenset[int] = frozenset()

    @classmethod
    def of(cls, t: float, c: Controller) -> Row:
        return cls(t, c.greens, c.yellows, c.reds, c.walks, c.ped_clears, c.phase_nexts)

    def letter(self, phase: int) -> str:
        if phase in self.walks:
            return "W"
        if phase in self.ped_clears:
            return "P"
        return "G" if phase in self.greens else "Y" if phase in self.yellows else "r"


DEFAULT_CALLS: tuple[tuple[float, tuple[int, ...]], ...] = (
    (2.0, (3, 7)),   # side-street lefts: crosses the barrier from the start-up [2,6]
    (14.0, (4, 8)),  # side-street throughs: same barrier group
    (26.0, (1, 5)),  # main-street lefts: back across the barrier
    (40.0, (1, 6)),  # a lead-lag pair: only ring 2 changes
)
DEFAULT_PED_CALLS: tuple[tuple[float, tuple[int, ...]], ...] = (
    (2.0, (4,)),     # a pedestrian crossing beside the north approach's through
)
DEMO_WALK, DEMO_PED_CLEAR = 4.0, 5.0  # s, given to the throughs that have no pedestrian timing of their own


def with_pedestrians(config: IntersectionConfig, walk: float = DEMO_WALK,
                     ped_clear: float = DEMO_PED_CLEAR) -> IntersectionConfig:
    """The config with Walk and pedestrian clearance on the throughs that have none (and room for them)."""
    phases = {p: dataclasses.replace(ph, walk=walk, ped_clear=ped_clear)
              if ph.turn == "through" and ph.walk == 0 and walk + ped_clear <= ph.max_green else ph
              for p, ph in config.phases.items()}
    return dataclasses.replace(config, phases=phases)


def run(config: IntersectionConfig, calls: Iterable[tuple[float, Iterable[int]]] = DEFAULT_CALLS,
        duration: float = 60.0,
        ped_calls: Iterable[tuple[float, Iterable[int]]] = DEFAULT_PED_CALLS) -> list[Row]:
    """Run the model for ``duration`` s, SET VehCall and PedCall at the given times; return the display changes."""
    env = simpy.Environment()
    controller = Controller(config)
    rows = [Row.of(0.0, controller)]

    def ticking():
        for _ in controller.process(env):
            yield _
            row = Row.of(round(controller.tick / 10, 1), controller)
            if dataclasses.replace(row, t=rows[-1].t, reds=rows[-1].reds) != rows[-1]:
                rows.append(row)

    def caller(column: ControlColumn, timed: Iterable[tuple[float, Iterable[int]]]):
        for at, phases in sorted(timed):
            yield env.timeout(at - env.now)
            controller.set_control(column, phases)

    env.process(ticking())
    env.process(caller(ControlColumn.VEH_CALL, calls))
    env.process(caller(ControlColumn.PED_CALL, ped_calls))
    env.run(until=duration)
    return rows


def render(rows: list[Row], config: IntersectionConfig) -> str:
    phases = config.phase_numbers
    head = "     t (s)  " + " ".join(f"{p:>2}" for p in phases) + "   green    yellow   next"
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = " ".join(f"{r.letter(p):>2}" for p in phases)
        lines.append(f"{r.t:10.1f}  {cells}   {_fmt(r.greens):8} {_fmt(r.yellows):8} {_fmt(r.nexts)}")
    lines.append("G green, W walk, P pedestrian clearance, Y yellow, r red; next: phaseStatusGroupPhaseNexts")
    return "\n".join(lines)


def _fmt(phases: frozenset[int]) -> str:
    return "[" + ",".join(map(str, sorted(phases))) + "]" if phases else "-"
