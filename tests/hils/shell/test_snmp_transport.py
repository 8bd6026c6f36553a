"""SnmpTransport against net-snmp's real snmpd on 127.0.0.1, driven by the wall clock.

Needs the Debian packages ``snmpd`` (the agent) and ``snmp`` (``snmpget``, to
tell when the agent answers). The agent runs in the foreground on a free UDP
port with a config file of its own and is killed at the end of the module.

Objects used (standard MIB-2 / net-snmp, always present):
sysDescr (OCTET STRING), sysUpTime (TimeTicks), snmpInPkts (Counter32, counts
every datagram the agent receives), snmpEnableAuthenTraps (writable INTEGER
1/2) and UCD-SNMP versionDoDebugging (writable INTEGER; 0 keeps it off).
"""

from __future__ import annotations

import re
import socket
import subprocess
import time
from collections.abc import Iterator

import numpy as np
import pytest
import simpy

from harness.bench.processes import SNMPD_V3_USERS, snmpd, tool
from hils.protocol.ntcip import ErrorStatus, SnmpError
from hils.protocol.usm import UsmFailure
from hils.shell.clock import WallClockDriver
from hils.shell.snmp import (
    AUTH_KEY_ENV,
    PRIV_KEY_ENV,
    AuthProtocol,
    PrivProtocol,
    SnmpTarget,
    SnmpTransport,
    SnmpVersion,
)
from hils.shell.transport import CommunicationTimeout, SecurityRefused, TransportError

pytestmark = pytest.mark.wallclock

SYS_DESCR = (1, 3, 6, 1, 2, 1, 1, 1, 0)
SYS_UPTIME = (1, 3, 6, 1, 2, 1, 1, 3, 0)
SNMP_IN_PKTS = (1, 3, 6, 1, 2, 1, 11, 1, 0)
AUTHEN_TRAPS = (1, 3, 6, 1, 2, 1, 11, 30, 0)
DO_DEBUGGING = (1, 3, 6, 1, 4, 1, 2021, 100, 20, 0)
MISSING = (1, 3, 6, 1, 2, 1, 1, 99, 0)

SLACK = 0.5
VERSIONS = ["1", "2c"]

@pytest.fixture(scope="module")
def snmpd_port(tmp_path_factory) -> Iterator[int]:
    with snmpd(tmp_path_factory.mktemp("snmpd")) as port:
        yield port


@pytest.fixture
def driver() -> Iterator[WallClockDriver]:
    drv = WallClockDriver(simpy.Environment())
    yield drv
    drv.close()


@pytest.fixture
def connect(driver):
    """Make transports on the test's driver; all are closed at teardown."""
    made: list[SnmpTransport] = []

    def make(port: int, *, version: str = "2c", community: str = "public", tau_udp: float = 1.0) -> SnmpTransport:
        target = SnmpTarget.parse(f"snmp://127.0.0.1:{port}?community={community}&version={version}")
        transport = SnmpTransport(driver.env, driver, target, tau_udp=tau_udp)
        made.append(transport)
        return transport

    yield make
    for transport in made:
        transport.close()


