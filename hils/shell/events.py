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
keeps every event logged before it. A record is written whole or not at all: when
the file cannot take one (a full disk, a file size limit), the file is cut back to
the records before it and the log stops writing; the records go on in memory and to
subscribers, and the failure is handed to ``on_failure`` (a run then ends as an error,
its calls cleared) or, without one, raised.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import orjson

from hils.protocol.errors import STOPS
from hils.shell.appendfile import AppendFile

log = logging.getLogger(__name__)


class Kind(StrEnum):
    """Event kinds and the keys each one adds."""

    RUN_STARTED = "run_started"                # config, source, seed, mode, action_type, agent, duration
    #                                                        (several: scenario, source, intersections; no config)
    ACTION_RECEIVED = "action_received"        # action_id, action_type, value
    ACTION_CONVERTED = "action_converted"      # action_id, command [p1, p2], green (s or null), keep; a phase-
    #                                                        control schedule: command [], orders (how many),
    #                                                        span_s (null: a step), dropped (orders left out)
    ACTION_REFUSED = "action_refused"          # action_id, error, reason
    ACTION_DROPPED = "action_dropped"          # action_id, state
    COMMAND_DISPATCHED = "command_dispatched"  # action_id, command_id, command, green
    SET_SENT = "set_sent"                      # command_id, phases, purpose: startup|command|retry|keepalive|
    #                                                        recovery|withdraw|clear (startup: all six objects
    #                                                        at 0; withdraw: no phase, as a preempt begins);
    #                                                        phase control: controls {object: phases} SET,
    #                                                        phases its VehCall, purposes schedule|reestablish|
    #                                                        release too
    SET_ANSWERED = "set_answered"              # command_id, purpose
    SET_FAILED = "set_failed"                  # command_id, purpose, error
    POLL = "poll"                              # poll_id, greens, yellows: a read that changed the state seen, or
    #                                                        the first answer after failed polls (poll 0: the
    #                                                        start-up read); counts in run_ended
    POLL_FAILED = "poll_failed"                # poll_id, error, consecutive
    TRANSITION_VERIFIED = "transition_verified"  # command_id, command, poll_id, hold_s
    HOLD_RELEASED = "hold_released"            # command_id, reason (verified|served|timeout|preempted|keep),
    #                                                        hold_s
    DRIFT = "drift"                            # step_s, took_s, consecutive
    TIMEOUT_ENTERED = "timeout_entered"        # reason (communication|transition|drift|foreign_control|agent),
    #                                                        command_id, detail
    AGENT_LATE = "agent_late"                  # took_s, discarded: the agent answered after the next SUMO step was
    #                                                        due (discarded: beyond the control interval)
    PREEMPT_BEGIN = "preempt_begin"            # preempts (in service), command_id (the command it ended, or
    #                                                        null): a poll read a preemptState in service
    PREEMPT_END = "preempt_end"                # duration_s, greens (shown on leaving): a poll read none in
    #                                                        service (a TIMEOUT meanwhile leaves it unended)
    RECOVERY_STARTED = "recovery_started"      # -
    RECOVERED = "recovered"                    # greens
    STATE = "state"                            # from, to: the paper's names (idle, on_hold, timeout) and preempted
    RUN_ENDED = "run_ended"                    # reason (duration|closed|interrupted|terminated|agent_error|error),
    #                                                        polls {polls, elided, answered, failed, late}
    QUEUES = "queues"                          # queues {approach: vehicles queued upstream} (SUMO runs, every 5 s)
    CABINET = "cabinet"                        # walks, ped_clears, veh_calls, ped_calls, nexts: phases
    #                                                        (dashboard runs, on change, read every 1 s)
    DETECTORS = "detectors"                    # active: vehicle detectors actuated now (on change;
    #                                                        runs on detectors, e.g. --agent actuated)
    PREEMPT_INPUTS = "preempt_inputs"          # active: preempts SUMO calls now (on change; configs whose
    #                                                        preempts name a detection zone)
    SCHEDULE_STARTED = "schedule_started"      # action_id, orders [[type, phase, start_s, end_s or null]], span_s
    SCHEDULE_ENDED = "schedule_ended"          # reason (done|replaced|cleared|preempted|closed)
    CONTROL_ORDER = "control_order"            # index, control, phase, from, to: an order's life cycle (waiting,
    #                                                        armed, acting, spent, ended, lapsed)
    CONTROLS_RESET = "controls_reset"          # detail: the controller no longer held the control objects the run
    #                                                        SET (backupMode, or cleared): SET again
    NOTE = "note"                              # free text for harness faults and components


class LogWriteError(Exception):
    """The event log's file cannot be written (a full disk, a file size limit, a folder that is not writable)."""


def signal_known(record: dict[str, Any]) -> bool | None:
    """What a record says of the signal state the middleware holds: True when it is verified again (a poll
    answered, a recovery's re-read), False when it no longer is (a poll failed with no newer answer in, or
    polling halted: in TIMEOUT, or by the close's clearing SET), None when the record says nothing of it.
    Until the next True, what was last polled is not known to be what the street shows: the plots draw it
    as no data."""
    kind = record["kind"]
    if kind in (Kind.POLL, Kind.RECOVERED):
        return True
    if (kind == Kind.TIMEOUT_ENTERED or (kind == Kind.POLL_FAILED and record.get("consecutive"))
            or (kind == Kind.SET_SENT and record.get("purpose") == "clear")):  # the close halts polling
        return False
    return None


