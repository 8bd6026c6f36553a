"""SUMO through libsumo: the traffic the controller's indications act on.

SUMO never runs a signal program of its own here. Its traffic light is put under external
control at start (all red) and from then on shows what :meth:`SumoSimulation.apply` gives
it: the controller's phase colours mapped onto SUMO's link indices by the phase map derived
from the network (:mod:`hils.sim.network`).

libsumo runs the simulation inside this process: one simulation per process at a time
(the library holds it in globals) and only from the thread that started it. Stepping is the
hot path of a co-simulation (four steps per simulated second), so :meth:`apply` and
:meth:`step` do almost nothing beyond the libsumo call; queues are read only when asked
for and, for the end-of-run maximum, sampled once per ``queue_sample_period``.

A libsumo run also depends on what the process did before it. SUMO decides some things by where
the objects it loads lie in memory (on RESCO's cologne1, whether a vehicle waiting inside the
junction yields or goes on): a fresh process places them in the order they are made, one whose
heap an earlier run (or anything else) left full of holes scatters them, and no libsumo call undoes
that (close and start, load). So runs whose figures must agree run in processes of their own, as
`hils run` and every cell of :mod:`hils.sweep.grid` do; several runs in one process agree as far as
the network allows (cologne1, coordinated, seed 0, 600 s: a RESCO delay of 24.983 s in a fresh
process, 25.009 s in some runs after others; the shipped networks have shown no such difference).
"""

from __future__ import annotations

import dataclasses
import operator
import os
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from itertools import accumulate
from pathlib import Path
from types import TracebackType

from hils.protocol.config import IntersectionConfig, load
from hils.protocol.errors import UserError
from hils.protocol.ntcip import SignalState
from hils.protocol.scenario import SignalLink, labels
from hils.sim.network import SUMO_CONFIG, TLS_ID, PhaseMap, data_path, derive_phase_map, read_net
from hils.sim.quiet_libsumo import libsumo
from hils.sim.resco_metrics import QueueTracker, RescoMetrics, read_tripinfo
from hils.sim.resco_metrics import metrics as resco_metrics
from hils.sim.webster import webster_plan


class SumoError(UserError, RuntimeError):
    """SUMO could not be started or used as asked."""


@dataclass(frozen=True, slots=True)
class LaneState:
    """One lane in the last step: halting vehicles (< 0.1 m/s), their summed waiting time, all vehicles."""

    halting: int
    waiting_time: float
    vehicles: int


@dataclass(frozen=True, slots=True)
class MovementState:
    """Queues of the links one phase serves: halting vehicles on their incoming and outgoing lanes."""

    phase: int
    upstream_queue: int
    downstream_queue: int

    @property
    def pressure(self) -> int:
        return self.upstream_queue - self.downstream_queue


@dataclass(frozen=True)
class TrafficState:
    """What the simulation looks like now. ``lanes`` covers the lanes of the signal's links;
    ``departed`` and ``arrived`` count vehicles since the start (arrived: no longer in the
    network, which includes any removed after a collision)."""

    time: float
    lanes: Mapping[str, LaneState]
    movements: Mapping[int, MovementState]
    departed: int
    arrived: int


@dataclass(frozen=True)
class ApproachSummary:
    """End-of-run figures of one approach (the side vehicles come from). ``mean_delay`` is
    over every vehicle of the approach that was due to enter (None when none was)."""

    departed: int
    arrived: int
    running: int
    waiting_to_enter: int
    mean_delay: float | None
    max_queue: int
    lane_storage: int  # vehicles its shortest lane holds end to end (lane length / (vehicle length + gap))
    spillback_minutes: tuple[int, ...]  # minutes in which a lane of it was full of halted vehicles (spillback)


@dataclass(frozen=True)
class RunSummary:
    """End-of-run figures that count every vehicle due to enter by the end.

    ``mean_delay`` is over every vehicle that departed or is ``waiting_to_enter`` (SUMO's
    insertion backlog): departure delay (desired to actual insertion, or so far for those still
    waiting) plus time loss (travel time lost to driving below the desired speed, so far for
    those still running). Time loss is read from libsumo once per ``queue_sample_period``, so
    an arrived vehicle's last period before it left is not counted. ``mean_time_loss`` and
    ``mean_waiting_time`` are SUMO's own trip statistics over the arrived vehicles only (None
    before any arrived). ``notes`` says what each figure counts and why any is None.
    ``sim_time`` is the simulated seconds since SUMO's ``begin``; ``resco`` RESCO's figures, from SUMO's
    tripinfo once the simulation has ended (:meth:`SumoSimulation.finish`; None before, and when not measured).
    """

    sim_time: float
    departed: int
    arrived: int
    running: int
    waiting_to_enter: int
    mean_delay: float | None
    mean_time_loss: float | None
    mean_waiting_time: float | None
    max_queue: Mapping[str, int]
    approaches: Mapping[str, ApproachSummary]
    collisions: int
    teleports: int
    notes: tuple[str, ...]
    begin: float = 0.0
    resco: RescoMetrics | None = None