@pytest.fixture
def silent_port() -> Iterator[socket.socket]:
    """A bound UDP socket that never answers: requests to it get no reply (and no ICMP error)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        yield sock


def run_process(driver: WallClockDriver, generator, limit: float = 5.0):
    """Run one SimPy process under the wall clock until it ends (at most `limit` s) and return its value."""
    env = driver.env
    proc = env.process(generator)
    proc.callbacks.append(lambda _: driver.stop())
    driver.run_sync(until=env.now + limit, handle_signals=False)
    assert proc.triggered, f"process not finished after {limit} s"
    return proc.value


@pytest.mark.parametrize("version", VERSIONS)
def test_get_of_several_objects_is_one_pdu_with_int_and_bytes(driver, connect, snmpd_port, version):
    transport = connect(snmpd_port, version=version)

    def poll():
        first = yield transport.get([SNMP_IN_PKTS, SYS_DESCR, SYS_UPTIME])
        second = yield transport.get([SNMP_IN_PKTS, SYS_DESCR, SYS_UPTIME])
        return first, second

    first, second = run_process(driver, poll())
    in_pkts, descr, uptime = first
    assert type(in_pkts) is int and type(uptime) is int
    assert isinstance(descr, bytes) and descr
    assert second[1] == descr
    assert second[2] >= uptime
    # One datagram per GET: the agent counted exactly one packet between the two reads.
    assert second[0] - in_pkts == 1


@pytest.mark.parametrize("version", VERSIONS)
def test_set_of_several_integers_in_one_pdu_then_read_back(driver, connect, snmpd_port, version):
    transport = connect(snmpd_port, version=version, community="private")

    def scenario():
        done = yield transport.set([(AUTHEN_TRAPS, np.int64(1)), (DO_DEBUGGING, 0)])
        after_first = yield transport.get([AUTHEN_TRAPS, DO_DEBUGGING])
        yield transport.set([(AUTHEN_TRAPS, 2)])
        after_second = yield transport.get([AUTHEN_TRAPS])
        return done, after_first, after_second

    done, after_first, after_second = run_process(driver, scenario())
    assert done is None
    assert after_first == (1, 0)
    assert after_second == (2,)


@pytest.mark.parametrize(("version", "status"), [("1", ErrorStatus.NO_SUCH_NAME), ("2c", ErrorStatus.NO_ACCESS)])
def test_set_with_the_read_only_community_is_refused(driver, connect, snmpd_port, version, status):
    reader = connect(snmpd_port, version=version)
    writer = connect(snmpd_port, version=version, community="private")

    def scenario():
        yield writer.set([(AUTHEN_TRAPS, 2)])
        try:
            yield reader.set([(AUTHEN_TRAPS, 1)])
        except SnmpError as exc:
            refusal = exc
        else:
            pytest.fail("a SET with the read-only community succeeded")
        value = yield reader.get([AUTHEN_TRAPS])
        return refusal, value

    refusal, value = run_process(driver, scenario())
    assert refusal.status is status
    assert refusal.index == 1
    assert value == (2,)


@pytest.mark.parametrize("version", VERSIONS)
def test_get_of_a_missing_object_is_no_such_name_at_its_index(driver, connect, snmpd_port, version):
    transport = connect(snmpd_port, version=version)

    def scenario():
        try:
            yield transport.get([SYS_UPTIME, MISSING])
        except SnmpError as exc:
            return exc
        pytest.fail("GET of a missing object succeeded")

    refusal = run_process(driver, scenario())
    assert refusal.status is ErrorStatus.NO_SUCH_NAME
    assert refusal.index == 2


def test_set_error_index_points_at_the_refused_varbind(driver, connect, snmpd_port):
    transport = connect(snmpd_port, community="private")

    def scenario():
        try:
            yield transport.set([(AUTHEN_TRAPS, 1), (MISSING, 1)])
        except SnmpError as exc:
            return exc
        pytest.fail("SET of a missing object succeeded")

    refusal = run_process(driver, scenario())
    assert refusal.index == 2
    assert refusal.status in {ErrorStatus.NOT_WRITABLE, ErrorStatus.NO_CREATION, ErrorStatus.NO_ACCESS}


def test_unhandled_refusal_propagates_from_the_run_with_its_status(driver, connect, snmpd_port):
    transport = connect(snmpd_port)

    def careless():
        yield transport.get([MISSING])

    with pytest.raises(SnmpError) as info:
        run_process(driver, careless())
    assert info.value.status is ErrorStatus.NO_SUCH_NAME
    assert info.value.index == 1


def test_no_answer_fails_with_timeout_after_tau_udp_and_is_not_retried(driver, connect, silent_port):
    tau = 0.2
    transport = connect(silent_port.getsockname()[1], tau_udp=tau)
    env = driver.env

    def scenario():
        sent_at, wall = env.now, time.perf_counter()
        try:
            yield transport.get([SYS_UPTIME])
        except CommunicationTimeout:
            failed = (env.now - sent_at, time.perf_counter() - wall)
        else:
            pytest.fail("a GET to a silent port succeeded")
        # Outlive pysnmp's own (later) timeout, which would be when a retry went out.
        yield env.timeout(tau + 1.5)
        return failed

    sim_elapsed, wall_elapsed = run_process(driver, scenario())
    assert tau <= sim_elapsed < tau + SLACK
    assert tau <= wall_elapsed < tau + SLACK
    datagrams = 0
    while True:
        try:
            silent_port.recv(65535)
        except BlockingIOError:
            break
        datagrams += 1
    assert datagrams == 1


def test_close_cancels_requests_in_flight_and_refuses_new_ones(driver, connect, silent_port):
    transport = connect(silent_port.getsockname()[1], tau_udp=0.1)
    env = driver.env

    def scenario():
        pending = transport.get([SYS_UPTIME])
        yield env.timeout(0.01)
        transport.close()
        yield env.timeout(0.3)
        return pending

    pending = run_process(driver, scenario())
    assert not pending.triggered
    with pytest.raises(RuntimeError, match="closed"):
        transport.get([SYS_UPTIME])


def test_concurrent_requests_each_get_their_own_answer(driver, connect, snmpd_port):
    transport = connect(snmpd_port)
    env = driver.env
    shapes = {"uptime": [SYS_UPTIME], "descr": [SYS_DESCR, SYS_UPTIME], "traps": [AUTHEN_TRAPS, SYS_DESCR]}
    results: dict[str, list] = {name: [] for name in shapes}

    def poller(name):
        for _ in range(20):
            results[name].append((yield transport.get(shapes[name])))

    def scenario():
        yield simpy.AllOf(env, [env.process(poller(name)) for name in shapes])

    run_process(driver, scenario())
    for name, oids in shapes.items():
        assert len(results[name]) == 20
        assert all(len(values) == len(oids) for values in results[name])
    assert all(type(v[0]) is int for v in results["uptime"])
    assert all(isinstance(v[0], bytes) and type(v[1]) is int for v in results["descr"])
    assert all(v[0] in (1, 2) and isinstance(v[1], bytes) for v in results["traps"])
    uptimes = [v[0] for v in results["uptime"]]
    assert uptimes == sorted(uptimes)


def test_sequential_gets_sustain_more_than_the_poll_rate(driver, connect, snmpd_port):
    transport = connect(snmpd_port)
    count = 300

    def poll():
        start = time.perf_counter()
        for _ in range(count):
            yield transport.get([SNMP_IN_PKTS, SYS_UPTIME, AUTHEN_TRAPS])
        return time.perf_counter() - start

    elapsed = run_process(driver, poll(), limit=30.0)
    # 100 Hz is the top of the poll path's range; loopback does well over 1000/s.
    assert count / elapsed > 100.0


def test_request_arguments_are_checked_before_anything_is_sent(driver, connect, silent_port):
    transport = connect(silent_port.getsockname()[1])
    with pytest.raises(ValueError, match="at least one OID"):
        transport.get([])
    with pytest.raises(ValueError, match="at least one varbind"):
        transport.set([])
    with pytest.raises(TypeError, match="only INTEGER"):
        transport.set([(AUTHEN_TRAPS, "1")])
    with pytest.raises(TypeError, match="only INTEGER"):
        transport.set([(AUTHEN_TRAPS, 1.0)])
    with pytest.raises(TypeError, match="only INTEGER"):
        transport.set([(AUTHEN_TRAPS, True)])
    with pytest.raises(ValueError, match="Integer32"):
        transport.set([(AUTHEN_TRAPS, 2**31)])


def test_transport_checks_its_driver_and_tau(driver):
    target = SnmpTarget("127.0.0.1")
    with pytest.raises(ValueError, match="environment"):
        SnmpTransport(simpy.Environment(), driver, target)
    with pytest.raises(ValueError, match="tau_udp"):
        SnmpTransport(driver.env, driver, target, tau_udp=0)


@pytest.mark.parametrize(("url", "expected"), [
    ("snmp://10.0.0.5", SnmpTarget("10.0.0.5", 161, "public", SnmpVersion.V2C)),
    ("snmp://controller.local:501?community=administrator&version=1",
     SnmpTarget("controller.local", 501, "administrator", SnmpVersion.V1)),
    ("snmp://127.0.0.1:1161/?version=2C&community=a%26b", SnmpTarget("127.0.0.1", 1161, "a&b", SnmpVersion.V2C)),
])
def test_target_url_parsing(url, expected):
    assert SnmpTarget.parse(url) == expected


@pytest.mark.parametrize(("url", "message"), [
    ("udp://10.0.0.5:161", "must start with snmp://"),
    ("10.0.0.5:161", "must start with snmp://"),
    ("snmp://", "no host"),
    ("snmp://10.0.0.5:port", "port must be a number"),
    ("snmp://10.0.0.5:70000", "port must be a number"),
    ("snmp://10.0.0.5:0", "outside 1..65535"),
    ("snmp://10.0.0.5?version=4", "version '4' is not one of 1, 2c, 3"),
    ("snmp://10.0.0.5?retries=2", "unknown option 'retries'; allowed: community, version, user"),
    ("snmp://10.0.0.5?user=u", "option 'user' does not go with version 2c; allowed: community, version"),
    ("snmp://10.0.0.5?version=3&community=c", "option 'community' does not go with version 3"),
    ("snmp://10.0.0.5?version=3&auth=SHA&auth_key=12345678", "needs a user"),
    ("snmp://10.0.0.5?version=3&user=u", "needs auth=SHA"),
    ("snmp://10.0.0.5?version=3&user=u&auth=MD5&auth_key=12345678", "auth 'MD5' is not supported; allowed: SHA"),
    ("snmp://10.0.0.5?version=3&user=u&auth=SHA&auth_key=12345678&priv=DES&priv_key=12345678",
     "priv 'DES' is not supported; allowed: AES"),
    ("snmp://10.0.0.5?version=3&user=u&auth=SHA", "auth=SHA needs a key: give auth_key=K or set HILS_SNMP_AUTH_KEY"),
    ("snmp://10.0.0.5?version=3&user=u&auth=SHA&auth_key=12345678&priv=AES",
     "priv=AES needs a key: give priv_key=K or set HILS_SNMP_PRIV_KEY"),
    ("snmp://10.0.0.5?version=3&user=u&auth=SHA&auth_key=short", "auth_key must have at least 8 characters"),
    ("snmp://10.0.0.5?community=a&community=b", "given twice"),
    ("snmp://10.0.0.5?community=", "community is empty"),
    ("snmp://10.0.0.5?community", "not KEY=VALUE"),
    ("snmp://admin@10.0.0.5", "as ?community=NAME"),
    ("snmp://10.0.0.5/1.3.6", "path or fragment"),
    ("snmp://[::1]:161", "IPv6"),
])
def test_target_url_errors_say_what_is_wrong(url, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        SnmpTarget.parse(url, environ={})


# --- SNMPv3 -------------------------------------------------------------------------------------------

def v3_url(port: int, user: str, auth_key: str, priv_key: str) -> str:
    url = f"snmp://127.0.0.1:{port}?version=3&user={user}&auth=SHA&auth_key={auth_key}"
    return url + (f"&priv=AES&priv_key={priv_key}" if priv_key else "")


def test_v3_keys_from_the_environment_and_never_in_the_repr():
    environ = {AUTH_KEY_ENV: "auth-from-env", PRIV_KEY_ENV: "priv-from-env"}
    target = SnmpTarget.parse("snmp://10.0.0.5?version=3&user=ops&auth=sha&priv=aes", environ=environ)
    assert (target.version, target.user, target.auth, target.priv) == (SnmpVersion.V3, "ops", AuthProtocol.SHA,
                                                                       PrivProtocol.AES)
    assert (target.auth_key, target.priv_key, target.security_level) == ("auth-from-env", "priv-from-env",
                                                                         "authPriv")
    assert "from-env" not in repr(target)
    # A key in the URL wins over the environment.
    url = "snmp://10.0.0.5?version=3&user=ops&auth=SHA&auth_key=auth-in-url"
    target = SnmpTarget.parse(url, environ=environ)
    assert (target.auth_key, target.priv, target.security_level) == ("auth-in-url", None, "authNoPriv")


@pytest.mark.parametrize("url", [
    "snmp://h?version=3&user=ops&auth=SHA&auth_key=secret-one&priv=DES&priv_key=secret-two",  # DES: not offered
    "snmp://h?version=3&user=ops&auth=SHA&auth_key=secret-one&priv_key=secret-two",  # a key without its protocol
    "snmp://h?version=3&auth=SHA&auth_key=secret-one",  # no user
])
def test_target_errors_quote_the_url_without_its_keys(url):
    with pytest.raises(ValueError) as refused:
        SnmpTarget.parse(url, environ={})
    assert "secret" not in str(refused.value) and "auth_key=..." in str(refused.value)


def test_a_v3_target_has_no_community():
    target = SnmpTarget.parse("snmp://h?version=3&user=ops&auth=SHA&auth_key=auth-pass-phrase")
    assert target.community == ""


@pytest.mark.parametrize("user", sorted(SNMPD_V3_USERS))
def test_v3_get_and_set_against_snmpd(driver, snmpd_port, user):
    level, auth_key, priv_key = SNMPD_V3_USERS[user]
    target = SnmpTarget.parse(v3_url(snmpd_port, user, auth_key, priv_key))
    assert target.security_level == level
    transport = SnmpTransport(driver.env, driver, target, tau_udp=1.0)

    def scenario():
        first = yield transport.get([SNMP_IN_PKTS, SYS_DESCR])
        yield transport.set([(DO_DEBUGGING, 0), (AUTHEN_TRAPS, 2)])
        second = yield transport.get([SNMP_IN_PKTS, AUTHEN_TRAPS])
        try:
            yield transport.get([SYS_UPTIME, MISSING])
        except SnmpError as exc:
            return first, second, exc
        pytest.fail("GET of a missing object succeeded")

    try:
        first, second, refusal = run_process(driver, scenario())
    finally:
        transport.close()
    assert isinstance(first[1], bytes) and first[1]
    assert second[0] > first[0] and second[1] == 2
    assert (refusal.status, refusal.index) == (ErrorStatus.NO_SUCH_NAME, 2)
    # net-snmp's own client reads what we wrote, with the same user.
    out = subprocess.run([tool("snmpget"), "-v3", "-l", level, "-u", user, "-a", "SHA", "-A", auth_key,
                          *(["-x", "AES", "-X", priv_key] if priv_key else []), "-On", "-t", "1", "-r", "0",
                          f"127.0.0.1:{snmpd_port}", ".1.3.6.1.2.1.11.30.0"], capture_output=True, text=True,
                         timeout=10)
    assert out.stdout.strip() == ".1.3.6.1.2.1.11.30.0 = INTEGER: 2", out.stderr


@pytest.mark.parametrize(("user", "auth_key", "priv_key", "failure"), [
    ("hilspriv", "not-the-auth-key", "hils-priv-key", UsmFailure.WRONG_DIGEST),
    ("nobody", "hils-auth-key", "hils-priv-key", UsmFailure.UNKNOWN_USER_NAME),
    ("hilsauth", "hils-auth-key", "hils-priv-key", UsmFailure.UNSUPPORTED_SEC_LEVEL),  # a user without privacy
    ("hilspriv", "hils-auth-key", "not-the-priv-key", None),  # snmpd drops what it cannot decrypt: no Report
], ids=["wrong-auth-key", "unknown-user", "priv-for-auth-only-user", "wrong-priv-key"])
@pytest.mark.parametrize("request_kind", ["get", "set"])
def test_v3_refusals_say_why_from_the_report(driver, snmpd_port, user, auth_key, priv_key, failure, request_kind):
    """GETs go through gufo-snmp and SETs through pysnmp: both name the usmStats counter of snmpd's Report."""
    transport = SnmpTransport(driver.env, driver, SnmpTarget.parse(v3_url(snmpd_port, user, auth_key, priv_key)),
                              tau_udp=0.5)

    def scenario():
        try:
            yield transport.get([SYS_UPTIME]) if request_kind == "get" else transport.set([(DO_DEBUGGING, 0)])
        except TransportError as exc:
            return exc
        pytest.fail("a request with wrong credentials succeeded")

    try:
        error = run_process(driver, scenario())
    finally:
        transport.close()
    if failure is None:
        assert isinstance(error, CommunicationTimeout)
        return
    assert isinstance(error, SecurityRefused), error
    assert str(error) == f"127.0.0.1:{snmpd_port} refused SNMPv3 user {user!r} at authPriv: {failure}"
    assert failure.value in str(error) and "community" not in str(error)


