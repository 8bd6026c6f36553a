"""Detectors: stop-bar presence in SUMO becomes the controller's detector inputs, and vehicles of a preempt's
classes in its detection zone its preempt input, over NTCIP.

A cabinet wires its loops to the controller's detector inputs; the controller places calls and extends
greens from them by its passage timer. Here every SUMO step reads which phases have a vehicle in their
stop-bar presence zone (:meth:`hils.sim.sumo.SumoSimulation.present`), maps them to vehicle detector numbers
(:attr:`hils.protocol.config.IntersectionConfig.detectors`: the config's ``[detectors]`` table, a loop per lane where it
names the lane, else one loop over every approach lane of the detector's phase; by default one detector per
phase numbered as the phase) and,
when that set changes, SETs NTCIP 1202 v03's ``vehicleDetectorControlGroupActuation`` (a set bit forces
that detector's actuation) through the run's transport: the same object in virtual time and against a
controller that accepts remote actuation at wall clock. A controller that does not (the standard marks
the object for testing) needs the lab's detector interface instead; the SET's refusal is logged.

Each change is one ``detectors`` record (the detectors actuated now), so the summary can count the
actuations per phase and a reader can see the controller was actuated. These SETs are cabinet inputs,
not commands: they do not go through the manager and are not ``set_sent`` records.

A preempt whose config names a detection zone (``vehicles``, ``approach``, ``zone``) is called while SUMO shows
a vehicle of those classes or types in it (:meth:`hils.sim.sumo.Light.preempt_calls`): on change the feed SETs the
preempt's ``preemptControlState`` (NTCIP 1202: ON "shall cause the associated preempt actions to occur") and logs
a ``preempt_inputs`` record. A rail crossing's or an emergency vehicle's detector wired to a cabinet's preempt
input does the same at a real controller; over NTCIP the standard's object is the remote one, which also
restarts the backup timer.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

import simpy

from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.ntcip import DETECTOR_ACTUATION, PREEMPT_CONTROL_STATE, phases_to_groups
from hils.shell.events import EventLog, Kind
from hils.shell.transport import Transport

__all__ = ["DetectorError", "DetectorFeed"]


class DetectorError(UserError):
    """A detector the network cannot carry: its lane is not an approach lane of its phase."""


class DetectorFeed:
    """Hands the lanes SUMO shows occupied at the stop bar to the controller as detector actuations, on change."""

    def __init__(self, transport: Transport, config: IntersectionConfig, events: EventLog,
                 lanes_of_phase: Mapping[int, Sequence[str]], *, detectors: bool = True,
                 preempt_calls: Callable[[], frozenset[int]] | None = None) -> None:
        self.transport = transport
        self.events = events
        self.detectors = detectors
        self.preempt_calls = preempt_calls  # the preempts SUMO calls now (None: no preempt input from SUMO)
        self.preempts: frozenset[int] = frozenset()
        # Each detector's loop: the lane the config gives it, else every approach lane of its phase.
        self.lanes_of = {d: frozenset([config.detector_lanes[d]] if d in config.detector_lanes
                                      else lanes_of_phase.get(phase, ()))
                         for d, phase in config.detectors.items()}
        for d, lane in config.detector_lanes.items():
            phase = config.detectors[d]
            if lane not in lanes_of_phase.get(phase, ()):
                raise DetectorError(f"{config.source}: detectors.{d}: lane {lane!r} is not an approach lane of "
                                    f"phase {phase}; allowed: {', '.join(lanes_of_phase.get(phase, ())) or 'none'}")
        self.groups = (max(config.detectors) + 7) // 8
        self.actuated: frozenset[int] = frozenset()

    def feed(self, present: Iterable[str]) -> None:
        """The lanes with a vehicle on their stop-bar zone now; SET the actuations when they changed, and the
        preempt inputs when the preempts SUMO calls changed."""
        if self.preempt_calls is not None:
            self._preempt(self.preempt_calls())
        if not self.detectors:
            return
        lanes = frozenset(present)
        actuated = frozenset(d for d, loop in self.lanes_of.items() if loop & lanes)
        if actuated == self.actuated:
            return
        self.actuated = actuated
        self.events.emit(Kind.DETECTORS, active=sorted(actuated))
        masks = phases_to_groups(actuated, self.groups)
        done = self.transport.set([(DETECTOR_ACTUATION.instance(g), m) for g, m in enumerate(masks, start=1)])
        done.callbacks.append(self._answered)

    def _preempt(self, called: frozenset[int]) -> None:
        if called == self.preempts:
            return
        changed = called ^ self.preempts
        self.preempts = called
        self.events.emit(Kind.PREEMPT_INPUTS, active=sorted(called))
        done = self.transport.set([(PREEMPT_CONTROL_STATE.instance(n), int(n in called)) for n in sorted(changed)])
        done.callbacks.append(lambda ev: self._answered(ev, "preempt input"))

    def _answered(self, ev: simpy.Event, what: str = "detector actuation") -> None:
        if not ev.ok:
            ev.defused = True
            self.events.emit(Kind.NOTE, message=f"{what} SET failed: {type(ev.value).__name__}: {ev.value}")
