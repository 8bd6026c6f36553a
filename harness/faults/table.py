"""Reading one table of a fault-scenario file: each key checked for its type and range, anything not allowed
refused with a :class:`FaultScenarioError` that names the file, the key and what is allowed.

The file's reader (:mod:`harness.faults.reader`) and the fault registry (:mod:`harness.faults.registry`) read
their tables through :class:`TableReader`, so every error of a scenario file reads the same way.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from hils.protocol.config import ConfigError

__all__ = ["FaultScenarioError", "TableReader"]


class FaultScenarioError(ConfigError):
    """A fault-scenario file that cannot be used; the message names the file and the key."""


class TableReader:
    """Reads keys of one TOML table, refusing what is not allowed, naming the file and the key."""

    def __init__(self, raw: Any, where: str, source: str, allowed: Iterable[str]) -> None:
        self.source = source
        self.where = where
        if not isinstance(raw, dict):
            raise FaultScenarioError(source, where.rstrip(".") or "<file>", "must be a table")
        self.raw = raw
        allowed = tuple(allowed)
        for key in raw:
            if key not in allowed:
                raise FaultScenarioError(source, f"{where}{key}", f"unknown key; allowed: {', '.join(allowed)}")

    def error(self, key: str, message: str) -> FaultScenarioError:
        return FaultScenarioError(self.source, f"{self.where}{key}", message)

    def has(self, key: str) -> bool:
        return key in self.raw

    def number(self, key: str, default: Any = None, *, integer: bool = False, low: float | None = None,
               low_open: bool = False, high: float | None = None) -> Any:
        value = self.raw.get(key, default)
        if value is None:
            raise self.error(key, "is required")
        kinds = (int,) if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds) or (
                isinstance(value, float) and not math.isfinite(value)):
            raise self.error(key, f"must be {'an integer' if integer else 'a finite number'}, got {value!r}")
        if (low is not None and (value <= low if low_open else value < low)) or (high is not None and value > high):
            lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
            hi = "" if high is None else f"<= {high:g}"
            raise self.error(key, f"is {value}; allowed: {' and '.join(x for x in (lo, hi) if x)}")
        return value if integer else float(value)

    def optional_number(self, key: str, **kwargs: Any) -> Any:
        return self.number(key, **kwargs) if key in self.raw else None

    def string(self, key: str, default: str | None = None, *, choices: Iterable[str] | None = None) -> str:
        value = self.raw.get(key, default)
        if value is None:
            raise self.error(key, "is required")
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {value!r}")
        if choices is not None:
            options = tuple(choices)
            if value not in options:
                raise self.error(key, f"is {value!r}; allowed: {', '.join(options)}")
        return value

    def strings(self, key: str, *, choices: Iterable[str]) -> tuple[str, ...]:
        """A string or a list of strings, each one of ``choices``."""
        value = self.raw.get(key)
        items = [value] if isinstance(value, str) else value
        options = tuple(choices)
        if not isinstance(items, list) or not items or not all(isinstance(v, str) for v in items):
            raise self.error(key, f"must be a string or a non-empty list of strings, got {value!r}")
        for v in items:
            if v not in options:
                raise self.error(key, f"has {v!r}; allowed: {', '.join(options)}")
        return tuple(items)

    def phases(self, key: str, allowed: Iterable[int]) -> tuple[int, ...]:
        """A non-empty list of phase numbers, each one of ``allowed``."""
        value = self.raw.get(key)
        options = sorted(allowed)
        if not isinstance(value, list) or not value or not all(
                isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise self.error(key, f"must be a non-empty list of phase numbers, got {value!r}")
        for v in value:
            if v not in options:
                raise self.error(key, f"has {v}; allowed: {', '.join(map(str, options))}")
        return tuple(sorted(set(value)))

    def boolean(self, key: str, default: bool) -> bool:
        value = self.raw.get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

