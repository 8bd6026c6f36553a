"""A controller config written from a controller's own hi-res log: on a log whose config is known (the emulator's),
and on the atspm package's real field log, whose plan the log's own events show."""

from __future__ import annotations

import itertools
import random
import subprocess
import sys
from collections import Counter
from datetime import datetime
from pathlib import Path

import atspm
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from harness.reference import field_log, hires_file
from harness.reference.hires_file import FieldLogError, Row
from harness.reference.replay_bench import nema_numbers, synthetic
from hils.protocol import config as config_mod
from hils.protocol.ntcip import PhaseStartup
from tests.emulator.model.test_hires import config_with

SAMPLE = Path(atspm.__file__).parent / "data" / "sample_raw_data.parquet"


def test_the_emulators_own_log_gives_back_its_config() -> None:
    """Passage 2 s, minimum 3 s, yellow 3 s, red clearance 2 s, walk 4 s and pedestrian clearance 5 s on the
    throughs, detector n calling phase n, push buttons on 2, 4, 6 and 8: read back from twenty minutes of log."""
    cfg = config_with()
    c = Controller(cfg, start=datetime(2024, 5, 1, 8))
    log = DataLogger(c)
    rng = random.Random(5)
    on: set[int] = set()
    for k in range(12_000):
        on = {d for d in cfg.detectors if (d in on and rng.random() > 0.1) or (d not in on and rng.random() < 0.01)}
        c.set_actuations(on)
        c.set_ped_actuations({p for p in (2, 4, 6, 8) if k % 600 == 37 * p})
        c.step()
    inferred = field_log.infer([Row(e.time, e.code, e.parameter) for e in log.events()], "own")
    got = inferred.config()
    assert got.rings == cfg.rings and [sorted(b) for b in got.barriers] == [sorted(b) for b in cfg.barriers]
    for p in cfg.phases:
        mine = got.phases[p]
        assert (mine.yellow, mine.red_clear, mine.min_green, mine.passage) == (3.0, 2.0, 3.0, 2.0), p
        if p % 2 == 0:
            assert (mine.walk, mine.ped_clear) == (4.0, 5.0), p
    assert got.detectors == cfg.detectors and got.ped_detectors == {2: 2, 4: 4, 6: 6, 8: 8}
    assert got.coordination.pattern == "free" or not got.coordination.patterns
    assert got.emulator.start == datetime(2024, 5, 1, 8)


def test_the_field_logs_plan_is_read_from_its_events() -> None:
    inferred = field_log.infer(hires_file.load(SAMPLE), "atspm sample 1136")
    cfg = inferred.config()
    assert cfg.rings == ((2, 4), (6, 5, 8))  # 5 lags 6; ring 1 has no phase of its own beside 8
    plan = cfg.coordination.patterns[1]
    # The local zeros (150/5) are 75 s apart at 45 s of the time of day modulo 75; 6 and 5 are forced off 24.5 s
    # and 43.5 s after it and 8 ends with the cycle, each split ending its clearance (4 s + 1.5 s) later.
    assert (plan.cycle, plan.offset, tuple(plan.coord_phases)) == (75, 45, (2, 6))
    assert dict(plan.splits) == {2: 49, 4: 26, 5: 19, 6: 30, 8: 26}
    assert all((ph.yellow, ph.red_clear) == (4.0, 1.5) for ph in cfg.phases.values())
    assert {p: cfg.phases[p].min_green for p in (2, 5, 6, 8)} == {2: 10, 5: 4, 6: 10, 8: 6}
    assert (cfg.phases[6].walk, cfg.phases[6].ped_clear) == (8, 26)
    calls = {d: p for d, p in cfg.detectors.items() if p}
    assert calls == {2: 2, 8: 8, 9: 8, 15: 5, 16: 6, 17: 6, 18: 6, 22: 8, 23: 8, 24: 8, 25: 8, 26: 8, 27: 5}
    assert cfg.ped_detectors == {6: 6}
    assert [o.included for o in cfg.overlaps.values()] == [(6,)]
    said = " ".join(inferred.guessed)
    assert "phase 4: not in the log" in said and "overlap E (5): not modelled" in said


def test_a_log_that_cannot_make_a_config_is_refused(tmp_path: Path) -> None:
    with pytest.raises(FieldLogError, match="at least two"):
        field_log.infer([Row(datetime(2024, 1, 1), 82, 3)])
    two = tmp_path / "two.parquet"
    frame = pd.read_parquet(SAMPLE).head(100)
    pd.concat([frame, frame.assign(DeviceId=7)]).to_parquet(two)
    with pytest.raises(FieldLogError, match=r"holds 2 controllers: 1136 \(100 rows\), 7 \(100 rows\); pick one: "
                                            "--device 1136, 7"):
        hires_file.load(two)
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(FieldLogError, match=r"no column EventId, Parameter, TimeStamp; allowed: the ATSPM layout"):
        hires_file.load(bad)
    bad = tmp_path / "bad.parquet"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(FieldLogError, match=r"cannot be read as an ATSPM log.*TimeStamp, DeviceId, EventId, Parameter"):
        hires_file.load(bad)


