"""A controller config written from a field controller's own hi-res log, for replaying the log into the emulator.

Signal-Replay replays a field log's detector, pedestrian and preempt inputs into a bench controller and compares
the bench's phase events with the field's; the bench must run the field's timing. :func:`infer` reads it from
the log's own events (Indiana enumerations) and says which values it had to guess:

- **phases and structure**: the phases that began green (event 1); two phases whose greens overlap are
  concurrent, so in different rings and one barrier group; barrier groups are the connected sets of concurrent
  phases, rings split each group by concurrency (NEMA's numbering, 1-4 and 9-12 in ring 1, when it agrees), and
  each ring serves its phases in the order the log shows them following each other. A ring without a phase in a
  group gets an unused phase number there that nothing calls (the controller skips it; NTCIP's split table needs
  a split for it);
- **timings**: yellow (8 to 9) and red clearance (10 to 11), the minimum (1 to 3, the most frequent), walk (21 to 22)
  and pedestrian clearance (22 to 23), passage (a gap-out, 4, after the last of the phase's calling detectors
  went off, 81: the most frequent gap, counted from the last tick with the call; the intersection's when a
  phase shows too few), the maximum (the longest green; coordination does not time it);
- **detectors**: a detector calls the phase whose call registrations (43) its actuations (82) bring most often, at
  the same tick or the next, when they do for at least a tenth of them; the others are logged but call nothing
  (phase 0, as a count station). Push buttons likewise with pedestrian calls (90 with 45);
- **overlaps**: an overlap that begins green (61) with phases (1, the same tick, nine times in ten) includes them
  (a normal overlap);
- **coordination**: the cycle is the spacing of the local zeros (event 150, parameter 5), the offset their time of
  day modulo the cycle with the local zero at the start of the coordinated greens (NEMA TS 2's lead-green
  reference); the coordinated phases have yield point events (151), the other ring's is the phase of the same
  group green at the local zero; each phase's split ends where its force-offs (6) fall in the cycle plus its
  clearance (when at least a fifth of its greens end so), the rings reach each barrier together, and what is still
  open goes to the last phase of its ring.

What the log does not show is guessed and said: a value a phase never showed (its event never logged), the
offset reference, detector extension, max 2, recalls, red revert, dual entry, overlaps and dynamic omits.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.hires import EventCode

E = EventCode
TICK = timedelta(milliseconds=100)
CALL_SHARE = 0.10  # a detector calls a phase when at least this share of its actuations registers the call
LOCAL_ZERO = 5  # event 150's parameter at the local zero
PASSAGE_SEEN = 3  # a phase's own most frequent gap counts as its passage when seen this often
FORCE_OFF_SHARE = 0.2  # a phase's force-offs mark where its split ends when they end at least this share of its greens


class FieldLogError(UserError, ValueError):
    """A log that cannot be read into a config; says what it lacks."""


@dataclass(frozen=True, slots=True)
class Row:
    time: datetime
    code: int
    parameter: int


@dataclass
class Inferred:
    """A config inferred from a log: its TOML, and what was read and what was guessed to write it."""

    toml: str
    read: list[str] = field(default_factory=list)
    guessed: list[str] = field(default_factory=list)

    def config(self) -> IntersectionConfig:
        return config_mod.parse(self.toml, "inferred.toml")


# --- reading a log ----------------------------------------------------------------------------------------------


def load(path: str | Path, device: Any | None = None, start: datetime | None = None,
         end: datetime | None = None) -> list[Row]:
    """One controller's events of an ATSPM-layout log (parquet or CSV: TimeStamp, DeviceId, EventId, Parameter),
    in time order, between ``start`` and ``end`` when given. ``device`` picks a controller of a log of several."""
    import pandas as pd

    path = Path(path)
    try:
        frame = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path, parse_dates=["TimeStamp"])
    except (OSError, ValueError) as exc:
        raise FieldLogError(f"{path}: cannot be read as an ATSPM log ({exc}); allowed: a .parquet or .csv file with "
                            "TimeStamp, DeviceId, EventId, Parameter") from None
    missing = {"TimeStamp", "EventId", "Parameter"} - set(frame.columns)
    if missing:
        raise FieldLogError(f"{path}: no column {', '.join(sorted(missing))}; allowed: the ATSPM layout "
                            "(TimeStamp, DeviceId, EventId, Parameter)")
    if "DeviceId" in frame.columns:
        devices = sorted(frame.DeviceId.astype(str).unique())
        if device is None and len(devices) > 1:
            raise FieldLogError(f"{path} holds {len(devices)} controllers; pick one: --device "
                                + ", ".join(devices[:10]))
        if device is not None:
            if str(device) not in devices:
                raise FieldLogError(f"{path}: no DeviceId {device}; allowed: {', '.join(devices[:10])}")
            frame = frame[frame.DeviceId.astype(str) == str(device)]
    if start is not None:
        frame = frame[frame.TimeStamp >= start]
    if end is not None:
        frame = frame[frame.TimeStamp < end]
    frame = frame.sort_values(["TimeStamp", "EventId", "Parameter"], kind="stable")
    return [Row(t.to_pydatetime(), int(c), int(p)) for t, c, p in zip(frame.TimeStamp, frame.EventId,
                                                                         frame.Parameter, strict=True)]


def _mode(values: Iterable[float]) -> float | None:
    counts = Counter(values)
    return max(counts, key=lambda v: (counts[v], -v)) if counts else None


def _durations(rows: Sequence[Row], phase: int, begin: int, ends: int) -> list[float]:
    """Seconds from each ``begin`` event of ``phase`` to its next ``ends`` event (a ``begin`` again drops it)."""
    out, since = [], None
    for r in rows:
        if r.parameter != phase:
            continue
        if r.code == begin:
            since = r.time
        elif r.code == ends and since is not None:
            out.append(round((r.time - since).total_seconds(), 1))
            since = None
    return out


def _greens(rows: Sequence[Row]) -> dict[int, list[tuple[datetime, datetime]]]:
    """Each phase's greens: begin green (1) to begin yellow (8)."""
    out: dict[int, list[tuple[datetime, datetime]]] = defaultdict(list)
    open_: dict[int, datetime] = {}
    for r in rows:
        if r.code == E.PHASE_BEGIN_GREEN:
            open_[r.parameter] = r.time
        elif r.code == E.PHASE_BEGIN_YELLOW and r.parameter in open_:
            out[r.parameter].append((open_.pop(r.parameter), r.time))
    return out


