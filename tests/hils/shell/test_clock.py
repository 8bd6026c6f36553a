"""The clock drivers: virtual time runs fast and deterministically, wall-clock time keeps to the wall.

Timing assertions use one-sided tolerances (never early, late by less than a
generous bound) so that a loaded CI machine does not make them flaky.
"""

from __future__ import annotations

import asyncio
import random
import signal
import time

import numpy as np
import pytest
import simpy

from hils.shell.clock import LatenessStats, VirtualClock, WallClockDriver

SLACK = 0.5  # seconds a wall-clock step may be late on a busy machine


@pytest.fixture
def driver():
    drv = WallClockDriver(simpy.Environment())
    yield drv
    drv.close()


def ticker(env: simpy.Environment, period: float, count: int, log: list[tuple[float, float]]):
    for _ in range(count):
        yield env.timeout(period)
        log.append((env.now, time.perf_counter()))


def test_timeouts_run_at_their_wall_time(driver):
    log: list[tuple[float, float]] = []
    driver.env.process(ticker(driver.env, 0.05, 10, log))
    start = time.perf_counter()
    driver.run_sync(until=0.6, handle_signals=False)
    elapsed = time.perf_counter() - start

    assert 0.6 <= elapsed < 0.6 + SLACK
    assert driver.env.now == 0.6
    assert [round(t, 9) for t, _ in log] == [round(0.05 * k, 9) for k in range(1, 11)]
    for sim_t, wall in log:
        assert sim_t <= wall - start < sim_t + SLACK


def test_lateness_is_measured_for_every_step_and_reported_to_the_hook(driver):
    seen: list[tuple[float, float]] = []
    driver.on_lateness = lambda due, late: seen.append((due, late))
    driver.env.process(ticker(driver.env, 0.05, 6, []))
    driver.run_sync(until=0.35, handle_signals=False)

    stats = driver.lateness.summary()
    # Process start plus six timeouts, each resuming the process.
    assert stats.count == len(seen) >= 7
    assert all(late >= 0.0 for _, late in seen)
    assert 0.0 <= stats.mean <= stats.p99 <= stats.max < SLACK
    assert stats.max == max(late for _, late in seen)
    assert [due for due, _ in seen] == sorted(due for due, _ in seen)


def test_lateness_shows_a_blocked_loop(driver):
    env = driver.env
    seen: dict[float, float] = {}
    driver.on_lateness = lambda due, late: seen.setdefault(due, late)

    def hog():
        yield env.timeout(0.1)
        time.sleep(0.08)  # a step that blocks the loop, as a slow agent would

    def victim():
        yield env.timeout(0.12)

    env.process(hog())
    env.process(victim())
    driver.run_sync(until=0.3, handle_signals=False)

    assert seen[0.12] >= 0.05
    assert driver.lateness.max >= 0.05


def test_deliver_resumes_a_waiting_process_at_the_wall_mapped_time(driver):
    env = driver.env
    result = {}

    def waiter(event):
        value = yield event
        result["value"], result["at"] = value, env.now
        driver.stop()

    event = env.event()
    env.process(waiter(event))
    env.process(ticker(env, 10.0, 1, []))  # the next timer is far away: only deliver can wake the driver
    driver.loop.call_later(0.3, driver.deliver, event, 42)
    start = time.perf_counter()
    driver.run_sync(handle_signals=False)

    assert result["value"] == 42
    assert 0.3 <= result["at"] < 0.3 + SLACK
    assert time.perf_counter() - start < 0.3 + SLACK


def test_deliver_with_an_exception_fails_the_event(driver):
    env = driver.env
    caught = []

    def waiter(event):
        try:
            yield event
        except KeyError as exc:
            caught.append((exc, env.now))

    event = env.event()
    env.process(waiter(event))
    driver.loop.call_later(0.1, lambda: driver.deliver(event, exc=KeyError("gone")))
    driver.run_sync(until=0.5, handle_signals=False)

    assert len(caught) == 1
    assert caught[0][0].args == ("gone",)
    assert 0.1 <= caught[0][1] < 0.1 + SLACK


def test_deliver_leaves_an_already_triggered_event_alone(driver):
    env = driver.env
    event = env.event()
    event.succeed("first")
    driver.loop.call_later(0.05, driver.deliver, event, "second")
    driver.run_sync(until=0.2, handle_signals=False)
    assert event.value == "first"


def test_stop_ends_run_cleanly_and_run_resumes_without_a_time_jump(driver):
    env = driver.env
    log: list[tuple[float, float]] = []
    env.process(ticker(env, 0.05, 1000, log))
    driver.loop.call_later(0.3, driver.stop)
    start = time.perf_counter()
    driver.run_sync(handle_signals=False)

    assert 0.3 <= time.perf_counter() - start < 0.3 + SLACK
    stopped_at = env.now
    assert 0.25 <= stopped_at < 0.3 + SLACK
    assert not driver.running

    ticks_before = len(log)
    time.sleep(0.2)  # wall time passes while stopped; sim time must not jump over it
    driver.loop.call_later(0.1, driver.stop)
    driver.run_sync(handle_signals=False)
    assert stopped_at < env.now < stopped_at + 0.1 + SLACK
    assert len(log) > ticks_before


def test_a_process_can_stop_the_driver(driver):
    env = driver.env

    def scenario():
        yield env.timeout(0.1)
        driver.stop()
        yield env.timeout(0.1)
        pytest.fail("the driver kept stepping after stop()")

    env.process(scenario())
    driver.run_sync(until=1.0, handle_signals=False)
    assert env.now == pytest.approx(0.1)


