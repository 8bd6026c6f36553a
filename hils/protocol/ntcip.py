"""NTCIP 1202 object model, SNMP value types and the latency model: what the middleware and
the emulator share (the emulator imports nothing else of hils but the intersection config).

Each object is defined as an edition of the standard defines it (:class:`Version`): v02, what an Econolite
Cobalt speaks, unless the object is one v03 added. Where v03 changed an object hils knows, :data:`V03_CHANGES`
says how. The definitions are checked against the compiled NTCIP 1202 v03 MIB by
:mod:`harness.reference.mib_conformance`.

This is the only module that spells an OID. Everything else names objects by
the definitions below and builds instance OIDs with the helpers here, so an
OID typo can exist in one place only.

Phase sets travel on the wire as group bitmasks: bit k of group g stands for
phase 8 * (g - 1) + k + 1. Inside the project a phase set is a ``frozenset`` of
phase numbers; :func:`phases_to_groups` and :func:`groups_to_phases` convert.
"""

from __future__ import annotations

import random
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from enum import Enum, IntEnum, IntFlag, StrEnum

Oid = tuple[int, ...]
Value = int | bytes  # what an NTCIP object holds: INTEGER or OCTET STRING

#: 1.3.6.1.4.1.1206.4.2.1: the NTCIP 1202 actuated signal controller node.
ASC: Oid = (1, 3, 6, 1, 4, 1, 1206, 4, 2, 1)
PHASES_PER_GROUP = 8


class Syntax(Enum):
    INTEGER = "INTEGER"
    OCTET_STRING = "OCTET STRING"


class Access(Enum):
    READ_ONLY = "read-only"
    READ_WRITE = "read-write"


class Version(StrEnum):
    """An edition of NTCIP 1202 (of its ASC MIB)."""

    V02 = "v02"
    V03 = "v03"


#: The edition the emulator serves and the middleware assumes: v02, what an Econolite Cobalt speaks (DESIGN.md);
#: an object v03 added is served as v03 defines it.
DEFAULT_VERSION = Version.V02

#: Where NTCIP 1202 v03 (1202v0328) defines an object otherwise than v02, among the objects hils knows: how, and
#: where v02's definition is read. The v02 text is not at hand here: v02's side comes from the ASC MIB before v03
#: (1202ASC.mib as pysmi compiled it into ASC_MIB1, in the repository Metrolla-Inc/ntcipy), which issue 36 confirms
#: for v02.
V03_CHANGES: dict[str, str] = {
    "patternSplitNumber": 'read-write before v03 (ASC_MIB1: patternSplitNumber.setMaxAccess("read-write")); '
                          "read-only in v03 (1202v0328 5.5.7.4)",
}
#: The access v03 gives the objects of :data:`V03_CHANGES` whose access it changed: what is served under v03.
V03_ACCESS: dict[str, Access] = {"patternSplitNumber": Access.READ_ONLY}
#: Objects v03 added that are served under v02 too, and why: a real controller's detectors are wired to its cabinet,
#: the emulator's reach it over SNMP only (hils' detector feed in virtual time and Signal-Replay SET them).
SERVED_IN_V02: dict[str, str] = {
    name: "the cabinet's detector inputs: the emulator has no wires, its detectors are actuated over SNMP"
    for name in ("maxVehicleDetectorControlGroups", "vehicleDetectorControlGroupNumber",
                 "vehicleDetectorControlGroupActuation", "pedestrianDetectorControlGroupNumber",
                 "pedestrianDetectorControlGroupActuation")
}


#: Environment variables holding SNMPv3 keys (pass phrases) when a target URL or
#: `hils emulator serve` does not give them: keeps keys out of shell history and process lists.
AUTH_KEY_ENV = "HILS_SNMP_AUTH_KEY"
PRIV_KEY_ENV = "HILS_SNMP_PRIV_KEY"


class ErrorStatus(IntEnum):
    """SNMP error-status values (RFC 3416); v1 uses the first six."""

    NO_ERROR = 0
    TOO_BIG = 1
    NO_SUCH_NAME = 2
    BAD_VALUE = 3
    READ_ONLY = 4
    GEN_ERR = 5
    NO_ACCESS = 6
    WRONG_TYPE = 7
    WRONG_LENGTH = 8
    WRONG_ENCODING = 9
    WRONG_VALUE = 10
    NO_CREATION = 11
    INCONSISTENT_VALUE = 12
    RESOURCE_UNAVAILABLE = 13
    COMMIT_FAILED = 14
    UNDO_FAILED = 15
    AUTHORIZATION_ERROR = 16
    NOT_WRITABLE = 17
    INCONSISTENT_NAME = 18


class SnmpError(Exception):
    """An SNMP-style refusal of a request: error status and the 1-based index of the varbind."""

    def __init__(self, status: ErrorStatus, index: int = 0, detail: str = "") -> None:
        # args are the constructor's arguments: SimPy re-raises an unhandled
        # failure as type(exc)(*exc.args), which must rebuild this error.
        super().__init__(status, index, detail)
        self.status = status
        self.index = index
        self.detail = detail

    def __str__(self) -> str:
        return f"{self.status.name.lower()} at varbind {self.index}" + (f": {self.detail}" if self.detail else "")


class PhaseColumn(IntEnum):
    """Columns of phaseTable (A.1.2.1.c.p)."""

    WALK = 2
    PEDESTRIAN_CLEAR = 3
    MINIMUM_GREEN = 4
    PASSAGE = 5
    MAXIMUM1 = 6
    MAXIMUM2 = 7
    YELLOW_CHANGE = 8
    RED_CLEAR = 9
    RED_REVERT = 10
    TIME_BEFORE_REDUCTION = 13
    TIME_TO_REDUCE = 15
    MINIMUM_GAP = 17
    STARTUP = 20
    OPTIONS = 21
    RING = 22
    CONCURRENCY = 23


