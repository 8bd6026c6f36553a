"""The controller's own record: its high-resolution event log, as ATSPM and the field's tools read it.

What the emulator logs and the middleware reads share this module (the shared layer, like
:mod:`hils.protocol.ntcip`): the event codes, the event record, the ATSPM file layout and Intelight MaxTime's
HTTP form of the log.

- **Event codes**: the Indiana enumerations (Sturdevant et al., "Indiana Traffic Signal Hi Resolution
  Data Logger Enumerations", INDOT and Purdue University, 2012, doi:10.4231/K4RN35SH), as UDOT's ATSPM
  carries them (``ATSPM.Data.Enums/IndianaEnumerations.cs``, with the descriptions quoted below) and as
  real ATC controllers log them (Econolite, Intelight MaxTime, Siemens, McCain): a timestamp at 0.1 s in
  the controller's local time, a code and one parameter (a phase, detector, overlap, preempt or pattern
  number, or a value). Vendors add codes of their own (MaxTime's 300s); a log read here keeps them as
  plain integers.
- **The ATSPM layout** (the ``atspm`` package's ``sample_raw_data.parquet``, UDOT's tables): one row per
  event, columns ``TimeStamp, DeviceId, EventId, Parameter``, one ``DeviceId`` per controller.
  :func:`encode` puts a run's logs in ``hires.parquet`` with pyarrow, or ``hires.csv`` without it
  (:func:`file_name`); :func:`csv_rows` gives the CSV form's lines, which a run also appends as its controllers
  log them (its journal, :mod:`hils.shell.hiresjournal`). The ``atspm`` package reads ``EventId`` and
  ``Parameter`` as 16-bit integers (``atspm/data_loader.py``: ``_CAST_TYPES = {'EventId': 'INT16', 'Parameter':
  'INT16'}``): a log read here keeps both within :data:`VALUE_RANGE`.
- **MaxTime's event log over HTTP**: ``GET /v1/asclog/xml/full`` answers
  ``<EventResponses><Event ID=".." TimeStamp="MM-DD-YYYY HH:MM:SS.f" EventTypeID=".." Parameter=".."/>
  ...</EventResponses>``, and ``?since=MM-DD-YYYY HH:MM:SS.f`` limits it to the events from that time on.
  That is what Signal-Replay's collector (``signal_replay.collector.fetch_output_data``) requests and
  parses (it drops ``ID`` and parses ``TimeStamp`` with ``%m-%d-%Y %H:%M:%S.%f``); UDOT ATSPM's MaxTime
  device configuration asks the same path with ``?since=[LogStartTime:MM-dd-yyyy HH:mm:ss.f]``.
  :class:`AsclogReader` reads such a body as it arrives (the middleware's collector: :mod:`hils.shell.asclog`).
"""

from __future__ import annotations

import re
import urllib.parse
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from enum import IntEnum

#: The ATSPM layout's columns, in order.
COLUMNS = ("TimeStamp", "DeviceId", "EventId", "Parameter")
#: The path of MaxTime's full event log.
ASCLOG_PATH = "/v1/asclog/xml/full"
_TIME_FORMAT = "%m-%d-%Y %H:%M:%S"


