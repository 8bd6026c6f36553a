"""Agents: max-pressure on crafted queues, the protocol check for users' agents."""

from __future__ import annotations

import re
import sys
import types

import pytest

from hils.agents.builtin import AgentError, MaxPressureAgent, Observation, QueueProportionalAgent, load_agent
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.protocol.ntcip import SignalState
from hils.sim.sumo import MovementState, TrafficState

CFG = config_mod.load()
ALL = frozenset(CFG.phases)


def traffic(up: dict[int, int], down: dict[int, int] | None = None) -> TrafficState:
    down = down or {}
    movements = {p: MovementState(p, up.get(p, 0), down.get(p, 0)) for p in CFG.phases}
    return TrafficState(0.0, {}, movements, 0, 0)


def observe(up, down=None, greens=(2, 6)) -> Observation:
    signal = SignalState(ALL - frozenset(greens), frozenset(), frozenset(greens))
    return Observation(0.0, signal, traffic(up, down))


@pytest.mark.parametrize(("up", "down", "expected"), [
    ({3: 9, 7: 1, 4: 4, 8: 5}, {}, (3, 7)),  # 10 on [3,7] beats 9 on [4,8]
    ({1: 6, 5: 6, 2: 5, 6: 5}, {}, (1, 5)),
    ({1: 6, 5: 6, 2: 5, 6: 5}, {1: 4, 5: 4}, (2, 6)),  # downstream queues cut [1,5]'s pressure to 4
    ({4: 3, 8: 3, 1: 20}, {}, (1, 5)),  # a single long queue wins for its pair
    ({}, {}, (2, 6)),  # no pressure anywhere: keep the pair shown
])
def test_max_pressure_picks_the_pair_with_the_largest_pressure(up, down, expected):
    agent = MaxPressureAgent(CFG)
    choice = agent.act(observe(up, down))
    assert choice == expected
    assert CFG.compatible(*choice)


def test_max_pressure_never_picks_a_conflicting_pair_even_when_single_phases_are_loudest():
    # Phase 2 and 3 (which conflict) have the longest queues; the answer is one configured pair.
    choice = MaxPressureAgent(CFG).act(observe({2: 50, 3: 50}))
    assert choice in CFG.pairs
    assert choice in ((2, 6), (3, 7))


def test_queue_proportional_duration_scales_with_the_next_pairs_queue():
    agent = QueueProportionalAgent(CFG)
    obs = Observation(0.0, None, traffic({3: 4, 7: 6}), next_pair=(3, 7))
    assert agent.act(obs) == pytest.approx(0.5)
    full = Observation(0.0, None, traffic({3: 40}), next_pair=(3, 7))
    assert agent.act(full) == 1.0


@pytest.fixture
def user_module():
    module = types.ModuleType("user_agents")

    class Good:
        def __init__(self, config, action_type, seed):
            self.action_type = ActionType.SWITCH

        def act(self, observation):
            return 1

    class NoAct:
        def __init__(self, config, action_type, seed):
            self.action_type = "switch"

    class BadType:
        action_type = "left-turn"

        def __init__(self, config, action_type, seed):
            pass

        def act(self, observation):
            return 0

    class BadInit:
        action_type = "switch"

        def act(self, observation):
            return 0

    for cls in (Good, NoAct, BadType, BadInit):
        setattr(module, cls.__name__, cls)
    sys.modules["user_agents"] = module
    yield module
    del sys.modules["user_agents"]


def test_a_users_agent_class_loads_by_module_and_class(user_module):
    agent = load_agent("user_agents:Good", CFG, ActionType.SWITCH)
    assert agent.act(None) == 1


@pytest.mark.parametrize(("spec", "message"), [
    ("user_agents:NoAct", "no act(observation) method"),
    ("user_agents:BadType", "action_type must be one of"),
    ("user_agents:BadInit", "constructor must take (config, action_type, seed)"),
    ("user_agents:Missing", "cannot be loaded"),
    ("no_such_module_xyz:Agent", "cannot be loaded"),
    ("just-a-name", "expected a built-in agent"),
])
def test_a_class_that_does_not_fit_the_protocol_is_refused_with_its_reason(user_module, spec, message):
    with pytest.raises(AgentError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_agent(spec, CFG, ActionType.SWITCH)


def test_an_agent_of_another_action_type_is_refused(user_module):
    with pytest.raises(AgentError, match="issues switch actions, but the run uses selection"):
        load_agent("user_agents:Good", CFG, ActionType.SELECTION)
    with pytest.raises(AgentError, match="phase selection actions only"):
        load_agent("max-pressure", CFG, ActionType.SWITCH)


def test_the_coordinated_agent_runs_the_plan_and_needs_one(paper_config, paper_toml) -> None:
    from hils.agents.builtin import OWN_OPERATION, controller_config

    agent = load_agent("coordinated", paper_config, "selection")
    assert agent.act(None) is None and "coordinated" in OWN_OPERATION
    assert controller_config("coordinated", paper_config).coordination.pattern == 1
    assert controller_config("max-pressure", paper_config).coordination.pattern == 254
    bare = config_mod.parse(paper_toml[:paper_toml.index("[coordination]")], "bare.toml")
    with pytest.raises(AgentError, match=re.escape("bare.toml has none: add [[coordination.patterns]]")):
        load_agent("coordinated", bare, "selection")


def test_the_fixed_time_agent_runs_the_plan_pretimed_and_needs_one(paper_config, paper_toml) -> None:
    from hils.agents.builtin import DETECTOR_AGENTS, OWN_OPERATION, controller_config, describe_plan
    from hils.protocol.ntcip import SplitMode

    agent = load_agent("fixed-time", paper_config, "selection")
    assert agent.act(None) is None and "fixed-time" in OWN_OPERATION and "fixed-time" not in DETECTOR_AGENTS
    c = controller_config("fixed-time", paper_config).coordination
    assert c.pattern == 1 and c.patterns[1].modes == dict.fromkeys(paper_config.phases, SplitMode.MAX_RECALL)
    assert controller_config("coordinated", paper_config).coordination.patterns[1].modes == {}
    assert describe_plan(controller_config("fixed-time", paper_config)).startswith(
        "Controller plan: pattern 1 pretimed (every phase on max recall), cycle 70 s")
    bare = config_mod.parse(paper_toml[:paper_toml.index("[coordination]")], "bare.toml")
    with pytest.raises(AgentError, match=re.escape("the fixed-time agent runs the controller's timing plan, and "
                                                   "bare.toml has none: add [[coordination.patterns]]")):
        load_agent("fixed-time", bare, "selection")


def test_an_agent_that_leaves_the_controller_to_itself_is_said_so_not_given_an_action_type() -> None:
    """Seen as a user: `hils run --agent coordinated` was summed up as "selection by coordinated"."""
    from hils.agents.builtin import BUILTIN, OWN_OPERATION, ActuatedAgent, controlled_by

    assert set(OWN_OPERATION) == {name for name, cls in BUILTIN.items() if issubclass(cls, ActuatedAgent)}
    assert controlled_by("coordinated", "selection") == ("coordinated: the controller's own operation, its "
                                                         "coordination plan on its detectors")
    assert controlled_by("max-pressure", "selection") == "selection by max-pressure"
