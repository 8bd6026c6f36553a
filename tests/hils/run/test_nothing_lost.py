"""Nothing the controllers logged is lost: a run killed with SIGKILL keeps its hi-res events, and a full disk costs
the file it fills, never summary.json.

- `hils run` in its own process, killed with SIGKILL mid-run: its hi-res journal (``hires.journal.csv``) holds
  every event the controller logged up to the kill, exactly as the same seed's run logs them in full.
- A full disk injected as the OS reports one (``write(2)`` failing with ENOSPC) for the largest file, or for
  everything from it on: summary.json is there, names the file and the reason, and the other files are written.
"""

from __future__ import annotations

import csv
import errno
import json
import os
import signal
import subprocess
import sys
import time
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from hils.cli.main import main
from hils.protocol.hires import Event
from hils.run.testbed import Testbed
from hils.shell.events import read
from hils.shell.hiresjournal import HiresJournal
from tests.hils.run.test_exits import _Filling


def journal_rows(path: Path) -> list[tuple[datetime, int, int, int]]:
    """The rows of a hi-res journal, as any CSV reader reads the ATSPM layout."""
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["TimeStamp", "DeviceId", "EventId", "Parameter"]
    return [(datetime.fromisoformat(t), int(d), int(c), int(p)) for t, d, c, p in rows[1:]]


def test_a_run_killed_with_sigkill_keeps_every_hi_res_event_logged_before_the_kill(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--duration", "360000",
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path)
    journal = out / "hires.journal.csv"
    deadline = time.monotonic() + 180  # a loaded machine: the run is a few seconds in, alone
    try:
        while not (journal.exists() and journal.stat().st_size > 150_000):  # about 40 simulated minutes in
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the run wrote no hi-res journal"
            time.sleep(0.05)
        time.sleep(0.3)
    finally:
        proc.kill()  # SIGKILL: no handler runs, nothing is flushed
        proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "summary.json").exists() and not (out / "hires.parquet").exists(), "killed before its end"
    kept = journal_rows(journal)
    last_t = list(read(out / "events.jsonl"))[-1]["t"]  # where the run was when it was killed (written through)
    # The same seed's run, to past the kill, is what the controller logged.
    with Testbed(duration=last_t + 60) as tb:
        tb.reset()
        tb.run()
        (logged,) = tb.hires().values()
    assert kept == [(e.time, 1, e.code, e.parameter) for e in logged[:len(kept)]], "the journal is the log, whole"
    # Every event logged up to a simulated second before the run's last record is on disk (the controller powered
    # up at the run's start, within a tick).
    start = logged[0].time
    lost = [e for e in logged[len(kept):] if e.time <= start + timedelta(seconds=last_t - 1.0)]
    assert not lost, f"{len(lost)} events logged before the kill are not in the journal: {lost[:3]}"
    assert len(kept) > 3000 and last_t > 1800


def _full_disk(monkeypatch: pytest.MonkeyPatch, *, from_name: str, everything_after: bool) -> list[str]:
    """``write(2)`` fails with ENOSPC, as on a full disk, for the file named ``from_name`` (its part written beside it)
    and, with ``everything_after``, for every file written after it. Returns the names it refused."""
    real = os.write
    refused: list[str] = []

    def write(fd: int, data: bytes) -> int:
        name = Path(os.readlink(f"/proc/self/fd/{fd}")).name
        if name == f".{from_name}.part" or (everything_after and refused):
            refused.append(name)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data)

    monkeypatch.setattr(os, "write", write)
    return refused


def _run(out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, dict]:
    """`hils run` of five simulated minutes of the controller's pretimed plan in ``out`` (a split monitor among its
    pictures): its exit status, its last line and its summary.json."""
    code = main(["run", "--no-sumo", "--agent", "fixed-time", "--no-progress", "--duration", "300", "--out", str(out)])
    return code, capsys.readouterr().err.splitlines()[-1], json.loads((out / "summary.json").read_text())