class EventCode(IntEnum):
    """The Indiana enumerations the emulator logs (2012; UDOT ATSPM's ``IndianaEnumerations``)."""

    PHASE_ON = 0  # "Set when NEMA Phase On becomes active, either upon start of green or walk interval"
    PHASE_BEGIN_GREEN = 1
    PHASE_CHECK = 2  # "Set when a conflicting call is registered against the active phase" (MAX timing begins)
    PHASE_MIN_COMPLETE = 3
    PHASE_GAP_OUT = 4
    PHASE_MAX_OUT = 5
    PHASE_FORCE_OFF = 6  # "Set when phase force off is applied by the coordinator to the active green phase"
    PHASE_GREEN_TERMINATION = 7
    PHASE_BEGIN_YELLOW = 8
    PHASE_END_YELLOW = 9
    PHASE_BEGIN_RED_CLEARANCE = 10  # "Set only if phase red clearance is served"
    PHASE_END_RED_CLEARANCE = 11
    PHASE_INACTIVE = 12  # "Set when the phase is no longer active within the ring"
    PED_BEGIN_WALK = 21
    PED_BEGIN_CLEARANCE = 22  # flashing don't walk
    PED_BEGIN_SOLID_DONT_WALK = 23
    BARRIER_TERMINATION = 31  # "all active phases become inactive in the ring and cross barrier phases are next"
    FYA_BEGIN_PERMISSIVE = 32
    FYA_END_PERMISSIVE = 33
    PHASE_HOLD_ACTIVE = 41
    PHASE_HOLD_RELEASED = 42
    PHASE_CALL_REGISTERED = 43  # "registered by vehicular demand. This event will not be set if a recall exists"
    PHASE_CALL_DROPPED = 44
    PED_CALL_REGISTERED = 45
    PHASE_OMIT_ON = 46  # "applied by the coordinator, preemptor, or other dynamic sources", not configuration
    PHASE_OMIT_OFF = 47
    PED_OMIT_ON = 48
    PED_OMIT_OFF = 49
    OVERLAP_BEGIN_GREEN = 61
    OVERLAP_BEGIN_TRAILING_GREEN = 62
    OVERLAP_BEGIN_YELLOW = 63
    OVERLAP_BEGIN_RED_CLEARANCE = 64
    OVERLAP_OFF = 65  # "completed all timing, allowing any conflicting phase next to begin service"
    OVERLAP_DARK = 66
    DETECTOR_OFF = 81  # vehicle detector; "triggered post any detector delay/extension processing"
    DETECTOR_ON = 82
    PED_DETECTOR_OFF = 89
    PED_DETECTOR_ON = 90
    PREEMPT_ADVANCE_WARNING = 101
    PREEMPT_CALL_INPUT_ON = 102
    PREEMPT_GATE_DOWN = 103
    PREEMPT_CALL_INPUT_OFF = 104
    PREEMPT_ENTRY_STARTED = 105
    PREEMPT_BEGIN_TRACK_CLEARANCE = 106
    PREEMPT_BEGIN_DWELL = 107
    PREEMPT_LINK_ACTIVE_ON = 108
    PREEMPT_LINK_ACTIVE_OFF = 109
    PREEMPT_MAX_PRESENCE_EXCEEDED = 110
    PREEMPT_BEGIN_EXIT = 111
    COORD_PATTERN_CHANGE = 131  # the pattern running (NTCIP coordPatternStatus: 254 free)
    CYCLE_LENGTH_CHANGE = 132  # s, 255 for 255 or more
    OFFSET_LENGTH_CHANGE = 133  # s, 255 for 255 or more
    SPLIT_1_CHANGE = 134  # 134 + p - 1: the split of phase p (1-16), s
    COORD_CYCLE_STATE_CHANGE = 150  # CycleState below
    COORD_YIELD_POINT = 151  # "Set once per cycle for each coordinated phase when controller suspends [it]"
    UNIT_CONTROL_STATUS_CHANGE = 155  # NTCIP 1202 v03 unitControlStatus
    UNIT_FLASH_STATUS_CHANGE = 173  # NTCIP 1202 unitFlashStatus
    POWER_FAILURE = 182
    POWER_RESTORED = 184


class CycleState(IntEnum):
    """The parameter of event 150, coord cycle state change (Indiana enumerations, 2012)."""

    FREE = 0
    IN_STEP = 1
    TRANSITION_ADD = 2
    TRANSITION_SUBTRACT = 3
    TRANSITION_DWELL = 4
    LOCAL_ZERO = 5
    BEGIN_PICKUP = 6


#: The event codes and parameters a log read here may hold: what the ATSPM layout's readers take (16-bit integers);
#: the Indiana enumerations use 0-255, vendors' own codes (MaxTime's 300s) go beyond.
VALUE_RANGE = range(0, 2**15)

