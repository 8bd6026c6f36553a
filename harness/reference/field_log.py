"""A controller config written from a field controller's own hi-res log, for replaying the log into the emulator.

Signal-Replay replays a field log's detector, pedestrian and preempt inputs into a bench controller and compares
the bench's phase events with the field's; the bench must run the field's timing. :func:`infer` reads it from
the log's own events (Indiana enumerations) and says which values it had to guess:

- **phases and structure**: the phases that began green (event 1). Two phases on at the same time are concurrent,
  so in different rings and one barrier group: a phase is on from its green to the end of its red clearance (11;
  of its yellow, 9, when no red clearance is served), as NTCIP 1202's phaseStatusGroupPhaseOns has it ("The phase
  is ON during the Green, Yellow, & Red Clearance intervals of that phase"), and phaseConcurrency says which
  phases "may run concurrently" ("Phases that are contained in the same ring may NOT run concurrently"). Greens
  alone are not enough: in a pretimed plan a phase may begin green as soon as the phase beside it ends its green,
  and two phases across a barrier never overlap at all. Barrier groups are the connected sets of concurrent
  phases and of phases that began green one after the other with no barrier termination (31) logged between
  (:func:`_unbarred`); rings split each group by concurrency (NEMA's numbering, 1-4 and 9-12 in ring 1, when it
  agrees). A ring without a phase in a group gets an unused phase number there that nothing calls (the controller
  skips it; NTCIP's split table needs a split for it);
- **service order** (:func:`_service_order`), in time polynomial in the phases (O(n^3) for the n phases of a ring
  in a group): NTCIP 1202 sequenceData, "The order of phase numbers determines the phase sequence for the ring",
  and a ring goes on to the next phase of that order that is called, within its barrier group until both rings
  cross the barrier. So each time a phase of a ring begins green right after another of its group, no phase of
  another group having begun green in between (:func:`_successions`), it comes later in the sequence: the
  successions the log shows point forward. The order is built one phase at a time: next is a phase no remaining
  phase was seen to precede (the one seen most often right after the phase before it; then the lower number),
  and when every remaining phase was seen to follow another (a cycle: a ring that backed into an earlier phase of
  its group while the other ring timed, TecNote 3013, or came round again with nothing called across the
  barrier), the phase with the largest surplus of successions out over successions in (the greedy of Eades, Lin
  and Smyth for a minimum feedback arc set). Guarantee: when the successions have no cycle, every one of them
  points forward in the order, and when each phase of the sequence was seen at least once right after the one
  before it, the order is the controller's sequence (the only one with every succession forward). The exhaustive
  search it replaces (the order whose adjacent pairs were seen most) took 11 phases 56 s and grew as n!; it also
  preferred a skip it saw often to the sequence (1 3 2 for a log that mostly skips 2);
- **timings**: yellow (8 to 9) and red clearance (10 to 11), the minimum (1 to 3, the most frequent), walk (21 to 22)
  and pedestrian clearance (22 to 23; a walk of whole seconds cut to end its clearance within the greens that served it,
  as an Econolite under a plan ends its walks' clearance at the force-off), passage (a gap-out, 4, after the last of the
  phase's calling detectors went off, 81, but not one logged as its minimum completes, 3, whose gap ran out during the
  minimum: the most frequent gap, counted from the last tick with the call; the intersection's when a phase shows too
  few), the maximum (the shortest green that maxed out, 5, timed from its phase check, 2, where the log has one within
  it, from its begin green on max recall; else the longest green, or the intersection's maximum when longer), each
  within what NTCIP's phase table holds (said when a value had to be brought inside);
- **detectors**: a detector calls the phase whose call registrations (43) its actuations (82) bring most often, at
  the same tick or the next, when they do for at least a tenth of them; the others are logged but call nothing
  (phase 0, as a count station). Push buttons likewise with pedestrian calls (90 with 45). Numbers past the
  emulator's (vehicle detectors 1-128, push buttons 1-255) are said and left out. A detector that calls nothing on
  its tick but whose actuations are followed by one phase's call the same time later has that detector delay
  (:func:`_delays`); one whose going off (81) is followed by its phase's call dropping (44) the same time later, that
  phase's last detector to go, holds its call that long: an extension when seen on the phase's green, a carryover when
  seen off it (:func:`_holds`);
- **overlaps**: an overlap that begins green (61) with phases (1, the same tick or the next: the fewest that together
  come with nine in ten of its greens, each with a tenth) includes them, or, failing that, one same time after them
  (a delayed green of that time); one that never logs a yellow (63) is a transit bar (NTCIP 1202 v03 transit-2),
  else a normal overlap; one that never begins green but goes dark (66) as phases begin green and yellow (63) with
  their yellow is a normal overlap of them, its green shown by their own outputs (:func:`dark_at_green`; replays
  count its 66 as the emulator's 61, a declared logging variant); overlaps past P (16) are said and left out;
- **recalls and dual entry** (:func:`_uncalled`, :func:`_extenders`, :func:`_dual_entries`): a phase served with no
  call the log registers (43), where the log registers calls of others or has no detector events (pretimed), or
  whose call registers as its own yellow begins (an Econolite's recall), or that a ring went on to within its group
  after a green that ended with nothing shown demanded and with no call of its own (:func:`_entered_undemanded`: a
  green with nothing else to serve rests, so a recall ended it), is recalled: max recall when its greens end
  by force-off or max-out, else min; a detector that calls nothing may extend a recalled phase (its gap-outs come the
  same time after the detector's off, never sooner nor while it is on; that time is the intersection's passage and
  the rest the detector's extension); a phase a ring entered at a barrier termination when it had no demand in the
  new group as the old one's last green ended, and that is not its nearest phase with demand as the group began, is
  dual entry (once is enough: nothing else makes such an entry), a coordinated phase never (the plan calls it); a
  phase with a walk whose every green began one, while the log registers no pedestrian call of it (45) and no push
  button calls it, has pedestrian recall (:func:`_ped_recalls`: under a plan the pattern's split mode,
  pedestrianRecall, beside its vehicle recall; free, the phase's recall if it has no other);
- **start-up**: the phases green when the log begins (their first interval event is a begin yellow);
- **coordination**: the cycle is the spacing of the local zeros (event 150, parameter 5; two at one time are one);
  the coordinated phases are the ones with the most yield point events (151) in the group that has them, else the
  phases green at the local zero; each phase's split is what the controller logged (split change, events 134-149,
  phases 1-16: the value in effect at most local zeros), else it ends where its force-offs (6) fall in the cycle
  plus its clearance (when at least a fifth of its greens end so), a ring's last phase before a barrier where the
  other ring's ends, the last phase with the cycle. Positions are seconds from midnight of the log's first day
  modulo the cycle (the emulator's clock, which counts on across midnights). The rings' orders are laid from the
  barrier where a ring's last split ends, as the controller lays them (:func:`_barrier_start`), and the offset is
  the start of the earliest coordinated split there (NEMA TS 2's lead-green reference, the emulator's), wherever
  the field's local zero is; only when no split's end is placed does the local zero stand for it (said). Then each
  split is made at least its phase's minimum green and clearance, the rings reach each barrier together and each
  ring fills the cycle, as NTCIP 1202's splitTime and the barrier require (what had to move is said).

A log whose events cannot make a config is refused with one line naming the event (its time, code and parameter)
and why: a begin green or yellow of phase 0 or past 255 (NTCIP's largest phase number), an overlap, detector or
push button 0, local zeros whose spacing is no cycle NTCIP allows (30-255 s) or shorter than the phases' minimum
service, no phase number left for a ring's group. Reading the file is :mod:`harness.reference.hires_file`'s job.

What the log does not show is guessed and said: a value a phase never showed (its event never logged; the
intersection's minimum and maximum for a phase that shows none), the offset reference when no split end is placed,
the timers of detectors the log shows too few of, max 2, red revert, overlaps and dynamic omits.
"""

from __future__ import annotations

import bisect
import itertools
import json
import math
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

from harness.reference.hires_file import FieldLogError, Row
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import EventCode

E = EventCode
TICK = timedelta(milliseconds=100)
CALL_SHARE = 0.10  # a detector calls a phase when at least this share of its actuations registers the call
LOCAL_ZERO = 5  # event 150's parameter at the local zero
PASSAGE_SEEN = 3  # a phase's own most frequent gap counts as its passage when seen this often
_INPUTS = frozenset({E.DETECTOR_ON, E.DETECTOR_OFF, E.PED_DETECTOR_ON, E.PED_DETECTOR_OFF})
DELAY_SHARE = 0.3  # a detector's actuations followed by one phase's call the same time later this often: a delay
#: The longest detector delay looked for (NTCIP 1202 vehicleDetectorDelay holds 0-255.0 s, "the period a detector
#: actuation ... shall be delayed when the phase is not Green"; the longer, the likelier a chance coincidence).
MAX_DELAY = timedelta(seconds=25.5)
RECALL_SHARE = 0.9  # a phase whose call registers as its yellow begins this often is recalled
PED_RECALLED = 3  # a phase whose every green began a walk, at least this many, with no pedestrian call: ped recall
REDUCTION_SEEN = 5  # gaps between the minimum gap and the passage, on one line, that show gap reduction
REDUCTION_FIT = 0.3  # s a gap of the reduction may lie off its line
YIELD_SEEN = 3  # a coordinated phase's greens ending at one place this often: its yield point (the first such)
FORCE_OFF_SHARE = 0.2  # a phase's force-offs mark where its split ends when they end at least this share of its greens
#: What the emulator's config holds (:mod:`hils.protocol.config`): phases 1-255, vehicle detectors 1-128, push
#: buttons 1-255, overlaps A-P (1-16), cycles 30-255 s.
PHASES, DETECTORS = config_mod.PHASE_NUMBERS[-1], config_mod.DETECTOR_NUMBERS[-1]
PUSH_BUTTONS = config_mod.PED_DETECTOR_NUMBERS[-1]
OVERLAPS, CYCLES = config_mod.OVERLAP_NUMBERS[-1], (config_mod.CYCLE_SECONDS[0], config_mod.CYCLE_SECONDS[-1])
#: The events whose parameter names what the config is written from, and what they name.
NAMED = {E.PHASE_BEGIN_GREEN: "a phase", E.PHASE_BEGIN_YELLOW: "a phase",
         **{code: "an overlap" for code in range(E.OVERLAP_BEGIN_GREEN, E.OVERLAP_DARK + 1)},
         E.DETECTOR_ON: "a detector", E.DETECTOR_OFF: "a detector", E.PED_DETECTOR_ON: "a push button",
         E.PED_DETECTOR_OFF: "a push button"}


@dataclass
class Inferred:
    """A config inferred from a log: its TOML, and what was read and what was guessed to write it."""

    toml: str
    read: list[str] = field(default_factory=list)
    guessed: list[str] = field(default_factory=list)

    def config(self) -> IntersectionConfig:
        return config_mod.parse(self.toml, "inferred.toml")


def _event(r: Row) -> str:
    """An event as a refusal names it: its code and name, its parameter and its time."""
    try:
        name = f" ({E(r.code).name.lower().replace('_', ' ')})"
    except ValueError:
        name = ""
    return f"event {r.code}{name}, parameter {r.parameter}, at {_when(r.time)}"


def _when(t: datetime) -> str:
    return f"{t:%Y-%m-%d %H:%M:%S}.{t.microsecond // 100_000}"


# --- the log's events -------------------------------------------------------------------------------------------


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


def _spans(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]]
           ) -> dict[int, list[tuple[datetime, datetime]]]:
    """Each phase's time on: each green to the end of the yellow (9) and red clearance (11) that follow it, before
    the phase's next begin green or yellow (a service whose begin green the log lost does not lend its clearance);
    the green's own end when neither is logged."""
    begins: dict[int, list[datetime]] = defaultdict(list)
    ends: dict[int, list[datetime]] = defaultdict(list)
    for r in rows:
        if r.code in (E.PHASE_BEGIN_GREEN, E.PHASE_BEGIN_YELLOW):
            begins[r.parameter].append(r.time)
        elif r.code in (E.PHASE_END_YELLOW, E.PHASE_END_RED_CLEARANCE):
            ends[r.parameter].append(r.time)
    out = {}
    for p, mine in greens.items():
        again, times = begins[p], ends.get(p, [])
        spans = []
        for begin, end in mine:
            k = bisect.bisect_right(again, end)
            last = bisect.bisect_left(times, again[k]) if k < len(again) else len(times)
            spans.append((begin, max(end, times[last - 1]) if last else end))
        out[p] = spans
    return out


