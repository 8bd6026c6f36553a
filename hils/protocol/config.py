"""Intersection configuration: phases, ring-and-barrier structure, middleware parameters.

Loaded from TOML and validated as a whole; every error names the file, the
field and what is allowed. The paper's four-leg intersection ships as package
data (``hils/data/four_leg.toml``) and is the default everywhere.

Times are given in seconds. Minimum and maximum green are whole seconds and
clearance times are tenths of a second, as NTCIP 1202 stores them; the
controller counts integer tenths internally. Every time the controller serves
from its MIB must fit the range of the NTCIP 1202 object that carries it (a
yellow change of 3.0-25.5 s, say): what a GET answers, a SET takes back.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import date, datetime
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Any

from hils.protocol.conflict import Permissives, first_conflict
from hils.protocol.errors import UserError
from hils.protocol.ntcip import (
    DEFAULT_VERSION,
    OVERLAP_TABLE,
    PHASE_TABLE,
    PREEMPT_TABLE,
    UNIT_BACKUP_TIME,
    UNIT_STARTUP_FLASH,
    VEHICLE_DETECTOR_DELAY,
    VEHICLE_DETECTOR_EXTEND,
    ObjectDef,
    OverlapColumn,
    PhaseColumn,
    PhaseStartup,
    PreemptColumn,
    SplitMode,
    Version,
    group_count,
    overlap_letter,
)

Pair = tuple[int, int]

#: The NTCIP 1202 object a config time is carried in, and its units per second (1: seconds, 10: tenths). A time the
#: object cannot hold would be answered by a GET as a value that a SET of the same object refuses: the config refuses
#: it first, naming the object's range (its SYNTAX in the MIB, or NEMA TS 2's narrower range where the MIB's
#: description gives one, as phaseYellowChange's "NEMA TS 2 range: 3-25.5 sec").
Carrier = tuple[ObjectDef, int]

DEFAULT_CONFIG_NAME = "four_leg.toml"

_STARTUP_NAMES = {
    "off": PhaseStartup.PHASE_NOT_ON,
    "green": PhaseStartup.GREEN_NO_WALK,
    "yellow": PhaseStartup.YELLOW_CHANGE,
    "red_clear": PhaseStartup.RED_CLEAR,
}
APPROACHES = ("north", "south", "east", "west")
#: The emulator's local date and time at power-up in virtual time, unless ``[emulator] start`` says otherwise.
DEFAULT_START = datetime(2024, 1, 1)


class Recall(StrEnum):
    """A phase's recall (NTCIP 1202 phaseOptions bits 6-9)."""

    NONE = "none"
    MIN = "min"    # a vehicle call whenever the phase is not green; extension only by real calls
    MAX = "max"    # a vehicle call that also extends the green to its maximum
    PED = "ped"    # a pedestrian call whenever the phase is not green
    SOFT = "soft"  # a vehicle call only while no other phase has demand


class NextPhaseLock(StrEnum):
    """Until when a call may still change a ring's committed next phase (``timing.next_phase_lock``).

    NTCIP 1202 phaseStatusGroupPhaseNexts: the next phase "shall be determined at the end of the green
    interval of the terminating phase"; controllers make the lock a setting (SUMO issue 9989, from an
    Econolite test bench: detector lock "a choice between the start of yellow or the start of red")."""

    GREEN_END = "green_end"  # committed when the green ends; calls during the clearance wait
    RED_END = "red_end"      # a call during the clearance may still redirect it on the same side of the barrier


#: What a config numbers: phases (NTCIP 1202 maxPhases, 1-255), vehicle detectors (1-128: the emulator's
#: maxVehicleDetectors, which NTCIP lets be 1-255), push buttons (maxPedestrianDetectors: 1-255), overlaps (A-P, NTCIP's
#: 1-16), and a pattern's cycle (patternCycleTime: "NEMA TS 2 range: 30-255").
PHASE_NUMBERS = range(1, 256)
DETECTOR_NUMBERS = range(1, 129)
PED_DETECTOR_NUMBERS = range(1, 256)
OVERLAP_NUMBERS = range(1, 17)
CYCLE_SECONDS = range(30, 256)

#: Each phase time of the config, and the phase-table object that carries it (NTCIP 1202 phaseTable).
_PHASE_OBJECTS: dict[str, Carrier] = {
    "min_green": (PHASE_TABLE[PhaseColumn.MINIMUM_GREEN], 1),
    "max_green": (PHASE_TABLE[PhaseColumn.MAXIMUM1], 1),
    "max2": (PHASE_TABLE[PhaseColumn.MAXIMUM2], 1),
    "passage": (PHASE_TABLE[PhaseColumn.PASSAGE], 10),
    "walk": (PHASE_TABLE[PhaseColumn.WALK], 1),
    "ped_clear": (PHASE_TABLE[PhaseColumn.PEDESTRIAN_CLEAR], 1),
    "yellow": (PHASE_TABLE[PhaseColumn.YELLOW_CHANGE], 10),
    "red_clear": (PHASE_TABLE[PhaseColumn.RED_CLEAR], 10),
    "red_revert": (PHASE_TABLE[PhaseColumn.RED_REVERT], 10),
    "time_before_reduction": (PHASE_TABLE[PhaseColumn.TIME_BEFORE_REDUCTION], 1),
    "time_to_reduce": (PHASE_TABLE[PhaseColumn.TIME_TO_REDUCE], 1),
    "min_gap": (PHASE_TABLE[PhaseColumn.MINIMUM_GAP], 10),
}
# Per-phase timings and options a phase may set itself or inherit from [timing].
_PHASE_OPTIONS = ("min_green", "max_green", "max2", "passage", "walk", "ped_clear", "yellow", "red_clear",
                  "red_revert", "time_before_reduction", "time_to_reduce", "min_gap", "recall", "dual_entry",
                  "backup_prevent", "conditional_service", "simultaneous_gap_disable", "ped_recycle")
TURNS = ("left", "through")
FREE = 254  # NTCIP's pattern number of free operation (systemPatternControl, coordPatternStatus)


class ForceOff(StrEnum):
    """coordForceMode (NTCIP 1202): where a non-coordinated phase is forced off."""

    FLOATING = "floating"  # "forced to limit its time to the split time value": unused time reverts to the coord phase
    FIXED = "fixed"        # "forced at a fixed position in the cycle": unused time reverts to the following phase


class OffsetReference(StrEnum):
    """The point of the coordinated phase that the local cycle's zero (and so the offset) refers to."""

    LEAD_GREEN = "lead_green"  # start of the first coordinated phase's green (NEMA TS 2)
    YELLOW = "yellow"          # start of the first coordinated phase's yellow (as 170 controllers count)


class Correction(StrEnum):
    """coordCorrectionMode (NTCIP 1202): how a new offset is reached."""

    SHORTWAY = "shortway"  # "adding or subtracting to/from the timings in a manner that limits the cycle change"
    DWELL = "dwell"        # "dwelling in the coord phase(s) until the desired offset is reached"
    ADD = "add"            # "adding to the timings in a manner that limits the cycle change"


@dataclass(frozen=True, slots=True)
class Pattern:
    """One coordination pattern: cycle, offset, coordinated phases and a split per phase, all in seconds."""

    number: int
    cycle: int
    offset: int
    coord_phases: tuple[int, ...]
    splits: Mapping[int, int]  # each including the phase's yellow and red clearance
    modes: Mapping[int, SplitMode] = field(default_factory=dict)  # splitMode of a phase, none where absent

    @property
    def pretimed(self) -> bool:
        """Every phase on maximum recall: the pattern runs as a fixed-time plan, whatever the detectors say."""
        return all(self.modes.get(p) is SplitMode.MAX_RECALL for p in self.splits)


@dataclass(frozen=True, slots=True)
class ScheduleEntry:
    """From a time of day (seconds after midnight), run a pattern (or :data:`FREE`)."""

    start: int
    pattern: int


@dataclass(frozen=True)
class Coordination:
    """The ``[coordination]`` section: the timing plans a city programs, and which runs when."""

    pattern: int = FREE  # in effect at power-up (until the schedule changes it)
    force_off: ForceOff = ForceOff.FIXED
    offset_reference: OffsetReference = OffsetReference.LEAD_GREEN
    correction: Correction = Correction.SHORTWAY
    patterns: Mapping[int, Pattern] = field(default_factory=dict)
    schedule: tuple[ScheduleEntry, ...] = ()
    unplanned: str = ""  # why a config derived from a signal program has no pattern (said where a plan is needed)

    def planned(self) -> Coordination:
        """A copy that runs its plan from power-up: the schedule's pattern of midnight, or else the lowest-numbered
        pattern, when free was the power-up pattern (what ``--agent coordinated`` runs)."""
        if self.pattern != FREE or not self.patterns:
            return self
        at_midnight = self.schedule[-1].pattern if self.schedule else min(self.patterns)
        return replace(self, pattern=at_midnight if at_midnight != FREE else min(self.patterns))

    def pretimed(self) -> Coordination:
        """:meth:`planned`, every phase of every pattern on maximum recall (splitMode maxRecall): each phase runs
        its whole split whatever its detectors say, the controller's own pretimed operation (``--agent fixed-time``)."""
        return replace(self.planned(), patterns={n: replace(p, modes=dict.fromkeys(p.splits, SplitMode.MAX_RECALL))
                                                 for n, p in self.patterns.items()})


