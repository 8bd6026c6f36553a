"""An Econolite controller's hi-res log file (``.dat``, ``.datZ``), read strictly: its events, or one line saying
which byte is wrong.

The layout, as ATSPM's own decoder reads it (udotdevelopment/ATSPM, ``MOE.Common/Business/LogDecoder/
ASC3Decoder.cs``; the same in utahudot/udot-atspm's event log decoders, whose test data holds the files this
project's tests read):

- a file whose first two bytes are a zlib header (``78 01``, ``78 9C``, ``78 DA``) is compressed (the ``.datZ``
  the controller offers): the rest is a raw deflate stream (ASC3Decoder skips the two bytes and inflates);
- a text header of seven lines, each ended by a line feed, each starting with the log's start time
  (``2-21-2024 11:15:00.0,Version #:,3``; then the file name, the intersection, IP and MAC addresses, "Controller
  Data Log Beginning:" and "Phases in use:"). The start is the first line's time, ``M-D-YYYY HH:MM:SS.f``;
- then records of four bytes each: the event code (one byte), its parameter (one byte), and the time after the
  start in tenths of a second (two bytes, big-endian).

A record cut short, a header without its seven lines or a start time that is none is refused, naming the file, the
byte offset, the field and what is allowed (:class:`harness.reference.hires_file.FieldLogError`).
"""

from __future__ import annotations

import re
import zlib
from datetime import datetime, timedelta
from pathlib import Path

from harness.reference.hires_file import FieldLogError, Row, read_bytes

ZLIB_HEADERS = (b"\x78\x01", b"\x78\x9c", b"\x78\xda")
HEADER_LINES = 7
RECORD = 4
_START = re.compile(rb"(\d{1,2})-(\d{1,2})-(\d{4}) (\d{1,2}):(\d{2}):(\d{2})(?:\.(\d))?,")


def read(path: str | Path) -> list[Row]:
    """The events of an Econolite ``.dat`` (or ``.datZ``) file, in time order (see the module's header)."""
    path = Path(path)
    data = read_bytes(path)
    if data[:2] in ZLIB_HEADERS:
        try:
            data = zlib.decompress(data[2:], wbits=-15)
        except zlib.error as exc:
            raise FieldLogError(f"{path}: byte 2: the compressed body does not inflate ({exc}); allowed: a zlib "
                                "stream after its two-byte header, as a .datZ holds") from None
    return decode(data, str(path))


def decode(data: bytes, name: str = "log") -> list[Row]:
    """The events of an uncompressed ``.dat`` body; ``name`` says whose in a refusal."""
    match = _START.match(data)
    if match is None:
        raise FieldLogError(f"{name}: byte 0: start time {data[:24]!r} is not a time; allowed: an Econolite .dat "
                            "header, whose lines start with M-D-YYYY HH:MM:SS.f and a comma")
    month, day, year, hour, minute, second, tenth = (int(g or 0) for g in match.groups())
    try:
        start = datetime(year, month, day, hour, minute, second, tenth * 100_000)
    except ValueError as exc:
        raise FieldLogError(f"{name}: byte 0: start time {match.group(0)[:-1].decode()!r} is not a date ({exc})") \
            from None
    offset = 0
    for line in range(HEADER_LINES):
        end = data.find(b"\n", offset)
        if end < 0:
            raise FieldLogError(f"{name}: byte {len(data)}: the header ends after {line} line(s); allowed: the "
                                f"{HEADER_LINES} lines of an Econolite .dat header, then 4-byte records")
        offset = end + 1
    body = data[offset:]
    if len(body) % RECORD:
        cut = offset + len(body) // RECORD * RECORD
        raise FieldLogError(f"{name}: byte {cut}: record cut short ({len(body) % RECORD} of {RECORD} bytes); allowed: "
                            "records of event code, parameter and a 2-byte time in tenths")
    rows = [Row(start + timedelta(milliseconds=100 * int.from_bytes(body[k + 2:k + 4], "big")), body[k], body[k + 1])
            for k in range(0, len(body), RECORD)]
    return sorted(rows, key=lambda r: (r.time, r.code, r.parameter))