def _since_midnight(t: datetime, day0: datetime) -> float:
    """Seconds from midnight of the log's first day: the emulator's clock, which counts on across midnights (so a
    cycle that does not divide a day keeps its place over a log of several days)."""
    return (t - day0).total_seconds()


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
    _check_numbers(rows)
    out = Inferred("")
    # What the controller did, without the inputs (detector and push-button events, most of a busy log): what reads
    # only that scans it, a day's log in a fraction of the time.
    events = [r for r in rows if r.code not in _INPUTS]
    greens = _greens(events)
    phases = sorted(greens)
    if len(phases) < 2:
        raise FieldLogError(f"the log shows {len(phases)} phase(s) served (begin green, event 1, then begin yellow, "
                            "event 8); a config needs at least two")
    out.read.append(f"phases served: {', '.join(map(str, phases))}")
    structure = _structure(phases, greens, _spans(events, greens), out, _unbarred(events))
    shared_min = _mode(m for p in phases for m in _minimums(events, p))
    timing = {p: _timing(events, p, greens[p], out, shared_min) for p in phases}
    detectors = _in_config(_detector_phases(rows, E.DETECTOR_ON, E.PHASE_CALL_REGISTERED, phases), "detector",
                           DETECTORS, out)
    pushes = _in_config(_detector_phases(rows, E.PED_DETECTOR_ON, E.PED_CALL_REGISTERED, phases), "push button",
                        PUSH_BUTTONS, out)
    recalled = _uncalled(rows, phases, structure)
    recalled |= _entered_undemanded(rows, structure, recalled)
    timers = _delays(rows, detectors, greens, out)
    for d, held in _holds(rows, detectors, greens, out).items():
        timers.setdefault(d, {}).update(held)
    for d in _locks(rows, detectors, greens, out):
        timers.setdefault(d, {})["lock"] = True
    held = {d: timedelta(seconds=max(t.get("extend", 0.0), t.get("carryover", 0.0))) for d, t in timers.items()}
    samples = {p: _gaps(rows, p, [d for d, q in detectors.items() if q == p], held) for p in phases}
    gaps = {p: [g for _, g in mine] for p, mine in samples.items()}
    everyone = Counter(g for values in gaps.values() for g in values)
    shared = _mode(everyone.elements())
    seen = shared if shared is not None and everyone[shared] >= PASSAGE_SEEN else None  # the intersection's passage
    # Of the detectors a delay leaves calling nothing, those that extend a recalled phase (its gaps counted then).
    yielding = {r.parameter for r in events if r.code == E.COORD_YIELD_POINT}  # coordinated: the plan holds them
    # A recalled phase whose greens its plan mostly forces off (6) is held by the plan, not by a detector: what ends
    # it now and then by gap-out says nothing of an extension (the atspm sample's coordinated 6: 94 force-offs, 2
    # gap-outs, and no yield point logged).
    ends = Counter((r.parameter, r.code) for r in events if r.code in (E.PHASE_GAP_OUT, E.PHASE_FORCE_OFF))
    forced = {p for p in recalled if ends[p, E.PHASE_FORCE_OFF] > ends[p, E.PHASE_GAP_OUT]}
    extended = _extenders(rows, detectors, recalled - yielding - forced, structure, seen, out)
    for p, (d, _) in extended.items():
        samples[p] = _gaps(rows, p, [d], held)
        gaps[p] = [g for _, g in samples[p]]
    shared = _mode(g for values in gaps.values() for g in values)
    for p in phases:
        counts = Counter(gaps[p])
        if (reduced := _reduction(samples[p])) is not None:
            timing[p] |= reduced
            out.read.append(f"phase {p}: gap reduction, passage {reduced['passage']:g} s reduced after "
                            f"{reduced['time_before_reduction']} s over {reduced['time_to_reduce']} s to "
                            f"{reduced['min_gap']:g} s (its gap-outs' gaps fall with the green's time)")
        elif p in extended:  # what its gap-outs show, the intersection's passage and the rest its detector's
            d, shown = extended[p]
            timing[p]["passage"] = min(shown, seen) if seen is not None else shown
            if shown - timing[p]["passage"] >= TICK.total_seconds():
                timers.setdefault(d, {})["extend"] = round(shown - timing[p]["passage"], 1)
                out.guessed.append(f"detector {d}: extends phase {p} {timers[d]['extend']:g} s (its gap-outs come "
                                   f"{shown:g} s after the detector's last tick on; the intersection's passage "
                                   f"{timing[p]['passage']:g} s, which its greens' starts time alone)")
        elif counts and counts.most_common(1)[0][1] >= PASSAGE_SEEN:
            timing[p]["passage"] = _mode(gaps[p])
        else:
            timing[p]["passage"] = shared if shared is not None else 2.0
            out.guessed.append(f"phase {p}: passage {timing[p]['passage']:g} s (the intersection's most frequent: "
                               f"no gap of its own seen {PASSAGE_SEEN} times)")
        low, high = config_mod.phase_time_range("passage")
        timing[p]["passage"] = _within(p, "passage", timing[p]["passage"], low, min(high, timing[p]["max_green"]), out)
        if "min_gap" in timing[p]:
            timing[p]["min_gap"] = min(timing[p]["min_gap"], timing[p]["passage"])
    for p in recalled - yielding:
        if _recall_kind(events, p)[0] == "max":
            _max_recall_maximum(events, p, timing[p], out)
    maxima = [t["maxed"] for t in timing.values() if "maxed" in t]
    if maxima:  # a phase that never maxed out has the intersection's maximum, if its longest green is shorter
        shared_max = math.ceil(max(maxima, key=maxima.count) - 1e-9)
        for p in phases:
            if "maxed" not in timing[p] and timing[p]["max_green"] < shared_max:
                timing[p]["max_green"] = shared_max
                out.guessed.append(f"phase {p}: max green {shared_max} s (it never maxed out: the intersection's most "
                                   "frequent maximum, longer than its longest green)")
    else:  # nothing maxed out: no maximum is shorter than a green, which may have waited at a barrier past its own
        top = config_mod.phase_time_range("max_green")[1]
        for p in phases:
            longest = math.ceil(max((b - a).total_seconds() for a, b in greens[p]) - 1e-9)
            timing[p]["max_green"] = max(timing[p]["max_green"], min(longest, top))
    for p, twin in structure.phantom.items():
        timing[p] = {k: v for k, v in timing[twin].items() if k not in ("walk", "ped_clear")}
    logged = sorted(d for d, q in detectors.items() if q == 0)
    out.read.append("detectors calling: " + ", ".join(f"{d}->{q}" for d, q in sorted(detectors.items()) if q)
                    + (f"; logged only: {', '.join(map(str, logged))}" if logged else ""))
    if any(pushes.values()):
        out.read.append("push buttons: " + ", ".join(f"{d}->{q}" for d, q in sorted(pushes.items()) if q))
    out.guessed.append("every calling detector also extends its phase's green; no detector delay, extension or "
                       "carryover but as said")
    day0 = datetime.combine(rows[0].time.date(), datetime.min.time())
    coordination = _coordination(events, day0, structure, timing, greens, out)
    coordinated = set(coordination["coord"]) if coordination else set()
    for p in recalled - coordinated:
        _recall(events, p, timing[p], out)
    _ped_recalls(events, greens, timing, pushes, coordination, out)
    _backings(events, greens, structure, timing, out)
    _reextensions(events, greens, structure, timing, out)
    _recycles(events, greens, timing, out)
    duals = [p for p in _dual_entries(events, structure, recalled) if p not in coordinated]  # the plan calls those
    for p in duals:
        timing[p]["dual_entry"] = True
    if duals:
        out.read.append(f"dual entry: phase(s) {', '.join(map(str, duals))} (entered as the rings crossed a barrier "
                        "when no phase of its ring there had a call)")
    overlaps = _overlaps(events, phases, out)
    out.guessed.append("recalls and dual entry only as said, no red revert or max 2 (the log shows the service, not "
                       "the settings); "
                       "dynamic omits (46-49 logged by the field controller's own logic) are not modelled")
    start = rows[0].time.replace(microsecond=rows[0].time.microsecond // 100_000 * 100_000)
    startup = _startup(events, greens, structure, out)
    powered = _powered(events, startup, timing, start, out)
    out.toml = _toml(name, structure, timing, detectors, timers, pushes, coordination, overlaps, startup, powered)
    return out


def _uncalled(rows: Sequence[Row], phases: Sequence[int], structure: Structure) -> set[int]:
    """The phases served without a vehicle call the log registers (43), or whose call registers as their yellow begins
    (at least :data:`RECALL_SHARE` of the time): recalled. The first only where the log registers calls of other
    phases, or has no detector events at all (a pretimed log): some controllers log no calls."""
    called = {r.parameter for r in rows if r.code == E.PHASE_CALL_REGISTERED}
    detected = any(r.code == E.DETECTOR_ON for r in rows)
    if detected and not called:
        return set()
    # A controller that logs a recall's call (an Econolite: 43 on the tick after the phase's own yellow begins, every
    # time) shows the recall that way.
    calls = {(r.time, r.parameter) for r in rows if r.code == E.PHASE_CALL_REGISTERED}
    yellows = Counter(r.parameter for r in rows if r.code == E.PHASE_BEGIN_YELLOW)
    recalled_call = Counter(r.parameter for r in rows if r.code == E.PHASE_BEGIN_YELLOW
                            and ((r.time, r.parameter) in calls or (r.time + TICK, r.parameter) in calls))
    logged = {p for p, n in recalled_call.items() if n >= 2 and n >= RECALL_SHARE * yellows[p]}
    return {p for p in phases if (p not in called or p in logged) and p not in structure.phantom}


def _take_calls(events: Iterable[Row], calls: set[int], peds: set[int]) -> None:
    """Registers one tick's vehicle calls (43, dropped by 44) in ``calls`` and its pedestrian calls (45) in ``peds``."""
    for r in events:
        if r.code == E.PHASE_CALL_REGISTERED:
            calls.add(r.parameter)
        elif r.code == E.PHASE_CALL_DROPPED:
            calls.discard(r.parameter)
        elif r.code == E.PED_CALL_REGISTERED:
            peds.add(r.parameter)


def _entered_undemanded(rows: Sequence[Row], structure: Structure, recalled: set[int]) -> set[int]:
    """The phases a ring went on to within its barrier group (no barrier termination, 31, on the tick) after a green
    that ended with no demand the log shows on any phase not green (a green with nothing else to serve rests), and
    with none on the phase itself then or as it begins: demand is a vehicle call registered (43) and not dropped
    (44), a pedestrian call (45) not yet served by a walk (21) or a green, a call on the next tick, a phase read as
    recalled already. Only a recall places demand a log does not register (NTCIP 1202 phaseOptions bit 6, "Min.
    Vehicle Recall - when set to 1 causes recurring demand for vehicle service on the phase when that phase is not in
    its Green interval"; the Indiana enumerations' 44: "Call to service on a phase is cleared by either service of
    the phase or removal of call"); a dual entry phase needs something else to end the green before it. Read once the
    ring has ended a green in the log; not for a coordinated phase (one that logs yield points, 151: the plan serves
    it); only in a log that registers and drops calls."""
    codes = {r.code for r in rows}
    if E.PHASE_CALL_REGISTERED not in codes or E.PHASE_CALL_DROPPED not in codes:
        return set()
    ring_of = {p: r for r in (1, 2) for p in structure.ring(r)}
    registered = {(r.time, r.parameter) for r in rows if r.code in (E.PHASE_CALL_REGISTERED, E.PED_CALL_REGISTERED)}
    yielding = {r.parameter for r in rows if r.code == E.COORD_YIELD_POINT}
    calls: set[int] = set()
    peds: set[int] = set()
    green: set[int] = set()
    unexplained: dict[int, bool] = {}  # ring -> its last green ended with no demand shown on any phase not green
    last_group: dict[int, int] = {}  # ring -> the group of its last green
    seen: set[int] = set()
    for _, tick in itertools.groupby(rows, key=lambda r: r.time):
        events = list(tick)
        _take_calls(events, calls, peds)  # the calls of the tick count for a green it starts
        crossing = any(r.code == E.BARRIER_TERMINATION for r in events)
        for r in events:  # in code order: a walk (21) serves a push after the green (1) it comes with is read
            p = r.parameter
            if r.code == E.PHASE_BEGIN_YELLOW and p in ring_of:
                green.discard(p)
                unexplained[ring_of[p]] = not (calls | peds | recalled) - green - {p}
            elif r.code == E.PED_BEGIN_WALK:
                peds.discard(p)
            if r.code != E.PHASE_BEGIN_GREEN or p not in ring_of:
                continue
            group = structure.group_of(p)
            ring = ring_of[p]
            if (not crossing and unexplained.get(ring) and last_group.get(ring) == group and p not in yielding
                    and p not in calls | peds | recalled and (r.time + TICK, p) not in registered):
                seen.add(p)
            last_group[ring] = group
            green.add(p)
            calls.discard(p)
            peds.discard(p)
    return seen


def _extenders(rows: Sequence[Row], detectors: dict[int, int], recalled: set[int], structure: Structure,
               passage: float | None, out: Inferred) -> dict[int, tuple[int, float]]:
    """A detector that calls nothing the log shows may extend a recalled phase (the emulator logs no call of a
    recalled phase, :mod:`emulator.model.datalogger`), read from the phase's gap-outs: the detector extends the phase
    when its gap-outs past its minimum (3) come one same time after the detector's last off in the green (twice, or
    once ending the green alone, or once at the intersection's ``passage``; on a tie one seen ending a green alone,
    then the time that passage gives), and none past its minimum that ends the green alone comes while the detector
    is on or sooner after its off (a vehicle on it would have held the green); of several detectors so, the one that
    shows it most. A gap-out ends the green alone when the phase its ring served next was called the tick before (a
    vehicle or a pedestrian call, or recalled or coordinated) and every other phase whose yellow begins on its tick
    had gapped out before and waited (:func:`_waiting` within); else it is logged later than the gap ran out and shows
    nothing against the detector: a green with nowhere to go rests in green and ends when a call comes, and one at a
    barrier may have gapped out before and waited for the other ring (NTCIP 1202 phaseOptions bit 11, simultaneous gap
    disable, keeps it gapped out), the detector coming on meanwhile. A gap-out on the tick the phase's minimum or
    walk clearance ends (3, 23) is not past its minimum: its gap may have run out during it. Returns each such
    phase's detector and its gap-outs' time from the last tick with the call: the phase's passage and the detector's
    extension together, which only the green's start, timed by the passage alone, tells apart."""
    gap_outs: dict[int, list[tuple[datetime, datetime | None, datetime, bool]]] = defaultdict(list)  # green, min,
    # gap-out, whether it ended the green alone
    began: dict[int, datetime] = {}
    yellows: dict[datetime, list[int]] = defaultdict(list)  # the phases whose yellow begins on each tick
    for r in rows:
        if r.code == E.PHASE_BEGIN_YELLOW:
            yellows[r.time].append(r.parameter)
    timed: dict[int, list[datetime]] = defaultdict(list)  # each phase's minimums and walks timed (3, 23)
    for r in rows:
        if r.code in (E.PHASE_MIN_COMPLETE, E.PED_BEGIN_SOLID_DONT_WALK):
            timed[r.parameter].append(r.time)
    ring_of = {p: r for r in (1, 2) for p in structure.ring(r)}
    yielding = {r.parameter for r in rows if r.code == E.COORD_YIELD_POINT}  # coordinated: the plan calls them
    starts = {r: [(row.time, row.parameter) for row in rows if row.code == E.PHASE_BEGIN_GREEN
                  and ring_of.get(row.parameter) == r] for r in (1, 2)}
    wants: dict[int, list[tuple[datetime, bool]]] = defaultdict(list)  # each phase's call registered (43), dropped
    for row in rows:
        if row.code in (E.PHASE_CALL_REGISTERED, E.PHASE_CALL_DROPPED):
            wants[row.parameter].append((row.time, row.code == E.PHASE_CALL_REGISTERED))
    pushed = _pushes(rows)

    def _waited(p: int, t: datetime) -> bool:
        """The phase the ring served next after ``p``'s green ending at ``t`` was called before ``t`` (a vehicle call,
        or a pedestrian call not yet served, :func:`_pushes`; or it is recalled, or a coordinated phase, 151, which
        the plan calls): the green ended when its gap ran out, not when a call came to a green resting with nowhere
        to go (under a plan too: one waiting at the barrier for the other ring ends when a phase of its group is
        called)."""
        mine = starts.get(ring_of.get(p, 0), [])
        k = bisect.bisect_right(mine, (t, PHASES + 1))
        if k == len(mine):
            return False
        q = mine[k][1]
        return q in recalled | yielding or _called_at(wants[q], t - TICK) or _called_at(pushed[q], t - TICK)

    def _waiting(q: int, t: datetime) -> bool:
        """``q``, whose yellow begins with another ring's at ``t``, had gapped out before and waited at the barrier
        (simultaneous gap disable, NTCIP 1202 phaseOptions bit 11, the default, keeps it out though a call comes
        back): a phase of its own calls (not recalled) whose call dropped (44) in its green and stayed off longer
        than the intersection's ``passage`` past its minimum and walk (3, 23), all before ``t``. The other ring's
        gap-out then ended both greens alone."""
        mine = [a for a, phase in starts.get(ring_of.get(q, 0), []) if phase == q and a < t]
        if q in recalled or passage is None or not mine:
            return False
        ready = [a for a in timed[q] if mine[-1] <= a <= t]
        if not ready or ready[-1] == t:  # its minimum or walk ended the green
            return False
        calls = wants[q]
        for j in range(bisect.bisect_left(calls, (mine[-1],)), bisect.bisect_right(calls, (t, True))):
            back = min(calls[j + 1][0] if j + 1 < len(calls) else t, t)
            out = max(calls[j][0] + timedelta(seconds=passage), ready[-1])
            if not calls[j][1] and (back - out).total_seconds() > TICK.total_seconds() / 2:
                return True
        return False

    changes: dict[int, list[tuple[datetime, bool]]] = defaultdict(list)  # each detector's on (82) and off (81)
    for r in rows:
        if r.code in (E.DETECTOR_ON, E.DETECTOR_OFF) and detectors.get(r.parameter) == 0:
            changes[r.parameter].append((r.time, r.code == E.DETECTOR_ON))
        elif r.parameter not in recalled:
            continue
        elif r.code == E.PHASE_BEGIN_GREEN:
            began[r.parameter] = r.time
        elif r.code == E.PHASE_GAP_OUT and r.parameter in began:
            alone = _waited(r.parameter, r.time) and all(_waiting(q, r.time) for q in yellows[r.time]
                                                         if q != r.parameter)
            # its minimum, or a walk's clearance, timed last (3, 23; logged on the gap-out's tick after it)
            least = max((a for a in timed[r.parameter] if began[r.parameter] <= a <= r.time), default=None)
            gap_outs[r.parameter].append((began[r.parameter], least, r.time, alone))
    claims: dict[int, list[tuple[int, bool, int, float]]] = defaultdict(list)  # phase -> (times, fits, detector, lag)
    for d, mine in sorted(changes.items()):
        best: tuple[int, int, bool, float] | None = None
        for p, ends in gap_outs.items():
            lags: list[tuple[float | None, bool, bool]] = []  # per gap-out: the time since the detector's last
            for green, least, t, alone in ends:  # off in the green (None: none; -1: on), past the minimum, alone
                k = bisect.bisect_left(mine, (t,)) - 1
                off = mine[k][0] if k >= 0 and mine[k][0] > green else None
                lag = -1.0 if k >= 0 and mine[k][1] else None if off is None else round((t - off).total_seconds(), 1)
                lags.append((lag, least is not None and t > least, alone))
            counts = Counter(lag for lag, past, _ in lags if past and lag is not None and 0 < lag <= 10)
            if not counts:
                continue
            # the most frequent time, on a tie one seen ending a green alone, then the one the intersection's passage
            # gives
            sole = {g for g, past, alone in lags if past and alone}
            lag = max(counts, key=lambda g: (counts[g], g in sole, round(g + TICK.total_seconds(), 1) == passage, -g))
            n, fits = counts[lag], round(lag + TICK.total_seconds(), 1) == passage
            against = sum(1 for g, past, alone in lags if past and alone and g is not None and g < lag)
            shown = n >= 2 or any(alone and past and g == lag for g, past, alone in lags) or fits  # else chance
            if shown and not against and (best is None or (n, fits) > best[1:3]):
                best = (p, n, fits, lag)
        if best is not None:
            claims[best[0]].append((best[1], best[2], d, best[3]))
    found: dict[int, tuple[int, float]] = {}
    for p, mine in sorted(claims.items()):  # the detector that shows it best (the others: chance coincidences)
        n, _, d, lag = max(mine, key=lambda c: (c[0], c[1], -c[2]))
        detectors[d] = p
        found[p] = (d, round(lag + TICK.total_seconds(), 1))
        out.guessed.append(f"detector {d}: extends recalled phase {p} (it registers no call; phase {p} gaps out "
                           f"{lag:g} s after it goes off in the green {n} time(s) past its minimum, never while it "
                           "is on or sooner after it)")
    return found


def _delays(rows: Sequence[Row], detectors: dict[int, int], greens: Mapping[int, list[tuple[datetime, datetime]]],
            out: Inferred) -> dict[int, dict[str, float]]:
    """A detector whose actuations off its phase's green that call nothing on their tick or the next are followed,
    while they last, by that phase's call registration (43) the same time later, for at least :data:`PASSAGE_SEEN`
    of them, for :data:`DELAY_SHARE` of those that lasted that long (a shorter one calls nothing) and twice as often
    as any other time, calls that phase with that detector delay (NTCIP 1202 vehicleDetectorDelay, "the period a
    detector actuation ... shall be delayed when the phase is not Green"). The phase is the detector's own, or for
    one calling nothing on its tick the phase the delay fits best. Returns detector -> ``{"delay": s}``."""
    calls: dict[int, list[datetime]] = defaultdict(list)
    actuations: dict[int, list[tuple[datetime, timedelta]]] = defaultdict(list)
    began: dict[int, datetime] = {}
    for r in rows:
        if r.code == E.PHASE_CALL_REGISTERED:
            calls[r.parameter].append(r.time)
        elif r.code == E.DETECTOR_ON and r.parameter in detectors:
            began[r.parameter] = r.time
        elif r.code == E.DETECTOR_OFF and r.parameter in began:
            t = began.pop(r.parameter)
            actuations[r.parameter].append((t, r.time - t))
    found: dict[int, dict[str, float]] = {}
    for d in sorted(actuations):
        best: tuple[int, float, int, int] | None = None
        for p in [detectors[d]] if detectors[d] else list(calls):
            # Actuations off the phase's green that called nothing on their tick or the next.
            red = [(t, held) for t, held in actuations[d] if not _green_at(greens.get(p, ()), t)
                   and bisect.bisect_right(calls[p], t + TICK) == bisect.bisect_left(calls[p], t)]
            lags: Counter[float] = Counter()
            for t, held in red:
                k = bisect.bisect_right(calls[p], t + TICK)
                if k < len(calls[p]) and calls[p][k] - t <= min(held + TICK, MAX_DELAY):  # while the vehicle is there
                    lags[round((calls[p][k] - t).total_seconds(), 1)] += 1
            if not lags:
                continue
            (lag, n), *others = lags.most_common(2)
            lasted = sum(1 for _, held in red if held.total_seconds() >= lag - 0.05)
            clear = not others or n >= 2 * others[0][1]  # one lag, not a spread of them (a chance of other calls)
            if clear and n >= max(PASSAGE_SEEN, DELAY_SHARE * lasted) and (best is None or n > best[2]):
                best = (p, lag, n, lasted)
        if best is not None:
            p, lag, n, lasted = best
            detectors[d] = p
            found[d] = {"delay": lag}
            out.guessed.append(f"detector {d}: calls phase {p} {lag:g} s after its actuation, off that phase's green "
                               f"({n} of the {lasted} actuations that lasted so long): detector delay {lag:g} s")
    return found


def _green_at(greens: Sequence[tuple[datetime, datetime]], t: datetime) -> bool:
    """``t`` falls in one of a phase's ``greens`` (sorted)."""
    k = bisect.bisect_right(greens, (t, datetime.max)) - 1
    return k >= 0 and greens[k][0] <= t < greens[k][1]


def _holds(rows: Sequence[Row], detectors: Mapping[int, int], greens: Mapping[int, list[tuple[datetime, datetime]]],
           out: Inferred) -> dict[int, dict[str, float]]:
    """Each calling detector whose going off (81), the last of its phase's detectors on, is followed by its phase's
    call dropping (44) the same time later (0.2 s or more: a call dropped on the tick or the next is the actuation's
    own), at least :data:`PASSAGE_SEEN` times and for :data:`DELAY_SHARE` of such offs, or every time it is seen,
    twice at least or on every such off (a phase served seldom shows its detector's extension seldom): on the
    phase's green an
    extension (vehicleDetectorExtend, "extended from the point of termination, when the phase is Green"), off it a
    carryover; one time seen both ways is a carryover. Returns detector -> its timers."""
    mine: dict[int, set[int]] = defaultdict(set)
    for d, p in detectors.items():
        if p:
            mine[p].add(d)
    lags: dict[tuple[int, bool], Counter[float]] = defaultdict(Counter)
    offs: Counter[tuple[int, bool]] = Counter()
    on: set[int] = set()
    pending: dict[int, tuple[int, datetime, bool]] = {}  # phase -> its last detector off, when, whether on green
    for r in rows:
        if r.code in (E.DETECTOR_ON, E.DETECTOR_OFF) and detectors.get(r.parameter):
            p = detectors[r.parameter]
            (on.add if r.code == E.DETECTOR_ON else on.discard)(r.parameter)
            pending.pop(p, None)
            if r.code == E.DETECTOR_OFF and not on & mine[p]:
                green = _green_at(greens.get(p, ()), r.time)
                pending[p] = (r.parameter, r.time, green)
                offs[(r.parameter, green)] += 1
        elif r.code == E.PHASE_CALL_DROPPED and r.parameter in pending:
            d, t, green = pending.pop(r.parameter)
            if r.time - t <= MAX_DELAY:
                lags[(d, green)][round((r.time - t).total_seconds(), 1)] += 1
    found: dict[int, dict[str, float]] = {}
    for (d, green), counts in sorted(lags.items()):
        lag, n = counts.most_common(1)[0]
        # every off seen so is followed by the drop that time later (twice at least, or every off of the detector)
        alone = len(counts) == 1 and (n >= 2 or n == offs[(d, green)])
        if lag < 0.2 or (n < max(PASSAGE_SEEN, DELAY_SHARE * offs[(d, green)]) and not alone):
            continue
        timer = "extend" if green else "carryover"
        found.setdefault(d, {})[timer] = lag
        out.guessed.append(f"detector {d}: its phase {detectors[d]}'s call drops {lag:g} s after it goes off "
                           f"{'on' if green else 'off'} that phase's green ({n} of {offs[(d, green)]}): {timer} "
                           f"{lag:g} s")
    for timers in found.values():
        if timers.get("extend") == timers.get("carryover"):
            del timers["extend"]  # the call is held as long whatever the phase shows: a carryover alone
    return found


def _locks(rows: Sequence[Row], detectors: Mapping[int, int], greens: Mapping[int, list[tuple[datetime, datetime]]],
           out: Inferred) -> list[int]:
    """The calling detectors whose actuations off their phase's green register its call (43, on their tick or the
    next) and hold it (no 44) after they go, no detector of the phase on, until the phase's next actuation or green,
    at least :data:`PASSAGE_SEEN` times and nine times in ten, where the log shows the phase's calls dropping: yellow
    lock call (NTCIP 1202 vehicleDetectorOptions bit 2,
    "the detector will lock a call to the assigned phase if an actuation occurs while the phase is not timing
    Green")."""
    spans: dict[int, list[tuple[datetime, datetime]]] = defaultdict(list)
    began: dict[int, datetime] = {}
    registered: dict[int, set[datetime]] = defaultdict(set)
    drops: dict[int, list[datetime]] = defaultdict(list)
    for r in rows:
        if r.code == E.DETECTOR_ON and detectors.get(r.parameter):
            began[r.parameter] = r.time
        elif r.code == E.DETECTOR_OFF and r.parameter in began:
            spans[r.parameter].append((began.pop(r.parameter), r.time))
        elif r.code == E.PHASE_CALL_REGISTERED:
            registered[r.parameter].add(r.time)
        elif r.code == E.PHASE_CALL_DROPPED:
            drops[r.parameter].append(r.time)
    seen: dict[int, Counter[bool]] = defaultdict(Counter)
    for d, mine in spans.items():
        p = detectors[d]
        starts = [begin for begin, _ in greens.get(p, ())]
        theirs = sorted(span for q, spans_q in spans.items() if detectors[q] == p for span in spans_q)
        ons = [a for a, _ in theirs]
        for on, off in mine:
            k = bisect.bisect_right(starts, on)
            if _green_at(greens.get(p, ()), on) or k == len(starts) or not drops[p] \
                    or not registered[p] & {on, on + TICK} or any(a <= off < b for a, b in theirs if a != on):
                continue
            n = bisect.bisect_right(ons, off)
            until = min(starts[k], ons[n]) if n < len(ons) else starts[k]  # its phase's next actuation or green
            if off >= until:
                continue  # the vehicle was still there
            j = bisect.bisect_right(drops[p], on + TICK)
            seen[d][not (j < len(drops[p]) and drops[p][j] < until)] += 1
    locking = [d for d, n in sorted(seen.items()) if n[True] >= PASSAGE_SEEN and n[True] >= RECALL_SHARE * n.total()]
    for d in locking:
        out.read.append(f"detector {d}: locks its call off phase {detectors[d]}'s green (held after it goes, until "
                        f"that phase's next actuation or green, {seen[d][True]} of {seen[d].total()} times): yellow "
                        "lock call")
    return locking


def _backings(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]], structure: Structure,
              timing: Mapping[int, dict[str, Any]], out: Inferred) -> None:
    """A ring that ended a green and next began an earlier phase of its barrier group's order while the other ring
    timed in that group (a green of it on after the ring's green ended and begun before the earlier phase's, not with
    it: both rings clearing and starting the group again together is no backing) backed into it: conditional service
    (NTCIP 1202 phaseOptions bit 14) on the phase it backed from when a call across the barrier was on as its green
    ended (registered, 43, and not dropped, 44; or a pedestrian call, 45, not yet served, :func:`_pushes`), Naztec's
    backing (``backup_prevent = false``) otherwise: Naztec's controllers back "when the cross street phases ... are
    skipped" (TecNote 3013), which a waiting push is not. The emulator backs only where set so."""
    ring_of = {p: r for r in (1, 2) for p in structure.ring(r)}
    order = {p: i for r in (1, 2) for i, p in enumerate(structure.ring(r))}
    group_of = {p: structure.group_of(p) for p in ring_of}
    starts = sorted((a, b, p) for p, mine in greens.items() for a, b in mine if p in ring_of)
    by_ring = {r: [(a, b, p) for a, b, p in starts if ring_of[p] == r] for r in (1, 2)}
    calls: dict[int, list[tuple[datetime, bool]]] = defaultdict(list)  # each phase's call registered (43), dropped (44)
    for r in rows:
        if r.code in (E.PHASE_CALL_REGISTERED, E.PHASE_CALL_DROPPED) and r.parameter in ring_of:
            calls[r.parameter].append((r.time, r.code == E.PHASE_CALL_REGISTERED))
    pushed = _pushes(rows)
    seen: dict[int, Counter[str]] = defaultdict(Counter)
    previous: dict[int, tuple[datetime, int]] = {}  # ring -> the end of its last green, its phase
    for begin, end, q in starts:
        r = ring_of[q]
        if r in previous:
            ended, p = previous[r]
            other = by_ring[3 - r]
            k = bisect.bisect_left(other, (ended,)) - 1  # the other ring's last green begun before the yellow
            timing_on = any(a < begin and b > ended and group_of[x] == group_of[p]
                            for a, b, x in other[max(k, 0):bisect.bisect_left(other, (begin,))])
            if group_of[p] == group_of[q] and order[q] < order[p] and timing_on:
                waiting = any(group_of[x] != group_of[p]
                              and (_called_at(calls[x], ended) or _called_at(pushed[x], ended)) for x in ring_of)
                seen[p]["conditional service" if waiting else "backing"] += 1
        previous[r] = (end, q)
    for p, kinds in sorted(seen.items()):
        if kinds["conditional service"]:
            timing[p]["conditional_service"] = True
        if kinds["backing"]:
            timing[p]["backup_prevent"] = False
        out.read.append(f"phase {p}: its ring backed into an earlier phase of its group "
                        + ", ".join(f"{n} time(s) as {kind}" for kind, n in sorted(kinds.items()))
                        + " (conditional service: a call was on across the barrier; backing: none was)")


