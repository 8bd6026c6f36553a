"""Overlaps: the shipped city four-leg's right-turn overlaps and flashing yellow arrows, trailing and
minus-green-yellow overlaps, their NTCIP objects, the conflict monitor, SUMO's links and the dashboard.

The city four-leg (``hils/data/four_leg_city.toml``): the paper's phases (min green 3 s, yellow 3 s, red
clearance 2 s; start-up in 2+6), right-turn overlaps A {8, 5}, B {4, 1}, C {6, 3}, D {2, 7}, flashing yellow
arrows E (protected 1, permissive 2), F (5, 6), G (3, 4), H (7, 8). Times are controller ticks (0.1 s).
"""

from __future__ import annotations

import copy
import itertools

import pytest

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from emulator.model.monitor import Lamps, Monitor
from emulator.model.overlaps import Show
from hils.dashboard.board import Board
from hils.protocol.config import ConfigError, IntersectionConfig, load, parse
from hils.protocol.conflict import first_conflict
from hils.protocol.hires import EventCode
from hils.protocol.ntcip import (
    MAX_OVERLAP_STATUS_GROUPS,
    MAX_OVERLAPS,
    OVERLAP_STATUS_TABLE,
    OVERLAP_TABLE,
    ControlColumn,
    ErrorStatus,
    OverlapColumn,
    OverlapState,
    OverlapStatusColumn,
    OverlapType,
    SignalState,
    SnmpError,
    UnitFlashStatus,
    Version,
    signal_oids,
)
from hils.sim.network import data_path, derive_phase_map, read_net

CALL = ControlColumn.VEH_CALL
A, B, C, D, E, F, G, H = range(1, 9)


def city(extra: str = "", timing: str = "") -> IntersectionConfig:
    """The shipped city four-leg, its overlap table replaced by ``extra`` when given, ``timing`` added to [timing]."""
    text = data_path("four_leg_city.toml").read_text()
    if extra:
        text = text[:text.index("[overlaps]")] + "[overlaps]\n" + extra
    if timing:
        text = text.replace("[timing]", f"[timing]\n{timing}", 1)
    return parse(text, "city.toml")


def watch(c: Controller, ticks: int, calls: dict[int, set[int]] | None = None) -> dict[str, list[tuple[int, str]]]:
    """Step ``ticks`` ticks with the calls due at each tick; per phase ("2") and overlap ("A") the (tick,
    display) changes, overlaps as the controller's own display (green, yellow, flashing, trail_green, ...)."""
    out: dict[str, list[tuple[int, str]]] = {}
    last: dict[str, str] = {}
    for _ in range(ticks):
        if calls and c.tick in calls:
            c.set_control(CALL, calls[c.tick])
        c.step()
        now = {str(p): "G" if p in c.greens else "Y" if p in c.yellows else "r" for p in c.config.phases}
        now |= {c.config.overlaps[n].letter: str(s) for n, s in c.overlaps.shown.items()}
        for k, v in now.items():
            if last.get(k) != v:
                out.setdefault(k, []).append((c.tick, v))
        last = now
        assert c.flash_status is UnitFlashStatus.NOT_FLASH, f"flash at tick {c.tick}"
    return out


def test_a_right_turn_overlap_is_green_with_its_through_and_clears_with_it() -> None:
    c = Controller(city())
    # 2+6 at start-up; 4+8 called: the rings cross at 3 s (min green), 8 green at 8 s (clearance 5 s); 2+6
    # called back at 15 s: 8 gaps out.
    seen = watch(c, 300, {0: {4, 8}, 150: {2, 6}})
    assert seen["8"][:4] == [(1, "r"), (80, "G"), (151, "Y"), (181, "r")]
    # A follows 8 (2+6 next: not included), yellow with its yellow, red with its red clearance.
    assert seen["A"][:4] == [(1, "red"), (80, "green"), (151, "yellow"), (181, "red")]
    # D (2 and 7) was green with 2 from power-up, cleared with it, and is green with it again.
    assert seen["D"][:4] == [(1, "green"), (30, "yellow"), (60, "red"), (201, "green")]


