"""The time grid every periodic process keeps: the index it gives a time is the one the grid's own float
instants say, however the quotient ``(t - start) / period`` rounds."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from hils.protocol.timegrid import Grid

starts = st.floats(min_value=0.0, max_value=1e5, allow_nan=False)
periods = st.sampled_from([0.1, 0.25, 1 / 3, 2.0, 0.05, 1 / 7])


@given(starts, periods, st.integers(min_value=0, max_value=10**6), st.integers(min_value=-3, max_value=3),
       st.integers(min_value=0, max_value=5))
def test_first_at_or_after_is_the_first_instant_not_before_the_time(start: float, period: float, k: int,
                                                                   nudge: int, floor: int) -> None:
    grid = Grid(start, period)
    t = grid.at(k) + nudge * 1e-12 * max(1.0, grid.at(k))  # on an instant, or a hair either side of it
    j = grid.first_at_or_after(t, floor)
    assert j >= floor and grid.at(j) >= t
    assert j == floor or grid.at(j - 1) < t


@given(starts, periods, st.integers(min_value=0, max_value=10**6), st.integers(min_value=-3, max_value=3))
def test_first_after_is_the_first_instant_past_the_time(start: float, period: float, k: int, nudge: int) -> None:
    grid = Grid(start, period)
    t = grid.at(k) + nudge * 1e-12 * max(1.0, grid.at(k))
    j = grid.first_after(t)
    assert grid.at(j) > t
    assert j == 0 or grid.at(j - 1) <= t


def test_an_instant_is_computed_from_the_start_not_summed() -> None:
    grid = Grid(0.0, 0.1)
    summed = 0.0
    for _ in range(30):
        summed += 0.1
    assert grid.at(30) == 0.0 + 30 * 0.1 != summed  # a sum of 30 periods has drifted off the grid
    assert grid.delay(30, 2.5) == grid.at(30) - 2.5 and grid.delay(3, 2.5) == 0.0