def _reextensions(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]], structure: Structure,
                  timing: Mapping[int, dict[str, Any]], out: Inferred) -> None:
    """Greens of the two rings that end together by gap-out or max-out (4 or 5, and 8, on one tick) as the rings cross
    a barrier, each having gapped out (its call off, 44, a passage since it dropped, past its minimum) before (not
    forced off by a plan; a green on max recall never gaps out): when they end more than a second past
    where both had, the one that gapped out first went back to extending when its call came back (43), waiting at
    the barrier for the other ring, which only a phase without simultaneous gap disable does (NTCIP 1202
    phaseOptions bit 11, "in multi-ring configurations when set to 1 disables a gapped out phase from reverting to
    the extensible portion"); when they end where the later gapped out although the first's call came back, that
    one has it. A phase seen going back :data:`PASSAGE_SEEN` times and more often than not has
    ``simultaneous_gap_disable = false``, and so has a phase seen fewer times either way beside which such a phase
    of the other ring waits at the barriers of their group. Logs without call events (43/44) show neither."""
    ring_of = {p: r for r in (1, 2) for p in structure.ring(r) if p not in structure.phantom}
    calls: dict[int, list[tuple[datetime, bool]]] = defaultdict(list)
    dont_walks: dict[int, list[datetime]] = defaultdict(list)  # the end of each pedestrian clearance (23)
    for r in rows:
        if r.code in (E.PHASE_CALL_REGISTERED, E.PHASE_CALL_DROPPED) and r.parameter in ring_of:
            calls[r.parameter].append((r.time, r.code == E.PHASE_CALL_REGISTERED))
        elif r.code == E.PED_BEGIN_SOLID_DONT_WALK:
            dont_walks[r.parameter].append(r.time)
    unforced = {(r.time, r.parameter) for r in rows if r.code in (E.PHASE_GAP_OUT, E.PHASE_MAX_OUT)}
    ending: dict[datetime, list[tuple[int, datetime]]] = defaultdict(list)  # begin yellow -> (phase, begin green)
    for p, mine in greens.items():
        for begin, end in mine:
            if p in ring_of:
                ending[end].append((p, begin))
    starts = sorted((begin, p) for p, mine in greens.items() for begin, _ in mine if p in ring_of)
    went_back: Counter[int] = Counter()
    stayed: Counter[int] = Counter()
    for end, pair in ending.items():
        k = bisect.bisect_right(starts, (end, PHASES + 1))
        if len(pair) != 2 or {ring_of[p] for p, _ in pair} != {1, 2} or k == len(starts) \
                or structure.group_of(starts[k][1]) == structure.group_of(pair[0][0]) \
                or any((end, p) not in unforced for p, _ in pair):
            continue
        gapped = {p: _gapped(calls[p], begin, end, timing[p], dont_walks[p]) for p, begin in pair}
        if not calls or None in gapped.values():
            continue
        first = min(gapped, key=gapped.__getitem__)
        if end - max(gapped.values()) > timedelta(seconds=1):
            went_back[first] += 1
        elif any(gapped[first] < t < end and on for t, on in calls[first]):
            stayed[first] += 1
    own = {p for p in ring_of if went_back[p] >= PASSAGE_SEEN and went_back[p] > stayed[p]}
    decided = {p for p in ring_of if went_back[p] + stayed[p] >= PASSAGE_SEEN}
    partners = {p for p in ring_of.keys() - decided
                if any(ring_of[q] != ring_of[p] and structure.group_of(q) == structure.group_of(p) for q in own)}
    for p in own | partners:
        timing[p]["simultaneous_gap_disable"] = False
    if own:
        out.read.append("no simultaneous gap disable (NTCIP 1202 phaseOptions bit 11 clear): " + ", ".join(
            f"phase {p} went back to extending at the barrier after it had gapped out {went_back[p]} time(s), "
            f"stayed gapped out {stayed[p]}" for p in sorted(own)))
    if partners:
        out.guessed.append(f"phase(s) {', '.join(map(str, sorted(partners)))}: no simultaneous gap disable, as the "
                           "other ring's phase(s) of their barrier group (seen fewer than "
                           f"{PASSAGE_SEEN} times either way on them)")


