"""Each fault model does what it says, and counts it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import simpy

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from harness.faults.inject import (
    BAD_KINDS,
    ActionBurst,
    BadActionKind,
    BadActions,
    DatagramLoss,
    Direction,
    ErrorResponses,
    FaultTarget,
    FaultyTransport,
    IndicationMonitor,
    KeepaliveSuppressed,
    Op,
    Reboot,
    ResponseDelay,
    SlowSteps,
    StuckController,
    Window,
    bad_value,
    error_status,
)
from hils.control.actions import ActionConverter, ActionError, ActionType
from hils.protocol.config import IntersectionConfig
from hils.protocol.conflict import Conflict
from hils.protocol.ntcip import (
    ControlColumn,
    ErrorStatus,
    SnmpError,
    UnitControlStatus,
    UnitFlashStatus,
    control_oid,
    signal_oids,
)
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind
from hils.shell.fastpath import modeled_cost
from hils.shell.transport import CommunicationTimeout, Latency, LocalTransport

TAU = 1.0
LATENCY = 0.01
CALL_1_5 = [(control_oid(ControlColumn.VEH_CALL, 1), 0b0001_0001)]  # phases 1 and 5


class CountingSurface:
    """The emulator's MIB view, counting the requests that reach it."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.controller = Controller(config)
        self.mib = MibView(self.controller)
        self.gets = 0
        self.sets = 0

    def get_many(self, oids):
        self.gets += 1
        return self.mib.get_many(oids)

    def set_many(self, varbinds):
        self.sets += 1
        self.mib.set_many(varbinds)


def wire(config: IntersectionConfig, *faults) -> tuple[simpy.Environment, CountingSurface, FaultyTransport]:
    env = simpy.Environment()
    surface = CountingSurface(config)
    inner = LocalTransport(env, surface, tau_udp=TAU, get_latency=Latency(LATENCY), set_latency=Latency(LATENCY))
    return env, surface, FaultyTransport(env, inner, tau_udp=TAU, faults=faults)


def outcome(env: simpy.Environment, event: simpy.Event) -> tuple[float, bool, object]:
    """Step the environment until the event is processed; its time, ok and value."""
    seen = []

    def record(ev):
        ev.defused = True
        seen.append((env.now, ev.ok, ev.value))

    event.callbacks.append(record)
    while not seen:
        env.step()
    return seen[0]


def test_a_dropped_request_never_reaches_the_controller_and_fails_at_tau_udp(paper_config):
    loss = DatagramLoss("loss", direction=Direction.REQUEST)
    env, surface, transport = wire(paper_config, loss)
    at, ok, value = outcome(env, transport.set(CALL_1_5))
    assert (at, ok) == (pytest.approx(TAU), False)
    assert isinstance(value, CommunicationTimeout)
    assert surface.sets == 0
    assert surface.controller.control[ControlColumn.VEH_CALL] == frozenset()
    assert loss.fired == 1 and loss.details == {"requests_lost": 1}


def test_a_dropped_response_reaches_the_controller_but_the_answer_is_lost(paper_config):
    loss = DatagramLoss("loss", direction=Direction.RESPONSE)
    env, surface, transport = wire(paper_config, loss)
    at, ok, value = outcome(env, transport.set(CALL_1_5))
    assert (at, ok) == (pytest.approx(TAU), False)
    assert isinstance(value, CommunicationTimeout)
    assert surface.controller.control[ControlColumn.VEH_CALL] == frozenset({1, 5})
    assert loss.details == {"responses_lost": 1}


def test_loss_applies_only_inside_its_window_and_to_its_operations(paper_config):
    loss = DatagramLoss("loss", ops=frozenset({Op.GET}), window=Window(1.0, 2.0))
    env, _, transport = wire(paper_config, loss)
    before = transport.get(signal_oids(1))
    assert outcome(env, before)[1] is True  # before the window
    env2, _, transport2 = wire(paper_config, loss)
    env2.run(until=1.5)
    assert outcome(env2, transport2.set(CALL_1_5))[1] is True  # a SET in the window: not a GET
    assert outcome(env2, transport2.get(signal_oids(1)))[1] is False  # a GET in the window
    assert loss.fired == 1


def test_burst_loss_drops_runs_of_burst_datagrams_reproducibly(paper_config):
    def pattern(seed: int) -> list[bool]:
        loss = DatagramLoss("burst", direction=Direction.REQUEST, probability=0.05, burst=4, seed=seed)
        return [loss.drops_request(Op.GET, 0.0) for _ in range(2000)]

    dropped = pattern(7)
    runs, n = [], 0
    for d in [*dropped, False]:
        if d:
            n += 1
        elif n:
            runs.append(n)
            n = 0
    assert runs and all(r >= 4 for r in runs)
    assert pattern(7) == dropped and pattern(8) != dropped


