"""The dashboard's board and server, without a browser (see test_dashboard_browser.py for the page).

The board is folded from the event log: a live board (fed record by record while the run runs) and
a replay of the finished log must show the same thing at every instant; the server must serve it,
refuse what it must refuse and say why.
"""

from __future__ import annotations

import json
import re
import select
import signal
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

from harness.bench.processes import start_emulator
from hils.dashboard.board import STRIP_S, Board, Panels, Replay, map_cells
from hils.dashboard.cabinet import COLUMNS as CABINET_COLUMNS
from hils.dashboard.cabinet import read_cabinet
from hils.protocol.config import IntersectionConfig, parse
from hils.protocol.scenario import load_scenario
from hils.run.testbed import Testbed
from hils.shell.events import Kind, read
from hils.sim.network import light_positions


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A virtual-time run with SUMO, its log on disk and the snapshot a live board fed by it ended with."""
    log = tmp_path_factory.mktemp("dash") / "events.jsonl"
    live: dict[str, Any] = {}
    boards: list[Board] = []

    def attach(tb: Testbed) -> None:
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
    replay = Replay(Board(paper_config), records, every=500)
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
    replay = Replay(Board(paper_config), records, every=97)  # checkpoints land anywhere between records
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
    assert snap["comms"]["failing"] == 0  # recovery read the controller: no longer failing, change or not


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
    paper_toml = paper_toml[:paper_toml.index("[coordination]")]  # pattern 1's split for 4 has no room for a walk
    start = paper_toml.index("\n4 = { ") + 1
    end = paper_toml.index("}", start)
    config = parse(paper_toml[:start] + paper_toml[start:end].rstrip() + ', walk = 6, ped_clear = 8, recall = "ped" '
                   + paper_toml[end:], "peds.toml")
    boards: list[Board] = []

    def attach(tb: Testbed) -> None:
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


# --- a run of several controllers: one panel per intersection ------------------------------------------


def test_panels_fold_each_intersection_s_records_into_its_own_board(paper_config: IntersectionConfig) -> None:
    panels = Panels.of({"J1": paper_config, "J2": paper_config}, {"J1": (0.0, 0.0), "J2": (300.0, 0.0)})
    j1, j2 = ({"intersection": tls} for tls in ("J1", "J2"))
    panels.feed_all([
        {"t": 0.0, "kind": "run_started", "scenario": "two", "source": "two.scenario.toml",
         "intersections": ["J1", "J2"], "seed": 0, "mode": "virtual", "action_type": "selection",
         "agent": "max-pressure", "duration": 60.0},
        {**_poll(0.0, [2, 6]), **j1}, {**_poll(0.0, [4, 8]), **j2},
        {"t": 1.0, "kind": "state", "from": "idle", "to": "on_hold", **j2},
        {"t": 3.0, "kind": "poll_failed", "poll_id": 30, "error": "CommunicationTimeout", "consecutive": 5, **j2},
        {"t": 3.0, "kind": "timeout_entered", "reason": "communication", "detail": "5 consecutive polls failed",
         "command_id": 4, **j2},
        {"t": 3.0, "kind": "state", "from": "on_hold", "to": "timeout", **j2},
        {**_poll(4.0, [1, 5]), **j1},
        {"t": 5.0, "kind": "command_dispatched", "action_id": 2, "command_id": 2, "command": [3, 7], "green": None,
         **j1},
        {"t": 5.0, "kind": "queues", "queues": {"north": 3}, **j1},
    ])
    snap = panels.snapshot()
    assert snap["run"]["scenario"] == "two" and snap["t"] == 5.0
    assert (snap["cols"], snap["rows"]) == (2, 1)
    first, second = snap["panels"]
    assert (first["id"], first["col"], first["row"], second["id"], second["col"]) == ("J1", 0, 0, "J2", 1)
    assert {p["phase"] for p in first["phases"] if p["shown"] == "G"} == {1, 5}
    assert {p["phase"] for p in second["phases"] if p["shown"] == "G"} == {4, 8}
    # J2's TIMEOUT is J2's alone; J1's command and queues are J1's.
    assert second["state"] == "timeout" and second["timeout"]["reason"] == "communication"
    assert first["state"] == "idle" and first["timeout"] is None
    assert second["comms"]["polls_failed"] == 1 and first["comms"]["polls_failed"] == 0
    assert [c["phases"] for c in first["commands"]] == [[3, 7]] and second["commands"] == []
    assert first["queues"] == {"north": 3} and second["queues"] is None
    # A quiet intersection's strip ends at the run's now, not at its own last record; in TIMEOUT it has no data.
    assert second["strip"]["segments"] == [[0.0, {"4": "G", "8": "G"}], [3.0, None]] and "t" not in second
    # run_ended counts the polls of each controller: each panel shows its own.
    panels.feed({"t": 6.0, "kind": "run_ended", "reason": "duration",
                 "polls": {"J1": {"polls": 60, "failed": 0}, "J2": {"polls": 60, "failed": 9}}})
    snap = panels.snapshot()
    assert snap["ended"] == "duration" and all(p["ended"] == "duration" for p in snap["panels"])
    assert [(p["comms"]["polls_ok"], p["comms"]["polls_failed"]) for p in snap["panels"]] == [(60, 0), (51, 9)]


def test_panels_are_placed_as_on_the_network_map() -> None:
    corridor = map_cells(light_positions(load_scenario("corridor")))
    assert corridor == {"J1": (0, 0), "J2": (1, 0), "J3": (2, 0), "J4": (3, 0)}  # a row, west to east
    grid = map_cells(light_positions(load_scenario("grid4x4")))
    # Columns A..D west to east, rows 4..1 north to south (the grid's rows are numbered from the south).
    assert grid == {f"{col}{row}": ("ABCD".index(col), 4 - row) for col in "ABCD" for row in range(1, 5)}
    # Junctions a few metres off a line still share it; a junction off every line gets its own.
    assert map_cells({"a": (0.0, 0.0), "b": (250.0, 7.5), "c": (496.0, -3.0), "d": (250.0, 180.0)}) == \
        {"a": (0, 1), "b": (1, 1), "c": (2, 1), "d": (1, 0)}


@pytest.fixture(scope="module")
def corridor_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Panels]:
    """A virtual-time corridor run with SUMO, its log on disk and the panels a live board fed by it ended with."""
    log = tmp_path_factory.mktemp("corridor") / "events.jsonl"
    scenario = load_scenario("corridor")
    live = Panels.of(scenario.intersections, light_positions(scenario))
    with Testbed(scenario=scenario, sumo=True, seed=1, duration=120.0, log_path=log,
                 on_reset=lambda tb: tb.events.subscribe(live.feed)) as tb:
        tb.reset_all()
        tb.run()
    return log, live


def test_a_corridor_run_replays_panel_by_panel(corridor_run: tuple[Path, Panels]) -> None:
    log, live = corridor_run
    records = list(read(log))
    scenario = load_scenario("corridor")
    replay = Replay(Panels.of(scenario.intersections, light_positions(scenario)), records, every=101)
    assert replay.at(replay.end).snapshot() == live.snapshot()
    for t in (0.0, 33.3, 61.0, 119.9):
        direct = Panels.of(scenario.intersections, light_positions(scenario)).feed_all(r for r in records
                                                                                      if r["t"] <= t)
        direct.t = max(direct.t, t)
        assert replay.at(t).snapshot() == direct.snapshot()
    end = live.snapshot()
    assert [p["id"] for p in end["panels"]] == ["J1", "J2", "J3", "J4"] and end["ended"] == "duration"
    for panel in end["panels"]:
        tls = panel["id"]
        last_poll = next(r for r in reversed(records) if r["kind"] == "poll" and r["intersection"] == tls)
        assert {p["phase"] for p in panel["phases"] if p["shown"] == "G"} == set(last_poll["greens"])
        assert panel["comms"]["polls_ok"] == 1200  # ten a second for 120 s: its own controller's count
        assert panel["commands"] and set(panel["queues"]) == {"north", "south", "east", "west"}
        *polled, (_, closed) = panel["strip"]["segments"]
        assert len({tuple(sorted(s)) for _, s in polled}) > 2  # its phases changed
        assert closed is None  # polling stopped with the close: no data
    assert end["panels"][2]["name"] == "corridor crossroad"  # J3's own config


@pytest.mark.slow
def test_hils_view_replays_a_corridor_run_and_finds_its_scenario(corridor_run: tuple[Path, Panels],
                                                                 tmp_path: Path) -> None:
    log, live = corridor_run
    proc, url = start_view(str(log.parent))
    try:
        status, snap = get(url + "api/snapshot")
        assert status == 200 and snap == json.loads(json.dumps(live.snapshot()))
        assert [(p["id"], p["col"], p["row"]) for p in snap["panels"]] == [("J1", 0, 0), ("J2", 1, 0), ("J3", 2, 0),
                                                                          ("J4", 3, 0)]
        status, snap = get(url + "api/snapshot?t=30")
        assert snap["t"] == 30.0 and len(snap["panels"]) == 4
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    # A log whose scenario file is not here: the view says how to name it, and replays once named.
    moved = tmp_path / "events.jsonl"
    moved.write_text(log.read_text().replace(load_scenario("corridor").source, "/elsewhere/corridor.scenario.toml"))
    lost = hils("view", str(moved))
    assert lost.returncode == 2 and "/elsewhere/corridor.scenario.toml is not a file here" in lost.stderr
    assert "--scenario" in lost.stderr
    wrong = hils("view", str(moved), "--scenario", "grid4x4")
    assert wrong.returncode == 2 and "are not those of" in wrong.stderr
    proc, url = start_view(str(moved), "--scenario", "corridor")
    try:
        assert len(get(url + "api/snapshot")[1]["panels"]) == 4
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# --- the command line and the server -----------------------------------------------------------------


def hils(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hils", *args], capture_output=True, text=True, timeout=60, cwd=cwd)


@pytest.mark.wallclock
def test_dashboard_options_refuse_what_cannot_work(tmp_path: Path) -> None:
    virtual = hils("run", "--no-sumo", "--duration", "5", "--dashboard", "0", "--out", str(tmp_path / "r"))
    assert virtual.returncode == 2 and "wall-clock" in virtual.stderr and "hils view" in virtual.stderr
    control = hils("run", "--no-sumo", "--duration", "5", "--dashboard-control", "--out", str(tmp_path / "r"))
    assert control.returncode == 2 and "--dashboard-control needs --dashboard PORT" in control.stderr
    empty = hils("view", str(tmp_path))
    assert empty.returncode == 2 and "no event log" in empty.stderr and "events.jsonl" in empty.stderr


@pytest.mark.wallclock
def test_only_the_dashboards_own_page_with_the_runs_secret_may_recover(tmp_path: Path) -> None:
    """A live run with --dashboard-control: the URL printed at start carries the run's secret; a POST without it,
    with another one, or from a page of another origin (another site, another port here) is refused with 403, and
    so is every request naming another host (DNS rebinding). The page itself, and curl with the secret, may."""
    served = start_emulator(tmp_path / "serve.log")
    proc = None
    try:
        proc, url = start_dashboard(sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--target",
                                    f"snmp://127.0.0.1:{served.port}?community=private&version=2c", "--duration",
                                    "60", "--dashboard", "0", "--dashboard-control", "--out", str(tmp_path / "run"))
        root, secret = page_root(url), secret_of(url)
        port = root.rsplit(":", 1)[1].rstrip("/")
        recover = root + "api/recover"
        assert get(root + "api/meta")[1]["control"] is True
        refused = {
            "no secret": get(recover, "POST"),
            "another secret": get(recover, "POST", {"X-Hils-Token": "guessed"}),
            "another site": get(recover, "POST", {**secret, "Origin": "http://evil.example"}),
            "another port": get(recover, "POST", {**secret, "Origin": "http://127.0.0.1:9"}),
            "rebound name, page": get(root, "GET", {"Host": "evil.example"}),
            "rebound name, board": get(root + "api/snapshot", "GET", {"Host": f"evil.example:{port}"}),
            "rebound name, recover": get(recover, "POST", {**secret, "Host": "evil.example"}),
        }
        for why, (status, body) in refused.items():
            assert status == 403, (why, status, body)
        assert "needs its secret" in refused["no secret"][1]["error"]
        assert "may not use this dashboard" in refused["another site"][1]["error"]
        assert "is not this dashboard's" in refused["rebound name, page"][1]["error"]
        for allowed in (secret, {**secret, "Origin": root.rstrip("/")}):  # curl with the secret, the page
            status, said = get(recover, "POST", allowed)
            assert status == 200 and said["recover"].startswith("nothing to recover: the manager is "), said
        assert get(f"http://localhost:{port}/api/meta", "GET")[0] == 200
    finally:
        if proc is not None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)
        served.stop()


def test_a_read_only_dashboard_prints_no_secret_and_refuses_control(tmp_path: Path, viewed: str) -> None:
    assert "token" not in viewed
    assert get(viewed + "api/snapshot", "GET", {"Host": "evil.example"})[0] == 403
    status, err = get(viewed + "api/recover", "POST", {"Origin": viewed.rstrip("/")})
    assert status == 403 and "--dashboard-control" in err["error"]


def start_dashboard(*cmd: str) -> tuple[subprocess.Popen[str], str]:
    """A command that serves the dashboard, started; the page's URL once it prints it (with the run's secret,
    ``?token=...``, when the page may control the run)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    line = proc.stdout.readline() if ready else ""
    match = re.match(r"dashboard: (http://127\.0\.0\.1:\d+/(\?token=[\w-]+)?)(\s|$)", line)
    if match is None:
        proc.kill()
        raise AssertionError(f"{' '.join(cmd[1:])}: printed no dashboard URL: {line!r} {proc.stderr.read()}")
    return proc, match[1]