def test_a_user_removed_mid_run_fails_each_request_with_the_reason(driver, tmp_path):
    """The agent's administrator deletes the user while a run polls and sets (net-snmp's snmpusm, on an snmpd of
    this test's own): the next GET and SET fail as unknown user, not as a lost datagram."""
    _, auth_key, _ = SNMPD_V3_USERS["hilsauth"]
    admin, admin_auth, admin_priv = "hilspriv", *SNMPD_V3_USERS["hilspriv"][1:]
    with snmpd(tmp_path) as port:
        transport = SnmpTransport(driver.env, driver, SnmpTarget.parse(v3_url(port, "hilsauth", auth_key, "")),
                                  tau_udp=0.5)

        def scenario():
            yield transport.get([SYS_UPTIME])
            yield transport.set([(DO_DEBUGGING, 0)])
            deleted = subprocess.run([tool("snmpusm"), "-v3", "-l", "authPriv", "-u", admin, "-a", "SHA", "-A",
                                      admin_auth, "-x", "AES", "-X", admin_priv, f"127.0.0.1:{port}", "delete",
                                      "hilsauth"], capture_output=True, text=True, timeout=10)
            assert deleted.returncode == 0, deleted.stderr
            errors = []
            for request in (lambda: transport.get([SYS_UPTIME]), lambda: transport.set([(DO_DEBUGGING, 0)])):
                try:
                    yield request()
                except TransportError as exc:
                    errors.append(exc)
            return errors

        try:
            errors = run_process(driver, scenario())
        finally:
            transport.close()
    assert [type(e) for e in errors] == [SecurityRefused, SecurityRefused]
    assert all(str(e).endswith(f"authNoPriv: {UsmFailure.UNKNOWN_USER_NAME}") for e in errors), errors


