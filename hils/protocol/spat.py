"""Signal phase and timing as a run hands it to its user: each signal's indication and when it next changes.

SAE J2735's SPaT gives per signal group its movement state and TimeChangeDetails (minEndTime, maxEndTime,
likelyTime); CTI 4501 asks for all three. Here they are in the run's own seconds (its ``now``), None where the
controller announces nothing: the model's rules (:mod:`emulator.model.spat`) give a bound only where it is firm.
A J2735 encoder adds the clock: minEndTime is ``min_end`` as tenths of a second of the hour.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class MovementTiming:
    """One phase's or overlap's indication and the times of its next change: ``min_end`` the earliest (None: no
    change is coming, as in a monitor's flash), ``max_end`` the latest and ``likely`` the likely one (None:
    unknown)."""

    kind: str  # "phase" or "overlap"
    number: int
    indication: str  # "green", "yellow" or "red"
    min_end: float | None
    max_end: float | None
    likely: float | None