def test_an_overlap_stays_green_while_its_ring_moves_between_included_phases() -> None:
    c = Controller(city())
    # 4+8, then 1+5: ring 2 goes from 8 straight to 5, both in A: A stays green through 8's clearance.
    seen = watch(c, 400, {0: {4, 8}, 150: {1, 5}})
    assert seen["8"][1:4] == [(80, "G"), (151, "Y"), (181, "r")]
    assert seen["5"][1:2] == [(201, "G")]
    assert seen["A"] == [(1, "red"), (80, "green")]
    assert 5 in c.greens and A in c.overlap_greens


def test_a_trailing_overlap_outlasts_its_phase_and_conflicting_phases_wait_for_it() -> None:
    c = Controller(city('A = { included = [2], trail_green = 4, trail_yellow = 3.5, trail_red = 1.5 }\n'))
    seen = watch(c, 400, {0: {4, 8}})
    # 2 ends its minimum at 3 s: yellow from 30, red clearance from 60, over at 80. The overlap trails 4 s of
    # green from 30, then 3.5 s of yellow and 1.5 s of red: clear at 120. 4 and 8 conflict with it (they never
    # run beside 2): they start when it has cleared, as a phase starts when a red clearance ends.
    assert seen["2"][:3] == [(1, "G"), (30, "Y"), (60, "r")]
    assert seen["A"] == [(1, "green"), (30, "trail_green"), (70, "trail_yellow"), (105, "trail_red"),
                         (120, "red")]
    assert seen["4"][1] == (120, "G") and seen["8"][1] == (120, "G")
    # Over NTCIP the trailing intervals are the overlap's green, yellow and red.
    c2 = Controller(c.config)
    watch(c2, 50, {0: {4, 8}})
    assert c2.overlap_greens == {1} and c2.greens == frozenset()


def test_a_phase_that_runs_beside_the_trailing_overlap_does_not_wait() -> None:
    c = Controller(city('A = { included = [2], trail_green = 4 }\n'))
    # 1 and 5 called: the rings back from 2+6 into them. 5 runs beside 2, so beside the trailing overlap, and
    # starts when 6 has cleared; 1 conflicts with it and waits for its 4 s green and 3 s yellow (no red).
    seen = watch(c, 200, {0: {1, 5}})
    assert seen["A"] == [(1, "green"), (30, "trail_green"), (70, "trail_yellow"), (100, "red")]
    assert seen["5"][1] == (80, "G") and seen["1"][1] == (100, "G")


def test_minus_green_yellow_clears_before_its_modifier_starts_and_is_red_while_it_shows() -> None:
    c = Controller(city('A = { type = "minus_green_yellow", included = [2], modifiers = [5] }\n',
                        "backup_prevent = false"))
    # 2+6; 5 called with 2: ring 2 backs from 6 into 5 (nothing across the barrier, Naztec's backing) while 2 rests.
    seen = watch(c, 300, {0: {2, 5}})
    assert seen["2"] == [(1, "G")] and seen["5"][1] == (80, "G")
    # Green with 2 while 5 is not green; 5 committed at 6's yellow (tick 30): A times its own yellow (3 s) and
    # is red before 5 starts, never green to red; red ("whenever the overlap green and yellow are not ON") while
    # 5 shows.
    assert seen["A"][:3] == [(1, "green"), (30, "trail_yellow"), (60, "red")]
    assert all(v == "red" for _, v in seen["A"][2:])


def test_a_modifier_that_would_start_at_once_waits_for_the_minus_green_yellow_overlap_to_clear() -> None:
    c = Controller(city('A = { type = "minus_green_yellow", included = [2], modifiers = [5], trail_yellow = 4.0,'
                        ' trail_red = 1.0 }\n', "backup_prevent = false"))
    # 5 called with 2 and omitted during 6's clearance: ring 2 rests in red with nothing committed, and A is
    # green with 2 again. When the omit goes, ring 2 commits 5 at once: it would start the next tick beside A.
    c.set_control(CALL, {2, 5})
    watch(c, 40)
    c.set_control(ControlColumn.PHASE_OMIT, {5})
    seen = watch(c, 60)
    assert seen["6"][-1] == (60, "r") and seen["5"] == [(41, "r")] and seen["A"][-1][1] == "green"
    c.set_control(ControlColumn.PHASE_OMIT, ())
    seen = watch(c, 100)
    # A times its own 4 s yellow and 1 s red; 5 starts the tick A is red.
    assert seen["A"] == [(101, "trail_yellow"), (141, "trail_red"), (151, "red")]
    assert seen["5"] == [(101, "r"), (151, "G")]


