"""sumo-rl's environments on hils (:mod:`hils.sumo_rl.environment.env`); importing this package registers the
single-agent environment with gymnasium as sumo-rl does, ``gymnasium.make("sumo-rl-v0", net_file=..., ...)``."""

from gymnasium.envs.registration import register

register(id="sumo-rl-v0", entry_point="hils.sumo_rl.environment.env:SumoEnvironment", kwargs={"single_agent": True})
