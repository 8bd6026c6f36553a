"""What a run shows on the console as it goes: a live status line, and a line for each event that matters.

A wall-clock run against a real controller is never silent: every half second the line shows the
elapsed time, the manager's state (with its TIMEOUT reason), the pair shown, the polls answered and
failed and the hold of the last verified transition. When the output is not a terminal (a log file,
CI), the same line goes to the log every ``log_every`` seconds instead. It runs as a SimPy process on
the run's own environment, so it reads the run between two steps and never from another thread.

Whatever the mode, :class:`Notices` writes one log line the moment a controller enters TIMEOUT (its
reason), recovers, or refuses the agent's first action (why): a lost controller must look lost while
it is lost, not only in the summary. Log lines written under a live status line (or a progress bar:
tqdm's own redirect) go above it, the line drawn again under them.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections import Counter
from collections.abc import Generator, Iterator, Mapping
from typing import IO, Any

import simpy

from hils.shell.events import Kind

__all__ = ["Notices", "StatusLine"]

log = logging.getLogger("hils.cli.status")
notice = logging.getLogger("hils.run")


class StatusLine:
    """Shows the state of a Testbed's run as it goes."""

    def __init__(self, *, stream: IO[str] | None = None, period: float = 0.5, log_every: float = 10.0) -> None:
        self.tb: Any = None
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.period = period if self.tty else log_every
        self._width = 0
        self._text = ""  # the line shown, drawn again under a log line written above it

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
                self._draw(text)
            else:
                log.info("%s", text)

    def _draw(self, text: str) -> None:
        self.stream.write("\r" + text.ljust(self._width))
        self.stream.flush()
        self._text, self._width = text, len(text)

    def _erase(self) -> None:
        if self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0

    @contextlib.contextmanager
    def above(self) -> Iterator[None]:
        """While in this block, console log lines go above the status line: it is erased, the record written,
        and the line drawn again (else a record would be glued to the end of the line). Off a terminal the
        status is itself log lines: nothing to do."""
        root = logging.getLogger()
        consoles = [h for h in root.handlers if isinstance(h, logging.StreamHandler)
                    and h.stream in (sys.stdout, sys.stderr)] if self.tty else []
        wrapped = [_Above(h, self) for h in consoles]
        for h, w in zip(consoles, wrapped, strict=True):
            root.removeHandler(h)
            root.addHandler(w)
        try:
            yield
        finally:
            for h, w in zip(consoles, wrapped, strict=True):
                root.removeHandler(w)
                root.addHandler(h)

    def close(self) -> None:
        """End the line on a terminal, so that what follows starts on a line of its own."""
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0


class _Above(logging.Handler):
    """A console handler that writes above a status line (see :meth:`StatusLine.above`)."""

    def __init__(self, inner: logging.Handler, status: StatusLine) -> None:
        super().__init__(inner.level)
        self.inner, self.status = inner, status

    def emit(self, record: logging.LogRecord) -> None:
        shown = self.status._width > 0
        self.status._erase()
        self.inner.handle(record)
        if shown:
            self.status._draw(self.status._text)


class Notices:
    """An event-log subscriber (:meth:`hils.shell.events.EventLog.subscribe`) that writes one log line when a user
    watching the run must know: a controller enters TIMEOUT (warning), recovers (info), or refuses the agent's
    first action (warning; the others are counted in the summary). In a run of several controllers each line
    names its traffic light."""

    def __init__(self) -> None:
        self._refused = False

    def __call__(self, record: Mapping[str, Any]) -> None:
        kind = record["kind"]
        if kind == Kind.TIMEOUT_ENTERED:
            notice.warning("%sTIMEOUT at %.1f s (%s): %s; commands and polls halt until it recovers",
                           _light(record), record["t"], record["reason"], record.get("detail"))
        elif kind == Kind.RECOVERED:
            notice.info("%srecovered from TIMEOUT at %.1f s, green %s", _light(record), record["t"],
                        "+".join(map(str, record.get("greens") or ())) or "none")
        elif kind == Kind.ACTION_REFUSED and not self._refused:
            self._refused = True
            notice.warning("%saction %s refused at %.1f s (%s): %s; nothing was sent (the agent is asked again at "
                           "its next decision; further refusals are counted in the summary)", _light(record),
                           record["action_id"], record["t"], record["error"], record.get("message"))


def _light(record: Mapping[str, Any]) -> str:
    where = record.get("intersection")
    return f"{where}: " if where else ""


def _shown(state: Any) -> str:
    if state is None:
        return "not read yet"
    for name, phases in (("green", state.greens), ("yellow", state.yellows)):
        if phases:
            return f"{name} {'+'.join(map(str, sorted(phases)))}"
    return "all red"
