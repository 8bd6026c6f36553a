"""The status a controller shows: its phase and overlap status groups, as one image per distinct state.

Rules of this file
------------------
- An image (:class:`Image`) is a tuple of phase (and overlap) sets (greens, yellows, phase ons, reds, walks,
  pedestrian clears, don't walks, phase nexts, overlap greens, yellows and reds); it is built from what the rings
  and the overlaps show and nothing else, and never changed once built.
- A controller shows a handful of distinct images: each is built once, keyed by what it is made of (every
  ring's interval, phase, next phase and pedestrian interval, and the overlaps' displays), and shared.

Theory of operation
-------------------
NTCIP 1202 phaseStatusGroup: Greens, Yellows and Reds of each phase, its Walk, pedestrian clearance and Don't
Walk, PhaseOns (the phase is timing: green, yellow or red clearance) and PhaseNexts (the phase each clearing
ring has committed to serve next, decided at the start of its yellow); overlapStatusGroup likewise for the
overlaps' greens, yellows and reds. In flash (start-up or the monitor's) every phase and overlap is red.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from emulator.model.overlaps import Overlaps
from emulator.model.ring import DWELL, GREEN, YELLOW, Ring
from hils.protocol.config import IntersectionConfig


class Image(NamedTuple):
    """One status image: the phase and overlap status groups (a named tuple, read by position as the controller
    unpacks it and by name as the monitor reads its lamps off it)."""

    greens: frozenset[int]
    yellows: frozenset[int]
    phase_ons: frozenset[int]
    reds: frozenset[int]
    walks: frozenset[int]
    ped_clears: frozenset[int]
    dont_walks: frozenset[int]
    phase_nexts: frozenset[int]
    overlap_greens: frozenset[int]
    overlap_yellows: frozenset[int]
    overlap_reds: frozenset[int]


class Images:
    """The status images of one controller, each built once."""

    def __init__(self, config: IntersectionConfig) -> None:
        self._phases = frozenset(config.phases)
        self._overlaps = frozenset(config.overlaps)
        self._images: dict[tuple | None, Image] = {}

    def of(self, rings: Sequence[Ring], overlaps: Overlaps, flashing: bool) -> Image:
        """The image of what ``rings`` and ``overlaps`` show now (all red when ``flashing``)."""
        key: tuple | None = None
        if not flashing:  # four items a ring (a loop, not a comprehension: this is asked at every real step)
            shown: list = []
            for r in rings:
                shown += (r.interval, r.phase, r.target,
                          r.interval is GREEN and (r.ticks < r.walk) + (r.ticks < r.walk + r.ped_clear))
            key = (*shown, overlaps.discrete() if self._overlaps else ())
        image = self._images.get(key)
        if image is None:
            image = self._images[key] = self._build(rings, overlaps, flashing)
        return image

    def _build(self, rings: Sequence[Ring], ov: Overlaps, flashing: bool) -> Image:
        greens, yellows, ons, walks, clears, nexts = set(), set(), set(), set(), set(), set()
        if not flashing:
            for r in rings:
                if r.interval is GREEN:
                    greens.add(r.phase)
                    if r.ticks < r.walk:
                        walks.add(r.phase)
                    elif r.ticks < r.walk + r.ped_clear:
                        clears.add(r.phase)
                elif r.interval is YELLOW:
                    yellows.add(r.phase)
                if r.interval is not DWELL:
                    ons.add(r.phase)
                if r.target is not None:
                    nexts.add(r.target)
        every = self._phases
        overlaps = (frozenset(), frozenset()) if flashing else (ov.greens, ov.yellows)
        return Image(frozenset(greens), frozenset(yellows), frozenset(ons), every - greens - yellows, frozenset(walks),
                     frozenset(clears), every - walks - clears, frozenset(nexts), *overlaps,
                     self._overlaps - overlaps[0] - overlaps[1])
