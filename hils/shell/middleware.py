"""The middleware: the manager's SimPy shell and the poller.

The manager (:mod:`hils.control.manager`) decides; this module does, and decides nothing. It turns agent
actions (phase commands, or phase-control schedules) into manager events, carries out the effects the manager
returns (SET the call or the control objects, start timers, halt or resume polling, read the controller, log) and
feeds back what happened: the start-up read, every poll's answer or failure (a poll reads the signal state and,
when the config lists preempts, their preemptState in the same GET), timer expiries, the answers to SETs, the
read-back of the control objects, the cost of simulation steps. It runs unchanged in virtual and wall-clock time:
only the environment's driver and the transport differ.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import simpy

from hils.control.actions import ActionConverter, ActionError, ActionType, Command
from hils.control.manager import Manager, Mode, State
from hils.control.manager_io import (
    AgentOverdue,
    AnotherManager,
    CallsFound,
    CallsWatched,
    CloseDone,
    CloseRequested,
    CommandEnded,
    CommandRequested,
    ControllerRead,
    ControllerUnreachable,
    ControllerUnreadable,
    ControlsRead,
    ControlsReset,
    Dispatch,
    DriftSeen,
    Dropped,
    Effect,
    Event,
    HaltPolling,
    KeepaliveSwitched,
    Note,
    OrderChanged,
    PollAnswered,
    PollFailed,
    PollFailureSeen,
    PreemptBegan,
    PreemptEnded,
    Purpose,
    ReadbackDue,
    ReadController,
    ReadControls,
    Recovered,
    RecoveryRequested,
    RecoveryStarted,
    Refused,
    ResumePolling,
    RetryStartup,
    ScheduleBegan,
    ScheduleEnded,
    ScheduleRequested,
    SendCall,
    SendControls,
    SetAnswered,
    SetFailed,
    ShowSignal,
    Started,
    StartTimer,
    StartupDone,
    StartupLost,
    StartupRefused,
    StepTimed,
    TimeoutEntered,
    TimeoutReason,
    TimerExpired,
    TimerKind,
    Verified,
    WatchCalls,
)
from hils.control.phase_control import Schedule
from hils.protocol.config import IntersectionConfig, Pair
from hils.protocol.ntcip import (
    CONTROL_TABLE,
    FOREIGN_COLUMNS,
    SYSTEM_PATTERN_CONTROL,
    UNIT_BACKUP_TIME,
    UNIT_CONTROL_STATUS,
    UNIT_FLASH_STATUS,
    ControlColumn,
    ErrorStatus,
    SignalState,
    SnmpError,
    UnitControlStatus,
    control_oid,
    groups_to_phases,
    phases_to_groups,
    preempt_state_oids,
    preempts_in_service,
    signal_oids,
)
from hils.protocol.timegrid import Grid
from hils.shell.events import EventLog, Kind
from hils.shell.fastpath import Foresight, QuietPolls, QuietReadbacks
from hils.shell.poller import Poller, SignalCache
from hils.shell.preflight import ControllerReading, Verdict, judge
from hils.shell.transport import CommunicationTimeout, SecurityRefused, Transport, TransportError

__all__ = ["READBACK_PERIOD", "Middleware", "Received", "Submission"]

log = logging.getLogger(__name__)

#: Seconds between read-backs of the control objects: a change by someone else is noticed within this.
READBACK_PERIOD = 2.0


@dataclass(slots=True)
class Received:
    """An action value as it arrived (``wall_ns``: the monotonic clock then) and what converting it gave."""

    value: Any
    wall_ns: int
    command: Command | Schedule | None  # a schedule for phase control
    error: ActionError | None = None  # refused by the converter, or preempted: nothing will be sent


@dataclass(frozen=True, slots=True)
class Submission:
    """What became of an action handed to :meth:`Middleware.submit`."""

    action_id: int
    error: ActionError | None = None  # refused (by the converter, or the manager while preempted): nothing was sent
    dropped: bool = False  # converted, but the manager was not IDLE


class Middleware:
    """Everything between the agent and the transport, on one SimPy environment.

    ``recover_after``: seconds in TIMEOUT before the manager recovers by itself (None: only when asked).
    ``foresight``: the transport's knowledge of when its answer can change (:mod:`hils.shell.fastpath`), given on
    virtual time's fast path: the polls and read-backs that cannot see a change are left out.
    ``take_over``: take a controller whose calls someone else placed without watching them first (see the
    manager's STARTING)."""

    def __init__(self, env: simpy.Environment, transport: Transport, config: IntersectionConfig,
                 action_type: ActionType | str, events: EventLog, *, where: str = "the controller",
                 community: str | None = None, recover_after: float | None = None,
                 foresight: Foresight | None = None, take_over: bool = False) -> None:
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
                               n_timeout=params.n_timeout, keepalive_period=params.keepalive_period or 0.0,
                               recover_after=recover_after, watch=2 * params.control_interval,
                               watch_period=params.poll_period, take_over=take_over,
                               phase_control=ActionType(action_type) is ActionType.CONTROL)
        self.converter = ActionConverter(config, ActionType(action_type))
        self.cache = SignalCache()
        # One GET per poll: the signal state, then the state of each preempt the config lists (none: no more).
        self._preempts = tuple(sorted(config.preempts))
        self.signal_oids = signal_oids(config.groups) + preempt_state_oids(self._preempts)
        self._veh_call_oids = [control_oid(ControlColumn.VEH_CALL, g) for g in range(1, config.groups + 1)]
        # The read-back: the control objects the run never sets, then VehCall.
        self._control_oids = [*(control_oid(c, g) for c in FOREIGN_COLUMNS for g in range(1, config.groups + 1)),
                              *self._veh_call_oids]
        quiet = QuietPolls(foresight, lambda: self.manager.newest_poll,
                           lambda: self.manager.counts_only(self.cache.state)) if foresight is not None else None
        self.poller = Poller(env, rate_hz=params.poll_hz, send=self._poll, quiet=quiet)
        self._quiet_readbacks = QuietReadbacks(foresight) if foresight is not None else None
        self.ready = env.event()
        self._entering: dict[State, simpy.Event] = {}  # events of processes waiting for a state
        self._leaving_recovery: simpy.Event | None = None
        self._closed: simpy.Event | None = None
        self._startup_over = False
        # A controller shows a handful of distinct states: each decoded once, with the preempts in service.
        self._decoded: dict[tuple[Any, ...], tuple[SignalState, frozenset[int]]] = {}
        self._log_fields: dict[SignalState, tuple[tuple[int, ...], tuple[int, ...]]] = {}
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
    def poll_counts(self) -> dict[str, int]:
        """Polls on the grid so far, and how each ended (``elided``: not sent, it could not see a change)."""
        m = self.manager
        counts = self.poller.counts
        return {**counts, "answered": m.polls_answered + self.poller.answered_unsent, "failed": m.polls_failed,
                "late": m.polls_late}

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

    def receive(self, value: Any) -> Received:
        """An agent's action value as it arrives, converted (logging and sending nothing yet): a run converts
        every action of a step before it submits any, so that a refused one leaves the others unsent. A valid
        action is refused too when the manager would refuse it (the controller preempted)."""
        received_ns = time.monotonic_ns()
        try:
            command = self.converter.convert(value, self.manager.position)
        except ActionError as exc:
            return Received(value, received_ns, None, exc)
        refusal = self.manager.refusal()
        return Received(value, received_ns, None if refusal else command, refusal)

    def submit(self, action: Any) -> Submission:
        """An agent's action (a value, or what :meth:`receive` made of one) logged and handed to the manager."""
        received = action if isinstance(action, Received) else self.receive(action)
        self._actions += 1
        action_id = self._actions
        # Stamped when it arrived: the internal latency counts its conversion.
        self.log.emit(Kind.ACTION_RECEIVED, action_id=action_id, action_type=self.converter.action_type.value,
                      value=_plain(received.value), wall_ns=received.wall_ns)
        if received.error is not None:
            return self._refused(action_id, received.error)
        command = received.command
        if isinstance(command, Schedule):
            self.log.emit(Kind.ACTION_CONVERTED, action_id=action_id, command=(), green=None, keep=False,
                          orders=len(command.orders), span_s=command.span, dropped=command.dropped)
            effects = self._feed(ScheduleRequested(self.env.now, action_id, command))
        else:
            self.log.emit(Kind.ACTION_CONVERTED, action_id=action_id, command=command.phases, green=command.green,
                          keep=command.keep)
            shown = self.cache.state.greens if self.cache.state is not None else frozenset()
            effects = self._feed(CommandRequested(self.env.now, action_id, command, shown))
        refused = next((e for e in effects if isinstance(e, Refused)), None)
        if refused is not None:
            return self._refused(action_id, refused.error)
        return Submission(action_id, dropped=any(isinstance(e, Dropped) for e in effects))

    def _refused(self, action_id: int, exc: ActionError) -> Submission:
        self.log.emit(Kind.ACTION_REFUSED, action_id=action_id, error=type(exc).__name__, reason=exc.reason,
                      message=str(exc))
        return Submission(action_id, error=exc)

    def agent_overdue(self, waited: float) -> None:
        """The agent asked ``waited`` s ago (the control interval) has given no action yet."""
        self._feed(AgentOverdue(self.env.now, waited))

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
        waiting = self._entering.get(state)
        if waiting is None:  # made once per entry: a decision asks each intersection for it twice
            waiting = self._entering[state] = self.env.event()
        return waiting

    def wait_idle(self) -> simpy.Event:
        return self.wait_for(State.IDLE)

    def recover(self) -> simpy.Process:
        """Recovery from TIMEOUT: re-read the controller, align the call with what it shows, return to
        IDLE. The process's value is True when the manager is not in TIMEOUT afterwards."""
        return self.env.process(self._recover())

    def close(self) -> simpy.Event:
        """Clear the calls this run placed and stop polling and the keepalive for good; the event fires when
        the close is over (the clear answered, or given up)."""
        self._closed = self.env.event()
        self._feed(CloseRequested(self.env.now))
        return self._closed

    # --- processes ----------------------------------------------------------------------------

    def _startup(self, after: float) -> Generator[simpy.Event, Any, None]:
        if after > 0:
            yield self.env.timeout(after)
        while not self._startup_over:  # the manager says whether a read without answer is made again
            try:
                seen, reading = yield from self._read_controller_setup()
                # Calls found are someone's: the manager may have them watched for another manager first.
                effects = self._feed(CallsFound(self.env.now, reading.control[ControlColumn.VEH_CALL]))
                while (watch := next((e for e in effects if isinstance(e, WatchCalls)), None)) is not None:
                    yield self.env.timeout(watch.delay)
                    calls = yield self.transport.get(self._veh_call_oids)
                    effects = self._feed(CallsWatched(self.env.now, groups_to_phases([int(v) for v in calls])))
                if self._startup_over:
                    return  # another manager drives the controller: nothing is SET
                # The control objects are ours while we run: whatever someone else left is cleared,
                # and this harmless SET shows whether the community may write.
                yield self._logged_set(_cleared_control(self.config.groups), frozenset(), "startup", None)
            except (SnmpError, SecurityRefused) as exc:
                # A refusal, not a loss: asking again gets the same answer.
                self.startup_error = (_refusal_text(exc, self.where) if isinstance(exc, SnmpError)
                                      else f"the start-up read or write failed: {exc}")
                self._feed(StartupRefused(self.env.now, self.startup_error))
                continue
            except TransportError as exc:
                self._feed(StartupLost(self.env.now, f"{type(exc).__name__}: {exc}"))
                continue
            self.verdict = judge(reading, where=self.where, community=self.community,
                                 keepalive_period=self.manager.keepalive_period)
            for line in (*self.verdict.refusals, *self.verdict.warnings):
                self.log.emit(Kind.NOTE, message=f"start-up: {line}")
            self._show(seen, 0)
            self._feed(Started(self.env.now, seen.greens, reading.backup_time))

    def _read_signal(self) -> Generator[simpy.Event, Any, SignalState]:
        """One GET of the signal state outside the poll grid (start-up, recovery)."""
        values = yield self.transport.get(self.signal_oids)
        return self._decode(values)[0]

    def _decode(self, values: tuple[Any, ...]) -> tuple[SignalState, frozenset[int]]:
        """The signal state and the preempts in service that a poll's values say."""
        decoded = self._decoded.get(values)
        if decoded is None:
            n = len(self._preempts)
            signal = values[:len(values) - n]
            decoded = self._decoded[tuple(values)] = (SignalState.from_values(signal, self.config.groups),
                                                      preempts_in_service(self._preempts, values[len(signal):]))
        return decoded

    def _read_controller_setup(self) -> Generator[simpy.Event, Any, tuple[SignalState, ControllerReading]]:
        seen = yield from self._read_signal()
        backup, pattern, flash = yield self.transport.get(
            [UNIT_BACKUP_TIME.instance(), SYSTEM_PATTERN_CONTROL.instance(), UNIT_FLASH_STATUS.instance()])
        groups = self.config.groups
        masks = yield self.transport.get([control_oid(c, g) for c in ControlColumn for g in range(1, groups + 1)])
        control = {c: groups_to_phases(masks[i * groups:(i + 1) * groups]) for i, c in enumerate(ControlColumn)}
        return seen, ControllerReading(int(backup), int(pattern), int(flash), control)

    def _read_back(self) -> Generator[simpy.Event, Any, None]:
        """Read the control objects back at every READBACK_PERIOD of its grid when the manager says so; the
        manager judges whose they are. On the fast path a read-back that cannot see a change is left out
        (:mod:`hils.shell.fastpath`, rule 3): the process sleeps until one could and goes on at the first time of its
        grid not before then (at that very instant, should they meet)."""
        env = self.env
        quiet = self._quiet_readbacks
        # Half a poll period off the poll grid, so that a read-back and a poll do not go out together.
        grid, k = Grid(env.now + self.poller.period / 2, READBACK_PERIOD), 1
        while self.manager.mode is not Mode.CLOSED:
            yield env.timeout(grid.delay(k, env.now))
            k += 1
            if not any(isinstance(e, ReadControls) for e in self._feed(ReadbackDue(env.now))):
                continue
            asleep = quiet.asleep() if quiet is not None else None
            if asleep is not None:
                # Woken by a SET of our own, the objects are still ours: a read-back due then would sleep again, and
                # the ReadbackDue fed before it sets nothing that the next one sent does not set anew.
                while asleep is not None:
                    yield asleep
                    asleep = quiet.asleep()
                k = grid.first_at_or_after(env.now, k)
                continue
            controls = quiet.sent() if quiet is not None else None
            self.transport.get(self._control_oids).callbacks.append(lambda ev, seen=controls: self._read(ev, seen))

    def _read(self, ev: simpy.Event, controls: int | None) -> None:
        """A read-back's answer to the manager (one that failed is let go: failed polls speak for the link)."""
        ev.defused = True
        if not ev.ok:
            return
        groups = self.config.groups
        values = [int(v) for v in ev.value]
        effects = self._feed(ControlsRead(self.env.now, tuple(
            (CONTROL_TABLE[c].name, groups_to_phases(values[i * groups:(i + 1) * groups]))
            for i, c in enumerate(FOREIGN_COLUMNS)), groups_to_phases(values[-groups:])))
        if self._quiet_readbacks is not None:
            self._quiet_readbacks.found(controls, ours=not any(isinstance(e, TimeoutEntered) for e in effects))

    def _recover(self) -> Generator[simpy.Event, Any, bool]:
        self._feed(RecoveryRequested(self.env.now))
        if self.manager.mode is Mode.RECOVERING:
            yield self._leaving_recovery
        return not self.timeout_flag

    def _read_controller(self) -> Generator[simpy.Event, Any, None]:
        """The recovery's re-read: the signal state; under phase control the control objects and unitControlStatus
        too (has the controller's backup timer run out meanwhile?)."""
        controls, backup_mode = None, False
        try:
            seen = yield from self._read_signal()
            if self.manager.phase_control:
                groups = self.config.groups
                values = yield self.transport.get([*(control_oid(c, g) for c in ControlColumn
                                                     for g in range(1, groups + 1)), UNIT_CONTROL_STATUS.instance()])
                controls = {c: groups_to_phases([int(v) for v in values[i * groups:(i + 1) * groups]])
                            for i, c in enumerate(ControlColumn)}
                backup_mode = int(values[-1]) == UnitControlStatus.BACKUP_MODE
        except (TransportError, SnmpError, ValueError) as exc:
            self._feed(ControllerUnreadable(self.env.now, str(exc)))
            return
        self._show(seen, self.poller.polls)
        self._feed(ControllerRead(self.env.now, seen.greens, controls, backup_mode))

    # --- polls ------------------------------------------------------------------------------------

    def _poll(self, poll_id: int) -> None:
        """Send poll ``poll_id``; its answer or failure goes to the manager, in whatever order they settle."""
        epoch = self.manager.poll_epoch
        self.transport.get(self.signal_oids).callbacks.append(
            lambda ev: self._polled(ev, poll_id, epoch))

    def _polled(self, ev: simpy.Event, poll_id: int, epoch: int) -> None:
        ev.defused = True
        try:
            if not ev.ok:
                raise ev.value
            state, preempts = self._decode(ev.value)
        except (TransportError, SnmpError, ValueError) as exc:
            self._feed(PollFailed(self.env.now, poll_id, epoch, type(exc).__name__, f"{type(exc).__name__}: {exc}"))
            return
        self._feed(PollAnswered(self.env.now, poll_id, epoch, state, preempts))

    def _show(self, state: SignalState, poll_id: int, *, logged: bool = False) -> None:
        """Put what a read saw into the cache, with a ``poll`` record when it changes the state, or ``logged``: the
        first answer after failed polls (the state is known again, changed or not: the plots mark the time between
        as no data)."""
        shown = self.cache.snapshot
        # A state decoded before is the same object (_decode keeps them): most answers are told apart by identity.
        if logged or shown is None or (state is not shown.state and state != shown.state):
            fields = self._log_fields.get(state)
            if fields is None:
                fields = self._log_fields[state] = (tuple(sorted(state.greens)), tuple(sorted(state.yellows)))
            self.log.emit(Kind.POLL, poll_id=poll_id, greens=fields[0], yellows=fields[1])
        self.cache.update(state, self.env.now, poll_id)

    # --- the manager's shell ----------------------------------------------------------------------

    def _feed(self, event: Event) -> list[Effect]:
        before = self.manager.mode
        effects = self.manager.handle(event)
        for effect in effects:
            self._carry_out(effect)
        after = self.manager.mode
        if before is after:  # most events (polls, timers, answers) leave the state as it was
            return effects
        if before.paper is not after.paper and after.paper is not None:
            self.log.emit(Kind.STATE, **{"from": before.log_name, "to": after.log_name})
            waiting = self._entering.pop(after.paper, None)
            if waiting is not None:
                waiting.succeed()
        if before is Mode.RECOVERING and self._leaving_recovery is not None:
            leaving, self._leaving_recovery = self._leaving_recovery, None
            leaving.succeed()
        return effects

    def _carry_out(self, effect: Effect) -> None:
        match effect:  # the most frequent first: every answered poll shows its state
            case ShowSignal(poll_id, state, after_failures):
                self._show(state, poll_id, logged=after_failures)
            case Dispatch(command_id, action_id, command):
                self.log.emit(Kind.COMMAND_DISPATCHED, action_id=action_id, command_id=command_id,
                              command=command.phases, green=command.green)
            case PollFailureSeen(poll_id, error, consecutive):
                self.log.emit(Kind.POLL_FAILED, poll_id=poll_id, error=error, consecutive=consecutive)
            case SendCall(phases, purpose, command_id):
                self._send(phases, purpose, command_id)
            case SendControls(controls, purpose):
                self._send_controls(dict(controls), purpose)
            case OrderChanged(change):
                o = change.order
                self.log.emit(Kind.CONTROL_ORDER, index=change.index, control=o.control.value, phase=o.phase,
                              **{"from": change.before.value, "to": change.after.value})
            case ScheduleBegan(action_id, schedule):
                self.log.emit(Kind.SCHEDULE_STARTED, action_id=action_id, orders=schedule.as_rows(),
                              span_s=schedule.span)
            case ScheduleEnded(reason):
                self.log.emit(Kind.SCHEDULE_ENDED, reason=reason)
            case ControlsReset(detail):
                log.warning("%s", detail)
                self.log.emit(Kind.CONTROLS_RESET, detail=detail)
            case StartTimer(kind, delay, token):
                self.env.timeout(delay).callbacks.append(lambda _ev, kind=kind, token=token: self._expired(kind, token))
            case Dropped(action_id, state):
                self.log.emit(Kind.ACTION_DROPPED, action_id=action_id, state=state)
            case Refused():
                pass  # submit() logs it and hands the error back
            case PreemptBegan(preempts, command_id):
                log.info("preempt %s in service: the middleware commands nothing until it is over",
                         ", ".join(map(str, sorted(preempts))))
                self.log.emit(Kind.PREEMPT_BEGIN, preempts=preempts, command_id=command_id)
            case PreemptEnded(duration, greens):
                log.info("preemption over after %.1f s: resuming from phases %s", duration, sorted(greens))
                self.log.emit(Kind.PREEMPT_END, duration_s=duration, greens=greens)
            case Verified(command_id, command, poll_id, hold):
                self.last_hold = hold
                self.log.emit(Kind.TRANSITION_VERIFIED, command_id=command_id, command=command.phases,
                              poll_id=poll_id, hold_s=hold)
            case CommandEnded(command_id, outcome, hold):
                self.log.emit(Kind.HOLD_RELEASED, command_id=command_id, reason=outcome, hold_s=hold)
            case TimeoutEntered(reason, detail, command_id):
                if reason is TimeoutReason.FOREIGN_CONTROL and self.startup_error is None:  # a refusal says it itself
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
            case ReadControls():
                pass  # the read-back process sends it: it is waiting for this answer
            case Recovered(greens):
                self.log.emit(Kind.RECOVERED, greens=greens)
            case Note(message):
                self.log.emit(Kind.NOTE, message=message)
            case RetryStartup():
                pass  # the start-up process reads again: it is waiting for this answer
            case WatchCalls():
                pass  # the start-up process reads VehCall again: it is waiting for this answer
            case AnotherManager(detail):
                self.startup_error = (f"the controller at {self.where}: {detail}; stop that run, or take the "
                                      "controller over (hils run --take-over, Testbed(take_over=True))")
            case ControllerUnreachable(attempts):
                credentials = {None: "?", "": ", and are the SNMPv3 user and its keys right (an agent may "
                                              "drop what it cannot decrypt without a word)?"}
                self.startup_error = (f"no answer from {self.where} within {attempts} x tau_udp = "
                                      f"{attempts * self.config.middleware.tau_udp:g} s: is the controller there, "
                                      "at that address and port"
                                      + credentials.get(self.community, ", and is the community right?"))
            case StartupDone():
                self._startup_over = True
                self.env.process(self.poller.run())
                self.env.process(self._read_back())
                self.ready.succeed()
            case CloseDone(error):
                if error:
                    log.warning("could not clear the calls at the end of the run: %s", error)
                if self._closed is not None:
                    self._closed.succeed()

    def _expired(self, kind: TimerKind, token: int) -> None:
        """A timer ran out: fed to the manager, unless it says the expiry changes nothing (most timers go stale)."""
        if not self.manager.stale(kind, token):
            self._feed(TimerExpired(self.env.now, kind, token))

    def _send(self, phases: frozenset[int], purpose: Purpose, command_id: int | None) -> None:
        """SET VehCall to ``phases``; logs the SET and its answer, and feeds the answer back."""
        masks = phases_to_groups(phases, self.config.groups)
        varbinds = [(control_oid(ControlColumn.VEH_CALL, g), m) for g, m in enumerate(masks, start=1)]
        if purpose is Purpose.RECOVERY:
            # Taking the controller back: what someone else set (a foreign control's TIMEOUT) goes too.
            varbinds += _cleared_control(self.config.groups, FOREIGN_COLUMNS)
        done = self._logged_set(varbinds, phases, purpose.value, command_id)
        done.callbacks.append(lambda ev: self._answered(ev, purpose, command_id))

    def _send_controls(self, controls: dict[ControlColumn, frozenset[int]], purpose: Purpose) -> None:
        """Phase control: SET each of ``controls`` to its phases in one request; logs it and its answer, and feeds
        the answer back."""
        groups = self.config.groups
        varbinds = [(control_oid(c, g), m) for c, phases in controls.items()
                    for g, m in enumerate(phases_to_groups(phases, groups), start=1)]
        done = self._logged_set(varbinds, controls.get(ControlColumn.VEH_CALL, self.manager.call), purpose.value,
                                None, {CONTROL_TABLE[c].name: phases for c, phases in controls.items()})
        done.callbacks.append(lambda ev: self._answered(ev, purpose, None))

    def _logged_set(self, varbinds: list[tuple[Any, int]], phases: frozenset[int], purpose: str,
                    command_id: int | None, controls: dict[str, frozenset[int]] | None = None) -> simpy.Event:
        """One SET, logged when sent and when answered or failed; every SET of the run goes through here."""
        if controls is None:
            self.log.emit(Kind.SET_SENT, command_id=command_id, phases=phases, purpose=purpose)
        else:
            self.log.emit(Kind.SET_SENT, command_id=command_id, phases=phases, purpose=purpose, controls=controls)
        ours = self._quiet_readbacks.writing() if self._quiet_readbacks is not None else None
        polls = self.poller.writing()
        done = self.transport.set(varbinds)
        if ours is not None:
            ours()
        if polls is not None:
            polls()

        def logged(ev: simpy.Event) -> None:
            if ev.ok:
                self.log.emit(Kind.SET_ANSWERED, command_id=command_id, purpose=purpose)
            else:
                self.log.emit(Kind.SET_FAILED, command_id=command_id, purpose=purpose,
                              error=f"{type(ev.value).__name__}: {ev.value}")

        done.callbacks.append(logged)
        return done

    def _answered(self, ev: simpy.Event, purpose: Purpose, command_id: int | None) -> None:
        """Feed a SET's answer back to the manager, which decides what follows a failure."""
        if ev.ok:
            self._feed(SetAnswered(self.env.now, purpose, command_id))
            return
        ev.defused = True
        self._feed(SetFailed(self.env.now, purpose, command_id, isinstance(ev.value, CommunicationTimeout),
                             str(ev.value)))


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
