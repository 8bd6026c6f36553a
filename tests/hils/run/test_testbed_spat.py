"""`Testbed.spat()` and the environment's ``spat=True``: the controller's announced timing in the run's seconds, in
virtual time (docs/spat.md). The shipped four-leg: minimum green 3 s, maximum 20 s, yellow 3 s, red clearance 2 s;
2+6 rest green from start-up."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import simpy

from emulator.inprocess import VirtualTarget
from hils.envs import ENV_ID
from hils.envs.intersection import EnvOptionError, IntersectionEnv
from hils.protocol.config import load
from hils.protocol.ntcip import ControlColumn, control_oid
from hils.protocol.spat import MovementTiming
from hils.run.testbed import NotStarted, Testbed
from hils.sim.network import TLS_ID, data_path


def phases(tb: Testbed) -> dict[int, MovementTiming]:
    return {m.number: m for m in tb.spat()[TLS_ID] if m.kind == "phase"}


def test_the_testbed_gives_each_controllers_announcement() -> None:
    with Testbed(action_type="selection", seed=3) as tb:
        with pytest.raises(NotStarted):
            tb.spat()
        tb.reset(seed=3)
        tb.run_for(7.0)
        now = tb.now
        rest = phases(tb)
        assert set(rest) == set(range(1, 9))
        assert rest[2].indication == "green" and rest[2].max_end is None
        assert now < rest[2].min_end <= now + 0.1  # its minimum is long timed: it may end at the next tick
        assert rest[4].indication == "red" and rest[4].min_end >= rest[2].min_end + 5.0 - 1e-9  # yellow + red
        tb.step((4, 8))
        served = phases(tb)
        assert served[4].indication == served[8].indication == "green" and served[2].indication == "red"
        assert served[2].min_end > tb.now and served[2].max_end is None


@pytest.mark.parametrize("fast_path", [True, False])
def test_the_announced_times_are_the_runs_seconds_and_a_yellow_ends_at_its_announced_end(fast_path: bool) -> None:
    env = simpy.Environment()
    target = VirtualTarget(env, load(data_path("four_leg.toml")), seed=3, fast_path=fast_path, hires=False)
    env.run(until=5.0)
    target.surface.set_many([(control_oid(ControlColumn.VEH_CALL, 1), 0b10001000)])

    def shown(p: int) -> MovementTiming:
        return next(m for m in target.spat() if m.kind == "phase" and m.number == p)

    while shown(2).indication != "yellow":
        assert env.now < 10.0, "2 never turned yellow"
        env.run(until=env.now + 0.1)
    yellow = shown(2)
    assert yellow.min_end == yellow.max_end == yellow.likely
    assert 2.8 < yellow.max_end - env.now <= 3.0 + 1e-9
    env.run(until=yellow.max_end - 0.01)
    assert shown(2).indication == "yellow"
    env.run(until=yellow.max_end + 0.01)
    assert shown(2).indication == "red"


def test_the_fast_path_and_the_reference_announce_the_same() -> None:
    seen = []
    for fast_path in (True, False):
        with Testbed(action_type="selection", fast_path=fast_path, seed=5) as tb:
            tb.reset(seed=5)
            out = []
            for pair in ((4, 8), (1, 5), (3, 7), (2, 6)):
                tb.step(pair)
                out.append(tb.spat())
            seen.append(out)
    assert seen[0] == seen[1]


def test_the_environment_observes_the_announced_times_with_spat_true() -> None:
    env = gymnasium.make(ENV_ID, action_type="selection", episode_length=60.0, spat=True)
    try:
        n = len(env.unwrapped.phases)
        assert env.observation_space.shape == (5 * n + 5,)
        obs, _ = env.reset(seed=2)
        assert env.observation_space.contains(obs)
        earliest, latest = obs[3 * n + 5:4 * n + 5], obs[4 * n + 5:]
        timing = {m.number: m for m in env.unwrapped.testbed.spat()[TLS_ID] if m.kind == "phase"}
        now = env.unwrapped.testbed.now
        for k, p in enumerate(env.unwrapped.phases):
            assert earliest[k] == pytest.approx(timing[p].min_end - now, abs=1e-4)
            assert latest[k] == (-1.0 if timing[p].max_end is None else pytest.approx(timing[p].max_end - now))
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.all(obs[3 * n + 5:] >= -1.0)
    finally:
        env.close()
    with pytest.raises(EnvOptionError, match="spat=True with target="):
        IntersectionEnv(spat=True, target="snmp://127.0.0.1:1161")
