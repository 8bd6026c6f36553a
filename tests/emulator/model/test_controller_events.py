"""The event-driven controller is the ticked one: identical timelines and identical reads.

:meth:`Controller.advance` skips the ticks that :meth:`Controller.quiet_ticks` proves change nothing
but counters. Here one controller steps every tick and its twin advances over the same stretches,
for random configs (every phase option, start-up flash, backup time, the controller's delays) and
random inputs (every control object, Max2, detectors with delays, extensions and carryovers, push buttons,
retimed phases (to what the phase table holds), backup time, patterns, preempts, power cycles):
after every stretch the two must agree on everything a read can see and on their whole working
memory, and their interval timelines must be the same, tick for tick.
"""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.model.controller import Change, Controller
from emulator.model.delays import STATUS_ATTRIBUTES, DelayedController
from emulator.model.ring import SETTABLE
from hils.protocol import config as config_mod
from hils.protocol.config import DetectorTiming, EmulatorParams, IntersectionConfig, Recall
from hils.protocol.ntcip import ControlColumn, PhaseStartup
from hils.sim.network import data_path
from tests.emulator.model.test_controller_properties import ALL_PHASES, configs, phase_sets

SETTINGS = settings(max_examples=150, deadline=None)
TIMING_FIELDS = ("min_green", "max1", "max2", "passage", "walk", "ped_clear", "yellow", "red_clear", "red_revert")


@st.composite
def units(draw: st.DrawFn, free: bool = False) -> IntersectionConfig:
    """A random config with a start-up flash, a backup time, detector timers and the controller's delays drawn, half the
    time a coordination plan (patterns, modes, maybe a time-of-day change), half the time overlaps and half the
    time preempts; ``free``: never a plan or overlaps (the units that rest most often)."""
    cfg = draw(configs(coordinated=not free and draw(st.booleans()), overlapped=not free and draw(st.booleans()),
                       preempted=draw(st.booleans())))
    timers = st.builds(DetectorTiming, *[st.sampled_from([0.0, 0.0, 0.1, 0.5, 2.0, 3.0])] * 3)
    return dataclasses.replace(
        cfg, startup_flash=draw(st.sampled_from([0, 0, 1, 3])),
        detector_timing=draw(st.dictionaries(st.sampled_from(sorted(ALL_PHASES)), timers, max_size=4)),
        middleware=dataclasses.replace(cfg.middleware, backup_time=draw(st.sampled_from([0, 2, 5, 30]))),
        emulator=EmulatorParams(call_processing_ticks=draw(st.integers(0, 3)),
                                status_update_ticks=draw(st.integers(0, 3))))


@st.composite
def retimes(draw: st.DrawFn) -> tuple[int, str, int]:
    """A SET of one phase's timing to a value its phase-table object holds, up to 8 s (a yellow of 3 s at least)."""
    phase, name = draw(st.sampled_from(sorted(ALL_PHASES))), draw(st.sampled_from(TIMING_FIELDS))
    return phase, name, draw(st.sampled_from([t for t in SETTABLE[name] if t <= 80]))


inputs = st.one_of(
    st.tuples(st.just("ticks"), st.integers(1, 600)),
    st.tuples(st.just("ticks"), st.integers(1, 5)),
    st.tuples(st.sampled_from(list(ControlColumn) + [ControlColumn.VEH_CALL] * 3), phase_sets),
    st.tuples(st.just("max2"), st.frozensets(st.sampled_from([1, 2]))),
    st.tuples(st.just("detectors"), phase_sets),
    st.tuples(st.just("push_buttons"), phase_sets),
    st.tuples(st.just("retime"), retimes()),
    st.tuples(st.just("backup_time"), st.sampled_from([0, 1, 3, 30])),
    st.tuples(st.just("power_cycle"), st.none()),
    st.tuples(st.just("pattern"), st.sampled_from([0, 1, 2, 254, 255])),
    st.tuples(st.just("preempt"), st.frozensets(st.sampled_from([1, 2]))),
    st.tuples(st.just("ticks"), st.integers(600, 2400)),
)


def apply(unit: Controller | DelayedController, op: str, value: object, *, ticked: bool) -> None:
    """One input, or a stretch of ticks: stepped one by one, or advanced over."""
    if op == "ticks":
        if ticked:
            for _ in range(value):
                unit.step()
        else:
            unit.advance(value)
    elif op == "max2":
        unit.set_max2(value)
    elif op == "detectors":
        unit.set_actuations(value)
    elif op == "push_buttons":
        unit.set_ped_actuations(value)
    elif op == "retime":
        unit.set_timing(*value)
    elif op == "backup_time":
        unit.set_backup_time(value)
    elif op == "power_cycle":
        unit.reset()
    elif op == "pattern":
        unit.set_pattern_control(value)
    elif op == "preempt":
        unit.set_preempt_control(value)
    else:
        unit.set_control(op, value)


