"""Controller scenarios on the paper intersection, counted in 0.1 s ticks.

The shipped config: every phase min green 3 s (30 ticks), max green 20 s (200
ticks), yellow 3 s (30 ticks), red clearance 2 s (20 ticks); start-up in [2,6].
"""

from __future__ import annotations

import itertools

import pytest
import simpy

from emulator.controller import Change, Controller, Interval
from emulator.mib import MibView
from hils.config import IntersectionConfig, parse
from hils.ntcip import UNIT_BACKUP_TIME, ControlColumn, UnitControlStatus, UnitFlashStatus

CALL, HOLD, OMIT = ControlColumn.VEH_CALL, ControlColumn.HOLD, ControlColumn.PHASE_OMIT
FORCE_OFF = ControlColumn.FORCE_OFF
ALL_PHASES = frozenset(range(1, 9))
MIN, MAX, YELLOW, RED = 30, 200, 30, 20


def show(c: Controller) -> str:
    """The display as SUMO-like letters, phase 1 first."""
    return "".join("G" if p in c.greens else "Y" if p in c.yellows else "r" for p in sorted(c.config.phases))


def record(c: Controller, ticks: int) -> list[str]:
    """The display after each of the next ``ticks`` ticks."""
    out = []
    for _ in range(ticks):
        c.step()
        out.append(show(c))
    return out


def runs(trace: list[str], phase: int) -> list[tuple[str, int]]:
    """One phase's indications in a trace as (letter, number of ticks) runs."""
    return [(k, len(list(g))) for k, g in itertools.groupby(s[phase - 1] for s in trace)]


def step_until(c: Controller, done, limit: int = 10_000) -> int:
    for _ in range(limit):
        if done(c):
            return c.tick
        c.step()
    raise AssertionError(f"condition not reached within {limit} ticks")


def serve(c: Controller, phases: set[int]) -> None:
    """Call the phases and step until they are green and have timed their minimum."""
    c.set_control(CALL, phases)
    step_until(c, lambda c: c.greens == phases)
    record(c, MIN)


def variant(paper_toml: str, *, replace: dict[str, str] | None = None, structure_extra: str = "") -> IntersectionConfig:
    text = paper_toml
    for old, new in (replace or {}).items():
        assert old in text
        text = text.replace(old, new)
    text = text.replace("[middleware]", f"{structure_extra}\n\n[middleware]")
    return parse(text, "variant.toml")


def compatibility_rows(allowed: set[tuple[int, int]]) -> list[list[int]]:
    """An explicit 8x8 compatibility matrix allowing exactly these pairs."""
    return [[1 if (min(a, b), max(a, b)) in allowed else 0 for b in range(1, 9)] for a in range(1, 9)]


def assert_status_consistent(c: Controller) -> None:
    assert c.greens | c.yellows | c.reds == ALL_PHASES
    assert not (c.greens & c.yellows) and not (c.greens & c.reds) and not (c.yellows & c.reds)


# --- start-up -----------------------------------------------------------------------------


def test_start_up_in_the_configured_phases(controller: Controller) -> None:
    assert controller.tick == 0
    assert controller.greens == {2, 6}
    assert controller.phase_ons == {2, 6}
    assert controller.yellows == frozenset()
    assert controller.reds == ALL_PHASES - {2, 6}
    assert controller.control_status is UnitControlStatus.OTHER
    assert controller.flash_status is UnitFlashStatus.NOT_FLASH
    assert controller.calls == frozenset()
    assert all(v == frozenset() for v in controller.control.values())


def test_start_up_on_other_phases(paper_toml: str) -> None:
    cfg = variant(paper_toml, replace={'startup = "green"': 'startup = "off"',
                                       '4 = { approach = "north", turn = "through" }':
                                       '4 = { approach = "north", turn = "through", startup = "green" }',
                                       '8 = { approach = "south", turn = "through" }':
                                       '8 = { approach = "south", turn = "through", startup = "green" }'})
    c = Controller(cfg)
    assert c.greens == {4, 8}
    c.set_control(CALL, {1, 5})
    # The start-up green began at tick 0: its minimum is timed at tick 30, the new green starts at tick 80.
    trace = record(c, MIN + YELLOW + RED)
    assert runs(trace, 4) == [("G", MIN - 1), ("Y", YELLOW), ("r", RED + 1)]
    assert runs(trace, 1) == [("r", MIN - 1 + YELLOW + RED), ("G", 1)]
    assert trace[-1] == "GrrrGrrr"


