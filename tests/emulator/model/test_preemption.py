"""Preemption: the NEMA preempt sequence (entry, track clearance, dwell, exit) of the controller model, its delay,
memory, priority and maximum presence, its NTCIP objects, and SUMO calling it when an emergency vehicle comes.

The city four-leg (``hils/data/four_leg_city.toml``): the paper's phases (min green 3 s, yellow 3 s, red clearance
2 s; start-up in 2+6) and preempt 1, an emergency vehicle from the east: dwell 2+5 (at least 5 s), exit 2+6,
greens cut after at most 2 s. Times are controller ticks (0.1 s).
"""

from __future__ import annotations

import itertools

import libsumo
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from hils.protocol.config import ConfigError, IntersectionConfig, from_dict, load, parse
from hils.protocol.ntcip import (
    MAX_PREEMPTS,
    PREEMPT_CONTROL_STATE,
    PREEMPT_TABLE,
    SHORT_ALARM_STATUS,
    ControlColumn,
    ErrorStatus,
    PreemptColumn,
    PreemptState,
    ShortAlarm,
    SnmpError,
    UnitControlStatus,
    UnitFlashStatus,
)
from hils.run.testbed import Testbed
from hils.shell.events import Kind
from hils.sim.network import data_path
from tests.emulator.model.test_controller_properties import ALL_PHASES, RING1, RING2, timings

CALL = ControlColumn.VEH_CALL
S = PreemptState


def city(preempts: str | None = None, phases: dict[int, str] | None = None) -> IntersectionConfig:
    """The shipped city four-leg, its preempt table replaced when given, some phases' settings added."""
    text = data_path("four_leg_city.toml").read_text()
    if preempts is not None:
        text = text[:text.index("[preempts]")] + "[preempts]\n" + preempts
    for p, extra in (phases or {}).items():
        start = text.index(f"\n{p} = {{ ") + 1
        end = text.index("}", start)
        text = text[:start] + text[start:end].rstrip() + f", {extra} " + text[end:]
    return parse(text, "city.toml")


def watch(c: Controller, ticks: int, inputs: dict[int, set[int]] | None = None,
          calls: dict[int, set[int]] | None = None) -> dict[str, list[tuple[int, str]]]:
    """Step ``ticks`` ticks, SETting preemptControlState (``inputs``) and VehCall (``calls``) at their ticks; per
    phase ("2") and preempt ("P1") the (tick, indication or preemptState name) changes."""
    out: dict[str, list[tuple[int, str]]] = {}
    last: dict[str, str] = {}
    for _ in range(ticks):
        if inputs and c.tick in inputs:
            c.set_preempt_control(inputs[c.tick])
        if calls and c.tick in calls:
            c.set_control(CALL, calls[c.tick])
        c.step()
        assert c.flash_status is UnitFlashStatus.NOT_FLASH, f"flash at tick {c.tick}"
        now = {str(p): "G" if p in c.greens else "Y" if p in c.yellows else "r" for p in c.config.phases}
        now |= {f"P{n}": s.name for n, s in c.preemptor.states.items()}
        for k, v in now.items():
            if last.get(k) != v:
                out.setdefault(k, []).append((c.tick, v))
        last = now
    return out


def test_an_emergency_preempt_cuts_the_greens_dwells_in_its_phases_and_exits() -> None:
    c = Controller(city())
    c.backup_time = 0
    # 4+8 green from 8 s (2+6 gapped out at 3 s); the ambulance called at 9 s, gone at 20 s.
    seen = watch(c, 400, {90: {1}, 200: set()}, {0: {4, 8}})
    assert seen["4"][:2] == [(1, "r"), (80, "G")]
    # Entry: 4 and 8 end at the lesser of their minimum green (3 s) and the preempt's (2 s), then their yellow
    # and red clearance in full (not capped): 2 and 5 green at 100 + 50.
    assert seen["P1"][:3] == [(1, "NOT_ACTIVE"), (91, "ENTRY_STARTED"), (150, "DWELL")]
    assert seen["4"][2:4] == [(100, "Y"), (130, "r")] and seen["8"][2:4] == [(100, "Y"), (130, "r")]
    assert seen["2"][3] == (150, "G") and seen["5"][1] == (150, "G")
    # Dwell: at least 5 s and until the call has gone (201): exit to 2+6, 5 ending after its minimum green
    # (shown since 150), 6 after 5's clearance; then the controller is itself again and serves 4+8's calls.
    assert seen["P1"][3:] == [(201, "EXIT_STARTED"), (251, "NOT_ACTIVE")]
    assert seen["5"][2:] == [(201, "Y"), (231, "r")]
    assert seen["6"][3:5] == [(251, "G"), (281, "Y")] and seen["2"][4] == (281, "Y")