def _seconds_of_day(t: datetime) -> float:
    return t.hour * 3600 + t.minute * 60 + t.second + t.microsecond / 1e6


# --- inference -----------------------------------------------------------------------------------------------


@dataclass
class Structure:
    """Barrier groups in order, and per ring and group the phases in service order (phantoms included)."""

    groups: list[list[int]]
    order: dict[int, list[list[int]]]  # ring -> group index -> phases
    phantom: dict[int, int] = field(default_factory=dict)  # phantom phase -> the phase whose timings it borrows

    def ring(self, r: int) -> list[int]:
        return [p for group in self.order[r] for p in group]

    def group_of(self, p: int) -> int:
        return next(g for r in (1, 2) for g, phases in enumerate(self.order[r]) if p in phases)

    @property
    def barriers(self) -> list[list[int]]:
        return [self.order[1][g] + self.order[2][g] for g in range(len(self.groups))]


def infer(rows: Sequence[Row], name: str = "field controller") -> Inferred:
    """The config of the controller whose log ``rows`` are (see the module's header for how)."""
    out = Inferred("")
    greens = _greens(rows)
    phases = sorted(greens)
    if len(phases) < 2:
        raise FieldLogError(f"the log shows {len(phases)} phase(s) served (begin green, event 1, then begin yellow, "
                            "event 8); a config needs at least two")
    out.read.append(f"phases served: {', '.join(map(str, phases))}")
    structure = _structure(phases, greens, out)
    timing = {p: _timing(rows, p, greens[p], out) for p in phases}
    detectors = _detector_phases(rows, E.DETECTOR_ON, E.PHASE_CALL_REGISTERED, phases)
    pushes = _detector_phases(rows, E.PED_DETECTOR_ON, E.PED_CALL_REGISTERED, phases)
    gaps = {p: _gaps(rows, p, [d for d, q in detectors.items() if q == p]) for p in phases}
    shared = _mode(g for values in gaps.values() for g in values)
    for p in phases:
        counts = Counter(gaps[p])
        if counts and counts.most_common(1)[0][1] >= PASSAGE_SEEN:
            timing[p]["passage"] = _mode(gaps[p])
        else:
            timing[p]["passage"] = shared if shared is not None else 2.0
            out.guessed.append(f"phase {p}: passage {timing[p]['passage']:g} s (the intersection's most frequent: "
                               f"no gap of its own seen {PASSAGE_SEEN} times)")
    for p, twin in structure.phantom.items():
        timing[p] = {k: v for k, v in timing[twin].items() if k not in ("walk", "ped_clear")}
    logged = sorted(d for d, q in detectors.items() if q == 0)
    out.read.append("detectors calling: " + ", ".join(f"{d}->{q}" for d, q in sorted(detectors.items()) if q)
                    + (f"; logged only: {', '.join(map(str, logged))}" if logged else ""))
    if any(pushes.values()):
        out.read.append("push buttons: " + ", ".join(f"{d}->{q}" for d, q in sorted(pushes.items()) if q))
    out.guessed.append("every calling detector also extends its phase's green (detector delay and extension are not "
                       "in the log: its detector events come after them)")
    coordination = _coordination(rows, structure, timing, greens, out)
    overlaps = _overlaps(rows, phases, out)
    out.guessed.append("no recalls, red revert, max 2 or dual entry (the log shows the service, not the settings); "
                       "dynamic omits (46-49 logged by the field controller's own logic) are not modelled")
    start = rows[0].time.replace(microsecond=rows[0].time.microsecond // 100_000 * 100_000)
    out.toml = _toml(name, structure, timing, detectors, pushes, coordination, overlaps, _startup(greens, structure),
                     start)
    return out


def _structure(phases: Sequence[int], greens: Mapping[int, list[tuple[datetime, datetime]]],
               out: Inferred) -> Structure:
    concurrent = {frozenset((p, q)) for p, q in itertools.combinations(phases, 2)
                  if any(a0 < b1 and b0 < a1 for a0, a1 in greens[p] for b0, b1 in greens[q])}
    groups: list[set[int]] = []
    for p in phases:
        touching = [g for g in groups if any(frozenset((p, q)) in concurrent for q in g)]
        groups = [g for g in groups if g not in touching] + [{p}.union(*touching)]
    ordered = sorted((sorted(g) for g in groups), key=min)
    ring_of: dict[int, int] = {}
    for group in ordered:
        ring = {p: _nema_ring(p) for p in group}
        if any(frozenset((p, q)) in concurrent for p, q in itertools.combinations(group, 2) if ring[p] == ring[q]):
            ring = _two_colour(group, concurrent)
            out.guessed.append(f"rings of phases {group}: split by which are concurrent, not NEMA's numbering")
        ring_of |= ring
    order = {r: [_service_order([p for p in group if ring_of[p] == r], [p for p in phases if ring_of[p] == r], greens)
                 for group in ordered] for r in (1, 2)}
    structure = Structure(ordered, order)
    used = set(phases)
    for r in (1, 2):
        for g, mine in enumerate(order[r]):
            if mine:
                continue
            twin = order[3 - r][g][0]
            base = 0 if r == 1 else 4
            # NEMA's numbering first: in ring 1 the second barrier group's through is 4, its left 3, and so on
            free = next(n for n in (base + 2 * g + 2, base + 2 * g + 1, *range(1, 65)) if n not in used)
            used.add(free)
            mine.append(free)
            structure.phantom[free] = twin
            out.guessed.append(f"phase {free}: not in the log; added to ring {r} beside {twin} (NTCIP's split table "
                               "needs a phase of each ring in each barrier group; nothing calls it, so it is skipped)")
    out.read.append(f"rings: {structure.ring(1)} and {structure.ring(2)}; barrier groups: {structure.barriers}")
    return structure


def _nema_ring(p: int) -> int:
    return 1 if (p - 1) % 8 < 4 else 2


def _two_colour(group: Sequence[int], concurrent: set[frozenset[int]]) -> dict[int, int]:
    """Rings for a group by concurrency: a phase goes to the ring none of whose phases it is never concurrent with."""
    colour = {group[0]: 1}
    for p in group[1:]:
        apart = {colour[q] for q in colour if frozenset((p, q)) not in concurrent}
        colour[p] = min(apart) if apart else 2
    return colour


def _service_order(mine: Sequence[int], ring: Sequence[int], greens: Mapping[int, list[tuple[datetime, datetime]]]
                   ) -> list[int]:
    """The order the log serves a ring's phases of one group (``mine``, of the ring's phases ``ring``): the one in
    which they most often follow each other directly."""
    if len(mine) < 2:
        return list(mine)
    starts = [p for _, p in sorted((t0, p) for p in ring for t0, _ in greens[p])]
    follows = Counter((a, b) for a, b in itertools.pairwise(starts) if a != b and a in mine and b in mine)
    return list(max(itertools.permutations(mine),
                    key=lambda order: sum(follows[(a, b)] for a, b in itertools.pairwise(order))))


def _timing(rows: Sequence[Row], p: int, greens: Sequence[tuple[datetime, datetime]], out: Inferred) -> dict[str, Any]:
    t: dict[str, Any] = {}
    found = {"yellow": _mode(_durations(rows, p, E.PHASE_BEGIN_YELLOW, E.PHASE_END_YELLOW)),
             "red_clear": _mode(_durations(rows, p, E.PHASE_BEGIN_RED_CLEARANCE, E.PHASE_END_RED_CLEARANCE)),
             "min_green": _mode(_minimums(rows, p))}
    for key, default in (("yellow", 4.0), ("red_clear", 1.0), ("min_green", 5)):
        if found[key] is None:
            out.guessed.append(f"phase {p}: {key} {default} (its events are not in the log)")
        t[key] = found[key] if found[key] is not None else default
    t["min_green"] = max(1, math.ceil(t["min_green"] - 1e-9))
    walk = _mode(_durations(rows, p, E.PED_BEGIN_WALK, E.PED_BEGIN_CLEARANCE))
    ped_clear = _mode(_durations(rows, p, E.PED_BEGIN_CLEARANCE, E.PED_BEGIN_SOLID_DONT_WALK))
    if walk and ped_clear:
        t["walk"], t["ped_clear"] = math.ceil(walk), math.ceil(ped_clear)
    longest = max(((b - a).total_seconds() for a, b in greens), default=0.0)
    t["max_green"] = max(t["min_green"], t.get("walk", 0) + t.get("ped_clear", 0), math.ceil(longest))
    return t


def _minimums(rows: Sequence[Row], p: int) -> list[float]:
    """Begin green to min complete of the greens of ``p`` that served no walk (a walk's timing is its minimum)."""
    walks = {r.time for r in rows if r.code == E.PED_BEGIN_WALK and r.parameter == p}
    out, since = [], None
    for r in rows:
        if r.parameter != p:
            continue
        if r.code == E.PHASE_BEGIN_GREEN:
            since = None if r.time in walks else r.time
        elif r.code == E.PHASE_MIN_COMPLETE and since is not None:
            out.append(round((r.time - since).total_seconds(), 1))
            since = None
    return out or _durations(rows, p, E.PHASE_BEGIN_GREEN, E.PHASE_MIN_COMPLETE)


def _detector_phases(rows: Sequence[Row], on: int, call: int, phases: Sequence[int]) -> dict[int, int]:
    """Detector -> the phase whose calls it registers (0: none), by coincidence of its on events with call events."""
    calls = {(r.time, r.parameter) for r in rows if r.code == call}
    seen: Counter[int] = Counter()
    hits: Counter[tuple[int, int]] = Counter()
    for r in rows:
        if r.code == on:
            seen[r.parameter] += 1
            for p in phases:
                if (r.time, p) in calls or (r.time + TICK, p) in calls:
                    hits[(r.parameter, p)] += 1
    out = {}
    for d, n in seen.items():
        best = max(phases, key=lambda p: hits[(d, p)])
        out[d] = best if hits[(d, best)] >= CALL_SHARE * n else 0
    return out


def _gaps(rows: Sequence[Row], p: int, detectors: Sequence[int]) -> list[float]:
    """Each time from the last of the phase's detectors going off to its gap-out (a gap-out logged when the green
    ends may come later than the gap: at a barrier, the green waits for the other ring)."""
    if not detectors:
        return []
    mine, on, gaps = set(detectors), set(), []
    last_off: datetime | None = None
    for r in rows:
        if r.parameter in mine and r.code in (E.DETECTOR_ON, E.DETECTOR_OFF):
            (on.add if r.code == E.DETECTOR_ON else on.discard)(r.parameter)
            if r.code == E.DETECTOR_OFF and not on:
                last_off = r.time
        elif r.code == E.PHASE_GAP_OUT and r.parameter == p and not on and last_off is not None:
            # the off event is the first tick without the call; passage counts from the last tick with it
            gaps.append(round((r.time - last_off + TICK).total_seconds(), 1))
    return gaps


def _coordination(rows: Sequence[Row], structure: Structure, timing: Mapping[int, dict[str, Any]],
                  greens: Mapping[int, list[tuple[datetime, datetime]]], out: Inferred) -> dict[str, Any] | None:
    zeros = [r.time for r in rows if r.code == E.COORD_CYCLE_STATE_CHANGE and r.parameter == LOCAL_ZERO]
    if len(zeros) < 2:
        out.read.append("coordination: no local zero in the log (event 150 with 5): free")
        return None
    cycle = round(_mode(round((b - a).total_seconds(), 1) for a, b in itertools.pairwise(zeros)))
    zero = _mode(round(_seconds_of_day(t) % cycle, 1) for t in zeros)
    yielding = {r.parameter for r in rows if r.code == E.COORD_YIELD_POINT}
    coord = {}
    for r in (1, 2):
        mine = structure.ring(r)
        coord[r] = next((p for p in mine if p in yielding), None)
        if coord[r] is None:  # the phase of this ring whose green most often covers the local zero
            covering = Counter(q for q in mine for z in zeros for a, b in greens.get(q, ()) if a <= z < b)
            coord[r] = covering.most_common(1)[0][0] if covering else mine[0]
            out.guessed.append(f"coordinated phase of ring {r}: {coord[r]} (no yield point event, 151: the phase of "
                               "that ring green at the local zero)")
    ends: dict[int, float] = {}
    for p in timing:
        force_offs = [round((_seconds_of_day(row.time) - zero) % cycle, 1) for row in rows
                      if row.code == E.PHASE_FORCE_OFF and row.parameter == p]
        if force_offs and len(force_offs) >= FORCE_OFF_SHARE * len(greens.get(p, ())):  # not a stray one
            ends[p] = _mode(force_offs) + timing[p]["yellow"] + timing[p]["red_clear"]
    splits = _splits(structure, coord, ends, cycle, timing, out)
    out.read.append(f"coordination: cycle {cycle} s, local zero at {zero:g} s of the time of day modulo the cycle, "
                    f"coordinated {coord[1]}+{coord[2]}, splits " + ", ".join(f"{p}: {s}" for p, s in splits.items()))
    out.guessed.append("offset reference: the local zero (event 150, 5) starts the coordinated greens (lead green)")
    return {"cycle": cycle, "offset": round(zero) % cycle, "coord": [coord[1], coord[2]], "splits": splits}


def _splits(structure: Structure, coord: Mapping[int, int], ends: Mapping[int, float], cycle: int,
            timing: Mapping[int, dict[str, Any]], out: Inferred) -> dict[int, int]:
    """Each phase's split from where it ends in the cycle (from the local zero, which starts the coordinated splits):
    force-offs where the log has them, the other ring's end of the barrier group, the cycle's end."""
    cyclic = {}
    for r in (1, 2):
        mine = structure.ring(r)
        i = mine.index(coord[r])
        cyclic[r] = mine[i:] + mine[:i]

    def last_of_group(order: Sequence[int], k: int) -> bool:
        return k == len(order) - 1 or structure.group_of(order[k + 1]) != structure.group_of(order[k])

    barrier_end: dict[int, float] = {}
    for r in (1, 2):
        for k, p in enumerate(cyclic[r]):
            if p in ends and last_of_group(cyclic[r], k):
                barrier_end.setdefault(structure.group_of(p), ends[p])
    splits: dict[int, int] = {}
    for r in (1, 2):
        at, order = 0.0, cyclic[r]
        for k, p in enumerate(order):
            end = ends.get(p)
            if end is None and k == len(order) - 1:
                end = float(cycle)
            if end is None and last_of_group(order, k):
                end = barrier_end.get(structure.group_of(p))
            if end is None:
                t = timing[p]
                end = at + t["max_green"] + t["yellow"] + t["red_clear"]
                if p not in structure.phantom:
                    out.guessed.append(f"phase {p}: split {round(end - at)} s (never forced off: its longest service)")
            splits[p] = max(1, round(end - at))
            at = end
        short = cycle - sum(splits[p] for p in order)
        if short:
            splits[order[-1]] += short
            out.guessed.append(f"phase {order[-1]}: split changed by {short} s so that ring {r} fills the cycle")
    return dict(sorted(splits.items()))


def _overlaps(rows: Sequence[Row], phases: Sequence[int], out: Inferred) -> dict[int, list[int]]:
    """Normal overlaps: an overlap whose begin greens (61) come with the begin greens of phases (1, the same tick,
    at least nine times in ten) includes those phases. An overlap that never begins green is not inferred."""
    begins = defaultdict(list)
    for r in rows:
        if r.code in (E.OVERLAP_BEGIN_GREEN, E.PHASE_BEGIN_GREEN):
            begins[r.time].append(r)
    starts: Counter[int] = Counter()
    with_phase: Counter[tuple[int, int]] = Counter()
    for same in begins.values():
        for r in same:
            if r.code == E.OVERLAP_BEGIN_GREEN:
                starts[r.parameter] += 1
                for q in same:
                    if q.code == E.PHASE_BEGIN_GREEN:
                        with_phase[(r.parameter, q.parameter)] += 1
    overlaps = {o: [p for p in phases if with_phase[(o, p)] >= 0.9 * n] for o, n in starts.items()}
    overlaps = {o: included for o, included in overlaps.items() if included}
    for o, included in overlaps.items():
        out.read.append(f"overlap {chr(64 + o)} ({o}): begins green with phase(s) {included}: a normal overlap of them")
    seen = {r.parameter for r in rows if E.OVERLAP_BEGIN_GREEN <= r.code <= E.OVERLAP_DARK}
    for o in sorted(seen - set(overlaps)):
        out.guessed.append(f"overlap {chr(64 + o)} ({o}): not modelled (it never begins green in the log; its other "
                           "events fit none of the types: normal, minus green-yellow, flashing yellow arrow)")
    return overlaps


def _startup(greens: Mapping[int, list[tuple[datetime, datetime]]], structure: Structure) -> list[int]:
    """The phases to power up in: the first phase served in each ring of the group served first."""
    first = min((t0, p) for p, spans in greens.items() for t0, _ in spans)[1]
    g = structure.group_of(first)
    return [structure.order[r][g][0] for r in (1, 2)]


def _toml(name: str, structure: Structure, timing: Mapping[int, dict[str, Any]], detectors: Mapping[int, int],
          pushes: Mapping[int, int], coordination: Mapping[str, Any] | None, overlaps: Mapping[int, list[int]],
          startup: Sequence[int], start: datetime) -> str:
    def value(v: Any) -> str:
        return f"{v:g}" if isinstance(v, float) else str(v)

    lines = ["# Written by harness.reference.field_log from a controller's hi-res log: what it read and guessed is "
             "printed with it.", f'name = "{name}"', "", "[phases]"]
    for p in sorted(timing):
        fields = {k: timing[p][k] for k in ("min_green", "max_green", "yellow", "red_clear", "passage", "walk",
                                            "ped_clear") if k in timing[p]}
        if p in startup:
            fields["startup"] = '"green"'
        lines.append(f"{p} = {{ " + ", ".join(f"{k} = {value(v)}" for k, v in fields.items()) + " }")
    barriers = structure.barriers
    pairs = [[a, b] for group in barriers for a in group for b in group
             if a in structure.ring(1) and b in structure.ring(2)]
    lines += ["", "[structure]", f"rings = [{structure.ring(1)}, {structure.ring(2)}]", f"barriers = {barriers}",
              f"sequence = {pairs}", f"pairs = {pairs}", "", "[emulator]",
              f"start = {start.isoformat(timespec='milliseconds')[:-2]}", "", "[detectors]"]
    lines += [f"{d} = {q}" for d, q in sorted(detectors.items())]
    if pushes:
        lines += ["", "[pedestrian_detectors]", *(f"{d} = {q}" for d, q in sorted(pushes.items()) if q)]
    if overlaps:
        lines += ["", "[overlaps]", *(f"{chr(64 + o)} = {{ included = {included} }}"
                                      for o, included in sorted(overlaps.items()))]
    if coordination is not None:
        c = coordination
        lines += ["", "[coordination]", "pattern = 1", 'force_off = "fixed"', 'offset_reference = "lead_green"',
                  'correction = "shortway"', "", "[[coordination.patterns]]", "number = 1", f"cycle = {c['cycle']}",
                  f"offset = {c['offset']}", f"coord_phases = {c['coord']}",
                  "splits = { " + ", ".join(f"{p} = {s}" for p, s in c["splits"].items()) + " }"]
    return "\n".join(lines) + "\n"
