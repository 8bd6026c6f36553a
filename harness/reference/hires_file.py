"""A controller's hi-res log file, read strictly: its rows, or one line saying which is wrong.

:func:`load` reads the file by its suffix: an Econolite ``.dat``/``.datZ`` (:mod:`harness.reference.econolite_dat`),
a MaxTime asclog ``.xml`` (:mod:`harness.reference.maxtime_xml`), else the ATSPM layout, read here.

A log comes from a field controller through collectors, exports and spreadsheets, so anything may be in a cell.
:func:`load` reads ``TimeStamp, DeviceId, EventId, Parameter`` (parquet, or CSV read as text) and refuses the first
cell that is not what the layout holds, naming the file, the line (CSV, counting the header as line 1) or row
(parquet, from 1), the column, the value and what is allowed:

- **TimeStamp**: the controller's local time, as ATSPM keeps it (``2024-04-15 12:00:00.1``, ISO 8601 without an
  offset: Indiana's enumerations log the controller's clock) or as MaxTime's event log writes it
  (``04-15-2024 12:00:00.1``, :func:`hils.protocol.hires.format_time`); a parquet timestamp column without a time
  zone. A time pandas cannot hold (before 1677 or after 2262) is refused as well.
- **EventId** and **Parameter**: whole numbers from 0 to 2,147,483,647 (ATSPM's ``int`` columns); what a code's
  parameter may be (a phase, an overlap...) is for the reader of the events to judge.
- **DeviceId**: not empty; a log of several controllers needs ``device``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from hils.protocol.errors import UserError

#: ATSPM's int columns.
LARGEST = 2**31 - 1
_ISO = re.compile(r"\d{4}-\d{2}-\d{2}[ T]\d{2}:\d{2}:\d{2}(\.\d{1,9})?")
_MAXTIME = re.compile(r"\d{2}-\d{2}-\d{4} \d{2}:\d{2}:\d{2}(\.\d{1,6})?")
_WHOLE = re.compile(r"\d{1,10}(\.0*)?")
_TIMES = ("the controller's local time, e.g. 2024-04-15 12:00:00.1 (ISO 8601, no offset) or 04-15-2024 12:00:00.1 "
          "(MaxTime), between 1678 and 2261")


class FieldLogError(UserError, ValueError):
    """A log that cannot be read into a config; says where and what it lacks."""


@dataclass(frozen=True, slots=True)
class Row:
    time: datetime
    code: int
    parameter: int


def load(path: str | Path, device: Any | None = None, start: datetime | None = None,
         end: datetime | None = None) -> list[Row]:
    """One controller's events of an ATSPM-layout log (see the module's header), in time order, between ``start``
    and ``end`` when given. ``device`` picks a controller of a log of several."""
    import pandas as pd

    path = Path(path)
    vendor = _VENDOR.get(path.suffix.lower())
    if vendor is not None:
        rows = vendor(path)
        rows = [r for r in rows if (start is None or r.time >= start) and (end is None or r.time < end)]
        if not rows:
            raise FieldLogError(f"{path}: no events in the time asked; allowed: a start and end within the log")
        return rows
    csv = path.suffix != ".parquet"
    try:
        frame = pd.read_csv(path, dtype=str, keep_default_na=False) if csv else pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise FieldLogError(f"{path}: cannot be read as an ATSPM log ({exc}); allowed: a .parquet or .csv file with "
                            "TimeStamp, DeviceId, EventId, Parameter") from None
    missing = {"TimeStamp", "EventId", "Parameter"} - set(frame.columns)
    if missing:
        raise FieldLogError(f"{path}: no column {', '.join(sorted(missing))}; allowed: the ATSPM layout "
                            "(TimeStamp, DeviceId, EventId, Parameter)")

    def where(index: int) -> str:
        return f"line {index + 2}" if csv else f"row {index + 1}"

    def refuse(column: str, bad: pd.Series, allowed: str) -> None:
        if bad.any():
            first = bad.idxmax()
            more = f" (and {int(bad.sum()) - 1} more rows)" if bad.sum() > 1 else ""
            raise FieldLogError(f"{path}: {where(first)}: {column} {frame.at[first, column]!r} is not {allowed}{more}")

    frame = frame.reset_index(drop=True)
    if "DeviceId" in frame.columns:
        ids = frame.DeviceId.astype(str).str.strip()
        refuse("DeviceId", frame.DeviceId.isna() | ids.isin(("", "nan", "<NA>", "None")), "a controller's id")
        devices = sorted(ids.unique())
        shown = {d: d if d.isprintable() else repr(d) for d in devices[:10]}  # one line, whatever a cell holds
        if device is None and len(devices) > 1:
            counts = ids.value_counts()
            each = ", ".join(f"{shown[d]} ({counts[d]:,} rows)" if counts[d] > 1
                             else f"{shown[d]} (1 row, {where(ids.eq(d).idxmax())})" for d in shown)
            raise FieldLogError(f"{path} holds {len(devices)} controllers: {each}; pick one: --device "
                                + ", ".join(shown.values()))
        if device is not None:
            if str(device) not in devices:
                raise FieldLogError(f"{path}: no DeviceId {device!r}; allowed: {', '.join(shown.values())}")
            frame = frame[ids == str(device)]
    times = _times(frame.TimeStamp)
    refuse("TimeStamp", times.isna(), _TIMES)
    numbers = {}
    for column in ("EventId", "Parameter"):
        numbers[column] = _whole(frame[column])
        refuse(column, numbers[column].isna(), f"a whole number from 0 to {LARGEST:,}")
    frame = pd.DataFrame({"TimeStamp": times, "EventId": numbers["EventId"], "Parameter": numbers["Parameter"]})
    if start is not None:
        frame = frame[frame.TimeStamp >= start]
    if end is not None:
        frame = frame[frame.TimeStamp < end]
    if frame.empty:
        raise FieldLogError(f"{path}: no events{' in the time asked' if start or end else ''}; allowed: a log of a "
                            "controller's events (TimeStamp, DeviceId, EventId, Parameter)")
    frame = frame.sort_values(["TimeStamp", "EventId", "Parameter"], kind="stable")
    return [Row(t, int(c), int(p)) for t, c, p in zip(frame.TimeStamp.array.to_pydatetime(), frame.EventId,
                                                         frame.Parameter, strict=True)]


def read_bytes(path: Path) -> bytes:
    """A vendor file's bytes, or one line saying why it cannot be read."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise FieldLogError(f"{path}: cannot be read ({exc.strerror})") from None


