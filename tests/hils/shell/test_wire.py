"""The middleware at wall-clock time against `hils emulator serve` in another process, over UDP."""

from __future__ import annotations

import re

import pytest

from harness.bench.processes import start_emulator
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.protocol.ntcip import groups_to_phases
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind

pytestmark = pytest.mark.wallclock

CFG = config_mod.load()


def test_thirty_seconds_of_phase_switching_over_snmp(tmp_path):
    served = start_emulator(tmp_path / "serve.log", verbose=True)
    try:
        spec = RunSpec(CFG.with_middleware(poll_hz=50.0), ActionType.SWITCH, duration=36.0, seed=0,
                       log_path=tmp_path / "events.jsonl")
        result = run_spec(spec, target=f"snmp://127.0.0.1:{served.port}?community=private&version=2c")
    finally:
        code, _ = served.stop()
    assert code == 0
    records = result.records
    dispatched = [r for r in records if r["kind"] == Kind.COMMAND_DISPATCHED]
    verified = {r["command_id"] for r in records if r["kind"] == Kind.TRANSITION_VERIFIED}
    assert len(dispatched) == 4
    assert {r["command_id"] for r in dispatched} == verified
    assert all(CFG.compatible(*r["command"]) for r in dispatched)
    assert not [r for r in records if r["kind"] in (Kind.TIMEOUT_ENTERED, Kind.POLL_FAILED, Kind.SET_FAILED)]
    assert records[-1]["kind"] == Kind.RUN_ENDED and records[-1]["reason"] == "duration"
    assert [r["seq"] for r in records] == list(range(len(records)))
    # What the controller says it received is what the middleware says it sent, in order.
    received = [groups_to_phases([int(v)]) for v in
                re.findall(r"phaseControlGroupVehCall\.1 = (\d+)[^\n]*-> applied", served.log.read_text())]
    sent = [frozenset(r["phases"]) for r in records if r["kind"] == Kind.SET_SENT]
    assert received == sent
    assert sent[-1] == frozenset()  # calls cleared at the end
    # Polls at 50 Hz over UDP: about 50 per second, all answered.
    polls = records[-1]["polls"]
    assert 0.8 * 50 * 36 <= polls["answered"] <= polls["polls"] <= 50 * 36 + 2 and polls["elided"] == 0
