"""RESCO's benchmark scenarios, every traffic light a NEMA controller derived from its SUMO program.

RESCO (Ault & Sharon, NeurIPS 2021 datasets and benchmarks track) is the benchmark RL traffic-signal
papers report on: eight SUMO scenarios (:data:`MAPS`). hils does not ship them (their licences differ:
see the README); it reads them from the installed ``sumo-rl`` package (``pip install 'hils[resco]'``),
which carries RESCO's networks and demand in ``sumo_rl/nets/RESCO``. ``load("cologne8")`` gives a
:class:`hils.protocol.scenario.Scenario` whose lights each run a config derived here from the light's SUMO program,
with its signal links bound to the config's phases (:class:`hils.protocol.scenario.SignalLink`).

Rules of this module
--------------------
- The program is the light's first one (RESCO takes ``getAllProgramLogics(light)[0]``); its *stages* are
  RESCO's green phases: the phases with a 'g' or 'G' and no 'y' (``multi_signal.py``: ``if "y" not in
  p.state and "g" in p.state.lower()``), in program order. They are what the controller must be able to
  serve, and the derived config's pairs and sequence are exactly they.
- A *movement* is the links of one incoming edge and one turn: left (SUMO's l, L and t: a U-turn runs with
  the left of its approach) or through (s, r, R: a right turn runs with its through, or with its approach's
  left where the approach has no straight, as a T-junction's stem). It is protected in the
  stages where its core links (its straights, or its lefts) are all 'G'. A link green in further stages is an
  overlap of the phases green there; a link shown 'g' (yielding) runs permissive beside a phase green then,
  its own approach's first.
- Dual ring: each protected movement is a phase; two movements a stage shows together go in different rings
  of one barrier group; a stage with one movement gets a partner in the other ring (its rights split off,
  or a phase driving no signal, as cabinets program a ring that has nothing to serve). Barrier groups that
  the stages leave apart are joined where SUMO's own conflict table (the junction's ``foes``) finds no
  conflict between the protected links of any pair the join makes concurrent: that is how grid4x4 and
  cologne come out eight-phase. Every pair of one barrier group must be conflict-free or shown by the program.
- Split phase, when no dual-ring structure fits (a stage of three movements that never run alone, an odd
  cycle, a concurrent pair that conflicts): each stage is its own barrier group of one phase per ring, its
  links split between them; a link green in several stages is an overlap of their phases.
- A light is refused, naming it and the reason, when its program has no stage, a stage shows no protected
  link, or a link is never green.
- Timings come from the program: yellow from the phase where the phase's links show 'y' after its green
  (RESCO's own yellow where the program has none: it inserts them), red clearance from all-red phases after
  it (0.1 s, one controller tick, the least a config allows, where there is none), minimum and maximum green
  from the stage's minDur/maxDur, or netconvert's defaults for lights with variable phase length (5 s and
  50 s: ``--tls.min-dur``, ``--tls.max-dur``) where the program gives none. The decision interval is RESCO's
  ``step_length`` (10 s; 5 s on arterial4x4).
- The timing plan (coordination pattern 1, the program's own signal timing; the controller powers up free, as the
  phase-commanding agents need, and ``coordinated`` and ``fixed-time`` run it): the cycle is the program's; each
  stage's interval runs from its start to the next stage's (its yellow and all-red included), on whole seconds (the
  stage starts rounded, so the intervals add up to the cycle); a phase's split is the sum of the intervals of the
  stages that show it (a phase the program shows twice a cycle, as grid4x4's throughs, gets both, served once a
  cycle as NEMA serves a phase). Every stage is one phase per ring of one barrier group, so each ring adds up to
  the cycle and the rings reach every barrier together by construction. The coordinated phases are the pair of the
  program's longest stage (the main street's through; the first of equals), the offset the time its green starts
  in the program's own schedule (the program's offset, when SUMO starts its first phase, plus the stages before
  it). A light gets no plan, and says why, when its cycle is outside NTCIP's 30-255 s or a split is shorter than
  its phase's minimum service (minimum green + yellow + red clearance).
- The scenario's begin is its ``.sumocfg``'s (cologne 25200 s, ingolstadt 57600 s, as RESCO's map_config
  ``start_time``); a run lasts one simulated hour by default, as RESCO evaluates.
- Any other network derives the same way (:func:`derive_network`), with the decision interval and default yellow
  its caller gives (:class:`RescoMap`) and, where given, one yellow, minimum and maximum green for every phase in
  place of the program's (:class:`Timing`: sumo-rl's ``yellow_time``, ``min_green`` and ``max_green``,
  :mod:`hils.sumo_rl`); the red clearance stays the program's.
"""