def test_a_rail_preempt_clears_the_track_then_dwells() -> None:
    c = Controller(city('1 = { track_phases = [4], track_green = 8, track_yellow = 3.0, dwell_phases = [2, 6], '
                        'dwell_green = 10, exit_phases = [2, 6], min_green = 1, enter_red = 1.0 }\n'))
    c.backup_time = 0
    seen = watch(c, 400, {45: {1}, 60: set()}, {0: {3, 7}})
    # 2+6 were clearing to 3+7 (yellow from 3 s): the entry takes the red clearance down to 1 s and serves the
    # track phase 4 instead; ring 2 rests in red.
    assert seen["2"][:3] == [(1, "G"), (30, "Y"), (60, "r")]
    assert seen["4"][1:4] == [(70, "G"), (150, "Y"), (180, "r")]  # 8 s of track green, its own clearance
    assert seen["8"] == [(1, "r")]
    # 10 s of dwell, the call gone long ago: the exit phases are the dwell phases, so the exit ends as it starts.
    assert seen["P1"] == [(1, "NOT_ACTIVE"), (46, "ENTRY_STARTED"), (70, "TRACK_SERVICE"), (200, "DWELL"),
                          (300, "NOT_ACTIVE")]
    assert seen["2"][3] == (200, "G") and seen["6"][3] == (200, "G")
    # Then 3+7, called all along, are served.
    assert seen["2"][4] == (301, "Y") and seen["3"] == [(1, "r"), (351, "G")]


def test_the_entry_shortens_a_walk_and_its_clearance_to_the_preempts_minimums() -> None:
    cfg = city('1 = { dwell_phases = [2, 6], min_green = 1, min_walk = 2, enter_ped_clear = 3 }\n',
               {4: "walk = 6, ped_clear = 8"})
    c = Controller(cfg)
    c.backup_time = 0
    c.set_control(ControlColumn.PED_CALL, {4})
    seen = watch(c, 200, {90: {1}}, {0: {4, 8}})
    # 4 green with its walk from 8 s; preempted at 9.1 s, 1.1 s into the walk: the walk ends at 2 s (the preempt's
    # minimum walk), the flashing don't walk lasts 3 s (its enter ped clear): 4 ends at 80 + 50.
    assert seen["4"][1:3] == [(80, "G"), (130, "Y")]
    # 8, without a walk, ends at once: it has shown the lesser of its minimum green and the preempt's (1 s).
    assert seen["8"][1:3] == [(80, "G"), (91, "Y")]


def test_a_delay_passes_before_the_entry_and_a_non_locking_call_that_goes_is_forgotten() -> None:
    locking = Controller(city('1 = { dwell_phases = [4, 8], delay = 3 }\n'))
    seen = watch(locking, 100, {10: {1}, 30: set()})
    assert seen["P1"][:3] == [(1, "NOT_ACTIVE"), (11, "NOT_ACTIVE_WITH_CALL"), (41, "ENTRY_STARTED")]
    forgetful = Controller(city('1 = { dwell_phases = [4, 8], delay = 3, non_locking = true }\n'))
    seen = watch(forgetful, 100, {10: {1}, 30: set()})
    assert seen["P1"] == [(1, "NOT_ACTIVE"), (11, "NOT_ACTIVE_WITH_CALL"), (31, "NOT_ACTIVE")]
    assert seen["2"] == [(1, "G")]  # nothing happened to the rings