def test_a_flashing_yellow_arrow_follows_its_protected_and_its_opposing_through() -> None:
    c = Controller(city())
    seen = watch(c, 600, {0: {4, 8}, 150: {1, 5}, 300: {2, 6}})
    # E: left from the west, protected 1, permissive 2 (the opposing through). 2 green from power-up: flashing;
    # 2's yellow: a steady yellow arrow; red in 2's red clearance; green arrow with 1, steady yellow with its
    # yellow, red; flashing again with 2.
    assert seen["2"][:4] == [(1, "G"), (30, "Y"), (60, "r"), (351, "G")]
    assert seen["1"][1:4] == [(201, "G"), (301, "Y"), (331, "r")]
    assert seen["E"][:7] == [(1, "flashing"), (30, "yellow"), (60, "red"), (201, "green"), (301, "yellow"),
                             (331, "red"), (351, "flashing")]
    # Over NTCIP the flashing arrow's lamp is yellow: the yellow bit, not green.
    c2 = Controller(c.config)
    c2.step()
    assert E in c2.overlap_yellows and E in c2.overlaps.flashing and E not in c2.overlap_greens


def clearing_4_into_1(config: IntersectionConfig) -> Controller:
    """4+8 served, then 1+5 called: returned on the tick 4's yellow starts (B, parents 4 and 1, stays green
    through the clearance: its ring has committed 1)."""
    c = Controller(config)
    c.set_control(CALL, {4, 8})
    while not {4, 8} <= c.greens:
        c.step()
    c.set_control(CALL, {1, 5})
    while 4 not in c.yellows:
        c.step()
    return c


def shown_at(changes: list[tuple[int, str]], tick: int) -> str:
    """The display a ``watch`` timeline holds at ``tick``."""
    return [v for t, v in changes if t <= tick][-1]


@pytest.mark.parametrize("change", ["preempt", "red_end redirect"])
def test_a_next_phase_changed_on_any_tick_of_the_clearance_waits_for_the_overlap_to_clear(change: str) -> None:
    # The shipped city four-leg: B stays green while ring 1 clears 4 with 1 committed. A preempt (dwell 2+5) or,
    # with the red_end lock, calls moved to 2+6 take 1's place. On the tick the red clearance ended, 2 used to
    # start beside B, which turned yellow on that same tick: the monitor flashed the unit.
    text = data_path("four_leg_city.toml").read_text()
    if change == "red_end redirect":
        text = text.replace("[timing]", '[timing]\nnext_phase_lock = "red_end"')
    start = clearing_4_into_1(parse(text, "city.toml"))
    for offset in range(52):  # every tick of 4's 3 s yellow and 2 s red clearance, and past it
        c = copy.deepcopy(start)
        for _ in range(offset):
            c.step()
        if change == "preempt":
            c.set_preempt_control({1})
        else:
            c.set_control(CALL, {2, 6})
        seen = watch(c, 150)  # asserts that the unit never flashes
        b, two = seen["B"], seen["2"]
        assert shown_at(two, two[-1][0] - 1) == "r" and two[-1][1] == "G", (offset, two)
        assert shown_at(b, two[-1][0]) == "red", f"2 green beside B at offset {offset}: {b}"
        for (_, before), (_, after) in itertools.pairwise(b):
            assert not (before == "green" and after == "red"), f"B green to red at offset {offset}: {b}"
        yellows = [(t, b[i + 1][0]) for i, (t, v) in enumerate(b[:-1]) if i > 0 and v.endswith("yellow")]
        assert all(end - begin >= 30 for begin, end in yellows), f"B's yellow under 3 s at offset {offset}: {b}"


def test_the_monitor_flashes_on_an_overlap_shown_beside_a_phase_it_conflicts_with() -> None:
    c = Controller(city())
    for _ in range(5):
        c.step()
    # Force A (8 and 5) into a trailing green while 2 and 6 are green: 6 conflicts with it.
    c.overlaps.shown[A] = Show.TRAIL_GREEN
    c.overlaps.timing[A].trail_green = 100
    c.step()
    assert c.flash_status is UnitFlashStatus.MMU
    assert c.overlap_greens == frozenset() and c.greens == frozenset()


