"""Reinforcement-learning environments on the Testbed.

- gymnasium: ``gymnasium.make("hils/Intersection-v1", action_type=...)``, one intersection
  (:mod:`hils.envs.intersection`).
- PettingZoo: :func:`parallel_env`, a ``ParallelEnv`` with one agent per traffic light of a scenario
  (:mod:`hils.envs.parallel`).

Importing this package registers the gymnasium environment (:func:`register`, by its entry-point string, so
that registering loads neither the Testbed nor SUMO), as gymnasium documents for third-party environments:
``import hils.envs`` before ``gymnasium.make("hils/Intersection-v1")``, or name the package in the id,
``gymnasium.make("hils.envs:hils/Intersection-v1")``, and gymnasium imports it. PettingZoo is imported only
when :func:`parallel_env` is called.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hils.control.actions import ActionType
    from hils.envs.parallel import IntersectionsEnv
    from hils.protocol.scenario import Scenario


__all__ = ["ENV_ID", "parallel_env", "register"]
ENV_ID = "hils/Intersection-v1"


def register() -> None:
    """Register :data:`ENV_ID` with gymnasium (idempotent)."""
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="hils.envs.intersection:IntersectionEnv",
                           disable_env_checker=False)


def parallel_env(scenario: str | Path | Scenario = "corridor", action_type: ActionType | str = "selection",
                 **options: Any) -> IntersectionsEnv:
    """A PettingZoo ``ParallelEnv`` of ``scenario`` (``corridor``, ``grid4x4`` or a ``.scenario.toml`` path),
    one agent per traffic light; ``options`` as :class:`hils.envs.parallel.IntersectionsEnv` takes them."""
    from hils.envs.parallel import IntersectionsEnv

    return IntersectionsEnv(scenario, action_type, **options)


register()
