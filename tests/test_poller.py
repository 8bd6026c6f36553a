"""The signal-state poller and cache, in virtual time against the in-process emulator."""

from __future__ import annotations

import math
from collections.abc import Sequence

import pytest
import simpy

from emulator.controller import Controller
from emulator.mib import MibView
from hils.config import IntersectionConfig
from hils.events import EventLog, Kind
from hils.manager import State
from hils.middleware import Middleware
from hils.ntcip import ErrorStatus, Oid, SignalState, SnmpError, signal_oids
from hils.poller import Poller, SignalCache, Snapshot
from hils.transport import LocalTransport


class Surface:
    """The emulator's MIB view, counting GETs and failing them on demand."""

    def __init__(self, env: simpy.Environment, mib: MibView) -> None:
        self.env = env
        self.mib = mib
        self.gets: list[tuple[float, tuple[Oid, ...]]] = []
        self.failing = False
        self.plan: list[bool] = []  # per GET: True = fail; used up before ``failing`` applies

    def get_many(self, oids: Sequence[Oid]) -> tuple[int | bytes, ...]:
        self.gets.append((self.env.now, tuple(oids)))
        fail = self.plan.pop(0) if self.plan else self.failing
        if fail:
            raise SnmpError(ErrorStatus.GEN_ERR, 1, "injected by the test")
        return self.mib.get_many(oids)

    def set_many(self, varbinds: Sequence[tuple[Oid, int]]) -> None:
        self.mib.set_many(varbinds)


class Rig:
    """A controller on an environment, reached through a counting surface."""

    def __init__(self, config: IntersectionConfig, **transport_options: float) -> None:
        self.env = simpy.Environment()
        self.config = config
        self.controller = Controller(config)
        self.surface = Surface(self.env, MibView(self.controller))
        self.transport = LocalTransport(self.env, self.surface, tau_udp=config.middleware.tau_udp,
                                        **transport_options)
        self.env.process(self.controller.process(self.env))
        self.log = EventLog()
        self.log.bind(lambda: self.env.now)
        self.failures: list[tuple[float, str]] = []

    def poller(self, rate_hz: float = 10.0, n_timeout: int = 5) -> Poller:
        cache = SignalCache()
        poller = Poller(self.env, self.transport, cache, self.log, groups=self.config.groups, rate_hz=rate_hz,
                        n_timeout=n_timeout, on_failure=lambda why: self.failures.append((self.env.now, why)))
        self.env.process(poller.run())
        return poller

    def middleware(self) -> Middleware:
        mw = Middleware(self.env, self.transport, self.config, "selection", self.log)
        mw.start()
        self.env.run(until=mw.ready)
        return mw


@pytest.mark.parametrize("rate_hz", [10, 50, 100])
def test_poll_rate_and_one_get_of_reds_yellows_greens_per_poll(paper_config, rate_hz: int) -> None:
    rig = Rig(paper_config)
    poller = rig.poller(rate_hz)
    rig.env.run(until=10.0)
    expected = 10 * rate_hz
    assert abs(poller.polls - expected) <= 1
    assert len(rig.surface.gets) == poller.polls
    assert all(oids == signal_oids(1) for _, oids in rig.surface.gets)
    assert len(signal_oids(1)) == 3
    assert poller.counts["answered"] == poller.polls and poller.elided == 0  # no change feed: every poll is sent
    assert [r["greens"] for r in rig.log.of(Kind.POLL)] == [(2, 6)]  # one record: the state never changed
    # Polls sit on a fixed grid, so the rate does not drift with the response time.
    for k, (t, _) in enumerate(rig.surface.gets):
        assert math.isclose(t, k / rate_hz, abs_tol=1e-6)


def test_poll_reads_what_the_controller_shows(paper_config) -> None:
    rig = Rig(paper_config)
    poller = rig.poller()
    rig.env.run(until=2.0)
    snap = poller.cache.snapshot
    assert snap.state == SignalState(rig.controller.reds, rig.controller.yellows, rig.controller.greens)
    assert snap.state.greens == frozenset({2, 6})
    assert snap.seq == poller.polls
    assert snap.t <= rig.env.now