def test_the_overlap_objects_over_ntcip() -> None:
    c = Controller(city())
    mib = MibView(c)
    for _ in range(5):
        c.step()
    assert mib.get(MAX_OVERLAPS.instance()) == 8 and mib.get(MAX_OVERLAP_STATUS_GROUPS.instance()) == 1
    assert mib.get(OVERLAP_TABLE[OverlapColumn.TYPE].instance(A)) == OverlapType.NORMAL
    assert mib.get(OVERLAP_TABLE[OverlapColumn.TYPE].instance(E)) == OverlapType.OTHER  # fya: a vendor type in v02
    assert mib.get(OVERLAP_TABLE[OverlapColumn.INCLUDED_PHASES].instance(A)) == bytes([8, 5])
    assert mib.get(OVERLAP_TABLE[OverlapColumn.MODIFIER_PHASES].instance(E)) == bytes([2])
    # 2+6 green: D (2) and C (6) green; E flashing with 2 and F flashing with 6 set their yellow bits.
    assert mib.get(OVERLAP_STATUS_TABLE[OverlapStatusColumn.GREENS].instance(1)) == 1 << (C - 1) | 1 << (D - 1)
    assert mib.get(OVERLAP_STATUS_TABLE[OverlapStatusColumn.YELLOWS].instance(1)) == 1 << (E - 1) | 1 << (F - 1)
    assert mib.get(OVERLAP_STATUS_TABLE[OverlapStatusColumn.REDS].instance(1)) == 0xFF ^ 0b00111100
    # One poll reads the phases and the overlaps.
    state = SignalState.from_values(mib.get_many(signal_oids(c.config.groups, c.config.overlap_groups)),
                                    c.config.groups, c.config.overlap_groups)
    assert state.greens == {2, 6} and state.overlaps == OverlapState(frozenset({A, B, G, H}), frozenset({E, F}),
                                                                       frozenset({C, D}))


def test_the_trailing_times_are_writable_with_the_standards_ranges() -> None:
    c = Controller(city('A = { included = [2], trail_green = 4 }\n'))
    mib = MibView(c)
    green, yellow = OVERLAP_TABLE[OverlapColumn.TRAIL_GREEN].instance(1), OVERLAP_TABLE[
        OverlapColumn.TRAIL_YELLOW].instance(1)
    mib.set_many([(green, 2), (yellow, 45)])
    assert c.overlaps.timing[1].trail_green == 20 and c.overlaps.timing[1].trail_yellow == 45
    assert (mib.get(green), mib.get(yellow)) == (2, 45)
    with pytest.raises(SnmpError) as info:
        mib.set_many([(yellow, 29)])  # NEMA range 3.0-25.5 s
    assert info.value.status is ErrorStatus.WRONG_VALUE
    with pytest.raises(SnmpError) as info:
        mib.set_many([(OVERLAP_TABLE[OverlapColumn.INCLUDED_PHASES].instance(1), 3)])
    assert info.value.status is ErrorStatus.NOT_WRITABLE
    seen = watch(c, 200, {0: {4, 8}})
    assert seen["A"][1:4] == [(30, "trail_green"), (50, "trail_yellow"), (95, "red")]


def test_sumo_shows_overlaps_on_their_links_and_the_phases_without_their_status() -> None:
    cfg = city()
    pm = derive_phase_map(cfg, read_net())
    # The shipped network: per approach a right (lane 0), two throughs and a left, link indices 0-15 from the
    # north approach clockwise (north, east, south, west).
    assert pm.link_overlaps == (B, 0, 0, H, D, 0, 0, F, A, 0, 0, G, C, 0, 0, E)
    phases = dict(reds=frozenset({1, 3, 4, 5, 7, 8}), yellows=frozenset(), greens=frozenset({2, 6}))
    overlaps = OverlapState(frozenset({A, B, G, H}), frozenset({E, F}), frozenset({C, D}))
    # With the overlaps polled: the west and east lefts flash ('g': yield) beside 2+6; the north and south rights
    # are red with their throughs, the west and east rights green.
    assert pm.state_string(SignalState(**phases, overlaps=overlaps)) == "rrrrGGGgrrrrGGGg"
    # A steady yellow arrow is 'y'.
    ending = SignalState(frozenset({1, 3, 4, 5, 7, 8}), frozenset({2, 6}), frozenset(),
                         OverlapState(frozenset({A, B, G, H}), frozenset({C, D, E, F}), frozenset()))
    assert pm.state_string(ending) == "rrrryyyyrrrryyyy"
    # A poll of the phases only shows what it did before overlaps: rights with their throughs, lefts protected.
    assert pm.state_string(SignalState(**phases)) == "rrrrGGGrrrrrGGGr"