def test_count_limits_how_often_a_fault_fires(paper_config):
    loss = DatagramLoss("four", direction=Direction.REQUEST, count=4)
    assert [loss.drops_request(Op.GET, 0.0) for _ in range(6)] == [True] * 4 + [False] * 2
    assert loss.fired == 4


def test_a_delayed_answer_arrives_late_with_its_value(paper_config):
    delay = ResponseDelay("late", delay=0.5)
    env, _, transport = wire(paper_config, delay)
    at, ok, value = outcome(env, transport.get(signal_oids(1)))
    assert ok and at == pytest.approx(LATENCY + 0.5)
    assert len(value) == 3  # reds, yellows, greens of group 1
    assert delay.fired == 1


def test_an_answer_later_than_tau_udp_fails_the_request_and_is_discarded(paper_config):
    delay = ResponseDelay("too-late", delay=1.5)
    env, surface, transport = wire(paper_config, delay)
    at, ok, value = outcome(env, transport.set(CALL_1_5))
    assert (at, ok) == (pytest.approx(TAU), False)
    assert isinstance(value, CommunicationTimeout)
    assert surface.controller.control[ControlColumn.VEH_CALL] == frozenset({1, 5})  # the SET itself arrived
    assert transport.late_discarded == 0
    env.run(until=LATENCY + 1.5 + 0.01)
    assert transport.late_discarded == 1


def test_jitter_spreads_delays_around_the_mean(paper_config):
    delay = ResponseDelay("jitter", delay=0.3, jitter=0.2, seed=3)
    drawn = [delay.response_delay(Op.GET, 0.0) for _ in range(500)]
    assert min(drawn) >= 0.1 and max(drawn) <= 0.5
    assert max(drawn) - min(drawn) > 0.3
    assert sum(drawn) / len(drawn) == pytest.approx(0.3, abs=0.03)


def test_error_responses_refuse_without_acting_inside_the_window_only(paper_config):
    errors = ErrorResponses("generr", status=ErrorStatus.GEN_ERR, ops=frozenset({Op.SET}), window=Window(0.0, 1.0))
    env, surface, transport = wire(paper_config, errors)
    at, ok, value = outcome(env, transport.set(CALL_1_5))
    assert not ok and isinstance(value, SnmpError) and value.status is ErrorStatus.GEN_ERR
    assert at < 0.1
    assert surface.sets == 0
    env.run(until=1.0)
    assert outcome(env, transport.set(CALL_1_5))[1] is True
    assert surface.sets == 1 and errors.fired == 1


def test_error_status_names_follow_rfc_3416():
    assert error_status("genErr") is ErrorStatus.GEN_ERR
    assert error_status("noSuchName") is ErrorStatus.NO_SUCH_NAME
    assert error_status("NOT_WRITABLE") is ErrorStatus.NOT_WRITABLE
    with pytest.raises(ValueError, match="unknown SNMP error status"):
        error_status("oops")


def test_requests_no_fault_touches_are_the_inner_transports_own(paper_config):
    env, _, transport = wire(paper_config, DatagramLoss("later", window=Window(5.0, 6.0)))
    request = transport.get(signal_oids(1))
    assert outcome(env, request)[:2] == (pytest.approx(LATENCY), True)


def test_a_stuck_controller_acknowledges_calls_but_ignores_them(paper_config):
    env = simpy.Environment()
    stuck = StuckController("stuck", window=Window(0.0, 5.0))
    target = FaultTarget(env, paper_config, faults=[stuck])
    omit = (control_oid(ControlColumn.PHASE_OMIT, 1), 0b0000_0100)  # phase 3
    ok = outcome(env, target.transport.set([*CALL_1_5, omit]))[1]
    assert ok
    c = target.mib.controller  # the NTCIP database: a SET is stored before the phase logic takes it
    assert c.control[ControlColumn.VEH_CALL] == frozenset()
    assert c.control[ControlColumn.PHASE_OMIT] == frozenset({3})  # other objects in the PDU still act
    assert stuck.fired == 1
    env.run(until=5.0)
    assert c.greens == frozenset({2, 6})  # no transition: the call was never placed
    assert outcome(env, target.transport.set(CALL_1_5))[1]
    assert c.control[ControlColumn.VEH_CALL] == frozenset({1, 5})
    assert stuck.fired == 1
    env.run(until=11.0)  # after the 3 s yellow and 2 s red clearance of 2 and 6
    assert c.greens == frozenset({1, 5})


