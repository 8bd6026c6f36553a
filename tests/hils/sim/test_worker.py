"""SUMO stepped in a worker process (hils.sim.worker) gives the very run SUMO stepped in process gives.

Each pair runs the same seed both ways, in this one process for the in-process side (as the environments do across
episodes; the networks used show no dependence on a process's history, hils.sim.sumo), and compares everything the
run gives: observations, rewards, infos, the event log less the wall clock, the end-of-run summary with RESCO's
figures, the hi-res log.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import hils.envs
from hils.run.testbed import Testbed
from hils.sim.sumo import SumoError
from tests.hils.run.same_seed import records

ROOT = Path(__file__).resolve().parents[3]


def _plain(value: object) -> object:
    """Observations as lists (numpy arrays compare element by element)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _episode(sumo_worker: bool) -> tuple[list, list, object]:
    env = hils.envs.parallel_env(scenario="resco:grid4x4", action_type="selection", episode_length=300.0,
                                 sumo_worker=sumo_worker)
    assert (env.testbed.sumo_process is not None) is sumo_worker
    try:
        out = [env.reset(seed=3)]
        for agent in env.possible_agents:
            env.action_space(agent).seed(3)
        while env.agents:
            out.append(env.step({agent: env.action_space(agent).sample() for agent in env.agents}))
        return _plain(out), records(env.testbed.records), env.testbed.traffic
    finally:
        env.close()


def test_an_episode_is_the_same_with_sumo_in_a_worker() -> None:
    """Sixteen lights, every observation, reward and info and every record equal; the traffic moved the same."""
    worker, in_process = _episode(True), _episode(False)
    assert worker[2].departed > 50  # traffic that the signals act on
    assert worker[0] == in_process[0]
    assert worker[1] == in_process[1]
    assert worker[2] == in_process[2]


def _measured_run(sumo_worker: bool, agent: str, **options: object) -> tuple[list, object, object]:
    with Testbed(scenario="resco:cologne8", sumo=True, seed=2, agent=agent, duration=240.0, sumo_worker=sumo_worker,
                 **options) as tb:
        tb.run()
        hires = tb.hires()
    return records(tb.records), tb.traffic, hires


@pytest.mark.parametrize("agent", ["max-pressure", "actuated"])
def test_a_measured_run_is_the_same_with_sumo_in_a_worker(agent: str) -> None:
    """The run ``hils run`` makes: per-second samples in SUMO, queue records, the summary with RESCO's figures from
    the tripinfo, the hi-res log; actuated: the stop-bar detectors read at every step."""
    worker, in_process = _measured_run(True, agent), _measured_run(False, agent)
    assert worker[1].resco is not None and worker[1].departed > 20
    assert any(r["kind"] == "queues" for r in worker[0])
    assert worker[0] == in_process[0]
    assert worker[1] == in_process[1]
    assert worker[2] == in_process[2]


def test_a_worker_that_dies_ends_the_run_with_a_sumo_error() -> None:
    env = hils.envs.parallel_env(scenario="resco:grid4x4", action_type="selection", episode_length=300.0,
                                 sumo_worker=True)
    try:
        env.reset(seed=0)
        os.kill(env.testbed.sumo_process._process.pid, signal.SIGKILL)
        with pytest.raises(SumoError, match=r"worker process ended \(exit code -9\)"):
            while env.agents:
                env.step({agent: env.action_space(agent).sample() for agent in env.agents})
    finally:
        with pytest.raises(SumoError):
            env.close()  # the run's summary cannot be had from a dead SUMO
    assert not env.testbed.sumo_process.alive


def test_sumo_refusing_a_start_is_told_from_the_worker(tmp_path: Path) -> None:
    missing = tmp_path / "nothing.sumocfg"
    missing.write_text("<configuration><input><net-file value='none.net.xml'/></input></configuration>")
    tb = Testbed(sumo=True, sumo_config=missing, sumo_worker=True)
    try:
        with pytest.raises(SumoError, match="SUMO did not start"):
            tb.reset()
    finally:
        tb.close()


def test_the_worker_is_refused_at_the_wall_clock() -> None:
    with pytest.raises(ValueError, match="sumo_worker: SUMO steps in a worker process in virtual time only"):
        Testbed(sumo=True, target="snmp://127.0.0.1:501", sumo_worker=True)


def test_a_script_without_a_main_guard_runs_its_environment(tmp_path: Path) -> None:
    """The worker is a fresh interpreter, not multiprocessing's spawn (which imports the script again and fails)."""
    script = tmp_path / "train.py"
    script.write_text(textwrap.dedent("""
        import hils.envs
        env = hils.envs.parallel_env(scenario="resco:grid4x4", episode_length=60.0, sumo_worker=True)
        env.reset(seed=1)
        while env.agents:
            env.step({agent: env.action_space(agent).sample() for agent in env.agents})
        print("worker", env.testbed.sumo_process is not None, "departed", env.testbed.traffic.departed)
        env.close()
    """))
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("worker True departed ")


def test_episodes_one_after_another_run_in_one_worker_each_on_a_fresh_sumo() -> None:
    env = hils.envs.parallel_env(scenario="resco:grid4x4", action_type="selection", episode_length=120.0,
                                 sumo_worker=True)
    try:
        worker = env.testbed.sumo_process
        episodes = []
        for _ in range(2):
            out = [env.reset(seed=5)]
            for agent in env.possible_agents:
                env.action_space(agent).seed(5)
            while env.agents:
                out.append(env.step({agent: env.action_space(agent).sample() for agent in env.agents}))
            episodes.append(_plain(out))
        assert env.testbed.sumo_process is worker and worker.alive
        assert episodes[0] == episodes[1]
    finally:
        env.close()
    assert not worker.alive
