"""The emulator's MIB view: NTCIP get and set by OID over a live controller model.

This is the single surface that both the in-process transport (virtual time)
and the SNMP agent (wall-clock time) use. Outcomes are SNMP-style: an unknown
object raises ``SnmpError(NO_SUCH_NAME)``, a read-only one ``NOT_WRITABLE``, a
value of the wrong type ``WRONG_TYPE`` and one out of range ``WRONG_VALUE``; the
agent maps these to each SNMP version's codes. A multi-varbind SET is checked
whole before anything is applied, so a refused SET changes nothing.

The phase table's timing columns are writable with NTCIP 1202's ranges, as on
a real controller, so a lab can retime the emulator live; a SET acts from the
next interval of that phase on (a green or clearance being timed keeps the
lengths it started with). The objects the model takes from the intersection
config (a phase's start-up, options, ring and concurrency, the detectors' wiring,
an overlap's or a preempt's phases) are writable in the standard but read-only
here: :data:`NOT_WRITABLE_HERE` lists them with why. ringControlGroupMax2
selects Maximum 2 per ring (bit 0 = ring 1) from the ring's next green.

The edition of NTCIP 1202 served is chosen per controller (``[emulator] ntcip`` of the config, or ``hils emulator
serve --ntcip``): under v02 the objects v03 added answer noSuchObject (but the detector inputs,
:data:`hils.protocol.ntcip.SERVED_IN_V02`), under v03 each object has v03's access
(:meth:`hils.protocol.ntcip.ObjectDef.in_edition`).

Every static table has rows 1..its max object, as the MIB says ("The number of
rows in this table is equal to the maxPhases object"; every max object is
1..255): a number the config leaves out, or the only row of a table the config
leaves empty (no overlap, no preempt, no pattern), is an unprogrammed row, as
the MIB defines one: a phase with phaseRing 0 and phaseOptions bit 0 clear, a
detector calling phase 0, an overlap with no included phase, a preempt with no
phases whose input (preemptControlState) calls nothing. Its times can be SET
and read back; they act on nothing.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

from emulator.model.controller import Controller, Timing
from emulator.model.coordination import DAY
from emulator.model.delays import DelayedController
from emulator.model.overlaps import OverlapTiming
from emulator.model.preemption import PreemptTiming
from emulator.model.ring import TIMING_COLUMNS
from hils.protocol.config import IntersectionConfig, Overlap, OverlapKind, Phase, Preempt, Recall, ScheduleEntry
from hils.protocol.ntcip import (
    ASC_CURRENT_TICK,
    CHANNEL_CONTROL_SOURCE,
    CHANNEL_CONTROL_TYPE,
    CHANNEL_NUMBER,
    CHANNEL_STATUS_GROUP_NUMBER,
    CHANNEL_TABLE,
    CONTROL_TABLE,
    COORD_CORRECTION_MODE,
    COORD_CYCLE_STATUS,
    COORD_FORCE_MODE,
    COORD_OPERATIONAL_MODE,
    COORD_PATTERN_STATUS,
    COORD_SYNC_STATUS,
    DETECTOR_ACTUATION,
    DETECTOR_STATUS_ACTIVE,
    LOCAL_FREE_STATUS,
    MAX_CHANNEL_STATUS_GROUPS,
    MAX_CHANNELS,
    MAX_OVERLAP_STATUS_GROUPS,
    MAX_OVERLAPS,
    MAX_PATTERNS,
    MAX_PED_DETECTOR_GROUPS,
    MAX_PED_DETECTORS,
    MAX_PHASE_GROUPS,
    MAX_PHASES,
    MAX_PREEMPT_GROUPS,
    MAX_PREEMPTS,
    MAX_RING_CONTROL_GROUPS,
    MAX_RINGS,
    MAX_SEQUENCES,
    MAX_SPLITS,
    MAX_TIMEBASE_ACTIONS,
    MAX_VEHICLE_DETECTOR_CONTROL_GROUPS,
    MAX_VEHICLE_DETECTOR_STATUS_GROUPS,
    MAX_VEHICLE_DETECTORS,
    OVERLAP_STATUS_TABLE,
    OVERLAP_TABLE,
    PATTERN_TABLE,
    PATTERN_TABLE_TYPE,
    PED_DETECTOR_ACTUATION,
    PED_DETECTOR_CALL_PHASE,
    PED_DETECTOR_CONTROL_GROUP_NUMBER,
    PED_DETECTOR_NUMBER,
    PED_DETECTOR_STATUS_ACTIVE,
    PED_DETECTOR_STATUS_GROUP_NUMBER,
    PHASE_CONTROL_GROUP_NUMBER,
    PHASE_NUMBER,
    PHASE_STATUS_GROUP_NUMBER,
    PHASE_TABLE,
    PREEMPT_CONTROL_NUMBER,
    PREEMPT_CONTROL_STATE,
    PREEMPT_STATUS,
    PREEMPT_STATUS_GROUP,
    PREEMPT_STATUS_GROUP_NUMBER,
    PREEMPT_TABLE,
    RING_CONTROL_GROUP_NUMBER,
    RING_CONTROL_MAX2,
    SEQUENCE_DATA,
    SEQUENCE_NUMBER,
    SEQUENCE_RING_NUMBER,
    SHORT_ALARM_STATUS,
    SPAT_OPTIONS,
    SPAT_TIMESTAMP,
    SPLIT_TABLE,
    STATUS_TABLE,
    SYSTEM_PATTERN_CONTROL,
    TIMEBASE_ACTION_NUMBER,
    TIMEBASE_ACTION_STATUS,
    TIMEBASE_PATTERN,
    TIMEBASE_PATTERN_SYNC,
    UNIT_BACKUP_TIME,
    UNIT_CONTROL_STATUS,
    UNIT_FLASH_STATUS,
    UNIT_RED_REVERT,
    UNIT_STARTUP_FLASH,
    VEHICLE_DETECTOR_CALL_PHASE,
    VEHICLE_DETECTOR_CONTROL_GROUP_NUMBER,
    VEHICLE_DETECTOR_DELAY,
    VEHICLE_DETECTOR_EXTEND,
    VEHICLE_DETECTOR_NUMBER,
    VEHICLE_DETECTOR_OPTIONS,
    VEHICLE_DETECTOR_STATUS_GROUP_NUMBER,
    Access,
    ChannelColumn,
    ChannelControlType,
    ControlColumn,
    CoordCorrectionMode,
    CoordForceMode,
    DetectorOption,
    ErrorStatus,
    ObjectDef,
    Oid,
    OverlapColumn,
    OverlapStatusColumn,
    OverlapType,
    PatternColumn,
    PhaseColumn,
    PhaseOption,
    PhaseStartup,
    PreemptColumn,
    PreemptState,
    SnmpError,
    SplitColumn,
    SplitMode,
    StatusColumn,
    Syntax,
    Value,
    Version,
    group_count,
    groups_to_phases,
    object_for,
    phases_to_groups,
    sequence_oid,
    spat_timestamp,
)

TICKS_PER_HOUR = 36_000  # ascCurrentTick: "a zero representing the top of the hour"

_FROM_CONFIG = "taken from the intersection config, which is validated whole before the controller starts"
_STRUCTURE = f"the ring-and-barrier structure: {_FROM_CONFIG} (rings, barriers, concurrency and sequence agree)"
#: Objects the standard makes writable that the emulator serves read-only (a SET is refused notWritable), and why:
#: the model takes them from the intersection config and does not rebuild itself while it runs.
NOT_WRITABLE_HERE: dict[str, str] = {
    "phaseStartup": f"a phase's start-up interval: {_FROM_CONFIG}",
    "phaseOptions": f"a phase's recalls, dual entry and options: {_FROM_CONFIG}",
    "phaseRing": _STRUCTURE,
    "phaseConcurrency": _STRUCTURE,
    "sequenceData": _STRUCTURE,
    "vehicleDetectorOptions": f"the detectors' wiring to phases: {_FROM_CONFIG}",
    "vehicleDetectorCallPhase": f"the detectors' wiring to phases: {_FROM_CONFIG}",
    "pedestrianDetectorCallPhase": f"the push buttons' wiring to phases: {_FROM_CONFIG}",
    "overlapType": f"an overlap's kind and phases (the monitor's conflict check is built from them): {_FROM_CONFIG}",
    "overlapIncludedPhases": f"an overlap's kind and phases (the monitor's conflict check is built from them): "
                             f"{_FROM_CONFIG}",
    "overlapModifierPhases": f"an overlap's kind and phases (the monitor's conflict check is built from them): "
                             f"{_FROM_CONFIG}",
    "preemptControl": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptLink": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptTrackPhase": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptDwellPhase": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptDwellPed": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptExitPhase": f"a preempt's options and phases: {_FROM_CONFIG}",
    "preemptCyclingPhase": f"a preempt's options and phases: {_FROM_CONFIG}",
    "channelControlSource": "the channel map: the emulator's load switches follow its phases one to one (channel i is "
                            "phase i), as the status of its channels does",
    "channelControlType": "the channel map: the emulator's load switches follow its phases one to one (channel i is "
                          "phase i), as the status of its channels does",
    "timebaseAscPattern": f"the time of day schedule ([[coordination.schedule]]): {_FROM_CONFIG}",
    "timebaseAscPatternSync": "the coordinator counts every pattern's cycle from midnight (0 minutes past it), "
                              "its one sync reference",
    "coordOperationalMode": "automatic (0) only: the pattern comes from systemPatternControl and the time base; "
                            "the coordinator has no manual override of them",
}

_RECALL_BITS = {
    Recall.NONE: PhaseOption(0),
    Recall.MIN: PhaseOption.MIN_VEHICLE_RECALL,
    Recall.MAX: PhaseOption.MAX_VEHICLE_RECALL,
    Recall.PED: PhaseOption.PED_RECALL,
    Recall.SOFT: PhaseOption.SOFT_VEHICLE_RECALL,
}


def phase_options(ph: Phase) -> PhaseOption:
    """phaseOptions of a configured phase: enabled, its recall, dual entry, simultaneous gap disable (a
    gapped-out green does not re-extend while it waits at the barrier: see emulator/model/ring.py) and conditional
    service (see emulator/model/sequencer.py)."""
    bits = PhaseOption.ENABLED | _RECALL_BITS[ph.recall]
    if ph.dual_entry:
        bits |= PhaseOption.DUAL_ENTRY
    if ph.simultaneous_gap_disable:
        bits |= PhaseOption.SIMULTANEOUS_GAP_DISABLE
    if ph.conditional_service:
        bits |= PhaseOption.CONDITIONAL_SERVICE
    return bits


#: What a configured vehicle detector does (vehicleDetectorOptions): it calls its phase ("Bit 7: Call") and, on its
#: green, restarts the phase's passage timer ("Bit 4: Passage").
DETECTOR_OPTIONS = DetectorOption.CALL | DetectorOption.PASSAGE
def _detector_options(cfg: IntersectionConfig, d: int) -> DetectorOption:
    """vehicleDetectorOptions of detector ``d``: call and passage when configured, and "Bit 2: Yellow Lock Call" when
    it locks its calls."""
    if d not in cfg.detectors:
        return DetectorOption(0)
    timing = cfg.detector_timing.get(d)
    return DETECTOR_OPTIONS | (DetectorOption.YELLOW_LOCK_CALL if timing is not None and timing.lock else 0)


#: The timings of an unprogrammed phase: none, but the yellow at NEMA's 3.0 s (the lowest phaseYellowChange).
_UNPROGRAMMED_TIMING = {"min_green": 0, "max1": 0, "max2": 0, "passage": 0, "walk": 0, "ped_clear": 0, "yellow": 30,
                        "red_clear": 0, "red_revert": 0}


def _rows(numbers: Iterable[int]) -> range:
    """The rows of a static table: 1..the highest configured number, at least one (the max object that counts
    them is 1..255)."""
    return range(1, max(numbers, default=1) + 1)


@dataclass(frozen=True, slots=True)
class Instance:
    oid: Oid
    obj: ObjectDef
    read: Callable[[], Value]
    write: Callable[[int], None] | None = None


class MibView:
    """get/set/next by OID over one controller (bare, or behind its delays), as one edition of NTCIP 1202 defines
    the objects (by default the intersection config's ``[emulator] ntcip``)."""

    def __init__(self, controller: Controller | DelayedController, edition: Version | None = None) -> None:
        self.controller = controller
        self.edition = edition or controller.config.emulator.ntcip
        self.set_count = 0
        self.spat_options = 1  # spatOptions: "Bit 0: Enabled SPAT"; the UDP SPaT packet is sent while it is set
        instances = [replace(i, obj=obj) for i in self._build() if (obj := i.obj.in_edition(self.edition))]
        self._by_oid = {i.oid: i for i in instances}
        self._sorted = sorted(self._by_oid)

    # --- the surface -------------------------------------------------------------------

    def get(self, oid: Oid) -> Value:
        return self.get_many((oid,))[0]

    def get_many(self, oids: Sequence[Oid]) -> tuple[Value, ...]:
        out = []
        for index, oid in enumerate(oids, start=1):
            inst = self._by_oid.get(tuple(oid))
            if inst is None:
                raise SnmpError(ErrorStatus.NO_SUCH_NAME, index, f"no object {'.'.join(map(str, oid))}")
            out.append(inst.read())
        return tuple(out)

    def set_many(self, varbinds: Sequence[tuple[Oid, Value]]) -> None:
        checked = []
        for index, (oid, value) in enumerate(varbinds, start=1):
            inst = self._by_oid.get(tuple(oid))
            if inst is None:
                raise SnmpError(ErrorStatus.NO_SUCH_NAME, index, f"no object {'.'.join(map(str, oid))}")
            if inst.write is None or inst.obj.access is not Access.READ_WRITE:
                raise SnmpError(ErrorStatus.NOT_WRITABLE, index, f"{inst.obj.name} is read-only")
            if isinstance(value, bool) or not isinstance(value, int):
                raise SnmpError(ErrorStatus.WRONG_TYPE, index, f"{inst.obj.name} is an INTEGER")
            if not inst.obj.low <= value <= inst.obj.high:
                raise SnmpError(ErrorStatus.WRONG_VALUE, index,
                                f"{inst.obj.name} = {value} outside {inst.obj.low}..{inst.obj.high}")
            checked.append((inst, value))
        for inst, value in checked:
            inst.write(value)
        self.set_count += 1

    def next_oid(self, oid: Oid) -> Oid | None:
        """The first instance strictly after ``oid`` in OID order (GETNEXT), or None at the end."""
        i = bisect.bisect_right(self._sorted, tuple(oid))
        return self._sorted[i] if i < len(self._sorted) else None

    def syntax(self, oid: Oid) -> Syntax:
        return self._by_oid[tuple(oid)].obj.syntax

    def __contains__(self, oid: Oid) -> bool:
        return tuple(oid) in self._by_oid

    def definition(self, oid: Oid) -> ObjectDef | None:
        """The object an instance OID belongs to, as the served edition defines it (None: no such object)."""
        return object_for(tuple(oid), self.edition)

    @property
    def oids(self) -> list[Oid]:
        return list(self._sorted)

    # --- building the instances ------------------------------------------------------------

    def _build(self) -> list[Instance]:
        c = self.controller
        cfg = c.config
        groups = cfg.groups
        red_revert = _RedRevert(c)
        out = [
            Instance(MAX_PHASES.instance(), MAX_PHASES, lambda: max(cfg.phases)),
            Instance(UNIT_RED_REVERT.instance(), UNIT_RED_REVERT, lambda: red_revert.unit, red_revert.set_unit),
            Instance(MAX_CHANNEL_STATUS_GROUPS.instance(), MAX_CHANNEL_STATUS_GROUPS, lambda: groups),
            Instance(MAX_RING_CONTROL_GROUPS.instance(), MAX_RING_CONTROL_GROUPS,
                     lambda: group_count(len(cfg.rings))),
            Instance(MAX_PHASE_GROUPS.instance(), MAX_PHASE_GROUPS, lambda: groups),
            Instance(UNIT_STARTUP_FLASH.instance(), UNIT_STARTUP_FLASH, lambda: c.startup_flash,
                     lambda v: setattr(c, "startup_flash", v)),
            Instance(UNIT_BACKUP_TIME.instance(), UNIT_BACKUP_TIME, lambda: c.backup_time,
                     lambda v: c.set_backup_time(v)),
            Instance(UNIT_CONTROL_STATUS.instance(), UNIT_CONTROL_STATUS, lambda: int(c.control_status)),
            Instance(UNIT_FLASH_STATUS.instance(), UNIT_FLASH_STATUS, lambda: int(c.flash_status)),
            Instance(SHORT_ALARM_STATUS.instance(), SHORT_ALARM_STATUS, lambda: int(c.short_alarm)),
            Instance(SYSTEM_PATTERN_CONTROL.instance(), SYSTEM_PATTERN_CONTROL, lambda: c.coordinator.command,
                     c.set_pattern_control),
            *_coordination(c),
            *_timebase(c),
            *_channels(cfg),
            *_spat(c, self),
        ]
        for p in _rows(cfg.phases):
            ph = cfg.phases.get(p)
            unprogrammed = None if ph else Timing(**_UNPROGRAMMED_TIMING)
            out.append(Instance(PHASE_NUMBER.instance(p), PHASE_NUMBER, _constant(p)))
            out += [Instance(PHASE_TABLE[col].instance(p), PHASE_TABLE[col], _constant(v))
                    for col, v in _phase_row(cfg, p, ph).items()]
            out += [Instance(PHASE_TABLE[col].instance(p), PHASE_TABLE[col],
                             *(_field_access(c, unprogrammed, name, unit) if unprogrammed
                               else red_revert.phase_access(p) if col is PhaseColumn.RED_REVERT
                               else _timing_access(c, p, name, unit)))
                    for col, (name, unit) in TIMING_COLUMNS.items()]
        out.append(Instance(RING_CONTROL_MAX2.instance(1), RING_CONTROL_MAX2,
                            lambda: sum(1 << (r - 1) for r in c.max2_rings),
                            lambda v: c.set_max2(k + 1 for k in range(8) if v >> k & 1)))
        out.append(Instance(RING_CONTROL_GROUP_NUMBER.instance(1), RING_CONTROL_GROUP_NUMBER, _constant(1)))
        st = c.status if isinstance(c, DelayedController) else c
        status: dict[StatusColumn, Callable[[], frozenset[int]]] = {
            StatusColumn.REDS: lambda: st.reds,
            StatusColumn.YELLOWS: lambda: st.yellows,
            StatusColumn.GREENS: lambda: st.greens,
            StatusColumn.DONT_WALKS: lambda: st.dont_walks,
            StatusColumn.PED_CLEARS: lambda: st.ped_clears,
            StatusColumn.WALKS: lambda: st.walks,
            StatusColumn.VEH_CALLS: lambda: st.calls,
            StatusColumn.PED_CALLS: lambda: st.ped_calls,
            StatusColumn.PHASE_ONS: lambda: st.phase_ons,
            StatusColumn.PHASE_NEXTS: lambda: st.phase_nexts,
        }
        channels = {ChannelColumn.REDS: status[StatusColumn.REDS], ChannelColumn.YELLOWS: status[StatusColumn.YELLOWS],
                    ChannelColumn.GREENS: status[StatusColumn.GREENS]}
        for g in range(1, groups + 1):
            out += [Instance(number.instance(g), number, _constant(g))
                    for number in (PHASE_STATUS_GROUP_NUMBER, PHASE_CONTROL_GROUP_NUMBER, CHANNEL_STATUS_GROUP_NUMBER)]
            out += [Instance(STATUS_TABLE[col].instance(g), STATUS_TABLE[col], _group_reader(read, g, groups))
                    for col, read in status.items()]
            # Channel i is driven by phase i: the emulator's load switches follow its phases one to one.
            out += [Instance(CHANNEL_TABLE[col].instance(g), CHANNEL_TABLE[col], _group_reader(read, g, groups))
                    for col, read in channels.items()]
            out += [Instance(CONTROL_TABLE[col].instance(g), CONTROL_TABLE[col],
                             _group_reader(lambda col=col: c.control[col], g, groups),
                             _group_writer(lambda col=col: c.control[col],
                                           lambda phases, col=col: c.set_control(col, phases), g))
                    for col in ControlColumn]
        out += _overlaps(c, st, self.edition)
        out += _preempts(c)
        # One sequence (sequenceData 1.r): the rings' order the config gives.
        out += [Instance(MAX_RINGS.instance(), MAX_RINGS, _constant(len(cfg.rings))),
                Instance(MAX_SEQUENCES.instance(), MAX_SEQUENCES, _constant(1))]
        for r, order in enumerate(cfg.rings, start=1):
            out += [Instance(SEQUENCE_NUMBER.instance(1, r), SEQUENCE_NUMBER, _constant(1)),
                    Instance(SEQUENCE_RING_NUMBER.instance(1, r), SEQUENCE_RING_NUMBER, _constant(r)),
                    Instance(sequence_oid(1, r), SEQUENCE_DATA, _constant(bytes(order)))]
        out += _detectors(cfg.detectors, (MAX_VEHICLE_DETECTORS, VEHICLE_DETECTOR_NUMBER, VEHICLE_DETECTOR_CALL_PHASE),
                          (MAX_VEHICLE_DETECTOR_STATUS_GROUPS, MAX_VEHICLE_DETECTOR_CONTROL_GROUPS),
                          (VEHICLE_DETECTOR_STATUS_GROUP_NUMBER, DETECTOR_STATUS_ACTIVE),
                          (VEHICLE_DETECTOR_CONTROL_GROUP_NUMBER, DETECTOR_ACTUATION),
                          lambda: c.actuations, c.set_actuations)
        out.extend(Instance(VEHICLE_DETECTOR_OPTIONS.instance(d), VEHICLE_DETECTOR_OPTIONS,
                            _constant(int(_detector_options(cfg, d))))
                   for d in _rows(cfg.detectors))
        out += [Instance(obj.instance(d), obj, *_detector_timer(c, d, name))
                for d in _rows(cfg.detectors) for obj, name in _DETECTOR_TIMERS.items()]
        out += _detectors(cfg.ped_detectors, (MAX_PED_DETECTORS, PED_DETECTOR_NUMBER, PED_DETECTOR_CALL_PHASE),
                          (MAX_PED_DETECTOR_GROUPS,), (PED_DETECTOR_STATUS_GROUP_NUMBER, PED_DETECTOR_STATUS_ACTIVE),
                          (PED_DETECTOR_CONTROL_GROUP_NUMBER, PED_DETECTOR_ACTUATION),
                          lambda: c.ped_actuations, c.set_ped_actuations)
        return out


def _phase_row(cfg: IntersectionConfig, p: int, ph: Phase | None) -> dict[PhaseColumn, Value]:
    """The columns of a phase's row that the config sets; an unprogrammed phase is disabled as the MIB says: start-up
    other ("this phase is not enabled (phaseOptions bit 0=0 or phaseRing=0)"), no option, ring 0 ("If the ring
    number is zero, the phase is disabled"), no concurrent phase."""
    if ph is None:
        return {PhaseColumn.STARTUP: int(PhaseStartup.OTHER), PhaseColumn.OPTIONS: 0, PhaseColumn.RING: 0,
                PhaseColumn.CONCURRENCY: b""}
    return {PhaseColumn.STARTUP: int(ph.startup), PhaseColumn.OPTIONS: int(phase_options(ph)),
            PhaseColumn.RING: ph.ring,
            PhaseColumn.CONCURRENCY: bytes(sorted(q for q in cfg.phases if cfg.compatible(p, q)))}


def _detectors(call_phases: dict[int, int], table: tuple[ObjectDef, ObjectDef, ObjectDef],
               group_counts: tuple[ObjectDef, ...], status: tuple[ObjectDef, ObjectDef],
               control: tuple[ObjectDef, ObjectDef], read: Callable[[], frozenset[int]],
               write: Callable[[frozenset[int]], None]) -> list[Instance]:
    """One kind of detector: how many, each one's number and the phase it calls (0 for an unprogrammed one: "The
    associated detector call capability is enabled when this object is set to a non-zero value"), how many groups
    of 8, and by group (its number) the active ones and their remote actuation (a SET of a group past the last is
    noSuchName in SNMPv1: that group does not exist)."""
    maximum, number, call_phase = table
    numbers = _rows(call_phases)
    groups = group_count(numbers[-1])
    out = [Instance(maximum.instance(), maximum, _constant(numbers[-1]))]
    out += [Instance(count.instance(), count, _constant(groups)) for count in group_counts]
    for d in numbers:
        out += [Instance(number.instance(d), number, _constant(d)),
                Instance(call_phase.instance(d), call_phase, _constant(call_phases.get(d, 0)))]
    for g in range(1, groups + 1):
        reader = _group_reader(read, g, groups)
        out += [Instance(obj.instance(g), obj, _constant(g)) for obj in (status[0], control[0])]
        out.append(Instance(status[1].instance(g), status[1], reader))
        out.append(Instance(control[1].instance(g), control[1], reader, _group_writer(read, write, g)))
    return out


class _RedRevert:
    """unitRedRevert beside each phase's phaseRedRevert: "if it is greater than a phaseRedRevert object value, then
    this value shall be used as the red revert time for the affected phase". The model times a phase's red revert
    from its timing row alone, so the view keeps what was SET of each and hands the model the greater of the two;
    phaseRedRevert reads back what was SET of it."""

    def __init__(self, c: Controller | DelayedController) -> None:
        self.controller = c
        self.unit = 0  # tenths, as the model's ticks
        self.phases = {p: timing.red_revert for p, timing in c.timing.items()}

    def set_unit(self, value: int) -> None:
        self.unit = value
        for p in self.phases:
            self._apply(p)

    def phase_access(self, phase: int) -> tuple[Callable[[], int], Callable[[int], None]]:
        def write(value: int) -> None:
            self.phases[phase] = value
            self._apply(phase)

        return lambda: self.phases[phase], write

    def _apply(self, phase: int) -> None:
        self.controller.set_timing(phase, "red_revert", max(self.phases[phase], self.unit))


def _channels(cfg: IntersectionConfig) -> list[Instance]:
    """The channel table: channel i is driven by phase i (the emulator's load switches follow its phases one to
    one, as channelStatusGroup says); a channel whose phase the config leaves out has no control source ("Value 00
    = No Control (Not In Use)")."""
    numbers = _rows(cfg.phases)
    out = [Instance(MAX_CHANNELS.instance(), MAX_CHANNELS, _constant(numbers[-1]))]
    for ch in numbers:
        out += [Instance(CHANNEL_NUMBER.instance(ch), CHANNEL_NUMBER, _constant(ch)),
                Instance(CHANNEL_CONTROL_SOURCE.instance(ch), CHANNEL_CONTROL_SOURCE,
                         _constant(ch if ch in cfg.phases else 0)),
                Instance(CHANNEL_CONTROL_TYPE.instance(ch), CHANNEL_CONTROL_TYPE,
                         _constant(int(ChannelControlType.PHASE_VEHICLE)))]
    return out


def _timebase(c: Controller | DelayedController) -> list[Instance]:
    """The time base action table: the config's [[coordination.schedule]] entries are its actions, numbered in the
    order of the day (the config orders them by their start), each running its pattern; with no schedule one
    unprogrammed action, pattern 0 ("A pattern of zero indicates that no pattern is being selected").
    timebaseAscActionStatus is the action of the time of day on the controller's clock ("the current time base
    Action Table row that will be used when the CU is in Time Base operation"; 0 with no schedule: "no time base
    Action is selected")."""
    schedule = c.config.coordination.schedule
    numbers = _rows(range(1, len(schedule) + 1))
    out = [Instance(TIMEBASE_PATTERN_SYNC.instance(), TIMEBASE_PATTERN_SYNC, _constant(0)),
           Instance(MAX_TIMEBASE_ACTIONS.instance(), MAX_TIMEBASE_ACTIONS, _constant(numbers[-1])),
           Instance(TIMEBASE_ACTION_STATUS.instance(), TIMEBASE_ACTION_STATUS,
                    lambda: _action_now(schedule, c.coordinator.clock % DAY))]
    for n in numbers:
        out += [Instance(TIMEBASE_ACTION_NUMBER.instance(n), TIMEBASE_ACTION_NUMBER, _constant(n)),
                Instance(TIMEBASE_PATTERN.instance(n), TIMEBASE_PATTERN,
                         _constant(schedule[n - 1].pattern if schedule else 0))]
    return out


def _action_now(schedule: Sequence[ScheduleEntry], tick_of_day: int) -> int:
    """The number (1-based, in the config's order) of the schedule entry in effect at this tick of the day: the last to
    start at or before it, or else the day's last (it runs on from the evening before); 0 with no schedule."""
    if not schedule:
        return 0
    started = [(e.start, n) for n, e in enumerate(schedule, start=1) if e.start * 10 <= tick_of_day]
    return max(started or [(e.start, n) for n, e in enumerate(schedule, start=1)])[1]


def _coordination(c: Controller | DelayedController) -> list[Instance]:
    """The coordination node: modes, the pattern and split tables (writable with NTCIP's ranges; a SET takes
    effect at the running pattern's next local zero), and the coordination status."""
    co = c.coordinator

    def table(apply: Callable[[int], None]) -> Callable[[int], None]:
        def write(value: int) -> None:
            apply(value)
            co.tables_changed()
            c.touch()
        return write

    out = [
        Instance(COORD_OPERATIONAL_MODE.instance(), COORD_OPERATIONAL_MODE, _constant(0)),
        Instance(COORD_CORRECTION_MODE.instance(), COORD_CORRECTION_MODE, lambda: int(co.correction),
                 table(lambda v: setattr(co, "correction", CoordCorrectionMode(v)))),
        Instance(COORD_FORCE_MODE.instance(), COORD_FORCE_MODE, lambda: int(co.force_mode),
                 table(lambda v: setattr(co, "force_mode", CoordForceMode(v)))),
        Instance(MAX_PATTERNS.instance(), MAX_PATTERNS, lambda: len(co.patterns)),
        Instance(PATTERN_TABLE_TYPE.instance(), PATTERN_TABLE_TYPE, lambda: 2),  # patterns(2): a row per pattern
        Instance(MAX_SPLITS.instance(), MAX_SPLITS, lambda: len(co.splits)),
        Instance(COORD_PATTERN_STATUS.instance(), COORD_PATTERN_STATUS, lambda: co.running),
        Instance(LOCAL_FREE_STATUS.instance(), LOCAL_FREE_STATUS, lambda: int(co.free_status)),
        Instance(COORD_CYCLE_STATUS.instance(), COORD_CYCLE_STATUS, lambda: co.cycle_status),
        Instance(COORD_SYNC_STATUS.instance(), COORD_SYNC_STATUS, lambda: co.sync_status),
    ]
    pattern_fields = {PatternColumn.CYCLE_TIME: "cycle", PatternColumn.OFFSET_TIME: "offset",
                      PatternColumn.SPLIT_NUMBER: "split", PatternColumn.SEQUENCE_NUMBER: "sequence"}
    for n, row in co.patterns.items():
        out.append(Instance(PATTERN_TABLE[PatternColumn.NUMBER].instance(n), PATTERN_TABLE[PatternColumn.NUMBER],
                            lambda n=n: n))
        out += [Instance(PATTERN_TABLE[col].instance(n), PATTERN_TABLE[col], lambda row=row, f=f: getattr(row, f),
                         table(lambda v, row=row, f=f: setattr(row, f, v)))
                for col, f in pattern_fields.items()]
    split_fields: dict[SplitColumn, tuple[str, Callable[[int], Any]]] = {
        SplitColumn.TIME: ("time", int), SplitColumn.MODE: ("mode", SplitMode),
        SplitColumn.COORD_PHASE: ("coord", bool)}
    for s, rows in co.splits.items():
        for p, row in rows.items():
            out.append(Instance(SPLIT_TABLE[SplitColumn.NUMBER].instance(s, p), SPLIT_TABLE[SplitColumn.NUMBER],
                                lambda s=s: s))
            out.append(Instance(SPLIT_TABLE[SplitColumn.PHASE].instance(s, p), SPLIT_TABLE[SplitColumn.PHASE],
                                lambda p=p: p))
            out += [Instance(SPLIT_TABLE[col].instance(s, p), SPLIT_TABLE[col],
                             lambda row=row, f=f: int(getattr(row, f)),
                             table(lambda v, row=row, f=f, kind=kind: setattr(row, f, kind(v))))
                    for col, (f, kind) in split_fields.items()]
    return out


_OVERLAP_TYPES = {OverlapKind.NORMAL: OverlapType.NORMAL,
                  OverlapKind.MINUS_GREEN_YELLOW: OverlapType.MINUS_GREEN_YELLOW,
                  OverlapKind.FYA: OverlapType.OTHER,
                  OverlapKind.TRANSIT: OverlapType.TRANSIT_2}
# Writable overlap columns: the OverlapTiming field each sets, and ticks per unit of the NTCIP value.
_OVERLAP_TIMING: dict[OverlapColumn, tuple[str, int]] = {
    OverlapColumn.TRAIL_GREEN: ("trail_green", 10),
    OverlapColumn.TRAIL_YELLOW: ("trail_yellow", 1),
    OverlapColumn.TRAIL_RED: ("trail_red", 1),
}


def _overlaps(c: Controller | DelayedController, st: Controller | DelayedController,
              edition: Version) -> list[Instance]:
    """The overlap node: the overlap table (type and phases from the config, the trailing times writable, acting
    from the next trailing interval on) and the overlap status by group of 8. A transit bar is v03's transit-2; v02
    has no such type, other(1) there."""
    cfg = c.config
    numbers = _rows(cfg.overlaps)
    groups = group_count(numbers[-1])
    out = [Instance(MAX_OVERLAPS.instance(), MAX_OVERLAPS, lambda: numbers[-1]),
           Instance(MAX_OVERLAP_STATUS_GROUPS.instance(), MAX_OVERLAP_STATUS_GROUPS, lambda: groups)]
    for n in numbers:
        o = cfg.overlaps.get(n) or Overlap(n, OverlapKind.NORMAL, ())  # unprogrammed: no included phase
        fixed: dict[OverlapColumn, Value] = {
            OverlapColumn.NUMBER: n,
            OverlapColumn.TYPE: int(OverlapType.OTHER if o.kind is OverlapKind.TRANSIT and edition is Version.V02
                                    else _OVERLAP_TYPES[o.kind]),
            OverlapColumn.INCLUDED_PHASES: bytes(o.included), OverlapColumn.MODIFIER_PHASES: bytes(o.modifiers)}
        out += [Instance(OVERLAP_TABLE[col].instance(n), OVERLAP_TABLE[col], lambda v=v: v) for col, v in fixed.items()]
        timing = c.overlaps.timing.get(n) or OverlapTiming.of(o)
        out += [Instance(OVERLAP_TABLE[col].instance(n), OVERLAP_TABLE[col], *_field_access(c, timing, name, unit))
                for col, (name, unit) in _OVERLAP_TIMING.items()]
    status: dict[OverlapStatusColumn, Callable[[], frozenset[int]]] = {
        OverlapStatusColumn.REDS: lambda: st.overlap_reds,
        OverlapStatusColumn.YELLOWS: lambda: st.overlap_yellows,
        OverlapStatusColumn.GREENS: lambda: st.overlap_greens,
    }
    for g in range(1, groups + 1):
        out.append(Instance(OVERLAP_STATUS_TABLE[OverlapStatusColumn.NUMBER].instance(g),
                            OVERLAP_STATUS_TABLE[OverlapStatusColumn.NUMBER], lambda g=g: g))
        out += [Instance(OVERLAP_STATUS_TABLE[col].instance(g), OVERLAP_STATUS_TABLE[col],
                         _group_reader(read, g, groups)) for col, read in status.items()]
    return out


# Writable preempt columns: the PreemptTiming field each sets, and ticks per unit of the NTCIP value.
_PREEMPT_TIMING: dict[PreemptColumn, tuple[str, int]] = {
    PreemptColumn.DELAY: ("delay", 10),
    PreemptColumn.MINIMUM_DURATION: ("min_duration", 10),
    PreemptColumn.MINIMUM_GREEN: ("min_green", 10),
    PreemptColumn.MINIMUM_WALK: ("min_walk", 10),
    PreemptColumn.ENTER_PED_CLEAR: ("enter_ped_clear", 10),
    PreemptColumn.TRACK_GREEN: ("track_green", 10),
    PreemptColumn.DWELL_GREEN: ("dwell_green", 10),
    PreemptColumn.MAXIMUM_PRESENCE: ("max_presence", 10),
    PreemptColumn.ENTER_YELLOW_CHANGE: ("enter_yellow", 1),
    PreemptColumn.ENTER_RED_CLEAR: ("enter_red", 1),
    PreemptColumn.TRACK_YELLOW_CHANGE: ("track_yellow", 1),
    PreemptColumn.TRACK_RED_CLEAR: ("track_red", 1),
}


def _spat(c: Controller | DelayedController, view: MibView) -> list[Instance]:
    """v03's ascSpat node: the controller's clock (spatTimestamp; ascCurrentTick, its tenths of the hour) and
    spatOptions. Not served (docs/spat.md says why): the enabled lanes (no MAP plan in the model), the SPaT port
    table (its rows are the RSU ports, maxRsuPorts, not modelled) and ascCurrentTickMsOffset (the model counts whole
    ticks: the milliseconds into one are the agent's wall clock, not the controller's)."""

    def set_options(v: int) -> None:
        view.spat_options = v

    return [Instance(SPAT_TIMESTAMP.instance(), SPAT_TIMESTAMP, lambda: spat_timestamp(c.coordinator.clock)),
            Instance(SPAT_OPTIONS.instance(), SPAT_OPTIONS, lambda: view.spat_options, set_options),
            Instance(ASC_CURRENT_TICK.instance(), ASC_CURRENT_TICK, lambda: c.coordinator.clock % TICKS_PER_HOUR)]


def _preempts(c: Controller | DelayedController) -> list[Instance]:
    """The preempt node: the preempt table (phases and control bits from the config, times writable, acting from
    the next use), each preempt's state, and preemptControlState (a SET calls or releases the preempt)."""
    pe = c.preemptor
    numbers = _rows(c.config.preempts)
    out = [Instance(MAX_PREEMPTS.instance(), MAX_PREEMPTS, lambda: numbers[-1])]
    for n in numbers:
        p = c.config.preempts.get(n) or Preempt(n)  # unprogrammed: no phases, its input calls nothing
        fixed: dict[PreemptColumn, Value] = {
            PreemptColumn.NUMBER: n, PreemptColumn.CONTROL: int(p.non_locking), PreemptColumn.LINK: 0,
            PreemptColumn.TRACK_PHASE: bytes(p.track_phases), PreemptColumn.DWELL_PHASE: bytes(p.dwell_phases),
            PreemptColumn.DWELL_PED: b"", PreemptColumn.EXIT_PHASE: bytes(p.exit_phases),
            PreemptColumn.CYCLING_PHASE: bytes(p.cycling_phases)}
        out += [Instance(PREEMPT_TABLE[col].instance(n), PREEMPT_TABLE[col], lambda v=v: v) for col, v in fixed.items()]
        timing = pe.timing.get(n) or PreemptTiming.of(p)
        out += [Instance(PREEMPT_TABLE[col].instance(n), PREEMPT_TABLE[col], *_field_access(c, timing, name, unit))
                for col, (name, unit) in _PREEMPT_TIMING.items()]
        out.append(Instance(PREEMPT_TABLE[PreemptColumn.STATE].instance(n), PREEMPT_TABLE[PreemptColumn.STATE],
                            lambda n=n: int(pe.states.get(n, PreemptState.NOT_ACTIVE))))
        out.append(Instance(PREEMPT_CONTROL_NUMBER.instance(n), PREEMPT_CONTROL_NUMBER, lambda n=n: n))
        out.append(Instance(PREEMPT_CONTROL_STATE.instance(n), PREEMPT_CONTROL_STATE,
                            lambda n=n: int(n in pe.control),
                            lambda v, n=n: c.set_preempt_control(pe.control - {n} | ({n} if v else set()))))
    # v03's preempt status: "the preempt number that is currently being serviced" (the lowest in service: lower
    # numbers override higher), and the preempt inputs by group of 8, of which the MIB allows 2 at most.
    out.append(Instance(PREEMPT_STATUS.instance(), PREEMPT_STATUS,
                        lambda: min((n for n, s in pe.states.items() if s.in_service), default=0)))
    groups = group_count(numbers[-1])
    if groups <= MAX_PREEMPT_GROUPS.high:
        out.append(Instance(MAX_PREEMPT_GROUPS.instance(), MAX_PREEMPT_GROUPS, _constant(groups)))
        for g in range(1, groups + 1):
            out += [Instance(PREEMPT_STATUS_GROUP_NUMBER.instance(g), PREEMPT_STATUS_GROUP_NUMBER, _constant(g)),
                    Instance(PREEMPT_STATUS_GROUP.instance(g), PREEMPT_STATUS_GROUP,
                             _group_reader(lambda: pe.control, g, groups))]
    return out


# Status is read at 10-100 Hz and takes few distinct values: convert each phase set once.
_masks = lru_cache(maxsize=1024)(phases_to_groups)


def _timing_access(c: Controller | DelayedController, phase: int, name: str, unit: int
                   ) -> tuple[Callable[[], int], Callable[[int], None]]:
    """Read and write one timing field in NTCIP units (seconds or tenths); the controller counts ticks."""
    timing = c.timing[phase]
    return lambda: getattr(timing, name) // unit, lambda v: c.set_timing(phase, name, v * unit)


def _field_access(c: Controller | DelayedController, row: Any, name: str, unit: int
                  ) -> tuple[Callable[[], int], Callable[[int], None]]:
    """Read and write one field of a timing row in NTCIP units; a write wakes the controller (a threshold moved)."""

    def write(v: int) -> None:
        setattr(row, name, v * unit)
        c.touch()

    return lambda: getattr(row, name) // unit, write


#: Writable detector table columns (tenths, the model's ticks): the detector unit's timer each sets.
_DETECTOR_TIMERS = {VEHICLE_DETECTOR_DELAY: "delay", VEHICLE_DETECTOR_EXTEND: "extend"}


def _detector_timer(c: Controller | DelayedController, d: int, name: str
                    ) -> tuple[Callable[[], int], Callable[[int], None]]:
    """Read and write one timer of detector ``d`` (:mod:`emulator.model.detectors`), acting from the next tick."""

    def write(v: int) -> None:
        c.detectors.retime(d, name, v, c.actuations)
        c.touch()

    return lambda: c.detectors.timer(d, name), write


def _constant(value: Value) -> Callable[[], Value]:
    return lambda: value


def _group_reader(read: Callable[[], frozenset[int]], group: int, groups: int) -> Callable[[], int]:
    return lambda: _masks(read(), groups)[group - 1]


def _group_writer(read: Callable[[], frozenset[int]], write: Callable[[frozenset[int]], None],
                  group: int) -> Callable[[int], None]:
    """SET of one group of 8 (phases or detectors): replaces that group's members, keeps the others'."""
    base = 8 * (group - 1)

    def set_group(mask: int) -> None:
        others = {n for n in read() if not base < n <= base + 8}
        write(frozenset(others | {base + n for n in groups_to_phases((mask,))}))

    return set_group
