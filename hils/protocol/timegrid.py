"""The time grid of every periodic process: instant k is ``start + k * period``.

Rules of this module
--------------------
- An instant is computed from the grid's start, never by adding periods up: a float sum drifts, and two
  processes adding the same periods from different starts disagree in the last bit about which of their
  instants meet.
- Which index an instant belongs to is decided by the grid's own float comparison (``at(k)`` against the
  time), never by the quotient ``(t - start) / period``, whose rounding may put a time on the wrong side of
  an instant it equals. The quotient only gives the first guess; the correction loops settle it.
- It belongs to the shared layer (the emulator's controller clocks use it beside the middleware's poller):
  it imports nothing of hils.

Every periodic process of a run keeps its grid here: the poller, the read-back of the control objects, the
simulation's steps, the controller's tick (ticked and event-driven), ``hils emulator serve``'s wall-clock
ticker and the fault harness's samplers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Grid"]


@dataclass(frozen=True, slots=True)
class Grid:
    """The instants ``start + k * period`` (``period`` > 0)."""

    start: float
    period: float

    def at(self, k: int) -> float:
        """Instant ``k``."""
        return self.start + k * self.period

    def delay(self, k: int, now: float) -> float:
        """How long from ``now`` until instant ``k`` (0 when it has passed): what a timeout to it waits."""
        return max(0.0, self.start + k * self.period - now)

    def first_at_or_after(self, t: float, k: int = 0) -> int:
        """The first index from ``k`` on whose instant is not before ``t``."""
        j = max(k, math.ceil((t - self.start) / self.period))
        while j > k and self.at(j - 1) >= t:
            j -= 1
        while self.at(j) < t:
            j += 1
        return j

    def first_after(self, t: float, k: int = 0) -> int:
        """The first index from ``k`` on whose instant is after ``t``."""
        j = max(k, math.floor((t - self.start) / self.period) + 1)
        while j > k and self.at(j - 1) > t:
            j -= 1
        while self.at(j) <= t:
            j += 1
        return j