class OverlapKind(StrEnum):
    """An overlap's type (NTCIP 1202 overlapType; ``fya`` is a vendor type there, other(1))."""

    NORMAL = "normal"                          # green with its included phases (and while they cycle among them)
    MINUS_GREEN_YELLOW = "minus_green_yellow"  # as normal, but not while a modifier phase is green
    FYA = "fya"  # a flashing yellow arrow: green arrow with its protected (included) phases, flashing yellow while a
    # modifier (the opposing through, the movement it yields to) is green
    TRANSIT = "transit"  # NTCIP 1202 v03 transit-2: a 2-section bar, green, flashing green, red: never yellow


OVERLAP_TURNS = ("left", "right")


@dataclass(frozen=True, slots=True)
class DetectorTiming:
    """A vehicle detector's timers, in seconds (all 0: the actuation is the call, as it comes and goes).

    NTCIP 1202 vehicleDetectorDelay: "The period a detector actuation (input recognition) shall be delayed when the
    phase is not Green"; vehicleDetectorExtend: "The period a vehicle detector actuation (input duration) shall be
    extended from the point of termination, when the phase is Green". Carryover has no NTCIP object: it is the
    detector unit's own output extension, "the time following the loss of detection before the Detect Output is
    dropped" whatever the phase shows (RAE H2 loop detector manual, "Detect Output Extension"); a controller's
    detector table carries it beside delay and extend. ``lock``: vehicleDetectorOptions bit 2, "Yellow Lock Call - if
    Enabled, the detector will lock a call to the assigned phase if an actuation occurs while the phase is not timing
    Green" (held until the phase is green)."""

    delay: float = 0.0
    extend: float = 0.0
    carryover: float = 0.0
    lock: bool = False


@dataclass(frozen=True, slots=True)
class Overlap:
    """One row of the overlap table: a signal output driven by its included (parent) phases.

    ``approach`` and ``turn`` name the movement it shows in SUMO (a right turn, or an FYA's left): those links
    follow the overlap instead of the phase of their approach."""

    number: int  # 1 = Overlap A
    kind: OverlapKind
    included: tuple[int, ...]
    modifiers: tuple[int, ...] = ()
    trail_green: int = 0       # s the green goes on after its included phases end (0: it clears with them)
    trail_yellow: float = 3.0  # s of the overlap's own yellow after a trailing green
    trail_red: float = 0.0     # s of the overlap's own red clearance after a trailing green
    approach: str | None = None
    turn: str | None = None
    delay_green: float = 0.0   # s the overlap stays red after an included phase's green starts (a delayed green)

    @property
    def letter(self) -> str:
        return overlap_letter(self.number)


@dataclass(frozen=True, slots=True)
class Preempt:
    """One row of the preempt table (NTCIP 1202 preemptTable): what a preempt input makes the controller do.

    Times in seconds. The entry values cap what a preempt-initiated transition honours of the phase being
    ended ("the lesser of the phase's ... or this period"); their defaults honour the phase's own times. With
    ``vehicles`` and ``approach`` SUMO calls it while a vehicle of one of those classes or types is within
    ``zone`` m of the approach's stop bar."""

    number: int  # lower numbers override higher ones
    dwell_phases: tuple[int, ...] = ()
    track_phases: tuple[int, ...] = ()
    exit_phases: tuple[int, ...] = ()
    # preemptCyclingPhase: phases "allowed to cycle during the Preempt Dwell interval", after the dwell phases
    cycling_phases: tuple[int, ...] = ()
    delay: int = 0
    min_duration: int = 0
    min_green: int = 255
    min_walk: int = 255
    enter_ped_clear: int = 255
    enter_yellow: float = 25.5
    enter_red: float = 25.5
    track_green: int = 0
    track_yellow: float = 25.5
    track_red: float = 25.5
    dwell_green: int = 1
    max_presence: int = 0  # 0: no limit
    non_locking: bool = False  # preemptControl bit 0: a call that goes before its delay ends is forgotten
    vehicles: tuple[str, ...] = ()
    approach: str | None = None
    zone: float = 100.0


# Options of the whole controller unit that [timing] holds beside the phase defaults.
_UNIT_OPTIONS = ("startup_flash", "next_phase_lock")


class ConfigError(UserError, ValueError):
    """A configuration that cannot be used; says where and what is allowed."""

    def __init__(self, source: str, field_name: str, message: str) -> None:
        super().__init__(f"{source}: {field_name}: {message}")
        self.source = source
        self.field = field_name
        self.message = message


@dataclass(frozen=True, slots=True)
class Phase:
    number: int
    ring: int
    min_green: float
    max_green: float
    yellow: float
    red_clear: float
    startup: PhaseStartup = PhaseStartup.PHASE_NOT_ON
    approach: str | None = None
    turn: str | None = None
    passage: float = 0.0          # s the green extends after its vehicle call drops (0: gap out at once)
    max2: float | None = None     # Maximum 2 (s), chosen per ring by ringControlGroupMax2; None = max_green
    walk: float = 0.0             # s of Walk when a pedestrian call is served (0: no pedestrian service)
    ped_clear: float = 0.0        # s of pedestrian clearance (flashing Don't Walk) after the walk
    red_revert: float = 0.0       # s of red at least between this phase's yellow and its next green
    recall: Recall = Recall.NONE
    dual_entry: bool = False      # served with the other ring's entry into its barrier group
    # its ring may not back from it into an earlier phase of its group while nothing is called across the barrier
    # (false: Naztec's default, TecNote 3013); conditional service may still back it (see emulator/model/sequencer.py)
    backup_prevent: bool = True
    # NTCIP 1202 phaseOptions bit 14: once gapped or maxed out it may back into an earlier phase of its group while
    # the other ring's green has time left before its maximum for the clearance and that phase's minimum
    conditional_service: bool = False
    # gapped out and waiting (at the barrier, for the other ring), a call coming back does not extend it again
    simultaneous_gap_disable: bool = True
    # a pedestrian call during its green starts a walk within that green (pedestrian recycle)
    ped_recycle: bool = False
    # Turns of the same approach that run permissive (yielding) while this phase is green,
    # e.g. the lefts of a four-phase plan without protected lefts.
    permissive: tuple[str, ...] = ()
    # Gap reduction (volume density, NTCIP 1202 phaseTimeBeforeReduction, phaseTimeToReduce, phaseMinimumGap): after
    # time_before_reduction s of serviceable conflicting demand the allowable gap falls linearly from the passage to
    # min_gap over time_to_reduce s. None: no reduction (the allowable gap stays the passage).
    time_before_reduction: float = 0.0
    time_to_reduce: float = 0.0
    min_gap: float | None = None

    @property
    def maximum2(self) -> float:
        return self.max_green if self.max2 is None else self.max2

    @property
    def clearance(self) -> float:
        """Yellow change plus red clearance, in seconds."""
        return self.yellow + self.red_clear


@dataclass(frozen=True, slots=True)
class MiddlewareParams:
    """The paper's middleware parameters (section "HILS Setup")."""

    poll_hz: float = 10.0
    sumo_step: float = 0.25
    tau_udp: float = 1.0
    tau_trans: float = 10.0
    n_timeout: int = 5
    n_drift: int = 5
    control_interval: float = 10.0
    backup_time: int = 30

    @property
    def poll_period(self) -> float:
        return 1.0 / self.poll_hz

    @property
    def keepalive_period(self) -> float | None:
        """How often the current call is SET again: well inside the backup time (None: no backup time)."""
        return self.backup_time / 3.0 if self.backup_time else None


@dataclass(frozen=True, slots=True)
class EmulatorParams:
    """How the emulator models a real controller (``[emulator]``): its own latency, in 0.1 s ticks, and the
    local date and time of its clock at power-up in virtual time (its hi-res log's timestamps, the time of day
    its coordination and schedule follow; ``hils emulator serve`` sets the clock to the host's time instead).

    A real controller has these delays without any table: they only tell the emulator how late to be.
    The defaults are calibrated on the paper's Cobalt (see :mod:`emulator.model.delays`). ``ntcip`` is the edition
    of NTCIP 1202 its SNMP objects follow (v02 by default, what the paper's Cobalt speaks)."""

    call_processing_ticks: int = 1  # a SET reaches the phase logic this many ticks after the next tick
    status_update_ticks: int = 0  # status objects lag the lamps by this many ticks
    start: datetime = DEFAULT_START
    ntcip: Version = DEFAULT_VERSION


