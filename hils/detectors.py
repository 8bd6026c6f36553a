"""Detectors: stop-bar presence in SUMO becomes the controller's detector inputs, over NTCIP.

A cabinet wires its loops to the controller's detector inputs; the controller places calls and extends
greens from them by its passage timer. Here every SUMO step reads which phases have a vehicle in their
stop-bar presence zone (:meth:`hils.sumo.SumoSimulation.present`), maps them to vehicle detector numbers
(:attr:`hils.config.IntersectionConfig.detectors`: the config's ``[detectors]`` table, by default one
detector per phase numbered as the phase; every detector of a present phase is actuated) and,
when that set changes, SETs NTCIP 1202 v03's ``vehicleDetectorControlGroupActuation`` (a set bit forces
that detector's actuation) through the run's transport: the same object in virtual time and against a
controller that accepts remote actuation at wall clock. A controller that does not (the standard marks
the object for testing) needs the lab's detector interface instead; the SET's refusal is logged.

Each change is one ``detectors`` record (the detectors actuated now), so the summary can count the
actuations per phase and a reader can see the controller was actuated. These SETs are cabinet inputs,
not commands: they do not go through the manager and are not ``set_sent`` records.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from typing import Any

import simpy

from hils.config import IntersectionConfig
from hils.events import EventLog, Kind
from hils.ntcip import DETECTOR_ACTUATION, phases_to_groups
from hils.transport import Transport

log = logging.getLogger(__name__)


class DetectorFeed:
    """Hands the phases SUMO shows present to the controller as detector actuations, on change."""

    def __init__(self, transport: Transport, config: IntersectionConfig, events: EventLog) -> None:
        self.transport = transport
        self.events = events
        self.detectors_of: dict[int, list[int]] = {}
        for d, phase in config.detectors.items():
            self.detectors_of.setdefault(phase, []).append(d)
        self.groups = (max(config.detectors) + 7) // 8
        self.actuated: frozenset[int] = frozenset()

    def feed(self, present: Iterable[int]) -> None:
        """The phases with a vehicle on their stop-bar zone now; SET the actuations when they changed."""
        actuated = frozenset(d for p in present for d in self.detectors_of.get(p, ()))
        if actuated == self.actuated:
            return
        self.actuated = actuated
        self.events.emit(Kind.DETECTORS, active=sorted(actuated))
        masks = phases_to_groups(actuated, self.groups)
        done = self.transport.set([(DETECTOR_ACTUATION.instance(g), m) for g, m in enumerate(masks, start=1)])
        done.callbacks.append(self._answered)

    def _answered(self, ev: simpy.Event) -> None:
        if not ev.ok:
            ev.defused = True
            self.events.emit(Kind.NOTE, message=f"detector actuation SET failed: {type(ev.value).__name__}: "
                                                f"{ev.value}")


def actuations_per_phase(records: Iterable[Mapping[str, Any]], config: IntersectionConfig) -> dict[int, int]:
    """How often each phase's detector went from idle to actuated over a run (its ``detectors`` records)."""
    counts = dict.fromkeys(config.detectors.values(), 0)
    before: set[int] = set()
    for r in records:
        if r["kind"] == Kind.DETECTORS:
            now = set(r["active"])
            for d in now - before:
                counts[config.detectors[d]] += 1
            before = now
    return counts
