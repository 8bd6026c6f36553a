"""The structured event log: one JSON Lines record per step of the data flow.

Schema of a record (every key always present, extra keys by kind)::

    {"seq": 17, "t": 12.3456, "wall_ns": 123456789, "kind": "command_dispatched", ...}

- ``seq``: 0-based position in the log, so a gap shows a lost record;
- ``t``: simulation time in seconds (the SimPy clock, virtual or wall-mapped);
- ``wall_ns``: ``time.monotonic_ns()`` when the record was made; the only field
  that differs between two runs of the same seed;
- ``kind``: one of :class:`Kind`; the other keys are documented there;
- ``intersection``: in a run of several controllers, the traffic light (SUMO tls id) whose
  controller the record is about; run-wide records (``run_started``, ``run_ended``) have none.

Records are written through (flushed) as they are made, so a run that dies
keeps every event logged before it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

import orjson


class Kind(StrEnum):
    """Event kinds and the keys each one adds."""

    RUN_STARTED = "run_started"                # config, source, seed, mode, action_type, agent, duration
    #                                                        (several: scenario, source, intersections; no config)
    ACTION_RECEIVED = "action_received"        # action_id, action_type, value
    ACTION_CONVERTED = "action_converted"      # action_id, command [p1, p2], green (s or null), keep
    ACTION_REFUSED = "action_refused"          # action_id, error, reason
    ACTION_DROPPED = "action_dropped"          # action_id, state
    COMMAND_DISPATCHED = "command_dispatched"  # action_id, command_id, command, green
    SET_SENT = "set_sent"                      # command_id, phases, purpose: startup|command|retry|keepalive|
    #                                                        recovery|clear (startup: all six objects at 0)
    SET_ANSWERED = "set_answered"              # command_id, purpose
    SET_FAILED = "set_failed"                  # command_id, purpose, error
    POLL = "poll"                              # poll_id, greens, yellows: a read that changed the state seen
    #                                                        (poll 0: the start-up read); counts in run_ended
    POLL_FAILED = "poll_failed"                # poll_id, error, consecutive
    TRANSITION_VERIFIED = "transition_verified"  # command_id, command, poll_id, hold_s
    HOLD_RELEASED = "hold_released"            # command_id, reason (verified|served|timeout|keep), hold_s
    DRIFT = "drift"                            # step_s, took_s, consecutive
    TIMEOUT_ENTERED = "timeout_entered"        # reason (communication|transition|drift|foreign_control), command_id,
    #                                                        detail
    RECOVERY_STARTED = "recovery_started"      # -
    RECOVERED = "recovered"                    # greens
    STATE = "state"                            # from, to: the paper's names (idle, on_hold, timeout)
    RUN_ENDED = "run_ended"                    # reason (duration|closed|interrupted|terminated|agent_error|error),
    #                                                        polls {polls, elided, answered, failed, late}
    QUEUES = "queues"                          # queues {approach: vehicles queued upstream} (SUMO runs, every 5 s)
    CABINET = "cabinet"                        # walks, ped_clears, veh_calls, ped_calls, nexts: phases
    #                                                        (dashboard runs, on change, read every 1 s)
    DETECTORS = "detectors"                    # active: vehicle detectors actuated now (on change;
    #                                                        runs on detectors, e.g. --agent actuated)
    PREEMPT_INPUTS = "preempt_inputs"          # active: preempts SUMO calls now (on change; configs whose
    #                                                        preempts name a detection zone)
    NOTE = "note"                              # free text for harness faults and components


class EventLog:
    """Write-through JSON Lines log; also keeps the records in memory when asked."""

    def __init__(self, path: str | Path | None = None, *, keep: bool = True, clock=None) -> None:
        self.path = Path(path) if path is not None else None
        self._file: IO[bytes] | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # Unbuffered: each record is one write(2), on disk (in the OS) before emit returns.
            self._file = self.path.open("wb", buffering=0)
        self.records: list[dict[str, Any]] = []
        self.keep = keep
        self._seq = 0
        self._clock = clock
        self._subscribers: list[Callable[[dict[str, Any]], None]] = []
        self._subscribers_of: dict[str, list[Callable[[dict[str, Any]], None]]] = {}

    def bind(self, clock) -> None:
        """Give the log the simulation clock: a callable returning the current sim time."""
        self._clock = clock

    def subscribe(self, fn: Callable[[dict[str, Any]], None], intersection: str | None = None) -> None:
        """Call ``fn(record)`` with every record emitted from now on (the live dashboard folds them); with
        ``intersection``, only with that intersection's records and the run's own (those naming none)."""
        if intersection is None:
            self._subscribers.append(fn)
        else:
            # Kept apart, so that a record reaches its own intersection's subscribers only: a grid's
            # tallies would otherwise each be handed, and each turn away, every other controller's records.
            self._subscribers_of.setdefault(intersection, []).append(fn)

    def emit(self, kind: Kind, **fields: Any) -> dict[str, Any]:
        rec = {"seq": self._seq, "t": self._clock() if self._clock else 0.0, "wall_ns": time.monotonic_ns(),
               "kind": kind.value, **fields}
        self._seq += 1
        if self.keep:
            self.records.append(rec)
        if self._file is not None:
            self._file.write(orjson.dumps(rec, default=_jsonable, option=orjson.OPT_APPEND_NEWLINE))
        for fn in self._subscribers:
            fn(rec)
        if self._subscribers_of:
            where = fields.get("intersection")
            for fn in (self._subscribers_of.get(where, ()) if where is not None else
                       [fn for fns in self._subscribers_of.values() for fn in fns]):
                fn(rec)
        return rec

    def of(self, *kinds: Kind) -> list[dict[str, Any]]:
        names = {k.value for k in kinds}
        return [r for r in self.records if r["kind"] in names]

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _jsonable(value: Any) -> Any:
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def read(path: str | Path) -> Iterator[dict[str, Any]]:
    """Records of a JSON Lines event log; a torn last line (a crash mid-write) is ignored."""
    with Path(path).open(encoding="utf-8") as f:
        for line in f:
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                return


class TaggedLog:
    """One controller's view of a run's log: every record it emits names its intersection.

    In a run of several controllers each middleware, poller and detector feed writes through its own
    view; the records land in the one log, in one sequence, each with ``intersection``."""

    def __init__(self, log: EventLog, intersection: str) -> None:
        self.log = log
        self.intersection = intersection

    def bind(self, clock) -> None:
        self.log.bind(clock)

    def emit(self, kind: Kind, **fields: Any) -> dict[str, Any]:
        return self.log.emit(kind, **fields, intersection=self.intersection)

    def of(self, *kinds: Kind) -> list[dict[str, Any]]:
        return [r for r in self.log.of(*kinds) if r.get("intersection") == self.intersection]
