"""Pictures that do not mislead: the timeline stops at the run's end, queues keep their last bin."""

from __future__ import annotations

from dataclasses import replace
from xml.etree import ElementTree

import pytest

from hils.protocol import config as config_mod
from hils.report import plots
from hils.report.summary import Tally
from hils.shell.events import Kind

CFG = config_mod.load()
SVG = "{http://www.w3.org/2000/svg}"


def polls(until: float, period: float = 0.1) -> list[dict]:
    out = []
    for i in range(round(until / period) + 1):
        t = i * period
        greens = [2, 6] if (t // 20) % 2 == 0 else [4, 8]
        out.append({"kind": Kind.POLL, "t": t, "greens": greens, "yellows": []})
    return out


def test_the_timeline_never_draws_past_the_end_of_the_run(tmp_path):
    records = [*polls(50.0), {"kind": Kind.RUN_ENDED, "t": 50.0}]
    start, end = plots.timeline_window(records, 0.0, 180.0)
    assert (start, end) == (0.0, 50.0)
    spans = plots.signal_intervals(records, CFG.phase_numbers, start, end)
    assert max(t1 for row in spans.values() for _, t1, _ in row) == 50.0
    assert plots.timeline_window(records, 100.0, 180.0) == (0.0, 50.0)  # a window after the end shows the end
    svg = ElementTree.parse(plots.signal_timeline(records, CFG, tmp_path / "t.svg", start=0, end=180)).getroot()
    labels = [t.text for t in svg.iter(f"{SVG}text")]
    assert [plots.movement_label(CFG, p) for p in CFG.phase_numbers] == [t for t in labels if t and t[0].isdigit()
                                                                        and "  " in t]
    colours = {r.get("fill") for r in svg.iter(f"{SVG}rect")}
    assert {plots.COLORS["G"], plots.COLORS["r"]} <= colours
    right = max(float(r.get("x")) + float(r.get("width")) for r in svg.iter(f"{SVG}rect")
                if r.get("fill") in plots.COLORS.values())
    axis = next(r for r in svg.iter(f"{SVG}rect") if r.get("fill") == "none")
    assert right == pytest.approx(float(axis.get("x")) + float(axis.get("width")))  # 50 s: the axis ends there


def test_rows_are_grouped_by_ring_and_barrier_and_labelled_with_their_movement():
    rows = plots.phase_rows(CFG)
    assert [p for p, _, _ in rows] == [1, 2, 3, 4, 5, 6, 7, 8]
    assert [(ring, barrier) for _, ring, barrier in rows] == [(1, 1), (1, 1), (1, 2), (1, 2),
                                                              (2, 1), (2, 1), (2, 2), (2, 2)]
    assert plots.movement_label(CFG, 2) == "2  east through"


def test_a_partial_last_bin_joins_the_one_before_instead_of_dropping(tmp_path):
    samples = [(float(t), {"west": 10 if t < 3600 else 1}) for t in range(0, 3601)]
    edges, tops = plots.queue_bins(samples, 60.0)
    assert edges[0] == 0.0 and edges[-1] == 3600.0 and len(edges) == 61
    assert tops["west"] == [10] * 60
    svg = ElementTree.parse(plots.queues(samples, tmp_path / "q.svg", spillback={"west": [120.0, 3599.0]})).getroot()
    lines = [pl for pl in svg.iter(f"{SVG}polyline") if pl.get("fill") == "none"]
    marks = [pl for pl in svg.iter(f"{SVG}polyline") if pl.get("fill") != "none"]
    assert len(lines) == 1 and len(lines[0].get("points").split()) == 2 * 60  # one step per bin
    assert len(marks) == 2  # the bins with a full lane: the third minute's and the last
    assert "west" in [t.text for t in svg.iter(f"{SVG}text")]


def test_the_timeline_draws_no_data_where_the_state_was_not_verified_never_the_last_state(tmp_path):
    records = [{"kind": Kind.POLL, "t": 0.0, "greens": [4, 8], "yellows": []},
               {"kind": Kind.POLL_FAILED, "t": 12.0, "consecutive": 1},
               {"kind": Kind.TIMEOUT_ENTERED, "t": 12.4, "reason": "communication"},
               {"kind": Kind.POLL, "t": 17.0, "greens": [4, 8], "yellows": []},
               {"kind": Kind.POLL_FAILED, "t": 20.0, "consecutive": 0},  # overtaken by a newer answer: no gap
               {"kind": Kind.RUN_ENDED, "t": 30.0}]
    spans = plots.signal_intervals(records, CFG.phase_numbers, 0.0, 30.0)
    assert spans[4] == [(0.0, 12.0, "G"), (12.0, 17.0, plots.NO_DATA), (17.0, 30.0, "G")]
    assert spans[1] == [(0.0, 12.0, "r"), (12.0, 17.0, plots.NO_DATA), (17.0, 30.0, "r")]
    svg = ElementTree.parse(plots.signal_timeline(records, CFG, tmp_path / "t.svg", start=0, end=30)).getroot()
    assert len([r for r in svg.iter(f"{SVG}rect") if r.get("fill") == "url(#no-data)"]) == len(CFG.phase_numbers)
    assert [t.text for t in svg.iter(f"{SVG}text")].count("no data") == len(CFG.phase_numbers)


def test_a_preemption_still_on_at_the_end_is_drawn_to_the_end():
    records = [*polls(30.0), {"kind": Kind.PREEMPT_BEGIN, "t": 12.0, "preempts": [2, 3], "command_id": None},
               {"kind": Kind.STATE, "t": 14.0, "from": "preempted", "to": "timeout"},
               {"kind": Kind.PREEMPT_BEGIN, "t": 20.0, "preempts": [1], "command_id": 4}]
    tally = Tally()
    for r in records:
        tally(r)
    assert plots.preempted_spans(tally.preemptions, 0.0, 30.0) == [(12.0, 14.0, (2, 3)), (20.0, 30.0, (1,))]
    assert plots.preempted_spans(tally.preemptions, 15.0, 19.0) == []


def test_a_title_too_long_for_the_picture_is_set_smaller_to_fit_and_names_a_resco_light_once(tmp_path):
    """Measured with matplotlib's own DejaVu Sans metrics, the font the pictures name first."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    records = [*polls(50.0), {"kind": Kind.RUN_ENDED, "t": 50.0}]
    cluster = "GS_cluster_2415878664_254486231_359566_359576"  # cologne3's third light
    derived = replace(CFG, name=f"{cluster}, dual-ring from its SUMO program")
    assert plots.named(cluster, derived) == derived.name and plots.named("J2", CFG) == f"J2 ({CFG.name})"
    for label, longest in ((None, False), (plots.named(cluster, derived), True)):
        svg = ElementTree.parse(plots.signal_timeline(records, CFG, tmp_path / "t.svg", end=50,
                                                      label=label)).getroot()
        title = next(t for t in svg.iter(f"{SVG}text") if t.text.startswith("Signal timeline"))
        size = float(title.get("font-size"))
        wide = TextPath((0, 0), title.text, size=size, prop=FontProperties(family="DejaVu Sans")).get_extents().width
        assert wide <= float(svg.get("width")) - 20, title.text
        assert (size < 15) is longest


def test_a_run_of_a_scenarios_one_light_titles_its_pictures_by_the_scenario() -> None:
    """As its console summary does: `hils run --scenario resco:cologne1` drew "Signal timeline,
    GS_cluster_357187_359543, dual-ring from its SUMO program" (its light's SUMO cluster id)."""
    derived = replace(CFG, name="GS_cluster_357187_359543, dual-ring from its SUMO program",
                      source="resco:cologne1 GS_cluster_357187_359543")
    assert plots.named(None, derived) == "resco:cologne1, light GS_cluster_357187_359543"
    assert plots.named(None, CFG) == CFG.name  # a config of its own keeps its name
