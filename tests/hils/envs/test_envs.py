"""The gymnasium environment on the Testbed, your own network, and parallel environments."""

from __future__ import annotations

import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AsyncVectorEnv

import hils
from harness.bench.processes import start_emulator
from hils.agents.builtin import Observation
from hils.envs import ENV_ID
from hils.envs.intersection import EnvOptionError, IntersectionEnv
from hils.protocol.config import ConfigError, load
from hils.protocol.ntcip import SignalState
from hils.run.testbed import Testbed
from hils.sim.network import NetworkError, data_path, derive_phase_map, read_net

SHORT = 200.0  # simulated seconds per test episode
FOUR_PHASE = {"config": str(data_path("four_phase.toml")), "net": str(data_path("four_phase.net.xml")),
              "routes": str(data_path("four_phase.rou.xml"))}


def make(action_type: str = "selection", **kwargs: object) -> gymnasium.Env:
    return gymnasium.make(ENV_ID, action_type=action_type, episode_length=kwargs.pop("episode_length", SHORT),
                          **kwargs)


def rollout(env: gymnasium.Env, seed: int, actions: list[object]) -> tuple[list[np.ndarray], list[float]]:
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            break
    return observations, rewards


@pytest.mark.parametrize("action_type", ["selection", "switch", "duration", "control"])
def test_gymnasium_check_env_passes(action_type: str) -> None:
    env = make(action_type)
    try:
        with warnings.catch_warnings():
            # The observation holds queues and pressures, which have no upper bound: the Box says so.
            warnings.filterwarnings("ignore", message=".*infinity.*")
            check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


@pytest.mark.parametrize(("action_type", "space"), [
    ("selection", gymnasium.spaces.Discrete(4)), ("switch", gymnasium.spaces.Discrete(2)),
    ("duration", gymnasium.spaces.Box(0.0, 1.0, (1,), np.float32))])
def test_action_spaces_and_sampled_actions_run_a_whole_episode(action_type: str, space: gymnasium.Space) -> None:
    env = make(action_type)
    try:
        assert env.action_space == space
        env.action_space.seed(7)
        obs, _ = env.reset(seed=1)
        steps, truncated, t = 0, False, 0.0
        while not truncated:
            obs, _, terminated, truncated, info = env.step(env.action_space.sample())
            assert not terminated, "an episode is never terminated, only truncated at its end"
            assert info["refused"] is None, info["refused"]
            assert "timeout" in info and "timeout_reason" in info
            assert env.observation_space.contains(obs)
            assert info["t"] > t
            t = info["t"]
            steps += 1
        assert t == pytest.approx(SHORT)
        if action_type != "duration":
            assert steps == SHORT / 10.0  # one decision per control interval
        assert env.unwrapped.testbed.traffic.departed > 0
    finally:
        env.close()


def test_observation_layout_matches_the_signal_and_the_manager() -> None:
    env = make("selection")
    try:
        obs, _ = env.reset(seed=2)
        n = len(env.unwrapped.phases)
        assert obs.shape == (3 * n + 5,)
        for _ in range(3):
            obs, *_ = env.step(np.int64(0))  # pair (1, 5)
        raw = env.unwrapped.testbed.observe()
        lights = obs[2 * n:3 * n]
        greens = {p for p, v in zip(env.unwrapped.phases, lights, strict=True) if v == 1.0}
        assert greens == set(raw.signal.greens) == {1, 5}
        assert obs[3 * n] >= 10.0, "the pair has been green since the first step"
        assert list(obs[3 * n + 1:]) == [1.0, 0.0, 0.0, 0.0]  # idle
        queues = [raw.traffic.movements[p].upstream_queue for p in env.unwrapped.phases]
        assert list(obs[:n]) == queues
    finally:
        env.close()


