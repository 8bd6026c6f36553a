"""Coordinated-actuated operation of the controller model, on the shipped four-leg's pattern 1.

Pattern 1: cycle 70 s, offset 0, coordinated phases 2 and 6, splits 14/28/12/16 (ring 1) and 12/30/13/15
(ring 2), each with its 5 s clearance, local zero at the start of 6's green (``lead_green``). Laid out in
ring order from the earliest coordinated green: 6 starts at 0 s and 2 at 2 s (5's split is 2 s shorter than
1's); the force-off points are 2 and 6 at 25 s (their yield point), 3 at 37 s, 7 at 38 s, 4 and 8 at 53 s,
5 at 65 s and 1 at 67 s. Times here are controller ticks (0.1 s) from power-up, when the system's cycle is
at its zero.
"""

from __future__ import annotations

import dataclasses
import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.agent.mib import MibView
from emulator.model.controller import Controller, Interval
from hils.protocol.config import (
    FREE,
    Correction,
    ForceOff,
    IntersectionConfig,
    ScheduleEntry,
    from_dict,
    load,
)
from hils.protocol.ntcip import (
    COORD_CYCLE_STATUS,
    COORD_PATTERN_STATUS,
    COORD_SYNC_STATUS,
    LOCAL_FREE_STATUS,
    PATTERN_TABLE,
    SPLIT_TABLE,
    SYSTEM_PATTERN_CONTROL,
    ControlColumn,
    ErrorStatus,
    LocalFreeStatus,
    PatternColumn,
    SnmpError,
    SplitColumn,
    SplitMode,
)
from tests.emulator.model.test_controller_properties import configs

CALL = ControlColumn.VEH_CALL
CYCLE = 700
FORCE_OFF = {2: 250, 6: 250, 3: 370, 7: 380, 4: 530, 8: 530, 5: 650, 1: 670}


def plan(**changes: object) -> IntersectionConfig:
    """The shipped four-leg running pattern 1 from power-up, with coordination settings changed."""
    cfg = load().planned()
    return dataclasses.replace(cfg, coordination=dataclasses.replace(cfg.coordination, **changes))


def run(c: Controller, ticks: int, calls: dict[int, set[int]] | None = None) -> list[tuple[int, int, str]]:
    """Step ``ticks`` ticks with the calls due at each tick; the (tick, phase, colour) onsets seen."""
    out, shown = [], {}
    for _ in range(ticks):
        if calls and c.tick in calls:
            c.set_control(CALL, calls[c.tick])
        c.step()
        now = {p: "G" if p in c.greens else "Y" if p in c.yellows else "r" for p in c.config.phases}
        out += [(c.tick, p, v) for p, v in now.items() if shown.get(p, v) != v]
        shown = now
    return out


def onsets(seen: list[tuple[int, int, str]], phase: int, colour: str) -> list[int]:
    return [t for t, p, v in seen if p == phase and v == colour]


@pytest.fixture
def coordinated() -> Controller:
    c = Controller(plan())
    c.backup_time = 0
    return c


def test_every_phase_called_ends_at_its_force_off_point_every_cycle(coordinated: Controller) -> None:
    seen = run(coordinated, 3 * CYCLE + 10, {0: set(range(1, 9))})
    for p, point in FORCE_OFF.items():
        assert onsets(seen, p, "Y") == [point + k * CYCLE for k in range(3 + (p in (2, 6)))
                                        if point + k * CYCLE <= 3 * CYCLE + 10], p


def test_the_coordinated_phases_rest_without_gapping_out(coordinated: Controller) -> None:
    """No call at all (the coordinated phases are on recall in coordination): 2+6 stay green through cycles."""
    seen = run(coordinated, 3 * CYCLE)
    assert seen == [] and coordinated.greens == {2, 6}