def test_the_dashboard_board_shows_the_overlaps_from_the_cabinet_read() -> None:
    board = Board(city())
    board.feed({"t": 0.0, "kind": "poll", "poll_id": 1, "greens": [2, 6], "yellows": []})
    assert [o["shown"] for o in board.snapshot()["overlaps"]] == [None] * 8
    board.feed({"t": 0.5, "kind": "cabinet", "walks": [], "ped_clears": [], "veh_calls": [], "ped_calls": [],
                "nexts": [], "overlap_greens": [C, D], "overlap_yellows": [E, F]})
    shown = {o["letter"]: o["shown"] for o in board.snapshot()["overlaps"]}
    assert shown == {"A": "r", "B": "r", "C": "G", "D": "G", "E": "F", "F": "F", "G": "r", "H": "r"}
    first = board.snapshot()["overlaps"][0]
    assert first | {"shown": None} == {"overlap": 1, "letter": "A", "type": "normal", "included": [8, 5],
                                       "modifiers": [], "approach": "south", "turn": "right", "shown": None}


@pytest.mark.parametrize(("table", "field", "message"), [
    ('Q = { included = [2] }', "overlaps.Q", "is not an overlap letter; allowed: A to P"),
    ('A = { included = [] }', "overlaps.A.included", "is required"),
    ('A = { included = [2, 9] }', "overlaps.A.included", "allowed: distinct configured phases"),
    ('A = { included = [2], modifiers = [5] }', "overlaps.A.modifiers", "is given for a normal overlap"),
    ('A = { type = "minus_green_yellow", included = [2] }', "overlaps.A.modifiers", "is required for type"),
    ('A = { type = "fya", included = [1], modifiers = [6] }', "overlaps.A.modifiers",
     "phase 6 runs beside protected phase 1"),
    ('A = { type = "fya", included = [1], modifiers = [2], trail_green = 2 }', "overlaps.A.trail_green",
     "allowed: 0"),
    ('A = { included = [2], trail_yellow = 2.5 }', "overlaps.A.trail_yellow", "allowed: >= 3.0"),
    ('A = { included = [2], approach = "east" }', "overlaps.A.turn", "is required with approach"),
    ('A = { type = "fya", included = [1], modifiers = [2], approach = "west", turn = "right" }', "overlaps.A.turn",
     "allowed: left"),
    ('A = { included = [2, 7], approach = "east", turn = "right" }\nB = { included = [2], approach = "east", '
     'turn = "right" }', "overlaps.B.turn", "overlap A already shows the right turn of the east approach"),
    ('A = { included = [2], kind = "normal" }', "overlaps.A.kind", "unknown field"),
    ('A = { type = "transit", included = [2], modifiers = [1] }', "overlaps.A.modifiers",
     "is given for a transit overlap"),
    ('A = { type = "transit", included = [2], trail_green = 2 }', "overlaps.A.trail_green", "allowed: 0"),
    ('A = { included = [2], delay_green = 30 }', "overlaps.A.delay_green", "allowed: >= 0 and <= 25.5"),
    ('A = { type = "fya", included = [1], modifiers = [2], delay_green = 2 }', "overlaps.A.delay_green",
     "allowed: 0"),
])
def test_bad_overlaps_are_refused_naming_the_field(table: str, field: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        city(table + "\n")
    assert info.value.field == field and message in str(info.value)


def test_the_shipped_four_leg_has_no_overlaps() -> None:
    """The paper's intersection stays as the paper ran it: overlaps live in the city variant."""
    assert load().overlaps == {} and load().overlap_groups == 0
    assert city().overlap_groups == 1 and city().overlaps[E].letter == "E"


def test_a_transit_bar_flashes_its_green_through_its_phases_yellow_and_goes_to_red_without_a_yellow() -> None:
    """NTCIP 1202 v03 transit-2: green with an included phase's green, flashing green while it is yellow with no
    included phase next, red with it; its channel has no yellow, and the monitor does not fault it."""
    c = Controller(city('A = { type = "transit", included = [2] }\n'))
    log = DataLogger(c)
    seen = watch(c, 300, {0: {4, 8}, 150: {2, 6}})
    assert seen["2"][:4] == [(1, "G"), (30, "Y"), (60, "r"), (201, "G")]
    assert seen["A"][:4] == [(1, "green"), (30, "flashing_green"), (60, "red"), (201, "green")]
    c.set_control(CALL, {4, 8})
    for tick in range(400):
        c.step()
        assert A in c.overlap_greens or A in c.overlap_reds, tick  # never yellow
        assert A not in c.overlap_yellows
    # Logged as the field's bars are: begin green, then red (no begin yellow, 63), and green again.
    codes = [e.code for e in log.events() if e.code in range(61, 67) and e.parameter == A]
    assert codes[:3] == [EventCode.OVERLAP_BEGIN_GREEN, EventCode.OVERLAP_OFF, EventCode.OVERLAP_BEGIN_GREEN]
    assert EventCode.OVERLAP_BEGIN_YELLOW not in codes


def test_the_conflict_check_sees_a_transit_bar() -> None:
    config = city('A = { type = "transit", included = [2] }\n')
    assert first_conflict(config.permissives, frozenset({2, 5}), frozenset({A})) is None
    assert first_conflict(config.permissives, frozenset({4}), frozenset({A})) is not None


@pytest.mark.parametrize(("kind", "fault"),
                         [("transit", None), ("normal", "overlap 1 from green to red without a yellow")])
def test_the_monitor_times_no_yellow_on_a_transit_bar_alone(kind: str, fault: str | None) -> None:
    monitor = Monitor(city(f'A = {{ type = "{kind}", included = [2] }}\n'))
    assert monitor.check(Lamps(frozenset({2}), frozenset(), frozenset({A}), frozenset()), 1) is None
    assert monitor.check(Lamps(frozenset(), frozenset({2}), frozenset(), frozenset()), 2) == fault


@pytest.mark.parametrize(("edition", "served"),
                         [(Version.V03, OverlapType.TRANSIT_2), (Version.V02, OverlapType.OTHER)])
def test_a_transit_bar_is_served_as_v03s_transit_2(edition: Version, served: OverlapType) -> None:
    mib = MibView(Controller(city('A = { type = "transit", included = [2] }\n')), edition)
    assert mib.get(OVERLAP_TABLE[OverlapColumn.TYPE].instance(A)) == served


def test_a_delayed_green_overlap_turns_green_its_delay_after_its_phase_and_clears_with_it() -> None:
    """delay_green 3.0 s: red for 30 ticks after its phase's green starts (logged: nothing), then green (61), then its
    yellow with the phase's; a phase that conflicts with it waits while it delays, as for a trailing overlap."""
    c = Controller(city('A = { included = [8], delay_green = 3.0 }\n'))
    log = DataLogger(c)
    seen = watch(c, 300, {0: {4, 8}, 150: {2, 6}})
    assert seen["8"][:3] == [(1, "r"), (80, "G"), (151, "Y")]
    assert seen["A"][:5] == [(1, "red"), (80, "delayed"), (110, "green"), (151, "yellow"), (181, "red")]
    assert A not in c.overlap_greens or c.tick > 110
    begins = [e for e in log.events() if e.code == EventCode.OVERLAP_BEGIN_GREEN and e.parameter == A]
    eights = [e for e in log.events() if e.code == EventCode.PHASE_BEGIN_GREEN and e.parameter == 8]
    assert (begins[0].time - eights[0].time).total_seconds() == pytest.approx(3.0)


def test_a_delayed_green_whose_phase_ends_first_never_shows_green() -> None:
    c = Controller(city('A = { included = [8], delay_green = 25.5 }\n'))
    log = DataLogger(c)
    seen = watch(c, 400, {0: {4, 8}, 90: {2, 6}})  # 8 gaps out at its minimum, long before 25.5 s
    assert [v for _, v in seen["A"]] == ["red", "delayed", "red"]
    assert not [e for e in log.events() if e.parameter == A and e.code in range(61, 66)]