@pytest.mark.parametrize("action_type", ["selection", "duration"])
def test_same_seed_and_actions_give_the_same_trajectory(action_type: str) -> None:
    space = make(action_type).action_space
    space.seed(11)
    actions = [space.sample() for _ in range(15)]
    runs = []
    for _ in range(2):
        env = make(action_type)
        try:
            runs.append(rollout(env, 42, actions))
        finally:
            env.close()
    (obs_a, rew_a), (obs_b, rew_b) = runs
    assert rew_a == rew_b
    assert all(np.array_equal(a, b) for a, b in zip(obs_a, obs_b, strict=True))
    env = make(action_type)
    try:
        obs_c, _ = rollout(env, 43, actions)
    finally:
        env.close()
    assert not all(np.array_equal(a, c) for a, c in zip(obs_a, obs_c, strict=True)), "the seed changes the traffic"


def test_numpy_and_plain_actions_are_accepted() -> None:
    for action_type, actions in (("selection", [np.int64(1), 2, np.array(3)]),
                                 ("switch", [np.int64(1), 0, np.array(1, dtype=np.int32)]),
                                 ("duration", [np.array([0.25], np.float32), 0.5, np.float64(1.0)])):
        env = make(action_type)
        try:
            env.reset(seed=0)
            for action in actions:
                *_, info = env.step(action)
                assert info["refused"] is None and info["acted"]
        finally:
            env.close()


def test_a_selection_taken_as_an_integer_scalar_is_the_one_its_array_gives() -> None:
    """The adapter takes Python's and numpy's integer scalars without building an array: every value of every such
    type gives the pair (or the refusal) that the same value as a 0-d array gives; bools stay refused."""
    from hils.control.actions import ActionType
    from hils.envs.intersection import IntersectionAdapter

    adapter = IntersectionAdapter(load(data_path("four_leg.toml")), ActionType.SELECTION)
    n = len(adapter.config.pairs)

    def taken(action: object) -> object:
        try:
            return adapter.action(action)
        except EnvOptionError as exc:
            return str(exc).split(": ", 1)[1]  # what is allowed (the value itself is spelt as each type spells it)

    kinds = (int, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64)
    for kind in kinds:
        for value in (0, 1, n - 1, n, n + 7, *((-1, -n) if not np.issubdtype(kind, np.unsignedinteger) else ())):
            assert taken(kind(value)) == taken(np.array(value, dtype=kind if kind is not int else np.int64)), \
                (kind, value)
    assert taken(0) == adapter.config.pairs[0] and taken(np.int64(n - 1)) == adapter.config.pairs[-1]
    for refused in (True, np.bool_(False), n, -1, 2**70, 1.0):
        with pytest.raises(EnvOptionError, match=r"selection action .*: allowed: an integer in \["):
            adapter.action(refused)


def test_rewards_named_and_callable() -> None:
    seen: list[tuple[float, float]] = []

    def custom(previous: Observation, current: Observation) -> float:
        seen.append((previous.t, current.t))
        return current.t

    env = make("switch", reward=custom)
    try:
        _, start = env.reset(seed=0)
        _, reward, *_ = env.step(1)
        assert seen == [(start["t"], reward)]
        assert reward - start["t"] == pytest.approx(10.0)
    finally:
        env.close()
    for name in ("queue", "pressure", "wait"):
        env = make("selection", reward=name)
        try:
            _, rewards = rollout(env, 3, [0, 1, 2, 3] * 5)
            assert any(r != 0 for r in rewards), name
            if name == "queue":
                assert all(r <= 0 for r in rewards)
        finally:
            env.close()
    with pytest.raises(EnvOptionError, match="reward 'speed': allowed: queue, pressure, wait"):
        IntersectionEnv(reward="speed")
    with pytest.raises(EnvOptionError, match="action_type 'phase'"):
        IntersectionEnv("phase")


def test_sumo_step_and_control_interval_options() -> None:
    env = make("selection", sumo_step=0.5, control_interval=5.0, episode_length=30.0)
    try:
        _, start = env.reset(seed=0)
        *_, info = env.step(0)
        assert info["t"] - start["t"] == pytest.approx(5.0)
        assert env.unwrapped.config.middleware.sumo_step == 0.5
    finally:
        env.close()


