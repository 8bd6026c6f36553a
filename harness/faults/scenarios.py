"""Declarative fault scenarios: TOML files of faults and expected outcomes, and their runner.

A scenario file says which intersection (or which scenario of several
controllers), agent and action type to run, for how long and from which seed,
which faults to inject when and on which controller (:mod:`harness.faults.inject`),
and what must come out, at each intersection. It is validated whole when
loaded; an unknown key or a bad value is refused with a :class:`ScenarioError`
naming the file and the key.

The format (only ``duration`` and one ``[[faults]]`` are required)::

    name = "communication-loss"         # default: the file name without .toml
    description = "one line shown by `hils faults list`"
    config = "my_intersection.toml"     # relative to this file; default: the shipped four-leg
    scenario = "corridor"               # instead of config: several controllers, one per traffic light (a
                                        # shipped scenario's name or a .scenario.toml path), run without SUMO
    action_type = "selection"           # selection | switch | duration
    agent = "random"                    # built-in or package.module:Class; default: the action type's
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

    [expect.J2]                         # several controllers: J2 is judged by this table alone, and every
    timeout = "communication"           # intersection without a table of its own by [expect]

Implicit expectations, always checked: every fault fired at least once (a
scenario cannot pass because its fault never happened); no SET holds two
conflicting phases or an unknown one; the controller never showed two
conflicting phases (sampled every tick) nor went to MMU flash; no command or
keepalive was sent while in TIMEOUT; the log is whole (seq gapless from 0, the
run started and ended, every dispatched command ended exactly once, every SET
was answered or failed). Each can be switched off in ``[expect]``
(``no_conflicting_command``, ``no_conflicting_indication``,
``no_commands_in_timeout``, ``log_complete`` = false) for a scenario that studies
that very failure. A scenario with no ``timeout`` key expects no TIMEOUT.

With several controllers every expectation, implicit ones included, is judged
for each intersection on its own records (those naming it) and its own
controller's samples, and the report gives each intersection's outcome.
"""

from __future__ import annotations

import itertools
import math
import time
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from harness.faults.inject import (
    BAD_KINDS,
    ActionBurst,
    ActionsDuringTimeout,
    BadActionKind,
    BadActions,
    DatagramLoss,
    Direction,
    ErrorResponses,
    Fault,
    FaultTarget,
    IndicationMonitor,
    KeepaliveSuppressed,
    Op,
    PreemptCall,
    Reboot,
    ResponseDelay,
    SlowSteps,
    StuckController,
    Window,
    error_status,
)
from hils.agents.builtin import AgentError, load_agent
from hils.control.actions import ActionError, ActionType
from hils.control.manager_io import TimeoutReason
from hils.protocol import config as config_mod
from hils.protocol.config import ConfigError, IntersectionConfig, MiddlewareParams
from hils.protocol.ntcip import UnitControlStatus
from hils.protocol.scenario import SUFFIX
from hils.protocol.scenario import Scenario as Network
from hils.protocol.scenario import load_scenario as load_network
from hils.run.testbed import RunSpec, Testbed
from hils.shell.events import Kind
from hils.sim.network import TLS_ID

__all__ = [
    "FAULT_TYPES",
    "Check",
    "Expectations",
    "FaultReport",
    "FaultSpec",
    "Outcome",
    "Scenario",
    "ScenarioError",
    "ScenarioResult",
    "default_suite",
    "discover",
    "evaluate",
    "load_scenario",
    "parse_scenario",
    "run_scenario",
]

SCENARIO_KEYS = ("name", "description", "config", "scenario", "action_type", "agent", "duration", "seed",
                 "recover_after", "middleware", "faults", "expect")


class ScenarioError(ConfigError):
    """A scenario file that cannot be used; the message names the file and the key."""


def default_suite() -> Path:
    """The shipped suite: ``fault_scenarios/``, package data, so it is there however hils was installed."""
    return Path(str(resources.files("fault_scenarios")))


# --- validation helpers -----------------------------------------------------------------------------