def test_a_lower_numbered_preempt_overrides_and_the_other_is_served_after_it() -> None:
    c = Controller(city('1 = { dwell_phases = [4, 8], dwell_green = 2 }\n2 = { dwell_phases = [2, 5] }\n'))
    c.backup_time = 0
    seen = watch(c, 500, {10: {2}, 100: {1, 2}, 150: {2}})
    # 2 from 1 s: 6 ends after its minimum green (3 s), 5 starts after its clearance; 2 stays green.
    assert seen["P2"][:3] == [(1, "NOT_ACTIVE"), (11, "ENTRY_STARTED"), (80, "DWELL")]
    assert seen["5"][1] == (80, "G") and seen["2"] [:2] == [(1, "G"), (101, "Y")]
    # 1 takes over at 10 s (2 waits, its input still on): 2 ends at once, 5 after its minimum; dwell in 4+8.
    assert seen["P1"][:3] == [(1, "NOT_ACTIVE"), (101, "ENTRY_STARTED"), (160, "DWELL")]
    assert seen["P2"][3] == (101, "NOT_ACTIVE_WITH_CALL")
    assert seen["5"][2] == (110, "Y") and seen["4"][1] == (160, "G")
    # 1's call gone at 15 s, its 2 s dwell done at 18 s: it exits (no exit phases) and 2 is served again.
    assert seen["P1"][3] == (180, "NOT_ACTIVE")
    assert seen["P2"][4:] == [(181, "ENTRY_STARTED"), (240, "DWELL")]


def test_past_its_maximum_presence_a_call_is_ignored_until_it_goes() -> None:
    c = Controller(city('1 = { dwell_phases = [4, 8], max_presence = 20 }\n'))
    c.backup_time = 0
    seen = watch(c, 600, {10: {1}, 500: set()}, {0: {1, 5}})
    # Called at 1 s: dwell in 4+8; at 21 s the call has been on 20 s: the controller returns to its own operation
    # and serves the calls on 1+5, the preempt in maxPresence until its input goes.
    assert seen["P1"] == [(1, "NOT_ACTIVE"), (11, "ENTRY_STARTED"), (80, "DWELL"), (210, "MAX_PRESENCE"),
                          (501, "NOT_ACTIVE")]
    assert seen["4"][2] == (210, "Y") and seen["1"] == [(1, "r"), (260, "G")]


def test_the_dwell_lasts_the_minimum_duration_from_the_entry() -> None:
    c = Controller(city('1 = { dwell_phases = [4, 8], min_duration = 15 }\n'))
    seen = watch(c, 300, {10: {1}, 20: set()})
    # 15 s from the entry's start (11): the dwell ends at 161 and, without exit phases, the preempt with it.
    assert seen["P1"] == [(1, "NOT_ACTIVE"), (11, "ENTRY_STARTED"), (80, "DWELL"), (161, "NOT_ACTIVE")]


def test_backup_mode_releases_the_preempt_control() -> None:
    c = Controller(city())
    c.backup_time = 5
    c.set_preempt_control({1})
    seen = watch(c, 200)
    # The SET armed the 5 s backup time: at 5 s the control objects reset, preemptControlState too, so the dwell
    # (2+5 from 7 s) ends when its 5 s minimum has passed and the exit returns to 2+6.
    assert c.control_status is UnitControlStatus.BACKUP_MODE and c.preemptor.control == frozenset()
    assert seen["P1"] == [(1, "ENTRY_STARTED"), (70, "DWELL"), (120, "EXIT_STARTED"), (170, "NOT_ACTIVE")]
    assert not c.preempted and c.greens == {2, 6}


