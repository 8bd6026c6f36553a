"""`hils bench corridor`: how many controllers one middleware process drives, and what each one costs.

Three figures, each run in a fresh process (a lab starts one middleware and one `hils emulator serve`):

- **Wall clock.** N controllers served by one `hils emulator serve --count N` on loopback, driven by one
  Testbed at 10 Hz polling each (the shipped four-leg config everywhere, no SUMO: the middleware's own
  work is what is measured; a fixed-cycle agent switches each controller every 10 s). A count passes when
  no manager entered TIMEOUT (drift or any other reason) and the driver's event lateness (the wall time
  an event started minus its due time, over the whole run, start-up included) has p99 under 20 ms.
  Counts go up until one fails.
- **Virtual time.** Wall seconds per simulated controller-hour, 1, 4 and 16 controllers: with SUMO
  (four_leg, corridor, grid4x4 with max-pressure: networks and traffic grow with the count) and without
  (the same config N times, a random agent: only the controllers and their middleware grow).
- **Memory.** Resident memory of the middleware process and of the serve process at the end of each
  wall-clock run, and the least-squares MB per added controller of each.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from harness.bench_serve import GOAL_MB_PER_CONTROLLER, per_added_controller, resident_mb
from harness.processes import in_fresh_process, start_emulator

WALL_COUNTS = (1, 4, 16, 64, 128, 256, 512)
VIRTUAL_COUNTS = (1, 4, 16)
SUMO_SCENARIOS = {1: "four_leg", 4: "corridor", 16: "grid4x4"}
GOAL_CONTROLLERS = 64
GOAL_P99_S = 0.020


def replicated(count: int) -> Any:
    """A scenario of ``count`` controllers, each with the shipped four-leg config, and no network."""
    from hils import config as config_mod
    from hils.scenario import Scenario

    cfg = config_mod.load()
    return Scenario(name=f"{count} x {cfg.name}", source="<bench corridor>", sumo_config=Path("none"),
                    intersections={f"C{i + 1}": cfg for i in range(count)})


def wall_clock_run(count: int, duration: float) -> dict[str, Any]:
    """One middleware process driving ``count`` served controllers for ``duration`` wall seconds."""
    from hils.events import Kind
    from hils.testbed import Testbed

    scenario = replicated(count)
    with tempfile.TemporaryDirectory() as tmp:
        served = start_emulator(Path(tmp) / "serve.log", count=count)
        try:
            targets = {tls: f"snmp://127.0.0.1:{port}?community=private&version=2c"
                       for tls, port in zip(scenario.tls_ids, served.ports, strict=True)}
            serve_cpu0 = _cpu_s(served.proc.pid)
            cpu0 = time.process_time()
            tb = Testbed(scenario=scenario, target=targets, action_type="switch", agent="fixed-cycle",
                         duration=duration, recover_after=None, log_path=Path(tmp) / "events.jsonl")
            tb.run()
            cpu = time.process_time() - cpu0
            serve_cpu = _cpu_s(served.proc.pid) - serve_cpu0
            rss, serve_rss = resident_mb(os.getpid()), resident_mb(served.proc.pid)
            lateness = tb.lateness
            polls: Counter[str] = Counter()
            timeouts: Counter[str] = Counter()
            kinds: Counter[str] = Counter()
            for i in tb.intersections.values():
                polls.update(i.middleware.poll_counts)
                timeouts.update(r["reason"] for r in i.tally.records if r["kind"] == Kind.TIMEOUT_ENTERED)
                kinds.update(i.tally.kinds)
            verified, drifted = kinds[Kind.TRANSITION_VERIFIED], kinds[Kind.DRIFT]
            tb.close()
        finally:
            served.stop()
    return {"controllers": count, "duration_s": duration, "lateness_p99_ms": lateness.p99 * 1e3,
            "lateness_mean_ms": lateness.mean * 1e3, "lateness_max_ms": lateness.max * 1e3,
            "events": lateness.count, "timeouts": dict(timeouts), "drifted_steps": drifted,
            "transitions_verified": verified, "polls": dict(polls),
            "cpu_share": cpu / duration, "serve_cpu_share": serve_cpu / duration,
            "rss_mb": rss, "serve_rss_mb": serve_rss,
            "passes": not timeouts and lateness.p99 < GOAL_P99_S}


def virtual_run(count: int, sumo: bool, duration: float) -> dict[str, Any]:
    """Wall seconds of a virtual-time run of ``count`` controllers, with the shipped scenario of that many
    lights under SUMO or, without SUMO, the four-leg config ``count`` times."""
    from hils.testbed import Testbed

    scenario = SUMO_SCENARIOS[count] if sumo else replicated(count)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        tb = Testbed(scenario=scenario, sumo=sumo, duration=duration, log_path=Path(tmp) / "events.jsonl")
        tb.run()
        wall = time.perf_counter() - t0
        tb.close()
    return {"controllers": count, "scenario": scenario if sumo else "four_leg config x N, no SUMO",
            "duration_s": duration, "wall_s": wall,
            "wall_per_controller_hour_s": per_controller_hour(wall, count, duration)}


def per_controller_hour(wall: float, count: int, duration: float) -> float:
    """Wall seconds per simulated controller-hour of a run of ``count`` controllers over ``duration`` s."""
    return wall / (count * duration / 3600.0)


def measure_corridor(wall_counts: Sequence[int] = WALL_COUNTS, wall_duration: float = 30.0,
                     virtual_duration: float = 600.0, repeat: int = 3) -> dict[str, Any]:
    """The three figures; wall-clock counts stop after the first that fails, virtual runs are medians of
    ``repeat`` (alternating with and without SUMO)."""
    wall: list[dict[str, Any]] = []
    for count in wall_counts:
        wall.append(in_fresh_process(wall_clock_run, count, wall_duration))
        if not wall[-1]["passes"]:
            break
    passing = [r["controllers"] for r in wall if r["passes"]]
    virtual: dict[str, list[dict[str, Any]]] = {}
    for with_sumo in (True, False):
        key = "with_sumo" if with_sumo else "controllers_only"
        virtual[key] = []
        for count in VIRTUAL_COUNTS:
            runs = [in_fresh_process(virtual_run, count, with_sumo, virtual_duration) for _ in range(repeat)]
            median = statistics.median(r["wall_s"] for r in runs)
            virtual[key].append({**runs[0], "wall_s": median, "runs_wall_s": [r["wall_s"] for r in runs],
                                 "wall_per_controller_hour_s": per_controller_hour(median, count,
                                                                                   virtual_duration)})
    memory = {}
    for side, field in (("middleware", "rss_mb"), ("serve", "serve_rss_mb")):
        rss = {r["controllers"]: r[field] for r in wall}
        memory[side] = {"rss_mb": rss, **per_added_controller(rss)}
    return {"wall_clock": {"runs": wall, "most_controllers_passing": max(passing, default=0),
                           "goal_controllers": GOAL_CONTROLLERS, "goal_p99_ms": GOAL_P99_S * 1e3},
            "virtual": virtual, "memory": {**memory, "goal_mb_per_controller": GOAL_MB_PER_CONTROLLER}}


def _cpu_s(pid: int) -> float:
    """User plus system CPU seconds of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
