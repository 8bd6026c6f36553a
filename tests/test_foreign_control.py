"""The control objects are ours while we run: one set by someone else during a run, through net-snmp's
snmpset against `hils emulator serve`, is a TIMEOUT with its own reason, and recovery takes it back."""

from __future__ import annotations

from pathlib import Path

from test_preflight import snmp

from harness.processes import start_emulator
from hils import Testbed
from hils.events import Kind
from hils.middleware import READBACK_PERIOD
from hils.ntcip import ControlColumn, control_oid, oid_str


def test_a_hold_set_by_someone_else_during_a_run_is_a_foreign_control_timeout(tmp_path: Path) -> None:
    hold = oid_str(control_oid(ControlColumn.HOLD, 1))
    served = start_emulator(tmp_path / "serve.log")
    try:
        with Testbed(target=f"snmp://127.0.0.1:{served.port}?community=private", recover_after=None) as tb:
            tb.reset()
            tb.run_for(1.0)
            assert tb.state.value == "idle"
            snmp("snmpset", served.port, hold, "i", str(0b10))  # someone else holds phase 2
            tb.run_for(READBACK_PERIOD + 0.5)
            (entered,) = [r for r in tb.records if r["kind"] == Kind.TIMEOUT_ENTERED]
            assert entered["reason"] == "foreign_control"
            assert entered["detail"] == "set by someone else: phaseControlGroupHold on phases [2]"
            assert tb.recover() is True
            assert snmp("snmpget", served.port, hold).strip().endswith("INTEGER: 0"), "recovery takes it back"
            tb.run_for(READBACK_PERIOD + 0.5)
            assert [r["reason"] for r in tb.records if r["kind"] == Kind.TIMEOUT_ENTERED] == ["foreign_control"]
    finally:
        served.stop()