class PhaseOption(IntFlag):
    """Bits of phaseOptions (NTCIP 1202 phaseOptions, REFERENCE NEMA TS 2 clause 3.5)."""

    ENABLED = 1 << 0
    AUTO_FLASH_ENTRY = 1 << 1
    AUTO_FLASH_EXIT = 1 << 2
    NON_ACTUATED_1 = 1 << 3
    NON_ACTUATED_2 = 1 << 4
    NON_LOCK_MEMORY = 1 << 5
    MIN_VEHICLE_RECALL = 1 << 6
    MAX_VEHICLE_RECALL = 1 << 7
    PED_RECALL = 1 << 8
    SOFT_VEHICLE_RECALL = 1 << 9
    DUAL_ENTRY = 1 << 10
    SIMULTANEOUS_GAP_DISABLE = 1 << 11
    GUARANTEED_PASSAGE = 1 << 12
    ACTUATED_REST_IN_WALK = 1 << 13
    CONDITIONAL_SERVICE = 1 << 14


class StatusColumn(IntEnum):
    """Columns of phaseStatusGroupTable (A.1.4.1.c.g)."""

    REDS = 2
    YELLOWS = 3
    GREENS = 4
    DONT_WALKS = 5
    PED_CLEARS = 6
    WALKS = 7
    VEH_CALLS = 8
    PED_CALLS = 9
    PHASE_ONS = 10
    PHASE_NEXTS = 11


class ControlColumn(IntEnum):
    """Columns of phaseControlGroupTable (A.1.5.1.c.g)."""

    PHASE_OMIT = 2
    PED_OMIT = 3
    HOLD = 4
    FORCE_OFF = 5
    VEH_CALL = 6
    PED_CALL = 7


class ChannelColumn(IntEnum):
    """Columns of channelStatusGroupTable (A.8.4.1.c.g)."""

    REDS = 2
    YELLOWS = 3
    GREENS = 4


class PhaseStartup(IntEnum):
    OTHER = 1
    PHASE_NOT_ON = 2
    GREEN_WALK = 3
    GREEN_NO_WALK = 4
    YELLOW_CHANGE = 5
    RED_CLEAR = 6


class UnitControlStatus(IntEnum):
    OTHER = 1
    SYSTEM_CONTROL = 2
    SYSTEM_STANDBY = 3
    BACKUP_MODE = 4
    MANUAL = 5
    TIMEBASE = 6
    INTERCONNECT = 7
    INTERCONNECT_BACKUP = 8


class UnitFlashStatus(IntEnum):
    OTHER = 1
    NOT_FLASH = 2
    AUTOMATIC = 3
    LOCAL_MANUAL = 4
    FAULT_MONITOR = 5
    MMU = 6
    STARTUP = 7
    PREEMPT = 8


class LocalFreeStatus(IntEnum):
    """localFreeStatus (NTCIP 1202 v02 A.4.11): why the unit runs free, or notFree while it coordinates."""

    OTHER = 1
    NOT_FREE = 2
    COMMAND_FREE = 3
    TRANSITION_FREE = 4
    INPUT_FREE = 5
    COORD_FREE = 6
    BAD_PLAN = 7
    BAD_CYCLE_TIME = 8
    SPLIT_OVERRUN = 9
    INVALID_OFFSET = 10
    FAILED = 11


class SplitMode(IntEnum):
    """splitMode (NTCIP 1202 v02 A.4.9.1.4): a phase's operation while its pattern runs."""

    OTHER = 1
    NONE = 2
    MIN_RECALL = 3
    MAX_RECALL = 4
    PED_RECALL = 5
    MAX_AND_PED_RECALL = 6
    OMITTED = 7


class CoordCorrectionMode(IntEnum):
    """coordCorrectionMode (NTCIP 1202 v02 A.4.2)."""

    OTHER = 1
    DWELL = 2
    SHORTWAY = 3
    ADD_ONLY = 4


class CoordForceMode(IntEnum):
    """coordForceMode (NTCIP 1202 v02 A.4.4)."""

    OTHER = 1
    FLOATING = 2
    FIXED = 3


@dataclass(frozen=True, slots=True)
class ObjectDef:
    """One NTCIP object type: its name, OID prefix and SNMP properties.

    ``prefix`` is the object's OID without the instance part; a scalar's
    instance is ``.0``, a table column's instance is its row index.
    """

    name: str
    prefix: Oid
    syntax: Syntax
    access: Access
    low: int = 0
    high: int = 255
    version: Version = DEFAULT_VERSION  # the edition whose definition this is (v03: an object v03 added)

    def instance(self, *index: int) -> Oid:
        return self.prefix + (index or (0,))

    def in_edition(self, edition: Version) -> ObjectDef | None:
        """This object as ``edition`` defines it: None where that edition has no such object (one v03 added, under
        v02, unless :data:`SERVED_IN_V02`), with v03's access where v03 changed it (:data:`V03_ACCESS`)."""
        if edition is Version.V02:
            return None if self.version is Version.V03 and self.name not in SERVED_IN_V02 else self
        access = V03_ACCESS.get(self.name)
        return self if access is None else replace(self, access=access, version=Version.V03)


def _o(name: str, suffix: Oid, syntax: Syntax = Syntax.INTEGER, access: Access = Access.READ_ONLY,
       low: int = 0, high: int = 255, version: Version = DEFAULT_VERSION) -> ObjectDef:
    return ObjectDef(name, ASC + suffix, syntax, access, low, high, version)


