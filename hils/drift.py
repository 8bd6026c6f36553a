"""Drift detection: simulation steps that take longer than their length.

A step whose cost exceeds the step length has drifted: simulation time and wall
time lose step. ``n_drift`` consecutive drifted steps raise the timeout event;
one step on time resets the count.
"""

from __future__ import annotations

from collections.abc import Callable

from hils.events import EventLog, Kind


class DriftMonitor:
    def __init__(self, n_drift: int, log: EventLog, on_drift: Callable[[str], None]) -> None:
        self.n_drift = n_drift
        self.log = log
        self.on_drift = on_drift
        self.consecutive = 0
        self.drifted = 0

    def observe(self, step: float, took: float) -> bool:
        """Record one step of length ``step`` that cost ``took`` seconds; True if it drifted."""
        if took <= step:
            self.consecutive = 0
            return False
        self.consecutive += 1
        self.drifted += 1
        self.log.emit(Kind.DRIFT, step_s=step, took_s=took, consecutive=self.consecutive)
        if self.consecutive == self.n_drift:
            self.on_drift(f"{self.n_drift} consecutive steps took longer than {step} s")
        return True

    def reset(self) -> None:
        self.consecutive = 0
