"""The live status of a wall-clock run: one line on a terminal, periodic log lines otherwise.

A wall-clock run against a real controller is never silent: every half second the line shows the
elapsed time, the manager's state (with its TIMEOUT reason), the pair shown, the polls answered and
failed and the hold of the last verified transition. When the output is not a terminal (a log file,
CI), the same line goes to the log every ``log_every`` seconds instead. It runs as a SimPy process on
the run's own environment, so it reads the run between two steps and never from another thread.
"""

from __future__ import annotations

import logging
import sys
from collections import Counter
from collections.abc import Generator
from typing import IO, Any

import simpy

__all__ = ["StatusLine"]

log = logging.getLogger("hils.status")


class StatusLine:
    """Shows the state of a Testbed's run as it goes."""

    def __init__(self, *, stream: IO[str] | None = None, period: float = 0.5, log_every: float = 10.0) -> None:
        self.tb: Any = None
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.period = period if self.tty else log_every
        self._width = 0

    def start(self, testbed: Any) -> None:
        """An ``on_reset`` hook of the Testbed: start showing once the run is assembled."""
        self.tb = testbed
        testbed.env.process(self._show())

    def line(self) -> str:
        tb = self.tb
        first = next(iter(tb.intersections.values()))
        if first.label is not None:
            return self._network_line()
        mw = first.middleware
        state = mw.state.value.upper() if mw.state else "CLOSED"
        if mw.timeout_flag and mw.manager.timeout_reason:
            state += f" ({mw.manager.timeout_reason.value})"
        counts = mw.poll_counts
        hold = mw.last_hold
        return (f"{tb.env.now:7.1f} s  {state:<22}  {_shown(mw.cache.state):<13}  polls "
                f"{counts['polls'] - counts['failed']} answered, {counts['failed']} failed  "
                f"last hold {'-' if hold is None else f'{hold:.3f} s'}")

    def _network_line(self) -> str:
        """A run of several intersections: how many are in each state (naming those in TIMEOUT), polls summed."""
        tb = self.tb
        states = Counter(i.middleware.state.name if i.middleware.state else "CLOSED" for i in tb.intersections.values())
        timed_out = [name for name, i in tb.intersections.items() if i.middleware.timeout_flag]
        counts = [i.middleware.poll_counts for i in tb.intersections.values()]
        failed = sum(c["failed"] for c in counts)
        return (f"{tb.env.now:7.1f} s  {len(tb.intersections)} controllers: "
                + ", ".join(f"{name} {n}" for name, n in sorted(states.items()))
                + (f" ({', '.join(timed_out)})" if timed_out else "")
                + f"  polls {sum(c['polls'] for c in counts) - failed} answered, {failed} failed")

    def _show(self) -> Generator[simpy.Event, Any, None]:
        while not self.tb.ended:
            yield self.tb.env.timeout(self.period)
            text = self.line()
            if self.tty:
                self.stream.write("\r" + text.ljust(self._width))
                self.stream.flush()
                self._width = len(text)
            else:
                log.info("%s", text)

    def close(self) -> None:
        """End the line on a terminal, so that what follows starts on a line of its own."""
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()


def _shown(state: Any) -> str:
    if state is None:
        return "not read yet"
    for name, phases in (("green", state.greens), ("yellow", state.yellows)):
        if phases:
            return f"{name} {'+'.join(map(str, sorted(phases)))}"
    return "all red"
