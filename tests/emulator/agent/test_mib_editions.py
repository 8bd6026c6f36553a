"""The MIB view as one edition of NTCIP 1202 defines it (v02, what a Cobalt speaks, or v03), and the objects it
answers from the config and the running controller: index columns, rings and sequences, the channel map, the time
base actions, v03's preempt status."""

from __future__ import annotations

import tomllib
from datetime import datetime, timedelta
from importlib import resources
from typing import Any

import pytest
import simpy
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.agent.mib import MibView
from emulator.inprocess import VirtualTarget
from emulator.model.controller import Controller
from hils.protocol.config import ConfigError, IntersectionConfig, from_dict
from hils.protocol.ntcip import (
    ASC_CURRENT_TICK,
    CHANNEL_CONTROL_SOURCE,
    CHANNEL_CONTROL_TYPE,
    DETECTOR_ACTUATION,
    MAX_CHANNELS,
    MAX_PREEMPT_GROUPS,
    MAX_RINGS,
    MAX_SEQUENCES,
    MAX_TIMEBASE_ACTIONS,
    MAX_VEHICLE_DETECTOR_CONTROL_GROUPS,
    PATTERN_TABLE,
    PED_DETECTOR_ACTUATION,
    PHASE_NUMBER,
    PREEMPT_CONTROL_STATE,
    PREEMPT_STATUS,
    PREEMPT_STATUS_GROUP,
    PREEMPT_TABLE,
    SEQUENCE_RING_NUMBER,
    SPAT_OPTIONS,
    SPAT_TIMESTAMP,
    TIMEBASE_ACTION_STATUS,
    TIMEBASE_PATTERN,
    UNIT_RED_REVERT,
    VEHICLE_DETECTOR_NUMBER,
    Access,
    ChannelControlType,
    ErrorStatus,
    PatternColumn,
    PhaseColumn,
    PreemptColumn,
    PreemptState,
    SnmpError,
    Version,
    phase_oid,
)

SPLIT_NUMBER_1 = PATTERN_TABLE[PatternColumn.SPLIT_NUMBER].instance(1)
V03_ONLY = (PREEMPT_STATUS.instance(), MAX_PREEMPT_GROUPS.instance(), PREEMPT_STATUS_GROUP.instance(1))


def _raw(name: str) -> dict[str, Any]:
    return tomllib.loads((resources.files("hils.data") / name).read_text(encoding="utf-8"))


def _config(name: str, ntcip: object = None, schedule: list[dict[str, object]] | None = None,
            source: str | None = None) -> IntersectionConfig:
    raw = _raw(name)
    if ntcip is not None:
        raw.setdefault("emulator", {})["ntcip"] = ntcip
    if schedule is not None:
        raw["coordination"]["schedule"] = schedule
    return from_dict(raw, source or name)


def _city(edition: Version, start: datetime | None = None) -> MibView:
    return MibView(Controller(_config("four_leg_city.toml"), **({"start": start} if start else {})), edition)


def test_under_v02_the_objects_v03_added_answer_no_such_object() -> None:
    v02, v03 = _city(Version.V02), _city(Version.V03)
    assert not any(oid in v02 for oid in V03_ONLY)
    assert [v02.definition(oid) for oid in V03_ONLY] == [None] * 3  # the agent's noSuchObject, not noSuchInstance
    assert [v03.get(oid) for oid in V03_ONLY] == [0, 1, 0]
    assert v03.definition(PREEMPT_STATUS.instance()) is PREEMPT_STATUS


def test_the_detector_inputs_are_served_in_both_editions() -> None:
    """v03 added them; the emulator has no cabinet wires, so its detectors are actuated through them under v02 too."""
    for edition in Version:
        mib = _city(edition)
        assert {DETECTOR_ACTUATION.instance(1), PED_DETECTOR_ACTUATION.instance(1),
                MAX_VEHICLE_DETECTOR_CONTROL_GROUPS.instance()} <= set(mib.oids)
        mib.set_many([(DETECTOR_ACTUATION.instance(1), 0b11)])
        assert mib.controller.actuations == {1, 2}


def test_pattern_split_number_is_written_under_v02_and_refused_under_v03() -> None:
    v02, v03 = _city(Version.V02), _city(Version.V03)
    v02.set_many([(SPLIT_NUMBER_1, 1)])
    with pytest.raises(SnmpError) as refused:
        v03.set_many([(SPLIT_NUMBER_1, 1)])
    assert refused.value.status is ErrorStatus.NOT_WRITABLE
    assert v03.definition(SPLIT_NUMBER_1).access is Access.READ_ONLY
    assert v02.definition(SPLIT_NUMBER_1).access is Access.READ_WRITE


