"""Wall-clock runs: the same Run on the same kind of environment, stepped to the wall clock,
talking SNMP over UDP to a real controller or to `hils emulator serve`.

Only two things differ from a virtual-time run: the driver (:class:`hils.clock.WallClockDriver`)
and the transport (:class:`hils.snmp.SnmpTransport`). A simulation step's cost is what it
really took, plus how late the driver started it, so that drift detection sees both.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import simpy

from hils.clock import WallClockDriver
from hils.runner import Run, RunResult, RunSpec, Simulation, measured_cost
from hils.snmp import SnmpTarget, SnmpTransport


def run_wire(spec: RunSpec, target_url: str, *, simulation: Simulation | None = None,
             configure: Callable[[Run, Any], None] | None = None) -> RunResult:
    """Run at wall-clock time against an SNMP target for ``spec.duration`` s or until Ctrl-C;
    the calls placed are cleared at the end either way."""
    target = SnmpTarget.parse(target_url)
    t0 = time.perf_counter()
    env = simpy.Environment()
    driver = WallClockDriver(env)
    transport = SnmpTransport(env, driver, target, tau_udp=spec.config.middleware.tau_udp)

    def step_cost(step: Callable[[], Any]) -> float:
        late = max(0.0, driver.sim_now() - env.now)
        return late + measured_cost(step)

    run = Run(spec, env, transport, simulation=simulation, step_cost=step_cost, mode="wall-clock")
    if configure is not None:
        configure(run, target)
    run.start()
    try:
        driver.run_sync(until=spec.duration)
        reason = "duration" if env.now >= spec.duration else "interrupted"
        ending = run.finish(reason)

        def settle():
            yield ending
            # Let an answer to the last poll, already on its way, land before the socket closes.
            yield env.timeout(0.05)
            driver.stop()

        env.process(settle())
        # Bounded: the clearing SET answers or fails within tau_udp.
        driver.run_sync(until=env.now + spec.config.middleware.tau_udp + 1.0)
    finally:
        transport.close()
        driver.close()
    return RunResult(run, target, time.perf_counter() - t0, lateness=driver.lateness.summary())
