"""A broken hi-res log gets one line saying where and why, never a traceback or a hang: each kind of cell the issue
found crashing `hils replay --infer-only`, and a fuzzer that changes one field of a real log at random."""

from __future__ import annotations

import functools
import re
import subprocess
import sys
import tempfile
from datetime import datetime, timedelta
from pathlib import Path

import atspm
import pandas as pd
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from harness.reference import field_log, hires_file
from harness.reference.hires_file import FieldLogError
from hils.protocol import config as config_mod
from hils.protocol.hires import EventCode

SAMPLE = Path(atspm.__file__).parent / "data" / "sample_raw_data.parquet"
E = EventCode


@functools.cache
def bases() -> dict[str, pd.DataFrame]:
    """Twenty minutes of the atspm package's field log and ten of the emulator's pretimed log, as CSV text."""
    field = pd.read_parquet(SAMPLE)
    field = field[field.TimeStamp < field.TimeStamp.iloc[0] + pd.Timedelta(minutes=20)]
    c = Controller(config_mod.load().pretimed(), start=datetime(2024, 5, 1, 8))
    log = DataLogger(c)
    for _ in range(6000):
        c.step()
    own = pd.DataFrame([(e.time, 1, int(e.code), e.parameter) for e in log.events()],
                       columns=["TimeStamp", "DeviceId", "EventId", "Parameter"])
    out = {}
    for name, frame in (("field", field), ("emulator", own)):
        text = frame.astype(str).reset_index(drop=True)
        text["TimeStamp"] = [t.isoformat(sep=" ", timespec="milliseconds") for t in frame.TimeStamp]
        out[name] = text
    return out


def changed(base: str, code: int, column: str, value: str, nth: int = 3) -> pd.DataFrame:
    frame = bases()[base].copy()
    frame.loc[frame.index[frame.EventId == str(code)][nth], column] = value
    return frame


def outcome(frame: pd.DataFrame, folder: Path) -> str:
    """The config inferred from ``frame`` written as CSV (validated), or the refusal's one line."""
    path = folder / "log.csv"
    frame.to_csv(path, index=False)
    try:
        field_log.infer(hires_file.load(path)).config()
    except FieldLogError as exc:
        return str(exc)
    return "config"


@pytest.mark.parametrize(("base", "code", "column", "value", "said"), [
    ("field", E.PHASE_BEGIN_GREEN, "EventId", "", r"line \d+: EventId '' is not a whole number from 0 to "),
    ("emulator", E.PHASE_BEGIN_GREEN, "EventId", "x", r"line \d+: EventId 'x' is not a whole number"),
    ("field", E.PHASE_BEGIN_GREEN, "Parameter", "2.5", r"line \d+: Parameter '2.5' is not a whole number"),
    ("field", E.PHASE_BEGIN_GREEN, "TimeStamp", "not a time", r"line \d+: TimeStamp 'not a time' is not the "
                                                              r"controller's local time, e.g. 2024-04-15 12:00:00.1"),
    ("emulator", E.PHASE_BEGIN_GREEN, "TimeStamp", "2024-02-30 12:00:00", r"TimeStamp '2024-02-30 12:00:00' is not"),
    ("emulator", E.PHASE_BEGIN_GREEN, "TimeStamp", "2024-05-01T08:00:00+02:00", r"is not the controller's local time"),
    ("field", E.PHASE_BEGIN_GREEN, "TimeStamp", "9999-12-31 23:59:59.9", r"between 1678 and 2261"),
    ("field", E.PHASE_BEGIN_GREEN, "DeviceId", "", r"line \d+: DeviceId '' is not a controller's id"),
    ("field", E.OVERLAP_BEGIN_GREEN, "Parameter", "0",
     r"event 61 \(overlap begin green\), parameter 0, at 2024-04-15 12:[0-9:.]+: 0 is not an overlap number; "
     r"allowed: 1"),
    ("field", E.DETECTOR_ON, "Parameter", "0", r"event 82 \(detector on\), parameter 0, .*not a detector number"),
    ("emulator", E.PHASE_BEGIN_YELLOW, "Parameter", "300", r"event 8 \(phase begin yellow\), parameter 300, .*"
                                                           r"allowed: 1-255"),
])
def test_a_cell_the_log_cannot_hold_is_refused_by_line_or_event(tmp_path: Path, base: str, code: int, column: str,
                                                                value: str, said: str) -> None:
    got = outcome(changed(base, code, column, value), tmp_path)
    assert "\n" not in got
    assert re.search(said, got), got
    if "line" in said:
        assert got.startswith(str(tmp_path / "log.csv") + ": line ")


def test_a_null_in_a_parquet_column_names_its_row(tmp_path: Path) -> None:
    frame = pd.read_parquet(SAMPLE).head(500).astype({"EventId": "Int64"})
    frame.loc[7, "EventId"] = None
    frame.to_parquet(tmp_path / "log.parquet")
    with pytest.raises(FieldLogError, match=r"log.parquet: row 8: EventId <NA> is not a whole number"):
        hires_file.load(tmp_path / "log.parquet")
    frame = pd.read_parquet(SAMPLE).head(500)
    frame["TimeStamp"] = frame.TimeStamp.dt.tz_localize("Europe/Berlin")
    frame.to_parquet(tmp_path / "log.parquet")
    with pytest.raises(FieldLogError, match=r"row 1: TimeStamp .* is not the controller's local time"):
        hires_file.load(tmp_path / "log.parquet")


