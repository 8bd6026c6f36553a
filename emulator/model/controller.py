"""A dual-ring NEMA actuated controller in free mode, ticking every 0.1 s.

Rules of this file
------------------
- Time is an integer count of ticks (tenths of a second), as in a real
  controller; no float time is compared anywhere in here.
- :meth:`Controller.step` is the only thing that advances timing. It reads the
  control objects (calls, holds, force-offs, omits) as they are at that tick.
- Interval changes of a ring follow ``_NEXT`` below and nothing else; a green
  ends only by ``_decide`` committing the ring's next phase (or none), and a
  ring leaves DWELL only by ``_enter_target`` starting its committed phase.
- An interval takes its lengths when it starts (``Timing`` copied into the
  ring), so a SET of the phase table acts from the next interval on.
- :meth:`Controller.advance` (n ticks) is exactly n calls of :meth:`Controller.step`:
  it only skips ticks that :meth:`Controller.quiet_ticks` proves change
  nothing but counters (a property test holds the two together).
- A recorder (the data logger, :mod:`emulator.model.datalogger`) hears every
  interval change, a yellow with why its green ended (``_ending``, the very
  reason ``_ready`` acts on), the end of every step and a power-up; it reads
  and never acts.
- The controller's clock is the coordinator's: local time in ticks since
  midnight of the day it first powered up (``start``: ``[emulator] start``, or
  the host's time when served). A power cycle resets ``tick``, not the clock.

Theory of operation
-------------------
Each ring times one phase at a time through GREEN, YELLOW and RED_CLEAR, then
DWELLs at red until its committed next phase may start. Both rings work inside
one barrier group (``group``) at a time, so any two phases they show are
concurrent by the ring-and-barrier structure.

*Demand* on a phase is a vehicle call, a latched pedestrian call, or a recall
(min, max, ped; soft only while no other phase has demand), never on an omitted
phase. A green is *ready to end* when it has timed its minimum (and Walk plus
pedestrian clearance if it served a walk), is not held, and has gapped out
(no vehicle call for its passage time), maxed out (Maximum1, or Maximum2 when
ringControlGroupMax2 selects it for the ring, timed while *conflicting demand*
waits: demand in its own ring or across the barrier; on max recall timed from
the start of the green, as NTCIP 1202 phaseMaximum1's timer is "held reset
unless Max Vehicle Recall is enabled for this phase") or been forced off. Once
a ready, gapped-out green sees conflicting demand it stays gapped out until it
ends, when its phase has ``simultaneous_gap_disable`` (the default; NTCIP 1202
phaseOptions bit 11: it "disables a gapped out phase from reverting to the
extensible portion"): a call coming back does not re-extend it. Without it, a
call coming back while it waits (at the barrier for the other ring) extends it
again. A green without anywhere to go rests in green, maxed out or not.

A ready ring *wishes* for the nearest phase with demand in its ring order after
its own (1, 2, 3, 4, 1, ...). Within the barrier group it goes there at once:
forward, or backing into an earlier phase of the group while the other ring
still times, but only when no demand waits across the barrier: a controller
backs "into a protected left-turn phase when the cross street phases and the
opposing left-turn are skipped" (Naztec TecNote 3013), not when they are
called. A ring may not back from a phase with ``backup_prevent`` either. A
backing refused counts as a wish beyond the barrier (the phase waits for the
group's next visit, or, with nothing across, both rings clear and restart the
group for it); when both rings are ready and one wishes beyond, the other does
not back either (crossing goes first). While a pattern runs, no ring backs
while ``backup_prevent`` makes another restart the group, even before that
one is ready: backed into its coordinated phase, it would rest there to its
yield point and hold the restart for a cycle (``_beyond`` says why). A wish
beyond the barrier is served only when every ring is ready (or idle in red)
and wishes beyond or nowhere: then all rings clear together into the new
group, a ring without demand there taking its ``dual_entry`` phase if it has
one and resting in red otherwise. Until then the ring wishing across keeps its
green (it waits at the barrier).

The next phase is *committed at the start of yellow* (shown in
phaseStatusGroupPhaseNexts from then). With ``next_phase_lock = "green_end"``
(the default; NTCIP 1202: PhaseNext "shall be determined at the end of the
green interval of the terminating phase") a call arriving during the clearance
does not redirect it. With ``"red_end"`` (controllers that lock their detectors
at the start of red, SUMO issue 9989) a call during the yellow or red
clearance redirects the ring to the nearest phase with demand on the committed
phase's side of the barrier. A committed phase that loses its call during the
clearance is still served (its minimum green, then it ends as usual): NEMA TS 2
commits Phase Next at the end of the green, and SUMO's NEMA controller, validated
against Econolite SIL, does the same (NEMAController.cpp, NEMAPhase::exit enters
``lastTransitionDecision`` at the end of red without re-checking its call). A
committed phase that is *omitted* during the clearance is dropped: the ring ends
its clearance in red with nothing committed and chooses again at the next tick,
because phaseControlGroupPhaseOmit (NTCIP 1202) says an omitted phase is not
serviced. A committed phase starts when its ring's clearance is over, no other
ring still shows a phase of another barrier group (both rings enter a new group
together) and its red revert since its own last yellow has passed.

A walk is served when the phase's green starts with a pedestrian call (latched
from phaseControlGroupPedCall or ped recall, not on a PedOmit phase); a call
arriving later in the green waits for the next service (no recycling). While a
pattern runs, the walk is served only if it and the pedestrian clearance end by
the phase's force-off point; otherwise the call stays latched for the next
cycle, and a phase wanted by its pedestrian call alone is skipped. A push
button (a pedestrian detector, pedestrianDetectorControlGroupActuation) latches
its phase's call at once, during that phase's green too: the walk comes at the
phase's next green. PedOmit stops new walks only; a walk being timed completes.

Omitted phases never start. ForceOff bits clear themselves when that phase's
green ends. unitBackupTime is armed by the first SET of a control object; when
it passes without another, the controller reports backupMode and clears every
control object. After power-up the controller flashes for unitStartUpFlash
seconds, then starts its start-up intervals. The monitor (the cabinet's MMU,
:mod:`emulator.model.monitor`) sees the lamps after every tick that changed
them: two conflicting signals lit together (phases, or an overlap and a phase)
or a channel leaving its green without a yellow of at least 2.7 s is a fault,
and the controller goes to flash (all red) and stops timing.

Overlaps follow the phases at the end of each tick; an overlap that will
still show green or yellow after this tick (its own trailing green, yellow
and red after its parents ended, or a green whose included next was taken
away) holds back a committed phase that conflicts with it until it has
cleared, as controllers do when their overlap clearance locks the next
phase; a minus-green-yellow overlap's modifier waits for it likewise.

Quiet time. Most ticks change nothing but counters: a green resting on its
call, a yellow timing its length. A tick's discrete effects (intervals,
targets, the gap latch, the status, latched pedestrian calls, the control
objects, flash and control status) depend on the inputs, on the discrete
state and on a few comparisons of counters with thresholds (minimum,
walk, pedestrian clearance, passage, maximum, clearance lengths, red
revert, backup time, start-up flash). So once a step has changed nothing
discrete, every following step with the same inputs changes nothing either
until a counter reaches its next threshold: :meth:`quiet_ticks` says how
many steps that is, and :meth:`skip` advances the counters over the quiet
ones at once. A step that did change something is mostly followed by one
that does not (a green or a clearance just started); where that is short
to prove (:meth:`_settles`), quiet time starts at once instead of after
that step. In quiet time a gap counter that runs is above zero (an
extending green resets it every tick), a max-out counter that runs is
above zero (it is held at zero without conflicting demand unless the
phase is on max recall, and its first tick of a green is a real step) and
the conflicting demand a green registered (``Ring.conflict``) stays as it
is, which is all :meth:`skip` needs to know. A green's minimum is a
threshold only while it has conflicting demand (or a pattern runs, or a
preempt is served): without any, a ready green has nowhere to go, even
one that max recall has maxed out. The data logger still logs
it at its tick, so with a recorder that tick is stepped for the recorder
alone (:meth:`step` skips it, quiet as :meth:`quiet_ticks` proved). Any
input (a SET, a detector, a retiming) makes the next step a real one:
:meth:`touch`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import datetime
from enum import StrEnum
from typing import Protocol

import simpy

from emulator.model.coordination import Coordinator, Plan
from emulator.model.monitor import Lamps, Monitor
from emulator.model.overlaps import Overlaps, Phases
from emulator.model.preemption import Event, Preemptor
from hils.protocol.config import IntersectionConfig, NextPhaseLock, Phase, Recall
from hils.protocol.ntcip import (
    ControlColumn,
    CoordForceMode,
    PhaseStartup,
    PreemptState,
    ShortAlarm,
    UnitControlStatus,
    UnitFlashStatus,
)
from hils.protocol.timegrid import Grid

log = logging.getLogger(__name__)

TICK = 0.1  # seconds per controller tick


class Interval(StrEnum):
    GREEN = "green"
    YELLOW = "yellow"
    RED_CLEAR = "red_clear"
    DWELL = "dwell"


# What a timed interval becomes when it has run its length.
_NEXT: dict[Interval, Interval] = {
    Interval.YELLOW: Interval.RED_CLEAR,
    Interval.RED_CLEAR: Interval.DWELL,
}

_CLEARANCE = (Interval.YELLOW, Interval.RED_CLEAR)

_STARTUP_INTERVAL = {
    PhaseStartup.GREEN_WALK: Interval.GREEN,
    PhaseStartup.GREEN_NO_WALK: Interval.GREEN,
    PhaseStartup.YELLOW_CHANGE: Interval.YELLOW,
    PhaseStartup.RED_CLEAR: Interval.RED_CLEAR,
}


def tenths(seconds: float) -> int:
    return round(seconds * 10)


@dataclass(slots=True)
class Timing:
    """One phase's timings in ticks; mutable so the phase table can be retimed over SNMP."""

    min_green: int
    max1: int
    max2: int
    passage: int
    walk: int
    ped_clear: int
    yellow: int
    red_clear: int
    red_revert: int

    @classmethod
    def of(cls, ph: Phase) -> Timing:
        return cls(tenths(ph.min_green), tenths(ph.max_green), tenths(ph.maximum2), tenths(ph.passage),
                   tenths(ph.walk), tenths(ph.ped_clear), tenths(ph.yellow), tenths(ph.red_clear),
                   tenths(ph.red_revert))