def test_a_call_waits_for_the_yield_point_and_gets_the_time_of_a_skipped_phase(coordinated: Controller) -> None:
    """4 called at 5 s: 2+6 hold to their yield point and past it while 3 (before 4, not called) could still
    be served (its permissive period); 4 then runs to its own force-off point with 3's time (fixed)."""
    seen = run(coordinated, CYCLE, {50: {4}})
    assert onsets(seen, 2, "Y") == onsets(seen, 6, "Y") == [291]  # 3 no longer fits after 29 s
    assert onsets(seen, 4, "G") == [341] and onsets(seen, 4, "Y") == [FORCE_OFF[4]]


def test_floating_force_offs_hold_a_phase_to_its_split(coordinated: Controller) -> None:
    c = Controller(plan(force_off=ForceOff.FLOATING))
    c.backup_time = 0
    seen = run(c, CYCLE, {50: {4}})
    assert onsets(seen, 4, "G") == [341] and onsets(seen, 4, "Y") == [341 + 110]  # split 16 s less 5 s clearance


def test_a_gapped_out_phase_returns_early_to_the_coordinated_phases(coordinated: Controller) -> None:
    seen = run(coordinated, CYCLE, {50: {4}, 400: set()})
    assert onsets(seen, 4, "Y") == [401] and onsets(seen, 2, "G") == onsets(seen, 6, "G") == [451]


def test_a_phase_that_can_no_longer_fit_is_skipped_until_the_next_cycle(coordinated: Controller) -> None:
    """3 called at 33 s: its force-off point (37 s) leaves no room for its minimum after the clearance."""
    seen = run(coordinated, 2 * CYCLE, {330: {3}})
    assert onsets(seen, 3, "G") == [CYCLE + 300]


def test_system_pattern_control_starts_a_pattern_at_once_and_free_ends_it() -> None:
    c = Controller(load())  # the shipped four-leg: free at power-up
    mib = MibView(c)
    assert mib.get(COORD_PATTERN_STATUS.instance()) == FREE
    run(c, 95, {0: {2, 6}})
    mib.set_many([(SYSTEM_PATTERN_CONTROL.instance(), 1)])
    assert mib.get(COORD_PATTERN_STATUS.instance()) == 1  # from free: at once, on the system's sync
    assert mib.get(LOCAL_FREE_STATUS.instance()) == LocalFreeStatus.NOT_FREE
    run(c, 5)
    assert mib.get(COORD_SYNC_STATUS.instance()) == 10 and mib.get(COORD_CYCLE_STATUS.instance()) == 60
    mib.set_many([(SYSTEM_PATTERN_CONTROL.instance(), 254)])
    assert mib.get(COORD_PATTERN_STATUS.instance()) == FREE
    assert mib.get(LOCAL_FREE_STATUS.instance()) == LocalFreeStatus.COMMAND_FREE


@pytest.mark.parametrize(("number", "status"), [(7, LocalFreeStatus.BAD_PLAN), (255, LocalFreeStatus.OTHER)])
def test_a_pattern_that_cannot_run_gives_free_and_says_why(number: int, status: LocalFreeStatus) -> None:
    c = Controller(load())
    mib = MibView(c)
    mib.set_many([(SYSTEM_PATTERN_CONTROL.instance(), number)])
    assert mib.get(COORD_PATTERN_STATUS.instance()) == FREE and mib.get(LOCAL_FREE_STATUS.instance()) == status


def test_a_split_set_that_breaks_the_cycle_runs_free_from_the_next_local_zero(coordinated: Controller) -> None:
    mib = MibView(coordinated)
    mib.set_many([(SPLIT_TABLE[SplitColumn.TIME].instance(1, 4), 20)])  # ring 1 now adds up to 74 s
    run(coordinated, CYCLE - 10)
    assert mib.get(COORD_PATTERN_STATUS.instance()) == 1  # the running pattern finishes its cycle
    run(coordinated, 20)
    assert mib.get(COORD_PATTERN_STATUS.instance()) == FREE
    assert mib.get(LOCAL_FREE_STATUS.instance()) == LocalFreeStatus.SPLIT_OVERRUN