from __future__ import annotations

import importlib.util
import itertools
import math
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import timedelta
from functools import cache
from pathlib import Path
from types import MappingProxyType
from typing import Any

from hils.protocol.config import DEFAULT_START, IntersectionConfig, from_dict
from hils.protocol.errors import UserError
from hils.protocol.scenario import RESCO_PREFIX, Scenario, SignalLink


@dataclass(frozen=True, slots=True)
class RescoMap:
    """What RESCO's ``map_config.py`` says of a scenario (its ``step_length`` is the decision interval); for another
    network, the same facts as its caller gives them."""

    decision_interval: float
    yellow: float
    start: float
    end: float


#: RESCO's eight scenarios as its map_config.py gives them.
MAPS = MappingProxyType({
    "grid4x4": RescoMap(10.0, 3.0, 0.0, 3600.0),
    "arterial4x4": RescoMap(5.0, 2.0, 0.0, 3600.0),
    "cologne1": RescoMap(10.0, 3.0, 25200.0, 28800.0),
    "cologne3": RescoMap(10.0, 3.0, 25200.0, 28800.0),
    "cologne8": RescoMap(10.0, 3.0, 25200.0, 28800.0),
    "ingolstadt1": RescoMap(10.0, 3.0, 57600.0, 61200.0),
    "ingolstadt7": RescoMap(10.0, 3.0, 57600.0, 61200.0),
    "ingolstadt21": RescoMap(10.0, 3.0, 57600.0, 61200.0),
})
NAMES = tuple(MAPS)

#: netconvert's defaults for the minimum and maximum green of lights with variable phase length
#: (``--tls.min-dur``, ``--tls.max-dur``), where the program gives none.
DEFAULT_MIN_GREEN = 5
DEFAULT_MAX_GREEN = 50
#: Red clearance where the program has no all-red: one controller tick, the least a config allows.
NO_ALL_RED = 0.1

_LEFT, _THROUGH = "left", "through"
_CORE = {_LEFT: frozenset("lL"), _THROUGH: frozenset("s")}


@dataclass(frozen=True, slots=True)
class Timing:
    """Timings every phase of a derived light gets in place of its program's (None: the program's)."""

    yellow: float | None = None
    min_green: int | None = None
    max_green: int | None = None


class RescoError(UserError, ValueError):
    """A RESCO scenario that cannot be loaded, or a light no NEMA structure fits."""


# --- the scenarios ------------------------------------------------------------------------------------


def networks_dir() -> Path:
    """sumo-rl's ``nets/RESCO`` folder, found without importing sumo-rl (which needs SUMO_HOME set)."""
    spec = importlib.util.find_spec("sumo_rl")
    if spec is None or not spec.submodule_search_locations:
        raise RescoError("RESCO's scenarios are read from the sumo-rl package, which is not installed; "
                         "allowed: pip install 'hils[resco]'")
    folder = Path(next(iter(spec.submodule_search_locations))) / "nets" / "RESCO"
    if not folder.is_dir():
        raise RescoError(f"the installed sumo-rl has no RESCO networks ({folder} is missing); allowed: sumo-rl >= 1.4")
    return folder


def sumo_config(name: str) -> Path:
    """The ``.sumocfg`` of RESCO's scenario ``name``."""
    if name not in MAPS:
        raise RescoError(f"{RESCO_PREFIX}{name}: no RESCO scenario of that name; allowed: "
                         f"{', '.join(RESCO_PREFIX + n for n in NAMES)}")
    path = networks_dir() / name / f"{name}.sumocfg"
    if not path.is_file():
        raise RescoError(f"{RESCO_PREFIX}{name}: {path} is missing from the installed sumo-rl")
    return path


def load(name: str) -> Scenario:
    """RESCO's scenario ``name``: its ``.sumocfg`` and, per traffic light, a derived config and link binding."""
    return _load(name)


@cache
def _load(name: str) -> Scenario:
    cfg = sumo_config(name)
    return derive_network(f"{RESCO_PREFIX}{name}", cfg, _net_file(cfg), MAPS[name])[0]


