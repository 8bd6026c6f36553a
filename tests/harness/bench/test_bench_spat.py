"""`hils bench spat` measures what it says: over two minutes of the four-leg with SUMO's traffic under each
operation, every indication change is counted, each against the window announced for it, and most had a finite
latest announced the tick before (the figure is not hollow); the report sums the runs per operation."""

from __future__ import annotations

import pytest

from harness.bench import spat


@pytest.mark.parametrize("operation", list(spat.OPERATIONS))
def test_every_change_inside_and_most_with_a_latest(operation: str) -> None:
    share = spat.measure(operation, seconds=120.0, seed=0)
    assert share.changes > 20 and share.inside == share.changes, share.first_outside
    assert share.bounded > share.changes / 2, share
    text, figures = spat.report([share, share])
    totals = figures["operations"][operation]
    assert totals["changes"] == 2 * share.changes and totals["inside_percent"] == 100.0
    assert f"{operation:14} {'all':>6}" in text
