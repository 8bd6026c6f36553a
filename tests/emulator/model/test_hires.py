"""The controller's own record: the emulator's hi-res event log against its interval timeline, its inputs and its
clock, in virtual time and at the wall clock, and the ATSPM layout it is kept in.

The timeline (:class:`emulator.model.controller.Change`) is what the controller does; the log must say it at the same
tick, in the Indiana enumerations, whether quiet ticks are skipped (virtual time) or every tick is stepped (the
wall clock).
"""

from __future__ import annotations

import itertools
import sys
from collections import Counter
from datetime import datetime, timedelta
from pathlib import Path

import pytest
from hypothesis import given, reject
from hypothesis import strategies as st

from emulator.model.controller import Change, Controller, Interval, Termination
from emulator.model.datalogger import DataLogger
from hils.protocol import config as config_mod
from hils.protocol import hires
from hils.protocol.config import ConfigError, IntersectionConfig, parse
from hils.protocol.hires import CycleState, Event, EventCode
from hils.protocol.ntcip import ControlColumn
from tests.emulator.model.test_controller_events import SETTINGS, apply, inputs, units

E = EventCode
TICK = timedelta(milliseconds=100)


def logged(c: Controller) -> tuple[DataLogger, list[tuple[int, Change]]]:
    """A logger on ``c`` and the timeline of its interval changes, each with the clock tick it happened at."""
    timeline: list[tuple[int, Change]] = []
    c.on_change = lambda change: timeline.append((c.coordinator.clock, change))
    return DataLogger(c), timeline


def at(log: DataLogger, clock: int) -> set[tuple[int, int]]:
    """(code, parameter) of the events logged at a clock tick."""
    t = log.time(clock)
    return {(e.code, e.parameter) for e in log.events(t) if e.time == t}


_INTERVAL_EVENTS = {Interval.GREEN: (E.PHASE_ON, E.PHASE_BEGIN_GREEN),
                    Interval.YELLOW: (E.PHASE_GREEN_TERMINATION, E.PHASE_BEGIN_YELLOW),
                    Interval.RED_CLEAR: (E.PHASE_END_YELLOW,), Interval.DWELL: (E.PHASE_INACTIVE,)}
_REASONS = {Termination.GAP_OUT: E.PHASE_GAP_OUT, Termination.MAX_OUT: E.PHASE_MAX_OUT,
            Termination.FORCE_OFF: E.PHASE_FORCE_OFF}


@st.composite
def logged_units(draw: st.DrawFn) -> IntersectionConfig:
    try:
        return draw(units())
    except ConfigError:
        reject()  # the shared strategy can draw a pattern whose cycle passes NTCIP's 255 s: not a unit to log


ped_inputs = st.tuples(st.just("ped_detectors"), st.frozensets(st.integers(1, 8)))


@SETTINGS
@given(config=logged_units(), ops=st.lists(inputs | ped_inputs, max_size=25))
def test_the_log_says_every_interval_change_at_its_tick_skipped_or_stepped(
        config: IntersectionConfig, ops: list[tuple[str, object]]) -> None:
    """Random configs (coordination half the time) and inputs (every control object, detectors, push buttons,
    retimings, power cycles): a controller stepped every tick (the wall clock) and its twin skipping quiet ticks
    (virtual time) log the same events, and each interval change of the timeline is in the log at its tick."""
    twins = []
    for ticked in (True, False):
        c = Controller(config)
        twins.append((c, *logged(c), ticked))
    for op, value in ops:
        for c, _, _, ticked in twins:
            if op == "ped_detectors":
                c.set_ped_actuations(value)
            else:
                apply(c, op, value, ticked=ticked)
    (c, log, timeline, _), (_, evented_log, _, _) = twins
    assert evented_log.events() == log.events()
    for clock, change in timeline:
        expected = {(code, change.phase) for code in _INTERVAL_EVENTS[change.interval]}
        if change.reason in _REASONS:
            expected.add((_REASONS[change.reason], change.phase))
        assert expected <= at(log, clock), (clock, change)
    codes = Counter(e.code for e in log.events())
    changes = Counter(change.interval for _, change in timeline)
    assert codes[E.PHASE_GREEN_TERMINATION] == changes[Interval.YELLOW]  # every termination, and only those
    assert codes[E.PHASE_END_YELLOW] == changes[Interval.RED_CLEAR]
    assert codes[E.PHASE_INACTIVE] == changes[Interval.DWELL]
    times = [e.time for e in log.events()]
    assert times == sorted(times)  # the clock never goes back, power cycles included


