"""The lights of a network a sumo-rl user brings, each a NEMA controller derived from its SUMO program, and how
sumo-rl's names for a light's phases and lanes map onto that controller.

Rules of this module
--------------------
- Every traffic light of the network gets the controller :mod:`hils.protocol.resco` derives from its first program, as
  ``resco:`` scenarios do, with sumo-rl's ``yellow_time``, ``min_green`` and ``max_green`` as every phase's yellow,
  minimum green and maximum green (:class:`hils.protocol.resco.Timing`), its red clearance the program's all-red (one
  0.1 s controller tick where the program has none), ``delta_time`` as the control interval and SUMO's step length
  as the run's SUMO step.
- sumo-rl's action is the index of one of the light's *green phases*: the phases of its first program with no 'y'
  that are not all 'r' and 's' (sumo-rl's ``TrafficSignal._build_phases``), in program order, repeats included. A
  green phase is the stage of the derived controller made from the same program phase (``DerivedLight.stages``):
  asking for it asks the controller for that stage's pair. A green phase that is no stage (one green only on link
  indices that control no connection: the derivation drops it, having nothing to serve) keeps what is shown.
- A light's lanes are sumo-rl's: its incoming lanes in link-index order, each once (``getControlledLanes``), and the
  outgoing lane of each link index's first connection, each once (sumo-rl keeps them as a set, in no order; here in
  link-index order). They are read from the network before SUMO runs, so that every space is known at construction.
- What the controller cannot honour is refused, naming the option and what is allowed: a yellow outside NTCIP 1202's
  phaseYellowChange (3-25.5 s; sumo-rl's default of 2 s is below it, and a signal monitor faults a yellow under
  2.7 s), a minimum or maximum green that is not whole seconds in NTCIP's range, ``max_green`` not above
  ``min_green`` (sumo-rl asserts it too), and a ``delta_time`` not longer than a light's clearance (yellow plus red
  clearance: sumo-rl asserts ``delta_time > yellow_time``; a decision due while the light still clears would be
  dropped by the middleware, which takes no command during a transition).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from hils.envs.intersection import EnvOptionError
from hils.protocol import resco
from hils.protocol.config import IntersectionConfig, Pair, phase_time_range
from hils.protocol.scenario import Scenario

__all__ = ["PREFIX", "Light", "Timings", "derive", "green_phases"]

#: How a run names the scenario of a sumo-rl network: ``sumo-rl:`` and the network's file name.
PREFIX = "sumo-rl:"


@dataclass(frozen=True, slots=True)
class Timings:
    """sumo-rl's timing options, in seconds, as the derived controllers take them."""

    delta_time: float
    yellow_time: float
    min_green: int
    max_green: int
    begin_time: float
    num_seconds: float
    step_length: float


@dataclass(frozen=True)
class Light:
    """One light as sumo-rl names it: its controller's config, the state of each of sumo-rl's green phases and the
    index in ``config.sequence`` of the stage each one is (None: no stage), its incoming and outgoing lanes and
    their lengths."""

    id: str
    config: IntersectionConfig
    green_states: tuple[str, ...]
    stage_of: tuple[int | None, ...]
    lanes: tuple[str, ...]
    out_lanes: tuple[str, ...]
    lanes_length: Mapping[str, float]

    def pair_of(self, green_phase: int) -> Pair | None:
        """The pair sumo-rl's green phase ``green_phase`` asks for (None: it is no stage)."""
        stage = self.stage_of[green_phase]
        return None if stage is None else self.config.sequence[stage]

    def green_phases_of(self, pair: Pair) -> tuple[int, ...]:
        """sumo-rl's green phases that ask for ``pair`` (a program may show one stage twice a cycle)."""
        return tuple(g for g, stage in enumerate(self.stage_of)
                     if stage is not None and self.config.sequence[stage] == pair)

    @property
    def clearance(self) -> float:
        """The longest yellow plus red clearance of its phases (s)."""
        return max(p.clearance for p in self.config.phases.values())


def green_phases(states: Sequence[str]) -> tuple[int, ...]:
    """The indices of sumo-rl's green phases among a program's phase states: no 'y', and not all 'r' and 's'."""
    return tuple(k for k, state in enumerate(states)
                 if "y" not in state and state.count("r") + state.count("s") != len(state))