def readable(unit: Controller | DelayedController) -> dict[str, object]:
    """What the NTCIP agent can read of the unit (status as the agent answers it)."""
    out = {name: getattr(unit, name) for name in STATUS_ATTRIBUTES}
    out |= {"control": dict(unit.control), "control_status": unit.control_status, "flash": unit.flash_status,
            "max2": unit.max2_rings, "actuations": unit.actuations, "ped_actuations": unit.ped_actuations,
            "backup_time": unit.backup_time, "status_version": unit.status_version}
    return out


def memory(c: Controller) -> dict[str, object]:
    """The controller's whole working memory."""
    co = c.coordinator
    return {"tick": c.tick, "rings": [dataclasses.astuple(r) for r in c.rings], "group": c.group,
            "since_set": c.backup.since, "ped_calls": c.ped_calls,
            "latches": (dict(c.coordinated.forced), dict(c.coordinated.limit), dict(c.coordinated.yielded),
                        dict(c.preempting.cut)),
            "coordination": (co.clock, co.command, co.local, co.running, co.timer, co.budget, co.free_status,
                             co.replan),
            "overlaps": (dict(c.overlaps.shown), dict(c.overlaps.ticks)),
            "detectors": (c.detectors.recognized, dict(c.detectors.waited), dict(c.detectors.held)),
            "preempts": (c.preemptor.discrete(), dict(c.preemptor.presence), dict(c.preemptor.waited),
                         dict(c.preemptor.since_entry), dict(c.preemptor.stage))}


def twins(config: IntersectionConfig, delayed: bool) -> list[tuple[Controller | DelayedController, list[Change]]]:
    out = []
    for _ in range(2):
        timeline: list[Change] = []
        c = Controller(config, on_change=timeline.append)
        out.append((DelayedController(c, config.emulator) if delayed else c, timeline))
    return out


def check_equal(config: IntersectionConfig, ops: list[tuple[str, object]], *, delayed: bool) -> None:
    (ticked, ticked_timeline), (evented, evented_timeline) = twins(config, delayed)
    for op, value in ops:
        apply(ticked, op, value, ticked=True)
        apply(evented, op, value, ticked=False)
        assert readable(evented) == readable(ticked), (op, value)
        bare = [u.controller if delayed else u for u in (ticked, evented)]
        assert memory(bare[1]) == memory(bare[0]), (op, value)
        assert evented_timeline == ticked_timeline


@SETTINGS
@given(config=units(), ops=st.lists(inputs, max_size=25))
def test_advance_is_stepping_every_tick(config: IntersectionConfig, ops: list[tuple[str, object]]) -> None:
    check_equal(config, ops, delayed=False)


@SETTINGS
@given(config=units(free=True), ops=st.lists(inputs, max_size=25))
def test_advance_is_stepping_every_tick_free(config: IntersectionConfig, ops: list[tuple[str, object]]) -> None:
    """Free, without overlaps: quiet time often starts right after a step that changed something."""
    check_equal(config, ops, delayed=False)


@pytest.mark.slow
@SETTINGS
@given(config=units(), ops=st.lists(inputs, max_size=25))
def test_advance_behind_the_delays_is_stepping_every_tick(config: IntersectionConfig,
                                                          ops: list[tuple[str, object]]) -> None:
    check_equal(config, ops, delayed=True)


def test_a_preempt_called_in_the_start_up_flash_is_read_after_it() -> None:
    """The step that ends the start-up flash starts the intervals and reads no input: the preempt called during the
    flash is read by the next step, which quiet time may not skip (the start-up greens called, nothing else)."""
    config = dataclasses.replace(config_mod.load(data_path("four_leg_city.toml")), startup_flash=3)
    assert config.preempts
    check_equal(config, [("preempt", frozenset({1})), (ControlColumn.VEH_CALL, frozenset({2, 6})), ("ticks", 60)],
                delayed=False)


def test_a_delaying_detector_actuated_in_the_start_up_flash_starts_its_delay_after_it() -> None:
    """Detector 1 (delay 0.1 s), or 2 (no timer), comes on during the start-up flash, which reads no input, no phase
    starting after it: the step after the flash starts its delay or recognizes it, and quiet time may not skip it
    (the detector unit's deadline; before, it had only delays already running, and the skipping twin never called
    the phase)."""
    config = config_mod.load()
    config = dataclasses.replace(
        config, startup_flash=1, detector_timing={1: DetectorTiming(delay=0.1)},
        phases={p: dataclasses.replace(ph, startup=PhaseStartup.PHASE_NOT_ON) for p, ph in config.phases.items()},
    ).with_middleware(backup_time=0)
    check_equal(config, [("detectors", frozenset({1})), ("ticks", 11), ("ticks", 40)], delayed=False)
    # detector 2, without a timer of its own, is read after the flash as well
    check_equal(config, [("ticks", 9), ("detectors", frozenset({2})), ("ticks", 2), ("ticks", 40)], delayed=False)