@dataclass(frozen=True)
class IntersectionConfig:
    name: str
    phases: Mapping[int, Phase]
    rings: tuple[tuple[int, ...], ...]
    barriers: tuple[frozenset[int], ...]
    sequence: tuple[Pair, ...]
    pairs: tuple[Pair, ...]
    compatibility: frozenset[frozenset[int]]
    middleware: MiddlewareParams = field(default_factory=MiddlewareParams)
    source: str = "<memory>"
    startup_flash: int = 0  # s of start-up flash after power-up (unitStartUpFlash)
    next_phase_lock: NextPhaseLock = NextPhaseLock.GREEN_END
    coordination: Coordination = field(default_factory=Coordination)
    emulator: EmulatorParams = field(default_factory=EmulatorParams)
    detector_phases: Mapping[int, int] = field(default_factory=dict)  # the [detectors] table, if any
    detector_lanes: Mapping[int, str] = field(default_factory=dict)  # the SUMO lane of a detector given one
    detector_timing: Mapping[int, DetectorTiming] = field(default_factory=dict)  # a detector given any timer
    ped_detector_phases: Mapping[int, int] = field(default_factory=dict)  # the [pedestrian_detectors] table, if any
    overlaps: Mapping[int, Overlap] = field(default_factory=dict)  # by overlap number (1 = A)
    preempts: Mapping[int, Preempt] = field(default_factory=dict)  # by preempt number
    #: What may be lit together, for :mod:`hils.protocol.conflict`'s one check: the compatibility matrix, and per
    #: overlap the phases :meth:`overlap_allows` refuses. Worked out as the config is made (a copy too), and held
    #: as a field: caching it in the instance's ``__dict__`` later slowed every read of the config by the
    #: controller's tick (1.4 % of a controller-hour's instructions).
    permissives: Permissives = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        conflicting = {n: frozenset(p for p in self.phases if not self.overlap_allows(n, p)) for n in self.overlaps}
        object.__setattr__(self, "permissives", Permissives(self.compatibility, conflicting))

    @property
    def detectors(self) -> dict[int, int]:
        """Vehicle detector number -> the phase it calls (``vehicleDetectorCallPhase``): the ``[detectors]``
        table, or one detector per phase numbered as the phase (the stop-bar loops of a phase's approach lanes
        wired to one input, as in many cabinets)."""
        return dict(self.detector_phases) or {p: p for p in self.phases}

    @property
    def ped_detectors(self) -> dict[int, int]:
        """Pedestrian detector (push button) number -> the phase it calls (``pedestrianDetectorCallPhase``): the
        ``[pedestrian_detectors]`` table, or one per phase numbered as the phase."""
        return dict(self.ped_detector_phases) or {p: p for p in self.phases}

    @property
    def groups(self) -> int:
        """Number of NTCIP phase groups (8 phases each) this intersection needs."""
        return group_count(max(self.phases))

    @property
    def overlap_groups(self) -> int:
        """Number of NTCIP overlap status groups (8 overlaps each) this intersection needs (0 without overlaps)."""
        return group_count(max(self.overlaps, default=0))

    def overlap_allows(self, overlap: int, phase: int) -> bool:
        """True when ``phase`` may show green or yellow beside the overlap's green or yellow: it is one of the
        overlap's included phases (or, for a flashing yellow arrow, its permissive modifiers) or runs beside one
        of them. Phases outside that set conflict with it (what the conflict monitor checks, and what waits for a
        trailing overlap to clear)."""
        o = self.overlaps[overlap]
        parents = o.included + (o.modifiers if o.kind is OverlapKind.FYA else ())
        return any(phase == q or self.compatible(phase, q) for q in parents)

    @property
    def phase_numbers(self) -> tuple[int, ...]:
        return tuple(sorted(self.phases))

    def compatible(self, a: int, b: int) -> bool:
        """True when phases a and b may show green together."""
        return frozenset((a, b)) in self.compatibility

    def ring_of(self, phase: int) -> int:
        return self.phases[phase].ring

    def barrier_of(self, phase: int) -> int:
        """Index (0-based) of the barrier group holding the phase."""
        return next(i for i, group in enumerate(self.barriers) if phase in group)

    def with_middleware(self, **changes: Any) -> IntersectionConfig:
        """A copy with some middleware parameters replaced (validated)."""
        raw = {f: getattr(self.middleware, f) for f in MiddlewareParams.__dataclass_fields__} | changes
        params = _middleware(raw, self.source)
        return replace(self, middleware=params)


    def planned(self) -> IntersectionConfig:
        """A copy whose controller runs its coordination plan from power-up (see :meth:`Coordination.planned`)."""
        return replace(self, coordination=self.coordination.planned())

    def pretimed(self) -> IntersectionConfig:
        """A copy whose controller runs its coordination plan pretimed from power-up (:meth:`Coordination.pretimed`)."""
        return replace(self, coordination=self.coordination.pretimed())

    def with_offset(self, seconds: int) -> IntersectionConfig:
        """A copy whose patterns all have this offset (modulo each cycle): one intersection's place in a
        corridor's progression, given by its scenario."""
        c = self.coordination
        patterns = {n: replace(p, offset=seconds % p.cycle) for n, p in c.patterns.items()}
        return replace(self, coordination=replace(c, patterns=patterns))


def load(path: str | Path | None = None) -> IntersectionConfig:
    """Load and validate a TOML config; the shipped four-leg intersection when path is None."""
    if path is None:
        ref = resources.files("hils.data") / DEFAULT_CONFIG_NAME
        return parse(ref.read_text(encoding="utf-8"), f"hils/data/{DEFAULT_CONFIG_NAME}")
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), "<file>", f"cannot be read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(str(p), "<file>", "is not UTF-8 text; allowed: a TOML file") from None
    return parse(text, str(p))


def parse(text: str, source: str = "<memory>") -> IntersectionConfig:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "<file>", f"is not valid TOML ({exc})") from None
    return from_dict(raw, source)


# --- validation helpers -------------------------------------------------------------


def _unknown(raw: Mapping[str, Any], allowed: tuple[str, ...], where: str, source: str) -> None:
    for key in raw:
        if key not in allowed:
            raise ConfigError(source, f"{where}{key}", f"unknown field; allowed: {', '.join(allowed)}")


def phase_time_range(key: str) -> tuple[float, float]:
    """The least and the most a phase time (``yellow``, ``min_green``, ...) may be, in the config's unit (seconds),
    as the NTCIP 1202 object that carries it can hold it."""
    return _carried(_PHASE_OBJECTS[key])


def _carried(carrier: Carrier) -> tuple[float, float]:
    obj, per_second = carrier
    return (obj.low, obj.high) if per_second == 1 else (obj.low / per_second, obj.high / per_second)


def _number(raw: Mapping[str, Any], key: str, where: str, source: str, default: Any = None, *,
            integer: bool = False, low: float | None = None, low_open: bool = False,
            high: float | None = None, step: float | None = None, ntcip: Carrier | None = None) -> Any:
    name = f"{where}{key}"
    value = raw.get(key, default)
    if value is None:
        raise ConfigError(source, name, "is required")
    kinds = (int,) if integer else (int, float)
    bad_type = isinstance(value, bool) or not isinstance(value, kinds)
    if bad_type or (isinstance(value, float) and not math.isfinite(value)):
        raise ConfigError(source, name, f"must be {'an integer' if integer else 'a finite number'}, got {value!r}")
    carried = ""
    if ntcip is not None:
        obj, per_second = ntcip
        lowest, highest = _carried(ntcip)
        if low is None or lowest > low:
            low, low_open = lowest, False
        high = highest if high is None else min(high, highest)
        carried = (f" s (NTCIP 1202 {obj.name}: {obj.low}-{obj.high} "
                   f"{'seconds' if per_second == 1 else 'tenths of a second'})")
    too_low = low is not None and (value <= low if low_open else value < low)
    if too_low or (high is not None and value > high):
        lo = "" if low is None else f"{'>' if low_open else '>='} {low}"
        hi = "" if high is None else f"<= {high}"
        raise ConfigError(source, name, f"is {value}; allowed: {' and '.join(x for x in (lo, hi) if x)}{carried}")
    if step is not None and abs(round(value / step) * step - value) > 1e-9:
        raise ConfigError(source, name, f"is {value}; allowed: multiples of {step} s")
    return value


def _int_list(value: Any, name: str, source: str) -> list[int]:
    if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        raise ConfigError(source, name, f"must be a list of phase numbers, got {value!r}")
    return value


def _middleware(raw: Mapping[str, Any], source: str) -> MiddlewareParams:
    d = MiddlewareParams()
    w = "middleware."
    _unknown(raw, tuple(MiddlewareParams.__dataclass_fields__), w, source)
    return MiddlewareParams(
        poll_hz=float(_number(raw, "poll_hz", w, source, d.poll_hz, low=0, low_open=True, high=1000)),
        sumo_step=float(_number(raw, "sumo_step", w, source, d.sumo_step, low=0, low_open=True, high=10)),
        tau_udp=float(_number(raw, "tau_udp", w, source, d.tau_udp, low=0, low_open=True, high=60)),
        tau_trans=float(_number(raw, "tau_trans", w, source, d.tau_trans, low=0, low_open=True, high=600)),
        n_timeout=_number(raw, "n_timeout", w, source, d.n_timeout, integer=True, low=1, high=1000),
        n_drift=_number(raw, "n_drift", w, source, d.n_drift, integer=True, low=1, high=1000),
        control_interval=float(_number(raw, "control_interval", w, source, d.control_interval,
                                       low=0, low_open=True, high=3600)),
        backup_time=_number(raw, "backup_time", w, source, d.backup_time, integer=True, ntcip=(UNIT_BACKUP_TIME, 1)),
    )


