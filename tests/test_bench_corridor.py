"""`hils bench corridor` measures what it says: controllers at the wall clock against served emulators, virtual
time per controller-hour, memory of both processes."""

from __future__ import annotations

import subprocess
import sys

from harness.bench_corridor import GOAL_P99_S, virtual_run, wall_clock_run


def test_a_wall_clock_count_runs_every_controller_against_its_served_emulator() -> None:
    r = wall_clock_run(3, 4.0)
    assert r["timeouts"] == {} and r["passes"]
    # 10 Hz each: every poll due in 4 s was settled, and answered (loopback loses nothing)
    assert r["polls"]["answered"] >= 3 * 4 * 10 * 0.9
    assert r["polls"]["failed"] == 0
    assert 0 < r["lateness_p99_ms"] < GOAL_P99_S * 1e3
    assert r["rss_mb"] > 20 and r["serve_rss_mb"] > 20
    assert 0 < r["cpu_share"] < 1 and 0 < r["serve_cpu_share"] < 1


def test_virtual_time_is_reported_per_simulated_controller_hour() -> None:
    r = virtual_run(2, False, 120.0)
    assert r["controllers"] == 2
    assert r["wall_per_controller_hour_s"] == r["wall_s"] * 3600.0 / (2 * 120.0)


def test_counts_that_are_not_a_list_of_positive_numbers_are_refused_in_one_line() -> None:
    done = subprocess.run([sys.executable, "-m", "hils.cli", "bench", "corridor", "--counts", "4,0"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines()[-1] == ("hils bench corridor: error: argument --counts: '4,0': allowed: counts "
                                            "of 1 or more, comma-separated (e.g. 1,4,16,64)")