def derive_network(name: str, sumocfg: Path, net_file: Path, resco: RescoMap, timing: Timing = Timing()
                   ) -> tuple[Scenario, dict[str, DerivedLight]]:
    """The scenario ``name`` of the network ``net_file`` run by ``sumocfg``: every traffic light (by id) a controller
    derived from its program; with each light's derivation (its stages among the program's phases)."""
    import sumolib  # here: `hils` names RESCO's scenarios at every start, and reads a network only to load one

    net = sumolib.net.readNet(str(net_file), withPrograms=True)
    lights = {tls.getID(): derive(tls, resco, name, timing)
              for tls in sorted(net.getTrafficLights(), key=lambda t: t.getID())}
    scenario = Scenario(name, f"{name} ({sumocfg})", sumocfg,
                        MappingProxyType({tls: light.config for tls, light in lights.items()}),
                        MappingProxyType({tls: light.links for tls, light in lights.items()}))
    return scenario, lights


def _net_file(sumocfg: Path) -> Path:
    value = ET.parse(sumocfg).find("input/net-file")
    if value is None:
        raise RescoError(f"{sumocfg}: input/net-file is missing")
    return sumocfg.parent / value.get("value", "")


# --- the derivation ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DerivedLight:
    """One light's derived controller: its config (as a TOML-shaped table and validated), how each of its signal
    links follows the phases, which structure fitted, and the program phase each stage (each pair of the config's
    sequence, in its order) comes from."""

    config: IntersectionConfig
    links: tuple[SignalLink, ...]
    structure: str  # "dual-ring" or "split phase"
    table: Mapping[str, Any] = field(repr=False)
    stages: tuple[int, ...] = ()


@dataclass
class _Phase:
    """A phase being built: the links it drives, the stages it is green in, its ring and barrier group."""

    links: list[int]
    stages: frozenset[int]
    turn: str | None
    edge: str | None
    ring: int = 0
    group: int = 0
    number: int = 0


@dataclass(frozen=True)
class _Light:
    """What the derivation reads of one light: per link index its connections' edge and turn, its state in
    every stage, and the program's phases."""

    id: str
    where: str
    edges: tuple[str | None, ...]
    turns: tuple[str | None, ...]
    directions: tuple[str, ...]
    stages: tuple[str, ...]
    stage_at: tuple[int, ...]  # program index of each stage
    program: tuple[Any, ...]
    connections: tuple[tuple[Any, ...], ...]
    offset: float = 0.0  # the program's offset (s)

    def protected(self, i: int) -> frozenset[int]:
        return frozenset(k for k, s in enumerate(self.stages) if s[i] == "G")

    def yielding(self, i: int) -> frozenset[int]:
        return frozenset(k for k, s in enumerate(self.stages) if s[i] == "g")


def derive(tls: Any, resco: RescoMap, scenario: str, timing: Timing = Timing()) -> DerivedLight:
    """The NEMA controller of the sumolib traffic light ``tls`` (read with programs), as the module header says;
    ``timing`` replaces the program's yellow, minimum and maximum green of every phase where it gives them."""
    light = _read(tls, f"{scenario}: traffic light {tls.getID()}")
    movements = _movements(light)
    try:
        phases, links = _dual_ring(light, movements)
        structure = "dual-ring"
    except _NoFit:
        phases, links = _split_phase(light)
        structure = "split phase"
    _number(phases)
    table = _table(light, phases, resco, structure, timing)
    plan = _plan(light, table)
    if isinstance(plan, dict):  # free at power-up, as the phase-commanding agents need
        table["coordination"] = {"pattern": "free", "patterns": [plan]}
    try:
        config = from_dict(table, source=source_of(scenario, light.id))
    except UserError as exc:  # a derivation that breaks a config rule is this module's bug, said so
        raise RescoError(f"{light.where}: the derived config is not valid ({exc})") from None
    if isinstance(plan, str):
        config = replace(config, coordination=replace(config.coordination, unplanned=plan))
    bound = tuple(SignalLink(None) if link is None else
                  SignalLink(phases[link[0]].number, link[1], _numbers(phases, link[2]), _numbers(phases, link[3]))
                  for link in links)
    return DerivedLight(config, bound, structure, MappingProxyType(table), light.stage_at)


def source_of(scenario: str, tls: str) -> str:
    """A derived config's source, as a run's log names it: the scenario and the light (``resco:cologne1 GS_...``)."""
    return f"{scenario} {tls}"


def light_of(source: str) -> tuple[str, str] | None:
    """The scenario and light a derived config's :func:`source_of` names; None for any other source (a file, or a
    RESCO scenario's own: ``resco:cologne3 (.../cologne3.sumocfg)``)."""
    scenario, _, tls = source.partition(" ")
    return (scenario, tls) if scenario.startswith(RESCO_PREFIX) and tls and not tls.startswith("(") else None


def titled(scenario: str, tls: str) -> str:
    """How a run of a scenario's one light is titled (console, pictures): the scenario, then the light."""
    return f"{scenario}, light {tls}"