@pytest.mark.parametrize("power_failure", [False, True])
def test_a_minimum_timed_in_quiet_time_is_logged_at_its_tick(power_failure: bool) -> None:
    """4 and 8 called and served, nothing else: their minimum changes nothing, and the controller skipping quiet
    ticks does not step there, but its logger logs it at its tick all the same, as the controller stepped every
    tick does (and before the power failure that comes next, if one does)."""
    logs = []
    for ticked in (True, False):
        c = Controller(config_mod.load())
        log, _ = logged(c)
        apply(c, ControlColumn.VEH_CALL, frozenset({4, 8}), ticked=ticked)
        apply(c, "ticks", 150, ticked=ticked)  # 4 and 8 green from tick 101, their minimum timed by tick 150
        if power_failure:
            apply(c, "power_cycle", None, ticked=ticked)
        apply(c, "ticks", 20, ticked=ticked)
        logs.append(log.events())
    assert logs[1] == logs[0]
    minimums = [e for e in logs[0] if e.code == E.PHASE_MIN_COMPLETE and e.parameter in (4, 8)]
    assert len(minimums) == 2 and len({e.time for e in minimums}) == 1
    later = [e for e in logs[0] if e.time > minimums[0].time]  # nothing until the power failure, if one comes
    assert (E.POWER_FAILURE in {e.code for e in later if e.time == later[0].time}) if power_failure else not later


def test_two_minimums_timed_in_one_quiet_stretch_are_each_logged_at_their_tick() -> None:
    """4 and 8 start green together with minimums of 8 s and 15 s, nothing else called: quiet time asks the units
    once for the stretch, and the logger of the skipping controller logs each minimum at its own tick (4's, then
    8's), as the controller stepped every tick logs them."""
    logs = []
    for ticked in (True, False):
        c = Controller(config_mod.load().with_middleware(backup_time=0))
        c.set_timing(4, "min_green", 80)
        c.set_timing(8, "min_green", 150)
        log, _ = logged(c)
        apply(c, ControlColumn.VEH_CALL, frozenset({4, 8}), ticked=ticked)
        apply(c, "ticks", 400, ticked=ticked)
        logs.append(log.events())
    assert logs[1] == logs[0]
    minimums = {e.parameter: e.time for e in logs[0] if e.code == E.PHASE_MIN_COMPLETE and e.parameter in (4, 8)}
    assert minimums[8] - minimums[4] == timedelta(seconds=7)


def test_the_logger_takes_no_step_of_its_own() -> None:
    """Minimums that change nothing else (4 and 8, then 2 and 6, nothing conflicting called while they time): the
    controller with a logger takes exactly the steps of its twin without one, and its log says each minimum at its
    tick, read between the steps or at the end."""
    class Counting(Controller):
        steps = 0

        def step(self) -> None:
            self.steps += 1
            super().step()

    twins = [Counting(config_mod.load().with_middleware(backup_time=0)) for _ in range(3)]
    log = DataLogger(twins[0])
    ticked_log = DataLogger(twins[2])
    for calls in ({4, 8}, {2, 6}):
        for c in twins:
            apply(c, ControlColumn.VEH_CALL, frozenset(calls), ticked=c is twins[2])
            apply(c, "ticks", 400, ticked=c is twins[2])
        assert log.events() == ticked_log.events()
    assert twins[0].steps == twins[1].steps < 20
    minimums = [e.parameter for e in log.events() if e.code == E.PHASE_MIN_COMPLETE]
    assert sorted(minimums[-4:]) == [2, 4, 6, 8]


def config_text(text: str = "", timing: str = "") -> str:
    """The shipped four-leg with walks on its throughs, a passage time and some TOML added (``text`` after its last
    table, [emulator], without a plan; ``timing`` in [timing])."""
    base = (Path(__file__).parents[3] / "hils/data/four_leg.toml").read_text()
    base = base.replace('[timing]            # shared by every phase, as in the paper',
                        f'[timing]\npassage = 2.0\n{timing}')
    for p in (2, 4, 6, 8):
        base = base.replace(f'{p} = {{ approach', f'{p} = {{ walk = 4, ped_clear = 5, approach', 1)
    return base[:base.index("[coordination]")] + text


