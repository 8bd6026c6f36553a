"""CTI 4501 conformance of a J2735 SPaT, judged as USDOT's jpo-geojsonconverter judges it.

Rules of this file
------------------
- The rule is the converter's, read from its Java (``usdot-jpo-ode/jpo-geojsonconverter``, commit c66b107,
  ``converter/spat/SpatProcessedJsonConverter.java``): a received SPaT, as the ODE writes it in JSON (metadata and
  payload), is validated against ``spat.schema.json`` with JSON Schema 2019-09 (``AbstractJsonValidator``), and
  the processed SPaT's ``cti4501Conformant`` is ``validationMessages.isValid()``: no message at all. The schemas are
  theirs, unchanged (``jpo_geojsonconverter/`` beside this file, with their licence).
- It reads a decoded SPAT (a dict as an ASN.1 decoder gives it: asn1tools' or pycrate's) and never encodes: what it
  judges is what a receiver decoded.

Theory of operation
-------------------
:func:`ode_json` writes the decoded SPAT in the ODE's names (``intersectionStateList.intersectionStatelist``,
``states.movementList``, ``state_time_speed.movementEventList``, the movement phase states in upper case, the
status as its fourteen named booleans), with null where the message left an optional field out. The metadata are
the ODE's for a message it received: the schema requires them; nothing in them depends on the SPaT.
:func:`judge` validates it and builds the processed SPaT as the converter's ``createProcessedSpat`` does: the
message's time from the year of ``odeReceivedAt``, the minute of the year (``moy``) and the milliseconds in the
minute (``generateUTCTimestamp``), and each TimeMark as an instant of that hour, the next hour when the message's
minute is past 50 and the mark below 6000, the epoch (1970) for "unknown" 36001 (``generateOffsetUTCTimestamp``).
The processed SPaT is checked against ``processed-spat.schema.json`` too.

What CTI 4501 asks beyond J2735, as the schema has it: a minute of the year on the SPAT, a DSecond and a region
on each intersection, and in every TimeChangeDetails ``startTime``, ``minEndTime``, ``maxEndTime`` and
``nextTime``, each a TimeMark (0..36001: 36001, "unknown", passes).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import cache
from importlib import resources
from typing import Any

#: IntersectionStatusObject's named bits, in order (bit 0 first).
STATUS_BITS = ("manualControlIsEnabled", "stopTimeIsActivated", "failureFlash", "preemptIsActive",
               "signalPriorityIsActive", "fixedTimeOperation", "trafficDependentOperation", "standbyOperation",
               "failureMode", "off", "recentMAPmessageUpdate", "recentChangeInMAPassignedLanesIDsUsed",
               "noValidMAPisAvailableAtThisTime", "noValidSPATisAvailableAtThisTime")
UNKNOWN_MARKS = (36001, 36011)  # the converter's "unknown" TimeMarks
_TIMING = ("startTime", "minEndTime", "maxEndTime", "likelyTime", "confidence", "nextTime")


@dataclass(frozen=True, slots=True)
class Judgement:
    """The converter's view of one SPaT: conformant to CTI 4501 or not, with the schema's messages, and the
    processed SPaT it writes."""

    conformant: bool
    messages: tuple[str, ...]
    processed: dict[str, Any]


@cache
def schema(name: str) -> dict[str, Any]:
    """One of the converter's schemas: ``spat`` or ``processed-spat``."""
    text = resources.files("harness.reference").joinpath(f"jpo_geojsonconverter/{name}.schema.json").read_text()
    return json.loads(text)


def _status(value: Any) -> dict[str, bool]:
    """The named booleans of an IntersectionStatusObject decoded as (bits, length): bytes (asn1tools) or an
    integer (pycrate), the first named bit leftmost."""
    bits, length = value
    number = int.from_bytes(bits, "big") >> (len(bits) * 8 - length) if isinstance(bits, bytes) else bits
    return {name: bool(number >> (length - 1 - k) & 1) for k, name in enumerate(STATUS_BITS)}


def _state(name: str) -> str:
    """A MovementPhaseState as ASN.1 names it (``protected-Movement-Allowed``), as the ODE writes it."""
    return name.replace("-", "_").upper()


