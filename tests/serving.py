"""`hils emulator serve` as a subprocess on a free port, for tests that need a real SNMP agent."""

from __future__ import annotations

import re
import select
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Served:
    proc: subprocess.Popen[str]
    port: int
    ready_at: float  # time.monotonic() when the ready line was read
    log: Path

    def stop(self, sig: signal.Signals = signal.SIGTERM) -> tuple[int, str]:
        """Signal the server; its exit code and the rest of its stdout."""
        self.proc.send_signal(sig)
        out, _ = self.proc.communicate(timeout=10)
        return self.proc.returncode, out


def start_server(log: Path, *args: str, verbose: bool = False) -> Served:
    """Start the agent (``--port 0``) and wait for its ready line; stderr goes to ``log``."""
    cmd = [sys.executable, "-m", "hils.cli", *(["-v"] if verbose else []), "emulator", "serve", "--port", "0", *args]
    with log.open("w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    line = proc.stdout.readline() if ready else ""
    match = re.fullmatch(r"serving (.+) on udp:127\.0\.0\.1:(\d+) \(ro=(\S+) rw=(\S+)\)\n", line)
    if match is None:
        proc.kill()
        proc.wait()
        raise AssertionError(f"no ready line, got {line!r}; stderr:\n{log.read_text()}")
    return Served(proc, int(match[2]), time.monotonic(), log)