def config_with(text: str = "", timing: str = "") -> IntersectionConfig:
    return parse(config_text(text, timing), "four_leg_peds.toml")


def run(c: Controller, ticks: int) -> None:
    for _ in range(ticks):
        c.step()


def test_detectors_calls_and_pushes_are_logged_in_order_at_their_ticks() -> None:
    c = Controller(config_with())
    log, _ = logged(c)
    run(c, 50)  # 2+6 rest in green
    c.set_actuations({4})
    run(c, 1)
    assert {(E.DETECTOR_ON, 4), (E.PHASE_CALL_REGISTERED, 4)} <= at(log, 51)
    assert (E.PHASE_CHECK, 2) in at(log, 51) and (E.PHASE_CHECK, 6) in at(log, 51)  # max timing begins
    c.set_ped_actuations({8})
    run(c, 1)
    assert {(E.PED_DETECTOR_ON, 8), (E.PED_CALL_REGISTERED, 8)} == at(log, 52)
    c.set_ped_actuations(set())
    c.set_actuations(set())
    run(c, 1)
    assert {(E.PED_DETECTOR_OFF, 8), (E.DETECTOR_OFF, 4), (E.PHASE_CALL_DROPPED, 4)} <= at(log, 53)
    run(c, 200)
    walk = next(e for e in log.events() if e.code == E.PED_BEGIN_WALK)
    green = next(e for e in log.events() if e.code == E.PHASE_BEGIN_GREEN and e.parameter == 8)
    assert walk.parameter == 8 and walk.time == green.time  # the walk begins with the green it was called for
    clear = next(e for e in log.events() if e.code == E.PED_BEGIN_CLEARANCE)
    solid = next(e for e in log.events() if e.code == E.PED_BEGIN_SOLID_DONT_WALK)
    assert (clear.time - walk.time, solid.time - clear.time) == (timedelta(seconds=4), timedelta(seconds=5))
    minimum = next(e for e in log.events() if e.code == E.PHASE_MIN_COMPLETE and e.parameter == 8)
    assert minimum.time - green.time == timedelta(seconds=9)  # walk and pedestrian clearance: its minimum


def test_why_each_green_ended() -> None:
    c = Controller(config_with())
    log, timeline = logged(c)
    run(c, 50)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    run(c, 1)  # 2 and 6 rest past their minimum: with a call across and no call of their own, they gap out
    assert {(E.PHASE_GAP_OUT, 2), (E.PHASE_GAP_OUT, 6), (E.PHASE_GREEN_TERMINATION, 2)} <= at(log, 51)
    c.set_control(ControlColumn.VEH_CALL, {2, 4, 6, 8})  # 4 and 8 hold their calls: they max out at 20 s
    run(c, 80)
    green = next(clock for clock, ch in timeline if ch.interval is Interval.GREEN and ch.phase == 4)
    run(c, 200)
    assert {(E.PHASE_MAX_OUT, 4), (E.PHASE_MAX_OUT, 8)} <= at(log, green + 200)
    c.set_control(ControlColumn.VEH_CALL, {4, 8, 2, 6})
    run(c, 120)
    green = max(clock for clock, ch in timeline if ch.interval is Interval.GREEN and ch.phase == 2)
    c.set_control(ControlColumn.FORCE_OFF, {2, 6})
    run(c, 1)
    assert {(E.PHASE_FORCE_OFF, 2), (E.PHASE_FORCE_OFF, 6)} <= at(log, c.coordinator.clock)
    assert c.coordinator.clock - green < 200  # forced off before its maximum
    ended = Counter(e.code for e in log.events() if e.code in (E.PHASE_GAP_OUT, E.PHASE_MAX_OUT, E.PHASE_FORCE_OFF))
    assert sum(ended.values()) == Counter(e.code for e in log.events())[E.PHASE_GREEN_TERMINATION]