def test_split_mode_omit_drops_a_phase_while_the_pattern_runs(coordinated: Controller) -> None:
    mib = MibView(coordinated)
    mib.set_many([(SPLIT_TABLE[SplitColumn.MODE].instance(1, 4), int(SplitMode.OMITTED))])
    seen = run(coordinated, 3 * CYCLE, {0: {4}})
    assert onsets(seen, 4, "G") == [341]  # served in the cycle running; from the next local zero, omitted


def test_pattern_table_sets_are_range_checked(coordinated: Controller) -> None:
    mib = MibView(coordinated)
    with pytest.raises(SnmpError) as info:
        mib.set_many([(PATTERN_TABLE[PatternColumn.CYCLE_TIME].instance(1), 256)])
    assert info.value.status is ErrorStatus.WRONG_VALUE
    assert mib.get(PATTERN_TABLE[PatternColumn.CYCLE_TIME].instance(1)) == 70


def test_backup_mode_hands_the_pattern_back_to_the_local_plan() -> None:
    c = Controller(load())
    c.backup_time = 1
    c.set_pattern_control(1)
    assert c.coordinator.running == 1
    run(c, 11)
    assert c.coordinator.command == 0 and c.coordinator.running == FREE  # the local plan: free


def test_the_time_of_day_schedule_changes_plans() -> None:
    cfg = plan(pattern=FREE, schedule=(ScheduleEntry(60, 1), ScheduleEntry(300, FREE)))
    c = Controller(cfg)
    run(c, 599)
    assert c.coordinator.running == FREE
    run(c, 1)
    assert c.coordinator.running == 1
    run(c, 2400)
    assert c.coordinator.running == FREE


def _with_offset(correction: Correction, offset: int) -> IntersectionConfig:
    """Pattern 1 at power-up and a pattern 2, the same but for its offset."""
    cfg = plan(correction=correction)
    one = cfg.coordination.patterns[1]
    two = dataclasses.replace(one, number=2, offset=offset)
    return dataclasses.replace(cfg, coordination=dataclasses.replace(cfg.coordination,
                                                                     patterns={1: one, 2: two}))


