"""The fault registry: every ``type`` a ``[[faults]]`` table may name, with its keys and how its fault is built.

:data:`FAULT_TYPES` is the table, one row a type: its keys (besides ``type``, ``name`` and, for a fault that acts
on one controller, ``intersection``), the function that builds the fault of :mod:`harness.faults.inject` from a
validated table, and the one-line help. A new fault type is a builder and a row. A :class:`FaultSpec` is one
validated entry of a file; it builds a fresh fault for each run, each drawing from its own random stream.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
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
from harness.faults.table import TableReader
from hils.control.actions import ActionType
from hils.protocol.config import IntersectionConfig

__all__ = ["FAULT_TYPES", "FaultSpec", "FaultType"]


_WINDOW_KEYS = ("start", "end", "count")


@dataclass(frozen=True)
class FaultType:
    """One ``type`` of ``[[faults]]``: its keys and how to build the fault from them."""

    keys: tuple[str, ...]
    build: Callable[[TableReader, str, int, ActionType], Fault]
    help: str
    per_controller: bool = True  # False: it acts on the whole run (the simulation every controller shares)
    # What the fault needs of the config of the controller it acts on: (key, problem) when it lacks it, else None.
    check: Callable[[Mapping[str, Any], IntersectionConfig], tuple[str, str] | None] | None = None

    @property
    def all_keys(self) -> tuple[str, ...]:
        return ("type", "name", *(("intersection",) if self.per_controller else ()), *self.keys)


def _window(r: TableReader) -> Window:
    start = r.number("start", 0.0, low=0)
    end = r.number("end", math.inf) if r.has("end") else math.inf
    if end <= start:
        raise r.error("end", f"is {end:g}; allowed: > start ({start:g})")
    return Window(start, end)


def _count(r: TableReader) -> int | None:
    return r.optional_number("count", integer=True, low=1)


def _ops(r: TableReader) -> frozenset[Op]:
    if not r.has("ops"):
        return frozenset(Op)
    return frozenset(Op(v) for v in r.strings("ops", choices=[o.value for o in Op]))


def _probability(r: TableReader) -> float:
    return r.number("probability", 1.0, low=0, low_open=True, high=1)


def _build_drop(r: TableReader, name: str, seed: int, _at: ActionType) -> Fault:
    return DatagramLoss(name, direction=Direction(r.string("direction", "both", choices=[d.value for d in Direction])),
                        probability=_probability(r), burst=r.number("burst", 1, integer=True, low=1),
                        seed=seed, ops=_ops(r), window=_window(r), count=_count(r))


def _build_delay(r: TableReader, name: str, seed: int, _at: ActionType) -> Fault:
    return ResponseDelay(name, delay=r.number("delay", low=0), jitter=r.number("jitter", 0.0, low=0),
                         probability=_probability(r), seed=seed, ops=_ops(r), window=_window(r), count=_count(r))


def _build_error(r: TableReader, name: str, seed: int, _at: ActionType) -> Fault:
    try:
        status = error_status(r.string("status", "genErr"))
    except ValueError as exc:
        raise r.error("status", str(exc)) from None
    return ErrorResponses(name, status=status, probability=_probability(r), seed=seed, ops=_ops(r),
                          window=_window(r), count=_count(r))


def _build_stuck(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return StuckController(name, window=_window(r), count=_count(r))


def _build_reboot(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return Reboot(name, at=r.number("at", low=0), silent_for=r.number("silent_for", low=0, low_open=True))


def _build_slow(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return SlowSteps(name, start=r.number("start", 0.0, low=0), count=r.number("count", integer=True, low=1),
                     cost=r.number("cost", low=0, low_open=True),
                     consecutive=r.number("consecutive", 1, integer=True, low=1),
                     gap=r.number("gap", 1, integer=True, low=0))


def _build_bad(r: TableReader, name: str, _seed: int, action_type: ActionType) -> Fault:
    kind = BadActionKind(r.string("action", choices=[k.value for k in BadActionKind]))
    if kind not in BAD_KINDS[action_type]:
        raise r.error("action", f"is {kind.value!r}, which a {action_type.value} agent cannot issue; allowed: "
                                f"{', '.join(sorted(BAD_KINDS[action_type]))}")
    return BadActions(name, action=kind, window=_window(r), count=_count(r))


def _build_burst(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return ActionBurst(name, size=r.number("size", integer=True, low=1), window=_window(r), count=_count(r))


def _build_during_timeout(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return ActionsDuringTimeout(name, rate_hz=r.number("rate_hz", 1.0, low=0, low_open=True, high=100),
                                window=_window(r), count=_count(r))


def _build_keepalive(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
    return KeepaliveSuppressed(name, window=_window(r))


def _build_preempt(r: TableReader, name: str, _seed: int, _at: ActionType) -> Fault:
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
        r = TableReader(dict(self.raw), f"faults[{self.index}].", self.source, FAULT_TYPES[self.type].all_keys)
        # Each fault draws from its own stream, so adding a fault leaves the others' draws alone.
        return FAULT_TYPES[self.type].build(r, self.name, seed * 1009 + self.index, action_type)