def _emulator(raw: Any, source: str) -> EmulatorParams:
    if not isinstance(raw, dict):
        raise ConfigError(source, "emulator", "must be a table of emulator parameters")
    d = EmulatorParams()
    w = "emulator."
    _unknown(raw, tuple(EmulatorParams.__dataclass_fields__), w, source)
    # Beyond 10 ticks (1 s) a controller is broken rather than slow.
    return EmulatorParams(
        call_processing_ticks=_number(raw, "call_processing_ticks", w, source, d.call_processing_ticks,
                                      integer=True, low=0, high=10),
        status_update_ticks=_number(raw, "status_update_ticks", w, source, d.status_update_ticks,
                                    integer=True, low=0, high=10),
        start=_start(raw.get("start", d.start), source),
        ntcip=_edition(raw.get("ntcip", d.ntcip.value), source),
    )


def _edition(value: Any, source: str) -> Version:
    """``[emulator] ntcip``: the edition of NTCIP 1202 served."""
    try:
        return Version(value)
    except (ValueError, TypeError):
        raise ConfigError(source, "emulator.ntcip", f"is {value!r}; allowed: "
                                                    f"{', '.join(repr(v.value) for v in Version)}") from None


def _start(value: Any, source: str) -> datetime:
    """``[emulator] start``: a TOML local date-time (or a date: its midnight) on the controller's 0.1 s grid."""
    allowed = "allowed: a local date and time without offset, e.g. 2024-04-15T07:00:00, or a date"
    if isinstance(value, date) and not isinstance(value, datetime):
        value = datetime.combine(value, datetime.min.time())
    if not isinstance(value, datetime):
        raise ConfigError(source, "emulator.start", f"is {value!r}; {allowed}")
    if value.tzinfo is not None:
        raise ConfigError(source, "emulator.start", f"is {value.isoformat()}, with an offset: the controller keeps "
                                                    f"local time; {allowed}")
    if value.microsecond % 100_000:
        raise ConfigError(source, "emulator.start", f"is {value.isoformat()}; allowed: whole tenths of a second")
    return value


def _phase(number: int, raw: Any, defaults: Mapping[str, Any], ring: int, source: str) -> Phase:
    w = f"phases.{number}."
    if not isinstance(raw, dict):
        raise ConfigError(source, f"phases.{number}", "must be a table of phase settings")
    _unknown(raw, (*_PHASE_OPTIONS, "startup", "approach", "turn", "permissive"), w, source)
    merged = {**defaults, **raw}

    def where(key: str) -> str:
        # A bad value inherited from [timing] is reported where the user wrote it.
        return w if key in raw or key not in defaults else "timing."

    def timing(key: str, default: Any = None, **limits: Any) -> Any:
        return _number(merged, key, where(key), source, default, ntcip=_PHASE_OBJECTS[key], **limits)

    min_green = timing("min_green", integer=True, low=1)
    max_green = timing("max_green", integer=True, low=1)
    if max_green < min_green:
        blame = w if "min_green" in raw else where("max_green")
        raise ConfigError(source, f"{blame}max_green",
                          f"is {max_green} s, below min_green {min_green} s; allowed: max_green >= min_green")
    yellow = timing("yellow", step=0.1)
    red_clear = timing("red_clear", low=0, low_open=True, step=0.1)
    startup = merged.get("startup", "off")
    if not isinstance(startup, str) or startup not in _STARTUP_NAMES:
        raise ConfigError(source, f"{w}startup", f"is {startup!r}; allowed: {', '.join(_STARTUP_NAMES)}")
    passage = timing("passage", 0, step=0.1)
    walk = timing("walk", 0, integer=True)
    ped_clear = timing("ped_clear", 0, integer=True)
    red_revert = timing("red_revert", 0, step=0.1)
    before_reduction = timing("time_before_reduction", 0, integer=True)
    to_reduce = timing("time_to_reduce", 0, integer=True)
    min_gap = merged.get("min_gap")
    if min_gap is not None:
        min_gap = timing("min_gap", step=0.1)
        if min_gap > passage:
            raise ConfigError(source, f"{where('min_gap')}min_gap", f"is {min_gap} s, beyond passage {passage} s; "
                              "allowed: min_gap <= passage (the allowable gap is reduced from the passage to it)")
    max2 = merged.get("max2")
    if max2 is not None:
        max2 = timing("max2", integer=True, low=min_green)
    if passage > max_green:
        raise ConfigError(source, f"{where('passage')}passage",
                          f"is {passage} s, beyond max_green {max_green} s; allowed: passage <= max_green")
    if (walk == 0) != (ped_clear == 0):
        raise ConfigError(source, f"{where('walk')}walk", f"walk {walk} s with ped_clear {ped_clear} s; allowed: "
                          "both 0 (no pedestrian service) or both > 0")
    if walk + ped_clear > max_green:
        raise ConfigError(source, f"{where('walk')}walk",
                          f"walk + ped_clear = {walk + ped_clear} s, beyond max_green {max_green} s; "
                          "allowed: walk + ped_clear <= max_green")
    recall = merged.get("recall", "none")
    if recall not in tuple(Recall):
        raise ConfigError(source, f"{where('recall')}recall",
                          f"is {recall!r}; allowed: {', '.join(r.value for r in Recall)}")
    if recall == Recall.PED and walk == 0:
        raise ConfigError(source, f"{where('recall')}recall", "is 'ped' on a phase without walk; allowed: a walk > 0 "
                          "for ped recall")
    flags = {}
    for key, default in (("dual_entry", False), ("backup_prevent", True), ("conditional_service", False),
                         ("simultaneous_gap_disable", True), ("ped_recycle", False)):
        flags[key] = merged.get(key, default)
        if not isinstance(flags[key], bool):
            raise ConfigError(source, f"{where(key)}{key}", f"is {flags[key]!r}; allowed: true, false")
    if raw.get("ped_recycle") and walk == 0:  # set in [timing], it acts on the phases with a walk
        raise ConfigError(source, f"{w}ped_recycle", "is true on a phase without walk; allowed: a walk > 0 for "
                          "pedestrian recycle")
    approach, turn = raw.get("approach"), raw.get("turn")
    if approach is not None and approach not in APPROACHES:
        raise ConfigError(source, f"{w}approach", f"is {approach!r}; allowed: {', '.join(APPROACHES)}")
    if turn is not None and turn not in TURNS:
        raise ConfigError(source, f"{w}turn", f"is {turn!r}; allowed: {', '.join(TURNS)}")
    permissive = raw.get("permissive", [])
    if not isinstance(permissive, list) or any(t not in TURNS or t == turn for t in permissive):
        raise ConfigError(source, f"{w}permissive", f"is {permissive!r}; allowed: a list of turns other than the "
                          f"phase's own turn, from {', '.join(TURNS)}")
    return Phase(number, ring, float(min_green), float(max_green), float(yellow), float(red_clear),
                 _STARTUP_NAMES[startup], approach, turn, float(passage), None if max2 is None else float(max2),
                 float(walk), float(ped_clear), float(red_revert), Recall(recall), flags["dual_entry"],
                 flags["backup_prevent"], flags["conditional_service"], flags["simultaneous_gap_disable"],
                 flags["ped_recycle"], tuple(permissive),
                 float(before_reduction), float(to_reduce), None if min_gap is None else float(min_gap))


def _pairs(raw: Any, name: str, phases: Mapping[int, Phase], permissives: Permissives,
           source: str) -> tuple[Pair, ...]:
    if not isinstance(raw, list) or not raw:
        raise ConfigError(source, name, "must be a non-empty list of [ring 1 phase, ring 2 phase] pairs")
    out = []
    for i, item in enumerate(raw):
        pair = _int_list(item, f"{name}[{i}]", source)
        if len(pair) != 2:
            raise ConfigError(source, f"{name}[{i}]", f"is {pair}; allowed: exactly two phases, one per ring")
        for p in pair:
            if p not in phases:
                raise ConfigError(source, f"{name}[{i}]", f"unknown phase {p}; allowed: {sorted(phases)}")
        a, b = pair
        if phases[a].ring != 1 or phases[b].ring != 2:
            raise ConfigError(source, f"{name}[{i}]",
                              f"is {pair}; allowed: a ring 1 phase first, then a ring 2 phase")
        if first_conflict(permissives, pair) is not None:
            raise ConfigError(source, f"{name}[{i}]", f"phases {a} and {b} conflict; allowed: compatible pairs")
        out.append((a, b))
    return tuple(out)


