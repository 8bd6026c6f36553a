"""Real SNMP agents in their own processes, on loopback: `hils emulator serve` and net-snmp's snmpd.

Used by the wire benchmark and by the tests that need an agent nobody here wrote (snmpd) or the
emulator served over real UDP.
"""

from __future__ import annotations

import multiprocessing
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: SNMPv3 users of the snmpd below: one with authentication and privacy, one with authentication only.
SNMPD_V3_USERS = {"hilspriv": ("authPriv", "hils-auth-key", "hils-priv-key"),
                  "hilsauth": ("authNoPriv", "hils-auth-key", "")}

SNMPD_CONF = """\
rocommunity public 127.0.0.1
rwcommunity private 127.0.0.1
createUser hilspriv SHA "hils-auth-key" AES "hils-priv-key"
createUser hilsauth SHA "hils-auth-key"
rwuser hilspriv priv
rwuser hilsauth auth
"""


@dataclass
class Served:
    """`hils emulator serve` in a subprocess, serving one or more controllers."""

    proc: subprocess.Popen[str]
    ports: tuple[int, ...]  # of each controller, in the order served
    names: tuple[str, ...]  # of each controller as its ready line gives it: "CONFIG NAME [TLS ID]" in a scenario
    ready_at: float  # time.monotonic() when the ready line was read
    log: Path
    http_ports: tuple[int, ...] = ()  # of each controller's event log, with http=True

    @property
    def port(self) -> int:
        """The (first) controller's port."""
        return self.ports[0]

    def stop(self, sig: signal.Signals = signal.SIGTERM) -> tuple[int, str]:
        """Signal the server; its exit code and the rest of its stdout."""
        self.proc.send_signal(sig)
        # Read through the text stream, not communicate(timeout=...): that reads the pipe itself and loses what the
        # ready lines' readline() already buffered (a line printed with them, such as the SPaT sender's).
        watchdog = threading.Timer(10, self.proc.kill)
        watchdog.start()
        try:
            out = self.proc.stdout.read()
            self.proc.wait()
        finally:
            watchdog.cancel()
        return self.proc.returncode, out


_LOG_LINE = re.compile(r"event log of .+: http://127\.0\.0\.1:(\d+)/v1/asclog/xml/full\n")
_CONTROLLER_LINE = re.compile(r"serving (.+) on udp:127\.0\.0\.1:(\d+) "
                              r"\(ro=(\S+) rw=(\S+)( v3=\S+)? ntcip=(v0[23])\)\n")


def start_emulator(log: Path, *args: str, count: int = 1, verbose: bool = False, http: bool = False) -> Served:
    """Start `hils emulator serve --port 0 --count COUNT` (each controller on a free port; with ``http`` its event
    log on a free TCP port) and wait until every controller answers (its ready lines, and with more than one the
    final line); stderr goes to ``log``."""
    cmd = [sys.executable, "-m", "hils", *(["-v"] if verbose else []), "emulator", "serve", "--port", "0",
           "--count", str(count), *(["--http", "0"] if http else []), *args]
    with log.open("w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    # The ready lines may come in one read: a select() per line would wait on lines already buffered,
    # so read them blocking, with a timer that kills a server that never gets ready.
    watchdog = threading.Timer(20 + 0.1 * count, proc.kill)
    watchdog.start()
    try:
        lines = [proc.stdout.readline() for _ in range(count + (count > 1) + (count if http else 0))]
    finally:
        watchdog.cancel()
    final = rf"serving {count} controllers on udp:127\.0\.0\.1:\S+\n"
    matches = [_CONTROLLER_LINE.fullmatch(line) for line in lines[:count]]
    logs = [_LOG_LINE.fullmatch(line) for line in lines[count + (count > 1):]]
    if not (all(matches) and all(logs) and all(re.fullmatch(final, line) for line in lines[count:count + (count > 1)])):
        proc.kill()
        proc.wait()
        raise RuntimeError(f"hils emulator serve printed no ready line, got {lines!r}; stderr:\n{log.read_text()}")
    return Served(proc, tuple(int(m[2]) for m in matches), tuple(m[1] for m in matches), time.monotonic(), log,
                  tuple(int(m[1]) for m in logs))


def tool(name: str) -> str:
    """Path of a net-snmp program (Debian packages snmp and snmpd)."""
    path = shutil.which(name, path=os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/usr/bin"]))
    if path is None:
        raise RuntimeError(f"{name} not found: install the Debian packages snmpd and snmp")
    return path


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _answers(snmpget: str, port: int) -> bool:
    probe = subprocess.run([snmpget, "-v2c", "-c", "public", "-t", "0.2", "-r", "0", "-On",
                            f"127.0.0.1:{port}", ".1.3.6.1.2.1.1.3.0"], capture_output=True, timeout=5)
    return probe.returncode == 0


@contextmanager
def snmpd(workdir: Path) -> Iterator[int]:
    """net-snmp's snmpd in the foreground on a free loopback port (communities public / private);
    yields the port once it answers."""
    snmpd_bin, snmpget = tool("snmpd"), tool("snmpget")
    conf = workdir / "snmpd.conf"
    conf.write_text(SNMPD_CONF)
    # No MIB loading (quiet, fast), persistent state in workdir, no smux listener on TCP 199.
    env = {**os.environ, "MIBS": "", "SNMP_PERSISTENT_DIR": str(workdir / "persist")}
    for _attempt in range(3):
        port = free_udp_port()
        proc = subprocess.Popen([snmpd_bin, "-f", "-Lf", str(workdir / "snmpd.log"), "-C", "-c", str(conf),
                                 "-I", "-smux", f"udp:127.0.0.1:{port}"],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10.0
        while proc.poll() is None and time.monotonic() < deadline and not _answers(snmpget, port):
            time.sleep(0.05)
        if proc.poll() is None and _answers(snmpget, port):
            break
        proc.kill()
        proc.wait()
    else:
        raise RuntimeError(f"snmpd did not start; see {workdir / 'snmpd.log'}")
    try:
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def in_fresh_process(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a newly spawned Python process (its own libsumo, its own memory), its result returned:
    benchmarks measure each run the way a user starts it, uninfluenced by the runs before."""
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, args)
