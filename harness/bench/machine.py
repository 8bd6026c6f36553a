"""What machine a benchmark ran on: stated beside every figure, since figures only compare within a run."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path


def describe() -> dict[str, object]:
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "system": f"{platform.system()} {platform.release()}",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        # Runnable processes averaged over 1, 5 and 15 min as the benchmark starts: on a shared machine, what the
        # others left it (a load over the core count means runs that waited for a core).
        "load": [round(x, 2) for x in os.getloadavg()],
    }


def header(info: dict[str, object]) -> str:
    load = "/".join(f"{x:.1f}" for x in info["load"])
    return (f"machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}, {info['system']}; load {load} "
            "(1/5/15 min) at the start")
