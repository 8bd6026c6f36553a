"""Fault models: SimPy components that wrap the real parts of a run without changing them.

Rules of this file
------------------
- A fault never edits the middleware, the emulator or the transport. It sits
  between two parts (a transport around the real transport, a surface around
  the emulator's MIB view, an agent around the real agent, a cost function
  around the run's step cost) or drives a public knob of one of them
  (``Middleware.keepalive_enabled``, ``Controller.reset``).
- Every fault counts how often it actually fired (:attr:`Fault.fired`) and
  when it first did, so that a scenario cannot pass because its fault never
  happened, and detection times are measured from the fault's first effect.
- Everything random draws from the fault's own ``random.Random(seed)``: a
  scenario is reproducible from its seed, and adding a fault does not change
  the draws of another.
- Transport faults are judged when a request is sent: a request belongs to a
  window when it is sent inside it, and its answer's fate (lost, delayed) is
  drawn at the same moment.

Theory of operation
-------------------
:class:`FaultTarget` builds the in-process emulator like
:class:`emulator.inprocess.VirtualTarget` does and puts the fault wrappers in
the path: ``middleware -> FaultyTransport -> LocalTransport -> [StuckSurface]
-> MibView -> Controller``. Each fault is told about the target when it is
built (:meth:`Fault.on_target`, where transport faults register with the
:class:`FaultyTransport`) and about the run before it starts
(:meth:`Fault.on_run`, where agent and keepalive faults wrap or drive the
parts of the intersection they are placed on, and step-cost faults the run's one
simulation). In a run of several controllers each controller has its own
target with the faults placed on it, so a fault on one controller's link
leaves the others alone. :class:`IndicationMonitor` samples the controller every
tick so that scenarios can check what it showed, whatever the middleware saw.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import simpy

from emulator.agent.mib import MibView
from emulator.inprocess import VirtualTarget
from emulator.model.controller import TICK, Controller
from hils.agents.builtin import Agent, Observation
from hils.control.actions import ActionType
from hils.control.manager import State
from hils.protocol.config import IntersectionConfig
from hils.protocol.conflict import Conflict, conflicts, first_conflict
from hils.protocol.ntcip import (
    CONTROL_TABLE,
    PREEMPT_CONTROL_STATE,
    ControlColumn,
    ErrorStatus,
    Oid,
    SnmpError,
    UnitControlStatus,
    UnitFlashStatus,
)
from hils.protocol.timegrid import Grid
from hils.run.intersection import Intersection
from hils.run.testbed import Testbed
from hils.shell.fastpath import Foresight, StepCost
from hils.shell.middleware import Middleware
from hils.shell.transport import CommunicationTimeout, LocalTransport, ObjectSurface, Transport, Value, VarBind

__all__ = [
    "ActionBurst",
    "ActionsDuringTimeout",
    "BadActionKind",
    "BadActions",
    "DatagramLoss",
    "Direction",
    "ErrorResponses",
    "Fault",
    "FaultTarget",
    "FaultyTransport",
    "IndicationMonitor",
    "KeepaliveSuppressed",
    "Op",
    "PreemptCall",
    "Reboot",
    "ResponseDelay",
    "SlowSteps",
    "StuckController",
    "StuckSurface",
    "TransportFault",
    "Window",
    "WrappedAgent",
    "bad_value",
    "error_status",
    "status_name",
]


@dataclass(frozen=True, slots=True)
class Window:
    """A half-open interval of simulation time [start, end) in seconds."""

    start: float = 0.0
    end: float = math.inf

    def contains(self, t: float) -> bool:
        return self.start <= t < self.end

    def describe(self) -> str:
        if math.isinf(self.end):
            return f"from {self.start:g} s" if self.start else "throughout"
        return f"in [{self.start:g}, {self.end:g}) s"


class Op(StrEnum):
    GET = "get"
    SET = "set"


class Direction(StrEnum):
    """Which datagrams of an exchange a loss applies to."""

    REQUEST = "request"  # lost on the way to the controller: it never sees the request
    RESPONSE = "response"  # lost on the way back: the controller acted, the answer is lost
    BOTH = "both"  # each datagram independently


ALL_OPS = frozenset(Op)


class Fault:
    """A named fault active in a window, optionally limited to ``count`` firings."""

    kind = "fault"

    def __init__(self, name: str, *, window: Window = Window(), count: int | None = None) -> None:
        self.name = name
        self.window = window
        self.limit = count
        self.fired = 0
        self.first_fired: float | None = None
        self.details: dict[str, int] = {}

    def active(self, now: float) -> bool:
        return self.window.contains(now) and (self.limit is None or self.fired < self.limit)

    def fire(self, now: float) -> None:
        self.fired += 1
        if self.first_fired is None:
            self.first_fired = now

    def note(self, key: str) -> None:
        """Count a secondary effect (shown in the report's details)."""
        self.details[key] = self.details.get(key, 0) + 1

    def on_target(self, target: FaultTarget) -> None:
        """Called once the target is built (transport faults register here)."""

    def wrap_surface(self, surface: ObjectSurface, env: simpy.Environment) -> ObjectSurface:
        """The object surface the transport should reach; unchanged unless the fault sits there."""
        return surface

    def on_run(self, run: Testbed, intersection: Intersection | None) -> None:
        """Called before the run starts (agent, step-cost and middleware faults install here).

        ``intersection``: the controller the fault is placed on (its agent and middleware); None for a fault
        of the whole run (slow simulation steps) in a run of several controllers."""

    def describe(self) -> str:
        """What the fault does, when, and how often at most (for reports)."""
        return f"{self.kind} {self.scope()}"

    def scope(self) -> str:
        limit = "" if self.limit is None else f", at most {self.limit} times"
        return f"{self.window.describe()}{limit}"


# --- the transport ------------------------------------------------------------------------------


class TransportFault(Fault):
    """A fault judged by :class:`FaultyTransport` for every request; the defaults do nothing."""

    def __init__(self, name: str, *, ops: frozenset[Op] = ALL_OPS, window: Window = Window(),
                 count: int | None = None) -> None:
        super().__init__(name, window=window, count=count)
        self.ops = ops

    def matches(self, op: Op, now: float) -> bool:
        return op in self.ops and self.active(now)

    def on_target(self, target: FaultTarget) -> None:
        target.transport.faults.append(self)

    def drops_request(self, op: Op, now: float) -> bool:
        return False

    def error_for(self, op: Op, now: float) -> SnmpError | None:
        return None

    def drops_response(self, op: Op, now: float) -> bool:
        return False

    def response_delay(self, op: Op, now: float) -> float:
        return 0.0

    def scope(self) -> str:
        return f"{'+'.join(sorted(self.ops))} {super().scope()}"


class FaultyTransport:
    """A :class:`hils.shell.transport.Transport` around another one, with transport faults in the path.

    A dropped request is never passed on: the controller does not see it and
    the request fails at tau_udp. A dropped response is passed on (the
    controller acts on it) but its answer is discarded, so the request fails
    at tau_udp too. A delayed answer arrives ``delay`` later than the real one;
    if that is at or after tau_udp the request has already failed and the late
    answer is discarded. An injected error answers at once with an SNMP error
    and the controller never sees the request, as an agent refusing it would.
    A request no fault touches is the inner transport's own event.

    On virtual time's fast path (:mod:`hils.shell.fastpath`) it is a foresight when the inner transport has one
    (``foresight``): it offers the inner change feed while no fault may act on a request, and none while one may
    (every request then goes out, for the fault to judge): a poller or read-back asleep meanwhile is woken when the
    next fault's window opens.
    """

    def __init__(self, env: simpy.Environment, inner: Transport, *, tau_udp: float,
                 faults: Sequence[TransportFault] = (), error_latency: float = 0.002,
                 foresight: Foresight | None = None) -> None:
        self.env = env
        self.inner = inner
        self.inner_foresight = foresight
        self.tau_udp = tau_udp
        self.faults: list[TransportFault] = list(faults)
        self.error_latency = error_latency
        self.late_discarded = 0  # answers that came after the request had failed

    # --- the change feed: the inner one's, while no fault may act -------------------------------------

    @property
    def change_feed(self) -> FaultyTransport | None:
        now = self.env.now
        inner = self.inner_foresight
        if inner is None or inner.change_feed is None or any(f.active(now) for f in self.faults):
            return None
        return self

    @property
    def version(self) -> int:
        return self.inner_foresight.change_feed.version

    @property
    def controls(self) -> int:
        return self.inner_foresight.change_feed.controls

    def changed(self) -> simpy.Event:
        return self._or_next_window(self.inner_foresight.change_feed.changed())

    def controls_changed(self) -> simpy.Event:
        return self._or_next_window(self.inner_foresight.change_feed.controls_changed())

    def bump(self) -> None:
        self.inner_foresight.change_feed.bump()

    def _or_next_window(self, event: simpy.Event) -> simpy.Event:
        """``event``, or the opening of the next fault's window if that comes first."""
        now = self.env.now
        opening = min((f.window.start for f in self.faults
                       if f.window.start > now and (f.limit is None or f.fired < f.limit)), default=None)
        return event if opening is None else self.env.any_of([event, self.env.timeout(opening - now)])

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        return self._request(Op.GET, lambda: self.inner.get(oids))

    def set(self, varbinds: Sequence[VarBind]) -> simpy.Event:
        return self._request(Op.SET, lambda: self.inner.set(varbinds))

    def close(self) -> None:
        self.inner.close()

    def _request(self, op: Op, send: Callable[[], simpy.Event]) -> simpy.Event:
        now = self.env.now
        faults = self.faults
        if any(f.drops_request(op, now) for f in faults):
            return self._unanswered()
        error = next((e for f in faults if (e := f.error_for(op, now)) is not None), None)
        if error is not None:
            refused = self.env.event()
            self.env.timeout(self.error_latency).callbacks.append(lambda _ev: refused.fail(error))
            return refused
        lost = any(f.drops_response(op, now) for f in faults)
        delay = sum(f.response_delay(op, now) for f in faults)
        answer = send()
        if not lost and delay <= 0.0:
            return answer
        done = self._unanswered()

        def deliver(ev: simpy.Event) -> None:
            if done.triggered:
                self.late_discarded += 1
            elif ev.ok:
                done.succeed(ev.value)
            else:
                done.fail(ev.value)

        def answered(ev: simpy.Event) -> None:
            ev.defused = True  # its outcome is handed on (or lost) through ``done``
            if lost:
                return
            self.env.timeout(delay).callbacks.append(lambda _t: deliver(ev))

        answer.callbacks.append(answered)
        return done

    def _unanswered(self) -> simpy.Event:
        """An event that fails at tau_udp unless something triggers it first."""
        done = self.env.event()

        def deadline(_ev: simpy.Event) -> None:
            if not done.triggered:
                done.fail(CommunicationTimeout(f"no answer within {self.tau_udp} s"))

        self.env.timeout(self.tau_udp).callbacks.append(deadline)
        return done


class DatagramLoss(TransportFault):
    """Datagrams lost at random with ``probability`` (1: all of them), in bursts of ``burst``.

    A burst starts when a datagram is lost at random; the next ``burst - 1``
    matching datagrams are lost with it.
    """

    kind = "drop"

    def __init__(self, name: str, *, direction: Direction = Direction.BOTH, probability: float = 1.0,
                 burst: int = 1, seed: int = 0, ops: frozenset[Op] = ALL_OPS, window: Window = Window(),
                 count: int | None = None) -> None:
        super().__init__(name, ops=ops, window=window, count=count)
        self.direction = direction
        self.probability = probability
        self.burst = burst
        self._rng = random.Random(seed)
        self._burst_left = 0

    def drops_request(self, op: Op, now: float) -> bool:
        return self.direction is not Direction.RESPONSE and self._lose(op, now, "requests_lost")

    def drops_response(self, op: Op, now: float) -> bool:
        return self.direction is not Direction.REQUEST and self._lose(op, now, "responses_lost")

    def _lose(self, op: Op, now: float, what: str) -> bool:
        if not self.matches(op, now):
            return False
        if self._burst_left > 0:
            self._burst_left -= 1
        elif self.probability >= 1.0 or self._rng.random() < self.probability:
            self._burst_left = self.burst - 1
        else:
            return False
        self.fire(now)
        self.note(what)
        return True

    def describe(self) -> str:
        burst = f" in bursts of {self.burst}" if self.burst > 1 else ""
        return f"{self.direction} datagrams lost, p={self.probability:g}{burst}, {self.scope()}"


class ResponseDelay(TransportFault):
    """Answers delayed by ``delay`` +/- ``jitter`` s (uniform), for a ``probability`` of requests."""

    kind = "delay"

    def __init__(self, name: str, *, delay: float, jitter: float = 0.0, probability: float = 1.0, seed: int = 0,
                 ops: frozenset[Op] = ALL_OPS, window: Window = Window(), count: int | None = None) -> None:
        super().__init__(name, ops=ops, window=window, count=count)
        self.delay = delay
        self.jitter = jitter
        self.probability = probability
        self._rng = random.Random(seed)

    def response_delay(self, op: Op, now: float) -> float:
        if not self.matches(op, now):
            return 0.0
        if self.probability < 1.0 and self._rng.random() >= self.probability:
            return 0.0
        extra = self.delay if self.jitter <= 0.0 else max(0.0, self.delay + self._rng.uniform(-self.jitter,
                                                                                               self.jitter))
        self.fire(now)
        return extra

    def describe(self) -> str:
        return f"answers {self.delay:g} +/- {self.jitter:g} s late, p={self.probability:g}, {self.scope()}"


_ERROR_NAMES = {"".join([w.lower() if i == 0 else w.capitalize() for i, w in enumerate(s.name.split("_"))]): s
                for s in ErrorStatus if s is not ErrorStatus.NO_ERROR}


def status_name(status: ErrorStatus) -> str:
    """The RFC 3416 name of an error status (``genErr``)."""
    return next(name for name, s in _ERROR_NAMES.items() if s is status)


def error_status(name: str) -> ErrorStatus:
    """An SNMP error status from its RFC 3416 name (``genErr``) or enum name (``GEN_ERR``)."""
    if name in _ERROR_NAMES:
        return _ERROR_NAMES[name]
    try:
        status = ErrorStatus[name.upper()]
    except KeyError:
        raise ValueError(f"unknown SNMP error status {name!r}; allowed: {', '.join(_ERROR_NAMES)}") from None
    if status is ErrorStatus.NO_ERROR:
        raise ValueError("noError is not an error response")
    return status


class ErrorResponses(TransportFault):
    """The controller answers with an SNMP error (genErr, noSuchName...) instead of acting."""

    kind = "snmp_error"

    def __init__(self, name: str, *, status: ErrorStatus = ErrorStatus.GEN_ERR, probability: float = 1.0,
                 seed: int = 0, ops: frozenset[Op] = ALL_OPS, window: Window = Window(),
                 count: int | None = None) -> None:
        super().__init__(name, ops=ops, window=window, count=count)
        self.status = status
        self.probability = probability
        self._rng = random.Random(seed)

    def error_for(self, op: Op, now: float) -> SnmpError | None:
        if not self.matches(op, now):
            return None
        if self.probability < 1.0 and self._rng.random() >= self.probability:
            return None
        self.fire(now)
        return SnmpError(self.status, 1, f"injected by fault {self.name!r}")

    def describe(self) -> str:
        return f"{status_name(self.status)} answers, p={self.probability:g}, {self.scope()}"


# --- the controller ------------------------------------------------------------------------------

_VEH_CALL_PREFIX = CONTROL_TABLE[ControlColumn.VEH_CALL].prefix


class StuckSurface:
    """An object surface that acknowledges VehCall SETs but ignores them while its fault is active."""

    def __init__(self, inner: ObjectSurface, fault: StuckController, clock: Callable[[], float]) -> None:
        self.inner = inner
        self.fault = fault
        self.clock = clock

    def get_many(self, oids: Sequence[Oid]) -> tuple[Value, ...]:
        return self.inner.get_many(oids)

    def set_many(self, varbinds: Sequence[VarBind]) -> None:
        now = self.clock()
        calls = [vb for vb in varbinds if tuple(vb[0][:len(_VEH_CALL_PREFIX)]) == _VEH_CALL_PREFIX]
        if not calls or not self.fault.active(now):
            self.inner.set_many(varbinds)
            return
        self.fault.fire(now)
        # A stuck controller drops the calls silently, and so does not restart its backup timer
        # for them either; other objects in the same PDU still take effect.
        rest = [vb for vb in varbinds if vb not in calls]
        if rest:
            self.inner.set_many(rest)


class StuckController(Fault):
    """The controller acknowledges phase calls but ignores them: a transition that never comes."""

    kind = "stuck"

    def wrap_surface(self, surface: ObjectSurface, env: simpy.Environment) -> ObjectSurface:
        return StuckSurface(surface, self, lambda: env.now)

    def describe(self) -> str:
        return f"VehCall SETs acknowledged and ignored {self.scope()}"


class Reboot(TransportFault):
    """The controller goes silent at ``at`` for ``silent_for`` s, then powers up again.

    While silent no request reaches it (each fails at tau_udp). Power-up is
    :meth:`emulator.model.controller.Controller.reset`: start-up intervals, control
    objects cleared, not under system control; its tick restarts from there.
    """

    kind = "reboot"

    def __init__(self, name: str, *, at: float, silent_for: float) -> None:
        super().__init__(name, window=Window(at, at + silent_for))
        self.at = at
        self.silent_for = silent_for

    def on_target(self, target: FaultTarget) -> None:
        super().on_target(target)
        target.env.process(self._cycle(target))

    def drops_request(self, op: Op, now: float) -> bool:
        if self.window.contains(now):
            self.note("requests_unanswered")
            return True
        return False

    def _cycle(self, target: FaultTarget) -> Generator[simpy.Event, Any, None]:
        env = target.env
        yield env.timeout(self.at)
        self.fire(env.now)
        yield env.timeout(self.silent_for)
        target.power_cycle()
        self.note("powered_up")

    def describe(self) -> str:
        return f"silent from {self.at:g} s for {self.silent_for:g} s, then power-up"


# --- the simulation ---------------------------------------------------------------------------------


class SlowSteps(Fault):
    """Simulation steps that cost ``cost`` s (more than the step length), from ``start`` on.

    ``count`` slow steps in runs of ``consecutive``, each run followed by ``gap``
    steps on time: ``consecutive = 1, gap = 3`` gives isolated slow steps,
    ``consecutive = count`` one run of them.
    """

    kind = "slow_steps"

    def __init__(self, name: str, *, start: float, count: int, cost: float, consecutive: int = 1,
                 gap: int = 1) -> None:
        super().__init__(name, window=Window(start), count=count)
        self.cost = cost
        self.consecutive = consecutive
        self.gap = gap
        self._offset = 0  # steps seen since the window opened

    def on_run(self, run: Testbed, intersection: Intersection | None) -> None:
        run.step_cost = self.wrap(run.step_cost, lambda: run.env.now)

    def wrap(self, inner: StepCost, clock: Callable[[], float]) -> StepCost:
        return _SlowCost(self, inner, clock)

    def judge(self, took: float, now: float) -> float:
        """What a step that took ``took`` s at ``now`` costs with this fault on it."""
        if not self.active(now):
            return took
        i = self._offset
        self._offset += 1
        if i % (self.consecutive + self.gap) < self.consecutive:
            self.fire(now)
            return max(took, self.cost)
        return took

    def quiet_until(self, now: float) -> float:
        """The time before which this fault makes no step cost: its window's start, or forever once spent."""
        if self.limit is not None and self.fired >= self.limit:
            return math.inf
        return self.window.start if now < self.window.start else now

    def describe(self) -> str:
        return (f"{self.limit} steps costing {self.cost:g} s, in runs of {self.consecutive} "
                f"with {self.gap} on time between, from {self.window.start:g} s")


class _SlowCost:
    """A step cost with a :class:`SlowSteps` fault on it: the fault judges every step while it is active, and
    says so to the fast path (:meth:`free_until`), which steps SUMO in stretches before and after."""

    def __init__(self, fault: SlowSteps, inner: StepCost, clock: Callable[[], float]) -> None:
        self.fault, self.inner, self.clock = fault, inner, clock

    def __call__(self, step: Callable[[], Any]) -> float:
        took = self.inner(step)
        return self.fault.judge(took, self.clock())

    def free_until(self, now: float) -> float:
        return min(self.fault.quiet_until(now), self.inner.free_until(now))


# --- the agent ------------------------------------------------------------------------------------------


class BadActionKind(StrEnum):
    CONFLICT = "conflict"  # a pair of phases that must never show green together
    UNKNOWN_PHASE = "unknown_phase"  # a phase the intersection does not have
    NOT_IN_SET = "not_in_set"  # a compatible pair outside the configured action set
    NAN = "nan"  # NaN where a number is due
    OUT_OF_RANGE = "out_of_range"  # switch 2, duration 1.5
    WRONG_TYPE = "wrong_type"  # a string


# Which bad values each action type can be given.
BAD_KINDS: dict[ActionType, frozenset[BadActionKind]] = {
    ActionType.SELECTION: frozenset({BadActionKind.CONFLICT, BadActionKind.UNKNOWN_PHASE, BadActionKind.NOT_IN_SET,
                                     BadActionKind.NAN, BadActionKind.WRONG_TYPE}),
    ActionType.SWITCH: frozenset({BadActionKind.NAN, BadActionKind.OUT_OF_RANGE, BadActionKind.WRONG_TYPE}),
    ActionType.DURATION: frozenset({BadActionKind.NAN, BadActionKind.OUT_OF_RANGE, BadActionKind.WRONG_TYPE}),
    ActionType.CONTROL: frozenset({BadActionKind.CONFLICT, BadActionKind.UNKNOWN_PHASE, BadActionKind.NAN,
                                   BadActionKind.WRONG_TYPE}),
}


def bad_value(kind: BadActionKind, action_type: ActionType, config: IntersectionConfig) -> Any:
    """An action value of ``kind`` for ``action_type`` that the converter must refuse."""
    if kind not in BAD_KINDS[action_type]:
        raise ValueError(f"a {action_type.value} agent cannot issue a {kind.value} action; allowed: "
                         f"{', '.join(sorted(BAD_KINDS[action_type]))}")
    ring1 = [p for p in config.phase_numbers if config.ring_of(p) == 1]
    ring2 = [p for p in config.phase_numbers if config.ring_of(p) == 2]
    if action_type is ActionType.CONTROL:  # a step that breaks a rule of hils.control.phase_control
        return {BadActionKind.CONFLICT: {"hold": [ring1[0]], "forceoff": [ring1[0]]},
                BadActionKind.UNKNOWN_PHASE: {"hold": [max(config.phases) + 1]},
                BadActionKind.NAN: [{"commandType": "hold", "commandPhase": ring1[0], "commandStartTime": math.nan,
                                     "commandEndTime": 5.0}],
                BadActionKind.WRONG_TYPE: "advance"}[kind]
    match kind:
        case BadActionKind.CONFLICT:
            return next([a, b] for a in ring1 for b in ring2 if first_conflict(config.permissives, (a, b)))
        case BadActionKind.UNKNOWN_PHASE:
            return [ring1[0], max(config.phases) + 1]
        case BadActionKind.NOT_IN_SET:
            pairs = set(config.pairs)
            return next([a, b] for a in ring1 for b in ring2
                        if first_conflict(config.permissives, (a, b)) is None and (a, b) not in pairs)
        case BadActionKind.NAN:
            return [math.nan, math.nan] if action_type is ActionType.SELECTION else math.nan
        case BadActionKind.OUT_OF_RANGE:
            return 2 if action_type is ActionType.SWITCH else 1.5
        case BadActionKind.WRONG_TYPE:
            return "advance"


class WrappedAgent:
    """An agent whose ``act`` goes through a fault's hook, which may call the real agent or not."""

    def __init__(self, inner: Agent, hook: Callable[[Agent, Observation], Any]) -> None:
        self.inner = inner
        self.action_type = inner.action_type
        self._hook = hook

    def act(self, observation: Observation) -> Any:
        return self._hook(self.inner, observation)


class BadActions(Fault):
    """The agent returns invalid actions instead of its own while active."""

    kind = "bad_actions"

    def __init__(self, name: str, *, action: BadActionKind, window: Window = Window(),
                 count: int | None = None) -> None:
        super().__init__(name, window=window, count=count)
        self.action = action

    def on_run(self, run: Testbed, intersection: Intersection) -> None:
        value = bad_value(self.action, run.action_type, intersection.config)

        def act(inner: Agent, observation: Observation) -> Any:
            now = intersection.env.now
            if self.active(now):
                self.fire(now)
                return value
            return inner.act(observation)

        intersection.agent = WrappedAgent(intersection.agent, act)

    def describe(self) -> str:
        return f"{self.action} actions {self.scope()}"


class ActionBurst(Fault):
    """Right after each of the agent's actions, ``size`` more actions while the command is ON_HOLD.

    Fires once per extra action actually submitted while ON_HOLD; after an
    action that left the manager IDLE (a keep) no burst is sent.
    """

    kind = "action_burst"

    def __init__(self, name: str, *, size: int, window: Window = Window(), count: int | None = None) -> None:
        super().__init__(name, window=window, count=count)
        self.size = size

    def on_run(self, run: Testbed, intersection: Intersection) -> None:
        env, mw = intersection.env, intersection.middleware

        def burst(inner: Agent) -> Generator[simpy.Event, Any, None]:
            # Started from act(), this process runs once the agent loop has submitted the action.
            yield env.timeout(0)
            for _ in range(self.size):
                now = env.now
                if mw.state is not State.ON_HOLD or not self.active(now):
                    return
                self.fire(now)
                mw.submit(inner.act(intersection.observe()))

        def act(inner: Agent, observation: Observation) -> Any:
            value = inner.act(observation)
            if self.active(env.now):
                env.process(burst(inner))
            return value

        intersection.agent = WrappedAgent(intersection.agent, act)

    def describe(self) -> str:
        return f"{self.size} extra actions after each action {self.scope()}"


class ActionsDuringTimeout(Fault):
    """The agent keeps acting at ``rate_hz`` while the middleware is in TIMEOUT."""

    kind = "actions_during_timeout"

    def __init__(self, name: str, *, rate_hz: float, window: Window = Window(), count: int | None = None) -> None:
        super().__init__(name, window=window, count=count)
        self.period = 1.0 / rate_hz

    def on_run(self, run: Testbed, intersection: Intersection) -> None:
        intersection.env.process(self._act(run, intersection))

    def _act(self, run: Testbed, intersection: Intersection) -> Generator[simpy.Event, Any, None]:
        env, mw = intersection.env, intersection.middleware
        grid, k = Grid(self.window.start, self.period), 0
        yield env.timeout(grid.delay(k, env.now))
        while env.now < self.window.end:
            if mw.timeout_flag and self.active(env.now) and not run.ended:
                self.fire(env.now)
                mw.submit(intersection.agent.act(intersection.observe()))
            k += 1
            yield env.timeout(grid.delay(k, env.now))

    def describe(self) -> str:
        return f"actions every {self.period:g} s while in TIMEOUT {self.scope()}"


# --- the middleware ----------------------------------------------------------------------------------------


class KeepaliveSuppressed(Fault):
    """The middleware's keepalive switched off for a window, so the controller's backup time can run out.

    Fires once for every keepalive period that passes with a call placed and
    no SET of it: each refresh the middleware would have sent.
    """

    kind = "keepalive_off"

    def on_run(self, run: Testbed, intersection: Intersection) -> None:
        intersection.env.process(self._suppress(run, intersection.middleware))

    def _suppress(self, run: Testbed, mw: Middleware) -> Generator[simpy.Event, Any, None]:
        env = run.env
        end = self.window.end
        yield env.timeout(self.window.start)
        mw.keepalive_enabled = False
        while True:
            seen, period = mw.last_set, mw.keepalive_period
            if math.isinf(seen):  # nothing SET yet: no refresh due
                wake = env.now + period
                yield env.timeout(min(wake, end) - env.now)
                if wake >= end:
                    break
                continue
            # The refreshes the keepalive would have sent fall every period after the last SET.
            refreshes = Grid(seen, period)
            due = refreshes.at(refreshes.first_after(env.now))
            yield env.timeout(max(0.0, min(due, end) - env.now))
            if due >= end:
                break
            if mw.last_set == seen and mw.call and not mw.timeout_flag:
                self.fire(env.now)
        if not run.ended:
            mw.keepalive_enabled = True

    def describe(self) -> str:
        return f"keepalive off {self.window.describe()}"


# --- the controller's own operation ------------------------------------------------------------------------


class PreemptCall(Fault):
    """Preempt ``preempt`` called at the controller ``after`` s into the first commanded transition (the middleware
    ON_HOLD) at or after ``start``, and released ``hold`` s later.

    The call is a SET of preemptControlState to 1 (then 0) at the controller itself, as a central system
    calling the preempt or the cabinet's preempt input would: it does not pass the middleware's link.
    """

    kind = "preempt"

    def __init__(self, name: str, *, preempt: int, start: float, after: float, hold: float) -> None:
        super().__init__(name, window=Window(start, math.inf), count=1)
        self.preempt = preempt
        self.after = after
        self.hold = hold
        self._target: FaultTarget | None = None

    def on_target(self, target: FaultTarget) -> None:
        self._target = target

    def on_run(self, run: Testbed, intersection: Intersection) -> None:
        intersection.env.process(self._call(intersection.middleware))

    def _call(self, mw: Middleware) -> Generator[simpy.Event, Any, None]:
        env, surface, oid = mw.env, self._target.base.surface, PREEMPT_CONTROL_STATE.instance(self.preempt)
        yield env.timeout(self.window.start)
        yield mw.wait_for(State.ON_HOLD)
        yield env.timeout(self.after)
        self.fire(env.now)
        surface.set_many([(oid, 1)])
        yield env.timeout(self.hold)
        surface.set_many([(oid, 0)])
        self.note("released")

    def describe(self) -> str:
        return (f"preempt {self.preempt} called {self.after:g} s into the first commanded transition from "
                f"{self.window.start:g} s, for {self.hold:g} s")


# --- the target and the monitor ---------------------------------------------------------------------------


class FaultTarget:
    """The in-process emulator with the faults' wrappers in the request path.

    Same parts as :class:`emulator.inprocess.VirtualTarget` (``controller``,
    ``mib``), and ``transport`` is a :class:`FaultyTransport` around the
    emulator's in-process transport.
    """

    def __init__(self, env: simpy.Environment, config: IntersectionConfig, *, seed: int = 0,
                 faults: Sequence[Fault] = (), fast_path: bool = True, hires: bool = True) -> None:
        self.env = env
        self.config = config
        self.base = VirtualTarget(env, config, seed=seed, fast_path=fast_path, hires=hires)
        self.controller: Controller = self.base.controller
        self.mib: MibView = self.base.mib
        surface: ObjectSurface = self.base.surface  # writes go through the controller's clock
        for fault in faults:
            surface = fault.wrap_surface(surface, env)
        inner = LocalTransport(env, surface, tau_udp=config.middleware.tau_udp, get_latency=self.base.get_latency,
                               set_latency=self.base.set_latency, seed=seed, change_feed=self.base.change_feed)
        self.transport = FaultyTransport(env, inner, tau_udp=config.middleware.tau_udp,
                                         foresight=inner if self.base.change_feed is not None else None)
        # The fast path's foresight (:class:`hils.shell.fastpath.Foresight`): the faulty transport's own, which knows
        # when a fault may act.
        self.foresight = self.transport
        for fault in faults:
            fault.on_target(self)

    def power_cycle(self) -> None:
        """Power the controller down and up: reset it and restart its tick from now (its new tick grid
        starts at power-up, wherever that falls against the middleware's times)."""
        self.base.power_cycle()


@dataclass(frozen=True, slots=True)
class ShownConflict:
    t: float
    conflict: Conflict  # two phases, or an overlap and a phase


class IndicationMonitor:
    """Samples the controller every tick: conflicting indications (phases and overlaps, by the one conflict check
    of :mod:`hils.protocol.conflict`, every conflict of a sample), MMU flash, control status."""

    def __init__(self, env: simpy.Environment, controller: Controller, config: IntersectionConfig) -> None:
        self.env = env
        self.controller = controller
        self.config = config
        self.samples = 0
        self.conflicts: list[ShownConflict] = []
        self.mmu_flash_at: float | None = None
        self.status_first_seen: dict[UnitControlStatus, float] = {}
        self.controls: list[tuple[float, dict[ControlColumn, frozenset[int]]]] = []  # the six objects, at each change
        env.process(self._sample())

    def _sample(self) -> Generator[simpy.Event, Any, None]:
        # Once per tick: a display lasts at least one tick, so none is missed.
        grid = Grid(self.env.now + TICK / 2, TICK)
        k = 0
        while True:
            yield self.env.timeout(grid.delay(k, self.env.now))
            k += 1
            self._check()

    def _check(self) -> None:
        c = self.controller
        self.samples += 1
        self.status_first_seen.setdefault(c.control_status, self.env.now)
        if not self.controls or self.controls[-1][1] != c.control:
            self.controls.append((self.env.now, dict(c.control)))
        if c.flash_status is UnitFlashStatus.MMU and self.mmu_flash_at is None:
            self.mmu_flash_at = self.env.now
        lit = conflicts(self.config.permissives, c.greens | c.yellows, c.overlap_greens | c.overlap_yellows)
        self.conflicts.extend(ShownConflict(self.env.now, conflict) for conflict in lit)
