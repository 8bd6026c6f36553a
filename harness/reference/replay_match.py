"""How a replay's bench log matches the field's: the measures `hils replay` reports, whatever the bench.

- **The whole-log match** (the headline): of the field's judged events (:data:`JUDGED`: what a controller decides,
  not its inputs or calls) over the whole log, the share the bench logged too, the same type and parameter within
  the tolerance (1 s), each bench event matched once (:func:`match_table`). No cutoff: the virtual-time bench runs
  the whole log, so every field event counts.
- **The per-green measure** (:func:`green_table`): a difference early in a log moves everything after it, so the
  whole-log match says little about how a green ends. This one re-anchors at each field green: for each green the
  field began, is there a bench green of the phase that began within the tolerance (anchored), and then did it end
  within the tolerance of the field's, and the same way (gap-out, max-out, force-off, or neither, as events 4-6 on
  the yellow's tick say)?
- **Declared logging variants** (:data:`EQUIVALENCES`): a vendor that logs the same thing as another event is
  matched through a row of this table, and only through it; every row names its source (a vendor's document or a
  log that shows it). The table is printed with the measures, so what was counted as what is never hidden.
"""

from __future__ import annotations

import csv
from bisect import bisect_left, bisect_right
from collections import defaultdict
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from enum import StrEnum
from pathlib import Path
from typing import Protocol

from hils.protocol.hires import EventCode

E = EventCode
#: The events the bench is judged on: Signal-Replay's COMPARISON_EVENT_IDS (phase, pedestrian, overlap, preempt)
#: and what else a controller decides (gap/max/force-off, min complete, barrier) besides calls.
JUDGED = (E.PHASE_BEGIN_GREEN, E.PHASE_MIN_COMPLETE, E.PHASE_GAP_OUT, E.PHASE_MAX_OUT, E.PHASE_FORCE_OFF,
          E.PHASE_GREEN_TERMINATION, E.PHASE_END_YELLOW, E.PHASE_END_RED_CLEARANCE, E.PED_BEGIN_WALK,
          E.PED_BEGIN_CLEARANCE, E.PED_BEGIN_SOLID_DONT_WALK, E.BARRIER_TERMINATION, E.OVERLAP_BEGIN_GREEN,
          E.OVERLAP_BEGIN_YELLOW, E.OVERLAP_OFF, E.OVERLAP_DARK, E.PREEMPT_ENTRY_STARTED, E.PREEMPT_BEGIN_EXIT)


class Logged(Protocol):
    """A logged event: a file's row or a bench's event."""

    time: datetime
    code: int
    parameter: int


@dataclass(frozen=True, slots=True)
class Equivalence:
    """A field event a vendor logs otherwise than the emulator, for the same thing: the field's ``code`` is judged at
    the time of the field's last ``judged_at`` event of the same parameter before it (where the emulator logs it), or
    judged as the emulator's ``counted_as`` event, for the ``parameters`` the log was read to show it (none until a
    log's reading binds them: see :func:`for_log`)."""

    vendor: str
    code: int
    judged_at: int | None
    says: str
    source: str
    counted_as: int | None = None
    parameters: frozenset[int] = frozenset()


#: An overlap dark (66) while its phases are green (:func:`harness.reference.field_log.dark_at_green`).
DARK_AT_GREEN = Equivalence(
    "an overlap dark while its phases are green (seen from an Intelight MaxTime)", E.OVERLAP_DARK, None,
    "the overlap's green is shown by its phase's own output, the overlap's outputs off: the field logs its dark (66) "
    "as the phase begins green where the emulator's overlap of the phase logs its begin green (61); its yellow (63) "
    "and off (65) are logged as the emulator's are",
    "log sample_raw_data.parquet of the atspm package (controller 1136, Intelight MaxTime): overlap E logs 66 as "
    "phase 5 begins green, 63 with 5's yellow and 65 as it ends, 91 of 91 cycles, never a 61; the Indiana "
    "enumerations (utahudot/udot-atspm, Atspm/Data/Enums/IndianaEnumerations.cs): \"Overlap Dark ... Set when overlap "
    "head is set dark (no active outputs)\"",
    counted_as=E.OVERLAP_BEGIN_GREEN)

#: The declared logging variants (see the header). Each row is matched only as it says.
EQUIVALENCES: tuple[Equivalence, ...] = (
    DARK_AT_GREEN,
    Equivalence(
        "Econolite", E.OVERLAP_OFF, E.OVERLAP_BEGIN_RED_CLEARANCE,
        "Econolite logs an overlap's off (65) at the end of its red clearance, after its 64; the emulator's overlap "
        "has no red clearance of its own and logs 65 where its red begins, where Econolite logs 64",
        "log ECON_10.205.17.215_2024_02_21_1115.dat (utahudot/udot-atspm, Atspm/InfrastructureTests/"
        "EventLogDecoderTests/TestData): overlap C logs 63, then 64 3.9 s later (its yellow), then 65 1.8 s later"),
)


