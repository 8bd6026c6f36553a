"""The board: what the dashboard shows, folded from the event log one record at a time.

Rules of this file
------------------
- The event log is the only input. A live run feeds each record as it is emitted (an
  :class:`hils.shell.events.EventLog` subscriber); a replay feeds the records of a finished run's log. Both
  go through :meth:`Board.feed`, so a replayed instant shows exactly what the live page showed then.
- No I/O, no clock, no SimPy: time is the records' ``t`` (sim seconds).
- Feeding a record is O(1) apart from trimming the strip: a wall-clock run feeds it on the SimPy hot
  path. :meth:`Board.snapshot` (the JSON the page draws) is where the work is done.
- A run of several controllers (a corridor, a grid) is folded by :class:`Panels`: one :class:`Board` per
  intersection, fed the records that name it (``intersection``); the run-wide records (``run_started``,
  ``run_ended``) belong to the run, and each board takes its own poll counts from ``run_ended``.

Theory of operation
-------------------
Each kind of record updates one part of the board (see ``_HANDLERS``):

- ``poll``: the indication of every phase (green, yellow, else red); a change opens a segment of the
  strip, which keeps the last :data:`STRIP_S` seconds. A record after which the signal state is not
  verified (:func:`hils.shell.events.signal_known`: polls failing, halted in TIMEOUT or by the close) opens a
  segment without indications, drawn as no data, until the next poll or recovery.
- ``cabinet`` (dashboard runs only, :mod:`hils.dashboard.cabinet`): walks, pedestrian clearances
  (flashing don't walk), the controller's vehicle and pedestrian calls and PhaseNext, and the
  overlaps' greens and yellows; a run logged without a dashboard has none, and the page says so. A
  flashing yellow arrow is told from a steady one by its permissive phase's green in the last poll.
- ``set_sent``: VehCall as last SET (the calls the middleware places), and the SET counts.
- ``command_dispatched`` / ``hold_released`` / ``transition_verified``: the last commands with their
  hold times; a command kept without a SET (``keep``) appears when its hold is released.
- ``state``, ``timeout_entered``, ``recovery_started``, ``recovered``: the manager's state and, in
  TIMEOUT, its reason and detail.
- ``poll_failed``, ``drift``, ``queues``, ``run_started``, ``run_ended``: counters, queues per
  approach, what the run is and how it ended.
"""

from __future__ import annotations

import bisect
import copy
import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from hils.dashboard.cabinet import COLUMNS as CABINET_COLUMNS
from hils.dashboard.cabinet import OVERLAP_COLUMNS
from hils.protocol.config import IntersectionConfig, OverlapKind
from hils.protocol.scenario import described
from hils.shell.events import signal_known

#: Seconds of signal history in the strip.
STRIP_S = 120.0
#: Commands listed.
LAST_COMMANDS = 8

GREEN, YELLOW, RED = "G", "Y", "r"
FLASHING = "F"  # a flashing yellow arrow (an overlap's permissive indication)


@dataclass
class CommandRow:
    """One command in the list of the last commands."""

    command_id: int | None
    phases: list[int]
    t: float
    green: float | None = None  # the prescribed green of a duration command
    verified_s: float | None = None  # dispatch to the poll that showed it
    hold_s: float | None = None  # dispatch to the release of the hold
    outcome: str | None = None  # verified, served, timeout, keep; None while held