def _gapped(changes: Sequence[tuple[datetime, bool]], begin: datetime, end: datetime, timing: Mapping[str, Any],
            dont_walks: Sequence[datetime]) -> datetime | None:
    """When a green from ``begin`` to ``end`` first gapped out: the first time past its minimum and the end of a
    pedestrian clearance it served (23, ``dont_walks``) its call (43/44, ``changes`` time-sorted) was off a passage
    since it dropped (None: not before ``end``, or not to be told: a green on max recall, or one the log shows no
    call change in, as for a recalled phase whose calls a controller does not log)."""
    k = bisect.bisect_right(changes, (begin, True))
    if timing.get("recall") == "max" or k == len(changes) or changes[k][0] >= end:
        return None
    on, since = _called_at(changes, begin), begin
    served = [t for t in dont_walks if begin < t <= end]
    earliest = max([begin + timedelta(seconds=timing["min_green"]), *served])
    for t, registered in [*changes[k:], (end, None)]:
        if not on and (out := max(since + timedelta(seconds=timing["passage"]), earliest)) < min(t, end):
            return out
        if registered is None or t >= end:
            return None
        on, since = registered, t if not registered else since
    return None


def _called_at(changes: Sequence[tuple[datetime, bool]], t: datetime) -> bool:
    """The phase's call is on at ``t``: its last change by then (registered, 43, or dropped, 44; time-sorted) is on."""
    k = bisect.bisect_right(changes, (t, True)) - 1
    return k >= 0 and changes[k][1]


def _pushes(rows: Sequence[Row]) -> dict[int, list[tuple[datetime, bool]]]:
    """Each phase's pedestrian call (45) on until served, as :func:`_called_at` reads it: by a walk (21), or for a
    phase that never walks by its green (1). A 45 on the tick after the service is the push that service latched (the
    emulator logs it a tick late), served already."""
    walking = {r.parameter for r in rows if r.code == E.PED_BEGIN_WALK}
    pushed: dict[int, list[tuple[datetime, bool]]] = defaultdict(list)
    served: dict[int, datetime] = {}
    for r in rows:
        if r.code == (E.PED_BEGIN_WALK if r.parameter in walking else E.PHASE_BEGIN_GREEN):
            served[r.parameter] = r.time
            pushed[r.parameter].append((r.time, False))
        elif r.code == E.PED_CALL_REGISTERED and served.get(r.parameter, datetime.min) < r.time - TICK:
            pushed[r.parameter].append((r.time, True))
    return pushed


def _recycles(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]],
              timing: Mapping[int, dict[str, Any]], out: Inferred) -> None:
    """A walk (21) that began within a green of its phase already running (a tick or more after the begin green):
    pedestrian recycle on that phase."""
    seen: Counter[int] = Counter()
    for r in rows:
        if r.code == E.PED_BEGIN_WALK and r.parameter in timing and "walk" in timing[r.parameter]:
            mine = greens.get(r.parameter, [])
            k = bisect.bisect_left(mine, (r.time,)) - 1  # the phase's last green begun before the walk
            if k >= 0 and mine[k][1] >= r.time:
                seen[r.parameter] += 1
    for p, n in sorted(seen.items()):
        timing[p]["ped_recycle"] = True
        out.read.append(f"phase {p}: pedestrian recycle ({n} walk(s) began within a green already running)")