DELAY_NOTE = ("mean_delay: per vehicle that departed or is waiting to enter, departure delay (desired to actual "
              "insertion, so far for those waiting) plus SUMO time loss (so far for those still running)")
NOT_MEASURED_NOTE = ("mean_delay, max_queue, approaches: not measured (measure=False: no per-vehicle and "
                     "per-lane samples every second, as environments run for speed); the counts are SUMO's own")
ARRIVED_NOTE = ("mean_time_loss, mean_waiting_time: SUMO trip statistics over arrived vehicles only; null when "
                "no vehicle arrived")


#: Metres before the stop bar in which a vehicle actuates its phase's detector: a stop-bar presence zone
#: long enough (a vehicle at 50 km/h crosses it in about 1.5 s) to carry a green across the gaps of a
#: platoon with the shipped passage of 0 s (which the paper's experiment needs); with 10 m, greens gap out
#: between vehicles and the mean delay of `--agent actuated` triples.
PRESENCE_ZONE_M = 20.0

# libsumo's C getters of the samples and of the traffic state, without the Python wrapper each public one is (pinned
# libsumo version: a change of these names fails at import, in every test).
_lane_halting = libsumo._libsumo.lane_getLastStepHaltingNumber
_lane_vehicles = libsumo._libsumo.lane_getLastStepVehicleNumber
_lane_waiting = libsumo._libsumo.lane_getWaitingTime
_vehicle_ids = libsumo._libsumo.vehicle_getIDList
_vehicle_time_loss = libsumo._libsumo.vehicle_getTimeLoss

_active: SumoSimulation | None = None