class _NoFit(Exception):
    """No dual-ring structure serves the program's stages (the split-phase one is used instead)."""


def _read(tls: Any, where: str) -> _Light:
    programs = list(tls.getPrograms().values())
    if not programs:
        raise RescoError(f"{where}: has no signal program; allowed: a light with a static program")
    program = tuple(programs[0].getPhases())
    size = len(program[0].state)
    connections: list[list[Any]] = [[] for _ in range(size)]
    for in_lane, out_lane, index in tls.getConnections():
        connections[index].append(in_lane.getConnection(out_lane))
    # RESCO's green phases, less those green only on indices that control no connection (they serve nothing)
    stage_at = tuple(k for k, ph in enumerate(program) if "y" not in ph.state and "g" in ph.state.lower()
                     and any(ph.state[i] in "Gg" for i in range(size) if connections[i]))
    if not stage_at:
        raise RescoError(f"{where}: its program has no green phase (one with 'g' or 'G' and no 'y'); no NEMA phase "
                         "has anything to serve")
    edges, turns, directions = [], [], []
    for conns in connections:
        dirs = "".join(c.getDirection() for c in conns)
        edges.append(conns[0].getFrom().getID() if conns else None)
        # an index carrying a straight, or only rights, is a through; one carrying lefts or U-turns, a left
        turns.append(None if not conns else _THROUGH if "s" in dirs or not set(dirs) & set("lLt") else _LEFT)
        directions.append(dirs)
    stages = tuple(program[k].state for k in stage_at)
    light = _Light(tls.getID(), where, tuple(edges), tuple(turns), tuple(directions), stages, stage_at, program,
                   tuple(tuple(c) for c in connections), float(programs[0].getOffset() or 0))
    for i, conns in enumerate(connections):
        if conns and not light.protected(i) and not light.yielding(i):
            raise RescoError(f"{where}: link {i} ({_describe(light, i)}) is green in no phase of the program; a "
                             "controller would hold it red for good")
    for k, state in enumerate(stages):
        if not any(state[i] == "G" for i in range(size) if connections[i]):
            raise RescoError(f"{where}: program phase {stage_at[k]} ({state}) shows no protected ('G') link; "
                             "allowed: stages that protect at least one movement")
    return light


def _describe(light: _Light, i: int) -> str:
    return f"{light.edges[i]}, {'/'.join(sorted(set(light.directions[i])))}"


def _movements(light: _Light) -> list[tuple[str, str, frozenset[int], list[int]]]:
    """(edge, turn, protected stages, link indices) of every movement, as the module header defines them."""
    grouped: dict[tuple[str, str], list[int]] = {}
    for i, edge in enumerate(light.edges):
        if edge is not None:
            grouped.setdefault((edge, light.turns[i]), []).append(i)
    for edge in {edge for edge, _ in grouped}:
        # an approach without a straight (a T-junction's stem) runs its rights with its left
        rights = grouped.get((edge, _THROUGH), [])
        if rights and (edge, _LEFT) in grouped and not any("s" in light.directions[i] for i in rights):
            grouped[(edge, _LEFT)] = sorted(grouped[(edge, _LEFT)] + grouped.pop((edge, _THROUGH)))
    out = []
    for (edge, turn), indices in grouped.items():
        protected = [i for i in indices if light.protected(i)]
        core = [i for i in protected if set(light.directions[i]) & _CORE[turn]] or protected
        stages = frozenset.intersection(*(light.protected(i) for i in core)) if core else frozenset()
        own = [i for i in indices if not light.protected(i) or light.protected(i) >= stages] if stages else indices
        out.append((edge, turn, stages, own))
        # a link protected apart from its movement's core (in stages disjoint from it) is a movement of its own
        for i in (i for i in indices if i not in own):
            out.append((edge, turn, light.protected(i), [i]))
    return out


def _parent(phases: Sequence[_Phase], stage: int, edge: str | None, shown: frozenset[int]) -> int:
    """The phase a link follows in ``stage``: one of that stage's, best one green only where the program shows the
    link green (``shown``), then its own approach's."""
    green = [n for n, p in enumerate(phases) if stage in p.stages and p.links]
    return min(green, key=lambda n: (not phases[n].stages <= shown, phases[n].edge != edge))


