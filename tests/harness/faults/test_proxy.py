"""The UDP fault proxy: its schedule on its own, then the communication-failure scenario over real UDP."""

from __future__ import annotations

import asyncio
import re
import select
import signal
import subprocess
import sys

import pytest

from harness.bench.processes import start_emulator
from harness.faults.inject import Direction, Window
from harness.faults.proxy import Action, ProxyRule, UdpFaultProxy, parse_delay, parse_drop
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind

pytestmark = pytest.mark.wallclock

LOCAL = ("127.0.0.1", 0)


class Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport):
        self.transport = transport

    def datagram_received(self, data, addr):
        self.transport.sendto(data, addr)


class Client(asyncio.DatagramProtocol):
    def __init__(self, loop):
        self.loop = loop
        self.received: dict[int, float] = {}

    def datagram_received(self, data, addr):
        self.received[int(data)] = self.loop.time()


async def ping_through_proxy(rules, count=13, period=0.1):
    """Send datagram i at i * period through a proxy to an echo server; the proxy, when each was
    sent and when each came back."""
    loop = asyncio.get_running_loop()
    echo, _ = await loop.create_datagram_endpoint(Echo, local_addr=LOCAL)
    proxy = UdpFaultProxy(LOCAL, echo.get_extra_info("sockname")[:2], rules)
    address = await proxy.start()
    client = Client(loop)
    sock, _ = await loop.create_datagram_endpoint(lambda: client, remote_addr=address)
    sent = {}
    start = loop.time()
    try:
        for i in range(count):
            await asyncio.sleep(max(0.0, start + i * period - loop.time()))
            sent[i] = loop.time()
            sock.sendto(str(i).encode())
        await asyncio.sleep(0.5)
    finally:
        sock.close()
        proxy.close()
        echo.close()
    return proxy, sent, client.received


def test_the_proxy_drops_in_its_window_and_delays_in_its_window():
    rules = [ProxyRule(Action.DROP, Window(0.25, 0.55)),
             ProxyRule(Action.DELAY, Window(0.75, 1.05), Direction.RESPONSE, delay=0.2)]
    proxy, sent, received = asyncio.run(ping_through_proxy(rules))
    assert set(received) == set(range(13)) - {3, 4, 5}  # sent at 0.3, 0.4, 0.5 s: never delivered
    rtt = {i: received[i] - sent[i] for i in received}
    assert all(rtt[i] >= 0.2 for i in (8, 9, 10))  # answered at 0.8, 0.9, 1.0 s: late
    assert all(rtt[i] < 0.1 for i in (0, 1, 2, 6, 7, 11, 12))
    assert proxy.stats.dropped == {"request": 3, "response": 0}
    assert proxy.stats.delayed == {"request": 0, "response": 3}
    assert proxy.stats.forwarded == {"request": 10, "response": 10}


def test_proxy_schedules_parse_from_the_command_line():
    assert parse_drop("2:9") == ProxyRule(Action.DROP, Window(2.0, 9.0))
    assert parse_drop("5::request").window == Window(5.0) and parse_drop("5::request").direction is Direction.REQUEST
    rule = parse_delay("0.3+-0.1@10:20:response")
    assert (rule.delay, rule.jitter, rule.window, rule.direction) == (0.3, 0.1, Window(10, 20), Direction.RESPONSE)


