"""The two clocks that drive the run's one SimPy environment.

SimPy is the scheduler in both modes and every active part is a SimPy
process; only the object that advances the environment differs:

- :class:`VirtualClock` runs the environment as fast as it can (CI, fault
  suites, training). Deterministic: nothing outside SimPy takes part.
  A simulation step costs no simulated time (:data:`hils.shell.fastpath.modeled_cost`).
- :class:`WallClockDriver` steps the same environment to the wall clock from
  asyncio on one thread, so that pysnmp's asyncio I/O and SimPy share a loop.
  Sim time ``s`` maps to wall time ``t0 + s`` on the loop's monotonic clock
  (``loop.time()``, which is ``time.monotonic`` for the default loop); ``t0``
  is re-anchored at each :meth:`WallClockDriver.run` so that sim time does not
  jump over the time spent stopped.

An agent's decision is asked through the clock too (``ask``): in virtual time it is called at once and takes no
simulated time; at the wall clock it runs in a thread of its own while the loop goes on stepping the
environment (polls, keepalives, SUMO), and its answer is delivered like an I/O completion. An agent that
thinks for 30 s does not stop the middleware.

Both follow SimPy's ``run(until=t)`` rule and never paper over it: every
event due strictly before ``t`` is processed, ``env.now`` ends at ``t``, and
an event due exactly at ``t`` stays queued for the next run. Code written
against ``env.run`` therefore behaves the same under either clock. The
Testbed moves time with one call, ``advance(until, events)``, the same on
both: run until one of ``events`` has been processed, or to ``until``.

I/O completions reach SimPy only through :meth:`WallClockDriver.deliver`,
which schedules them at their wall-mapped time with public SimPy API. SimPy is
touched from the loop's thread only; there are no threads and no locks.
"""

from __future__ import annotations

import asyncio
import math
import random
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
import simpy

from hils.protocol.errors import STOPS
from hils.shell.fastpath import StepCost, modeled_cost

__all__ = ["Answer", "Clock", "LatenessStats", "LatenessSummary", "VirtualClock", "WallClockDriver"]

LatenessHook = Callable[[float, float], None]

# Events processed back to back before the driver yields to the I/O loop, so
# that a driver that has fallen behind still lets datagrams in and requests out.
_MAX_BATCH = 256


@dataclass(slots=True)
class Answer:
    """An agent's answer the run is waiting for (:meth:`Clock.ask`): ``done`` once it came (``value``, or the
    ``error`` its call raised), at ``answered_at``; ``event`` fires then at the wall clock (None: it came at once)."""

    asked_at: float
    event: simpy.Event | None = None
    done: bool = False
    value: Any = None
    error: BaseException | None = None
    answered_at: float | None = None
    overdue: bool = False  # it did not come within the decision's deadline: the run went on without it

    def settle(self, now: float, value: Any = None, error: BaseException | None = None) -> None:
        self.done, self.value, self.error, self.answered_at = True, value, error, now


class Clock(Protocol):
    """What a run needs from either clock."""

    env: simpy.Environment
    step_cost: StepCost  # what a simulation step costs under this clock

    def ask(self, fn: Callable[..., Any], *args: Any) -> Answer:
        """Call ``fn(*args)`` (an agent's ``act``) the way this clock lets time pass meanwhile."""
        ...

    def advance(self, until: float | None, events: Sequence[simpy.Event]) -> signal.Signals | None:
        """Run until one of ``events`` has been processed, or to ``until``; returns the signal (SIGINT, SIGTERM)
        that stopped it, if one did."""
        ...

    def sim_now(self) -> float:
        """The sim time of the present instant (``env.now`` in virtual time)."""
        ...