def for_log(vendor: str | None, dark_at_green: Collection[int]) -> list[Equivalence]:
    """The rows a log is matched through: its vendor's, and :data:`DARK_AT_GREEN` bound to the overlaps the log was
    read to show dark while their phases are green, whoever the vendor (an ATSPM file names none)."""
    rows = [q for q in EQUIVALENCES if q.vendor == vendor]
    return rows + ([replace(DARK_AT_GREEN, parameters=frozenset(dark_at_green))] if dark_at_green else [])


@dataclass(frozen=True, slots=True)
class MatchRow:
    """One event type of one phase (or overlap, barrier...): the log's count, the bench's, and how many of the log's
    the bench logged within the tolerance."""

    code: int
    parameter: int
    field: int
    bench: int
    matched: int

    @property
    def share(self) -> float | None:
        return None if not self.field else round(100 * self.matched / self.field, 1)


def overall(table: Iterable[MatchRow]) -> float | None:
    """The whole-log match: the share of the field's judged events the bench logged within the tolerance."""
    table = list(table)
    n = sum(r.field for r in table)
    return None if not n else round(100 * sum(r.matched for r in table) / n, 1)


def match_table(rows: Iterable[Logged], bench: Iterable[Logged], shift: timedelta = timedelta(0),
                tolerance_s: float = 1.0, codes: Sequence[int] = JUDGED,
                span: tuple[datetime, datetime] | None = None,
                equivalences: Sequence[Equivalence] = ()) -> list[MatchRow]:
    """Per event type and parameter: the log's events (within ``span`` of log time when given, else all), the
    bench's (its times minus ``shift``), and how many of the log's have a bench event of the same type and parameter
    within ``tolerance_s`` (each bench event matched once), a field event that ``equivalences`` declare judged at the
    time of the field event it names, or as the event they count it as."""
    at = {q.code: q.judged_at for q in equivalences if q.judged_at is not None}
    counted = {(q.code, p): q.counted_as for q in equivalences if q.counted_as is not None for p in q.parameters}
    last: dict[tuple[int, int], datetime] = {}
    mine: dict[tuple[int, int], list[datetime]] = defaultdict(list)
    theirs: dict[tuple[int, int], list[datetime]] = defaultdict(list)
    for r in rows:
        if r.code in at.values():
            last[(r.code, r.parameter)] = r.time
        if r.code in codes and (span is None or span[0] <= r.time <= span[1]):
            anchor = last.get((at[r.code], r.parameter)) if r.code in at else None
            mine[(counted.get((r.code, r.parameter), r.code), r.parameter)].append(anchor or r.time)
    for e in bench:
        if e.code in codes:
            theirs[(e.code, e.parameter)].append(e.time - shift)
    free = {key: sorted(times) for key, times in theirs.items()}
    tolerance = timedelta(seconds=tolerance_s)
    matched: dict[tuple[int, int], int] = defaultdict(int)
    for key in sorted(mine):
        for t in sorted(mine[key]):
            pool = free.get(key, [])
            near = range(bisect_left(pool, t - tolerance), bisect_right(pool, t + tolerance))
            if near:
                del pool[min(near, key=lambda i: abs(pool[i] - t))]
                matched[key] += 1
    return [MatchRow(key[0], key[1], len(mine.get(key, [])), len(theirs.get(key, [])), matched[key])
            for key in sorted(set(mine) | set(theirs))]


# --- the per-green measure ----------------------------------------------------------------------------------


class Ending(StrEnum):
    """How a green ended, as the events logged on its yellow's tick say."""

    GAP_OUT = "gap out"
    MAX_OUT = "max out"
    FORCE_OFF = "force off"
    UNSAID = "no reason logged"


_ENDINGS = {E.PHASE_GAP_OUT: Ending.GAP_OUT, E.PHASE_MAX_OUT: Ending.MAX_OUT, E.PHASE_FORCE_OFF: Ending.FORCE_OFF}


@dataclass(frozen=True, slots=True)
class Green:
    phase: int
    begin: datetime
    end: datetime
    ending: Ending


def greens(events: Iterable[Logged]) -> list[Green]:
    """Each green of a log: its begin (1), its end (8, begin yellow) and the reason logged with it (4-6)."""
    begun: dict[int, datetime] = {}
    reason: dict[tuple[datetime, int], Ending] = {}
    out = []
    for e in events:
        if e.code == E.PHASE_BEGIN_GREEN:
            begun[e.parameter] = e.time
        elif e.code in _ENDINGS:
            reason[(e.time, e.parameter)] = _ENDINGS[E(e.code)]
        elif e.code == E.PHASE_BEGIN_YELLOW and e.parameter in begun:
            out.append((e.parameter, begun.pop(e.parameter), e.time))
    return [Green(p, a, b, reason.get((b, p), Ending.UNSAID)) for p, a, b in out]


