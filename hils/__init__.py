"""hils: a hardware-in-the-loop testbed for real-time traffic-signal phase control over NTCIP 1202.

The public API: :class:`Testbed` assembles and drives a run (virtual time against the built-in
emulator, or wall-clock time against a real controller); :class:`ActionType` names the three action
designs; :class:`Observation` is what an agent sees; :class:`ActionError` is the typed refusal of an
action that cannot be served; :func:`load_config` reads an intersection config.
"""

from hils.actions import ActionError, ActionType
from hils.agents import Agent, Observation
from hils.config import ConfigError, IntersectionConfig
from hils.config import load as load_config
from hils.manager import State
from hils.testbed import AgentFailed, RunInterrupted, Testbed

__all__ = [
    "ActionError",
    "ActionType",
    "Agent",
    "AgentFailed",
    "ConfigError",
    "IntersectionConfig",
    "Observation",
    "RunInterrupted",
    "State",
    "Testbed",
    "load_config",
]
