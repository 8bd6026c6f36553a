"""The same seed, the same run: nothing of hils survives a run (issue 33, item 7). Each family of runs twice in this
one process, with identical event logs, hi-res logs and summaries.

Only SUMO's side can tell a process's history: a libsumo run depends on where the objects it loads lie in memory
(:mod:`hils.sim.sumo`), so `hils sweep` and `hils compare` run every cell in a process of its own
(tests/hils/sweep/test_sweep.py). On cologne1 that shows after 520 simulated seconds at the earliest; the RESCO run
here stops before it."""

from __future__ import annotations

from typing import Any

import pytest

from hils import Testbed
from hils.report import summary
from tests.hils.run import same_seed

# (family, Testbed arguments, simulated seconds): the shipped four-leg and corridor with the agents that command
# them, RESCO's cologne1, and the controller's own operation (a coordinated plan along the corridor, the pretimed
# plan, actuated on its detectors).
FAMILIES = [
    ("four-leg", {}, 300.0),
    ("corridor", {"scenario": "corridor"}, 180.0),
    ("resco", {"scenario": "resco:cologne1"}, 300.0),
    ("coordinated", {"scenario": "corridor", "agent": "coordinated"}, 180.0),
    ("fixed-time", {"agent": "fixed-time"}, 300.0),
    ("actuated", {"agent": "actuated"}, 300.0),
]


def run(arguments: dict[str, Any], duration: float) -> tuple[list[dict], dict, dict]:
    """One run of seed 0: its event log, its summary (as `hils run` writes it) and each controller's hi-res log."""
    with Testbed(sumo=True, seed=0, duration=duration, **arguments) as tb:
        tb.run()
    s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()}, traffic=tb.traffic,
                          wall_s=tb.wall_s)
    return same_seed.records(tb.records), same_seed.summary(s), tb.hires()


@pytest.mark.parametrize(("family", "arguments", "duration"), FAMILIES, ids=[f for f, _, _ in FAMILIES])
def test_a_run_twice_in_one_process_is_the_same_run(family: str, arguments: dict[str, Any], duration: float) -> None:
    first, second = run(arguments, duration), run(arguments, duration)
    records, summarised, hires = first
    assert records[-1]["kind"] == "run_ended" and records[-1]["reason"] == "duration"
    assert summarised["traffic"]["arrived"] > 0 and all(hires.values())
    assert second[0] == records, "the event logs differ"
    assert second[2] == hires, "the controllers' hi-res logs differ"
    assert second[1] == summarised, "the summaries differ"