def test_start_up_in_clearance_then_rest_in_red(paper_toml: str) -> None:
    cfg = variant(paper_toml, replace={'startup = "green"': 'startup = "off"',
                                       '3 = { approach = "south", turn = "left" }':
                                       '3 = { approach = "south", turn = "left", startup = "yellow" }',
                                       '7 = { approach = "north", turn = "left" }':
                                       '7 = { approach = "north", turn = "left", startup = "red_clear" }'})
    c = Controller(cfg)
    assert show(c) == "rrYrrrrr"
    assert c.phase_ons == {3, 7}
    trace = record(c, 500)
    assert runs(trace, 3) == [("Y", YELLOW - 1), ("r", 500 - YELLOW + 1)]
    assert all(s == "rrrrrrrr" for s in trace[YELLOW:])
    assert c.phase_ons == frozenset()


def test_without_start_up_phases_a_call_is_served_from_red(paper_toml: str) -> None:
    c = Controller(variant(paper_toml, replace={'startup = "green"': 'startup = "off"'}))
    assert show(c) == "rrrrrrrr"
    c.set_control(CALL, {4})
    c.step()
    assert show(c) == "rrrGrrrr"


# --- serving calls ------------------------------------------------------------------------


def test_a_call_in_the_same_barrier_group_times_exact_clearances(controller: Controller) -> None:
    serve(controller, {3, 7})
    controller.set_control(CALL, {4, 8})
    trace = record(controller, YELLOW + RED + 5)
    for ending in (3, 7):
        assert runs(trace, ending) == [("Y", YELLOW), ("r", RED + 5)]
    for starting in (4, 8):
        assert runs(trace, starting) == [("r", YELLOW + RED), ("G", 5)]
    for other in (1, 2, 5, 6):
        assert runs(trace, other) == [("r", YELLOW + RED + 5)]


def test_clearance_reports_phase_ons_and_phase_nexts(controller: Controller) -> None:
    serve(controller, {3, 7})
    controller.set_control(CALL, {4, 8})
    controller.step()
    assert controller.yellows == {3, 7}
    assert (controller.phase_ons, controller.phase_nexts) == ({3, 7}, {4, 8})
    step_until(controller, lambda c: not c.yellows)
    assert show(controller) == "rrrrrrrr"
    assert (controller.phase_ons, controller.phase_nexts) == ({3, 7}, {4, 8})
    step_until(controller, lambda c: c.greens)
    assert (controller.phase_ons, controller.phase_nexts) == ({4, 8}, frozenset())


def test_a_call_across_the_barrier_and_back(controller: Controller) -> None:
    controller.set_control(CALL, {3, 7})
    trace = record(controller, MIN + YELLOW + RED + 9)
    # The start-up green began at tick 0: it has timed its minimum at tick 30.
    for ending in (2, 6):
        assert runs(trace, ending) == [("G", MIN - 1), ("Y", YELLOW), ("r", RED + 10)]
    for starting in (3, 7):
        assert runs(trace, starting) == [("r", MIN - 1 + YELLOW + RED), ("G", 10)]
    assert controller.greens == {3, 7}

    record(controller, MIN)
    controller.set_control(CALL, {2, 6})
    trace = record(controller, YELLOW + RED + 10)
    for ending in (3, 7):
        assert runs(trace, ending) == [("Y", YELLOW), ("r", RED + 10)]
    for starting in (2, 6):
        assert runs(trace, starting) == [("r", YELLOW + RED), ("G", 10)]


def test_the_minimum_green_is_served_before_a_conflicting_call(controller: Controller) -> None:
    controller.set_control(CALL, {3, 7})
    step_until(controller, lambda c: c.greens == {3, 7})
    controller.set_control(CALL, {1, 5})  # in the first tick of green 3 and 7
    trace = record(controller, MIN + YELLOW + RED)
    assert runs(trace, 3) == [("G", MIN - 1), ("Y", YELLOW), ("r", RED + 1)]
    assert trace[-1] == "GrrrGrrr"


def test_one_ring_changes_alone_inside_a_barrier_group(controller: Controller) -> None:
    controller.backup_time = 0
    serve(controller, {3, 7})
    # 8 follows 7 in ring 2 within the barrier group, so ring 1 keeps its green (a lead-lag change).
    controller.set_control(CALL, {3, 8})
    trace = record(controller, 1000)
    assert runs(trace, 3) == [("G", 1000)]
    assert runs(trace, 7) == [("Y", YELLOW), ("r", 1000 - YELLOW)]
    assert runs(trace, 8) == [("r", YELLOW + RED), ("G", 1000 - YELLOW - RED)]


