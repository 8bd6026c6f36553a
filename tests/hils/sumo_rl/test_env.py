"""sumo-rl's environments on hils: gymnasium's and PettingZoo's own checkers, observations, rewards and info computed
as sumo-rl computes them (sumo-rl's own functions, run on the same SUMO state, are the reference), and what the
controller does with sumo-rl's actions."""

from __future__ import annotations

import copy
import csv
from collections.abc import Iterator
from contextlib import closing
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test

from harness.reference.sumo_rl_peer import sumo_rl
from hils import sumo_rl as hils_sumo_rl
from hils.sim.quiet_libsumo import libsumo
from hils.sim.sumo import _console
from hils.sumo_rl import SumoEnvironment
from hils.sumo_rl.environment import register
from tests.hils.sumo_rl.test_lights import files

SHORT = 60  # simulated seconds of a test episode


def opened(name: str, **options: Any) -> closing[SumoEnvironment]:
    """The environment on one of sumo-rl's networks, closed (its run, its SUMO) when the ``with`` block ends."""
    return closing(SumoEnvironment(**files(name), num_seconds=options.pop("num_seconds", SHORT), sumo_warnings=False,
                                   **options))


@pytest.fixture
def sumo_rls_own() -> Iterator[Any]:
    """sumo-rl itself, and gymnasium's ``sumo-rl-v0`` given back to hils after (importing sumo-rl takes it)."""
    yield sumo_rl()
    register()


def test_gymnasiums_checker_passes_a_single_light() -> None:
    with opened("single-intersection", single_agent=True) as env:
        check_env(env, skip_render_check=True)


def test_gymnasium_makes_hils_environment_under_sumo_rls_id() -> None:
    env = gymnasium.make("sumo-rl-v0", **files("single-intersection"), num_seconds=SHORT, sumo_warnings=False)
    try:
        assert isinstance(env.unwrapped, SumoEnvironment)
        obs, info = env.reset(seed=0)
        assert env.observation_space.contains(obs) and info["step"] == 1.0
    finally:
        env.close()


def test_pettingzoos_checkers_pass_the_parallel_and_aec_environments() -> None:
    env = hils_sumo_rl.parallel_env(**files("2x2grid"), num_seconds=SHORT, sumo_warnings=False)
    try:
        parallel_api_test(env, num_cycles=15)  # past the episode's end: the agents are gone after it
    finally:
        env.close()
    env = hils_sumo_rl.env(**files("2x2grid"), num_seconds=SHORT, sumo_warnings=False)
    try:
        api_test(env, num_cycles=15)
    finally:
        env.close()


def test_rescos_networks_as_sumo_rl_gives_them() -> None:
    """``grid4x4()`` is the parallel environment on RESCO's grid: 16 lights, one simulated hour from 0;
    ``cologne1(parallel=False)`` the AEC one, from RESCO's 07:00."""
    grid = hils_sumo_rl.grid4x4(sumo_warnings=False)
    try:
        assert len(grid.possible_agents) == 16 and grid.unwrapped.env.sim_max_time == 3600
        observations, _ = grid.reset(seed=0)
        assert set(observations) == set(grid.possible_agents)
    finally:
        grid.close()
    cologne = hils_sumo_rl.cologne1(parallel=False, sumo_warnings=False)
    try:
        cologne.reset(seed=0)
        assert cologne.unwrapped.env.sim_step == 25201.0 and cologne.unwrapped.env.sim_max_time == 28800
    finally:
        cologne.close()