def derive(net_file: str | Path, sumocfg: Path, timings: Timings) -> tuple[Scenario, dict[str, Light]]:
    """Every light of ``net_file`` (run by ``sumocfg``) derived as the module header says: the scenario the Testbed
    runs, and each light as sumo-rl names it, by id in SUMO's order."""
    import sumolib  # here: reading a network is what constructing an environment costs, not importing hils

    _check(timings)
    net_file = Path(net_file)
    given = resco.Timing(timings.yellow_time, timings.min_green, timings.max_green)
    params = resco.RescoMap(timings.delta_time, timings.yellow_time, timings.begin_time,
                            timings.begin_time + timings.num_seconds)
    scenario, derived = resco.derive_network(f"{PREFIX}{net_file.name}", sumocfg, net_file, params, given)
    if not derived:
        raise EnvOptionError(f"net_file {net_file}: has no traffic light; allowed: a network with at least one (each "
                             "light is an agent)")
    configs = {tls: light.config.with_middleware(sumo_step=timings.step_length, control_interval=timings.delta_time)
               for tls, light in derived.items()}
    net = sumolib.net.readNet(str(net_file), withPrograms=True)
    lights = {}
    for tls in configs:
        lights[tls] = light = _light(net, net.getTLS(tls), configs[tls], derived[tls].stages)
        if timings.delta_time <= light.clearance:
            raise EnvOptionError(f"delta_time {timings.delta_time:g} s: traffic light {tls} clears for "
                                 f"{light.clearance:g} s (yellow {timings.yellow_time:g} s + the red clearance of its "
                                 f"program); allowed: delta_time > {light.clearance:g} s, so that a decision never "
                                 "falls while the light is still clearing")
    scenario = Scenario(scenario.name, scenario.source, sumocfg, MappingProxyType(configs), scenario.links)
    return scenario, lights


def _check(t: Timings) -> None:
    """Refuse a timing the derived controllers cannot take (the module header's list)."""
    for name in ("delta_time", "num_seconds", "step_length", "yellow_time", "min_green", "max_green"):
        value = getattr(t, name)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
            raise EnvOptionError(f"{name} {value!r}: allowed: a positive number of seconds")
    if t.delta_time < t.step_length:
        raise EnvOptionError(f"delta_time {t.delta_time:g} s is shorter than SUMO's step of {t.step_length:g} s; "
                             "allowed: delta_time >= the step length")
    low, high = phase_time_range("yellow")
    if not low <= t.yellow_time <= high or abs(round(t.yellow_time * 10) - t.yellow_time * 10) > 1e-9:
        raise EnvOptionError(f"yellow_time {t.yellow_time!r}: a NEMA controller's yellow change is NTCIP 1202's "
                             f"phaseYellowChange; allowed: {low:g}-{high:g} s in tenths (sumo-rl's default of 2 s is "
                             "below it, and a signal monitor faults a yellow under 2.7 s)")
    for name in ("min_green", "max_green"):
        value, high = getattr(t, name), phase_time_range(name)[1]
        if not 1 <= value <= high or value != int(value):
            raise EnvOptionError(f"{name} {value!r}: allowed: whole seconds, 1-{high:g} (NTCIP 1202)")
    if t.max_green <= t.min_green:
        raise EnvOptionError(f"max_green {t.max_green} s is not above min_green {t.min_green} s; allowed: "
                             "max_green > min_green (as sumo-rl asserts)")


def _light(net: Any, tls: Any, config: IntersectionConfig, stages: Sequence[int]) -> Light:
    """One light as sumo-rl names it (the module header's rules), read from the sumolib network."""
    program = next(iter(tls.getPrograms().values()))
    states = [phase.state for phase in program.getPhases()]
    greens = green_phases(states)
    stage_at = {at: k for k, at in enumerate(stages)}
    # per link index, its connections in the network's order: the incoming lane of each, the outgoing lane of the first
    by_index: dict[int, list[tuple[str, str]]] = {}
    for in_lane, out_lane, index in tls.getConnections():
        by_index.setdefault(index, []).append((in_lane.getID(), out_lane.getID()))
    lanes = tuple(dict.fromkeys(lane for index in sorted(by_index) for lane, _ in by_index[index]))
    out_lanes = tuple(dict.fromkeys(by_index[index][0][1] for index in sorted(by_index)))
    lengths = {lane: net.getLane(lane).getLength() for lane in (*lanes, *out_lanes)}
    return Light(tls.getID(), config, tuple(states[g] for g in greens), tuple(stage_at.get(g) for g in greens),
                 lanes, out_lanes, MappingProxyType(lengths))
