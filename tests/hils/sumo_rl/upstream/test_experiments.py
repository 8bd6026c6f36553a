"""sumo-rl's experiment scripts (``experiments/``: its files but the import of its environments) run on hils.

They are written for hours of training (80,000 to 400,000 simulated seconds, up to 30 runs of 4 episodes): here each
episode is cut to :data:`EPISODE` simulated seconds and each script to its first :data:`EPISODES` episodes, by the test
(the scripts' own code and arguments are as written; where a script takes the length on its command line, it is given
there). A script that ends by itself ends the test; one cut short raises :class:`Enough` from its next reset.

Not here: ``dqn_2way-single-intersection.py``, ``dqn_big-intersection.py``, ``ppo_4x4grid.py`` and ``sb3_grid4x4.py``
need PyTorch (Stable-Baselines3, RLlib) and are not among the files kept; the test extra has torch and
Stable-Baselines3 (not RLlib) for hils' own training smoke test (``tests/harness/bench/test_train.py``).
``dqn_big-intersection`` also names a network sumo-rl does not ship, ``sb3_grid4x4`` also sumo-gui, a virtual display
and ffmpeg to film it.
"""

from __future__ import annotations

import csv
import runpy
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hils.envs.intersection import EnvOptionError
from hils.sumo_rl.environment.env import SumoEnvironment

EXPERIMENTS = Path(__file__).parent / "experiments"
EPISODE = 60  # simulated seconds
EPISODES = 2


class Enough(Exception):
    """The test has seen enough episodes of a script."""


@pytest.fixture
def resets(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[SumoEnvironment]]:
    """Every environment a script builds, its episodes cut to EPISODE s; the reset after EPISODES episodes raises
    :class:`Enough`. The environments are closed after the test."""
    built: list[SumoEnvironment] = []
    counted = {"resets": 0}
    init, reset = SumoEnvironment.__init__, SumoEnvironment.reset

    def short_init(self: SumoEnvironment, *args: Any, **kwargs: Any) -> None:
        kwargs["num_seconds"] = EPISODE
        init(self, *args, **kwargs)
        built.append(self)

    def counted_reset(self: SumoEnvironment, *args: Any, **kwargs: Any) -> Any:
        counted["resets"] += 1
        if counted["resets"] > EPISODES:
            raise Enough
        return reset(self, *args, **kwargs)

    monkeypatch.setattr(SumoEnvironment, "__init__", short_init)
    monkeypatch.setattr(SumoEnvironment, "reset", counted_reset)
    yield built
    for env in built:
        env.close()


def run(script: str, *argv: str) -> None:
    """``python experiments/SCRIPT ARGV...`` in this process; a script cut short is over."""
    sys_argv = sys.argv
    sys.argv = [script, *argv]
    try:
        runpy.run_path(str(EXPERIMENTS / script), run_name="__main__")
    except Enough:
        pass
    finally:
        sys.argv = sys_argv


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize(("script", "argv", "route"), [
    ("ql_single-intersection.py", ("-s", str(EPISODE)), None),
    ("ql_2way-single-intersection.py", ("-s", str(EPISODE)), "sumo_rl/nets/2way-single-intersection/"
                                                             "single-intersection-vhvh.rou.xml"),
])
def test_q_learning_on_a_single_intersection_runs_and_writes_its_csv(script: str, argv: tuple[str, ...],
                                                                     route: str | None, resets: list,
                                                                     in_sumo_rl_checkout: Path) -> None:
    """Tabular Q-learning (sumo-rl's QLAgent on ``env.encode``d states), one run, to the end; its CSV has a row per
    decision. (``ql_2way``'s default route, ``nets/...``, is not where its network is, in sumo-rl's repository too:
    it is given.)"""
    run(script, *argv, *(("-route", route) if route else ()))
    written = list((in_sumo_rl_checkout / "outputs" / script.removeprefix("ql_").removesuffix(".py")).glob("*.csv"))
    assert len(written) == 1 and len(rows(written[0])) == EPISODE // 5
    written[0].unlink()


@pytest.mark.parametrize("script", ["ql_4x4grid.py", "ql_4x4grid-mo.py"])
def test_q_learning_on_sumo_rls_4x4_grid_runs_its_episodes(script: str, resets: list,
                                                           in_sumo_rl_checkout: Path) -> None:
    """16 Q-learning agents on 4x4-Lucas, episode after episode (``-mo``: two rewards weighted, max green enforced);
    each episode's CSV written by the script."""
    run(script)
    env = resets[0]
    assert env.episode == EPISODES and len(env.ts_ids) == 16
    assert (script == "ql_4x4grid-mo.py") == env.enforce_max_green
    written = sorted((in_sumo_rl_checkout / "outputs" / "4x4").glob("ql-4x4grid_run1_conn*_ep*.csv"))
    assert [p.name.rsplit("_", 1)[1] for p in written] == [f"ep{k}.csv" for k in range(1, EPISODES + 1)]
    for path in written:
        assert len(rows(path)) == EPISODE // 5
        path.unlink()


def test_q_learning_through_the_aec_environment_runs_to_its_end(resets: list, in_sumo_rl_checkout: Path) -> None:
    """16 agents acting in turn through PettingZoo's AEC API (``agent_iter``, ``last``), the episode to its end."""
    run("ql_4x4grid_pz.py")
    env = resets[0]
    assert env.episode == 1 and env.episode_done
    assert len(rows(in_sumo_rl_checkout / "outputs" / "4x4" / f"pz_ql_conn{env.label}_ep1.csv")) == EPISODE // 5 + 1


@pytest.mark.parametrize(("script", "argv", "lights"), [
    ("sarsa_2way-single-intersection.py",
     ("-s", str(EPISODE), "-route", "sumo_rl/nets/2way-single-intersection/single-intersection-gen.rou.xml"), 1),
    # slow: the script's agents build their Fourier bases (order 7) for about a minute before the first step
    pytest.param("sarsa_double.py", ("--use_gui=False", "--runs=1"), 2, marks=pytest.mark.slow),
])
def test_true_online_sarsa_runs_to_the_end_of_its_episode(script: str, argv: tuple[str, ...], lights: int,
                                                          resets: list) -> None:
    """linear_rl's True Online Sarsa(lambda) on Fourier features of the observation: single agent on the 2-way
    intersection (the script writes its demand first; its default route, like ql_2way's, is given), and two agents on
    ``double`` (no GUI here: ``--use_gui=False``)."""
    run(script, *argv)
    assert [(env.episode, env.episode_done, len(env.ts_ids)) for env in resets] == [(1, True, lights)]


def test_sarsa_on_cologne8_is_refused_its_two_second_yellow() -> None:
    """``sarsa_resco.py`` asks for ``yellow_time=2``: below NTCIP 1202's 3 s, refused before anything runs."""
    with pytest.raises(EnvOptionError, match=r"yellow_time 2: .* allowed: 3-25.5 s"):
        run("sarsa_resco.py", "--episodes=1")
