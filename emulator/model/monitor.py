"""The monitor: the cabinet's malfunction management unit (MMU), watching the lamps apart from the controller.

Rules of this file
------------------
- The monitor reads the lamps (the phases' and the overlaps' greens and yellows) and nothing of the
  controller's timing. The controller shows it each set of lamps that differs from the last one it passed;
  :meth:`Monitor.check` answers with a fault or None, and on a fault the controller goes to flash (all red) and
  stops timing, as a cabinet's MMU puts the intersection in flash.
- Two checks, nothing else: conflict and short yellow. The conflict check is
  :func:`hils.protocol.conflict.first_conflict`, the one conflict check of hils (the config validator, the
  action converter and the fault harness call it too); this module adds no rule to it.
- Time is the controller's integer tick (0.1 s). A power cycle puts every lamp out, so :meth:`Monitor.reset`
  starts the monitor afresh.

Theory of operation
-------------------
Conflict monitoring: "While a channel has a Green, Walk, or Yellow display active, the channel is tested to
see if a non-permissive channel has a Green, Walk, or Yellow display active at the same time" (Reno A&E
MMU-1600G operation manual, 2.5.1 Conflict Monitoring). Our channels are the phases and the overlaps; what is
permissive is the config's (:class:`hils.protocol.conflict.Permissives`): two phases its compatibility matrix
allows, an overlap and the phases beside one of its parents. The MMU's conflict timer (a fault once a
conflict has lasted 300 ms) has no counterpart here: the monitor faults the first tick a conflict shows.

Short yellow: "When a channel has a Green or Walk that turns off, a Yellow must follow it and it must stay on
for at least 2.7 seconds" (Reno A&E MMU-1600G, 2.5.5 Short Yellow Monitoring). A channel, phase or overlap,
whose green goes straight to red, or whose yellow lasts under :data:`SHORT_YELLOW`, faults, but a transit bar's
(an overlap with no yellow lamp, whose channel's check an MMU disables with its "Minimum Yellow Change Disable"
jumper). A yellow that
ends in green (a flashing yellow arrow's yellow lamp going to its green arrow) is no clearance and is not
timed.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

from hils.protocol.config import IntersectionConfig, OverlapKind
from hils.protocol.conflict import first_conflict

SHORT_YELLOW = 27  # ticks: the least yellow a channel may show after its green (2.7 s)


class Lamps(NamedTuple):
    """The phases and the overlaps (1 = A) lit green or yellow, as a test shows them to the monitor (the controller
    shows it its status image, which carries the same sets)."""

    greens: frozenset[int]
    yellows: frozenset[int]
    overlap_greens: frozenset[int]
    overlap_yellows: frozenset[int]


_NONE = Lamps(frozenset(), frozenset(), frozenset(), frozenset())


class Shown(Protocol):
    """What the monitor reads: :class:`Lamps`, or the controller's status image as it is
    (:class:`emulator.model.status.Image`), which carries the same four sets."""

    @property
    def greens(self) -> frozenset[int]: ...

    @property
    def yellows(self) -> frozenset[int]: ...

    @property
    def overlap_greens(self) -> frozenset[int]: ...

    @property
    def overlap_yellows(self) -> frozenset[int]: ...


class Monitor:
    """One controller's MMU: the lamps it last passed, and when each channel's yellow began."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.permissives = config.permissives
        #: Transit bars (two sections, no yellow lamp): their channels are jumpered "Minimum Yellow Change Disable"
        #: (Reno A&E MMU2-1600GE operations manual), so a green going straight to red is no fault there.
        self.bars = frozenset(n for n, o in config.overlaps.items() if o.kind is OverlapKind.TRANSIT)
        self._conflicts: dict[tuple[frozenset[int], frozenset[int]], str | None] = {}  # lamps lit -> their fault
        self.reset()

    def reset(self) -> None:
        """Power-up: every lamp out."""
        self._passed: Shown = _NONE  # the lamps of the last check that found no fault
        self._yellow_began: dict[tuple[str, int], int] = {}  # (channel kind, number) -> the tick its yellow began

    def watch(self, image: Shown, tick: int) -> str | None:
        """The fault the controller's status ``image`` shows at ``tick``, or None: an image is judged once, what it
        lights being all the monitor sees."""
        if image is self._passed:
            return None
        return self.check(image, tick)

    def check(self, lamps: Shown, tick: int) -> str | None:
        """The fault these lamps show at ``tick`` (after the ones last passed), or None."""
        fault = self._conflict(lamps) or self._short_yellow(lamps, tick)
        if fault is None:
            self._passed = lamps
        return fault

    def _conflict(self, lamps: Shown) -> str | None:
        lit = lamps.greens | lamps.yellows, lamps.overlap_greens | lamps.overlap_yellows
        if lit not in self._conflicts:  # a controller shows few sets of lamps: each is judged once
            conflict = first_conflict(self.permissives, *lit)
            self._conflicts[lit] = None if conflict is None else f"{conflict} shown together"
        return self._conflicts[lit]

    def _short_yellow(self, lamps: Shown, tick: int) -> str | None:
        was = self._passed
        return (self._channels("phase", lamps.greens, lamps.yellows, was.greens, was.yellows, tick)
                or self._channels("overlap", lamps.overlap_greens, lamps.overlap_yellows, was.overlap_greens,
                                  was.overlap_yellows, tick))

    def _channels(self, kind: str, greens: frozenset[int], yellows: frozenset[int], was_green: frozenset[int],
                  was_yellow: frozenset[int], tick: int) -> str | None:
        """One kind of channel's fault: a green gone to red without its yellow, or a yellow too short."""
        if greens is was_green and yellows is was_yellow:
            return None  # the same lamps (the status images are kept, each built once)
        for n in was_green - greens - yellows:
            if kind == "overlap" and n in self.bars:
                continue  # a transit bar has no yellow lamp: its channel's minimum yellow check is disabled
            return f"{kind} {n} from green to red without a yellow"
        began = self._yellow_began
        for n in yellows - was_yellow:
            began[kind, n] = tick
        for n in was_yellow - yellows:
            since = began.pop((kind, n), None)
            if n not in greens and since is not None and tick - since < SHORT_YELLOW:
                return f"{kind} {n} yellow for {(tick - since) / 10:g} s"
        return None