def _matrix(raw: Mapping[str, Any], numbers: list[int], source: str) -> frozenset[frozenset[int]] | None:
    given = [k for k in ("compatibility", "conflict") if k in raw]
    if not given:
        return None
    if len(given) == 2:
        raise ConfigError(source, "structure.conflict", "give either compatibility or conflict, not both")
    key = given[0]
    rows = raw[key]
    n = len(numbers)
    if (not isinstance(rows, list) or len(rows) != n
            or not all(isinstance(r, list) and len(r) == n and all(v in (0, 1) and not isinstance(v, bool)
                                                                   for v in r) for r in rows)):
        raise ConfigError(source, f"structure.{key}", f"must be a {n}x{n} matrix of 0 and 1 over phases {numbers}")
    for i in range(n):
        for j in range(i + 1, n):
            if rows[i][j] != rows[j][i]:
                raise ConfigError(source, f"structure.{key}",
                                  f"is not symmetric: [{numbers[i]}][{numbers[j]}] = {rows[i][j]} but "
                                  f"[{numbers[j]}][{numbers[i]}] = {rows[j][i]}; allowed: symmetric matrices")
    mark = 1 if key == "compatibility" else 0
    return frozenset(frozenset((numbers[i], numbers[j])) for i in range(n) for j in range(i + 1, n)
                     if rows[i][j] == mark)


def from_dict(raw: Mapping[str, Any], source: str = "<memory>") -> IntersectionConfig:
    _unknown(raw, ("name", "timing", "phases", "structure", "middleware", "emulator", "detectors",
                   "pedestrian_detectors", "coordination", "overlaps", "preempts"), "", source)
    name = raw.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise ConfigError(source, "name", "must be a string")
    structure = raw.get("structure")
    if not isinstance(structure, dict):
        raise ConfigError(source, "structure", "is required: rings, barriers, sequence and pairs")
    _unknown(structure, ("rings", "barriers", "sequence", "pairs", "compatibility", "conflict"), "structure.", source)

    raw_phases = raw.get("phases")
    if not isinstance(raw_phases, dict) or not raw_phases:
        raise ConfigError(source, "phases", "is required: a table of phases keyed by phase number")
    numbers = []
    for key in raw_phases:
        # "01" would name phase 1 a second way and miss every later lookup by str(number).
        if not key.isdigit() or key != str(int(key)) or int(key) not in PHASE_NUMBERS:
            raise ConfigError(source, f"phases.{key}", "is not a phase number; allowed: 1..255")
        numbers.append(int(key))
    numbers.sort()

    rings_raw = structure.get("rings")
    if not isinstance(rings_raw, list) or len(rings_raw) != 2:
        raise ConfigError(source, "structure.rings", "must list exactly two rings (dual-ring controller)")
    ring_of: dict[int, int] = {}
    rings = []
    for r, members in enumerate(rings_raw, start=1):
        members = _int_list(members, f"structure.rings[{r - 1}]", source)
        for p in members:
            if p not in raw_phases and str(p) not in raw_phases:
                raise ConfigError(source, f"structure.rings[{r - 1}]", f"unknown phase {p}; allowed: {numbers}")
            if p in ring_of:
                raise ConfigError(source, f"structure.rings[{r - 1}]",
                                  f"phase {p} is in rings {ring_of[p]} and {r}; allowed: one ring per phase")
            ring_of[p] = r
        rings.append(tuple(members))
    for p in numbers:
        if p not in ring_of:
            raise ConfigError(source, f"phases.{p}", "is in no ring; every phase belongs to exactly one ring")

    timing = raw.get("timing", {})
    if not isinstance(timing, dict):
        raise ConfigError(source, "timing", "must be a table of default phase timings")
    _unknown(timing, (*_PHASE_OPTIONS, *_UNIT_OPTIONS), "timing.", source)
    startup_flash = _number(timing, "startup_flash", "timing.", source, 0, integer=True, ntcip=(UNIT_STARTUP_FLASH, 1))
    lock = timing.get("next_phase_lock", NextPhaseLock.GREEN_END.value)
    if lock not in tuple(NextPhaseLock):
        raise ConfigError(source, "timing.next_phase_lock",
                          f"is {lock!r}; allowed: {', '.join(x.value for x in NextPhaseLock)}")
    phase_timing = {k: v for k, v in timing.items() if k not in _UNIT_OPTIONS}
    phases = {p: _phase(p, raw_phases[str(p)], phase_timing, ring_of[p], source) for p in numbers}

    barriers_raw = structure.get("barriers")
    if not isinstance(barriers_raw, list) or not barriers_raw:
        raise ConfigError(source, "structure.barriers", "must list the phases of each barrier group")
    barrier_of: dict[int, int] = {}
    for b, members in enumerate(barriers_raw):
        for p in _int_list(members, f"structure.barriers[{b}]", source):
            if p not in phases:
                raise ConfigError(source, f"structure.barriers[{b}]", f"unknown phase {p}; allowed: {numbers}")
            if p in barrier_of:
                raise ConfigError(source, f"structure.barriers[{b}]",
                                  f"phase {p} is in barrier groups {barrier_of[p]} and {b}")
            barrier_of[p] = b
    for p in numbers:
        if p not in barrier_of:
            raise ConfigError(source, "structure.barriers", f"phase {p} is in no barrier group")
    for r, ring in enumerate(rings):
        seen = [barrier_of[p] for p in ring]
        if seen != sorted(seen):
            raise ConfigError(source, f"structure.rings[{r}]",
                              "must list its phases barrier group by barrier group, in barrier order")

    derived = frozenset(frozenset((a, b)) for a in numbers for b in numbers
                        if a < b and ring_of[a] != ring_of[b] and barrier_of[a] == barrier_of[b])
    explicit = _matrix(structure, numbers, source)
    # An explicit matrix wins even when it allows nothing at all.
    compatibility = derived if explicit is None else explicit
    # What the controller shows together (its pairs, its start-up phases, a preempt's phases) must not conflict.
    permissives = Permissives(compatibility)

    startups = [p for p in numbers if phases[p].startup != PhaseStartup.PHASE_NOT_ON]
    for i, a in enumerate(startups):
        for b in startups[i + 1:]:
            if frozenset((a, b)) not in derived or first_conflict(permissives, (a, b)) is not None:
                raise ConfigError(source, f"phases.{b}.startup",
                                  f"phase {b} cannot start together with phase {a}; allowed: one phase per ring, "
                                  "all in one barrier group")

    pairs = _pairs(structure.get("pairs"), "structure.pairs", phases, permissives, source)
    sequence = _pairs(structure.get("sequence"), "structure.sequence", phases, permissives, source)
    for key, listed in (("pairs", pairs), ("sequence", sequence)):
        for i, (a, b) in enumerate(listed):
            if frozenset((a, b)) not in derived:
                raise ConfigError(source, f"structure.{key}[{i}]",
                                  f"phases {a} and {b} are in different barrier groups, so the controller never "
                                  "shows them together; allowed: pairs within one barrier group")
    for p in numbers:
        if phases[p].dual_entry and not any(frozenset((p, q)) in compatibility for q in numbers):
            raise ConfigError(source, f"phases.{p}.dual_entry",
                              f"phase {p} has no concurrent phase in the other ring; allowed: dual_entry on a phase "
                              "that runs beside some phase of the other ring")
    middleware = raw.get("middleware", {})
    if not isinstance(middleware, dict):
        raise ConfigError(source, "middleware", "must be a table of middleware parameters")
    rings_t = tuple(rings)
    barriers_t = tuple(frozenset(b) for b in barriers_raw)
    return IntersectionConfig(
        name=name,
        phases=phases,
        rings=rings_t,
        barriers=barriers_t,
        sequence=sequence,
        pairs=pairs,
        compatibility=compatibility,
        middleware=_middleware(middleware, source),
        source=source,
        startup_flash=startup_flash,
        next_phase_lock=NextPhaseLock(lock),
        coordination=_coordination(raw.get("coordination", {}), phases, rings_t, barriers_t, source),
        emulator=_emulator(raw.get("emulator", {}), source),
        **_detectors(raw.get("detectors", {}), phases, source),
        ped_detector_phases=_ped_detectors(raw.get("pedestrian_detectors", {}), phases, source),
        overlaps=_overlaps(raw.get("overlaps", {}), phases, compatibility, source),
        preempts=_preempts(raw.get("preempts", {}), phases, permissives, source),
    )


def _ped_detectors(raw: Any, phases: Mapping[int, Phase], source: str) -> dict[int, int]:
    """``[pedestrian_detectors]``: push button number (1-255) = the phase whose pedestrian call it places."""
    if not isinstance(raw, dict):
        raise ConfigError(source, "pedestrian_detectors", "must be a table: push button number = phase it calls, "
                                                          "e.g. 1 = 2")
    out: dict[int, int] = {}
    for key, phase in raw.items():
        where = f"pedestrian_detectors.{key}"
        if not (key.isdigit() and int(key) in PED_DETECTOR_NUMBERS):
            raise ConfigError(source, where,
                              f"unknown pedestrian detector; allowed: numbers 1-{PED_DETECTOR_NUMBERS[-1]}")
        if not isinstance(phase, int) or isinstance(phase, bool) or phase not in phases:
            raise ConfigError(source, where, f"calls phase {phase!r}; allowed: the configured phases "
                                             f"{', '.join(map(str, phases))}")
        out[int(key)] = phase
    return out


