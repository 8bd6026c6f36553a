"""Our controller against SUMO's own NEMA controller (issue 9, "Proof").

The reference side is checked first, so that a broken harness cannot pass for agreement: SUMO's
NEMA logic must show each rule of the targeted scenarios in its own timeline. Then both
controllers get the same calls, targeted and random, and at least 95 % of the interval
changes must agree within 0.1 s. libsumo runs one simulation per process and each run starts
and closes its own (about 10 ms), so the tests run sequentially in this process.
"""

from __future__ import annotations

import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from harness.nema_reference import (
    AGREEMENT_REQUIRED,
    SCENARIOS,
    WARM_UP,
    WARM_UP_TICKS,
    CallSequence,
    Color,
    ColorChange,
    NemaReferenceError,
    Quirk,
    QuirkSighting,
    compare,
    differential,
    pooled,
    random_calls,
    reference_quirks,
    run_ours,
    run_reference,
    seconds,
    sumo_program,
)
from hils.config import IntersectionConfig
from hils.sumo_net import derive_phase_map, read_net


def onset(timeline: tuple[ColorChange, ...], phase: int, color: Color, after: int = 0) -> int | None:
    """Tick of the first onset of ``color`` on ``phase`` after tick ``after``."""
    return next((c.tick for c in timeline if c.phase == phase and c.color is color and c.tick > after), None)


def test_program_names_the_rings_barriers_and_switches_recalls_off(paper_config: IntersectionConfig) -> None:
    program = sumo_program(paper_config, derive_phase_map(paper_config, read_net()))
    for key, value in [("ring1", "1,2,3,4"), ("ring2", "5,6,7,8"), ("barrierPhases", "4,8"),
                       ("coordinatePhases", "2,6"), ("minRecall", ""), ("maxRecall", "")]:
        assert f'<param key="{key}" value="{value}"/>' in program
    assert program.count("<phase ") == 8
    assert 'minDur="3" maxDur="20"' in program and 'yellow="3" red="2"' in program


def test_compare_pairs_within_a_tick_and_counts_both_sides() -> None:
    g = Color.GREEN
    ours = (ColorChange(10, 2, g), ColorChange(50, 4, g), ColorChange(90, 6, g))
    ref = (ColorChange(11, 2, g), ColorChange(52, 4, g), ColorChange(90, 6, Color.YELLOW))
    result = compare(ours, ref)
    assert [(a.tick, b.tick) for a, b in result.matched] == [(10, 11)]
    assert len(result.only_ours) == 2 and len(result.only_reference) == 2
    assert result.agreement == pytest.approx(1 / 5)
    assert compare((), ()).agreement == 1.0


def test_bad_call_sequences_are_refused(paper_config: IntersectionConfig) -> None:
    with pytest.raises(NemaReferenceError, match="unknown phase"):
        run_ours(paper_config, ((0, frozenset({9})),), 10)
    with pytest.raises(NemaReferenceError, match="ascending"):
        run_reference(paper_config, ((5, frozenset()), (5, frozenset({2}))), 10)


# --- the reference shows each rule ---------------------------------------------------------


def test_reference_rests_and_times_minimum_yellow_and_red(paper_config: IntersectionConfig) -> None:
    ref = run_reference(paper_config, seconds((0, []), (10, [2, 6])), 200)
    assert onset(ref, 1, Color.YELLOW) == 101  # 1+5 rest in green until the call, then end at once
    assert onset(ref, 1, Color.RED) == 131 and onset(ref, 2, Color.GREEN) == 151


def test_reference_crosses_the_barrier_with_both_rings(paper_config: IntersectionConfig) -> None:
    ref = run_reference(paper_config, *SCENARIOS["barrier crossing together"])
    assert onset(ref, 2, Color.YELLOW) == onset(ref, 6, Color.YELLOW) == 261  # 6's call dropped at 26 s
    maxed = run_reference(paper_config, *SCENARIOS["max-out of one ring while the other times"])
    assert onset(maxed, 2, Color.YELLOW) == onset(maxed, 6, Color.YELLOW) == 300  # 20 s after the call on 8


def test_reference_keeps_the_next_phase_chosen_at_yellow(paper_config: IntersectionConfig) -> None:
    ref = run_reference(paper_config, *SCENARIOS["phase next decided at yellow"])
    assert onset(ref, 4, Color.GREEN) == 80 < onset(ref, 2, Color.GREEN, after=80)


def test_reference_backs_into_an_earlier_phase(paper_config: IntersectionConfig) -> None:
    ref = run_reference(paper_config, *SCENARIOS["backing into a phase"])
    assert onset(ref, 5, Color.GREEN) == 191 and onset(ref, 2, Color.YELLOW, after=81) is None


def test_reference_enters_with_the_dual_entry_phase(paper_config: IntersectionConfig) -> None:
    ref = run_reference(paper_config, *SCENARIOS["dual entry"])
    assert onset(ref, 4, Color.GREEN) == onset(ref, 8, Color.GREEN) == 80


