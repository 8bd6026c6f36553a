"""The 10 Hz UDP SPaT packet of an Econolite controller, built from the controller's own timers and sent each tick.

Rules of this file
------------------
- :func:`encode` reads the controller between two ticks and returns the packet's bytes; it never acts.
  :class:`SpatSender` only sends what :func:`encode` gives, once per tick, to one address; a lost datagram or a
  closed port at the other end is the receiver's business, as on a cabinet's Ethernet.
- The timing is :meth:`emulator.model.controller.Controller.spat`, the announcement the model's property holds to
  the truth: nothing here estimates a time of its own.

Theory of operation
-------------------
The layout is the one the open connected-vehicle stacks parse (written here from the layout, no code copied):
V2X Hub's SpatPlugin (``usdot-fhwa-OPS/V2X-Hub``, ``src/v2i-hub/SpatPlugin/src/NTCIP1202.h``: the packed struct
``Ntcip1202Ext`` read with ``ntohs``) and MMITSS (``mmitss/mmitss-az``, ``Ntcip1202v2Blob.py``, which reads the
same bytes by offset "using byte-structure provided in Econolite SPAT Guide"). 245 bytes, big-endian:

====== ===== ==================================================================================================
offset bytes field
====== ===== ==================================================================================================
0      1     header (neither parser reads it; 0xCD)
1      1     number of phase entries (16)
2      13x16 per entry i: phase number (i+1), then uint16 vehicle min and max time to change, pedestrian min and
             max, overlap min and max (of overlap i+1), in tenths of a second from now
210    2x11  phaseStatusGroup Reds, Yellows, Greens, DontWalks, PedClears, Walks; overlapStatusGroup Reds, Yellows,
             Greens; flashing output of phases, of overlaps (bit k: phase or overlap k+1)
232    1x4   intersection status, time base action, discontinuous-change flag, message sequence counter (mod 256)
236    5     the controller's clock: hour, minute, second, millisecond (2 bytes), as NTCIP 1202 v03's spatTimestamp
241    2x2   pedestrian calls, pedestrian detections (bit k: phase k+1)
====== ===== ==================================================================================================

What each field carries here:

- Min time to change is the announced earliest change, max the latest; 0 where the model has none (V2X Hub
  sends no maxEndTime for 0, as J2735 leaves it out when unknown): a green resting or held, a red phase whose next
  service is not known, and every time of a controller in a monitor's flash (:mod:`emulator.model.spat` says which).
- The pedestrian min and max are 0: the model announces no pedestrian timing (:mod:`emulator.model.spat`).
- In flash every phase and overlap shows red and its flashing-output bit is set. The intersection status, time
  base action, discontinuous-change flag and pedestrian detections are 0: the model has no field to fill them.
- MMITSS reads only the low byte of each time (offsets 4, 6, ...): a time above 25.5 s reaches it modulo 25.6 s.
  V2X Hub reads both bytes.
- The packet goes out while spatOptions bit 0 ("Enabled SPAT", NTCIP 1202 v03 5.17.4) is set, as it is from
  power-up; under v02 the object is not served and the packet always goes out.
"""

from __future__ import annotations

import asyncio
import logging
import struct
from collections.abc import Callable, Iterable

from emulator.model.controller import Controller
from emulator.model.spat import SignalTiming
from hils.protocol.ntcip import spat_timestamp

log = logging.getLogger(__name__)

HEADER = 0xCD
ENTRIES = 16
_ENTRY = struct.Struct(">B6H")
_HEAD = struct.Struct(">BB")
_TAIL = struct.Struct(">11H4B")  # then spatTimestamp's five bytes
_PEDS = struct.Struct(">2H")
LENGTH = _HEAD.size + ENTRIES * _ENTRY.size + _TAIL.size + 5 + _PEDS.size  # 245
_MAX = 0xFFFF


def _tenths(ticks: int | None) -> int:
    return 0 if ticks is None else min(ticks, _MAX)


def _bits(numbers: Iterable[int]) -> int:
    return sum(1 << (n - 1) for n in numbers if 1 <= n <= ENTRIES)


def encode(c: Controller, sequence: int) -> bytes:
    """The packet of ``c`` as it stands between two ticks; ``sequence`` is the message counter (taken mod 256)."""
    phases: dict[int, SignalTiming] = {}
    overlaps: dict[int, SignalTiming] = {}
    for t in c.spat():
        (phases if t.kind == "phase" else overlaps)[t.number] = t
    out = bytearray(_HEAD.pack(HEADER, ENTRIES))
    for n in range(1, ENTRIES + 1):
        ph, ov = phases.get(n), overlaps.get(n)
        out += _ENTRY.pack(n, _tenths(ph and ph.earliest), _tenths(ph and ph.latest), 0, 0,
                           _tenths(ov and ov.earliest), _tenths(ov and ov.latest))
    flashing_phases = _bits(c.config.phases) if c.flashing else 0
    flashing_overlaps = _bits(c.config.overlaps) if c.flashing else 0
    out += _TAIL.pack(_bits(c.reds), _bits(c.yellows), _bits(c.greens), _bits(c.dont_walks), _bits(c.ped_clears),
                      _bits(c.walks), _bits(c.overlap_reds), _bits(c.overlap_yellows), _bits(c.overlap_greens),
                      flashing_phases, flashing_overlaps,
                      0, 0, 0, sequence % 256)
    out += spat_timestamp(c.coordinator.clock)
    out += _PEDS.pack(_bits(c.ped_calls), 0)
    return bytes(out)


class _Quiet(asyncio.DatagramProtocol):
    def error_received(self, exc: Exception) -> None:
        # A receiver not listening yet answers ICMP port unreachable: a broadcaster keeps sending.
        log.debug("SPaT datagram not delivered: %s", exc)


class SpatSender:
    """Sends one controller's SPaT to one UDP address, each time :meth:`send` is called (once per tick): this
    packet, or what ``encode`` makes of the controller and the message counter (a J2735 SPaT,
    :func:`emulator.agent.j2735.encode`)."""

    def __init__(self, controller: Controller, host: str, port: int,
                 enabled: Callable[[], bool] = lambda: True,
                 encode: Callable[[Controller, int], bytes] = encode) -> None:
        self.controller = controller
        self.enabled = enabled  # spatOptions bit 0, "Enabled SPAT", as the controller's MIB holds it
        self.encode = encode
        self.address = (host, port)
        self.sent = 0
        self._transport: asyncio.DatagramTransport | None = None

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(_Quiet, remote_addr=self.address)

    def send(self) -> None:
        if self._transport is None or self._transport.is_closing() or not self.enabled():
            return
        self._transport.sendto(self.encode(self.controller, self.sent))
        self.sent += 1

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