def _detectors(raw: Any, phases: Mapping[int, Phase], source: str) -> dict[str, dict[int, Any]]:
    """``[detectors]``: vehicle detector number (1-128) = the phase it calls, or a table ``{ phase = P, lane = "ID",
    delay = s, extend = s, carryover = s, lock = true }``: a loop on one SUMO lane (without a lane, the detector sees
    every approach lane of its phase), its timers and its yellow lock (:class:`DetectorTiming`). Phase 0 is NTCIP's
    vehicleDetectorCallPhase 0: the controller logs the detector and places no call (a count station)."""
    if not isinstance(raw, dict):
        raise ConfigError(source, "detectors", "must be a table: detector number = phase it calls, e.g. 1 = 2, or "
                                               "1 = { phase = 2, lane = \"E2C_0\", delay = 3.0 }")
    out: dict[int, int] = {}
    lanes: dict[int, str] = {}
    timing: dict[int, DetectorTiming] = {}
    for key, value in raw.items():
        where = f"detectors.{key}"
        if not (key.isdigit() and int(key) in DETECTOR_NUMBERS):
            raise ConfigError(source, where, f"unknown detector; allowed: detector numbers 1-{DETECTOR_NUMBERS[-1]}")
        if isinstance(value, dict):
            _unknown(value, ("phase", "lane", *_DETECTOR_TIMERS, "lock"), f"{where}.", source)
            phase, lane = value.get("phase"), value.get("lane")
            if lane is not None and not (isinstance(lane, str) and lane):
                raise ConfigError(source, f"{where}.lane", "must be a SUMO lane id, e.g. \"E2C_0\"")
            if lane is not None:
                lanes[int(key)] = lane
            timers = {name: float(_number(value, name, f"{where}.", source, 0.0, low=0, high=high, step=0.1,
                                          ntcip=carrier))
                      for name, (carrier, high) in _DETECTOR_TIMERS.items()}
            lock = value.get("lock", False)
            if not isinstance(lock, bool):
                raise ConfigError(source, f"{where}.lock", f"is {lock!r}; allowed: true (a call placed off the phase's "
                                                           "green is held until it is green), false")
            if any(timers.values()) or lock:
                timing[int(key)] = DetectorTiming(**timers, lock=lock)
        else:
            phase = value
        if isinstance(phase, bool) or not isinstance(phase, int) or (phase not in phases and phase != 0):
            raise ConfigError(source, where, f"calls phase {phase!r}; allowed: the configured phases "
                                             f"{', '.join(map(str, phases))}, or 0 (logged, calls no phase)")
        out[int(key)] = phase
    return {"detector_phases": out, "detector_lanes": lanes, "detector_timing": timing}


#: Each detector timer of the config, the object that carries it (None: no NTCIP object) and its highest value in
#: seconds: vehicleDetectorDelay "0-255.0 sec", vehicleDetectorExtend "0-25.5 sec"; carryover, carried by no object,
#: as long as an extension.
_DETECTOR_TIMERS: dict[str, tuple[Carrier | None, float]] = {
    "delay": ((VEHICLE_DETECTOR_DELAY, 10), 255.0),
    "extend": ((VEHICLE_DETECTOR_EXTEND, 10), 25.5),
    "carryover": (None, 25.5),
}


# --- [coordination] ----------------------------------------------------------------------------


def _coordination(raw: Any, phases: Mapping[int, Phase], rings: tuple[tuple[int, ...], ...],
                  barriers: tuple[frozenset[int], ...], source: str) -> Coordination:
    """``[coordination]``: a pattern, force-off mode, offset reference, correction, ``[[coordination.patterns]]``
    and ``[[coordination.schedule]]``. Validated against the phases: every split serves its phase's minimum and
    clearances, each ring's splits add up to the cycle and reach each barrier together, the coordinated phases
    are one per ring and concurrent."""
    w = "coordination."
    if not isinstance(raw, dict):
        raise ConfigError(source, "coordination", "must be a table (pattern, force_off, offset_reference, "
                                                  "correction, [[coordination.patterns]], [[coordination.schedule]])")
    _unknown(raw, ("pattern", "force_off", "offset_reference", "correction", "patterns", "schedule"), w, source)
    modes = {}
    for key, kind, default in (("force_off", ForceOff, ForceOff.FIXED),
                               ("offset_reference", OffsetReference, OffsetReference.LEAD_GREEN),
                               ("correction", Correction, Correction.SHORTWAY)):
        value = raw.get(key, default.value)
        if value not in tuple(kind):
            raise ConfigError(source, f"{w}{key}", f"is {value!r}; allowed: {', '.join(x.value for x in kind)}")
        modes[key] = kind(value)
    listed = raw.get("patterns", [])
    if not isinstance(listed, list) or not all(isinstance(p, dict) for p in listed):
        raise ConfigError(source, f"{w}patterns", "must be an array of tables: [[coordination.patterns]]")
    patterns: dict[int, Pattern] = {}
    for i, item in enumerate(listed):
        pattern = _pattern(item, f"{w}patterns[{i}].", phases, rings, barriers, source)
        if pattern.number in patterns:
            raise ConfigError(source, f"{w}patterns[{i}].number", f"pattern {pattern.number} is given twice; allowed: "
                                                                   "one table per pattern number")
        patterns[pattern.number] = pattern

    def pattern_number(value: Any, name: str) -> int:
        if value == "free" or (type(value) is int and value in (0, FREE)):
            return FREE
        if type(value) is not int or value not in patterns:
            known = ", ".join(map(str, sorted(patterns))) or "none"
            raise ConfigError(source, name, f"is {value!r}; allowed: \"free\" (or 0) or a pattern of "
                                            f"[[coordination.patterns]] ({known})")
        return value

    schedule_raw = raw.get("schedule", [])
    if not isinstance(schedule_raw, list) or not all(isinstance(e, dict) for e in schedule_raw):
        raise ConfigError(source, f"{w}schedule", "must be an array of tables: [[coordination.schedule]] with "
                                                  "from = \"HH:MM\" and pattern = N or \"free\"")
    schedule = []
    for i, entry in enumerate(schedule_raw):
        where = f"{w}schedule[{i}]."
        _unknown(entry, ("from", "pattern"), where, source)
        if "pattern" not in entry:
            raise ConfigError(source, f"{where}pattern", "is required: a pattern number or \"free\"")
        schedule.append(ScheduleEntry(_time_of_day(entry.get("from"), f"{where}from", source),
                                      pattern_number(entry["pattern"], f"{where}pattern")))
    starts = [e.start for e in schedule]
    if len(set(starts)) != len(starts):
        raise ConfigError(source, f"{w}schedule", "two entries start at the same time; allowed: one entry per time")
    return Coordination(pattern_number(raw.get("pattern", "free"), f"{w}pattern"), patterns=patterns,
                        schedule=tuple(sorted(schedule, key=lambda e: e.start)), **modes)


def _time_of_day(value: Any, name: str, source: str) -> int:
    parts = value.split(":") if isinstance(value, str) else []
    ok = 2 <= len(parts) <= 3 and all(p.isdigit() and len(p) == 2 for p in parts)
    h, m, sec = (int(p) for p in [*parts, "00"][:3]) if ok else (99, 0, 0)
    if not (ok and h < 24 and m < 60 and sec < 60):
        raise ConfigError(source, name, f"is {value!r}; allowed: a time of day \"HH:MM\" or \"HH:MM:SS\" "
                                        "(00:00 to 23:59:59)")
    return 3600 * h + 60 * m + sec


