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
our controller the same start-up, SUMO's next-phase lock (``red_end``: a call during the
clearance may still change the decision on the same side of the barrier) and no backup timer
(the sequences never refresh a SET).

:func:`compare` pairs the changes of the two timelines over whole sequences (same phase, same
colour, at most ``tolerance`` ticks apart, in order; no cut-off) and reports the agreement:
matched changes over all distinct changes (matched + unmatched on either side), so a change
only one side makes counts against it. :func:`differential` also judges every divergence (the
first change only one side makes, and each one after the two showed the same colours again) by
the sourced rules of :mod:`harness.reference.nema_rules`, and audits every green our controller
ends against the same rules, whatever SUMO did there; each judgement is one of three verdicts:
SUMO departs from a quoted rule, a setting both may take, the model's fault. Calls come from a
:data:`CallSequence` (targeted scenarios, seeded random sequences) or from SUMO's own detectors
while it serves the shipped demand (:func:`run_traffic`). ``python -m harness.reference.nema``
prints the figures and the three counts. Our side is built by a ``model`` factory (the
:class:`~emulator.model.controller.Controller`): the judge's own tests give it a faulty subclass
and ask for a model fault.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import random
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from xml.sax.saxutils import quoteattr

from emulator.model.controller import Controller, tenths
from emulator.model.coordination import Coordinator
from harness.reference.nema_rules import (
    BACKED_WITH_CALL_ACROSS,
    CONDITIONAL_SERVICE,
    COORD_WAITS_FOR_OTHER_RING,
    ENDED_BEFORE_MIN,
    ENDED_WHILE_EXTENDING,
    ENTERED_PAST_FORCE_OFF,
    HELD_PAST_MAXIMUM,
    PERMISSIVE_PERIOD,
    PULLED_ACROSS,
    RE_EXTENDED,
    SKIPPED,
    Color,
    ColorChange,
    DifferenceClass,
    Judgement,
    Timeline,
    Verdict,
    audit,
    classify,
)
from hils.protocol.config import FREE, ForceOff, IntersectionConfig, NextPhaseLock, OffsetReference, Pattern, load
from hils.protocol.ntcip import ControlColumn, PhaseStartup
from hils.sim.network import NET_FILE, ROUTE_FILE, PhaseMap, data_path, derive_phase_map, read_net
from hils.sim.quiet_libsumo import libsumo

TICK = 0.1  # seconds per step, both controllers
PROGRAM_ID = "NEMA"
SUMO_PASSAGE = 0.1  # s: SUMO's vehicle extension, one step (see the theory of operation)

CallSequence = tuple[tuple[int, frozenset[int]], ...]
"""``(tick, phases)`` in ascending tick order: from that tick on exactly these phases are called."""

Model = Callable[[IntersectionConfig], Controller]
"""What builds our side from its config: the controller, or (in the judge's own tests) a faulty subclass."""


