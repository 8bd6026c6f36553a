"""`hils emulator serve --count N` and `--scenario`: many controllers in one process, each its own model and agent
on its own UDP port, ticked together; net-snmp's tools are the independent client."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from emulator.agent.serve import WallClockTicker
from emulator.model.controller import Controller
from harness.bench.processes import free_udp_port, start_emulator, tool
from harness.bench.serve import GOAL_MB_PER_CONTROLLER, measure_serve_memory
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn, PhaseColumn, StatusColumn, control_oid, oid_str, phase_oid, status_oid

pytestmark = pytest.mark.wallclock

GREENS = oid_str(status_oid(StatusColumn.GREENS, 1))  # 1.3.6.1.4.1.1206.4.2.1.1.4.1.4.1
YELLOWS = oid_str(status_oid(StatusColumn.YELLOWS, 1))
PHASE_NEXTS = oid_str(status_oid(StatusColumn.PHASE_NEXTS, 1))
VEH_CALL = oid_str(control_oid(ControlColumn.VEH_CALL, 1))
PHASES_2_6 = 0b00100010
PHASES_4_8 = 0b10001000


def snmp(program: str, port: int, *args: str, community: str = "public") -> list[int]:
    """The integer values net-snmp's ``program`` prints (``-Oqv``: values only, one a line)."""
    done = subprocess.run([tool(program), "-v2c", "-c", community, "-On", "-Oqv", "-t", "1", "-r", "1",
                           f"127.0.0.1:{port}", *args], capture_output=True, text=True, timeout=20)
    assert done.returncode == 0, done.stderr
    return [int(v) for v in done.stdout.split()]


def test_three_controllers_answer_each_on_its_port_and_a_call_moves_only_its_own(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log", count=3)
    try:
        assert len(set(served.ports)) == 3
        assert [snmp("snmpget", port, GREENS) for port in served.ports] == [[PHASES_2_6]] * 3
        called, *others = served.ports[1], served.ports[0], served.ports[2]
        assert snmp("snmpset", called, VEH_CALL, "i", str(PHASES_4_8), community="private") == [PHASES_4_8]
        assert snmp("snmpget", called, VEH_CALL) == [PHASES_4_8]
        # {2, 6} end after their 3 s minimum green from power-up: the called controller then times its
        # yellow with {4, 8} committed next; the others rest in green without a call.
        deadline = time.monotonic() + 6.0
        while snmp("snmpget", called, YELLOWS) != [PHASES_2_6]:
            assert time.monotonic() < deadline, "the called controller never ended its green"
            time.sleep(0.1)
        assert snmp("snmpget", called, PHASE_NEXTS) == [PHASES_4_8]
        for port in others:
            assert snmp("snmpget", port, GREENS, YELLOWS, VEH_CALL, PHASE_NEXTS) == [PHASES_2_6, 0, 0, 0]
    finally:
        code, out = served.stop()
    assert code == 0 and "by 3 controllers" in out


def test_a_scenario_serves_each_intersection_with_its_own_config(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log", "--scenario", "corridor", count=4)
    try:
        assert served.names == ("corridor arterial intersection [J1]", "corridor arterial intersection [J2]",
                                "corridor crossroad [J3]", "corridor arterial intersection [J4]")
        max_green_2 = oid_str(phase_oid(PhaseColumn.MAXIMUM1, 2))
        max_green_4 = oid_str(phase_oid(PhaseColumn.MAXIMUM1, 4))
        assert [snmp("snmpget", port, max_green_2, max_green_4) for port in served.ports] == [
            [40, 20], [40, 20], [35, 30], [40, 20]]
    finally:
        served.stop()


def test_the_controllers_are_on_consecutive_ports_from_the_first(tmp_path: Path) -> None:
    first = free_udp_port()
    # the last --port given wins over start_emulator's --port 0
    served = start_emulator(tmp_path / "serve.log", "--port", str(first), count=2)
    served.stop()
    assert served.ports == (first, first + 1)


@pytest.mark.parametrize(("args", "message"), [
    (["--count", "0"], "hils: --count 0: no controller to serve; allowed: 1 or more"),
    (["--count", "-3"], "hils: --count -3: no controller to serve; allowed: 1 or more"),
    (["--port", "65534", "--count", "3"], "hils: --port 65534 with --count 3 needs ports 65534..65536; allowed: "
                                          "--port 1..65533, or 0 (each controller on a free port)"),
    (["--scenario", "corridor", "--count", "3"], "hils: --count 3 with --scenario corridor, which has 4 "
                                                 "intersections; allowed: --count 4, or no --count"),
    (["--scenario", "corridr"], "hils: corridr: <scenario>: no shipped scenario of that name; allowed: a "
                                "shipped scenario (four_leg, four_phase, corridor, grid4x4), resco:NAME (RESCO's "
                                "benchmark) or a path to a .scenario.toml file"),
    (["--count", "2", "--trace", "t.jsonl"], "hils: --trace records one controller, not 2; allowed: --trace with "
                                             "--count 1"),
], ids=["count-0", "count-negative", "ports-beyond-65535", "count-not-the-scenario's", "unknown-scenario",
        "trace-of-many"])
def test_what_cannot_be_served_is_refused_in_one_line(args: list[str], message: str) -> None:
    done = subprocess.run([sys.executable, "-m", "hils", "emulator", "serve", "--port", "0", *args],
                          capture_output=True, text=True, timeout=30)
    assert (done.returncode, done.stderr, done.stdout) == (2, message + "\n", "")


def test_a_port_in_use_is_named_and_nothing_is_served(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "hils", "emulator", "serve", "--port", str(port - 1),
                               "--count", "3"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr == f"hils emulator serve: cannot bind udp:127.0.0.1:{port}: Address already in use\n"


def test_one_ticker_steps_every_controller_once_per_deadline(paper_config: IntersectionConfig) -> None:
    controllers = [Controller(paper_config) for _ in range(3)]
    ticker = WallClockTicker(*controllers)

    async def tick_a_while() -> None:
        task = asyncio.create_task(ticker.run())
        await asyncio.sleep(0.55)
        task.cancel()

    asyncio.run(tick_a_while())
    assert 4 <= ticker.stats.ticks <= 6
    assert [c.tick for c in controllers] == [ticker.stats.ticks] * 3


def test_each_added_controller_costs_far_less_than_the_goal_of_10_mb() -> None:
    figures = measure_serve_memory((1, 16))
    assert 0 < figures["rss_mb"][1] < figures["rss_mb"][16]
    assert figures["mb_per_controller"] < GOAL_MB_PER_CONTROLLER / 10
