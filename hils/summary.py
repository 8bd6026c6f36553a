"""The end-of-run summary a traffic engineer reads, and the run folder's plots."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from hils import jsonout
from hils.config import IntersectionConfig
from hils.detectors import actuations_per_phase
from hils.events import Kind
from hils.latency import Stats, internal_latencies_ms, transition_holds


class Tally:
    """What the summary and the run's plots read of its records, kept as they are emitted.

    Subscribed to a run's event log (:meth:`hils.events.EventLog.subscribe`; in a run of several controllers,
    one tally per intersection subscribed to that intersection's records), it counts every kind and
    keeps the few records the figures come from, so that the end of a run re-reads nothing: a long
    run's log is mostly polls and SETs, none of which the summary needs one by one."""

    KEPT = frozenset({Kind.RUN_STARTED, Kind.RUN_ENDED, Kind.ACTION_RECEIVED, Kind.COMMAND_DISPATCHED,
                      Kind.TRANSITION_VERIFIED, Kind.TIMEOUT_ENTERED, Kind.DETECTORS, Kind.POLL})

    def __init__(self, intersection: str | None = None) -> None:
        self.intersection = intersection  # in a run of several controllers: whose records it is handed
        self.kinds: Counter[str] = Counter()
        self.records: list[dict[str, Any]] = []

    def __call__(self, record: dict[str, Any]) -> None:
        kind = record["kind"]
        self.kinds[kind] += 1
        if kind in self.KEPT:
            self.records.append(record)


def summarize(tally: Tally, config: IntersectionConfig, *, traffic: Any = None,
              wall_s: float | None = None) -> dict[str, Any]:
    """The summary of a run of one controller: the run, its signal control and its traffic."""
    out = {"config": config.name, **_run(tally, wall_s), **_control(tally, config)}
    if traffic is not None:
        out["traffic"] = _plain(traffic)
    return out


def summarize_network(tally: Tally, junctions: Mapping[str, tuple[Tally, IntersectionConfig]], *,
                      traffic: Any = None, wall_s: float | None = None) -> dict[str, Any]:
    """The summary of a run of several controllers: the run, the signal control of each intersection (from its
    own tally) and the network's traffic (its approaches named by traffic light: ``J2 north``)."""
    started = next((r for r in tally.records if r["kind"] == Kind.RUN_STARTED), {})
    out = {"scenario": started.get("scenario"), **_run(tally, wall_s),
           "intersections": {tls: {"config": cfg.name, **_control(t, cfg)} for tls, (t, cfg) in junctions.items()}}
    if traffic is not None:
        out["traffic"] = _plain(traffic)
    return out


def _plain(traffic: Any) -> Any:
    return asdict(traffic) if is_dataclass(traffic) else traffic


def _run(tally: Tally, wall_s: float | None) -> dict[str, Any]:
    records = tally.records
    started = next((r for r in records if r["kind"] == Kind.RUN_STARTED), {})
    ended = [r for r in records if r["kind"] == Kind.RUN_ENDED]
    return {
        "mode": started.get("mode"),
        "action_type": started.get("action_type"),
        "agent": started.get("agent"),
        "seed": started.get("seed"),
        "sim_time_s": ended[-1]["t"] if ended else (records[-1]["t"] if records else 0.0),
        "wall_time_s": wall_s,
    }


def _control(tally: Tally, config: IntersectionConfig) -> dict[str, Any]:
    """One controller's signal control: actions, transitions and their holds, timeouts, polls, latency."""
    kinds, records = tally.kinds, tally.records
    ended = [r for r in records if r["kind"] == Kind.RUN_ENDED]
    timeouts = Counter(r["reason"] for r in records if r["kind"] == Kind.TIMEOUT_ENTERED)
    latency = {k: Stats.of(v).as_dict() for k, v in internal_latencies_ms(records).items()}
    out: dict[str, Any] = {
        "actions": kinds[Kind.ACTION_RECEIVED],
        "actions_refused": kinds[Kind.ACTION_REFUSED],
        "actions_dropped": kinds[Kind.ACTION_DROPPED],
        "commands_dispatched": kinds[Kind.COMMAND_DISPATCHED],
        "transitions_verified": kinds[Kind.TRANSITION_VERIFIED],
        "hold_s": Stats.of(transition_holds(records)).as_dict(),
        "timeouts": dict(timeouts),
        "recoveries": kinds[Kind.RECOVERED],
        "polls": _polls(ended[-1] if ended else {}, tally.intersection),
        "drifted_steps": kinds[Kind.DRIFT],
        "internal_latency_ms": latency,
        "controller_plan": _plan(config),
    }
    if kinds[Kind.DETECTORS]:
        out["detector_actuations"] = actuations_per_phase(records, config)
    return out