class NemaReferenceError(ValueError):
    """A config or call sequence SUMO's NEMA controller cannot be given; says what is allowed."""


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
        """The earliest change only one side makes: where the timelines part."""
        return min((*self.only_ours, *self.only_reference), default=None)

    def divergences(self, red_settled: int) -> tuple[int, ...]:
        """The tick each divergence starts at: the first change only one side makes, and every later one made
        after a resync: both sides show the same colours, each green and yellow since a change they both made (a
        matched pair), each red since such a change or for ``red_settled`` ticks on both (its clearance and red
        revert over). Equal colours alone are no resync: two sides making the same changes a second apart show the
        same colours in between, and a yellow or red begun later ends later."""
        partner = {a: b for a, b in self.matched}
        before = {Color.GREEN: Color.RED, Color.YELLOW: Color.GREEN, Color.RED: Color.YELLOW}
        start: dict[int, Color] = {}  # both start alike: a phase's colour before its first change on either side
        for c in sorted((*self.ours, *self.reference)):
            start.setdefault(c.phase, before[c.color])
        last: dict[str, dict[int, ColorChange]] = {"ours": {}, "SUMO": {}}  # per phase, its latest change
        by_tick: dict[int, list[tuple[str, ColorChange]]] = {}
        for name, timeline in (("ours", self.ours), ("SUMO", self.reference)):
            for c in timeline:
                by_tick.setdefault(c.tick, []).append((name, c))

        def in_step(now: int) -> bool:
            for p, color in start.items():
                ours, sumo = last["ours"].get(p), last["SUMO"].get(p)
                shown = ours.color if ours else color
                if shown is not (sumo.color if sumo else color):
                    return False
                if ours is sumo is None or (ours is not None and partner.get(ours) == sumo):
                    continue
                if shown is not Color.RED or any(c and now - c.tick < red_settled for c in (ours, sumo)):
                    return False
            return True

        resyncs = []
        for t in sorted(by_tick):
            if in_step(t - 1):  # the colours shown until this tick's changes
                resyncs.append(t - 1)
            for name, c in by_tick[t]:
                last[name][c.phase] = c
            if in_step(t):
                resyncs.append(t)
        starts: list[int] = []
        for t in sorted({c.tick for c in (*self.only_ours, *self.only_reference)}):
            if not starts or any(starts[-1] < r < t for r in resyncs):
                starts.append(t)
        return tuple(starts)

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


def running_pattern(config: IntersectionConfig) -> Pattern | None:
    """The pattern the controller runs from power-up (None: free)."""
    return config.coordination.patterns.get(config.coordination.pattern)


def comparable_config(config: IntersectionConfig) -> IntersectionConfig:
    """Our side of the comparison: SUMO's start-up (free mode: the first phase of each ring green;
    coordinated: the coordinated phases, where SUMO's ``calculateInitialPhases`` starts on the local zero),
    its hard-coded dual entry (the last phase of each ring in each barrier group: the throughs), its
    next-phase lock and no backup timer, everything else as given."""
    pattern = running_pattern(config)
    firsts = set(pattern.coord_phases) if pattern else {ring[0] for ring in config.rings}
    duals = {[p for p in ring if config.barrier_of(p) == b][-1] for ring in config.rings
             for b in range(len(config.barriers)) if any(config.barrier_of(p) == b for p in ring)}
    phases = {p: dataclasses.replace(ph, startup=PhaseStartup.GREEN_NO_WALK if p in firsts
                                     else PhaseStartup.PHASE_NOT_ON, dual_entry=p in duals)
              for p, ph in config.phases.items()}
    return dataclasses.replace(config, phases=phases, next_phase_lock=NextPhaseLock.RED_END).with_middleware(
        backup_time=0)


