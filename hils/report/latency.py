"""Figures from an event log: the middleware internal latency and transition holds.

Internal latency, as the paper defines it: from the moment the agent's action
reaches the middleware (``action_received``) to the moment the SET is
dispatched (``command_dispatched``, logged just before the transport is
called), exclusive of the SET itself, from the monotonic wall-clock stamps.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from hils.shell.events import Kind

__all__ = ["PAPER_LATENCY_MS", "Stats", "internal_latencies_ms", "transition_holds"]

#: The paper's Table (Cobalt, MacBook Pro M1): N, mean ms, std ms per action type.
PAPER_LATENCY_MS = {
    "selection": (71, 0.6464, 0.6278),
    "switch": (91, 0.8745, 1.0798),
    "duration": (54, 0.6906, 0.6729),
}


@dataclass(frozen=True, slots=True)
class Stats:
    n: int
    mean: float
    std: float
    p50: float
    p99: float
    min: float
    max: float
    p5: float
    p95: float

    @classmethod
    def of(cls, values: Sequence[float]) -> Stats:
        if not values:
            return cls(0, *[float("nan")] * 8)
        import numpy as np  # here, not at import: a run that needs no statistics does not load numpy

        a = np.asarray(values, dtype=float)
        p5, p50, p95, p99 = (float(x) for x in np.percentile(a, [5, 50, 95, 99]))
        return cls(len(a), float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0, p50, p99,
                   float(a.min()), float(a.max()), p5, p95)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def internal_latencies_ms(records: Iterable[dict[str, Any]]) -> dict[str, list[float]]:
    """Per action type, the internal latency (ms) of every action that was dispatched."""
    received: dict[int, tuple[str, int]] = {}
    out: dict[str, list[float]] = {}
    for r in records:
        kind = r["kind"]
        if kind == Kind.ACTION_RECEIVED:
            received[r["action_id"]] = (r["action_type"], r["wall_ns"])
        elif kind == Kind.COMMAND_DISPATCHED and r["action_id"] in received:
            action_type, start = received.pop(r["action_id"])
            out.setdefault(action_type, []).append((r["wall_ns"] - start) / 1e6)
    return out


def transition_holds(records: Iterable[dict[str, Any]]) -> list[float]:
    """Seconds from dispatch to the verifying poll, per verified transition."""
    return [r["hold_s"] for r in records if r["kind"] == Kind.TRANSITION_VERIFIED]