@pytest.mark.parametrize("delayed", [False, True])
def test_a_max_recalled_green_times_its_maximum_in_quiet_time(delayed: bool) -> None:
    """4+8 on max recall start green with nothing else called: their maximum timers run from the green's first tick
    on, through quiet time that starts right after the green does (the units' deadlines); they rest maxed
    out until a call on 2 ends them. The twins agree throughout (a proof that took the timer to run only with
    conflicting demand left the skipping twin's timer at zero)."""
    config = config_mod.load().with_middleware(backup_time=0)
    config = dataclasses.replace(config, phases={p: dataclasses.replace(ph, recall=Recall.MAX) if p in (4, 8) else ph
                                                 for p, ph in config.phases.items()})
    check_equal(config, [("ticks", 150), ("ticks", 300), (ControlColumn.VEH_CALL, frozenset({2})), ("ticks", 20)],
                delayed=delayed)


@pytest.mark.parametrize("delayed", [False, True])
def test_a_repeated_set_restarts_the_backup_timer_and_nothing_else(delayed: bool) -> None:
    """The same calls SET again while resting in their green, and again while a backup time runs out: the twins
    agree (the backup timer restarts at the write's tick, the status counts the write)."""
    config = dataclasses.replace(config_mod.load(), middleware=dataclasses.replace(config_mod.load().middleware,
                                                                                   backup_time=30))
    calls = (ControlColumn.VEH_CALL, frozenset({4, 8}))
    check_equal(config, [calls, ("ticks", 200), calls, ("ticks", 250), calls, ("ticks", 100), ("ticks", 300), calls,
                         ("ticks", 5), calls, ("ticks", 400)], delayed=delayed)


def test_a_repeated_set_is_no_step() -> None:
    """Resting in the called green, the same calls again (within the backup time): quiet time goes on, and the status
    counts the write."""
    c = CountingController(config_mod.load())
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    c.advance(200)
    c.steps, version = 0, c.status_version
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    assert c.status_version > version  # a poller waiting for a change reads the unit again, as after any write
    c.advance(100)
    assert c.greens == {4, 8} and c.steps == 0


class CountingController(Controller):
    """Counts the steps it really runs."""

    steps = 0

    def step(self) -> None:
        self.steps += 1
        super().step()


def test_quiet_time_is_skipped() -> None:
    """The paper's intersection resting in green, then one transition: a handful of real steps, not one per tick."""
    c = CountingController(config_mod.load())
    c.advance(100)
    assert c.greens == {2, 6} and c.quiet_ticks() is None  # resting in green on the start-up pair, nothing called
    assert c.steps <= 1  # the first tick (its minimum changes nothing: nothing else is called)
    c.set_control(ControlColumn.VEH_CALL, {4, 8})
    c.steps = 0
    c.advance(100)  # yellow 3 s, red clearance 2 s, then minimum green of 4 and 8, resting there
    assert c.greens == {4, 8} and c.tick == 200
    # The call ending 2 and 6, their yellows ending, their red clearances ending (4 and 8 start): no step after a
    # change only to see that the next one changes nothing, none where 4 and 8 time their minimum with nothing
    # else called.
    assert c.steps <= 3


def test_quiet_time_is_skipped_under_a_pattern_with_overlaps() -> None:
    """The city four-leg (overlaps, a preempt configured) under its pattern, every phase called: the units' deadlines
    (the coordinator's marks, the rings' thresholds, the overlaps following their phases) leave most ticks quiet, as
    they do free; a twin stepping every tick agrees. (Quiet time that started only after a step that changed
    nothing never started under a pattern: the points the local timer passes change at every tick.)"""
    config = config_mod.load(data_path("four_leg_city.toml")).with_middleware(backup_time=0)
    ops = [(ControlColumn.VEH_CALL, frozenset({2, 4, 6, 8})), ("pattern", 1), ("ticks", 100), ("ticks", 3000)]
    check_equal(config, ops, delayed=False)
    c = CountingController(config)
    for op, value in ops[:-1]:
        apply(c, op, value, ticked=False)
    c.steps = 0
    c.advance(3000)
    assert c.coordinator.plan is not None and c.steps < 3000 // 5