def test_barrier_termination_names_the_group_that_ended() -> None:
    c = Controller(config_with())
    log, _ = logged(c)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    run(c, 150)
    c.set_control(ControlColumn.VEH_CALL, {2, 6})
    run(c, 150)
    barriers = [(e.parameter, e.time) for e in log.events() if e.code == E.BARRIER_TERMINATION]
    greens: dict[datetime, set[int]] = {}
    for e in log.events():
        if e.code == E.PHASE_BEGIN_GREEN:
            greens.setdefault(e.time, set()).add(e.parameter)
    assert [(b, greens[t]) for b, t in barriers] == [(1, {4, 8}), (2, {2, 6})]  # 1+2+5+6 ended, then 3+4+7+8


def test_coordination_events_follow_the_running_pattern() -> None:
    c = Controller(config_mod.load().planned())  # the four-leg's pattern 1 from power-up: 70 s, 2+6 coordinated
    log, _ = logged(c)
    run(c, 7000)  # ten cycles
    events = log.events()
    first = {(e.code, e.parameter) for e in events if e.time == events[0].time}
    splits = {(hires.split_code(p), s) for p, s in {1: 14, 2: 28, 3: 12, 4: 16, 5: 12, 6: 30, 7: 13, 8: 15}.items()}
    assert {(E.COORD_PATTERN_CHANGE, 1), (E.CYCLE_LENGTH_CHANGE, 70), (E.OFFSET_LENGTH_CHANGE, 0),
            (E.COORD_CYCLE_STATE_CHANGE, CycleState.IN_STEP)} | splits <= first
    zeros = [e.time for e in events if e.code == E.COORD_CYCLE_STATE_CHANGE and e.parameter == CycleState.LOCAL_ZERO]
    assert len(zeros) == 10 and {b - a for a, b in itertools.pairwise(zeros)} == {timedelta(seconds=70)}
    yields = Counter(e.parameter for e in events if e.code == E.COORD_YIELD_POINT)
    assert yields == {2: 10, 6: 10}
    # a coordinated phase that ends at its yield point is forced off there; one held past it ends without a reason
    for e in events:
        if e.code == E.PHASE_GREEN_TERMINATION and e.parameter in (2, 6):
            here = {(x.code, x.parameter) for x in events if x.time == e.time}
            assert ((E.PHASE_FORCE_OFF, e.parameter) in here) == ((E.COORD_YIELD_POINT, e.parameter) in here)
    c.set_pattern_control(254)
    run(c, 1)
    assert (E.COORD_PATTERN_CHANGE, 254) in at(log, c.coordinator.clock)
    assert (E.COORD_CYCLE_STATE_CHANGE, CycleState.FREE) in at(log, c.coordinator.clock)


def test_the_clock_starts_at_the_configured_time_and_counts_through_a_power_cycle() -> None:
    c = Controller(config_with('start = 2024-04-15T07:30:00\n'))
    log, _ = logged(c)
    assert log.events()[0].time == datetime(2024, 4, 15, 7, 30)
    assert (E.POWER_RESTORED, 1) in at(log, c.coordinator.clock)
    run(c, 600)
    c.reset()
    assert {(E.POWER_FAILURE, 1), (E.POWER_RESTORED, 1), (E.PHASE_BEGIN_GREEN, 2)} <= at(log, c.coordinator.clock)
    assert log.events()[-1].time == datetime(2024, 4, 15, 7, 31)
    run(c, 10)
    assert log.time(c.coordinator.clock) == datetime(2024, 4, 15, 7, 31, 1)


@pytest.mark.parametrize(("value", "says"), [
    ('"7:00"', "local date and time"), ("2024-04-15T07:00:00+02:00", "with an offset"),
    ("2024-04-15T07:00:00.05", "whole tenths"), ("12", "local date and time")])
def test_a_bad_start_is_refused_naming_the_field(value: str, says: str) -> None:
    with pytest.raises(ConfigError, match=rf"emulator\.start.*{says}"):
        config_with(f"start = {value}\n")


def test_a_pedestrian_detector_table_is_checked() -> None:
    assert config_with("[pedestrian_detectors]\n1 = 4\n").ped_detectors == {1: 4}
    with pytest.raises(ConfigError, match=r"pedestrian_detectors\.1.*allowed: the configured phases"):
        config_with("[pedestrian_detectors]\n1 = 9\n")
    assert config_with("[pedestrian_detectors]\n255 = 4\n").ped_detectors == {255: 4}  # maxPedestrianDetectors
    with pytest.raises(ConfigError, match=r"pedestrian_detectors\.256.*1-255"):
        config_with("[pedestrian_detectors]\n256 = 4\n")


