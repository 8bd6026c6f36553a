"""Our controller against SUMO's own NEMA controller (issues 9, 24 and 35, "Proof").

The reference side is checked first, so that a broken harness cannot pass for agreement: SUMO's
NEMA logic must show each rule of the targeted scenarios in its own timeline. Then both
controllers get the same calls (targeted, random, and those SUMO's detectors placed serving
traffic) and are compared over whole sequences: the targeted scenarios (the paper's intersection)
agree change for change, every divergence is judged by a rule quoted from a source, and neither
a divergence nor the audit of our own greens finds a fault of the model. The agreement figures of
issue 35 stay as floors. That the judge can fail is tested in test_nema_judge_fails.py. libsumo
runs one simulation per process and each run starts and closes its own (about 10 ms), so the
tests run sequentially in this process.
"""

from __future__ import annotations

import dataclasses
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from harness.reference.mib import REFERENCE
from harness.reference.nema import (
    EXAMPLES,
    SCENARIOS,
    WARM_UP,
    WARM_UP_TICKS,
    CallSequence,
    Differential,
    Mode,
    NemaReferenceError,
    calls_read,
    comparable_config,
    compare,
    differential,
    in_mode,
    pooled,
    random_calls,
    run_ours,
    run_reference,
    seconds,
    sumo_options,
    sumo_program,
    traffic_differential,
)
from harness.reference.nema_rules import (
    BACKED_WITH_CALL_ACROSS,
    CLASSES,
    CONDITIONAL_SERVICE,
    NTCIP,
    SKIPPED,
    Color,
    ColorChange,
    DifferenceClass,
    Right,
    Settings,
    Side,
    Verdict,
    classify,
)
from hils.protocol.config import IntersectionConfig, NextPhaseLock
from hils.sim.network import derive_phase_map, read_net


def onset(timeline: tuple[ColorChange, ...], phase: int, color: Color, after: int = 0) -> int | None:
    """Tick of the first onset of ``color`` on ``phase`` after tick ``after``."""
    return next((c.tick for c in timeline if c.phase == phase and c.color is color and c.tick > after), None)


@pytest.fixture(scope="module")
def sumo_set(paper_config: IntersectionConfig) -> IntersectionConfig:
    """The paper's intersection set as SUMO's NEMA controller is where NTCIP 1202 leaves a setting (conditional
    service on every phase): what the figures compare."""
    return sumo_options(paper_config)


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


def test_reference_redirects_a_ring_during_clearance(sumo_set: IntersectionConfig) -> None:
    """SUMO lets a call during the clearance change the phase chosen at yellow on the same side (3 for 4): the
    red_end lock, which the comparable config gives our controller too."""
    calls, ticks = seconds((0, [2, 6]), (12, [4]), (13, [3, 4]), (40, [])), 500
    ref = run_reference(sumo_set, calls, ticks)
    assert onset(ref, 3, Color.GREEN) == 171 and onset(ref, 4, Color.GREEN) == 421
    assert comparable_config(sumo_set).next_phase_lock is NextPhaseLock.RED_END
    assert differential(sumo_set, calls, ticks).comparison.agreement == 1.0


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_targeted_scenarios_agree_change_for_change(sumo_set: IntersectionConfig, name: str) -> None:
    """The paper's intersection under issue 9's call patterns: 100 % of the changes, nothing to judge."""
    calls, ticks = SCENARIOS[name]
    result = differential(sumo_set, calls, ticks)
    assert result.first is None, f"{name}: {result.first}\n{result.comparison.report(calls)}"
    assert result.comparison.agreement == 1.0 and not result.audited


def test_barrier_crossing_example_of_the_issue(paper_config: IntersectionConfig) -> None:
    ours = run_ours(paper_config, *SCENARIOS["barrier crossing together"])
    assert onset(ours, 2, Color.YELLOW) == onset(ours, 6, Color.YELLOW) == 261


# --- the rules that judge a difference --------------------------------------------------------