def _dual_entries(rows: Sequence[Row], structure: Structure, recalled: set[int]) -> list[int]:
    """The phases a ring entered as the rings crossed a barrier though neither its demand then nor its demand as the
    new group began made it go there: dual entry (NTCIP 1202 v03 phaseOptions bit 10, "Dual Entry Phase - in
    multi-ring configurations when set to 1 causes the phase to become active upon entry into a concurrency group
    (crossing a barrier) when no calls exist in its ring within its concurrency group"). The rings commit to the new
    group as the last green of the old one ends (NTCIP 1202 PhaseNext, "determined at the end of the green interval
    of the terminating phase"), the last begin yellow (8) before the group's first green: a ring with demand there
    goes to it; one without takes its dual entry phase then, or else the nearest phase with demand in its order as
    the group begins (the emulator's sequencer). So the entry shows a dual entry when the ring had no demand in the
    group at the yellow and the phase it entered, at the barrier termination (31), is not its nearest with demand
    then. Demand: a vehicle call registered (43) and not dropped (44), a pedestrian call (45) not yet served (by a
    walk, 21, or for a phase that never walks by its green, 1), a recall (a phase the log shows served without its
    calls); for the nearest, the calls registered on the tick, and a push's 45 on the next too (the emulator logs it
    on the tick after the green it latched for began; a vehicle call, 43, on the next tick is a vehicle that came
    after the green began, which did not choose it). Read once seen: nothing else makes such an entry. Only in a log
    that registers and drops calls: one without them shows no demand at all."""
    codes = {r.code for r in rows}
    if E.PHASE_CALL_REGISTERED not in codes or E.PHASE_CALL_DROPPED not in codes:
        return []
    ring_of = {p: r for r in (1, 2) for p in structure.ring(r)}
    group_of = {p: structure.group_of(p) for p in ring_of}
    walking = {r.parameter for r in rows if r.code == E.PED_BEGIN_WALK}
    pushed = {(r.time, r.parameter) for r in rows if r.code == E.PED_CALL_REGISTERED}
    calls: set[int] = set()
    peds: set[int] = set()
    committed: set[int] | None = None  # the phases with demand at the last begin yellow
    last_group: dict[int, int] = {}  # ring -> the group of its last green
    seen: set[int] = set()
    for _, tick in itertools.groupby(rows, key=lambda r: r.time):
        events = list(tick)
        _take_calls(events, calls, peds)  # the tick's calls count for a green it starts (read before the rings move)
        crossing = committed is not None and any(r.code == E.BARRIER_TERMINATION for r in events)
        for r in events:
            p = r.parameter
            if r.code != E.PHASE_BEGIN_GREEN or p not in ring_of:
                continue
            ring = ring_of[p]
            if crossing and last_group.get(ring, group_of[p]) != group_of[p]:
                mine = [q for q in structure.ring(ring) if group_of[q] == group_of[p]]
                nearest = next((q for q in mine if q in calls | peds | recalled
                                or (r.time + TICK, q) in pushed), None)
                if not (committed | recalled) & set(mine) and nearest != p:
                    seen.add(p)
            last_group[ring] = group_of[p]
        for r in events:
            if r.code == (E.PED_BEGIN_WALK if r.parameter in walking else E.PHASE_BEGIN_GREEN):
                peds.discard(r.parameter)
        if any(r.code == E.PHASE_BEGIN_GREEN for r in events):
            committed = None  # a ring entering the group later was called there
        if any(r.code == E.PHASE_BEGIN_YELLOW for r in events):
            committed = calls | peds
    return sorted(seen)


def _recall_kind(rows: Sequence[Row], p: int) -> tuple[str, Counter[int]]:
    """A recalled phase's recall, maximum when its greens end by force-off or max-out more often than by gap-out
    (NTCIP 1202 phaseOptions: Max Vehicle Recall times the green to its maximum), else minimum; and how they end."""
    ends = Counter(r.code for r in rows if r.parameter == p and r.code in (E.PHASE_GAP_OUT, E.PHASE_MAX_OUT,
                                                                           E.PHASE_FORCE_OFF))
    return "max" if ends[E.PHASE_GAP_OUT] < ends[E.PHASE_MAX_OUT] + ends[E.PHASE_FORCE_OFF] else "min", ends


def _recall(rows: Sequence[Row], p: int, timing: dict[str, Any], out: Inferred) -> None:
    """A phase served without a call the log registers is recalled (a pretimed plan's phases, a recall, or detectors
    the log does not record): :func:`_recall_kind`."""
    timing["recall"], ends = _recall_kind(rows, p)
    out.guessed.append(f"phase {p}: {timing['recall']} recall (served where the log shows no vehicle call of it "
                       f"live; its greens end by gap-out {ends[E.PHASE_GAP_OUT]} times, by max-out or force-off "
                       f"{ends[E.PHASE_MAX_OUT] + ends[E.PHASE_FORCE_OFF]})")


def _max_recall_maximum(rows: Sequence[Row], p: int, timing: dict[str, Any], out: Inferred) -> None:
    """A phase on max recall times its maximum from its begin green, not from its phase check: NTCIP 1202
    phaseMaximum1's timer is "held reset unless Max Vehicle Recall is enabled for this phase" (or a serviceable
    conflicting call waits), so the shortest of its greens that maxed out, timed from their start, is its maximum."""
    maxed = _max_timings(rows, p, from_check=False)
    if not maxed:
        return
    timing["maxed"] = min(maxed)
    timing["max_green"] = _within(p, "max_green", max(timing["min_green"], math.ceil(min(maxed) - 1e-9)), 1,
                                  config_mod.phase_time_range("max_green")[1], out)
    out.read.append(f"phase {p}: max green {timing['max_green']:g} s (on max recall: its max-outs timed from their "
                    "begin green)")


def _ped_recalls(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]],
                 timing: Mapping[int, dict[str, Any]], pushes: Mapping[int, int],
                 coordination: dict[str, Any] | None, out: Inferred) -> None:
    """Pedestrian recall (NTCIP 1202 phaseOptions bit 8, "a recurring pedestrian demand"): a phase with a walk whose
    every green began with one (21 on its begin green, at least :data:`PED_RECALLED` greens), while the log
    registers no pedestrian call of it (45) and no push button calls it. Under a plan it goes into the pattern's
    split modes (splitMode pedestrianRecall), beside the phase's own vehicle recall; free, it is the phase's recall
    where it has none other (the config holds one recall a phase)."""
    called = {r.parameter for r in rows if r.code == E.PED_CALL_REGISTERED} | set(pushes.values())
    for p in sorted(timing):
        starts = [a for a, _ in greens.get(p, [])]
        if "walk" not in timing[p] or p in called or len(starts) < PED_RECALLED \
                or not set(starts) <= _walk_starts(rows, p):
            continue
        why = f"every one of its {len(starts)} greens began a walk, and the log registers no pedestrian call of it"
        if coordination is not None:
            coordination.setdefault("modes", {})[p] = "ped_recall"
            out.guessed.append(f"phase {p}: pedestrian recall in the pattern (splitMode pedestrianRecall: {why})")
        elif "recall" not in timing[p]:
            timing[p]["recall"] = "ped"
            out.guessed.append(f"phase {p}: ped recall ({why})")
        else:
            out.guessed.append(f"phase {p}: no pedestrian recall written beside its {timing[p]['recall']} recall (the "
                               f"config holds one recall a phase; {why})")


def _check_numbers(rows: Iterable[Row]) -> None:
    """Refuse an event whose parameter cannot be what it names (phase 0, overlap 0...), naming the first."""
    for r in rows:
        kind = NAMED.get(r.code)
        if kind is None:
            continue
        top = PHASES if kind == "a phase" else None
        if r.parameter < 1 or (top is not None and r.parameter > top):
            allowed = f"1-{top}" if top else "1 and up"
            raise FieldLogError(f"{_event(r)}: {r.parameter} is not {kind} number; allowed: {allowed}")


def _unbarred(rows: Sequence[Row]) -> set[frozenset[int]]:
    """Pairs of phases that began green one after the other with no barrier termination (31) logged at or before
    the second: one barrier group (the data logger logs 31 on the tick "all active phases become inactive in the
    ring and cross barrier phases are next"). None when the log has no 31 at all (a controller that does not log
    it)."""
    if not any(r.code == E.BARRIER_TERMINATION for r in rows):
        return set()
    out: set[frozenset[int]] = set()
    last: list[int] = []
    crossed = False
    tick: datetime | None = None
    now: list[int] = []
    for r in rows:
        if r.time != tick:
            if now:
                if not crossed:
                    out.update(frozenset((a, b)) for a in last for b in now if a != b)
                last, now, crossed = now, [], False
            tick = r.time
        if r.code == E.BARRIER_TERMINATION:
            crossed = True
        elif r.code == E.PHASE_BEGIN_GREEN:
            now.append(r.parameter)
    if now and not crossed:
        out.update(frozenset((a, b)) for a in last for b in now if a != b)
    return out


def _structure(phases: Sequence[int], greens: Mapping[int, list[tuple[datetime, datetime]]],
               spans: Mapping[int, list[tuple[datetime, datetime]]], out: Inferred,
               unbarred: set[frozenset[int]] = frozenset()) -> Structure:
    concurrent = _concurrent(spans)
    linked = concurrent | unbarred
    groups: list[set[int]] = []
    for p in phases:
        touching = [g for g in groups if any(frozenset((p, q)) in linked for q in g)]
        groups = [g for g in groups if g not in touching] + [{p}.union(*touching)]
    ordered = sorted((sorted(g) for g in groups), key=min)
    ring_of: dict[int, int] = {}
    for group in ordered:
        ring = {p: _nema_ring(p) for p in group}
        if any(frozenset((p, q)) in concurrent for p, q in itertools.combinations(group, 2) if ring[p] == ring[q]):
            ring = _two_colour(group, concurrent)
            out.guessed.append(f"rings of phases {group}: split by which are concurrent, not NEMA's numbering")
        ring_of |= ring
    group_of = {p: g for g, group in enumerate(ordered) for p in group}
    starts = sorted((t0, p) for p in phases for t0, _ in greens[p])
    order = {r: [_service_order([p for p in group if ring_of[p] == r], _successions(starts, r, ring_of, group_of))
                 for group in ordered] for r in (1, 2)}
    structure = Structure(ordered, order)
    for r in (1, 2):
        for g, mine in enumerate(order[r]):
            if not mine:
                free = _phantom(structure, r, g, order[3 - r][g][0])
                out.guessed.append(f"phase {free}: not in the log; added to ring {r} beside {structure.phantom[free]} "
                                   "(NTCIP's split table needs a phase of each ring in each barrier group; nothing "
                                   "calls it, so it is skipped)")
    out.read.append(f"rings: {structure.ring(1)} and {structure.ring(2)}; barrier groups: {structure.barriers}")
    return structure


def _phantom(structure: Structure, r: int, g: int, twin: int) -> int:
    """Add to ring ``r``'s barrier group ``g`` (last) a phase the log never shows, timed as ``twin``: its number."""
    used = set(structure.ring(1) + structure.ring(2))
    base = 0 if r == 1 else 4
    # NEMA's numbering first: in ring 1 the second barrier group's through is 4, its left 3, and so on
    free = next((n for n in (base + 2 * g + 2, base + 2 * g + 1, *range(1, PHASES + 1))
                 if n not in used and n <= PHASES), None)
    if free is None:
        raise FieldLogError(f"the log's phases use every phase number 1-{PHASES}: none is left for ring {r} beside "
                            f"phase {twin}, where NTCIP's split table needs one; allowed: a log of fewer phases")
    structure.order[r][g].append(free)
    structure.phantom[free] = twin
    return free


def _concurrent(spans: Mapping[int, Sequence[tuple[datetime, datetime]]]) -> set[frozenset[int]]:
    """The pairs of phases that were on at the same time (a sweep over the spans in time order)."""
    out: set[frozenset[int]] = set()
    on: list[tuple[datetime, int]] = []
    for begin, end, p in sorted((a, b, p) for p, mine in spans.items() for a, b in mine):
        on = [(until, q) for until, q in on if until > begin]
        out.update(frozenset((p, q)) for _, q in on if q != p)
        on.append((end, p))
    return out


def _nema_ring(p: int) -> int:
    return 1 if (p - 1) % 8 < 4 else 2


def _two_colour(group: Sequence[int], concurrent: set[frozenset[int]]) -> dict[int, int]:
    """Rings for a group by concurrency: a phase goes to the ring none of whose phases it is never concurrent with."""
    colour = {group[0]: 1}
    for p in group[1:]:
        apart = {colour[q] for q in colour if frozenset((p, q)) not in concurrent}
        colour[p] = min(apart) if apart else 2
    return colour


def _successions(starts: Sequence[tuple[datetime, int]], ring: int, ring_of: Mapping[int, int],
                 group_of: Mapping[int, int]) -> Counter[tuple[int, int]]:
    """How often each phase of ``ring`` began green right after another of its barrier group, with no phase of
    another group begun in between (in either ring: a ring with nothing to serve across a barrier crosses it without
    a green of its own)."""
    out: Counter[tuple[int, int]] = Counter()
    last: int | None = None
    for _, p in starts:
        if ring_of[p] == ring:
            if last is not None and last != p and group_of[last] == group_of[p]:
                out[(last, p)] += 1
            last = p
        elif last is not None and group_of[p] != group_of[last]:
            last = None
    return out


def _service_order(mine: Sequence[int], follows: Mapping[tuple[int, int], int]) -> list[int]:
    """The order a ring serves its phases ``mine`` of one barrier group, from how often each followed another
    (``follows``; see the module's header for the rule and what it guarantees)."""
    order: list[int] = []
    left = sorted(mine)
    while left:
        inward = {p: sum(follows.get((q, p), 0) for q in left) for p in left}
        first = [p for p in left if not inward[p]]
        if not first:  # a cycle: the phase that most often leads rather than follows
            surplus = {p: sum(follows.get((p, q), 0) for q in left) - inward[p] for p in left}
            first = [p for p in left if surplus[p] == max(surplus.values())]
        before = order[-1] if order else None
        order.append(max(first, key=lambda p: (follows.get((before, p), 0), -p)))
        left.remove(order[-1])
    return order