def _pattern(raw: Mapping[str, Any], w: str, phases: Mapping[int, Phase], rings: tuple[tuple[int, ...], ...],
             barriers: tuple[frozenset[int], ...], source: str) -> Pattern:
    _unknown(raw, ("number", "cycle", "offset", "coord_phases", "splits", "modes"), w, source)
    number = _number(raw, "number", w, source, integer=True, low=1, high=253)
    # NTCIP 1202 patternCycleTime: "NEMA TS 2 range: 30-255"; an offset at or past the cycle "shall result in Free".
    cycle = _number(raw, "cycle", w, source, integer=True, low=CYCLE_SECONDS[0], high=CYCLE_SECONDS[-1])
    offset = _number(raw, "offset", w, source, 0, integer=True, low=0, high=cycle - 1)
    coord = _int_list(raw.get("coord_phases"), f"{w}coord_phases", source)
    ring_of = {p: ph.ring for p, ph in phases.items()}
    if any(p not in phases for p in coord) or sorted(ring_of[p] for p in coord) != list(range(1, len(rings) + 1)):
        raise ConfigError(source, f"{w}coord_phases", f"is {coord}; allowed: one configured phase per ring "
                                                      f"(rings {[list(r) for r in rings]})")
    if len({next(i for i, b in enumerate(barriers) if p in b) for p in coord}) != 1:
        raise ConfigError(source, f"{w}coord_phases", f"phases {coord} are not concurrent (they lie in different "
                                                      "barrier groups); allowed: coordinated phases that show together")
    splits_raw = raw.get("splits")
    if not isinstance(splits_raw, dict):
        raise ConfigError(source, f"{w}splits", "is required: a table of split seconds per phase, e.g. "
                                                "{ 1 = 15, 2 = 35, ... }")
    splits: dict[int, int] = {}
    for key in splits_raw:
        if not key.isdigit() or int(key) not in phases:
            raise ConfigError(source, f"{w}splits.{key}", f"unknown phase; allowed: {', '.join(map(str, phases))}")
        splits[int(key)] = _number(splits_raw, key, f"{w}splits.", source, integer=True, low=1, high=255)
    missing = sorted(set(phases) - set(splits))
    if missing:
        raise ConfigError(source, f"{w}splits", f"has no split for phase(s) {missing}; allowed: a split for every "
                                                f"phase ({', '.join(map(str, phases))})")
    modes = _split_modes(raw.get("modes", {}), f"{w}modes", phases, coord, source)
    for p, split in splits.items():
        ph = phases[p]
        # NTCIP 1202 splitTime: "The split time shall be longer than the sum of the phase minimum service
        # requirements"; those of "a phase with a not-actuated ped include Minimum Green, Walk, Pedestrian Clear,
        # Yellow Clearance, and Red Clearance". The walk and its clearance time from the start of the green beside
        # the minimum green, not after it (the ring's minimum is the greater of the two, as a pattern's fit counts
        # it), so its service is the greater plus the clearances: a pedestrian's minimum is "walk + ped clearance +
        # veh clearance" (Naztec's coordination manual, Stop-in-Walk), and an Econolite ran its 40 s splits with
        # a walk every cycle of 21 s, 13 s of clearance, 4.1 s of yellow and 1.9 s of red, coordinated throughout
        # (ECON_10.204.9.227_2024_07_22_1332.dat, utahudot/udot-atspm test data).
        ped = ph.recall is Recall.PED or modes.get(p) in (SplitMode.PED_RECALL, SplitMode.MAX_AND_PED_RECALL)
        need = max(ph.min_green, ph.walk + ph.ped_clear if ped else 0) + ph.yellow + ph.red_clear
        if split < need:
            what = "minimum green or walk and pedestrian clearance" if ped else "minimum green"
            raise ConfigError(source, f"{w}splits.{p}", f"is {split} s, shorter than phase {p}'s {what}, "
                                                        f"yellow and red clearance ({need:g} s); "
                                                        f"allowed: >= {need:g} s")
    for r, ring in enumerate(rings, start=1):
        total = sum(splits[p] for p in ring)
        if total != cycle:
            raise ConfigError(source, f"{w}splits", f"ring {r} ({', '.join(map(str, ring))}) adds up to {total} s, "
                                                    f"not the cycle of {cycle} s; allowed: each ring's splits = cycle")
    for b, group in enumerate(barriers, start=1):
        sums = {r: sum(splits[p] for p in ring if p in group) for r, ring in enumerate(rings, start=1)}
        if len(set(sums.values())) > 1:
            raise ConfigError(source, f"{w}splits", f"the rings reach barrier {b} at different times (ring sums in its "
                                                    f"group: {sums}); allowed: equal sums in every barrier group")
    return Pattern(number, cycle, offset, tuple(coord), splits, modes)


# NTCIP 1202 splitMode by name in a pattern's ``modes`` (other(1), "not specified in this standard", left out).
SPLIT_MODE_NAMES = {m.name.lower(): m for m in SplitMode if m is not SplitMode.OTHER}


def _split_modes(raw: Any, w: str, phases: Mapping[int, Phase], coord: list[int],
                 source: str) -> dict[int, SplitMode]:
    """A pattern's ``modes = { 4 = "max_and_ped_recall" }``: each phase's splitMode while the pattern runs (none
    where absent)."""
    allowed = ", ".join(SPLIT_MODE_NAMES)
    if not isinstance(raw, dict):
        raise ConfigError(source, w, f"must be a table of split modes by phase, e.g. {{ 4 = \"ped_recall\" }}; "
                                     f"allowed modes: {allowed}")
    modes = {}
    for key, value in raw.items():
        if not key.isdigit() or int(key) not in phases:
            raise ConfigError(source, f"{w}.{key}", f"unknown phase; allowed: {', '.join(map(str, phases))}")
        if not isinstance(value, str) or value not in SPLIT_MODE_NAMES:
            raise ConfigError(source, f"{w}.{key}", f"is {value!r}; allowed: {allowed}")
        if value == "omitted" and int(key) in coord:
            raise ConfigError(source, f"{w}.{key}", "omits a coordinated phase; allowed: a mode that serves it")
        if value in ("ped_recall", "max_and_ped_recall") and phases[int(key)].walk == 0:
            raise ConfigError(source, f"{w}.{key}", f"is {value!r} on a phase without walk; allowed: a walk > 0 for "
                                                    "pedestrian recall")
        modes[int(key)] = SPLIT_MODE_NAMES[value]
    return modes


# --- [overlaps] -----------------------------------------------------------------------------------


def _overlaps(raw: Any, phases: Mapping[int, Phase], compatibility: frozenset[frozenset[int]],
              source: str) -> dict[int, Overlap]:
    """``[overlaps]``: a table per overlap letter (A-P; NTCIP numbers them 1 = A), e.g.
    ``A = { included = [8, 5], approach = "south", turn = "right" }``."""
    if not isinstance(raw, dict):
        raise ConfigError(source, "overlaps", "must be a table of overlaps by letter, e.g. A = { included = [8, 5] }")
    out = {}
    for key, item in raw.items():
        if not (len(key) == 1 and ord(key) - ord("A") + 1 in OVERLAP_NUMBERS):
            raise ConfigError(source, f"overlaps.{key}", "is not an overlap letter; allowed: A to P")
        out[ord(key) - ord("A") + 1] = _overlap(ord(key) - ord("A") + 1, item, f"overlaps.{key}.", phases,
                                                 compatibility, source)
    claimed: dict[tuple[str, str], str] = {}
    for o in out.values():
        if o.approach is not None:
            movement = (o.approach, o.turn)
            if movement in claimed:
                raise ConfigError(source, f"overlaps.{o.letter}.turn", f"overlap {claimed[movement]} already shows the "
                                                                     f"{o.turn} turn of the {o.approach} approach")
            claimed[movement] = o.letter
    return dict(sorted(out.items()))


