"""SAE J2735 SPaT from the controller's own timers: a UPER MessageFrame (messageId 19) per controller and tick.

Rules of this file
------------------
- :func:`encode` reads the controller between two ticks and returns the message's bytes; it never acts. The
  timing is :meth:`emulator.model.controller.Controller.spat`, the announcement the model's property holds to the
  truth: nothing here estimates a time of its own.
- SAE's J2735 ASN.1 is not shipped, and nothing here is written from it. The SPAT inside the frame is encoded by
  pycrate with ISO TS 19091's DSRC module as pycrate ships it compiled (``pycrate_asn1dir/ITS_IS.py``, module
  ``DSRC {iso(1) standard(0) signalizedIntersection(19091) profilec(2) dsrc(2) version2(2)}``, the ASN.1 of ETSI TS
  103 301's release), whose SPAT, IntersectionState, MovementState, MovementEvent, TimeChangeDetails and TimeMark
  are those of J2735 2016 (the same components, constraints and extension markers; the regional extensions
  differ, and none is sent). pycrate is an optional dependency (the ``j2735`` extra): it is imported when the first
  message is encoded.

Theory of operation
-------------------
Written by hand, and only this: J2735's MessageFrame around the SPAT, as the DSRC module of ETSI's ITS release 1318
defines it (``pycrate_asn1dir/ITS_r1318.py``: ``MessageFrame ::= SEQUENCE { messageId MESSAGE-ID-AND-TYPE.&id,
value MESSAGE-ID-AND-TYPE.&Type, ... }``, ``DSRCmsgID ::= INTEGER (0..32767)``, ``signalPhaseAndTimingMessage
DSRCmsgID ::= 19``), in unaligned PER (ITU-T X.691): one bit for the extension marker (0: no additions), messageId
in 15 bits, then the value as an open type: a length determinant in octets (one octet below 128, two octets
``10`` + 14 bits below 16384; X.691 11.9) and the SPAT's own UPER octets. The frame of a SPAT thus opens ``00 13``.

What the fields carry:

- ``SPAT.timeStamp`` and the intersection's ``moy``: the minute of the year of the controller's clock;
  ``timeStamp`` (DSecond): the milliseconds in that minute. The controller's clock is its coordinator's (local
  time, ``[emulator] start`` or the host's clock when served).
- ``id``: region 0 (none assigned) and the intersection's number (``--j2735`` numbers the served controllers 1, 2,
  ...); ``revision`` counts the messages sent, modulo 128; ``status``: ``failureFlash`` in a monitor's flash,
  ``preemptIsActive`` while a preempt is served, ``trafficDependentOperation`` otherwise.
- One MovementState per phase (signalGroup = the phase number) and per overlap (signalGroup = 16 + its number):
  without a MAP of the intersection no lane is named, and a receiver maps signal groups to lanes with its MAP.
- eventState: green ``protected-Movement-Allowed``, yellow ``protected-clearance``, red ``stop-And-Remain``, every
  signal in flash ``stop-Then-Proceed`` (flashing red), a flashing yellow arrow ``permissive-Movement-Allowed``.
- TimeChangeDetails, in TimeMarks (tenths of a second past the top of the hour of the controller's clock):
  ``startTime`` when the indication began, ``minEndTime`` the earliest change, ``maxEndTime`` the latest,
  ``likelyTime`` the likely one, ``nextTime`` 36001. J2735's TimeMark 36001 is "unknown": sent where the
  controller announces nothing (a green with no latest, no change coming in a monitor's flash, a start not kept)
  and for ``nextTime`` (the model does not announce the next start after this change). ``startTime``,
  ``maxEndTime`` and ``nextTime`` are always present, as CTI 4501 asks (USDOT's ``jpo-geojsonconverter`` checks
  it with its ``spat.schema.json``); ``likelyTime`` is left out where unknown. A time an hour or more away is
  unknown too: a TimeMark cannot say which hour.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import timedelta
from functools import cache
from typing import Any

from emulator.model.controller import Controller
from emulator.model.spat import Indication, SignalTiming
from hils.protocol.ntcip import UnitFlashStatus

#: J2735's DSRCmsgID of a SPaT message (signalPhaseAndTimingMessage).
SPAT_MESSAGE_ID = 19
#: TimeMark: "unknown".
UNKNOWN = 36001
_HOUR = 36000  # tenths of a second
#: Overlaps' signal groups follow the 16 phases'.
OVERLAP_GROUPS = 16

_STATE = {Indication.GREEN: "protected-Movement-Allowed", Indication.YELLOW: "protected-clearance",
          Indication.RED: "stop-And-Remain"}
# IntersectionStatusObject's named bits (ISO TS 19091 DSRC, as J2735)
_FAILURE_FLASH, _PREEMPT, _TRAFFIC_DEPENDENT = 2, 3, 6


@cache
def _spat_type() -> Any:
    from pycrate_asn1dir import ITS_IS  # the j2735 extra

    return ITS_IS.DSRC.SPAT


def require() -> None:
    """Load the codec now (a quarter of a second), so that a missing pycrate is said before serving starts."""
    _spat_type()


def frame(message_id: int, value: bytes) -> bytes:
    """J2735's MessageFrame in UPER around a message's own UPER octets (see the module's header)."""
    n = len(value)
    if n < 128:
        length = bytes([n])
    elif n < 16384:
        length = (0x8000 | n).to_bytes(2, "big")
    else:
        raise ValueError(f"a {n}-octet message needs a fragmented length determinant (X.691 11.9.3.8): not written")
    return (message_id & 0x7FFF).to_bytes(2, "big") + length + value


def encode(c: Controller, revision: int, *, intersection: int = 1) -> bytes:
    """The MessageFrame of ``c``'s SPaT as it stands between two ticks; ``revision`` is the message counter."""
    clock = c.coordinator.clock  # ticks since midnight of the controller's first day
    now = c.day0 + timedelta(seconds=clock // 10)
    moy = (now.timetuple().tm_yday - 1) * 1440 + now.hour * 60 + now.minute
    hour = clock % _HOUR

    def mark(ticks: int | None) -> int:
        return UNKNOWN if ticks is None or abs(ticks) >= _HOUR else (hour + ticks) % _HOUR

    status = (_FAILURE_FLASH if c.flash_status is UnitFlashStatus.MMU
              else _PREEMPT if c.preempted else _TRAFFIC_DEPENDENT)
    states = [_movement(t, c, mark) for t in c.spat()]
    spat = _spat_type()
    spat.set_val({
        "timeStamp": moy,
        "intersections": [{
            "id": {"region": 0, "id": intersection},
            "revision": revision % 128,
            "status": (1 << (15 - status), 16),  # named bit k is the k-th from the left
            "moy": moy,
            "timeStamp": (clock % 600) * 100,  # milliseconds in the minute
            "states": states,
        }],
    })
    return frame(SPAT_MESSAGE_ID, spat.to_uper())


def _movement(t: SignalTiming, c: Controller, mark: Callable[[int | None], int]) -> dict[str, Any]:
    if c.flashing:
        state = "stop-Then-Proceed"
    elif t.kind == "overlap" and t.number in c.overlaps.flashing:
        state = "permissive-Movement-Allowed"
    else:
        state = _STATE[t.indication]
    timing = {"startTime": mark(None if t.started is None else -t.started), "minEndTime": mark(t.earliest),
              "maxEndTime": mark(t.latest), "nextTime": UNKNOWN}
    if t.likely is not None:
        timing["likelyTime"] = mark(t.likely)
    group = t.number if t.kind == "phase" else OVERLAP_GROUPS + t.number
    return {"signalGroup": group, "state-time-speed": [{"eventState": state, "timing": timing}]}
