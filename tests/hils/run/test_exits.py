"""Every way a run ends clears the calls and says how it ended; a controller lost mid-run looks lost.

End to end through `hils run` in its own process against `hils emulator serve` over UDP, as a user runs it:
a full disk (a file size limit set in the run's process, no root needed), a controller killed mid-run,
agents that fail or are refused. What the controller holds afterwards is read with net-snmp's snmpget.
"""

from __future__ import annotations

import io
import json
import logging
import os
import re
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from xml.etree import ElementTree

import pytest

from harness.bench.processes import Served, start_emulator
from hils.cli.main import main
from hils.cli.status import Notices, StatusLine
from hils.run.testbed import Testbed
from hils.shell.events import EventLog, Kind, LogWriteError, read
from tests.hils.run.test_testbed import short_interval_config, veh_call

pytestmark = pytest.mark.wallclock  # most of these run against a served emulator

SVG = "{http://www.w3.org/2000/svg}"


def vehcalls_applied(served: Served) -> list[int]:
    """Every VehCall value the served controller applied, in order, from its own log of SETs."""
    return [int(m[1]) for m in re.finditer(r"phaseControlGroupVehCall\.1 = (\d+)[^\n]*-> applied",
                                           served.log.read_text())]


def file_size_limit(size: int) -> Callable[[], None]:
    """For the run's process only: files may not grow beyond ``size`` bytes (a full disk, without root)."""
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


def hils_run(tmp_path: Path, served: Served, *args: str, limit: int | None = None) -> subprocess.Popen[str]:
    url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-m", "hils", "run", "--target", url, "--no-sumo", "--no-progress",
                             "--out", str(tmp_path / "run"), "--config", str(short_interval_config(tmp_path)), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env,
                            preexec_fn=None if limit is None else file_size_limit(limit))


def last_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("hils run: ")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# --- a full disk ----------------------------------------------------------------------------------------------