def _timing(rows: Sequence[Row], p: int, greens: Sequence[tuple[datetime, datetime]], out: Inferred,
            shared_min: float | None = None) -> dict[str, Any]:
    """The phase's timings (see the module's header); ``shared_min``: the intersection's most frequent minimum green,
    for a phase that shows none of its own."""
    t: dict[str, Any] = {}
    found = {"yellow": _mode(_durations(rows, p, E.PHASE_BEGIN_YELLOW, E.PHASE_END_YELLOW)),
             "red_clear": _mode(_durations(rows, p, E.PHASE_BEGIN_RED_CLEARANCE, E.PHASE_END_RED_CLEARANCE)),
             "min_green": _mode(_minimums(rows, p))}
    for key, default in (("yellow", 4.0), ("red_clear", 1.0), ("min_green", shared_min or 5)):
        if found[key] is None:
            why = ("every green served a walk, whose timing is then the minimum" if key == "min_green" and
                   _durations(rows, p, E.PHASE_BEGIN_GREEN, E.PHASE_MIN_COMPLETE) else "its events are not in the log")
            whose = "the intersection's most frequent, " if key == "min_green" and shared_min else ""
            out.guessed.append(f"phase {p}: {key} {default:g} ({whose}{why})")
        t[key] = found[key] if found[key] is not None else default
    # What NTCIP 1202's phase table carries (phaseYellowChange "NEMA range: 3.0-25.5 sec", ...), and what the config
    # asks beyond it: a red clearance of a tenth at least, greens of a second, walk and clearance within the maximum.
    carried = config_mod.phase_time_range
    t["yellow"] = _within(p, "yellow", t["yellow"], *carried("yellow"), out)
    t["red_clear"] = _within(p, "red_clear", t["red_clear"], max(0.1, carried("red_clear")[0]), carried("red_clear")[1],
                             out)
    t["min_green"] = _within(p, "min_green", math.ceil(t["min_green"] - 1e-9), 1, carried("min_green")[1], out)
    walk = _mode(_durations(rows, p, E.PED_BEGIN_WALK, E.PED_BEGIN_CLEARANCE))
    ped_clear = _mode(_durations(rows, p, E.PED_BEGIN_CLEARANCE, E.PED_BEGIN_SOLID_DONT_WALK))
    top = carried("max_green")[1]
    if walk and ped_clear:
        t["walk"] = _within(p, "walk", math.ceil(walk), 1, top - 1, out)
        t["ped_clear"] = _within(p, "ped_clear", math.ceil(ped_clear), 1, top - t["walk"], out)
        # A walk of whole seconds (phaseWalk's unit) still ends with its clearance within the greens that served it:
        # an Econolite under a plan cuts its walks so that their clearance ends at the force-off (phase 4 of
        # ECON_10.204.9.227: 14.8 s walks, 11 s clearances, 25.8 s greens), and a pattern serves a walk only where
        # it fits by the force-off point.
        walks = _walk_starts(rows, p)
        served = [(b - a).total_seconds() for a, b in greens if a in walks]
        if served and t["walk"] + t["ped_clear"] > min(served) and min(served) - t["ped_clear"] >= 1:
            t["walk"] = math.floor(min(served) - t["ped_clear"])
    # The maximum: the shortest green that maxed out (max-out, 5, on its end: no green maxes out before its maximum,
    # and one whose max timer started with it, by a call waiting or max recall, maxes out at it), else the longest;
    # timed from its phase check (2) where the log has one within the green: "Set when a conflicting call is
    # registered against the active phase. (Marks beginning of MAX timing)" (the Indiana enumerations,
    # utahudot/udot-atspm Atspm/Data/Enums/IndianaEnumerations.cs). The MaxTime of 638572533917628534.xml maxes 2 out
    # 55.6 s into its green, 46.2 s after its phase check.
    maxed = _max_timings(rows, p)
    longest = _longest_timed(rows, p, greens)
    if maxed:
        longest = t["maxed"] = min(maxed)
    t["max_green"] = _within(p, "max_green", max(t["min_green"], t.get("walk", 0) + t.get("ped_clear", 0),
                                                 math.ceil(longest - 1e-9)), 1, top, out)
    return t


def _longest_timed(rows: Sequence[Row], p: int, greens: Sequence[tuple[datetime, datetime]]) -> float:
    """The longest time a green of ``p`` ran with its maximum timing and ended by itself: from the first conflicting
    call registered against it (phase check, 2: "MAX timing begins") to its end (no other phase's yellow on the
    tick), which no maximum is shorter than. A green with no conflicting call (resting, or stretched by a recycled
    walk, which waits for no maximum then) bounds nothing, nor one that ends with the other ring's at a barrier: it
    may have maxed out and waited there. In a log without phase checks, the longest green."""
    checks = [r.time for r in rows if r.code == E.PHASE_CHECK and r.parameter == p]
    if not checks:
        return max(((b - a).total_seconds() for a, b in greens), default=0.0)
    yellows = Counter(r.time for r in rows if r.code == E.PHASE_BEGIN_YELLOW)
    longest = 0.0
    for a, b in greens:
        k = bisect.bisect_left(checks, a)
        if k < len(checks) and checks[k] < b and yellows[b] == 1:
            longest = max(longest, (b - checks[k]).total_seconds())
    return longest


def _within(p: int, key: str, value: Any, low: float, high: float, out: Inferred) -> Any:
    """``value`` brought inside ``low``..``high`` (saying so when it was not)."""
    if low <= value <= high:
        return value
    inside = min(max(value, low), high)
    out.guessed.append(f"phase {p}: {key} {inside:g} s (the log's {value:g} s is outside what the config holds, "
                       f"{low:g}-{high:g} s)")
    return inside


def _max_timings(rows: Sequence[Row], p: int, from_check: bool = True) -> list[float]:
    """Seconds each green of ``p`` that maxed out (5) timed its maximum: from its phase check (2) within it when
    ``from_check``, else from its begin green (1); a green running as the log begins counts from its phase check."""
    out, since, checked, began = [], None, False, False
    for r in rows:
        if r.parameter != p:
            continue
        if r.code == E.PHASE_BEGIN_GREEN:
            since, checked, began = r.time, False, True
        elif r.code == E.PHASE_CHECK and ((since is None and not began) or (from_check and since is not None)) \
                and not checked:
            since, checked = r.time, True
        elif r.code == E.PHASE_MAX_OUT and since is not None:
            out.append(round((r.time - since).total_seconds(), 1))
            since = None
        elif r.code == E.PHASE_BEGIN_YELLOW:
            since = None
    return out


def _walk_starts(rows: Sequence[Row], p: int) -> set[datetime]:
    """When walks of ``p`` began (21)."""
    return {r.time for r in rows if r.code == E.PED_BEGIN_WALK and r.parameter == p}


def _minimums(rows: Sequence[Row], p: int) -> list[float]:
    """Begin green to min complete of the greens of ``p`` that served no walk (a walk's timing is its minimum)."""
    walks = _walk_starts(rows, p)
    out, since = [], None
    for r in rows:
        if r.parameter != p:
            continue
        if r.code == E.PHASE_BEGIN_GREEN:
            since = None if r.time in walks else r.time
        elif r.code == E.PHASE_MIN_COMPLETE and since is not None:
            out.append(round((r.time - since).total_seconds(), 1))
            since = None
    return out


def _detector_phases(rows: Sequence[Row], on: int, call: int, phases: Sequence[int]) -> dict[int, int]:
    """Detector -> the phase whose calls it registers (0: none), by coincidence of its on events with call events:
    a call registered at a tick is the call of the detectors that went on the log's own lag before it (an Econolite
    logs the call on its actuation's tick, a MaxTime on the next: the lag most of its calls show), else of those
    that went on at the other, so a detector going on a tick before another that places the call is not given it."""
    calls = {(r.time, r.parameter) for r in rows if r.code == call and r.parameter in phases}
    seen: Counter[int] = Counter()
    ons: dict[datetime, set[int]] = defaultdict(set)
    for r in rows:
        if r.code == on:
            seen[r.parameter] += 1
            ons[r.time].add(r.parameter)
    lags = Counter(lag for t, _ in calls for lag in (timedelta(0), TICK) if t - lag in ons)
    first, then = sorted((timedelta(0), TICK), key=lambda lag: -lags[lag])
    hits: Counter[tuple[int, int]] = Counter()
    for t, p in calls:
        for d in ons.get(t - first) or ons.get(t - then, ()):
            hits[(d, p)] += 1
    out = {}
    for d, n in seen.items():
        best = max(phases, key=lambda p: hits[(d, p)])
        out[d] = best if hits[(d, best)] >= CALL_SHARE * n else 0
    return out


def _in_config(detectors: Mapping[int, int], kind: str, top: int, out: Inferred) -> dict[int, int]:
    """The detectors (or push buttons) the emulator's config holds (numbered 1-``top``); the others are said."""
    beyond = sorted(d for d in detectors if d > top)
    if beyond:
        out.guessed.append(f"{kind}s {', '.join(map(str, beyond))}: left out (the emulator's are numbered "
                           f"1-{top}); their inputs are not replayed")
    return {d: q for d, q in detectors.items() if d <= top}


def _gaps(rows: Sequence[Row], p: int, detectors: Sequence[int],
          held: Mapping[int, timedelta]) -> list[tuple[float, float]]:
    """Each gap-out's time into its green and its gap: the time from the last of the phase's detectors going off,
    during the green, to the gap-out (a gap-out logged when the green ends may come later than the gap: at a barrier,
    the green waits for the other ring); a detector whose call is ``held`` after it goes off (its extension or
    carryover) goes off that much later. A gap-out logged as the minimum green completes (3, the same tick) is left
    out: its gap ran out during the minimum, which no green ends before, so it says only that the passage is no
    longer (the atspm sample's phase 8: gaps of 2.5-3.5 s logged 6.0 s into the green, its minimum, against a
    passage of 2.4 s; counted, a day of that log, seeing each of them a dozen times, read the passage as 3.5 s)."""
    if not detectors:
        return []
    mine, on, gaps = set(detectors), set(), []
    last_off: datetime | None = None
    began: datetime | None = None
    minimum: datetime | None = None
    for r in rows:
        if r.parameter in mine and r.code in (E.DETECTOR_ON, E.DETECTOR_OFF):
            (on.add if r.code == E.DETECTOR_ON else on.discard)(r.parameter)
            if r.code == E.DETECTOR_OFF and not on:
                last_off = r.time + held.get(r.parameter, timedelta())
        elif r.code == E.PHASE_BEGIN_GREEN and r.parameter == p:
            began = r.time
        elif r.code == E.PHASE_MIN_COMPLETE and r.parameter == p:
            minimum = r.time
        elif (r.code == E.PHASE_GAP_OUT and r.parameter == p and not on and last_off is not None and r.time != minimum
              and began is not None and last_off > began):  # an off before the green extended nothing
            # the off event is the first tick without the call; passage counts from the last tick with it
            gaps.append(((r.time - began).total_seconds(), round((r.time - last_off + TICK).total_seconds(), 1)))
    return gaps


def _reduction(samples: Sequence[tuple[float, float]]) -> dict[str, float] | None:
    """Gap reduction (NTCIP 1202 phaseTimeBeforeReduction, phaseTimeToReduce, phaseMinimumGap) from a phase's gap-outs
    (time into the green, gap), when their gaps fall with the green's time: the minimum gap is the most frequent gap,
    the passage the largest seen :data:`PASSAGE_SEEN` times, and the gaps between them lie on one line (least squares,
    at least :data:`REDUCTION_SEEN` of them, none more than :data:`REDUCTION_FIT` s off it) that reaches the passage
    at the time before reduction (counted from the green's start: a conflicting call waits from then on in these
    logs) and the minimum gap a time to reduce later. None when they do not."""
    counts = Counter(g for _, g in samples)
    least = _mode(counts.elements())
    seen = [g for g, n in counts.items() if n >= PASSAGE_SEEN and g > least]
    if least is None or not seen:
        return None
    passage = max(seen)
    ramp = [(t, g) for t, g in samples if least < g < passage]
    if len(ramp) < REDUCTION_SEEN:
        return None
    mean_t, mean_g = sum(t for t, _ in ramp) / len(ramp), sum(g for _, g in ramp) / len(ramp)
    spread = sum((t - mean_t) ** 2 for t, _ in ramp)
    slope = sum((t - mean_t) * (g - mean_g) for t, g in ramp) / spread if spread else 0.0
    if slope >= 0 or any(abs(mean_g + slope * (t - mean_t) - g) > REDUCTION_FIT for t, g in ramp):
        return None
    before = mean_t + (passage - mean_g) / slope
    return {"passage": passage, "time_before_reduction": min(255, max(0, round(before))),
            "time_to_reduce": min(255, max(1, round((least - passage) / slope))), "min_gap": least}