def test_lane_measures_rewards_and_info_are_sumo_rls_on_the_same_state(sumo_rls_own: Any) -> None:
    """At every decision of a random episode on 4x4-Lucas, sumo-rl's own TrafficSignal and SumoEnvironment functions,
    called on hils' lights and SUMO, give what hils' do: densities, queues, waiting times, speeds, pressure, every
    reward, the default observation (less its min-green flag, which is the controller's), the info."""
    theirs = sumo_rls_own
    with opened("4x4-Lucas", reward_fn=["diff-waiting-time", "average-speed", "queue", "pressure"]) as env:
        env.reset(seed=3)
        for ts in env.ts_ids:
            env.action_spaces(ts).seed(3)
        done, decisions = False, 0
        while not done:
            before = {ts: copy.copy(signal) for ts, signal in env.traffic_signals.items()}  # their own waiting memory
            _, rewards, dones, info = env.step({ts: env.action_spaces(ts).sample() for ts in env.ts_ids})
            done, decisions = dones["__all__"], decisions + 1
            for ts, signal in env.traffic_signals.items():
                TS = theirs.TrafficSignal  # noqa: N806 - sumo-rl's class
                assert signal.get_lanes_density() == TS.get_lanes_density(signal)
                assert signal.get_lanes_queue() == TS.get_lanes_queue(signal)
                assert signal.get_out_lanes_density() == TS.get_out_lanes_density(signal)
                assert signal.get_accumulated_waiting_time_per_lane() == \
                    TS.get_accumulated_waiting_time_per_lane(signal)
                assert signal.get_average_speed() == TS.get_average_speed(signal)
                assert signal.get_pressure() == TS.get_pressure(signal)
                assert signal.get_total_queued() == TS.get_total_queued(signal)
                expected = [TS.reward_fns[name](before[ts]) for name in signal.reward_fn]
                assert rewards[ts].tolist() == pytest.approx(expected, rel=1e-6), ts
                ours = env.observations[ts]
                reference = theirs.environment.observations.DefaultObservationFunction(signal)()
                flag = signal.num_green_phases
                assert np.array_equal(np.delete(ours, flag), np.delete(reference, flag)), ts
                assert ours[flag] == float(signal.min_green_passed)
            reference = theirs.SumoEnvironment._get_system_info(SimpleNamespace(sumo=libsumo))
            assert {key: info[key] for key in reference} == reference  # sumo-rl 1.4.5's keys
            assert info["system_total_running"] == len(libsumo.vehicle.getIDList())
            assert info["system_total_departed"] - info["system_total_arrived"] == info["system_total_running"]
            agents = theirs.SumoEnvironment._get_per_agent_info(env)
            assert {key: info[key] for key in agents} == agents
        assert decisions == SHORT // 5


#: The info's keys before the lights' own, as sumo-rl's repository gives them (``SumoEnvironment._compute_info`` and
#: ``_get_system_info``, commit 41e4c63, July 2025: 1.4.5 and five more).
INFO_KEYS = ["step", "system_total_running", "system_total_backlogged", "system_total_stopped", "system_total_arrived",
             "system_total_departed", "system_total_teleported", "system_total_waiting_time",
             "system_mean_waiting_time", "system_mean_speed"]


def test_info_has_sumo_rls_keys(sumo_rls_own: Any) -> None:
    """The info of a step has the keys of sumo-rl's repository, in its order; those of the released sumo-rl (the
    installed 1.4.5's own environment on the same network) come in the same order."""
    with _console(quiet=True):
        theirs = sumo_rls_own.SumoEnvironment(**files("2x2grid"), num_seconds=10, sumo_warnings=False, sumo_seed=0)
    try:
        theirs.reset()
        *_, released = theirs.step({ts: 0 for ts in theirs.ts_ids})
    finally:
        theirs.close()
    with opened("2x2grid") as env:
        env.reset(seed=0)
        *_, info = env.step({ts: 0 for ts in env.ts_ids})
    per_agent = [f"{ts}_{what}" for ts in env.ts_ids for what in ("stopped", "accumulated_waiting_time",
                                                                  "average_speed")]
    assert list(info) == [*INFO_KEYS, *per_agent, "agents_total_stopped", "agents_total_accumulated_waiting_time"]
    assert [key for key in info if key in released] == list(released)


def test_an_action_before_minimum_green_is_served_when_the_controller_can() -> None:
    """sumo-rl ignores an action that comes before the minimum green has passed; the controller takes the call and
    ends the green once its minimum green has passed. Meanwhile the light is changing (``is_yellow``), the one-hot
    shows the green phase asked for, the min-green flag is 0, and an action for another phase is dropped (the
    middleware takes no command during a transition)."""
    with opened("single-intersection", min_green=12, delta_time=5) as env:
        env.reset(seed=0)
        light = env.traffic_signals["t"]
        assert light.green_phase == 0 and not light.min_green_passed
        obs, *_ = env.step({"t": 1})  # at 1 s: green since 0, minimum green 12 s
        assert libsumo.trafficlight.getRedYellowGreenState("t") == light.green_phases[0].state  # still green (6 s)
        assert light.green_phase == 1 and light.is_yellow and obs["t"][:3].tolist() == [0, 1, 0]
        env.step({"t": 0})  # at 6 s, the transition to green phase 1 under way: dropped
        assert env.controller_infos["t"]["dropped"] and light.green_phase == 1
        assert libsumo.trafficlight.getRedYellowGreenState("t") == light.green_phases[0].state  # (11 s)
        obs, *_ = env.step({"t": 1})  # at 11 s; green phase 0 ends at 12 s, yellow 3 s, red clearance 0.1 s
        assert not light.is_yellow and 3.8 <= light.time_since_last_phase_change <= 4.0 and obs["t"][2] == 0
        assert libsumo.trafficlight.getRedYellowGreenState("t") == "yyrr"  # SUMO's last step, at 15 s
        env.step({"t": 1})
        assert libsumo.trafficlight.getRedYellowGreenState("t") == light.green_phases[1].state  # (21 s)


