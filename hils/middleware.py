"""The middleware: the manager's SimPy shell, the poller, keepalive, drift and recovery.

The manager (:mod:`hils.manager`) decides; this module does. It turns agent
actions into manager events, carries out the effects the manager returns (SET
the call, start timers, halt polling, log), and feeds back timer expiries and
signal observations. It runs unchanged in virtual and wall-clock time: only the
environment's driver and the transport differ.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import simpy

from hils.actions import ActionConverter, ActionError, ActionType, Command
from hils.config import IntersectionConfig
from hils.drift import DriftMonitor
from hils.events import EventLog, Kind
from hils.manager import (
    CommandEnded,
    CommandRequested,
    Dispatch,
    Dropped,
    Effect,
    FailureDetected,
    Manager,
    Recovered,
    RecoveryCompleted,
    SignalObserved,
    Stage,
    StartTimer,
    State,
    TimeoutEntered,
    TimeoutReason,
    TimerExpired,
    Verified,
)
from hils.ntcip import UNIT_BACKUP_TIME, ControlColumn, SnmpError, control_oid, phases_to_groups
from hils.poller import Poller, SignalCache, Snapshot
from hils.transport import CommunicationTimeout, Transport, TransportError

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Submission:
    """What became of an action handed to :meth:`Middleware.submit`."""

    action_id: int
    error: ActionError | None = None  # refused by the converter: nothing was sent
    dropped: bool = False  # converted, but the manager was not IDLE


class Middleware:
    """Everything between the agent and the transport, on one SimPy environment."""

    def __init__(self, env: simpy.Environment, transport: Transport, config: IntersectionConfig,
                 action_type: ActionType | str, events: EventLog) -> None:
        params = config.middleware
        self.env = env
        self.transport = transport
        self.config = config
        self.log = events
        events.bind(lambda: env.now)
        self.manager = Manager(params.tau_trans)
        self.converter = ActionConverter(config, ActionType(action_type))
        self.cache = SignalCache()
        self.poller = Poller(env, transport, self.cache, events, groups=config.groups,
                             rate_hz=params.poll_hz, n_timeout=params.n_timeout,
                             on_failure=lambda why: self._fail(TimeoutReason.COMMUNICATION, why))
        self.drift = DriftMonitor(params.n_drift, events, lambda why: self._fail(TimeoutReason.DRIFT, why))
        # Every poll, not only changes: a command for phases already green is verified by the
        # next poll, which shows no change.
        self.cache.subscribe(self._on_signal, every_poll=True)
        self.keepalive_enabled = True
        self.keepalive_period = params.keepalive_period
        self.call: frozenset[int] = frozenset()  # the VehCall last SET
        self.last_set = float("-inf")
        self.ready = env.event()
        self._entering: dict[State, simpy.Event] = {}  # events of processes waiting for a state
        self._actions = 0

    # --- public API -------------------------------------------------------------------------

    @property
    def state(self) -> State:
        return self.manager.state

    @property
    def timeout_flag(self) -> bool:
        """The system-wide timeout event flag: set in TIMEOUT until recovery."""
        return self.manager.state is State.TIMEOUT

    def start(self) -> simpy.Process:
        """Read the controller, then start polling and the keepalive; ``ready`` fires when done."""
        return self.env.process(self._startup())

    def submit(self, value: Any) -> Submission:
        """An agent's action value, converted and handed to the manager."""
        self._actions += 1
        action_id = self._actions
        self.log.emit(Kind.ACTION_RECEIVED, action_id=action_id, action_type=self.converter.action_type.value,
                      value=_plain(value))
        try:
            command = self.converter.convert(value)
        except ActionError as exc:
            self.log.emit(Kind.ACTION_REFUSED, action_id=action_id, error=type(exc).__name__, reason=exc.reason,
                          message=str(exc))
            return Submission(action_id, error=exc)
        self.log.emit(Kind.ACTION_CONVERTED, action_id=action_id, command=command.phases, green=command.green,
                      keep=command.keep)
        effects = self._feed(CommandRequested(self.env.now, action_id, command))
        return Submission(action_id, dropped=any(isinstance(e, Dropped) for e in effects))

    def observe_step(self, step: float, took: float) -> None:
        """Report one simulation step's cost to drift detection (ignored while in TIMEOUT)."""
        if not self.timeout_flag:
            self.drift.observe(step, took)

    def wait_for(self, state: State) -> simpy.Event:
        """An event that fires when the manager is (or next becomes) in ``state``."""
        if self.manager.state is state:
            ev = self.env.event()
            ev.succeed()
            return ev
        return self.entering(state)

    def entering(self, state: State) -> simpy.Event:
        """An event that fires the next time the manager enters ``state`` (not if it is there now)."""
        return self._entering.setdefault(state, self.env.event())

    def wait_idle(self) -> simpy.Event:
        return self.wait_for(State.IDLE)

    def recover(self) -> simpy.Process:
        """Manual recovery: re-read the controller, align the call with what it shows, return to IDLE."""
        return self.env.process(self._recover())

    def close(self) -> simpy.Process:
        """Clear the calls this run placed."""
        return self.env.process(self._clear())

    # --- processes ----------------------------------------------------------------------------

    def _startup(self) -> Generator[simpy.Event, Any, None]:
        # Like the poller, give up only after n_timeout consecutive failures: one lost datagram
        # at start-up is no reason to halt.
        for attempt in range(1, self.config.middleware.n_timeout + 1):
            try:
                state = yield from self.poller.read_once()
                (backup,) = yield self.transport.get([UNIT_BACKUP_TIME.instance()])
            except (TransportError, SnmpError) as exc:
                self.log.emit(Kind.POLL_FAILED, poll_id=0, error=f"start-up read: {type(exc).__name__}: {exc}",
                              consecutive=attempt)
                if attempt == self.config.middleware.n_timeout:
                    self._fail(TimeoutReason.COMMUNICATION, f"controller unreachable at start-up: {exc}")
                continue
            self.cache.update(state, self.env.now, 0)
            self.converter.sync(state.greens)
            if backup:
                limit = backup / 3.0  # the controller's own backup time rules
                self.keepalive_period = min(self.keepalive_period, limit) if self.keepalive_period else limit
            break
        self.env.process(self.poller.run())
        self.env.process(self._keepalive())
        self.ready.succeed()

    def _keepalive(self) -> Generator[simpy.Event, Any, None]:
        # Any SET of a control object restarts the controller's backup timer, so only
        # refresh when no command has been SET within the period.
        period = self.keepalive_period
        if not period:
            return  # neither the config nor the controller has a backup time: nothing to refresh
        while True:
            due = self.last_set + period
            if self.env.now < due:
                yield self.env.timeout(due - self.env.now)
                continue
            if self.keepalive_enabled and self.call and not self.timeout_flag:
                self._send(self.call, "keepalive")
            else:
                yield self.env.timeout(period)

    def _recover(self) -> Generator[simpy.Event, Any, bool]:
        if not self.timeout_flag:
            # Outside TIMEOUT there is nothing to recover, and re-SETting the call to the greens
            # shown would cancel a command in transition.
            self.log.emit(Kind.NOTE, message=f"recover() in {self.manager.state.value}: nothing to recover")
            return True
        self.log.emit(Kind.RECOVERY_STARTED, state=self.manager.state.value)
        try:
            state = yield from self.poller.read_once()
            yield self._send(state.greens, "recovery")
        except (TransportError, SnmpError) as exc:
            self.log.emit(Kind.NOTE, message=f"recovery failed, still in TIMEOUT: {exc}")
            return False
        self.cache.update(state, self.env.now, self.poller.polls)
        self.converter.sync(state.greens)
        self.drift.reset()
        self._feed(RecoveryCompleted(self.env.now, state.greens))
        return True

    def _clear(self) -> Generator[simpy.Event, Any, None]:
        try:
            yield self._send(frozenset(), "clear")
        except (TransportError, SnmpError) as exc:
            log.warning("could not clear the calls at the end of the run: %s", exc)

    # --- the manager's shell ----------------------------------------------------------------------

    def _feed(self, event) -> list[Effect]:
        before = self.manager.state
        effects = self.manager.handle(event)
        for effect in effects:
            self._carry_out(effect)
        after = self.manager.state
        if after is not before:
            self.log.emit(Kind.STATE, **{"from": before.value, "to": after.value})
            waiting = self._entering.pop(after, None)
            if waiting is not None:
                waiting.succeed()
        return effects

    def _carry_out(self, effect: Effect) -> None:
        match effect:
            case Dispatch(command_id, action_id, command):
                self._dispatch(command_id, action_id, command)
            case StartTimer(kind, delay, token):
                self.env.timeout(delay).callbacks.append(
                    lambda _ev, kind=kind, token=token: self._feed(TimerExpired(self.env.now, kind, token)))
            case Dropped(action_id, state):
                self.log.emit(Kind.ACTION_DROPPED, action_id=action_id, state=state.value)
            case Verified(command_id, command, poll_id, hold):
                self.log.emit(Kind.TRANSITION_VERIFIED, command_id=command_id, command=command.phases,
                              poll_id=poll_id, hold_s=hold)
            case CommandEnded(command_id, outcome, hold):
                self.log.emit(Kind.HOLD_RELEASED, command_id=command_id, reason=outcome, hold_s=hold)
            case TimeoutEntered(reason, detail, command_id):
                self.log.emit(Kind.TIMEOUT_ENTERED, reason=reason.value, detail=detail, command_id=command_id)
                self.poller.halt()
            case Recovered(greens):
                self.log.emit(Kind.RECOVERED, greens=greens)
                self.poller.resume()

    def _dispatch(self, command_id: int, action_id: int, command: Command) -> None:
        self.log.emit(Kind.COMMAND_DISPATCHED, action_id=action_id, command_id=command_id,
                      command=command.phases, green=command.green)
        self.converter.commit(command)
        self._send(frozenset(command.phases), "command", command_id)

    def _send(self, phases: frozenset[int], purpose: str, command_id: int | None = None) -> simpy.Event:
        """SET VehCall to ``phases``; logs the SET and its answer. Returns the transport's event."""
        masks = phases_to_groups(phases, self.config.groups)
        varbinds = [(control_oid(ControlColumn.VEH_CALL, g), m) for g, m in enumerate(masks, start=1)]
        self.call = phases
        self.last_set = self.env.now
        self.log.emit(Kind.SET_SENT, command_id=command_id, phases=phases, purpose=purpose)
        done = self.transport.set(varbinds)
        done.callbacks.append(lambda ev: self._answered(ev, purpose, command_id))
        return done

    def _answered(self, ev: simpy.Event, purpose: str, command_id: int | None) -> None:
        if ev.ok:
            self.log.emit(Kind.SET_ANSWERED, command_id=command_id, purpose=purpose)
        else:
            ev.defused = True  # a failed SET is logged; what follows is decided here or by the timers
            self.log.emit(Kind.SET_FAILED, command_id=command_id, purpose=purpose,
                          error=f"{type(ev.value).__name__}: {ev.value}")
            pending = self.manager.pending
            if (isinstance(ev.value, CommunicationTimeout) and purpose in ("command", "retry")
                    and pending is not None and pending.command_id == command_id
                    and pending.stage is Stage.TRANSITION):
                # No answer: the call may never have reached the controller. SET it again (it is
                # idempotent) while the command waits for its transition; tau_trans still bounds the
                # wait, and each try takes tau_udp. A refusal (an SNMP error) is not retried.
                self._send(frozenset(pending.command.phases), "retry", command_id)

    def _on_signal(self, snap: Snapshot, changed: bool) -> None:
        # ON_HOLD verifies on every poll (a command may target what is already shown); otherwise
        # an unchanged poll tells the manager nothing new.
        if changed or self.manager.state is State.ON_HOLD:
            self._feed(SignalObserved(snap.t, snap.state.greens, snap.seq))

    def _fail(self, reason: TimeoutReason, detail: str) -> None:
        self._feed(FailureDetected(self.env.now, reason, detail))


def _plain(value: Any) -> Any:
    """A JSON-friendly copy of an action value for the log (whatever the agent returned)."""
    if hasattr(value, "tolist"):
        value = value.tolist()  # numpy arrays and scalars
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, int) and not isinstance(value, bool):
        # The log's encoder takes 64-bit integers only: a larger one is logged as its text.
        return value if -(2**63) <= value < 2**64 else repr(value)[:40]
    if isinstance(value, (float, str, bool)) or value is None:
        return value
    try:
        return float(value)
    except (TypeError, ValueError):
        return repr(value)
