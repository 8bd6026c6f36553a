"""`hils bench corridor`: how many controllers one middleware process drives, and what each one costs.

Three figures, each run in a fresh process (a lab starts one middleware and one `hils emulator serve`):

- **Wall clock.** N controllers served by one `hils emulator serve --count N` on loopback, driven by one
  Testbed at 10 Hz polling each (the shipped four-leg config everywhere, no SUMO: the middleware's own
  work is what is measured; a fixed-cycle agent switches each controller every 10 s). A count passes when
  no manager entered TIMEOUT (drift or any other reason) and the driver's event lateness (the wall time
  an event started minus its due time, over the whole run, start-up included) has p99 under 20 ms.
  Counts go up until one fails: a *climb*. The climb is made several times (``--climbs``, 3): the count
  that passes is reported with its spread over the climbs, and what each climb's first failing count ran
  into (its lateness, TIMEOUTs, polls a second, and how busy the middleware's one thread and the serve
  process were).
- **Virtual time.** Wall seconds per simulated controller-hour, 1, 4 and 16 controllers: with SUMO
  (four_leg, corridor, grid4x4 with max-pressure: networks and traffic grow with the count) and without
  (the same config N times, a random agent: only the controllers and their middleware grow); one run per
  seed (``--seeds``, 0-4), alternately (:mod:`harness.bench.seeds`), median and min-max over the seeds.
- **Memory.** Resident memory of the middleware process and of the serve process at the end of each
  wall-clock run (per count, the median over the climbs), and the least-squares MB per added controller
  of each.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

from harness.bench.processes import in_fresh_process, start_emulator
from harness.bench.seeds import Spread, alternate
from harness.bench.serve import GOAL_MB_PER_CONTROLLER, per_added_controller, resident_mb

WALL_COUNTS = (1, 4, 16, 64, 128, 256, 512)
VIRTUAL_COUNTS = (1, 4, 16)
SUMO_SCENARIOS = {1: "four_leg", 4: "corridor", 16: "grid4x4"}
GOAL_CONTROLLERS = 64
GOAL_P99_S = 0.020


def replicated(count: int) -> Any:
    """A scenario of ``count`` controllers, each with the shipped four-leg config, and no network."""
    from hils.protocol import config as config_mod
    from hils.protocol.scenario import Scenario

    cfg = config_mod.load()
    return Scenario(name=f"{count} x {cfg.name}", source="<bench corridor>", sumo_config=Path("none"),
                    intersections={f"C{i + 1}": cfg for i in range(count)})


def wall_clock_run(count: int, duration: float) -> dict[str, Any]:
    """One middleware process driving ``count`` served controllers for ``duration`` wall seconds. A count whose
    controllers are not all read at start-up (the middleware's first reads unanswered within n_timeout x tau_udp)
    fails without running: ``started`` False, with how many were refused and the first reason."""
    from hils.run.testbed import Testbed
    from hils.shell.events import Kind
    from hils.shell.preflight import ControllerCheckFailed

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
            try:
                tb.run()
            except ControllerCheckFailed as exc:
                refusals = str(exc).split("; ")
                return {"controllers": count, "duration_s": duration, "started": False, "passes": False,
                        "refused": len(refusals), "refusal": refusals[0]}
            finally:
                tb.close()
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
        finally:
            served.stop()
    return {"controllers": count, "duration_s": duration, "started": True, "lateness_p99_ms": lateness.p99 * 1e3,
            "lateness_mean_ms": lateness.mean * 1e3, "lateness_max_ms": lateness.max * 1e3,
            "events": lateness.count, "timeouts": dict(timeouts), "drifted_steps": drifted,
            "transitions_verified": verified, "polls": dict(polls),
            "cpu_share": cpu / duration, "serve_cpu_share": serve_cpu / duration,
            "rss_mb": rss, "serve_rss_mb": serve_rss,
            "passes": not timeouts and lateness.p99 < GOAL_P99_S}


def virtual_run(seed: int, *, count: int, sumo: bool, duration: float) -> dict[str, Any]:
    """Wall seconds of a virtual-time run of ``count`` controllers at ``seed``, with the shipped scenario of that
    many lights under SUMO or, without SUMO, the four-leg config ``count`` times."""
    from hils.run.testbed import Testbed

    scenario = SUMO_SCENARIOS[count] if sumo else replicated(count)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        tb = Testbed(scenario=scenario, sumo=sumo, duration=duration, seed=seed, log_path=Path(tmp) / "events.jsonl")
        tb.run()
        wall = time.perf_counter() - t0
        tb.close()
    return {"controllers": count, "scenario": scenario if sumo else "four_leg config x N, no SUMO",
            "duration_s": duration, "seed": seed, "wall_s": wall,
            "wall_per_controller_hour_s": per_controller_hour(wall, count, duration)}


def per_controller_hour(wall: float, count: int, duration: float) -> float:
    """Wall seconds per simulated controller-hour of a run of ``count`` controllers over ``duration`` s."""
    return wall / (count * duration / 3600.0)


def wall_clock_ladder(counts: Sequence[int], duration: float) -> list[dict[str, Any]]:
    """One climb: each count in a fresh process, in order, until one fails (that one included)."""
    runs: list[dict[str, Any]] = []
    for count in counts:
        runs.append(in_fresh_process(wall_clock_run, count, duration))
        if not runs[-1]["passes"]:
            break
    return runs


def most_passing(ladder: Sequence[Mapping[str, Any]]) -> int:
    """The largest count of a climb that passed before the first that failed (0 if the first failed)."""
    passing = [r["controllers"] for r in ladder if r["passes"]]
    return max(passing, default=0)


def limit(run: Mapping[str, Any]) -> dict[str, Any]:
    """What a failing count ran into: its lateness, its TIMEOUTs, how busy each process was, the polls it made (or,
    when it did not start, how many controllers the start-up refused and why)."""
    if not run["started"]:
        return {"controllers": run["controllers"], "started": False, "refused": run["refused"],
                "refusal": run["refusal"]}
    polls = run["polls"]
    return {"controllers": run["controllers"], "started": True, "lateness_p99_ms": run["lateness_p99_ms"],
            "timeouts": run["timeouts"], "failed_polls": polls.get("failed", 0),
            "polls_per_s": polls.get("polls", 0) / run["duration_s"], "cpu_share": run["cpu_share"],
            "serve_cpu_share": run["serve_cpu_share"]}


def measure_wall_clock(counts: Sequence[int], duration: float, climbs: int) -> dict[str, Any]:
    """``climbs`` climbs of the counts (:func:`wall_clock_ladder`): each climb's runs, the count that passes with
    its spread over the climbs, and what each climb's first failing count ran into."""
    ladders = [wall_clock_ladder(counts, duration) for _ in range(climbs)]
    passing = [most_passing(ladder) for ladder in ladders]
    return {"climbs": ladders, "most_controllers_passing": passing,
            "most_controllers_passing_spread": Spread.of(passing).as_dict(),
            "limits": [limit(ladder[-1]) for ladder in ladders if not ladder[-1]["passes"]],
            "goal_controllers": GOAL_CONTROLLERS, "goal_p99_ms": GOAL_P99_S * 1e3}


def measure_virtual(seeds: Sequence[int], duration: float) -> dict[str, list[dict[str, Any]]]:
    """Per count, with SUMO and without, one run per seed, alternately, each in a fresh process: every run and the
    wall seconds per controller-hour over the seeds."""
    sides = {(sumo, count): partial(virtual_run, count=count, sumo=sumo, duration=duration)
             for sumo in (True, False) for count in VIRTUAL_COUNTS}
    runs = alternate(seeds, {f"{'with_sumo' if sumo else 'controllers_only'}:{count}": run
                             for (sumo, count), run in sides.items()})
    out: dict[str, list[dict[str, Any]]] = {"with_sumo": [], "controllers_only": []}
    for side, by_seed in runs.items():
        key, count = side.split(":")
        first = next(iter(by_seed.values()))
        out[key].append({"controllers": int(count), "scenario": first["scenario"], "duration_s": duration,
                         "runs": list(by_seed.values()),
                         "wall_s": Spread.of([r["wall_s"] for r in by_seed.values()]).as_dict(),
                         "wall_per_controller_hour_s": Spread.of([r["wall_per_controller_hour_s"]
                                                                  for r in by_seed.values()]).as_dict()})
    return out


def measure_memory(ladders: Sequence[Sequence[Mapping[str, Any]]]) -> dict[str, Any]:
    """Resident memory of each process at the end of the wall-clock runs that started (per count, the median over
    the climbs), and the least-squares MB per added controller of each."""
    memory: dict[str, Any] = {}
    for side, field in (("middleware", "rss_mb"), ("serve", "serve_rss_mb")):
        by_count: dict[int, list[float]] = {}
        for ladder in ladders:
            for r in ladder:
                if r["started"]:
                    by_count.setdefault(r["controllers"], []).append(r[field])
        rss = {count: statistics.median(values) for count, values in sorted(by_count.items())}
        memory[side] = {"rss_mb": rss, **per_added_controller(rss)}
    return {**memory, "goal_mb_per_controller": GOAL_MB_PER_CONTROLLER}


def measure_corridor(wall_counts: Sequence[int] = WALL_COUNTS, wall_duration: float = 30.0,
                     virtual_duration: float = 600.0, seeds: Sequence[int] = (0, 1, 2, 3, 4),
                     climbs: int = 3) -> dict[str, Any]:
    """The three figures: the wall-clock climbs, the virtual-time runs over ``seeds``, the memory."""
    wall = measure_wall_clock(wall_counts, wall_duration, climbs)
    return {"wall_clock": wall, "virtual": measure_virtual(seeds, virtual_duration), "seeds": list(seeds),
            "memory": measure_memory(wall["climbs"])}


def _cpu_s(pid: int) -> float:
    """User plus system CPU seconds of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