def test_the_transports_of_one_run_share_an_engine_and_keep_their_communities_apart(driver, connect, snmpd_port):
    """A corridor's controllers share one pysnmp engine (one each cost ~50 ms and the MIB modules again):
    SETs in flight together with the read-write and the read-only community are each judged by their own."""
    writers = [connect(snmpd_port, community="private") for _ in range(3)]
    reader = connect(snmpd_port)
    assert len({id(t._engine) for t in (*writers, reader)}) == 1
    env = driver.env
    outcomes: dict[str, object] = {}

    def one(name, transport, value):
        try:
            yield transport.set([(AUTHEN_TRAPS, value)])
            outcomes[name] = "done"
        except SnmpError as exc:
            outcomes[name] = exc.status

    def scenario():
        yield simpy.AllOf(env, [env.process(one(f"w{i}", w, 1)) for i, w in enumerate(writers)]
                          + [env.process(one("r", reader, 2))])

    run_process(driver, scenario())
    assert outcomes == {"w0": "done", "w1": "done", "w2": "done", "r": ErrorStatus.NO_ACCESS}


def test_closing_one_controllers_transport_leaves_the_shared_engine_to_the_others(driver, connect, snmpd_port):
    first, second = connect(snmpd_port, community="private"), connect(snmpd_port, community="private")

    def set_and_read(transport, value):
        yield transport.set([(AUTHEN_TRAPS, value)])
        return (yield transport.get([AUTHEN_TRAPS]))

    assert run_process(driver, set_and_read(first, 1)) == (1,)
    first.close()
    assert run_process(driver, set_and_read(second, 2)) == (2,)