class VirtualClock:
    """Runs the environment in virtual time, as fast as the CPU allows."""

    def __init__(self, env: simpy.Environment) -> None:
        self.env = env
        self.step_cost = modeled_cost

    def ask(self, fn: Callable[..., Any], *args: Any) -> Answer:
        """At once: an agent's decision takes no simulated time."""
        answer = Answer(self.env.now)
        try:
            answer.settle(self.env.now, fn(*args))
        except STOPS:
            raise
        except BaseException as exc:  # SystemExit too: an agent does not end the process
            answer.settle(self.env.now, error=exc)
        return answer

    def advance(self, until: float | None, events: Sequence[simpy.Event]) -> None:
        """Run until one of ``events`` has been processed, or to ``until`` (events due exactly then stay queued,
        so that an agent deciding at ``until`` acts before them)."""
        if until is not None:
            events = (*events, _deadline(self.env, until))
        _run_until_one(events, simpy.core.StopSimulation.callback, self.env.run)

    def run(self, until: float | None = None) -> None:
        """Process every event due before ``until`` and leave ``env.now == until``.

        Events due exactly at ``until`` are not processed (SimPy's rule); with
        ``until=None`` the run lasts until no event is left, which is forever
        when a periodic process exists.
        """
        _check_until(self.env, until)
        self.env.run(until=until)

    run_sync = run

    def sim_now(self) -> float:
        return self.env.now


@dataclass(frozen=True, slots=True)
class LatenessSummary:
    """Lateness of the processed events, in seconds (p99 from a uniform sample of the run)."""

    count: int
    mean: float
    max: float
    p99: float


class LatenessStats:
    """Running statistics of event lateness with a bounded memory.

    Count, mean and max are exact; the p99 comes from a reservoir (Vitter's
    algorithm R) of at most ``reservoir`` values, a uniform sample of the whole
    run, seeded so that equal inputs give equal results.
    """

    def __init__(self, reservoir: int = 8192, seed: int = 0) -> None:
        if reservoir < 1:
            raise ValueError(f"reservoir must hold at least one value, got {reservoir}")
        self.count = 0
        self.max = -math.inf
        self._sum = 0.0
        self._sample = np.empty(reservoir)
        self._rng = random.Random(seed)

    def add(self, lateness: float) -> None:
        n = self.count
        self.count = n + 1
        self._sum += lateness
        if lateness > self.max:
            self.max = lateness
        size = len(self._sample)
        if n < size:
            self._sample[n] = lateness
        else:
            slot = self._rng.randrange(n + 1)
            if slot < size:
                self._sample[slot] = lateness

    @property
    def mean(self) -> float:
        return self._sum / self.count if self.count else math.nan

    @property
    def p99(self) -> float:
        filled = min(self.count, len(self._sample))
        return float(np.percentile(self._sample[:filled], 99)) if filled else math.nan

    def summary(self) -> LatenessSummary:
        return LatenessSummary(self.count, self.mean, self.max if self.count else math.nan, self.p99)


