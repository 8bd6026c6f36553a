"""SUMO's own NEMA controller as an independent reference for ours: the differential test.

Rules of this file
------------------
- The reference is SUMO's ``tlLogic type="NEMA"`` (``NEMAController.cpp`` of libsumo 1.28),
  run on the shipped four-leg network with the timings of an :class:`IntersectionConfig`.
  Nothing of it is re-implemented here: SUMO decides, we only feed calls and read colours.
- Calls reach SUMO the way a cabinet's detectors would: through the lane-area detectors its
  NEMA logic generates on every incoming lane, with ``lanearea.overrideVehicleNumber`` (one
  vehicle while the phase is called, override released when not). No vehicle ever drives.
- Both controllers get the same :data:`CallSequence` and run on the same 0.1 s grid: the
  calls of tick ``k`` are in place before the step that ends at tick ``k + 1``. SUMO runs one
  step ahead (its start-up greens time their minimum from its first step), so its tick ``k`` is
  simulation time ``(k + 1) * 0.1`` s.
- A timeline is read from the colours each controller shows after every step (green,
  yellow, red per phase), never from internal state, so the comparison stays valid whatever
  either controller's internals look like. A change is the onset of a colour on one phase.
- One libsumo simulation per process: a run starts SUMO, steps it and closes it before
  returning (a start costs about 10 ms on this network).

Theory of operation
-------------------
:func:`sumo_program` writes the NEMA program: ring strings with two slots per barrier group
(SUMO derives a phase's barrier side from its slot, ``barrierNum = ringIter / 2``), the last
phase of each ring in each group as SUMO's barrier and coordinate phases (in free mode they
only name its default, dual-entry phases: the throughs here), minimum and maximum green,
yellow and red from the config, and the vehicle extension (passage) of one step, the
shortest SUMO times correctly (with 0 a green would end at once despite its call): with it a
held call extends a green as a presence call does in ours. SUMO's default of minimum recall
on every phase is switched off (``minRecall`` empty), as our controller serves only calls.
In free mode SUMO starts in the first phase of each ring; :func:`comparable_config` gives
our controller the same start-up and no backup timer (the sequences never refresh a SET).

:func:`compare` pairs the changes of the two timelines (same phase, same colour, at most
``tolerance`` ticks apart, in order) and reports the agreement: matched changes over all
distinct changes (matched + unmatched on either side), so a change only one side makes
counts against it. ``python -m harness.nema_reference`` prints the figure for the targeted
scenarios and for seeded random call sequences.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import random
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from xml.sax.saxutils import quoteattr

import libsumo

from emulator.controller import Controller, tenths
from hils.config import IntersectionConfig, load
from hils.ntcip import ControlColumn, PhaseStartup
from hils.sumo_net import NET_FILE, PhaseMap, data_path, derive_phase_map, read_net

TICK = 0.1  # seconds per step, both controllers
PROGRAM_ID = "NEMA"
SUMO_PASSAGE = 0.1  # s: SUMO's vehicle extension, one step (see the theory of operation)
AGREEMENT_REQUIRED = 0.95

CallSequence = tuple[tuple[int, frozenset[int]], ...]
"""``(tick, phases)`` in ascending tick order: from that tick on exactly these phases are called."""


class NemaReferenceError(ValueError):
    """A config or call sequence SUMO's NEMA controller cannot be given; says what is allowed."""