def test_the_edition_served_is_the_configs_unless_one_is_given() -> None:
    v03 = _config("four_leg.toml", "v03")
    assert v03.emulator.ntcip is Version.V03
    assert _config("four_leg.toml").emulator.ntcip is Version.V02  # what the paper's Cobalt speaks
    assert MibView(Controller(v03)).edition is Version.V03
    assert MibView(Controller(v03), Version.V02).edition is Version.V02
    # The controller a virtual-time run reaches in process serves it too.
    target = VirtualTarget(simpy.Environment(), v03)
    assert PREEMPT_STATUS.instance() in target.mib


@pytest.mark.parametrize("value", ["v04", "V03", 3, ["v03"]])
def test_an_edition_that_is_none_is_refused_naming_the_field_and_the_allowed(value: object) -> None:
    with pytest.raises(ConfigError) as info:
        _config("four_leg.toml", value, source="lab.toml")
    message = str(info.value)
    assert "lab.toml" in message and "emulator.ntcip" in message and "'v02', 'v03'" in message


def test_the_index_columns_and_the_rings_are_served_from_the_config() -> None:
    mib = _city(Version.V02)
    assert [mib.get(PHASE_NUMBER.instance(p)) for p in range(1, 9)] == list(range(1, 9))
    assert [mib.get(VEHICLE_DETECTOR_NUMBER.instance(d)) for d in (1, 8)] == [1, 8]
    assert (mib.get(MAX_RINGS.instance()), mib.get(MAX_SEQUENCES.instance())) == (2, 1)
    assert [mib.get(SEQUENCE_RING_NUMBER.instance(1, r)) for r in (1, 2)] == [1, 2]


def test_the_channel_map_drives_channel_i_from_phase_i() -> None:
    mib = MibView(Controller(_config("four_phase.toml")))  # phases 2, 4, 6, 8
    assert mib.get(MAX_CHANNELS.instance()) == 8
    # "Value 00 = No Control (Not In Use)" where the config has no phase of that number.
    assert [mib.get(CHANNEL_CONTROL_SOURCE.instance(ch)) for ch in range(1, 9)] == [0, 2, 0, 4, 0, 6, 0, 8]
    assert {mib.get(CHANNEL_CONTROL_TYPE.instance(ch)) for ch in range(1, 9)} == {ChannelControlType.PHASE_VEHICLE}
    with pytest.raises(SnmpError) as refused:
        mib.set_many([(CHANNEL_CONTROL_SOURCE.instance(1), 1)])
    assert refused.value.status is ErrorStatus.NOT_WRITABLE


SCHEDULE = [{"from": "22:00", "pattern": "free"}, {"from": "06:30", "pattern": 1}]


@pytest.mark.parametrize(("start", "action"), [("2024-04-15T07:00:00", 1), ("2024-04-15T23:00:00", 2),
                                               ("2024-04-15T03:00:00", 2), ("2024-04-15T06:30:00", 1)])
def test_the_time_base_actions_are_the_schedule_and_the_one_of_the_time_of_day_is_in_effect(start: str,
                                                                                            action: int) -> None:
    """The actions are numbered in the order of the day (the config orders the entries by their start); before the
    day's first, the evening's runs on."""
    config = _config("four_leg_city.toml", schedule=SCHEDULE)
    mib = MibView(Controller(config, start=datetime.fromisoformat(start)))
    assert mib.get(MAX_TIMEBASE_ACTIONS.instance()) == 2
    assert [mib.get(TIMEBASE_PATTERN.instance(n)) for n in (1, 2)] == [1, 254]  # free is 254
    assert mib.get(TIMEBASE_ACTION_STATUS.instance()) == action


def test_with_no_schedule_one_unprogrammed_action_and_none_in_effect() -> None:
    mib = _city(Version.V02)
    assert mib.get(MAX_TIMEBASE_ACTIONS.instance()) == 1
    assert mib.get(TIMEBASE_PATTERN.instance(1)) == 0  # "no pattern is being selected"
    assert mib.get(TIMEBASE_ACTION_STATUS.instance()) == 0