def test_a_full_disk_costs_the_hi_res_file_alone_and_summary_json_names_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    refused = _full_disk(monkeypatch, from_name="hires.parquet", everything_after=False)
    out = tmp_path / "run"
    code, last, s = _run(out, capsys)
    assert refused and code == 1 and "not written: hires.parquet: No space left on device" in last
    assert s["outputs"]["failed"] == {"hires.parquet": "No space left on device"} and s["outputs"]["finished"]
    for name in ("events.jsonl", "signal_timeline.svg", "atspm.csv", "split_monitor.svg"):
        assert name in s["outputs"]["written"] and (out / name).stat().st_size > 0, name
    # The journal, whole, stands in for the file that could not be written.
    record = s["record"]
    assert record["file"] == "hires.journal.csv" and "hires.parquet could not be written" in record["format_note"]
    assert not (out / "hires.parquet").exists() and not list(out.glob(".*.part"))
    assert len(journal_rows(out / "hires.journal.csv")) == record["events"]["1"] > 0


def test_a_disk_that_fills_with_the_hi_res_file_still_leaves_summary_json(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The largest file comes last: summary.json and the pictures are in before the disk fills."""
    refused = _full_disk(monkeypatch, from_name="hires.parquet", everything_after=True)
    out = tmp_path / "run"
    code, last, s = _run(out, capsys)  # summary.json written first, and whole
    assert code == 1 and refused == [".hires.parquet.part", ".summary.json.part"]
    assert "hires.parquet: No space left on device" in last
    assert s["outputs"] == {"written": ["events.jsonl", "hires.journal.csv", "summary.json"], "failed": {},
                            "finished": False}
    assert s["config"] and s["polls"]["polls"] > 0
    for name in ("signal_timeline.svg", "atspm.csv", "split_monitor.svg"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "hires.journal.csv").stat().st_size > 0, "the hi-res log stays in the journal"


def test_a_journal_the_disk_cannot_take_keeps_whole_rows_and_says_why(tmp_path: Path) -> None:
    journal = HiresJournal(tmp_path / "hires.journal.csv")
    one = journal.device(1)
    tick = [Event(datetime(2024, 1, 1, 0, 0, 0, 100_000), 1, 2), Event(datetime(2024, 1, 1, 0, 0, 0, 100_000), 1, 6)]
    one(tick)
    journal._file._file = _Filling(journal._file._file, 40)  # room for less than the next tick
    one(tick)
    one(tick)  # the journal has stopped: nothing more is written, nothing raised
    journal.close()
    assert journal_rows(journal.path) == [(e.time, 1, e.code, e.parameter) for e in tick]
    assert journal.failure == "No space left on device (it keeps its first 2 events, whole)"


def _journal_fills(monkeypatch: pytest.MonkeyPatch, *, room: int, and_the_record: bool) -> None:
    """The hi-res journal's disk fills after ``room`` bytes (as a full disk does: a short write, then ENOSPC); with
    ``and_the_record``, ``hires.parquet`` cannot be written either."""
    opened = HiresJournal.__init__

    def filling(journal: HiresJournal, path: Path) -> None:
        opened(journal, path)
        journal._file._file = _Filling(journal._file._file, room)

    monkeypatch.setattr(HiresJournal, "__init__", filling)
    if and_the_record:
        _full_disk(monkeypatch, from_name="hires.parquet", everything_after=False)


def test_a_journal_that_stopped_is_removed_once_the_record_is_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _journal_fills(monkeypatch, room=4000, and_the_record=False)
    out = tmp_path / "run"
    assert main(["run", "--no-sumo", "--agent", "fixed-time", "--no-progress", "--duration", "300", "--out",
                 str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["record"]["file"] == "hires.parquet" and s["outputs"]["failed"] == {}
    assert not (out / "hires.journal.csv").exists() and "hires.journal.csv" not in s["outputs"]["written"]


def test_a_journal_that_stopped_stays_and_is_named_when_the_record_cannot_be_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _journal_fills(monkeypatch, room=4000, and_the_record=True)
    out = tmp_path / "run"
    code, last, s = _run(out, capsys)
    assert code == 1 and "hires.parquet: No space left on device" in last
    record = s["record"]
    assert "file" not in record and "the journal stopped: No space left on device" in record["format_note"]
    assert "hires.journal.csv keeps those" in record["format_note"]
    assert "hires.journal.csv" in s["outputs"]["written"]
    kept = journal_rows(out / "hires.journal.csv")
    assert 0 < len(kept) < record["events"]["1"], "its first events, whole"
