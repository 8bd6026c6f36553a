"""The emulator as a Signal-Replay bench: Signal-Replay itself (the PyPI package, unmodified) replays a hi-res log's
detector and push-button inputs into `hils emulator serve` over NTCIP, collects the emulator's events from its
MaxTime endpoint and scores them against the log's.

Two logs: one the emulator wrote itself, replayed into a fresh emulator with the same config (the emulator is
deterministic and its log complete: the match must be 100 %, and the two logs the same event for event); and a
short window of the atspm package's real field log, replayed into the config harness.reference.field_log writes from
that
log (the match is what it is: docs/replay.md gives the whole two hours).
"""

from __future__ import annotations

import random
from datetime import datetime, timedelta
from pathlib import Path

import atspm
import pytest

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from harness.reference import field_log, hires_file
from harness.reference.hires_file import Row
from harness.reference.replay import replay
from harness.reference.replay_match import match_table
from hils.protocol.hires import EventCode
from tests.emulator.model.test_hires import config_text, config_with

pytestmark = pytest.mark.wallclock

E = EventCode

TICK = timedelta(milliseconds=100)
LEAD_IN_S = 5  # the emulator rests in its start-up green (minimum timed) before the first input
TAIL_S = 30  # and comes to rest after the last
# Power-up and unit events: the fresh emulator's are its own power-up's, not the replay's.
UNIT = {E.POWER_RESTORED, E.POWER_FAILURE, E.UNIT_CONTROL_STATUS_CHANGE, E.UNIT_FLASH_STATUS_CHANGE,
        E.COORD_PATTERN_CHANGE, E.COORD_CYCLE_STATE_CHANGE}


def own_log(seconds: int, seed: int = 3) -> list[Row]:
    """An emulator's log (virtual time): a quiet lead-in, ``seconds`` of random vehicle detector and push-button
    inputs, then :data:`TAIL_S` without any, in which the controller comes to rest."""
    cfg = config_with()
    c = Controller(cfg, start=datetime.now().replace(microsecond=0) - timedelta(days=1))
    log = DataLogger(c)
    rng = random.Random(seed)
    on: set[int] = set()
    pushed: set[int] = set()
    for k in range((LEAD_IN_S + seconds + TAIL_S) * 10):
        if LEAD_IN_S * 10 < k < (LEAD_IN_S + seconds) * 10:
            on = {d for d in cfg.detectors
                  if (d in on and rng.random() > 0.15) or (d not in on and rng.random() < 0.012)}
            pushed = {d for d in (2, 4, 6, 8) if (d in pushed and rng.random() > 0.3) or rng.random() < 0.003}
        elif k >= (LEAD_IN_S + seconds) * 10:
            on, pushed = set(), set()
        c.set_actuations(on)
        c.set_ped_actuations(pushed)
        c.step()
    return [Row(e.time, e.code, e.parameter) for e in log.events()]


def test_the_emulators_own_log_replays_at_100_percent(tmp_path: Path) -> None:
    config = tmp_path / "bench.toml"
    config.write_text(config_text())
    rows = own_log(30)
    # The bench runs on after the last input as long as the log does, so that both end at rest.
    replayed = replay(rows, config, tmp_path / "replay", warm_up_s=LEAD_IN_S + 1, settle_s=TAIL_S)
    assert replayed.signal_replay_match == 100.0
    # Stronger than the score: the fresh emulator logged exactly the log's events (bar its own power-up), each at
    # its time (shifted by the replay's start).
    first = next(r.time for r in rows if r.code == E.DETECTOR_ON)
    theirs = [(e.time - replayed.shift, e.code, e.parameter) for e in replayed.bench
              if e.code not in UNIT and first <= e.time - replayed.shift]
    mine = [(r.time, r.code, r.parameter) for r in rows if r.code not in UNIT and first <= r.time]
    assert len(mine) > 200 and {c for _, c, _ in mine} >= {E.PHASE_BEGIN_GREEN, E.PHASE_GAP_OUT, E.PED_BEGIN_WALK,
                                                           E.PED_DETECTOR_ON, E.BARRIER_TERMINATION}
    assert theirs == mine
    # and the replay's table says so: every event of the log found (from the first input on: before it each
    # emulator rests in its start-up green from its own power-up)
    table = match_table([r for r in rows if r.time >= first],
                        [e for e in replayed.bench if e.time - replayed.shift >= first], replayed.shift)
    assert table and all(r.matched == r.field == r.bench for r in table)


def test_a_window_of_a_real_field_log_replays_into_the_config_written_from_it(tmp_path: Path) -> None:
    sample = Path(atspm.__file__).parent / "data" / "sample_raw_data.parquet"
    every = hires_file.load(sample)
    inferred = field_log.infer(every, "atspm sample 1136")
    config = tmp_path / "field.toml"
    config.write_text(inferred.toml)
    # A window of one cycle (75 s) whose cycle position is that of the host's clock a few seconds from now, so that
    # Signal-Replay's wait for the log's cycle position is short.
    cycle = 75
    due = datetime.now() + timedelta(seconds=10)
    base = datetime(2024, 4, 15, 12, 10)
    start = base + timedelta(seconds=(due - base).total_seconds() % cycle)
    rows = [r for r in every if start <= r.time < start + timedelta(seconds=cycle)]
    replayed = replay(rows, config, tmp_path / "replay")
    # The inputs were replayed: the emulator logged the field's detector actuations at their field times, give or
    # take a few ticks (over the wire in real time, on a loaded machine, a send late by half a tick moves one by a
    # tick, and an on a tick after the off before it, 1 % of this log's, is missed when the two land in one tick).
    ons = {(e.time - replayed.shift, e.parameter) for e in replayed.bench if e.code == E.DETECTOR_ON}
    found = [any((r.time + k * TICK, r.parameter) in ons for k in range(-3, 4)) for r in rows
             if r.code == E.DETECTOR_ON]
    assert sum(found) >= 0.85 * len(found) > 80
    # The bench ran the field's plan where the field ran it: its local zeros are the field's, in the field's time.
    zeros = [e.time - replayed.shift for e in replayed.bench
             if e.code == E.COORD_CYCLE_STATE_CHANGE and e.parameter == 5]
    assert zeros and all(round((t - datetime(2024, 4, 15)).total_seconds()) % cycle == 45 for t in zeros)
    served = {e.parameter for e in replayed.bench if e.code == E.PHASE_BEGIN_GREEN}
    assert served <= {2, 5, 6, 8} and {2, 6} <= served
    assert 0 <= replayed.signal_replay_match <= 100 and replayed.table