def test_v03s_preempt_status_names_the_preempt_in_service_and_the_inputs_on() -> None:
    mib = _city(Version.V03)
    state = PREEMPT_TABLE[PreemptColumn.STATE].instance(1)
    mib.set_many([(PREEMPT_CONTROL_STATE.instance(1), 1)])
    assert mib.get(PREEMPT_STATUS_GROUP.instance(1)) == 0b1  # the input, at once
    for _ in range(100):
        mib.controller.step()
        if PreemptState(mib.get(state)).in_service:
            break
    assert PreemptState(mib.get(state)).in_service and mib.get(PREEMPT_STATUS.instance()) == 1
    mib.set_many([(PREEMPT_CONTROL_STATE.instance(1), 0)])
    assert mib.get(PREEMPT_STATUS_GROUP.instance(1)) == 0


def test_the_unit_red_revert_is_the_least_red_revert_of_every_phase() -> None:
    """"if it is greater than a phaseRedRevert object value, then this value shall be used as the red revert time
    for the affected phase": the model times the greater, and each phaseRedRevert reads back what was SET of it."""
    mib = _city(Version.V02)
    timing = mib.controller.timing
    phase_1, phase_2 = phase_oid(PhaseColumn.RED_REVERT, 1), phase_oid(PhaseColumn.RED_REVERT, 2)
    assert (mib.get(UNIT_RED_REVERT.instance()), mib.get(phase_1), timing[1].red_revert) == (0, 0, 0)
    mib.set_many([(UNIT_RED_REVERT.instance(), 50), (phase_1, 70)])
    assert (timing[1].red_revert, timing[2].red_revert) == (70, 50)
    assert (mib.get(phase_1), mib.get(phase_2)) == (70, 0)
    mib.set_many([(UNIT_RED_REVERT.instance(), 20)])
    assert {p: t.red_revert for p, t in timing.items()} == {1: 70} | {p: 20 for p in range(2, 9)}


@settings(max_examples=40, deadline=None)
@given(starts=st.lists(st.integers(0, 24 * 60 - 1), min_size=1, max_size=4, unique=True),
       patterns=st.lists(st.sampled_from([1, "free"]), min_size=4, max_size=4), which=st.integers(0, 3))
def test_the_action_in_effect_runs_the_pattern_the_coordinator_takes_up(starts: list[int], patterns: list[object],
                                                                        which: int) -> None:
    """Across any schedule boundary, the coordinator's time-of-day pattern is the one timebaseAscActionStatus
    names."""
    schedule = [{"from": f"{m // 60:02d}:{m % 60:02d}", "pattern": p} for m, p in zip(starts, patterns, strict=False)]
    boundary = sorted(starts)[which % len(starts)]
    start = datetime(2024, 4, 15) + timedelta(minutes=boundary) - timedelta(seconds=1)
    mib = MibView(Controller(_config("four_leg_city.toml", schedule=schedule), start=start))
    for _ in range(20):  # 2 s: the boundary passes
        mib.controller.step()
    action = mib.get(TIMEBASE_ACTION_STATUS.instance())
    assert mib.get(TIMEBASE_PATTERN.instance(action)) == mib.controller.coordinator.local


def test_v03s_asc_spat_gives_the_controllers_clock_and_its_spat_enable() -> None:
    """spatTimestamp: "Byte 1: hours (0..23) Byte 2: minutes (0..59) Byte 3: seconds ... Byte 4-5: milliseconds";
    ascCurrentTick: tenths of a second, "a zero representing the top of the hour"; spatOptions bit 0 "Enabled SPAT".
    Under v02 none of them is served."""
    start = datetime(2026, 3, 2, 13, 59, 58, 700_000)
    v02, v03 = _city(Version.V02, start), _city(Version.V03, start)
    tick, stamp, options = ASC_CURRENT_TICK.instance(), SPAT_TIMESTAMP.instance(), SPAT_OPTIONS.instance()
    assert not any(oid in v02 for oid in (tick, stamp, options))
    assert v03.get(stamp) == bytes([13, 59, 58, 0x02, 0xBC]) and v03.get(tick) == 35987
    for _ in range(14):
        v03.controller.step()
    assert v03.get(stamp) == bytes([14, 0, 0, 0x00, 0x64]) and v03.get(tick) == 1  # the hour rolled over
    assert v03.get(options) == 1
    v03.set_many([(options, 0)])
    assert v03.get(options) == 0 and v03.spat_options == 0
