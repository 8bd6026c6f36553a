"""sumo-rl's API on hils: ``from hils.sumo_rl import SumoEnvironment`` (or ``from hils import sumo_rl``) in place of
sumo-rl's, and the same code drives NEMA controllers through the middleware, every light's controller derived from
its SUMO program.

The names are sumo-rl's (1.4.5 and its repository since: ``enforce_max_green``, reward lists with
``reward_weights``): :class:`SumoEnvironment`, :func:`env`, :func:`parallel_env`, :class:`TrafficSignal`,
:class:`ObservationFunction`, RESCO's eight networks (:func:`grid4x4`...), and the modules under
``hils.sumo_rl.environment`` as sumo-rl names its own (``hils.sumo_rl.environment.observations``...). Importing it
registers ``sumo-rl-v0`` with gymnasium. What differs from sumo-rl, and why, is in ``docs/sumo-rl.md``.

The modules under ``hils.sumo_rl.environment`` follow sumo-rl's of the same names, which carry this notice:

    MIT License

    Copyright (c) 2018 Lucas Alegre

    Permission is hereby granted, free of charge, to any person obtaining a copy
    of this software and associated documentation files (the "Software"), to deal
    in the Software without restriction, including without limitation the rights
    to use, copy, modify, merge, publish, distribute, sublicense, and/or sell
    copies of the Software, and to permit persons to whom the Software is
    furnished to do so, subject to the following conditions:

    The above copyright notice and this permission notice shall be included in all
    copies or substantial portions of the Software.

    THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND, EXPRESS OR
    IMPLIED, INCLUDING BUT NOT LIMITED TO THE WARRANTIES OF MERCHANTABILITY,
    FITNESS FOR A PARTICULAR PURPOSE AND NONINFRINGEMENT. IN NO EVENT SHALL THE
    AUTHORS OR COPYRIGHT HOLDERS BE LIABLE FOR ANY CLAIM, DAMAGES OR OTHER
    LIABILITY, WHETHER IN AN ACTION OF CONTRACT, TORT OR OTHERWISE, ARISING FROM,
    OUT OF OR IN CONNECTION WITH THE SOFTWARE OR THE USE OR OTHER DEALINGS IN THE
    SOFTWARE.
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