@dataclass(frozen=True, slots=True)
class GreenRow:
    """The field's greens that ended one way: how many, how many the bench began within the tolerance (anchored),
    and of those how many it ended within the tolerance, and within it and the same way."""

    ending: Ending
    field: int
    anchored: int
    ended: int
    same: int


def green_table(rows: Iterable[Logged], bench: Iterable[Logged], shift: timedelta = timedelta(0),
                tolerance_s: float = 1.0) -> list[GreenRow]:
    """The per-green measure (see the module's header), one row per way the field's greens ended."""
    tolerance = timedelta(seconds=tolerance_s)
    theirs: dict[int, list[Green]] = defaultdict(list)
    for g in greens(bench):
        theirs[g.phase].append(Green(g.phase, g.begin - shift, g.end - shift, g.ending))
    counts: dict[Ending, list[int]] = {ending: [0, 0, 0, 0] for ending in Ending}
    for g in greens(rows):
        row = counts[g.ending]
        row[0] += 1
        mine = theirs.get(g.phase, [])
        k = bisect_left([b.begin for b in mine], g.begin - tolerance)
        near = [b for b in mine[k:k + 3] if abs(b.begin - g.begin) <= tolerance]
        if not near:
            continue
        b = min(near, key=lambda b: abs(b.begin - g.begin))
        row[1] += 1
        if abs(b.end - g.end) <= tolerance:
            row[2] += 1
            row[3] += b.ending is g.ending
    return [GreenRow(ending, *row) for ending, row in counts.items() if row[0]]


# --- output -------------------------------------------------------------------------------------------------------


def _pct(n: int, d: int) -> str:
    return "-" if not d else f"{100 * n / d:.1f} %"


def render(table: Sequence[MatchRow], green: Sequence[GreenRow], equivalences: Sequence[Equivalence] = ()) -> str:
    """The measures as text: the per-green table and the per-event table, a row that counts a field event declared
    equivalent (:data:`EQUIVALENCES`) saying which."""
    names = {int(c): c.name.lower().replace("_", " ") for c in E}
    counted = _counted_from(equivalences)
    lines = [f"{'field green ended by':<22}{'greens':>8}{'anchored':>10}{'ended within':>14}{'same way':>10}"
             f"{'ended/anchored':>16}"]
    for g in green:
        lines.append(f"{g.ending.value:<22}{g.field:>8}{g.anchored:>10}{g.ended:>14}{g.same:>10}"
                     f"{_pct(g.ended, g.anchored):>16}")
    anchored = sum(g.anchored for g in green)
    lines += [f"{'all':<22}{sum(g.field for g in green):>8}{anchored:>10}{sum(g.ended for g in green):>14}"
              f"{sum(g.same for g in green):>10}{_pct(sum(g.ended for g in green), anchored):>16}", "",
              f"{'event':<34}{'no.':>4}{'log':>7}{'bench':>7}{'found':>7}{'share':>8}"]
    for r in table:
        share = "-" if r.share is None else f"{r.share:.1f} %"
        name = names.get(r.code, str(r.code))
        if (r.code, r.parameter) in counted:
            name += f" (log's {counted[(r.code, r.parameter)]})"
        lines.append(f"{name:<34}{r.parameter:>4}{r.field:>7}{r.bench:>7}{r.matched:>7}"
                     f"{share:>8}")
    return "\n".join(lines)


def render_equivalences(equivalences: Sequence[Equivalence]) -> str:
    if not equivalences:
        return "logging variants counted as equivalent: none"
    return "logging variants counted as equivalent:\n" + "\n".join(
        f"  {q.vendor}: field event {q.code} "
        + (f"judged at the field's {q.judged_at} before it" if q.counted_as is None else
           f"of {', '.join(map(str, sorted(q.parameters)))} counted as {q.counted_as}")
        + f" ({q.says}; source: {q.source})"
        for q in equivalences)


def _counted_from(equivalences: Sequence[Equivalence]) -> dict[tuple[int, int], int]:
    """Per emulator event and parameter, the field event a row of ``equivalences`` counts as it."""
    return {(q.counted_as, p): q.code for q in equivalences if q.counted_as is not None for p in q.parameters}


def write_table(table: Sequence[MatchRow], path: Path, equivalences: Sequence[Equivalence] = ()) -> None:
    """The per-event table as CSV; ``log_EventId`` is the field event counted as the row's (a declared variant)."""
    counted = _counted_from(equivalences)
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["EventId", "Parameter", "log", "bench", "found", "share_percent", "log_EventId"])
        out.writerows((r.code, r.parameter, r.field, r.bench, r.matched, r.share,
                       counted.get((r.code, r.parameter), r.code)) for r in table)
