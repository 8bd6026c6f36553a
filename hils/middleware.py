"""The middleware: the manager's SimPy shell and the poller.

The manager (:mod:`hils.manager`) decides; this module does, and decides nothing. It turns agent
actions into manager events, carries out the effects the manager returns (SET the call, start
timers, halt or resume polling, re-read the controller, log) and feeds back what happened: timer
expiries, signal observations, the answers to SETs, the cost of simulation steps. It runs unchanged
in virtual and wall-clock time: only the environment's driver and the transport differ.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import simpy

from hils.actions import ActionConverter, ActionError, ActionType
from hils.config import IntersectionConfig, Pair
from hils.events import EventLog, Kind
from hils.manager import (
    CloseRequested,
    CommandEnded,
    CommandRequested,
    ControllerRead,
    ControllerUnreadable,
    ControlsRead,
    Dispatch,
    DriftSeen,
    Dropped,
    Effect,
    Event,
    FailureDetected,
    HaltPolling,
    KeepaliveSwitched,
    Manager,
    Mode,
    Note,
    Purpose,
    ReadController,
    Recovered,
    RecoveryRequested,
    RecoveryStarted,
    ResumePolling,
    SendCall,
    SetAnswered,
    SetFailed,
    SignalObserved,
    Started,
    StartTimer,
    State,
    StepTimed,
    TimeoutEntered,
    TimeoutReason,
    TimerExpired,
    Verified,
)
from hils.ntcip import (
    CONTROL_TABLE,
    FOREIGN_COLUMNS,
    SYSTEM_PATTERN_CONTROL,
    UNIT_BACKUP_TIME,
    UNIT_FLASH_STATUS,
    ControlColumn,
    ErrorStatus,
    SnmpError,
    control_oid,
    groups_to_phases,
    phases_to_groups,
)
from hils.poller import Decoded, Poller, SignalCache, Snapshot
from hils.preflight import ControllerReading, Verdict, judge
from hils.transport import CommunicationTimeout, SecurityRefused, Transport, TransportError

log = logging.getLogger(__name__)

#: Seconds between read-backs of the control objects: a change by someone else is noticed within this.
READBACK_PERIOD = 2.0


@dataclass(frozen=True, slots=True)
class Submission:
    """What became of an action handed to :meth:`Middleware.submit`."""

    action_id: int
    error: ActionError | None = None  # refused by the converter: nothing was sent
    dropped: bool = False  # converted, but the manager was not IDLE


class Middleware:
    """Everything between the agent and the transport, on one SimPy environment."""

    def __init__(self, env: simpy.Environment, transport: Transport, config: IntersectionConfig,
                 action_type: ActionType | str, events: EventLog, *, where: str = "the controller",
                 community: str | None = None) -> None:
        params = config.middleware
        self.where = where  # how messages name the controller (HOST:PORT)
        self.community = community  # SNMPv1/v2c's; "" over SNMPv3 (none), None in process
        self.startup_error: str | None = None  # why the start-up read or write failed, if it did
        self.verdict = Verdict((), ())  # the start-up checks' refusals and warnings
        self.env = env
        self.transport = transport
        self.config = config
        self.log = events
        events.bind(lambda: env.now)
        self.manager = Manager(params.tau_trans, sequence=config.sequence, n_drift=params.n_drift,
                               keepalive_period=params.keepalive_period or 0.0)
        self.converter = ActionConverter(config, ActionType(action_type))
        self.cache = SignalCache()
        self.poller = Poller(env, transport, self.cache, events, groups=config.groups,
                             rate_hz=params.poll_hz, n_timeout=params.n_timeout,
                             on_failure=lambda why: self._fail(TimeoutReason.COMMUNICATION, why))
        # Every poll, not only changes: a command for phases already green is verified by the
        # next poll, which shows no change.
        self.cache.subscribe(self._on_signal, every_poll=True)
        self.ready = env.event()
        self._entering: dict[State, simpy.Event] = {}  # events of processes waiting for a state
        self._leaving_recovery: simpy.Event | None = None
        self._clearing: simpy.Event | None = None
        self._actions = 0
        self.last_hold: float | None = None  # s from dispatch to verification of the last verified transition

    # --- public API -------------------------------------------------------------------------

    @property
    def state(self) -> State | None:
        """The manager's state by the paper's names (None once the run has closed)."""
        return self.manager.state

    @property
    def timeout_flag(self) -> bool:
        """The system-wide timeout event flag: set in TIMEOUT until recovery."""
        return self.manager.state is State.TIMEOUT

    @property
    def next_pair(self) -> Pair:
        """The pair a switch or duration action would serve next."""
        return self.converter.pair_after(self.manager.position)

    @property
    def call(self) -> frozenset[int]:
        """VehCall as last SET."""
        return self.manager.call

    @property
    def last_set(self) -> float:
        return self.manager.last_set

    @property
    def keepalive_period(self) -> float:
        return self.manager.keepalive_period

    @property
    def keepalive_enabled(self) -> bool:
        return self.manager.keepalive_on

    @keepalive_enabled.setter
    def keepalive_enabled(self, on: bool) -> None:
        self._feed(KeepaliveSwitched(self.env.now, on))

    def start(self, after: float = 0.0) -> simpy.Process:
        """Read the controller, then start polling; ``ready`` fires when done. ``after``: seconds to wait first
        (the controllers of a corridor start apart, so that their polls do not all go out at one instant)."""
        return self.env.process(self._startup(after))

    def check(self, value: Any) -> None:
        """Raise the :class:`hils.actions.ActionError` that :meth:`submit` would refuse ``value`` with, logging
        and sending nothing (a run of several controllers checks every action before it submits any)."""
        self.converter.convert(value, self.manager.position)

    def submit(self, value: Any) -> Submission:
        """An agent's action value, converted and handed to the manager."""
        self._actions += 1
        action_id = self._actions
        self.log.emit(Kind.ACTION_RECEIVED, action_id=action_id, action_type=self.converter.action_type.value,
                      value=_plain(value))
        try:
            command = self.converter.convert(value, self.manager.position)
        except ActionError as exc:
            self.log.emit(Kind.ACTION_REFUSED, action_id=action_id, error=type(exc).__name__, reason=exc.reason,
                          message=str(exc))
            return Submission(action_id, error=exc)
        self.log.emit(Kind.ACTION_CONVERTED, action_id=action_id, command=command.phases, green=command.green,
                      keep=command.keep)
        shown = self.cache.state.greens if self.cache.state is not None else frozenset()
        effects = self._feed(CommandRequested(self.env.now, action_id, command, shown))
        return Submission(action_id, dropped=any(isinstance(e, Dropped) for e in effects))

    def observe_step(self, step: float, took: float) -> None:
        """Report one simulation step's cost to drift detection (when the manager would notice it)."""
        if self.manager.notices(step, took):
            self._feed(StepTimed(self.env.now, step, took))

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
        """Recovery from TIMEOUT: re-read the controller, align the call with what it shows, return to
        IDLE. The process's value is True when the manager is not in TIMEOUT afterwards."""
        return self.env.process(self._recover())

    def close(self) -> simpy.Process:
        """Clear the calls this run placed and stop polling and the keepalive for good."""
        return self.env.process(self._close())

    # --- processes ----------------------------------------------------------------------------

    def _startup(self, after: float) -> Generator[simpy.Event, Any, None]:
        if after > 0:
            yield self.env.timeout(after)
        # Like the poller, give up only after n_timeout consecutive failures: one lost datagram
        # at start-up is no reason to halt.
        n = self.config.middleware.n_timeout
        for attempt in range(1, n + 1):
            try:
                seen, reading = yield from self._read_controller_setup()
                # The control objects are ours while we run: whatever someone else left is cleared,
                # and this harmless SET shows whether the community may write.
                yield self._logged_set(_cleared_control(self.config.groups), frozenset(), "startup", None)
            except (SnmpError, SecurityRefused) as exc:
                # A refusal, not a loss: asking again gets the same answer.
                self.startup_error = (_refusal_text(exc, self.where) if isinstance(exc, SnmpError)
                                      else f"the start-up read or write failed: {exc}")
                self.log.emit(Kind.NOTE, message=f"start-up: {self.startup_error}")
                self._fail(TimeoutReason.COMMUNICATION, self.startup_error)
                break
            except TransportError as exc:
                self.log.emit(Kind.POLL_FAILED, poll_id=0, error=f"start-up read: {type(exc).__name__}: {exc}",
                              consecutive=attempt)
                if attempt == n:
                    credentials = {None: "?", "": ", and are the SNMPv3 user and its keys right (an agent may "
                                                  "drop what it cannot decrypt without a word)?"}
                    self.startup_error = (f"no answer from {self.where} within {n} x tau_udp = "
                                          f"{n * self.config.middleware.tau_udp:g} s: is the controller there, "
                                          "at that address and port"
                                          + credentials.get(self.community, ", and is the community right?"))
                    self._fail(TimeoutReason.COMMUNICATION, f"controller unreachable at start-up: {exc}")
                continue
            self.verdict = judge(reading, where=self.where, community=self.community,
                                 keepalive_period=self.manager.keepalive_period)
            for line in (*self.verdict.refusals, *self.verdict.warnings):
                self.log.emit(Kind.NOTE, message=f"start-up: {line}")
            self.poller.show(seen, 0)
            self._feed(Started(self.env.now, seen.state.greens, reading.backup_time))
            break
        self.env.process(self.poller.run())
        self.env.process(self._read_back())
        self.ready.succeed()

    def _read_controller_setup(self) -> Generator[simpy.Event, Any, tuple[Decoded, ControllerReading]]:
        seen = yield from self.poller.read_once()
        backup, pattern, flash = yield self.transport.get(
            [UNIT_BACKUP_TIME.instance(), SYSTEM_PATTERN_CONTROL.instance(), UNIT_FLASH_STATUS.instance()])
        groups = self.config.groups
        masks = yield self.transport.get([control_oid(c, g) for c in ControlColumn for g in range(1, groups + 1)])
        control = {c: groups_to_phases(masks[i * groups:(i + 1) * groups]) for i, c in enumerate(ControlColumn)}
        return seen, ControllerReading(int(backup), int(pattern), int(flash), control)

    def _read_back(self) -> Generator[simpy.Event, Any, None]:
        """Read the control objects back every READBACK_PERIOD s; the manager judges whose they are.

        Like a poll, a read-back that cannot see a change is not sent: with a change feed, every read-back
        after one that found the control objects ours would find them ours again until the feed's
        ``controls`` moves (someone wrote one), so the process sleeps until then and goes on at the first
        time of its grid not before the write (at the write's own instant, should they meet)."""
        env = self.env
        groups = self.config.groups
        oids = [control_oid(c, g) for c in FOREIGN_COLUMNS for g in range(1, groups + 1)]
        ours: int | None = None  # the feed's controls when a read-back last found the control objects ours
        # Half a poll period off the poll grid, so that a read-back and a poll do not go out together.
        yield env.timeout(self.poller.period / 2)
        wait = READBACK_PERIOD
        while self.manager.mode is not Mode.CLOSED:
            yield env.timeout(wait)
            wait = READBACK_PERIOD
            if self.poller.halted or self.poller.consecutive_failures:
                continue  # in TIMEOUT only recovery sends; while polls fail, the poller counts them
            feed = self.transport.change_feed
            controls = feed.controls if feed is not None else None
            if controls is not None and controls == ours:
                # The grid's times as successive timeouts make them, float for float; from 2 s on a wait
                # below 2 s is exact (due - now), so the timeout lands on due itself.
                due = env.now + READBACK_PERIOD
                yield feed.controls_changed()
                while due < env.now:
                    due += READBACK_PERIOD
                wait = due - env.now
                continue
            try:
                values = yield self.transport.get(oids)
            except (TransportError, SnmpError):
                continue  # the poller counts communication failures
            if self.manager.mode is Mode.CLOSED:
                return
            effects = self._feed(ControlsRead(self.env.now, tuple(
                (CONTROL_TABLE[c].name, groups_to_phases([int(v) for v in values[i * groups:(i + 1) * groups]]))
                for i, c in enumerate(FOREIGN_COLUMNS))))
            ours = None if any(isinstance(e, TimeoutEntered) for e in effects) else controls

    def _recover(self) -> Generator[simpy.Event, Any, bool]:
        self._feed(RecoveryRequested(self.env.now))
        if self.manager.mode is Mode.RECOVERING:
            yield self._leaving_recovery
        return not self.timeout_flag

    def _read_controller(self) -> Generator[simpy.Event, Any, None]:
        try:
            seen = yield from self.poller.read_once()
        except (TransportError, SnmpError) as exc:
            self._feed(ControllerUnreadable(self.env.now, str(exc)))
            return
        self.poller.show(seen, self.poller.polls)
        self._feed(ControllerRead(self.env.now, seen.state.greens))

    def _close(self) -> Generator[simpy.Event, Any, None]:
        self._feed(CloseRequested(self.env.now))
        while self._clearing is not None:
            clearing = self._clearing
            try:
                yield clearing
                return
            except (TransportError, SnmpError) as exc:
                if self._clearing is clearing:  # the manager sent no other: the calls stay until the backup time
                    log.warning("could not clear the calls at the end of the run: %s", exc)
                    return

    # --- the manager's shell ----------------------------------------------------------------------

    def _feed(self, event: Event) -> list[Effect]:
        before = self.manager.mode
        effects = self.manager.handle(event)
        for effect in effects:
            self._carry_out(effect)
        after = self.manager.mode
        if before.paper is not after.paper and after.paper is not None:
            self.log.emit(Kind.STATE, **{"from": before.log_name, "to": after.log_name})
            waiting = self._entering.pop(after.paper, None)
            if waiting is not None:
                waiting.succeed()
        if before is Mode.RECOVERING and after is not Mode.RECOVERING and self._leaving_recovery is not None:
            leaving, self._leaving_recovery = self._leaving_recovery, None
            leaving.succeed()
        return effects

    def _carry_out(self, effect: Effect) -> None:
        match effect:
            case Dispatch(command_id, action_id, command):
                self.log.emit(Kind.COMMAND_DISPATCHED, action_id=action_id, command_id=command_id,
                              command=command.phases, green=command.green)
            case SendCall(phases, purpose, command_id):
                self._send(phases, purpose, command_id)
            case StartTimer(kind, delay, token):
                self.env.timeout(delay).callbacks.append(
                    lambda _ev, kind=kind, token=token: self._feed(TimerExpired(self.env.now, kind, token)))
            case Dropped(action_id, state):
                self.log.emit(Kind.ACTION_DROPPED, action_id=action_id, state=state)
            case Verified(command_id, command, poll_id, hold):
                self.last_hold = hold
                self.log.emit(Kind.TRANSITION_VERIFIED, command_id=command_id, command=command.phases,
                              poll_id=poll_id, hold_s=hold)
            case CommandEnded(command_id, outcome, hold):
                self.log.emit(Kind.HOLD_RELEASED, command_id=command_id, reason=outcome, hold_s=hold)
            case TimeoutEntered(reason, detail, command_id):
                if reason is TimeoutReason.FOREIGN_CONTROL:
                    log.warning("control objects %s: TIMEOUT (foreign_control)", detail)
                self.log.emit(Kind.TIMEOUT_ENTERED, reason=reason.value, detail=detail, command_id=command_id)
            case DriftSeen(step, took, consecutive):
                self.log.emit(Kind.DRIFT, step_s=step, took_s=took, consecutive=consecutive)
            case HaltPolling():
                self.poller.halt()
            case ResumePolling():
                self.poller.resume()
            case RecoveryStarted():
                self.log.emit(Kind.RECOVERY_STARTED, state=State.TIMEOUT.value)
                self._leaving_recovery = self.env.event()
            case ReadController():
                self.env.process(self._read_controller())
            case Recovered(greens):
                self.log.emit(Kind.RECOVERED, greens=greens)
            case Note(message):
                self.log.emit(Kind.NOTE, message=message)

    def _send(self, phases: frozenset[int], purpose: Purpose, command_id: int | None) -> None:
        """SET VehCall to ``phases``; logs the SET and its answer, and feeds the answer back."""
        masks = phases_to_groups(phases, self.config.groups)
        varbinds = [(control_oid(ControlColumn.VEH_CALL, g), m) for g, m in enumerate(masks, start=1)]
        if purpose is Purpose.RECOVERY:
            # Taking the controller back: what someone else set (a foreign control's TIMEOUT) goes too.
            varbinds += _cleared_control(self.config.groups, FOREIGN_COLUMNS)
        done = self._logged_set(varbinds, phases, purpose.value, command_id)
        done.callbacks.append(lambda ev: self._answered(ev, purpose, command_id))
        if purpose is Purpose.CLEAR:
            self._clearing = done

    def _logged_set(self, varbinds: list[tuple[Any, int]], phases: frozenset[int], purpose: str,
                    command_id: int | None) -> simpy.Event:
        """One SET, logged when sent and when answered or failed; every SET of the run goes through here."""
        self.log.emit(Kind.SET_SENT, command_id=command_id, phases=phases, purpose=purpose)
        done = self.transport.set(varbinds)

        def logged(ev: simpy.Event) -> None:
            if ev.ok:
                self.log.emit(Kind.SET_ANSWERED, command_id=command_id, purpose=purpose)
            else:
                self.log.emit(Kind.SET_FAILED, command_id=command_id, purpose=purpose,
                              error=f"{type(ev.value).__name__}: {ev.value}")

        done.callbacks.append(logged)
        return done

    def _answered(self, ev: simpy.Event, purpose: Purpose, command_id: int | None) -> None:
        """Feed a VehCall SET's answer back to the manager, which decides what follows a failure."""
        if ev.ok:
            self._feed(SetAnswered(self.env.now, purpose, command_id))
            return
        if purpose is not Purpose.CLEAR:
            ev.defused = True
        self._feed(SetFailed(self.env.now, purpose, command_id, isinstance(ev.value, CommunicationTimeout)))

    def _on_signal(self, snap: Snapshot, changed: bool) -> None:
        # ON_HOLD verifies on every poll (a command may target what is already shown); otherwise
        # an unchanged poll tells the manager nothing new.
        if changed or self.manager.mode is Mode.IN_TRANSITION:
            self._feed(SignalObserved(snap.t, snap.state.greens, snap.seq))

    def _fail(self, reason: TimeoutReason, detail: str) -> None:
        self._feed(FailureDetected(self.env.now, reason, detail))


_NOT_WRITABLE = {ErrorStatus.NO_ACCESS, ErrorStatus.NOT_WRITABLE, ErrorStatus.READ_ONLY, ErrorStatus.NO_SUCH_NAME,
                 ErrorStatus.AUTHORIZATION_ERROR}


def _cleared_control(groups: int, columns: tuple[ControlColumn, ...] = tuple(ControlColumn)) -> list[tuple[Any, int]]:
    """The given control objects (default: all six) of every group at 0."""
    return [(control_oid(c, g), 0) for c in columns for g in range(1, groups + 1)]


def _refusal_text(exc: SnmpError, where: str) -> str:
    if exc.status in _NOT_WRITABLE:
        return (f"the controller at {where} refuses to be written ({exc.status.name.lower()}): the community "
                "can read but not write; use the controller's read-write community (Cobalt: its user name)")
    return f"the controller at {where} refused the start-up read or write: {exc}"


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
