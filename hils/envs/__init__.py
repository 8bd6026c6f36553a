"""Gymnasium environments on the Testbed: ``gymnasium.make("hils/Intersection-v0", action_type=...)``.

:func:`register` puts the environment into gymnasium's registry by its entry-point string, so that
registering loads neither the Testbed nor SUMO. ``import hils`` registers it when gymnasium is
already imported; ``import hils.envs`` always does (gymnasium is imported then).
"""

from __future__ import annotations

ENV_ID = "hils/Intersection-v0"


def register() -> None:
    """Register :data:`ENV_ID` with gymnasium (idempotent)."""
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="hils.envs.intersection:IntersectionEnv",
                           disable_env_checker=False)


register()