def _bind(light: _Light, phases: list[_Phase], primary: Mapping[int, int]) -> list[Any]:
    """Per link index: None (no connection) or (phase, yields, also, yields_with) as indices into ``phases``."""
    out: list[Any] = []
    for i, edge in enumerate(light.edges):
        if edge is None:
            out.append(None)
            continue
        protected, yielding = light.protected(i), light.yielding(i)
        if i in primary:
            own = primary[i]
            covered = phases[own].stages
            yields = not protected
        else:  # permissive only: beside the phase of its first yielding stage
            own = _parent(phases, min(yielding), edge, yielding)
            covered, yields = phases[own].stages, True
        also = sorted({_parent(phases, k, edge, protected) for k in protected - covered} - {own})
        covered = covered | {k for n in also for k in phases[n].stages}
        yields_with = sorted({_parent(phases, k, edge, protected | yielding) for k in yielding - covered}
                             - {own, *also})
        out.append((own, yields, tuple(also), tuple(yields_with)))
    return out


def _dual_ring(light: _Light, movements: list[tuple[str, str, frozenset[int], list[int]]]) -> tuple[list[_Phase], list]:
    phases = [_Phase(list(links), stages, turn, edge) for edge, turn, stages, links in movements if stages]
    primary = {i: n for n, p in enumerate(phases) for i in p.links}
    for k in range(len(light.stages)):
        if sum(k in p.stages for p in phases) > 2:
            phases, primary = _merge_alike(phases, primary, k)
    for k in range(len(light.stages)):
        here = [n for n, p in enumerate(phases) if k in p.stages]
        if len(here) > 2:
            raise _NoFit
        if len(here) == 1:
            _partner(light, phases, primary, here[0], k)
    links = _bind(light, phases, primary)
    _rings(light, phases, links)
    return phases, links


def _merge_alike(phases: list[_Phase], primary: dict[int, int], stage: int) -> tuple[list[_Phase], dict[int, int]]:
    """The phases of ``stage`` that are green in the same stages (always shown together: all of an approach, or
    both directions of a through) merged into one."""
    alike: dict[frozenset[int], list[int]] = {}
    for n, p in enumerate(phases):
        if stage in p.stages:
            alike.setdefault(p.stages, []).append(n)
    merged: list[_Phase] = []
    new_index: dict[int, int] = {}
    for n, p in enumerate(phases):
        if n in new_index:
            continue
        group = alike.get(p.stages, [n]) if stage in p.stages else [n]
        if len(group) > 1:
            members = [phases[m] for m in group]
            p = _Phase(sorted(i for q in members for i in q.links), p.stages, _common(q.turn for q in members),
                       _common(q.edge for q in members))
        new_index.update(dict.fromkeys(group, len(merged)))
        merged.append(p)
    return merged, {i: new_index[n] for i, n in primary.items()}


def _common(values: Iterable[str | None]) -> str | None:
    found = set(values)
    return found.pop() if len(found) == 1 else None


def _partner(light: _Light, phases: list[_Phase], primary: dict[int, int], alone: int, stage: int) -> None:
    """Give the stage's one phase a partner in the other ring: its rights split off, or a phase driving nothing
    (one for the whole light)."""
    p = phases[alone]
    rights = [i for i in p.links if set(light.directions[i]) <= set("rR")]
    rest = [i for i in p.links if i not in rights]
    if rights and rest and p.stages == frozenset({stage}):
        p.links[:] = rest
        phases.append(_Phase(rights, p.stages, _THROUGH, p.edge))
        primary.update(dict.fromkeys(rights, len(phases) - 1))
        return
    dummy = next((q for q in phases if not q.links), None)
    if dummy is None:
        phases.append(_Phase([], frozenset({stage}), None, None))
    else:
        dummy.stages = dummy.stages | {stage}


def _rings(light: _Light, phases: list[_Phase], links: Sequence[Any]) -> None:
    """Ring and barrier group of every phase: two-colour the stages' pairs, then join the groups that stay
    conflict-free; raises :class:`_NoFit` when no colouring exists or a concurrent pair conflicts."""
    pairs = {frozenset(n for n, p in enumerate(phases) if k in p.stages) for k in range(len(light.stages))}
    neighbours: dict[int, set[int]] = {n: set() for n in range(len(phases))}
    for a, b in map(tuple, pairs):
        neighbours[a].add(b)
        neighbours[b].add(a)
    groups: list[list[int]] = []
    for start in sorted(range(len(phases)), key=lambda n: min(phases[n].stages)):
        if phases[start].ring:
            continue
        phases[start].ring, todo, group = 1, [start], []
        while todo:
            n = todo.pop()
            group.append(n)
            for m in neighbours[n]:
                if not phases[m].ring:
                    phases[m].ring = 3 - phases[n].ring
                    todo.append(m)
                elif phases[m].ring == phases[n].ring:
                    raise _NoFit
        groups.append(group)
    # what each phase shows protected: its own links the program shows 'G', and the links overlapping it
    green = [[i for i, link in enumerate(links)
              if link is not None and ((link[0] == n and not link[1]) or n in link[2])] for n in range(len(phases))]

    def safe(a: list[int], b: list[int]) -> bool:
        # concurrent (other ring, same group): shown together by the program, or no conflict between their greens
        return all(phases[x].ring == phases[y].ring or frozenset((x, y)) in pairs
                   or not _conflict(light, green[x], green[y]) for x in a for y in b)

    def join(target: list[int], group: list[int]) -> bool:
        for _ in range(2):
            if safe(target, group):
                target.extend(group)
                return True
            for n in group:  # try it the other way round: its ring 1 phases in ring 2
                phases[n].ring = 3 - phases[n].ring
        return False

    if not all(safe(group, group) for group in groups):
        raise _NoFit
    joined: list[list[int]] = []
    for group in groups:
        if not any(join(target, group) for target in joined):
            joined.append(group)
    for index, group in enumerate(joined):
        for n in group:
            phases[n].group = index