@pytest.mark.parametrize("value", ["{ phase = 4, lock = true }", "[4]"])
def test_a_push_button_given_as_a_vehicle_detectors_table_is_refused_naming_the_field(value: str) -> None:
    """A push button written as a vehicle detector's table (or a list) is a config error naming the field, not a
    TypeError from the check of its phase (a table cannot be looked up among the phases)."""
    with pytest.raises(ConfigError, match=r"pedestrian_detectors\.2.*allowed: the configured phases"):
        config_with(f"[pedestrian_detectors]\n2 = {value}\n")


# --- the ATSPM layout and MaxTime's XML ----------------------------------------------------------------------


EVENTS = [Event(datetime(2024, 4, 15, 12, 0, 0, 100_000), E.PHASE_BEGIN_GREEN, 2),
          Event(datetime(2024, 4, 15, 12, 0, 3, 500_000), E.DETECTOR_ON, 17),
          Event(datetime(2024, 4, 15, 12, 0, 3, 500_000), 316, 75)]  # a vendor's code passes through


def test_the_maxtime_xml_reads_back_and_since_takes_maxtimes_form() -> None:
    body = hires.asclog_xml(EVENTS)
    assert b'TimeStamp="04-15-2024 12:00:00.1" EventTypeID="1" Parameter="2"' in body
    assert hires.parse_asclog(body) == EVENTS
    assert hires.asclog_url("http://h:80", datetime(2024, 4, 15, 12)) == \
        "http://h:80/v1/asclog/xml/full?since=04-15-2024+12%3A00%3A00.0"
    with pytest.raises(hires.AsclogError, match="MM-DD-YYYY"):
        hires.parse_time("2024-04-15 12:00")
    with pytest.raises(hires.AsclogError, match="EventResponses"):
        hires.parse_asclog(b"<html")


def test_the_atspm_layout_in_parquet(tmp_path: Path) -> None:
    import pandas as pd
    assert hires.file_name() == "hires.parquet"
    path = tmp_path / "hires.parquet"
    path.write_bytes(hires.encode({1: EVENTS[:2], 2: EVENTS[2:]}))
    frame = pd.read_parquet(path)
    assert list(frame.columns) == list(hires.COLUMNS)
    assert frame.values.tolist() == [[pd.Timestamp(e.time), d, e.code, e.parameter]
                                     for e, d in zip(EVENTS, (1, 1, 2), strict=True)]


