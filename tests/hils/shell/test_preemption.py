"""The middleware sees preemption as the controller's own operation: read in the poll's one GET, the manager
PREEMPTED (no command, no transition TIMEOUT), the log's preempt records and the run summary, against the
emulator's real preempt sequence (four_leg_city's preempt 1: dwell 2+5, exit 2+6)."""

from __future__ import annotations

from collections.abc import Generator
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import pytest

from hils import Testbed
from hils.control.actions import PreemptedError
from hils.protocol.config import load
from hils.protocol.ntcip import (
    PREEMPT_CONTROL_STATE,
    PREEMPT_TABLE,
    PreemptColumn,
    PreemptState,
    preempts_in_service,
    signal_oids,
)
from hils.report import plots, summary
from hils.shell.events import Kind
from hils.sim.network import data_path
from tests.hils.shell.test_fast_path import comparable

CITY = data_path("four_leg_city.toml")
CALLED, RELEASED = 10.5, 28.0  # the preempt input's window: called half a second into the transition of 10 s


def preempt(tb: Testbed) -> None:
    """Call preempt 1 at the controller from CALLED to RELEASED (preemptControlState, as a central system would)."""
    oid = PREEMPT_CONTROL_STATE.instance(1)

    def call() -> Generator[Any, Any, None]:
        yield tb.env.timeout(CALLED)
        tb.target.surface.set_many([(oid, 1)])
        yield tb.env.timeout(RELEASED - CALLED)
        tb.target.surface.set_many([(oid, 0)])

    tb.env.process(call())


def between(records: list[dict[str, Any]]) -> tuple[float, float]:
    (begin,) = [r for r in records if r["kind"] == Kind.PREEMPT_BEGIN]
    (end,) = [r for r in records if r["kind"] == Kind.PREEMPT_END]
    return begin["t"], end["t"]


def test_a_preempt_in_service_is_read_in_the_polls_one_get() -> None:
    config = load(CITY)
    with Testbed(config, action_type="switch", seed=1) as tb:
        tb.reset()
        oids = tb.middleware.signal_oids
    assert oids == (*signal_oids(config.groups), PREEMPT_TABLE[PreemptColumn.STATE].instance(1))
    with Testbed(action_type="switch", seed=1) as plain:  # no preempt configured: the poll the paper's
        plain.reset()
        assert plain.middleware.signal_oids == signal_oids(plain.config.groups)
    in_service = [s for s in PreemptState if preempts_in_service((1,), (int(s),))]
    assert in_service == [PreemptState.ENTRY_STARTED, PreemptState.TRACK_SERVICE, PreemptState.DWELL,
                          PreemptState.LINK_ACTIVE, PreemptState.EXIT_STARTED]
    assert preempts_in_service((1, 3), (6, 3)) == frozenset({1}), "a call waiting out its delay is not in service"
    with pytest.raises(ValueError, match=r"preemptState outside 1\.\.9"):
        preempts_in_service((1,), (0,))


def test_a_preempt_during_a_commanded_transition_is_preempted_not_a_timeout() -> None:
    refused: list[PreemptedError] = []
    with Testbed(CITY, action_type="switch", seed=1, duration=70.0, on_reset=preempt) as tb:
        tb.reset()
        while not tb.done:
            try:
                tb.step(1)
            except PreemptedError as exc:  # typed, logged, nothing sent: the run goes on
                refused.append(exc)
                tb.wait()
        records = tb.records
        s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()})
    begin, end = between(records)
    (began,) = [r for r in records if r["kind"] == Kind.PREEMPT_BEGIN]
    dispatched = {r["command_id"]: r for r in records if r["kind"] == Kind.COMMAND_DISPATCHED}
    ended = {r["command_id"]: r["reason"] for r in records if r["kind"] == Kind.HOLD_RELEASED}
    # Seen within a poll period of the call, ending the command in transition: no TIMEOUT for it, ever.
    assert CALLED < begin <= CALLED + 0.2
    assert dispatched[began["command_id"]]["t"] == pytest.approx(10.0, abs=0.1)
    assert ended[began["command_id"]] == "preempted"
    assert not [r for r in records if r["kind"] == Kind.TIMEOUT_ENTERED]
    states = [(r["from"], r["to"]) for r in records if r["kind"] == Kind.STATE]
    assert ("on_hold", "preempted") in states and ("preempted", "idle") in states
    # While preempted: the call withdrawn once, the keepalive, and nothing else; every action refused.
    sent = [(r["purpose"], sorted(r["phases"])) for r in records
            if r["kind"] == Kind.SET_SENT and begin <= r["t"] < end]
    assert sent[0] == ("withdraw", []) and {p for p, _ in sent[1:]} <= {"keepalive"} and all(not ph for _, ph in sent)
    assert refused and all(exc.reason == "preempted" and "preempt 1" in str(exc) for exc in refused)
    assert not [r for r in records if r["kind"] == Kind.COMMAND_DISPATCHED and begin <= r["t"] < end]
    assert {r["reason"] for r in records if r["kind"] == Kind.ACTION_REFUSED} == {"preempted"}
    # Over when the controller shows its exit phases; the next command is a transition verified again.
    (over,) = [r for r in records if r["kind"] == Kind.PREEMPT_END]
    assert {2, 6} <= set(over["greens"]) and over["duration_s"] == pytest.approx(end - begin)
    assert RELEASED < end < RELEASED + 10.0
    assert [r for r in records if r["kind"] == Kind.TRANSITION_VERIFIED and r["t"] > end]
    # The summary: how many, when and how long, in summary.json and on the console.
    p = s["preemptions"]
    assert p["count"] == 1 and p["total_s"] == p["longest_s"] == pytest.approx(end - begin)
    assert p["episodes"] == [{"t": begin, "preempts": [1], "duration_s": pytest.approx(end - begin), "ended": "over"}]
    assert f"  preemptions          1 ({begin:.1f} s for {end - begin:.1f} s); total {end - begin:.1f} s, longest" in (
        summary.render(s))