def test_the_preempt_objects_over_ntcip() -> None:
    c = Controller(city())
    mib = MibView(c)
    c.step()
    assert mib.get(MAX_PREEMPTS.instance()) == 1
    table = {col: mib.get(PREEMPT_TABLE[col].instance(1)) for col in PreemptColumn}
    assert table[PreemptColumn.DWELL_PHASE] == bytes([2, 5]) and table[PreemptColumn.EXIT_PHASE] == bytes([2, 6])
    assert table[PreemptColumn.TRACK_PHASE] == b"" and table[PreemptColumn.CONTROL] == 0
    assert (table[PreemptColumn.MINIMUM_GREEN], table[PreemptColumn.DWELL_GREEN]) == (2, 5)
    assert (table[PreemptColumn.ENTER_YELLOW_CHANGE], table[PreemptColumn.ENTER_RED_CLEAR]) == (255, 255)
    assert table[PreemptColumn.STATE] == S.NOT_ACTIVE and mib.get(SHORT_ALARM_STATUS.instance()) == 0
    # A SET of preemptControlState calls it: shortAlarmStatus's preempt bit, then the entry.
    mib.set_many([(PREEMPT_CONTROL_STATE.instance(1), 1)])
    assert mib.get(SHORT_ALARM_STATUS.instance()) == ShortAlarm.PREEMPT
    c.step()
    assert mib.get(PREEMPT_TABLE[PreemptColumn.STATE].instance(1)) == S.ENTRY_STARTED
    mib.set_many([(PREEMPT_TABLE[PreemptColumn.DELAY].instance(1), 600),
                  (PREEMPT_TABLE[PreemptColumn.ENTER_RED_CLEAR].instance(1), 5)])
    assert c.preemptor.timing[1].delay == 6000 and c.preemptor.timing[1].enter_red == 5
    for col, value, status in ((PreemptColumn.DELAY, 601, ErrorStatus.WRONG_VALUE),
                               (PreemptColumn.ENTER_YELLOW_CHANGE, 29, ErrorStatus.WRONG_VALUE),
                               (PreemptColumn.DWELL_PHASE, 4, ErrorStatus.NOT_WRITABLE),
                               (PreemptColumn.STATE, 2, ErrorStatus.NOT_WRITABLE)):
        with pytest.raises(SnmpError) as info:
            mib.set_many([(PREEMPT_TABLE[col].instance(1), value)])
        assert info.value.status is status, col
    with pytest.raises(SnmpError) as info:
        mib.set_many([(PREEMPT_CONTROL_STATE.instance(1), 2)])
    assert info.value.status is ErrorStatus.WRONG_VALUE