def test_reference_redirects_a_ring_during_clearance(paper_config: IntersectionConfig) -> None:
    """SUMO's quirk: a call during clearance changes the phase next chosen at yellow (3 for 4)."""
    calls, ticks = seconds((0, [2, 6]), (12, [4]), (13, [3, 4]), (40, [])), 500
    ref = run_reference(paper_config, calls, ticks)
    assert onset(ref, 3, Color.GREEN) == 171 and onset(ref, 4, Color.GREEN) == 421
    assert reference_quirks(paper_config, calls, ref, ticks) == (QuirkSighting(122, 171, 3, Quirk.REDIRECTED),)
    for name, (calls, ticks) in SCENARIOS.items():
        assert reference_quirks(paper_config, calls, run_reference(paper_config, calls, ticks), ticks) == (), name


@pytest.mark.parametrize(("calls", "ticks", "kind", "tick"), [
    # 3+7 green, calls on 1, 5 and 8: SUMO crosses to 1+5 and leaves 8 (after 7, before the barrier) unserved
    (seconds((0, [3, 7]), (12, [1, 5, 8]), (30, [])), 400, Quirk.SKIPPED, 171),
    # 2+5 green; 5 ends alone toward 6 (called), then 2 becomes ready with 3 called: SUMO takes ring 2
    # across with ring 1 (3+8) instead of serving 6
    (seconds((0, [2, 5]), (9, [3, 6]), (30, [])), 400, Quirk.PULLED_ACROSS, 160),
    # 3+8 -> 4+8; 8's max-out (timed from the call on 4, its concurrent phase) ends 4 too, 15 s into
    # its 20 s maximum with its call on
    (seconds((0, [3, 8]), (12, [4, 8]), (15, [2, 4, 8]), (45, [])), 500, Quirk.FORCED_END, 320),
])
def test_reference_quirks_are_recognised(paper_config: IntersectionConfig, calls: CallSequence, ticks: int,
                                         kind: Quirk, tick: int) -> None:
    quirks = reference_quirks(paper_config, calls, run_reference(paper_config, calls, ticks), ticks)
    assert quirks and quirks[0].kind is kind and quirks[0].tick == tick, quirks


# --- our controller agrees ---------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_targeted_scenarios_agree(paper_config: IntersectionConfig, name: str) -> None:
    calls, ticks = SCENARIOS[name]
    result = differential(paper_config, calls, ticks)
    assert result.agreement >= AGREEMENT_REQUIRED, f"{name}: {result.report(calls)}"


def test_barrier_crossing_example_of_the_issue(paper_config: IntersectionConfig) -> None:
    ours = run_ours(paper_config, *SCENARIOS["barrier crossing together"])
    assert onset(ours, 2, Color.YELLOW) == onset(ours, 6, Color.YELLOW) == 261


def _pooled_agreement(config: IntersectionConfig, cases: list[tuple[CallSequence, int]]) -> None:
    """At least 95 % of the changes of all ``cases`` agree, each compared up to SUMO's first quirk."""
    results = [(calls, differential(config, calls, ticks, stop_at_quirk=True)) for calls, ticks in cases]
    matched, total = pooled([r for _, r in results])
    assert matched >= AGREEMENT_REQUIRED * total, f"{matched} of {total} changes agree:\n" + "\n".join(
        r.report(calls) for calls, r in results if r.agreement < 1)


def test_seeded_random_sequences_agree(paper_config: IntersectionConfig) -> None:
    """40 sequences of five minutes (the figure of python -m harness.nema_reference, other seed)."""
    rng = random.Random(9)
    cases = [(random_calls(rng, 3000, sorted(paper_config.phases)), 3000) for _ in range(40)]
    compared = sum(len(differential(paper_config, c, t, stop_at_quirk=True).reference) for c, t in cases[:5])
    assert compared >= 50  # SUMO's quirks leave enough of the sequences to compare
    _pooled_agreement(paper_config, cases)


@st.composite
def call_sequences(draw: st.DrawFn) -> tuple[CallSequence, int]:
    """After the warm-up, calls that are held (up to 30 s) and calls that come and go (down to a tick)."""
    segments = draw(st.lists(st.tuples(st.one_of(st.integers(1, 20), st.integers(20, 300)),
                                       st.frozensets(st.integers(1, 8), max_size=4)), min_size=1, max_size=25))
    out, tick = list(WARM_UP), WARM_UP_TICKS
    for length, phases in segments:
        out.append((tick, phases))
        tick += length
    return tuple(out), tick + 300  # and 30 s without a change to settle


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(cases=st.lists(call_sequences(), min_size=10, max_size=10))
def test_random_call_sequences_agree(paper_config: IntersectionConfig,
                                     cases: list[tuple[CallSequence, int]]) -> None:
    _pooled_agreement(paper_config, cases)