def test_sigint_stops_run_sync_without_keyboard_interrupt(driver):
    previous = signal.getsignal(signal.SIGINT)
    env = driver.env
    env.process(ticker(env, 0.05, 1000, []))
    driver.loop.call_later(0.2, signal.raise_signal, signal.SIGINT)
    driver.run_sync()

    assert 0.15 <= env.now < 0.2 + SLACK
    assert signal.getsignal(signal.SIGINT) is previous


def test_exception_in_a_process_propagates_from_run(driver):
    env = driver.env

    def broken():
        yield env.timeout(0.05)
        raise ZeroDivisionError("model bug")

    env.process(broken())
    with pytest.raises(ZeroDivisionError, match="model bug"):
        driver.run_sync(until=1.0, handle_signals=False)
    assert not driver.running


def test_run_must_be_awaited_on_the_drivers_loop(driver):
    with pytest.raises(RuntimeError, match=r"driver\.loop"):
        asyncio.run(driver.run(until=0.1))


def test_driver_on_a_loop_passed_in_leaves_it_open():
    loop = asyncio.new_event_loop()
    try:
        drv = WallClockDriver(simpy.Environment(), loop=loop)
        assert drv.loop is loop
        loop.run_until_complete(drv.run(until=0.05))
        drv.close()
        assert not loop.is_closed()
        assert drv.env.now == 0.05
    finally:
        loop.close()


def _until_trace(env: simpy.Environment) -> list[float]:
    seen: list[float] = []

    def proc():
        while True:
            yield env.timeout(0.25)
            seen.append(env.now)

    env.process(proc())
    return seen


@pytest.mark.parametrize("clock_kind", ["virtual", "wall"])
def test_until_follows_simpy_rule_under_both_clocks(clock_kind):
    env = simpy.Environment()
    seen = _until_trace(env)
    clock = VirtualClock(env) if clock_kind == "virtual" else WallClockDriver(env)
    try:
        run = clock.run if clock_kind == "virtual" else lambda until: clock.run_sync(until, handle_signals=False)
        run(0.5)
        # The timeout due exactly at `until` stays queued; env.now ends at `until`.
        assert seen == [0.25]
        assert env.now == 0.5
        run(0.75)
        assert seen == [0.25, 0.5]
        with pytest.raises(ValueError, match="later than the current sim time"):
            run(0.75)
    finally:
        if clock_kind == "wall":
            clock.close()


def _random_walk(seed: int, hours: float) -> tuple[float, int, list[float]]:
    env = simpy.Environment()
    rng = random.Random(seed)
    samples: list[float] = []
    state = {"x": 0.0, "n": 0}

    def walker():
        while True:
            yield env.timeout(0.1)
            state["x"] += rng.gauss(0.0, 1.0)
            state["n"] += 1
            if state["n"] % 3600 == 0:
                samples.append(state["x"])

    env.process(walker())
    VirtualClock(env).run(until=hours * 3600.0)
    return state["x"], state["n"], samples


def test_virtual_clock_runs_hours_in_a_moment_and_deterministically():
    start = time.perf_counter()
    first = _random_walk(seed=7, hours=4.0)
    elapsed = time.perf_counter() - start
    second = _random_walk(seed=7, hours=4.0)

    assert elapsed < 10.0  # 4 h of 0.1 s ticks: 144 000 events, typically ~0.3 s
    assert first[1] >= 143_999  # the tick due exactly at 4 h stays queued
    assert first == second
    assert _random_walk(seed=8, hours=0.1) != _random_walk(seed=7, hours=0.1)


def test_lateness_stats_match_exact_statistics():
    rng = np.random.default_rng(3)
    values = rng.exponential(0.001, size=50_000)
    stats = LatenessStats(reservoir=8192)
    for v in values:
        stats.add(float(v))

    summary = stats.summary()
    assert summary.count == 50_000
    assert summary.mean == pytest.approx(values.mean(), rel=1e-9)
    assert summary.max == values.max()
    assert summary.p99 == pytest.approx(np.percentile(values, 99), rel=0.15)


def test_lateness_stats_empty_and_invalid():
    summary = LatenessStats().summary()
    assert summary.count == 0
    assert np.isnan(summary.mean) and np.isnan(summary.max) and np.isnan(summary.p99)
    with pytest.raises(ValueError, match="reservoir"):
        LatenessStats(reservoir=0)


def test_an_agent_is_asked_at_once_in_virtual_time_and_in_a_thread_at_the_wall_clock() -> None:
    """Virtual time: the call takes no simulated time and its error is kept for the asker. Wall clock: the
    environment goes on stepping while the call sleeps, and the answer arrives as a completion."""
    env = simpy.Environment()
    clock = VirtualClock(env)
    answer = clock.ask(lambda x: x + 1, 41)
    assert answer.done and answer.value == 42 and answer.answered_at == answer.asked_at == env.now == 0.0
    failed = clock.ask(lambda: 1 / 0)
    assert failed.done and isinstance(failed.error, ZeroDivisionError)

    env = simpy.Environment()
    driver = WallClockDriver(env)
    ticks: list[float] = []

    def ticking():
        while True:
            yield env.timeout(0.05)
            ticks.append(env.now)

    env.process(ticking())
    try:
        answer = driver.ask(lambda: time.sleep(0.4) or "done")
        assert not answer.done
        driver.advance(2.0, [answer.event])
        assert answer.done and answer.value == "done" and answer.error is None
        assert answer.answered_at == pytest.approx(0.4, abs=0.15)
        assert len([t for t in ticks if t < answer.answered_at]) >= 5, "the environment stepped while it slept"
        failing = driver.ask(lambda: 1 / 0)
        driver.advance(env.now + 2.0, [failing.event])
        assert failing.done and isinstance(failing.error, ZeroDivisionError)
    finally:
        driver.close()
