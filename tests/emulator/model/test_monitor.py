"""The monitor (the cabinet's MMU) on the bench, fed lamps as an MMU tester feeds a unit its field inputs, and
in the controller, which shows it every set of lamps it lights.

The city four-leg (``hils/data/four_leg_city.toml``): right-turn overlap A {8, 5}, which 6 and 7 run beside
neither of; flashing yellow arrow E (protected 1, flashing beside 2). Times are controller ticks (0.1 s).
"""

from __future__ import annotations

import pytest

from emulator.model.controller import Controller
from emulator.model.monitor import SHORT_YELLOW, Lamps, Monitor, Shown
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn

A, E = 1, 5
NONE: frozenset[int] = frozenset()


def lamps(greens=(), yellows=(), overlap_greens=(), overlap_yellows=()) -> Lamps:
    return Lamps(frozenset(greens), frozenset(yellows), frozenset(overlap_greens), frozenset(overlap_yellows))


def test_the_monitor_faults_two_conflicting_phases_lit_together(city_config: IntersectionConfig) -> None:
    assert Monitor(city_config).check(lamps({2, 6}), 1) is None
    assert Monitor(city_config).check(lamps({2}, {7}), 1) == "phases 2 and 7 shown together"


@pytest.mark.parametrize(("shown", "fault"), [
    (lamps({2, 6}, overlap_greens={A}), "overlap A and phase 6 shown together"),
    (lamps({2}, {6}, overlap_yellows={A}), "overlap A and phase 6 shown together"),  # yellow against yellow
    (lamps({4, 8}, overlap_yellows={E}), "overlap E and phase 4 shown together"),  # a flashing yellow arrow
    (lamps({2, 5}, overlap_greens={A}, overlap_yellows={E}), None),
])
def test_the_monitor_faults_an_overlap_lit_beside_a_phase_it_conflicts_with(city_config: IntersectionConfig,
                                                                           shown: Lamps, fault: str | None) -> None:
    # The controller never lights these (a phase that conflicts with a lit overlap waits for it): what the monitor
    # sees is fed to it directly, and a monitor blind to overlaps passes them.
    assert Monitor(city_config).check(shown, 1) == fault


@pytest.mark.parametrize("kind", ["phase", "overlap"])
def test_the_monitor_faults_a_green_that_goes_to_red_without_a_yellow(city_config: IntersectionConfig,
                                                                     kind: str) -> None:
    green, red = (lamps({2}), lamps()) if kind == "phase" else (lamps(overlap_greens={A}), lamps())
    m = Monitor(city_config)
    assert m.check(green, 1) is None
    assert m.check(red, 2) == f"{kind} {2 if kind == 'phase' else A} from green to red without a yellow"


@pytest.mark.parametrize("kind", ["phase", "overlap"])
@pytest.mark.parametrize("ticks", [SHORT_YELLOW - 1, SHORT_YELLOW])
def test_the_monitor_faults_a_yellow_under_2_7_s(city_config: IntersectionConfig, kind: str, ticks: int) -> None:
    green, yellow = ((lamps({2}), lamps(yellows={2})) if kind == "phase" else
                     (lamps(overlap_greens={A}), lamps(overlap_yellows={A})))
    m = Monitor(city_config)
    assert m.check(green, 1) is None
    assert m.check(yellow, 2) is None
    short = f"{kind} {2 if kind == 'phase' else A} yellow for {ticks / 10:g} s"
    assert m.check(lamps(), 2 + ticks) == (None if ticks >= SHORT_YELLOW else short)


def test_a_yellow_that_goes_to_green_is_no_clearance(city_config: IntersectionConfig) -> None:
    # A flashing yellow arrow's yellow lamp may go straight to its green arrow: no yellow to time.
    m = Monitor(city_config)
    assert m.check(lamps({1, 5}, overlap_yellows={E}), 1) is None
    assert m.check(lamps({1, 5}, overlap_greens={E}), 2) is None


def test_a_power_cycle_starts_the_monitor_afresh(city_config: IntersectionConfig) -> None:
    m = Monitor(city_config)
    assert m.check(lamps({2, 6}), 1) is None
    m.reset()  # every lamp went out with the power: no green to time a yellow against
    assert m.check(lamps(), 1) is None


def test_the_controller_shows_its_monitor_every_lamp_it_lights_overlaps_included(
        city_config: IntersectionConfig) -> None:
    c = Controller(city_config)
    shown: list[Lamps] = []

    class Watched(Monitor):
        def check(self, seen: Shown, tick: int) -> str | None:
            shown.append(lamps(seen.greens, seen.yellows, seen.overlap_greens, seen.overlap_yellows))
            return super().check(seen, tick)

    c.monitor = Watched(city_config)
    c.backup_time = 0
    lit = set()
    for pair in [(1, 5), (2, 6), (3, 7), (4, 8), (1, 6), (2, 5)] * 2:
        c.set_control(ControlColumn.VEH_CALL, pair)
        for _ in range(150):
            c.step()
            lit.add(lamps(c.greens, c.yellows, c.overlap_greens, c.overlap_yellows))
    assert not c.flashing
    assert lit <= set(shown), "lamps the controller lit that its monitor never saw"
    assert any(s.overlap_greens for s in shown) and any(s.overlap_yellows for s in shown)