def _coordination(rows: Sequence[Row], day0: datetime, structure: Structure, timing: Mapping[int, dict[str, Any]],
                  greens: Mapping[int, list[tuple[datetime, datetime]]], out: Inferred) -> dict[str, Any] | None:
    zeros = sorted({r.time for r in rows if r.code == E.COORD_CYCLE_STATE_CHANGE and r.parameter == LOCAL_ZERO})
    if len(zeros) < 2:
        out.read.append("coordination: no local zero in the log (event 150 with 5): free")
        return None
    apart = [(round((b - a).total_seconds(), 1), a, b) for a, b in itertools.pairwise(zeros)]
    cycle = round(_mode(s for s, _, _ in apart))
    if not CYCLES[0] <= cycle <= CYCLES[1]:
        s, a, b = next(x for x in apart if round(x[0]) == cycle)
        raise FieldLogError(f"local zeros (event 150, parameter 5) at {_when(a)} and {_when(b)}: {s:g} s apart, as "
                            f"most are, a cycle of {cycle} s; allowed: {CYCLES[0]}-{CYCLES[1]} s (NTCIP 1202 "
                            "patternCycleTime)")
    zero = _mode(round(_since_midnight(t, day0) % cycle, 1) for t in zeros)
    ringed = set(structure.ring(1) + structure.ring(2))
    yields = Counter(r.parameter for r in rows if r.code == E.COORD_YIELD_POINT and r.parameter in ringed)
    covering = _covering(zeros, greens)
    votes = yields or covering or Counter({structure.ring(1)[0]: 1})
    group = structure.group_of(max(votes, key=lambda p: (votes[p], -p)))
    coord = {}
    for r in (1, 2):
        mine = structure.order[r][group]
        coord[r] = max(mine, key=lambda p: (yields[p], covering[p], -mine.index(p)))
        if not yields[coord[r]]:
            out.guessed.append(f"coordinated phase of ring {r}: {coord[r]} (no yield point event, 151: the phase of "
                               "that ring green at the local zero)")
    # Where each forced-off phase's split ends in the cycle: its force-off plus its clearance (seconds from midnight,
    # modulo the cycle). The controller lays each ring's splits end to end from the start of its first barrier group
    # (NTCIP 1202 sequenceData's order); that start is where the rings' last splits end. The local zero is where the
    # field's controller counts from, which need not be at a coordinated green (an offset referred to a yield point):
    # the offset is written for the emulator's reference, the start of the earliest coordinated split.
    at_end: dict[int, float] = {}
    for p in timing:
        force_offs = [round(_since_midnight(row.time, day0) % cycle, 1) for row in rows
                      if row.code == E.PHASE_FORCE_OFF and row.parameter == p]
        if p in greens and force_offs and len(force_offs) >= FORCE_OFF_SHARE * len(greens[p]):  # not a stray one
            at_end[p] = (_mode(force_offs) + timing[p]["yellow"] + timing[p]["red_clear"]) % cycle
    _own_yield_points(rows, structure, coord, at_end, timing, day0, cycle, out)
    logged = {p: s for p, s in _logged_splits(rows, zeros).items() if p in greens}
    orders = {r: structure.ring(r) for r in (1, 2)}
    begin = _barrier_start(orders, logged, at_end, cycle)
    if begin is None:  # no split end the log shows can be placed: the coordinated splits start at the local zero
        begin = zero
        orders = {r: mine[mine.index(coord[r]):] + mine[:mine.index(coord[r])] for r, mine in orders.items()}
        out.guessed.append("offset reference: the local zero (event 150, 5) starts the coordinated greens (lead green; "
                           "no split's end is placed by a force-off in the log)")
    ends = {p: e if (e := (at - begin) % cycle) > 0.05 else float(cycle) for p, at in at_end.items()}
    splits = _splits(structure, orders, ends, logged, cycle, timing, out)
    raw_start = {p: sum(splits[q] for q in mine[:mine.index(p)]) for mine in orders.values() for p in mine}
    lead = min(raw_start[c] for c in coord.values())
    offset = round(begin + lead) % cycle
    if 86_400 % cycle:
        out.guessed.append(f"cycle {cycle} s does not divide a day: the cycle's place is counted from midnight of the "
                           "log's first day on, as the emulator's clock counts, not from each day's midnight")
    out.read.append(f"coordination: cycle {cycle} s, offset {offset} s (the start of the earliest coordinated split; "
                    f"the field's local zero is at {zero:g} s of the day modulo the cycle), coordinated "
                    f"{coord[1]}+{coord[2]}, splits " + ", ".join(f"{p}: {s}" for p, s in splits.items())
                    + (f" (as logged, events 134-149, for {', '.join(map(str, logged))})" if logged else ""))
    return {"cycle": cycle, "offset": offset, "coord": [coord[1], coord[2]], "splits": splits}


def _own_yield_points(rows: Sequence[Row], structure: Structure, coord: Mapping[int, int], at_end: dict[int, float],
                      timing: dict[int, dict[str, Any]], day0: datetime, cycle: int, out: Inferred) -> None:
    """Each ring's coordinated phase ends its split at its own yield point: NTCIP 1202 splitTime is "the time in
    seconds the splitPhase is allowed to receive (i.e. before a Force Off is applied)", the coordinated phase's as
    any other's, ring by ring. A coordinated phase last of its ring in its barrier group, whose split end no force-off
    places, would otherwise get the group's end; but where its greens end (begin yellow, 8) at one place of the cycle
    again and again (:data:`YIELD_SEEN` times) before the group's end, which the other ring's last phase there puts
    (the atspm sample: 2 ends with 6 at 6's force-off whenever 5 is not served, and with 5 otherwise), that is its
    yield point (it never ends before it), and the rest of the group is a phase of its ring the log never shows
    served. So the split table gets that phase, timed as the other ring's phase after its coordinated one, and
    ``at_end`` the coordinated phase's end (its yield point plus its clearance)."""
    for r in (1, 2):
        c = coord[r]
        g = structure.group_of(c)
        other = structure.order[3 - r][g]
        if c in at_end or structure.order[r][g][-1] != c or other[-1] not in at_end:
            continue
        point = _yield_point(rows, c, day0, cycle)
        if point is None:
            continue
        end = (point + timing[c]["yellow"] + timing[c]["red_clear"]) % cycle
        short = (at_end[other[-1]] - end) % cycle
        if not 1 < short < cycle / 2:
            continue
        twin = other[other.index(coord[3 - r]) + 1] if coord[3 - r] in other[:-1] else other[-1]
        free = _phantom(structure, r, g, twin)
        timing[free] = {k: v for k, v in timing[twin].items() if k not in ("walk", "ped_clear")}
        at_end[c] = end
        out.read.append(f"coordinated phase {c}: its yield point at {point:g} s of the day modulo the cycle, where its "
                        f"greens end when nothing holds them, {short:g} s before its barrier group's end; phase "
                        f"{free} (not in the log, timed as {twin}) fills its ring's split there: ring {r} "
                        f"{structure.ring(r)}, barrier groups {structure.barriers}")


def _yield_point(rows: Sequence[Row], phase: int, day0: datetime, cycle: int) -> float | None:
    """The first place of the cycle (seconds of the day modulo the cycle) where the phase's greens end at least
    :data:`YIELD_SEEN` times, its greens' ends read as one arc of the cycle (from past the widest stretch without
    one); None when no place repeats."""
    ends = Counter(round(_since_midnight(r.time, day0) % cycle, 1) for r in rows
                   if r.code == E.PHASE_BEGIN_YELLOW and r.parameter == phase)
    places = sorted(ends)
    if not places:
        return None
    widest = max(range(len(places)), key=lambda k: (places[k] - places[k - 1]) % cycle)
    arc = places[widest:] + places[:widest]
    return next((x for x in arc if ends[x] >= YIELD_SEEN), None)


def _barrier_start(orders: Mapping[int, Sequence[int]], logged: Mapping[int, int], at_end: Mapping[int, float],
                   cycle: int) -> float | None:
    """Where the rings' orders start in the cycle (seconds from midnight modulo the cycle): where a ring's last split
    ends, or, when every split of a ring was logged, where a forced-off phase's end puts it (the most frequent)."""
    for mine in orders.values():
        if mine[-1] in at_end:
            return at_end[mine[-1]]
    placed = []
    for mine in orders.values():
        if all(p in logged for p in mine):
            placed += [(at_end[p] - sum(logged[q] for q in mine[:k + 1])) % cycle
                       for k, p in enumerate(mine) if p in at_end]
    return _mode(round(b, 1) for b in placed) if placed else None


def _logged_splits(rows: Sequence[Row], zeros: Sequence[datetime]) -> dict[int, int]:
    """Each phase's split as the controller logged it (split change, events 134-149 for phases 1-16), the value in
    effect at most local zeros; a split of 0 is none."""
    changes: dict[int, list[tuple[datetime, int]]] = defaultdict(list)
    for r in rows:
        if E.SPLIT_1_CHANGE <= r.code < E.SPLIT_1_CHANGE + 16:
            changes[r.code - E.SPLIT_1_CHANGE + 1].append((r.time, r.parameter))
    out = {}
    for p, mine in changes.items():
        times = [t for t, _ in mine]
        value = _mode(mine[k - 1][1] for z in zeros if (k := bisect.bisect_right(times, z)))
        if value:
            out[p] = int(value)
    return out


def _covering(zeros: Sequence[datetime], greens: Mapping[int, Sequence[tuple[datetime, datetime]]]) -> Counter[int]:
    """How many local zeros fall in each phase's greens."""
    out: Counter[int] = Counter()
    for p, mine in greens.items():
        begins = [a for a, _ in mine]
        for z in zeros:
            k = bisect.bisect_right(begins, z) - 1
            if k >= 0 and z < mine[k][1]:
                out[p] += 1
    return out


def _splits(structure: Structure, cyclic: Mapping[int, Sequence[int]], ends: Mapping[int, float],
            logged: Mapping[int, int], cycle: int, timing: Mapping[int, dict[str, Any]], out: Inferred
            ) -> dict[int, int]:
    """Each phase's split as logged, or from where it ends in the cycle (from where each ring's order ``cyclic``
    starts): force-offs where the log has them, the other ring's end of the barrier group, the cycle's end; then
    fitted (:func:`_fit`)."""

    def last_of_group(order: Sequence[int], k: int) -> bool:
        return k == len(order) - 1 or structure.group_of(order[k + 1]) != structure.group_of(order[k])

    barrier_end: dict[int, float] = {}
    for r in (1, 2):
        for k, p in enumerate(cyclic[r]):
            if p in ends and p not in logged and last_of_group(cyclic[r], k):
                barrier_end.setdefault(structure.group_of(p), ends[p])
    splits: dict[int, int] = {}
    for r in (1, 2):
        at, order = 0.0, cyclic[r]
        for k, p in enumerate(order):
            end = at + logged[p] if p in logged else ends.get(p)
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
    return dict(sorted(_fit(splits, structure, cyclic, cycle, timing, out).items()))


def _fit(splits: dict[int, int], structure: Structure, cyclic: Mapping[int, Sequence[int]], cycle: int,
         timing: Mapping[int, dict[str, Any]], out: Inferred) -> dict[int, int]:
    """The splits made what NTCIP 1202's splitTime asks ("longer than the sum of the phase minimum service
    requirements") and the barrier: each ring's splits in a barrier group add up to the same, and to the cycle over
    the groups. A ring short of the other at a barrier gets the difference on its last phase before it; the cycle's
    rest goes to both rings' last phases, and an excess is taken back from the latest phases that have more than
    their minimum."""
    need = {p: math.ceil(t["min_green"] + t["yellow"] + t["red_clear"] - 1e-9) for p, t in timing.items()}
    for p in splits:
        if splits[p] < need[p]:
            out.guessed.append(f"phase {p}: split {need[p]} s, its minimum green and clearance (the log's ends "
                               f"give {splits[p]} s)")
            splits[p] = need[p]

    def in_group(r: int, g: int) -> list[int]:
        return [p for p in cyclic[r] if structure.group_of(p) == g]

    before = dict(splits)
    for g in range(len(structure.groups)):
        sums = {r: sum(splits[p] for p in in_group(r, g)) for r in (1, 2)}
        for r in (1, 2):
            splits[in_group(r, g)[-1]] += max(0, sums[3 - r] - sums[r])
    short = cycle - sum(splits[p] for p in cyclic[1])
    if short > 0:
        g = structure.group_of(cyclic[1][-1])
        for r in (1, 2):
            splits[in_group(r, g)[-1]] += short
    for g in dict.fromkeys(structure.group_of(p) for p in reversed(cyclic[1])):
        if short >= 0:
            break
        cut = min(-short, *(sum(splits[p] - need[p] for p in in_group(r, g)) for r in (1, 2)))
        for r in (1, 2):
            left = cut
            for p in reversed(in_group(r, g)):
                by = min(left, splits[p] - need[p])
                splits[p] -= by
                left -= by
        short += cut
    if short < 0:
        raise FieldLogError(f"local zeros (event 150, parameter 5) every {cycle} s: a cycle shorter than the "
                            f"{cycle - short} s the phases' minimum greens and clearances need in each ring; allowed: "
                            "a cycle that serves every phase's minimum (NTCIP 1202 splitTime)")
    for p in splits:
        if splits[p] != before[p]:
            out.guessed.append(f"phase {p}: split changed by {splits[p] - before[p]} s so that the rings reach each "
                               f"barrier together and fill the {cycle} s cycle")
    return splits


@dataclass(frozen=True, slots=True)
class InferredOverlap:
    """An overlap as the log shows it: its included phases, its type and the delay of its green (s)."""

    included: list[int]
    kind: str
    delay: float = 0.0


