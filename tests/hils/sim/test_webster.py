"""Webster's fixed-time plan from the shipped demand, and the agent that runs it."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hils.agents.builtin import AgentError, Observation, WebsterAgent, load_agent
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.sim.network import ROUTE_FILE, data_path
from hils.sim.webster import DemandError, webster_plan

CFG = config_mod.load()
PLAN = webster_plan(CFG)


def green_bounds(pair):
    g_min = max(CFG.phases[p].min_green for p in pair)
    return g_min, max(g_min, min(CFG.phases[p].max_green for p in pair))


def test_flows_per_phase_are_the_route_files_volumes():
    # the comments of four_leg.rou.xml: right turns run with the through of their approach
    expected = {1: 180, 2: 550 + 55, 3: 80, 4: 300 + 30, 5: 140, 6: 650 + 65, 7: 110, 8: 220 + 25}
    assert PLAN.flows == pytest.approx(expected, abs=1.0)


def test_the_plan_for_the_shipped_demand_is_webster_within_the_config_bounds():
    lost = sum(max(CFG.phases[p].clearance for p in pair) for pair in CFG.sequence)
    assert PLAN.lost_time == lost == 20.0
    assert 0 < PLAN.total_flow_ratio < 1
    assert PLAN.optimal_cycle == pytest.approx((1.5 * lost + 5) / (1 - PLAN.total_flow_ratio))
    for stage in PLAN.stages:
        lo, hi = green_bounds(stage.pair)
        assert lo <= stage.green <= hi
    assert sum(lo for lo, _ in map(green_bounds, CFG.sequence)) + lost <= PLAN.cycle
    assert PLAN.cycle <= sum(hi for _, hi in map(green_bounds, CFG.sequence)) + lost
    # the splits are ordered like the demand: the major through pair (2, 6) gets the most green
    by_ratio = sorted(PLAN.stages, key=lambda s: s.flow_ratio)
    assert [s.green for s in by_ratio] == sorted(s.green for s in PLAN.stages)
    assert max(PLAN.stages, key=lambda s: s.green).pair == (2, 6)
    assert "Webster plan: cycle" in PLAN.describe()


def test_the_agent_asks_for_exactly_the_planned_green():
    agent = load_agent("webster", CFG, ActionType.DURATION)
    assert isinstance(agent, WebsterAgent)
    for pair in CFG.sequence:
        x = agent.act(Observation(0.0, None, next_pair=pair))
        lo, hi = green_bounds(pair)
        assert 0.0 <= x <= 1.0
        assert lo + x * (hi - lo) == pytest.approx(PLAN.green_of(pair))
    with pytest.raises(AgentError, match="duration actions only"):
        WebsterAgent(CFG, ActionType.SELECTION)


def route_file(tmp_path, rates: dict[str, float], period: str = "exp({})"):
    text = data_path(ROUTE_FILE).read_text(encoding="utf-8")
    for flow, rate in rates.items():
        old = text[text.index(f'<flow id="{flow}"'):]
        old = old[:old.index("/>")]
        start = old.index('period="') + len('period="')
        end = old.index('"', start)
        text = text.replace(old, old[:start] + period.format(rate) + old[end:])
    path = tmp_path / "demand.rou.xml"
    path.write_text(text, encoding="utf-8")
    return path


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(0.001, 0.3), min_size=4, max_size=4))
def test_greens_stay_in_bounds_and_follow_the_critical_ratios(tmp_path_factory, rates):
    names = ["west_left", "west_through", "north_left", "north_through"]
    path = route_file(tmp_path_factory.mktemp("demand"), dict(zip(names, rates, strict=True)))
    plan = webster_plan(CFG, route_file=path)
    for stage in plan.stages:
        lo, hi = green_bounds(stage.pair)
        assert lo <= stage.green <= hi
    if plan.optimal_cycle is None:
        assert plan.total_flow_ratio >= 1 and all(s.green == green_bounds(s.pair)[1] for s in plan.stages)
    else:
        assert math.isfinite(plan.optimal_cycle)
        by_ratio = sorted(plan.stages, key=lambda s: s.flow_ratio)
        assert [s.green for s in by_ratio] == sorted(s.green for s in plan.stages)


def test_a_flow_without_an_hourly_rate_names_file_field_and_allowed(tmp_path):
    path = route_file(tmp_path, {"west_left": 0}, period="uniform")
    with pytest.raises(DemandError) as err:
        webster_plan(CFG, route_file=path)
    assert str(path) in str(err.value) and "west_left" in str(err.value) and "vehsPerHour" in str(err.value)
