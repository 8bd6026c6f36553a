"""The controller's SPaT (:meth:`Controller.spat`) holds to the truth: every change of a phase's or an overlap's
indication comes no sooner than every earliest announced since its last change, and no later than every latest
announced since its last change and the last input (a latest holds while the inputs stand: emulator/model/spat.py),
over random configs (coordination, overlaps, preempts, pedestrians, start-up flash, backup time) and random inputs
between the ticks (every control object, detectors, push buttons, Max2, patterns, preempts, the backup time).
Announcements are not promised across a power cycle or a retiming of the phase table, which the inputs here leave
out. A planted error (a latest one tick short, an earliest one tick late) is caught."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.model import spat
from emulator.model.controller import Controller
from emulator.model.spat import Indication, SignalTiming
from hils.protocol.config import DetectorTiming, IntersectionConfig, from_dict, load, parse
from hils.protocol.ntcip import ControlColumn
from hils.sim.network import data_path
from tests.emulator.model.test_controller_events import apply, inputs, units
from tests.emulator.model.test_overlaps import city

SETTINGS = settings(max_examples=100, deadline=None)

steady = inputs.filter(lambda op: op[0] not in ("retime", "power_cycle", "ticks"))
# Each input, then a stretch of ticks; a stretch to start with.
ops = st.builds(lambda first, rest: [("ticks", first), *(x for op, ticks in rest for x in (op, ("ticks", ticks)))],
                st.integers(1, 600), st.lists(st.tuples(steady, st.integers(1, 600)), max_size=12))


def shown(c: Controller) -> dict[tuple[str, int], Indication]:
    def of(n: int, greens: frozenset[int], yellows: frozenset[int]) -> Indication:
        return Indication.GREEN if n in greens else Indication.YELLOW if n in yellows else Indication.RED
    return ({("phase", p): of(p, c.greens, c.yellows) for p in c.config.phases}
            | {("overlap", n): of(n, c.overlap_greens, c.overlap_yellows) for n in c.config.overlaps})


class Outside(AssertionError):
    """A change outside the window announced for it."""


def check(config: IntersectionConfig, steps: list[tuple[str, object]]) -> tuple[int, int]:
    """Run the inputs, announcing after every tick; the number of changes checked, and of them those a latest was
    announced for since their last change and the last input."""
    c = Controller(config)
    # signal -> (soonest tick since its change, latest tick since its change and the last input)
    window: dict[tuple[str, int], tuple[float, float]] = {}
    checked = bounded = 0

    def announce() -> None:
        for s in c.spat():
            key = (s.kind, s.number)
            soonest = math.inf if s.earliest is None else c.tick + s.earliest
            latest = math.inf if s.latest is None else c.tick + s.latest
            was = window.get(key, (-math.inf, math.inf))
            window[key] = (max(was[0], soonest), min(was[1], latest))

    before = shown(c)
    announce()
    for op, value in steps:
        if op != "ticks":
            apply(c, op, value, ticked=True)
            window = {key: (soonest, math.inf) for key, (soonest, _) in window.items()}
            continue
        for _ in range(value):
            c.step()
            now = shown(c)
            for key, indication in now.items():
                if indication is not before[key]:
                    soonest, latest = window.pop(key)
                    if not soonest <= c.tick <= latest:
                        raise Outside(key, before[key], indication, c.tick, soonest, latest)
                    checked += 1
                    bounded += latest < math.inf
            before = now
            announce()
    return checked, bounded


@SETTINGS
@given(config=units(), steps=ops)
def test_every_change_comes_within_the_announced_earliest_and_latest(config: IntersectionConfig,
                                                                      steps: list[tuple[str, object]]) -> None:
    check(config, steps)


def test_the_four_leg_announces_its_minimum_its_yellow_and_the_red_behind_it() -> None:
    """The shipped four-leg (minimum green 3 s, maximum 20 s, yellow 3 s, red clearance 2 s), 2+6 resting from
    start-up and a call on 4+8 at tick 0: 2 and 6 may end at their minimum (tick 30), and end by their maximum (tick
    200: the call standing, their maximum timers run), likely then; 4 and 8 turn green no sooner than 2+6 have
    cleared (tick 30 + 30 + 20) and by tick 200 + 30 + 20; once 2+6 are yellow, their end is exact. The city
    four-leg with a preempt checks a run through."""
    c = Controller(load(data_path("four_leg.toml")))
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    c.step()
    spat = {(s.kind, s.number): s for s in c.spat()}
    assert spat["phase", 2] == SignalTiming("phase", 2, Indication.GREEN, 30 - c.tick, 200 - c.tick, 200 - c.tick,
                                            c.tick)  # green since power-up
    assert spat["phase", 4] == SignalTiming("phase", 4, Indication.RED, 80 - c.tick, 250 - c.tick, 250 - c.tick,
                                            None)  # never shown: when its red began is not known
    assert spat["phase", 3].latest is None  # not called: nothing brings it
    while 2 in c.greens:
        c.step()
    yellow = {(s.kind, s.number): s for s in c.spat()}["phase", 2]
    assert (yellow.indication, yellow.earliest, yellow.latest) == (Indication.YELLOW, 30, 30)
    # 2+6 end at their minimum exactly (no call of their own, passage 0): the earliest announced is met to the tick.
    assert check(load(data_path("four_leg.toml")), [(ControlColumn.VEH_CALL, {4, 8}), ("ticks", 300)])[0] == 6
    assert check(load(data_path("four_leg_city.toml")), [(ControlColumn.VEH_CALL, {1, 5}), ("ticks", 300),
                                                         ("preempt", {1}), ("ticks", 300)])[0] > 0


def test_a_delayed_detector_call_is_a_horizon_of_the_latest() -> None:
    """The shipped four-leg, 2+6 extended by calls standing (maximum 20 s), detectors 3 and 4 actuated at once, 3 with
    a delay of 2 s. At first only 4 is demand: 4 would start by 2's maximum and clearance. The delay running out puts
    3 (before 4 in ring 1's order) in the demand with no input, and 4 then waits for 3's green (to its maximum, its
    detector standing) and clearance: the detector's timer bounds every latest announced before it, none may be
    announced past it (before, 4 came 25 s after the latest announced for it)."""
    config = dataclasses.replace(load(data_path("four_leg.toml")), detector_timing={3: DetectorTiming(delay=2.0)})
    steps = [(ControlColumn.VEH_CALL, {2, 6}), ("ticks", 50), ("detectors", {3, 4}), ("ticks", 600)]
    checked, bounded = check(config.with_middleware(backup_time=0), steps)
    assert checked > 0 and bounded > 0


def test_a_delayed_overlap_released_by_its_phase_announces_no_latest() -> None:
    """The city four-leg, every phase on pedestrian recall (walk 2 s, pedestrian clearance 2 s), overlap A following 2
    with a delayed green of 3 s. 2 starts green at power-up without a walk, A delaying, and ends at its minimum, 3 s
    in, the tick A's delay would run out: released, A stays red. It turns green only when the ring comes back to 2,
    whose green then serves its walk and outlasts the delay. Its first delay's end was no latest (before, it was
    announced as one, and A turned green a cycle after it)."""
    config = city('A = { included = [2], delay_green = 3.0 }\n', 'recall = "ped"\nwalk = 2\nped_clear = 2')
    checked, bounded = check(config.with_middleware(backup_time=0), [("ticks", 1000)])
    assert checked > 0 and bounded > 0


def test_a_delayed_overlap_waits_for_a_parent_whose_green_outlasts_the_delay() -> None:
    """The city four-leg, overlap A following 1 and 2 with a delayed green of 3 s, every phase on pedestrian recall
    (walk 2 s, pedestrian clearance 2 s) but 1 (minimum recall, no walk: 3 s of green). 1's green starts A's delay and
    ends with it, releasing A; 2's green, 4 s, then holds A through its delay. Announced while 1 is red, A's latest
    is 2's start and the delay, not 1's (before, A turned green 8 s after the latest announced for it)."""
    text = data_path("four_leg_city.toml").read_text()
    text = text[:text.index("[overlaps]")] + "[overlaps]\nA = { included = [1, 2], delay_green = 3.0 }\n"
    text = text.replace("[timing]", '[timing]\nrecall = "ped"\nwalk = 2\nped_clear = 2', 1)
    text = text.replace('1 = { approach = "west", turn = "left" }',
                        '1 = { approach = "west", turn = "left", recall = "min", walk = 0, ped_clear = 0 }')
    checked, bounded = check(parse(text, "city.toml").with_middleware(backup_time=0), [("ticks", 1000)])
    assert checked > 0 and bounded > 0


def test_a_green_waits_at_the_barrier_for_a_conditional_service_to_come() -> None:
    """1 alone in its ring's first barrier group, 6 beside it with conditional service, 5 (before 6) on max recall,
    4 across on min recall; 1 and 6 start green. At first 6 may not back into 5 (not ready to end), so the rings
    would cross when 1 maxes out; once 6 is ready, conditional service takes it back into 5, and 1 waits at the
    barrier for 5's maximum. While 6 can still back by conditional service no crossing time is announced (before, 1's
    maximum was, and 1 ended 0.5 s after it)."""
    plain = {"backup_prevent": False, "simultaneous_gap_disable": False}
    phases = {str(p): dict(plain) for p in range(1, 9)}
    phases["1"] |= {"min_green": 2, "max_green": 6, "startup": "green"}
    phases["4"] |= {"max_green": 2, "passage": 0.1, "recall": "min"}
    phases["5"] |= {"max_green": 2, "passage": 0.1, "recall": "max"}
    phases["6"] |= {"startup": "green", "conditional_service": True}
    raw = {"name": "conditional service", "timing": {"min_green": 1, "max_green": 1, "yellow": 3.0, "red_clear": 0.5},
           "phases": phases,
           "structure": {"rings": [[1, 2, 3, 4], [5, 6, 7, 8]], "barriers": [[1, 5, 6], [2, 3, 4, 7, 8]],
                         "sequence": [[1, 5], [4, 8]],
                         "pairs": [[1, 5], [1, 6], [2, 7], [2, 8], [3, 7], [3, 8], [4, 7], [4, 8]]},
           "middleware": {"backup_time": 0}}
    checked, bounded = check(from_dict(raw, "conditional.toml"), [("ticks", 65)])
    assert checked > 0 and bounded > 0


@pytest.mark.parametrize("plant", ["latest one tick short", "earliest one tick late"])
def test_a_planted_error_is_caught(monkeypatch: pytest.MonkeyPatch, plant: str) -> None:
    """The check can fail: announcements made wrong by one tick (every latest one short, or every earliest one
    late) are caught on the shipped four-leg, 2+6 ending for a call on 4+8."""
    true = spat.announce

    def planted(c: Controller) -> tuple[SignalTiming, ...]:
        if plant.startswith("latest"):
            return tuple(dataclasses.replace(s, latest=None if s.latest is None else s.latest - 1) for s in true(c))
        return tuple(dataclasses.replace(s, earliest=None if s.earliest is None else s.earliest + 1) for s in true(c))

    steps = [(ControlColumn.VEH_CALL, {4, 8}), ("ticks", 600)]
    assert check(load(data_path("four_leg.toml")), steps)[1] > 0  # latest announced, and met, before the plant
    monkeypatch.setattr("emulator.model.controller.announce", planted)
    with pytest.raises(Outside):
        check(load(data_path("four_leg.toml")), steps)


@pytest.mark.parametrize("pattern", [254, 1], ids=["free", "coordinated"])
def test_most_changes_had_a_latest_announced(pattern: int) -> None:
    """Not hollow: on the city four-leg (overlaps, a preempt configured), free and under its pattern 1, with calls
    standing on every phase for ten minutes, most changes had a latest announced since their last change, and all
    came within their windows."""
    steps = [("backup_time", 0), ("pattern", pattern), (ControlColumn.VEH_CALL, set(range(1, 9))), ("ticks", 6000)]
    checked, bounded = check(load(data_path("four_leg_city.toml")), steps)
    assert checked > 100 and bounded > 0.5 * checked, (checked, bounded)
