"""The controller's 0.1 s tick in virtual time, stepping only the ticks that may change something.

Rules of this file
------------------
- Tick k of a power-up is due at ``start + k * TICK``, as in the ticked process
  (:meth:`emulator.model.controller.Controller.process`); the unit's own integer tick
  counter is k. No tick is ever dropped: skipped ticks are counted by
  ``unit.skip``, and the model's state after them is what stepping each would give
  (``tests/emulator/model/test_controller_events.py``).
- A real step runs at its own due time, on the environment, so everything that
  watches the model (interval changes, monitors) sees it when it happens.
- Every write reaches the unit through :class:`ClockedSurface`: the unit is first
  brought up to the present (:meth:`EventClock.catch_up`), then written, then its
  next real step is scheduled anew (:meth:`EventClock.touched`): the unit's own
  write methods say which steps the write makes real.

Theory of operation
-------------------
After each real step the unit says how many ticks ahead the next step that may
change anything is (``quiet_ticks``): the clock schedules one SimPy event there
and nothing in between. A write in between catches the counters up to the
present first, so a SET lands on the tick it would have landed on.

The clock is also the change feed of the in-process transport
(:class:`hils.shell.fastpath.ChangeFeed`): ``version`` counts the moments a GET could
start answering differently (every write, every real step that changed the
status the agent answers or the controller's own status and control objects),
and ``changed()`` fires at the next one. A poller
that knows the version it last read needs no GET until the version moves.
``controls`` moves more rarely: when a control object may have been given
phases, which only a write of one does (the controller itself only ever clears
them), or a ``bump()``; the middleware's read-back of the control objects
sleeps until it moves (and knows its own writes).
"""

from __future__ import annotations

from collections.abc import Sequence

import simpy

from emulator.agent.mib import MibView
from emulator.model.controller import TICK
from emulator.model.delays import DelayedController
from hils.protocol.ntcip import CONTROL_TABLE, Oid, Value
from hils.protocol.timegrid import Grid

#: The OID prefixes of the control objects, a write of which moves ``EventClock.controls``.
_CONTROL_PREFIXES = frozenset(entry.prefix for entry in CONTROL_TABLE.values())


class _Moves:
    """A count of moments, and an event that fires at the next one."""

    def __init__(self, env: simpy.Environment) -> None:
        self.env = env
        self.count = 0
        self._next: simpy.Event | None = None

    def next(self) -> simpy.Event:
        if self._next is None:
            self._next = self.env.event()
        return self._next

    def move(self) -> None:
        self.count += 1
        if self._next is not None:
            moved, self._next = self._next, None
            moved.succeed()


class EventClock:
    """Runs ``unit``'s ticks on ``env`` from ``phase`` seconds on, event by event."""

    def __init__(self, env: simpy.Environment, unit: DelayedController, phase: float = 0.0) -> None:
        self.env = env
        self.unit = unit
        self._version = _Moves(env)
        self._controls = _Moves(env)
        self.steps = 0  # steps run (real ones, and ticks stepped for the data logger alone); the rest were skipped
        self._grid = Grid(env.now + phase, TICK)
        self._due: int | None = None  # tick count after the next scheduled real step
        self._generation = 0  # an alarm from an older schedule is stale
        self._schedule(1)

    # --- the change feed ---------------------------------------------------------------------

    @property
    def version(self) -> int:
        return self._version.count

    @property
    def controls(self) -> int:
        return self._controls.count

    def changed(self) -> simpy.Event:
        """An event that fires when ``version`` next moves."""
        return self._version.next()

    def controls_changed(self) -> simpy.Event:
        """An event that fires when ``controls`` next moves."""
        return self._controls.next()

    def bump(self) -> None:
        """Something besides the unit changed what a GET may answer: move ``version`` and ``controls`` (the
        caller does not say what changed) and wake whoever waits for them."""
        self._version.move()
        self._controls.move()

    def written(self, varbinds: Sequence[tuple[Oid, Value]]) -> None:
        """A SET reached the unit: what it answers may differ, and its control objects too when it wrote one."""
        self.touched()
        if any(oid[:-1] in _CONTROL_PREFIXES for oid, _ in varbinds):
            self._controls.move()

    # --- inputs ----------------------------------------------------------------------------------

    def catch_up(self) -> None:
        """Bring the unit to the present: the real steps due by now, then the quiet ticks since."""
        now_tick = self._ticks_due()
        while self._due is not None and self._due <= now_tick:
            self._step()
        self.unit.skip(now_tick - self.unit.tick)

    def touched(self) -> None:
        """The unit was written: what it answers may differ, and its next step may not be quiet (every write
        reaches the unit through a method that says so: a SET waiting for its tick, or a touched controller)."""
        self._version.move()
        self._schedule(self.unit.quiet_ticks())

    def power_cycle(self) -> None:
        """Power down and up: the unit resets and its tick grid starts now (its clock, which keeps counting through a
        power cycle, brought up to the present first)."""
        self.catch_up()
        self.unit.reset()
        self._grid = Grid(self.env.now, TICK)
        self._version.move()  # the control objects are cleared: none has phases it did not have
        self._schedule(1)

    # --- ticking ---------------------------------------------------------------------------------

    def _ticks_due(self) -> int:
        """The tick count the unit has by now: every tick due at or before the present."""
        return max(0, self._grid.first_after(self.env.now) - 1)

    def delay(self, ticks: int) -> float:
        """Seconds from now until the unit's tick ``ticks`` ahead of its own count is due."""
        return self._grid.delay(self.unit.tick + ticks, self.env.now)

    def _versions(self) -> tuple[int, int]:
        # The status as the agent answers it, and the controller's own: the control objects (a backup
        # time expiring, a force-off clearing) change with the latter, whatever the status image lags.
        return self.unit.status_version, self.unit.controller.status_version

    def _schedule(self, ahead: int | None) -> None:
        self._generation += 1
        if ahead is None:
            self._due = None  # nothing changes until something is written
            return
        self._due = due = self.unit.tick + ahead
        generation = self._generation
        alarm = self.env.timeout(self._grid.delay(due, self.env.now))
        alarm.callbacks.append(lambda _ev: generation == self._generation and self._step())

    def _step(self) -> None:
        unit = self.unit
        unit.skip(self._due - 1 - unit.tick)
        versions = self._versions()
        unit.step()
        self.steps += 1
        if self._versions() != versions:
            self._version.move()
        self._schedule(unit.quiet_ticks())


class ClockedSurface:
    """The MIB view as the in-process transport reaches it: every write goes through the clock."""

    def __init__(self, mib: MibView, clock: EventClock) -> None:
        self.mib = mib
        self.clock = clock
        self.get_many = mib.get_many  # a read needs no clock: the MIB's own, without a frame between (every poll)

    def set_many(self, varbinds: Sequence[tuple[Oid, Value]]) -> None:
        self.clock.catch_up()
        try:
            self.mib.set_many(varbinds)
        finally:
            self.clock.written(varbinds)