def _econolite(path: Path) -> list[Row]:
    from harness.reference import econolite_dat

    return econolite_dat.read(path)


def _maxtime(path: Path) -> list[Row]:
    from harness.reference import maxtime_xml

    return maxtime_xml.read(path)


#: A vendor's own file form, by suffix (lower case).
_VENDOR = {".dat": _econolite, ".datz": _econolite, ".xml": _maxtime}


def _times(column: Any) -> Any:
    """The column as naive datetime64[ns]; NaT where a value is not a time the header allows."""
    import pandas as pd

    if isinstance(column.dtype, pd.DatetimeTZDtype):  # an offset the controller's local time does not carry
        return pd.Series(pd.NaT, index=column.index, dtype="datetime64[ns]")
    if pd.api.types.is_datetime64_dtype(column.dtype):
        try:
            return column.astype("datetime64[ns]")
        except (ValueError, OverflowError):
            return pd.Series([_one_time(t) for t in column], index=column.index, dtype="datetime64[ns]")
    if not pd.api.types.is_object_dtype(column.dtype) and not pd.api.types.is_string_dtype(column.dtype):
        return pd.Series(pd.NaT, index=column.index, dtype="datetime64[ns]")  # numbers are not times
    text = column.astype(str).str.strip()
    out = pd.Series(pd.NaT, index=column.index, dtype="datetime64[ns]")
    iso, maxtime = text.str.fullmatch(_ISO), text.str.fullmatch(_MAXTIME)
    if iso.any():
        out[iso] = pd.to_datetime(text[iso], format="ISO8601", errors="coerce")
    if maxtime.any():
        whole = text[maxtime].where(text[maxtime].str.contains(".", regex=False), text[maxtime] + ".0")
        out[maxtime] = pd.to_datetime(whole, format="%m-%d-%Y %H:%M:%S.%f", errors="coerce")
    return out


def _one_time(t: Any) -> Any:
    import pandas as pd

    try:
        return pd.Timestamp(t).as_unit("ns")
    except (ValueError, OverflowError):
        return pd.NaT


def _whole(column: Any) -> Any:
    """The column as int64; NaN where a value is not a whole number from 0 to :data:`LARGEST`."""
    import pandas as pd

    if pd.api.types.is_bool_dtype(column.dtype):
        values = pd.Series(float("nan"), index=column.index)
    elif pd.api.types.is_numeric_dtype(column.dtype):
        values = pd.to_numeric(column, errors="coerce").astype("float64")
    else:
        text = column.astype(str).str.strip()
        values = pd.to_numeric(text.where(text.str.fullmatch(_WHOLE)), errors="coerce").astype("float64")
    good = values.notna() & (values == values.round()) & (values >= 0) & (values <= LARGEST)
    return values.where(good).astype("Int64")
