"""Real controllers' logs in their vendors' own forms (Econolite .dat/.datZ, MaxTime asclog XML), read strictly:
their events, or one line naming the file, the position, the field and what is allowed (tests/harness/reference/
field_logs/NOTICE.md says where the files come from)."""

from __future__ import annotations

import zlib
from collections import Counter
from datetime import datetime
from pathlib import Path

import pytest

from harness.reference import econolite_dat, field_log, hires_file, maxtime_xml
from harness.reference.hires_file import FieldLogError, Row
from hils.protocol.hires import EventCode

E = EventCode
LOGS = Path(__file__).parent / "field_logs"
FREE = LOGS / "4895_ECON_10.210.8.179_2024_02_21_1115.dat"
MAXTIME = LOGS / "maxtime_1015_2024_07_22_1333_excerpt.xml"


def test_an_econolite_dat_is_read_record_by_record() -> None:
    rows = econolite_dat.read(FREE)
    # The file's first record, bytes 51 1D 00 0A: detector 29 off, 1.0 s after the header's 2-21-2024 11:15:00.0.
    assert Row(datetime(2024, 2, 21, 11, 15, 1), E.DETECTOR_OFF, 29) in rows[:5]
    assert len(rows) == (FREE.stat().st_size - 366) // 4 == 1914
    assert rows == sorted(rows, key=lambda r: (r.time, r.code, r.parameter))
    assert {r.code for r in rows} >= {E.PHASE_BEGIN_GREEN, E.PHASE_GAP_OUT, E.DETECTOR_ON, E.PED_DETECTOR_ON}


def test_a_compressed_datz_is_inflated() -> None:
    rows = econolite_dat.read(LOGS / "1210_ECON_10.204.7.239_2021_08_09_1841.datZ")
    assert len(rows) == 275 and rows[0].time.date() == datetime(2021, 8, 9).date()


def test_hils_reads_each_form_by_its_suffix() -> None:
    assert hires_file.load(FREE) == econolite_dat.read(FREE)
    assert hires_file.load(MAXTIME) == maxtime_xml.read(MAXTIME)
    start = datetime(2024, 2, 21, 11, 20)
    assert all(r.time >= start for r in hires_file.load(FREE, start=start))


def test_a_maxtime_asclog_is_read() -> None:
    rows = maxtime_xml.read(MAXTIME)
    assert len(rows) == 1200
    assert rows[0] == Row(datetime(2024, 7, 22, 13, 33, 19, 300000), E.PHASE_GAP_OUT, 1)
    # its MaxTime-only events (300s, 600s) are kept as they are
    assert Counter(r.code for r in rows)[E.PHASE_BEGIN_GREEN] > 30 and any(r.code >= 300 for r in rows)


def _broken(tmp_path: Path, body: bytes, name: str = "bad.dat") -> str:
    path = tmp_path / name
    path.write_bytes(body)
    with pytest.raises(FieldLogError) as caught:
        hires_file.load(path)
    text = str(caught.value)
    assert "\n" not in text and str(path) in text
    return text


def test_a_broken_dat_is_refused_by_byte(tmp_path: Path) -> None:
    good = FREE.read_bytes()
    assert "byte 8022: record cut short (2 of 4 bytes)" in _broken(tmp_path, good + b"\x01\x02")
    assert "byte 0: start time" in _broken(tmp_path, b"Version 3\n" + good[100:])
    assert "the header ends after 2 line(s)" in _broken(tmp_path, good[:good.index(b"\n", 40) + 1])
    assert "byte 2: the compressed body does not inflate" in _broken(tmp_path, b"\x78\x9c not deflate", "bad.datZ")
    squeezed = zlib.compress(good)
    assert econolite_dat.decode(zlib.decompress(squeezed)) == econolite_dat.read(FREE)


def test_a_broken_asclog_is_refused_by_event(tmp_path: Path) -> None:
    body = MAXTIME.read_bytes().replace(b'EventTypeID="4" Parameter="1"', b'EventTypeID="four" Parameter="1"', 1)
    assert "event 1 " in _broken(tmp_path, body, "bad.xml")
    assert "not an event log" in _broken(tmp_path, b"<html>no</html>", "page.xml")


def test_each_vendor_log_gets_a_config_the_emulator_takes_or_one_line() -> None:
    outcomes = {}
    for path in [*sorted(LOGS.glob("*.dat*")), MAXTIME]:
        try:
            field_log.infer(hires_file.load(path)).config()
            outcomes[path.name] = "config"
        except FieldLogError as exc:
            assert "\n" not in str(exc)
            outcomes[path.name] = str(exc)
    assert all(v == "config" for v in outcomes.values()), outcomes