def test_cache_notifies_on_change_only_with_time_and_sequence() -> None:
    cache = SignalCache()
    changes: list[tuple[Snapshot, bool]] = []
    every: list[tuple[Snapshot, bool]] = []
    cache.subscribe(lambda snap, changed: changes.append((snap, changed)))
    cache.subscribe(lambda snap, changed: every.append((snap, changed)), every_poll=True)
    a = SignalState(frozenset({1, 3, 4, 5, 7, 8}), frozenset(), frozenset({2, 6}))
    b = SignalState(frozenset({1, 3, 4, 5, 7, 8}), frozenset({2, 6}), frozenset())
    assert cache.state is None
    assert cache.update(a, 0.1, 1) is True
    assert cache.update(a, 0.2, 2) is False
    assert cache.update(b, 0.3, 3) is True
    assert cache.update(b, 0.4, 4) is False
    assert [(s.state, s.t, s.seq, c) for s, c in changes] == [(a, 0.1, 1, True), (b, 0.3, 3, True)]
    assert [(s.seq, c) for s, c in every] == [(1, True), (2, False), (3, True), (4, False)]
    assert cache.snapshot == Snapshot(b, 0.4, 4)


def test_n_timeout_lost_polls_report_one_failure(paper_config) -> None:
    rig = Rig(paper_config, loss=1.0)
    poller = rig.poller(n_timeout=5)
    rig.env.run(until=20.0)
    # Each lost GET fails tau_udp (1 s) after it went out; polls keep their grid meanwhile, so the fifth
    # one, sent 4 periods after the first, reports, and only that one.
    assert len(rig.failures) == 1
    assert math.isclose(rig.failures[0][0], 4 * 0.1 + paper_config.middleware.tau_udp)
    assert "5 consecutive polls failed" in rig.failures[0][1]
    assert poller.consecutive_failures >= 19
    failed = rig.log.of(Kind.POLL_FAILED)
    assert [r["consecutive"] for r in failed[:6]] == [1, 2, 3, 4, 5, 6]
    assert "CommunicationTimeout" in failed[0]["error"]


def test_a_success_in_between_resets_the_failure_count(paper_config) -> None:
    rig = Rig(paper_config)
    rig.surface.plan = [True] * 4 + [False] + [True] * 4 + [False]
    poller = rig.poller(n_timeout=5)
    rig.env.run(until=2.0)
    assert rig.failures == []
    assert poller.consecutive_failures == 0
    assert [r["consecutive"] for r in rig.log.of(Kind.POLL_FAILED)] == [1, 2, 3, 4, 1, 2, 3, 4]
    rig.surface.plan = [True] * 5
    rig.env.run(until=3.0)
    assert len(rig.failures) == 1


def test_failures_put_the_manager_in_timeout_and_polling_halts(paper_config) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.env.run(until=2.0)
    assert mw.state is State.IDLE
    rig.surface.failing = True
    rig.env.run(until=3.0)
    assert mw.state is State.TIMEOUT and mw.timeout_flag
    (entered,) = rig.log.of(Kind.TIMEOUT_ENTERED)
    assert entered["reason"] == "communication"
    assert len(rig.log.of(Kind.POLL_FAILED)) == paper_config.middleware.n_timeout
    assert mw.poller.halted

    gets = len(rig.surface.gets)
    rig.env.run(until=30.0)
    assert len(rig.surface.gets) == gets, "a GET was made while halted"
    assert len(rig.log.of(Kind.TIMEOUT_ENTERED)) == 1

    rig.surface.failing = False
    assert rig.env.run(until=mw.recover()) is True
    assert mw.state is State.IDLE and not mw.poller.halted
    rig.env.run(until=31.0)
    assert len(rig.surface.gets) >= gets + 5, "polling did not resume after recovery"
    assert mw.cache.snapshot.t > 30.0 and mw.cache.snapshot.seq == mw.poller.polls


