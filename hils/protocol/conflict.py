"""The conflict check: which signals may be lit together, and the signals lit together that may not be.

Rules of this file
------------------
- :func:`conflicts` (and :func:`first_conflict`, its first answer) is the one conflict check of hils. The config
  validator (its pairs and sequence, its start-up phases, each preempt's phases), the action converter, the
  emulator's monitor (its MMU, :mod:`emulator.model.monitor`) and the fault harness's observer and judge all
  ask it; nothing else decides whether signals lit together conflict.
- It judges by :class:`Permissives`, which the config says (``IntersectionConfig.permissives``: the
  compatibility matrix and the overlaps), never by what a controller does.
- Lit is green or yellow, steady or flashing. A walk shows only in its own phase's green, so the phases' greens
  stand for it.

Theory of operation
-------------------
A malfunction management unit is programmed with which channels may be lit together, apart from the
controller: "The jumpers installed on the Program Card determine permissive (non-conflicting) channels ...
This is a two-way relationship", and "While a channel has a Green, Walk, or Yellow display active, the channel
is tested to see if a non-permissive channel has a Green, Walk, or Yellow display active at the same time"
(Reno A&E MMU-1600G operation manual, 2.5.1 Conflict Monitoring). Our channels are the phases and the overlaps:

- Two phases are permissive when the config's matrix says so (derived from its rings and barriers unless the
  config gives one: DESIGN.md, "Actions").
- An overlap is permissive with its included phases (and, for a flashing yellow arrow, its permissive
  modifiers) and with every phase permissive with one of them; it conflicts with every other phase
  (``IntersectionConfig.overlap_allows``). Overlaps are not checked against each other: the config says nothing
  of two overlaps, and an overlap lit beside a phase is checked against that phase.

Conflicts come in a fixed order: pairs of phases by number, then each lit overlap by number against the lit
phases by number.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field

from hils.protocol.ntcip import overlap_letter

__all__ = ["Conflict", "Permissives", "conflicts", "first_conflict"]


@dataclass(frozen=True)
class Permissives:
    """What may be lit together, as an MMU's program card says it."""

    phases: frozenset[frozenset[int]]  # the pairs of phases that may be lit together
    overlaps: Mapping[int, frozenset[int]] = field(default_factory=dict)  # per overlap, the phases it conflicts with


@dataclass(frozen=True, slots=True)
class Conflict:
    """Two signals lit together that may not be: phases ``signal`` and ``phase`` (``signal`` the lower), or, with
    ``overlap``, overlap ``signal`` (1 = A) and phase ``phase``."""

    signal: int
    phase: int
    overlap: bool = False

    def __str__(self) -> str:
        if self.overlap:
            return f"overlap {overlap_letter(self.signal)} and phase {self.phase}"
        return f"phases {self.signal} and {self.phase}"


def conflicts(permissives: Permissives, phases: Collection[int], overlaps: Collection[int] = ()) -> Iterator[Conflict]:
    """Every conflict among the phases and overlaps lit together (each lit once: a set), in the order above."""
    lit = sorted(phases)
    allowed = permissives.phases
    for i, a in enumerate(lit):
        for b in lit[i + 1:]:
            if frozenset((a, b)) not in allowed:
                yield Conflict(a, b)
    for o in sorted(overlaps):
        against = permissives.overlaps[o]
        for p in lit:
            if p in against:
                yield Conflict(o, p, overlap=True)


def first_conflict(permissives: Permissives, phases: Collection[int],
                   overlaps: Collection[int] = ()) -> Conflict | None:
    """The first conflict among the phases and overlaps lit together, or None when they may all be lit."""
    return next(conflicts(permissives, phases, overlaps), None)
