"""Controller scenarios on the paper intersection, counted in 0.1 s ticks.

The shipped config: every phase min green 3 s (30 ticks), max green 20 s (200
ticks), yellow 3 s (30 ticks), red clearance 2 s (20 ticks); start-up in [2,6].
"""

from __future__ import annotations

import itertools

import pytest
import simpy

from emulator.agent.mib import MibView
from emulator.model.controller import Change, Controller, Interval, Termination
from hils.protocol.config import IntersectionConfig, parse
from hils.protocol.ntcip import (
    PHASE_TABLE,
    UNIT_BACKUP_TIME,
    ControlColumn,
    PhaseColumn,
    PhaseOption,
    UnitControlStatus,
    UnitFlashStatus,
)

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


def test_a_ring_backs_into_an_earlier_phase_while_the_other_times_where_backup_prevent_is_off(
        paper_toml: str) -> None:
    """Naztec's default (TecNote 3013: a controller backs "into a protected left-turn phase when the cross street
    phases and the opposing left-turn are skipped"), reached with ``backup_prevent = false``."""
    c = with_options(paper_toml, {8: "backup_prevent = false"})
    serve(c, {3, 8})
    # 7 precedes 8 in ring 2: ring 2 backs into it while 3 stays green (no trip round the cycle).
    c.set_control(CALL, {3, 7})
    trace = record(c, MAX + 2 * (YELLOW + RED))
    assert runs(trace, 8) == [("Y", YELLOW), ("r", MAX + 2 * RED + YELLOW)]
    assert runs(trace, 7) == [("r", YELLOW + RED), ("G", MAX + RED + YELLOW)]
    assert runs(trace, 3) == [("G", MAX + 2 * (YELLOW + RED))]


def test_a_ring_does_not_back_into_an_earlier_phase_by_default(controller: Controller) -> None:
    """No phaseOptions bit is set by default, conditional service (bit 14) neither, and the field logs of issue 35
    never show a backing: 8 may not back into 7, so 7 needs the group to start over: 3 (with its call) maxes out,
    timed from the call on 7, and both rings clear together and restart the group."""
    serve(controller, {3, 8})
    controller.set_control(CALL, {3, 7})
    trace = record(controller, MAX + YELLOW + RED)
    assert runs(trace, 8) == [("G", MAX - 1), ("Y", YELLOW), ("r", RED + 1)]
    assert runs(trace, 3) == [("G", MAX - 1), ("Y", YELLOW), ("r", RED), ("G", 1)]
    assert runs(trace, 7) == [("r", MAX - 1 + YELLOW + RED), ("G", 1)]


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


