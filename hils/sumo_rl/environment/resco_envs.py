"""RESCO's networks as sumo-rl gives them (``sumo_rl.grid4x4(...)`` and the seven others), on hils: each one the
PettingZoo environment of :mod:`hils.sumo_rl.environment.env` (parallel by default) on the network and demand that
the installed sumo-rl package carries, with RESCO's begin and one simulated hour, and sumo-rl's defaults for the rest
(a decision every 5 s; these are sumo-rl's environments on RESCO's networks, not hils' ``resco:`` scenarios, which
take RESCO's own decision interval and the programs' timings).

This follows sumo-rl's ``sumo_rl/environment/resco_envs.py`` (MIT License, Copyright (c) 2018 Lucas Alegre: its
notice is in :mod:`hils.sumo_rl`).
"""

from __future__ import annotations

from functools import partial
from typing import Any

from hils.protocol.resco import networks_dir
from hils.sumo_rl.environment.env import env, parallel_env

__all__ = ["arterial4x4", "cologne1", "cologne3", "cologne8", "grid4x4", "ingolstadt1", "ingolstadt7", "ingolstadt21"]

#: Each network's route file and, where RESCO's demand starts later in the day, its begin and end (s).
_NETWORKS = {
    "grid4x4": ("grid4x4_1.rou.xml", 0, 3600),
    "arterial4x4": ("arterial4x4_1.rou.xml", 0, 3600),
    "cologne1": ("cologne1.rou.xml", 25200, 28800),
    "cologne3": ("cologne3.rou.xml", 25200, 28800),
    "cologne8": ("cologne8.rou.xml", 25200, 28800),
    "ingolstadt1": ("ingolstadt1.rou.xml", 57600, 61200),
    "ingolstadt7": ("ingolstadt7.rou.xml", 57600, 61200),
    "ingolstadt21": ("ingolstadt21.rou.xml", 57600, 61200),
}


def _resco(name: str, parallel: bool = True, **kwargs: Any) -> Any:
    """RESCO's network ``name``: a PettingZoo parallel environment (AEC with ``parallel=False``); ``kwargs`` are
    :class:`hils.sumo_rl.SumoEnvironment`'s, less the network, demand and times, which are RESCO's."""
    folder = networks_dir() / name
    routes, begin, end = _NETWORKS[name]
    kwargs.update({"net_file": str(folder / f"{name}.net.xml"), "route_file": str(folder / routes),
                   "num_seconds": end - begin})
    if begin:
        kwargs["begin_time"] = begin
    return parallel_env(**kwargs) if parallel else env(**kwargs)


grid4x4 = partial(_resco, "grid4x4")
arterial4x4 = partial(_resco, "arterial4x4")
cologne1 = partial(_resco, "cologne1")
cologne3 = partial(_resco, "cologne3")
cologne8 = partial(_resco, "cologne8")
ingolstadt1 = partial(_resco, "ingolstadt1")
ingolstadt7 = partial(_resco, "ingolstadt7")
ingolstadt21 = partial(_resco, "ingolstadt21")
