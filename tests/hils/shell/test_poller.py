"""The poll grid and the signal cache, through the middleware (whose manager judges every poll's fate), in
virtual time against the in-process emulator."""

from __future__ import annotations

import math
from collections.abc import Sequence

import pytest
import simpy

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from hils.control.manager import State
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ErrorStatus, Oid, SignalState, SnmpError, signal_oids
from hils.shell.events import EventLog, Kind
from hils.shell.middleware import Middleware
from hils.shell.poller import SignalCache, Snapshot
from hils.shell.transport import LocalTransport

SIGNAL = tuple(signal_oids(1))


class Surface:
    """The emulator's MIB view, counting GETs and failing signal polls on demand."""

    def __init__(self, env: simpy.Environment, mib: MibView) -> None:
        self.env = env
        self.mib = mib
        self.gets: list[tuple[float, tuple[Oid, ...]]] = []
        self.failing = False
        self.plan: list[bool] = []  # per signal GET: True = fail; used up before ``failing`` applies

    @property
    def polls(self) -> list[float]:
        """When each GET of the signal state reached the controller (the start-up read first)."""
        return [t for t, oids in self.gets if oids == SIGNAL]

    def get_many(self, oids: Sequence[Oid]) -> tuple[int | bytes, ...]:
        self.gets.append((self.env.now, tuple(oids)))
        if tuple(oids) == SIGNAL:
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

    def middleware(self, rate_hz: float = 10.0, n_timeout: int = 5) -> Middleware:
        config = self.config.with_middleware(poll_hz=rate_hz, n_timeout=n_timeout)
        mw = Middleware(self.env, self.transport, config, "selection", self.log)
        mw.start()
        self.env.run(until=mw.ready)
        return mw


@pytest.mark.parametrize("rate_hz", [10, 50, 100])
def test_poll_rate_and_one_get_of_reds_yellows_greens_per_poll(paper_config, rate_hz: int) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware(rate_hz)
    start = rig.env.now
    rig.env.run(until=start + 10.0)
    counts = mw.poll_counts
    polls = rig.surface.polls[1:]  # after the start-up read
    assert abs(counts["polls"] - 10 * rate_hz) <= 1
    assert len(polls) == counts["polls"]
    assert len(SIGNAL) == 3
    assert counts["answered"] == counts["polls"] and counts["elided"] == 0  # no change feed: every poll is sent
    assert [r["greens"] for r in rig.log.of(Kind.POLL)] == [(2, 6)]  # one record: the state never changed
    # Polls sit on a fixed grid, so the rate does not drift with the response time.
    for k, t in enumerate(polls):
        assert math.isclose(t, start + k / rate_hz, abs_tol=1e-6)


def test_poll_reads_what_the_controller_shows(paper_config) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.env.run(until=2.0)
    snap = mw.cache.snapshot
    assert snap.state == SignalState(rig.controller.reds, rig.controller.yellows, rig.controller.greens)
    assert snap.state.greens == frozenset({2, 6})
    assert snap.seq == mw.poller.polls
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


def test_n_timeout_lost_polls_are_one_communication_timeout(paper_config) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.env.run(until=2.0)
    lost_from = rig.env.now
    rig.transport.loss = 1.0
    rig.env.run(until=20.0)
    # Each lost GET fails tau_udp (1 s) after it went out; polls keep their grid meanwhile, so the fifth
    # one, sent 4 periods after the first, is the failure; the polls already on their way are let go.
    (entered,) = rig.log.of(Kind.TIMEOUT_ENTERED)
    first_lost = rig.surface.polls[-1] + 0.1
    assert first_lost >= lost_from
    assert math.isclose(entered["t"], first_lost + 4 * 0.1 + paper_config.middleware.tau_udp)
    assert entered["reason"] == "communication" and "5 consecutive polls failed" in entered["detail"]
    failed = rig.log.of(Kind.POLL_FAILED)
    assert [r["consecutive"] for r in failed] == [1, 2, 3, 4, 5]
    assert "CommunicationTimeout" in failed[0]["error"]
    assert mw.state is State.TIMEOUT and mw.poller.halted