@pytest.mark.parametrize(("disable", "ends"), [(True, 151), (False, MAX)])
def test_simultaneous_gap_disable_keeps_a_gapped_out_green_from_extending_again(paper_toml: str, disable: bool,
                                                                                 ends: int) -> None:
    """NTCIP 1202 phaseOptions bit 11, Simultaneous Gap Disable: "when set to 1 disables a gapped out phase from
    reverting to the extensible portion". 2 gaps out at its minimum and waits at the barrier for 6 (4 is called);
    its call comes back at 10 s, and 6's call goes at 15 s. With the bit, 2 stays gapped out and both cross as 6
    gaps out; without it, 2 extends again on its call, to its maximum (timed from the call on 4)."""
    option = f"simultaneous_gap_disable = {str(disable).lower()}"
    c = with_options(paper_toml, {2: option, 6: option})
    seen = onsets(c, 400, {0: {4, 6}, 100: {2, 4, 6}, 150: {2, 4}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == ends


def test_a_gapped_out_green_waits_at_the_barrier_for_the_other_ring(controller: Controller) -> None:
    controller.set_control(CALL, {6, 4})
    trace = record(controller, MAX + 1)
    # 2 gaps out at its minimum but its next service (4) is across the barrier: it keeps its green until
    # 6, which has its call, maxes out (timed from the call on 4); both clear together.
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
    # 6 maxes out, but 4 and 8 lie across the barrier: 6 waits there with 2.
    assert runs(trace, 2) == runs(trace, 6) == [("G", 2 * MAX)]
    assert runs(trace, 4) == [("r", 2 * MAX)]
    controller.set_control(HOLD, set())
    controller.step()
    assert controller.yellows == {2, 6}


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
    # 2 is forced off at its minimum and waits at the barrier until 6 maxes out: they cross together.
    assert runs(trace, 2) == runs(trace, 6) == [("G", MAX - 1), ("Y", 1)]
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


@pytest.mark.parametrize("yellow", [0, 26, 27])
def test_the_monitor_flashes_on_a_yellow_shorter_than_an_mmu_takes(controller: Controller, yellow: int) -> None:
    # A phase table corrupted past what a SET may write (set_timing refuses a yellow under 3.0 s, as the agent does):
    # 2 leaves its green with 0 or 2.6 s of yellow, which an MMU faults ("a Yellow must follow it and it must stay on
    # for at least 2.7 seconds"); 2.7 s passes.
    c = controller
    c.backup_time = 0
    c.timing[2].yellow = yellow
    serve(c, {2, 6})
    c.set_control(CALL, {3, 7})
    record(c, 100)
    if yellow < 27:
        assert c.flash_status is UnitFlashStatus.MMU and c.reds == ALL_PHASES
    else:
        assert not c.flashing and 3 in c.greens


@pytest.mark.parametrize(("name", "ticks"), [("yellow", 0), ("yellow", 29), ("min_green", 35), ("passage", 256),
                                           ("max1", -10)])
def test_a_timing_its_object_cannot_hold_is_refused(controller: Controller, name: str, ticks: int) -> None:
    """NTCIP 1202 phaseYellowChange: "NEMA TS 2 range: 3-25.5 sec"; a phase's minimum green and maximum are whole
    seconds, its passage at most 25.5 s: a SET of anything else is refused, naming the phase, the timing and what is
    allowed, and the timing stays as it was (the agent refuses it with wrongValue before it comes here)."""
    before = getattr(controller.timing[2], name)
    with pytest.raises(ValueError, match=f"phase 2 {name} = {ticks} ticks; allowed: "):
        controller.set_timing(2, name, ticks)
    assert getattr(controller.timing[2], name) == before
    controller.set_timing(2, "yellow", 30)
    assert controller.timing[2].yellow == 30


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
        # a yellow says why its green ended: no call on 2 or 6, so both gapped out at their minimum
        Change(MIN, 1, 2, Interval.YELLOW, Termination.GAP_OUT),
        Change(MIN, 2, 6, Interval.YELLOW, Termination.GAP_OUT),
        Change(MIN + YELLOW, 1, 2, Interval.RED_CLEAR), Change(MIN + YELLOW, 2, 6, Interval.RED_CLEAR),
        Change(MIN + YELLOW + RED, 1, 2, Interval.DWELL), Change(MIN + YELLOW + RED, 2, 6, Interval.DWELL),
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


# --- NEMA semantics (issue 9), in ticks ---------------------------------------------------------

PED_CALL, PED_OMIT = ControlColumn.PED_CALL, ControlColumn.PED_OMIT


def with_options(paper_toml: str, options: dict[int, str]) -> Controller:
    """A controller on the paper intersection with extra settings on some phases."""
    text = paper_toml
    for p, extra in options.items():
        start = text.index(f"\n{p} = {{ ") + 1
        end = text.index("}", start)
        text = text[:start] + text[start:end].rstrip() + f", {extra} " + text[end:]
    c = Controller(parse(text, "variant.toml"))
    c.backup_time = 0
    return c


def onsets(c: Controller, ticks: int, calls: dict[int, set[int]] | None = None) -> dict[tuple[int, str], int]:
    """Step ``ticks`` ticks, SETting the calls due at each tick; the first tick each phase showed each colour."""
    out: dict[tuple[int, str], int] = {}
    for _ in range(ticks):
        if calls and c.tick in calls:
            c.set_control(CALL, calls[c.tick])
        c.step()
        for p, letter in zip(sorted(c.config.phases), show(c), strict=True):
            out.setdefault((p, letter), c.tick)
    return out


def test_both_rings_cross_the_barrier_together(controller: Controller) -> None:
    # 2+6 green, 4 and 8 called; 2's call drops at 15 s and 6's at 18 s: 2 and 6 turn yellow together at 18 s.
    controller.backup_time = 0
    seen = onsets(controller, 300, {0: {2, 6, 4, 8}, 150: {6, 4, 8}, 180: {4, 8}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 181
    assert seen[(4, "G")] == seen[(8, "G")] == 181 + YELLOW + RED


def test_a_max_out_of_one_ring_waits_for_the_other_at_the_barrier(controller: Controller) -> None:
    controller.backup_time = 0
    seen = onsets(controller, 400, {0: {2, 6}, 100: {2, 6, 8}, 140: {6, 8}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 100 + MAX  # 6 maxes out 20 s after the call on 8; 2 waited


def test_phase_next_is_committed_at_yellow_and_not_redirected(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {4, 8})
    onsets(controller, MIN)
    assert controller.yellows == {2, 6} and controller.phase_nexts == {4, 8}
    controller.set_control(CALL, {3, 4, 8})  # 3 precedes 4 in ring 1, but 4 is committed
    seen = onsets(controller, YELLOW + RED + 10)
    assert controller.phase_nexts == frozenset()
    assert seen[(4, "G")] == seen[(8, "G")] == MIN + YELLOW + RED and (3, "G") not in seen


def test_a_committed_phase_that_loses_its_call_is_still_served(controller: Controller) -> None:
    controller.backup_time = 0
    seen = onsets(controller, 300, {0: {4, 8}, MIN + 5: set()})
    assert seen[(4, "G")] == seen[(8, "G")] == MIN + YELLOW + RED
    assert (4, "Y") not in seen  # served, then resting in green without other demand


def test_a_committed_phase_omitted_during_clearance_is_dropped(controller: Controller) -> None:
    controller.backup_time = 0
    controller.set_control(CALL, {4, 8})
    onsets(controller, MIN + 5)
    controller.set_control(OMIT, {4})
    seen = onsets(controller, 200)
    assert (4, "G") not in seen and seen[(8, "G")] == MIN + YELLOW + RED


@pytest.mark.parametrize("option", ["backup_prevent = false", "conditional_service = true"])
def test_a_ring_backs_into_its_earlier_phase_while_the_other_rests(paper_toml: str, option: str) -> None:
    """Nothing waits across the barrier: with Naztec's backing or with conditional service (2's maximum held reset,
    its whole 20 s left) 6 backs into 5 while 2 stays green."""
    c = with_options(paper_toml, {6: option})
    seen = onsets(c, 200, {0: {2, 6}, 140: {2, 5}})
    assert seen[(6, "Y")] == 141 and seen[(5, "G")] == 141 + YELLOW + RED
    assert (2, "Y") not in seen  # 2 stays green all along


def test_without_an_option_the_group_restarts_for_an_earlier_phase(controller: Controller) -> None:
    """The same calls by default: 5 is served by a restart of the group, once 2 has maxed out (timed from the call
    on 5, which 2's ring cannot reach before the group restarts)."""
    seen = onsets(controller, 500, {0: {2, 6}, 140: {2, 5}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 140 + MAX
    assert seen[(5, "G")] == 140 + MAX + YELLOW + RED


@pytest.mark.parametrize("option", ["", "backup_prevent = false"])
def test_no_backing_while_a_call_waits_across_the_barrier(paper_toml: str, option: str) -> None:
    """Issue 24's sequence: 2 held, 6's call drops, calls on 5 and 4 at 15 s. Neither by default nor as Naztec backs
    (only "when the cross street phases and the opposing left-turn are skipped", Naztec TecNote 3013): 6 waits at
    the barrier, 2 maxes out 20 s after the call on 4 and both cross at 35 s (backing into 5 made it 40 s)."""
    c = with_options(paper_toml, {6: option} if option else {})
    seen = onsets(c, 700, {0: {2, 6}, 150: {2, 4, 5}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 150 + MAX
    assert seen[(4, "G")] == 150 + MAX + YELLOW + RED
    assert seen[(5, "G")] > seen[(4, "G")]  # 5 waits for the group's next visit


def test_conditional_service_backs_with_a_call_across_when_the_other_green_has_time(paper_toml: str) -> None:
    """NTCIP 1202 phaseOptions bit 14: "causes a gapped/maxed phase to conditionally service a preceding actuated
    vehicle phase when sufficient time remains before max time out of the phase(s) not prepared to terminate".
    The sequence above with the bit on 6: 2 (its maximum timing from the call on 4 at 15 s) has 20 s left, more
    than 6's clearance and 5's minimum (8 s): 6 backs into 5 at once."""
    c = with_options(paper_toml, {6: "conditional_service = true"})
    seen = onsets(c, 700, {0: {2, 6}, 150: {2, 4, 5}})
    assert seen[(6, "Y")] == 151 and seen[(5, "G")] == 151 + YELLOW + RED
    # 5 then extends on its call to its own maximum (timed from the call on 4), and 2 waits for it at the barrier
    assert seen[(2, "Y")] == seen[(5, "Y")] == 151 + YELLOW + RED + MAX
    assert seen[(4, "G")] == 151 + YELLOW + RED + MAX + YELLOW + RED


def test_conditional_service_waits_when_the_other_green_has_too_little_time(paper_toml: str) -> None:
    """The bit on 6, but 2's maximum has timed 15 s of its 20 (4 called from the start) when 6 gaps out with 5
    called: 5 s left, less than 6's clearance and 5's minimum, so 6 waits at the barrier and both cross at 20 s."""
    c = with_options(paper_toml, {6: "conditional_service = true"})
    seen = onsets(c, 400, {0: {2, 4, 6}, 150: {2, 4, 5}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == MAX
    assert (5, "G") not in seen or seen[(5, "G")] > seen[(4, "G")]


def test_conditional_service_is_served_in_phase_options(paper_toml: str) -> None:
    """phaseOptions bit 14 (Conditional Service Enable) set where the phase has it, clear elsewhere."""
    c = with_options(paper_toml, {6: "conditional_service = true"})
    view = MibView(c)
    options = {p: PhaseOption(view.get(PHASE_TABLE[PhaseColumn.OPTIONS].instance(p))) for p in (2, 6)}
    assert PhaseOption.CONDITIONAL_SERVICE == 1 << 14
    assert PhaseOption.CONDITIONAL_SERVICE in options[6] and PhaseOption.CONDITIONAL_SERVICE not in options[2]


@pytest.mark.parametrize("option", ["backup_prevent = false", "conditional_service = true"])
def test_backing_resumes_once_nothing_waits_across(paper_toml: str, option: str) -> None:
    c = with_options(paper_toml, {6: option})
    seen = onsets(c, 400, {0: {2, 6}, 150: {2, 4, 5}, 200: {2, 5}})
    backed = 201 if option.startswith("backup") else 151
    assert seen[(6, "Y")] == backed and seen[(5, "G")] == backed + YELLOW + RED and (2, "Y") not in seen


def test_red_end_lock_lets_a_call_in_the_clearance_redirect_on_the_same_side(paper_toml: str) -> None:
    c = Controller(variant(paper_toml, replace={"[timing]": '[timing]\nnext_phase_lock = "red_end"'}))
    c.backup_time = 0
    c.set_control(CALL, {4, 8})
    onsets(c, MIN)
    assert c.yellows == {2, 6} and c.phase_nexts == {4, 8}
    c.set_control(CALL, {3, 4, 8})  # 3 precedes 4 in ring 1 and lies on 4's side of the barrier
    onsets(c, 5)
    assert c.phase_nexts == {3, 8}
    seen = onsets(c, YELLOW + RED)
    assert seen[(3, "G")] == seen[(8, "G")] == MIN + YELLOW + RED and (4, "G") not in seen


def test_red_end_lock_never_redirects_across_the_barrier(paper_toml: str) -> None:
    c = Controller(variant(paper_toml, replace={"[timing]": '[timing]\nnext_phase_lock = "red_end"\n'
                                                            'backup_prevent = false'}))
    c.backup_time = 0
    serve(c, {2, 6})
    c.set_control(CALL, {1, 6})  # ring 1 backs from 2 into 1 (nothing waits across)
    onsets(c, 5)
    assert c.phase_nexts == {1}
    c.set_control(CALL, {1, 3, 6})  # 3 comes before 1 after 2, but across the barrier from the committed 1
    seen = onsets(c, YELLOW + RED)
    assert c.greens == {1, 6} and (3, "G") not in seen


def test_red_end_lock_reads_the_calls_of_the_tick_that_ends_the_red(paper_toml: str) -> None:
    c = Controller(variant(paper_toml, replace={"[timing]": '[timing]\nnext_phase_lock = "red_end"'}))
    c.backup_time = 0
    end_of_red = MIN + YELLOW + RED
    seen = onsets(c, 200, {0: {4, 8}, end_of_red - 1: {3, 4, 8}})
    assert seen[(3, "G")] == seen[(8, "G")] == end_of_red and (4, "G") not in seen


def test_red_end_lock_keeps_a_committed_phase_without_a_better_call(paper_toml: str) -> None:
    c = Controller(variant(paper_toml, replace={"[timing]": '[timing]\nnext_phase_lock = "red_end"'}))
    c.backup_time = 0
    seen = onsets(c, 300, {0: {4, 8}, MIN + 5: set()})
    assert seen[(4, "G")] == seen[(8, "G")] == MIN + YELLOW + RED


def test_dual_entry_serves_the_other_ring_with_the_called_one(paper_toml: str) -> None:
    c = with_options(paper_toml, {p: "dual_entry = true" for p in (2, 4, 6, 8)})
    seen = onsets(c, 200, {0: {4}})
    assert seen[(4, "G")] == seen[(8, "G")] == MIN + YELLOW + RED
    plain = with_options(paper_toml, {})
    seen = onsets(plain, 200, {0: {4}})
    assert seen[(4, "G")] == MIN + YELLOW + RED and (8, "G") not in seen


def test_passage_extends_the_green_after_the_call_drops(paper_toml: str) -> None:
    c = with_options(paper_toml, {2: "passage = 2.5"})
    seen = onsets(c, 300, {0: {2, 6, 4, 8}, 100: {4, 8}})
    # 6 gaps out at once and waits at the barrier; 2 extends 2.5 s past its last call, then both cross.
    assert seen[(2, "Y")] == seen[(6, "Y")] == 100 + 25


def test_a_held_call_extends_to_the_maximum_despite_passage(paper_toml: str) -> None:
    c = with_options(paper_toml, {2: "passage = 2.5", 6: "passage = 2.5"})
    seen = onsets(c, 300, {0: {2, 6}, 50: {2, 6, 4}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 50 + MAX


def test_min_and_max_recall(paper_toml: str) -> None:
    c = with_options(paper_toml, {4: 'recall = "min"', 8: 'recall = "max"'})
    seen = onsets(c, 300, {100: {2}})
    # Served by recall without any call; once 2 is called, 4 (min recall) is ready at once and waits
    # at the barrier while 8 (max recall) extends to its maximum, timed from the start of its green: max
    # recall runs the maximum timer without a conflicting call (NTCIP 1202 phaseMaximum1).
    assert seen[(4, "G")] == seen[(8, "G")] == MIN + YELLOW + RED
    assert seen[(4, "Y")] == seen[(8, "Y")] == MIN + YELLOW + RED + MAX


def test_max_recall_times_the_maximum_without_a_conflicting_call(paper_toml: str) -> None:
    """NTCIP 1202 phaseMaximum1: "In the absence of a serviceable conflicting call the Maximum Green timer shall be
    held reset unless Max Vehicle Recall is enabled for this phase." 2+6 on max recall (20 s) from start-up have
    timed their maximum by 20 s and rest there: a call on 4 at 40 s ends them at the next tick."""
    c = with_options(paper_toml, {2: 'recall = "max"', 6: 'recall = "max"'})
    seen = onsets(c, 500, {400: {4}})
    assert seen[(2, "Y")] == seen[(6, "Y")] == 401
    assert seen[(4, "G")] == 401 + YELLOW + RED


def test_max_recall_under_maximum_2_times_it_from_the_start_of_green(paper_toml: str) -> None:
    """phaseMaximum2 is "held reset" the same way: a ring on Maximum 2 (30 s here) times it from its green's start
    under max recall."""
    c = with_options(paper_toml, {4: 'max2 = 30, recall = "max"', 8: 'max2 = 30, recall = "max"'})
    c.set_max2({1, 2})
    seen = onsets(c, 900, {100: {2}})
    start = MIN + YELLOW + RED
    assert seen[(4, "G")] == seen[(8, "G")] == start
    assert seen[(4, "Y")] == seen[(8, "Y")] == start + 300


def test_soft_recall_yields_to_any_other_demand(paper_toml: str) -> None:
    soft = with_options(paper_toml, {4: 'recall = "soft"'})
    seen = onsets(soft, 400, {0: {2}})
    assert (4, "G") not in seen
    seen = onsets(soft, 400, {400: set()})
    assert seen[(4, "G")] == 401 + YELLOW + RED


def test_a_pedestrian_call_is_served_with_walk_and_clearance(paper_toml: str) -> None:
    c = with_options(paper_toml, {4: "walk = 7, ped_clear = 9"})
    c.set_control(PED_CALL, {4})
    assert c.ped_calls == set()  # latched at the next tick
    c.step()
    assert c.ped_calls == {4}
    walks, clears = [], []
    for _ in range(400):
        c.step()
        walks.append(4 in c.walks)
        clears.append(4 in c.ped_clears)
        assert (4 in c.dont_walks) == (4 not in c.walks | c.ped_clears)
    start = walks.index(True)
    assert sum(walks) == 70 and sum(clears) == 90 and clears.index(True) == start + 70
    assert c.ped_calls == set()


def test_the_green_lasts_at_least_walk_plus_ped_clear(paper_toml: str) -> None:
    c = with_options(paper_toml, {4: "walk = 7, ped_clear = 9"})
    c.set_control(PED_CALL, {4})
    seen = onsets(c, 400, {60: {1}})
    assert seen[(4, "Y")] - seen[(4, "G")] == 160


def test_ped_omit_keeps_the_walk_from_being_served(paper_toml: str) -> None:
    c = with_options(paper_toml, {4: "walk = 7, ped_clear = 9"})
    c.set_control(PED_CALL, {4})
    c.set_control(PED_OMIT, {4})
    seen = onsets(c, 300)
    assert (4, "G") not in seen and c.ped_calls == set()


def _pushed_during_green(paper_toml: str, options: str, calls: set[int], push: int = 100,
                         held: int = 1) -> tuple[Controller, list]:
    """2+6 resting on ``calls``; push button 1 (phase 2) pressed for ``held`` ticks from ``push``; each tick's walk,
    pedestrian clearance and green of phase 2 for 40 s."""
    text = paper_toml.replace("\n2 = { ", f"\n2 = {{ {options}, ", 1) + "\n[pedestrian_detectors]\n1 = 2\n"
    c = Controller(parse(text, "recycle.toml"))
    c.backup_time = 0
    c.set_control(CALL, calls)
    seen = []
    for _ in range(400):
        c.set_ped_actuations({1} if push <= c.tick < push + held else ())
        c.step()
        seen.append((2 in c.walks, 2 in c.ped_clears, 2 in c.greens))
    return c, seen


def test_pedestrian_recycle_starts_a_walk_within_the_running_green(paper_toml: str) -> None:
    """``ped_recycle``: the push at 10 s, in the middle of 2's green (resting, nothing conflicting), starts its walk
    at once: 7 s of walk, 9 s of clearance, the green kept all along; the call is answered."""
    c, seen = _pushed_during_green(paper_toml, "walk = 7, ped_clear = 9, ped_recycle = true", {2, 6})
    walks = [w for w, _, _ in seen]
    start = walks.index(True)
    assert start == 100 and sum(walks) == 70 and sum(cl for _, cl, _ in seen) == 90
    assert all(g for _, _, g in seen) and c.ped_calls == frozenset()


def test_a_push_held_into_the_walk_it_brought_is_answered_by_that_walk(paper_toml: str) -> None:
    """The MaxTime of issue 35's 638572533917628534.xml: four pushes held 0.1-0.7 s into the walk they brought, with no
    other push before their phase's next green, and no walk at that green. Held 0.5 s here, the recycled walk answers
    it: one walk, no call left. Held past the walk (a stuck button) it calls again: a second walk after the first's
    clearance."""
    c, seen = _pushed_during_green(paper_toml, "walk = 7, ped_clear = 9, ped_recycle = true", {2, 6}, held=5)
    assert sum(w for w, _, _ in seen) == 70 and c.ped_calls == frozenset()
    c, seen = _pushed_during_green(paper_toml, "walk = 7, ped_clear = 9, ped_recycle = true", {2, 6}, held=75)
    assert sum(w for w, _, _ in seen) == 140


def test_without_pedestrian_recycle_the_walk_waits_for_the_next_green(paper_toml: str) -> None:
    c, seen = _pushed_during_green(paper_toml, "walk = 7, ped_clear = 9", {2, 6})
    assert not any(w or cl for w, cl, _ in seen) and c.ped_calls == {2}


def test_no_recycle_where_the_walk_would_outlast_the_maximum(paper_toml: str) -> None:
    """4 called from the start: 2's maximum (20 s) times from 0 and has 10 s left at the push, less than the walk and
    its clearance (16 s): no walk in this green, 2 maxes out at 20 s and the call waits for the next one."""
    c, seen = _pushed_during_green(paper_toml, "walk = 7, ped_clear = 9, ped_recycle = true", {2, 4, 6})
    greens = [g for _, _, g in seen]
    assert not any(w or cl for w, cl, _ in seen[:greens.index(False)]) and greens.index(False) == MAX - 1
    assert 2 in c.ped_calls or any(w for w, _, _ in seen[greens.index(False):])


def test_red_revert_delays_the_return_of_a_phase(paper_toml: str) -> None:
    c = with_options(paper_toml, {8: "backup_prevent = true", 3: "red_revert = 5.0"})
    onsets(c, 200, {0: {3, 8}})
    c.set_control(CALL, {3, 7})
    trace = record(c, MAX + YELLOW + 60)
    # The group restarts for 7 (8 may not back up); 3 returns after 5 s of red, not its 2 s red clearance.
    assert runs(trace, 3) == [("G", MAX - 1), ("Y", YELLOW), ("r", 50), ("G", 11)]
    assert runs(trace, 7) == [("r", MAX - 1 + YELLOW + RED), ("G", 41)]


def test_the_demo_shows_pedestrian_intervals_and_phase_next(paper_config: IntersectionConfig) -> None:
    from emulator import demo

    config = demo.with_pedestrians(paper_config)
    rows = demo.run(config)
    walk = next(r for r in rows if r.walks)
    clear = next(r for r in rows if r.ped_clears)
    assert walk.walks == clear.ped_clears == {4}
    assert round(clear.t - walk.t, 1) == demo.DEMO_WALK
    assert any(r.yellows == {2, 6} and r.nexts == {3, 7} for r in rows)
    text = demo.render(rows, config)
    assert " W " in text and " P " in text and "[3,7]" in text


def test_gap_reduction_lowers_the_allowable_gap_while_conflicting_demand_waits(paper_toml: str) -> None:
    """NTCIP 1202 phaseTimeBeforeReduction: the TBR period "shall begin when the phase is Green and there is a
    serviceable conflicting call", then "the linear reduction of the allowable gap from the Passage Time shall
    begin"; phaseTimeToReduce sets its rate and past phaseMinimumGap "the allowable gap shall remain fixed". 2 on
    passage 3 s, reduced after 5 s of the call on 4 over 10 s to 1 s: its call drops at 10 s, 5 s into the
    reduction, where the allowable gap is 2 s (3 - 2 * 5 / 10) and falls on while the gap times: 2 gaps out 1.7 s
    later (the first tick the gap reaches it), not 3 s; a call dropping after 15 s+ leaves the minimum gap, 1 s."""
    reduced = "passage = 3, time_before_reduction = 5, time_to_reduce = 10, min_gap = 1"
    c = with_options(paper_toml, {2: reduced})
    seen = onsets(c, 400, {0: {2, 4}, 100: {4}})
    assert seen[(2, "Y")] == 100 + 17
    late = with_options(paper_toml, {2: reduced.replace("passage = 3", "passage = 3, max_green = 40")})
    seen = onsets(late, 600, {0: {2, 4}, 200: {4}})
    assert seen[(2, "Y")] == 200 + 10
    plain = with_options(paper_toml, {2: "passage = 3"})
    seen = onsets(plain, 400, {0: {2, 4}, 100: {4}})
    assert seen[(2, "Y")] == 100 + 30


def test_quiet_time_stops_where_the_reduced_gap_runs_out(paper_toml: str) -> None:
    """The same green advanced over (quiet ticks skipped at once) ends where stepping it does: the gap timer meets
    the falling allowable gap 1.7 s after the call drops, not after the passage."""
    c = with_options(paper_toml, {2: "passage = 3, time_before_reduction = 5, time_to_reduce = 10, min_gap = 1"})
    c.set_control(CALL, {2, 4})
    c.advance(100)
    c.set_control(CALL, {4})
    c.advance(16)
    assert 2 in c.greens
    c.advance(1)
    assert 2 in c.yellows
