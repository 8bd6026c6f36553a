"""Judging a fault scenario's run: its records, its faults and its controllers' samples against the expectations
of :class:`~harness.faults.reader.Expectations`, into a :class:`FaultScenarioResult` of checks (each a
:class:`Check`: what was expected and, if it failed, what happened instead) and, per intersection, an
:class:`Outcome` (its TIMEOUT episodes, detection and recovery times, verified transitions).

Implicit expectations, always checked: every fault fired at least once (a
scenario cannot pass because its fault never happened); no SET holds two
conflicting phases or an unknown one; the controller never showed two
conflicting signals, two phases or an overlap and a phase (sampled every tick;
conflicts as :mod:`hils.protocol.conflict`, the one check, finds them), nor went
to MMU flash; no command or keepalive was sent while in TIMEOUT; the log is
whole (seq gapless from 0, the run started and ended, every dispatched command
ended exactly once, every SET was answered or failed). Each can be switched off
in ``[expect]`` (``no_conflicting_command``, ``no_conflicting_indication``,
``no_commands_in_timeout``, ``log_complete`` = false) for a scenario that studies
that very failure. A scenario with no ``timeout`` key expects no TIMEOUT.

With several controllers every expectation, implicit ones included, is judged
for each intersection on its own records (those naming it) and its own
controller's samples, and the report gives each intersection's outcome.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

from harness.faults.inject import Fault, IndicationMonitor
from harness.faults.reader import ANY_TIMEOUT, NO_TIMEOUT, Expectations, FaultScenario, status_name
from hils.protocol.config import IntersectionConfig
from hils.protocol.conflict import first_conflict
from hils.protocol.ntcip import ControlColumn
from hils.shell.events import Kind

__all__ = ["Check", "Episode", "FaultReport", "FaultScenarioResult", "Outcome", "evaluate"]


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
class FaultScenarioResult:
    scenario: FaultScenario
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


def evaluate(scenario: FaultScenario, records: list[dict[str, Any]], faults: list[Fault],
             monitors: Mapping[str, IndicationMonitor], *, wall_s: float = 0.0) -> FaultScenarioResult:
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
    return FaultScenarioResult(scenario, tuple(checks), reports, len(records), wall_s, tuple(outcomes))


def _judge(scenario: FaultScenario, tls: str, cfg: IntersectionConfig, records: list[dict[str, Any]],
           faults: list[Fault], monitor: IndicationMonitor | None, seq_problems: list[str], check: Checker) -> Outcome:
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
    if ex.held_as_scheduled_from is not None:
        _check_held(ex.held_as_scheduled_from, scenario, by_kind.get(Kind.SCHEDULE_STARTED, []), monitor, check)
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
        if unknown or first_conflict(cfg.permissives, phases) is not None:
            bad.append(f"set_sent seq {r['seq']} at {r['t']:.3f} s phases {phases}")
    check("no_conflicting_command", not bad,
          f"no SET of conflicting or unknown phases ({len(sets)} SETs checked)" + (
              "" if not bad else "; got: " + "; ".join(bad[:5])))


def _check_held(since: float, scenario: FaultScenario, started: list[dict[str, Any]],
                monitor: IndicationMonitor | None, check: Checker) -> None:
    """From ``since`` to the end, every change of the controller's control objects (and what they held at ``since``)
    is what the schedule asks then, counted from its receipt; force-offs aside (the controller resets them itself
    when their green ends)."""
    if not started or monitor is None:
        check("held_as_scheduled_from", False, "a schedule started and the controller sampled; got "
              f"{len(started)} schedules started")
        return
    received = started[0]["t"]
    changes = monitor.controls
    # each change, and half a second after each instant of the schedule (a change that should have come)
    moments = sorted({since, *(t for t, _ in changes if t > since),
                      *(t for i in scenario.schedule.instants if since < (t := received + i / 10 + 0.5)
                        <= scenario.duration)})
    wrong = []
    for t in moments:
        held = next(h for at, h in reversed(changes) if at <= t)
        asked = scenario.schedule.at(math.floor((t - received) * 10 + 1e-6))
        if any(held[c] != asked[c] for c in ControlColumn if c is not ControlColumn.FORCE_OFF):
            wrong.append(f"at {t:.1f} s the controller held {_named(held)}, the schedule asks {_named(asked)}")
    check("held_as_scheduled_from", not wrong, f"the controller holds what the schedule asks from {since:g} s"
          + ("" if not wrong else "; " + "; ".join(wrong[:3])))


def _named(controls: Mapping[ControlColumn, frozenset[int]]) -> str:
    return ", ".join(f"{c.name.lower()} {sorted(p)}" for c, p in controls.items() if p) or "nothing"


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
        bad = [f"{c.conflict} at {c.t:.3f} s" for c in monitor.conflicts[:5]]
        if monitor.mmu_flash_at is not None:
            bad.append(f"MMU flash at {monitor.mmu_flash_at:.3f} s")
        check("no_conflicting_indication", not bad,
              f"the controller never showed conflicting phases ({monitor.samples} samples)" + (
                  "" if not bad else "; got: " + "; ".join(bad)))
    seen = {status_name(s): t for s, t in monitor.status_first_seen.items()}
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