@pytest.mark.parametrize(("table", "field", "message"), [
    ('0 = { dwell_phases = [2] }', "preempts.0", "is not a preempt number; allowed: 1..255"),
    ('1 = { dwell_phases = [2, 1] }', "preempts.1.dwell_phases", "at most one per ring"),
    ('1 = { dwell_phases = [2, 7] }', "preempts.1.dwell_phases", "phases 2 and 7 conflict"),
    ('1 = { dwell_phases = [2, 9] }', "preempts.1.dwell_phases", "allowed: configured phases"),
    ('1 = { track_green = 5 }', "preempts.1.track_phases", "is required with track_green"),
    ('1 = { delay = 601 }', "preempts.1.delay", "allowed: >= 0 and <= 600"),
    ('1 = { enter_yellow = 2.0 }', "preempts.1.enter_yellow", "allowed: >= 3.0"),
    ('1 = { dwell_green = 0 }', "preempts.1.dwell_green", "allowed: >= 1"),
    ('1 = { vehicles = ["emergency"] }', "preempts.1.approach", "is required with vehicles"),
    ('1 = { vehicles = ["emergency"], approach = "up" }', "preempts.1.approach", "allowed: north, south"),
    ('1 = { non_locking = 1 }', "preempts.1.non_locking", "allowed: true, false"),
    ('1 = { dwell = [2] }', "preempts.1.dwell", "unknown field"),
])
def test_bad_preempts_are_refused_naming_the_field(table: str, field: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        city(table + "\n")
    assert info.value.field == field and message in str(info.value)


def test_an_ambulance_in_sumo_calls_the_preempt_over_ntcip() -> None:
    """A run of the city four-leg with the actuated baseline; an ambulance (vehicle type "ambulance") from the
    east at 20 s: while it is within 150 m of the stop bar the detection feed SETs preemptControlState.1, the controller
    dwells in 2+5, and lets go after it has passed."""
    seen: list[tuple[float, PreemptState]] = []

    def ambulance(tb: Testbed) -> None:
        libsumo.route.add("east_west", ["E2C", "C2W"])
        libsumo.vehicletype.copy("DEFAULT_VEHTYPE", "ambulance")  # a passenger car: the lanes allow no other
        libsumo.vehicle.add("ambulance", "east_west", typeID="ambulance", depart="20")
        unit = tb.target.unit

        def sample():
            while True:
                seen.append((tb.env.now, unit.preemptor.states[1]))
                yield tb.env.timeout(0.5)

        tb.env.process(sample())

    with Testbed(load(data_path("four_leg_city.toml")), agent="actuated", sumo=True, seed=4, duration=90.0,
                 on_reset=ambulance) as tb:
        tb.reset()
        tb.run()
        records = tb.events.of(Kind.PREEMPT_INPUTS)
    assert [r["active"] for r in records] == [[1], []]
    called, released = records[0]["t"], records[1]["t"]
    assert 20 < called < released < 60
    states = [s for _, s in seen]
    assert S.DWELL in states and states[-1] is S.NOT_ACTIVE
    dwelling = [t for t, s in seen if s is S.DWELL]
    assert called < dwelling[0] <= called + 8  # the greens cut after 2 s, their 5 s clearance: within 8 s


# --- properties -----------------------------------------------------------------------------------


@st.composite
def preempted(draw: st.DrawFn) -> IntersectionConfig:
    """Random four-leg-shaped configs (barrier after phase 2 and 6) with one preempt of random times."""
    together = [[], *([p] for p in sorted(ALL_PHASES)), [1, 5], [1, 6], [2, 5], [2, 6], [3, 7], [3, 8], [4, 7],
                [4, 8]]
    phases = {str(p): draw(timings()) for p in ALL_PHASES}
    preempt = {"dwell_phases": draw(st.sampled_from(together)), "exit_phases": draw(st.sampled_from(together)),
               "delay": draw(st.integers(0, 3)), "min_green": draw(st.integers(0, 5)),
               "min_walk": draw(st.integers(0, 5)), "enter_ped_clear": draw(st.integers(0, 5)),
               "enter_yellow": draw(st.integers(30, 60)) / 10, "enter_red": draw(st.integers(0, 30)) / 10,
               "dwell_green": draw(st.integers(1, 5))}
    if draw(st.booleans()):
        preempt |= {"track_phases": [draw(st.sampled_from(sorted(ALL_PHASES)))], "track_green": draw(st.integers(1, 8))}
    return from_dict({"name": "random", "phases": phases, "preempts": {"1": preempt},
                      "structure": {"rings": [list(RING1), list(RING2)], "barriers": [[1, 2, 5, 6], [3, 4, 7, 8]],
                                    "sequence": [[1, 5], [4, 8]], "pairs": [[1, 5], [2, 6]]}}, "random.toml")


def entry_bound(config: IntersectionConfig) -> int:
    """Ticks from a call to the track clearance (or the dwell, without one): the preempt's delay, then the longest
    green it may still honour (the lesser of each phase's minimum green, walk and pedestrian clearance and the
    preempt's), the longest clearance (likewise capped) or red revert, and the target's own start."""
    p = config.preempts[1]

    def cut(ph):
        walk = min(ph.walk, p.min_walk) + min(ph.ped_clear, p.enter_ped_clear)
        return 10 * max(min(ph.min_green, p.min_green), walk)

    green = max(cut(ph) for ph in config.phases.values())
    clear = max(round(10 * (min(ph.yellow, p.enter_yellow) + max(min(ph.red_clear, p.enter_red), ph.red_revert)))
                for ph in config.phases.values())
    return 10 * p.delay + green + clear + 2


@settings(max_examples=60, deadline=None)
@given(config=preempted(), start=st.integers(1, 600), calls=st.frozensets(st.sampled_from(sorted(ALL_PHASES))),
       hold=st.integers(1, 200))
def test_a_preempt_reaches_its_track_clearance_in_bound_and_always_exits_to_its_exit_phases(
        config: IntersectionConfig, start: int, calls: frozenset[int], hold: int) -> None:
    """Whatever the controller is doing when the call comes: the track clearance (or the dwell) starts within the
    preempt's delay plus the minimum times it honours, the dwell comes, and once the call goes the exit phases
    show green and the controller is no longer preempted."""
    c = Controller(config)
    c.backup_time = 0
    c.set_control(CALL, calls)
    for _ in range(start):
        c.step()
    c.set_preempt_control({1})
    served = S.TRACK_SERVICE if config.preempts[1].track_green else S.DWELL
    for ticks in itertools.count(1):
        c.step()
        if c.preemptor.states[1] in (served, S.DWELL):
            break
        assert ticks <= entry_bound(config), f"{served.name} not reached within {entry_bound(config)} ticks"
    for _ in range(hold):
        c.step()
    c.set_preempt_control(())
    p = config.preempts[1]
    bound = 10 * (p.track_green + p.dwell_green) + 3 * max(10 * (ph.min_green + ph.yellow + ph.red_clear
                                                                 + ph.red_revert) for ph in config.phases.values())
    exit_phases = set(p.exit_phases)
    for _ in range(round(bound) + 10):
        c.step()
        if not c.preempted:
            break
    assert not c.preempted and c.preemptor.states[1] is S.NOT_ACTIVE
    assert exit_phases <= c.greens, f"exit phases {sorted(exit_phases)} not green: {sorted(c.greens)}"


def test_the_shipped_four_leg_has_no_preempts() -> None:
    """The paper's intersection stays as the paper ran it: the preempt lives in the city variant."""
    assert load().preempts == {}
    assert city().preempts[1].vehicles == ("emergency", "ambulance") and city().preempts[1].approach == "east"


def test_phases_cycle_in_the_dwell_where_the_preempt_allows_it() -> None:
    """preemptCyclingPhase: phases "allowed to cycle during the Preempt Dwell interval", after the dwell phases. Dwell
    2+6 with 4 and 8 allowed to cycle; 3 and 4 called during the dwell: 4 is served in the dwell (the rings cross
    and come back to the dwell phases), 3 (not allowed) only after the preempt has ended."""
    c = Controller(city('1 = { dwell_phases = [2, 6], exit_phases = [2, 6], cycling_phases = [4, 8], '
                        'dwell_green = 40 }\n'))
    c.backup_time = 0
    seen = watch(c, 1200, {100: {1}, 700: set()}, {150: {3, 4}})
    dwell = next(t for t, s in seen["P1"] if s == "DWELL")
    done = next(t for t, s in seen["P1"] if s == "NOT_ACTIVE" and t > dwell)
    greens4 = [t for t, s in seen["4"] if s == "G"]
    assert greens4 and dwell < greens4[0] < done
    assert any(t > greens4[0] and s == "G" for t, s in seen["2"] if t < done)  # back to the dwell phases
    assert all(t > done for t, s in seen["3"] if s == "G") and any(s == "G" for _, s in seen["3"])


def test_cycling_phases_are_served_in_the_preempt_table() -> None:
    c = Controller(city('1 = { dwell_phases = [2, 6], cycling_phases = [4, 8] }\n'))
    view = MibView(c)
    assert view.get(PREEMPT_TABLE[PreemptColumn.CYCLING_PHASE].instance(1)) == bytes([4, 8])
    with pytest.raises(ConfigError, match=r"preempts\.1\.dwell_phases.*required with cycling_phases"):
        city('1 = { cycling_phases = [4, 8] }\n')