MAX_PHASES = _o("maxPhases", (1, 1), low=2)
MAX_PHASE_GROUPS = _o("maxPhaseGroups", (1, 3), low=1)
UNIT_STARTUP_FLASH = _o("unitStartUpFlash", (3, 1), access=Access.READ_WRITE)
UNIT_BACKUP_TIME = _o("unitBackupTime", (3, 3), access=Access.READ_WRITE, high=65535)
# unitRedRevert (A.3.4), tenths: "the minimum red revert time for all phases (i.e. if it is greater than a
# phaseRedRevert object value, then this value shall be used as the red revert time for the affected phase)".
UNIT_RED_REVERT = _o("unitRedRevert", (3, 4), access=Access.READ_WRITE)
UNIT_CONTROL_STATUS = _o("unitControlStatus", (3, 5), low=1, high=8)
UNIT_FLASH_STATUS = _o("unitFlashStatus", (3, 6), low=1, high=8)
SYSTEM_PATTERN_CONTROL = _o("systemPatternControl", (4, 14), access=Access.READ_WRITE)
# coordOperationalMode (A.4.1): "0 Automatic - ... coord operation, free, and flash to be determined automatically
# by the possible sources (i.e. Interconnect, Time Base, or System Commands)"; 1-255 override them.
COORD_OPERATIONAL_MODE = _o("coordOperationalMode", (4, 1), access=Access.READ_WRITE)
# timebaseAscPatternSync (A.5.1): "Pattern Sync Reference in minutes past midnight".
TIMEBASE_PATTERN_SYNC = _o("timebaseAscPatternSync", (5, 1), access=Access.READ_WRITE, high=65535)

# Coordination (NTCIP 1202 v02 node coord, A.4; OIDs and ranges from the standard's ASC MIB, 1202ASC.mib as
# compiled by pysmi into ASC_MIB1, the enumerations named there). The pattern table is indexed by pattern
# number, the split table by split number and phase.
COORD_CORRECTION_MODE = _o("coordCorrectionMode", (4, 2), access=Access.READ_WRITE, low=1, high=4)
COORD_FORCE_MODE = _o("coordForceMode", (4, 4), access=Access.READ_WRITE, low=1, high=3)
MAX_PATTERNS = _o("maxPatterns", (4, 5), low=1, high=253)
PATTERN_TABLE_TYPE = _o("patternTableType", (4, 6), low=1, high=4)
MAX_SPLITS = _o("maxSplits", (4, 8), low=1)
COORD_PATTERN_STATUS = _o("coordPatternStatus", (4, 10))
LOCAL_FREE_STATUS = _o("localFreeStatus", (4, 11), low=1, high=11)
COORD_CYCLE_STATUS = _o("coordCycleStatus", (4, 12), high=510)
COORD_SYNC_STATUS = _o("coordSyncStatus", (4, 13), high=510)


class PatternColumn(IntEnum):
    """Columns of patternTable (A.4.7.1.c.pattern)."""

    NUMBER = 1
    CYCLE_TIME = 2
    OFFSET_TIME = 3
    SPLIT_NUMBER = 4
    SEQUENCE_NUMBER = 5


class SplitColumn(IntEnum):
    """Columns of splitTable (A.4.9.1.c.split.phase)."""

    NUMBER = 1
    PHASE = 2
    TIME = 3
    MODE = 4
    COORD_PHASE = 5


PATTERN_TABLE: dict[PatternColumn, ObjectDef] = {
    PatternColumn.NUMBER: _o("patternNumber", (4, 7, 1, 1), low=1, high=253),
    PatternColumn.CYCLE_TIME: _o("patternCycleTime", (4, 7, 1, 2), access=Access.READ_WRITE),
    PatternColumn.OFFSET_TIME: _o("patternOffsetTime", (4, 7, 1, 3), access=Access.READ_WRITE),
    # v02's access (see V03_CHANGES); the range both editions admit.
    PatternColumn.SPLIT_NUMBER: _o("patternSplitNumber", (4, 7, 1, 4), access=Access.READ_WRITE, low=1),
    PatternColumn.SEQUENCE_NUMBER: _o("patternSequenceNumber", (4, 7, 1, 5), access=Access.READ_WRITE, low=1),
}
SPLIT_TABLE: dict[SplitColumn, ObjectDef] = {
    SplitColumn.NUMBER: _o("splitNumber", (4, 9, 1, 1), low=1),
    SplitColumn.PHASE: _o("splitPhase", (4, 9, 1, 2), low=1),
    SplitColumn.TIME: _o("splitTime", (4, 9, 1, 3), access=Access.READ_WRITE),
    SplitColumn.MODE: _o("splitMode", (4, 9, 1, 4), access=Access.READ_WRITE, low=1, high=7),
    SplitColumn.COORD_PHASE: _o("splitCoordPhase", (4, 9, 1, 5), access=Access.READ_WRITE, high=1),
}

