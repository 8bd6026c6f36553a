"""SNMPv3 (USM: HMAC-SHA-96, AES-128) against `hils emulator serve --v3-user`, with net-snmp's tools
as the independent client, and the middleware's transport against the same agent; refusals that say why at
both ends, and the agent under hostile SNMPv3 traffic (floods, Reports, state kept per message)."""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import simpy
from pyasn1.codec.ber import decoder
from pysnmp.proto.mpmod.rfc3412 import SNMPv3Message
from pysnmp.proto.secmod.rfc3414.service import UsmSecurityParameters

from emulator.agent.mib import MibView
from emulator.agent.snmp import DropReason, ReportBudget, SnmpAgent, V3User
from emulator.model.controller import Controller
from harness.bench.commands import FLOODS, measure_tick_lateness_under_flood
from harness.bench.floods import discover_engine_id, v3_get
from harness.bench.processes import Served, start_emulator, tool
from hils.protocol.ntcip import MAX_PHASES, ControlColumn, control_oid, oid_str, signal_oids
from hils.protocol.usm import UsmFailure
from hils.shell.clock import WallClockDriver
from hils.shell.snmp import SnmpTarget, SnmpTransport
from hils.shell.transport import TransportError

pytestmark = pytest.mark.wallclock

USER, AUTH_KEY, PRIV_KEY = "hils", "auth-pass-phrase", "priv-pass-phrase"
MAX_PHASES_0 = "." + oid_str(MAX_PHASES.instance())
VEH_CALL_1 = control_oid(ControlColumn.VEH_CALL, 1)


def net_snmp(program: str, port: int, level: str, *args: str, auth_key: str = AUTH_KEY,
             priv_key: str = PRIV_KEY) -> subprocess.CompletedProcess[str]:
    security = ["-l", level, "-u", USER, "-a", "SHA", "-A", auth_key]
    if level == "authPriv":
        security += ["-x", "AES", "-X", priv_key]
    return subprocess.run([tool(program), "-v3", *security, "-On", "-t", "1", "-r", "0", f"127.0.0.1:{port}",
                           *args], capture_output=True, text=True, timeout=10)


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[Served]:
    server = start_emulator(tmp_path_factory.mktemp("v3") / "serve.log", "--v3-user", USER, "--v3-auth-key",
                            AUTH_KEY, "--v3-priv-key", PRIV_KEY, verbose=True)
    yield server
    server.stop()


def test_net_snmp_reads_and_writes_with_auth_priv(served: Served) -> None:
    got = net_snmp("snmpget", served.port, "authPriv", MAX_PHASES_0)
    assert got.stdout.strip() == f"{MAX_PHASES_0} = INTEGER: 8", got.stderr
    veh_call = "." + oid_str(VEH_CALL_1)
    written = net_snmp("snmpset", served.port, "authPriv", veh_call, "i", "34")
    assert written.stdout.strip() == f"{veh_call} = INTEGER: 34", written.stderr
    assert net_snmp("snmpget", served.port, "authPriv", veh_call).stdout.strip() == f"{veh_call} = INTEGER: 34"
    assert net_snmp("snmpset", served.port, "authPriv", veh_call, "i", "0").returncode == 0
    walk = net_snmp("snmpbulkwalk", served.port, "authPriv", ".1.3.6.1.4.1.1206.4.2.1.1")
    assert walk.returncode == 0 and len(walk.stdout.splitlines()) > 50


@pytest.mark.parametrize(("level", "keys", "message"), [
    ("authPriv", {"auth_key": "wrong-pass-phrase"}, "Authentication failure"),
    ("authNoPriv", {}, "Unsupported security level"),  # the user needs privacy
])
def test_net_snmp_refused(served: Served, level: str, keys: dict[str, str], message: str) -> None:
    refused = net_snmp("snmpget", served.port, level, MAX_PHASES_0, **keys)
    assert refused.returncode != 0
    assert message in refused.stderr


def test_wrong_privacy_key_gets_no_answer(served: Served) -> None:
    refused = net_snmp("snmpget", served.port, "authPriv", MAX_PHASES_0, priv_key="wrong-pass-phrase")
    assert refused.returncode != 0 and not refused.stdout


def test_communities_still_work_beside_v3(served: Served) -> None:
    got = subprocess.run([tool("snmpget"), "-v2c", "-c", "public", "-On", "-t", "1", "-r", "0",
                          f"127.0.0.1:{served.port}", MAX_PHASES_0], capture_output=True, text=True, timeout=10)
    assert got.stdout.strip() == f"{MAX_PHASES_0} = INTEGER: 8"