def ode_json(spat: dict[str, Any], received: datetime) -> dict[str, Any]:
    """The ODE's JSON of a decoded SPAT received at ``received`` (UTC)."""
    stamp = _iso(received)
    intersections = []
    for x in spat["intersections"]:
        movements = []
        for m in x["states"]:
            events = [{"eventState": _state(e["eventState"]),
                       "timing": {k: e.get("timing", {}).get(k) for k in _TIMING} if "timing" in e else None,
                       "speeds": None} for e in m["state-time-speed"]]
            movements.append({"movementName": m.get("movementName"), "signalGroup": m["signalGroup"],
                              "state_time_speed": {"movementEventList": events}})
        intersections.append({"name": x.get("name"), "id": {"region": x["id"].get("region"), "id": x["id"]["id"]},
                              "revision": x["revision"], "status": _status(x["status"]), "moy": x.get("moy"),
                              "timeStamp": x.get("timeStamp"), "enabledLanes": None,
                              "states": {"movementList": movements}, "maneuverAssistList": None})
    return {
        "metadata": {
            "spatSource": "unknown", "logFileName": "", "recordType": "spatTx", "securityResultCode": "success",
            "receivedMessageDetails": {"rxSource": "NA"}, "payloadType": "us.dot.its.jpo.ode.model.OdeSpatPayload",
            "serialId": {"streamId": "hils", "bundleSize": 1, "bundleId": 0, "recordId": 0, "serialNumber": 0},
            "odeReceivedAt": stamp, "schemaVersion": 6, "recordGeneratedAt": stamp, "sanitized": False, "asn1": None},
        "payload": {"dataType": "us.dot.its.jpo.ode.plugin.j2735.J2735SPAT",
                    "data": {"timeStamp": spat.get("timeStamp"), "name": spat.get("name"),
                             "intersectionStateList": {"intersectionStatelist": intersections}}},
    }


def judge(spat: dict[str, Any], received: datetime) -> Judgement:
    """Whether the converter finds the decoded SPAT conformant, and the processed SPaT it writes for its first
    intersection (the converter takes the first)."""
    import jsonschema  # the j2735 extra

    ode = ode_json(spat, received)
    validator = jsonschema.Draft201909Validator(schema("spat"))
    messages = tuple(f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
                     for e in sorted(validator.iter_errors(ode), key=lambda e: list(map(str, e.absolute_path))))
    x = ode["payload"]["data"]["intersectionStateList"]["intersectionStatelist"][0]
    utc = _utc(x["moy"], x["timeStamp"], received)
    processed = {
        "messageType": "SPAT", "odeReceivedAt": ode["metadata"]["odeReceivedAt"], "name": x["name"],
        "region": x["id"]["region"], "intersectionId": x["id"]["id"], "cti4501Conformant": not messages,
        "validationMessages": [{"message": m} for m in messages], "revision": x["revision"],
        "status": x["status"], "utcTimeStamp": _iso(utc), "schemaVersion": 1,
        "states": [{"signalGroup": m["signalGroup"],
                    "stateTimeSpeed": [{"eventState": e["eventState"],
                                        "timing": {k: _iso(_offset(utc, (e["timing"] or {}).get(k)))
                                                   for k in _TIMING if k != "confidence"}}
                                       for e in m["state_time_speed"]["movementEventList"]]}
                   for m in x["states"]["movementList"]],
    }
    processed = _drop_nulls(processed)
    jsonschema.Draft202012Validator(schema("processed-spat"),
                                    format_checker=jsonschema.FormatChecker()).validate(processed)
    return Judgement(not messages, messages, processed)


def _utc(moy: int | None, dsecond: int | None, received: datetime) -> datetime:
    """generateUTCTimestamp: the year received, plus the minute of the year and the milliseconds in the minute."""
    if moy is None:
        base = received.replace(second=0, microsecond=0) if dsecond is not None else received
        return base + timedelta(milliseconds=dsecond or 0)
    return datetime(received.year, 1, 1, tzinfo=UTC) + timedelta(minutes=moy, milliseconds=dsecond or 0)


def _offset(utc: datetime, mark: int | None) -> datetime | None:
    """generateOffsetUTCTimestamp: a TimeMark as an instant of the message's hour (or the next, see above)."""
    if mark is None:
        return None
    if mark in UNKNOWN_MARKS:
        return datetime(1970, 1, 1, tzinfo=UTC)
    hour = utc + timedelta(hours=1) if utc.minute > 50 and mark < 6000 else utc
    return hour.replace(minute=0, second=0, microsecond=0) + timedelta(milliseconds=mark * 100)


def _iso(t: datetime | None) -> str | None:
    return None if t is None else t.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _drop_nulls(value: Any) -> Any:
    """The processed SPaT as the converter's JSON leaves an unset field: out."""
    if isinstance(value, dict):
        return {k: _drop_nulls(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_drop_nulls(v) for v in value]
    return value
