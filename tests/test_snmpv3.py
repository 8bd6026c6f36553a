"""SNMPv3 (USM: HMAC-SHA-96, AES-128) against `hils emulator serve --v3-user`, with net-snmp's tools
as the independent client, and the middleware's transport against the same agent."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import simpy

from harness.processes import Served, start_emulator, tool
from hils.clock import WallClockDriver
from hils.ntcip import MAX_PHASES, ControlColumn, control_oid, oid_str, signal_oids
from hils.snmp import SnmpTarget, SnmpTransport
from hils.transport import TransportError

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
    done = subprocess.run([sys.executable, "-m", "hils.cli", "emulator", "serve", "--port", "0", *args],
                          capture_output=True, text=True, timeout=30, env=env)
    assert done.returncode != 0
    assert message in done.stderr
    assert "Traceback" not in done.stderr


def test_v3_bulk_answers_are_cut_to_the_maximum_message_size(served: Served) -> None:
    # 200 repetitions would be far more than one datagram: the answer is cut short, still secured.
    bulk = net_snmp("snmpbulkget", served.port, "authPriv", "-Cr200", ".1.3.6.1.4.1.1206")
    assert bulk.returncode == 0, bulk.stderr
    assert 40 < len(bulk.stdout.splitlines()) < 200
