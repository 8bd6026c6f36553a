"""The controller model: NEMA ring-and-barrier timing on a 0.1 s tick, coordination, overlaps,
preemption, the monitor (the cabinet's MMU), the controller's own hi-res data logger and latency,
and the event-driven clock that steps only the ticks that matter."""
