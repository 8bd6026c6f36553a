"""The RESCO study: every cell a fresh process whose figures are kept, so a study resumes; gains seed by seed and the
share that survives; a README and results.json a reader can use."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from harness.bench.resco_study import Cell, _cached, aggregate, cells, render_readme

CODE = "0123456789abcdef"


def _result(scenario: str, agent: str, side: str, seed: int, delay: float) -> dict:
    return {"cell": {"scenario": scenario, "agent": agent, "side": side, "seed": seed, "duration": 3600.0},
            "code": CODE,
            "resco": {"delay_s": delay, "trip_time_s": delay + 100, "waiting_time_s": delay / 2, "queue": 1.0},
            "wall_s": 10.0, "commit": "abc1234", "machine": {"cpu": "test", "cores": 2}}


def test_the_gain_is_taken_seed_by_seed_and_what_survives_is_the_ratio_of_the_mean_gains() -> None:
    delays = {("max-pressure", "sumo_rl"): (20.0, 30.0, 40.0), ("fixed-cycle", "sumo_rl"): (50.0, 70.0, 60.0),
              ("max-pressure", "hils"): (35.0, 44.0, 50.0), ("fixed-cycle", "hils"): (55.0, 72.0, 60.0)}
    results = [_result("grid4x4", agent, side, seed, d) for (agent, side), ds in delays.items()
               for seed, d in enumerate(ds)]
    table = aggregate(results)["grid4x4"]
    assert table["seeds"] == [0, 1, 2]
    # sumo-rl: gains 30, 40, 20 (mean 30); hils: 20, 28, 10 (mean 19.33)
    assert table["gain"]["sumo_rl"]["delay_s"]["mean"] == pytest.approx(30.0)
    assert table["gain"]["hils"]["delay_s"]["mean"] == pytest.approx(58.0 / 3)
    assert table["gain_surviving"] == pytest.approx((58.0 / 3) / 30.0)
    # the share of fixed-time's delay, seed by seed: 1 - 20/50, 1 - 30/70, 1 - 40/60
    assert table["gain"]["sumo_rl"]["share"]["mean"] == pytest.approx((0.6 + 4 / 7 + 1 / 3) / 3)
    # 95 % CI of the three gains 30, 40, 20: t(2) = 4.303, sd 10
    assert table["gain"]["sumo_rl"]["delay_s"]["half_width"] == pytest.approx(4.303 * 10 / 3 ** 0.5)
    # what the controller costs each agent, seed by seed: 15, 14, 10 and 5, 2, 0
    assert table["hils_minus_sumo_rl_delay_s"]["max-pressure"]["mean"] == pytest.approx(13.0)
    assert table["hils_minus_sumo_rl_delay_s"]["fixed-cycle"]["mean"] == pytest.approx(7.0 / 3)
    assert table["figures"]["max-pressure/hils"]["trip_time_s"]["mean"] == pytest.approx(143.0)
    readme = render_readme({"grid4x4": table}, {"scenarios": "grid4x4", "sumo_rl": "1.4.5", "duration": "3600",
                                                "seeds": "0-2", "duration_arg": "3600",
                                                "timing": ""})
    assert "| grid4x4 | max-pressure | hils | 43.0 ± " in readme and "| 3 |" in readme
    assert "by 30.0 ± 24.8 s" in readme and "64% of the gain survives" in readme


def test_where_max_pressure_does_worse_under_sumo_rl_there_is_no_gain_to_survive() -> None:
    delays = {("max-pressure", "sumo_rl"): (250.0, 270.0), ("fixed-cycle", "sumo_rl"): (60.0, 50.0),
              ("max-pressure", "hils"): (260.0, 280.0), ("fixed-cycle", "hils"): (62.0, 58.0)}
    table = aggregate([_result("cologne8", agent, side, seed, d) for (agent, side), ds in delays.items()
                       for seed, d in enumerate(ds)])
    assert table["cologne8"]["gain"]["sumo_rl"]["delay_s"]["mean"] == pytest.approx(-205.0)
    assert table["cologne8"]["gain_surviving"] is None  # not -210 / -205: no gain, nothing survives
    readme = render_readme(table, {"scenarios": "cologne8", "sumo_rl": "1.4.5", "duration": "3600", "seeds": "0,1",
                                   "duration_arg": "3600", "timing": ""})
    assert "- cologne8: max-pressure adds to RESCO's delay 205.0 ± " in readme and "there is none to survive" in readme
    assert "| cologne8 | -205.0 ± " in readme


def test_a_cell_is_read_back_only_for_the_same_run(tmp_path: Path) -> None:
    cell = Cell("cologne1", "max-pressure", "hils", 3, 600.0)
    assert _cached(cell, tmp_path, CODE) is None
    path = cell.path(tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(_result("cologne1", "max-pressure", "hils", 3, 12.0)))  # an hour, not 600 s
    assert _cached(cell, tmp_path, CODE) is None
    assert _cached(Cell("cologne1", "max-pressure", "hils", 3, 3600.0), tmp_path, CODE)["resco"]["delay_s"] == 12.0
    # other code: hils' or the emulator's files, the peer, sumo-rl or SUMO changed
    assert _cached(Cell("cologne1", "max-pressure", "hils", 3, 3600.0), tmp_path, "other code") is None
    path.write_text('{"cell": ')  # torn: run it again
    assert _cached(cell, tmp_path, CODE) is None


def test_the_cells_put_both_sides_of_a_seed_side_by_side() -> None:
    todo = cells(["grid4x4", "cologne1"], ["max-pressure", "fixed-cycle"], [0, 1], 60.0)
    assert len(todo) == 2 * 2 * 2 * 2 and len(set(todo)) == len(todo)
    assert [(c.side, c.seed) for c in todo[:4]] == [("sumo_rl", 0), ("hils", 0), ("sumo_rl", 1), ("hils", 1)]


def _study(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "harness.bench.resco_study", "--scenarios", "cologne1", "--seeds", "0",
                           "--duration", "120", "--out", str(out), "--workers", "2", "--no-progress", *extra],
                          capture_output=True, text=True, timeout=600)


def test_the_study_runs_both_agents_on_both_sides_and_resumes_from_its_cells(tmp_path: Path) -> None:
    out = tmp_path / "resco"
    done = _study(out)
    assert done.returncode == 0, done.stderr
    files = sorted((out / "cells" / "cologne1").iterdir())
    assert [f.name for f in files] == ["hils-fixed-cycle-seed0.json", "hils-max-pressure-seed0.json",
                                       "sumo_rl-fixed-cycle-seed0.json", "sumo_rl-max-pressure-seed0.json"]
    doc = json.loads((out / "results.json").read_text())
    assert doc["seeds"] == [0] and len(doc["runs"]) == 4 and doc["failed"] == []
    for run in doc["runs"]:
        assert run["resco"]["queue_steps"] == 12 and run["resco"]["delay_s"] > 0 and run["machine"]["cores"]
        if run["cell"]["side"] == "hils":
            assert run["timeouts"] == 0
    readme = (out / "README.md").read_text()
    assert "| cologne1 | max-pressure | sumo-rl |" in readme and "| cologne1 | fixed-time | hils |" in readme
    assert "--scenarios cologne1" in readme and "## What differs between the two sides" in readme
    stamps = [f.stat().st_mtime_ns for f in files]
    again = _study(out)
    assert again.returncode == 0, again.stderr
    assert [f.stat().st_mtime_ns for f in files] == stamps  # read back, not run again
    assert json.loads((out / "results.json").read_text())["aggregates"] == doc["aggregates"]


def test_a_study_of_an_unknown_scenario_is_refused_in_one_line(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "harness.bench.resco_study", "--scenarios", "grid5x5", "--out",
                           str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.splitlines()[-1].startswith("python -m harness.bench.resco_study: error: --scenarios: grid5x5: "
                                                   "allowed: all, or some of grid4x4,")
    assert not (tmp_path / "cells").exists()
