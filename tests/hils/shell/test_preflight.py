"""Start-up checks that fail fast and say why, against `hils emulator serve` with net-snmp as the observer."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.bench.processes import free_udp_port, start_emulator, tool
from hils.protocol.ntcip import SYSTEM_PATTERN_CONTROL, UNIT_BACKUP_TIME, ControlColumn, control_oid, oid_str
from hils.shell.preflight import ControllerReading, judge

pytestmark = pytest.mark.wallclock

PATTERN = oid_str(SYSTEM_PATTERN_CONTROL.instance())
BACKUP = oid_str(UNIT_BACKUP_TIME.instance())
OMIT = oid_str(control_oid(ControlColumn.PHASE_OMIT, 1))


def hils_run(tmp_path: Path, url: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--target", url,
                           "--out", str(tmp_path / "run"), *args], capture_output=True, text=True, timeout=90)


def snmp(program: str, port: int, *args: str, community: str = "private") -> str:
    done = subprocess.run([tool(program), "-v2c", "-c", community, "-On", "-t", "1", "-r", "2",
                           f"127.0.0.1:{port}", *args], capture_output=True, text=True, timeout=20)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_verdict_of_a_reading() -> None:
    fine = ControllerReading(30, 254, 2, {c: frozenset() for c in ControlColumn})
    assert judge(fine, where="h:1", community="c", keepalive_period=10.0).refusals == ()
    bad = ControllerReading(0, 3, 6, {ControlColumn.HOLD: frozenset({2})})
    verdict = judge(bad, where="h:1", community="c", keepalive_period=10.0)
    assert len(verdict.refusals) == 2
    assert "not in free mode (systemPatternControl = 3, needs 254" in verdict.refusals[0]
    assert f"snmpset -v1 -c c h:1 {PATTERN} i 254" in verdict.refusals[0]
    assert "in flash (unitFlashStatus = mmu)" in verdict.refusals[1]
    assert any("no backup time" in w for w in verdict.warnings)
    assert any("HOLD [2]" in w for w in verdict.warnings)


def test_nothing_listening_fails_fast_with_one_line(tmp_path: Path) -> None:
    started = time.monotonic()
    done = hils_run(tmp_path, f"snmp://127.0.0.1:{free_udp_port()}?community=private", "--duration", "3600")
    assert time.monotonic() - started < 30, "it did not wait for the run's duration"
    assert done.returncode == 2
    assert "no answer from 127.0.0.1:" in done.stderr and "within 5 x tau_udp = 5 s" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_a_host_that_does_not_resolve_is_refused_before_anything_starts(tmp_path: Path) -> None:
    done = hils_run(tmp_path, "snmp://no-such-host.invalid:161?community=private", "--duration", "60")
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr.startswith("hils: target 'snmp://no-such-host.invalid:161?community=private': cannot "
                                  "resolve SNMP target host 'no-such-host.invalid'")
    assert done.stderr.strip().endswith("allowed: a host name this machine resolves, or an IPv4 address")
    assert len(done.stderr.strip().splitlines()) == 1


def test_a_read_only_community_and_a_controller_not_in_free_mode_are_refused(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        ro = hils_run(tmp_path, f"snmp://127.0.0.1:{served.port}?community=public", "--duration", "60")
        assert ro.returncode == 2
        assert "refuses to be written (no_access): the community can read but not write" in ro.stderr
        snmp("snmpset", served.port, PATTERN, "i", "5")
        coordinated = hils_run(tmp_path, f"snmp://127.0.0.1:{served.port}?community=private", "--duration", "60")
        assert coordinated.returncode == 2
        assert "not in free mode (systemPatternControl = 5, needs 254" in coordinated.stderr
        assert f"snmpset -v1 -c private 127.0.0.1:{served.port} {PATTERN} i 254" in coordinated.stderr
        assert "Traceback" not in ro.stderr + coordinated.stderr
    finally:
        served.stop()


@pytest.mark.parametrize("backup", ["0", "30"])
def test_control_objects_left_by_someone_else_are_reported_and_cleared(tmp_path: Path, backup: str) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        snmp("snmpset", served.port, OMIT, "i", str(0b100), BACKUP, "i", backup)  # phase 3 omitted
        done = hils_run(tmp_path, f"snmp://127.0.0.1:{served.port}?community=private", "--duration", "3")
        assert done.returncode == 0, done.stderr
        assert "had control objects set by someone else, cleared now: PHASE_OMIT [3]" in done.stderr
        assert ("no backup time (unitBackupTime = 0)" in done.stderr) == (backup == "0")
        assert snmp("snmpget", served.port, OMIT, community="public").strip().endswith("INTEGER: 0")
    finally:
        served.stop()