def test_backing_into_an_earlier_phase_while_the_other_ring_times(controller: Controller) -> None:
    controller.backup_time = 0
    serve(controller, {3, 8})
    # 7 precedes 8 in ring 2: ring 2 backs into it within the barrier group while 3 stays green.
    controller.set_control(CALL, {3, 7})
    trace = record(controller, YELLOW + RED + 10)
    assert runs(trace, 8) == [("Y", YELLOW), ("r", RED + 10)]
    assert runs(trace, 7) == [("r", YELLOW + RED), ("G", 10)]
    assert runs(trace, 3) == [("G", YELLOW + RED + 10)]
    assert all(s[0] == "r" and s[4] == "r" for s in trace)  # no side trip to 1 or 5 without a call


def test_backup_prevent_keeps_the_ring_from_backing_until_the_barrier(paper_toml: str) -> None:
    cfg = variant(paper_toml, replace={"7 = { approach": "7 = { backup_prevent = true, approach"})
    c = Controller(cfg)
    c.backup_time = 0
    serve(c, {3, 8})
    c.set_control(CALL, {3, 7})
    trace = record(c, MAX + YELLOW + RED + 10)
    # Ring 2 may not back into 7: it gets there through a barrier cycle. For 3 (which has its call)
    # the call on 7 is conflicting demand: 3 maxes out, then both rings clear and re-enter the group.
    assert runs(trace, 8) == [("G", MAX - 1), ("Y", YELLOW), ("r", RED + 11)]
    assert runs(trace, 3)[:2] == [("G", MAX - 1), ("Y", YELLOW)]
    assert runs(trace, 7) == [("r", MAX - 1 + YELLOW + RED), ("G", 11)]


@pytest.mark.parametrize("calls", [set(), {2}, {2, 6}])
def test_rest_in_green_without_conflicting_calls(controller: Controller, calls: set[int]) -> None:
    if calls:
        controller.set_control(CALL, calls)
    controller.backup_time = 0
    trace = record(controller, 2000)
    assert set(trace) == {"rGrrrGrr"}


def test_rest_in_green_after_serving_a_call(controller: Controller) -> None:
    controller.set_control(CALL, {4, 8})
    step_until(controller, lambda c: c.greens == {4, 8})
    controller.set_control(CALL, set())
    assert set(record(controller, 1000)) == {"rrrGrrrG"}


def test_maximum_green_is_timed_from_the_conflicting_call(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 6})
    record(controller, 100)  # resting: no conflicting demand, so no maximum timing either
    controller.set_control(CALL, {2, 6, 4, 8})
    trace = record(controller, MAX + YELLOW + RED)
    for ending in (2, 6):
        assert runs(trace, ending) == [("G", MAX - 1), ("Y", YELLOW), ("r", RED + 1)]
    assert trace[-1] == "rrrGrrrG"


def test_maximum_timing_restarts_when_the_conflicting_call_goes_away(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 6, 4, 8})
    record(controller, MAX - 50)
    controller.set_control(CALL, {2, 6})
    record(controller, 100)
    controller.set_control(CALL, {2, 6, 4, 8})
    trace = record(controller, MAX)
    assert runs(trace, 2) == [("G", MAX - 1), ("Y", 1)]


def test_a_green_without_its_own_call_gaps_out_at_minimum(controller: Controller) -> None:
    controller.set_control(CALL, {6, 4})
    trace = record(controller, MAX + 1)
    # 2 gapped out at its minimum, but its next service (4) lies across the barrier: it waits there,
    # green, until 6 (which has its call) maxes out; then both clear together.
    assert runs(trace, 2) == [("G", MAX - 1), ("Y", 2)]
    assert runs(trace, 6) == [("G", MAX - 1), ("Y", 2)]


def test_hold_keeps_green_past_maximum_and_the_phase_ends_after_release(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 6, 4, 8})
    controller.set_control(HOLD, {2, 6})
    trace = record(controller, 3 * MAX)
    assert set(trace) == {"rGrrrGrr"}
    controller.set_control(HOLD, set())
    trace = record(controller, YELLOW + RED + 1)
    for ending in (2, 6):
        assert runs(trace, ending) == [("Y", YELLOW), ("r", RED + 1)]
    assert trace[-1] == "rrrGrrrG"


def test_hold_on_one_ring_holds_the_barrier(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 6, 4, 8})
    controller.set_control(HOLD, {2})
    trace = record(controller, 2 * MAX)
    assert runs(trace, 2) == [("G", 2 * MAX)]
    # 6 maxes out, but the barrier is crossed by both rings together: 6 waits green with held 2.
    assert runs(trace, 6) == [("G", 2 * MAX)]
    assert runs(trace, 4) == [("r", 2 * MAX)]


