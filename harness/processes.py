"""Real SNMP agents in their own processes, on loopback: `hils emulator serve` and net-snmp's snmpd.

Used by the wire benchmark and by the tests that need an agent nobody here wrote (snmpd) or the
emulator served over real UDP.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

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
    """`hils emulator serve` in a subprocess."""

    proc: subprocess.Popen[str]
    port: int
    ready_at: float  # time.monotonic() when the ready line was read
    log: Path

    def stop(self, sig: signal.Signals = signal.SIGTERM) -> tuple[int, str]:
        """Signal the server; its exit code and the rest of its stdout."""
        self.proc.send_signal(sig)
        out, _ = self.proc.communicate(timeout=10)
        return self.proc.returncode, out


def start_emulator(log: Path, *args: str, verbose: bool = False) -> Served:
    """Start `hils emulator serve --port 0` and wait for its ready line; stderr goes to ``log``."""
    cmd = [sys.executable, "-m", "hils.cli", *(["-v"] if verbose else []), "emulator", "serve", "--port", "0", *args]
    with log.open("w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    line = proc.stdout.readline() if ready else ""
    match = re.fullmatch(r"serving (.+) on udp:127\.0\.0\.1:(\d+) \(ro=(\S+) rw=(\S+)( v3=\S+)?\)\n", line)
    if match is None:
        proc.kill()
        proc.wait()
        raise RuntimeError(f"hils emulator serve printed no ready line, got {line!r}; stderr:\n{log.read_text()}")
    return Served(proc, int(match[2]), time.monotonic(), log)


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