class Light:
    """What a running simulation shows for one intersection: its traffic light's phase map, what it shows, and
    the lanes it serves.

    ``prefix`` names its approaches in the run's summary, after the intersection's label
    (:func:`hils.protocol.scenario.labels`): nothing in a simulation of one intersection (``west``), its name in one of
    several (``J2 north``)."""

    def __init__(self, tls_id: str, config: IntersectionConfig, phase_map: PhaseMap, *, label: str | None,
                 readings: _Readings) -> None:
        self.tls_id = tls_id
        self._readings = readings
        self.config = config
        self.phase_map = phase_map
        self.prefix = f"{label} " if label else ""
        self._state_strings: dict[SignalState, str] = {}
        self._applied_state: SignalState | None = None
        self._applied = "r" * len(phase_map.link_phases)
        libsumo.trafficlight.setRedYellowGreenState(tls_id, self._applied)
        self.approach_lanes = tuple((self.prefix + approach, lanes)
                                    for approach, lanes in phase_map.approach_lanes.items())
        self._movement_lanes = tuple((p, phase_map.incoming_lanes(p), phase_map.outgoing_lanes(p))
                                     for p in config.phase_numbers)
        self._lanes = tuple(dict.fromkeys(lane for _, inc, out in self._movement_lanes for lane in (*inc, *out)))
        # each movement's lanes by their place in _lanes: the traffic state sums from a list, not a dict by name
        place = {lane: i for i, lane in enumerate(self._lanes)}
        self._movement_places = tuple((p, tuple(place[n] for n in inc), tuple(place[n] for n in out))
                                      for p, inc, out in self._movement_lanes)
        self._lane_length = {lane: libsumo.lane.getLength(lane) for lane in self._lanes}
        self.incoming_lanes = tuple(dict.fromkeys(lane for _, inc, _ in self._movement_lanes for lane in inc))
        lanes_of = phase_map.approach_lanes
        for n, p in config.preempts.items():
            if p.approach is not None and p.approach not in lanes_of:
                raise SumoError(f"{config.source}: preempts.{n}.approach: traffic light {tls_id} has no {p.approach} "
                                f"approach; allowed: {', '.join(lanes_of)}")
        # Each preempt SUMO calls: the incoming lanes of its approach, how far up from the stop bar it looks, and
        # the vehicle classes or types that call it.
        self._preempt_zones = tuple((n, lanes_of[p.approach], p.zone, frozenset(p.vehicles))
                                    for n, p in config.preempts.items() if p.approach is not None)

    def apply(self, state: SignalState) -> bool:
        """Show ``state`` on the traffic light; True when SUMO's state had to change."""
        if state is self._applied_state or state == self._applied_state:
            return False
        self._applied_state = state
        text = self._state_strings.get(state)
        if text is None:
            text = self._state_strings[state] = self.phase_map.state_string(state)
        if text == self._applied:
            return False
        self.show(text)
        return True

    def show(self, text: str) -> None:
        """Show SUMO's per-link state string ``text`` on the traffic light."""
        libsumo.trafficlight.setRedYellowGreenState(self.tls_id, text)
        self._applied = text

    def release(self) -> None:
        """Forget what was shown: SUMO's own program runs the light from now on."""
        self._applied_state = None
        self._applied = ""

    def indications(self) -> str:
        """SUMO's current per-link state string of this light."""
        return libsumo.trafficlight.getRedYellowGreenState(self.tls_id)

    def present(self, zone: float = PRESENCE_ZONE_M) -> frozenset[str]:
        """Incoming lanes with a vehicle within ``zone`` m of the stop bar: the stop-bar presence loops of a
        cabinet (a vehicle's front is past the zone's start)."""
        position, vehicles, length = libsumo.vehicle.getLanePosition, libsumo.lane.getLastStepVehicleIDs, \
            self._lane_length
        return frozenset(lane for lane in self.incoming_lanes
                         if any(position(v) >= length[lane] - zone for v in vehicles(lane)))

    def preempt_calls(self) -> frozenset[int]:
        """The preempts with a vehicle of one of their classes (SUMO's vClass, e.g. ``emergency``, ``rail``) or
        vehicle types within their zone of their approach's stop bar (on the incoming lanes)."""
        if not self._preempt_zones:
            return frozenset()
        vehicle = libsumo.vehicle
        return frozenset(n for n, lanes, zone, kinds in self._preempt_zones
                         if any(vehicle.getLanePosition(v) >= libsumo.lane.getLength(lane) - zone
                                and (vehicle.getVehicleClass(v) in kinds or vehicle.getTypeID(v) in kinds)
                                for lane in lanes for v in libsumo.lane.getLastStepVehicleIDs(lane)))

    def queues(self) -> dict[int, int]:
        """Halting vehicles on the incoming lanes of each phase's movement (``upstream_queue`` of the traffic
        state, read alone: the queue plot samples it every few seconds)."""
        return {p: sum(map(_lane_halting, inc)) for p, inc, _ in self._movement_lanes}

    @property
    def lanes(self) -> tuple[str, ...]:
        """The lanes of the light's links, incoming and outgoing: those its traffic state reads."""
        return self._lanes

    def traffic_state(self) -> TrafficState:
        now, read, departed, arrived = self._readings.read(self._lanes)
        states = [read[n] for n in self._lanes]
        halting = [state.halting for state in states].__getitem__
        movements = {p: _movement(p, sum(map(halting, inc)), sum(map(halting, out)))
                     for p, inc, out in self._movement_places}
        return TrafficState(now, dict(zip(self._lanes, states, strict=True)), movements, departed, arrived)


#: Movement states made so far, by their fields: a grid's sixteen lights make a hundred and twenty-eight at every
#: decision, mostly the same few small queues again, and a frozen dataclass costs several times a dict lookup to make.
#: Values, so one object serves every light and decision that has it; cleared past a size no run of queues reaches.
_MOVEMENTS: dict[tuple[int, int, int], MovementState] = {}
_MOVEMENTS_KEPT = 1 << 16


def _movement(phase: int, upstream: int, downstream: int) -> MovementState:
    key = (phase, upstream, downstream)
    made = _MOVEMENTS.get(key)
    if made is None:
        if len(_MOVEMENTS) >= _MOVEMENTS_KEPT:
            _MOVEMENTS.clear()
        made = _MOVEMENTS[key] = MovementState(phase, upstream, downstream)
    return made