#: The largest value a one-byte parameter holds: "Cycle lengths in excess of 255 shall record this event
#: with a 255 parameter".
MAX_PARAMETER = 255


def split_code(phase: int) -> int:
    """The split change event of ``phase`` (1-16)."""
    return EventCode.SPLIT_1_CHANGE + phase - 1


@dataclass(frozen=True, slots=True, order=True)
class Event:
    """One logged event: when (controller local time, 0.1 s), what (an Indiana code, or a vendor's) and of what."""

    time: datetime
    code: int
    parameter: int


# --- MaxTime's HTTP form ------------------------------------------------------------------------------------


class AsclogError(ValueError):
    """A MaxTime event log or ``since`` value that cannot be read; says what was expected."""


def format_time(t: datetime) -> str:
    """``MM-DD-YYYY HH:MM:SS.f``: MaxTime's timestamp, in tenths."""
    return f"{t.strftime(_TIME_FORMAT)}.{t.microsecond // 100_000}"


#: ``MM-DD-YYYY HH:MM:SS[.f]`` as ``strptime("%m-%d-%Y %H:%M:%S.%f")`` reads it (a log's every event has one: read
#: without strptime, about three times faster).
_TIME = re.compile(r"(\d{1,2})-(\d{1,2})-(\d{4}) (\d{1,2}):(\d{1,2}):(\d{1,2})(?:\.(\d{1,6}))?")


def parse_time(text: str) -> datetime:
    """A MaxTime timestamp (``MM-DD-YYYY HH:MM:SS`` with or without a fraction)."""
    match = _TIME.fullmatch(text.strip())
    if match is not None:
        month, day, year, hour, minute, second, fraction = match.groups()
        try:
            return datetime(int(year), int(month), int(day), int(hour), int(minute), int(second),
                            int((fraction or "0").ljust(6, "0")))
        except ValueError:
            pass
    raise AsclogError(f"timestamp {text!r}: allowed: MM-DD-YYYY HH:MM:SS.f, e.g. 04-15-2024 12:00:00.0")


#: What MaxTime's event log body starts and ends with; :func:`asclog_rows` go between.
ASCLOG_HEAD = b'<?xml version="1.0" encoding="UTF-8"?>\n<EventResponses>\n'
ASCLOG_TAIL = b"</EventResponses>\n"


def asclog_rows(events: Iterable[Event], first: int = 1) -> bytes:
    """The ``<Event .../>`` lines of ``events`` in order, their IDs counted from ``first`` (a body's first is 1)."""
    return "".join(f'<Event ID="{i}" TimeStamp="{format_time(e.time)}" EventTypeID="{int(e.code)}" '
                   f'Parameter="{e.parameter}"/>\n' for i, e in enumerate(events, start=first)).encode()


def asclog_xml(events: Iterable[Event]) -> bytes:
    """The body MaxTime answers ``GET /v1/asclog/xml/full`` with, for ``events`` in order."""
    return ASCLOG_HEAD + asclog_rows(events) + ASCLOG_TAIL


class AsclogReader:
    """A MaxTime event log body read as it arrives (:meth:`feed` each chunk, then :meth:`close`): the events of a
    long log are kept, not the document's tree."""

    def __init__(self) -> None:
        self._parser = ET.XMLPullParser(events=("start", "end"))
        self._root: ET.Element | None = None
        self.events: list[Event] = []

    def feed(self, chunk: bytes) -> None:
        """Read ``chunk``; raises :class:`AsclogError` at the first event (or byte) that is not a log's."""
        try:
            self._parser.feed(chunk)
        except ET.ParseError as exc:
            raise _not_a_log(exc) from None
        self._read()

    def close(self) -> list[Event]:
        """The events, once the body is whole (a body cut short raises :class:`AsclogError`)."""
        try:
            self._parser.close()
        except ET.ParseError as exc:
            raise _not_a_log(exc) from None
        self._read()
        if self._root is None or self._root.tag != "EventResponses":
            raise _not_a_log(f"the document is <{getattr(self._root, 'tag', '')}>")
        return self.events

    def _read(self) -> None:
        for kind, element in self._parser.read_events():
            if self._root is None:
                self._root = element
            if kind == "end" and element.tag == "Event":
                self.events.append(_event(element.attrib, len(self.events) + 1))
                element.clear()
        if self._root is not None:
            self._root.clear()  # the events read are kept as Events, not as the document's elements


