"""SUMO at the wall clock: a minute of the shipped scenario against `hils emulator serve`, SUMO paced
to the clock, its step cost feeding drift detection, and no drift TIMEOUT on this machine."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.bench.processes import start_emulator
from hils import Testbed
from hils.protocol.config import load
from hils.shell.events import Kind

pytestmark = pytest.mark.wallclock


def test_a_minute_of_sumo_at_the_wall_clock_does_not_drift(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    cfg = load()
    try:
        with Testbed(cfg, target=f"snmp://127.0.0.1:{served.port}?community=private", sumo=True, seed=1,
                     duration=60.0, agent="max-pressure") as tb:
            tb.reset()
            assert tb.run() == "duration"
            records = tb.records
            lateness = tb.lateness
    finally:
        served.stop()
    assert [r for r in records if r["kind"] == Kind.TIMEOUT_ENTERED] == []
    # Drift detection saw every step: as many steps as the clock allowed, none of them late for long.
    drifts = [r for r in records if r["kind"] == Kind.DRIFT]
    assert max((r["consecutive"] for r in drifts), default=0) < cfg.middleware.n_drift
    verified = [r for r in records if r["kind"] == Kind.TRANSITION_VERIFIED]
    assert len(verified) >= 4, "the agent commanded and the controller served over the run"
    assert lateness.p99 < cfg.middleware.sumo_step