@pytest.mark.parametrize("correction", list(Correction))
@pytest.mark.parametrize("offset", [10, 35, 60])
def test_a_new_offset_is_reached_within_the_corrections_bound(correction: Correction, offset: int) -> None:
    """Pattern 2 is pattern 1 with another offset: after the change the local cycle regains the system's sync
    within the bound of its correction, each corrected cycle changed by at most a fifth (add, shortway)."""
    c = Controller(_with_offset(correction, offset))
    c.backup_time = 0
    run(c, 100, {0: set(range(1, 9))})
    c.set_pattern_control(2)
    co = c.coordinator
    while co.running != 2:
        run(c, 1)
    lag = co.lag
    assert lag == 10 * offset  # the timer restarted at its zero; the system's zero comes an offset later
    bound = co.plan.correction_cycles(lag, co.correction)
    zeros = [c.tick]
    for _ in range((bound + 1) * (2 * CYCLE)):
        run(c, 1)
        if 0 in co.passed:
            zeros.append(c.tick)
        if co.lag == 0:
            break
    assert co.lag == 0 and len(zeros) - 1 <= bound, (correction, offset, bound, zeros)
    lengths = [b - a for a, b in itertools.pairwise(zeros)]
    if correction is not Correction.DWELL:
        assert all(CYCLE - CYCLE // 5 <= n <= CYCLE + CYCLE // 5 for n in lengths), lengths


# --- properties over random coordinated configs ---------------------------------------------------------------


def _running(config: IntersectionConfig, **changes: object) -> IntersectionConfig:
    """The config's first pattern in effect from power-up, no time-of-day change, coordination settings changed."""
    co = config.coordination
    first = min(co.patterns)
    return dataclasses.replace(config, coordination=dataclasses.replace(co, pattern=first, schedule=(), **changes))


@settings(max_examples=40, deadline=None)
@given(config=configs(coordinated=True), calls=st.frozensets(st.sampled_from(range(1, 9))),
       changes=st.lists(st.tuples(st.integers(0, 3000), st.frozensets(st.sampled_from(range(1, 9)))), max_size=4))
@pytest.mark.slow
def test_coordinated_phases_are_served_every_cycle_and_fixed_force_offs_hold(
        config: IntersectionConfig, calls: frozenset[int], changes: list[tuple[int, frozenset[int]]]) -> None:
    """Whatever the calls: every cycle (local zero to local zero) shows both coordinated phases green once the
    controller is in step (its coordinated phases served once: a unit that powers up in its start-up phases just
    before a local zero finishes their barrier group first, a transition), and a non-coordinated green past its
    force-off point ends within one tick, unless its ring waits at the barrier for the other ring's green (it may
    not cross alone)."""
    c = Controller(_running(config, force_off=ForceOff.FIXED))
    c.backup_time = 0
    co = c.coordinator
    plan = co.plan
    assert plan is not None and co.running == plan.number
    c.set_control(CALL, calls)
    due = dict(changes)
    seen: set[int] = set()
    cycles = 0
    ever: set[int] = set()  # every phase that has shown green: the controller is in step once the coordinated have
    overdue: dict[int, int] = {}  # ring -> the last tick its green may show after passing its force-off point
    late: dict[int, bool] = {}  # ring -> its green started past its force-off point (it ends at its minimum)
    shown = {r.number: r.interval for r in c.rings}
    late = {r.number: c.coordinated.forced[r.number] for r in c.rings if r.interval is Interval.GREEN}
    for _ in range(6 * plan.cycle):
        if c.tick in due:
            c.set_control(CALL, due[c.tick])
        c.step()
        if 0 in co.passed:
            if cycles:  # a whole cycle seen (the first zero closes a partial one)
                assert set(plan.coord.values()) <= seen, f"cycle {cycles} served {sorted(seen)}"
            cycles, seen = cycles + int(cycles > 0 or set(plan.coord.values()) <= ever), set()
        seen |= c.greens
        ever |= c.greens
        for r in c.rings:
            p = r.phase
            if r.interval is Interval.GREEN and shown[r.number] is not Interval.GREEN:
                late[r.number] = c.coordinated.forced[r.number]
            shown[r.number] = r.interval
            if r.interval is not Interval.GREEN or p in plan.coord.values() or late[r.number]:
                overdue.pop(r.number, None)
                continue
            if r.number in overdue and overdue[r.number] < c.tick:
                other = c.rings[2 - r.number]
                waits = other.interval is not Interval.DWELL and c.config.barrier_of(other.phase) == c.group
                assert waits, (f"phase {p} green at tick {c.tick}, past its force-off at {overdue[r.number] - 1}",
                               [(x.phase, x.interval, x.ticks, x.target, c.coordinated.forced[x.number])
                                for x in c.rings], co.timer,
                               dict(plan.force_off), c.calls, c.config.phases[p])
            if plan.force_off[p] in co.passed:
                overdue.setdefault(r.number, c.tick + 1)
    assert cycles >= 4


def _backup_prevented_after_the_coordinated_phase() -> IntersectionConfig:
    """The case the property below once shrank to: coordinated phases 1 and 5 (cycle 30 s, local zero at 1's
    green), 3 and 4 called, ``backup_prevent`` on 3, and phase 7 (on pedestrian recall) clearing in 4.2 s against
    the others' 3.5 s. 4's split no longer fits once both rings have cleared, so ring 1 leaves 3 for 1, which
    backup prevent allows only through the barrier."""
    short = {"min_green": 1, "max_green": 1, "yellow": 3.0, "red_clear": 0.5}
    phases = {str(p): dict(short) for p in range(1, 9)}
    phases["3"]["backup_prevent"] = True
    phases["7"] = {"min_green": 1, "max_green": 2, "yellow": 3.0, "red_clear": 1.2, "walk": 1, "ped_clear": 1,
                   "recall": "ped"}
    return from_dict({
        "name": "backup prevent", "phases": phases,
        "structure": {"rings": [[1, 2, 3, 4], [5, 6, 7, 8]], "barriers": [[1, 2, 3, 5, 6, 7], [4, 8]],
                      "sequence": [[1, 5], [4, 8]],
                      "pairs": [[a, b] for a in (1, 2, 3) for b in (5, 6, 7)] + [[4, 8]]},
        "coordination": {"pattern": 1, "force_off": "fixed", "patterns": [{
            "number": 1, "cycle": 30, "offset": 0, "coord_phases": [1, 5],
            "splits": {"1": 12, "2": 5, "3": 8, "4": 5, "5": 12, "6": 5, "7": 8, "8": 5}}]},
    }, "backup_prevent.toml")


def test_a_ring_that_may_not_back_restarts_its_group_and_the_coordinated_phases_are_served_every_cycle() -> None:
    """Before: ring 2 backed from 7 into its coordinated phase 5 while ring 1's 3, forced off, could neither back
    into 1 (backup prevent) nor cross alone; 3 then held until 5's yield point a cycle later and 1 was skipped every
    other cycle. Now ring 2 does not back while ring 1 must go through the barrier: both rings leave 3 and 7 at 3's
    force-off point (21.5 s) and restart the group, and every cycle shows 1 and 5."""
    c = Controller(_backup_prevented_after_the_coordinated_phase())
    c.backup_time = 0
    c.set_control(CALL, {3, 4})
    seen = run(c, 6 * 300)
    cycles = range(6)
    assert onsets(seen, 3, "Y") == onsets(seen, 7, "Y") == [215 + 300 * k for k in cycles]
    assert onsets(seen, 1, "G") == [250 + 300 * k for k in cycles]  # after 3's clearance
    assert onsets(seen, 5, "G") == [257 + 300 * k for k in cycles]  # after 7's longer one
    # 4 is skipped: once both rings have cleared (at 25.7 s) its minimum no longer ends by its force-off (26.5 s)
    assert onsets(seen, 4, "G") == []


def _walks_outlasting_a_late_start() -> IntersectionConfig:
    """The case the property above once shrank to: every phase on pedestrian recall, its walk and pedestrian
    clearance 22 s of a 28 s split; the unit powers up at 100 s of a 140 s cycle, 12 s before phase 6's
    force-off point (local zero at the coordinated 2+7's yellow, ``offset_reference = "yellow"``)."""
    timing = {"min_green": 2, "max_green": 22, "yellow": 3.0, "red_clear": 0.5, "walk": 1, "ped_clear": 21,
              "recall": "ped"}
    return from_dict({
        "name": "late walk", "phases": {str(p): dict(timing) for p in range(1, 9)},
        "structure": {"rings": [[1, 2, 3, 4], [5, 6, 7, 8]], "barriers": [[1, 5, 6], [2, 3, 4, 7, 8]],
                      "sequence": [[1, 5], [4, 8]],
                      "pairs": [[1, 5], [1, 6], [2, 7], [2, 8], [3, 7], [3, 8], [4, 7], [4, 8]]},
        "coordination": {"pattern": 1, "force_off": "fixed", "offset_reference": "yellow", "patterns": [{
            "number": 1, "cycle": 140, "offset": 40, "coord_phases": [2, 7],
            "splits": {"1": 56, "5": 28, "6": 28, "2": 28, "3": 28, "4": 28, "7": 28, "8": 56}}]},
    }, "late_walk.toml")


@pytest.mark.parametrize("called", [False, True])
def test_a_walk_that_cannot_end_by_the_force_off_waits_for_the_next_cycle(called: bool) -> None:
    """Before: phase 6 started at power-up with its walk, 12 s before its force-off point, and its walk and
    pedestrian clearance held the green 10 s past it. Now its pedestrian call waits for a cycle where they fit
    (a controller without stop-in-walk keeps to its splits): on pedestrian recall alone 6 is skipped and the rings
    cross to 2+7; with a vehicle call too, 6 is served without its walk, to its force-off point. Either way every
    green ends by its force-off point, and 6's walk comes with its next service."""
    c = Controller(_walks_outlasting_a_late_start())
    c.backup_time = 0
    plan, co = c.coordinator.plan, c.coordinator
    if called:
        c.set_control(CALL, {6})
    walked: dict[int, list[int]] = {}
    for _ in range(3 * 1400):
        c.step()
        for r in c.rings:
            if r.interval is Interval.GREEN and r.ticks == 0:
                walked.setdefault(r.phase, []).append(r.walk)
            if r.interval is Interval.GREEN and r.phase not in plan.coord.values():
                assert co.timer != plan.force_off[r.phase] + 1, (c.tick, r.phase, r.ticks)  # never past it
    assert walked[6] == ([0] if called else []) + [10, 10, 10]  # the walk, in ticks, of each service
    assert all(w == [10, 10, 10] for p, w in walked.items() if p != 6)


@settings(max_examples=40, deadline=None)
@given(config=configs(coordinated=True), offset=st.integers(1, 254), at=st.integers(0, 2000),
       correction=st.sampled_from(list(Correction)), calls=st.frozensets(st.sampled_from(range(1, 9))))
def test_a_pattern_change_regains_the_offset_within_its_corrections_bound(
        config: IntersectionConfig, offset: int, at: int, correction: Correction, calls: frozenset[int]) -> None:
    """The running pattern again with another offset, called at a random instant: the local cycle reaches the
    system's sync within the bound its correction mode gives (dwell one cycle; add and shortway a fifth of the
    cycle per cycle, shortway the shorter way)."""
    cfg = _running(config, correction=correction)
    one = cfg.coordination.patterns[cfg.coordination.pattern]
    two = dataclasses.replace(one, number=one.number + 1 if one.number < 253 else 1, offset=offset % one.cycle)
    cfg = dataclasses.replace(cfg, coordination=dataclasses.replace(cfg.coordination,
                                                                    patterns={one.number: one, two.number: two}))
    c = Controller(cfg)
    c.backup_time = 0
    c.set_control(CALL, calls)
    co = c.coordinator
    for _ in range(at):
        c.step()
    c.set_pattern_control(two.number)
    cycle = 10 * one.cycle  # ticks
    for _ in range(cycle + 1):  # it starts at the running pattern's next local zero
        c.step()
        if co.running == two.number:
            break
    assert co.running == two.number
    bound = co.plan.correction_cycles(co.lag, co.correction)
    zeros = 0
    for _ in range((bound + 2) * 2 * cycle):
        if co.lag == 0:
            break
        c.step()
        zeros += 0 in co.passed
    assert co.lag == 0 and zeros <= bound, (correction, bound, zeros)


def test_a_pretimed_plan_serves_every_split_whole_every_cycle_without_a_call() -> None:
    """``--agent fixed-time``: pattern 1 with every phase on max recall (splitMode 4 in the split table) runs as a
    fixed-time signal: with no call at all each phase is green for its split less its 5 s clearance, once a cycle."""
    c = Controller(load().pretimed())
    c.backup_time = 0
    mib = MibView(c)
    assert {p: mib.get(SPLIT_TABLE[SplitColumn.MODE].instance(1, p)) for p in c.config.phases} == \
        dict.fromkeys(c.config.phases, int(SplitMode.MAX_RECALL))
    seen = run(c, 4 * CYCLE)
    splits = c.config.coordination.patterns[1].splits
    for p, split in splits.items():
        yellows = onsets(seen, p, "Y")[-3:]
        greens = [max(g for g in onsets(seen, p, "G") if g < y) for y in yellows]
        assert [b - a for a, b in itertools.pairwise(greens)] == [CYCLE, CYCLE], p
        assert [y - g for g, y in zip(greens, yellows, strict=True)] == [10 * split - 50] * 3, p
        assert all(y % CYCLE == FORCE_OFF[p] for y in yellows), p  # at its force-off point, fixed in the cycle
