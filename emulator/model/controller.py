"""A dual-ring NEMA actuated controller, ticking every 0.1 s: the units of a cabinet, assembled.

Rules of this file
------------------
- Time is an integer count of ticks (tenths of a second), as in a real
  controller; no float time is compared anywhere in here.
- :meth:`Controller.step` is the only thing that advances timing. It reads the
  control objects (calls, holds, force-offs, omits) as they are at that tick and
  ticks the units in a fixed order (:meth:`Controller._step`): the backup timer,
  the coordinator and its part in the rings, the inputs and the pedestrian calls,
  the preemptor and its part in the rings, the ring timers, the sequencer, the
  overlaps, the status and the monitor.
- The controller decides nothing of its own about the rings: their intervals move
  by their table (:mod:`emulator.model.ring`) through :meth:`Controller._move`,
  which also tells the units that care (the pedestrian calls a green serves, the
  coordinator's latches, a preempt's entry minimum, the recorder); which phase is
  next and when a green ends is the sequencer's (:mod:`emulator.model.sequencer`);
  what a pattern or a preempt asks is theirs (:mod:`emulator.model.coordinated`,
  :mod:`emulator.model.preempted`).
- :meth:`Controller.advance` (n ticks) is exactly n calls of :meth:`Controller.step`:
  it only skips ticks that quiet time (:mod:`emulator.model.quiet`) proves change
  nothing but counters (a property test holds the two together).
- A recorder (the data logger, :mod:`emulator.model.datalogger`) hears every
  interval change, a yellow with why its green ended (the very reason the
  sequencer's ``ending`` acts on), the end of every step and a power-up; it reads
  and never acts.
- The controller's clock is the coordinator's: local time in ticks since
  midnight of the day it first powered up (``start``: ``[emulator] start``, or
  the host's time when served). A power cycle resets ``tick``, not the clock.

Theory of operation
-------------------
The units, as a cabinet has them: a timer per ring (:mod:`emulator.model.ring`),
the sequencer (:mod:`emulator.model.sequencer`), the coordinator
(:mod:`emulator.model.coordination`) and its part in the rings
(:mod:`emulator.model.coordinated`), the preemptor
(:mod:`emulator.model.preemption`) and its part in the rings
(:mod:`emulator.model.preempted`), the overlaps (:mod:`emulator.model.overlaps`),
the pedestrian calls (:mod:`emulator.model.pedestrians`), the backup timer
(:mod:`emulator.model.backup`) and the monitor (:mod:`emulator.model.monitor`).
The inputs are read as phase sets (:mod:`emulator.model.inputs`) once per write.

When the backup timer (unitBackupTime) passes without a control SET, the
controller reports backupMode and clears every control object. After power-up
the controller flashes for unitStartUpFlash seconds, then starts its start-up
intervals. The monitor (the cabinet's MMU,
:mod:`emulator.model.monitor`) sees the lamps after every tick that changed
them: two conflicting signals lit together (phases, or an overlap and a phase)
or a channel leaving its green without a yellow of at least 2.7 s is a fault,
and the controller goes to flash (all red) and stops timing. Overlaps follow the
phases at the end of each tick.

Quiet time (:mod:`emulator.model.quiet`). Most ticks change nothing but counters: every unit says when it next
acts (the backup timer, the coordinator, the pedestrian calls, the preemptor and its part in the rings, the
overlaps and, through the sequencer, the ring timers and every decision the sequencer takes), and
:meth:`Controller.advance` skips the ticks before the least of those deadlines at once (:meth:`Controller.skip`).
Any input (a SET, a detector, a retiming) makes the next step a real one: :meth:`Controller.touch`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from datetime import datetime
from typing import Protocol

import simpy

from emulator.model.backup import BackupTimer
from emulator.model.coordinated import Coordinated
from emulator.model.coordination import Coordinator
from emulator.model.detectors import Detectors
from emulator.model.inputs import Inputs, Reader
from emulator.model.monitor import Monitor
from emulator.model.overlaps import Overlaps, Phases
from emulator.model.pedestrians import PedCalls
from emulator.model.preempted import Preempted
from emulator.model.preemption import Preemptor
from emulator.model.quiet import QuietTime
from emulator.model.ring import (
    CLEARANCE,
    GREEN,
    SETTABLE,
    STARTUP,
    Change,
    Event,
    Interval,
    Ring,
    Termination,
    Timing,
    tenths,
)
from emulator.model.sequencer import Sequencer
from emulator.model.spat import SignalTiming, announce
from emulator.model.status import Image, Images
from hils.protocol.config import IntersectionConfig, NextPhaseLock
from hils.protocol.ntcip import ControlColumn, ShortAlarm, UnitControlStatus, UnitFlashStatus
from hils.protocol.timegrid import Grid

__all__ = ["TICK", "Change", "Controller", "Inputs", "Interval", "Recorder", "Termination", "Timing", "tenths"]

log = logging.getLogger(__name__)

TICK = 0.1  # seconds per controller tick

# Bound once (Python 3.11's EnumType.__getattr__ makes every member lookup through the class slow): a SET reads it.
SYSTEM_CONTROL = UnitControlStatus.SYSTEM_CONTROL


class Recorder(Protocol):
    """What watches the controller as a controller's data logger does (:mod:`emulator.model.datalogger`)."""

    def changed(self, ring: Ring, reason: Termination | None) -> None:
        """``ring`` entered its interval at this tick (a yellow with ``reason``, why its green ended)."""

    def stepped(self) -> None:
        """A tick is done: what else it changed is there to read."""

    def powered_up(self) -> None:
        """The unit powered up again (:meth:`Controller.reset` after the first)."""