def test_without_pyarrow_the_layout_is_csv(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if not installed
    assert hires.file_name() == "hires.csv"
    assert hires.encode({1: EVENTS}).decode().splitlines() == ["TimeStamp,DeviceId,EventId,Parameter",
                                             "2024-04-15 12:00:00.100,1,1,2", "2024-04-15 12:00:03.500,1,82,17",
                                             "2024-04-15 12:00:03.500,1,316,75"]


def test_since_keeps_the_events_from_that_time_on() -> None:
    c = Controller(config_with())
    log, _ = logged(c)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    run(c, 100)
    events = log.events()
    cut = events[len(events) // 2].time
    assert log.events(cut) == [e for e in events if e.time >= cut]
    assert log.events(cut + timedelta(microseconds=1)) == [e for e in events if e.time > cut]
    assert log.events(events[0].time - timedelta(days=1)) == events


def test_overlaps_are_logged_with_the_phases_that_drive_them() -> None:
    """The four-leg as a city runs it: right-turn overlaps A-D and flashing yellow arrows E-H (numbered 1-8)."""
    c = Controller(config_mod.load(Path(__file__).parents[3] / "hils/data/four_leg_city.toml"))
    log, timeline = logged(c)
    run(c, 50)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    run(c, 120)
    yellow = next(clock for clock, ch in timeline if ch.interval is Interval.YELLOW and ch.phase == 2)
    green = next(clock for clock, ch in timeline if ch.interval is Interval.GREEN and ch.phase == 4)
    A, B, C, D, E_, F, G, H = range(1, 9)  # noqa: N806 - the overlaps' letters
    # 2 and 6 clear: their right turns C and D turn yellow; the arrows E and F, flashing while 2 and 6 were green,
    # end their permissive and show a steady yellow.
    assert {(E.OVERLAP_BEGIN_YELLOW, C), (E.OVERLAP_BEGIN_YELLOW, D), (E.FYA_END_PERMISSIVE, E_),
            (E.FYA_END_PERMISSIVE, F), (E.OVERLAP_BEGIN_YELLOW, E_), (E.OVERLAP_BEGIN_YELLOW, F)} <= at(log, yellow)
    # 4 and 8 start: their right turns A and B green, the arrows G and H (yielding to 4 and 8) flash.
    assert {(E.OVERLAP_BEGIN_GREEN, A), (E.OVERLAP_BEGIN_GREEN, B), (E.FYA_BEGIN_PERMISSIVE, G),
            (E.FYA_BEGIN_PERMISSIVE, H)} <= at(log, green)
    offs = {e.parameter for e in log.events() if e.code == E.OVERLAP_OFF}
    assert {C, D, E_, F} <= offs  # each went red when its yellow ended


def test_a_bounded_log_keeps_the_last_events_as_a_ring_buffer() -> None:
    twins = [Controller(config_with()) for _ in range(2)]
    whole, ring = DataLogger(twins[0]), DataLogger(twins[1], capacity=100)
    for c in twins:
        c.set_actuations({1, 2, 3, 4, 5, 6, 7, 8})  # every phase called, each green to its maximum
        run(c, 3000)
    assert len(whole) > 250 and 100 <= len(ring) <= 125
    assert ring.events() == whole.events()[-len(ring):]


def test_a_snapshot_stays_the_log_it_was_while_the_controller_logs_on_and_drops_its_oldest() -> None:
    """What the served log streams from, between ticks that go on logging (emulator.agent.asclog)."""
    c = Controller(config_with())
    ring = DataLogger(c, capacity=100)
    c.set_actuations({1, 2, 3, 4, 5, 6, 7, 8})
    run(c, 1000)
    snapshot, then = ring.snapshot(), ring.events()
    since = then[40].time
    later = ring.snapshot(since)
    run(c, 3000)  # the oldest dropped several times over
    assert ring.events() != then
    assert snapshot.events() == then and len(snapshot) == len(then)
    assert later.events() == [e for e in then if e.time >= since]
    assert snapshot.events(10, 5) == then[10:15] and snapshot.events(len(then) - 2, 5) == then[-2:]


def test_a_preempt_is_logged_from_its_input_to_its_exit() -> None:
    """The four-leg as a city runs it: preempt 1 (no delay, 2 s entry minimum green, dwell on 2+5 at least 5 s,
    exit to 2+6) called while 4 and 8 are green."""
    c = Controller(config_mod.load(Path(__file__).parents[3] / "hils/data/four_leg_city.toml"))
    log, _ = logged(c)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    run(c, 120)
    assert {4, 8} <= c.greens
    c.set_preempt_control({1})
    run(c, 150)
    c.set_preempt_control(set())
    run(c, 150)
    order = [(e.code, e.time) for e in log.events() if e.code in (
        E.PREEMPT_CALL_INPUT_ON, E.PREEMPT_ENTRY_STARTED, E.PREEMPT_BEGIN_DWELL, E.PREEMPT_CALL_INPUT_OFF,
        E.PREEMPT_BEGIN_EXIT) and e.parameter == 1]
    assert [code for code, _ in order] == [E.PREEMPT_CALL_INPUT_ON, E.PREEMPT_ENTRY_STARTED, E.PREEMPT_BEGIN_DWELL,
                                           E.PREEMPT_CALL_INPUT_OFF, E.PREEMPT_BEGIN_EXIT]
    times = dict(order)
    dwell = {e.parameter for e in log.events()
             if e.code == E.PHASE_BEGIN_GREEN and e.time == times[E.PREEMPT_BEGIN_DWELL]}
    assert dwell == {2, 5}  # the dwell begins with its phases' green
    assert times[E.PREEMPT_CALL_INPUT_ON] <= times[E.PREEMPT_ENTRY_STARTED]  # no delay configured
    assert times[E.PREEMPT_BEGIN_EXIT] - times[E.PREEMPT_BEGIN_DWELL] >= timedelta(seconds=5)  # its minimum dwell
