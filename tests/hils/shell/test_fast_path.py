"""Virtual time's fast path is switched by the run's flag alone (hils.shell.fastpath): a fault wrapped around the step
cost or the transport is seen wherever it may act, the rest of the run stays on the path the flag says, and the
result is the reference's (``fast_path=False``) record for record."""

from __future__ import annotations

from typing import Any

import pytest

from harness.faults.inject import DatagramLoss, FaultTarget, SlowSteps, Window
from hils import Testbed
from hils.shell.events import Kind
from hils.shell.fastpath import every_step, modeled_cost


class CountingSimulation:
    """A simulation without traffic that notes how many steps each call made it take."""

    def __init__(self) -> None:
        self.lights: dict[str, Any] = {}
        self.calls: list[int] = []

    def step(self) -> None:
        self.calls.append(1)

    def advance(self, steps: int) -> None:
        self.calls.append(steps)


def comparable(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records but for the wall clock and how many polls went out (the fast path sends fewer)."""
    out = []
    for r in records:
        r = {k: v for k, v in r.items() if k != "wall_ns"}
        if r["kind"] == Kind.RUN_ENDED:
            r["polls"] = {k: v for k, v in r["polls"].items() if k not in ("elided", "answered")}
        out.append(r)
    return out


def slow_run(fast_path: bool) -> tuple[list[dict[str, Any]], CountingSimulation, SlowSteps, Any]:
    """Five drifted steps in a row from 30 s on (a drift TIMEOUT), the step cost wrapped by the fault."""
    fault = SlowSteps("slow", start=30.0, count=5, cost=1.0, consecutive=5)
    sim = CountingSimulation()
    with Testbed(sumo=sim, seed=2, duration=120.0, agent="random", fast_path=fast_path,
                 on_reset=lambda tb: fault.on_run(tb, None)) as tb:
        tb.reset()
        tb.run()
        return tb.records, sim, fault, tb.target


def test_a_step_cost_wrapped_in_a_fault_keeps_the_path_the_flag_says() -> None:
    fast, sim, fault, target = slow_run(True)
    reference, ref_sim, ref_fault, ref_target = slow_run(False)
    assert comparable(fast) == comparable(reference)
    assert fault.fired == ref_fault.fired == 5
    assert [r["reason"] for r in fast if r["kind"] == Kind.TIMEOUT_ENTERED] == ["drift"]
    # The same steps, at the same times: one by one in the fault's window, in stretches before and after it.
    assert sum(sim.calls) == sum(ref_sim.calls) and set(ref_sim.calls) == {1}
    assert max(sim.calls) > 1 and len(sim.calls) < len(ref_sim.calls) / 4
    # The controller's quiet ticks are left out on the fast path, all stepped on the reference.
    assert target.clock.steps < 0.3 * 1200 and ref_target.clock is None


def test_a_transport_wrapped_in_a_fault_keeps_the_path_the_flag_says() -> None:
    """Polls go out while the fault may act (its window), and only then; the run is the reference's."""
    runs = {}
    for fast_path in (True, False):
        loss = DatagramLoss("loss", probability=0.3, window=Window(40.0, 55.0), seed=4)

        def target(env: Any, config: Any, *, seed: int, fast_path: bool, hires: bool,
                   loss: DatagramLoss = loss) -> FaultTarget:
            return FaultTarget(env, config, seed=seed, faults=[loss], fast_path=fast_path, hires=hires)

        with Testbed(target=target, seed=4, duration=100.0, agent="random", fast_path=fast_path) as tb:
            tb.reset()
            tb.run()
            runs[fast_path] = (tb.records, loss.fired, tb.target)
    (fast, fired, target), (reference, ref_fired, ref_target) = runs[True], runs[False]
    assert comparable(fast) == comparable(reference) and fired == ref_fired > 0
    polls = fast[-1]["polls"]
    assert polls["elided"] > 0.8 * polls["polls"] and reference[-1]["polls"]["elided"] == 0
    assert target.base.clock.steps < 0.3 * 1000 and ref_target.base.clock is None


def test_a_plain_cost_function_is_refused_and_one_that_sees_every_step_says_so() -> None:
    def cost(step: Any) -> float:
        step()
        return 0.0

    def wrap(plain: bool) -> Any:
        def on_reset(tb: Testbed) -> None:
            tb.step_cost = cost if plain else every_step(cost)
        return on_reset

    sim = CountingSimulation()
    with Testbed(sumo=sim, duration=10.0, agent="random", on_reset=wrap(plain=True)) as tb, pytest.raises(
            TypeError, match="every_step"):
        tb.reset()
    with Testbed(sumo=sim, duration=10.0, agent="random", on_reset=wrap(plain=False)) as tb:
        tb.reset()
        tb.run()
    assert set(sim.calls) == {1} and len(sim.calls) == 40, "a cost that sees every step gets every step"


def test_the_modeled_cost_is_free_forever() -> None:
    assert modeled_cost.free_until(12.5) == float("inf")
    assert modeled_cost(lambda: None) == 0.0
