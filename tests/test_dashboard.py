"""The dashboard's board and server, without a browser (see test_dashboard_browser.py for the page).

The board is folded from the event log: a live board (fed record by record while the run runs) and
a replay of the finished log must show the same thing at every instant; the server must serve it,
refuse what it must refuse and say why.
"""

from __future__ import annotations

import json
import re
import select
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hils.config import IntersectionConfig, parse
from hils.dashboard.board import STRIP_S, Board, Replay
from hils.dashboard.cabinet import COLUMNS as CABINET_COLUMNS
from hils.dashboard.cabinet import read_cabinet
from hils.events import Kind, read
from hils.testbed import Testbed


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A virtual-time run with SUMO, its log on disk and the snapshot a live board fed by it ended with."""
    log = tmp_path_factory.mktemp("dash") / "events.jsonl"
    live: dict[str, Any] = {}
    boards: list[Board] = []

    def attach(tb: Testbed, _target: Any) -> None:
        board = Board(tb.config)
        tb.events.subscribe(board.feed)
        boards.append(board)

    with Testbed(sumo=True, seed=3, duration=200.0, log_path=log, on_reset=attach) as tb:
        tb.reset()
        tb.run()
    live.update(boards[0].snapshot())
    return log, live


def test_live_board_and_replay_agree_at_the_end(run: tuple[Path, dict[str, Any]],
                                                paper_config: IntersectionConfig) -> None:
    log, live = run
    records = list(read(log))
    replay = Replay(paper_config, records, every=500)
    assert replay.at(replay.end).snapshot() == live
    assert live["ended"] == "duration"
    assert live["state"] in {"idle", "on_hold", "closed"}
    # What the run did shows: polls counted, commands listed with hold times, queues per approach.
    assert live["comms"]["polls_ok"] == 2000  # ten a second for 200 s, none failed (the poller's own count)
    assert live["commands"] and all(c["hold_s"] is not None for c in live["commands"][1:])
    assert set(live["queues"]) == {"north", "south", "east", "west"}
    last_poll = next(r for r in reversed(records) if r["kind"] == "poll")
    greens = {p["phase"] for p in live["phases"] if p["shown"] == "G"}
    assert greens == set(last_poll["greens"])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(t=st.floats(min_value=-5.0, max_value=260.0, allow_nan=False))
def test_replay_at_any_instant_is_the_log_folded_up_to_it(run: tuple[Path, dict[str, Any]], t: float,
                                                          paper_config: IntersectionConfig) -> None:
    records = list(read(run[0]))
    replay = Replay(paper_config, records, every=97)  # checkpoints land anywhere between records
    direct = Board(paper_config).feed_all(r for r in records if r["t"] <= t)
    direct.t = max(direct.t, min(t, replay.end))
    assert replay.at(t).snapshot() == direct.snapshot()


def _poll(t: float, greens: list[int], yellows: list[int] = ()) -> dict[str, Any]:
    return {"t": t, "kind": "poll", "poll_id": round(t * 10), "greens": greens, "yellows": list(yellows)}


def test_strip_keeps_the_last_two_minutes_and_indications_follow_polls(paper_config: IntersectionConfig) -> None:
    board = Board(paper_config)
    assert all(p["shown"] is None for p in board.snapshot()["phases"])  # nothing polled: nothing claimed
    for k in range(40):  # a change every 10 s for 400 s
        board.feed(_poll(10.0 * k, [2, 6] if k % 2 else [4, 8], [1] if k % 3 == 0 else []))
    snap = board.snapshot()
    starts = [s[0] for s in snap["strip"]["segments"]]
    # The oldest segment kept is the one showing at t - 120 s; nothing older.
    assert starts[0] <= snap["t"] - STRIP_S < starts[1]
    shown = {p["phase"]: p["shown"] for p in snap["phases"]}
    assert shown == {1: "Y", 2: "G", 3: "r", 4: "r", 5: "r", 6: "G", 7: "r", 8: "r"}


def test_timeout_shows_its_reason_until_the_manager_is_idle_again(paper_config: IntersectionConfig) -> None:
    board = Board(paper_config)
    board.feed_all([
        {"t": 1.0, "kind": "state", "from": "idle", "to": "on_hold"},
        {"t": 3.0, "kind": "poll_failed", "poll_id": 30, "error": "CommunicationTimeout", "consecutive": 5},
        {"t": 3.0, "kind": "timeout_entered", "reason": "communication", "detail": "5 consecutive polls failed",
         "command_id": 4},
        {"t": 3.0, "kind": "state", "from": "on_hold", "to": "timeout"},
    ])
    snap = board.snapshot()
    assert snap["state"] == "timeout"
    assert snap["timeout"]["reason"] == "communication" and "5 consecutive" in snap["timeout"]["detail"]
    assert snap["comms"]["polls_failed"] == 1 and snap["comms"]["failing"] == 5
    board.feed_all([{"t": 9.0, "kind": "recovery_started"}, {"t": 9.1, "kind": "recovered", "greens": [2, 6]},
                    {"t": 9.1, "kind": "state", "from": "timeout", "to": "idle"}])
    snap = board.snapshot()
    assert snap["state"] == "idle" and snap["timeout"] is None


def test_a_kept_command_is_listed_with_its_phases(paper_config: IntersectionConfig) -> None:
    board = Board(paper_config).feed_all([
        {"t": 0.0, "kind": "action_converted", "action_id": 1, "command": [2, 6], "green": None, "keep": True},
        {"t": 0.0, "kind": "hold_released", "command_id": 1, "reason": "keep", "hold_s": 0.0},
        {"t": 10.0, "kind": "command_dispatched", "action_id": 2, "command_id": 2, "command": [4, 8], "green": 12},
        {"t": 10.0, "kind": "set_sent", "command_id": 2, "phases": [4, 8], "purpose": "command"},
        {"t": 15.1, "kind": "transition_verified", "command_id": 2, "command": [4, 8], "poll_id": 9, "hold_s": 5.1},
    ])
    newest, kept = board.snapshot()["commands"]
    assert kept == {"id": 1, "phases": [2, 6], "t": 0.0, "green": None, "verified_s": None, "hold_s": 0.0,
                    "outcome": "keep"}
    assert newest["phases"] == [4, 8] and newest["verified_s"] == 5.1 and newest["outcome"] is None
    assert board.snapshot()["comms"]["last_lag_s"] == 5.1
    assert [p["phase"] for p in board.snapshot()["phases"] if p["vehcall"]] == [4, 8]


def test_the_cabinet_read_shows_walks_clearances_calls_and_next(paper_toml: str) -> None:
    """Phase 4 with pedestrian timing and ped recall: the page shows its WALK, then FDW, and PhaseNext."""
    start = paper_toml.index("\n4 = { ") + 1
    end = paper_toml.index("}", start)
    config = parse(paper_toml[:start] + paper_toml[start:end].rstrip() + ', walk = 6, ped_clear = 8, recall = "ped" '
                   + paper_toml[end:], "peds.toml")
    boards: list[Board] = []

    def attach(tb: Testbed, _target: Any) -> None:
        boards.append(Board(tb.config))
        tb.events.subscribe(boards[0].feed)
        tb.env.process(read_cabinet(tb.env, tb.transport, tb.events, tb.config.groups))

    peds: dict[str, set[float]] = {"walk": set(), "ped_clear": set()}
    nexts: set[int] = set()
    with Testbed(config, sumo=False, seed=2, duration=240.0, on_reset=attach) as tb:
        tb.reset()
        while not tb.done:
            tb.run_for(1.0)
            for ph in boards[0].snapshot()["phases"]:
                if ph["ped"] in peds:
                    assert ph["phase"] == 4  # the only phase with pedestrian timing
                    peds[ph["ped"]].add(tb.env.now)
                if ph["next"]:
                    nexts.add(ph["phase"])
        records = tb.events.of(Kind.CABINET)
    # Walk, then flashing don't walk, each for about its time (reads are 1 s apart), while 4 is green.
    assert len(peds["walk"]) >= 5 and len(peds["ped_clear"]) >= 7
    first_walk = min(peds["walk"])
    assert first_walk < min(t for t in peds["ped_clear"] if t > first_walk) <= first_walk + 7
    assert nexts and nexts <= set(config.phases)  # PhaseNext shows during clearances
    assert any(4 in r["ped_calls"] for r in records)  # the ped recall is a call the controller holds
    # Logged on change only: no two consecutive records alike.
    fields = [{k: r[k] for k in CABINET_COLUMNS} for r in records]
    assert all(a != b for a, b in pairwise(fields))


def test_a_board_without_cabinet_reads_claims_nothing(paper_config: IntersectionConfig) -> None:
    snap = Board(paper_config).feed_all([_poll(0.0, [2, 6])]).snapshot()
    assert snap["cabinet_read"] is False
    assert all(p["ped"] is None and p["next"] is None and p["call"] is None for p in snap["phases"])


# --- the command line and the server -----------------------------------------------------------------


def hils(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hils", *args], capture_output=True, text=True, timeout=60, cwd=cwd)


def test_dashboard_options_refuse_what_cannot_work(tmp_path: Path) -> None:
    virtual = hils("run", "--no-sumo", "--duration", "5", "--dashboard", "0", "--out", str(tmp_path / "r"))
    assert virtual.returncode == 2 and "wall-clock" in virtual.stderr and "hils view" in virtual.stderr
    control = hils("run", "--no-sumo", "--duration", "5", "--dashboard-control", "--out", str(tmp_path / "r"))
    assert control.returncode == 2 and "--dashboard-control needs --dashboard PORT" in control.stderr
    empty = hils("view", str(tmp_path))
    assert empty.returncode == 2 and "no event log" in empty.stderr and "events.jsonl" in empty.stderr


def start_view(*args: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen([sys.executable, "-m", "hils", "view", "--port", "0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    line = proc.stdout.readline() if ready else ""
    match = re.match(r"dashboard: (http://127\.0\.0\.1:\d+/)", line)
    if match is None:
        proc.kill()
        raise AssertionError(f"hils view printed no URL: {line!r} {proc.stderr.read()}")
    return proc, match[1]


@pytest.fixture
def viewed(run: tuple[Path, dict[str, Any]]) -> Iterator[str]:
    proc, url = start_view(str(run[0].parent), "--realtime", "10")
    yield url
    proc.terminate()
    proc.wait(timeout=10)


def get(url: str, method: str = "GET") -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, method=method), timeout=10) as res:
            return res.status, json.loads(res.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def test_replay_server_serves_the_board_at_an_instant_and_refuses_control(viewed: str,
                                                                         run: tuple[Path, dict[str, Any]]) -> None:
    assert get(viewed + "api/meta") == (200, {"mode": "replay", "control": False, "end": pytest.approx(200.0, abs=0.1),
                                              "realtime": 10.0})
    status, snap = get(viewed + "api/snapshot?t=60")
    assert status == 200 and snap["t"] == 60.0 and snap["ended"] is None
    status, snap = get(viewed + "api/snapshot")
    assert snap == run[1]  # the end of the replay is what the live board showed last
    status, err = get(viewed + "api/snapshot?t=soon")
    assert status == 400 and "allowed: sim seconds" in err["error"]
    status, err = get(viewed + "api/recover", method="POST")
    assert status == 403 and "--dashboard-control" in err["error"]
    with urllib.request.urlopen(viewed, timeout=10) as page:
        html = page.read().decode()
    assert "/static/app.js" in html and "http" not in html.split("<body>", 1)[1]  # nothing from the internet