def test_force_off_ends_the_green_right_after_minimum(controller: Controller) -> None:
    controller.set_control(CALL, {2, 6, 4, 8})
    controller.set_control(FORCE_OFF, {2, 6})
    trace = record(controller, MIN + YELLOW + RED)
    for ending in (2, 6):
        assert runs(trace, ending) == [("G", MIN - 1), ("Y", YELLOW), ("r", RED + 1)]
    assert trace[-1] == "rrrGrrrG"
    assert controller.control[FORCE_OFF] == frozenset()


def test_the_force_off_bit_clears_itself_only_when_that_green_ends(controller: Controller) -> None:
    controller.set_control(CALL, {2, 6, 4, 8})
    controller.set_control(FORCE_OFF, {2, 6, 3})
    record(controller, MIN - 1)
    assert controller.control[FORCE_OFF] == {2, 6, 3}
    controller.step()
    assert controller.yellows == {2, 6}
    assert controller.control[FORCE_OFF] == {3}


def test_force_off_one_ring_the_other_maxes_out(controller: Controller) -> None:
    controller.set_control(CALL, {2, 6, 4, 8})
    controller.set_control(FORCE_OFF, {2})
    trace = record(controller, MAX)
    # 2 is forced off at its minimum, yet waits at the barrier for 6, which maxes out: both clear together.
    assert runs(trace, 2) == [("G", MAX - 1), ("Y", 1)]
    assert runs(trace, 6) == [("G", MAX - 1), ("Y", 1)]
    assert controller.control[FORCE_OFF] == frozenset()


def test_force_off_without_conflicting_demand_rests(controller: Controller) -> None:
    controller.set_control(CALL, {2, 6})
    controller.set_control(FORCE_OFF, {2, 6})
    assert set(record(controller, 100)) == {"rGrrrGrr"}
    assert controller.control[FORCE_OFF] == {2, 6}


def test_omitted_phases_are_never_served_and_the_others_are(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(OMIT, {4, 8})
    controller.set_control(CALL, {1, 3, 4, 5, 7, 8})
    assert controller.calls == {1, 3, 5, 7}
    served: set[int] = set()
    for _ in range(20 * (MAX + YELLOW + RED)):
        controller.step()
        served |= controller.greens
    assert served == {1, 2, 3, 5, 6, 7}  # 2 and 6 only from start-up
    controller.set_control(OMIT, set())
    step_until(controller, lambda c: {4, 8} <= c.greens)


def test_calls_on_unconfigured_phases_are_ignored(controller: Controller) -> None:
    controller.set_control(CALL, {12, 16})
    assert controller.calls == frozenset()
    assert set(record(controller, 100)) == {"rGrrrGrr"}


# --- unit backup time -------------------------------------------------------------------------


def test_backup_time_expiry_clears_the_control_objects(controller: Controller) -> None:
    controller.backup_time = 5
    for column in ControlColumn:
        controller.set_control(column, {3})
    assert controller.control_status is UnitControlStatus.SYSTEM_CONTROL
    record(controller, 49)
    assert controller.control_status is UnitControlStatus.SYSTEM_CONTROL
    assert controller.control[CALL] == {3}
    controller.step()
    assert controller.control_status is UnitControlStatus.BACKUP_MODE
    assert all(v == frozenset() for v in controller.control.values())
    assert controller.calls == frozenset()


def test_a_set_before_expiry_restarts_the_backup_timer(controller: Controller) -> None:
    controller.backup_time = 5
    controller.set_control(CALL, {2, 6})
    record(controller, 40)
    controller.set_control(CALL, {2, 6})
    record(controller, 49)
    assert controller.control_status is UnitControlStatus.SYSTEM_CONTROL
    controller.step()
    assert controller.control_status is UnitControlStatus.BACKUP_MODE


def test_a_set_after_backup_mode_returns_to_system_control(controller: Controller) -> None:
    controller.backup_time = 1
    controller.set_control(CALL, {4})
    record(controller, 10)
    assert controller.control_status is UnitControlStatus.BACKUP_MODE
    controller.set_control(CALL, {4})
    assert controller.control_status is UnitControlStatus.SYSTEM_CONTROL
    assert controller.calls == {4}


def test_backup_time_through_the_mib(controller: Controller) -> None:
    mib = MibView(controller)
    mib.set_many([(UNIT_BACKUP_TIME.instance(), 3)])
    assert controller.backup_time == 3
    controller.set_control(CALL, {4, 8})
    record(controller, 30)
    assert controller.control_status is UnitControlStatus.BACKUP_MODE
    assert controller.calls == frozenset()


def test_backup_time_zero_disables_it(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 6})
    record(controller, 3000)
    assert controller.control_status is UnitControlStatus.SYSTEM_CONTROL
    assert controller.control[CALL] == {2, 6}