def _plan(config: IntersectionConfig) -> dict[str, Any]:
    """What the controller ran from power-up: its coordination pattern (cycle, offset, coordinated phases), or free."""
    c = config.coordination
    p = c.patterns.get(c.pattern)
    if p is None:
        return {"pattern": "free"}
    return {"pattern": p.number, "cycle_s": p.cycle, "offset_s": p.offset, "coord_phases": list(p.coord_phases),
            "force_off": c.force_off.value, "offset_reference": c.offset_reference.value,
            "schedule_changes": len(c.schedule)}


def _plan_text(plan: Mapping[str, Any]) -> str:
    if plan.get("pattern", "free") == "free":
        return "free"
    return (f"pattern {plan['pattern']}: cycle {plan['cycle_s']} s, offset {plan['offset_s']} s, coordinated "
            f"{'+'.join(map(str, plan['coord_phases']))}, {plan['force_off']} force-offs")


def _polls(ended: Mapping[str, Any], intersection: str | None) -> dict[str, int]:
    """The poll counts of ``run_ended``: its own in a run of one controller, the intersection's in one of several."""
    polls = ended.get("polls") or {}
    if intersection is not None and intersection in polls:
        polls = polls[intersection]
    return dict(polls)


def render(summary: Mapping[str, Any]) -> str:
    s = summary
    lines = [f"Run summary: {s['config']} ({s['mode']}, {s['action_type']} by {s['agent']}, seed {s['seed']})",
             _simulated(s)]
    t = s.get("traffic")
    if t:
        lines += _traffic_lines(t)
    h = s["hold_s"]
    lines += [
        "Signal control",
        f"  actions              {s['actions']} ({s['actions_refused']} refused, {s['actions_dropped']} dropped)",
        f"  transitions          {s['transitions_verified']} verified of {s['commands_dispatched']} commanded",
    ]
    if h["n"]:
        lines.append(f"  hold per transition  mean {h['mean']:.3f} s, min {h['min']:.3f} s, max {h['max']:.3f} s")
    lines.append(f"  timeouts             {_timeouts(s)}")
    lines.append(f"  controller plan      {_plan_text(s.get('controller_plan', {}))}")
    polls = _polls_shown(s)
    sent = polls["polls"] - polls["elided"]
    lines.append(f"  polls                {polls['polls']} ({polls['failed']} failed"
                 + (f"; {sent} sent, {polls['elided']} could not see a change" if polls["elided"] else "")
                 + f"); drifted steps {s['drifted_steps']}")
    if s.get("detector_actuations"):
        per_phase = ", ".join(f"phase {p} {n}" for p, n in s["detector_actuations"].items())
        lines.append(f"  detector actuations  {per_phase} (stop-bar presence in SUMO, NTCIP remote actuation)")
    for action_type, st in s["internal_latency_ms"].items():
        lines.append(f"  internal latency     {action_type}: N {st['n']}, mean {st['mean'] * 1000:.1f} us, "
                     f"p99 {st['p99'] * 1000:.1f} us")
    return "\n".join(lines)


def render_network(summary: Mapping[str, Any]) -> str:
    """The console summary of a run of several controllers: the network's traffic, then a line per intersection."""
    s = summary
    lines = [f"Run summary: {s['scenario']} ({len(s['intersections'])} controllers, {s['mode']}, "
             f"{s['action_type']} by {s['agent']}, seed {s['seed']})",
             _simulated(s)]
    if s.get("traffic"):
        lines += _traffic_lines(s["traffic"])
    plans = {tls: _plan_text(c.get("controller_plan", {})) for tls, c in s["intersections"].items()}
    if any(text != "free" for text in plans.values()):
        lines += ["Controller plans"] + [f"  {tls:<7} {text}" for tls, text in plans.items()]
    lines += ["Signal control per intersection",
              "  light   transitions  hold mean   timeouts               polls (failed, not sent)   drifted"]
    for tls, c in s["intersections"].items():
        h, polls, timeouts = c["hold_s"], _polls_shown(c), _timeouts(c)
        lines.append(f"  {tls:<7} {c['transitions_verified']:>5} of {c['commands_dispatched']:<4} "
                     f"{_fmt(h['mean'] if h['n'] else None):>9}   {timeouts:<22} "
                     f"{polls['polls']:>6} ({polls['failed']}, {polls['elided']})"
                     f"{'':>10}{c['drifted_steps']:>3}")
    return "\n".join(lines)


