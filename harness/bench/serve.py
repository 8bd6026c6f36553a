"""Resident memory of `hils emulator serve --count N` as N grows (issue 16: at most 10 MB per added controller).

Each N runs in a fresh process, as a lab would start it; its resident set is read from /proc once every
controller has answered one GET (so what a first request allocates is counted) and the process has settled.
``python -m harness.bench.serve`` prints the figures.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from harness.bench.processes import start_emulator, tool

COUNTS = (1, 4, 16, 64)
GOAL_MB_PER_CONTROLLER = 10.0
# maxPhases: every controller answers it, through the whole path of a GET.
_PROBE_OID = ".1.3.6.1.4.1.1206.4.2.1.1.1.0"


def resident_mb(pid: int) -> float:
    """VmRSS of a process, in MB (10^6 bytes)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024 / 1e6
    raise RuntimeError(f"/proc/{pid}/status has no VmRSS line")


def serve_rss_mb(count: int, workdir: Path, settle: float = 1.0) -> float:
    """Resident memory of one `hils emulator serve --count COUNT` serving every controller."""
    served = start_emulator(workdir / f"serve-{count}.log", count=count)
    try:
        snmpget = tool("snmpget")
        for port in served.ports:
            subprocess.run([snmpget, "-v2c", "-c", "public", "-On", "-t", "2", "-r", "1", f"127.0.0.1:{port}",
                            _PROBE_OID], capture_output=True, check=True, timeout=10)
        time.sleep(settle)
        return resident_mb(served.proc.pid)
    finally:
        served.stop()


def measure_serve_memory(counts: Sequence[int] = COUNTS) -> dict[str, Any]:
    """RSS (MB) per N and the least-squares slope, MB per added controller."""
    with tempfile.TemporaryDirectory() as tmp:
        rss = {n: serve_rss_mb(n, Path(tmp)) for n in counts}
    return {"rss_mb": rss, **per_added_controller(rss), "goal_mb_per_controller": GOAL_MB_PER_CONTROLLER}


def per_added_controller(rss: Mapping[int, float]) -> dict[str, float | None]:
    """The least-squares line through resident MB against controllers: MB per added controller and the base
    (None for both with fewer than two counts)."""
    if len(rss) < 2:
        return {"mb_per_controller": None, "base_mb": None}
    slope, intercept = np.polyfit(list(rss), list(rss.values()), 1)
    return {"mb_per_controller": float(slope), "base_mb": float(intercept)}


def main(argv: Sequence[str] | None = None) -> int:
    counts = [int(n) for n in argv] if argv else list(COUNTS)
    figures = measure_serve_memory(counts)
    for n, mb in figures["rss_mb"].items():
        print(f"  {n:4d} controllers  {mb:7.1f} MB")
    print(f"  {figures['mb_per_controller']:.3f} MB per added controller (goal <= {GOAL_MB_PER_CONTROLLER:g}), "
          f"{figures['base_mb']:.1f} MB base")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
