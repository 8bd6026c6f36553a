"""sumo-rl's observation functions: the base class a user's own derives from, and the default observation.

The default observation of a light is sumo-rl's vector::

    [phase_one_hot, min_green, lane_1_density, ..., lane_n_density, lane_1_queue, ..., lane_n_queue]

``phase_one_hot`` marks ``green_phase`` (the green phase the controller serves or is changing to); ``min_green`` is 1
once that green has been shown for its minimum green (sumo-rl documents it so: "whether min_green seconds have already
passed in the current phase"; its code counts ``min_green + yellow_time`` from the change, the same thing without a
red clearance); densities and queues are those of :class:`hils.sumo_rl.environment.traffic_signal.TrafficSignal`, in
[0, 1]. A user's class derives from :class:`ObservationFunction`, takes the light (``self.ts``) and gives
``__call__`` and ``observation_space``, as with sumo-rl.

This follows sumo-rl's ``sumo_rl/environment/observations.py``
(MIT License, Copyright (c) 2018 Lucas Alegre: its notice is in :mod:`hils.sumo_rl`).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import TYPE_CHECKING

import numpy as np
from gymnasium import spaces

if TYPE_CHECKING:
    from hils.sumo_rl.environment.traffic_signal import TrafficSignal

__all__ = ["DefaultObservationFunction", "ObservationFunction"]


class ObservationFunction:
    """What a light's observation is: ``__call__`` computes it, ``observation_space`` says its space."""

    def __init__(self, ts: TrafficSignal) -> None:
        self.ts = ts

    @abstractmethod
    def __call__(self) -> np.ndarray:
        """The observation now."""

    @abstractmethod
    def observation_space(self) -> spaces.Space:
        """The space of the observation."""


class DefaultObservationFunction(ObservationFunction):
    """sumo-rl's default observation (see the module header)."""

    def __call__(self) -> np.ndarray:
        ts = self.ts
        phase_id = [1 if ts.green_phase == i else 0 for i in range(ts.num_green_phases)]
        min_green = [1 if ts.min_green_passed else 0]
        return np.array(phase_id + min_green + ts.get_lanes_density() + ts.get_lanes_queue(), dtype=np.float32)

    def observation_space(self) -> spaces.Box:
        size = self.ts.num_green_phases + 1 + 2 * len(self.ts.lanes)
        return spaces.Box(low=np.zeros(size, dtype=np.float32), high=np.ones(size, dtype=np.float32))