def _simulated(s: Mapping[str, Any]) -> str:
    return f"  simulated {s['sim_time_s']:.0f} s" + (f" in {s['wall_time_s']:.1f} s wall" if s.get("wall_time_s")
                                                   else "")


def _timeouts(control: Mapping[str, Any]) -> str:
    """One controller's TIMEOUTs by reason, and how many it recovered from."""
    text = ", ".join(f"{k} {v}" for k, v in control["timeouts"].items()) or "none"
    return text + (f" ({control['recoveries']} recovered)" if control["timeouts"] else "")


def _polls_shown(control: Mapping[str, Any]) -> dict[str, int]:
    # none counted: the run did not end cleanly
    return {"polls": 0, "failed": 0, "elided": 0, **control["polls"]}


def _fmt(value: float | None, unit: str = " s") -> str:
    return "n/a" if value is None else f"{value:.1f}{unit}"


def _traffic_lines(t: Mapping[str, Any]) -> list[str]:
    """Every vehicle due to enter, where it is now, and the delay each approach suffered."""
    lines = [
        "Traffic (every vehicle due to enter by the end)",
        f"  departed             {t['departed']}: {t['arrived']} arrived, {t['running']} still in the network",
        f"  waiting to enter     {t['waiting_to_enter']} (SUMO's insertion backlog: no room on the entry lane)",
        f"  mean delay           {_fmt(t['mean_delay'])} over departed and waiting vehicles "
        "(departure delay + time loss, so far for those not arrived)",
        f"  arrived only         time loss {_fmt(t['mean_time_loss'])}, waiting time {_fmt(t['mean_waiting_time'])}"
        " (SUMO trip statistics)",
    ]
    r = t.get("resco")
    if r:
        queue = "n/a" if r["queue"] is None else f"{r['queue']:.2f}"
        lines.append(f"  RESCO's figures      delay {_fmt(r['delay_s'])}, trip time {_fmt(r['trip_time_s'])}, "
                     f"waiting time {_fmt(r['waiting_time_s'])}, queue {queue} (SUMO tripinfo of {r['vehicles']} "
                     f"vehicles, {r['never_entered']} never entered; queue over {r['queue_steps']} decision steps)")
    lines += [
        "  per approach         arrived  running  waiting  mean delay  max queue  minutes with a lane full",
    ]
    for name, a in t["approaches"].items():
        spill = len(a["spillback_minutes"])
        lines.append(f"    {name:<18} {a['arrived']:>7}  {a['running']:>7}  {a['waiting_to_enter']:>7}  "
                     f"{_fmt(a['mean_delay']):>10}  {a['max_queue']:>9}  "
                     + (f"{spill} (spillback; a lane holds {a['lane_storage']})" if spill else "0"))
    return lines


def warnings(summary: Mapping[str, Any]) -> list[str]:
    """What a reader must not miss: vehicles that could not enter, naming their approaches."""
    t = summary.get("traffic")
    if not t or not t["waiting_to_enter"]:
        return []
    blocked = [f"{name} {a['waiting_to_enter']}" for name, a in t["approaches"].items() if a["waiting_to_enter"]]
    return [f"WARNING: {t['waiting_to_enter']} vehicles could not enter the network by the end "
            f"({', '.join(blocked)}): their approaches were not served enough; their delay so far is "
            "in the mean delay"]


def write(summary: Mapping[str, Any], path: Path) -> None:
    """summary.json, without NaN (see :mod:`hils.jsonout`)."""
    path.write_text(jsonout.dumps(summary) + "\n", encoding="utf-8")