def start_proxy(upstream_port: int, *args: str) -> tuple[subprocess.Popen[str], int]:
    cmd = [sys.executable, "-m", "hils", "faults", "proxy", "--upstream", f"127.0.0.1:{upstream_port}", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    line = proc.stdout.readline() if ready else ""
    match = re.fullmatch(r"proxying udp:127\.0\.0\.1:(\d+) -> 127\.0\.0\.1:\d+\n", line)
    if match is None:
        proc.kill()
        raise AssertionError(f"no ready line from the proxy, got {line!r}; stderr: {proc.communicate()[1]}")
    return proc, int(match[1])


def test_communication_failure_over_real_udp_at_wall_clock_time(tmp_path):
    """The paper's first error through the proxy: every datagram lost from 2 s to 9 s of the run."""
    config = config_mod.load()  # the paper's parameters: 10 Hz polls, tau_udp 1 s, n_timeout 5
    served = start_emulator(tmp_path / "serve.log")
    proxy, port = start_proxy(served.port, "--drop", "2:9")
    try:
        spec = RunSpec(config, ActionType.SELECTION, duration=14.0, seed=1, recover_after=1.0,
                       log_path=tmp_path / "events.jsonl")
        result = run_spec(spec, target=f"snmp://127.0.0.1:{port}?community=private&version=2c")
    finally:
        proxy.send_signal(signal.SIGTERM)
        proxy_out, _ = proxy.communicate(timeout=10)
        served.stop()
    records = result.records
    (timeout,) = [r for r in records if r["kind"] == Kind.TIMEOUT_ENTERED]
    assert timeout["reason"] == "communication"
    # The proxy's clock starts at the run's first poll. From 2 s on every poll is lost; polls keep their
    # 0.1 s grid, so the fifth lost one, sent 0.4 s after the first, times out tau_udp later.
    assert 3.3 <= timeout["t"] <= 3.9
    failed = [r for r in records if r["kind"] == Kind.POLL_FAILED and r["t"] <= timeout["t"]]
    assert [r["consecutive"] for r in failed] == [1, 2, 3, 4, 5]
    (recovered,) = [r for r in records if r["kind"] == Kind.RECOVERED]
    assert 9.0 <= recovered["t"] <= 12.5  # the first recover() after the link is back
    assert not [r for r in records if r["kind"] == Kind.SET_SENT and r["purpose"] == "command"
                and timeout["t"] <= r["t"] < recovered["t"]]
    assert all(config.compatible(*r["phases"]) for r in records if r["kind"] == Kind.SET_SENT and r["phases"])
    assert [r["seq"] for r in records] == list(range(len(records)))
    dropped = re.search(r"dropped (\d+) requests", proxy_out)
    assert dropped and int(dropped[1]) >= 6, proxy_out


def test_polls_keep_their_rate_under_loss_at_wall_clock_time(tmp_path, paper_toml):
    """20 % of datagrams lost each way: a lost poll does not hold the next back, so at least 90 % of the
    configured 10 polls a second still reach the proxy (which counts them, independently of the poller)."""
    # Enough failures allowed in a row that the run never halts polling: 5 in a row happen at this loss.
    config = config_mod.parse(paper_toml.replace("n_timeout = 5 ", "n_timeout = 1000 "), "lossy.toml")
    served = start_emulator(tmp_path / "serve.log")
    proxy, port = start_proxy(served.port, "--loss", "0.2", "--seed", "3")
    try:
        spec = RunSpec(config, ActionType.SELECTION, duration=20.0, seed=1)
        result = run_spec(spec, target=f"snmp://127.0.0.1:{port}?community=private&version=2c")
    finally:
        proxy.send_signal(signal.SIGTERM)
        proxy_out, _ = proxy.communicate(timeout=10)
        served.stop()
    counts = re.search(r"forwarded (\d+) requests, (\d+) responses; dropped (\d+) requests, (\d+) responses",
                       proxy_out)
    assert counts, proxy_out
    forwarded, answered, dropped, lost = map(int, counts.groups())
    sets = sum(r["kind"] == Kind.SET_SENT for r in result.records)
    polls = forwarded + dropped - sets
    assert polls >= 0.9 * 10 * 20, proxy_out
    assert 0.1 < dropped / (forwarded + dropped) < 0.3 and 0.1 < lost / (answered + lost) < 0.3
    counted = result.records[-1]["polls"]
    failed_polls = sum(r["kind"] == Kind.POLL_FAILED and r["poll_id"] > 0 for r in result.records)  # 0: start-up
    assert counted["elided"] == 0 and counted["failed"] == failed_polls  # over the wire every poll is sent
    # each settled; the last second's may be in flight
    assert counted["answered"] + counted["failed"] + counted["late"] >= 0.9 * 10 * 19
    assert not [r for r in result.records if r["kind"] == Kind.TIMEOUT_ENTERED]
