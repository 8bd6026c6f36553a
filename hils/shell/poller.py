"""The poll grid and the shared signal cache.

The poller sends one GET of reds, yellows and greens per period; the middleware hands each poll's fate
to the manager, which counts failures, discards late answers and says what the signal state is now
(:class:`SignalCache`, which every other part reads: SUMO to show the lights, the agents).

Rules of this module:

- Polls go out on a fixed grid (:class:`hils.protocol.timegrid.Grid`), whatever the answers do: a poll that has
  not been answered does not hold the next one back, so a lost datagram costs one poll, not tau_udp of
  them. Requests overlap, each with its own poll id (the transport's sessions keep them apart).
- The poller decides nothing about what an answer or a failure means: it sends (``send(poll_id)``) and
  counts the polls of its grid. While halted (the manager in TIMEOUT) no poll goes out; polling resumes
  on a new grid from the moment it is resumed.
- On virtual time's fast path (:mod:`hils.shell.fastpath`, rule 2) a poll that cannot see a change is counted on
  the grid (its poll id used up) and not sent, and the poller sleeps until one could or polling halts; the
  next poll on the grid then goes out.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

import simpy

from hils.protocol.ntcip import SignalState
from hils.protocol.timegrid import Grid
from hils.shell.fastpath import QuietPolls

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
        changed = self.snapshot is None or (state is not self.snapshot.state and state != self.snapshot.state)
        self.snapshot = Snapshot(state, t, seq)
        for fn in self._subscribers:
            fn(self.snapshot, changed)
        return changed


class Poller:
    """The poll grid: ``send(poll_id)`` once per period of ``rate_hz`` while not halted, leaving out on the fast
    path (``quiet``) the polls that cannot see a change."""

    def __init__(self, env: simpy.Environment, *, rate_hz: float, send: Callable[[int], None],
                 quiet: QuietPolls | None = None) -> None:
        self.env = env
        self.period = 1.0 / rate_hz
        self.send = send
        self.quiet = quiet
        self.polls = 0  # polls on the grid, sent or not
        self.elided = 0  # polls not sent: they could not see a change
        self.answered_unsent = 0  # polls not sent that a SET of ours would once have sent, counted as answered
        self._owed: set[int] = set()  # grid instants of such polls, not yet passed
        self.halted = False
        self._resume = env.event()
        self._alarm: _Alarm | None = None  # an elided sleep's: set off when the feed moves or polling halts
        self._grid, self._k = Grid(env.now, self.period), 0  # poll k is due at the grid's instant k

    @property
    def counts(self) -> dict[str, int]:
        """Polls on the grid so far and those not sent (``elided``: they could not see a change; those a SET of ours
        once sent are in ``answered_unsent``)."""
        if self._alarm is not None and not self._alarm.triggered:
            self._pass_quiet_polls()
        return {"polls": self.polls, "elided": self.elided}

    def writing(self) -> Callable[[], None] | None:
        """A SET of ours is about to be sent: call the function returned once it is (None off the fast path). When
        the polls left out stay left out (:meth:`QuietPolls.written`), the poll of the grid's first instant not
        before now is owed: counted as answered when it passes."""
        quiet = self.quiet
        if quiet is None:
            return None
        before = quiet.before_write()

        def sent() -> None:
            if quiet.written(before):
                self._owed.add(self._grid.first_at_or_after(self.env.now, self._k))
        return sent

    def halt(self) -> None:
        self.halted = True
        if self.quiet is not None:
            self.quiet.forget()
        if self._alarm is not None:
            self._wake(self._alarm)  # the polls passed asleep are counted first, those owed to SETs among them
        self._owed.clear()  # the polls owed after now would not have gone out: polling halts

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
            self._k += 1
            if self.quiet is None or not self.quiet.leaves_out(self.polls):
                self._owed.discard(self._k - 1)
                self.send(self.polls)
                yield env.timeout(self._grid.delay(self._k, env.now))
                continue
            # Left out: every poll until the feed moves would be this one again. Sleep until it does (or polling
            # halts), on to the first instant of the grid from then; the polls due meanwhile are counted as they pass.
            self._left_out(self._k - 1, self._k)
            self._alarm = alarm = _Alarm(env)
            self.quiet.moved().callbacks.append(lambda _ev, alarm=alarm: self._moved(alarm))
            yield alarm
            self._alarm = None

    def _moved(self, alarm: _Alarm) -> None:
        """The feed moved during an elided sleep: wake, unless a poll would still read the newest answer (a SET of
        ours moved it): then sleep on until its next move."""
        if not self.halted and not alarm.triggered and self.quiet.still():
            self.quiet.moved().callbacks.append(lambda _ev: self._moved(alarm))
            return
        self._wake(alarm)

    def _left_out(self, first: int, end: int) -> None:
        """Count the polls of the grid's instants ``first`` to ``end - 1`` as not sent: as answered those a SET of ours
        would once have sent, as elided the others."""
        owed = [k for k in self._owed if k < end]
        passed = sum(1 for k in owed if k >= first)
        self._owed.difference_update(owed)
        self.answered_unsent += passed
        self.elided += end - first - passed

    def _wake(self, alarm: _Alarm) -> None:
        """End an elided sleep: the feed moved (the grid's next instant polls) or polling halted (at once)."""
        if alarm.triggered:
            return  # already woken: polling halted, then the feed moved (or the other way round)
        self._pass_quiet_polls()
        alarm.set_off(0.0 if self.halted else self._grid.delay(self._k, self.env.now))

    def _pass_quiet_polls(self) -> None:
        """Count, as elided, the polls of the grid due before now that an elided sleep passed over."""
        due = self._grid.first_at_or_after(self.env.now, self._k)
        self.polls += due - self._k
        self._left_out(self._k, due)
        self._k = due


class _Alarm(simpy.Event):
    """A timeout whose delay is known only when it is set off: an elided sleep wakes straight at the grid's next
    instant, one event where waking and then timing out to that instant took two (and an ``AnyOf`` besides)."""

    def set_off(self, delay: float) -> None:
        # What simpy.Timeout does as it is made: the event succeeds, scheduled ``delay`` from now.
        self._ok, self._value = True, None
        self.env.schedule(self, delay=delay)