def test_an_outage_shorter_than_tau_udp_is_a_communication_timeout(paper_config) -> None:
    """Eight polls lost in 0.8 s, less than tau_udp: the poll after them is answered before their failures come
    in. In poll order they are eight failed polls in a row: a TIMEOUT, seen tau_udp after the fifth went out."""
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.env.run(until=2.0)

    def outage():
        rig.transport.loss = 1.0
        yield rig.env.timeout(0.8)
        rig.transport.loss = 0.0

    answers: list[Snapshot] = []
    mw.cache.subscribe(lambda snap, _changed: answers.append(snap), every_poll=True)
    rig.env.process(outage())
    rig.env.run(until=6.0)
    failed = rig.log.of(Kind.POLL_FAILED)
    (entered,) = rig.log.of(Kind.TIMEOUT_ENTERED)
    assert [r["consecutive"] for r in failed] == [1, 2, 3, 4, 5]
    assert entered["reason"] == "communication" and entered["t"] == failed[4]["t"]
    overtaking = [a for a in answers if a.seq > failed[-1]["poll_id"] and a.t < failed[0]["t"]]
    assert overtaking, "polls after the outage were answered before its first failure came in"
    assert mw.state is State.TIMEOUT


def test_a_success_in_between_resets_the_failure_count(paper_config) -> None:
    rig = Rig(paper_config)
    mw = rig.middleware()
    rig.surface.plan = [True] * 4 + [False] + [True] * 4 + [False]
    rig.env.run(until=2.0)
    assert mw.state is State.IDLE and not mw.manager.polls_failing
    assert [r["consecutive"] for r in rig.log.of(Kind.POLL_FAILED)] == [1, 2, 3, 4, 1, 2, 3, 4]
    rig.surface.plan = [True] * 5
    rig.env.run(until=3.0)
    assert mw.state is State.TIMEOUT and len(rig.log.of(Kind.TIMEOUT_ENTERED)) == 1


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
    mw = rig.middleware(n_timeout=50)  # count failures without a TIMEOUT
    answered: list[Snapshot] = []
    mw.cache.subscribe(lambda snap, _changed: answered.append(snap), every_poll=True)
    start = rig.env.now
    rig.env.run(until=start + 60.0)
    counts = mw.poll_counts
    # Every slot of the grid got its poll, lost ones included (a lost GET does not wait tau_udp).
    assert counts["polls"] == 600 and counts["elided"] == 0
    assert len(answered) == counts["answered"]
    # (lost polls of the last second have not timed out yet)
    assert 0.7 * 600 < len(answered) < 0.9 * 600 and 590 <= len(answered) + counts["failed"] <= 600
    assert all(math.isclose(snap.t, start + (snap.seq - 1) / 10 + 0.002, abs_tol=1e-3) for snap in answered)
    assert mw.state is State.IDLE


class Reordering:
    """A transport whose signal GETs answer after the latency given per request (in order of the requests, the
    start-up read first); every other request answers after 2 ms."""

    def __init__(self, env: simpy.Environment, mib: MibView, latencies: list[float]) -> None:
        self.env, self.mib, self.latencies = env, mib, latencies

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        values = self.mib.get_many(oids)
        late = self.latencies.pop(0) if tuple(oids) == SIGNAL and self.latencies else 0.002
        return self.env.timeout(late, values)

    def set(self, varbinds: Sequence[tuple[Oid, int]]) -> simpy.Event:
        self.mib.set_many(varbinds)
        return self.env.timeout(0.002)


def test_an_answer_older_than_the_newest_applied_is_discarded(paper_config) -> None:
    env = simpy.Environment()
    controller = Controller(paper_config)
    env.process(controller.process(env))
    log = EventLog()
    log.bind(lambda: env.now)
    # Poll 2 answers after 0.25 s, after polls 3 and 4 have answered.
    transport = Reordering(env, MibView(controller), [0.002, 0.002, 0.25])
    mw = Middleware(env, transport, paper_config, "selection", log)
    applied: list[int] = []
    mw.cache.subscribe(lambda snap, _changed: applied.append(snap.seq), every_poll=True)
    mw.start()
    env.run(until=1.0)
    assert 2 not in applied and applied == sorted(applied) and applied[:4] == [0, 1, 3, 4]
    assert mw.poll_counts["late"] == 1 and mw.cache.snapshot.seq == applied[-1]


def test_the_first_answer_after_failed_polls_is_logged_even_when_nothing_changed(paper_config) -> None:
    """The state seen is known again from that answer on: the log says when, so that the plots' no-data stretch
    ends there and not at the next change of the signal."""
    rig = Rig(paper_config)
    rig.surface.plan = [False] * 4 + [True] * 2 + [False] * 5  # the start-up read, polls 1-3, then 4 and 5 fail
    rig.middleware(n_timeout=5)
    rig.env.run(until=1.0)  # the start-up green rests: no change at all after the start-up read
    polls = rig.log.of(Kind.POLL)
    failed = rig.log.of(Kind.POLL_FAILED)
    assert [r["poll_id"] for r in failed] == [4, 5]
    assert [r["poll_id"] for r in polls] == [0, 6], "the start-up read, and the first answer after the failures"
    assert polls[1]["greens"] == polls[0]["greens"]
