"""Scenarios: one SUMO simulation and the controller config of each of its traffic lights.

A scenario file (``NAME.scenario.toml``) names the ``.sumocfg`` SUMO starts with and, under
``[intersections]``, each traffic light of the network (its SUMO tls id) with the intersection config
its controller runs; several lights may share one config file. Paths are relative to the scenario file::

    name = "corridor: four signalised intersections on an arterial"
    sumocfg = "corridor.sumocfg"

    [intersections]
    J1 = "corridor_arterial.toml"
    J2 = "corridor_arterial.toml"

The shipped scenarios (:data:`SCENARIOS`) live in ``hils/data``; the single-intersection ones are
scenarios of one light, "C". RESCO's eight benchmark scenarios load by name too (``resco:grid4x4``,
:mod:`hils.protocol.resco`): read from the installed sumo-rl, each light's config derived from its SUMO program,
with its signal links bound to the phases (:class:`SignalLink`) rather than mapped by compass geometry.
This module belongs to the shared layer (it reads files and imports only the config, the RESCO
derivation and the error base class), so the emulator serves a scenario's controllers without loading
the middleware or SUMO; :func:`hils.sim.network.check_scenario` checks a scenario against its network.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from hils.protocol.config import ConfigError, IntersectionConfig, load

#: The shipped scenarios, each ``hils/data/NAME.scenario.toml``.
SCENARIOS = ("four_leg", "four_phase", "corridor", "grid4x4")
#: Scenarios derived from RESCO's networks are named ``resco:NAME`` (:data:`hils.protocol.resco.MAPS`).
RESCO_PREFIX = "resco:"
SUFFIX = ".scenario.toml"
_FIELDS = ("name", "sumocfg", "intersections", "offsets")
_ALLOWED = (f"a shipped scenario ({', '.join(SCENARIOS)}), {RESCO_PREFIX}NAME (RESCO's benchmark) or a path to a "
            f"{SUFFIX} file")


@dataclass(frozen=True, slots=True)
class SignalLink:
    """How one signal link index of a traffic light follows its controller, when bound explicitly.

    Green ('G') while ``phase`` or one of ``also`` (an overlap, as a cabinet wires a right turn to two
    phases) is green, 'g' (yielding) instead when ``yields``; otherwise 'g' while one of ``yields_with`` is
    green (a permissive left beside its through); yellow while one of them is yellow; red otherwise.
    ``phase`` None: an index that controls no connection, always red."""

    phase: int | None
    yields: bool = False
    also: tuple[int, ...] = ()
    yields_with: tuple[int, ...] = ()

    @property
    def parents(self) -> tuple[int, ...]:
        """Every phase whose indication this link shows."""
        return tuple(p for p in (self.phase, *self.also, *self.yields_with) if p is not None)


@dataclass(frozen=True)
class Scenario:
    """A SUMO simulation and, per traffic light (SUMO tls id, in the file's order), its controller config.

    ``links``: per traffic light whose signal links are bound explicitly, one :class:`SignalLink` per link
    index (a derived RESCO scenario); a light not in it has its links mapped by the compass geometry of its
    network and its config's approaches and turns (:func:`hils.sim.network.derive_phase_map`)."""

    name: str
    source: str
    sumo_config: Path
    intersections: Mapping[str, IntersectionConfig]
    links: Mapping[str, tuple[SignalLink, ...]] = field(default_factory=dict)

    @property
    def tls_ids(self) -> tuple[str, ...]:
        return tuple(self.intersections)


def labels(names: Sequence[str]) -> dict[str, str | None]:
    """How the outputs of a run of these intersections name each one: by its name (every record's
    ``intersection``, ``J2 north`` in a summary, ``J2:`` in a message), or, in a run of one, not at all: it
    writes what the single-controller run always wrote."""
    return {name: name if len(names) > 1 else None for name in names}


def described(label: str | None, config: IntersectionConfig) -> str:
    """An intersection's config name less the label it repeats: a RESCO light's derived config is named after the
    light ("A0, dual-ring from its SUMO program"), where a label already names it."""
    return config.name.removeprefix(f"{label}, ") if label else config.name


def scenario_path(name_or_path: str | Path) -> Path:
    """The file of a shipped scenario's name, or the path given."""
    if str(name_or_path) in SCENARIOS:
        return Path(str(resources.files("hils.data") / f"{name_or_path}{SUFFIX}"))
    path = Path(name_or_path)
    # A bare word is a misspelt name rather than a file in the working directory.
    if isinstance(name_or_path, str) and path.suffix != ".toml" and len(path.parts) == 1:
        raise ConfigError(str(name_or_path), "<scenario>", f"no shipped scenario of that name; allowed: {_ALLOWED}")
    return path


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a shipped scenario by name, RESCO's by ``resco:NAME``, or a ``.scenario.toml`` file, with the config
    of every intersection."""
    if isinstance(name_or_path, str) and name_or_path.startswith(RESCO_PREFIX):
        from hils.protocol import resco  # here: it reads networks with sumolib, which a file scenario never needs

        return resco.load(name_or_path.removeprefix(RESCO_PREFIX))
    path = scenario_path(name_or_path)
    source = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(source, "<file>", f"cannot be read ({exc.strerror}); allowed: {_ALLOWED}") from None
    except UnicodeDecodeError:
        raise ConfigError(source, "<file>", "is not UTF-8 text; allowed: a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "<file>", f"is not valid TOML ({exc})") from None
    for key in raw:
        if key not in _FIELDS:
            raise ConfigError(source, key, f"unknown field; allowed: {', '.join(_FIELDS)}")
    name = raw.get("name", path.name.removesuffix(SUFFIX))
    if not isinstance(name, str):
        raise ConfigError(source, "name", f"is {name!r}; allowed: a string")
    sumocfg = _relative_file(raw.get("sumocfg"), path, source, "sumocfg", "a SUMO configuration (.sumocfg)")
    intersections = _intersections(raw.get("intersections"), path, source)
    return Scenario(name, source, sumocfg, MappingProxyType(_offsets(raw.get("offsets", {}), intersections, source)))


def _offsets(raw: Any, intersections: dict[str, IntersectionConfig], source: str) -> dict[str, IntersectionConfig]:
    """``[offsets]``: a light's offset (s) in its coordination patterns, for progression along a corridor."""
    if not isinstance(raw, dict):
        raise ConfigError(source, "offsets", "must be a table of traffic light id = offset in seconds, e.g. J2 = 22")
    out = dict(intersections)
    for tls, value in raw.items():
        if tls not in intersections:
            raise ConfigError(source, f"offsets.{tls}", f"unknown traffic light; allowed: {', '.join(intersections)}")
        if type(value) is not int or not 0 <= value <= 254:
            raise ConfigError(source, f"offsets.{tls}", f"is {value!r}; allowed: whole seconds 0-254 "
                                                        "(NTCIP patternOffsetTime)")
        if not intersections[tls].coordination.patterns:
            raise ConfigError(source, f"offsets.{tls}", "its config has no [[coordination.patterns]] to offset")
        out[tls] = intersections[tls].with_offset(value)
    return out


def _relative_file(value: Any, scenario: Path, source: str, field_name: str, what: str) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(source, field_name, f"is {value!r}; allowed: the path of {what}, relative to this file")
    path = scenario.parent / value
    if not path.is_file():
        raise ConfigError(source, field_name, f"{path} does not exist; allowed: the path of {what}, "
                                              "relative to this file")
    return path


def _intersections(raw: Any, scenario: Path, source: str) -> dict[str, IntersectionConfig]:
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(source, "intersections", "is required: a table of traffic light id = intersection config "
                                                   'file, e.g. J1 = "arterial.toml"')
    loaded: dict[Path, IntersectionConfig] = {}
    out = {}
    for tls, value in raw.items():
        path = _relative_file(value, scenario, source, f"intersections.{tls}", "an intersection config (.toml)")
        # Lights that share a file share one (immutable) config.
        key = path.resolve()
        if key not in loaded:
            loaded[key] = load(path)
        out[tls] = loaded[key]
    return out


def load_targets(path: str | Path) -> dict[str, str]:
    """The controllers of a scenario at the wall clock: a TOML file of ``TLS = "snmp://HOST:PORT?..."`` lines,
    one per traffic light (``hils run --scenario corridor --target targets.toml``)."""
    source = str(path)
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(source, "<file>", f"cannot be read ({exc.strerror}); allowed: a TOML file of "
                                            'TLS = "snmp://HOST:PORT?community=NAME&version=1|2c" lines') from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(source, "<file>", f"is not a TOML file ({exc})") from None
    for tls, url in raw.items():
        if not isinstance(url, str) or not url.startswith("snmp://"):
            raise ConfigError(source, tls, f"is {url!r}; allowed: an snmp://HOST:PORT URL")
    return dict(raw)
