"""Reading a fault-scenario file: a TOML file of faults and expected outcomes, validated whole into a
:class:`FaultScenario`.

A fault-scenario file says which intersection (or which scenario of several
controllers), agent and action type to run, for how long and from which seed,
which faults to inject when and on which controller (:mod:`harness.faults.inject`),
and what must come out, at each intersection. It is validated whole when
loaded; an unknown key or a bad value is refused with a :class:`FaultScenarioError`
naming the file and the key. The faults' keys are the registry's
(:mod:`harness.faults.registry`); what the expectations mean, and the ones always
checked, is the judge's (:mod:`harness.faults.judge`).

The format (only ``duration`` and one ``[[faults]]`` are required)::

    name = "communication-loss"         # default: the file name without .toml
    description = "one line shown by `hils faults list`"
    config = "my_intersection.toml"     # relative to this file; default: the shipped four-leg
    scenario = "corridor"               # instead of config: several controllers, one per traffic light (a
                                        # shipped scenario's name or a .scenario.toml path), run without SUMO
    action_type = "selection"           # selection | switch | duration
    agent = "random"                    # built-in or package.module:Class; default: the action type's
    [[schedule]]                        # instead of an agent (action_type = "control"): a phase-control schedule
    commandType = "omit_veh"            # in MMITSS's keys, handed over at the first decision
    commandPhase = 1
    commandStartTime = 0.0
    commandEndTime = 120.0
    duration = 60.0                     # simulated seconds
    seed = 1
    recover_after = 5.0                 # s in TIMEOUT before recover() is called; negative: never

    [middleware]                        # overrides of the config's middleware parameters
    n_timeout = 5

    [[faults]]                          # one table per fault; ``type`` picks one of FAULT_TYPES
    type = "drop"
    name = "link-down"                  # default: type#index; shown in reports
    intersection = "J2"                 # the controller it acts on: required with several (slow_steps
                                        # takes none: it slows the one simulation they all share)
    start = 20.0                        # most types: a window [start, end) and an optional count
    end = 35.0

    [expect]
    timeout = "communication"           # none (default) | any | communication | transition | drift, or a list
    timeouts = 1                        # exact number of TIMEOUT episodes
    detect_within = 5.2                 # s from the fault's first firing to TIMEOUT
    detect_from = "fault"               # or "dispatch": from the dispatch of the command that timed out
    after_fault = "link-down"           # the fault detection counts from; default: the first to fire
    recover_within = 0.1                # s from the recover() call that succeeded back to IDLE, every TIMEOUT
    refused = 3                         # exactly this many actions refused, and no command for any of them
    refused_reason = "conflict"         # every refusal for this reason
    dropped_on_hold = 5                 # at least this many actions dropped while ON_HOLD
    dropped_in_timeout = 5              # ... while in TIMEOUT
    records = { drift = 5 }             # exact number of event records of a kind
    control_status_seen = ["backup_mode"]   # unitControlStatus values the controller must show
    control_status_never = ["backup_mode"] # ... and must never show
    verified_every = 20.0               # s: never longer than this without a verified transition, start to end
    recovered_greens = [2, 6]           # phases every recovery's re-read found green (after a reboot: start-up)
    preemptions = 1                     # exactly this many PREEMPTED episodes, each ended by the controller (no
                                        # TIMEOUT within), no command SET in it, a transition verified after it
    held_as_scheduled_from = 60.0       # from this time to the end, the controller's control objects (force-offs
                                        # aside: they reset themselves) hold what the schedule asks, every tick

    [expect.J2]                         # several controllers: J2 is judged by this table alone, and every
    timeout = "communication"           # intersection without a table of its own by [expect]
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from harness.faults.inject import Fault
from harness.faults.registry import FAULT_TYPES, FaultSpec
from harness.faults.table import FaultScenarioError, TableReader
from hils.agents.builtin import AgentError, load_agent
from hils.control import phase_control
from hils.control.actions import ActionError, ActionType
from hils.control.manager_io import TimeoutReason
from hils.control.phase_control import Schedule
from hils.protocol import config as config_mod
from hils.protocol.config import ConfigError, IntersectionConfig, MiddlewareParams
from hils.protocol.ntcip import UnitControlStatus
from hils.protocol.scenario import SUFFIX, Scenario, load_scenario
from hils.run.testbed import RunSpec
from hils.shell.events import Kind
from hils.sim.network import TLS_ID

__all__ = [
    "ANY_TIMEOUT",
    "NO_TIMEOUT",
    "Expectations",
    "FaultScenario",
    "default_suite",
    "discover",
    "load_fault_scenario",
    "parse_fault_scenario",
    "status_name",
]

_FILE_KEYS = ("name", "description", "config", "scenario", "action_type", "agent", "schedule", "duration", "seed",
              "recover_after", "middleware", "faults", "expect")


def default_suite() -> Path:
    """The shipped suite: ``fault_scenarios/``, package data, so it is there however hils was installed."""
    return Path(str(resources.files("fault_scenarios")))


# --- expectations ---------------------------------------------------------------------------------------------

NO_TIMEOUT = "none"
ANY_TIMEOUT = "any"
_TIMEOUT_CHOICES = (NO_TIMEOUT, ANY_TIMEOUT, *(r.value for r in TimeoutReason))


def _refusal_reasons() -> tuple[str, ...]:
    seen, todo = set(), [ActionError]
    while todo:
        cls = todo.pop()
        seen.add(cls.reason)
        todo.extend(cls.__subclasses__())
    return tuple(sorted(seen))


def status_name(status: UnitControlStatus) -> str:
    """How scenario files (and the judge's messages) name a unitControlStatus value."""
    return status.name.lower()


_STATUS_NAMES = {status_name(s): s for s in UnitControlStatus}


@dataclass(frozen=True)
class Expectations:
    timeout: tuple[str, ...] = (NO_TIMEOUT,)  # "none", "any", or the reasons allowed (at least one TIMEOUT)
    timeouts: int | None = None  # exact number of TIMEOUT episodes
    detect_within: float | None = None
    detect_from: str = "fault"  # fault: its first firing | dispatch: the command that timed out
    after_fault: str | None = None  # the fault detection is measured from; default: the first to fire
    recover_within: float | None = None
    refused: int | None = None
    refused_reason: str | None = None
    dropped_on_hold: int | None = None  # at least
    dropped_in_timeout: int | None = None  # at least
    records: Mapping[str, int] = field(default_factory=dict)  # kind -> exact count
    control_status_seen: tuple[str, ...] = ()
    control_status_never: tuple[str, ...] = ()
    verified_every: float | None = None  # s: longest stretch allowed without a verified transition
    recovered_greens: tuple[int, ...] | None = None  # what every recovery's re-read must find green
    preemptions: int | None = None  # exact number of PREEMPTED episodes, each ended, quiet, and commanding after
    held_as_scheduled_from: float | None = None  # s: from then on the controller holds what the schedule asks
    no_conflicting_command: bool = True
    no_conflicting_indication: bool = True
    no_commands_in_timeout: bool = True
    log_complete: bool = True


_EXPECT_KEYS = tuple(Expectations.__dataclass_fields__)


def _expect_tables(raw: Any, source: str, faults: Sequence[FaultSpec],
                   intersections: Mapping[str, IntersectionConfig]) -> tuple[Expectations, dict[str, Expectations]]:
    """``[expect]`` and, with several controllers, each ``[expect.TLS]``: the table that judges that intersection
    alone; ``[expect]`` judges every intersection without one."""
    several = len(intersections) > 1
    r = TableReader(raw, "expect.", source, (*_EXPECT_KEYS, *(intersections if several else ())))
    own = {tls: r.raw[tls] for tls in intersections if several and tls in r.raw}
    rest = [tls for tls in intersections if tls not in own]

    def table(raw_table: Any, where: str, judged: Sequence[str]) -> Expectations:
        # after_fault names a fault acting on every intersection the table judges.
        names = [f.name for f in faults if all(f.acts_at(tls) for tls in judged)]
        configs = [intersections[tls] for tls in judged]
        return _expectations(raw_table, where, source, names, configs)

    default = table({k: v for k, v in r.raw.items() if k not in own}, "expect.", rest)
    return default, {tls: table(value, f"expect.{tls}.", [tls]) for tls, value in own.items()}


def _expectations(raw: Any, where: str, source: str, fault_names: Iterable[str],
                  configs: Sequence[IntersectionConfig]) -> Expectations:
    r = TableReader(raw, where, source, _EXPECT_KEYS)
    timeout = r.strings("timeout", choices=_TIMEOUT_CHOICES) if r.has("timeout") else (NO_TIMEOUT,)
    if len(timeout) > 1 and (NO_TIMEOUT in timeout or ANY_TIMEOUT in timeout):
        raise r.error("timeout", "'none' and 'any' stand alone; a list names TIMEOUT reasons")
    enters = timeout != (NO_TIMEOUT,)
    for key in ("detect_within", "recover_within", "timeouts", "detect_from", "after_fault", "recovered_greens"):
        if r.has(key) and not enters:
            raise r.error(key, "needs expect.timeout to allow a TIMEOUT (a reason, a list of reasons, or 'any')")
    detect_from = r.string("detect_from", "fault", choices=("fault", "dispatch"))
    if detect_from == "dispatch" and timeout != (TimeoutReason.TRANSITION.value,):
        raise r.error("detect_from", "'dispatch' applies to timeout = 'transition' only")
    after_fault = r.string("after_fault", choices=tuple(fault_names)) if r.has("after_fault") else None
    records = TableReader(r.raw.get("records", {}), f"{where}records.", source, [k.value for k in Kind])
    phases = set.intersection(*(set(c.phases) for c in configs)) if configs else set()
    return Expectations(
        timeout=timeout,
        timeouts=r.optional_number("timeouts", integer=True, low=1),
        detect_within=r.optional_number("detect_within", low=0, low_open=True),
        detect_from=detect_from,
        after_fault=after_fault,
        recover_within=r.optional_number("recover_within", low=0, low_open=True),
        refused=r.optional_number("refused", integer=True, low=0),
        refused_reason=r.string("refused_reason", choices=_refusal_reasons()) if r.has("refused_reason") else None,
        dropped_on_hold=r.optional_number("dropped_on_hold", integer=True, low=1),
        dropped_in_timeout=r.optional_number("dropped_in_timeout", integer=True, low=1),
        records={k: records.number(k, integer=True, low=0) for k in records.raw},
        control_status_seen=r.strings("control_status_seen", choices=_STATUS_NAMES) if r.has(
            "control_status_seen") else (),
        control_status_never=r.strings("control_status_never", choices=_STATUS_NAMES) if r.has(
            "control_status_never") else (),
        verified_every=r.optional_number("verified_every", low=0, low_open=True),
        recovered_greens=r.phases("recovered_greens", phases) if r.has("recovered_greens") else None,
        preemptions=r.optional_number("preemptions", integer=True, low=0),
        held_as_scheduled_from=r.optional_number("held_as_scheduled_from", low=0),
        no_conflicting_command=r.boolean("no_conflicting_command", True),
        no_conflicting_indication=r.boolean("no_conflicting_indication", True),
        no_commands_in_timeout=r.boolean("no_commands_in_timeout", True),
        log_complete=r.boolean("log_complete", True),
    )


# --- the fault scenario ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultScenario:
    """A validated fault-scenario file: what to run, the faults to inject, what must come out."""

    name: str
    source: str
    description: str
    config: IntersectionConfig  # the first intersection's, with several
    action_type: ActionType
    agent: str | None
    schedule: Schedule | None  # phase control by a schedule, instead of an agent
    duration: float
    seed: int
    recover_after: float | None
    faults: tuple[FaultSpec, ...]
    expect: Expectations  # every intersection's, but for those of expect_at
    intersections: Mapping[str, IntersectionConfig]  # traffic light -> its controller's config
    network: Scenario | None = None  # the scenario of several controllers run, if one was named
    expect_at: Mapping[str, Expectations] = field(default_factory=dict)

    @property
    def several(self) -> bool:
        return len(self.intersections) > 1

    def expectations(self, tls: str) -> Expectations:
        return self.expect_at.get(tls, self.expect)

    def spec(self, log_path: Path | None = None) -> RunSpec:
        return RunSpec(self.config, self.action_type, self.agent, self.duration, self.seed, log_path,
                       recover_after=self.recover_after)

    def build_faults(self) -> list[Fault]:
        return [f.build(self.seed, self.action_type) for f in self.faults]

    def shown(self, tls: str | None) -> str | None:
        """How reports name an intersection: only runs of several controllers name one."""
        return tls if self.several else None

    def summary(self) -> str:
        kinds = ", ".join(f.type + (f" at {f.intersection}" if self.several else "") for f in self.faults)
        layout = f", {Path(self.network.source).name.removesuffix(SUFFIX)}" if self.several else ""
        return f"{self.description or kinds} [{self.action_type.value}, {self.duration:g} s{layout}; faults: {kinds}]"


def load_fault_scenario(path: str | Path) -> FaultScenario:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FaultScenarioError(str(p), "<file>", f"cannot be read ({exc.strerror})") from None
    return parse_fault_scenario(text, str(p), base=p.parent, default_name=p.stem)


def parse_fault_scenario(text: str, source: str = "<memory>", *, base: Path | None = None,
                         default_name: str = "scenario") -> FaultScenario:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FaultScenarioError(source, "<file>", f"is not valid TOML ({exc})") from None
    r = TableReader(raw, "", source, _FILE_KEYS)
    network = _network(r, base)
    intersections = dict(network.intersections) if network is not None else {TLS_ID: _config(r, base)}
    action_type = ActionType(r.string("action_type", ActionType.SELECTION.value, choices=[t.value for t in ActionType]))
    recover_after = r.number("recover_after", 5.0)
    faults = _fault_specs(r, source, action_type, tuple(intersections))
    for spec in faults:
        check = FAULT_TYPES[spec.type].check
        for tls, cfg in intersections.items() if check is not None else ():
            if spec.acts_at(tls) and (problem := check(spec.raw, cfg)):
                raise FaultScenarioError(source, f"faults[{spec.index}].{problem[0]}", problem[1])
    expect, expect_at = _expect_tables(raw.get("expect", {}), source, faults, intersections)
    if any(e.held_as_scheduled_from is not None for e in (expect, *expect_at.values())) and not r.has("schedule"):
        raise FaultScenarioError(source, "expect.held_as_scheduled_from", "needs a [[schedule]] to compare with")
    scenario = FaultScenario(
        name=r.string("name", default_name),
        source=source,
        description=r.string("description", ""),
        config=next(iter(intersections.values())),
        action_type=action_type,
        agent=r.string("agent") if r.has("agent") else None,
        schedule=_schedule(r, action_type, next(iter(intersections.values()))),
        duration=r.number("duration", low=0, low_open=True, high=24 * 3600),
        seed=r.number("seed", 0, integer=True, low=0),
        recover_after=None if recover_after < 0 else recover_after,
        faults=tuple(faults),
        expect=expect,
        intersections=intersections,
        network=network,
        expect_at=expect_at,
    )
    try:
        for config in intersections.values() if scenario.schedule is None else ():
            load_agent(scenario.spec().agent_spec, config, action_type, scenario.seed)
    except AgentError as exc:
        raise r.error("agent", str(exc)) from None
    return scenario


def _schedule(r: TableReader, action_type: ActionType, config: IntersectionConfig) -> Schedule | None:
    """The ``[[schedule]]`` of a phase-control scenario, checked as the middleware checks one (None without it)."""
    if not r.has("schedule"):
        return None
    if action_type is not ActionType.CONTROL or r.has("agent"):
        raise r.error("schedule", "is phase control's agent: allowed with action_type = 'control' and no agent")
    try:
        return phase_control.parse(r.raw["schedule"], config)
    except ActionError as exc:
        raise r.error("schedule", str(exc)) from None


def _config(r: TableReader, base: Path | None) -> IntersectionConfig:
    try:
        if r.has("config"):
            path = Path(r.string("config"))
            cfg = config_mod.load(path if path.is_absolute() or base is None else base / path)
        else:
            cfg = config_mod.load()
    except ConfigError as exc:
        raise r.error("config", str(exc)) from None
    return _with_overrides(r, cfg)


def _network(r: TableReader, base: Path | None) -> Scenario | None:
    """The scenario of several controllers named by ``scenario``, with the ``[middleware]`` overrides in each
    controller's config; None when the file names one intersection's ``config`` instead."""
    if not r.has("scenario"):
        return None
    if r.has("config"):
        raise r.error("scenario", "and config both given; allowed: config (one intersection) or scenario "
                                  "(one controller per traffic light), not both")
    given = r.string("scenario")
    # A name is a shipped scenario's (a misspelt one is refused as such); a .toml file is relative to this one.
    where = base / given if Path(given).suffix == ".toml" and base is not None else given
    try:
        network = load_scenario(where)
    except ConfigError as exc:
        raise r.error("scenario", str(exc)) from None
    return replace(network, intersections={tls: _with_overrides(r, cfg) for tls, cfg in network.intersections.items()})


def _with_overrides(r: TableReader, cfg: IntersectionConfig) -> IntersectionConfig:
    overrides = TableReader(r.raw.get("middleware", {}), "middleware.", r.source, MiddlewareParams.__dataclass_fields__)
    try:
        return cfg.with_middleware(**overrides.raw) if overrides.raw else cfg
    except ConfigError as exc:
        raise FaultScenarioError(r.source, exc.field, exc.message) from None


def _fault_specs(r: TableReader, source: str, action_type: ActionType,
                 intersections: tuple[str, ...]) -> list[FaultSpec]:
    raw = r.raw.get("faults")
    if not isinstance(raw, list) or not raw or not all(isinstance(f, dict) for f in raw):
        raise r.error("faults", "must be a non-empty array of tables ([[faults]])")
    specs, names = [], set()
    for i, item in enumerate(raw):
        where = f"faults[{i}]."
        kind = item.get("type")
        if kind not in FAULT_TYPES:
            raise FaultScenarioError(source, f"{where}type", f"is {kind!r}; allowed: {', '.join(FAULT_TYPES)}")
        fault_type = FAULT_TYPES[kind]
        if not fault_type.per_controller and "intersection" in item:
            raise FaultScenarioError(source, f"{where}intersection", f"not allowed: {kind} acts on the one simulation "
                                                                f"every controller shares")
        fr = TableReader(item, where, source, fault_type.all_keys)
        name = fr.string("name", f"{kind}#{i}")
        if name in names:
            raise fr.error("name", f"{name!r} is used by another fault; names must be unique")
        names.add(name)
        place = None
        if fault_type.per_controller:
            if len(intersections) > 1 and not fr.has("intersection"):
                raise fr.error("intersection", f"is required with several controllers; allowed: "
                                               f"{', '.join(intersections)}")
            place = fr.string("intersection", intersections[0], choices=intersections)
        spec = FaultSpec(kind, name, i, dict(item), source, place)
        spec.build(0, action_type)  # refuses a bad value now, not mid-suite
        specs.append(spec)
    return specs


def discover(paths: Iterable[str | Path]) -> list[Path]:
    """Fault-scenario files: each path is a file, or a directory whose ``*.toml`` files are taken in name order."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out.extend(sorted(p.glob("*.toml")))
        elif p.is_file():
            out.append(p)
        else:
            raise FaultScenarioError(str(p), "<file>", "does not exist")
    return out