def test_a_full_disk_ends_the_run_as_an_error_with_the_calls_cleared_and_whole_records(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        proc = hils_run(tmp_path, served, "--action-type", "switch", "--duration", "60", limit=3000)
        _, err = proc.communicate(timeout=90)
        assert proc.returncode == 1, err
        line = last_line(err)
        assert "cannot write the event log" in line and "File too large" in line and "calls cleared" in line
        applied = vehcalls_applied(served)
        assert any(applied), "the run had placed a call when the disk filled"
        assert applied[-1] == 0 and veh_call(served.port) == 0, "the calls are cleared, as net-snmp reads them"
    finally:
        served.stop()
    run = tmp_path / "run"
    log = run / "events.jsonl"
    assert log.read_bytes().endswith(b"\n") and 0 < log.stat().st_size <= 3000
    records = list(read(log))  # every line a whole record: read() refuses anything else
    assert [r["seq"] for r in records] == list(range(len(records)))
    assert any(r["kind"] == "set_sent" and r["purpose"] == "command" for r in records)
    assert records[-1]["t"] < 50, "the run ended when its log failed, not at its duration"
    # What could not be written whole is not there at all.
    for name in ("summary.json", "signal_timeline.svg"):
        path = run / name
        if path.exists():
            text = path.read_text()
            assert json.loads(text) if name.endswith(".json") else text.endswith("</svg>\n")


def test_a_run_with_no_room_at_all_is_refused_before_anything_is_sent(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    try:
        proc = hils_run(tmp_path, served, "--duration", "20", limit=0)
        _, err = proc.communicate(timeout=60)
    finally:
        served.stop()
    assert proc.returncode == 2, err
    assert err.count("\n") == 1 and "no room for the run's outputs in" in err and "File too large" in err
    assert "SET from" not in served.log.read_text(), "nothing was sent to the controller"


class _Filling:
    """A file that takes ``room`` bytes and no more, writing short as a full disk does."""

    def __init__(self, file, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(28, "No space left on device")
        n = min(len(data), self.room)
        self.room -= n
        return self.file.write(bytes(data[:n]))

    def fileno(self) -> int:
        return self.file.fileno()

    def close(self) -> None:
        self.file.close()


def test_a_record_the_file_cannot_take_whole_is_cut_back_out(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    log = EventLog(path, clock=lambda: 1.0)
    log.emit(Kind.NOTE, message="first")
    log._file._file = _Filling(log._file._file, 70)
    failures: list[LogWriteError] = []
    log.on_failure = failures.append
    log.emit(Kind.NOTE, message="second, a little longer than the room left for it")
    kept = log.emit(Kind.NOTE, message="third")  # the log goes on in memory
    assert [r["message"] for r in read(path)] == ["first"], "no half record"
    assert len(failures) == 1 and "No space left on device" in str(failures[0]) and "first 1 records" in str(
        failures[0])
    assert log.records[-1] is kept and kept["seq"] == 2
    bare = EventLog(tmp_path / "bare.jsonl")
    bare._file._file = _Filling(bare._file._file, 10)
    with pytest.raises(LogWriteError, match="No space left on device"):  # nobody to tell: raised
        bare.emit(Kind.NOTE, message="x")


def test_sigterm_inside_the_logs_encoder_is_still_a_termination(tmp_path: Path, monkeypatch) -> None:
    """Ctrl-C or SIGTERM that lands while orjson calls back into Python is raised as itself, not as orjson's
    TypeError: a terminated run must exit 143, not as an error."""
    from hils.protocol.errors import RunInterrupted
    from hils.shell import events

    def interrupted(value):
        raise RunInterrupted("terminated")

    monkeypatch.setattr(events, "_jsonable", interrupted)
    log = EventLog(tmp_path / "events.jsonl")
    with pytest.raises(RunInterrupted):
        log.emit(Kind.POLL, poll_id=1, greens=frozenset({2, 6}), yellows=())


# --- a controller lost mid-run ---------------------------------------------------------------------------------


def test_a_controller_lost_mid_run_is_said_when_it_happens_exits_3_and_is_drawn_as_no_data(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    proc = hils_run(tmp_path, served, "--action-type", "switch", "--duration", "20")
    try:
        deadline = time.monotonic() + 30
        while not any(vehcalls_applied(served)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert any(vehcalls_applied(served)), "the run commands the controller"
        served.proc.kill()  # the controller is gone, mid-run
        served.proc.wait(timeout=10)
        killed = time.monotonic()
        # The TIMEOUT line comes while the run goes on (--no-progress, no status line), not with the summary.
        line = proc.stderr.readline()
        while line and "TIMEOUT at" not in line:
            line = proc.stderr.readline()
        assert "TIMEOUT at" in line and "(communication)" in line
        assert proc.poll() is None and time.monotonic() - killed < 10
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 3, err
    ending = last_line(err)
    assert "the controller was lost" in ending and "ended in TIMEOUT" in ending and "calls NOT cleared" in ending
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["timeout_at_end"]["reason"] == "communication" and summary["calls_cleared"] is False
    # The timeline hatches the outage as no data, from the first unanswered poll to the end, on every row.
    records = list(read(run / "events.jsonl"))
    lost_at = next(r["t"] for r in records if r["kind"] == "poll_failed" and r["consecutive"] >= 1)
    end = records[-1]["t"]
    svg = ElementTree.parse(run / "signal_timeline.svg").getroot()
    axis = next(r for r in svg.iter(f"{SVG}rect") if r.get("fill") == "none")
    left, width = float(axis.get("x")), float(axis.get("width"))
    hatched = [r for r in svg.iter(f"{SVG}rect") if r.get("fill") == "url(#no-data)"]
    assert len(hatched) == 8
    for r in hatched:
        assert float(r.get("x")) == pytest.approx(left + lost_at / end * width, abs=0.01)
        assert float(r.get("x")) + float(r.get("width")) == pytest.approx(left + width, abs=0.01)
    assert "no data" in [t.text for t in svg.iter(f"{SVG}text")]
    assert svg.find(f"{SVG}defs/{SVG}pattern[@id='no-data']") is not None


# --- agents -------------------------------------------------------------------------------------------------------

AGENTS = """
from hils import ActionType


class Unready:
    action_type = ActionType.SELECTION

    def __init__(self, config, action_type, seed):
        raise RuntimeError("my model file is missing")

    def act(self, obs):
        return (2, 6)


class Quitter:
    action_type = ActionType.SELECTION

    def __init__(self, config, action_type, seed):
        self.n = 0

    def act(self, obs):
        self.n += 1
        if self.n > 2:
            raise SystemExit(3)
        return (4, 8) if self.n % 2 else (2, 6)


class Conflicted:
    action_type = ActionType.SELECTION

    def __init__(self, config, action_type, seed):
        pass

    def act(self, obs):
        return (2, 5)
"""


@pytest.fixture
def agents(tmp_path: Path, monkeypatch) -> Path:
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "hostile_agents.py").write_text(AGENTS)
    yield tmp_path
    sys.modules.pop("hostile_agents", None)


def run_agent(tmp_path: Path, agent: str, *args: str) -> int:
    return main(["run", "--no-sumo", "--duration", "60", "--no-progress", "--out", str(tmp_path / "run"),
                 "--agent", agent, *args])


def test_an_agent_whose_constructor_raises_is_named_with_its_own_error(agents: Path, capsys) -> None:
    assert run_agent(agents, "hostile_agents:Unready") == 1
    err = capsys.readouterr().err
    assert last_line(err) == ("hils run: the run did not start: agent 'hostile_agents:Unready' could not start: its "
                              "constructor raised RuntimeError: my model file is missing; use -v for a traceback")
    assert "zip()" not in err


def test_an_agent_raising_system_exit_ends_the_run_as_an_agent_error(agents: Path, capsys) -> None:
    assert run_agent(agents, "hostile_agents:Quitter") == 1
    captured = capsys.readouterr()
    assert "the agent failed: the agent's act() raised SystemExit: 3" in last_line(captured.err)
    assert "calls cleared" in captured.err and "Run summary" in captured.out
    records = list(read(agents / "run" / "events.jsonl"))
    assert records[-1]["kind"] == "run_ended" and records[-1]["reason"] == "agent_error"
    assert [r["phases"] for r in records if r["kind"] == "set_sent"][-1] == []


def test_an_agent_whose_every_action_is_refused_hears_why(agents: Path, capsys, caplog) -> None:
    with caplog.at_level("WARNING", logger="hils.run"):
        assert run_agent(agents, "hostile_agents:Conflicted") == 0
    out = capsys.readouterr().out
    reason = "pair [2, 5] is not in the configured set of pairs"
    live = [r.getMessage() for r in caplog.records if r.name == "hils.run"]
    assert len(live) == 1 and "action 1 refused at 0.0 s (NotInActionSetError)" in live[0] and reason in live[0]
    assert re.search(r"first refused +at 0\.0 s, action 1: NotInActionSetError: " + re.escape(reason), out)
    assert "WARNING: every action of the agent was refused (6 of 6)" in out


def test_a_built_in_agent_asked_for_another_action_type_says_which_it_issues(capsys) -> None:
    assert main(["run", "--no-sumo", "--agent", "max-pressure", "--action-type", "duration"]) == 2
    err = capsys.readouterr().err
    assert err == ("hils: the max-pressure agent issues phase selection actions only (--action-type selection), "
                   "not duration\n")


def test_the_run_help_documents_the_exit_statuses(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    for status in ("0 ", "1 ", "2 ", "3 ", "130", "143"):
        assert f"\n  {status}" in text, status
    assert "a controller was lost" in text



# --- the console ---------------------------------------------------------------------------------------------------


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_timeout_line_goes_above_the_status_line_which_is_drawn_again_under_it(monkeypatch) -> None:
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    console = logging.StreamHandler(sys.stderr)  # what logging.basicConfig gives `hils`
    root = logging.getLogger()
    root.addHandler(console)
    status, notices = StatusLine(stream=terminal), Notices()

    def on_reset(tb: Testbed) -> None:
        status.start(tb)
        tb.events.subscribe(notices)

    try:
        with Testbed(action_type="switch", agent="fixed-cycle", on_reset=on_reset) as tb, status.above():
            tb.reset()
            tb.run_for(2.0)
            tb.events.emit(Kind.TIMEOUT_ENTERED, reason="communication", detail="5 consecutive polls failed",
                           command_id=None)
            tb.run_for(1.0)
    finally:
        root.removeHandler(console)
    status.close()
    lines = terminal.getvalue().split("\n")
    said = next(i for i, line in enumerate(lines) if "TIMEOUT at 2.0 s (communication)" in line)
    # On its own line: the status line was erased first, and is drawn again under it.
    assert lines[said].rsplit("\r", 1)[1].startswith("TIMEOUT at 2.0 s (communication): 5 consecutive polls failed")
    assert lines[said + 1].startswith("\r") and " s  " in lines[said + 1]