def run_process(driver: WallClockDriver, generator, limit: float = 5.0):
    proc = driver.env.process(generator)
    proc.callbacks.append(lambda _: driver.stop())
    driver.run_sync(until=driver.env.now + limit, handle_signals=False)
    assert proc.triggered
    return proc.value


@pytest.mark.parametrize("priv", [True, False])
def test_our_client_polls_and_calls_over_v3(tmp_path: Path, priv: bool) -> None:
    args = ["--v3-user", USER, "--v3-auth-key", AUTH_KEY] + (["--v3-priv-key", PRIV_KEY] if priv else [])
    server = start_emulator(tmp_path / "serve.log", *args, verbose=True)
    url = f"snmp://127.0.0.1:{server.port}?version=3&user={USER}&auth=SHA&auth_key={AUTH_KEY}"
    url += f"&priv=AES&priv_key={PRIV_KEY}" if priv else ""
    driver = WallClockDriver(simpy.Environment())
    transport = SnmpTransport(driver.env, driver, SnmpTarget.parse(url), tau_udp=1.0)

    def scenario():
        polls = []
        for _ in range(20):
            polls.append((yield transport.get(signal_oids(1))))
        yield transport.set([(VEH_CALL_1, 0b100010)])
        called = yield transport.get([VEH_CALL_1, MAX_PHASES.instance()])
        yield transport.set([(VEH_CALL_1, 0)])
        return polls, called

    try:
        polls, called = run_process(driver, scenario())
    finally:
        transport.close()
        driver.close()
        code, out = server.stop()
    assert code == 0
    assert all(len(poll) == 3 and all(type(v) is int for v in poll) for poll in polls)
    assert called == (0b100010, 8)
    assert "served 24 requests (get 22, set 2)" in out
    assert "phaseControlGroupVehCall.1 = 34 -> applied" in server.log.read_text()


def test_our_client_with_a_wrong_key_fails_the_request(served: Served) -> None:
    url = (f"snmp://127.0.0.1:{served.port}?version=3&user={USER}&auth=SHA&auth_key=wrong-pass-phrase"
           f"&priv=AES&priv_key={PRIV_KEY}")
    driver = WallClockDriver(simpy.Environment())
    transport = SnmpTransport(driver.env, driver, SnmpTarget.parse(url), tau_udp=0.5)

    def scenario():
        try:
            yield transport.get(signal_oids(1))
        except TransportError as exc:
            return exc
        pytest.fail("a GET with a wrong key succeeded")

    try:
        assert isinstance(run_process(driver, scenario()), TransportError)
    finally:
        transport.close()
        driver.close()


@pytest.mark.parametrize(("args", "message"), [
    (["--v3-user", "u"], "--v3-user needs --v3-auth-key (or $HILS_SNMP_AUTH_KEY)"),
    (["--v3-auth-key", "12345678"], "--v3-auth-key and --v3-priv-key need --v3-user"),
    (["--v3-user", "u", "--v3-auth-key", "short"], "auth key must have at least 8 characters"),
])
def test_serve_v3_option_errors(args: list[str], message: str) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("HILS_SNMP_")}
    done = subprocess.run([sys.executable, "-m", "hils", "emulator", "serve", "--port", "0", *args],
                          capture_output=True, text=True, timeout=30, env=env)
    assert done.returncode != 0
    assert message in done.stderr
    assert "Traceback" not in done.stderr


def test_v3_bulk_answers_are_cut_to_the_maximum_message_size(served: Served) -> None:
    # 200 repetitions would be far more than one datagram: the answer is cut short, still secured.
    bulk = net_snmp("snmpbulkget", served.port, "authPriv", "-Cr200", ".1.3.6.1.4.1.1206")
    assert bulk.returncode == 0, bulk.stderr
    assert 40 < len(bulk.stdout.splitlines()) < 200


# --- refusals that say why, and hostile SNMPv3 traffic -------------------------------------------------

def hils_run(port: int, query: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hils", "run", "--target",
                           f"snmp://127.0.0.1:{port}?version=3&{query}", "--no-sumo", "--no-progress",
                           "--duration", "5"], capture_output=True, text=True, timeout=60)


