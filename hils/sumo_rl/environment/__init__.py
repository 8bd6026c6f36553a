"""sumo-rl's environments on hils (:mod:`hils.sumo_rl.environment.env`); importing this package registers the
single-agent environment with gymnasium under sumo-rl's id, ``gymnasium.make("sumo-rl-v0", net_file=..., ...)``.

sumo-rl registers the same id when it is imported: the package imported last holds it. :func:`register` takes it
back for hils.
"""

import gymnasium

ENV_ID = "sumo-rl-v0"
ENTRY_POINT = "hils.sumo_rl.environment.env:SumoEnvironment"


def register() -> None:
    """Register :data:`ENV_ID` as hils' single-agent ``SumoEnvironment`` (again, if sumo-rl has taken it)."""
    spec = gymnasium.registry.get(ENV_ID)
    if spec is None or spec.entry_point != ENTRY_POINT:
        gymnasium.registry.pop(ENV_ID, None)
        gymnasium.register(id=ENV_ID, entry_point=ENTRY_POINT, kwargs={"single_agent": True})


register()