@pytest.mark.wallclock
def test_the_same_env_runs_at_wall_clock_against_the_served_emulator(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
    try:
        env = make("selection", target=url, control_interval=2.0, episode_length=30.0)
        try:
            obs, _ = env.reset(seed=0)
            assert env.unwrapped.testbed.mode == "wall-clock"
            start = time.monotonic()
            # The transition from the startup pair takes min green + clearance (8 s): 12 s covers it.
            for _ in range(6):
                obs, _, terminated, truncated, info = env.step(np.int64(2))  # pair (3, 7)
                assert not terminated and not truncated and not info["timeout"]
            assert time.monotonic() - start == pytest.approx(12.0, abs=0.8), "each step lasts its control interval"
            n = len(env.unwrapped.phases)
            greens = {p for p, v in zip(env.unwrapped.phases, obs[2 * n:3 * n], strict=True) if v == 1.0}
            assert greens == {3, 7}
        finally:
            env.close()
    finally:
        served.stop()


def test_registration_is_gymnasiums_own_way_and_import_hils_hooks_nothing() -> None:
    """``import hils`` loads no gymnasium and leaves the import system alone; ``import hils.envs`` registers the
    environment, and gymnasium's ``module:id`` form imports it by itself."""
    for code in ("import sys\nhooks = list(sys.meta_path)\nimport hils\n"
                 "assert 'gymnasium' not in sys.modules, 'import hils loaded gymnasium'\n"
                 "assert sys.meta_path == hooks, 'import hils changed the import system'\n",
                 f"import gymnasium, hils.envs\nassert {ENV_ID!r} in gymnasium.registry\n"
                 f"gymnasium.make({ENV_ID!r}).close()\n",
                 f"import gymnasium\nassert {ENV_ID!r} not in gymnasium.registry\n"
                 f"gymnasium.make('hils.envs:{ENV_ID}').close()\n"):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
    assert hils.envs.ENV_ID == ENV_ID


# --- your own network ------------------------------------------------------------------------------


def test_the_four_phase_intersection_runs_with_permissive_lefts() -> None:
    env = make("switch", **FOUR_PHASE)
    try:
        assert env.action_space == gymnasium.spaces.Discrete(2)
        env.reset(seed=5)
        for _ in range(int(SHORT / 10)):
            *_, truncated, info = env.step(1)
            assert info["refused"] is None
        assert truncated
        links = env.unwrapped.testbed.intersection.signals.phase_map.links
        lefts = [link.index for link in links if link.turn == "left"]
        assert lefts and all(link.permissive for link in links if link.turn == "left")
        traffic = env.unwrapped.testbed.traffic
        assert traffic.arrived > 50 and traffic.collisions == 0
    finally:
        env.close()


def test_a_timeout_is_visible_in_info_and_the_episode_goes_on() -> None:
    # tau_trans below what a transition takes here (min green + clearance = 10 s): the first switch times out.
    config = load(FOUR_PHASE["config"]).with_middleware(tau_trans=8.0)
    env = make("switch", **{**FOUR_PHASE, "config": config}, episode_length=60.0)
    try:
        env.reset(seed=5)
        infos = []
        truncated = False
        while not truncated:
            *_, terminated, truncated, info = env.step(1)
            assert not terminated
            infos.append(info)
        timed_out = [i for i in infos if i["timeout"]]
        assert timed_out and timed_out[0]["timeout_reason"] == "transition" and timed_out[0]["state"] == "timeout"
        assert infos[-1]["state"] != "timeout", "the Testbed recovered and the episode went on"
        assert infos[-1]["t"] == pytest.approx(60.0)
    finally:
        env.close()


def test_the_four_phase_run_through_the_cli(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "hils", "run", "--config", FOUR_PHASE["config"], "--sumocfg",
           str(data_path("four_phase.sumocfg")), "--duration", "120", "--no-progress", "--out", str(tmp_path / "r")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Run ended: its duration passed." in done.stdout


def test_permissive_links_yield_and_protected_links_do_not() -> None:
    config = load(FOUR_PHASE["config"])
    pm = derive_phase_map(config, read_net(FOUR_PHASE["net"]))
    text = pm.state_string(SignalState(frozenset({4, 8}), frozenset(), frozenset({2, 6})))
    for link, letter in zip(pm.links, text, strict=True):
        if link.phase in (2, 6):
            assert letter == ("g" if link.turn == "left" else "G")
        else:
            assert letter == "r"


def test_an_unmappable_movement_is_refused_with_how_to_fix_it(tmp_path: Path) -> None:
    permissive = '2 = { approach = "east", turn = "through", permissive = ["left"],'
    text = data_path("four_phase.toml").read_text(encoding="utf-8")
    text = text.replace(permissive, permissive.split(" permissive")[0])
    path = tmp_path / "no_east_left.toml"
    path.write_text(text, encoding="utf-8")
    expected = (r"no phase serves the left movement of the east approach; fix the config .*no_east_left.toml: "
                r'add a phase with approach = "east", turn = "left", .*permissive')
    with pytest.raises(NetworkError, match=expected):
        make("selection", config=str(path), net=FOUR_PHASE["net"], routes=FOUR_PHASE["routes"])
    cmd = [sys.executable, "-m", "hils", "run", "--config", str(path), "--net", FOUR_PHASE["net"],
           "--routes", FOUR_PHASE["routes"], "--duration", "20", "--no-progress", "--out", str(tmp_path / "r")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert "no phase serves the left movement of the east approach" in done.stderr
    assert "Traceback" not in done.stderr


def test_bad_permissive_and_scenario_options_are_refused(tmp_path: Path) -> None:
    text = data_path("four_phase.toml").read_text(encoding="utf-8").replace('permissive = ["left"]',
                                                                            'permissive = ["right"]', 1)
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=r"phases\.2\.permissive: is \['right'\]; allowed"):
        load(path)
    with pytest.raises(NetworkError, match="give both"):
        make("selection", net=FOUR_PHASE["net"])
    with pytest.raises(NetworkError, match="does not exist"):
        make("selection", sumocfg=str(tmp_path / "missing.sumocfg"))


def test_the_testbed_takes_a_sumocfg() -> None:
    with Testbed(FOUR_PHASE["config"], sumo=True, sumo_config=data_path("four_phase.sumocfg"), duration=60,
                 seed=1) as tb:
        tb.reset()
        assert tb.run() == "duration"
        assert tb.intersection.signals.phase_map.phases == (2, 4, 6, 8)


# --- parallel environments ------------------------------------------------------------------------------


def test_async_vector_env_with_two_workers() -> None:
    envs = AsyncVectorEnv([lambda: make("selection", episode_length=60.0)] * 2)
    try:
        obs, _ = envs.reset(seed=[9, 9])
        assert obs.shape == (2, 29)
        assert np.array_equal(obs[0], obs[1])
        trajectory = []
        for _ in range(6):
            obs, _, terminated, truncated, _ = envs.step(np.array([1, 1]))
            trajectory.append(obs)
            assert np.array_equal(obs[0], obs[1]), "same seed and actions in both workers"
        assert truncated.all() and not terminated.any()
        obs, _ = envs.reset(seed=[1, 2])
        for _ in range(6):
            obs, *_ = envs.step(np.array([0, 2]))
        assert not np.array_equal(obs[0], obs[1])
        assert any(o.sum() > 0 for o in trajectory)
    finally:
        envs.close()


def test_episodes_skip_the_summary_samples_unless_asked() -> None:
    """Training needs no end-of-run delays: by default an episode takes no per-vehicle samples (measure=True
    brings them back), and the trajectory is the same either way."""
    returns = {}
    for measure in (False, True):
        env = IntersectionEnv("selection", episode_length=120.0, measure=measure)
        try:
            env.reset(seed=3)
            total = 0.0
            for step in range(12):
                _, reward, _, truncated, _ = env.step(step % len(env.config.pairs))
                total += reward
                if truncated:
                    break
            returns[measure] = (total, env.testbed.traffic)
        finally:
            env.close()
    (unmeasured, counts), (measured, traffic) = returns[False], returns[True]
    assert unmeasured == measured
    assert counts.mean_delay is None and traffic.mean_delay is not None
    assert (counts.departed, counts.arrived) == (traffic.departed, traffic.arrived)
