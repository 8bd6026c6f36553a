"""The one conflict check: phases against the config's matrix, overlaps against the phases none of their parents
runs beside, in a fixed order."""

from __future__ import annotations

from dataclasses import replace

from hils.protocol.config import IntersectionConfig
from hils.protocol.conflict import Conflict, conflicts, first_conflict

# The city four-leg's overlaps (hils/data/four_leg_city.toml): A right turn {8, 5}, D right turn {2, 7}, E the
# flashing yellow arrow protected with 1 and flashing beside 2.
A, D, E = 1, 4, 5


def test_two_phases_conflict_unless_the_matrix_allows_them(paper_config: IntersectionConfig) -> None:
    card = paper_config.permissives
    for a, b in ((1, 5), (1, 6), (2, 5), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8)):
        assert first_conflict(card, {a, b}) is None
    assert first_conflict(card, {2, 7}) == Conflict(2, 7)
    assert first_conflict(card, (7, 2)) == Conflict(2, 7)  # the lower phase first, whatever the order given
    assert first_conflict(card, {1, 2}) == Conflict(1, 2)  # one ring
    assert str(Conflict(2, 7)) == "phases 2 and 7"
    assert first_conflict(card, set()) is None and first_conflict(card, {4}) is None


def test_an_overlap_conflicts_with_the_phases_none_of_its_parents_runs_beside(city_config: IntersectionConfig) -> None:
    card = city_config.permissives
    # A shows with 8 and 5: beside them run 3 and 4 (with 8) and 1 and 2 (with 5); 6 and 7 run beside neither.
    assert card.overlaps[A] == {6, 7}
    assert first_conflict(card, {2, 5}, {A}) is None
    assert first_conflict(card, {2, 6}, {A}) == Conflict(A, 6, overlap=True)
    assert str(Conflict(A, 6, overlap=True)) == "overlap A and phase 6"
    # A flashing yellow arrow's permissive modifier is a parent too: E runs beside 1, 2 and what runs beside them.
    assert card.overlaps[E] == {3, 4, 7, 8}
    assert first_conflict(card, {2, 6}, {E}) is None
    assert first_conflict(card, {4, 8}, {E}) == Conflict(E, 4, overlap=True)
    # An overlap lit alone (trailing its parents) conflicts with nothing lit.
    assert first_conflict(card, set(), {A, E}) is None


def test_every_conflict_comes_phases_first_then_overlaps_each_in_number_order(city_config: IntersectionConfig) -> None:
    found = list(conflicts(city_config.permissives, {7, 6, 2}, {E, A, D}))
    assert found == [Conflict(2, 7), Conflict(6, 7),
                     Conflict(A, 6, overlap=True), Conflict(A, 7, overlap=True), Conflict(E, 7, overlap=True)]
    assert first_conflict(city_config.permissives, {7, 6, 2}, {E, A, D}) == found[0]


def test_the_permissives_are_the_configs_and_follow_a_copy(city_config: IntersectionConfig,
                                                           paper_config: IntersectionConfig) -> None:
    assert city_config.permissives.phases == city_config.compatibility
    assert set(city_config.permissives.overlaps) == set(city_config.overlaps)
    assert paper_config.permissives.overlaps == {}
    # A copy with another matrix is judged by it: nothing runs beside anything, so every overlap conflicts with
    # every phase but its own parents.
    strict = replace(city_config, compatibility=frozenset())
    assert first_conflict(strict.permissives, {2, 6}) == Conflict(2, 6)
    assert strict.permissives.overlaps[A] == set(city_config.phases) - {8, 5}
    assert replace(city_config) == city_config