def test_the_backup_timer_is_disarmed_until_the_first_set(controller: Controller) -> None:
    controller.backup_time = 1
    record(controller, 100)
    assert controller.control_status is UnitControlStatus.OTHER


# --- the conflict monitor ---------------------------------------------------------------------


def test_the_monitor_flashes_on_a_pair_the_matrix_forbids(paper_toml: str) -> None:
    allowed = {(1, 5), (1, 6), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8)}  # 2-5 is forbidden
    cfg = variant(paper_toml, structure_extra=f"compatibility = {compatibility_rows(allowed)}")
    assert not cfg.compatible(2, 5)
    c = Controller(cfg)
    c.backup_time = 0
    c.set_control(CALL, {2, 5})
    step_until(c, lambda c: c.flashing, limit=2 * (MAX + YELLOW + RED))
    assert c.flash_status is UnitFlashStatus.MMU
    assert c.reds == ALL_PHASES
    assert c.greens == c.yellows == c.phase_ons == frozenset()
    # The monitor stops the timing: nothing changes any more, calls or not.
    rings = [(r.phase, r.interval, r.ticks) for r in c.rings]
    c.set_control(CALL, {4, 8})
    record(c, 500)
    assert [(r.phase, r.interval, r.ticks) for r in c.rings] == rings
    assert c.reds == ALL_PHASES
    assert c.flash_status is UnitFlashStatus.MMU


def test_a_flash_during_clearance_announces_no_next_phase(paper_toml: str) -> None:
    # 1 clears for 6.0 s of yellow while 5 clears in 5.0 s: 6 starts beside a yellow 1, which the matrix forbids.
    allowed = {(1, 5), (2, 5), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8)}
    cfg = variant(paper_toml, replace={'1 = { approach = "west", turn = "left" }':
                                       '1 = { approach = "west", turn = "left", yellow = 6.0 }'},
                  structure_extra=f"compatibility = {compatibility_rows(allowed)}")
    c = Controller(cfg)
    serve(c, {1, 5})
    c.set_control(CALL, {2, 6})
    start = c.tick
    step_until(c, lambda c: c.flashing, limit=60)
    assert c.tick - start == YELLOW + RED + 1
    assert c.yellows == frozenset() and c.reds == ALL_PHASES
    assert c.phase_nexts == frozenset()


def test_status_sets_are_frozen(controller: Controller) -> None:
    controller.set_control(CALL, {3, 4})
    controller.step()
    status = (controller.calls, controller.greens, controller.yellows, controller.reds, controller.phase_ons,
              controller.phase_nexts)
    assert all(isinstance(s, frozenset) for s in status)


def test_the_monitor_stays_quiet_on_the_paper_matrix(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {2, 5})
    for _ in range(2000):
        controller.step()
        assert_status_consistent(controller)
    assert controller.flash_status is UnitFlashStatus.NOT_FLASH


# --- timelines and the SimPy process ---------------------------------------------------------


def test_on_change_reports_every_interval_change(paper_config: IntersectionConfig) -> None:
    changes: list[Change] = []
    c = Controller(paper_config, on_change=changes.append)
    c.set_control(CALL, {3, 7})
    record(c, MIN + YELLOW + RED)
    assert changes == [
        Change(MIN, 1, 2, Interval.YELLOW), Change(MIN, 2, 6, Interval.YELLOW),
        Change(MIN + YELLOW, 1, 2, Interval.RED_CLEAR), Change(MIN + YELLOW, 2, 6, Interval.RED_CLEAR),
        Change(MIN + YELLOW + RED, 1, 2, Interval.WAIT), Change(MIN + YELLOW + RED, 2, 6, Interval.WAIT),
        Change(MIN + YELLOW + RED, 1, 3, Interval.GREEN), Change(MIN + YELLOW + RED, 2, 7, Interval.GREEN),
    ]


def test_the_simpy_process_ticks_every_tenth_without_drift(controller: Controller) -> None:
    env = simpy.Environment()
    env.process(controller.process(env))
    env.run(until=3600.05)
    assert controller.tick == 36000


def test_reset_powers_up_again(controller: Controller) -> None:
    controller.set_control(CALL, {4, 8})
    step_until(controller, lambda c: c.greens == {4, 8})
    controller.reset()
    assert (controller.tick, controller.greens, controller.calls) == (0, {2, 6}, frozenset())
    assert controller.control_status is UnitControlStatus.OTHER
