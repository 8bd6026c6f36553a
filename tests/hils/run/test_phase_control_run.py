"""Phase control from the user's side: `hils run --schedule FILE` with MMITSS's own schedule, a broken schedule file
refused naming the file, the field and what is allowed, schedules the rules refuse leaving no SET on the controller,
and the environment's MultiBinary step."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hils.cli.main import main
from hils.control.actions import ActionError, ActionType
from hils.envs.intersection import EnvOptionError, IntersectionAdapter
from hils.protocol.config import load as load_config
from hils.protocol.ntcip import ControlColumn
from hils.run.testbed import Testbed
from hils.shell.events import Kind, read

MMITSS = Path(__file__).resolve().parents[3] / "examples" / "mmitss"


def test_hils_run_schedule_carries_out_mmitss_example_and_clears_at_the_end(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    code = main(["run", "--schedule", str(MMITSS / "schedule_ev.json"), "--no-sumo", "--duration", "150",
                 "--out", str(out), "--no-progress"])
    assert code == 0, capsys.readouterr()
    assert json.loads((out / "summary.json").read_text())["action_type"] == "control"
    records = list(read(out / "events.jsonl"))
    assert [r["kind"] for r in records].count(Kind.SCHEDULE_STARTED) == 1
    sets = [r for r in records if r["kind"] == Kind.SET_SENT and r.get("controls")]
    # the schedule's objects are SET as its orders start and end; the run's end clears all six
    assert any(r["purpose"] == "schedule" and r["controls"].get("phaseControlGroupPhaseOmit") for r in sets)
    assert sets[-1]["purpose"] == "clear" and not any(sets[-1]["controls"].values())
    assert len(sets[-1]["controls"]) == 6


@pytest.mark.parametrize(("content", "field", "allowed"), [
    ('{"MsgType": "Schedule", "Schedule": [{"commandPhase": 2, "commandType": "hodl", "commandStartTime": 0, '
     '"commandEndTime": 5}]}', "Schedule[0].commandType", "allowed: hold, forceoff, omit_veh, omit_ped"),
    ('{"MsgType": "Schedule", "Schedule": [{"commandPhase": 2, "commandType": "hold", "commandStartTime": 9, '
     '"commandEndTime": 5}]}', "Schedule[0]", "allowed: commandEndTime >= commandStartTime"),
    ('{"MsgType": "Schedule", "Schedule": [{"commandPhase": 12, "commandType": "hold", "commandStartTime": 0, '
     '"commandEndTime": 5}]}', "unknown phase 12", "allowed phases: [1, 2, 3, 4, 5, 6, 7, 8]"),
    ('{"MsgType": "Schedule", "Schedule": [{"commandPhase": 2, "commandType": "hold", "commandStartTime": 0}]}',
     "Schedule[0] has no commandEndTime", "a command has commandPhase, commandType"),
    ('{"MsgType": "Schedule", "Schedule": [', "is not JSON", ""),
])
def test_a_broken_schedule_file_names_the_file_the_field_and_what_is_allowed(tmp_path, capsys, content, field,
                                                                            allowed) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    assert main(["run", "--schedule", str(bad), "--no-sumo", "--duration", "10", "--out", str(tmp_path / "run"),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and field in err and allowed in err
    assert not (tmp_path / "run" / "events.jsonl").exists(), "refused before the run started"


def test_schedule_refuses_another_action_type_and_an_agent(tmp_path, capsys) -> None:
    ev = str(MMITSS / "schedule_ev.json")
    assert main(["run", "--schedule", ev, "--action-type", "selection", "--no-sumo", "--no-progress"]) == 2
    assert "--schedule commands by phase control" in capsys.readouterr().err
    assert main(["run", "--schedule", ev, "--agent", "random", "--no-sumo", "--no-progress"]) == 2
    assert "leave out --agent and --scenario" in capsys.readouterr().err


REFUSED = {
    "hold_and_force_off": {"hold": [2], "forceoff": [2]},
    "call_of_omitted_phase": {"call_veh": [3], "omit_veh": [3]},
    "hold_of_omitted_phase": {"hold": [4], "omit_veh": [4]},
    "ring_omitted": {"omit_veh": [1, 2, 3, 4]},
    "unknown_phase": {"hold": [9]},
}


def test_a_refused_schedule_leaves_no_set_on_the_controller(tmp_path) -> None:
    log = tmp_path / "events.jsonl"
    with Testbed(action_type="control", seed=3, duration=200.0, log_path=log) as tb:
        tb.reset()
        controller = tb.target.controller
        tb.step({"call_veh": [4, 8], "hold": [4, 8]})  # a valid step first: the refusals must not undo it
        held = dict(controller.control)
        assert held[ControlColumn.HOLD] == {4, 8} and held[ControlColumn.VEH_CALL] == {4, 8}
        sets = sum(1 for r in read(log) if r["kind"] == Kind.SET_SENT)
        for reason, step in REFUSED.items():
            with pytest.raises(ActionError) as refused:
                tb.step(step)
            assert refused.value.reason == reason
            assert controller.control == held, f"{reason}: the controller's objects changed"
        assert sum(1 for r in read(log) if r["kind"] == Kind.SET_SENT) == sets, "a refused schedule sent a SET"
        tb.step("clear")
        assert not any(controller.control.values())


def test_the_environment_takes_a_step_of_six_rows_of_bits() -> None:
    adapter = IntersectionAdapter(load_config(), ActionType.CONTROL)
    assert adapter.action_space.shape == (6, 8)
    bits = np.zeros((6, 8), dtype=np.int8)
    bits[0, [1, 5]] = 1  # hold 2 and 6
    bits[4, [1, 5]] = 1  # call_veh 2 and 6
    assert adapter.action(bits) == {"hold": [2, 6], "call_veh": [2, 6]}
    assert adapter.action(np.zeros((6, 8), dtype=np.int8)) == "clear"
    with pytest.raises(EnvOptionError, match="allowed: 0/1 of shape"):
        adapter.action(np.zeros((8,)))


def test_a_schedule_with_traffic_runs_the_controller_on_its_detectors_too(tmp_path) -> None:
    """MMITSS's schedules drive an actuated controller: SUMO's stop-bar loops call its phases beside the schedule."""
    out = tmp_path / "run"
    assert main(["run", "--schedule", str(MMITSS / "schedule_ev.json"), "--duration", "120", "--out", str(out),
                 "--no-progress"]) == 0
    actuations = json.loads((out / "summary.json").read_text())["detector_actuations"]
    assert sum(actuations.values()) > 10
