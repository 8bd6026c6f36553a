"""sumo-rl's API on hils: ``from hils.sumo_rl import SumoEnvironment`` (or ``from hils import sumo_rl``) in place of
sumo-rl's, and the same code drives NEMA controllers through the middleware, every light's controller derived from
its SUMO program.

The names are sumo-rl's (1.4.5 and its repository since: ``enforce_max_green``, reward lists with
``reward_weights``): :class:`SumoEnvironment`, :func:`env`, :func:`parallel_env`, :class:`TrafficSignal`,
:class:`ObservationFunction`, RESCO's eight networks (:func:`grid4x4`...), and the modules under
``hils.sumo_rl.environment`` as sumo-rl names its own (``hils.sumo_rl.environment.observations``...). Importing it
registers ``sumo-rl-v0`` with gymnasium. What differs from sumo-rl, and why, is in ``docs/sumo-rl.md``.
"""

from hils.sumo_rl.environment.env import ObservationFunction, SumoEnvironment, TrafficSignal, env, parallel_env
from hils.sumo_rl.environment.resco_envs import (
    arterial4x4,
    cologne1,
    cologne3,
    cologne8,
    grid4x4,
    ingolstadt1,
    ingolstadt7,
    ingolstadt21,
)

__all__ = [
    "ObservationFunction", "SumoEnvironment", "TrafficSignal", "arterial4x4", "cologne1", "cologne3", "cologne8", "env",
    "grid4x4", "ingolstadt1", "ingolstadt7", "ingolstadt21", "parallel_env",
]
