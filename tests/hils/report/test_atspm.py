"""ATSPM measures of a run, by the atspm package, on runs whose answer is known; and the run folder's record."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections import Counter
from datetime import timedelta
from pathlib import Path

import pytest

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from hils.protocol import hires
from hils.protocol.hires import EventCode
from hils.report import atspm, atspm_charts
from hils.sweep import grid as sweep
from tests.emulator.model.test_hires import config_with

E = EventCode

def fixed_time_log(failing: set[int], cycles: int = 8) -> tuple[list[hires.Event], dict[str, int]]:
    """A fixed-time controller (every phase on maximum recall: 20 s greens, 3 s yellow, 2 s red clearance, a 100 s
    cycle) whose detector 4 is occupied from just after phase 4's green begins until 8 s into its red in the
    cycles ``failing``, and in the others actuated for 0.5 s every 4 s of green only. Returns the log and what the
    answer must be."""
    c = Controller(config_with(timing='recall = "max"'))
    log = DataLogger(c)
    expect = Counter()
    cycle = 0
    while cycle < cycles:
        while 4 not in c.greens:
            c.step()
        on = cycle in failing
        for k in range(200):  # phase 4's 20 s green, tick by tick
            if on:
                c.set_actuations({4} if k >= 1 else set())
            else:
                c.set_actuations({4} if k % 40 in range(1, 6) else set())
            if (on and k == 1) or (not on and k % 40 == 1):
                expect["arrivals"] += 1
                expect["on_green"] += 1
            c.step()
        for _ in range(50 + 80 if on else 50):  # yellow and red clearance, and 8 s of red with a queue
            c.step()
        c.set_actuations(set())
        cycle += 1
    expect["split_failures"] = len(failing)
    return log.events(), expect


def test_split_failures_arrivals_and_terminations_of_a_fixed_time_plan() -> None:
    events, expect = fixed_time_log({2, 3, 6})
    m = atspm.measures(hires.rows({7: events}), {7: config_with()})
    assert m.missing is None
    totals = m.totals()[7]
    assert totals[4]["split_failures"] == expect["split_failures"] == 3
    assert all(t["split_failures"] == 0 for p, t in totals.items() if p != 4)
    assert totals[4]["arrivals"] == totals[4]["actuations"] == expect["arrivals"]
    assert totals[4]["arrivals_on_green"] == expect["on_green"]
    greens = Counter(e.parameter for e in events if e.code == E.PHASE_BEGIN_GREEN)
    yellows = Counter(e.parameter for e in events if e.code == E.PHASE_BEGIN_YELLOW)
    for p, t in totals.items():  # every green maxed out: 20 s of maximum recall against recalled phases
        assert (t["max_outs"], t["gap_outs"], t["force_offs"]) == (yellows[p], 0, 0), p
        assert greens[p] >= yellows[p]
    assert m.run_figures()["split_failures"] == 3
    rows = {(r["TimeStamp"], r["Phase"]) for r in m.rows}
    assert len({t for t, _ in rows}) == 1 + (events[-1].time - events[0].time).seconds // 900  # 15-minute bins


def test_the_charts_of_a_log_collected_after_power_up_hold_no_pattern_event(tmp_path: Path) -> None:
    """A log collected from a controller that powered up long before (``hils run --asclog``) has no pattern event:
    the split monitor draws its services and says the programmed split is unknown; the coordination diagram draws
    its phases' cycles."""
    events, _ = fixed_time_log(set(), cycles=4)
    later = [e for e in events if e.time >= events[0].time + timedelta(seconds=60)]
    assert not any(e.code == E.COORD_PATTERN_CHANGE for e in later)
    config = config_with()
    for name, chart in atspm_charts.CHARTS.items():
        assert chart(later, config, tmp_path / name, "no pattern"), name
        assert (tmp_path / name).read_text().endswith("</svg>\n")
    monitor = (tmp_path / "split_monitor.svg").read_text()
    assert "programmed split unknown" in monitor and "stroke-dasharray" not in monitor
    # The whole log (from power-up) says the controller ran free: no split to draw, nothing unknown.
    assert atspm_charts.split_monitor(events, config, tmp_path / "whole.svg", "whole")
    assert "programmed split" not in (tmp_path / "whole.svg").read_text()


def test_without_the_package_the_measures_say_so(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "atspm", None)
    m = atspm.measures([], {1: config_with()})
    assert m.rows == () and "pip install 'hils[atspm]'" in m.missing