def test_a_rebooting_controller_is_silent_then_back_in_its_startup_phases_with_controls_cleared(paper_config):
    env = simpy.Environment()
    reboot = Reboot("reboot", at=20.0, silent_for=5.0)
    target = FaultTarget(env, paper_config, faults=[reboot])
    c = target.controller
    outcome(env, target.transport.set([(control_oid(ControlColumn.VEH_CALL, 1), 0b1000_1000)]))  # phases 4, 8
    env.run(until=20.0)
    assert c.greens == frozenset({4, 8}) and c.control_status is UnitControlStatus.SYSTEM_CONTROL
    env.run(until=21.0)
    at, ok, value = outcome(env, target.transport.get(signal_oids(1)))
    assert (at, ok) == (pytest.approx(22.0), False) and isinstance(value, CommunicationTimeout)
    assert reboot.fired == 1 and reboot.details == {"requests_unanswered": 1}
    env.run(until=25.05)
    assert c.greens == frozenset({2, 6})  # the config's start-up phases
    assert all(not phases for phases in c.control.values())
    assert c.control_status is UnitControlStatus.OTHER
    assert reboot.details["powered_up"] == 1
    env.run(until=35.05)
    target.base.clock.catch_up()  # the event-driven clock counts the quiet ticks when asked
    assert c.tick == 100  # ticking again at 0.1 s from power-up, not catching up
    assert outcome(env, target.transport.get(signal_oids(1)))[1]


def run_with(config: IntersectionConfig, faults, *, action_type=ActionType.SELECTION, agent=None, duration=60.0,
             monitors: list | None = None):
    def factory(env, cfg, *, seed, fast_path, hires):
        target = FaultTarget(env, cfg, seed=seed, faults=faults, fast_path=fast_path, hires=hires)
        if monitors is not None:
            monitors.append(IndicationMonitor(env, target.controller, cfg))
        return target

    def configure(run):
        for f in faults:
            f.on_run(run, run.intersection)

    return run_spec(RunSpec(config, action_type, agent, duration, seed=1), target=factory,
                       configure=configure)


def test_slow_steps_raise_drift_records_isolated_or_consecutive(paper_config):
    isolated = SlowSteps("isolated", start=10.0, count=4, cost=0.5, consecutive=1, gap=2)
    run = run_with(paper_config, [isolated])
    drifts = run.testbed.events.of(Kind.DRIFT)
    assert len(drifts) == 4 == isolated.fired
    assert [d["consecutive"] for d in drifts] == [1, 1, 1, 1]
    assert [d["t"] for d in drifts] == pytest.approx([10.0, 10.75, 11.5, 12.25])
    assert all(d["took_s"] == 0.5 for d in drifts)
    assert not run.testbed.events.of(Kind.TIMEOUT_ENTERED)

    consecutive = SlowSteps("run", start=10.0, count=5, cost=0.5, consecutive=5)
    run = run_with(paper_config, [consecutive])
    assert [d["consecutive"] for d in run.testbed.events.of(Kind.DRIFT)] == [1, 2, 3, 4, 5]
    (timeout,) = run.testbed.events.of(Kind.TIMEOUT_ENTERED)
    assert timeout["reason"] == "drift" and timeout["t"] == pytest.approx(11.0)


def test_slow_steps_wrap_the_real_step_cost():
    slow = SlowSteps("slow", start=0.0, count=1, cost=0.4)
    calls = []
    cost = slow.wrap(modeled_cost, lambda: 0.0)
    assert cost(lambda: calls.append(1)) == 0.4
    assert cost(lambda: calls.append(2)) == 0.0
    assert calls == [1, 2]  # the step itself ran both times


@pytest.mark.parametrize("action_type", list(ActionType))
def test_every_bad_action_is_one_the_converter_refuses(paper_config, action_type):
    converter = ActionConverter(paper_config, action_type)
    for kind in BAD_KINDS[action_type]:
        value = bad_value(kind, action_type, paper_config)
        with pytest.raises(ActionError):
            converter.convert(value)
    for kind in set(BadActionKind) - BAD_KINDS[action_type]:
        with pytest.raises(ValueError, match="cannot issue"):
            bad_value(kind, action_type, paper_config)


def test_the_conflict_pair_is_really_conflicting(paper_config):
    a, b = bad_value(BadActionKind.CONFLICT, ActionType.SELECTION, paper_config)
    assert not paper_config.compatible(a, b)
    assert math.isnan(bad_value(BadActionKind.NAN, ActionType.DURATION, paper_config))


