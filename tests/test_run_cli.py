"""`hils run`, the main job, end to end through the command line (SUMO, emulator, virtual time)."""

from __future__ import annotations

import json

import pytest

from hils.cli import main
from hils.events import Kind, read


@pytest.mark.parametrize("action_type", ["selection", "switch", "duration"])
def test_hils_run_300_s_writes_every_output(tmp_path, capsys, action_type):
    out = tmp_path / "run"
    code = main(["run", "--duration", "300", "--action-type", action_type, "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0
    for name in ("events.jsonl", "summary.json", "signal_timeline.png", "queues.png"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["action_type"] == action_type
    assert summary["traffic"]["departed"] > 50
    assert summary["traffic"]["arrived"] > 0
    assert summary["commands_dispatched"] > 5
    assert summary["transitions_verified"] >= summary["commands_dispatched"] - 1
    assert summary["timeouts"] == {}
    assert summary["internal_latency_ms"][action_type]["n"] == summary["commands_dispatched"]
    records = list(read(out / "events.jsonl"))
    assert records[0]["kind"] == Kind.RUN_STARTED and records[-1]["kind"] == Kind.RUN_ENDED
    assert "vehicles served" in printed and "internal latency" in printed


def test_hils_run_refuses_an_agent_that_does_not_fit(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "my_agents.py").write_text("class NotAnAgent:\n    def __init__(self, *a):\n        pass\n")
    code = main(["run", "--no-sumo", "--duration", "30", "--agent", "my_agents:NotAnAgent", "--out",
                 str(tmp_path / "run"), "--no-progress"])
    assert code == 2
    assert "does not fit the agent protocol: it has no act(observation) method" in capsys.readouterr().err


def test_a_wrong_config_names_file_field_and_allowed(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[timing]\nmin_green = 5\nmax_green = 4\nyellow = 3.0\nred_clear = 2.0\n'
                   "[phases]\n1 = {}\n2 = {}\n[structure]\nrings = [[1], [2]]\nbarriers = [[1, 2]]\n"
                   "sequence = [[1, 2]]\npairs = [[1, 2]]\n")
    assert main(["run", "--no-sumo", "--config", str(bad), "--duration", "10", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "timing.max_green" in err and "max_green >= min_green" in err