def _conflict(light: _Light, a: Iterable[int], b: Iterable[int]) -> bool:
    """True when a link of ``a`` and one of ``b`` are foes in SUMO's junction conflict table."""
    return any(c.getJunction() is d.getJunction() and c.getJunction().areFoes(c.getJunctionIndex(),
                                                                             d.getJunctionIndex())
               for i in a for j in b for c in light.connections[i] for d in light.connections[j])


def _split_phase(light: _Light) -> tuple[list[_Phase], list]:
    """Each stage its own barrier group, the links it turns green first split between a phase of each ring; a link
    green in a later stage too is an overlap of that stage's ring 1 phase."""
    phases: list[_Phase] = []
    links = [i for i in range(len(light.edges)) if light.edges[i] is not None]
    first = {i: min(light.protected(i) or light.yielding(i)) for i in links}
    for k in range(len(light.stages)):
        mine = [i for i in links if first[i] == k]
        edges = list(dict.fromkeys(light.edges[i] for i in mine))
        ring1 = [i for i in mine if light.edges[i] == edges[0]] if len(edges) > 1 else \
            [i for i in mine if not set(light.directions[i]) <= set("rR")] or mine
        for ring, own in ((1, ring1), (2, [i for i in mine if i not in ring1])):
            phases.append(_Phase(own, frozenset({k}), _common(light.turns[i] for i in own),
                                 _common(light.edges[i] for i in own), ring, k))
    lead = {k: 2 * k for k in range(len(light.stages))}  # each stage's ring 1 phase
    bound: list[Any] = [None] * len(light.edges)
    for i in links:
        own = next(n for n, p in enumerate(phases) if i in p.links)
        protected = light.protected(i)
        bound[i] = (own, not protected, tuple(sorted(lead[k] for k in protected - {first[i]})),
                    tuple(sorted(lead[k] for k in light.yielding(i) - protected - {first[i]})))
    return phases, bound


def _number(phases: list[_Phase]) -> None:
    """NEMA numbers: with two barrier groups of at most two phases per ring, the standard eight (1-2 | 3-4 in
    ring 1, 5-6 | 7-8 in ring 2, the left of a group the odd one); otherwise ring 1 from 1 and ring 2 from 5 (or
    after ring 1's last), in service order."""
    groups = sorted({p.group for p in phases})
    cells = {(r, g): [p for p in phases if p.ring == r and p.group == g] for r in (1, 2) for g in groups}
    if len(groups) <= 2 and all(len(c) <= 2 for c in cells.values()):
        for (ring, group), cell in cells.items():
            base = 1 + 2 * groups.index(group) + 4 * (ring - 1)
            lefts = sorted(cell, key=lambda p: (p.turn != _LEFT, min(p.stages)))
            if len(cell) == 1:
                cell[0].number = base + (0 if cell[0].turn == _LEFT else 1)
            else:
                for offset, p in enumerate(lefts):
                    p.number = base + offset
        return
    ring1 = sorted((p for p in phases if p.ring == 1), key=lambda p: (p.group, min(p.stages)))
    ring2 = sorted((p for p in phases if p.ring == 2), key=lambda p: (p.group, min(p.stages)))
    for number, p in enumerate(ring1, start=1):
        p.number = number
    for number, p in enumerate(ring2, start=max(len(ring1), 4) + 1):
        p.number = number


def _numbers(phases: Sequence[_Phase], indices: Iterable[int]) -> tuple[int, ...]:
    return tuple(sorted(phases[n].number for n in indices))