# The timing columns are writable with NTCIP 1202's ranges (seconds, or tenths for passage and clearances).
_RW = Access.READ_WRITE
_PHASE_NAMES: dict[PhaseColumn, tuple[str, Syntax, Access, int, int]] = {
    PhaseColumn.WALK: ("phaseWalk", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.PEDESTRIAN_CLEAR: ("phasePedestrianClear", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.MINIMUM_GREEN: ("phaseMinimumGreen", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.PASSAGE: ("phasePassage", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.MAXIMUM1: ("phaseMaximum1", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.MAXIMUM2: ("phaseMaximum2", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.YELLOW_CHANGE: ("phaseYellowChange", Syntax.INTEGER, _RW, 30, 255),
    PhaseColumn.RED_CLEAR: ("phaseRedClear", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.RED_REVERT: ("phaseRedRevert", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.TIME_BEFORE_REDUCTION: ("phaseTimeBeforeReduction", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.TIME_TO_REDUCE: ("phaseTimeToReduce", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.MINIMUM_GAP: ("phaseMinimumGap", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.STARTUP: ("phaseStartup", Syntax.INTEGER, _RW, 1, 6),
    PhaseColumn.OPTIONS: ("phaseOptions", Syntax.INTEGER, _RW, 0, 65535),
    PhaseColumn.RING: ("phaseRing", Syntax.INTEGER, _RW, 0, 255),
    PhaseColumn.CONCURRENCY: ("phaseConcurrency", Syntax.OCTET_STRING, _RW, 0, 255),
}
PHASE_TABLE: dict[PhaseColumn, ObjectDef] = {
    col: _o(name, (1, 2, 1, int(col)), syntax, access, low, high)
    for col, (name, syntax, access, low, high) in _PHASE_NAMES.items()
}
STATUS_TABLE: dict[StatusColumn, ObjectDef] = {
    col: _o("phaseStatusGroup" + col.name.title().replace("_", ""), (1, 4, 1, int(col))) for col in StatusColumn
}
CONTROL_TABLE: dict[ControlColumn, ObjectDef] = {
    col: _o("phaseControlGroup" + col.name.title().replace("_", ""), (1, 5, 1, int(col)), access=Access.READ_WRITE)
    for col in ControlColumn
}
#: The control objects a middleware never sets, read back to see whether someone else did (VehCall is the
#: middleware's, re-SET by every command and keepalive, and its read races with its own SETs in flight).
FOREIGN_COLUMNS = tuple(c for c in ControlColumn if c is not ControlColumn.VEH_CALL)
MAX_CHANNEL_STATUS_GROUPS = _o("maxChannelStatusGroups", (8, 3), low=1)
CHANNEL_TABLE: dict[ChannelColumn, ObjectDef] = {
    col: _o("channelStatusGroup" + col.name.title().replace("_", ""), (8, 4, 1, int(col))) for col in ChannelColumn
}
SEQUENCE_DATA = _o("sequenceData", (7, 3, 1, 3), Syntax.OCTET_STRING, access=Access.READ_WRITE)
MAX_RING_CONTROL_GROUPS = _o("maxRingControlGroups", (7, 4), low=1)
# ringControlGroupMax2 (A.1.7.5.1.4.g): bit k-1 of group 1 selects Maximum 2 for ring k.
RING_CONTROL_MAX2 = _o("ringControlGroupMax2", (7, 5, 1, 4), access=Access.READ_WRITE)

# Overlaps (NTCIP 1202 v02 node overlap, A.9; OIDs, ranges and the overlapType enumeration from the same ASC
# MIB): the overlap table by overlap number (1 = Overlap A) and the overlap status by group of 8 overlaps.
MAX_OVERLAPS = _o("maxOverlaps", (9, 1), low=1)
MAX_OVERLAP_STATUS_GROUPS = _o("maxOverlapStatusGroups", (9, 3), low=1)


def overlap_letter(number: int) -> str:
    """An overlap's name by its number: 1 = Overlap A."""
    return chr(ord("A") + number - 1)


class OverlapType(IntEnum):
    """overlapType (A.9.2.1.2). NTCIP 1202 v02 knows normal and minusGreenYellow; a flashing yellow arrow is a
    vendor's type there, other(1). v03 adds transit-2 (9), a 2-section transit bar."""

    OTHER = 1
    NORMAL = 2
    MINUS_GREEN_YELLOW = 3
    TRANSIT_2 = 9


class OverlapColumn(IntEnum):
    """Columns of overlapTable (A.9.2.1.c.overlap)."""

    NUMBER = 1
    TYPE = 2
    INCLUDED_PHASES = 3
    MODIFIER_PHASES = 4
    TRAIL_GREEN = 5
    TRAIL_YELLOW = 6
    TRAIL_RED = 7


class OverlapStatusColumn(IntEnum):
    """Columns of overlapStatusGroupTable (A.9.4.1.c.group); bit k of group g is overlap 8(g-1)+k+1."""

    NUMBER = 1
    REDS = 2
    YELLOWS = 3
    GREENS = 4


# The trailing times in the MIB's units (green in seconds, yellow and red in tenths; the yellow from 3.0 s, "NEMA
# range: 3.0-25.5 sec", as the phase table's yellow change).
OVERLAP_TABLE: dict[OverlapColumn, ObjectDef] = {
    OverlapColumn.NUMBER: _o("overlapNumber", (9, 2, 1, 1), low=1),
    # 1-3 as v02 has them, and v03's transit-2 (9), the one type v03 added that the emulator serves.
    OverlapColumn.TYPE: _o("overlapType", (9, 2, 1, 2), access=Access.READ_WRITE, low=1, high=9),
    OverlapColumn.INCLUDED_PHASES: _o("overlapIncludedPhases", (9, 2, 1, 3), Syntax.OCTET_STRING,
                                      access=Access.READ_WRITE),
    OverlapColumn.MODIFIER_PHASES: _o("overlapModifierPhases", (9, 2, 1, 4), Syntax.OCTET_STRING,
                                      access=Access.READ_WRITE),
    OverlapColumn.TRAIL_GREEN: _o("overlapTrailGreen", (9, 2, 1, 5), access=Access.READ_WRITE),
    OverlapColumn.TRAIL_YELLOW: _o("overlapTrailYellow", (9, 2, 1, 6), access=Access.READ_WRITE, low=30),
    OverlapColumn.TRAIL_RED: _o("overlapTrailRed", (9, 2, 1, 7), access=Access.READ_WRITE),
}
OVERLAP_STATUS_TABLE: dict[OverlapStatusColumn, ObjectDef] = {
    OverlapStatusColumn.NUMBER: _o("overlapStatusGroupNumber", (9, 4, 1, 1), low=1),
    **{col: _o("overlapStatusGroup" + col.name.title(), (9, 4, 1, int(col)))
       for col in (OverlapStatusColumn.REDS, OverlapStatusColumn.YELLOWS, OverlapStatusColumn.GREENS)},
}

# Preemption (NTCIP 1202 v02 node preempt, A.6; OIDs, ranges and the preemptState enumeration from the ASC MIB,
# the v02 columns past .16 numbered as the standard lists them: preemptEnterYellowChange .22 and
# preemptEnterRedClear .23 as controller firmware spells them, preemptTrackYellowChange .24 and
# preemptTrackRedClear .25 after them). The table is indexed by preempt number: lower numbers override higher.
MAX_PREEMPTS = _o("maxPreempts", (6, 1), low=1)
# shortAlarmStatus (A.3.9): "Bit 1: T&F Flash - When either the Local Flash or MMU Flash input becomes active.
# Bit 0: Preempt - When any of the CU Preempt inputs become active."
SHORT_ALARM_STATUS = _o("shortAlarmStatus", (3, 9))


class ShortAlarm(IntFlag):
    """The shortAlarmStatus bits the emulator sets."""

    PREEMPT = 1
    TF_FLASH = 2


class PreemptState(IntEnum):
    """preemptState (A.6.2.1.16): where a preempt's service is."""

    OTHER = 1
    NOT_ACTIVE = 2
    NOT_ACTIVE_WITH_CALL = 3
    ENTRY_STARTED = 4
    TRACK_SERVICE = 5
    DWELL = 6
    LINK_ACTIVE = 7
    EXIT_STARTED = 8
    MAX_PRESENCE = 9

    @property
    def in_service(self) -> bool:
        """The preempt drives the controller: its entry, track clearance, dwell, linked preempt or exit. Not while
        its input waits out the delay (notActiveWithCall), nor once the maximum presence has returned the controller
        to "normal operation" (maxPresence)."""
        return self in _IN_SERVICE


_IN_SERVICE = frozenset({PreemptState.ENTRY_STARTED, PreemptState.TRACK_SERVICE, PreemptState.DWELL,
                         PreemptState.LINK_ACTIVE, PreemptState.EXIT_STARTED})


class PreemptColumn(IntEnum):
    """Columns of preemptTable (A.6.2.1.c.preempt)."""

    NUMBER = 1
    CONTROL = 2
    LINK = 3
    DELAY = 4
    MINIMUM_DURATION = 5
    MINIMUM_GREEN = 6
    MINIMUM_WALK = 7
    ENTER_PED_CLEAR = 8
    TRACK_GREEN = 9
    DWELL_GREEN = 10
    MAXIMUM_PRESENCE = 11
    TRACK_PHASE = 12
    DWELL_PHASE = 13
    DWELL_PED = 14
    EXIT_PHASE = 15
    STATE = 16
    CYCLING_PHASE = 19
    ENTER_YELLOW_CHANGE = 22
    ENTER_RED_CLEAR = 23
    TRACK_YELLOW_CHANGE = 24
    TRACK_RED_CLEAR = 25


# The times in the standard's units (seconds; tenths for the clearances, the yellows from NEMA's 3.0 s as the phase
# table's).
_PREEMPT_NAMES: dict[PreemptColumn, tuple[str, Syntax, Access, int, int]] = {
    PreemptColumn.NUMBER: ("preemptNumber", Syntax.INTEGER, Access.READ_ONLY, 1, 255),
    PreemptColumn.CONTROL: ("preemptControl", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.LINK: ("preemptLink", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.DELAY: ("preemptDelay", Syntax.INTEGER, _RW, 0, 600),
    PreemptColumn.MINIMUM_DURATION: ("preemptMinimumDuration", Syntax.INTEGER, _RW, 0, 65535),
    PreemptColumn.MINIMUM_GREEN: ("preemptMinimumGreen", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.MINIMUM_WALK: ("preemptMinimumWalk", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.ENTER_PED_CLEAR: ("preemptEnterPedClear", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.TRACK_GREEN: ("preemptTrackGreen", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.DWELL_GREEN: ("preemptDwellGreen", Syntax.INTEGER, _RW, 1, 255),
    PreemptColumn.MAXIMUM_PRESENCE: ("preemptMaximumPresence", Syntax.INTEGER, _RW, 0, 65535),
    PreemptColumn.TRACK_PHASE: ("preemptTrackPhase", Syntax.OCTET_STRING, _RW, 0, 255),
    PreemptColumn.DWELL_PHASE: ("preemptDwellPhase", Syntax.OCTET_STRING, _RW, 0, 255),
    PreemptColumn.DWELL_PED: ("preemptDwellPed", Syntax.OCTET_STRING, _RW, 0, 255),
    PreemptColumn.EXIT_PHASE: ("preemptExitPhase", Syntax.OCTET_STRING, _RW, 0, 255),
    PreemptColumn.STATE: ("preemptState", Syntax.INTEGER, Access.READ_ONLY, 1, 9),
    PreemptColumn.CYCLING_PHASE: ("preemptCyclingPhase", Syntax.OCTET_STRING, _RW, 0, 255),
    PreemptColumn.ENTER_YELLOW_CHANGE: ("preemptEnterYellowChange", Syntax.INTEGER, _RW, 30, 255),
    PreemptColumn.ENTER_RED_CLEAR: ("preemptEnterRedClear", Syntax.INTEGER, _RW, 0, 255),
    PreemptColumn.TRACK_YELLOW_CHANGE: ("preemptTrackYellowChange", Syntax.INTEGER, _RW, 30, 255),
    PreemptColumn.TRACK_RED_CLEAR: ("preemptTrackRedClear", Syntax.INTEGER, _RW, 0, 255),
}
PREEMPT_TABLE: dict[PreemptColumn, ObjectDef] = {
    col: _o(name, (6, 2, 1, int(col)), syntax, access, low, high)
    for col, (name, syntax, access, low, high) in _PREEMPT_NAMES.items()
}
# preemptControlTable (A.6.3.1.c.preempt): "when set to ON (one) shall cause the associated preempt actions to
# occur ... The device shall reset this object to ZERO when in BACKUP Mode. A write to this object shall reset
# the Backup timer".
PREEMPT_CONTROL_NUMBER = _o("preemptControlNumber", (6, 3, 1, 1), low=1)
PREEMPT_CONTROL_STATE = _o("preemptControlState", (6, 3, 1, 2), access=Access.READ_WRITE, high=1)


class DetectorOption(IntFlag):
    """Bits of vehicleDetectorOptions (A.2.2.1.2), "0=Disabled, 1=Enabled"."""

    VOLUME = 1 << 0
    OCCUPANCY = 1 << 1
    YELLOW_LOCK_CALL = 1 << 2
    RED_LOCK_CALL = 1 << 3
    PASSAGE = 1 << 4
    ADDED_INITIAL = 1 << 5
    QUEUE = 1 << 6
    CALL = 1 << 7


# Vehicle detectors (A.1.2): the detector table (call phase, options), the active detectors by group of 8
# (vehicleDetectorStatusGroupActive) and NTCIP 1202 v03's remote actuation by group of 8
# (vehicleDetectorControlGroupActuation: a set bit forces that detector's actuation, as a cabinet input would).
MAX_VEHICLE_DETECTORS = _o("maxVehicleDetectors", (2, 1), low=1)
VEHICLE_DETECTOR_OPTIONS = _o("vehicleDetectorOptions", (2, 2, 1, 2), access=Access.READ_WRITE)
VEHICLE_DETECTOR_CALL_PHASE = _o("vehicleDetectorCallPhase", (2, 2, 1, 4), access=Access.READ_WRITE)
# vehicleDetectorDelay (tenths, "0-255.0 sec"; "If a management station attempts to set a value between 2551 and
# 65535, inclusive, the parameter is undefined": such a SET is refused) and vehicleDetectorExtend (tenths, "0-25.5
# sec").
VEHICLE_DETECTOR_DELAY = _o("vehicleDetectorDelay", (2, 2, 1, 6), access=Access.READ_WRITE, high=2550)
VEHICLE_DETECTOR_EXTEND = _o("vehicleDetectorExtend", (2, 2, 1, 7), access=Access.READ_WRITE)
MAX_VEHICLE_DETECTOR_STATUS_GROUPS = _o("maxVehicleDetectorStatusGroups", (2, 3), low=1)
DETECTOR_STATUS_ACTIVE = _o("vehicleDetectorStatusGroupActive", (2, 4, 1, 2))
MAX_VEHICLE_DETECTOR_CONTROL_GROUPS = _o("maxVehicleDetectorControlGroups", (2, 11), low=1, version=Version.V03)
DETECTOR_ACTUATION = _o("vehicleDetectorControlGroupActuation", (2, 12, 1, 2), access=Access.READ_WRITE,
                        version=Version.V03)
# Pedestrian detectors (push buttons) likewise: the table's call phase, the active ones by group of 8, and v03's
# remote actuation (pedestrianDetectorControlGroupActuation, what Signal-Replay SETs to replay a field log's
# pedestrian detector events).
MAX_PED_DETECTORS = _o("maxPedestrianDetectors", (2, 6), low=1)
PED_DETECTOR_CALL_PHASE = _o("pedestrianDetectorCallPhase", (2, 7, 1, 2), access=Access.READ_WRITE)
MAX_PED_DETECTOR_GROUPS = _o("maxPedestrianDetectorGroups", (2, 8), low=1)
PED_DETECTOR_STATUS_ACTIVE = _o("pedestrianDetectorStatusGroupActive", (2, 9, 1, 2))
PED_DETECTOR_ACTUATION = _o("pedestrianDetectorControlGroupActuation", (2, 13, 1, 2), access=Access.READ_WRITE,
                            version=Version.V03)

# The index columns of the tables served (read-only, "the ... number for objects in this row"), each the row's or
# group's number; a column of a table takes its table's edition.
PHASE_NUMBER = _o("phaseNumber", (1, 2, 1, 1), low=1)
PHASE_STATUS_GROUP_NUMBER = _o("phaseStatusGroupNumber", (1, 4, 1, 1), low=1)
PHASE_CONTROL_GROUP_NUMBER = _o("phaseControlGroupNumber", (1, 5, 1, 1), low=1)
VEHICLE_DETECTOR_NUMBER = _o("vehicleDetectorNumber", (2, 2, 1, 1), low=1)
VEHICLE_DETECTOR_STATUS_GROUP_NUMBER = _o("vehicleDetectorStatusGroupNumber", (2, 4, 1, 1), low=1)
PED_DETECTOR_NUMBER = _o("pedestrianDetectorNumber", (2, 7, 1, 1), low=1)
PED_DETECTOR_STATUS_GROUP_NUMBER = _o("pedestrianDetectorStatusGroupNumber", (2, 9, 1, 1), low=1)
VEHICLE_DETECTOR_CONTROL_GROUP_NUMBER = _o("vehicleDetectorControlGroupNumber", (2, 12, 1, 1), low=1,
                                           version=Version.V03)
PED_DETECTOR_CONTROL_GROUP_NUMBER = _o("pedestrianDetectorControlGroupNumber", (2, 13, 1, 1), low=1,
                                       version=Version.V03)
CHANNEL_STATUS_GROUP_NUMBER = _o("channelStatusGroupNumber", (8, 4, 1, 1), low=1)
RING_CONTROL_GROUP_NUMBER = _o("ringControlGroupNumber", (7, 5, 1, 1), low=1)
SEQUENCE_NUMBER = _o("sequenceNumber", (7, 3, 1, 1), low=1)
SEQUENCE_RING_NUMBER = _o("sequenceRingNumber", (7, 3, 1, 2), low=1)
MAX_RINGS = _o("maxRings", (7, 1), low=1)
MAX_SEQUENCES = _o("maxSequences", (7, 2), low=1)

# The channel table (A.8.2): which phase or overlap drives each load switch channel, and how.
MAX_CHANNELS = _o("maxChannels", (8, 1), low=1)
CHANNEL_NUMBER = _o("channelNumber", (8, 2, 1, 1), low=1)
CHANNEL_CONTROL_SOURCE = _o("channelControlSource", (8, 2, 1, 2), access=Access.READ_WRITE)
CHANNEL_CONTROL_TYPE = _o("channelControlType", (8, 2, 1, 3), access=Access.READ_WRITE, low=1, high=5)


class ChannelControlType(IntEnum):
    """channelControlType (A.8.2.1.3), the values v02 and v03 share."""

    OTHER = 1
    PHASE_VEHICLE = 2
    PHASE_PEDESTRIAN = 3
    OVERLAP = 4
    PED_OVERLAP = 5


# The time base action table (A.5.3): per action, the pattern it runs. The config's [[coordination.schedule]]
# entries are its actions, in the order of the day; timebaseAscActionStatus is the action in effect now.
MAX_TIMEBASE_ACTIONS = _o("maxTimebaseAscActions", (5, 2), low=1)
TIMEBASE_ACTION_NUMBER = _o("timebaseAscActionNumber", (5, 3, 1, 1), low=1)
TIMEBASE_PATTERN = _o("timebaseAscPattern", (5, 3, 1, 2), access=Access.READ_WRITE)
TIMEBASE_ACTION_STATUS = _o("timebaseAscActionStatus", (5, 4))

# v03's preempt status (A.6.4-6.6): the preempt being serviced, and the preempt inputs by group of 8 (at most 2).
PREEMPT_STATUS = _o("preemptStatus", (6, 4), version=Version.V03)
MAX_PREEMPT_GROUPS = _o("maxPreemptGroups", (6, 5), high=2, version=Version.V03)
PREEMPT_STATUS_GROUP_NUMBER = _o("preemptStatusGroupNumber", (6, 6, 1, 1), low=1, version=Version.V03)
PREEMPT_STATUS_GROUP = _o("preemptStatusGroup", (6, 6, 1, 2), version=Version.V03)

# v03's ascSpat node (A.16): the time the SPaT data is generated, SPaT enabled (spatOptions bit 0), and the tick
# counter of the hour ("Values equal to or greater than 36000 are reserved").
SPAT_TIMESTAMP = _o("spatTimestamp", (16, 1), Syntax.OCTET_STRING, version=Version.V03)
SPAT_OPTIONS = _o("spatOptions", (16, 4), access=Access.READ_WRITE, version=Version.V03)
ASC_CURRENT_TICK = _o("ascCurrentTick", (16, 6), high=35999, version=Version.V03)

ALL_OBJECTS: tuple[ObjectDef, ...] = (
    MAX_PHASES, MAX_PHASE_GROUPS, UNIT_STARTUP_FLASH, UNIT_BACKUP_TIME, UNIT_CONTROL_STATUS, UNIT_FLASH_STATUS,
    SYSTEM_PATTERN_CONTROL, COORD_CORRECTION_MODE, COORD_FORCE_MODE, MAX_PATTERNS, PATTERN_TABLE_TYPE, MAX_SPLITS,
    COORD_PATTERN_STATUS, LOCAL_FREE_STATUS, COORD_CYCLE_STATUS, COORD_SYNC_STATUS, *PATTERN_TABLE.values(),
    *SPLIT_TABLE.values(), SEQUENCE_DATA, MAX_RING_CONTROL_GROUPS, RING_CONTROL_MAX2, MAX_VEHICLE_DETECTORS,
    VEHICLE_DETECTOR_OPTIONS, VEHICLE_DETECTOR_CALL_PHASE, VEHICLE_DETECTOR_DELAY, VEHICLE_DETECTOR_EXTEND,
    MAX_VEHICLE_DETECTOR_STATUS_GROUPS, DETECTOR_STATUS_ACTIVE,
    MAX_VEHICLE_DETECTOR_CONTROL_GROUPS, DETECTOR_ACTUATION, MAX_PED_DETECTORS,
    PED_DETECTOR_CALL_PHASE, MAX_PED_DETECTOR_GROUPS, PED_DETECTOR_STATUS_ACTIVE, PED_DETECTOR_ACTUATION,
    *PHASE_TABLE.values(), *STATUS_TABLE.values(), *CONTROL_TABLE.values(), MAX_CHANNEL_STATUS_GROUPS,
    *CHANNEL_TABLE.values(),
    MAX_OVERLAPS, MAX_OVERLAP_STATUS_GROUPS, *OVERLAP_TABLE.values(), *OVERLAP_STATUS_TABLE.values(),
    MAX_PREEMPTS, SHORT_ALARM_STATUS, *PREEMPT_TABLE.values(), PREEMPT_CONTROL_NUMBER, PREEMPT_CONTROL_STATE,
    PHASE_NUMBER, PHASE_STATUS_GROUP_NUMBER, PHASE_CONTROL_GROUP_NUMBER, VEHICLE_DETECTOR_NUMBER,
    VEHICLE_DETECTOR_STATUS_GROUP_NUMBER, PED_DETECTOR_NUMBER, PED_DETECTOR_STATUS_GROUP_NUMBER,
    VEHICLE_DETECTOR_CONTROL_GROUP_NUMBER, PED_DETECTOR_CONTROL_GROUP_NUMBER, CHANNEL_STATUS_GROUP_NUMBER,
    RING_CONTROL_GROUP_NUMBER, SEQUENCE_NUMBER, SEQUENCE_RING_NUMBER, MAX_RINGS, MAX_SEQUENCES, MAX_CHANNELS,
    CHANNEL_NUMBER, CHANNEL_CONTROL_SOURCE, CHANNEL_CONTROL_TYPE, MAX_TIMEBASE_ACTIONS, TIMEBASE_ACTION_NUMBER,
    TIMEBASE_PATTERN, TIMEBASE_ACTION_STATUS, PREEMPT_STATUS, MAX_PREEMPT_GROUPS, PREEMPT_STATUS_GROUP_NUMBER,
    PREEMPT_STATUS_GROUP, UNIT_RED_REVERT, COORD_OPERATIONAL_MODE, TIMEBASE_PATTERN_SYNC, SPAT_TIMESTAMP, SPAT_OPTIONS,
    ASC_CURRENT_TICK,
)


def spat_timestamp(tenths: int) -> bytes:
    """spatTimestamp of a time of day in tenths of a second since midnight: "Byte 1: hours (0..23) Byte 2: minutes
    (0..59) Byte 3: seconds (0..60) ... Byte 4-5: milliseconds (0..999)" (NTCIP 1202 v03 5.17.1); the UDP SPaT
    packet's clock has the same five bytes."""
    minutes, tenth = divmod(tenths % 864_000, 600)
    return bytes((minutes // 60, minutes % 60, tenth // 10)) + (tenth % 10 * 100).to_bytes(2, "big")


def phase_oid(column: PhaseColumn, phase: int) -> Oid:
    return PHASE_TABLE[column].instance(phase)


def status_oid(column: StatusColumn, group: int) -> Oid:
    return STATUS_TABLE[column].instance(group)


def control_oid(column: ControlColumn, group: int) -> Oid:
    return CONTROL_TABLE[column].instance(group)


def sequence_oid(sequence: int, ring: int) -> Oid:
    return SEQUENCE_DATA.instance(sequence, ring)


def group_count(max_phase: int) -> int:
    """Number of 8-phase groups needed to hold phases 1..max_phase."""
    return (max_phase + PHASES_PER_GROUP - 1) // PHASES_PER_GROUP


def phases_to_groups(phases: Iterable[int], groups: int) -> tuple[int, ...]:
    """Bitmask per group (group 1 first) for a set of phase numbers."""
    masks = [0] * groups
    for p in phases:
        g, bit = divmod(p - 1, PHASES_PER_GROUP)
        if p < 1 or g >= groups:
            raise ValueError(f"phase {p} does not fit in {groups} phase group(s) (phases 1..{groups * 8})")
        masks[g] |= 1 << bit
    return tuple(masks)


def groups_to_phases(masks: Sequence[int]) -> frozenset[int]:
    """Phase numbers whose bits are set in the group bitmasks (group 1 first)."""
    out = []
    for g, mask in enumerate(masks):
        if not 0 <= mask <= 255:
            raise ValueError(f"group {g + 1} bitmask {mask} is outside 0..255")
        out.extend(PHASES_PER_GROUP * g + k + 1 for k in range(PHASES_PER_GROUP) if mask >> k & 1)
    return frozenset(out)


def oid_str(oid: Oid) -> str:
    return ".".join(map(str, oid))


def parse_oid(text: str) -> Oid:
    try:
        return tuple(int(part) for part in text.strip().lstrip(".").split("."))
    except ValueError:
        raise ValueError(f"not a numeric OID: {text!r}") from None


def object_for(oid: Oid, edition: Version = DEFAULT_VERSION) -> ObjectDef | None:
    """The object type whose prefix the OID extends, as ``edition`` defines it, or None."""
    for obj in ALL_OBJECTS:
        if oid[: len(obj.prefix)] == obj.prefix and len(oid) > len(obj.prefix):
            return obj.in_edition(edition)
    return None


SIGNAL_COLUMNS = (StatusColumn.REDS, StatusColumn.YELLOWS, StatusColumn.GREENS)


OVERLAP_SIGNAL_COLUMNS = (OverlapStatusColumn.REDS, OverlapStatusColumn.YELLOWS, OverlapStatusColumn.GREENS)


def signal_oids(groups: int, overlap_groups: int = 0) -> tuple[Oid, ...]:
    """The OIDs of one signal-state poll: reds, yellows, greens, each for groups 1..n; then, when the
    intersection has overlaps, the overlaps' reds, yellows and greens by overlap status group."""
    return (tuple(status_oid(col, g) for col in SIGNAL_COLUMNS for g in range(1, groups + 1))
            + tuple(OVERLAP_STATUS_TABLE[col].instance(g) for col in OVERLAP_SIGNAL_COLUMNS
                    for g in range(1, overlap_groups + 1)))


def preempt_state_oids(preempts: Iterable[int]) -> tuple[Oid, ...]:
    """preemptState of each of these preempts: what a poll reads after the signal state to see preemption."""
    return tuple(PREEMPT_TABLE[PreemptColumn.STATE].instance(n) for n in preempts)


def preempts_in_service(preempts: Sequence[int], values: Sequence[int]) -> frozenset[int]:
    """The preempts (numbered as read by :func:`preempt_state_oids`) whose preemptState is in service."""
    if len(values) != len(preempts):
        raise ValueError(f"a preempt poll has {len(preempts)} values, got {len(values)}")
    try:
        return frozenset(n for n, v in zip(preempts, values, strict=True) if PreemptState(int(v)).in_service)
    except ValueError:
        raise ValueError(f"preemptState outside 1..9: {list(values)}") from None


@dataclass(frozen=True, slots=True)
class OverlapState:
    """The overlaps (by number, 1 = A) showing red, yellow and green, as read in one poll."""

    reds: frozenset[int]
    yellows: frozenset[int]
    greens: frozenset[int]


@dataclass(frozen=True, slots=True)
class SignalState:
    """The phases showing red, yellow and green, as read in one poll; the overlaps' when the poll read them."""

    reds: frozenset[int]
    yellows: frozenset[int]
    greens: frozenset[int]
    overlaps: OverlapState | None = None

    @classmethod
    def from_values(cls, values: Sequence[int], groups: int, overlap_groups: int = 0) -> SignalState:
        """Decode the values of a poll of :func:`signal_oids` (same order)."""
        if len(values) != 3 * (groups + overlap_groups):
            raise ValueError(f"a signal poll has {3 * (groups + overlap_groups)} values, got {len(values)}")
        phases = [groups_to_phases(values[i * groups:(i + 1) * groups]) for i in range(3)]
        if not overlap_groups:
            return cls(*phases)
        rest = values[3 * groups:]
        overlaps = OverlapState(*(groups_to_phases(rest[i * overlap_groups:(i + 1) * overlap_groups])
                                  for i in range(3)))
        return cls(*phases, overlaps)

    def indication(self, phase: int) -> str:
        """'G', 'Y' or 'r' for one phase (SUMO's letters)."""
        return "G" if phase in self.greens else "Y" if phase in self.yellows else "r"


@dataclass(frozen=True, slots=True)
class Latency:
    """Modeled response time of a request: mean and uniform jitter, in seconds."""

    mean: float = 0.0075
    jitter: float = 0.0

    def draw(self, rng: random.Random) -> float:
        if self.jitter <= 0.0:
            return self.mean
        return max(0.0, self.mean + rng.uniform(-self.jitter, self.jitter))