class Controller:
    """The controller model: its units, its control objects and the tick."""

    def __init__(self, config: IntersectionConfig, *, on_change: Callable[[Change], None] | None = None,
                 start: datetime | None = None) -> None:
        self.config = config
        self.on_change = on_change
        self.recorder: Recorder | None = None
        self.timing = {p: Timing.of(ph) for p, ph in config.phases.items()}
        self._barrier = {p: config.barrier_of(p) for p in config.phases}
        self._ring_of = {p: config.ring_of(p) for p in config.phases}
        self._red_end_lock = config.next_phase_lock is NextPhaseLock.RED_END
        self._reader = Reader(config)
        self.detectors = Detectors(config)
        self.backup = BackupTimer(config.middleware.backup_time)
        self.startup_flash = config.startup_flash
        # The controller's clock: local time, in ticks since midnight of the day it first powered up.
        start = start or config.emulator.start
        self.day0 = datetime.combine(start.date(), datetime.min.time())
        self.control: dict[ControlColumn, frozenset[int]] = dict.fromkeys(ControlColumn, frozenset())
        self.rings: list[Ring] = []
        self.coordinator = Coordinator(config, clock=tenths((start - self.day0).total_seconds()))
        self.coordinated = Coordinated(config, self.coordinator, self.timing)
        self.overlaps = Overlaps(config)
        self.preemptor = Preemptor(config)
        self.preempting = Preempted(config, self.preemptor, self.timing)
        self.monitor = Monitor(config)
        self.peds = PedCalls(self.timing, self.coordinated,
                             frozenset(p for p, ph in config.phases.items() if ph.ped_recycle), self.rings)
        self.sequencer = Sequencer(config, self.rings, self.timing, self.control, self.coordinated, self.preemptor,
                                   self.overlaps, self._move)
        # Counts changes of the status objects (what a poll reads), across power cycles too.
        # Inputs count too: they change the calls the status shows.
        self.status_version = 0
        self._inputs: Inputs | None = None  # derived from the inputs since the last write, if read since
        self._status_seen: tuple = ()
        self.images = Images(config)
        self.quiet = QuietTime(self)
        self._status: Image | None = None  # the image shown now
        self.reset()

    # --- lifecycle -------------------------------------------------------------------

    def reset(self) -> None:
        """Power-up: start-up flash, then start-up intervals; control objects cleared, not under system control."""
        self.tick = 0
        self.control.update(dict.fromkeys(ControlColumn, frozenset()))
        self.max2_rings: frozenset[int] = frozenset()
        self.control_status = UnitControlStatus.OTHER
        self._flash(UnitFlashStatus.STARTUP if self.startup_flash else UnitFlashStatus.NOT_FLASH)
        self.peds.reset()
        self.actuations: frozenset[int] = frozenset()  # vehicle detectors actuated now
        self.ped_actuations: frozenset[int] = frozenset()  # pedestrian detectors actuated now
        self.detectors.reset()
        self._inputs = None
        self.monitor.reset()  # a power cycle puts every lamp out: the monitor starts afresh
        self.backup.reset()
        self.rings[:] = [Ring(i + 1, order) for i, order in enumerate(self.config.rings)]
        self.coordinator.reset()
        self.coordinated.reset()
        self.overlaps.reset()
        self.preemptor.reset()
        self.preempting.reset()
        self.sequencer.reset()
        self.quiet.touched()
        if not self.flashing:
            self._power_up()
        self._refresh_status()
        if self.recorder is not None:
            self.recorder.powered_up()

    def _power_up(self) -> None:
        started = [p for p, ph in self.config.phases.items() if ph.startup in STARTUP]
        self.sequencer.group = self._barrier[started[0]] if started else 0
        for p in started:
            ring = self.rings[self._ring_of[p] - 1]
            ring.phase = p
            self._move(ring, STARTUP[self.config.phases[p].startup], notify=False)
        if self.config.overlaps:  # they follow what the phases show
            self.overlaps.step(Phases.of(self.rings))

    def process(self, env: simpy.Environment, phase: float = 0.0):
        """SimPy process ticking the controller every 0.1 s, without accumulating float error.

        ``phase`` (0 <= phase < 0.1 s) shifts the tick grid: a real controller's ticks keep their
        own phase relative to whoever talks to it."""
        grid = Grid(env.now + phase, TICK)
        while True:
            yield env.timeout(grid.delay(self.tick + 1, env.now))
            self.step()

    @property
    def group(self) -> int:
        """The barrier group the rings serve (the sequencer's)."""
        return self.sequencer.group

    # --- control objects ----------------------------------------------------------------

    def set_control(self, column: ControlColumn, phases: Iterable[int]) -> None:
        """A SET of one control object: replaces its phases and restarts the backup timer."""
        phases = frozenset(phases)
        if phases == self.control[column] and self.control_status is SYSTEM_CONTROL:
            # The same phases again (a middleware repeats its calls): no input a step reads changed, so quiet time
            # goes on; the backup timer restarts (its threshold only moves later) and the status counts the write.
            self.backup.restart()
            self.quiet.written()
            self.status_version += 1
            return
        self.control[column] = phases
        self._system_set()

    def set_timing(self, phase: int, name: str, ticks: int) -> None:
        """A SET of the phase table: one timing of ``phase``, acting from that phase's next interval on; a value its
        object cannot hold (:data:`emulator.model.ring.SETTABLE`: a yellow under 3.0 s, say) is refused."""
        allowed = SETTABLE[name]
        if ticks not in allowed:
            raise ValueError(f"phase {phase} {name} = {ticks} ticks; allowed: {allowed.start}..{allowed.stop - 1} "
                             f"ticks in steps of {allowed.step} (its NTCIP 1202 phase-table object's range)")
        setattr(self.timing[phase], name, ticks)
        self.touch()  # a threshold may have moved (red revert acts at once)

    def set_backup_time(self, seconds: int) -> None:
        """A SET of unitBackupTime: the backup timer's threshold moves at once."""
        self.backup.seconds = seconds
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

    backup_time = property(lambda self: self.backup.seconds, lambda self, s: setattr(self.backup, "seconds", s),
                           doc="unitBackupTime, in seconds (the backup timer's).")

    def _system_set(self) -> None:
        self.backup.restart()
        self.control_status = SYSTEM_CONTROL
        self.touch()

    def touch(self) -> None:
        """An input changed (a SET, a detector, a retiming): the next step is a real one, the status counts a change."""
        self.quiet.touched()
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
            self._inputs = self._reader.read(self.coordinator, self.control, self.detected, self.ped_actuations)
        return self._inputs

    @property
    def detected(self) -> frozenset[int]:
        """The vehicle detectors the controller acts on: the actuated ones, as their delay, extension and carryover
        pass them (the detector unit's, :mod:`emulator.model.detectors`)."""
        return self.detectors.recognized if self.detectors.timers else self.actuations

    @property
    def ped_calls(self) -> frozenset[int]:
        """The latched pedestrian calls (the pedestrian unit's)."""
        return self.peds.calls

    @property
    def calls(self) -> frozenset[int]:
        """Vehicle calls the controller acts on: SET (VehCall) or from an actuated detector, configured and
        not omitted. The step and the logger read them here, never from ``inputs``: one place says which count."""
        return self.inputs.calls

    # --- status -------------------------------------------------------------------------

    def _flash(self, status: UnitFlashStatus) -> None:
        """unitFlashStatus becomes ``status``; ``flashing`` follows it (both read every tick, so kept, not derived)."""
        self.flash_status = status
        self.flashing = status is not UnitFlashStatus.NOT_FLASH

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
        status = self.images.of(self.rings, self.overlaps, self.flashing)
        if status is not self._status:
            self._status = status
            (self.greens, self.yellows, self.phase_ons, self.reds, self.walks, self.ped_clears, self.dont_walks,
             self.phase_nexts, self.overlap_greens, self.overlap_yellows, self.overlap_reds) = status
        # preemptState is status too: a poll reads it beside the signals, and a preempt's entry may start before
        # any indication changes.
        seen = (status, self.peds.calls, tuple(self.preemptor.states.values()) if self.config.preempts else ())
        if seen != self._status_seen:
            self._status_seen = seen
            self.status_version += 1

    def _backup_mode(self) -> None:
        log.warning("backup time %d s passed without a control SET: backup mode, control objects cleared",
                    self.backup_time)
        self.control.update(dict.fromkeys(ControlColumn, frozenset()))
        self.max2_rings = frozenset()
        self.coordinator.set_command(0)  # systemPatternControl: "reset ... to ZERO when in BACKUP Mode"
        self.preemptor.set_control(frozenset())  # preemptControlState, likewise
        self.control_status = UnitControlStatus.BACKUP_MODE
        self.touch()  # the calls it shows are gone

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

    # --- the tick -------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one tick (0.1 s)."""
        if self.quiet.proven():
            self.skip(1)  # a tick quiet time proved quiet: counted
            return
        self._step()
        self.quiet.stepped()
        if self.recorder is not None:
            self.recorder.stepped()

    def _step(self) -> None:
        """One tick of the units, in their order."""
        self.tick += 1
        if self.backup.step():
            self._backup_mode()
        self.coordinator.step()
        self.coordinated.step(self.rings)
        if self.flashing and self.flash_status is UnitFlashStatus.STARTUP and self.tick >= self.startup_flash * 10:
            self._flash(UnitFlashStatus.NOT_FLASH)
            self._power_up()
            self._refresh_status()
            return
        if self.flashing:
            return
        if self.detectors.timers and self.detectors.step(self.actuations, self.greens):
            self._inputs = None  # the calls and extensions the detectors place changed: so may the status
            self.status_version += 1
        inputs = self.inputs
        demand = self.peds.latch(self.greens, inputs)  # the status image: the greens as the last tick left them
        pe, seq = self.preemptor, self.sequencer
        if self.config.preempts:
            pe.step()
            self.preempting.caps_now()
            if pe.started:
                self.preempting.entry(self.rings)
        cycling = self.preempting.cycling(demand) if pe.serving is not None else None
        if cycling is not None:
            demand, omitted = cycling
        seq.prepare(demand, inputs)
        if self._red_end_lock and pe.serving is None:
            # before timing: the tick that ends a red clearance still reads the calls of that clearance
            for r in self.rings:
                if r.interval in CLEARANCE and r.target is not None:
                    seq.redirect(r, demand, inputs)
        seq.time(demand, inputs, self.tick)
        if pe.serving is None:
            if self.peds.recycling:
                self.peds.recycle(self.rings)
            seq.decide(demand, inputs)
        elif cycling is not None:
            seq.decide(demand, inputs, omitted)
        else:
            self.preempting.drive(seq, inputs)
        seq.start(self.tick)
        if pe.serving is not None:
            self.preempting.progress(self.rings)
        if self.config.overlaps:  # they follow what the phases show after this tick's timing
            self.overlaps.step(Phases.of(self.rings))
        self._refresh_status()
        self._monitor()

    def _move(self, r: Ring, event: Event, *, reason: Termination | None = None, notify: bool = True) -> None:
        """Move ``r`` by ``event`` (its table) and tell the units that care: the coordinator's latches, a preempt's
        entry minimum (none yet for a new green), the listeners."""
        interval = r.move(event, self.timing[r.phase], walk=self.peds.serve, max2=r.number in self.max2_rings,
                          caps=self.preempting.caps)
        self.coordinated.entered(r)
        if interval is GREEN:
            self.preempting.cut[r.number] = 0
        if notify:
            if self.on_change is not None:
                self.on_change(Change(self.tick, r.number, r.phase, interval, reason))
            if self.recorder is not None:
                self.recorder.changed(r, reason)

    def _monitor(self) -> None:
        fault = self.monitor.watch(self._status, self.tick)
        if fault is not None:
            log.error("conflict monitor: %s at tick %d: flash", fault, self.tick)
            self._flash(UnitFlashStatus.MMU)
            self._refresh_status()

    def spat(self) -> tuple[SignalTiming, ...]:
        """Each phase's and overlap's indication and the earliest, latest and likely tick of its next change, in
        ticks from now (:mod:`emulator.model.spat`)."""
        return announce(self)

    # --- quiet time ----------------------------------------------------------------------

    def quiet_ticks(self) -> int | None:
        """How many steps from now the next one that may change anything is, inputs staying as they are (None:
        none will): :meth:`emulator.model.quiet.QuietTime.ticks`."""
        return self.quiet.ticks()

    def skip(self, n: int) -> None:
        """Advance ``n`` quiet ticks at once; ``n`` must be below :meth:`quiet_ticks` (or any, when None)."""
        self.quiet.skip(n)