def test_two_local_zeros_at_one_time_are_one(tmp_path: Path) -> None:
    frame = bases()["field"]
    zeros = frame.index[(frame.EventId == "150") & (frame.Parameter == "5")]
    twice = pd.concat([frame, frame.loc[zeros]]).sort_index(kind="stable")
    assert outcome(twice, tmp_path) == "config"


def test_local_zeros_that_make_no_cycle_are_refused(tmp_path: Path) -> None:
    frame = bases()["emulator"]
    zeros = frame.index[(frame.EventId == "150") & (frame.Parameter == "5")]
    soon = frame.copy()
    for k, i in enumerate(zeros):  # every local zero 0.1 s after the one before
        soon.loc[i, "TimeStamp"] = (datetime(2024, 5, 1, 8, 1) + timedelta(seconds=k / 10)).isoformat(sep=" ")
    got = outcome(soon, tmp_path)
    assert got.startswith("local zeros (event 150, parameter 5) at 2024-05-01 08:01:00.0 and 2024-05-01 08:01:00.1: "
                          "0.1 s apart, as most are, a cycle of 0 s; allowed: 30-255 s"), got


def test_a_log_with_no_phase_number_left_is_refused(tmp_path: Path) -> None:
    """255 phases that never run together: each is a barrier group of its own, and the other ring's place beside it
    needs a number nothing uses."""
    rows = []
    for k in range(2 * 255):
        p, t0 = k % 255 + 1, datetime(2024, 1, 1) + timedelta(seconds=15 * k)
        rows += [(t0, 1, p), (t0 + timedelta(seconds=10), 8, p), (t0 + timedelta(seconds=13), 9, p)]
    frame = pd.DataFrame(rows, columns=["TimeStamp", "EventId", "Parameter"]).assign(DeviceId=1)
    got = outcome(frame.astype(str), tmp_path)
    assert got.startswith("the log's phases use every phase number 1-255: none is left for ring 1 beside phase 5"), got


def test_hils_replay_refuses_a_broken_log_in_one_line(tmp_path: Path) -> None:
    changed("field", E.PHASE_BEGIN_GREEN, "EventId", "").to_csv(tmp_path / "broken.csv", index=False)
    done = subprocess.run([sys.executable, "-m", "hils", "replay", "broken.csv", "--infer-only", "--out", "out"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith("hils: broken.csv: line ") and done.stderr.count("\n") == 1, done.stderr


@st.composite
def one_field_changed(draw: st.DrawFn) -> tuple[str, int, str, str]:
    """A base log, a row, a column and a value: garbage, a number near what the column holds, or (TimeStamp) the
    row's own time moved."""
    base = draw(st.sampled_from(["field", "emulator"]))
    row = draw(st.integers(0, len(bases()[base]) - 1))
    column = draw(st.sampled_from(["TimeStamp", "DeviceId", "EventId", "Parameter"]))
    garbage = st.sampled_from(["", " ", "x", "-1", "1.5", "NaN", "1e3", "99999999999", "0x10", "None", "12:00:00",
                               "2024-02-30 12:00:00", "2024-04-15T12:00:00+02:00", "9999-12-31 23:59:59.9"])
    if column == "TimeStamp":
        moved = st.floats(-3600, 3600).map(
            lambda s: (pd.Timestamp(bases()[base].TimeStamp[row]) + pd.Timedelta(seconds=round(s, 1))).isoformat(
                sep=" ", timespec="milliseconds"))
        value = draw(st.one_of(garbage, moved))
    elif column == "EventId":
        value = draw(st.one_of(garbage, st.sampled_from([str(int(c)) for c in E]), st.integers(0, 600).map(str)))
    else:
        value = draw(st.one_of(garbage, st.integers(-3, 300).map(str), st.text(max_size=6)))
    return base, row, column, value


@settings(max_examples=40, deadline=timedelta(seconds=20), suppress_health_check=[HealthCheck.too_slow])
@given(one_field_changed())
@example(("field", 0, "DeviceId", "0\n0"))  # found by it: a DeviceId with a line break broke the refusal's line
def test_a_log_with_one_field_changed_gives_a_config_or_a_one_line_refusal(change: tuple[str, int, str, str]) -> None:
    """Whatever one cell of a real log says, the validator takes the config inferred from it, or the reader or the
    inference refuses the log in one line naming the line or the event (a hang shows as the deadline)."""
    base, row, column, value = change
    frame = bases()[base].copy()
    frame.loc[row, column] = value
    with tempfile.TemporaryDirectory() as folder:
        got = outcome(frame, Path(folder))
        refused = got.startswith((folder, "event ", "local zeros", "the log"))
        assert got == "config" or ("\n" not in got and refused), got