def _overlaps(rows: Sequence[Row], phases: Sequence[int], out: Inferred) -> dict[int, InferredOverlap]:
    """Overlaps and their type: an overlap includes the phases whose begin greens (1) its own (61) come with, on the
    same tick or the next (a MaxTime logs some a tick later): the fewest that together come with nine in ten of
    them, each with a tenth (an overlap of 2 and 6 begins green with whichever starts first). Failing that, the
    phases whose begin greens come one same time before its own, 0.2-25.5 s, nine in ten times: a delayed green of
    that time. One that ends its greens (64, 65) at least :data:`PASSAGE_SEEN` times and never logs a yellow (63) is
    a transit bar (NTCIP 1202 v03 transit-2: green, flashing green, red), else a normal overlap. An overlap that
    never begins green is inferred only when it is dark while its phases are green (:func:`dark_at_green`)."""
    starts: dict[int, list[datetime]] = defaultdict(list)
    greens: dict[int, list[datetime]] = defaultdict(list)
    ended: Counter[int] = Counter()
    yellowed: set[int] = set()
    for r in rows:
        if r.code == E.OVERLAP_BEGIN_GREEN:
            starts[r.parameter].append(r.time)
        elif r.code == E.PHASE_BEGIN_GREEN:
            greens[r.parameter].append(r.time)
        elif r.code in (E.OVERLAP_BEGIN_RED_CLEARANCE, E.OVERLAP_OFF):
            ended[r.parameter] += 1
        elif r.code == E.OVERLAP_BEGIN_YELLOW:
            yellowed.add(r.parameter)
    began_at = {p: set(times) for p, times in greens.items()}
    overlaps: dict[int, InferredOverlap] = {}
    for o, times in starts.items():
        kind = "transit" if o not in yellowed and ended[o] >= PASSAGE_SEEN else "normal"
        included = _cover(times, phases, lambda t, p: t in began_at.get(p, ()) or t - TICK in began_at.get(p, ()))
        if included:
            overlaps[o] = InferredOverlap(included, kind)
            continue
        lags: Counter[float] = Counter()  # the time from each phase's last begin green to the overlap's
        for t in times:
            for p in phases:
                k = bisect.bisect_right(greens.get(p, []), t) - 1
                if k >= 0 and TICK < t - greens[p][k] <= MAX_DELAY:
                    lags[round((t - greens[p][k]).total_seconds(), 1)] += 1
        for lag, _ in lags.most_common(1):
            delay = timedelta(seconds=lag)
            included = _cover(times, phases, lambda t, p, delay=delay: t - delay in began_at.get(p, ()))
            if included:
                overlaps[o] = InferredOverlap(included, kind, lag)
    darks = {o: d for o, d in dark_at_green(rows).items() if o <= OVERLAPS}
    for o, d in darks.items():
        overlaps[o] = InferredOverlap(d.included, "normal")
        out.guessed.append(
            f"overlap {chr(64 + o)} ({o}): a normal overlap of phase(s) {d.included}, dark while they are green "
            f"(never a begin green, 61; {d.said()}): read as a flashing yellow arrow's head "
            "whose green arrow is the phase's own output, its flashing (32) never logged; the field's 66 is counted "
            "as its begin green, 61 (a declared logging variant)")
    beyond = sorted(o for o in overlaps if o > OVERLAPS)
    for o in beyond:
        out.guessed.append(f"overlap {o}: left out (it begins green with phase(s) {overlaps.pop(o).included}, but "
                           f"the emulator's overlaps are A-P, 1-{OVERLAPS})")
    for o, ov in ((o, ov) for o, ov in overlaps.items() if o not in darks):
        after = f"{ov.delay:g} s after" if ov.delay else "with"
        out.read.append(f"overlap {chr(64 + o)} ({o}): begins green {after} phase(s) {ov.included}: "
                        + ("a normal overlap of them" if ov.kind == "normal" else
                           f"never yellow ({ended[o]} greens end in red): a transit bar of them (transit-2)")
                        + (f", its green delayed {ov.delay:g} s" if ov.delay else ""))
    seen = {r.parameter for r in rows if E.OVERLAP_BEGIN_GREEN <= r.code <= E.OVERLAP_DARK}
    for o in sorted(seen - set(overlaps) - set(beyond)):
        letter = f"{chr(64 + o)} ({o})" if o <= OVERLAPS else str(o)
        out.guessed.append(f"overlap {letter}: not modelled (its begin greens come with no phase's, nor one time "
                           "after; its other events fit none of the types: normal, transit, minus green-yellow, "
                           "flashing yellow arrow)")
    return overlaps


#: An overlap dark while its phases are green: each of its events, the phase event it comes with, and how to say so.
_DARK_AT_GREEN = {E.OVERLAP_DARK: (E.PHASE_BEGIN_GREEN, "dark (66) as they begin green (1)"),
                  E.OVERLAP_BEGIN_YELLOW: (E.PHASE_BEGIN_YELLOW, "yellow (63) with their yellow (8)"),
                  E.OVERLAP_OFF: (E.PHASE_END_YELLOW, "off (65) as their yellow ends (9)")}
_PHASE_CODES = [phase_code for phase_code, _ in _DARK_AT_GREEN.values()]


@dataclass(frozen=True, slots=True)
class DarkAtGreen:
    """An overlap the log shows dark while its phases are green: its included phases and, per event of it (dark,
    yellow, off: 66, 63, 65), how many it logged and how many came with its phases' (1, 8, 9)."""

    included: list[int]
    seen: dict[int, tuple[int, int]]

    def said(self) -> str:
        return ", ".join(f"{_DARK_AT_GREEN[code][1]} {n} of {of}" for code, (n, of) in self.seen.items())


def dark_at_green(rows: Sequence[Row]) -> dict[int, DarkAtGreen]:
    """The overlaps that never begin green (61) but go dark (66) as phases begin green (the same tick or the next,
    the fewest phases that come with nine in ten of them, as :func:`_cover` reads), then turn yellow (63) as those
    phases do (8) and off (65) as their yellow ends (9), nine in ten times each: the phases' own overlap, its green
    shown by the phases' outputs ("Overlap Dark: set when overlap head is set dark (no active outputs)", the Indiana
    enumerations). The atspm sample's overlap E does it every cycle with phase 5 (a MaxTime's flashing yellow arrow
    head, read so, its flashing unused)."""
    events: dict[int, dict[int, list[datetime]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        if r.code in _PHASE_CODES or E.OVERLAP_BEGIN_GREEN <= r.code <= E.OVERLAP_DARK:
            events[r.code][r.parameter].append(r.time)
    at = {code: {p: set(times) for p, times in events[code].items()} for code in _PHASE_CODES}

    def near(code: int, t: datetime, p: int) -> bool:
        return t in at[code].get(p, ()) or t - TICK in at[code].get(p, ())

    out: dict[int, DarkAtGreen] = {}
    for o, darks in events[E.OVERLAP_DARK].items():
        included = _cover(darks, sorted(at[E.PHASE_BEGIN_GREEN]), lambda t, p: near(E.PHASE_BEGIN_GREEN, t, p))
        if o in events[E.OVERLAP_BEGIN_GREEN] or not included:
            continue
        seen = {code: (sum(any(near(phase_code, t, p) for p in included) for t in events[code].get(o, [])),
                       len(events[code].get(o, []))) for code, (phase_code, _) in _DARK_AT_GREEN.items()}
        if all(of and n >= 0.9 * of for n, of in seen.values()):
            out[o] = DarkAtGreen(included, seen)
    return out


def _cover(times: Sequence[datetime], phases: Sequence[int], began: Callable[[datetime, int], bool]) -> list[int]:
    """The fewest phases whose begin greens come with nine in ten of ``times``, each with a tenth (greedy: the phase
    that comes with most, then the one that comes with most of those left), sorted; none if no such set."""
    included: list[int] = []
    left = list(times)
    while left:
        p = max(phases, key=lambda p: sum(began(t, p) for t in left))
        if sum(began(t, p) for t in left) < 0.1 * len(times):
            break
        included.append(p)
        left = [t for t in left if not began(t, p)]
    return sorted(included) if included and len(left) <= 0.1 * len(times) else []


def _startup(rows: Sequence[Row], greens: Mapping[int, list[tuple[datetime, datetime]]], structure: Structure,
             out: Inferred) -> list[int]:
    """The phases to power up in: the log's first state, the phases green when it began (their first interval event
    is the end of a green: gap-out, max-out, force-off, green termination or begin yellow, 4-8), when there is one
    in each ring of one barrier group; else in each ring
    the phase of the group served first that the log shows green first (the group's first in the ring's order when
    none of its phases is)."""
    first_seen: dict[int, int] = {}
    for r in rows:
        if r.code == E.PHASE_BEGIN_GREEN or E.PHASE_GAP_OUT <= r.code <= E.PHASE_BEGIN_YELLOW:
            first_seen.setdefault(r.parameter, r.code)
    green_at_start = {p for p, code in first_seen.items() if code != E.PHASE_BEGIN_GREEN and p in greens}
    by_ring = {ring: [p for p in structure.ring(ring) if p in green_at_start] for ring in (1, 2)}
    if all(len(mine) == 1 for mine in by_ring.values()) and \
            structure.group_of(by_ring[1][0]) == structure.group_of(by_ring[2][0]):
        out.read.append(f"start-up: phases {by_ring[1][0]} and {by_ring[2][0]}, green when the log begins")
        return [by_ring[1][0], by_ring[2][0]]
    first = min((t0, p) for p, spans in greens.items() for t0, _ in spans)[1]
    g = structure.group_of(first)
    return [min(structure.order[r][g], key=lambda p: greens[p][0][0] if p in greens else datetime.max)
            for r in (1, 2)]


def _powered(rows: Sequence[Row], startup: Sequence[int], timing: Mapping[int, Mapping[str, Any]], start: datetime,
             out: Inferred) -> datetime:
    """When the controller powers up (``[emulator] start``): a start-up phase green when the log begins whose green
    ends (8) before its minimum could have run from the log's first tenth began that much earlier (a green ends no
    sooner than its minimum: the log began in the middle of a green that had timed it), so the model powers up
    that long before the log (its greens resting past their minimum, as the field's were), but not before midnight
    of the log's first day (the emulator's coordination clock counts from midnight of its power-up's day)."""
    seen: dict[int, dict[int, datetime]] = defaultdict(dict)  # phase -> its first begin green and begin yellow
    for r in rows:
        if r.parameter in startup and r.code in (E.PHASE_BEGIN_GREEN, E.PHASE_BEGIN_YELLOW):
            seen[r.parameter].setdefault(r.code, r.time)
    ends = {p: t[E.PHASE_BEGIN_YELLOW] for p, t in seen.items()
            if t.get(E.PHASE_BEGIN_YELLOW, datetime.max) < t.get(E.PHASE_BEGIN_GREEN, datetime.max)}
    early = {p: round(timing[p]["min_green"] - (t - start).total_seconds(), 1) for p, t in ends.items()}
    early = {p: s for p, s in early.items() if s > 0}
    midnight = datetime.combine(start.date(), datetime.min.time())
    lead = min(max(early.values(), default=0.0), (start - midnight).total_seconds())
    if lead <= 0:
        return start
    out.read.append(f"start-up: powered up {lead:g} s before the log begins: " + ", ".join(
        f"phase {p}'s green ends {(ends[p] - start).total_seconds():g} s into the log, its minimum is "
        f"{timing[p]['min_green']:g} s" for p in sorted(early))
        + " (a green runs its minimum: it began before the log)")
    return start - timedelta(seconds=lead)


def _toml(name: str, structure: Structure, timing: Mapping[int, dict[str, Any]], detectors: Mapping[int, int],
          timers: Mapping[int, Mapping[str, float]], pushes: Mapping[int, int],
          coordination: Mapping[str, Any] | None, overlaps: Mapping[int, InferredOverlap], startup: Sequence[int],
          start: datetime) -> str:
    def value(v: Any) -> str:
        return f"{v:g}" if isinstance(v, float) else str(v)

    lines = ["# Written by harness.reference.field_log from a controller's hi-res log: what it read and guessed is "
             "printed with it.", f"name = {json.dumps(name)}", "", "[phases]"]
    for p in sorted(timing):
        fields = {k: timing[p][k] for k in ("min_green", "max_green", "yellow", "red_clear", "passage",
                                            "time_before_reduction", "time_to_reduce", "min_gap", "walk",
                                            "ped_clear") if k in timing[p]}
        for option in ("dual_entry", "conditional_service", "ped_recycle"):
            if timing[p].get(option):
                fields[option] = "true"
        for option in ("backup_prevent", "simultaneous_gap_disable"):
            if timing[p].get(option) is False:
                fields[option] = "false"
        if "recall" in timing[p]:
            fields["recall"] = f'"{timing[p]["recall"]}"'
        if p in startup:
            fields["startup"] = '"green"'
        lines.append(f"{p} = {{ " + ", ".join(f"{k} = {value(v)}" for k, v in fields.items()) + " }")
    barriers = structure.barriers
    pairs = [[a, b] for group in barriers for a in group for b in group
             if a in structure.ring(1) and b in structure.ring(2)]
    lines += ["", "[structure]", f"rings = [{structure.ring(1)}, {structure.ring(2)}]", f"barriers = {barriers}",
              f"sequence = {pairs}", f"pairs = {pairs}", "", "[emulator]",
              f"start = {start.isoformat(timespec='milliseconds')[:-2]}", "", "[detectors]"]
    lines += [f"{d} = {{ phase = {q}, " + ", ".join(f"{k} = {str(v).lower() if v is True else f'{v:g}'}"
                                                     for k, v in timers[d].items()) + " }"
              if timers.get(d) else f"{d} = {q}" for d, q in sorted(detectors.items())]
    if pushes:
        lines += ["", "[pedestrian_detectors]", *(f"{d} = {q}" for d, q in sorted(pushes.items()) if q)]
    if overlaps:
        lines += ["", "[overlaps]"]
        for o, ov in sorted(overlaps.items()):
            typed = "" if ov.kind == "normal" else f'type = "{ov.kind}", '
            delayed = f", delay_green = {ov.delay:g}" if ov.delay else ""
            lines.append(f"{chr(64 + o)} = {{ {typed}included = {ov.included}{delayed} }}")
    if coordination is not None:
        c = coordination
        lines += ["", "[coordination]", "pattern = 1", 'force_off = "fixed"', 'offset_reference = "lead_green"',
                  'correction = "shortway"', "", "[[coordination.patterns]]", "number = 1", f"cycle = {c['cycle']}",
                  f"offset = {c['offset']}", f"coord_phases = {c['coord']}",
                  "splits = { " + ", ".join(f"{p} = {s}" for p, s in c["splits"].items()) + " }"]
        if c.get("modes"):
            lines.append("modes = { " + ", ".join(f'{p} = "{m}"' for p, m in sorted(c["modes"].items())) + " }")
    return "\n".join(lines) + "\n"