def test_hils_run_says_why_the_agent_refused_and_the_agent_warns_why(tmp_path: Path) -> None:
    """Each refusal is one line naming the usmStats counter of the agent's Report, never the address or a
    community; the agent logs each kind once as a warning, and a flood of one kind once (with a count later)."""
    server = start_emulator(tmp_path / "serve.log", "--v3-user", USER, "--v3-auth-key", AUTH_KEY,
                            "--v3-priv-key", PRIV_KEY)
    cases = {"usmStatsWrongDigests": f"user={USER}&auth=SHA&auth_key=wrong-pass-phrase&priv=AES&priv_key={PRIV_KEY}",
             "usmStatsDecryptionErrors": f"user={USER}&auth=SHA&auth_key={AUTH_KEY}&priv=AES&priv_key=wrong-pass",
             "usmStatsUnknownUserNames": f"user=nobody&auth=SHA&auth_key={AUTH_KEY}&priv=AES&priv_key={PRIV_KEY}",
             "usmStatsUnsupportedSecLevels": f"user={USER}&auth=SHA&auth_key={AUTH_KEY}"}  # the user needs privacy
    try:
        runs = {counter: hils_run(server.port, query) for counter, query in cases.items()}
        engine_id = discover_engine_id(("127.0.0.1", server.port))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for i in range(500):
                sock.sendto(v3_get(engine_id, message_id=i + 1), ("127.0.0.1", server.port))
        time.sleep(0.5)
    finally:
        code, out = server.stop()
    for counter, run in runs.items():
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(lines) == 1, run.stderr
        assert lines[0].startswith(f"hils: the start-up read or write failed: 127.0.0.1:{server.port} refused "
                                   "SNMPv3 user ") and lines[0].endswith(f"({counter})"), lines[0]
        assert "community" not in lines[0] and "no answer" not in lines[0]
    warnings = [line for line in server.log.read_text().splitlines() if " WARNING " in line]
    for counter in cases:
        assert sum(counter in line for line in warnings) == 1, warnings
    no_user = [line for line in warnings if "without a user name" in line]
    assert len(no_user) == 1 and "127.0.0.1:" in no_user[0]
    assert code == 0 and "dropped 500 datagrams (SNMPv3 without a user name 500)" in out


def test_the_v3_flood_keeps_neither_memory_nor_the_controller_waiting() -> None:
    """3000 noAuthNoPriv GETs a second with the agent's engine ID and no user name, from another process, for
    4 s: the agent drops them all before pysnmp sees them (which kept ~4.6 KB of each for ever and fell behind),
    its process keeps its memory and the controller's tick its time."""
    [flood] = [f for f in FLOODS if f.name == "v3_no_user"]
    measured = measure_tick_lateness_under_flood(4.0, [flood])["floods"]["v3_no_user"]
    assert measured["dropped"] > 4000  # a flood that happened (3000 a second were sent)
    assert measured["rss_growth_mb"] < 4.0
    assert measured["p99"] < 20.0, measured


def test_reports_are_budgeted_and_the_users_own_requests_are_not(paper_config) -> None:
    """With one Report to spend, net-snmp's walk (discovery, then authentic requests) gets all its answers; the
    next client's discovery finds the budget spent and gets no answer."""
    agent = SnmpAgent(MibView(Controller(paper_config)), v3_user=V3User(USER, AUTH_KEY, PRIV_KEY),
                      reports=ReportBudget(per_second=0.0, burst=1))
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        _, port = asyncio.run_coroutine_threadsafe(agent.start("127.0.0.1", 0), loop).result(5)
        walk = net_snmp("snmpbulkwalk", port, "authPriv", ".1.3.6.1.4.1.1206.4.2.1.1")
        refused = net_snmp("snmpget", port, "authPriv", MAX_PHASES_0)
    finally:
        loop.call_soon_threadsafe(agent.close)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
    assert walk.returncode == 0 and len(walk.stdout.splitlines()) > 50, walk.stderr
    assert agent.stats.reports == {UsmFailure.UNKNOWN_ENGINE_ID: 1}
    assert refused.returncode != 0 and "Timeout" in refused.stderr
    assert agent.stats.dropped[DropReason.REPORTS_SPENT] >= 1


def engine_of(agent: SnmpAgent) -> bytes:
    """The agent's engine ID, from its answer to a discovery request."""
    answer = agent.respond(v3_get(b""))
    assert answer is not None
    message, _ = decoder.decode(answer, asn1Spec=SNMPv3Message())
    security, _ = decoder.decode(bytes(message["msgSecurityParameters"]), asn1Spec=UsmSecurityParameters())
    return bytes(security["msgAuthoritativeEngineId"])