def test_transition_is_verified_on_the_first_poll_that_shows_it(paper_config) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.env.run(until=5.0)  # phases 2 and 6 have served their minimum green
    mw.submit((3, 7))
    rig.env.run(until=16.0)
    (dispatched,) = rig.log.of(Kind.COMMAND_DISPATCHED)
    (verified,) = rig.log.of(Kind.TRANSITION_VERIFIED)
    polls = [r for r in rig.log.of(Kind.POLL) if r["t"] >= dispatched["t"]]
    first = next(r for r in polls if {3, 7} <= set(r["greens"]))
    assert verified["poll_id"] == first["poll_id"]
    assert verified["t"] == first["t"]
    before = [r for r in polls if r["poll_id"] < first["poll_id"]]
    assert before and not any({3, 7} <= set(r["greens"]) for r in before)
    # Yellow 3 s + red clearance 2 s, seen within one poll period.
    assert 5.0 <= verified["hold_s"] <= 5.0 + 0.1 + 0.01
    assert mw.state is State.IDLE


def test_lost_polls_do_not_hold_the_next_back(paper_config) -> None:
    rig = Rig(paper_config, loss=0.2)
    poller = rig.poller(n_timeout=50)  # count failures without reporting one
    answered: list[Snapshot] = []
    poller.cache.subscribe(lambda snap, _changed: answered.append(snap), every_poll=True)
    rig.env.run(until=60.0)
    # Every slot of the grid got its poll, lost ones included (a lost GET does not wait tau_udp).
    assert poller.polls == 600 and poller.elided == 0
    assert len(answered) == poller.counts["answered"]
    # (lost polls of the last second have not timed out yet)
    assert 0.7 * 600 < len(answered) < 0.9 * 600 and 590 <= len(answered) + poller.failed <= 600
    assert all(math.isclose(snap.t, (snap.seq - 1) / 10 + 0.002, abs_tol=1e-3) for snap in answered)
    assert not rig.failures


class Reordering:
    """A transport whose GETs answer after the latency given per request (in order of the requests)."""

    def __init__(self, env: simpy.Environment, mib: MibView, latencies: list[float]) -> None:
        self.env, self.mib, self.latencies = env, mib, latencies
        self.change_feed = None

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        answer = self.env.event()
        values = self.mib.get_many(oids)
        self.env.timeout(self.latencies.pop(0) if self.latencies else 0.002).callbacks.append(
            lambda _ev: answer.succeed(values))
        return answer


def test_an_answer_older_than_the_newest_applied_is_discarded(paper_config) -> None:
    env = simpy.Environment()
    controller = Controller(paper_config)
    env.process(controller.process(env))
    log = EventLog()
    log.bind(lambda: env.now)
    # Poll 2 answers after 0.25 s, after polls 3 and 4 have answered.
    transport = Reordering(env, MibView(controller), [0.002, 0.25])
    poller = Poller(env, transport, SignalCache(), log, groups=1, rate_hz=10.0, n_timeout=5,
                    on_failure=lambda why: None)
    applied: list[int] = []
    poller.cache.subscribe(lambda snap, _changed: applied.append(snap.seq), every_poll=True)
    env.process(poller.run())
    env.run(until=1.0)
    assert 2 not in applied and applied == sorted(applied) and applied[:3] == [1, 3, 4]
    assert poller.late == 1 and poller.cache.snapshot.seq == applied[-1]


def test_the_first_answer_after_failed_polls_is_logged_even_when_nothing_changed(paper_config) -> None:
    """The state seen is known again from that answer on: the log says when, so that the plots' no-data stretch
    ends there and not at the next change of the signal."""
    rig = Rig(paper_config)
    rig.surface.plan = [False] * 3 + [True] * 2 + [False] * 5
    rig.poller(n_timeout=5)
    rig.env.run(until=1.0)  # the start-up green rests: no change at all after the first poll
    polls = rig.log.of(Kind.POLL)
    failed = rig.log.of(Kind.POLL_FAILED)
    assert [r["poll_id"] for r in failed] == [4, 5]
    assert [r["poll_id"] for r in polls] == [1, 6], "the first poll, and the first answer after the failures"
    assert polls[1]["greens"] == polls[0]["greens"]