class _Reader:
    """Reads keys of one TOML table, refusing what is not allowed, naming the file and the key."""

    def __init__(self, raw: Any, where: str, source: str, allowed: Iterable[str]) -> None:
        self.source = source
        self.where = where
        if not isinstance(raw, dict):
            raise ScenarioError(source, where.rstrip(".") or "<file>", "must be a table")
        self.raw = raw
        allowed = tuple(allowed)
        for key in raw:
            if key not in allowed:
                raise ScenarioError(source, f"{where}{key}", f"unknown key; allowed: {', '.join(allowed)}")

    def error(self, key: str, message: str) -> ScenarioError:
        return ScenarioError(self.source, f"{self.where}{key}", message)

    def has(self, key: str) -> bool:
        return key in self.raw

    def number(self, key: str, default: Any = None, *, integer: bool = False, low: float | None = None,
               low_open: bool = False, high: float | None = None) -> Any:
        value = self.raw.get(key, default)
        if value is None:
            raise self.error(key, "is required")
        kinds = (int,) if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds) or (
                isinstance(value, float) and not math.isfinite(value)):
            raise self.error(key, f"must be {'an integer' if integer else 'a finite number'}, got {value!r}")
        if (low is not None and (value <= low if low_open else value < low)) or (high is not None and value > high):
            lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
            hi = "" if high is None else f"<= {high:g}"
            raise self.error(key, f"is {value}; allowed: {' and '.join(x for x in (lo, hi) if x)}")
        return value if integer else float(value)

    def optional_number(self, key: str, **kwargs: Any) -> Any:
        return self.number(key, **kwargs) if key in self.raw else None

    def string(self, key: str, default: str | None = None, *, choices: Iterable[str] | None = None) -> str:
        value = self.raw.get(key, default)
        if value is None:
            raise self.error(key, "is required")
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {value!r}")
        if choices is not None:
            options = tuple(choices)
            if value not in options:
                raise self.error(key, f"is {value!r}; allowed: {', '.join(options)}")
        return value

    def strings(self, key: str, *, choices: Iterable[str]) -> tuple[str, ...]:
        """A string or a list of strings, each one of ``choices``."""
        value = self.raw.get(key)
        items = [value] if isinstance(value, str) else value
        options = tuple(choices)
        if not isinstance(items, list) or not items or not all(isinstance(v, str) for v in items):
            raise self.error(key, f"must be a string or a non-empty list of strings, got {value!r}")
        for v in items:
            if v not in options:
                raise self.error(key, f"has {v!r}; allowed: {', '.join(options)}")
        return tuple(items)

    def phases(self, key: str, allowed: Iterable[int]) -> tuple[int, ...]:
        """A non-empty list of phase numbers, each one of ``allowed``."""
        value = self.raw.get(key)
        options = sorted(allowed)
        if not isinstance(value, list) or not value or not all(
                isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise self.error(key, f"must be a non-empty list of phase numbers, got {value!r}")
        for v in value:
            if v not in options:
                raise self.error(key, f"has {v}; allowed: {', '.join(map(str, options))}")
        return tuple(sorted(set(value)))

    def boolean(self, key: str, default: bool) -> bool:
        value = self.raw.get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value


# --- faults -------------------------------------------------------------------------------------------------

_WINDOW_KEYS = ("start", "end", "count")


@dataclass(frozen=True)
class FaultType:
    """One ``type`` of ``[[faults]]``: its keys and how to build the fault from them."""

    keys: tuple[str, ...]
    build: Callable[[_Reader, str, int, ActionType], Fault]
    help: str
    per_controller: bool = True  # False: it acts on the whole run (the simulation every controller shares)
    # What the fault needs of the config of the controller it acts on: (key, problem) when it lacks it, else None.
    check: Callable[[Mapping[str, Any], IntersectionConfig], tuple[str, str] | None] | None = None

    @property
    def all_keys(self) -> tuple[str, ...]:
        return ("type", "name", *(("intersection",) if self.per_controller else ()), *self.keys)


def _window(r: _Reader) -> Window:
    start = r.number("start", 0.0, low=0)
    end = r.number("end", math.inf) if r.has("end") else math.inf
    if end <= start:
        raise r.error("end", f"is {end:g}; allowed: > start ({start:g})")
    return Window(start, end)


def _count(r: _Reader) -> int | None:
    return r.optional_number("count", integer=True, low=1)


def _ops(r: _Reader) -> frozenset[Op]:
    if not r.has("ops"):
        return frozenset(Op)
    return frozenset(Op(v) for v in r.strings("ops", choices=[o.value for o in Op]))


def _probability(r: _Reader) -> float:
    return r.number("probability", 1.0, low=0, low_open=True, high=1)


def _build_drop(r: _Reader, name: str, seed: int, _at: ActionType) -> Fault:
    return DatagramLoss(name, direction=Direction(r.string("direction", "both", choices=[d.value for d in Direction])),
                        probability=_probability(r), burst=r.number("burst", 1, integer=True, low=1),
                        seed=seed, ops=_ops(r), window=_window(r), count=_count(r))


def _build_delay(r: _Reader, name: str, seed: int, _at: ActionType) -> Fault:
    return ResponseDelay(name, delay=r.number("delay", low=0), jitter=r.number("jitter", 0.0, low=0),
                         probability=_probability(r), seed=seed, ops=_ops(r), window=_window(r), count=_count(r))


def _build_error(r: _Reader, name: str, seed: int, _at: ActionType) -> Fault:
    try:
        status = error_status(r.string("status", "genErr"))
    except ValueError as exc:
        raise r.error("status", str(exc)) from None
    return ErrorResponses(name, status=status, probability=_probability(r), seed=seed, ops=_ops(r),
                          window=_window(r), count=_count(r))


def _build_stuck(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return StuckController(name, window=_window(r), count=_count(r))


def _build_reboot(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return Reboot(name, at=r.number("at", low=0), silent_for=r.number("silent_for", low=0, low_open=True))


def _build_slow(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return SlowSteps(name, start=r.number("start", 0.0, low=0), count=r.number("count", integer=True, low=1),
                     cost=r.number("cost", low=0, low_open=True),
                     consecutive=r.number("consecutive", 1, integer=True, low=1),
                     gap=r.number("gap", 1, integer=True, low=0))


def _build_bad(r: _Reader, name: str, _seed: int, action_type: ActionType) -> Fault:
    kind = BadActionKind(r.string("action", choices=[k.value for k in BadActionKind]))
    if kind not in BAD_KINDS[action_type]:
        raise r.error("action", f"is {kind.value!r}, which a {action_type.value} agent cannot issue; allowed: "
                                f"{', '.join(sorted(BAD_KINDS[action_type]))}")
    return BadActions(name, action=kind, window=_window(r), count=_count(r))


def _build_burst(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return ActionBurst(name, size=r.number("size", integer=True, low=1), window=_window(r), count=_count(r))


def _build_during_timeout(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return ActionsDuringTimeout(name, rate_hz=r.number("rate_hz", 1.0, low=0, low_open=True, high=100),
                                window=_window(r), count=_count(r))


def _build_keepalive(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return KeepaliveSuppressed(name, window=_window(r))


def _build_preempt(r: _Reader, name: str, _seed: int, _at: ActionType) -> Fault:
    return PreemptCall(name, preempt=r.number("preempt", 1, integer=True, low=1, high=255),
                       start=r.number("start", 0.0, low=0), after=r.number("after", 0.5, low=0),
                       hold=r.number("hold", low=0, low_open=True))


def _check_preempt(raw: Mapping[str, Any], config: IntersectionConfig) -> tuple[str, str] | None:
    number = raw.get("preempt", 1)
    if number in config.preempts:
        return None
    return "preempt", (f"is {number}, which the config {config.name!r} has not; allowed: its [preempts] "
                       f"{', '.join(map(str, sorted(config.preempts))) or '(none)'}")


_TRANSPORT = ("ops", "probability", *_WINDOW_KEYS)
FAULT_TYPES: dict[str, FaultType] = {
    "drop": FaultType(("direction", "burst", *_TRANSPORT), _build_drop,
                      "datagrams lost (direction request, response or both; probability; burst)"),
    "delay": FaultType(("delay", "jitter", *_TRANSPORT), _build_delay, "answers delayed by delay +/- jitter s"),
    "snmp_error": FaultType(("status", *_TRANSPORT), _build_error, "SNMP error answers (status genErr...)"),
    "stuck": FaultType(_WINDOW_KEYS, _build_stuck, "the controller acknowledges and ignores phase calls"),
    "reboot": FaultType(("at", "silent_for"), _build_reboot, "silent for silent_for s, then power-up"),
    "slow_steps": FaultType(("start", "count", "cost", "consecutive", "gap"), _build_slow,
                            "count simulation steps costing cost s, in runs of consecutive", per_controller=False),
    "bad_actions": FaultType(("action", *_WINDOW_KEYS), _build_bad,
                             "invalid agent actions (conflict, unknown_phase, not_in_set, nan, out_of_range, "
                             "wrong_type)"),
    "action_burst": FaultType(("size", *_WINDOW_KEYS), _build_burst, "size extra actions right after each action"),
    "actions_during_timeout": FaultType(("rate_hz", *_WINDOW_KEYS), _build_during_timeout,
                                        "agent actions at rate_hz while in TIMEOUT"),
    "keepalive_off": FaultType(("start", "end"), _build_keepalive, "the middleware's keepalive switched off"),
    "preempt": FaultType(("preempt", "start", "after", "hold"), _build_preempt,
                         "preempt called at the controller after s into the first commanded transition from start, "
                         "for hold s", check=_check_preempt),
}


@dataclass(frozen=True)
class FaultSpec:
    """One validated ``[[faults]]`` entry; :meth:`build` makes a fresh fault for each run."""

    type: str
    name: str
    index: int
    raw: Mapping[str, Any]
    source: str
    intersection: str | None  # the traffic light of the controller it acts on; None: the whole run

    def acts_at(self, tls: str) -> bool:
        return self.intersection is None or self.intersection == tls

    def build(self, seed: int, action_type: ActionType) -> Fault:
        r = _Reader(dict(self.raw), f"faults[{self.index}].", self.source, FAULT_TYPES[self.type].all_keys)
        # Each fault draws from its own stream, so adding a fault leaves the others' draws alone.
        return FAULT_TYPES[self.type].build(r, self.name, seed * 1009 + self.index, action_type)


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


def _status_name(status: UnitControlStatus) -> str:
    return status.name.lower()


_STATUS_NAMES = {_status_name(s): s for s in UnitControlStatus}


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
    r = _Reader(raw, "expect.", source, (*_EXPECT_KEYS, *(intersections if several else ())))
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
    r = _Reader(raw, where, source, _EXPECT_KEYS)
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
    records = _Reader(r.raw.get("records", {}), f"{where}records.", source, [k.value for k in Kind])
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
        no_conflicting_command=r.boolean("no_conflicting_command", True),
        no_conflicting_indication=r.boolean("no_conflicting_indication", True),
        no_commands_in_timeout=r.boolean("no_commands_in_timeout", True),
        log_complete=r.boolean("log_complete", True),
    )


# --- the scenario ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scenario:
    name: str
    source: str
    description: str
    config: IntersectionConfig  # the first intersection's, with several
    action_type: ActionType
    agent: str | None
    duration: float
    seed: int
    recover_after: float | None
    faults: tuple[FaultSpec, ...]
    expect: Expectations  # every intersection's, but for those of expect_at
    intersections: Mapping[str, IntersectionConfig]  # traffic light -> its controller's config
    network: Network | None = None  # the scenario of several controllers run, if one was named
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


def load_scenario(path: str | Path) -> Scenario:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(str(p), "<file>", f"cannot be read ({exc.strerror})") from None
    return parse_scenario(text, str(p), base=p.parent, default_name=p.stem)


def parse_scenario(text: str, source: str = "<memory>", *, base: Path | None = None,
                   default_name: str = "scenario") -> Scenario:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(source, "<file>", f"is not valid TOML ({exc})") from None
    r = _Reader(raw, "", source, SCENARIO_KEYS)
    network = _network(r, base)
    intersections = dict(network.intersections) if network is not None else {TLS_ID: _config(r, base)}
    action_type = ActionType(r.string("action_type", ActionType.SELECTION.value, choices=[t.value for t in ActionType]))
    recover_after = r.number("recover_after", 5.0)
    faults = _fault_specs(r, source, action_type, tuple(intersections))
    for spec in faults:
        check = FAULT_TYPES[spec.type].check
        problems = [check(spec.raw, cfg) for tls, cfg in intersections.items() if check and spec.acts_at(tls)]
        if problem := next((p for p in problems if p), None):
            raise ScenarioError(source, f"faults[{spec.index}].{problem[0]}", problem[1])
    expect, expect_at = _expect_tables(raw.get("expect", {}), source, faults, intersections)
    scenario = Scenario(
        name=r.string("name", default_name),
        source=source,
        description=r.string("description", ""),
        config=next(iter(intersections.values())),
        action_type=action_type,
        agent=r.string("agent") if r.has("agent") else None,
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
        for config in intersections.values():
            load_agent(scenario.spec().agent_spec, config, action_type, scenario.seed)
    except AgentError as exc:
        raise r.error("agent", str(exc)) from None
    return scenario


def _config(r: _Reader, base: Path | None) -> IntersectionConfig:
    try:
        if r.has("config"):
            path = Path(r.string("config"))
            cfg = config_mod.load(path if path.is_absolute() or base is None else base / path)
        else:
            cfg = config_mod.load()
    except ConfigError as exc:
        raise r.error("config", str(exc)) from None
    return _with_overrides(r, cfg)


def _network(r: _Reader, base: Path | None) -> Network | None:
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
        network = load_network(where)
    except ConfigError as exc:
        raise r.error("scenario", str(exc)) from None
    return replace(network, intersections={tls: _with_overrides(r, cfg) for tls, cfg in network.intersections.items()})


def _with_overrides(r: _Reader, cfg: IntersectionConfig) -> IntersectionConfig:
    overrides = _Reader(r.raw.get("middleware", {}), "middleware.", r.source, MiddlewareParams.__dataclass_fields__)
    try:
        return cfg.with_middleware(**overrides.raw) if overrides.raw else cfg
    except ConfigError as exc:
        raise ScenarioError(r.source, exc.field, exc.message) from None


def _fault_specs(r: _Reader, source: str, action_type: ActionType, intersections: tuple[str, ...]) -> list[FaultSpec]:
    raw = r.raw.get("faults")
    if not isinstance(raw, list) or not raw or not all(isinstance(f, dict) for f in raw):
        raise r.error("faults", "must be a non-empty array of tables ([[faults]])")
    specs, names = [], set()
    for i, item in enumerate(raw):
        where = f"faults[{i}]."
        kind = item.get("type")
        if kind not in FAULT_TYPES:
            raise ScenarioError(source, f"{where}type", f"is {kind!r}; allowed: {', '.join(FAULT_TYPES)}")
        fault_type = FAULT_TYPES[kind]
        if not fault_type.per_controller and "intersection" in item:
            raise ScenarioError(source, f"{where}intersection", f"not allowed: {kind} acts on the one simulation "
                                                                f"every controller shares")
        fr = _Reader(item, where, source, fault_type.all_keys)
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
    """Scenario files: each path is a file, or a directory whose ``*.toml`` files are taken in name order."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out.extend(sorted(p.glob("*.toml")))
        elif p.is_file():
            out.append(p)
        else:
            raise ScenarioError(str(p), "<file>", "does not exist")
    return out


# --- running and judging ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Check:
    """One expectation and what happened."""

    expectation: str
    ok: bool
    message: str  # what was expected and, if it failed, what happened instead
    intersection: str | None = None  # the one judged, in a run of several controllers

    @property
    def label(self) -> str:
        return self.expectation if self.intersection is None else f"[{self.intersection}] {self.expectation}"


@dataclass(frozen=True)
class FaultReport:
    name: str
    kind: str
    description: str
    fired: int
    first_fired: float | None
    details: Mapping[str, int]
    intersection: str | None = None  # where it acted, in a run of several controllers

    @property
    def label(self) -> str:
        return self.name if self.intersection is None else f"{self.name} at {self.intersection}"


@dataclass(frozen=True)
class Episode:
    """One stay in TIMEOUT."""

    reason: str
    entered: float
    command_id: int | None
    recovery_called: float | None  # the recover() call that succeeded
    recovered: float | None
    failed_recoveries: int
    intersection: str | None = None  # whose controller, in a run of several


@dataclass(frozen=True)
class Outcome:
    """What happened at one intersection of a run."""

    intersection: str
    faults: tuple[str, ...]  # the faults that acted on it
    episodes: tuple[Episode, ...]
    detection_s: float | None
    recovery_s: float | None
    verified: int  # transitions verified
    longest_unverified: tuple[float, float]  # the longest stretch (from, to) without a verified transition

    def to_json(self) -> dict[str, Any]:
        start, end = self.longest_unverified
        return {"intersection": self.intersection, "faults": list(self.faults),
                "timeouts": [e.reason for e in self.episodes], "detection_s": _round(self.detection_s),
                "recovery_s": _round(self.recovery_s), "transitions_verified": self.verified,
                "longest_unverified_s": _round(end - start)}


@dataclass(frozen=True)
class ScenarioResult:
    scenario: Scenario
    checks: tuple[Check, ...]
    faults: tuple[FaultReport, ...]
    records: int
    wall_s: float
    outcomes: tuple[Outcome, ...]  # one per intersection

    @property
    def episodes(self) -> list[Episode]:
        """Every intersection's TIMEOUT episodes, in time order."""
        return sorted((e for o in self.outcomes for e in o.episodes), key=lambda e: e.entered)

    @property
    def detection_s(self) -> float | None:
        """With several controllers: the slowest intersection's."""
        return max((o.detection_s for o in self.outcomes if o.detection_s is not None), default=None)

    @property
    def recovery_s(self) -> float | None:
        """The slowest, at any intersection."""
        return max((o.recovery_s for o in self.outcomes if o.recovery_s is not None), default=None)

    @property
    def passed(self) -> bool:
        return all(c.ok for c in self.checks)

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.ok]

    def passed_at(self, tls: str) -> bool:
        """Every check of intersection ``tls`` held, and every check of the whole run."""
        return all(c.ok for c in self.checks if c.intersection in (None, tls))

    def fired_text(self) -> str:
        return ", ".join(f"{f.label} x{f.fired}" for f in self.faults)

    def timeouts_text(self) -> str:
        """How many TIMEOUT episodes, and where when several controllers ran."""
        where = sorted({e.intersection for e in self.episodes if e.intersection is not None})
        return f"{len(self.episodes)}" + (f" at {', '.join(where)}" if where else "")

    def to_json(self) -> dict[str, Any]:
        doc = {
            "scenario": self.scenario.name,
            "seed": self.scenario.seed,
            "source": self.scenario.source,
            "passed": self.passed,
            "detection_s": _round(self.detection_s),
            "recovery_s": _round(self.recovery_s),
            "timeouts": [{k: _round(v) if isinstance(v, float) else v for k, v in asdict(e).items()}
                         for e in self.episodes],
            "faults": [asdict(f) for f in self.faults],
            "checks": [asdict(c) for c in self.checks],
            "records": self.records,
            "wall_s": round(self.wall_s, 4),
            "sim_s": self.scenario.duration,
        }
        if self.scenario.several:
            doc["intersections"] = [{**o.to_json(), "passed": self.passed_at(o.intersection)}
                                    for o in self.outcomes]
        return doc


def _round(t: float | None) -> float | None:
    return None if t is None else round(t, 6)


def run_scenario(scenario: Scenario, *, log_path: Path | None = None) -> ScenarioResult:
    """Run one scenario in virtual time, without SUMO, and judge its expectations."""
    t0 = time.perf_counter()
    faults = scenario.build_faults()
    placed = list(zip(scenario.faults, faults, strict=True))
    monitors: dict[str, IndicationMonitor] = {}

    def target_factory(tls: str) -> Callable[..., FaultTarget]:
        # Each controller's target carries only the faults placed on it: the others' links stay whole.
        here = [fault for spec, fault in placed if spec.acts_at(tls)]

        def make(env: Any, config: IntersectionConfig, *, seed: int, fast_path: bool) -> FaultTarget:
            target = FaultTarget(env, config, seed=seed, faults=here, fast_path=fast_path)
            monitors[tls] = IndicationMonitor(env, target.controller, config)
            return target
        return make

    def configure(run: Testbed) -> None:
        for spec, fault in placed:
            fault.on_run(run, None if spec.intersection is None else run.intersections[spec.intersection])

    with Testbed(None if scenario.network else scenario.config, scenario=scenario.network,
                 action_type=scenario.action_type, target={tls: target_factory(tls) for tls in scenario.intersections},
                 seed=scenario.seed, agent=scenario.agent, duration=scenario.duration, log_path=log_path,
                 recover_after=scenario.recover_after, on_reset=configure) as tb:
        tb.reset_all()
        tb.run()
        records = tb.records
    return evaluate(scenario, records, faults, monitors, wall_s=time.perf_counter() - t0)


def _episodes(records: list[dict[str, Any]], intersection: str | None) -> list[Episode]:
    out: list[Episode] = []
    current: dict[str, Any] | None = None
    for rec in records:
        kind = rec["kind"]
        if kind == Kind.TIMEOUT_ENTERED:
            current = {"reason": rec["reason"], "entered": rec["t"], "command_id": rec.get("command_id"),
                       "calls": [], "recovered": None}
        elif current is None:
            continue
        elif kind == Kind.RECOVERY_STARTED:
            current["calls"].append(rec["t"])
        elif kind == Kind.RECOVERED:
            current["recovered"] = rec["t"]
            out.append(_episode(current, intersection))
            current = None
    if current is not None:
        out.append(_episode(current, intersection))
    return out


def _episode(d: dict[str, Any], intersection: str | None) -> Episode:
    calls = d["calls"]
    if d["recovered"] is None:
        return Episode(d["reason"], d["entered"], d["command_id"], None, None, len(calls), intersection)
    return Episode(d["reason"], d["entered"], d["command_id"], calls[-1] if calls else None, d["recovered"],
                   max(0, len(calls) - 1), intersection)


Checker = Callable[[str, bool, str], None]


def evaluate(scenario: Scenario, records: list[dict[str, Any]], faults: list[Fault],
             monitors: Mapping[str, IndicationMonitor], *, wall_s: float = 0.0) -> ScenarioResult:
    """Judge a run's records, faults and controller samples (``monitors``: each traffic light's) against the
    scenario's expectations, intersection by intersection."""
    checks: list[Check] = []

    def checker(tls: str | None) -> Checker:
        where = scenario.shown(tls)
        return lambda name, ok, message: checks.append(Check(name, ok, message, where))

    placed = list(zip(scenario.faults, faults, strict=True))
    for spec, f in placed:
        checker(spec.intersection)(
            f"fault {f.name} fired", f.fired > 0, f"fault {f.name!r} ({f.describe()}) to fire at least once" + (
                f"; fired {f.fired} times" if f.fired else "; it never fired, so the scenario proves nothing about it"))
    seq_problems = _seq_problems(records)
    outcomes = []
    for tls, cfg in scenario.intersections.items():
        # Its own records, and the run-wide ones (run_started, run_ended), which name no intersection.
        mine = [r for r in records if r.get("intersection", tls) == tls] if scenario.several else records
        outcomes.append(_judge(scenario, tls, cfg, mine, [f for spec, f in placed if spec.acts_at(tls)],
                               monitors.get(tls), seq_problems, checker(tls)))
    reports = tuple(FaultReport(f.name, f.kind, f.describe(), f.fired, f.first_fired, dict(f.details),
                                scenario.shown(spec.intersection)) for spec, f in placed)
    return ScenarioResult(scenario, tuple(checks), reports, len(records), wall_s, tuple(outcomes))


def _judge(scenario: Scenario, tls: str, cfg: IntersectionConfig, records: list[dict[str, Any]], faults: list[Fault],
           monitor: IndicationMonitor | None, seq_problems: list[str], check: Checker) -> Outcome:
    """Check one intersection's expectations on its records, faults and controller samples."""
    ex = scenario.expectations(tls)
    episodes = _episodes(records, scenario.shown(tls))
    by_kind: dict[str, list[dict[str, Any]]] = {}
    for rec in records:
        by_kind.setdefault(rec["kind"], []).append(rec)

    # Detection: from the reference fault's first firing (or the command's dispatch) to the first TIMEOUT after it.
    fired = [f for f in faults if f.first_fired is not None]
    ref_fault = next((f for f in fired if f.name == ex.after_fault), None) if ex.after_fault else (
        min(fired, key=lambda f: f.first_fired) if fired else None)
    detection = None
    first_episode = None
    if ref_fault is not None:
        first_episode = next((e for e in episodes if e.entered >= ref_fault.first_fired), None)
    if first_episode is not None:
        if ex.detect_from == "dispatch":
            dispatched = {r["command_id"]: r["t"] for r in by_kind.get(Kind.COMMAND_DISPATCHED, [])}
            start = dispatched.get(first_episode.command_id)
            detection = None if start is None else first_episode.entered - start
        else:
            detection = first_episode.entered - ref_fault.first_fired
    recoveries = [e.recovered - e.recovery_called for e in episodes if e.recovered is not None]
    verified = [r["t"] for r in by_kind.get(Kind.TRANSITION_VERIFIED, []) if r["t"] <= scenario.duration]
    marks = [0.0, *verified, scenario.duration]
    longest = max(itertools.pairwise(marks), key=lambda gap: gap[1] - gap[0])

    _check_timeouts(ex, episodes, check)
    if ex.detect_within is not None:
        _check_detection(ex, ref_fault, first_episode, detection, check)
    if ex.recover_within is not None:
        _check_recovery(ex, episodes, check)
    if ex.recovered_greens is not None:
        _check_recovered_greens(ex.recovered_greens, by_kind.get(Kind.RECOVERED, []), check)
    if ex.verified_every is not None:
        gap = longest[1] - longest[0]
        check("verified_every", gap <= ex.verified_every,
              f"a transition verified at least every {ex.verified_every:g} s ({len(verified)} verified)" + (
                  "" if gap <= ex.verified_every else
                  f"; got {gap:.3f} s without one, from {longest[0]:.3f} s to {longest[1]:.3f} s"))
    _check_actions(ex, by_kind, check)
    if ex.preemptions is not None:
        _check_preemptions(ex.preemptions, records, check)
    for kind, n in ex.records.items():
        got = len(by_kind.get(kind, []))
        check(f"records.{kind}", got == n, f"{n} {kind} records" + ("" if got == n else f"; got {got}"))
    if ex.no_conflicting_command:
        _check_commands(cfg, by_kind.get(Kind.SET_SENT, []), check)
    if ex.no_commands_in_timeout:
        _check_quiet_in_timeout(records, check)
    if ex.no_conflicting_indication or ex.control_status_seen or ex.control_status_never:
        _check_controller(ex, monitor, check)
    if ex.log_complete:
        _check_log(records, cfg, seq_problems, check)
    return Outcome(tls, tuple(f.name for f in faults), tuple(episodes), detection, max(recoveries, default=None),
                   len(verified), longest)


def _check_timeouts(ex: Expectations, episodes: list[Episode], check: Checker) -> None:
    seen = ", ".join(f"{e.reason} at {e.entered:.3f} s" for e in episodes) or "none"
    if ex.timeout == (NO_TIMEOUT,):
        check("timeout", not episodes, "no TIMEOUT" + ("" if not episodes else f"; got TIMEOUT: {seen}"))
    elif ex.timeout != (ANY_TIMEOUT,):
        allowed = set(ex.timeout)
        wrong = [e for e in episodes if e.reason not in allowed]
        ok = bool(episodes) and not wrong
        want = " or ".join(ex.timeout)
        check("timeout", ok, f"TIMEOUT because of {want}" + ("" if ok else f"; got: {seen}"))
    if ex.timeouts is not None:
        check("timeouts", len(episodes) == ex.timeouts,
              f"{ex.timeouts} TIMEOUT episodes" + ("" if len(episodes) == ex.timeouts else
                                                   f"; got {len(episodes)}: {seen}"))


def _check_detection(ex: Expectations, ref: Fault | None, episode: Episode | None, detection: float | None,
                     check: Checker) -> None:
    origin = "the dispatch of the command that timed out" if ex.detect_from == "dispatch" else (
        f"fault {ref.name!r} first fired" if ref else "the fault first fired")
    want = f"TIMEOUT within {ex.detect_within:g} s after {origin}"
    if ref is None or ref.first_fired is None:
        check("detect_within", False, f"{want}; no fault fired")
    elif episode is None:
        check("detect_within", False, f"{want} (at {ref.first_fired:.3f} s); no TIMEOUT followed")
    elif detection is None:
        check("detect_within", False, f"{want}; TIMEOUT at {episode.entered:.3f} s has no dispatched command")
    else:
        ok = 0.0 <= detection <= ex.detect_within
        check("detect_within", ok, want + ("" if ok else
                                           f"; got TIMEOUT ({episode.reason}) at {episode.entered:.3f} s, "
                                           f"{detection:.3f} s after"))


def _check_recovery(ex: Expectations, episodes: list[Episode], check: Checker) -> None:
    want = f"every TIMEOUT back to IDLE within {ex.recover_within:g} s of the recover() call that succeeded"
    problems = []
    for e in episodes:
        if e.recovered is None:
            problems.append(f"TIMEOUT ({e.reason}) at {e.entered:.3f} s never recovered "
                            f"({e.failed_recoveries} recover() calls failed)")
        elif e.recovered - e.recovery_called > ex.recover_within:
            problems.append(f"TIMEOUT at {e.entered:.3f} s took {e.recovered - e.recovery_called:.3f} s to recover")
    check("recover_within", not problems, want + ("" if not problems else "; got: " + "; ".join(problems)))


def _check_recovered_greens(greens: tuple[int, ...], recovered: list[dict[str, Any]], check: Checker) -> None:
    want = f"every recovery found phases {list(greens)} green"
    wrong = [f"{sorted(r['greens'])} at {r['t']:.3f} s" for r in recovered if sorted(r["greens"]) != list(greens)]
    ok = bool(recovered) and not wrong
    check("recovered_greens", ok, want + ("" if ok else "; got " + ("; ".join(wrong) if wrong else "no recovery")))


def _check_actions(ex: Expectations, by_kind: dict[str, list[dict[str, Any]]],
                   check: Checker) -> None:
    refused = by_kind.get(Kind.ACTION_REFUSED, [])
    if ex.refused is not None:
        ids = {r["action_id"] for r in refused}
        sent_for = sorted(r["action_id"] for r in by_kind.get(Kind.COMMAND_DISPATCHED, []) if r["action_id"] in ids)
        ok = len(refused) == ex.refused and not sent_for
        got = f"; got {len(refused)} refused" + (f", commands dispatched for refused actions {sent_for}"
                                                 if sent_for else "")
        check("refused", ok, f"{ex.refused} actions refused and nothing sent for them" + ("" if ok else got))
    if ex.refused_reason is not None:
        other = sorted({r["reason"] for r in refused} - {ex.refused_reason})
        ok = bool(refused) and not other
        check("refused_reason", ok, f"refusals because of {ex.refused_reason}" + (
            "" if ok else f"; got reasons {other or 'none (nothing refused)'}"))
    dropped = by_kind.get(Kind.ACTION_DROPPED, [])
    for key, state, least in (("dropped_on_hold", "on_hold", ex.dropped_on_hold),
                              ("dropped_in_timeout", "timeout", ex.dropped_in_timeout)):
        if least is not None:
            got = sum(1 for r in dropped if r["state"] == state)
            check(key, got >= least, f"at least {least} actions dropped while {state.upper()}" + (
                "" if got >= least else f"; got {got}"))


def _check_commands(cfg: IntersectionConfig, sets: list[dict[str, Any]],
                    check: Checker) -> None:
    bad = []
    for r in sets:
        phases = sorted(r["phases"])
        unknown = [p for p in phases if p not in cfg.phases]
        clash = [(a, b) for i, a in enumerate(phases) for b in phases[i + 1:] if not cfg.compatible(a, b)]
        if unknown or clash:
            bad.append(f"set_sent seq {r['seq']} at {r['t']:.3f} s phases {phases}")
    check("no_conflicting_command", not bad,
          f"no SET of conflicting or unknown phases ({len(sets)} SETs checked)" + (
              "" if not bad else "; got: " + "; ".join(bad[:5])))


def _check_quiet_in_timeout(records: list[dict[str, Any]], check: Checker) -> None:
    in_timeout = False
    bad = []
    for r in records:
        if r["kind"] == Kind.TIMEOUT_ENTERED:
            in_timeout = True
        elif r["kind"] == Kind.RECOVERED:
            in_timeout = False
        elif in_timeout and r["kind"] == Kind.SET_SENT and r["purpose"] in ("command", "keepalive"):
            bad.append(f"{r['purpose']} SET at {r['t']:.3f} s")
    check("no_commands_in_timeout", not bad,
          "no command or keepalive SET while in TIMEOUT" + ("" if not bad else "; got: " + "; ".join(bad[:5])))


def _check_preemptions(expected: int, records: list[dict[str, Any]], check: Checker) -> None:
    """Each PREEMPTED episode (preempt_begin to preempt_end): ended by the controller, not by a TIMEOUT; no
    command, retry or recovery SET within it; a transition verified after it."""
    episodes: list[dict[str, Any]] = []
    for r in records:
        kind, open_ = r["kind"], episodes and episodes[-1]["end"] is None
        if kind == Kind.PREEMPT_BEGIN:
            episodes.append({"begin": r["t"], "end": None, "sent": [], "cut": False, "verified": False})
        elif open_ and kind == Kind.PREEMPT_END:
            episodes[-1]["end"] = r["t"]
        elif open_ and kind == Kind.TIMEOUT_ENTERED:
            episodes[-1]["cut"] = True
        elif open_ and kind == Kind.SET_SENT and r["purpose"] in ("command", "retry", "recovery"):
            episodes[-1]["sent"].append(f"{r['purpose']} SET at {r['t']:.3f} s")
        elif episodes and not open_ and kind == Kind.TRANSITION_VERIFIED:
            episodes[-1]["verified"] = True
    problems = [f"{len(episodes)} episodes"] if len(episodes) != expected else []
    for e in episodes:
        at = f"the preemption at {e['begin']:.3f} s"
        if e["end"] is None or e["cut"]:
            problems.append(f"{at} " + ("was cut by a TIMEOUT" if e["cut"] else "never ended"))
        if e["sent"]:
            problems.append(f"{at} sent " + ", ".join(e["sent"][:3]))
        if e["end"] is not None and not e["verified"]:
            problems.append(f"no transition verified after {at}")
    check("preemptions", not problems,
          f"{expected} preemptions, each ended by the controller, no command SET while PREEMPTED, commanding "
          "resumed after each" + ("" if not problems else "; got: " + "; ".join(problems)))


def _check_controller(ex: Expectations, monitor: IndicationMonitor | None,
                      check: Checker) -> None:
    if monitor is None:
        check("controller", False, "controller samples needed, but the target has no controller to sample")
        return
    if ex.no_conflicting_indication:
        bad = [f"{list(c.phases)} at {c.t:.3f} s" for c in monitor.conflicts[:5]]
        if monitor.mmu_flash_at is not None:
            bad.append(f"MMU flash at {monitor.mmu_flash_at:.3f} s")
        check("no_conflicting_indication", not bad,
              f"the controller never showed conflicting phases ({monitor.samples} samples)" + (
                  "" if not bad else "; got: " + "; ".join(bad)))
    seen = {_status_name(s): t for s, t in monitor.status_first_seen.items()}
    for name in ex.control_status_seen:
        check("control_status_seen", name in seen, f"unitControlStatus {name} seen" + (
            f" (first at {seen[name]:.3f} s)" if name in seen else f"; got only {sorted(seen)}"))
    for name in ex.control_status_never:
        check("control_status_never", name not in seen, f"unitControlStatus never {name}" + (
            "" if name not in seen else f"; got {name} at {seen[name]:.3f} s"))


def _seq_problems(records: list[dict[str, Any]]) -> list[str]:
    """The whole log's sequence numbers run from 0 without a gap."""
    seqs = [r["seq"] for r in records]
    if seqs == list(range(len(records))):
        return []
    gap = next((i for i, s in enumerate(seqs) if s != i), len(seqs))
    return [f"seq not gapless from 0 (first break at position {gap})"]


def _check_log(records: list[dict[str, Any]], cfg: IntersectionConfig, seq_problems: list[str],
               check: Checker) -> None:
    problems = list(seq_problems)
    if not records or records[0]["kind"] != Kind.RUN_STARTED or records[-1]["kind"] != Kind.RUN_ENDED:
        problems.append("the log does not run from run_started to run_ended")
    ends: dict[int, int] = {}
    for r in records:
        if r["kind"] == Kind.HOLD_RELEASED:
            ends[r["command_id"]] = ends.get(r["command_id"], 0) + 1
    dispatched = [r["command_id"] for r in records if r["kind"] == Kind.COMMAND_DISPATCHED]
    final_state = next((r["to"] for r in reversed(records) if r["kind"] == Kind.STATE), "idle")
    for i, cid in enumerate(dispatched):
        n = ends.get(cid, 0)
        # Only the last command may still be ON_HOLD when the run ends.
        if n > 1 or (n == 0 and not (i == len(dispatched) - 1 and final_state == "on_hold")):
            problems.append(f"command {cid} ended {n} times")
    answers: dict[tuple[Any, str], int] = {}
    for r in records:
        if r["kind"] in (Kind.SET_ANSWERED, Kind.SET_FAILED):
            key = (r["command_id"], r["purpose"])
            answers[key] = answers.get(key, 0) + 1
    end_t = records[-1]["t"] if records else 0.0
    unanswered = 0
    for r in records:
        if r["kind"] == Kind.SET_SENT:
            key = (r["command_id"], r["purpose"])
            if answers.get(key, 0) > 0:
                answers[key] -= 1
            elif end_t - r["t"] >= cfg.middleware.tau_udp:
                unanswered += 1  # a SET still in flight at the end of the run is not missing
    if unanswered:
        problems.append(f"{unanswered} SETs neither answered nor failed")
    check("log_complete", not problems, f"every event logged ({len(records)} records)" + (
        "" if not problems else "; got: " + "; ".join(problems[:5])))