@dataclass(slots=True)
class Ring:
    """Timing state of one ring (mutable: the controller's working memory)."""

    number: int
    order: tuple[int, ...]
    phase: int | None = None  # the phase timing now, or last timed while in DWELL
    interval: Interval = Interval.DWELL
    ticks: int = 0  # ticks completed in the current interval
    length: int = 0  # ticks the current yellow / red clearance lasts, fixed when it starts
    minimum: int = 0  # ticks the current green lasts at least (minimum green, or walk + ped clear)
    maximum: int = 0  # max-out ticks of the current green (Maximum1 or Maximum2)
    passage: int = 0  # passage ticks of the current green
    walk: int = 0  # walk ticks served in the current green (0: no walk)
    ped_clear: int = 0
    max_ticks: int = 0  # the maximum timer: ticks of conflicting demand (or of max recall) during this green
    conflict: bool = False  # conflicting demand registered at the green's last tick (the max timer may run without)
    gap: int = 0  # ticks since the green's own vehicle call was last present
    gapped: bool = False  # gapped out with conflicting demand: latched until the green ends (simultaneous gap disable)
    target: int | None = None  # the committed next phase (PhaseNext), from the start of yellow
    # Coordination (a pattern running): this green passed its force-off point or started past it; the green
    # ticks a floating force-off allows (0: none); the ring's yield point passed since its coordinated phase
    # last ended (its coordinated phase may then end).
    forced: bool = False
    limit: int = 0
    yielded: bool = False
    # Preemption: the ticks the green must show before a preempt's entry may end it (lesser of the minimum and
    # the preempt's entry minimums).
    cut: int = 0


class Termination(StrEnum):
    """Why a green ended (the hi-res log's gap-out, max-out and force-off events)."""

    GAP_OUT = "gap_out"
    MAX_OUT = "max_out"
    FORCE_OFF = "force_off"  # the coordinator's force-off point (or floating split), or phaseControlGroupForceOff
    YIELD = "yield"  # a coordinated phase ending after its yield point


@dataclass(frozen=True, slots=True)
class Change:
    """One interval change, for timelines and logs (a yellow says why its green ended)."""

    tick: int
    ring: int
    phase: int | None
    interval: Interval
    reason: Termination | None = None


@dataclass(frozen=True, slots=True)
class Inputs:
    """What the inputs ask of the rings: the control objects, the detectors and the running pattern, read as
    phase sets. A step reads them every tick but they change only with a write or a new pattern, so they are
    derived once per change (:attr:`Controller.inputs`)."""

    plan: Plan | None  # the pattern they were derived under
    calls: frozenset[int]  # vehicle calls the controller acts on (phaseStatusGroupVehCalls)
    holds: frozenset[int]
    omits: frozenset[int]  # PhaseOmit and the pattern's omitted splits
    ped_omits: frozenset[int]  # omits and PedOmit: no pedestrian call latches
    peds: frozenset[int]  # pedestrian calls asked: PedCall, pedestrian recall, the pattern's pedestrian recall
    pushed: frozenset[int]  # phases of the push buttons actuated now
    recalled: frozenset[int]  # demand whatever the calls: min and max recall, the pattern's recalls (not omitted)
    soft: frozenset[int]  # soft recall (not omitted): demand only while no other phase has any
    extending: frozenset[int]  # phases a green extends on without a call: max recall, the pattern's max recall


class Recorder(Protocol):
    """What watches the controller as a controller's data logger does (:mod:`emulator.model.datalogger`)."""

    def changed(self, change: Change) -> None:
        """An interval change, as the tick makes it."""

    def stepped(self) -> None:
        """A tick is done: what else it changed is there to read."""

    def powered_up(self) -> None:
        """The unit powered up again (:meth:`Controller.reset` after the first)."""


