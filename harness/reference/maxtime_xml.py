"""An Intelight MaxTime controller's hi-res log as its asclog XML (a saved ``/v1/asclog/xml/full`` answer), read
strictly: its events, or one line saying which is wrong.

The layout is the one the controller serves and ATSPM collects (utahudot/udot-atspm's event log decoders read it;
their test data, ``Atspm/InfrastructureTests/EventLogDecoderTests/TestData/*.xml``, holds two real controllers'):
``<EventResponses>``, an optional ``<EventResponse><Description>`` with the intersection's number, addresses, start
time and phases in use, then one ``<Event ID=".." TimeStamp="M-D-YYYY HH:MM:SS.f" EventTypeID=".." Parameter=".."/>``
per event. :func:`hils.protocol.hires.parse_asclog` reads it (the same reader `hils run --asclog` collects with);
this module names the file in its refusal (the event's number, its attributes and what is allowed).
"""

from __future__ import annotations

from pathlib import Path

from harness.reference.hires_file import FieldLogError, Row, read_bytes
from hils.protocol.hires import AsclogError, parse_asclog


def read(path: str | Path) -> list[Row]:
    """The events of a MaxTime asclog XML file, in time order."""
    path = Path(path)
    body = read_bytes(path)
    try:
        events = parse_asclog(body)
    except AsclogError as exc:
        raise FieldLogError(f"{path}: {exc}") from None
    if not events:
        raise FieldLogError(f"{path}: no events; allowed: a MaxTime event log with <Event .../> elements")
    return sorted((Row(e.time, e.code, e.parameter) for e in events), key=lambda r: (r.time, r.code, r.parameter))