@pytest.mark.parametrize("kind", list(EXAMPLES), ids=str)
def test_each_class_is_recognised_on_its_minimal_example(paper_config: IntersectionConfig,
                                                         kind: DifferenceClass) -> None:
    """The examples of docs/nema_differences.md: SUMO makes the difference and the class's rule names it. Ours backs
    as Naztec's controllers do (``backup_prevent = false``: only while nothing is called across the barrier), where
    SUMO backs too, and not as conditional service, which SUMO gives where the examples show it."""
    mode, calls, ticks = EXAMPLES[kind]
    naztec = dataclasses.replace(paper_config, phases={p: dataclasses.replace(ph, backup_prevent=False)
                                                       for p, ph in paper_config.phases.items()})
    first = differential(in_mode(naztec, mode), calls, ticks).first
    assert first is not None and first.kind is kind, first
    assert first.breaker is (None if kind.right is Right.SETTING else Side.SUMO)
    assert first.verdict is (Verdict.SETTING if kind.right is Right.SETTING else Verdict.REFERENCE)


def test_every_class_has_a_rule_a_source_and_an_example() -> None:
    assert set(EXAMPLES) == set(CLASSES)
    for kind in CLASSES:
        assert kind.rule and kind.quotes and all(q.text for q in kind.quotes), kind  # a quoted source


def test_every_quote_of_ntcip_1202_is_in_the_mib_text() -> None:
    """Word for word (spacing aside) in the NTCIP 1202 v03 MIB text kept beside the compiled MIB."""
    text = " ".join((REFERENCE.parent / "NTCIP1202-v03.mib").read_text(encoding="utf-8").split())
    quotes = {q for kind in CLASSES for q in kind.quotes if q.where.startswith(NTCIP)}
    assert len(quotes) >= 8
    for q in quotes:
        assert " ".join(q.text.split()) in text, q


def test_a_rule_holds_ours_to_it_too(paper_config: IntersectionConfig) -> None:
    """The rules judge what a controller showed, whichever it is: our timeline, given SUMO's skip, is the
    one that breaks the sequence rule."""
    _, calls, ticks = EXAMPLES[SKIPPED]
    ours, ref = run_ours(paper_config, calls, ticks), run_reference(paper_config, calls, ticks)
    first = compare(ours, ref).first_difference
    judged = classify(paper_config, calls_read(calls, ticks), ref, ours, first.tick)  # the sides swapped
    assert judged.kind is SKIPPED and judged.breaker is Side.OURS


def test_conditional_service_is_a_setting_only_on_a_side_that_has_it(paper_config: IntersectionConfig) -> None:
    """SUMO's backing shown as ours is our fault (the model has no conditional service), and a setting once ours is
    given the setting."""
    _, calls, ticks = EXAMPLES[CONDITIONAL_SERVICE]
    ours, ref = run_ours(paper_config, calls, ticks), run_reference(paper_config, calls, ticks)
    tick, called = compare(ours, ref).first_difference.tick, calls_read(calls, ticks)
    judged = classify(paper_config, called, ref, ours, tick)  # the sides swapped
    assert judged.kind is BACKED_WITH_CALL_ACROSS and judged.verdict is Verdict.MODEL
    given = {Side.OURS: Settings(conditional_service=True), Side.SUMO: Settings(conditional_service=False)}
    judged = classify(paper_config, called, ref, ours, tick, settings=given)
    assert judged.kind is CONDITIONAL_SERVICE and judged.verdict is Verdict.SETTING


# --- divergences -------------------------------------------------------------------------------


def _changes(*spec: tuple[float, int, str]) -> tuple[ColorChange, ...]:
    return tuple(sorted(ColorChange(round(t * 10), p, Color(c)) for t, p, c in spec))