@dataclass
class Board:
    """The dashboard's view of one intersection's run."""

    config: IntersectionConfig
    t: float = 0.0
    run: dict[str, Any] = field(default_factory=dict)  # the run_started record's fields
    ended: str | None = None  # run_ended's reason
    polled: bool = False
    shown: dict[int, str] = field(default_factory=dict)  # phase -> G / Y / r
    vehcall: list[int] = field(default_factory=list)
    state: str = "idle"
    timeout_reason: str | None = None
    timeout_detail: str | None = None
    recovering: bool = False
    commands: deque[CommandRow] = field(default_factory=lambda: deque(maxlen=LAST_COMMANDS))
    last_poll: int = 0  # the newest poll id a record named (poll records come on changes only)
    polls_failed: int = 0
    failing: int = 0  # consecutive failed polls
    poll_counts: dict[str, int] | None = None  # the poller's own counts: run_ended's, or live (counter)
    counter: Callable[[], dict[str, int]] | None = None  # a live run's poller counts, read at each snapshot
    sets: dict[str, int] = field(default_factory=lambda: {"sent": 0, "answered": 0, "failed": 0})
    dropped: int = 0
    refused: int = 0
    drifts: int = 0
    last_lag: float | None = None  # the last transition's dispatch-to-verification time
    queues: dict[str, int] | None = None
    cabinet: dict[str, list[int]] | None = None  # the last cabinet record's phase lists
    # (start, indications; None: no verified signal state)
    strip: deque[tuple[float, dict[int, str] | None]] = field(default_factory=deque)
    records: int = 0
    _pending: list[int] = field(default_factory=list)  # the last converted command, for a keep

    def feed(self, record: Mapping[str, Any]) -> None:
        """Fold one event-log record into the board."""
        self.records += 1
        self.t = max(self.t, float(record["t"]))
        handler = _HANDLERS.get(record["kind"])
        if handler is not None:
            handler(self, record)
        known = signal_known(record)
        if known is not None:
            self._segment(float(record["t"]), self.shown if known and self.polled else None)

    def feed_all(self, records: Iterable[Mapping[str, Any]]) -> Board:
        for record in records:
            self.feed(record)
        return self

    @staticmethod
    def refuses(record: Mapping[str, Any]) -> str | None:
        """Why the board cannot fold ``record`` (a field it reads missing or of another type), or None."""
        return _refused(record, _READS)

    # --- handlers -------------------------------------------------------------------------------

    def _run_started(self, r: Mapping[str, Any]) -> None:
        self.run = {k: r.get(k) for k in ("config", "mode", "action_type", "agent", "seed", "duration")}

    def _run_ended(self, r: Mapping[str, Any]) -> None:
        self.ended = r["reason"]
        self.poll_counts = r.get("polls")

    def _poll(self, r: Mapping[str, Any]) -> None:
        self.last_poll = max(self.last_poll, int(r["poll_id"]))
        self.failing = 0
        greens, yellows = set(r["greens"]), set(r["yellows"])
        self.shown = {p: GREEN if p in greens else YELLOW if p in yellows else RED for p in self.config.phase_numbers}
        self.polled = True

    def _poll_failed(self, r: Mapping[str, Any]) -> None:
        if r.get("poll_id"):  # poll 0 is the start-up read
            self.polls_failed += 1
            self.last_poll = max(self.last_poll, int(r["poll_id"]))
        self.failing = int(r.get("consecutive", 0))

    def _set_sent(self, r: Mapping[str, Any]) -> None:
        self.sets["sent"] += 1
        self.vehcall = sorted(r["phases"])

    def _set_answered(self, r: Mapping[str, Any]) -> None:
        self.sets["answered"] += 1

    def _set_failed(self, r: Mapping[str, Any]) -> None:
        self.sets["failed"] += 1

    def _converted(self, r: Mapping[str, Any]) -> None:
        self._pending = list(r["command"])

    def _dispatched(self, r: Mapping[str, Any]) -> None:
        self.commands.append(CommandRow(r["command_id"], list(r["command"]), float(r["t"]), r.get("green")))

    def _verified(self, r: Mapping[str, Any]) -> None:
        self.last_lag = float(r["hold_s"])
        row = self._row(r["command_id"])
        if row is not None:
            row.verified_s = self.last_lag

    def _released(self, r: Mapping[str, Any]) -> None:
        row = self._row(r["command_id"])
        if row is None:  # kept without a SET: never dispatched
            row = CommandRow(r["command_id"], self._pending, float(r["t"]))
            self.commands.append(row)
        row.hold_s, row.outcome = float(r["hold_s"]), r["reason"]

    def _dropped(self, r: Mapping[str, Any]) -> None:
        self.dropped += 1

    def _refused(self, r: Mapping[str, Any]) -> None:
        self.refused += 1

    def _state(self, r: Mapping[str, Any]) -> None:
        self.state = r["to"]
        if self.state != "timeout":
            self.timeout_reason = self.timeout_detail = None
            self.recovering = False

    def _timeout(self, r: Mapping[str, Any]) -> None:
        self.timeout_reason, self.timeout_detail = r["reason"], r.get("detail")

    def _recovery_started(self, r: Mapping[str, Any]) -> None:
        self.recovering = True

    def _recovered(self, r: Mapping[str, Any]) -> None:
        self.recovering = False
        self.failing = 0  # recovery has read the controller; a poll record would say so only on a change

    def _drift(self, r: Mapping[str, Any]) -> None:
        self.drifts += 1

    def _queues(self, r: Mapping[str, Any]) -> None:
        self.queues = dict(r["queues"])

    def _cabinet(self, r: Mapping[str, Any]) -> None:
        # Logs from before overlaps were read have no overlap fields: no overlap shown.
        self.cabinet = {name: list(r[name]) for name in CABINET_COLUMNS} | {name: list(r.get(name, ()))
                                                                           for name in OVERLAP_COLUMNS}

    # --- helpers ----------------------------------------------------------------------------------

    def _row(self, command_id: int | None) -> CommandRow | None:
        return next((row for row in reversed(self.commands) if row.command_id == command_id), None)

    def _cabinet_of(self, phase: int) -> dict[str, Any]:
        """The phase's pedestrian indication, calls and PhaseNext as last read (None before a read)."""
        c = self.cabinet
        if c is None:
            return {"ped": None, "call": None, "ped_call": None, "next": None}
        ped = "walk" if phase in c["walks"] else "ped_clear" if phase in c["ped_clears"] else "dont_walk"
        return {"ped": ped, "call": phase in c["veh_calls"], "ped_call": phase in c["ped_calls"],
                "next": phase in c["nexts"]}

    def _segment(self, t: float, shown: dict[int, str] | None) -> None:
        """The strip from ``t`` on shows ``shown`` (None: no data), unless it shows that already."""
        if not self.strip or self.strip[-1][1] != shown:
            self.strip.append((t, shown))
            self._trim()

    def _overlaps(self) -> list[dict[str, Any]]:
        """Each overlap, its parents and what it showed at the last cabinet read (None before a read)."""
        c = self.cabinet
        out = []
        for n, o in self.config.overlaps.items():
            shown = None
            if c is not None:
                flashing = o.kind is OverlapKind.FYA and any(self.shown.get(p) == GREEN for p in o.modifiers)
                shown = (GREEN if n in c["overlap_greens"] else
                         (FLASHING if flashing else YELLOW) if n in c["overlap_yellows"] else RED)
            out.append({"overlap": n, "letter": o.letter, "type": o.kind.value, "included": list(o.included),
                        "modifiers": list(o.modifiers), "approach": o.approach, "turn": o.turn, "shown": shown})
        return out

    def _trim(self) -> None:
        # Drop segments that ended before the strip's window (a segment ends where the next starts).
        horizon = self.t - STRIP_S
        while len(self.strip) > 1 and self.strip[1][0] <= horizon:
            self.strip.popleft()

    # --- what the page draws ------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The board as JSON for the page (see ``static/app.js``)."""
        cfg = self.config
        self._trim()
        return {
            "t": round(self.t, 3),
            "run": self.run,
            "ended": self.ended,
            "phases": [{"phase": p, "ring": ph.ring, "barrier": cfg.barrier_of(p), "approach": ph.approach,
                        "turn": ph.turn, "shown": self.shown.get(p) if self.polled else None,
                        "vehcall": p in self.vehcall, **self._cabinet_of(p)} for p, ph in sorted(cfg.phases.items())],
            "cabinet_read": self.cabinet is not None,
            "overlaps": self._overlaps(),
            "rings": [list(r) for r in cfg.rings],
            "barriers": len(cfg.barriers),
            "state": self.state,
            "timeout": {"reason": self.timeout_reason, "detail": self.timeout_detail,
                        "recovering": self.recovering} if self.state == "timeout" else None,
            "commands": [{"id": c.command_id, "phases": c.phases, "t": round(c.t, 3), "green": c.green,
                          "verified_s": _r(c.verified_s), "hold_s": _r(c.hold_s), "outcome": c.outcome}
                         for c in reversed(self.commands)],
            "comms": {**self._polls(), "failing": self.failing,
                      "sets": dict(self.sets), "dropped": self.dropped, "refused": self.refused,
                      "drifts": self.drifts, "last_lag_s": _r(self.last_lag)},
            "queues": self.queues,
            "strip": {"window_s": STRIP_S,
                      "segments": [[round(t0, 3), None if shown is None else
                                    {str(p): s for p, s in shown.items() if s != RED}] for t0, shown in self.strip]},
        }


    def _polls(self) -> dict[str, int]:
        """Polls answered and failed: the poller's counts when known, else as far as the records tell."""
        counts = self.counter() if self.counter is not None else self.poll_counts
        if counts is not None:
            return {"polls_ok": counts["polls"] - counts["failed"], "polls_failed": counts["failed"]}
        return {"polls_ok": self.last_poll - self.polls_failed, "polls_failed": self.polls_failed}


