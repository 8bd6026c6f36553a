"""The signal-state poller and the shared signal cache.

One SimPy process reads reds, yellows and greens in a single GET at a fixed
rate and pushes the result to :class:`SignalCache`, which every other part
reads (the manager to verify transitions, SUMO to show the lights).

Rules of this module:

- Polls go out on a fixed grid (start + k * period), whatever the answers do:
  a poll that has not been answered does not hold the next one back, so a lost
  datagram costs one poll, not tau_udp of them. Requests overlap, each with
  its own request id (the transport's sessions keep them apart).
- Answers are applied in poll order: an answer older than the newest one
  applied is late and is discarded (counted, not logged: it says nothing new).
- Communication failure is n_timeout consecutive unanswered polls, as the
  paper defines it: failed polls newer than the newest answered one are
  counted; an answer resets the count. With overlapping polls a dead link is
  therefore seen about (n_timeout - 1) periods + tau_udp after it dies.
- While halted (the manager in TIMEOUT) no poll goes out, and answers to
  polls sent before the halt are ignored: recovery reads the controller itself.
- A poll that cannot see a change costs nothing. When the transport has a
  change feed (an in-process controller, no random loss or jitter), a poll
  whose feed version is the one the last answered poll read would get that
  same answer at the same latency: it is counted on the grid (its poll id is
  used up) and not sent, and the poller sleeps until the feed moves (a write,
  a change of status) or polling halts. The next poll on the grid then goes
  out. What the cache holds, and when the manager sees it, is what polling
  every period gives (``tests/test_poll_elision.py`` compares the logs).
- The log keeps a ``poll`` record when the signal state changes, and for the first
  answer after failed polls (the state is known again, changed or not: the plots
  mark the time between as no data); the counts (:attr:`Poller.counts`) say how
  many polls there were.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import simpy

from hils.events import EventLog, Kind
from hils.ntcip import SignalState, SnmpError, signal_oids
from hils.transport import Transport, TransportError

Subscriber = Callable[["Snapshot", bool], None]


@dataclass(frozen=True, slots=True)
class Snapshot:
    """The latest signal state, when it was read, and which poll read it."""

    state: SignalState
    t: float
    seq: int


@dataclass(frozen=True, slots=True)
class Decoded:
    """A signal state as a read saw it, with its fields for the log."""

    state: SignalState
    greens: tuple[int, ...]
    yellows: tuple[int, ...]


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
    """Polls the signal state through a transport into a cache."""

    def __init__(self, env: simpy.Environment, transport: Transport, cache: SignalCache, log: EventLog, *,
                 groups: int, rate_hz: float, n_timeout: int,
                 on_failure: Callable[[str], None]) -> None:
        self.env = env
        self.transport = transport
        self.cache = cache
        self.log = log
        self.oids = signal_oids(groups)
        self.groups = groups
        self.period = 1.0 / rate_hz
        self.n_timeout = n_timeout
        self.on_failure = on_failure
        self.consecutive_failures = 0
        self.polls = 0  # polls on the grid, sent or not
        self.elided = 0  # polls not sent: they could not see a change
        self.answered = 0  # answers applied
        self.failed = 0  # polls that got no usable answer, over the run
        self.late = 0  # answers that came after a newer poll's, discarded
        self.halted = False
        self._newest = 0  # the newest poll whose answer was applied
        self._sent = 0  # the newest poll sent
        self._seen: int | None = None  # the feed's version when the newest poll sent read the controller
        self._epoch = 0  # polling periods between halts; answers from an earlier one are ignored
        self._resume = env.event()
        self._halting: simpy.Event | None = None  # set during an elided sleep; wakes it when polling halts
        self._start, self._k = env.now, 0  # the grid: poll k is due at start + k * period
        self._decoded: dict[tuple, Decoded] = {}

    @property
    def counts(self) -> dict[str, int]:
        """Polls on the grid so far, and how each ended (``elided``: not sent, it could not see a change)."""
        if self._halting is not None:
            self._pass_quiet_polls()
        return {"polls": self.polls, "elided": self.elided, "answered": self.answered, "failed": self.failed,
                "late": self.late}

    def halt(self) -> None:
        self.halted = True
        self._epoch += 1
        self._seen = None  # after a halt the first poll goes out
        if self._halting is not None and not self._halting.triggered:
            self._halting.succeed()

    def resume(self) -> None:
        self.halted = False
        self.consecutive_failures = 0
        if not self._resume.triggered:
            self._resume.succeed()

    def read_once(self):
        """One GET of the signal state (a SimPy process body) outside the grid; returns what it saw (give it
        to :meth:`show`) or raises."""
        values = yield self.transport.get(self.oids)
        return self._decode(values)

    def _decode(self, values: tuple) -> Decoded:
        # A controller shows a handful of distinct states: decode each once, with its log fields.
        decoded = self._decoded.get(values)
        if decoded is None:
            state = SignalState.from_values(values, self.groups)
            decoded = self._decoded[tuple(values)] = Decoded(state, tuple(sorted(state.greens)),
                                                              tuple(sorted(state.yellows)))
        return decoded

    def run(self):
        env = self.env
        self._start, self._k = env.now, 0
        while True:
            if self.halted:
                self._resume = env.event()
                yield self._resume
                self._start, self._k = env.now, 0
            self.polls += 1
            feed = self.transport.change_feed
            if self._unchanged():
                self.elided += 1
            else:
                self._sent, self._seen = self.polls, feed.version if feed is not None else None
                self.transport.get(self.oids).callbacks.append(
                    lambda ev, poll_id=self.polls, epoch=self._epoch: self._settled(ev, poll_id, epoch))
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
            yield env.timeout(max(0.0, self._start + self._k * self.period - env.now))

    def _pass_quiet_polls(self) -> None:
        """Count, as elided, the polls of the grid due before now that an elided sleep passed over."""
        now, start, period = self.env.now, self._start, self.period
        due = max(self._k, math.ceil((now - start) / period))
        while due > self._k and start + (due - 1) * period >= now:
            due -= 1  # the first poll time at or after now, however the division rounded
        while start + due * period < now:
            due += 1
        self.polls += due - self._k
        self.elided += due - self._k
        self._k = due

    def _unchanged(self) -> bool:
        """True when a poll now would get the answer the newest poll got (sent, answered, nothing since)."""
        feed = self.transport.change_feed
        return feed is not None and self._seen == feed.version and self._newest == self._sent and not self.halted

    def _settled(self, ev: simpy.Event, poll_id: int, epoch: int) -> None:
        """One poll's answer or failure, in whatever order the polls settle."""
        ev.defused = True
        if self.halted or epoch != self._epoch:
            return  # sent before a halt: recovery reads the controller itself
        try:
            if not ev.ok:
                raise ev.value
            decoded = self._decode(ev.value)
        except (TransportError, SnmpError, ValueError) as exc:
            self.failed += 1
            # A poll overtaken by a newer answer is not part of a run of failures: it is logged with the
            # count as it stands.
            overtaken = poll_id < self._newest
            if not overtaken:
                self.consecutive_failures += 1
            self.log.emit(Kind.POLL_FAILED, poll_id=poll_id, error=f"{type(exc).__name__}: {exc}",
                          consecutive=self.consecutive_failures)
            if not overtaken and self.consecutive_failures == self.n_timeout:
                self.on_failure(f"{self.n_timeout} consecutive polls failed (last: {type(exc).__name__})")
            return
        if poll_id < self._newest:
            self.late += 1
            return
        self._newest = poll_id
        self.answered += 1
        failing, self.consecutive_failures = self.consecutive_failures, 0
        self.show(decoded, poll_id, logged=failing > 0)

    def show(self, decoded: Decoded, poll_id: int, *, logged: bool = False) -> None:
        """Put what a read saw into the cache, with a ``poll`` record when it changes the state (or ``logged``)."""
        if logged or self.cache.snapshot is None or decoded.state != self.cache.snapshot.state:
            self.log.emit(Kind.POLL, poll_id=poll_id, greens=decoded.greens, yellows=decoded.yellows)
        self.cache.update(decoded.state, self.env.now, poll_id)