class WallClockDriver:
    """Steps a SimPy environment to the wall clock from an asyncio loop.

    The loop waits until the wall time of ``env.peek()`` (or of ``until``), or
    until an I/O completion or :meth:`stop` wakes it, then processes every
    event now due, measuring each one's lateness: the wall time it started
    running minus its due time. Transports run their I/O as tasks on
    :attr:`loop` and hand results back with :meth:`deliver`.

    Without ``loop`` the driver creates its own and :meth:`close` closes it.
    """

    def __init__(self, env: simpy.Environment, *, loop: asyncio.AbstractEventLoop | None = None,
                 on_lateness: LatenessHook | None = None) -> None:
        self.env = env
        self.step_cost: StepCost = _WallCost(self)
        self._owns_loop = loop is None
        self.loop: asyncio.AbstractEventLoop = asyncio.new_event_loop() if loop is None else loop
        #: Called after every processed event with (due sim time, lateness in s); drift detection hooks in here.
        self.on_lateness: LatenessHook | None = on_lateness
        self.lateness = LatenessStats()
        self._t0 = 0.0
        self._running = False
        self._stop_requested = False
        self._waiter: asyncio.Future[None] | None = None
        #: The signal (SIGINT or SIGTERM) that stopped :meth:`run_sync`, until its caller clears it.
        self.signalled: signal.Signals | None = None

    @property
    def running(self) -> bool:
        return self._running

    def sim_now(self) -> float:
        """The sim time mapped to the wall clock now; ``env.now`` while not running, as sim time is then frozen."""
        return self.loop.time() - self._t0 if self._running else self.env.now

    def wall_time(self, sim_time: float) -> float:
        """The ``loop.time()`` instant at which ``sim_time`` is due in the current run."""
        return self._t0 + sim_time

    async def run(self, until: float | None = None) -> None:
        """Step the environment in step with the wall clock until ``until`` or :meth:`stop`.

        Must be awaited on :attr:`loop`. With ``until`` the call returns at the
        wall time of ``until`` with ``env.now == until`` (events due exactly
        then stay queued, as with ``env.run``); with None it runs until
        stopped, waiting for I/O when no event is queued. An exception raised
        by a SimPy process propagates from here, as from ``env.run``.
        """
        loop = asyncio.get_running_loop()
        if loop is not self.loop:
            raise RuntimeError("WallClockDriver.run() must be awaited on driver.loop, the loop its transports use")
        if self._running:
            raise RuntimeError("WallClockDriver.run() is already running")
        _check_until(self.env, until)
        env = self.env
        end = math.inf if until is None else until
        self._stop_requested = False
        self._t0 = loop.time() - env.now
        self._running = True
        try:
            while not self._stop_requested:
                due = env.peek()
                target = min(due, end)
                if target == math.inf or self._t0 + target > loop.time():
                    await self._sleep_until(target)
                elif due >= end:
                    env.run(until=end)
                    return
                else:
                    self._step_due(end)
                    # Let request tasks send and datagrams arrive before the next batch.
                    await asyncio.sleep(0)
        finally:
            self._running = False

    def ask(self, fn: Callable[..., Any], *args: Any) -> Answer:
        """In a thread of its own (a daemon: one that never returns does not hold the process at exit), while the
        loop steps the environment on; the answer reaches SimPy as a completion at the wall-mapped present."""
        answer = Answer(self.env.now, self.env.event())
        # The event always succeeds: an agent's error is the run's to raise where it asked, not SimPy's.
        answer.event.callbacks.append(lambda ev: answer.settle(self.env.now, *ev.value))

        def call() -> None:
            try:
                outcome = (fn(*args), None)
            except BaseException as exc:  # SystemExit too: an agent does not end the process
                outcome = (None, exc)
            self.loop.call_soon_threadsafe(self.deliver, answer.event, outcome)

        threading.Thread(target=call, name="hils-agent", daemon=True).start()
        return answer

    def advance(self, until: float | None, events: Sequence[simpy.Event]) -> signal.Signals | None:
        """Run at the wall clock until one of ``events`` has been processed, or to ``until``; returns the signal
        (SIGINT, SIGTERM) that stopped it, if one did."""
        _run_until_one(events, lambda _ev: self.stop(), lambda: self.run_sync(until=until))
        signalled, self.signalled = self.signalled, None
        return signalled

    def run_sync(self, until: float | None = None, *, handle_signals: bool = True) -> None:
        """Run :meth:`run` to completion on :attr:`loop` from synchronous code.

        With ``handle_signals`` (main thread only), SIGINT and SIGTERM call
        :meth:`stop` for the duration of the run, so Ctrl-C ends the run
        between two SimPy steps instead of inside one; :attr:`signalled`
        then says which signal it was.
        """
        installed: list[signal.Signals] = []
        if handle_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.loop.add_signal_handler(sig, self._on_signal, sig)
                installed.append(sig)
        try:
            self.loop.run_until_complete(self.run(until))
        finally:
            for sig in installed:
                self.loop.remove_signal_handler(sig)

    def _on_signal(self, sig: signal.Signals) -> None:
        self.signalled = sig
        self.stop()

    def stop(self) -> None:
        """Make :meth:`run` return after the event being processed; safe from a signal handler."""
        self._stop_requested = True
        waiter = self._waiter
        if waiter is not None:
            # call_soon_threadsafe only writes to the loop's self-pipe, which is
            # what a plain signal.signal handler may safely do.
            self.loop.call_soon_threadsafe(_wake, waiter)

    def deliver(self, event: simpy.Event, value: Any = None, exc: BaseException | None = None) -> None:
        """Complete ``event`` at the wall-mapped present: succeed with ``value``, or fail with ``exc``.

        For transports: call from the loop's thread (an I/O callback or task).
        The completion is queued as a timeout at the present sim time, so SimPy
        processes see it in time order with everything else; an event that has
        meanwhile been triggered by someone else is left as it is.
        """
        timeout = self.env.timeout(max(0.0, self.sim_now() - self.env.now))
        timeout.callbacks.append(partial(_complete, event, value, exc))
        if self._waiter is not None:
            _wake(self._waiter)

    def close(self) -> None:
        """Cancel what is left on the driver's own loop and close it; a loop passed in is left to its owner."""
        if not self._owns_loop or self.loop.is_closed():
            return
        pending = asyncio.all_tasks(self.loop)
        for task in pending:
            task.cancel()
        if pending:
            self.loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
        self.loop.run_until_complete(self.loop.shutdown_asyncgens())
        self.loop.close()

    def _step_due(self, end: float) -> None:
        env, loop, stats = self.env, self.loop, self.lateness
        for _ in range(_MAX_BATCH):
            due = env.peek()
            wall = loop.time()
            if self._stop_requested or due >= end or self._t0 + due > wall:
                return
            env.step()
            late = wall - (self._t0 + due)
            stats.add(late)
            if self.on_lateness is not None:
                self.on_lateness(due, late)

    async def _sleep_until(self, target: float) -> None:
        waiter = self.loop.create_future()
        self._waiter = waiter
        timer = None if target == math.inf else self.loop.call_at(self._t0 + target, _wake, waiter)
        try:
            await waiter
        finally:
            self._waiter = None
            if timer is not None:
                timer.cancel()


