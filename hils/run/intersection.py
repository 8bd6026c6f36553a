"""One intersection of a run: its controller, the middleware that drives it, its agent, its decision schedule
and what SUMO shows for it.

A :class:`hils.Testbed` holds one :class:`Intersection` per signalised intersection, keyed by its name (its
traffic light's SUMO id): one for the paper's four-leg (``C``), four for the corridor, sixteen for the grid.
A run of one intersection is the case N = 1 of the same code. Each intersection has its own transport,
manager, poller and signal cache (its :class:`hils.shell.middleware.Middleware`), its own agent and decision
schedule, and, when SUMO runs, the traffic light it drives; they share the Testbed's one SimPy environment,
clock and event log. A failure on one controller's link times that controller out and leaves the others
running: nothing here reaches across intersections.

How outputs name an intersection (:func:`hils.protocol.scenario.labels`): by its name in a run of several (every
record's
``intersection``, ``J2 north`` in the summary, ``J2:`` in a message); a run of one names none, and writes
what the single-controller run always wrote.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Generator
from typing import Any

import simpy

from hils.agents.builtin import Agent, Observation
from hils.control.actions import ActionType
from hils.control.manager import State
from hils.protocol.config import IntersectionConfig
from hils.protocol.timegrid import Grid
from hils.report.summary import Tally
from hils.run.detectors import DetectorFeed
from hils.shell.events import EventLog, Kind, TaggedLog
from hils.shell.middleware import Middleware
from hils.shell.transport import Transport

__all__ = ["Intersection"]

log = logging.getLogger(__name__)


class Intersection:
    """One intersection's controller in a run, and everything that acts on it alone.

    ``name``: its traffic light's SUMO id (``C`` for a single intersection); ``label``: how outputs name it
    (:func:`hils.protocol.scenario.labels`); ``signals``: what it shows in the simulation (a
    :class:`hils.sim.sumo.Light`), or None
    without SUMO."""

    def __init__(self, name: str, label: str | None, config: IntersectionConfig, target: Any, transport: Transport,
                 middleware: Middleware, events: EventLog | TaggedLog, tally: Tally) -> None:
        self.name = name
        self.label = label
        self.config = config
        self.target = target
        self.transport = transport
        self.middleware = middleware
        self.events = events
        self.tally = tally
        self.agent: Agent | None = None
        self.signals: Any = None
        self.detector_feed: DetectorFeed | None = None
        self.traffic_samples: list[tuple[float, dict[str, int]]] = []
        # Its own decision schedule: asked now (``due``), or when ``deadline`` passes or one of ``waits`` fires.
        self.due = True
        self.deadline: float | None = None
        self.waits: list[simpy.Event] = []

    @property
    def env(self) -> simpy.Environment:
        return self.middleware.env

    @property
    def state(self) -> State | None:
        return self.middleware.state

    def named(self, message: str) -> str:
        """``message`` as said of this intersection (``J2: ...`` in a run of several)."""
        return f"{self.label}: {message}" if self.label else message

    def observe(self) -> Observation:
        """What this intersection's agent sees now."""
        mw = self.middleware
        traffic = self.signals.traffic_state() if self.signals is not None else None
        return Observation(mw.env.now, mw.cache.state, traffic, mw.next_pair, mw.state)

    def refusals(self) -> list[str]:
        """The start-up checks' refusals (warnings are logged here)."""
        mw = self.middleware
        for line in mw.verdict.warnings:
            log.warning("%s", line)
        return ([mw.startup_error] if mw.startup_error else []) + list(mw.verdict.refusals)

    def decision(self, action_type: ActionType) -> tuple[float | None, list[simpy.Event]]:
        """When this intersection next wants a decision: a delay from now (or None) and the events that end the
        wait earlier (the manager entering TIMEOUT, a served green ending)."""
        mw, params = self.middleware, self.config.middleware
        timeout_entered = mw.entering(State.TIMEOUT)
        if action_type is not ActionType.DURATION:
            return params.control_interval, [timeout_entered]
        if mw.state is State.ON_HOLD:
            return None, [mw.entering(State.IDLE), timeout_entered]  # the prescribed green is being served
        if mw.state in (State.TIMEOUT, State.PREEMPTED):  # asked again when commanding resumes, if not before
            return params.control_interval, [mw.entering(State.IDLE)]
        return params.sumo_step, []  # nothing to serve: do not ask again at the same instant

    def schedule(self, action_type: ActionType) -> None:
        """Start the wait for this intersection's next decision point, from now."""
        delay, self.waits = self.decision(action_type)
        self.deadline = None if delay is None else self.env.now + delay

    def at_decision(self) -> bool:
        """True when the wait :meth:`schedule` started is over: its deadline reached, or a wait event fired."""
        return ((self.deadline is not None and self.env.now >= self.deadline - 1e-9)
                or any(ev.triggered for ev in self.waits))

    def info(self, action_id: int | None, acted: bool, dropped: bool, timed_out: bool) -> dict[str, Any]:
        mw = self.middleware
        return {"t": mw.env.now, "action_id": action_id, "acted": acted, "dropped": dropped,
                "state": mw.state.value, "timeout": timed_out,
                "timeout_reason": mw.manager.timeout_reason.value if mw.manager.timeout_reason else None}

    # --- processes ---------------------------------------------------------------------------------

    def sample_traffic(self, ended: Callable[[], bool], period: float = 5.0) -> Generator[simpy.Event, Any, None]:
        """Queue per approach every ``period`` s, for the queue plot."""
        phases = self.config.phases
        env = self.env
        grid, k = Grid(env.now, period), 0
        while not ended():
            k += 1
            yield env.timeout(grid.delay(k, env.now))
            per_approach: dict[str, int] = {}
            for p, queue in self.signals.queues().items():
                name = phases[p].approach or f"phase {p}"
                per_approach[name] = per_approach.get(name, 0) + queue
            self.traffic_samples.append((env.now, per_approach))
            self.events.emit(Kind.QUEUES, queues=per_approach)