class EventLog:
    """Write-through JSON Lines log; also keeps the records in memory when asked."""

    def __init__(self, path: str | Path | None = None, *, keep: bool = True, clock=None) -> None:
        self.path = Path(path) if path is not None else None
        self._file: AppendFile | None = None
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                # Each record on disk (in the OS) before emit returns.
                self._file = AppendFile(self.path)
            except OSError as exc:
                raise LogWriteError(f"cannot write the event log {self.path}: {exc.strerror or exc}") from None
        #: Why the file stopped taking records (None while it takes them).
        self.failure: LogWriteError | None = None
        #: Called once with :attr:`failure` when the file stops taking records; without it the failure is raised.
        self.on_failure: Callable[[LogWriteError], None] | None = None
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
        return self.record(kind, fields, fields.get("intersection"))

    def record(self, kind: Kind, fields: dict[str, Any], intersection: str | None) -> dict[str, Any]:
        """:meth:`emit` of ``fields`` (a dict the log may keep) about ``intersection`` (None: the run's own)."""
        # kind._value_, not kind.value: Enum's value is a property, a Python call for every record of the run.
        rec = {"seq": self._seq, "t": self._clock() if self._clock else 0.0, "wall_ns": time.monotonic_ns(),
               "kind": kind._value_, **fields}
        self._seq += 1
        if self.keep:
            self.records.append(rec)
        if self._file is not None:
            try:
                line = orjson.dumps(rec, default=_jsonable, option=orjson.OPT_APPEND_NEWLINE)
            except orjson.JSONEncodeError as exc:
                # Ctrl-C or SIGTERM raised inside _jsonable: orjson wraps it, and the run must see it as what it is.
                if isinstance(exc.__cause__, STOPS):
                    raise exc.__cause__ from None
                raise
            self._write(line)
        for fn in self._subscribers:
            fn(rec)
        if self._subscribers_of:
            for fn in (self._subscribers_of.get(intersection, ()) if intersection is not None else
                       [fn for fns in self._subscribers_of.values() for fn in fns]):
                fn(rec)
        return rec

    def _write(self, line: bytes) -> None:
        """One record, whole (:class:`hils.shell.appendfile.AppendFile`); a file that stops taking them is a failure."""
        if self._file.append(line):
            return
        file, self._file = self._file, None
        self.failure = LogWriteError(f"cannot write the event log {self.path}: {file.failure.strerror or file.failure} "
                                     f"(it keeps its first {file.records} records, whole)")
        if self.on_failure is None:
            raise self.failure
        self.on_failure(self.failure)

    def of(self, *kinds: Kind) -> list[dict[str, Any]]:
        names = {k.value for k in kinds}
        return [r for r in self.records if r["kind"] in names]

    def close(self) -> None:
        if self._file is not None:
            file, self._file = self._file, None
            file.close()


def _jsonable(value: Any) -> Any:
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


class EventLogError(ValueError):
    """A line of an event log that is not a record; names the file and the line."""


@dataclass(frozen=True, slots=True)
class BadLine:
    """A line of an event log that :func:`read` skipped, and why."""

    path: Path
    line: int  # 1-based
    why: str

    def __str__(self) -> str:
        return f"{self.path}: line {self.line}: {self.why}"


#: How deep a record's values may nest: ours go three levels deep; a deeper one was not written by a run.
MAX_DEPTH = 32


def read(path: str | Path, *, on_bad: Callable[[BadLine], None] | None = None) -> Iterator[dict[str, Any]]:
    """The records of a JSON Lines event log, each checked: a JSON object with an integer ``seq``, a finite
    number ``t`` and a string ``kind``, nested at most :data:`MAX_DEPTH` deep.

    A line that is not such a record raises :class:`EventLogError` naming the file and the line, or, given
    ``on_bad``, is handed to it and skipped. A torn last line (no end of line: the run was killed as it wrote
    it) is skipped either way, and handed to ``on_bad`` or logged as a warning: never dropped unsaid."""
    path = Path(path)
    with path.open("rb") as f:
        for number, line in enumerate(f, start=1):
            record, why = _record(line)
            if record is not None:
                yield record
                continue
            torn = not line.endswith(b"\n")
            bad = BadLine(path, number, "torn (no end of line: the run stopped as it wrote it)" if torn else why)
            if on_bad is not None:
                on_bad(bad)
            elif torn:
                log.warning("%s; skipped", bad)
            else:
                raise EventLogError(f"{bad}; allowed: one JSON object per line, with seq, t and kind")


def _record(line: bytes) -> tuple[dict[str, Any] | None, str]:
    """The record a line of a log holds, or None and why it holds none."""
    try:
        record = orjson.loads(line)
    except orjson.JSONDecodeError as exc:
        return None, f"not JSON ({exc})"
    if not isinstance(record, dict):
        return None, f"a JSON {type(record).__name__}, not an object"
    seq, t, kind = record.get("seq"), record.get("t"), record.get("kind")
    if isinstance(seq, bool) or not isinstance(seq, int):
        return None, f"seq is {_short(seq)}; allowed: an integer"
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
        return None, f"t is {_short(t)}; allowed: a finite number of seconds"
    if not isinstance(kind, str):
        return None, f"kind is {_short(kind)}; allowed: a string"
    if _depth(record) > MAX_DEPTH:
        return None, f"nested deeper than {MAX_DEPTH} levels"
    return record, ""


def _depth(value: Any) -> int:
    """How deep lists and objects nest in ``value`` (without recursion: a crafted line may nest a thousand deep)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict | list):
            deepest = max(deepest, depth)
            stack.extend((child, depth + 1) for child in (node.values() if isinstance(node, dict) else node))
    return deepest


def _short(value: Any) -> str:
    return "missing" if value is None else repr(value)[:40]


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
        fields["intersection"] = self.intersection  # last, as in every record that names one
        return self.log.record(kind, fields, self.intersection)

    def of(self, *kinds: Kind) -> list[dict[str, Any]]:
        return [r for r in self.log.of(*kinds) if r.get("intersection") == self.intersection]
