"""hils: a hardware-in-the-loop testbed for real-time traffic-signal phase control over NTCIP 1202.

The public API: :class:`Testbed` assembles and drives a run (virtual time against the built-in
emulator, or wall-clock time against a real controller); :class:`ActionType` names the three action
designs; :class:`Observation` is what an agent sees; :class:`ActionError` is the typed refusal of an
action that cannot be served; :func:`load_config` reads an intersection config.

The names are loaded when first used, so that importing the shared layer (``hils.ntcip``,
``hils.config``), as the emulator does, does not load the middleware.

The gymnasium environment ``hils/Intersection-v0`` (:mod:`hils.envs`) is registered on ``import hils``
without importing gymnasium: at once when gymnasium is already loaded, else the moment it is (an import
hook that steps aside after that one import), so ``gymnasium.make`` finds it whichever came first.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
from typing import Any

_EXPORTS = {
    "ActionError": ("hils.actions", "ActionError"),
    "ActionType": ("hils.actions", "ActionType"),
    "Agent": ("hils.agents", "Agent"),
    "AgentFailed": ("hils.errors", "AgentFailed"),
    "ConfigError": ("hils.config", "ConfigError"),
    "IntersectionConfig": ("hils.config", "IntersectionConfig"),
    "Observation": ("hils.agents", "Observation"),
    "RunInterrupted": ("hils.errors", "RunInterrupted"),
    "State": ("hils.manager", "State"),
    "Testbed": ("hils.testbed", "Testbed"),
    "UserError": ("hils.errors", "UserError"),
    "load_config": ("hils.config", "load"),
}

__all__ = sorted(_EXPORTS)



class _RegisterWithGymnasium(importlib.abc.MetaPathFinder):
    """Registers hils' environments right after gymnasium is first imported (then leaves the import path)."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            exec_module = spec.loader.exec_module

            def exec_and_register(module: Any) -> None:
                exec_module(module)
                importlib.import_module("hils.envs")

            spec.loader.exec_module = exec_and_register
        return spec


if "gymnasium" in sys.modules:
    importlib.import_module("hils.envs")
else:
    sys.meta_path.insert(0, _RegisterWithGymnasium())


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
