"""`hils bench corridor` measures what it says: controllers at the wall clock against served emulators, virtual
time per controller-hour, memory of both processes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from harness.bench.corridor import GOAL_P99_S, limit, measure_memory, most_passing, virtual_run, wall_clock_run

pytestmark = pytest.mark.wallclock


def test_a_wall_clock_count_runs_every_controller_against_its_served_emulator() -> None:
    r = wall_clock_run(3, 4.0)
    assert r["started"] and r["timeouts"] == {} and r["passes"]
    # 10 Hz each: every poll due in 4 s was settled, and answered (loopback loses nothing)
    assert r["polls"]["answered"] >= 3 * 4 * 10 * 0.9
    assert r["polls"]["failed"] == 0
    assert 0 < r["lateness_p99_ms"] < GOAL_P99_S * 1e3
    assert r["rss_mb"] > 20 and r["serve_rss_mb"] > 20
    assert 0 < r["cpu_share"] < 1 and 0 < r["serve_cpu_share"] < 1


def test_virtual_time_is_reported_per_simulated_controller_hour() -> None:
    r = virtual_run(3, count=2, sumo=False, duration=120.0)
    assert r["controllers"] == 2 and r["seed"] == 3
    assert r["wall_per_controller_hour_s"] == r["wall_s"] * 3600.0 / (2 * 120.0)


def _run(count: int, passes: bool, *, started: bool = True, rss: float = 60.0) -> dict:
    if not started:
        return {"controllers": count, "started": False, "passes": False, "refused": count, "refusal": "C1: no answer"}
    return {"controllers": count, "started": True, "passes": passes, "duration_s": 30.0, "lateness_p99_ms": 25.0,
            "timeouts": {} if passes else {"communication": 2}, "polls": {"polls": 300 * count, "failed": 3},
            "cpu_share": 0.9, "serve_cpu_share": 0.4, "rss_mb": rss + 0.1 * count, "serve_rss_mb": rss + 0.2 * count}


def test_a_climb_passes_the_count_before_its_first_failure_and_says_what_stopped_it() -> None:
    climb = [_run(1, True), _run(4, True), _run(16, False)]
    assert most_passing(climb) == 4
    assert most_passing([_run(1, False)]) == 0
    stopped = limit(climb[-1])
    assert stopped == {"controllers": 16, "started": True, "lateness_p99_ms": 25.0,
                       "timeouts": {"communication": 2}, "failed_polls": 3, "polls_per_s": 160.0, "cpu_share": 0.9,
                       "serve_cpu_share": 0.4}
    assert limit(_run(512, False, started=False)) == {"controllers": 512, "started": False, "refused": 512,
                                                       "refusal": "C1: no answer"}


def test_memory_per_controller_takes_the_median_of_the_climbs_and_leaves_out_counts_that_did_not_start() -> None:
    climbs = [[_run(1, True, rss=60), _run(4, True, rss=60), _run(2000, False, started=False)],
              [_run(1, True, rss=70), _run(4, True, rss=70), _run(16, False, rss=70)],
              [_run(1, True, rss=62), _run(4, True, rss=62), _run(16, False, rss=62)]]
    m = measure_memory(climbs)
    # per count the median of the climbs that ran it: 16 ran in two (71.6 and 63.6 MB); 2000 never started
    assert m["middleware"]["rss_mb"] == pytest.approx({1: 62.1, 4: 62.4, 16: 67.6})
    assert m["serve"]["rss_mb"][16] == pytest.approx(69.2)


def test_counts_that_are_not_a_list_of_positive_numbers_are_refused_in_one_line() -> None:
    done = subprocess.run([sys.executable, "-m", "hils", "bench", "corridor", "--counts", "4,0"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines()[-1] == ("hils bench corridor: error: argument --counts: '4,0': allowed: counts "
                                            "of 1 or more, comma-separated (e.g. 1,4,16,64)")