class Controller:
    """The controller model: state, control objects and the tick."""

    def __init__(self, config: IntersectionConfig, *, on_change: Callable[[Change], None] | None = None,
                 start: datetime | None = None) -> None:
        self.config = config
        self.on_change = on_change
        self.recorder: Recorder | None = None
        self.timing = {p: Timing.of(ph) for p, ph in config.phases.items()}
        self._barrier = {p: config.barrier_of(p) for p in config.phases}
        self._order = {p: ring.index(p) for ring in config.rings for p in ring}
        self._ring_of = {p: config.ring_of(p) for p in config.phases}
        self._recall = {rc: frozenset(p for p, ph in config.phases.items() if ph.recall is rc) for rc in Recall}
        self._detector_phase = config.detectors
        self._ped_detector_phase = config.ped_detectors
        self.backup_time = config.middleware.backup_time
        self.startup_flash = config.startup_flash
        # The controller's clock: local time, in ticks since midnight of the day it first powered up.
        start = start or config.emulator.start
        self.day0 = datetime.combine(start.date(), datetime.min.time())
        self.coordinator = Coordinator(config, clock=tenths((start - self.day0).total_seconds()))
        self.overlaps = Overlaps(config)
        self.preemptor = Preemptor(config)
        self.monitor = Monitor(config)
        # Counts changes of the status objects (what a poll reads), across power cycles too.
        # Inputs count too: they change the calls the status shows.
        self.status_version = 0
        self._inputs: Inputs | None = None  # derived from the inputs since the last write, if read since
        self._status_seen: tuple = ()
        self._images: dict[tuple | None, tuple[frozenset[int], ...]] = {}
        self._status: tuple[frozenset[int], ...] | None = None  # the image shown now
        self.reset()

    # --- lifecycle -------------------------------------------------------------------

    def reset(self) -> None:
        """Power-up: start-up flash, then start-up intervals; control objects cleared, not under system control."""
        self.tick = 0
        self.control: dict[ControlColumn, frozenset[int]] = {c: frozenset() for c in ControlColumn}
        self.max2_rings: frozenset[int] = frozenset()
        self.control_status = UnitControlStatus.OTHER
        self.flash_status = UnitFlashStatus.STARTUP if self.startup_flash else UnitFlashStatus.NOT_FLASH
        self.ped_calls: frozenset[int] = frozenset()  # latched pedestrian calls
        self.actuations: frozenset[int] = frozenset()  # vehicle detectors actuated now
        self.ped_actuations: frozenset[int] = frozenset()  # pedestrian detectors actuated now
        self._inputs = None
        # The image the monitor last passed: a power cycle puts every lamp out, so the monitor starts afresh.
        self._checked: tuple[frozenset[int], ...] | None = None
        self.monitor.reset()
        self._yellow_end: dict[int, int] = {}  # tick each phase's last yellow ended (red revert)
        self._since_set: int | None = None  # ticks since the last control SET; None = backup timer disarmed
        self.rings = [Ring(i + 1, order) for i, order in enumerate(self.config.rings)]
        self.coordinator.reset()
        self.overlaps.reset()
        self.preemptor.reset()
        self._caps: tuple[int, int] | None = None  # a preempt's caps on the yellow and red clearance, in ticks
        self._placed: Plan | None = None  # the plan the rings' coordination latches were placed under
        self.group = 0
        self._waiting_across = False  # demand on a phase of another barrier group, this tick
        self._restarting = False  # a pattern runs and a ring must restart its group through the barrier, this tick
        self._quiet = False  # the last step changed nothing discrete, and no input came since
        self._settled: tuple | None = None  # the discrete state the last step left, if nothing changed it since
        # quiet_ticks' proof: steps before this tick change nothing (None: none proven; every step is real)
        self._next_real: float | None = None
        if not self.flashing:
            self._power_up()
        self._refresh_status()
        if self.recorder is not None:
            self.recorder.powered_up()

    def _power_up(self) -> None:
        started = [p for p, ph in self.config.phases.items() if ph.startup in _STARTUP_INTERVAL]
        self.group = self._barrier[started[0]] if started else 0
        for p in started:
            ring = self.rings[self._ring_of[p] - 1]
            ring.phase = p
            self._enter(ring, _STARTUP_INTERVAL[self.config.phases[p].startup], notify=False)
        self._step_overlaps()

    def process(self, env: simpy.Environment, phase: float = 0.0):
        """SimPy process ticking the controller every 0.1 s, without accumulating float error.

        ``phase`` (0 <= phase < 0.1 s) shifts the tick grid: a real controller's ticks keep their
        own phase relative to whoever talks to it."""
        grid = Grid(env.now + phase, TICK)
        while True:
            yield env.timeout(grid.delay(self.tick + 1, env.now))
            self.step()

    # --- control objects ----------------------------------------------------------------

    def set_control(self, column: ControlColumn, phases: Iterable[int]) -> None:
        """A SET of one control object: replaces its phases and restarts the backup timer."""
        phases = frozenset(phases)
        if phases == self.control[column] and self.control_status is UnitControlStatus.SYSTEM_CONTROL:
            # The same phases again (a middleware repeats its calls): no input a step reads changed, so quiet time
            # goes on; the backup timer restarts (its threshold only moves later) and the status counts the write.
            self._since_set = 0
            self._settled = None
            self.status_version += 1
            return
        self.control[column] = phases
        self._system_set()

    def set_timing(self, phase: int, name: str, ticks: int) -> None:
        """A SET of the phase table: one timing of ``phase``, acting from that phase's next interval on."""
        setattr(self.timing[phase], name, ticks)
        self.touch()  # a threshold may have moved (red revert acts at once)

    def set_backup_time(self, seconds: int) -> None:
        """A SET of unitBackupTime: the backup timer's threshold moves at once."""
        self.backup_time = seconds
        self.touch()

    def set_pattern_control(self, value: int) -> None:
        """A SET of systemPatternControl: the system calls a pattern (1-253), free (254) or none (0: the local
        plan runs); like any control SET it restarts the backup timer."""
        self.coordinator.set_command(value)
        self._system_set()

    def set_preempt_control(self, preempts: Iterable[int]) -> None:
        """A SET of preemptControlState: these preempts are called (ON); like any control SET it restarts the
        backup timer ("A write to this object shall reset the Backup timer")."""
        self.preemptor.set_control(frozenset(preempts))
        self._system_set()

    def set_max2(self, rings: Iterable[int]) -> None:
        """A SET of ringControlGroupMax2: these rings time Maximum 2 from their next green."""
        self.max2_rings = frozenset(rings)
        self._system_set()

    def _system_set(self) -> None:
        self._since_set = 0
        self.control_status = UnitControlStatus.SYSTEM_CONTROL
        self.touch()

    def touch(self) -> None:
        """An input changed (a SET, a detector, a retimed phase, the backup time): the next step is a real one,
        and the status counts as changed (the calls it shows may have)."""
        self._quiet = False
        self._settled = None
        self._next_real = None
        self._inputs = None
        self.status_version += 1

    def set_actuations(self, detectors: Iterable[int]) -> None:
        """The vehicle detectors actuated now (a cabinet's detector inputs, or NTCIP's remote actuation).

        A detector calls its phase while actuated (non-locking: the call goes when the vehicle does) and,
        on a green, restarts the phase's passage timer; it is an input, not a system command, so it does
        not restart the backup timer."""
        self.actuations = frozenset(detectors)
        self.touch()

    def set_ped_actuations(self, detectors: Iterable[int]) -> None:
        """The pedestrian detectors (push buttons) actuated now: each latches a pedestrian call on its phase, as
        phaseControlGroupPedCall does (an input, like a vehicle detector: no backup timer restart)."""
        self.ped_actuations = frozenset(detectors)
        self.touch()

    @property
    def inputs(self) -> Inputs:
        """The inputs as phase sets; a write (:meth:`touch`) or a new pattern derives them anew."""
        plan = self.coordinator.plan
        if self._inputs is None or self._inputs.plan is not plan:
            self._inputs = self._derive_inputs(plan)
        return self._inputs

    def _derive_inputs(self, plan: Plan | None) -> Inputs:
        co, control, phases = self.coordinator, self.control, self.config.phases
        omits = control[ControlColumn.PHASE_OMIT] | co.omitted()
        # Vehicle calls: SET (VehCall) or from an actuated detector, configured and not omitted.
        detected = {self._detector_phase[d] for d in self.actuations if d in self._detector_phase}
        calls = (control[ControlColumn.VEH_CALL] | detected).intersection(phases) - control[ControlColumn.PHASE_OMIT]
        recall = self._recall
        return Inputs(
            plan=plan, calls=calls, holds=control[ControlColumn.HOLD], omits=omits,
            ped_omits=omits | control[ControlColumn.PED_OMIT],
            peds=control[ControlColumn.PED_CALL].intersection(phases) | recall[Recall.PED] | co.ped_recalled(),
            pushed=frozenset(self._ped_detector_phase[d] for d in self.ped_actuations if d in self._ped_detector_phase),
            recalled=(recall[Recall.MIN] | recall[Recall.MAX] | co.recalled()) - omits,
            soft=recall[Recall.SOFT] - omits,
            extending=recall[Recall.MAX] | co.max_recalled())

    @property
    def calls(self) -> frozenset[int]:
        """Vehicle calls the controller acts on: SET (VehCall) or from an actuated detector, configured and
        not omitted. The step and the logger read them here, never from ``inputs``: one place says which count."""
        return self.inputs.calls

    # --- status -------------------------------------------------------------------------

    @property
    def flashing(self) -> bool:
        return self.flash_status is not UnitFlashStatus.NOT_FLASH

    @property
    def short_alarm(self) -> ShortAlarm:
        """shortAlarmStatus: a preempt input is on; the MMU has put the unit in flash."""
        alarm = ShortAlarm.PREEMPT if self.preemptor.control else ShortAlarm(0)
        return alarm | ShortAlarm.TF_FLASH if self.flash_status is UnitFlashStatus.MMU else alarm

    @property
    def preempted(self) -> bool:
        """A preempt drives the rings (its entry, track clearance, dwell or exit)."""
        return self.preemptor.serving is not None

    def _refresh_status(self) -> None:
        # A controller shows a handful of distinct status images: each is built once, keyed by what it is
        # made of (every ring's interval, phase, next phase and pedestrian interval).
        key = None if self.flashing else (tuple(
            (r.interval, r.phase, r.target,
             r.interval is Interval.GREEN and (r.ticks < r.walk) + (r.ticks < r.walk + r.ped_clear))
            for r in self.rings), self.overlaps.discrete())
        status = self._images.get(key)
        if status is None:
            status = self._images[key] = self._status_image()
        if status is not self._status:
            self._status = status
            (self.greens, self.yellows, self.phase_ons, self.reds, self.walks, self.ped_clears, self.dont_walks,
             self.phase_nexts, self.overlap_greens, self.overlap_yellows, self.overlap_reds) = status
        # preemptState is status too: a poll reads it beside the signals, and a preempt's entry may start before
        # any indication changes.
        seen = (status, self.ped_calls, tuple(self.preemptor.states.values()))
        if seen != self._status_seen:
            self._status_seen = seen
            self.status_version += 1

    def _status_image(self) -> tuple[frozenset[int], ...]:
        greens, yellows, ons, walks, clears, nexts = set(), set(), set(), set(), set(), set()
        if not self.flashing:
            for r in self.rings:
                if r.interval is Interval.GREEN:
                    greens.add(r.phase)
                    if r.ticks < r.walk:
                        walks.add(r.phase)
                    elif r.ticks < r.walk + r.ped_clear:
                        clears.add(r.phase)
                elif r.interval is Interval.YELLOW:
                    yellows.add(r.phase)
                if r.interval is not Interval.DWELL:
                    ons.add(r.phase)
                if r.target is not None:
                    nexts.add(r.target)
        every = frozenset(self.config.phases)
        ov = self.overlaps
        overlaps = (frozenset(), frozenset()) if self.flashing else (ov.greens, ov.yellows)
        # greens, yellows, phase ons, reds, walks, pedestrian clears, don't walks, the phase each clearing
        # ring has committed to serve next (decided at the start of its yellow), and the overlaps' greens,
        # yellows and reds
        return (frozenset(greens), frozenset(yellows), frozenset(ons), every - greens - yellows, frozenset(walks),
                frozenset(clears), every - walks - clears, frozenset(nexts), *overlaps,
                frozenset(self.config.overlaps) - overlaps[0] - overlaps[1])

    # --- the tick -------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one tick (0.1 s)."""
        if self._next_real is not None and self.tick + 1 < self._next_real:
            # A tick quiet_ticks proved quiet, stepped for the recorder (a green's minimum to log at its tick).
            self.skip(1)
            if self.recorder is not None:
                self.recorder.stepped()
            return
        self._next_real = None
        before = self._settled if self._settled is not None else self._discrete()
        self._step()
        self._settled = self._discrete()
        self._quiet = self._settled == before or self._settles()
        if self.recorder is not None:
            self.recorder.stepped()

    def _step(self) -> None:
        self.tick += 1
        self._backup_timer()
        self._coordinate()
        if self.flash_status is UnitFlashStatus.STARTUP and self.tick >= self.startup_flash * 10:
            self.flash_status = UnitFlashStatus.NOT_FLASH
            self._power_up()
            self._refresh_status()
            return
        if self.flashing:
            return
        inputs = self.inputs
        demand = self._demand(inputs)
        pe = self.preemptor
        pe.step()
        self._caps = self._preempt_caps()
        if pe.started:
            self._preempt_entry()
        self._waiting_across = self._waits_across(demand)
        self._restarting = self.coordinator.plan is not None and any(self._restarts(r, demand) for r in self.rings)
        if self.config.next_phase_lock is NextPhaseLock.RED_END and pe.serving is None:
            # before timing: the tick that ends a red clearance still reads the calls of that clearance
            for r in self.rings:
                if r.interval in _CLEARANCE and r.target is not None:
                    self._redirect(r, demand)
        for r in self.rings:
            self._time(r, demand, inputs)
        if pe.serving is None:
            self._decide(demand)
        else:
            self._preempt()
        for r in self.rings:
            self._enter_target(r)
        if pe.serving is not None:
            self._preempt_progress()
        self._step_overlaps()
        self._refresh_status()
        self._monitor()

    def _discrete(self) -> tuple:
        """Everything a step can change but counters (see "Quiet time" above)."""
        return (self.group, self.flash_status, self.control_status, self.ped_calls, self.status_version,
                tuple(self.control.values()), self.coordinator.discrete(), self.overlaps.discrete(),
                self.preemptor.discrete(),
                tuple((r.phase, r.interval, r.target, r.gapped, r.forced, r.yielded, r.cut) for r in self.rings))

    # --- quiet time ----------------------------------------------------------------------

    def _settles(self) -> bool:
        """After a step that changed something: the next step changes nothing but counters, as a step that
        changed nothing would show (see "Quiet time" above). Proven here only where it is short: free, no
        preempt, no overlap, the next phase locked at the end of green.

        Nothing is proven for a next step that :meth:`quiet_ticks` makes real anyway (a counter reaches a
        threshold), so every comparison of a counter with a threshold is the same at the next tick as now: the
        predicates below are the step's own, read now. What the next step does, part by part: the backup timer,
        start-up flash and time-of-day plan act only at thresholds; the coordinator retries a pattern that this
        step could not start and fails alike; no preempt is called or active; the pedestrian calls latch as
        checked; a clearance only counts; a green's conflicting demand is what this step registered and its gap
        and max-out counters run as :meth:`skip` runs them (max recall runs the latter without conflicting
        demand), as checked, so its gap latch is decided as this step decided it; no ring is both ready and
        wishing, so ``_decide`` commits nothing and no green ends; a ring resting in red with a phase to start
        stays blocked (by another ring's green or clearance, which stays, or its red revert, a threshold); the
        status image, its walk thresholds unpassed, stays."""
        if (self.flashing or self.coordinator.plan is not None or self.config.overlaps
                or self.config.next_phase_lock is not NextPhaseLock.GREEN_END):
            return False
        pe = self.preemptor
        if pe.control or any(s is not PreemptState.NOT_ACTIVE for s in pe.states.values()):
            return False
        inputs = self.inputs
        if self._latched(inputs) != self.ped_calls:
            return False
        demand = self._wanted(inputs)
        # What the next step computes before anything reads it: set now, so the predicates below read it.
        self._waiting_across = self._waits_across(demand)
        for r in self.rings:
            if r.interval is Interval.GREEN:
                conflict = self._conflicting(r, demand)
                if ((r.gap == 0) != self._extending(r, inputs) or r.conflict != conflict
                        or (r.max_ticks > 0) != self._maximum_runs(r, conflict, inputs)):
                    return False  # a counter starts or stops, or the conflicting demand changes: not skip's work
            if self._ready(r) and self._wish(r, demand) is not None:
                return False
        return True

    def quiet_ticks(self) -> int | None:
        """How many steps from now the next one that may change anything is, inputs staying as they are:
        1 unless quiet time started (the last step changed nothing discrete, or :meth:`_settles` proved the
        next one will not) and no input came since; None when no step will."""
        self._next_real = None
        if not self._quiet:
            return 1
        ahead: list[int] = []
        logged: list[int] = []  # ticks the recorder needs stepped, though nothing changes there

        def until(counter: int, threshold: int) -> None:
            if counter < threshold:
                ahead.append(threshold - counter)

        if self._since_set is not None and self.backup_time:
            until(self._since_set, self.backup_time * 10)
        if self.flash_status is UnitFlashStatus.STARTUP:
            until(self.tick, self.startup_flash * 10)
        coordination = self.coordinator.quiet_ticks()
        if coordination is not None:
            ahead.append(coordination)
        if self.flashing:
            return min(ahead, default=None)
        preempt = self.preemptor.quiet_ticks()
        if preempt is not None:
            ahead.append(preempt)
        trailing = self.overlaps.quiet_ticks()
        if trailing is not None:
            ahead.append(max(1, trailing))
        # A green's minimum matters only with conflicting demand (registered by the last step, and constant in
        # quiet time): without any, the ready green has nowhere to go and no ring waits across the barrier for it.
        # While a pattern runs or a preempt is served it may be what ends it. The data logger logs it.
        minimums = self.coordinator.plan is not None or self.preemptor.serving is not None
        for r in self.rings:
            if r.interval is Interval.GREEN:
                if minimums or r.conflict:
                    until(r.ticks, r.minimum)
                elif self.recorder is not None and r.ticks < r.minimum:
                    logged.append(r.minimum - r.ticks)
                for threshold in (r.walk, r.walk + r.ped_clear, r.limit, r.cut):
                    until(r.ticks, threshold)
                if r.gap:
                    until(r.gap, r.passage)
                if r.max_ticks:
                    until(r.max_ticks, r.maximum)
            elif r.interval is Interval.DWELL:
                revert = None if r.target is None else self._yellow_end.get(r.target)
                if revert is not None:
                    until(self.tick, revert + self.timing[r.target].red_revert)
            else:
                until(r.ticks, r.length)
        self._next_real = self.tick + min(ahead) if ahead else math.inf
        return min(ahead + logged, default=None)

    def skip(self, n: int) -> None:
        """Advance ``n`` quiet ticks at once; ``n`` must be below :meth:`quiet_ticks` (or any, when None)."""
        if n <= 0:
            return
        self.tick += n
        self.coordinator.skip(n)
        if self._since_set is not None and self.backup_time:
            self._since_set += n
        if self.flashing:
            return
        self.overlaps.skip(n)
        self.preemptor.skip(n)
        for r in self.rings:
            if r.interval is not Interval.DWELL:
                r.ticks += n
            if r.gap:
                r.gap += n
            if r.max_ticks:
                r.max_ticks += n

    def advance(self, n: int) -> None:
        """Exactly ``n`` steps, quiet stretches skipped at once."""
        while n > 0:
            quiet = self.quiet_ticks()
            if quiet is None or quiet > n:
                self.skip(n)
                return
            self.skip(quiet - 1)
            self.step()
            n -= quiet

    def _backup_timer(self) -> None:
        if self._since_set is None or self.backup_time == 0:
            return
        self._since_set += 1
        if self._since_set >= self.backup_time * 10:
            log.warning("backup time %d s passed without a control SET: backup mode, control objects cleared",
                        self.backup_time)
            self.control = {c: frozenset() for c in ControlColumn}
            self.max2_rings = frozenset()
            self.coordinator.set_command(0)  # systemPatternControl: "reset ... to ZERO when in BACKUP Mode"
            self.preemptor.set_control(frozenset())  # preemptControlState, likewise
            self.control_status = UnitControlStatus.BACKUP_MODE
            self._since_set = None
            self.touch()  # the calls it shows are gone

    def _demand(self, inputs: Inputs) -> frozenset[int]:
        """Phases wanting service this tick, once the pedestrian calls of phases not showing green latched."""
        ped_calls = self._latched(inputs)
        if ped_calls != self.ped_calls:  # kept while it holds the same calls: the logger compares it every step
            self.ped_calls = ped_calls
        return self._wanted(inputs)

    def _latched(self, inputs: Inputs) -> frozenset[int]:
        """The pedestrian calls latched this tick: those asked on phases not showing green, and push buttons."""
        greens = {r.phase for r in self.rings if r.interval is Interval.GREEN}
        return (self.ped_calls | (inputs.peds - greens) | inputs.pushed) - inputs.ped_omits

    def _wanted(self, inputs: Inputs) -> frozenset[int]:
        """Phases wanting service: calls, latched pedestrian calls and recalls (while a pattern runs its coordinated
        phases and its split-mode recalls too), soft recalls when nothing else is."""
        demand = (self.calls - inputs.omits) | self.ped_calls | inputs.recalled
        soft = inputs.soft
        if soft and not demand - soft:
            demand |= soft
        return demand

    def _waits_across(self, demand: frozenset[int]) -> bool:
        """Demand waits across the barrier (which forbids backing); while a pattern runs only demand that can still
        be served in this cycle counts (a phase past its permissive period is skipped anyway), measured as its own
        ring measures it (:meth:`_serviceable`)."""
        plan = self.coordinator.plan
        return any(self._barrier[q] != self.group
                   and (plan is None or self._serviceable(self.rings[self._ring_of[q] - 1], q, demand))
                   for q in demand)

    def _restarts(self, r: Ring, demand: frozenset[int]) -> bool:
        """``r``'s next service is a backing that ``backup_prevent`` on its phase forbids: the ring will restart its
        barrier group through the barrier (see :meth:`_beyond`)."""
        if r.phase is None or not self.config.phases[r.phase].backup_prevent or not (
                r.interval is Interval.GREEN or (r.interval is Interval.DWELL and r.target is None)):
            return False
        q = self._wish(r, demand)
        return q is not None and self._backing(r, q)

    def _backing(self, r: Ring, q: int) -> bool:
        """Serving ``q`` next would back ``r`` up: ``q`` comes before the ring's phase in their barrier group."""
        p = r.phase
        return p is not None and self._barrier[p] == self._barrier[q] and self._order[q] < self._order[p]

    def _beyond(self, q: int) -> bool:
        """True when a phase with demand cannot be served in this visit of the barrier group: it lies across
        the barrier, or its ring would have to back into it while demand waits across the barrier, from a
        phase with ``backup_prevent``, or (a pattern running) while another ring restarts the group.

        The last case keeps the coordinated phases served. A ring that ``backup_prevent`` keeps from backing
        restarts its group through the barrier, which takes every ring: Naztec TecNote 3013 gives the option's
        purpose, to "insure that the controller never 'backs into' a protected left-turn phase", so it holds under
        coordination too. Had the other ring backed meanwhile into its coordinated phase, that phase would rest
        to its yield point a cycle later and hold the restarting ring at the barrier until then, its own
        coordinated phase unserved for that cycle. No source found (NTCIP 1202 defines no backup prevent; SUMO's
        NEMA controller has none) says what a controller does here; this choice keeps coordination's promise,
        every coordinated phase served every cycle, and in free mode (where a backed phase ends by its maximum)
        nothing changes."""
        if self._barrier[q] != self.group:
            return True
        r = self.rings[self._ring_of[q] - 1]
        return self._backing(r, q) and (self._waiting_across or self.config.phases[r.phase].backup_prevent
                                        or self._restarting)

    def _conflicting(self, r: Ring, demand: frozenset[int]) -> bool:
        return any(q != r.phase and (self._ring_of[q] == r.number or self._beyond(q)) for q in demand)

    def _time(self, r: Ring, demand: frozenset[int], inputs: Inputs) -> None:
        if r.interval is Interval.DWELL:
            return
        r.ticks += 1
        if r.interval is not Interval.GREEN:
            if r.ticks >= r.length:
                if r.interval is Interval.YELLOW:
                    self._yellow_end[r.phase] = self.tick
                self._enter(r, _NEXT[r.interval])
                if r.interval is Interval.RED_CLEAR and r.length == 0:
                    self._enter(r, Interval.DWELL)  # a red clearance a preempt's entry cut to nothing
            return
        r.gap = 0 if self._extending(r, inputs) else r.gap + 1
        r.conflict = self._conflicting(r, demand)
        r.max_ticks = r.max_ticks + 1 if self._maximum_runs(r, r.conflict, inputs) else 0
        if not r.conflict:
            r.gapped = False
        elif (r.ticks >= r.minimum and r.gap > 0 and r.gap >= r.passage
              and self.config.phases[r.phase].simultaneous_gap_disable):
            r.gapped = True

    @staticmethod
    def _maximum_runs(r: Ring, conflict: bool, inputs: Inputs) -> bool:
        """The green's maximum timer (Maximum 1 or 2) times this tick: with conflicting demand, or always under max
        recall. NTCIP 1202 phaseMaximum1 (phaseMaximum2 alike): "This time setting shall determine the maximum
        length of time this phase may be held in Green in the presence of a serviceable conflicting call. In the
        absence of a serviceable conflicting call the Maximum Green timer shall be held reset unless Max Vehicle
        Recall is enabled for this phase." So a max-recalled green times out its maximum and rests there: a
        conflicting call then ends it at once. While a pattern runs the maximum is inhibited (:meth:`_ending`)."""
        return conflict or r.phase in inputs.extending

    def _extending(self, r: Ring, inputs: Inputs) -> bool:
        """The green's phase is called (or recalled to its maximum): its passage timer restarts."""
        return r.phase in self.calls or r.phase in inputs.extending

    def _ready(self, r: Ring) -> bool:
        """A green that may end now, or a ring resting in red with nothing committed."""
        if r.interval is Interval.DWELL:
            return r.target is None
        return self._ending(r) is not None

    def _ending(self, r: Ring) -> Termination | None:
        """Why the ring's green may end now (None: it may not); a force-off before a gap-out before a max-out."""
        if r.interval is not Interval.GREEN or r.ticks < r.minimum or r.phase in self.inputs.holds:
            return None
        if r.phase in self.control[ControlColumn.FORCE_OFF]:
            return Termination.FORCE_OFF
        plan = self.coordinator.plan
        if plan is not None and r.phase == plan.coord[r.number]:
            # a coordinated phase ends only after its yield point, never gapped or maxed out
            return Termination.YIELD if r.yielded else None
        if r.gapped or (r.gap > 0 and r.gap >= r.passage):
            return Termination.GAP_OUT
        if plan is not None:  # coordination inhibits the maximum: the force-off points limit a green
            return Termination.FORCE_OFF if r.forced or (r.limit > 0 and r.ticks >= r.limit) else None
        return Termination.MAX_OUT if r.max_ticks >= r.maximum else None

    def _wish(self, r: Ring, demand: frozenset[int]) -> int | None:
        """The nearest phase with demand after the ring's own, in ring order.

        A ring resting in red may re-serve its own phase (last in the order). A ring leaves its coordinated
        phase for a phase only in that phase's permissive period (:meth:`Plan.permitted`: sequential
        periods, as SUMO's ``PhaseTransitionLogic::fromCoord``, written to match Econolite
        software-in-the-loop, SUMO pull request 10082)."""
        n = len(r.order)
        i = 0 if r.phase is None else self._order[r.phase]
        stop = n + 1 if r.interval is Interval.DWELL else n
        plan = self.coordinator.plan
        leaving = plan is not None and r.interval is Interval.GREEN and r.phase == plan.coord[r.number]
        for k in range(1, stop):
            q = r.order[(i + k) % n]
            if self._serviceable(r, q, demand):
                if leaving and not plan.permitted(r.order[(i + k - 1) % n], self.coordinator.timer):
                    return None  # outside q's permissive period the coordinated phase stays
                return q
        return None

    def _serviceable(self, r: Ring, q: int, demand: frozenset[int]) -> bool:
        """``q`` has demand and, while a pattern runs, still fits before its force-off point once ``r`` has
        cleared, and with it every ring showing a phase of another barrier group than ``q``'s (rings cross a
        barrier together: :meth:`_enter_target`). A phase that does not fit is skipped: its time goes to the
        phases after it."""
        if q not in demand:
            return False
        plan = self.coordinator.plan
        if plan is None:
            return True
        side = self._barrier[q]
        clear = max(self._clearance_left(o) for o in self.rings
                    if o is r or (o.interval is not Interval.DWELL and self._barrier[o.phase] != side))
        inputs = self.inputs
        # wanted for a vehicle, not only for its pedestrian call (soft recall counts as _wanted counts it: when
        # nothing else wants service)
        vehicle = (q in self.calls and q not in inputs.omits) or q in inputs.recalled or (
            q in inputs.soft and demand <= inputs.soft)
        return plan.fits(q, self.coordinator.timer, clear, walk=not vehicle and self.timing[q].walk > 0)

    def _walk_fits(self, phase: int) -> bool:
        """A green of ``phase`` starting now may serve its walk: no pattern runs, or its walk and pedestrian
        clearance end by its force-off point. Otherwise the pedestrian call waits for a cycle where they do: a
        controller without stop-in-walk keeps to its splits, and stop-in-walk "will allow an occasional pedestrian
        call to push the controller out of coordination" (Naztec, Coordination Modes+, MM->2->1)."""
        plan = self.coordinator.plan
        return plan is None or plan.fits(phase, self.coordinator.timer, 0, walk=True)

    def _clearance_left(self, r: Ring) -> int:
        tm = None if r.phase is None else self.timing[r.phase]
        if r.interval is Interval.GREEN:
            return tm.yellow + tm.red_clear
        if r.interval is Interval.YELLOW:
            return r.length - r.ticks + tm.red_clear
        if r.interval is Interval.RED_CLEAR:
            return r.length - r.ticks
        return 0

    def _redirect(self, r: Ring, demand: frozenset[int]) -> None:
        """``red_end`` lock: a ring in its clearance takes the nearest phase with demand after its own on the
        committed phase's side of the barrier (SUMO's ``NEMAPhase::trySwitch`` lets a later call override the
        decision "only if the new transition is on the same side of a barrier"); without one it keeps it."""
        side = self._barrier[r.target]
        n, i = len(r.order), self._order[r.phase]
        for k in range(1, n):
            q = r.order[(i + k) % n]
            if (self._barrier[q] == side and self._serviceable(r, q, demand)
                    and (side != self.group or not self._beyond(q))):
                r.target = q
                return

    def _decide(self, demand: frozenset[int]) -> None:
        ready = {r.number: self._ready(r) for r in self.rings}
        if not any(ready.values()):
            return  # most ticks: every ring is timing
        wish = {r.number: self._wish(r, demand) for r in self.rings if ready[r.number]}
        across = {n: q for n, q in wish.items() if q is not None and self._beyond(q)}
        all_ready = all(ready.values())
        for r in self.rings:
            q = wish.get(r.number)
            if q is None or r.number in across:
                continue
            if r.interval is Interval.GREEN and self._order[q] < self._order[r.phase] and all_ready and across:
                wish[r.number] = None  # both rings could cross: crossing goes before backing
                continue
            self._commit(r, q)
        if not across or not all(ready[r.number] and (wish[r.number] is None or r.number in across)
                                 for r in self.rings):
            return  # the ring wishing across waits at the barrier
        # Cross to the nearest group (cyclically) that a wish lies in; restart the group only when every
        # wish beyond it is a backing that backup_prevent forbids (crossing serves those on the way back).
        groups = {self._barrier[q] for q in across.values()}
        n = len(self.config.barriers)
        self.group = next(g for g in ((self.group + k) % n for k in range(1, n + 1)) if g in groups)
        for r in self.rings:
            target = across.get(r.number)
            if target is None or self._barrier[target] != self.group:
                # Nearest demand of the ring in the new group; a restarted group serves its own phase again.
                target = next((q for q in r.order if self._barrier[q] == self.group
                               and self._serviceable(r, q, demand)), None)
            if target is None:
                omit = self.control[ControlColumn.PHASE_OMIT]
                target = next((q for q in r.order if self._barrier[q] == self.group
                               and self.config.phases[q].dual_entry and q not in omit), None)
            self._commit(r, target)

    def _commit(self, r: Ring, target: int | None) -> None:
        """Commit the ring's next phase: a green ends (yellow starts), a resting red ring takes it."""
        r.target = target
        if r.interval is Interval.GREEN:
            reason = self._ending(r)
            self.control[ControlColumn.FORCE_OFF] -= {r.phase}
            self._enter(r, Interval.YELLOW, reason=reason)

    def _enter_target(self, r: Ring) -> None:
        if r.interval is not Interval.DWELL or r.target is None:
            return
        t = r.target
        if t in self.control[ControlColumn.PHASE_OMIT] and self.preemptor.serving is None:
            r.target = None  # omitted during the clearance: not serviced, choose again (a preempt overrides omits)
            return
        others_elsewhere = any(o is not r and o.interval is not Interval.DWELL
                               and self._barrier[o.phase] != self._barrier[t] for o in self.rings)
        revert = self._yellow_end.get(t)
        if others_elsewhere or (revert is not None and self.tick - revert < self.timing[t].red_revert):
            return
        if self.config.overlaps and self.overlaps.blocks(t, self._phases()):
            return  # an overlap it waits for still shows (or clears) after this tick
        r.phase, r.target = t, None
        self._enter(r, Interval.GREEN)

    def _enter(self, r: Ring, interval: Interval, *, notify: bool = True, reason: Termination | None = None) -> None:
        r.interval, r.ticks, r.max_ticks, r.conflict, r.gap, r.gapped = interval, 0, 0, False, 0, False
        tm = self.timing[r.phase]
        plan = self.coordinator.plan
        if plan is not None and r.phase == plan.coord[r.number] and interval is Interval.YELLOW:
            r.yielded = False
        if interval is Interval.GREEN:
            self._place(r)
            r.cut = 0
            called = r.phase in self.ped_calls and tm.walk > 0
            served = called and self._walk_fits(r.phase)
            if served or not called:
                self.ped_calls -= {r.phase}
            r.walk, r.ped_clear = (tm.walk, tm.ped_clear) if served else (0, 0)
            r.minimum = max(tm.min_green, r.walk + r.ped_clear)
            r.maximum = tm.max2 if r.number in self.max2_rings else tm.max1
            r.passage = tm.passage
        else:
            r.length = {Interval.YELLOW: tm.yellow, Interval.RED_CLEAR: tm.red_clear}.get(interval, 0)
            if self._caps is not None and interval in _CLEARANCE:
                r.length = min(r.length, self._caps[interval is Interval.RED_CLEAR])
        if notify and (self.on_change is not None or self.recorder is not None):
            change = Change(self.tick, r.number, r.phase, interval, reason)
            if self.on_change is not None:
                self.on_change(change)
            if self.recorder is not None:
                self.recorder.changed(change)

    # --- preemption ------------------------------------------------------------------------------

    def _preempt_targets(self) -> dict[int, int]:
        """Per ring, the phase the preempt being served wants green now (a ring without one rests in red; in
        the exit, it is left to itself)."""
        pe = self.preemptor
        n, state = pe.serving, pe.state
        p, tm = self.config.preempts[n], pe.timing[n]
        if state is PreemptState.ENTRY_STARTED:
            phases = p.track_phases if tm.track_green and p.track_phases else p.dwell_phases
        elif state is PreemptState.TRACK_SERVICE:
            phases = p.track_phases if pe.stage[n] < tm.track_green else p.dwell_phases
        elif state is PreemptState.DWELL:
            phases = p.dwell_phases
        else:
            phases = p.exit_phases
        return {self._ring_of[q]: q for q in phases}

    def _preempt_caps(self) -> tuple[int, int] | None:
        """The yellow and red clearance a preempt-initiated transition may shorten to (entry, track), or None."""
        pe = self.preemptor
        if pe.state is PreemptState.ENTRY_STARTED:
            tm = pe.timing[pe.serving]
            return tm.enter_yellow, tm.enter_red
        if pe.state is PreemptState.TRACK_SERVICE:
            tm = pe.timing[pe.serving]
            return tm.track_yellow, tm.track_red
        return None

    def _preempt_entry(self) -> None:
        """A preempt's entry starts: running clearances shorten to its caps, and each green's end is set to the
        lesser of its minimum green and the preempt's, its walk and pedestrian clearance likewise."""
        tm = self.preemptor.timing[self.preemptor.serving]
        for r in self.rings:
            if r.interval in _CLEARANCE:
                r.length = min(r.length, self._caps[r.interval is Interval.RED_CLEAR])
            elif r.interval is Interval.GREEN:
                walked = r.walk > 0  # this green serves a walk (its walk may be cut to nothing below)
                if walked and r.ticks < r.walk:
                    r.walk = max(r.ticks, min(r.walk, tm.min_walk))
                if walked and r.ticks < r.walk + r.ped_clear:
                    r.ped_clear = max(r.ticks - r.walk, min(r.ped_clear, tm.enter_ped_clear))
                r.cut = max(min(self.timing[r.phase].min_green, tm.min_green), r.walk + r.ped_clear)

    def _preempt(self) -> None:
        """The preempt being served drives the rings to its phases: a green of another phase ends once it may
        (its entry minimum, the end of the track green, else its minimum), a clearing or resting ring takes the
        preempt's phase as its next. In the exit a ring without an exit phase keeps what it shows, unless that is
        a green across the barrier from the exit phases: it clears to red."""
        pe = self.preemptor
        state = pe.state
        targets = self._preempt_targets()
        exit_group = next((self._barrier[q] for q in targets.values()), None)
        for r in self.rings:
            t = targets.get(r.number)
            if t is None and state is PreemptState.EXIT_STARTED and (
                    r.interval is not Interval.GREEN or exit_group in (None, self._barrier[r.phase])):
                continue  # no exit phase of its own: left to itself, unless it holds the exit across a barrier
            if r.interval is Interval.GREEN:
                if r.phase == t:
                    continue
                limit = {PreemptState.ENTRY_STARTED: r.cut, PreemptState.TRACK_SERVICE: 0}.get(state, r.minimum)
                if r.ticks >= limit:
                    self._commit(r, t)
            else:
                r.target = t
            if t is not None:
                self.group = self._barrier[t]

    def _preempt_progress(self) -> None:
        """After the rings moved: the entry, track clearance or exit is done when every ring shows its phase (or,
        without one, rests in red)."""
        pe = self.preemptor
        n, state = pe.serving, pe.state
        targets = self._preempt_targets()

        def there(r: Ring) -> bool:
            t = targets.get(r.number)
            if t is None:
                return state is PreemptState.EXIT_STARTED or (r.interval is Interval.DWELL and r.target is None)
            return r.interval is Interval.GREEN and r.phase == t

        if not all(there(r) for r in self.rings):
            return
        if state is PreemptState.ENTRY_STARTED:
            track = pe.timing[n].track_green and self.config.preempts[n].track_phases
            pe.event(n, Event.CLEARED_TO_TRACK if track else Event.CLEARED)
        elif state is PreemptState.TRACK_SERVICE and pe.stage[n] >= pe.timing[n].track_green:
            pe.event(n, Event.TRACKED)
        elif state is PreemptState.EXIT_STARTED:
            pe.event(n, Event.EXITED)

    # --- coordination --------------------------------------------------------------------------

    def _coordinate(self) -> None:
        """One tick of the coordinator; the rings' force-off and yield latches follow the points it passed."""
        co = self.coordinator
        co.step()
        plan = co.plan
        if plan is not self._placed:  # a pattern started (or the unit powered up in one): where is each ring?
            self._placed = plan
            for r in self.rings:
                r.yielded = plan is not None and not plan.held(plan.coord[r.number], co.timer)
                self._place(r)
            return
        if plan is None:
            return
        for r in self.rings:
            if plan.force_off[plan.coord[r.number]] in co.passed:
                r.yielded = True
            if (r.interval is Interval.GREEN and r.phase not in plan.coord.values()
                    and plan.force_off[r.phase] in co.passed):
                r.forced = True

    def _place(self, r: Ring) -> None:
        """A green starts (or a pattern starts under it): its force-off latch and floating limit."""
        plan, co = self.coordinator.plan, self.coordinator
        if plan is None or r.interval is not Interval.GREEN or r.phase in plan.coord.values():
            r.forced, r.limit = False, 0
            return
        r.forced = not plan.in_window(r.phase, co.timer)
        floating = co.force_mode is CoordForceMode.FLOATING
        r.limit = plan.split[r.phase] - plan.clearance[r.phase] if floating else 0

    def _step_overlaps(self) -> None:
        """The overlaps follow what the phases show after this tick's timing."""
        if self.config.overlaps:
            self.overlaps.step(self._phases())

    def _phases(self) -> Phases:
        """What the rings show now, as the overlaps read it."""
        rings = self.rings
        return Phases(
            greens=frozenset(r.phase for r in rings if r.interval is Interval.GREEN),
            yellows=frozenset(r.phase for r in rings if r.interval is Interval.YELLOW),
            starting=frozenset(r.phase for r in rings if r.interval is Interval.YELLOW and r.ticks == 0),
            nexts={r.phase: r.target for r in rings if r.interval is not Interval.GREEN and r.phase is not None},
            committed=frozenset(r.target for r in rings if r.target is not None))

    def _monitor(self) -> None:
        if self._status is self._checked:
            return  # what it sees is all in the status image, and this one passed
        lamps = Lamps(self.greens, self.yellows, self.overlap_greens, self.overlap_yellows)
        fault = self.monitor.check(lamps, self.tick)
        if fault is None:
            self._checked = self._status
        else:
            log.error("conflict monitor: %s at tick %d: flash", fault, self.tick)
            self.flash_status = UnitFlashStatus.MMU
            self._refresh_status()