def test_a_run_keeps_its_controllers_record(tmp_path: Path) -> None:
    """`hils run` from another folder: the hi-res log in the ATSPM layout, the measures and both charts."""
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--agent", "actuated", "--duration", "600",
                           "--no-progress", "--out", str(out)], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    for name in ("hires.parquet", "atspm.csv", "coordination_diagram.svg", "split_monitor.svg"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    record = summary["record"]
    assert record["devices"] == {"1": "C"} and record["file"] == "hires.parquet"
    # what sweeps and `hils compare` show beside SUMO's delays
    figures = sweep.figures(summary)
    assert figures["atspm_split_failures"] == record["atspm"]["split_failures"] is not None
    assert figures["atspm_percent_on_green"] == record["atspm"]["percent_on_green"]
    assert record["atspm"]["bin_minutes"] == 15 and set(record["atspm"]["per_phase"]["1"]) == {str(p)
                                                                                             for p in range(1, 9)}
    assert "ATSPM (15-minute bins in atspm.csv)" in done.stdout and "split failures" in done.stdout
    import pandas as pd

    frame = pd.read_parquet(out / "hires.parquet")
    # the actuated controller's detectors, as SUMO actuated them, are in its record
    actuations = sum(t["actuations"] for t in record["atspm"]["per_phase"]["1"].values())
    assert actuations == (frame.EventId == E.DETECTOR_ON).sum() > 0


def test_a_run_of_several_controllers_names_one_device_each(tmp_path: Path) -> None:
    out = tmp_path / "corridor"
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--scenario", "corridor", "--agent", "actuated",
                           "--duration", "300", "--no-progress", "--out", str(out)], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    record = json.loads((out / "summary.json").read_text())["record"]
    assert record["devices"] == {"1": "J1", "2": "J2", "3": "J3", "4": "J4"}
    import pandas as pd

    assert sorted(pd.read_parquet(out / "hires.parquet").DeviceId.unique()) == [1, 2, 3, 4]
    assert all((out / tls / "split_monitor.svg").exists() for tls in ("J1", "J2", "J3", "J4"))


def _record_of(agent: str, action_type: str, duration: float) -> tuple[dict[str, list[hires.Event]], dict]:
    """A virtual-time run of the four-leg without SUMO (no traffic, so no detector is actuated): its controller's log
    and its config."""
    from hils.protocol.config import load
    from hils.run.testbed import Testbed

    with Testbed(load(), sumo=False, agent=agent, action_type=action_type, duration=duration, seed=0) as tb:
        tb.reset()
        tb.run()
        return tb.hires(), tb.configs


def test_a_controller_on_the_middlewares_calls_alone_gets_no_chart_and_the_run_says_why(tmp_path: Path) -> None:
    """Seen as a user: the default run drew a coordination diagram (an empty "detector" legend, no arrival) and a
    split monitor ("dashed: programmed split", none drawn) of a controller that ran no plan and read no detector."""
    from hils.report import atspm_charts, record
    from hils.report.outfiles import Outputs

    logs, configs = _record_of("fixed-cycle", "switch", 600.0)
    kept = record.gather(logs, configs, {tls: n for n, tls in enumerate(configs, start=1)})
    files = Outputs(tmp_path)
    kept.write_small(files, several=False)
    section = kept.section
    assert files.written == ["atspm.csv"] and not files.failed
    assert not list(tmp_path.glob("*.svg"))
    assert section["charts"] == atspm_charts.NOTHING_TO_DRAW
    assert f"  {atspm_charts.NOTHING_TO_DRAW}" in record.describe(section)


def test_the_charts_read_the_time_of_day_as_a_clock_and_name_only_what_they_show(tmp_path: Path) -> None:
    """The coordination diagram of the phases whose detectors were read, the split monitor of a controller on its
    detectors or its plan; ticks at 00:05, 00:10 (not 0.1 h); a legend of what is drawn."""
    from hils.report.atspm_charts import coordination_diagram, split_monitor

    events, _ = fixed_time_log({2, 3, 6})  # detector 4 (phase 4) actuated; every green maxed out; no plan
    config = config_with(timing='recall = "max"')
    assert coordination_diagram(events, config, tmp_path / "pcd.svg", "t")
    pcd = (tmp_path / "pcd.svg").read_text()
    assert ">phase 4<" in pcd and ">phase 2<" not in pcd  # only the phase whose detector was read
    assert ">detector on (arrival)<" in pcd and "(h)" not in pcd
    assert re.findall(r">(\d\d:\d\d)<", pcd)[:3] == ["00:02", "00:04", "00:06"]  # 800 s of log from midnight
    assert split_monitor(events, config, tmp_path / "split.svg", "t")
    split = (tmp_path / "split.svg").read_text()
    assert ">max-out<" in split and ">gap-out<" not in split and "programmed split" not in split
    assert "stroke-dasharray" not in split
    logs, configs = _record_of("fixed-time", "selection", 600.0)  # its plan pretimed: no detector read
    (log,), (config,) = logs.values(), configs.values()
    assert split_monitor(log, config, tmp_path / "planned.svg", "t")
    planned = (tmp_path / "planned.svg").read_text()
    assert ">programmed split<" in planned and "stroke-dasharray" in planned
    assert not coordination_diagram(log, config, tmp_path / "none.svg", "t")  # no detector read: no arrival to show
