"""sumo-rl's ``TrafficSignal`` on a NEMA controller: one light, its spaces, its observation and reward functions.

sumo-rl switches SUMO's light itself; here the light shows what its controller shows (a controller derived from
the light's program, :mod:`hils.sumo_rl.lights`), and this class says what sumo-rl's names mean on it.

Rules of this module
--------------------
- An action is sumo-rl's: the index of a green phase. It asks the controller, through the middleware, for the pair
  of the stage that green phase is (:meth:`TrafficSignal.set_next_phase`); the controller ends the current green
  once its minimum green has passed (not before: sumo-rl ignores an action that comes too early, the controller
  serves it when it can), times the yellow and red clearance and shows the pair. With ``enforce_max_green`` an
  action that keeps a green shown for ``max_green`` s or more asks for the next green phase instead, as sumo-rl does.
- What the light shows is the controller's, as the middleware's 10 Hz polls read it (its signal cache):
  ``green_phase`` is the green phase of the pair the controller was last asked for (the one chosen last, when a
  program shows that pair twice), or of the pair it shows when it was asked for none; ``is_yellow`` is True while
  that pair is not yet green (yellow, red clearance, a barrier being crossed); ``time_since_last_phase_change`` is the
  seconds since the last change began (a green ended), or since the episode began.
- The default observation keeps sumo-rl's layout and meaning (:mod:`hils.sumo_rl.environment.observations`); its
  ``min_green`` entry is the controller's own: 1 once the pair's green has been shown for its minimum green.
- Lane measures and rewards are sumo-rl's, computed as sumo-rl computes them, from the same SUMO state through
  libsumo (``self.sumo``): densities and queues of the incoming lanes over what each holds (length over vehicle length
  plus SUMO's 2.5 m minimum gap), the accumulated waiting time per lane (each vehicle's SUMO accumulated waiting time,
  shared out over the lanes it waited on), the mean speed over the allowed speed, the pressure (vehicles on the
  outgoing lanes minus on the incoming ones). ``reward_fns`` holds sumo-rl's four rewards by name:
  ``diff-waiting-time`` (the default: the fall of the accumulated waiting time, in hundreds of seconds),
  ``average-speed``, ``queue`` (minus the halting vehicles) and ``pressure``.

The names, the reward functions and the lane measures follow sumo-rl's ``sumo_rl/environment/traffic_signal.py``
(MIT License, Copyright (c) 2018 Lucas Alegre: its notice is in :mod:`hils.sumo_rl`).
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from gymnasium import spaces

from hils.envs.intersection import EnvOptionError
from hils.protocol.config import Pair
from hils.shell.poller import Snapshot

if TYPE_CHECKING:
    from hils.run.intersection import Intersection
    from hils.sumo_rl.environment.env import SumoEnvironment

__all__ = ["TrafficSignal"]

RewardFn = Callable[["TrafficSignal"], float]


class TrafficSignal:
    """One traffic light of a :class:`hils.sumo_rl.SumoEnvironment`, with sumo-rl's attributes and methods.

    ``sumo`` is libsumo (the simulation the run steps). The environment builds one per light at construction (for
    its spaces) and again at every reset, then hands it the light's intersection of the run (:meth:`drive`)."""

    # SUMO's default minimum gap (m), as sumo-rl counts a lane's room
    MIN_GAP = 2.5

    def __init__(self, env: SumoEnvironment, ts_id: str, delta_time: float, yellow_time: float, min_green: int,
                 max_green: int, enforce_max_green: bool, begin_time: float, reward_fn: str | RewardFn | list,
                 reward_weights: list[float] | None, sumo: Any) -> None:
        self.id = ts_id
        self.env = env
        self.light = env.lights[ts_id]
        self.delta_time = delta_time
        self.yellow_time = yellow_time
        self.min_green = min_green
        self.max_green = max_green
        self.enforce_max_green = enforce_max_green
        self.begin_time = begin_time
        self.green_phase = self.light.green_phases_of(self.light.config.sequence[0])[0]
        self.last_ts_waiting_time = 0.0
        self.last_reward: float | np.ndarray | None = None
        self.reward_fn = reward_fn
        self.reward_weights = reward_weights
        self.sumo = sumo
        if isinstance(reward_fn, list):
            self.reward_dim = len(reward_fn)
            self.reward_list = [self._get_reward_fn_from_string(fn) for fn in reward_fn]
        else:
            self.reward_dim = 1
            self.reward_list = [self._get_reward_fn_from_string(reward_fn)]
        if reward_weights is not None:
            self.reward_dim = 1  # scalarised
        self.reward_space = spaces.Box(low=-np.inf, high=np.inf, shape=(self.reward_dim,), dtype=np.float32)
        # sumo-rl's green phases, as objects with a ``state`` (sumo-rl's are libsumo Phase objects)
        self.green_phases = [SimpleNamespace(state=state) for state in self.light.green_states]
        self.num_green_phases = len(self.green_phases)
        self.lanes = list(self.light.lanes)
        self.out_lanes = list(self.light.out_lanes)
        self.lanes_length = dict(self.light.lanes_length)
        self.observation_fn = env.observation_class(self)
        self.observation_space = self.observation_fn.observation_space()
        self.action_space = spaces.Discrete(self.num_green_phases)
        self._intersection: Intersection | None = None
        self._green_at: dict[int, float] = {}  # each phase shown green: since when
        self._change_at = 0.0

    @property
    def last_measure(self) -> float:
        """sumo-rl 1.4.5's name of :attr:`last_ts_waiting_time` (a reward function written for it reads this)."""
        return self.last_ts_waiting_time

    @last_measure.setter
    def last_measure(self, value: float) -> None:
        self.last_ts_waiting_time = value

    def _get_reward_fn_from_string(self, reward_fn: str | RewardFn) -> RewardFn:
        if isinstance(reward_fn, str):
            if reward_fn not in TrafficSignal.reward_fns:
                raise EnvOptionError(f"reward_fn {reward_fn!r}: allowed: {', '.join(TrafficSignal.reward_fns)}, a "
                                     "function of the TrafficSignal, a list of them or a dict of them by light")
            return TrafficSignal.reward_fns[reward_fn]
        if not callable(reward_fn):
            raise EnvOptionError(f"reward_fn {reward_fn!r}: allowed: a reward's name or a function of the "
                                 "TrafficSignal")
        return reward_fn

    # --- the controller ---------------------------------------------------------------------------------

    def drive(self, intersection: Intersection) -> None:
        """Follow the controller of ``intersection`` (a run just reset): what it shows from now on."""
        self._intersection = intersection
        cache = intersection.middleware.cache
        now = intersection.env.now
        shown = cache.state.greens if cache.state is not None else frozenset()
        self._green_at = dict.fromkeys(shown, now)
        self._change_at = now
        cache.subscribe(self._on_signal)
        self.settle()

    def _on_signal(self, snapshot: Snapshot, changed: bool) -> None:
        greens = snapshot.state.greens
        ended = [p for p in self._green_at if p not in greens]
        for p in ended:
            del self._green_at[p]
        if ended:
            self._change_at = snapshot.t
        for p in greens:
            self._green_at.setdefault(p, snapshot.t)

    @property
    def _now(self) -> float:
        return self._intersection.env.now if self._intersection is not None else 0.0

    @property
    def time_to_act(self) -> bool:
        """True when the light is at a decision point (or its episode has ended, when every light is)."""
        return self._intersection is None or self._intersection.due or self.env.episode_done

    @property
    def time_since_last_phase_change(self) -> float:
        """Seconds since the light's last change began (a green ended), or since the episode began."""
        return self._now - self._change_at

    @property
    def is_yellow(self) -> bool:
        """True while the pair of ``green_phase`` is not (yet) all green: the light is changing."""
        return self._green_for() is None

    @property
    def min_green_passed(self) -> bool:
        """True once the pair of ``green_phase`` has been green for its minimum green: the controller can end it."""
        served = self._green_for()
        pair = self.light.pair_of(self.green_phase) or ()
        return served is not None and served >= max(self.light.config.phases[p].min_green for p in pair) - 1e-9

    def _green_for(self) -> float | None:
        """Seconds the pair of ``green_phase`` has been all green (None: it is not)."""
        pair = self.light.pair_of(self.green_phase)
        if pair is None or not all(p in self._green_at for p in pair):
            return None
        return self._now - max(self._green_at[p] for p in pair)

    def set_next_phase(self, new_phase: int) -> Pair | None:
        """Ask for green phase ``new_phase`` (as the module header says); returns the pair the controller is asked
        for (None: nothing, the green phase is no stage)."""
        new_phase = int(new_phase)
        if not 0 <= new_phase < self.num_green_phases:
            raise EnvOptionError(f"action {new_phase} for traffic light {self.id}: allowed: a green phase index in "
                                 f"[0, {self.num_green_phases})")
        if (self.enforce_max_green and new_phase == self.green_phase
                and self.time_since_last_phase_change >= self.max_green):
            new_phase = (self.green_phase + 1) % self.num_green_phases
        pair = self.light.pair_of(new_phase)
        if pair is not None:
            self.green_phase = new_phase
        return pair

    def settle(self) -> None:
        """After a step: ``green_phase`` follows the pair the controller was last asked for (an action dropped, or a
        recovery, leaves another one called), or the pair it shows when none is called."""
        called, pairs = self._intersection.middleware.call, self.light.config.pairs
        if called:
            pair = next((p for p in pairs if frozenset(p) == called), None)
        else:
            pair = next((p for p in pairs if set(p) <= self._green_at.keys()), None)
        if pair is not None and self.light.pair_of(self.green_phase) != pair:
            self.green_phase = self.light.green_phases_of(pair)[0]

    # --- observation and reward -----------------------------------------------------------------------

    def compute_observation(self) -> np.ndarray:
        """The observation of the light's observation function."""
        return self.observation_fn()

    def compute_reward(self) -> float | np.ndarray:
        """The reward: one function's, several as an array, or their weighted sum (``reward_weights``)."""
        if self.reward_dim == 1 and self.reward_weights is None:
            self.last_reward = self.reward_list[0](self)
        else:
            self.last_reward = np.array([fn(self) for fn in self.reward_list], dtype=np.float32)
            if self.reward_weights is not None:
                self.last_reward = float(np.dot(self.last_reward, self.reward_weights))
        return self.last_reward

    def _pressure_reward(self) -> float:
        return self.get_pressure()

    def _average_speed_reward(self) -> float:
        return self.get_average_speed()

    def _queue_reward(self) -> float:
        return -self.get_total_queued()

    def _diff_waiting_time_reward(self) -> float:
        ts_wait = sum(self.get_accumulated_waiting_time_per_lane()) / 100.0
        reward = self.last_ts_waiting_time - ts_wait
        self.last_ts_waiting_time = ts_wait
        return reward

    def get_accumulated_waiting_time_per_lane(self) -> list[float]:
        """The waiting time accumulated on each incoming lane: each vehicle's SUMO accumulated waiting time, less what
        it accumulated on the other lanes it was seen on."""
        vehicle, seen = self.sumo.vehicle, self.env.vehicles
        out = []
        for lane in self.lanes:
            wait = 0.0
            for veh in self.sumo.lane.getLastStepVehicleIDs(lane):
                veh_lane = vehicle.getLaneID(veh)
                acc = vehicle.getAccumulatedWaitingTime(veh)
                if veh not in seen:
                    seen[veh] = {veh_lane: acc}
                else:
                    seen[veh][veh_lane] = acc - sum(t for other, t in seen[veh].items() if other != veh_lane)
                wait += seen[veh][veh_lane]
            out.append(wait)
        return out

    def get_average_speed(self) -> float:
        """The mean speed of the vehicles on the incoming lanes over their allowed speed (1.0 with none)."""
        vehicles = self._get_veh_list()
        if not vehicles:
            return 1.0
        vehicle = self.sumo.vehicle
        return sum(vehicle.getSpeed(v) / vehicle.getAllowedSpeed(v) for v in vehicles) / len(vehicles)

    def get_pressure(self) -> int:
        """Vehicles on the outgoing lanes minus vehicles on the incoming lanes."""
        count = self.sumo.lane.getLastStepVehicleNumber
        return sum(map(count, self.out_lanes)) - sum(map(count, self.lanes))

    def get_out_lanes_density(self) -> list[float]:
        """Vehicles on each outgoing lane over what it holds, at most 1."""
        return self._per_room(self.out_lanes, self.sumo.lane.getLastStepVehicleNumber)

    def get_lanes_density(self) -> list[float]:
        """Vehicles on each incoming lane over what it holds, at most 1."""
        return self._per_room(self.lanes, self.sumo.lane.getLastStepVehicleNumber)

    def get_lanes_queue(self) -> list[float]:
        """Halting vehicles (below 0.1 m/s) on each incoming lane over what it holds, at most 1."""
        return self._per_room(self.lanes, self.sumo.lane.getLastStepHaltingNumber)

    def _per_room(self, lanes: list[str], count: Callable[[str], int]) -> list[float]:
        mean_length = self.sumo.lane.getLastStepLength  # SUMO's mean length of the lane's vehicles (7.5 m with none)
        return [min(1, count(lane) / (self.lanes_length[lane] / (self.MIN_GAP + mean_length(lane)))) for lane in lanes]

    def get_total_queued(self) -> int:
        """Halting vehicles on the incoming lanes."""
        return sum(map(self.sumo.lane.getLastStepHaltingNumber, self.lanes))

    def _get_veh_list(self) -> list[str]:
        return [v for lane in self.lanes for v in self.sumo.lane.getLastStepVehicleIDs(lane)]

    @classmethod
    def register_reward_fn(cls, fn: RewardFn) -> None:
        """Register a reward function under its ``__name__``."""
        if fn.__name__ in cls.reward_fns:
            raise KeyError(f"Reward function {fn.__name__} already exists")
        cls.reward_fns[fn.__name__] = fn

    reward_fns: ClassVar[dict[str, RewardFn]] = {
        "diff-waiting-time": _diff_waiting_time_reward,
        "average-speed": _average_speed_reward,
        "queue": _queue_reward,
        "pressure": _pressure_reward,
    }
