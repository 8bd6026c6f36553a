"""The control objects are ours while we run: one set by someone else during a run, through net-snmp's
snmpset against `hils emulator serve`, is a TIMEOUT with its own reason, and recovery takes it back."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import pytest

from harness.bench.processes import start_emulator
from hils import Testbed
from hils.protocol.ntcip import ControlColumn, control_oid, oid_str
from hils.shell.events import Kind, read
from hils.shell.middleware import READBACK_PERIOD
from tests.hils.shell.test_preflight import snmp

pytestmark = pytest.mark.wallclock


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


def _run_cli(tmp_path: Path, name: str, url: str, control_interval: float, *extra: str) -> list[str]:
    """The command line of a `hils run` of the fixed-cycle agent at the wall clock, its config's control interval
    set (the start-up watches calls for two of them)."""
    config = tmp_path / f"{name}.toml"
    text = (resources.files("hils.data") / "four_leg.toml").read_text(encoding="utf-8")
    config.write_text(re.sub(r"(?m)^control_interval = .*$", f"control_interval = {control_interval}", text))
    return [sys.executable, "-m", "hils", "run", "--target", url, "--config", str(config), "--no-sumo",
            "--action-type", "switch", "--agent", "fixed-cycle", "--out", str(tmp_path / name), "--no-progress",
            *extra]


def test_a_second_run_on_a_controller_a_first_drives_refuses_to_start_unless_it_takes_over(tmp_path: Path) -> None:
    """Two runs on one controller: the second finds the first's call, watches it change, and refuses to start in
    one line (exit 2) having SET nothing, so the first goes on undisturbed. Told to take over, a third starts at
    once, and the first sees its call changed by someone else: a foreign_control TIMEOUT naming VehCall."""
    served = start_emulator(tmp_path / "serve.log")
    url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
    log = tmp_path / "first" / "events.jsonl"

    def first_has(ready: Callable[[list[dict]], bool]) -> None:
        deadline = time.monotonic() + 30
        while not (log.exists() and ready(list(read(log)))) and time.monotonic() < deadline:
            time.sleep(0.2)

    def kinds(records: list[dict], kind: Kind) -> int:
        return sum(r["kind"] == kind for r in records)

    # The first commands a new pair every 20 s; the second watches for 2 x 10 s.
    first = subprocess.Popen(_run_cli(tmp_path, "first", url, 20.0, "--duration", "42"),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first_has(lambda records: kinds(records, Kind.TRANSITION_VERIFIED) == 1)
        second = subprocess.run(_run_cli(tmp_path, "second", url, 10.0, "--duration", "5"), capture_output=True,
                                text=True, timeout=60)
        assert second.returncode == 2, second.stderr
        (line,) = second.stderr.strip().splitlines()
        assert "another manager drives the controller: its VehCall went from phases" in line
        assert "take the controller over (hils run --take-over" in line
        refused = list(read(tmp_path / "second" / "events.jsonl"))
        assert not [r for r in refused if r["kind"] == Kind.SET_SENT], "the refused run SET nothing"
        # Once the first's new pair shows, a run that takes over commands the pair after it: another call.
        first_has(lambda records: kinds(records, Kind.TRANSITION_VERIFIED) == 2)
        before_take_over = time.monotonic_ns()  # the clock the logs' wall_ns read, in every process
        third = subprocess.run(_run_cli(tmp_path, "third", url, 2.0, "--duration", "6", "--take-over"),
                               capture_output=True, text=True, timeout=60)
        took_over = list(read(tmp_path / "third" / "events.jsonl"))
        assert [r["purpose"] for r in took_over if r["kind"] == Kind.SET_SENT][:2] == ["startup", "command"], (
            third.stderr)
        first.communicate(timeout=60)
    finally:
        if first.poll() is None:
            first.kill()
        served.stop()
    timeouts = [r for r in read(log) if r["kind"] == Kind.TIMEOUT_ENTERED]
    assert timeouts and timeouts[0]["reason"] == "foreign_control", timeouts
    assert "phaseControlGroupVehCall on phases" in timeouts[0]["detail"]
    assert timeouts[0]["wall_ns"] > before_take_over, "nothing disturbed the first run before the take-over"