def test_conditional_service_stops_when_the_other_green_has_no_time_left() -> None:
    """Phase 2 (conditional service) held past its gap-out with a call on 1, beside 6 on max recall: 2 may back into 1
    while 6 has time left before its maximum (20 s) for 2's clearance and 1's minimum (8 s), so the call on 1 is no
    conflicting demand against 6 until 6's maximum timer passes 12 s; then it is, and 6 registers it. Nothing else
    reaches a threshold at that tick: quiet time must end there (the conditional-service thresholds), or a skipping
    twin registers the call only when 6 maxes out."""
    config = config_mod.load().with_middleware(backup_time=0)
    config = dataclasses.replace(config, phases=config.phases | {
        2: dataclasses.replace(config.phases[2], conditional_service=True),
        6: dataclasses.replace(config.phases[6], recall=Recall.MAX)})
    ops = [(ControlColumn.HOLD, frozenset({2})), (ControlColumn.VEH_CALL, frozenset({1})), ("ticks", 115),
           ("ticks", 25), ("ticks", 460)]
    check_equal(config, ops, delayed=False)
    c = Controller(config)
    for op, value in ops[:3]:
        apply(c, op, value, ticked=True)
    assert c.greens == {2, 6} and not c.rings[1].conflict  # 2 may still back into 1
    apply(c, "ticks", 25, ticked=True)
    assert c.greens == {2, 6} and c.rings[1].conflict  # no more: the call on 1 waits across 6's green


def test_a_phase_cycling_in_a_preempts_dwell_registers_the_dwell_phase_waiting() -> None:
    """The city four-leg's preempt 1 (dwell 2+5) with 6 cycling in its dwell, and a call on 6: in the dwell 5 gives
    way to 6, whose green registers the dwell phase 5 (always demanded in the dwell) as conflicting demand at its
    first tick. Quiet time must read the demand as the dwell cycles on it (the cycling dwell's deadline), or a
    skipping twin leaves that demand unregistered and 6's maximum timer held."""
    config = config_mod.load(data_path("four_leg_city.toml")).with_middleware(backup_time=0)
    config = dataclasses.replace(config, preempts=config.preempts | {
        1: dataclasses.replace(config.preempts[1], cycling_phases=(6,))})
    ops = [(ControlColumn.VEH_CALL, frozenset({6})), ("ticks", 30), ("preempt", frozenset({1})), ("ticks", 131),
           ("ticks", 1), ("ticks", 100)]
    check_equal(config, ops, delayed=False)
    c = Controller(config)
    for op, value in ops[:4]:
        apply(c, op, value, ticked=True)
    assert c.greens == {2, 6} and c.preempted and not c.rings[1].conflict  # 6 starts in the dwell
    apply(c, "ticks", 1, ticked=True)
    assert c.greens == {2, 6} and c.rings[1].conflict  # 5, the dwell phase, waits for 6


def test_a_retimed_clearance_moves_where_a_phase_stops_fitting() -> None:
    """3 and 5 coordinated (cycle 42 s), every phase called. 5's red clearance retimed to 0 in its green: 6 fits
    until 5's clearance (now 3.0 s, not the plan's 3.5 s) and 6's minimum no longer reach 6's force-off, and from
    that tick 5 leaves for 7 across the barrier (with 3 for 4). That tick is none of the coordinator's marks, laid out
    with the config's clearances: the coordinated part in the rings reports it (before, the skipping twin ended 3 and
    5 0.4 s late, at the next whole second)."""
    raw = {"name": "3 and 5 coordinated", "timing": {"min_green": 1, "max_green": 1, "yellow": 3.0, "red_clear": 0.5},
           "phases": {str(p): {} for p in range(1, 9)},
           "structure": {"rings": [[1, 2, 3, 4], [5, 6, 7, 8]], "barriers": [[1, 2, 3, 5, 6], [4, 7, 8]],
                         "sequence": [[1, 5], [4, 8]],
                         "pairs": [[1, 5], [1, 6], [2, 5], [2, 6], [3, 5], [3, 6], [4, 7], [4, 8]]},
           "middleware": {"backup_time": 0},
           "coordination": {"pattern": 1, "patterns": [{"number": 1, "cycle": 42, "offset": 0, "coord_phases": [3, 5],
                                                        "splits": {"1": 5, "2": 5, "3": 22, "4": 10, "5": 5, "6": 27,
                                                                   "7": 5, "8": 5}}]}}
    config = config_mod.from_dict(raw, "coordinated.toml")
    every = (ControlColumn.VEH_CALL, frozenset(config.phases))
    check_equal(config, [("ticks", 204), every, ("ticks", 7), ("retime", (5, "red_clear", 0)), ("ticks", 600)],
                delayed=False)
