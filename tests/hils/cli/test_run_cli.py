"""`hils run`, the main job, end to end through the command line (SUMO, emulator, virtual time)."""

from __future__ import annotations

import json

import pytest

from hils.cli.main import main
from hils.shell.events import Kind, read
from hils.sim.network import NET_FILE, ROUTE_FILE, data_path


@pytest.mark.parametrize("action_type", ["selection", "switch", "duration"])
def test_hils_run_300_s_writes_every_output(tmp_path, capsys, action_type):
    out = tmp_path / "run"
    code = main(["run", "--duration", "300", "--action-type", action_type, "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0
    for name in ("events.jsonl", "summary.json", "signal_timeline.svg", "queues.svg"):
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
    assert "waiting to enter" in printed and "mean delay" in printed and "internal latency" in printed


STARVING = """
class EastWestOnly:
    action_type = "selection"

    def __init__(self, config, action_type, seed):
        self.turn = 0

    def act(self, observation):
        self.turn += 1
        return (1, 5) if self.turn % 3 == 0 else (2, 6)
"""


@pytest.mark.slow
def test_a_starving_agent_shows_who_could_not_enter(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "starving.py").write_text(STARVING)
    out = tmp_path / "run"
    code = main(["run", "--duration", "1500", "--agent", "starving:EastWestOnly", "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0
    traffic = json.loads((out / "summary.json").read_text())["traffic"]
    north, south = traffic["approaches"]["north"], traffic["approaches"]["south"]
    assert traffic["waiting_to_enter"] > 20
    assert north["waiting_to_enter"] + south["waiting_to_enter"] == traffic["waiting_to_enter"]
    assert north["arrived"] == south["arrived"] == 0
    assert north["spillback_minutes"] and south["spillback_minutes"]  # their lanes filled up before the backlog
    assert not any(traffic["approaches"][a]["spillback_minutes"] for a in ("east", "west"))
    assert north["mean_delay"] > 300 and south["mean_delay"] > 300
    assert traffic["mean_delay"] > 3 * traffic["mean_time_loss"]  # the arrived alone would hide the starving
    warning = next(line for line in printed.splitlines() if line.startswith("WARNING"))
    assert "could not enter" in warning and "north" in warning and "south" in warning
    assert "east" not in warning and "west" not in warning


def test_no_nan_in_the_summary_of_a_run_where_nothing_arrived(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--duration", "20", "--out", str(out), "--no-progress"]) == 0

    def refuse(name):
        raise AssertionError(f"{name} in summary.json")

    summary = json.loads((out / "summary.json").read_text(), parse_constant=refuse)
    assert summary["traffic"]["arrived"] == 0
    assert summary["traffic"]["mean_time_loss"] is None
    assert any("arrived vehicles only" in note for note in summary["traffic"]["notes"])


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


def test_webster_refuses_a_network_it_did_not_plan_for(tmp_path, capsys):
    code = main(["run", "--agent", "webster", "--action-type", "duration", "--net", str(data_path(NET_FILE)),
                 "--routes", str(data_path(ROUTE_FILE)), "--out", str(tmp_path / "run"), "--no-progress"])
    captured = capsys.readouterr()
    assert code == 2
    assert "--agent webster plans from the shipped four-leg network" in captured.out + captured.err