def _table(light: _Light, phases: list[_Phase], resco: RescoMap, structure: str, timing: Timing) -> dict[str, Any]:
    """The config as TOML would hold it: phases with their program timings (or ``timing``'s), the structure, the
    middleware."""
    stage_pairs = []
    for k in range(len(light.stages)):
        here = sorted((p for p in phases if k in p.stages), key=lambda p: p.ring)
        stage_pairs.append([here[0].number, here[1].number])
    table_phases: dict[str, Any] = {}
    for p in sorted(phases, key=lambda p: p.number):
        yellow, red_clear = _clearance(light, p, resco)
        low, high = _green_limits(light, p)
        given = {"min_green": timing.min_green, "max_green": timing.max_green, "yellow": timing.yellow}
        # An agent selects any stage of the program, as sumo-rl's do, so a ring may have to go back to an earlier
        # phase of its group while the other ring times: Naztec's backing (TecNote 3013), not the NTCIP default.
        entry: dict[str, Any] = {"min_green": low, "max_green": high, "yellow": yellow, "red_clear": red_clear,
                                 "backup_prevent": False} | {
            key: value for key, value in given.items() if value is not None}
        if p.number in stage_pairs[0]:
            entry["startup"] = "green"
        table_phases[str(p.number)] = entry
    groups = sorted({p.group for p in phases})
    rings = [[p.number for p in sorted((p for p in phases if p.ring == r), key=lambda p: (p.group, min(p.stages)))]
             for r in (1, 2)]
    clearance = max(e["yellow"] + e["red_clear"] for e in table_phases.values())
    longest_min = max(e["min_green"] for e in table_phases.values())
    return {
        "name": f"{light.id}, {structure} from its SUMO program",
        "phases": table_phases,
        "structure": {
            "rings": rings,
            "barriers": [[p.number for p in phases if p.group == g] for g in groups],
            "sequence": stage_pairs,
            "pairs": [list(pair) for pair in dict.fromkeys(map(tuple, stage_pairs))],
        },
        # A commanded transition takes up to a minimum green, a clearance and the other ring's minimum green at a
        # barrier: tau_trans covers that with a poll's margin.
        "middleware": {"control_interval": resco.decision_interval,
                       "tau_trans": float(math.ceil(longest_min + clearance + 5.0))},
        # The controller's clock shows SUMO's time of day (cologne starts at 07:00): its hi-res log, its ATSPM bins
        # and its cycle timer count from midnight as SUMO's program does.
        "emulator": {"start": DEFAULT_START + timedelta(seconds=resco.start)},
    }


def _plan(light: _Light, table: Mapping[str, Any]) -> dict[str, Any] | str:
    """The program's own timing as coordination pattern 1 (or why no legal NEMA plan comes of it), as the module
    header says: each stage's interval runs from its start to the next stage's (its yellow and all-red included),
    on whole seconds (the stage starts rounded, so the intervals add up to the cycle); a phase's split is the sum of
    the intervals of the stages that show it."""
    table_phases, stage_pairs = table["phases"], table["structure"]["sequence"]
    durations = [ph.duration for ph in light.program]
    at = [sum(durations[:k]) for k in light.stage_at]
    cycle = round(sum(durations))
    bounds = [round(t) for t in at] + [round(at[0]) + cycle]
    interval = [b - a for a, b in itertools.pairwise(bounds)]
    if not 30 <= cycle <= 255:
        return f"its program's cycle of {sum(durations):g} s is outside NTCIP's 30-255 s"
    splits: dict[str, int] = dict.fromkeys(table_phases, 0)
    for k, pair in enumerate(stage_pairs):
        for p in pair:
            splits[str(p)] += interval[k]
    for p, split in splits.items():
        e = table_phases[p]
        need = e["min_green"] + e["yellow"] + e["red_clear"]
        if split < need:
            stages = [light.stage_at[k] for k, pair in enumerate(stage_pairs) if int(p) in pair]
            shown = (f"program phases {', '.join(map(str, stages))} with their" if len(stages) > 1
                     else f"program phase {stages[0]} with its")
            return (f"phase {p}'s split of {split} s ({shown} yellow and all-red) is shorter than its minimum service "
                    f"of {need:g} s (minimum green + yellow + red clearance)")
    # the coordinated phases: the pair of the longest stage (the main street's through), the first of equals
    main = max(range(len(stage_pairs)), key=lambda k: (durations[light.stage_at[k]], -k))
    return {"number": 1, "cycle": cycle, "offset": round(light.offset + at[main]) % cycle,
            "coord_phases": list(stage_pairs[main]), "splits": splits}