def start_view(*args: str) -> tuple[subprocess.Popen[str], str]:
    return start_dashboard(sys.executable, "-m", "hils", "view", "--port", "0", *args)


@pytest.fixture
def viewed(run: tuple[Path, dict[str, Any]]) -> Iterator[str]:
    proc, url = start_view(str(run[0].parent), "--realtime", "10")
    yield url
    proc.terminate()
    proc.wait(timeout=10)


def get(url: str, method: str = "GET", headers: dict[str, str] | None = None) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, method=method, headers=headers or {}),
                                    timeout=10) as res:
            return res.status, json.loads(res.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def page_root(url: str) -> str:
    """The dashboard's root (``http://HOST:PORT/``) of the URL it printed."""
    return url.split("?", 1)[0]


def secret_of(url: str) -> dict[str, str]:
    """The header that controls the run, with the secret of the URL it printed."""
    return {"X-Hils-Token": url.split("?token=", 1)[1]}


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


def test_the_strip_shows_no_data_while_the_signal_state_is_not_verified(paper_config: IntersectionConfig) -> None:
    board = Board(paper_config)
    board.feed_all([
        _poll(0.0, [2, 6]),
        {"t": 1.0, "kind": "poll_failed", "poll_id": 9, "error": "CommunicationTimeout", "consecutive": 0},  # overtaken
        {"t": 2.0, "kind": "poll_failed", "poll_id": 10, "error": "CommunicationTimeout", "consecutive": 1},
        {"t": 2.1, "kind": "poll_failed", "poll_id": 11, "error": "CommunicationTimeout", "consecutive": 2},
        _poll(2.5, [2, 6]),  # known again, unchanged
        {"t": 4.0, "kind": "timeout_entered", "reason": "transition", "detail": "x", "command_id": 3},
        {"t": 9.0, "kind": "recovered", "greens": [2, 6]},
        {"t": 12.0, "kind": "set_sent", "command_id": None, "phases": [], "purpose": "clear"},
    ])
    segments = board.snapshot()["strip"]["segments"]
    green = {"2": "G", "6": "G"}
    assert segments == [[0.0, green], [2.0, None], [2.5, green], [4.0, None], [9.0, green], [12.0, None]]


def test_hils_view_finds_a_resco_runs_lights_by_their_names(tmp_path: Path) -> None:
    """A RESCO run's source lies inside sumo-rl's wheel ("resco:cologne3 (.../cologne3.sumocfg)", for one light
    "resco:cologne1 GS_cluster_357187_359543"): the view derives the lights again by name, as the run did, instead of
    asking for a file."""
    from hils.cli.main import main
    from hils.dashboard.cli import load_replay

    for name, lights in (("cologne1", 1), ("cologne3", 3)):
        out = tmp_path / name
        assert main(["run", "--scenario", f"resco:{name}", "--duration", "20", "--no-progress", "--out", str(out)]) == 0
        replay, _, skipped = load_replay(out)
        snap = replay.at(replay.end).snapshot()
        boards = snap["panels"] if lights > 1 else [snap]
        assert not skipped and len(boards) == lights
        assert all(b["comms"]["polls_ok"] == 200 for b in boards)  # ten a second for 20 s, each its own
        if lights > 1:  # each panel's heading names its light; the derived config's name does not repeat it
            assert {b["name"] for b in boards} == {"dual-ring from its SUMO program"}