class Color(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED = "red"


@dataclass(frozen=True, slots=True, order=True)
class ColorChange:
    """A phase starts showing a colour at a tick."""

    tick: int
    phase: int
    color: Color

    def __str__(self) -> str:
        return f"{self.tick / 10:.1f}s {self.phase} {self.color}"


Timeline = tuple[ColorChange, ...]


@dataclass(frozen=True)
class Comparison:
    """Two timelines of the same calls, paired change by change."""

    ours: Timeline
    reference: Timeline
    matched: tuple[tuple[ColorChange, ColorChange], ...]
    only_ours: Timeline
    only_reference: Timeline

    @property
    def agreement(self) -> float:
        """Matched changes over distinct changes (1.0 when neither side changes anything)."""
        total = len(self.matched) + len(self.only_ours) + len(self.only_reference)
        return len(self.matched) / total if total else 1.0

    @property
    def first_difference(self) -> ColorChange | None:
        """The earliest change only one side makes: where the timelines part (the rest often follows from it)."""
        return min((*self.only_ours, *self.only_reference), default=None)

    def report(self, calls: CallSequence = (), window: int = 150) -> str:
        """Agreement and, around the first difference, the calls and both timelines."""
        lines = [f"agreement {self.agreement:.1%} ({len(self.matched)} matched, "
                 f"{len(self.only_ours)} only ours, {len(self.only_reference)} only SUMO)"]
        first = self.first_difference
        if first is not None:
            t = first.tick
            lines.append(f"  first difference at {t / 10:.1f}s")
            if calls:
                start = max((k for k, _ in calls if k <= t - window), default=0)
                shown = [f"{k / 10:.1f}s {sorted(ps)}" for k, ps in calls if start <= k <= t]
                lines.append("  calls: " + ", ".join(shown))
            for name, timeline in (("ours", self.ours), ("SUMO", self.reference)):
                near = [str(c) for c in timeline if t - window <= c.tick <= t + window // 2]
                lines.append(f"  {name}: " + ", ".join(near))
        return "\n".join(lines)


# --- the two configs -------------------------------------------------------------------


def comparable_config(config: IntersectionConfig) -> IntersectionConfig:
    """Our side of the comparison: SUMO's free-mode start-up (first phase of each ring green), its
    hard-coded dual entry (the last phase of each ring in each barrier group: the throughs) and no
    backup timer, everything else as given."""
    firsts = {ring[0] for ring in config.rings}
    duals = {[p for p in ring if config.barrier_of(p) == b][-1] for ring in config.rings
             for b in range(len(config.barriers)) if any(config.barrier_of(p) == b for p in ring)}
    phases = {p: dataclasses.replace(ph, startup=PhaseStartup.GREEN_NO_WALK if p in firsts
                                     else PhaseStartup.PHASE_NOT_ON, dual_entry=p in duals)
              for p, ph in config.phases.items()}
    return dataclasses.replace(config, phases=phases).with_middleware(backup_time=0)


def _ring_slots(config: IntersectionConfig) -> list[list[int]]:
    """Per ring, two slots per barrier group (0 for an empty slot), as SUMO's ring strings."""
    where = f"{config.source}: structure"
    if len(config.rings) != 2 or len(config.barriers) != 2:
        raise NemaReferenceError(f"{where}: SUMO's NEMA controller has exactly 2 rings and 2 barrier groups; "
                             f"this config has {len(config.rings)} rings and {len(config.barriers)} groups")
    if max(config.phases) > 8:
        raise NemaReferenceError(f"{where}: SUMO's NEMA controller reads phase numbers as single digits; "
                             f"allowed: phases 1 to 8, got {max(config.phases)}")
    slots = []
    for ring in config.rings:
        row = []
        for group in range(2):
            mine = [p for p in ring if config.barrier_of(p) == group]
            if len(mine) > 2 or not mine:
                raise NemaReferenceError(f"{where}: ring {list(ring)} has {len(mine)} phases in barrier group "
                                     f"{group + 1}; SUMO's NEMA controller allows 1 or 2")
            row += mine + [0] * (2 - len(mine))
        slots.append(row)
    return slots


def _default_phases(config: IntersectionConfig) -> list[list[int]]:
    """Per ring and barrier group, the last phase of the ring there: SUMO's barrier (group 2) and
    coordinate (group 1) phases, which in free mode are the phases it enters by dual entry."""
    return [[next(p for p in reversed(row[2 * g:2 * g + 2]) if p) for g in range(2)] for row in _ring_slots(config)]


def sumo_program(config: IntersectionConfig, phase_map: PhaseMap) -> str:
    """The additional file with SUMO's NEMA program for ``config`` (see the theory of operation)."""
    slots = _ring_slots(config)
    last = _default_phases(config)
    params = {
        "ring1": ",".join(map(str, slots[0])),
        "ring2": ",".join(map(str, slots[1])),
        "barrierPhases": f"{last[0][1]},{last[1][1]}",
        "coordinatePhases": f"{last[0][0]},{last[1][0]}",
        "minRecall": "",
        "maxRecall": "",
    }
    lines = [f'<additional>\n  <tlLogic id="{phase_map.tls_id}" programID="{PROGRAM_ID}" type="NEMA" offset="0">']
    lines += [f"    <param key={quoteattr(k)} value={quoteattr(v)}/>" for k, v in params.items()]
    for p, ph in sorted(config.phases.items()):
        state = "".join("G" if q == p else "r" for q in phase_map.link_phases)
        lines.append(f'    <phase duration="99" minDur="{ph.min_green:g}" maxDur="{ph.max_green:g}" '
                     f'vehext="{SUMO_PASSAGE:g}" yellow="{ph.yellow:g}" red="{ph.red_clear:g}" '
                     f'name="{p}" state="{state}"/>')
    lines.append("  </tlLogic>\n</additional>\n")
    return "\n".join(lines)


# --- running each side -----------------------------------------------------------------


def _check(calls: CallSequence, ticks: int, config: IntersectionConfig) -> None:
    last = -1
    for tick, phases in calls:
        if tick <= last or tick < 0:
            raise NemaReferenceError(f"call sequence: tick {tick} after tick {last}; allowed: ascending ticks >= 0")
        unknown = set(phases) - set(config.phases)
        if unknown:
            raise NemaReferenceError(f"call sequence: tick {tick} calls unknown phase(s) {sorted(unknown)}; "
                                 f"allowed: {sorted(config.phases)}")
        last = tick
    if ticks <= 0:
        raise NemaReferenceError(f"run length {ticks} ticks; allowed: > 0")


def _changes(previous: Mapping[int, Color], now: Mapping[int, Color], tick: int) -> list[ColorChange]:
    return [ColorChange(tick, p, c) for p, c in now.items() if previous[p] is not c]


def run_ours(config: IntersectionConfig, calls: CallSequence, ticks: int) -> Timeline:
    """Our controller (on :func:`comparable_config`) under ``calls`` for ``ticks`` steps."""
    _check(calls, ticks, config)
    controller = Controller(comparable_config(config))
    pending = dict(calls)

    def colors() -> dict[int, Color]:
        g, y = controller.greens, controller.yellows
        return {p: Color.GREEN if p in g else Color.YELLOW if p in y else Color.RED for p in config.phases}

    shown = colors()
    out: list[ColorChange] = []
    for k in range(ticks):
        if k in pending:
            controller.set_control(ControlColumn.VEH_CALL, pending[k])
        controller.step()
        now = colors()
        out += _changes(shown, now, controller.tick)
        shown = now
    return tuple(out)


_SUMO_COLOR = {"G": Color.GREEN, "g": Color.GREEN, "y": Color.YELLOW, "Y": Color.YELLOW}


@contextlib.contextmanager
def _sumo(program: str) -> Iterator[None]:
    if libsumo.simulation.isLoaded():
        raise NemaReferenceError("a SUMO simulation is already running in this process (libsumo runs one at a "
                             "time); close it before running the reference")
    with tempfile.TemporaryDirectory(prefix="hils-nema-") as tmp:
        additional = Path(tmp) / "nema.add.xml"
        additional.write_text(program, encoding="utf-8")
        libsumo.start(["sumo", "-n", str(data_path(NET_FILE)), "-a", str(additional), "--step-length", str(TICK),
                       "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true"])
        try:
            yield
        finally:
            libsumo.close()


def run_reference(config: IntersectionConfig, calls: CallSequence, ticks: int) -> Timeline:
    """SUMO's NEMA controller under ``calls`` for ``ticks`` steps of 0.1 s."""
    _check(calls, ticks, config)
    phase_map = derive_phase_map(config, read_net())
    first_link = {p: phase_map.link_phases.index(p) for p in config.phases}
    pending = dict(calls)
    out: list[ColorChange] = []
    with _sumo(sumo_program(config, phase_map)):
        if libsumo.trafficlight.getProgram(phase_map.tls_id) != PROGRAM_ID:
            libsumo.trafficlight.setProgram(phase_map.tls_id, PROGRAM_ID)
        lane_detector = {libsumo.lanearea.getLaneID(d): d for d in libsumo.lanearea.getIDList()}
        detectors = {p: [lane_detector[lane] for lane in phase_map.incoming_lanes(p)] for p in config.phases}

        def colors() -> dict[int, Color]:
            state = libsumo.trafficlight.getRedYellowGreenState(phase_map.tls_id)
            return {p: _SUMO_COLOR.get(state[i], Color.RED) for p, i in first_link.items()}

        # SUMO's start-up greens count their minimum from its first step, not from time 0: one
        # step without calls first puts its clock on our tick 0 (start-up greens then end together)
        libsumo.simulationStep()
        shown = colors()
        called: frozenset[int] = frozenset()
        for k in range(ticks):
            if k in pending:
                for p in called ^ pending[k]:
                    for d in detectors[p]:
                        libsumo.lanearea.overrideVehicleNumber(d, 1 if p in pending[k] else -1)
                called = pending[k]
            libsumo.simulationStep()
            now = colors()
            out += _changes(shown, now, k + 1)
            shown = now
    return tuple(out)


# --- comparison ------------------------------------------------------------------------


def compare(ours: Timeline, reference: Timeline, tolerance: int = 1, until: int | None = None) -> Comparison:
    """Pair changes of the same phase and colour at most ``tolerance`` ticks apart, in order;
    with ``until``, only the changes before that tick take part."""
    if until is not None:
        ours = tuple(c for c in ours if c.tick < until)
        reference = tuple(c for c in reference if c.tick < until)
    matched: list[tuple[ColorChange, ColorChange]] = []
    only_ours: list[ColorChange] = []
    only_ref: list[ColorChange] = []
    keys = sorted({(c.phase, c.color) for c in (*ours, *reference)})
    for phase, color in keys:
        a = [c for c in ours if (c.phase, c.color) == (phase, color)]
        b = [c for c in reference if (c.phase, c.color) == (phase, color)]
        i = j = 0
        while i < len(a) and j < len(b):
            if abs(a[i].tick - b[j].tick) <= tolerance:
                matched.append((a[i], b[j]))
                i, j = i + 1, j + 1
            elif a[i].tick < b[j].tick:
                only_ours.append(a[i])
                i += 1
            else:
                only_ref.append(b[j])
                j += 1
        only_ours += a[i:]
        only_ref += b[j:]
    return Comparison(ours, reference, tuple(sorted(matched)), tuple(sorted(only_ours)), tuple(sorted(only_ref)))


def differential(config: IntersectionConfig, calls: CallSequence, ticks: int, *,
                 stop_at_quirk: bool = False) -> Comparison:
    """Both controllers under the same calls, compared within 0.1 s; with ``stop_at_quirk``, only
    up to the first of SUMO's documented quirks (:func:`reference_quirks`)."""
    reference = run_reference(config, calls, ticks)
    quirks = reference_quirks(config, calls, reference, ticks) if stop_at_quirk else ()
    return compare(run_ours(config, calls, ticks), reference, until=quirks[0].since if quirks else None)


class Quirk(StrEnum):
    """Where SUMO's NEMA logic departs from NEMA TS2 operation as our controller implements it
    (docs/nema_differences.md gives an example of each and the source)."""

    REDIRECTED = "next phase changed during clearance"
    PULLED_ACROSS = "clearing ring pulled across the barrier"
    FORCED_END = "green ended early by the other ring"
    SKIPPED = "called phase skipped to cross the barrier"


@dataclass(frozen=True, slots=True)
class QuirkSighting:
    """A quirk seen at ``tick`` in SUMO's timeline; from ``since`` on the controllers may differ."""

    since: int
    tick: int
    phase: int
    kind: Quirk


def reference_quirks(config: IntersectionConfig, calls: CallSequence, reference: Timeline,
                     ticks: int) -> tuple[QuirkSighting, ...]:
    """SUMO's departures from the NEMA rules our controller keeps, found in its timeline and calls.

    - REDIRECTED: a ring enters another phase than the one it chose at the start of its yellow,
      i.e. the first phase called then on the entered phase's side in ring order after the one
      that ended (or that side's dual-entry phase when none was called). SUMO lets later calls
      change a decision while the new target is on the same barrier side
      (``NEMAPhase::trySwitch``); rule 2 of issue 9 keeps it.
    - PULLED_ACROSS: a ring that began its yellow alone (a move on its side of the barrier) enters
      a phase across the barrier, because the other ring became ready to cross meanwhile
      (``NEMALogic::getNextPhases`` gives the clearing ring its default transition across).
    - FORCED_END: a green ends while its own call is on, before its minimum, or before its
      maximum timed from the conflicting call, without having gapped out: the other ring's
      green-rest max-out sets it ready too (``NEMAPhase::update``, "force the counterparty to be
      ready to switch").
    - SKIPPED: both rings cross the barrier while one of them had a call on a phase after its
      own before the barrier (1 -> 4 with 2 called): the crossing pair has the smaller summed
      ring distance (``NEMALogic::getNextPhases``) because a green-rest phase staying counts the
      full ring (``PhaseTransitionLogic::getDistance``); a NEMA ring serves its called phases in
      sequence before the barrier.
    """
    called = _calls_read(calls, ticks)
    side = {p: config.barrier_of(p) for p in config.phases}
    ring_of = {p: config.ring_of(p) - 1 for p in config.phases}
    order = [list(r) for r in config.rings]
    defaults = _default_phases(config)
    shown = {ring[0]: Color.GREEN for ring in config.rings}
    green_since = {r: 0 for r in range(len(order))}
    phase = {r: order[r][0] for r in range(len(order))}
    yellow: dict[int, tuple[int, bool]] = {}  # ring -> (yellow onset, began alone)
    out: list[QuirkSighting] = []

    def after(p: int) -> list[int]:
        ring = order[ring_of[p]]
        i = ring.index(p)
        return [ring[(i + k) % len(ring)] for k in range(1, len(ring))]

    def conflict(p: int, k: int) -> bool:
        return any(q != p and (ring_of[q] == ring_of[p] or side[q] != side[p]) for q in called[k])

    by_tick: dict[int, list[ColorChange]] = {}
    for c in reference:
        by_tick.setdefault(c.tick, []).append(c)
    for t in sorted(by_tick):
        changes = by_tick[t]
        turning = {c.phase for c in changes if c.color is Color.YELLOW}
        for c in changes:
            r = ring_of[c.phase]
            if c.color is Color.YELLOW:
                p, g = c.phase, green_since[r]
                ph = config.phases[p]
                if p in called[t] and not _legitimate_end(p, g, t, ph.min_green, ph.max_green, called, conflict):
                    out.append(QuirkSighting(t, t, p, Quirk.FORCED_END))
                yellow[r] = (t, phase[1 - r] not in turning)
            elif c.color is Color.GREEN and r in yellow:
                y, alone = yellow.pop(r)
                p, q = phase[r], c.phase
                ahead = list(itertools.takewhile(side[p].__eq__, (side[x] for x in after(p))))
                ahead = after(p)[:len(ahead)]
                if alone and side[q] != side[p]:
                    out.append(QuirkSighting(y + 1, t, q, Quirk.PULLED_ACROSS))
                elif side[q] != side[p] and any(x in called[y] for x in ahead):
                    out.append(QuirkSighting(y, t, q, Quirk.SKIPPED))
                else:
                    chosen = next((x for x in after(p) if x in called[y] and side[x] == side[q]),
                                  defaults[r][side[q]])
                    if q != chosen:
                        out.append(QuirkSighting(y + 1, t, q, Quirk.REDIRECTED))
                phase[r], green_since[r] = q, t
        for c in changes:
            shown[c.phase] = c.color
    return tuple(sorted(out, key=lambda s: s.since))


def _legitimate_end(p: int, green: int, end: int, min_green: float, max_green: float,
                    called: Sequence[frozenset[int]], conflict: Callable[[int, int], bool]) -> bool:
    """A green of ``p`` from ``green`` ending at ``end`` with its call on: after its minimum, and
    either maxed out (conflicting demand for its maximum without a break) or gapped out earlier
    (call off with conflicting demand after the minimum: the gap-out is kept)."""
    if end - green < tenths(min_green):
        return False
    run = 0
    for k in range(end, green, -1):
        if not conflict(p, k):
            break
        run += 1
    if run >= tenths(max_green):
        return True
    return any(p not in called[k] and conflict(p, k) for k in range(green + tenths(min_green), end))


def _calls_read(calls: CallSequence, ticks: int) -> list[frozenset[int]]:
    """Per tick k, the calls the step ending at tick k reads (those placed at tick k - 1 or before)."""
    out = [frozenset()] * (ticks + 1)
    pending = dict(calls)
    now: frozenset[int] = frozenset()
    for k in range(1, ticks + 1):
        now = pending.get(k - 1, now)
        out[k] = now
    return out


# --- call sequences --------------------------------------------------------------------


def seconds(*steps: tuple[float, Sequence[int]]) -> CallSequence:
    """A call sequence written in seconds: ``seconds((0, [2, 6]), (15, [6, 4, 8]))``."""
    return tuple((round(t * 10), frozenset(ps)) for t, ps in steps)


# Targeted scenarios on the paper's intersection (rings 1-2-3-4 / 5-6-7-8, barriers 1256 | 3478,
# min 3 s, max 20 s, yellow 3 s, red 2 s). Both controllers start with 1+5 green; a call on 2+6
# at 0 s brings 2+6 green at 8 s. Each is (calls, length in ticks).
SCENARIOS: dict[str, tuple[CallSequence, int]] = {
    # 4 and 8 called while 2+6 time; 2's call drops at 23 s (15 s into its green), 6's at 26 s:
    # 2 waits at the barrier, 2 and 6 turn yellow together at 26 s
    "barrier crossing together": (seconds((0, [2, 6]), (12, [2, 6, 4, 8]), (23, [6, 4, 8]), (26, [4, 8]),
                                          (45, [])), 500),
    # 6 maxes out (20 s after the conflicting call) while 2 has gapped out: both cross together
    "max-out of one ring while the other times": (seconds((0, [2, 6]), (10, [2, 6, 8]), (14, [6, 8]),
                                                          (45, [])), 500),
    # 1+5 end for a call on 4 at 3 s (next: 4, with 8 by dual entry); a call on 2 during their
    # yellow does not redirect ring 1: 4+8 first, then 2 (with 6)
    "phase next decided at yellow": (seconds((0, [4]), (5, [2, 4]), (20, [2]), (40, [])), 450),
    # 2+6 green, 6's call drops and 5 is called while 2 keeps its call: ring 2 backs into 5
    "backing into a phase": (seconds((0, [2, 6]), (14, [2, 5]), (30, [])), 400),
    # from 1+5, only 4 is called: ring 2 enters the other side on its dual-entry phase 8
    "dual entry": (seconds((0, [4]), (20, [])), 300),
    # a lone call on 1 while 4+8 rest: 1 enters with its dual-entry partner 6
    "dual entry back across": (seconds((0, [4, 8]), (10, [1]), (30, [])), 400),
}


WARM_UP: CallSequence = ((0, frozenset({2, 6})),)
"""Calls that move both controllers off their start-up greens (1+5) first: SUMO times the maximum
of a start-up green from the end of its minimum (docs/nema_differences.md, start-up)."""
WARM_UP_TICKS = 100


def random_calls(rng: random.Random, ticks: int, phases: Sequence[int]) -> CallSequence:
    """After :data:`WARM_UP`, random held and flickering calls: every 1-15 s a new set of 0-4 called phases."""
    out: list[tuple[int, frozenset[int]]] = list(WARM_UP)
    tick = WARM_UP_TICKS
    while tick < ticks:
        out.append((tick, frozenset(rng.sample(list(phases), rng.randint(0, 4)))))
        tick += rng.randint(10, 150)
    return tuple(out)


def pooled(results: Sequence[Comparison]) -> tuple[int, int]:
    """Matched and distinct changes over several comparisons (their pooled agreement is the ratio)."""
    matched = sum(len(r.matched) for r in results)
    return matched, matched + sum(len(r.only_ours) + len(r.only_reference) for r in results)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.nema_reference",
                                     description="Agreement of our controller with SUMO's NEMA controller.")
    parser.add_argument("--config", help="intersection TOML (default: the shipped four-leg intersection)")
    parser.add_argument("--random", type=int, default=50, help="random call sequences (default 50)")
    parser.add_argument("--length", type=float, default=300.0, help="seconds per random sequence (default 300)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("-v", "--verbose", action="store_true", help="show where each sequence first differs")
    args = parser.parse_args(argv)
    try:
        config = load(args.config)
        targeted = []
        for name, (calls, ticks) in SCENARIOS.items():
            targeted.append(differential(config, calls, ticks))
            print(f"{name:45s} {targeted[-1].agreement:6.1%}")
            if args.verbose and targeted[-1].agreement < 1:
                print(targeted[-1].report(calls))
        rng = random.Random(args.seed)
        ticks = round(args.length * 10)
        whole, until_quirk, kinds = [], [], Counter[Quirk]()
        for i in range(args.random):
            calls = random_calls(rng, ticks, sorted(config.phases))
            ours, reference = run_ours(config, calls, ticks), run_reference(config, calls, ticks)
            quirks = reference_quirks(config, calls, reference, ticks)
            whole.append(compare(ours, reference))
            until_quirk.append(compare(ours, reference, until=quirks[0].since if quirks else None))
            kinds.update(q.kind for q in quirks[:1])
            if args.verbose and until_quirk[-1].agreement < 1:
                print(f"random {i}: " + until_quirk[-1].report(calls))
    except (NemaReferenceError, ValueError) as exc:
        print(f"nema_reference: {exc}", file=sys.stderr)
        return 1
    for label, results in ((f"targeted scenarios ({len(targeted)})", targeted),
                           (f"{args.random} random sequences of {args.length:g} s", whole),
                           ("  the same, up to SUMO's first quirk", until_quirk)):
        matched, total = pooled(results)
        print(f"{label:45s} {matched / max(total, 1):6.1%} of {total} changes")
    if kinds:
        print("  first quirks: " + ", ".join(f"{k} {n}" for k, n in kinds.most_common()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
