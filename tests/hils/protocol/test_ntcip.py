"""The NTCIP 1202 object model: OIDs against DESIGN.md's table, bitmasks, signal polls."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hils.protocol.ntcip import (
    ALL_OBJECTS,
    ASC,
    CHANNEL_TABLE,
    CONTROL_TABLE,
    MAX_PHASE_GROUPS,
    MAX_PHASES,
    PHASE_TABLE,
    RING_CONTROL_MAX2,
    SEQUENCE_DATA,
    STATUS_TABLE,
    SYSTEM_PATTERN_CONTROL,
    UNIT_BACKUP_TIME,
    UNIT_CONTROL_STATUS,
    UNIT_FLASH_STATUS,
    UNIT_STARTUP_FLASH,
    Access,
    ChannelColumn,
    ControlColumn,
    ErrorStatus,
    PhaseColumn,
    PhaseOption,
    PhaseStartup,
    SignalState,
    SnmpError,
    StatusColumn,
    Syntax,
    UnitControlStatus,
    UnitFlashStatus,
    control_oid,
    group_count,
    groups_to_phases,
    object_for,
    oid_str,
    parse_oid,
    phase_oid,
    phases_to_groups,
    sequence_oid,
    signal_oids,
    status_oid,
)

A = "1.3.6.1.4.1.1206.4.2.1"


# --- OIDs: DESIGN.md's table, spelled out independently -----------------------------------


def test_the_asc_node() -> None:
    assert oid_str(ASC) == A


@pytest.mark.parametrize(("obj", "oid", "access"), [
    (MAX_PHASES, f"{A}.1.1.0", Access.READ_ONLY),
    (MAX_PHASE_GROUPS, f"{A}.1.3.0", Access.READ_ONLY),
    (UNIT_BACKUP_TIME, f"{A}.3.3.0", Access.READ_WRITE),
    (UNIT_CONTROL_STATUS, f"{A}.3.5.0", Access.READ_ONLY),
    (UNIT_FLASH_STATUS, f"{A}.3.6.0", Access.READ_ONLY),
    (SYSTEM_PATTERN_CONTROL, f"{A}.4.14.0", Access.READ_WRITE),
])
def test_scalar_oids(obj, oid: str, access: Access) -> None:
    assert oid_str(obj.instance()) == oid
    assert obj.access is access
    assert obj.syntax is Syntax.INTEGER


def test_scalar_ranges() -> None:
    assert (UNIT_BACKUP_TIME.low, UNIT_BACKUP_TIME.high) == (0, 65535)
    assert (UNIT_CONTROL_STATUS.low, UNIT_CONTROL_STATUS.high) == (1, 8)
    assert (UNIT_FLASH_STATUS.low, UNIT_FLASH_STATUS.high) == (1, 8)
    assert (SYSTEM_PATTERN_CONTROL.low, SYSTEM_PATTERN_CONTROL.high) == (0, 255)


def test_unit_start_up_flash_and_ring_control_max2_oids() -> None:
    assert oid_str(UNIT_STARTUP_FLASH.instance()) == f"{A}.3.1.0"
    assert oid_str(RING_CONTROL_MAX2.instance(1)) == f"{A}.7.5.1.4.1"
    assert UNIT_STARTUP_FLASH.access is RING_CONTROL_MAX2.access is Access.READ_WRITE


def test_phase_option_bits_follow_ntcip_1202() -> None:
    assert [int(b).bit_length() - 1 for b in (PhaseOption.MIN_VEHICLE_RECALL, PhaseOption.MAX_VEHICLE_RECALL,
                                               PhaseOption.PED_RECALL, PhaseOption.SOFT_VEHICLE_RECALL,
                                               PhaseOption.DUAL_ENTRY, PhaseOption.SIMULTANEOUS_GAP_DISABLE)] == [
        6, 7, 8, 9, 10, 11]
    assert PhaseOption.ENABLED == 1


@pytest.mark.parametrize(("column", "number", "name", "access"), [
    (PhaseColumn.WALK, 2, "phaseWalk", Access.READ_WRITE),
    (PhaseColumn.PEDESTRIAN_CLEAR, 3, "phasePedestrianClear", Access.READ_WRITE),
    (PhaseColumn.MINIMUM_GREEN, 4, "phaseMinimumGreen", Access.READ_WRITE),
    (PhaseColumn.PASSAGE, 5, "phasePassage", Access.READ_WRITE),
    (PhaseColumn.MAXIMUM1, 6, "phaseMaximum1", Access.READ_WRITE),
    (PhaseColumn.MAXIMUM2, 7, "phaseMaximum2", Access.READ_WRITE),
    (PhaseColumn.YELLOW_CHANGE, 8, "phaseYellowChange", Access.READ_WRITE),
    (PhaseColumn.RED_CLEAR, 9, "phaseRedClear", Access.READ_WRITE),
    (PhaseColumn.RED_REVERT, 10, "phaseRedRevert", Access.READ_WRITE),
    # Writable in the standard; the emulator serves them read-only (emulator.agent.mib.NOT_WRITABLE_HERE).
    (PhaseColumn.STARTUP, 20, "phaseStartup", Access.READ_WRITE),
    (PhaseColumn.OPTIONS, 21, "phaseOptions", Access.READ_WRITE),
    (PhaseColumn.RING, 22, "phaseRing", Access.READ_WRITE),
    (PhaseColumn.CONCURRENCY, 23, "phaseConcurrency", Access.READ_WRITE),
])
def test_phase_table_oids(column: PhaseColumn, number: int, name: str, access: Access) -> None:
    assert oid_str(phase_oid(column, 7)) == f"{A}.1.2.1.{number}.7"
    assert PHASE_TABLE[column].name == name
    assert PHASE_TABLE[column].access is access
    expected_syntax = Syntax.OCTET_STRING if column is PhaseColumn.CONCURRENCY else Syntax.INTEGER
    assert PHASE_TABLE[column].syntax is expected_syntax


@pytest.mark.parametrize(("column", "number", "name"), [
    (StatusColumn.REDS, 2, "phaseStatusGroupReds"),
    (StatusColumn.YELLOWS, 3, "phaseStatusGroupYellows"),
    (StatusColumn.GREENS, 4, "phaseStatusGroupGreens"),
    (StatusColumn.DONT_WALKS, 5, "phaseStatusGroupDontWalks"),
    (StatusColumn.PED_CLEARS, 6, "phaseStatusGroupPedClears"),
    (StatusColumn.WALKS, 7, "phaseStatusGroupWalks"),
    (StatusColumn.VEH_CALLS, 8, "phaseStatusGroupVehCalls"),
    (StatusColumn.PED_CALLS, 9, "phaseStatusGroupPedCalls"),
    (StatusColumn.PHASE_ONS, 10, "phaseStatusGroupPhaseOns"),
    (StatusColumn.PHASE_NEXTS, 11, "phaseStatusGroupPhaseNexts"),
])
def test_status_table_oids(column: StatusColumn, number: int, name: str) -> None:
    assert oid_str(status_oid(column, 2)) == f"{A}.1.4.1.{number}.2"
    assert STATUS_TABLE[column].name == name
    assert STATUS_TABLE[column].access is Access.READ_ONLY
    assert (STATUS_TABLE[column].low, STATUS_TABLE[column].high) == (0, 255)


@pytest.mark.parametrize(("column", "number", "name"), [
    (ControlColumn.PHASE_OMIT, 2, "phaseControlGroupPhaseOmit"),
    (ControlColumn.PED_OMIT, 3, "phaseControlGroupPedOmit"),
    (ControlColumn.HOLD, 4, "phaseControlGroupHold"),
    (ControlColumn.FORCE_OFF, 5, "phaseControlGroupForceOff"),
    (ControlColumn.VEH_CALL, 6, "phaseControlGroupVehCall"),
    (ControlColumn.PED_CALL, 7, "phaseControlGroupPedCall"),
])
def test_control_table_oids(column: ControlColumn, number: int, name: str) -> None:
    assert oid_str(control_oid(column, 1)) == f"{A}.1.5.1.{number}.1"
    assert CONTROL_TABLE[column].name == name
    assert CONTROL_TABLE[column].access is Access.READ_WRITE
    assert (CONTROL_TABLE[column].low, CONTROL_TABLE[column].high) == (0, 255)


@pytest.mark.parametrize(("column", "number", "name"), [
    (ChannelColumn.REDS, 2, "channelStatusGroupReds"),
    (ChannelColumn.YELLOWS, 3, "channelStatusGroupYellows"),
    (ChannelColumn.GREENS, 4, "channelStatusGroupGreens"),
])
def test_channel_table_oids(column: ChannelColumn, number: int, name: str) -> None:
    assert oid_str(CHANNEL_TABLE[column].instance(3)) == f"{A}.8.4.1.{number}.3"
    assert CHANNEL_TABLE[column].name == name


def test_the_oids_the_issue_names() -> None:
    assert oid_str(control_oid(ControlColumn.VEH_CALL, 1)) == "1.3.6.1.4.1.1206.4.2.1.1.5.1.6.1"
    assert oid_str(UNIT_BACKUP_TIME.instance()) == "1.3.6.1.4.1.1206.4.2.1.3.3.0"
    assert oid_str(status_oid(StatusColumn.GREENS, 1)) == "1.3.6.1.4.1.1206.4.2.1.1.4.1.4.1"
    assert oid_str(sequence_oid(1, 2)) == "1.3.6.1.4.1.1206.4.2.1.7.3.1.3.1.2"
    assert SEQUENCE_DATA.syntax is Syntax.OCTET_STRING


def test_enumerations_match_ntcip() -> None:
    assert [(s.name, s.value) for s in PhaseStartup] == [
        ("OTHER", 1), ("PHASE_NOT_ON", 2), ("GREEN_WALK", 3), ("GREEN_NO_WALK", 4), ("YELLOW_CHANGE", 5),
        ("RED_CLEAR", 6)]
    assert [(s.name, s.value) for s in UnitControlStatus] == [
        ("OTHER", 1), ("SYSTEM_CONTROL", 2), ("SYSTEM_STANDBY", 3), ("BACKUP_MODE", 4), ("MANUAL", 5),
        ("TIMEBASE", 6), ("INTERCONNECT", 7), ("INTERCONNECT_BACKUP", 8)]
    assert [(s.name, s.value) for s in UnitFlashStatus] == [
        ("OTHER", 1), ("NOT_FLASH", 2), ("AUTOMATIC", 3), ("LOCAL_MANUAL", 4), ("FAULT_MONITOR", 5), ("MMU", 6),
        ("STARTUP", 7), ("PREEMPT", 8)]
    assert (ErrorStatus.NO_SUCH_NAME, ErrorStatus.BAD_VALUE, ErrorStatus.READ_ONLY, ErrorStatus.GEN_ERR) == (2, 3, 4, 5)
    assert (ErrorStatus.WRONG_TYPE, ErrorStatus.WRONG_VALUE, ErrorStatus.NOT_WRITABLE) == (7, 10, 17)


def test_object_prefixes_are_unique_and_none_extends_another() -> None:
    prefixes = [obj.prefix for obj in ALL_OBJECTS]
    assert len(set(prefixes)) == len(prefixes)
    for a in prefixes:
        for b in prefixes:
            assert a == b or a[: len(b)] != b, (oid_str(a), oid_str(b))


def test_object_for_finds_the_object_of_an_instance() -> None:
    assert object_for(control_oid(ControlColumn.HOLD, 2)) is CONTROL_TABLE[ControlColumn.HOLD]
    assert object_for(UNIT_FLASH_STATUS.instance()) is UNIT_FLASH_STATUS
    assert object_for(sequence_oid(1, 1)) is SEQUENCE_DATA
    assert object_for(UNIT_FLASH_STATUS.prefix) is None  # no instance part
    assert object_for((*ASC, 99, 1, 0)) is None


def test_oid_text_round_trip() -> None:
    oid = control_oid(ControlColumn.VEH_CALL, 1)
    assert parse_oid(oid_str(oid)) == oid
    assert parse_oid(" ." + oid_str(oid)) == oid
    with pytest.raises(ValueError, match="not a numeric OID"):
        parse_oid("1.3.six")


def test_snmp_error_carries_status_and_index() -> None:
    err = SnmpError(ErrorStatus.NOT_WRITABLE, 2, "maxPhases is read-only")
    assert (err.status, err.index, err.detail) == (ErrorStatus.NOT_WRITABLE, 2, "maxPhases is read-only")
    assert str(err) == "not_writable at varbind 2: maxPhases is read-only"


# --- bitmasks ---------------------------------------------------------------------------------


def test_group_count() -> None:
    assert [group_count(n) for n in (1, 8, 9, 16, 17, 255)] == [1, 1, 2, 2, 3, 32]


@pytest.mark.parametrize(("phases", "groups", "masks"), [
    ((), 1, (0,)),
    ((1,), 1, (0b1,)),
    ((8,), 1, (0b1000_0000,)),
    ((2, 6), 1, (0b0010_0010,)),
    (range(1, 9), 1, (255,)),
    ((9,), 2, (0, 1)),
    ((1, 16), 2, (1, 128)),
    ((4, 8, 12), 2, (0b1000_1000, 0b1000)),
    ((17,), 3, (0, 0, 1)),
])
def test_phases_to_groups(phases, groups: int, masks: tuple[int, ...]) -> None:
    assert phases_to_groups(phases, groups) == masks
    assert groups_to_phases(masks) == frozenset(phases)


@pytest.mark.parametrize(("phases", "groups"), [((0,), 1), ((-3,), 1), ((9,), 1), ((17,), 2), ((1,), 0)])
def test_phases_outside_the_groups_are_refused(phases: tuple[int, ...], groups: int) -> None:
    with pytest.raises(ValueError, match="does not fit"):
        phases_to_groups(phases, groups)


@pytest.mark.parametrize("masks", [(256,), (0, -1), (0, 0, 1000)])
def test_masks_outside_a_byte_are_refused(masks: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match=r"outside 0\.\.255"):
        groups_to_phases(masks)


@given(st.integers(1, 4).flatmap(
    lambda groups: st.tuples(st.just(groups), st.frozensets(st.integers(1, 8 * groups)))))
def test_phase_sets_round_trip(case: tuple[int, frozenset[int]]) -> None:
    groups, phases = case
    masks = phases_to_groups(phases, groups)
    assert len(masks) == groups
    assert all(0 <= m <= 255 for m in masks)
    assert groups_to_phases(masks) == phases


@given(st.lists(st.integers(0, 255), min_size=1, max_size=4))
def test_masks_round_trip(masks: list[int]) -> None:
    assert phases_to_groups(groups_to_phases(masks), len(masks)) == tuple(masks)


# --- signal polls -------------------------------------------------------------------------


def test_signal_oids_are_reds_yellows_greens_group_by_group() -> None:
    assert signal_oids(1) == (status_oid(StatusColumn.REDS, 1), status_oid(StatusColumn.YELLOWS, 1),
                              status_oid(StatusColumn.GREENS, 1))
    assert [oid_str(o) for o in signal_oids(2)] == [
        f"{A}.1.4.1.2.1", f"{A}.1.4.1.2.2", f"{A}.1.4.1.3.1", f"{A}.1.4.1.3.2", f"{A}.1.4.1.4.1", f"{A}.1.4.1.4.2"]


def test_signal_state_decodes_a_poll() -> None:
    state = SignalState.from_values((0b1101_1101, 0b0000_0000, 0b0010_0010), 1)
    assert state == SignalState(frozenset({1, 3, 4, 5, 7, 8}), frozenset(), frozenset({2, 6}))
    assert [state.indication(p) for p in range(1, 9)] == list("rGrrrGrr")
    two = SignalState.from_values((1, 0, 2, 1, 0, 128), 2)
    assert (two.reds, two.yellows, two.greens) == ({1}, {2, 9}, {16})
    assert two.indication(9) == "Y"


@pytest.mark.parametrize("values", [(0, 0), (0, 0, 0, 0)])
def test_signal_state_refuses_a_poll_of_the_wrong_length(values: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="has 3 values"):
        SignalState.from_values(values, 1)


@given(st.lists(st.sampled_from("rYG"), min_size=16, max_size=16))
def test_signal_state_round_trips_through_a_poll(letters: list[str]) -> None:
    sets = {c: frozenset(p for p, x in enumerate(letters, start=1) if x == c) for c in "rYG"}
    values = phases_to_groups(sets["r"], 2) + phases_to_groups(sets["Y"], 2) + phases_to_groups(sets["G"], 2)
    state = SignalState.from_values(values, 2)
    assert [state.indication(p) for p in range(1, 17)] == letters
