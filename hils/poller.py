"""The poll grid and the shared signal cache.

The poller sends one GET of reds, yellows and greens per period; the middleware hands each poll's fate
to the manager, which counts failures, discards late answers and says what the signal state is now
(:class:`SignalCache`, which every other part reads: SUMO to show the lights, the agents).

Rules of this module:

- Polls go out on a fixed grid (:class:`hils.timegrid.Grid`), whatever the answers do: a poll that has
  not been answered does not hold the next one back, so a lost datagram costs one poll, not tau_udp of
  them. Requests overlap, each with its own poll id (the transport's sessions keep them apart).
- The poller decides nothing about what an answer or a failure means: it sends (``send(poll_id)``) and
  counts the polls of its grid. While halted (the manager in TIMEOUT) no poll goes out; polling resumes
  on a new grid from the moment it is resumed.
- A poll that cannot see a change costs nothing. When the transport has a change feed (an in-process
  controller, no random loss or jitter), a poll whose feed version is the one the newest answered poll
  read would get that same answer at the same latency: it is counted on the grid (its poll id is
  used up) and not sent, and the poller sleeps until the feed moves (a write, a change of status) or
  polling halts. The next poll on the grid then goes out. What the cache holds, and when the manager
  sees it, is what polling every period gives (``tests/test_poll_elision.py`` compares the logs).
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

import simpy

from hils.ntcip import SignalState
from hils.timegrid import Grid
from hils.transport import Transport

__all__ = ["Poller", "SignalCache", "Snapshot"]

Subscriber = Callable[["Snapshot", bool], None]


@dataclass(frozen=True, slots=True)
class Snapshot:
    """The latest signal state, when it was read, and which poll read it."""

    state: SignalState
    t: float
    seq: int


class SignalCache:
    """Latest signal state; notifies subscribers when it changes."""

    def __init__(self) -> None:
        self.snapshot: Snapshot | None = None
        self._subscribers: list[Subscriber] = []

    @property
    def state(self) -> SignalState | None:
        return self.snapshot.state if self.snapshot else None

    def subscribe(self, fn: Subscriber, *, every_poll: bool = False) -> None:
        """Call ``fn(snapshot, changed)`` on changes, or on every update with ``every_poll``."""
        self._subscribers.append(fn if every_poll else (lambda snap, changed: changed and fn(snap, changed)))

    def update(self, state: SignalState, t: float, seq: int) -> bool:
        changed = self.snapshot is None or state != self.snapshot.state
        self.snapshot = Snapshot(state, t, seq)
        for fn in self._subscribers:
            fn(self.snapshot, changed)
        return changed


class Poller:
    """The poll grid: ``send(poll_id)`` once per period of ``rate_hz`` while not halted.

    ``newest()`` is the newest poll whose answer was applied (the manager's): a poll may be left out only
    when that is the newest one sent."""

    def __init__(self, env: simpy.Environment, transport: Transport, *, rate_hz: float,
                 send: Callable[[int], None], newest: Callable[[], int]) -> None:
        self.env = env
        self.transport = transport
        self.period = 1.0 / rate_hz
        self.send = send
        self.newest = newest
        self.polls = 0  # polls on the grid, sent or not
        self.elided = 0  # polls not sent: they could not see a change
        self.halted = False
        self._sent = 0  # the newest poll sent
        self._seen: int | None = None  # the feed's version when the newest poll sent read the controller
        self._resume = env.event()
        self._halting: simpy.Event | None = None  # set during an elided sleep; wakes it when polling halts
        self._grid, self._k = Grid(env.now, self.period), 0  # poll k is due at the grid's instant k

    @property
    def counts(self) -> dict[str, int]:
        """Polls on the grid so far and those not sent (``elided``: they could not see a change)."""
        if self._halting is not None:
            self._pass_quiet_polls()
        return {"polls": self.polls, "elided": self.elided}

    def halt(self) -> None:
        self.halted = True
        self._seen = None  # after a halt the first poll goes out
        if self._halting is not None and not self._halting.triggered:
            self._halting.succeed()

    def resume(self) -> None:
        self.halted = False
        if not self._resume.triggered:
            self._resume.succeed()

    def run(self) -> Generator[simpy.Event, Any, None]:
        env = self.env
        self._grid, self._k = Grid(env.now, self.period), 0
        while True:
            if self.halted:
                self._resume = env.event()
                yield self._resume
                self._grid, self._k = Grid(env.now, self.period), 0
            self.polls += 1
            feed = self.transport.change_feed
            if self._unchanged():
                self.elided += 1
            else:
                self._sent, self._seen = self.polls, feed.version if feed is not None else None
                self.send(self.polls)
            self._k += 1
            if self._unchanged():
                # Every poll until the feed moves would be this one again: sleep until then; the polls due
                # meanwhile are counted as they pass (_pass_quiet_polls).
                self._halting = env.event()
                yield env.any_of([feed.changed(), self._halting])
                self._pass_quiet_polls()
                self._halting = None
                if self.halted:
                    continue
            yield env.timeout(self._grid.delay(self._k, env.now))

    def _pass_quiet_polls(self) -> None:
        """Count, as elided, the polls of the grid due before now that an elided sleep passed over."""
        due = self._grid.first_at_or_after(self.env.now, self._k)
        self.polls += due - self._k
        self.elided += due - self._k
        self._k = due

    def _unchanged(self) -> bool:
        """True when a poll now would get the answer the newest poll got (sent, answered, nothing since)."""
        feed = self.transport.change_feed
        return feed is not None and self._seen == feed.version and self.newest() == self._sent and not self.halted