def test_two_sides_a_second_apart_are_one_divergence_until_they_change_together_again() -> None:
    """Equal colours are no resync while the greens and yellows shown began at different times; once both show the
    same colours since changes they made together, the next difference is a divergence of its own."""
    ours = _changes((10, 2, "yellow"), (13, 2, "red"), (15, 3, "green"), (30, 3, "yellow"), (33, 3, "red"),
                    (35, 4, "green"), (50, 4, "yellow"))
    sumo = _changes((11, 2, "yellow"), (14, 2, "red"), (16, 3, "green"), (30, 3, "yellow"), (33, 3, "red"),
                    (35, 4, "green"), (52, 4, "yellow"))
    result = compare(ours, sumo)
    assert result.divergences(red_settled=21) == (100, 500)  # 3 yellow at 30 s, paired: back in step
    lagging = compare(ours, _changes(*((t + 1.1, p, c.value) for t, p, c in ((c.tick / 10, c.phase, c.color)
                                                                               for c in ours))))
    assert lagging.divergences(red_settled=21) == (100,)  # never in step again: one divergence


def test_a_red_begun_apart_is_in_step_once_its_clearance_is_over() -> None:
    ours = _changes((10, 2, "yellow"), (13, 2, "red"), (40, 3, "green"))
    sumo = _changes((11, 2, "yellow"), (14, 2, "red"), (41, 3, "green"))
    assert compare(ours, sumo).divergences(red_settled=21) == (100, 400)
    assert compare(ours, sumo).divergences(red_settled=300) == (100,)


def test_every_divergence_is_judged(paper_config: IntersectionConfig) -> None:
    """Two of the examples one after the other (the second after both sides are back in step): both judged."""
    first, second = EXAMPLES[SKIPPED][1], seconds((60, [2, 6]), (75, [2, 4, 5]), (105, []))
    result = differential(paper_config, first[:-1] + second, 1100)
    assert [j.kind for j in result.judgements] == [SKIPPED, CONDITIONAL_SERVICE], [str(j) for j in result.judgements]


# --- whole sequences ---------------------------------------------------------------------------


def _no_model_fault(results: list[Differential]) -> None:
    """Every divergence explained, and our controller breaks none of the rules there nor in any green it ends."""
    bad = [d for d in results if d.model_faults]
    assert not bad, "\n".join(f"{list(map(str, d.model_faults))}\n{d.comparison.report(d.calls)}" for d in bad)


#: Issue 35's figures of python -m harness.reference.nema (free mode, 50 random sequences of 300 s per seed), kept
#: as floors: matched over distinct changes, rounded down to 0.1 %. The 80 % goal of issue 24 is withdrawn: what
#: keeps the figures below it is SUMO departing from quoted rules (docs/nema_differences.md).
RANDOM_FLOORS = {1: 0.670, 2: 0.709, 3: 0.740}
TRAFFIC_FLOOR = 0.713  # 10 runs of 300 s of detector-driven traffic, SUMO seeds 0-9


@pytest.mark.slow
@pytest.mark.parametrize("seed", sorted(RANDOM_FLOORS))
def test_fifty_random_sequences_keep_the_floor_with_no_model_fault(sumo_set: IntersectionConfig,
                                                                   seed: int) -> None:
    """The figures of python -m harness.reference.nema --seed N: whole five-minute sequences, no cut-off."""
    rng = random.Random(seed)
    results = [differential(sumo_set, random_calls(rng, 3000, sorted(sumo_set.phases)), 3000)
               for _ in range(50)]
    _no_model_fault(results)
    matched, total = pooled([d.comparison for d in results])
    assert total > 4000 and matched >= RANDOM_FLOORS[seed] * total, f"{matched} of {total}"
    assert sum(len(d.judgements) for d in results) > 50  # the sequences exercise both sides


def test_detector_driven_traffic_keeps_the_floor_with_no_model_fault(sumo_set: IntersectionConfig) -> None:
    """SUMO serving the shipped demand on its own detectors; ours given the calls those detectors placed."""
    results = [traffic_differential(sumo_set, 3000, seed) for seed in range(10)]
    assert all(len(d.calls) > 20 for d in results)  # vehicles did call phases
    _no_model_fault(results)
    matched, total = pooled([d.comparison for d in results])
    assert matched >= TRAFFIC_FLOOR * total, f"{matched} of {total}"



