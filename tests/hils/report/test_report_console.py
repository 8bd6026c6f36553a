"""`hils report paper` prints what it writes: each table under its own header."""

from __future__ import annotations

from pathlib import Path

from harness.reference import paper
from hils.cli.main import main
from hils.report.latency import Stats


def test_the_console_prints_each_table_under_its_own_header(tmp_path: Path, monkeypatch, capsys) -> None:
    # The runs are not what is tested here (they take minutes): their figures are fixed, the printing is real.
    latency = {name: Stats.of([0.05, 0.06, 0.07]) for name in ("selection", "switch", "duration")}
    holds = {rate: Stats.of([5.2, 5.2, 5.3]) for rate in (10.0, 50.0, 100.0)}
    zoom = {"start_window_us": 40.0, "set_answered_after_dispatch_ms": 7.5, "hold_s": 5.2, "end_window_us": 30.0}
    monkeypatch.setattr(paper, "latency_table", lambda cfg, duration, seed: latency)
    monkeypatch.setattr(paper, "trajectory_run", lambda cfg, seed: ([], 0.0))
    monkeypatch.setattr(paper, "trajectory_figure", lambda records, t0, path: None)
    monkeypatch.setattr(paper, "trajectory_zoom_figure", lambda records, t0, path: zoom)
    monkeypatch.setattr(paper, "holds_by_rate", lambda cfg, rates, seed: holds)
    monkeypatch.setattr(paper, "holds_figure", lambda holds, clearance, path: None)
    assert main(["report", "paper", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    tables: list[list[str]] = []
    for line in lines:
        if line.startswith("|"):
            if not tables or not tables[-1]:
                tables.append([])
            tables[-1].append(line)
        elif tables and tables[-1]:
            tables.append([])
    tables = [t for t in tables if t]
    assert len(tables) == 2, lines
    latency_table, holds_table = tables
    assert latency_table[0].startswith("| action type |") and latency_table[1].startswith("|---")
    assert holds_table[0].startswith("| holds | N | mean (s) |") and holds_table[1].startswith("|---")
    assert [row.split(" | ")[0] for row in holds_table[2:]] == ["| ours, 10 Hz", "| ours, 50 Hz", "| ours, 100 Hz",
                                                                "| paper (Cobalt), 10 Hz"]
    assert "| holds |" in (tmp_path / "README.md").read_text()  # the report has the same table
