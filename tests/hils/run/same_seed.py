"""What two runs of one seed share: their event logs and summaries less what the wall clock stamps.

The event log's ``wall_ns`` (:mod:`hils.shell.events`: the only field of a record that differs between two runs of
the same seed) and the summary's figures measured on the wall clock: the run's wall time and the middleware's
internal latencies (each intersection's, in a run of several)."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from hils.report import jsonout

WALL_CLOCK_FIGURES = frozenset({"wall_time_s", "internal_latency_ms"})


def records(records: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The records less their ``wall_ns``."""
    return [{k: v for k, v in r.items() if k != "wall_ns"} for r in records]


def logged(path: Path) -> list[dict[str, Any]]:
    """An event log file's records less their ``wall_ns``."""
    return records(json.loads(line) for line in path.read_text(encoding="utf-8").splitlines())


def summary(summary: Mapping[str, Any]) -> dict[str, Any]:
    """A summary as summary.json holds it, less the wall clock's figures at every level."""
    def without(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: without(v) for k, v in value.items() if k not in WALL_CLOCK_FIGURES}
        return value
    return without(json.loads(jsonout.dumps(summary)))