def test_a_gap_out_held_when_its_call_comes_back_is_no_fault_however_late(sumo_set: IntersectionConfig) -> None:
    """Pattern 1, the sixth random sequence of seed 1 to 200 s: 4 gaps out at 180.8 s with nothing called, its call
    comes back at 181.8 s with calls on 5 and 6 across, and both controllers hold the gap-out: 4 ends with 8 at
    186.7 s, its call on (simultaneous gap disable). The rule excused that only when the call came back within
    0.2 s of the end, or a conflicting call had waited since the gap-out; the bit's words set no such limit."""
    config, rng = in_mode(sumo_set, Mode.TS2), random.Random(1)
    for _ in range(6):
        calls = random_calls(rng, 3000, sorted(config.phases))
    calls = tuple((k, ps) for k, ps in calls if k < 2000)
    result = differential(config, calls, 2000)
    four = [c for c in result.comparison.ours if c.phase == 4 and c.color is Color.YELLOW]
    assert four[-1].tick == 1867 and 4 in calls_read(calls, 2000)[1867]  # the case: ended with its call on
    assert not result.model_faults, [str(f) for f in result.model_faults]


# --- coordinated ------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", [Mode.TS2, Mode.TS2_FLOATING])
def test_the_plan_with_every_phase_called_agrees_change_for_change(sumo_set: IntersectionConfig,
                                                                   mode: Mode) -> None:
    """Both lay pattern 1 out the same way: every force-off point on the same tick, for three cycles."""
    result = differential(in_mode(sumo_set, mode), seconds((0, range(1, 9))), 2100)
    assert result.first is None and len(result.comparison.matched) > 60, result.first


def test_type_170_offsets_put_the_coordinated_yellow_on_the_local_zero(paper_config: IntersectionConfig) -> None:
    """With the Type 170 reference both end the coordinated phases at the local zero (every 70 s): SUMO's zero sits
    at the end of their clearance, which the program's offset compensates (see sumo_program)."""
    config = in_mode(paper_config, Mode.TYPE170)
    calls = seconds((0, range(1, 9)))
    for timeline in (run_ours(config, calls, 2200), run_reference(config, calls, 2200)):
        assert [c.tick for c in timeline if c.phase == 2 and c.color is Color.YELLOW][1:] == [700, 1400, 2100]


def test_the_sumo_program_runs_the_plan(paper_config: IntersectionConfig) -> None:
    program = sumo_program(in_mode(paper_config, Mode.TS2), derive_phase_map(paper_config, read_net()))
    for key, value in [("coordinate-mode", "true"), ("cycle-length", "70"), ("coordinatePhases", "2,6"),
                       ("barrierPhases", "4,8"), ("fixForceOff", "true"), ("controllerType", "TS2"),
                       ("minRecall", "2,6")]:
        assert f'<param key="{key}" value="{value}"/>' in program
    assert 'name="2"' in program and 'maxDur="23"' in program  # split 28 s less its 5 s clearance


@pytest.mark.slow
def test_coordinated_random_sequences_agree_with_no_model_fault(
        sumo_set: IntersectionConfig) -> None:
    """Issue 24's goal for coordinated operation: at least 95 % of the changes over whole sequences."""
    config = in_mode(sumo_set, Mode.TS2)
    rng = random.Random(1)
    results = [differential(config, random_calls(rng, 3000, sorted(config.phases)), 3000) for _ in range(50)]
    _no_model_fault(results)
    matched, total = pooled([d.comparison for d in results])
    assert total > 2000 and matched >= 0.95 * total, f"{matched} of {total}"


def test_coordinated_traffic_has_no_model_fault(sumo_set: IntersectionConfig) -> None:
    results = [traffic_differential(in_mode(sumo_set, Mode.TS2), 3000, seed) for seed in range(3)]
    _no_model_fault(results)


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


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(case=call_sequences())
def test_random_call_sequences_have_no_model_fault(sumo_set: IntersectionConfig,
                                                                 case: tuple[CallSequence, int]) -> None:
    _no_model_fault([differential(sumo_set, *case)])
