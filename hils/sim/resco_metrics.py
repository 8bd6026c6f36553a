"""RESCO's figures of a run: average delay, trip time and waiting time from SUMO's own tripinfo, and queue.

RESCO reports its benchmark in these four figures; they are computed here as its code computes them
(Pi-Star-Lab/RESCO, ``resco_benchmark/utils/readXML.py`` and ``readCSV.py``, ``multi_signal.py``,
``traffic_signal.py``), with the differences said where SUMO now gives directly what RESCO approximated:

- **average delay**: over every vehicle due to enter by the end, ``timeLoss + departDelay`` of its tripinfo
  (``total += float(child.attrib[metric])`` then ``if metric == 'timeLoss': total += float(child.attrib
  ['departDelay'])``), arrived or not (RESCO runs SUMO with ``--tripinfo-output.write-unfinished``).
  A vehicle that never entered counts ``end - depart`` (RESCO: ``np.sum(float(map_configs[map_name]
  ['end_time']) - never_departed)``). RESCO finds those in the route file (the vehicles scheduled after the
  last one that entered); SUMO 1.28 writes every one of them itself (``--tripinfo-output.write-undeparted``,
  ``departDelay`` = end - depart), which is used here, so a backlog on one entry while later vehicles enter
  elsewhere is counted too.
- **trip time** and **waiting time**: the mean ``duration`` and ``waitingTime`` of the tripinfo of the
  vehicles that entered (arrived or still running at the end; RESCO's SUMO wrote no others).
- **queue**: at every decision step (RESCO's ``step_length``), per light, the vehicles on its incoming lanes
  within 200 m of the stop line (``get_vehicles(lane, max_distance)``, max_distance 200) that have stopped
  (SUMO waiting time > 0) since they came within that range (``if vehicle_measures['wait'] > 0:
  lane_measures['queue'] += 1``, a vehicle's wait kept until it leaves); averaged over the lights, then over
  the steps. RESCO's ``readCSV.py`` divides each step's sum by the number of lights plus one (``step_avg =
  step_total / len(signals)``, where ``signals`` holds one more item than there are lights): its queue
  figures are ``n / (n + 1)`` of the mean over lights given here.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from hils.protocol.errors import UserError
from hils.sim.quiet_libsumo import libsumo

#: RESCO's range of a light's detection: ``max_distance=200`` in MultiSignal.
DETECTION_RANGE_M = 200.0

NOTES = (
    "delay_s: RESCO's average delay, over every vehicle due to enter by the end: timeLoss + departDelay of SUMO's "
    "tripinfo (arrived, still running, and never entered with departDelay = end - depart)",
    "trip_time_s, waiting_time_s: mean duration and waitingTime of the tripinfo of the vehicles that entered",
    "queue: RESCO's queue, per decision step the vehicles within 200 m of a light on its incoming lanes that have "
    "stopped since coming in range, averaged over the lights and the steps (RESCO's readCSV.py divides by the "
    "lights plus one: its figure is n/(n+1) of this)",
)

_lane_vehicles = libsumo._libsumo.lane_getLastStepVehicleIDs
_lane_position = libsumo._libsumo.vehicle_getLanePosition
_waiting_time = libsumo._libsumo.vehicle_getWaitingTime


class TripinfoError(UserError):
    """A tripinfo file that cannot be read."""


@dataclass(frozen=True, slots=True)
class Trips:
    """What SUMO's tripinfo says of a run: the three RESCO figures and the vehicles they count."""

    delay_s: float | None
    trip_time_s: float | None
    waiting_time_s: float | None
    vehicles: int  # every vehicle due to enter by the end
    arrived: int
    running: int  # entered, not arrived by the end
    never_entered: int


@dataclass(frozen=True, slots=True)
class RescoMetrics:
    """RESCO's four figures of a run (see the module header for the definitions) and the vehicles counted."""

    delay_s: float | None
    trip_time_s: float | None
    waiting_time_s: float | None
    queue: float | None
    vehicles: int
    arrived: int
    running: int
    never_entered: int
    queue_steps: int
    notes: tuple[str, ...] = NOTES


def read_tripinfo(path: str | Path) -> Trips:
    """The RESCO figures of a tripinfo file SUMO wrote with ``write-unfinished`` and ``write-undeparted``."""
    delays, durations, waits = [], [], []
    arrived = never = 0
    try:
        for _, element in ET.iterparse(path):
            if element.tag != "tripinfo":
                continue
            a = element.attrib
            delays.append(float(a["timeLoss"]) + float(a["departDelay"]))
            if float(a["depart"]) < 0:
                never += 1
            else:
                durations.append(float(a["duration"]))
                waits.append(float(a["waitingTime"]))
                arrived += float(a["arrival"]) >= 0
            element.clear()
    except (OSError, ET.ParseError, KeyError, ValueError) as exc:
        raise TripinfoError(f"{path}: cannot be read as SUMO tripinfo output ({exc})") from None
    return Trips(_mean(delays), _mean(durations), _mean(waits), len(delays), arrived, len(durations) - arrived, never)


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


class QueueTracker:
    """RESCO's queue, sampled from the running simulation once per decision step (see the module header)."""

    def __init__(self, lanes: Mapping[str, Iterable[str]], lengths: Mapping[str, float]) -> None:
        self._lanes = {light: tuple(lanes_) for light, lanes_ in lanes.items()}
        self._start = {lane: max(0.0, length - DETECTION_RANGE_M) for lane, length in lengths.items()}
        self._stopped: dict[str, set[str]] = {light: set() for light in self._lanes}
        self._total = 0.0
        self.steps = 0

    def sample(self) -> None:
        per_light = 0
        for light, lanes in self._lanes.items():
            stopped = self._stopped[light]
            seen = {v for lane in lanes for v in _lane_vehicles(lane) if _lane_position(v) >= self._start[lane]}
            stopped &= seen  # RESCO forgets the wait of a vehicle out of range
            stopped.update(v for v in seen if v not in stopped and _waiting_time(v) > 0)
            per_light += len(stopped)
        self._total += per_light / len(self._lanes)
        self.steps += 1

    @property
    def mean(self) -> float | None:
        return self._total / self.steps if self.steps else None


def metrics(trips: Trips, queue: QueueTracker) -> RescoMetrics:
    return RescoMetrics(trips.delay_s, trips.trip_time_s, trips.waiting_time_s, queue.mean, trips.vehicles,
                        trips.arrived, trips.running, trips.never_entered, queue.steps)
