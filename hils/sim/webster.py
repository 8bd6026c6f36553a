"""A fixed-time signal plan from the demand, by Webster's method.

Theory of operation
-------------------
Webster (1958) sets the cycle of a fixed-time signal that minimises the mean delay of
undersaturated traffic and splits its green in proportion to how loaded each stage is:

1. Demand per phase: the route file's flows (veh/h) are put on the phase whose link carries
   their first turn through the junction (right turns run with the through of their approach,
   as the phase map derived from the network says).
2. Flow ratio per phase: y = q / (n s), with n the phase's incoming lanes and s the
   saturation flow of a lane (1800 veh/h, the Highway Capacity Manual's base).
3. Critical flow ratio per stage: the sequence serves one pair of phases at a time, so the
   stage's ratio is the larger of its two; Y is the sum over the stages.
4. Lost time L: the yellow plus red clearance of every stage (the larger of its pair).
5. Optimal cycle C0 = (1.5 L + 5) / (1 - Y); the effective green C0 - L is split in
   proportion to the stages' critical ratios and each green is clipped to the pair's
   [min_green, max_green] of the config. The cycle actually run is the sum of the clipped
   greens plus L; when Y >= 1 the demand exceeds what any cycle serves and every stage gets
   its maximum green.

Rules: the plan is computed from files only (no SUMO run); bad demand is an error naming the
file, the field and what is allowed.
"""

from __future__ import annotations

import itertools
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from hils.protocol.config import IntersectionConfig, Pair
from hils.sim.network import ROUTE_FILE, PhaseMap, data_path, derive_phase_map, read_net

SATURATION_FLOW = 1800.0  # veh/h per lane (HCM base saturation flow rate)

_EXP_PERIOD = re.compile(r"^exp\(([0-9.eE+-]+)\)$")


class DemandError(ValueError):
    """A route file whose demand cannot be read as hourly flows."""


@dataclass(frozen=True, slots=True)
class Stage:
    """One pair of the sequence in the plan."""

    pair: Pair
    flow_ratio: float  # critical flow ratio y (larger of the pair's)
    green: float  # s, clipped to the pair's green range
    clearance: float  # s, yellow + red clearance


@dataclass(frozen=True, slots=True)
class WebsterPlan:
    """Webster's fixed-time plan: optimal cycle, the cycle run after clipping, green per stage."""

    flows: Mapping[int, float]  # veh/h per phase
    stages: tuple[Stage, ...]
    lost_time: float
    total_flow_ratio: float
    optimal_cycle: float | None  # None when Y >= 1 (oversaturated)

    @property
    def cycle(self) -> float:
        return sum(s.green + s.clearance for s in self.stages)

    def green_of(self, pair: Pair) -> float:
        for stage in self.stages:
            if set(stage.pair) == set(pair):
                return stage.green
        raise KeyError(f"pair {pair} is not in the plan's sequence")

    def describe(self) -> str:
        c0 = "none (Y >= 1, oversaturated)" if self.optimal_cycle is None else f"{self.optimal_cycle:.1f} s"
        splits = ", ".join(f"{s.pair[0]}+{s.pair[1]} {s.green:.1f} s (y {s.flow_ratio:.3f})" for s in self.stages)
        return (f"Webster plan: cycle {self.cycle:.1f} s (optimal C0 {c0}, lost time {self.lost_time:.1f} s, "
                f"Y {self.total_flow_ratio:.3f}); greens {splits}")


def route_flows(route_file: Path, phase_map: PhaseMap) -> dict[int, float]:
    """Hourly demand (veh/h) per phase from the ``<flow>`` elements of a route file."""
    served = {(_edge(link.from_lane), _edge(link.to_lane)): link.phase for link in phase_map.links}
    root = ET.parse(route_file).getroot()
    routes = {r.get("id"): (r.get("edges") or "").split() for r in root.iter("route")}
    out = {p: 0.0 for p in phase_map.phases}
    for flow in root.iter("flow"):
        fid = flow.get("id")
        edges = routes.get(flow.get("route"), [])
        phase = next((served[(a, b)] for a, b in itertools.pairwise(edges) if (a, b) in served), None)
        if phase is None:
            raise DemandError(f"{route_file}: flow {fid!r}: route {flow.get('route')!r} does not pass the "
                              "signal; allowed: a route id of this file through a signalled junction link")
        out[phase] += _hourly(flow, route_file)
    return out


def _hourly(flow: ET.Element, source: Path) -> float:
    fid = flow.get("id")
    if (vph := flow.get("vehsPerHour")) is not None:
        return float(vph)
    period = flow.get("period")
    if period is not None:
        m = _EXP_PERIOD.match(period)
        if m:
            return float(m.group(1)) * 3600.0
        try:
            return 3600.0 / float(period)
        except (ValueError, ZeroDivisionError):
            pass
    raise DemandError(f"{source}: flow {fid!r}: period/vehsPerHour: no hourly rate; allowed: vehsPerHour=N, "
                      f"period=SECONDS or period=\"exp(RATE)\", got period={period!r}")


def _edge(lane: str) -> str:
    return lane.rsplit("_", 1)[0]


def webster_plan(config: IntersectionConfig, *, route_file: Path | None = None, net_file: Path | None = None,
                 saturation_flow: float = SATURATION_FLOW) -> WebsterPlan:
    """Webster's plan for ``config`` on a network and its demand (default: the shipped ones)."""
    phase_map = derive_phase_map(config, read_net(net_file))
    flows = route_flows(route_file or data_path(ROUTE_FILE), phase_map)
    ratio = {p: flows[p] / (len(phase_map.incoming_lanes(p)) * saturation_flow) for p in phase_map.phases}
    phases = config.phases
    crit = [max(ratio[p] for p in pair) for pair in config.sequence]
    clear = [max(phases[p].clearance for p in pair) for pair in config.sequence]
    lost = sum(clear)
    total = sum(crit)
    c0 = (1.5 * lost + 5.0) / (1.0 - total) if total < 1.0 else None
    stages = []
    for pair, y, c in zip(config.sequence, crit, clear, strict=True):
        g_min = max(phases[p].min_green for p in pair)
        g_max = max(g_min, min(phases[p].max_green for p in pair))
        green = g_max if c0 is None else min(g_max, max(g_min, (c0 - lost) * y / total))
        stages.append(Stage(pair, y, green, c))
    return WebsterPlan(flows, tuple(stages), lost, total, c0)
