"""The signal-state poller and the shared signal cache.

One SimPy process reads reds, yellows and greens in a single GET at a fixed
rate and pushes the result to :class:`SignalCache`, which every other part
reads (the manager to verify transitions, SUMO to show the lights). Polls are
scheduled on a fixed grid (start + k * period) so the rate does not drift with
response times; a poll that takes longer than a period is followed at once by
the next. After n_timeout consecutive failed polls the poller reports a
communication failure. While halted (the manager in TIMEOUT) it does not poll.
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
class _Decoded:
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
        self.polls = 0
        self.failed = 0  # polls that got no usable answer, over the run
        self.halted = False
        self._resume = env.event()
        self._decoded: dict[tuple, _Decoded] = {}

    def halt(self) -> None:
        self.halted = True

    def resume(self) -> None:
        self.halted = False
        self.consecutive_failures = 0
        if not self._resume.triggered:
            self._resume.succeed()

    def read_once(self):
        """One GET of the signal state (a SimPy process body); returns the SignalState or raises."""
        decoded = yield from self._read()
        return decoded.state

    def _read(self):
        values = yield self.transport.get(self.oids)
        return self._decode(values)

    def _decode(self, values: tuple) -> _Decoded:
        # A controller shows a handful of distinct states: decode each once, with its log fields.
        decoded = self._decoded.get(values)
        if decoded is None:
            state = SignalState.from_values(values, self.groups)
            decoded = self._decoded[tuple(values)] = _Decoded(state, tuple(sorted(state.greens)),
                                                              tuple(sorted(state.yellows)))
        return decoded

    def run(self):
        start = self.env.now
        k = 0
        while True:
            if self.halted:
                self._resume = self.env.event()
                yield self._resume
                start, k = self.env.now, 0
            self.polls += 1
            poll_id = self.polls
            try:
                decoded = yield from self._read()
            except (TransportError, SnmpError, ValueError) as exc:
                self.consecutive_failures += 1
                self.failed += 1
                self.log.emit(Kind.POLL_FAILED, poll_id=poll_id, error=f"{type(exc).__name__}: {exc}",
                              consecutive=self.consecutive_failures)
                if self.consecutive_failures == self.n_timeout:
                    self.on_failure(f"{self.n_timeout} consecutive polls failed (last: {type(exc).__name__})")
            else:
                self.consecutive_failures = 0
                state = decoded.state
                changed = self.cache.snapshot is None or state != self.cache.snapshot.state
                self.log.emit(Kind.POLL, poll_id=poll_id, greens=decoded.greens, yellows=decoded.yellows,
                              changed=changed)
                self.cache.update(state, self.env.now, poll_id)
            # Next slot on the fixed grid; if this poll overran, go at once on the next free slot.
            k = max(k + 1, math.ceil((self.env.now - start) / self.period - 1e-9))
            yield self.env.timeout(max(0.0, start + k * self.period - self.env.now))
