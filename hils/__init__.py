"""hils: a hardware-in-the-loop testbed for real-time traffic-signal phase control over NTCIP 1202.

The public API: :class:`Testbed` assembles and drives a run (virtual time against the built-in
emulator, or wall-clock time against a real controller); :class:`ActionType` names the three action
designs; :class:`Observation` is what an agent sees; :class:`ActionError` is the typed refusal of an
action that cannot be served; :func:`load_config` reads an intersection config.

The names are loaded when first used, so that importing the shared layer (``hils.protocol.ntcip``,
``hils.protocol.config``), as the emulator does, does not load the middleware.

The gymnasium environment ``hils/Intersection-v1`` is registered by :mod:`hils.envs`, as gymnasium documents
for third-party environments: ``import hils.envs`` first, or let gymnasium import it,
``gymnasium.make("hils.envs:hils/Intersection-v1")``. ``import hils`` loads neither gymnasium nor the envs.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ActionError": ("hils.control.actions", "ActionError"),
    "ActionType": ("hils.control.actions", "ActionType"),
    "Agent": ("hils.agents.builtin", "Agent"),
    "AgentFailed": ("hils.protocol.errors", "AgentFailed"),
    "ConfigError": ("hils.protocol.config", "ConfigError"),
    "IntersectionConfig": ("hils.protocol.config", "IntersectionConfig"),
    "Observation": ("hils.agents.builtin", "Observation"),
    "RunInterrupted": ("hils.protocol.errors", "RunInterrupted"),
    "State": ("hils.control.manager", "State"),
    "Testbed": ("hils.run.testbed", "Testbed"),
    "UserError": ("hils.protocol.errors", "UserError"),
    "load_config": ("hils.protocol.config", "load"),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    try:
        module, attribute = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'hils' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