#: What a lane without vehicles reads, known without asking SUMO twice more (most lanes of a network are empty at any
#: time): libsumo's halting number and waiting time loop over the very vehicles its vehicle number counts (Lane.cpp:
#: ``getLastStepVehicleNumber`` is the lane's ``getVehicleNumber()``, ``getLastStepHaltingNumber`` counts its
#: ``getVehiclesSecure()``, ``getWaitingTime`` is ``MSLane::getWaitingSeconds()``, 0 without vehicles).
_EMPTY_LANE = LaneState(0, 0.0, 0)


class _Readings:
    """The traffic state's figures, read at most once per simulated time: lights observed at the same time share
    them (a grid's sixteen are observed at every decision point, and one light's outgoing lanes are its neighbour's
    incoming ones). Every figure is of SUMO's last step, so it stands until the next."""

    def __init__(self) -> None:
        self._time: float | None = None
        self._lanes: dict[str, LaneState] = {}
        self._counts = (0, 0)

    def read(self, names: Sequence[str]) -> tuple[float, dict[str, LaneState], int, int]:
        """The time, the states of at least the lanes ``names``, and the vehicles departed and arrived."""
        now = libsumo.simulation.getTime()
        if now != self._time:
            self._time, self._lanes = now, {}
            departed = statistic("stats.vehicles.inserted")
            self._counts = (int(departed), int(departed - statistic("stats.vehicles.running")))
        lanes = self._lanes
        for n in names:
            if n not in lanes:
                vehicles = _lane_vehicles(n)
                lanes[n] = LaneState(_lane_halting(n), _lane_waiting(n), vehicles) if vehicles else _EMPTY_LANE
        return now, lanes, *self._counts


