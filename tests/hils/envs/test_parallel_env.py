"""The PettingZoo environment: one agent per traffic light of a scenario, on one multi-controller Testbed."""

from __future__ import annotations

import dataclasses
import itertools
import re
import time
import warnings
from contextlib import closing
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import parallel_api_test

import hils.envs
from harness.bench.processes import start_emulator
from hils.agents.builtin import Observation
from hils.control.actions import ActionError
from hils.control.manager import State
from hils.envs.intersection import STATES, EnvOptionError
from hils.envs.parallel import IntersectionsEnv
from hils.protocol.config import load
from hils.protocol.ntcip import PREEMPT_CONTROL_STATE
from hils.protocol.scenario import load_scenario
from hils.run.testbed import NotStarted
from hils.shell.events import Kind

SHORT = 120.0  # simulated seconds per test episode
CORRIDOR = ["J1", "J2", "J3", "J4"]
RL_DOCS = Path(__file__).resolve().parents[3] / "docs" / "rl.md"


def opened(**options: Any) -> closing[IntersectionsEnv]:
    """The environment, closed (its SUMO, its transports) when the ``with`` block ends."""
    return closing(hils.envs.parallel_env(**options))


def rollout(env: IntersectionsEnv, seed: int, actions: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """Every step's (observations, rewards, truncations, infos) from ``reset(seed)`` on, as plain values."""
    obs, infos = env.reset(seed=seed)
    out: list[tuple[Any, ...]] = [({a: o.tolist() for a, o in obs.items()}, infos)]
    for step_actions in actions:
        if not env.agents:
            break
        obs, rewards, _, truncations, infos = env.step(step_actions)
        out.append(({a: o.tolist() for a, o in obs.items()}, rewards, truncations, infos))
    return out


def sampled_actions(env: IntersectionsEnv, seed: int, steps: int) -> list[dict[str, Any]]:
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    return [{a: env.action_space(a).sample() for a in env.possible_agents} for _ in range(steps)]


@pytest.mark.parametrize("action_type", ["selection", "switch", "duration"])
def test_pettingzoo_parallel_api_test_passes(action_type: str) -> None:
    with opened(scenario="corridor", action_type=action_type, episode_length=SHORT) as env:
        with warnings.catch_warnings():
            # The API test only warns about an agent given a value it should not have (or not given one it
            # should): here that is a failure. The observation's unbounded queues and pressures are by design.
            warnings.simplefilter("error")
            warnings.filterwarnings("ignore", message=".*infinity.*")
            parallel_api_test(env, num_cycles=1000)
        assert env.agents == [], "the API test ran the last episode to its truncation"
        assert env.testbed.end_reason == "duration"


@pytest.mark.parametrize(("action_type", "space"), [
    ("selection", spaces.Discrete(4)), ("switch", spaces.Discrete(2)),
    ("duration", spaces.Box(0.0, 1.0, (1,), np.float32))])
def test_one_agent_per_light_with_the_single_envs_spaces_until_all_are_truncated(action_type: str,
                                                                                  space: spaces.Space) -> None:
    with opened(scenario="corridor", action_type=action_type, episode_length=60.0) as env:
        assert env.possible_agents == CORRIDOR and env.agents == []
        assert all(env.action_space(a) == space for a in CORRIDOR)
        obs, infos = env.reset(seed=4)
        assert env.agents == CORRIDOR
        assert all(obs[a].shape == (29,) and env.observation_space(a).contains(obs[a]) for a in CORRIDOR)
        assert {i["seed"] for i in infos.values()} == {4}
        steps, t = 0, infos["J1"]["t"]
        while env.agents:
            actions = {a: env.action_space(a).sample() for a in env.agents}
            obs, rewards, terminations, truncations, infos = env.step(actions)
            assert set(obs) == set(rewards) == set(terminations) == set(truncations) == set(infos) == set(CORRIDOR)
            assert not any(terminations.values()), "an episode is never terminated, only truncated at its end"
            assert len(set(truncations.values())) == 1, "all agents are truncated together"
            assert all(isinstance(r, float) and r <= 0 for r in rewards.values())  # minus the queue
            assert all(env.observation_space(a).contains(obs[a]) for a in CORRIDOR)
            assert all(i["timeout"] is False and i["timeout_reason"] is None for i in infos.values())
            assert infos["J1"]["t"] > t
            t = infos["J1"]["t"]
            steps += 1
        assert t == pytest.approx(60.0) and all(truncations.values())
        if action_type != "duration":
            assert steps == 6, "one decision per control interval of 10 s"
        assert env.testbed.traffic.departed > 0
        with pytest.raises(NotStarted, match="call reset"):
            env.step({})


def test_each_agents_observation_is_its_own_intersection() -> None:
    with opened(scenario="corridor", action_type="selection", episode_length=SHORT) as env:
        env.reset(seed=2)
        # J1 and J3 serve the cross street's lefts (3, 7), J2 and J4 the arterial's lefts (1, 5).
        for _ in range(3):
            obs, *_ = env.step({"J1": 2, "J2": np.int64(0), "J3": np.array(2), "J4": 0})
        raw = env.testbed.observe_all()
        phases = env.adapters["J1"].phases
        for agent, pair in (("J1", {3, 7}), ("J2", {1, 5}), ("J3", {3, 7}), ("J4", {1, 5})):
            lights = obs[agent][16:24]
            assert {p for p, v in zip(phases, lights, strict=True) if v == 1.0} == set(raw[agent].signal.greens) == pair
            assert list(obs[agent][:8]) == [raw[agent].traffic.movements[p].upstream_queue for p in phases]
            assert list(obs[agent][25:]) == [1.0, 0.0, 0.0, 0.0]  # idle


@pytest.mark.parametrize("action_type", ["selection", "duration"])
def test_same_seed_and_actions_give_the_same_trajectory(action_type: str) -> None:
    with opened(scenario="corridor", action_type=action_type, episode_length=SHORT) as env:
        actions = sampled_actions(env, 11, 40)
        first, again, other = rollout(env, 42, actions), rollout(env, 42, actions), rollout(env, 43, actions)
    assert len(first) > 10
    assert first == again
    assert first != other, "the seed changes the traffic"


def test_duration_actions_are_taken_only_from_agents_at_their_decision_point() -> None:
    with opened(scenario="corridor", action_type="duration", episode_length=SHORT) as env:
        _, infos = env.reset(seed=1)
        due = dict.fromkeys(env.agents, True)
        skipped = 0
        while env.agents:
            before = {a: i["state"] for a, i in infos.items()}
            _, _, _, _, infos = env.step({a: np.array([0.8], np.float32) for a in env.agents})
            for agent, info in infos.items():
                # An intersection serving the green it was given (ON_HOLD) is not at its decision point: its
                # agent's action is not taken; one at its decision point (IDLE) acts.
                assert info["acted"] == due[agent] and not info["dropped"], (agent, before, info)
                assert due[agent] == (before[agent] == "idle"), (agent, before, info)
                skipped += not due[agent]
            due = {a: i["due"] for a, i in infos.items()}
        assert skipped > 0


def test_invalid_actions_are_refused_naming_the_agent_and_nothing_is_sent() -> None:
    with opened(scenario="corridor", action_type="switch", episode_length=SHORT) as env:
        env.reset(seed=0)
        t0 = env.testbed.now
        converted = sum(r["kind"] == Kind.ACTION_CONVERTED for r in env.testbed.records)
        with pytest.raises(ActionError, match=r"phase switch takes 0 \(keep\) or 1 \(advance\), got 2") as refused:
            env.step({"J1": 1, "J2": np.int64(2), "J3": 0, "J4": 1})
        assert "the action of intersection J2; nothing was sent to any controller" in refused.value.__notes__
        with pytest.raises(EnvOptionError, match="actions for J9: no such live agent; allowed: J1, J2, J3, J4"):
            env.step({"J9": 1})
        assert sum(r["kind"] == Kind.ACTION_CONVERTED for r in env.testbed.records) == converted
        assert env.testbed.now == t0, "no time passed"
        *_, infos = env.step({"J1": 1, "J2": 0})  # J3 and J4 left out: they do not act
        assert [infos[a]["acted"] for a in CORRIDOR] == [True, True, False, False]
    with opened(scenario="corridor", action_type="selection", episode_length=SHORT) as selection:
        selection.reset(seed=0)
        with pytest.raises(EnvOptionError, match=r"agent J3: selection action 4: allowed: an integer in \[0, 4\)"):
            selection.step({"J1": 0, "J3": 4})


def test_a_timeout_shows_in_that_agents_info_and_the_others_run_on() -> None:
    corridor = load_scenario("corridor")
    # tau_trans below yellow + red clearance (5 s): every transition of J2 times out, none of the others'.
    configs = dict(corridor.intersections) | {"J2": corridor.intersections["J2"].with_middleware(tau_trans=4.0)}
    scenario = dataclasses.replace(corridor, intersections=MappingProxyType(configs))
    with opened(scenario=scenario, action_type="switch", episode_length=60.0) as env:
        env.reset(seed=5)
        history = []
        while env.agents:
            *_, terminations, _, infos = env.step(dict.fromkeys(env.agents, 1))
            assert not any(terminations.values())
            history.append(infos)
        timed_out = [i["J2"] for i in history if i["J2"]["timeout"]]
        assert timed_out and timed_out[0]["timeout_reason"] == "transition" and timed_out[0]["state"] == "timeout"
        assert not any(i[a]["timeout"] for i in history for a in ("J1", "J3", "J4"))
        assert history[-1]["J1"]["t"] == pytest.approx(60.0)


def test_a_preempted_controller_refuses_its_agents_action_and_the_others_act(tmp_path: Path) -> None:
    arterial = load_scenario("corridor").intersections["J2"].source
    preempted = tmp_path / "arterial_preempted.toml"
    preempted.write_text(Path(arterial).read_text(encoding="utf-8")
                         + "\n[preempts]\n1 = { dwell_phases = [2, 5], exit_phases = [2, 6], dwell_green = 5 }\n",
                         encoding="utf-8")
    corridor = load_scenario("corridor")
    configs = dict(corridor.intersections) | {"J2": load(preempted)}
    scenario = dataclasses.replace(corridor, intersections=MappingProxyType(configs))
    with opened(scenario=scenario, action_type="selection", episode_length=90.0) as env:
        env.reset(seed=3)
        tb = env.testbed

        def call() -> Any:  # a central system calls the preempt at 25 s and releases it at 45 s
            surface = tb.intersections["J2"].target.surface
            yield tb.env.timeout(25.0)
            surface.set_many([(PREEMPT_CONTROL_STATE.instance(1), 1)])
            yield tb.env.timeout(20.0)
            surface.set_many([(PREEMPT_CONTROL_STATE.instance(1), 0)])

        tb.env.process(call())
        steps = []
        while env.agents:
            obs, _, _, _, infos = env.step(dict.fromkeys(env.agents, 1))
            steps.append((obs, infos))
    one_hot = {s: i for i, s in enumerate(STATES)}
    n = len(configs["J2"].phase_numbers)
    seen = [(o, i) for o, i in steps if i["J2"]["state"] == "preempted"]
    assert seen, "the preempt was served"
    for o, _ in seen:
        assert list(o["J2"][3 * n + 1:]) == [float(k == one_hot[State.PREEMPTED]) for k in range(len(STATES))]
    # an action chosen on a preempted observation is refused, alone
    answered = [i for (_, before), (_, i) in itertools.pairwise(steps) if before["J2"]["state"] == "preempted"]
    assert answered
    for i in answered:
        assert not i["J2"]["acted"] and "serves preempt 1" in i["J2"]["refused"]
        assert all(i[a]["acted"] and i[a]["refused"] is None for a in ("J1", "J3", "J4")), "the others act"
    after = steps[-1][1]["J2"]
    assert after["state"] != "preempted" and after["acted"], "J2 commands again once the preempt is over"
    refused = [r for r in tb.records if r["kind"] == Kind.ACTION_REFUSED]
    assert refused and {(r["intersection"], r["reason"]) for r in refused} == {("J2", "preempted")}


def test_named_and_callable_rewards_and_the_timing_options() -> None:
    seen: list[tuple[float, float]] = []

    def custom(previous: Observation, current: Observation) -> float:
        seen.append((previous.t, current.t))
        return current.t

    with opened(scenario="corridor", reward=custom, control_interval=5.0, sumo_step=0.5, episode_length=20.0) as env:
        _, start = env.reset(seed=0)
        _, rewards, *_ = env.step(dict.fromkeys(CORRIDOR, 1))
        assert rewards == dict.fromkeys(CORRIDOR, start["J1"]["t"] + 5.0)
        assert seen == [(start["J1"]["t"], start["J1"]["t"] + 5.0)] * 4
        assert {cfg.middleware.sumo_step for cfg in env.scenario.intersections.values()} == {0.5}
    with pytest.raises(EnvOptionError, match="reward 'speed': allowed: queue, pressure, wait"):
        hils.envs.parallel_env(reward="speed")
    with pytest.raises(EnvOptionError, match="action_type 'phase'"):
        hils.envs.parallel_env(action_type="phase")


def test_the_grid_has_sixteen_agents_and_runs() -> None:
    with opened(scenario="grid4x4", action_type="switch", episode_length=SHORT) as env:
        _, start = env.reset(seed=3)
        assert env.agents == [f"{col}{row}" for row in range(1, 5) for col in "ABCD"]
        for _ in range(3):
            obs, rewards, _, truncations, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert len(obs) == len(rewards) == 16 and not any(truncations.values())
        assert all(o.shape == (29,) for o in obs.values())
        assert all(i["t"] == pytest.approx(start["A1"]["t"] + 30.0) for i in infos.values())


def test_an_episode_that_keeps_no_hi_res_record_is_the_same_episode_without_its_data_loggers() -> None:
    """measure=False (the default) runs no controller's data logger: on RESCO's grid4x4, sixteen controllers beside
    SUMO, the episode is the measured one step for step (observations, rewards, infos), record for record (but for
    the queue samples only a measured run writes) and controller step for controller step (a logger takes none of its
    own)."""
    episodes = {}
    for measure in (True, False):
        with opened(scenario="resco:grid4x4", action_type="selection", episode_length=SHORT, measure=measure) as env:
            trajectory = rollout(env, 5, sampled_actions(env, 5, 13))
            targets = [i.target for i in env.testbed.intersections.values()]
            records = [{k: v for k, v in r.items() if k not in ("wall_ns", "seq")} for r in env.testbed.records
                       if r["kind"] != Kind.QUEUES]
            unlogged, steps = [t.log is None for t in targets], sum(t.clock.steps for t in targets)
            episodes[measure] = trajectory, records, unlogged, steps
    (trajectory, records, unlogged, steps), (bare_trajectory, bare_records, bare_unlogged, bare_steps) = (
        episodes[True], episodes[False])
    assert not any(unlogged) and all(bare_unlogged)
    assert bare_steps == steps, "a data logger takes no controller step of its own"
    assert records[-1]["kind"] == Kind.RUN_ENDED and len(trajectory) == 13
    assert bare_trajectory == trajectory
    assert bare_records == records


@pytest.mark.wallclock
def test_the_same_env_runs_at_wall_clock_against_the_served_corridor(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log", "--scenario", "corridor", count=4)
    targets = {tls: f"snmp://127.0.0.1:{port}?community=private&version=2c"
               for tls, port in zip(CORRIDOR, served.ports, strict=True)}
    try:
        with opened(scenario="corridor", target=targets, control_interval=2.0, episode_length=30.0) as env:
            obs, _ = env.reset(seed=0)
            assert env.testbed.mode == "wall-clock"
            start = time.monotonic()
            # A transition from the startup pair takes at most min green + clearance (10 s): 12 s covers it.
            for _ in range(6):
                obs, _, terminations, truncations, infos = env.step(dict.fromkeys(env.agents, np.int64(2)))
                assert not any(terminations.values()) and not any(truncations.values())
                assert not any(i["timeout"] for i in infos.values()), infos
            assert time.monotonic() - start == pytest.approx(12.0, abs=0.8), "each step lasts its control interval"
            phases = env.adapters["J1"].phases
            for agent in CORRIDOR:
                assert {p for p, v in zip(phases, obs[agent][16:24], strict=True) if v == 1.0} == {3, 7}
    finally:
        served.stop()


def test_the_documented_snippet_runs() -> None:
    section = RL_DOCS.read_text(encoding="utf-8").split("## Multi-agent (PettingZoo)", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    namespace: dict[str, Any] = {}
    exec(compile(code, str(RL_DOCS), "exec"), namespace)
    env = namespace["env"]
    assert env.agents == [] and env.testbed.ended, "the snippet ran its episode to the end"