def sumo_options(config: IntersectionConfig) -> IntersectionConfig:
    """``config`` set as SUMO's NEMA controller is where NTCIP 1202 leaves the behaviour to a setting, so that the
    figures compare the two controllers and not their settings: ``PhaseTransitionLogic::fromBarrier`` backs a ring
    whenever its own ring has no call across the barrier, so every phase backs: with a call across as conditional
    service (phaseOptions bit 14), with none as Naztec's controllers do (``backup_prevent = false``). The judge still
    tells a backing outside the setting's words (too little time left) from one within."""
    phases = {p: dataclasses.replace(ph, conditional_service=True, backup_prevent=False)
              for p, ph in config.phases.items()}
    return dataclasses.replace(config, phases=phases)


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
    """The additional file with SUMO's NEMA program for ``config`` (see the theory of operation).

    With a pattern running from power-up SUMO runs coordinated: ``coordinate-mode``, the pattern's cycle,
    offset and coordinated phases, a phase's maximum its split less its clearance (SUMO's force-offs are
    laid out from those: ``NEMALogic::calculateForceOffs170``), ``fixForceOff`` from the force-off mode and
    ``controllerType`` TS2 (zero at the coordinated green) or Type170 (zero at its yellow) from the offset
    reference. SUMO's clock runs one step ahead of ours, so its offset is one step later."""
    slots = _ring_slots(config)
    last = _default_phases(config)
    pattern = running_pattern(config)
    coord = [next(p for p in pattern.coord_phases if config.ring_of(p) == r) for r in (1, 2)] if pattern else None
    side = None if coord is None else config.barrier_of(coord[0])
    defaults = [[next(p for p in reversed(row[2 * g:2 * g + 2]) if p) for g in range(2)] for row in slots]
    coordinate = coord or [last[r][0] for r in range(2)]
    barrier = [defaults[r][1 - side] for r in range(2)] if coord else [last[r][1] for r in range(2)]
    params = {
        "ring1": ",".join(map(str, slots[0])),
        "ring2": ",".join(map(str, slots[1])),
        "barrierPhases": ",".join(map(str, barrier)),
        "coordinatePhases": ",".join(map(str, coordinate)),
        "minRecall": "",
        "maxRecall": "",
    }
    offset = 0.0
    if pattern:
        c = config.coordination
        params |= {"coordinate-mode": "true", "cycle-length": str(pattern.cycle),
                   "minRecall": ",".join(map(str, coordinate)),
                   "fixForceOff": "true" if c.force_off is ForceOff.FIXED else "false",
                   "controllerType": "TS2" if c.offset_reference is OffsetReference.LEAD_GREEN else "Type170"}
        offset = pattern.offset
        if c.offset_reference is OffsetReference.YELLOW:
            # SUMO's Type170 zero is the end of the coordinated phase's clearance (calculateForceOffs170 adds
            # the transition time before taking zeroTime, against its own comment "the cycle 'starts' when
            # the coordinated phase goes to yellow"): a later offset puts it on the yellow, as ours.
            offset += max(config.phases[p].clearance for p in coordinate)
    lines = [f'<additional>\n  <tlLogic id="{phase_map.tls_id}" programID="{PROGRAM_ID}" type="NEMA" '
             f'offset="{offset:g}">']
    lines += [f"    <param key={quoteattr(k)} value={quoteattr(v)}/>" for k, v in params.items()]
    for p, ph in sorted(config.phases.items()):
        state = "".join("G" if q == p else "r" for q in phase_map.link_phases)
        maximum = pattern.splits[p] - ph.clearance if pattern else ph.max_green
        lines.append(f'    <phase duration="99" minDur="{ph.min_green:g}" maxDur="{maximum:g}" '
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


def run_ours(config: IntersectionConfig, calls: CallSequence, ticks: int, model: Model = Controller) -> Timeline:
    """Our controller (on :func:`comparable_config`) under ``calls`` for ``ticks`` steps."""
    _check(calls, ticks, config)
    controller = model(comparable_config(config))
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
def _sumo(program: str, *extra: str) -> Iterator[None]:
    if libsumo.simulation.isLoaded():
        raise NemaReferenceError("a SUMO simulation is already running in this process (libsumo runs one at a "
                             "time); close it before running the reference")
    with tempfile.TemporaryDirectory(prefix="hils-nema-") as tmp:
        additional = Path(tmp) / "nema.add.xml"
        additional.write_text(program, encoding="utf-8")
        libsumo.start(["sumo", "-n", str(data_path(NET_FILE)), "-a", str(additional), "--step-length", str(TICK),
                       "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true", *extra])
        try:
            yield
        finally:
            libsumo.close()


class _Junction:
    """SUMO's NEMA-controlled junction while a simulation runs: its detectors per phase and its colours."""

    def __init__(self, config: IntersectionConfig, phase_map: PhaseMap) -> None:
        self.tls = phase_map.tls_id
        if libsumo.trafficlight.getProgram(self.tls) != PROGRAM_ID:
            libsumo.trafficlight.setProgram(self.tls, PROGRAM_ID)
        self.first_link = {p: phase_map.link_phases.index(p) for p in config.phases}
        lane_detector = {libsumo.lanearea.getLaneID(d): d for d in libsumo.lanearea.getIDList()}
        self.detectors = {p: [lane_detector[lane] for lane in phase_map.incoming_lanes(p)] for p in config.phases}

    def colors(self) -> dict[int, Color]:
        state = libsumo.trafficlight.getRedYellowGreenState(self.tls)
        return {p: _SUMO_COLOR.get(state[i], Color.RED) for p, i in self.first_link.items()}

    def occupied(self) -> frozenset[int]:
        """The phases with a vehicle on one of their detectors now (what the NEMA logic reads as a call)."""
        return frozenset(p for p, ds in self.detectors.items()
                         if any(libsumo.lanearea.getLastStepVehicleNumber(d) for d in ds))


def run_reference(config: IntersectionConfig, calls: CallSequence, ticks: int) -> Timeline:
    """SUMO's NEMA controller under ``calls`` for ``ticks`` steps of 0.1 s."""
    _check(calls, ticks, config)
    phase_map = derive_phase_map(config, read_net())
    pending = dict(calls)
    out: list[ColorChange] = []
    with _sumo(sumo_program(config, phase_map)):
        junction = _Junction(config, phase_map)
        # SUMO's start-up greens count their minimum from its first step, not from time 0: one
        # step without calls first puts its clock on our tick 0 (start-up greens then end together)
        libsumo.simulationStep()
        shown = junction.colors()
        called: frozenset[int] = frozenset()
        for k in range(ticks):
            if k in pending:
                for p in called ^ pending[k]:
                    for d in junction.detectors[p]:
                        libsumo.lanearea.overrideVehicleNumber(d, 1 if p in pending[k] else -1)
                called = pending[k]
            libsumo.simulationStep()
            now = junction.colors()
            out += _changes(shown, now, k + 1)
            shown = now
    return tuple(out)


def run_traffic(config: IntersectionConfig, ticks: int, seed: int) -> tuple[CallSequence, Timeline]:
    """SUMO's NEMA controller serving the shipped demand (its own vehicles on its own detectors) for ``ticks``
    steps: the calls its detectors placed, as a sequence our controller can be given, and its timeline."""
    if ticks <= 0:
        raise NemaReferenceError(f"run length {ticks} ticks; allowed: > 0")
    phase_map = derive_phase_map(config, read_net())
    calls: list[tuple[int, frozenset[int]]] = []
    out: list[ColorChange] = []
    with _sumo(sumo_program(config, phase_map), "-r", str(data_path(ROUTE_FILE)), "--seed", str(seed)):
        junction = _Junction(config, phase_map)
        libsumo.simulationStep()  # as in run_reference: SUMO's clock one step ahead of ours
        shown = junction.colors()
        for k in range(ticks):
            # what the detectors hold after step k is what the NEMA logic reads in step k + 1
            occupied = junction.occupied()
            if not calls or calls[-1][1] != occupied:
                calls.append((k, occupied))
            libsumo.simulationStep()
            now = junction.colors()
            out += _changes(shown, now, k + 1)
            shown = now
    return tuple(calls), tuple(out)


# --- comparison ------------------------------------------------------------------------


def compare(ours: Timeline, reference: Timeline, tolerance: int = 1) -> Comparison:
    """Pair changes of the same phase and colour at most ``tolerance`` ticks apart, in order, over the whole
    timelines."""
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


@dataclass(frozen=True)
class Differential:
    """Both controllers under one call sequence: the comparison over the whole sequence, every divergence judged,
    and the faults the audit of our own greens found."""

    calls: CallSequence
    comparison: Comparison
    judgements: tuple[Judgement, ...]
    audited: tuple[Judgement, ...]

    @property
    def first(self) -> Judgement | None:
        """The first divergence judged (None when the two agree throughout)."""
        return self.judgements[0] if self.judgements else None

    @property
    def model_faults(self) -> tuple[Judgement, ...]:
        """Every fault of the model: divergences judged ours, and greens the audit found at fault (once each)."""
        faults = [j for j in self.judgements if j.verdict is Verdict.MODEL]
        seen = {(j.tick, j.phase) for j in faults}
        return tuple(faults + [j for j in self.audited if (j.tick, j.phase) not in seen])

    def counts(self) -> Counter[Verdict]:
        """The three counts: divergences by verdict, the audit's further faults counted as the model's."""
        out = Counter({v: 0 for v in Verdict})
        out.update(j.verdict for j in self.judgements if j.verdict is not Verdict.MODEL)
        out[Verdict.MODEL] += len(self.model_faults)
        return out


JUDGE_MARGIN = 400
"""Ticks both sides run on past a sequence's end, its last calls held, for the judge only: a green ending near the
end shows where its ring goes. The comparison stops at the sequence's end."""


def differential(config: IntersectionConfig, calls: CallSequence, ticks: int,
                 model: Model = Controller) -> Differential:
    """Both controllers under the same calls, compared within 0.1 s over the whole sequence; every divergence
    judged by :func:`harness.reference.nema_rules.classify`, every green of ours by its ``audit``."""
    longer = ticks + JUDGE_MARGIN
    return _judged(config, calls, ticks, run_ours(config, calls, longer, model),
                   run_reference(config, calls, longer))


def traffic_differential(config: IntersectionConfig, ticks: int, seed: int, model: Model = Controller) -> Differential:
    """SUMO's NEMA controller serving traffic, and ours given the calls its detectors placed."""
    longer = ticks + JUDGE_MARGIN
    calls, reference = run_traffic(config, longer, seed)
    return _judged(config, calls, ticks, run_ours(config, calls, longer, model), reference)


def _judged(config: IntersectionConfig, calls: CallSequence, ticks: int, ours: Timeline,
            reference: Timeline) -> Differential:
    """Compare up to ``ticks``; judge on the timelines as long as they run."""
    comparison = compare(*(tuple(c for c in timeline if c.tick <= ticks) for timeline in (ours, reference)))
    pattern = running_pattern(config)
    plan = None if pattern is None else Coordinator(config).plan
    called = calls_read(calls, ticks + JUDGE_MARGIN)
    settled = max(tenths(ph.red_clear) + tenths(ph.red_revert) for ph in config.phases.values()) + 1
    judged = tuple(classify(config, called, ours, reference, tick, plan=plan)
                   for tick in comparison.divergences(settled))
    faults = tuple(j for j in audit(config, called, ours, plan=plan) if j.tick <= ticks)
    return Differential(tuple((k, ps) for k, ps in calls if k <= ticks), comparison, judged, faults)


def calls_read(calls: CallSequence, ticks: int) -> list[frozenset[int]]:
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


class Mode(StrEnum):
    """How the controllers run: free, or the config's coordination plan with TS2 or Type 170 offsets."""

    FREE = "free"
    TS2 = "coordinated TS2 (lead_green), fixed force-offs"
    TS2_FLOATING = "coordinated TS2 (lead_green), floating force-offs"
    TYPE170 = "coordinated Type 170 (yellow), fixed force-offs"


def in_mode(config: IntersectionConfig, mode: Mode) -> IntersectionConfig:
    """``config`` running free, or its plan from power-up with the mode's offset reference and force-off mode."""
    if mode is Mode.FREE:
        return dataclasses.replace(config, coordination=dataclasses.replace(config.coordination, pattern=FREE))
    if not config.coordination.patterns:
        raise NemaReferenceError(f"{config.source}: coordination: no [[coordination.patterns]] to compare in "
                                 f"{mode.value} mode; allowed: a config with a plan (the shipped four-leg has one)")
    c = config.planned().coordination
    reference = OffsetReference.YELLOW if mode is Mode.TYPE170 else OffsetReference.LEAD_GREEN
    force = ForceOff.FLOATING if mode is Mode.TS2_FLOATING else ForceOff.FIXED
    return dataclasses.replace(config, coordination=dataclasses.replace(c, offset_reference=reference,
                                                                        force_off=force))


# A minimal sequence for each class of first difference (docs/nema_differences.md shows them): on the paper's
# intersection, free or running its plan, SUMO's NEMA controller makes the difference and its rule names it.
EXAMPLES: dict[DifferenceClass, tuple[Mode, CallSequence, int]] = {
    # 2+6 green, 6's call drops as 4 (across) and 5 are called: SUMO backs ring 2 from 6 into 5, with 20 s of 2's
    # maximum left for 6's clearance and 5's minimum (8 s)
    CONDITIONAL_SERVICE: (Mode.FREE, seconds((0, [2, 6]), (15, [2, 4, 5]), (45, [])), 500),
    # the same backing with 4 called since 10 s: 2's maximum runs out at 30 s, 6 s after the backing at 24 s, too
    # soon for 6's clearance and 5's minimum
    BACKED_WITH_CALL_ACROSS: (Mode.FREE, seconds((0, [2, 6]), (10, [2, 4, 6]), (24, [2, 4, 5]), (50, [])), 600),
    # 3+7 green; calls on 1, 5 and 8: SUMO crosses to 1+5 and leaves 8 (after 7, before the barrier) unserved
    SKIPPED: (Mode.FREE, seconds((0, [3, 7]), (12, [1, 5, 8]), (30, [])), 400),
    # 2+5 green; 5 ends alone toward 6 (called), then 2 can go with 3 called: SUMO takes ring 2 across with ring 1
    PULLED_ACROSS: (Mode.FREE, seconds((0, [2, 5]), (9, [3, 6]), (30, [])), 400),
    # 3+8 -> 4+8; 8's green-rest max-out (timed from the call on 4, its concurrent phase) ends 4 with its call on
    ENDED_WHILE_EXTENDING: (Mode.FREE, seconds((0, [3, 8]), (12, [4, 8]), (15, [2, 4, 8]), (45, [])), 500),
    # 4+7 with a call on 1 across; ring 2 moves 7 -> 8 as 4 maxes out: SUMO ends 8 1.9 s into its green
    ENDED_BEFORE_MIN: (Mode.FREE, seconds((0, [2, 6]), (10, [4, 7]), (20, [1, 4, 7]), (33, [1, 4, 8]), (60, [])),
                       700),
    # 6 rests green with its call, 3 called across from 11.2 s; ring 1 changes 2 -> 1 meanwhile: SUMO times 6's
    # maximum from 1's start (36 s), not from the call on 3 (31.2 s)
    HELD_PAST_MAXIMUM: (Mode.FREE, seconds((0, [2, 6]), (10, [1]), (11.2, [3, 6]), (45, [])), 500),
    # 2 gaps out while only its concurrent 5 and 6 are called; its call returns with one on 1: SUMO ends it, ours
    # extends it
    RE_EXTENDED: (Mode.FREE, seconds((0, [2, 6]), (10, [5, 6]), (19.5, [1, 2, 5, 6]), (40, [])), 500),
    # Pattern 1 (70 s): 2+6 yield at 32.3 s for 3 and 8; 3's force-off point is at 37 s, too soon for its minimum
    # after the clearance: SUMO serves it (from 37.3 s), ours skips it for 4
    ENTERED_PAST_FORCE_OFF: (Mode.TS2, seconds((0, [2, 6]), (32.2, [3, 8]), (60, [])), 800),
    # Pattern 1: ring 1 serves 1 from 50.1 s; 5 is called at 54.5 s in its permissive period: ours ends 6 for it,
    # SUMO keeps 6 until ring 1 is ready too
    COORD_WAITS_FOR_OTHER_RING: (Mode.TS2, seconds((0, [2, 6]), (40, [1]), (54.5, [1, 5]), (70, [])), 900),
    # Pattern 1 with Type 170 offsets: 4 is called at 10 s, 3 (before it) no longer fits: ours ends 2+6 for it,
    # SUMO does not
    PERMISSIVE_PERIOD: (Mode.TYPE170, seconds((0, [2, 6]), (10, [4]), (60, [])), 800),
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


def counts(results: Sequence[Differential]) -> Counter[Verdict]:
    """The three counts over several differentials."""
    return sum((d.counts() for d in results), Counter({v: 0 for v in Verdict}))


def tally(results: Sequence[Differential]) -> Counter[tuple[Verdict, str]]:
    """Judgements per verdict and class: every divergence, and the model's faults the audit found besides."""
    out: Counter[tuple[Verdict, str]] = Counter()
    for d in results:
        out.update((j.verdict, str(j.kind)) for j in d.judgements if j.verdict is not Verdict.MODEL)
        out.update((Verdict.MODEL, str(j.kind)) for j in d.model_faults)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.reference.nema",
                                     description="Agreement of our controller with SUMO's NEMA controller over whole "
                                                 "call sequences, free and running the config's coordination plan, "
                                                 "and every divergence judged by quoted rules, counted in three "
                                                 "kinds: SUMO departs from a rule, a setting both may take, the "
                                                 "model's fault (every green of ours is audited too).")
    parser.add_argument("--config", help="intersection TOML (default: the shipped four-leg intersection)")
    parser.add_argument("--random", type=int, default=50, help="random call sequences per mode (default 50)")
    parser.add_argument("--length", type=float, default=300.0, help="seconds per random sequence (default 300)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--traffic", type=int, default=10,
                        help="runs of SUMO serving the shipped demand on its detectors per mode (default 10, "
                             "seeds 0..N-1)")
    parser.add_argument("--mode", choices=[m.name.lower() for m in Mode], action="append",
                        help="compare in this mode only (repeatable; default: every mode, coordinated ones when the "
                             "config has a plan)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="show each random sequence's judgements and where it first differs")
    args = parser.parse_args(argv)
    ticks = round(args.length * 10)
    try:
        config = load(args.config)
        modes = [Mode[m.upper()] for m in args.mode] if args.mode else [
            m for m in Mode if m is Mode.FREE or config.coordination.patterns]
        for mode in modes:
            cfg = sumo_options(in_mode(config, mode))
            print(f"== {mode.value}")
            if mode is Mode.FREE:
                targeted = [differential(cfg, calls, t) for calls, t in SCENARIOS.values()]
                _figure(f"targeted scenarios ({len(targeted)})", targeted)
            rng = random.Random(args.seed)
            randoms = []
            for i in range(args.random):
                randoms.append(differential(cfg, random_calls(rng, ticks, sorted(cfg.phases)), ticks))
                d = randoms[-1]
                if args.verbose and (d.judgements or d.audited):
                    judged = "\n  ".join(map(str, (*d.judgements, *d.audited)))
                    print(f"random {i}:\n  {judged}\n" + d.comparison.report(d.calls))
            traffic = [traffic_differential(cfg, ticks, seed) for seed in range(args.traffic)]
            _figure(f"{args.random} random sequences of {args.length:g} s", randoms)
            _figure(f"{args.traffic} runs of {args.length:g} s of detector-driven traffic", traffic)
    except (NemaReferenceError, ValueError) as exc:
        print(f"nema_reference: {exc}", file=sys.stderr)
        return 1
    return 0


def _figure(label: str, results: Sequence[Differential]) -> None:
    if not results:
        return
    matched, total = pooled([d.comparison for d in results])
    print(f"{label:52s} {matched / max(total, 1):6.1%} of {total} changes, whole sequences")
    classes = tally(results)
    total = counts(results)
    for verdict in Verdict:
        print(f"  {total[verdict]:4d}  {verdict}")
        for (v, kind), m in sorted(classes.items(), key=lambda item: -item[1]):
            if v is verdict:
                print(f"        {m:4d}  {kind}")


if __name__ == "__main__":
    sys.exit(main())