class _WallCost:
    """What a step cost at the wall clock: its own time plus how late it started. Never free."""

    def __init__(self, driver: WallClockDriver) -> None:
        self.driver = driver

    def __call__(self, step: Callable[[], Any]) -> float:
        late = max(0.0, self.driver.sim_now() - self.driver.env.now)
        t0 = time.perf_counter()
        step()
        return late + time.perf_counter() - t0

    def free_until(self, now: float) -> float:
        return now


def _run_until_one(events: Sequence[simpy.Event], stop: Callable[[simpy.Event], None], run: Callable[[], None]
                   ) -> None:
    """``run()`` with ``stop`` called back by whichever of ``events`` is processed first; the callbacks go again."""
    for ev in events:
        ev.callbacks.append(stop)
    try:
        run()
    finally:
        for ev in events:
            if ev.callbacks is not None and stop in ev.callbacks:
                ev.callbacks.remove(stop)


def _deadline(env: simpy.Environment, at: float) -> simpy.Event:
    """An event due at ``at`` that runs before every other event due then, as ``env.run(until=at)``'s own.

    Built as SimPy builds that one; unlike it, a deadline that another event beat to the stop is left
    without callbacks, so it cannot stop a later run."""
    event = simpy.Event(env)
    event._ok, event._value = True, None
    env.schedule(event, simpy.core.URGENT, at - env.now)
    return event


def _wake(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


def _complete(event: simpy.Event, value: Any, exc: BaseException | None, _: simpy.Event) -> None:
    if event.triggered:
        return
    if exc is None:
        event.succeed(value)
    else:
        event.fail(exc)


def _check_until(env: simpy.Environment, until: float | None) -> None:
    if until is not None and not until > env.now:
        raise ValueError(f"until ({until}) must be later than the current sim time ({env.now})")