class SumoSimulation:
    """One libsumo run of a network whose traffic lights follow :class:`SignalState` s: once started, ``lights``
    holds what it shows for each intersection (:class:`Light`), by its traffic light's id.

    ``sumo_config`` defaults to the shipped four-leg scenario (``hils/data/four_leg.sumocfg``,
    one hour of demand). The simulation starts at the ``.sumocfg``'s ``begin`` (:attr:`begin`, 0 when it
    gives none); ``end`` (s after it) is passed to SUMO as ``--end`` for its own outputs; how
    far to step is the caller's choice, since libsumo steps on past it. ``time_to_teleport``
    < 0 keeps vehicles that wait at a red in place however long it lasts, so delays are never
    cut short by teleports. ``links``: per light whose signal links are bound explicitly, its
    :class:`hils.protocol.scenario.SignalLink` s (a derived RESCO light). When measuring, SUMO writes its tripinfo
    (``tripinfo``, or a temporary file) for RESCO's figures, which :meth:`finish` reads once SUMO has ended.
    """

    def __init__(self, config: IntersectionConfig | None = None, *, seed: int = 0, end: float | None = None,
                 step_length: float | None = None, sumo_config: str | Path | None = None,
                 time_to_teleport: float = -1.0, quiet: bool = True, queue_sample_period: float = 1.0,
                 tls_id: str = TLS_ID, lights: Mapping[str, IntersectionConfig] | None = None,
                 measure: bool = True, extra_args: Sequence[str] = (),
                 links: Mapping[str, Sequence[SignalLink]] | None = None, tripinfo: str | Path | None = None) -> None:
        self.configs: dict[str, IntersectionConfig] = dict(lights) if lights else {tls_id: config or load()}
        self.config = next(iter(self.configs.values()))
        self.links = dict(links or {})
        self.lights: dict[str, Light] = {}
        self.seed = seed
        self.end = end
        self.step_length = step_length if step_length is not None else self.config.middleware.sumo_step
        self.sumo_config = Path(sumo_config) if sumo_config is not None else data_path(SUMO_CONFIG)
        self.begin = sumocfg_begin(self.sumo_config)
        self.tripinfo = Path(tripinfo) if tripinfo is not None else None
        self._tripinfo_dir: tempfile.TemporaryDirectory | None = None
        self._queue: QueueTracker | None = None
        self._resco_every = max(1, round(self.config.middleware.control_interval / queue_sample_period))
        self._until_resco = self._resco_every
        self.time_to_teleport = time_to_teleport
        self.quiet = quiet
        self.measure = measure
        self.extra_args = tuple(extra_args)
        self._sample_every = max(1, round(queue_sample_period / self.step_length))
        self._until_sample = self._sample_every
        self._max_queue: dict[str, int] = {}
        self._approach_of_edge: dict[str, str] = {}
        # every light's approaches (named as Light says), their lanes and how many vehicles each lane holds
        self._storage: tuple[tuple[str, tuple[str, ...], tuple[int, ...]], ...] = ()
        # the same lanes end to end with their capacities, each approach a slice of them: the samples read them all
        # in one pass
        self._sampled: tuple[tuple[str, ...], tuple[int, ...], tuple[tuple[str, slice], ...]] = ((), (), ())
        self._spill_minutes: dict[str, set[int]] = {}
        # per vehicle seen in the network: its approach and departure delay, and its last sampled time loss
        self._seen: dict[str, tuple[str, float]] = {}
        self._time_loss: dict[str, float] = {}
        self._finished: dict[str, list[float]] = {}
        self._readings = _Readings()

    # --- life cycle ----------------------------------------------------------------------

    def command(self) -> list[str]:
        """The SUMO command line this simulation starts with."""
        cmd = ["sumo", "-c", str(self.sumo_config), "--step-length", repr(self.step_length),
               "--seed", str(self.seed), "--time-to-teleport", repr(self.time_to_teleport),
               "--no-step-log", "true"]
        if self.measure:
            # the tripinfo statistics give the mean delay of arrived vehicles during the run, and the tripinfo
            # RESCO's figures at its end; a run that measures nothing (training) spares SUMO a tripinfo device
            # per vehicle
            cmd += ["--duration-log.statistics", "true", "--tripinfo-output", str(self._tripinfo_path()),
                    "--tripinfo-output.write-unfinished", "true", "--tripinfo-output.write-undeparted", "true"]
        if self.end is not None:
            cmd += ["--end", repr(self.begin + self.end)]
        if self.quiet:
            cmd += ["--no-warnings", "true"]
        return cmd + list(self.extra_args)

    def start(self) -> None:
        """Start SUMO and take its traffic light over, showing all red until the first :meth:`apply`."""
        global _active
        if _active is not None:
            raise SumoError("a SUMO simulation is already running in this process (libsumo runs one at a time); "
                            "close it first")
        if not self.sumo_config.is_file():
            raise SumoError(f"SUMO configuration {self.sumo_config} does not exist")
        with _console(self.quiet) as console:
            try:
                libsumo.start(self.command())
            except libsumo.TraCIException as exc:
                raise SumoError(f"SUMO did not start: {_start_error(console.text(), str(exc))}") from None
        _active = self
        try:
            self._setup()
        except BaseException:
            self.close()
            raise

    def _setup(self) -> None:
        present = libsumo.trafficlight.getIDList()
        missing = [tls for tls in self.configs if tls not in present]
        if missing:
            raise SumoError(f"the network has no traffic light {', '.join(map(repr, missing))}; it has "
                            f"{', '.join(map(repr, present)) or 'none'}")
        net = read_net(libsumo.simulation.getOption("net-file"))
        named = labels(list(self.configs))
        readings = self._readings = _Readings()
        self.lights = {tls: Light(tls, cfg, derive_phase_map(cfg, net, libsumo.trafficlight.getControlledLinks(tls),
                                                             tls, self.links.get(tls)), label=named[tls],
                                  readings=readings)
                       for tls, cfg in self.configs.items()}
        self._until_sample = self._sample_every
        self._until_resco = self._resco_every
        incoming = {tls: light.incoming_lanes for tls, light in self.lights.items()}
        self._queue = QueueTracker(incoming, {lane: libsumo.lane.getLength(lane) for lanes in incoming.values()
                                              for lane in lanes})
        approach_lanes = [item for light in self.lights.values() for item in light.approach_lanes]
        self._max_queue = {approach: 0 for approach, _ in approach_lanes}
        self._approach_of_edge = {link.from_lane.rsplit("_", 1)[0]: light.prefix + link.approach
                                  for light in self.lights.values() for link in light.phase_map.links}
        spacing = _vehicle_spacing()
        self._storage = tuple((approach, tuple(lanes),
                               tuple(int(libsumo.lane.getLength(lane) // spacing) for lane in lanes))
                              for approach, lanes in approach_lanes)
        ends = accumulate(len(its) for _, its, _ in self._storage)
        # A lane shorter than one vehicle (RESCO's networks have such) cannot show a queue reaching back: it is never
        # full.
        self._sampled = (tuple(lane for _, its, _ in self._storage for lane in its),
                         tuple(c or sys.maxsize for _, _, capacities in self._storage for c in capacities),
                         tuple((a, slice(end - len(its), end))
                               for (a, its, _), end in zip(self._storage, ends, strict=True)))
        self._spill_minutes = {approach: set() for approach, _ in approach_lanes}
        self._seen, self._time_loss = {}, {}
        self._finished = {approach: [] for approach, _ in approach_lanes}

    def close(self) -> None:
        """End the simulation (idempotent); SUMO's end-of-run report is swallowed when quiet."""
        global _active
        if _active is not self:
            return
        _active = None
        with _console(self.quiet):
            libsumo.close()

    def finish(self) -> RunSummary:
        """The end-of-run summary (:meth:`summary`), then end the simulation, so that SUMO writes the tripinfo of the
        vehicles still running or never entered, and add RESCO's figures from it (when measuring)."""
        summary = self.summary()
        self.close()
        if not self.measure or self._queue is None:
            return summary
        path = self._tripinfo_path()
        try:
            resco = resco_metrics(read_tripinfo(path), self._queue)
        finally:
            if self._tripinfo_dir is not None:
                self._tripinfo_dir.cleanup()
                self._tripinfo_dir = None
        return dataclasses.replace(summary, resco=resco)

    def _tripinfo_path(self) -> Path:
        if self.tripinfo is not None:
            return self.tripinfo
        if self._tripinfo_dir is None:
            self._tripinfo_dir = tempfile.TemporaryDirectory(prefix="hils-tripinfo-")
        return Path(self._tripinfo_dir.name) / "tripinfo.xml"

    @property
    def running(self) -> bool:
        return _active is self

    def __enter__(self) -> SumoSimulation:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # --- hot path ------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return libsumo.simulation.getTime()

    def read_lanes(self, names: Sequence[str]) -> tuple[float, dict[str, LaneState], int, int]:
        """What the lights' traffic states are made of, read as they read it (once per simulated time): the time, the
        states of at least the lanes ``names``, and the vehicles departed and arrived."""
        return self._readings.read(names)

    def step(self) -> float:
        """Advance one SUMO step; returns the wall seconds it took."""
        t0 = time.perf_counter()
        self.advance(1)
        return time.perf_counter() - t0

    def advance(self, steps: int) -> None:
        """``steps`` SUMO steps with nothing shown changing between them: what as many :meth:`step` calls do.

        libsumo steps to a given time in one call, its own loop over the very steps single calls make, so
        a stretch costs one call (one per sample when measuring) rather than a trip into Python per step."""
        while steps > 0:
            n = min(steps, self._until_sample) if self.measure else steps
            step_on(n, self.step_length)
            steps -= n
            if self.measure:
                self._until_sample -= n
                if not self._until_sample:
                    self._until_sample = self._sample_every
                    self._sample_queues()
                    self._until_resco -= 1
                    if not self._until_resco:  # once per decision step, as RESCO observes
                        self._until_resco = self._resco_every
                        self._queue.sample()

    def _sample_queues(self) -> None:
        # Once a second, for the whole run. The getters are libsumo's own C functions mapped over every approach's
        # lanes in one pass (a Python frame per call, or per approach, was most of this sample's cost); a full lane
        # is looked for approach by approach only in the rare sample that has one.
        lanes, capacities, approaches = self._sampled
        halting = list(map(_lane_halting, lanes))
        top = self._max_queue
        for approach, its in approaches:
            queue = sum(halting[its])
            if queue > top[approach]:
                top[approach] = queue
        # a lane holding as many halted vehicles as fit on it: the queue reaches back beyond the network (vehicles
        # merely on it do not: a short lane holds one moving vehicle as often as not)
        full = list(map(operator.ge, halting, capacities))
        if any(full):
            minute = int((self.time - self.begin) // 60.0)
            for approach, its in approaches:
                if any(full[its]):
                    self._spill_minutes[approach].add(minute)
        self._sample_vehicles()

    def _sample_vehicles(self) -> None:
        """Bring the per-vehicle delays up to date: new vehicles get their approach and departure
        delay, vehicles gone since the last sample are finished with their last time loss."""
        ids = _vehicle_ids()
        time_loss = dict(zip(ids, map(_vehicle_time_loss, ids), strict=True))
        seen, last = self._seen, self._time_loss
        for vid in [v for v in last if v not in time_loss]:
            approach, depart_delay = seen.pop(vid)
            self._finished.setdefault(approach, []).append(depart_delay + last[vid])
        for vid in [v for v in ids if v not in seen]:
            seen[vid] = (self._approach(vid), libsumo.vehicle.getDepartDelay(vid))
        self._time_loss = time_loss

    def _approach(self, vid: str) -> str:
        return self._approach_of_edge.get(libsumo.vehicle.getRoute(vid)[0], "other")

    # --- observation ---------------------------------------------------------------------

    def summary(self) -> RunSummary:
        """Every vehicle counted: arrived, running, waiting to enter, with delays so far (see
        :class:`RunSummary` for what each figure counts); without ``measure``, the counts only."""
        departed = int(statistic("stats.vehicles.inserted"))
        running = int(statistic("stats.vehicles.running"))
        arrived = departed - running
        if not self.measure:
            return RunSummary(self.time - self.begin, departed, arrived, running,
                              len(libsumo.simulation.getPendingVehicles()), None, None, None, {}, {},
                              int(statistic("stats.safety.collisions")), int(statistic("stats.teleports.total")),
                              (NOT_MEASURED_NOTE,), self.begin)
        self._sample_vehicles()
        delays = {a: list(done) for a, done in self._finished.items()}
        counts = {a: Counter() for a in delays}
        for a, done in self._finished.items():
            counts[a]["arrived"] = len(done)
        for vid, (approach, depart_delay) in self._seen.items():
            delays.setdefault(approach, []).append(depart_delay + self._time_loss[vid])
            counts.setdefault(approach, Counter())["running"] += 1
        pending = libsumo.simulation.getPendingVehicles()
        for vid in pending:
            approach = self._approach(vid)
            delays.setdefault(approach, []).append(libsumo.vehicle.getDepartDelay(vid))
            counts.setdefault(approach, Counter())["waiting"] += 1
        storage = {a: min(filter(None, capacities), default=0) for a, _, capacities in self._storage}
        approaches = {a: ApproachSummary(
            departed=counts[a]["arrived"] + counts[a]["running"], arrived=counts[a]["arrived"],
            running=counts[a]["running"], waiting_to_enter=counts[a]["waiting"],
            mean_delay=sum(d) / len(d) if d else None, max_queue=self._max_queue.get(a, 0),
            lane_storage=storage.get(a, 0),
            spillback_minutes=tuple(sorted(self._spill_minutes.get(a, ())))) for a, d in sorted(delays.items())}
        every = [x for d in delays.values() for x in d]
        notes = [DELAY_NOTE, ARRIVED_NOTE]
        if not every:
            notes.append("mean_delay: null because no vehicle was due to enter yet")
        return RunSummary(
            sim_time=self.time - self.begin,
            departed=departed,
            arrived=arrived,
            running=running,
            waiting_to_enter=len(pending),
            mean_delay=sum(every) / len(every) if every else None,
            mean_time_loss=statistic("device.tripinfo.vehicleTripStatistics.timeLoss") if arrived else None,
            mean_waiting_time=statistic("device.tripinfo.vehicleTripStatistics.waitingTime") if arrived else None,
            max_queue=dict(self._max_queue),
            approaches=approaches,
            collisions=int(statistic("stats.safety.collisions")),
            teleports=int(statistic("stats.teleports.total")),
            notes=tuple(notes),
            begin=self.begin,
        )

    def run_fixed_time(self) -> None:
        """Hand the lights to SUMO itself, each running :func:`fixed_time_states` of its config as a static
        program."""
        for light in self.lights.values():
            phases = [libsumo.trafficlight.Phase(duration, light.phase_map.state_string(state))
                      for duration, state in fixed_time_states(light.config)]
            logic = libsumo.trafficlight.Logic("hils-fixed", 0, 0, phases)
            libsumo.trafficlight.setProgramLogic(light.tls_id, logic)
            libsumo.trafficlight.setProgram(light.tls_id, "hils-fixed")
            light.release()


def sumocfg_begin(sumocfg: Path) -> float:
    """The ``time/begin`` of a ``.sumocfg`` in seconds (SUMO's default 0 when it has none or cannot be read here:
    SUMO itself then says what is wrong)."""
    try:
        value = ET.parse(sumocfg).find("time/begin")
    except (OSError, ET.ParseError):
        return 0.0
    text = value.get("value", "0") if value is not None else "0"
    try:
        # SUMO takes seconds or H:M:S
        return sum(float(part) * 60.0 ** i for i, part in enumerate(reversed(text.split(":"))))
    except ValueError:
        raise SumoError(f"{sumocfg}: time/begin: {text!r} is not a time; allowed: seconds or H:M:S") from None


def fixed_time_states(config: IntersectionConfig) -> list[tuple[float, SignalState]]:
    """One cycle of Webster's plan for the shipped demand (:mod:`hils.sim.webster`), the fixed-time
    baseline: (duration, state) per interval."""
    phases = config.phases
    every = frozenset(phases)
    plan = webster_plan(config)
    out: list[tuple[float, SignalState]] = []
    for pair in config.sequence:
        on = frozenset(pair)
        green = plan.green_of(pair)
        yellow = max(phases[p].yellow for p in pair)
        red_clear = max(phases[p].red_clear for p in pair)
        out.append((green, SignalState(every - on, frozenset(), on)))
        out.append((yellow, SignalState(every - on, on, frozenset())))
        out.append((red_clear, SignalState(every, frozenset(), frozenset())))
    return out


def _vehicle_spacing() -> float:
    """Metres a queued vehicle takes (length plus minimum gap), over the loaded vehicle types
    other than SUMO's defaults (which every network has), or the default car's when none."""
    vtype = libsumo.vehicletype
    types = [t for t in vtype.getIDList() if not t.startswith("DEFAULT_")] or ["DEFAULT_VEHTYPE"]
    return sum(vtype.getLength(t) + vtype.getMinGap(t) for t in types) / len(types)


def statistic(key: str) -> float:
    """One of SUMO's running statistics (vehicle counts, trip means of the arrived)."""
    return float(libsumo.simulation.getParameter("", key))


def time_bare_sumo(seconds: float = 3600.0, *, seed: int = 0, config: IntersectionConfig | None = None,
                   step_length: float | None = None, sumo_config: str | Path | None = None) -> float:
    """Wall seconds libsumo alone takes to step the scenario for ``seconds`` of simulated time.

    The same network, demand and SUMO options as :class:`SumoSimulation`, with SUMO running
    the fixed-time (Webster) cycle itself and no middleware: the baseline of the overhead benchmark.
    Start-up is not timed.
    """
    sim = SumoSimulation(config, seed=seed, step_length=step_length, sumo_config=sumo_config, end=seconds)
    with sim:
        sim.run_fixed_time()
        steps = round(seconds / sim.step_length)
        t0 = time.perf_counter()
        step_on(steps, sim.step_length)  # every step in one call, as SUMO alone would
        return time.perf_counter() - t0


def step_on(steps: int, step_length: float) -> None:
    """``steps`` SUMO steps of ``step_length`` s in one libsumo call (SUMO's own loop over the very steps single
    calls make)."""
    if steps == 1:
        libsumo.simulationStep()
    else:
        # half a step short of the last step's end: SUMO steps while its time is below the target
        libsumo.simulationStep(libsumo.simulation.getTime() + (steps - 0.5) * step_length)


class _Console:
    def __init__(self, path: Path | None) -> None:
        self.path = path

    def text(self) -> str:
        if self.path is None:
            return ""
        return self.path.read_text(encoding="utf-8", errors="replace").strip()


def _start_error(console: str, exception: str) -> str:
    """Why SUMO did not start, on one line: the errors it printed (from its first ``Error:`` line on) and the
    exception's own text (an error in a route file, say, is only there)."""
    lines = console.splitlines()
    first = next((i for i, line in enumerate(lines) if line.startswith("Error")), len(lines))
    told = [line.strip() for line in lines[first:] if line.strip()]
    told += [line.strip() for line in exception.splitlines() if line.strip() and line.strip() not in told]
    return " ".join(told) or console.replace("\n", " ") or "no reason given"


@contextmanager
def _console(quiet: bool) -> Iterator[_Console]:
    """Catch what SUMO prints on start and close (it has no option to stay silent).

    libsumo writes from C++ straight to file descriptors 1 and 2, so Python's sys.stdout
    cannot catch it: the descriptors themselves are pointed at a temporary file meanwhile.
    """
    if not quiet:
        yield _Console(None)
        return
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryDirectory(prefix="hils-sumo-") as tmp:
        path = Path(tmp) / "console.txt"
        saved = os.dup(1), os.dup(2)
        try:
            with path.open("wb") as sink:
                os.dup2(sink.fileno(), 1)
                os.dup2(sink.fileno(), 2)
                yield _Console(path)
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