def test_hils_replay_infer_only_from_another_folder(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "hils", "replay", str(SAMPLE), "--infer-only", "--out", "out"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "Read from the log:" in done.stdout and "Guessed:" in done.stdout
    assert (tmp_path / "out" / "inferred.toml").exists()
    wrong = subprocess.run([sys.executable, "-m", "hils", "replay", "nothing.parquet", "--infer-only"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert wrong.returncode == 2 and "nothing.parquet" in wrong.stderr and "Traceback" not in wrong.stderr


def test_the_emulators_pretimed_log_gives_a_config_the_validator_takes() -> None:
    """`hils run --agent fixed-time`'s controller: the shipped four-leg's plan on max recall. Its pretimed greens
    never overlap across the ring (phase 3 ends its green before 8 begins), so greens alone split the intersection
    into four barrier groups whose splits cannot meet; the phases' time on (to the end of red clearance) gives back
    its two, and the split change events its plan."""
    cfg = config_mod.load().pretimed()
    c = Controller(cfg, start=datetime(2024, 5, 1, 8))
    log = DataLogger(c)
    for _ in range(6000):
        c.step()
    got = field_log.infer([Row(e.time, e.code, e.parameter) for e in log.events()], "pretimed").config()
    assert got.rings == cfg.rings and sorted(map(sorted, got.barriers)) == sorted(map(sorted, cfg.barriers))
    plan, mine = cfg.coordination.patterns[1], got.coordination.patterns[1]
    assert (mine.cycle, mine.offset, mine.coord_phases) == (plan.cycle, plan.offset, plan.coord_phases)
    assert dict(mine.splits) == dict(plan.splits)  # as the controller logged them (split change, 134-141)
    assert {p for p, ph in got.phases.items() if ph.startup is not PhaseStartup.PHASE_NOT_ON} == {2, 6}


def test_a_ring_of_sixteen_phases_is_ordered() -> None:
    """Sixteen phases a ring in one barrier group: the search over every order took 56 s at 11 and grew as n!."""
    got = field_log.infer(hires_file_rows(synthetic(16)), "sixteen").config()
    assert got.rings == (tuple(nema_numbers(1, 16)), tuple(nema_numbers(2, 16)))


def hires_file_rows(frame: pd.DataFrame) -> list[Row]:
    return [Row(t.to_pydatetime(), int(c), int(p)) for t, c, p in zip(frame.TimeStamp, frame.EventId,
                                                                         frame.Parameter, strict=True)]


@st.composite
def served(draw: st.DrawFn) -> tuple[list[int], list[list[int]]]:
    """A ring's sequence in one barrier group, and the phases each cycle served: the called ones, in order."""
    sequence = draw(st.lists(st.integers(1, 40), min_size=2, max_size=12, unique=True))
    cycles = draw(st.lists(st.lists(st.booleans(), min_size=len(sequence), max_size=len(sequence)), min_size=1,
                           max_size=30))
    return sequence, [[p for p, called in zip(sequence, calls, strict=True) if called] for calls in cycles]


@settings(max_examples=200, deadline=None)
@given(served())
def test_the_service_order_is_the_sequence_the_log_shows(case: tuple[list[int], list[list[int]]]) -> None:
    """NTCIP 1202 sequenceData: a ring serves its called phases in the sequence's order. Every succession the log
    shows then points forward in the inferred order, and when each phase was seen right after the one before it, the
    order is the sequence (where the search over every order could take a skip seen often for the sequence)."""
    sequence, cycles = case
    follows = Counter(pair for served in cycles for pair in itertools.pairwise(served))
    order = field_log._service_order(sorted(sequence), follows)
    assert sorted(order) == sorted(sequence)
    assert all(order.index(a) < order.index(b) for a, b in follows)
    if all(follows[pair] for pair in itertools.pairwise(sequence)):
        assert order == sequence


def test_a_skip_seen_more_often_than_the_sequence_does_not_reorder_it() -> None:
    """2 served in one cycle of ten: 1 -> 3 nine times, 1 -> 2 -> 3 once. The order is 1 2 3, not 1 3 2 (which
    the search over every order chose: its adjacent pairs, 1-3, were seen nine times)."""
    assert field_log._service_order([1, 2, 3], Counter({(1, 3): 9, (1, 2): 1, (2, 3): 1})) == [1, 2, 3]


def test_a_ring_that_backs_or_comes_round_is_cut_where_it_was_seen_least() -> None:
    assert field_log._service_order([1, 2], Counter({(1, 2): 50, (2, 1): 3})) == [1, 2]  # 2 backed into 1
    cycle = Counter({(1, 2): 10, (2, 3): 10, (3, 4): 10, (4, 1): 10})  # one group, nothing across the barrier
    assert field_log._service_order([1, 2, 3, 4], cycle) == [1, 2, 3, 4]
    assert field_log._service_order([1, 2, 3, 4], cycle | {(1, 2): 9}) == [2, 3, 4, 1]
