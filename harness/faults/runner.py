"""Running a fault scenario: one Testbed in virtual time, without SUMO, each controller behind a
:class:`~harness.faults.inject.FaultTarget` that carries the faults placed on it and an
:class:`~harness.faults.inject.IndicationMonitor` that samples what it shows; the run's records, its faults and
the samples then go to the judge (:mod:`harness.faults.judge`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from harness.faults.inject import FaultTarget, IndicationMonitor
from harness.faults.judge import FaultScenarioResult, evaluate
from harness.faults.reader import FaultScenario
from hils.agents.builtin import ScheduleAgent
from hils.protocol.config import IntersectionConfig
from hils.run.testbed import Testbed

__all__ = ["run_fault_scenario"]


def run_fault_scenario(scenario: FaultScenario, *, log_path: Path | None = None) -> FaultScenarioResult:
    """Run one fault scenario in virtual time, without SUMO, and judge its expectations."""
    t0 = time.perf_counter()
    faults = scenario.build_faults()
    placed = list(zip(scenario.faults, faults, strict=True))
    monitors: dict[str, IndicationMonitor] = {}

    def target_factory(tls: str) -> Callable[..., FaultTarget]:
        # Each controller's target carries only the faults placed on it: the others' links stay whole.
        here = [fault for spec, fault in placed if spec.acts_at(tls)]

        def make(env: Any, config: IntersectionConfig, *, seed: int, fast_path: bool, hires: bool) -> FaultTarget:
            target = FaultTarget(env, config, seed=seed, faults=here, fast_path=fast_path, hires=hires)
            monitors[tls] = IndicationMonitor(env, target.controller, config)
            return target
        return make

    def configure(run: Testbed) -> None:
        for spec, fault in placed:
            fault.on_run(run, None if spec.intersection is None else run.intersections[spec.intersection])

    with Testbed(None if scenario.network else scenario.config, scenario=scenario.network,
                 action_type=scenario.action_type, target={tls: target_factory(tls) for tls in scenario.intersections},
                 seed=scenario.seed,
                 agent=scenario.agent if scenario.schedule is None else ScheduleAgent(scenario.schedule),
                 duration=scenario.duration, log_path=log_path, recover_after=scenario.recover_after,
                 on_reset=configure) as tb:
        tb.reset_all()
        tb.run()
        records = tb.records
    return evaluate(scenario, records, faults, monitors, wall_s=time.perf_counter() - t0)