def _overlap(number: int, raw: Any, w: str, phases: Mapping[int, Phase], compatibility: frozenset[frozenset[int]],
             source: str) -> Overlap:
    if not isinstance(raw, dict):
        raise ConfigError(source, w[:-1], "must be a table: included, modifiers, type, trail_green, trail_yellow, "
                                          "trail_red, delay_green, approach, turn")
    _unknown(raw, ("type", "included", "modifiers", "trail_green", "trail_yellow", "trail_red", "delay_green",
                   "approach", "turn"), w, source)
    kind = raw.get("type", OverlapKind.NORMAL.value)
    if kind not in tuple(OverlapKind):
        raise ConfigError(source, f"{w}type", f"is {kind!r}; allowed: {', '.join(k.value for k in OverlapKind)}")
    kind = OverlapKind(kind)
    lists = {}
    for key in ("included", "modifiers"):
        value = _int_list(raw.get(key, []), f"{w}{key}", source)
        unknown = [p for p in value if p not in phases]
        if unknown or len(set(value)) != len(value):
            raise ConfigError(source, f"{w}{key}", f"is {value}; allowed: distinct configured phases "
                                                   f"({', '.join(map(str, phases))})")
        lists[key] = tuple(value)
    included, modifiers = lists["included"], lists["modifiers"]
    if not included:
        raise ConfigError(source, f"{w}included", "is required: the phases (parents) whose green the overlap shows")
    both = sorted(set(included) & set(modifiers))
    if both:
        raise ConfigError(source, f"{w}modifiers", f"phase(s) {both} are also included; allowed: phases not included")
    # NTCIP 1202 overlapModifierPhases: "A null value provides a normal overlap type. A non-null value provides a
    # minusGreenYellow overlap type."
    if kind is OverlapKind.NORMAL and modifiers:
        raise ConfigError(source, f"{w}modifiers", "is given for a normal overlap; allowed: none (modifiers make a "
                                                   "minus_green_yellow or fya overlap)")
    if kind is OverlapKind.TRANSIT and modifiers:
        raise ConfigError(source, f"{w}modifiers", "is given for a transit overlap; allowed: none (NTCIP 1202 v03 "
                                                   "transit-2 is controlled by its included phases alone)")
    if kind not in (OverlapKind.NORMAL, OverlapKind.TRANSIT) and not modifiers:
        raise ConfigError(source, f"{w}modifiers", f"is required for type {kind.value!r}: "
                                                   + ("the phases whose green holds the overlap red"
                                                      if kind is OverlapKind.MINUS_GREEN_YELLOW else
                                                      "the permissive phases (the opposing through the turn yields "
                                                      "to) during whose green the arrow flashes"))
    if kind is OverlapKind.FYA:
        # The arrow flashes while the opposing through is green: that phase never runs beside the protected turn.
        bad = [(m, p) for m in modifiers for p in included if frozenset((m, p)) in compatibility]
        if bad:
            m, p = bad[0]
            raise ConfigError(source, f"{w}modifiers", f"phase {m} runs beside protected phase {p}; allowed: "
                                                       "permissive phases that conflict with every included phase")
    trail_green = _number(raw, "trail_green", w, source, 0, integer=True,
                          ntcip=(OVERLAP_TABLE[OverlapColumn.TRAIL_GREEN], 1))
    if trail_green and kind in (OverlapKind.FYA, OverlapKind.TRANSIT):
        raise ConfigError(source, f"{w}trail_green", "is given for " + (
            "an fya overlap; allowed: 0 (a flashing yellow arrow clears with its phases)" if kind is OverlapKind.FYA
            else "a transit overlap; allowed: 0 (a transit bar flashes its green through its phases' yellow and has "
                 "no yellow of its own)"))
    trail_yellow = _number(raw, "trail_yellow", w, source, 3.0, step=0.1,
                           ntcip=(OVERLAP_TABLE[OverlapColumn.TRAIL_YELLOW], 10))
    trail_red = _number(raw, "trail_red", w, source, 0.0, step=0.1, ntcip=(OVERLAP_TABLE[OverlapColumn.TRAIL_RED], 10))
    approach, turn = raw.get("approach"), raw.get("turn")
    if (approach is None) != (turn is None):
        missing, given = ("turn", "approach") if turn is None else ("approach", "turn")
        raise ConfigError(source, f"{w}{missing}", f"is required with {given}: both name the movement shown")
    if approach is not None and approach not in APPROACHES:
        raise ConfigError(source, f"{w}approach", f"is {approach!r}; allowed: {', '.join(APPROACHES)}")
    allowed_turns = ("left",) if kind is OverlapKind.FYA else OVERLAP_TURNS
    if turn is not None and turn not in allowed_turns:
        raise ConfigError(source, f"{w}turn", f"is {turn!r}; allowed: {', '.join(allowed_turns)}"
                                              + (" (a flashing yellow arrow shows a left turn)"
                                                 if kind is OverlapKind.FYA else ""))
    # No NTCIP object carries it: tenths up to 25.5 s, as the overlap's own trailing yellow and red.
    delay_green = _number(raw, "delay_green", w, source, 0.0, low=0, high=25.5, step=0.1)
    if delay_green and kind is OverlapKind.FYA:
        raise ConfigError(source, f"{w}delay_green", "is given for an fya overlap; allowed: 0 (a flashing yellow arrow "
                                                     "follows its protected and permissive phases at once)")
    return Overlap(number, kind, included, modifiers, trail_green, float(trail_yellow), float(trail_red), approach,
                   turn, float(delay_green))


# --- [preempts] -----------------------------------------------------------------------------------

#: Each preempt time of the config, and the preempt-table object that carries it (NTCIP 1202 preemptTable).
_PREEMPT_TIMES: dict[str, Carrier] = {
    "delay": (PREEMPT_TABLE[PreemptColumn.DELAY], 1),
    "min_duration": (PREEMPT_TABLE[PreemptColumn.MINIMUM_DURATION], 1),
    "min_green": (PREEMPT_TABLE[PreemptColumn.MINIMUM_GREEN], 1),
    "min_walk": (PREEMPT_TABLE[PreemptColumn.MINIMUM_WALK], 1),
    "enter_ped_clear": (PREEMPT_TABLE[PreemptColumn.ENTER_PED_CLEAR], 1),
    "enter_yellow": (PREEMPT_TABLE[PreemptColumn.ENTER_YELLOW_CHANGE], 10),
    "enter_red": (PREEMPT_TABLE[PreemptColumn.ENTER_RED_CLEAR], 10),
    "track_green": (PREEMPT_TABLE[PreemptColumn.TRACK_GREEN], 1),
    "track_yellow": (PREEMPT_TABLE[PreemptColumn.TRACK_YELLOW_CHANGE], 10),
    "track_red": (PREEMPT_TABLE[PreemptColumn.TRACK_RED_CLEAR], 10),
    "dwell_green": (PREEMPT_TABLE[PreemptColumn.DWELL_GREEN], 1),
    "max_presence": (PREEMPT_TABLE[PreemptColumn.MAXIMUM_PRESENCE], 1),
}


def _preempts(raw: Any, phases: Mapping[int, Phase], permissives: Permissives, source: str) -> dict[int, Preempt]:
    """``[preempts]``: a table per preempt number (1-255; lower numbers override higher), e.g.
    ``1 = { dwell_phases = [2, 6], exit_phases = [2, 6], vehicles = ["emergency"], approach = "east" }``."""
    if not isinstance(raw, dict):
        raise ConfigError(source, "preempts", "must be a table of preempts by number, e.g. "
                                              "1 = { dwell_phases = [2, 6] }")
    out = {}
    for key, item in raw.items():
        if not key.isdigit() or key != str(int(key)) or not 1 <= int(key) <= 255:
            raise ConfigError(source, f"preempts.{key}", "is not a preempt number; allowed: 1..255")
        out[int(key)] = _preempt(int(key), item, f"preempts.{key}.", phases, permissives, source)
    return dict(sorted(out.items()))


def _preempt(number: int, raw: Any, w: str, phases: Mapping[int, Phase], permissives: Permissives,
             source: str) -> Preempt:
    if not isinstance(raw, dict):
        raise ConfigError(source, w[:-1], "must be a table of preempt settings")
    lists = ("track_phases", "dwell_phases", "exit_phases")
    _unknown(raw, (*lists, "cycling_phases", *_PREEMPT_TIMES, "non_locking", "vehicles", "approach", "zone"), w,
             source)
    got: dict[str, Any] = {}
    cycling = _int_list(raw.get("cycling_phases", []), f"{w}cycling_phases", source)
    if any(p not in phases for p in cycling) or len(set(cycling)) != len(cycling):
        raise ConfigError(source, f"{w}cycling_phases", f"is {cycling}; allowed: configured phases, each once")
    for key in lists:
        value = _int_list(raw.get(key, []), f"{w}{key}", source)
        # NTCIP 1202 Annex B's consistency checks: the phases of one list run together, one per ring.
        if any(p not in phases for p in value) or len({phases[p].ring for p in value if p in phases}) != len(value):
            raise ConfigError(source, f"{w}{key}", f"is {value}; allowed: configured phases, at most one per ring")
        clash = first_conflict(permissives, value)
        if clash is not None:
            raise ConfigError(source, f"{w}{key}", f"{clash} conflict; allowed: phases that run together")
        got[key] = tuple(value)
    for key, (obj, per_second) in _PREEMPT_TIMES.items():
        default = Preempt.__dataclass_fields__[key].default
        integer = per_second == 1
        value = _number(raw, key, w, source, default, integer=integer, step=None if integer else 0.1,
                        ntcip=(obj, per_second))
        got[key] = value if integer else float(value)
    if cycling and not got["dwell_phases"]:
        raise ConfigError(source, f"{w}dwell_phases", "is required with cycling_phases: the phases they cycle after")
    if got["track_green"] and not got["track_phases"]:
        raise ConfigError(source, f"{w}track_phases", "is required with track_green: the phases that clear the track")
    non_locking = raw.get("non_locking", False)
    if not isinstance(non_locking, bool):
        raise ConfigError(source, f"{w}non_locking", f"is {non_locking!r}; allowed: true, false")
    vehicles, approach = raw.get("vehicles", []), raw.get("approach")
    if not isinstance(vehicles, list) or not all(isinstance(v, str) and v for v in vehicles):
        raise ConfigError(source, f"{w}vehicles", f"is {vehicles!r}; allowed: a list of SUMO vehicle classes or "
                                                  "vehicle type ids, e.g. [\"emergency\"]")
    if bool(vehicles) != (approach is not None):
        missing, given = ("approach", "vehicles") if vehicles else ("vehicles", "approach")
        raise ConfigError(source, f"{w}{missing}", f"is required with {given}: both name the SUMO detection zone")
    if approach is not None and approach not in APPROACHES:
        raise ConfigError(source, f"{w}approach", f"is {approach!r}; allowed: {', '.join(APPROACHES)}")
    zone = _number(raw, "zone", w, source, Preempt.__dataclass_fields__["zone"].default, low=1, high=2000)
    return Preempt(number, got["dwell_phases"], got["track_phases"], got["exit_phases"], tuple(cycling),
                   **{k: got[k] for k in _PREEMPT_TIMES}, non_locking=non_locking, vehicles=tuple(vehicles),
                   approach=approach, zone=float(zone))