def preempted_run(config: Path, fast_path: bool) -> list[dict[str, Any]]:
    with Testbed(config, action_type="switch", agent="fixed-cycle", seed=3, duration=60.0, on_reset=preempt,
                 fast_path=fast_path) as tb:
        tb.reset()
        tb.run()
        return tb.records


@pytest.mark.parametrize(("dwell", "dwell_green"), [("[2, 5]", 5), ("[2, 6]", 25)])
def test_the_fast_path_sees_preemption_as_the_reference_does(tmp_path: Path, dwell: str, dwell_green: int) -> None:
    """preemptState moves the controller's status version, so a poll left out could not have seen its change:
    with the dwell phases the exit phases (2+6) and a dwell outlasting the input, the preempt ends on the
    controller's own timer without any indication changing."""
    config = tmp_path / "city.toml"
    config.write_text(CITY.read_text().replace("dwell_phases = [2, 5]", f"dwell_phases = {dwell}").replace(
        "dwell_green = 5", f"dwell_green = {dwell_green}"))
    fast = preempted_run(config, True)
    kinds = [r["kind"] for r in fast]
    assert kinds.count(Kind.PREEMPT_BEGIN) == kinds.count(Kind.PREEMPT_END) == 1
    assert comparable(fast) == comparable(preempted_run(config, False))


def test_a_run_without_preemption_says_none() -> None:
    with Testbed(action_type="switch", agent="fixed-cycle", seed=1, duration=30.0) as tb:
        tb.reset()
        tb.run()
        s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()})
    assert s["preemptions"] == {"count": 0, "total_s": 0, "longest_s": 0.0, "episodes": []}
    assert "preemptions" not in summary.render(s)


def test_the_signal_timeline_marks_the_preemption(tmp_path: Path) -> None:
    records = preempted_run(CITY, True)
    begin, end = between(records)
    tally = summary.Tally()  # what `hils run` draws from: the records it keeps, the episodes it saw
    for r in records:
        tally(r)
    episodes = tally.preemptions
    picture = plots.signal_timeline(tally.records, load(CITY), tmp_path / "timeline.svg", start=0.0, end=60.0,
                                    preemptions=episodes)
    svg = ElementTree.parse(picture).getroot()
    ns = "{http://www.w3.org/2000/svg}"
    axis = next(r for r in svg.iter(f"{ns}rect") if r.get("fill") == "none")
    left, width = float(axis.get("x")), float(axis.get("width"))
    (bar,) = [r for r in svg.iter(f"{ns}rect") if r.get("fill") == plots.PREEMPTED]
    assert float(bar.get("x")) == pytest.approx(left + begin / 60.0 * width, abs=0.01)
    assert float(bar.get("width")) == pytest.approx((end - begin) / 60.0 * width, abs=0.01)
    texts = [t.text or "" for t in svg.iter(f"{ns}text")]
    assert "preempt 1" in texts and any(t.endswith("; purple: controller preempted") for t in texts)
    assert plots.preempted_spans(episodes, 0.0, begin) == [], "a window before it shows none"
    assert plots.preempted_spans(episodes, begin + 1.0, 60.0) == [(begin + 1.0, end, (1,))], "cut to the window"