def _r(x: float | None) -> float | None:
    return None if x is None else round(x, 3)


def _integer(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _phases(v: Any) -> bool:
    return isinstance(v, list) and all(_integer(p) for p in v)


def _text(v: Any) -> bool:
    return isinstance(v, str)


def _counts(v: Any) -> bool:
    """A poller's counts, as run_ended has them."""
    return isinstance(v, dict) and {"polls", "failed"} <= v.keys() and all(_integer(n) for n in v.values())


def _optional(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is None or check(v)


_MISSING = object()

#: What the board reads of each kind it folds, and what each field must be. A finished run's log is checked
#: against it before it is replayed (:meth:`Board.refuses`): a record that would not fold is left out and
#: named, never half applied. Records of a live run are the run's own and are not checked.
_READS: dict[str, dict[str, Callable[[Any], bool]]] = {
    "run_ended": {"reason": _text, "polls": _optional(_counts)},
    "poll": {"poll_id": _integer, "greens": _phases, "yellows": _phases},
    "poll_failed": {"poll_id": _optional(_integer), "consecutive": _optional(_integer)},
    "set_sent": {"phases": _phases},
    "action_converted": {"command": _phases},
    "command_dispatched": {"command_id": _optional(_integer), "command": _phases, "green": _optional(_number)},
    "transition_verified": {"command_id": _optional(_integer), "hold_s": _number},
    "hold_released": {"command_id": _optional(_integer), "hold_s": _number, "reason": _text},
    "state": {"to": _text},
    "timeout_entered": {"reason": _text},
    "queues": {"queues": lambda v: isinstance(v, dict) and all(_integer(n) for n in v.values())},
    "cabinet": dict.fromkeys(CABINET_COLUMNS, _phases),
}
# A run of several controllers: its run_ended has each intersection's counts.
_READS_OF_RUN = {"run_ended": {"reason": _text,
                               "polls": _optional(lambda v: isinstance(v, dict) and all(map(_optional(_counts),
                                                                                            v.values())))}}
_OPTIONAL_FIELDS = {("poll_failed", "poll_id"), ("poll_failed", "consecutive"), ("run_ended", "polls")}


def _refused(record: Mapping[str, Any], reads: Mapping[str, Mapping[str, Callable[[Any], bool]]]) -> str | None:
    """Why a record does not give what ``reads`` says its kind must give (None when it does)."""
    kind = record["kind"]
    for name, check in reads.get(kind, {}).items():
        value = record.get(name, _MISSING)
        if value is _MISSING:
            if (kind, name) in _OPTIONAL_FIELDS:
                continue
            return f"{kind} without {name}"
        if not check(value):
            return f"{kind}.{name} is {repr(value)[:40]}"
    return None


_HANDLERS: dict[str, Callable[[Board, Mapping[str, Any]], None]] = {
    "run_started": Board._run_started,
    "run_ended": Board._run_ended,
    "poll": Board._poll,
    "poll_failed": Board._poll_failed,
    "set_sent": Board._set_sent,
    "set_answered": Board._set_answered,
    "set_failed": Board._set_failed,
    "action_converted": Board._converted,
    "action_dropped": Board._dropped,
    "action_refused": Board._refused,
    "command_dispatched": Board._dispatched,
    "transition_verified": Board._verified,
    "hold_released": Board._released,
    "state": Board._state,
    "timeout_entered": Board._timeout,
    "recovery_started": Board._recovery_started,
    "recovered": Board._recovered,
    "drift": Board._drift,
    "queues": Board._queues,
    "cabinet": Board._cabinet,
}


@dataclass
class Panels:
    """The dashboard's view of a run of several controllers: one board per intersection, placed as on the map.

    ``cells`` gives each intersection's (column, row) on the page (:func:`map_cells`)."""

    boards: dict[str, Board]
    cells: Mapping[str, tuple[int, int]]
    t: float = 0.0
    run: dict[str, Any] = field(default_factory=dict)  # the run_started record's fields
    ended: str | None = None
    records: int = 0

    @classmethod
    def of(cls, configs: Mapping[str, IntersectionConfig], positions: Mapping[str, tuple[float, float]],
           counters: Mapping[str, Callable[[], dict[str, int]]] | None = None) -> Panels:
        """Empty boards for ``configs`` (traffic light -> config) at their network ``positions`` (x east, y north);
        ``counters``: a live run's poller counts of each."""
        return cls({tls: Board(cfg, counter=counters[tls] if counters else None) for tls, cfg in configs.items()},
                   map_cells(positions))

    def feed(self, record: Mapping[str, Any]) -> None:
        """Fold one event-log record into the board of the intersection it names, or into the run's."""
        self.records += 1
        self.t = max(self.t, float(record["t"]))
        tls = record.get("intersection")
        if tls is not None:
            self.boards[tls].feed(record)
        elif record["kind"] == "run_started":
            self.run = {k: record.get(k) for k in ("scenario", "mode", "action_type", "agent", "seed", "duration")}
        elif record["kind"] == "run_ended":
            self.ended = record["reason"]
            polls = record.get("polls") or {}
            for tls, board in self.boards.items():
                board.feed({**record, "polls": polls.get(tls)})

    def feed_all(self, records: Iterable[Mapping[str, Any]]) -> Panels:
        for record in records:
            self.feed(record)
        return self

    def refuses(self, record: Mapping[str, Any]) -> str | None:
        """Why these panels cannot fold ``record`` (an intersection not of the run, or what a board refuses)."""
        tls = record.get("intersection")
        if tls is None:
            return _refused(record, _READS_OF_RUN)
        if tls not in self.boards:
            return f"intersection {repr(tls)[:20]} is not one of the run's ({', '.join(self.boards)})"
        return Board.refuses(record)

    def snapshot(self) -> dict[str, Any]:
        """The run and each intersection's board, with its cell on the page (see ``static/app.js``)."""
        panels = []
        for tls, board in self.boards.items():
            board.t = self.t  # a quiet intersection's strip still ends now
            col, row = self.cells[tls]
            snap = board.snapshot()
            del snap["t"], snap["run"]  # the run's, given once
            panels.append({"id": tls, "name": described(tls, board.config), "col": col, "row": row, **snap})
        return {"t": round(self.t, 3), "run": self.run, "ended": self.ended, "panels": panels,
                "cols": 1 + max(c for c, _ in self.cells.values()), "rows": 1 + max(r for _, r in self.cells.values())}


#: Junctions closer than this (metres) along an axis share a column (or a row) of the page.
SAME_LINE_M = 20.0


def map_cells(positions: Mapping[str, tuple[float, float]]) -> dict[str, tuple[int, int]]:
    """The page cell (column, row) of each junction at ``positions`` (x east, y north): columns west to east and
    rows north to south, one per distinct coordinate. A corridor is a row, a grid a grid, whatever the
    spacing: the page is a schematic map, as on a traffic engineer's wall."""
    cols = _lines({tls: x for tls, (x, _) in positions.items()})
    rows = _lines({tls: -y for tls, (_, y) in positions.items()})
    return {tls: (cols[tls], rows[tls]) for tls in positions}


def _lines(coordinate: Mapping[str, float]) -> dict[str, int]:
    """The rank of each coordinate among the distinct ones (within :data:`SAME_LINE_M`)."""
    out: dict[str, int] = {}
    line, start = -1, -math.inf
    for tls, c in sorted(coordinate.items(), key=lambda kv: kv[1]):
        if c - start > SAME_LINE_M:
            line, start = line + 1, c
        out[tls] = line
    return out


class Replay:
    """A finished run's board at any instant: the records folded up to it, from the nearest checkpoint.

    ``empty`` is the board the run starts from: a :class:`Board`, or :class:`Panels` for a run of several."""

    def __init__(self, empty: Board | Panels, records: Iterable[Mapping[str, Any]], *, every: int = 2000) -> None:
        #: (seq, why) of the records left out: the board could not fold them (a log not written by a run).
        self.skipped: list[tuple[Any, str]] = []
        self.records = []
        for record in records:
            why = empty.refuses(record)
            if why is None:
                self.records.append(record)
            else:
                self.skipped.append((record.get("seq"), why))
        if not self.records:
            raise ValueError("the event log has no records")
        self.times = [float(r["t"]) for r in self.records]
        self.end = self.times[-1]
        # Checkpoint k is the board after the first k * every records.
        self._every = every
        self._checkpoints = [copy.deepcopy(empty)]
        board = copy.deepcopy(empty)
        for i, record in enumerate(self.records, start=1):
            board.feed(record)
            if i % every == 0:
                self._checkpoints.append(copy.deepcopy(board))

    def at(self, t: float) -> Board | Panels:
        """The board once every record with ``t`` at or before ``t`` has been fed."""
        n = bisect.bisect_right(self.times, t)
        k = min(n // self._every, len(self._checkpoints) - 1)
        board = copy.deepcopy(self._checkpoints[k])
        board.feed_all(self.records[k * self._every:n])
        board.t = max(board.t, min(t, self.end))
        return board
