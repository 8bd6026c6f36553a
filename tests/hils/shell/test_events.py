"""The structured event log: schema, write-through, crash safety and determinism."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from hils.agents.builtin import Observation
from hils.control.actions import ActionType
from hils.run.testbed import AgentFailed, RunSpec, Testbed, run_spec
from hils.shell.events import EventLog, Kind, read


def _without_wall(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k != "wall_ns"} for r in records]


def _as_written(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """In-memory records as they read back from the file (sets become sorted lists)."""
    return [json.loads(json.dumps(r, default=lambda v: sorted(v) if isinstance(v, (set, frozenset)) else list(v)))
            for r in records]


def test_every_record_has_the_common_keys_and_a_gapless_seq(paper_config, tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    run_spec(RunSpec(paper_config, ActionType.SWITCH, agent="random", duration=120.0, seed=2,
                                 log_path=path))
    records = list(read(path))
    assert len(records) > 50
    assert [r["seq"] for r in records] == list(range(len(records)))
    kinds = {k.value for k in Kind}
    for r in records:
        assert {"seq", "t", "wall_ns", "kind"} <= r.keys()
        assert isinstance(r["t"], float | int) and isinstance(r["wall_ns"], int)
        assert r["kind"] in kinds
    assert all(a["t"] <= b["t"] for a, b in pairwise(records))
    assert all(a["wall_ns"] <= b["wall_ns"] for a, b in pairwise(records))
    assert records[0]["kind"] == "run_started" and records[-1]["kind"] == "run_ended"


def test_records_are_written_through_while_the_log_is_open(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "log.jsonl"
    log = EventLog(path, clock=lambda: 1.5)
    emitted = [log.emit(Kind.NOTE, message="one"), log.emit(Kind.POLL, poll_id=1, greens=frozenset({6, 2}))]
    seen = list(read(path))
    assert seen == _as_written(emitted)
    assert seen[1]["greens"] == [2, 6]
    log.emit(Kind.NOTE, message="three")
    assert [r["seq"] for r in read(path)] == [0, 1, 2]
    log.close()
    assert len(list(read(path))) == 3


def test_the_log_can_stay_out_of_memory(tmp_path: Path) -> None:
    log = EventLog(tmp_path / "log.jsonl", keep=False)
    log.emit(Kind.NOTE, message="x")
    assert log.records == []
    assert [r["message"] for r in read(tmp_path / "log.jsonl")] == ["x"]


class CrashingAgent:
    """Switches a few times, then fails the way a buggy user agent would."""

    action_type = ActionType.SWITCH

    def __init__(self, crash_after: int) -> None:
        self.crash_after = crash_after
        self.calls = 0

    def act(self, observation: Observation) -> int:
        self.calls += 1
        if self.calls > self.crash_after:
            raise RuntimeError("agent crashed")
        return 1


def test_a_run_whose_agent_crashes_keeps_every_record_and_ends_cleanly(paper_config, tmp_path: Path) -> None:
    path = tmp_path / "crash.jsonl"
    emitted: list[dict[str, Any]] = []

    def configure(run: Testbed) -> None:
        run.agent = CrashingAgent(crash_after=3)
        emit = run.events.emit

        def spy(kind: Kind, **fields: Any) -> dict[str, Any]:
            emitted.append(emit(kind, **fields))
            return emitted[-1]

        run.events.emit = spy

    with pytest.raises(AgentFailed, match="agent crashed") as caught:
        run_spec(RunSpec(paper_config, ActionType.SWITCH, duration=600.0, seed=1, log_path=path),
                 configure=configure)
    assert isinstance(caught.value.__cause__, RuntimeError)
    on_disk = list(read(path))
    assert len(emitted) > 20
    assert on_disk == _as_written(emitted)
    assert len([r for r in on_disk if r["kind"] == "action_received"]) == 3
    assert len([r for r in on_disk if r["kind"] == "transition_verified"]) == 3
    assert on_disk[-1]["t"] >= 20.0, "the run went on until the fourth decision"
    clear = [r for r in on_disk if r["kind"] == "set_sent" and r["purpose"] == "clear"]
    assert len(clear) == 1 and clear[0]["phases"] == [], "the calls are cleared"
    assert on_disk[-1]["kind"] == "run_ended" and on_disk[-1]["reason"] == "agent_error"


def test_read_ignores_a_torn_last_line(tmp_path: Path) -> None:
    path = tmp_path / "torn.jsonl"
    log = EventLog(path)
    for i in range(3):
        log.emit(Kind.NOTE, message=f"n{i}")
    log.close()
    with path.open("a", encoding="utf-8") as f:
        f.write('{"seq":3,"t":0.0,"wall_ns":12,"kind":"no')
    assert [r["message"] for r in read(path)] == ["n0", "n1", "n2"]


def _log_of(config, action_type: ActionType, seed: int, path: Path) -> list[dict[str, Any]]:
    run_spec(RunSpec(config, action_type, agent="random", duration=600.0, seed=seed, log_path=path))
    return _without_wall(list(read(path)))


@pytest.mark.parametrize("action_type", list(ActionType))
def test_same_seed_same_log_and_another_seed_differs(paper_config, tmp_path: Path, action_type) -> None:
    first = _log_of(paper_config, action_type, 7, tmp_path / "a.jsonl")
    again = _log_of(paper_config, action_type, 7, tmp_path / "b.jsonl")
    other = _log_of(paper_config, action_type, 8, tmp_path / "c.jsonl")
    commanded = "schedule_started" if action_type is ActionType.CONTROL else "command_dispatched"
    assert len([r for r in first if r["kind"] == commanded]) >= 10
    assert first == again
    # Beyond the seed written in the first record, the agent's choices differ.
    assert first[1:] != other[1:]
    actions = [r["value"] for r in first if r["kind"] == "action_received"]
    assert actions != [r["value"] for r in other if r["kind"] == "action_received"]


def test_a_subscriber_of_one_intersection_sees_its_records_and_the_runs_own_only() -> None:
    from hils.shell.events import TaggedLog

    log = EventLog()
    everything: list[dict[str, Any]] = []
    of_j2: list[dict[str, Any]] = []
    log.subscribe(everything.append)
    log.subscribe(of_j2.append, intersection="J2")
    log.emit(Kind.RUN_STARTED)
    for tls in ("J1", "J2", "J3"):
        TaggedLog(log, tls).emit(Kind.NOTE, message=tls)
    log.emit(Kind.RUN_ENDED, reason="duration")
    assert [r["kind"] for r in everything] == ["run_started", "note", "note", "note", "run_ended"]
    assert [(r["kind"], r.get("intersection")) for r in of_j2] == [
        ("run_started", None), ("note", "J2"), ("run_ended", None)]