def _clearance(light: _Light, phase: _Phase, resco: RescoMap) -> tuple[float, float]:
    """Yellow and red clearance of ``phase``: the program's after each of its stages, the longest seen."""
    # a phase driving nothing clears with the phases it runs beside
    links = phase.links or [i for i in range(len(light.edges)) if light.protected(i) & phase.stages]
    yellows, reds = [], []
    program = light.program
    for k in phase.stages:
        at = light.stage_at[k]
        yellow = red = 0.0
        for step in range(1, len(program)):
            state = program[(at + step) % len(program)]
            if (at + step) % len(program) in light.stage_at:
                break
            if any(state.state[i] == "y" for i in links):
                yellow += state.duration
            elif yellow and not any(c in "Gg" for c in state.state):
                red += state.duration
            elif yellow:
                break
        if yellow:
            yellows.append(yellow)
            reds.append(red)
    yellow = max(yellows, default=resco.yellow)
    red = max(reds, default=0.0)
    return round(min(yellow, 25.5), 1), round(min(red, 25.5), 1) or NO_ALL_RED


def _green_limits(light: _Light, phase: _Phase) -> tuple[int, int]:
    """Minimum and maximum green: the program's minDur/maxDur of the phase's stages, or netconvert's defaults."""
    lows = [light.program[light.stage_at[k]].minDur for k in phase.stages]
    highs = [light.program[light.stage_at[k]].maxDur for k in phase.stages]
    low = max((v for v in lows if v is not None and v > 0), default=DEFAULT_MIN_GREEN)
    high = max((v for v in highs if v is not None and v > 0), default=DEFAULT_MAX_GREEN)
    low = max(1, math.ceil(low))
    return low, max(low, math.floor(high))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hils.protocol.resco NAME``: every light's derived config as TOML, with how each signal link follows
    it."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m hils.protocol.resco", description=main.__doc__)
    parser.add_argument("name", choices=NAMES)
    args = parser.parse_args(argv)
    try:
        scenario = load(args.name)
    except UserError as exc:
        print(f"hils.protocol.resco: {exc}", file=sys.stderr)
        return 1
    for tls, config in scenario.intersections.items():
        print(f"# {tls}")
        print(to_toml(config))
        print("# signal links: index = phase (+ overlaps, ~ yields with)")
        for index, link in enumerate(scenario.links[tls]):
            print(f"#   {index:>2} {describe_link(link)}")
        print()
    return 0


def describe_link(link: SignalLink) -> str:
    """One signal link's binding in a line: ``2``, ``2 g``, ``2 +5``, ``2 ~6``, ``-`` for no connection."""
    if link.phase is None:
        return "-"
    return " ".join([str(link.phase) + (" g" if link.yields else ""), *(f"+{p}" for p in link.also),
                     *(f"~{p}" for p in link.yields_with)])


def to_toml(config: IntersectionConfig) -> str:
    """A derived config written as an intersection config file (its phases, structure, middleware timing and plan)."""
    lines = [f'name = "{config.name}"', "", "[phases]"]
    for number, p in sorted(config.phases.items()):
        startup = ', startup = "green"' if p.startup.name != "PHASE_NOT_ON" else ""
        backing = "" if p.backup_prevent else ", backup_prevent = false"
        lines.append(f"{number} = {{ min_green = {p.min_green:g}, max_green = {p.max_green:g}, yellow = {p.yellow:g}, "
                     f"red_clear = {p.red_clear:g}{backing}{startup} }}")
    pairs = ", ".join(f"[{a}, {b}]" for a, b in config.pairs)
    sequence = ", ".join(f"[{a}, {b}]" for a, b in config.sequence)
    lines += ["", "[structure]", f"rings = {[list(r) for r in config.rings]}",
              f"barriers = {[sorted(b) for b in config.barriers]}", f"sequence = [{sequence}]", f"pairs = [{pairs}]",
              "", "[middleware]", f"control_interval = {config.middleware.control_interval:g}",
              f"tau_trans = {config.middleware.tau_trans:g}", "", "[emulator]",
              f"start = {config.emulator.start.isoformat()}"]
    c = config.coordination
    if c.patterns:
        lines += ["", "[coordination]", 'pattern = "free"']
    for pattern in c.patterns.values():
        splits = ", ".join(f"{p} = {t}" for p, t in sorted(pattern.splits.items()))
        lines += ["", "[[coordination.patterns]]", f"number = {pattern.number}", f"cycle = {pattern.cycle}",
                  f"offset = {pattern.offset}", f"coord_phases = {list(pattern.coord_phases)}",
                  f"splits = {{ {splits} }}"]
    if c.unplanned:
        lines += ["", f"# no timing plan: {c.unplanned}"]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