@pytest.mark.parametrize("enforce", [False, True])
def test_enforce_max_green_asks_for_the_next_green_phase(enforce: bool) -> None:
    """An agent that keeps asking for green phase 0: with ``enforce_max_green`` its action at the first decision
    (16 s) after the green has lasted ``max_green`` (12 s) asks for the next green phase instead, as sumo-rl does,
    and its next action asks for phase 0 again; without it the green stays (the controller's max green times only
    against a conflicting call, and none is placed)."""
    with opened("single-intersection", min_green=5, max_green=12, enforce_max_green=enforce) as env:
        env.reset(seed=0)
        asked = []
        for _ in range(6):
            env.step({"t": 0})
            asked.append(env.traffic_signals["t"].green_phase)
    assert asked == ([0, 0, 0, 1, 0, 0] if enforce else [0] * 6)


def test_a_green_phase_that_is_no_stage_keeps_what_is_shown() -> None:
    """3x3grid's 'Y' phases are green phases to sumo-rl and no stage of the controller: asking for one places no
    call, and the light stays where it is."""
    with opened("3x3grid") as env:
        env.reset(seed=0)
        env.step(dict.fromkeys(env.ts_ids, 1))
        assert all(not env.controller_infos[ts]["acted"] for ts in env.ts_ids)
        assert {env.traffic_signals[ts].green_phase for ts in env.ts_ids} == {0}


def test_fixed_ts_runs_each_controllers_timing_plan() -> None:
    """No action is taken: each controller runs its program's cycle (2x2grid: 4 stages) by itself."""
    with opened("2x2grid", fixed_ts=True, num_seconds=120) as env:
        env.reset(seed=0)
        seen, done = set(), False
        while not done:
            _, _, dones, _ = env.step({ts: 1 for ts in env.ts_ids})
            done = dones["__all__"]
            seen.add(env.traffic_signals["1"].green_phase)
            assert not any(i["acted"] for i in env.controller_infos.values())
    assert seen == {0, 1, 2, 3}


def test_the_same_seed_gives_the_same_episode() -> None:
    def episode(env: SumoEnvironment) -> list[Any]:
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        out, done = [obs.tolist()], False
        while not done:
            obs, reward, _, done, info = env.step(env.action_space.sample())
            out.append((obs.tolist(), reward, info))
        return out

    with opened("single-intersection", single_agent=True) as env:
        first, second = episode(env), episode(env)
    assert first == second
    assert len({o[2]["system_total_departed"] for o in first[1:]}) > 1, "the episode has traffic"


def test_sumo_seed_random_draws_each_episodes_seed() -> None:
    """``sumo_seed="random"``: each reset draws a seed; ``reset(seed=s)`` runs with ``s``, and keeps it for the resets
    after (sumo-rl's rule)."""
    with opened("single-intersection", sumo_seed="random") as env:
        env.reset()
        first = env.testbed.seed
        env.reset()
        assert env.testbed.seed != first
        env.reset(seed=5)
        env.reset()
        assert env.testbed.seed == env.sumo_seed == 5


def test_out_csv_name_writes_every_steps_info_per_episode(tmp_path: Path) -> None:
    """One CSV per episode, written at the next reset, named as sumo-rl names it; one row per step (and, single agent,
    one for the reset), the info's keys as columns."""
    out = tmp_path / "outputs" / "run"
    with opened("single-intersection", single_agent=True, out_csv_name=str(out), num_seconds=30) as env:
        env.reset(seed=0)
        infos, done = [], False
        while not done:
            *_, done, info = env.step(0)
            infos.append(info)
        env.reset(seed=0)
        label = env.label
    written = tmp_path / "outputs" / f"run_conn{label}_ep1.csv"
    with written.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(infos) + 1 == 7
    assert list(rows[0]) == list(infos[0])
    assert [float(r["step"]) for r in rows[1:]] == [i["step"] for i in infos] == [6, 11, 16, 21, 26, 30]
    assert rows[-1]["system_total_departed"] == str(infos[-1]["system_total_departed"])


def test_encode_gives_sumo_rls_discrete_state() -> None:
    with opened("single-intersection") as env:
        observations = env.reset(seed=0)
        state = env.encode(observations["t"], "t")
    phases = env.traffic_signals["t"].num_green_phases
    assert state[0] == 0 and len(state) == 2 + 2 * len(env.traffic_signals["t"].lanes)
    assert all(0 <= d <= 9 for d in state[2:]) and state[1] == observations["t"][phases]