def test_bad_actions_replace_the_agents_actions_and_are_refused(paper_config):
    bad = BadActions("bad", action=BadActionKind.CONFLICT, window=Window(5.0), count=2)
    run = run_with(paper_config, [bad])
    refused = run.testbed.events.of(Kind.ACTION_REFUSED)
    assert bad.fired == 2 and [r["reason"] for r in refused] == ["conflict", "conflict"]
    received = {r["action_id"]: r["value"] for r in run.testbed.events.of(Kind.ACTION_RECEIVED)}
    assert [received[r["action_id"]] for r in refused] == [[1, 7], [1, 7]]


def test_action_bursts_arrive_while_on_hold_and_are_dropped(paper_config):
    burst = ActionBurst("burst", size=3, window=Window(0.0, 25.0))
    run = run_with(paper_config, [burst], action_type=ActionType.SWITCH, agent="fixed-cycle")
    dropped = run.testbed.events.of(Kind.ACTION_DROPPED)
    assert burst.fired == 9  # commands at 0, 10 and 20 s, 3 extra actions each
    assert len(dropped) == 9 and {d["state"] for d in dropped} == {"on_hold"}
    assert len(run.testbed.events.of(Kind.COMMAND_DISPATCHED)) == 6


def test_keepalive_suppressed_lets_the_backup_time_run_out(paper_config):
    config = paper_config.with_middleware(control_interval=60.0)  # no command SET between 0 and 60 s

    def statuses(faults):
        monitors = []
        run = run_with(config, faults, action_type=ActionType.SWITCH, agent="fixed-cycle", duration=45.0,
                       monitors=monitors)
        return monitors[0].status_first_seen, run.testbed.events.of(Kind.SET_SENT)

    seen, sets = statuses([])
    assert UnitControlStatus.BACKUP_MODE not in seen
    t0 = next(r["t"] for r in sets if r["purpose"] == "command")  # the command's SET, right after start-up
    assert [r["t"] for r in sets if r["purpose"] == "keepalive"] == pytest.approx([t0 + 10, t0 + 20, t0 + 30, t0 + 40])
    off = KeepaliveSuppressed("off")
    seen, sets = statuses([off])
    # 30 s after the command's SET took effect (the next tick plus one tick of call processing), to a tick.
    assert 30.1 <= seen[UnitControlStatus.BACKUP_MODE] <= 30.35
    assert not any(r["purpose"] == "keepalive" for r in sets)
    assert off.fired == 4  # at 10, 20, 30 and 40 s a refresh was due
    short = KeepaliveSuppressed("short", window=Window(0.0, 15.0))
    seen, sets = statuses([short])
    assert UnitControlStatus.BACKUP_MODE not in seen  # switched back on in time
    assert [r["t"] for r in sets if r["purpose"] == "keepalive"] == pytest.approx([t0 + 20, t0 + 30, t0 + 40])
    assert short.fired == 1


def lit(greens=(), yellows=(), overlap_greens=(), overlap_yellows=()) -> SimpleNamespace:
    """What a controller shows, as the monitor samples it."""
    return SimpleNamespace(greens=frozenset(greens), yellows=frozenset(yellows),
                           overlap_greens=frozenset(overlap_greens), overlap_yellows=frozenset(overlap_yellows),
                           flash_status=UnitFlashStatus.NOT_FLASH, control_status=UnitControlStatus.SYSTEM_CONTROL,
                           control={c: frozenset() for c in ControlColumn})


def test_the_monitor_sees_conflicting_indications_and_mmu_flash(paper_config):
    env = simpy.Environment()
    shown = lit({2, 6})
    monitor = IndicationMonitor(env, shown, paper_config)
    env.run(until=1.0)
    assert monitor.samples == 10 and not monitor.conflicts and monitor.mmu_flash_at is None
    shown.yellows = frozenset({7})
    shown.flash_status = UnitFlashStatus.MMU
    env.run(until=1.2)
    assert [c.conflict for c in monitor.conflicts] == [Conflict(2, 7), Conflict(6, 7)] * 2
    assert monitor.mmu_flash_at == pytest.approx(1.05)


def test_the_monitor_sees_an_overlap_lit_beside_a_phase_it_conflicts_with(city_config):
    # The city's right-turn overlap A shows with 8 and 5; 6 runs beside neither.
    env = simpy.Environment()
    shown = lit({2, 6}, overlap_greens={1}, overlap_yellows={5})  # A green, E (flashing beside 2) yellow
    monitor = IndicationMonitor(env, shown, city_config)
    env.run(until=0.2)
    assert [(c.t, c.conflict) for c in monitor.conflicts] == [
        (pytest.approx(0.05), Conflict(1, 6, overlap=True)), (pytest.approx(0.15), Conflict(1, 6, overlap=True))]
    assert str(monitor.conflicts[0].conflict) == "overlap A and phase 6"