def _not_a_log(why: object) -> AsclogError:
    return AsclogError(f"not an event log: {why}; expected <EventResponses><Event .../></EventResponses>")


def _event(attrib: Mapping[str, str], number: int) -> Event:
    try:
        event = Event(parse_time(attrib["TimeStamp"]), int(attrib["EventTypeID"]), int(attrib["Parameter"]))
    except (KeyError, ValueError) as exc:
        raise AsclogError(f"event {number} {dict(attrib)!r}: {exc}; expected TimeStamp, EventTypeID and Parameter "
                          "attributes") from None
    for name, value in (("EventTypeID", event.code), ("Parameter", event.parameter)):
        if value not in VALUE_RANGE:
            raise AsclogError(f"event {number} at {attrib['TimeStamp']}: {name} {value}; allowed: "
                              f"{VALUE_RANGE.start} to {VALUE_RANGE.stop - 1}")
    return event


def parse_asclog(body: bytes) -> list[Event]:
    """The events of a MaxTime event log body (what :func:`asclog_xml` writes, or a controller's)."""
    reader = AsclogReader()
    reader.feed(body)
    return reader.close()


def asclog_url(base: str, since: datetime | None = None) -> str:
    """The URL of a controller's event log at ``base`` (``http://HOST:PORT``), from ``since`` on."""
    url = base.rstrip("/") + ASCLOG_PATH
    return url if since is None else f"{url}?{urllib.parse.urlencode({'since': format_time(since)})}"


# --- the ATSPM layout ----------------------------------------------------------------------------------------


def rows(logs: Mapping[int, Sequence[Event]]) -> list[tuple[datetime, int, int, int]]:
    """``(TimeStamp, DeviceId, EventId, Parameter)`` of every device's events, in time order (stable per device)."""
    out = [(e.time, device, int(e.code), e.parameter) for device, events in logs.items() for e in events]
    out.sort(key=lambda r: (r[0], r[1]))
    return out


def csv_rows(rows: Iterable[tuple[datetime, int, int, int]]) -> str:
    """Rows in the CSV form of the ATSPM layout (without the header :data:`CSV_HEADER`): integers and a timestamp,
    nothing to quote."""
    out, last, stamp = [], None, ""
    for t, device, code, parameter in rows:
        if t != last:  # a tick's events share their time: written once
            last, stamp = t, t.isoformat(sep=" ", timespec="milliseconds")
        out.append(f"{stamp},{device},{code},{parameter}\n")  # an IntEnum code formats as its number
    return "".join(out)


#: The first line of the CSV form of the ATSPM layout.
CSV_HEADER = ",".join(COLUMNS) + "\n"


def file_name() -> str:
    """The name of a run's hi-res file: ``hires.parquet`` when pyarrow is installed, ``hires.csv`` when not."""
    try:
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return "hires.csv"
    return "hires.parquet"


def encode(logs: Mapping[int, Sequence[Event]]) -> bytes:
    """The bytes of :func:`file_name`: ``logs``, by device, in the ATSPM layout. Made in memory, so that writing them is
    one write the caller can name."""
    table = rows(logs)
    if file_name() == "hires.csv":
        return (CSV_HEADER + csv_rows(table)).encode()
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns = list(zip(*table, strict=True)) if table else [[], [], [], []]
    types = (pa.timestamp("ms"), pa.int32(), pa.int16(), pa.int32())
    sink = pa.BufferOutputStream()
    pq.write_table(pa.table({name: pa.array(col, type=kind) for name, col, kind in zip(COLUMNS, columns, types,
                                                                                         strict=True)}), sink)
    return sink.getvalue().to_pybytes()
