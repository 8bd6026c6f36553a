"""The end-of-run summary a traffic engineer reads, and the run folder's plots."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from hils.protocol.config import IntersectionConfig
from hils.protocol.resco import light_of, titled
from hils.report import jsonout
from hils.report.latency import Stats, internal_latencies_ms, transition_holds
from hils.report.outfiles import write_whole
from hils.shell.events import Kind

__all__ = ["Tally", "render", "summarize", "warnings", "write"]


class Tally:
    """What the summary and the run's plots read of its records, kept as they are emitted.

    Subscribed to a run's event log, one per intersection (:meth:`hils.shell.events.EventLog.subscribe` with its
    label: that intersection's records and the run's own; in a run of one, every record), it counts every kind and
    keeps the few records the figures come from, so that the end of a run re-reads nothing: a long
    run's log is mostly polls and SETs, none of which the summary needs one by one."""

    # Polls, their failures and recoveries: what the signal timeline draws (a poll record is a change of the
    # state seen; failures are few when a link works, and each one is part of the timeline when it fails).
    KEPT = frozenset({Kind.RUN_STARTED, Kind.RUN_ENDED, Kind.ACTION_RECEIVED, Kind.COMMAND_DISPATCHED,
                      Kind.TRANSITION_VERIFIED, Kind.TIMEOUT_ENTERED, Kind.DETECTORS, Kind.POLL, Kind.POLL_FAILED,
                      Kind.RECOVERED})

    def __init__(self, intersection: str | None = None) -> None:
        self.intersection = intersection  # in a run of several controllers: whose records it is handed
        self.kinds: Counter[str] = Counter()
        self.records: list[dict[str, Any]] = []
        self.timeout: dict[str, Any] | None = None  # the TIMEOUT the manager is in (its record), None when not in one
        self.clear: dict[str, Any] | None = None  # the closing clear's last SET record (sent, answered or failed)
        self.first_refusal: dict[str, Any] | None = None
        # Each PREEMPTED episode: when it began, the preempts in service, and how long it lasted (None while on).
        self.preemptions: list[dict[str, Any]] = []

    def __call__(self, record: dict[str, Any]) -> None:
        kind = record["kind"]
        self.kinds[kind] += 1
        if kind in self.KEPT:
            self.records.append(record)
        watch = _WATCHES.get(kind)
        if watch is not None:
            watch(self, record)

    # How the run stands at its end: in TIMEOUT or not, its calls cleared or not, why an action was refused. One
    # handler per kind watched, found by the record's kind (a chain of comparisons with Kind's members cost every
    # record several enum lookups).

    def _timeout_entered(self, record: dict[str, Any]) -> None:
        self.timeout = record

    def _preempt_began(self, record: dict[str, Any]) -> None:
        self.preemptions.append({"t": record["t"], "preempts": list(record["preempts"]), "duration_s": None})

    def _state(self, record: dict[str, Any]) -> None:
        if record["from"] == "preempted":
            # Over when the controller reported it (preempt_end), or cut by a TIMEOUT (then unknown beyond it).
            self.preemptions[-1]["duration_s"] = record["t"] - self.preemptions[-1]["t"]
            self.preemptions[-1]["ended"] = "over" if record["to"] == "idle" else record["to"]
        if record["to"] != "timeout":
            self.timeout = None  # recovered (a close leaves the state as it was: no record)

    def _set(self, record: dict[str, Any]) -> None:
        if record.get("purpose") == "clear":
            if self.clear is None:
                self.records.append(record)  # polling halted with the close: the timeline's no data from here
            self.clear = record

    def _action_refused(self, record: dict[str, Any]) -> None:
        if self.first_refusal is None:
            self.first_refusal = record


_WATCHES = {Kind.TIMEOUT_ENTERED.value: Tally._timeout_entered, Kind.PREEMPT_BEGIN.value: Tally._preempt_began,
            Kind.STATE.value: Tally._state, Kind.SET_SENT.value: Tally._set, Kind.SET_ANSWERED.value: Tally._set,
            Kind.SET_FAILED.value: Tally._set, Kind.ACTION_REFUSED.value: Tally._action_refused}


def summarize(intersections: Mapping[str | None, tuple[Tally, IntersectionConfig]], *, traffic: Any = None,
              wall_s: float | None = None) -> dict[str, Any]:
    """The summary of a run: the run, the signal control of each intersection (from its own tally, keyed by its
    label) and the traffic. A run of one intersection (labelled None) is summed up as the single controller's
    run always was; a run of several names each intersection, and the network's approaches (``J2 north``)."""
    run = next(iter(intersections.values()))[0]  # every tally holds the run's own records
    started = next((r for r in run.records if r["kind"] == Kind.RUN_STARTED), {})
    if None in intersections:
        tally, config = intersections[None]
        # a scenario's one light (RESCO's cologne1): the scenario names the run, not the light's derived config
        light = light_of(started.get("source") or "")
        out = {"config": config.name, **({"scenario": light[0], "light": light[1]} if light else {}),
               **_run(tally, wall_s), **_control(tally, config)}
    else:
        out = {"scenario": started.get("scenario"), **_run(run, wall_s),
               "intersections": {label: {"config": cfg.name, **_control(t, cfg)}
                                 for label, (t, cfg) in intersections.items()}}
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
        "agent_late": kinds[Kind.AGENT_LATE],  # answers after the next SUMO step was due (wall clock)
        "commands_dispatched": kinds[Kind.COMMAND_DISPATCHED],
        "transitions_verified": kinds[Kind.TRANSITION_VERIFIED],
        "hold_s": Stats.of(transition_holds(records)).as_dict(),
        "timeouts": dict(timeouts),
        "recoveries": kinds[Kind.RECOVERED],
        "polls": _polls(ended[-1] if ended else {}, tally.intersection),
        "drifted_steps": kinds[Kind.DRIFT],
        "internal_latency_ms": latency,
        "first_refusal": _refusal(tally.first_refusal),
        "timeout_at_end": _timeout_at_end(tally.timeout),
        "calls_cleared": _cleared(tally.clear),
        "clear_error": tally.clear.get("error") if tally.clear else None,
        "controller_plan": _plan(config),
        "preemptions": _preemptions(tally.preemptions, _run(tally, None)["sim_time_s"]),
    }
    if kinds[Kind.DETECTORS]:
        out["detector_actuations"] = actuations_per_phase(records, config)
    return out


def _preemptions(episodes: list[dict[str, Any]], end: float) -> dict[str, Any]:
    """How often the controller was preempted, when, and for how long (an episode still on at the end: until then)."""
    shown = [{"ended": "running at the end", **e, "duration_s": end - e["t"]} if e["duration_s"] is None else e
             for e in episodes]
    durations = [e["duration_s"] for e in shown]
    return {"count": len(shown), "total_s": sum(durations), "longest_s": max(durations, default=0.0),
            "episodes": shown}


def _preemptions_text(p: Mapping[str, Any]) -> str:
    at = ", ".join(f"{e['t']:.1f} s for {e['duration_s']:.1f} s" + (
        "" if e.get("ended") == "over" else f" ({e.get('ended')})") for e in p["episodes"][:5])
    more = f" and {p['count'] - 5} more" if p["count"] > 5 else ""
    return f"{p['count']} ({at}{more}); total {p['total_s']:.1f} s, longest {p['longest_s']:.1f} s"


def _refusal(record: Mapping[str, Any] | None) -> dict[str, Any] | None:
    if record is None:
        return None
    return {"t": record["t"], "action_id": record["action_id"], "error": record["error"],
            "message": record.get("message") or record["reason"]}


def _timeout_at_end(record: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The TIMEOUT a run ended in, unrecovered (None when it ended out of TIMEOUT)."""
    if record is None:
        return None
    return {"t": record["t"], "reason": record["reason"], "detail": record.get("detail")}


def _cleared(record: Mapping[str, Any] | None) -> bool | None:
    """Whether the closing clear was answered (None: the run placed no call, there was nothing to clear)."""
    if record is None:
        return None
    return record["kind"] == Kind.SET_ANSWERED
def _plan(config: IntersectionConfig) -> dict[str, Any]:
    """What the controller ran from power-up: its coordination pattern (cycle, offset, coordinated phases), or free."""
    c = config.coordination
    p = c.patterns.get(c.pattern)
    if p is None:
        return {"pattern": "free"}
    return {"pattern": p.number, "cycle_s": p.cycle, "offset_s": p.offset, "coord_phases": list(p.coord_phases),
            "force_off": c.force_off.value, "offset_reference": c.offset_reference.value,
            "schedule_changes": len(c.schedule), "pretimed": p.pretimed}


def _plan_text(plan: Mapping[str, Any]) -> str:
    if plan.get("pattern", "free") == "free":
        return "free"
    return (f"pattern {plan['pattern']}{' pretimed' if plan.get('pretimed') else ''}: cycle {plan['cycle_s']} s, "
            f"offset {plan['offset_s']} s, coordinated "
            f"{'+'.join(map(str, plan['coord_phases']))}, {plan['force_off']} force-offs")


def _polls(ended: Mapping[str, Any], intersection: str | None) -> dict[str, int]:
    """The poll counts of ``run_ended``: its own in a run of one controller, the intersection's in one of several."""
    polls = ended.get("polls") or {}
    if intersection is not None and intersection in polls:
        polls = polls[intersection]
    return dict(polls)


def render(summary: Mapping[str, Any], *, by: str | None = None) -> str:
    """The console summary of a run: the run, its traffic and its signal control (per intersection when the
    summary names them). ``by`` says who drove the signals (default: the action type and the agent; an agent that
    leaves the controller to its own operation has none: :func:`hils.agents.builtin.controlled_by`)."""
    by = by or f"{summary['action_type']} by {summary['agent']}"
    return _render_network(summary, by) if "intersections" in summary else _render_one(summary, by)


def _render_one(summary: Mapping[str, Any], by: str) -> str:
    s = summary
    named = titled(s["scenario"], s["light"]) if s.get("light") else s["config"]
    lines = [f"Run summary: {named} ({s['mode']}, {by}, seed {s['seed']})",
             _simulated(s)]
    t = s.get("traffic")
    if t:
        lines += _traffic_lines(t)
    h = s["hold_s"]
    lines += [
        "Signal control",
        f"  actions              {s['actions']} ({s['actions_refused']} refused, {s['actions_dropped']} dropped"
        + (f"; the agent answered late {s['agent_late']} times" if s.get("agent_late") else "") + ")",
    ]
    if s["first_refusal"]:
        lines.append(f"  first refused        {_refused(s['first_refusal'])}")
    lines.append(f"  transitions          {s['transitions_verified']} verified of {s['commands_dispatched']} commanded")
    if h["n"]:
        lines.append(f"  hold per transition  mean {h['mean']:.3f} s, min {h['min']:.3f} s, max {h['max']:.3f} s")
    lines.append(f"  timeouts             {_timeouts(s)}")
    if s.get("preemptions", {}).get("count"):
        lines.append(f"  preemptions          {_preemptions_text(s['preemptions'])}")
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


def _render_network(summary: Mapping[str, Any], by: str) -> str:
    """The network's traffic, then a line per intersection."""
    s = summary
    lines = [f"Run summary: {s['scenario']} ({len(s['intersections'])} controllers, {s['mode']}, "
             f"{by}, seed {s['seed']})",
             _simulated(s)]
    if s.get("traffic"):
        lines += _traffic_lines(s["traffic"])
    w = _width(s["intersections"], 7)
    plans = {tls: _plan_text(c.get("controller_plan", {})) for tls, c in s["intersections"].items()}
    if any(text != "free" for text in plans.values()):
        lines += ["Controller plans"] + [f"  {_fit(tls, w)} {text}" for tls, text in plans.items()]
    lines += ["Signal control per intersection",
              f"  {'light':<{w}} transitions  hold mean   timeouts               polls (failed, not sent)   drifted"]
    for tls, c in s["intersections"].items():
        h, polls, timeouts = c["hold_s"], _polls_shown(c), _timeouts(c)
        lines.append(f"  {_fit(tls, w)} {c['transitions_verified']:>5} of {c['commands_dispatched']:<4} "
                     f"{_fmt(h['mean'] if h['n'] else None):>9}   {timeouts:<22} "
                     f"{polls['polls']:>6} ({polls['failed']}, {polls['elided']})"
                     f"{'':>10}{c['drifted_steps']:>3}")
    preempted = {tls: c["preemptions"] for tls, c in s["intersections"].items()
                 if c.get("preemptions", {}).get("count")}
    if preempted:
        lines += ["Preemptions"] + [f"  {_fit(tls, w)} {_preemptions_text(p)}" for tls, p in preempted.items()]
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
    w = _width(t["approaches"], 18)
    lines.append(f"  {'per approach':<{w + 2}} arrived  running  waiting  mean delay  max queue  "
                 "minutes with a lane full")
    fed = False  # an approach no vehicle entered the network on: fed by a neighbouring intersection
    for name, a in t["approaches"].items():
        spill = len(a["spillback_minutes"])
        entered = (a["arrived"], a["running"], a["waiting_to_enter"], _fmt(a["mean_delay"]))
        if not a["departed"] and not a["waiting_to_enter"]:
            entered, fed = ("-",) * 4, True
        lines.append(f"    {_fit(name, w)} {entered[0]:>7}  {entered[1]:>7}  {entered[2]:>7}  {entered[3]:>10}  "
                     f"{a['max_queue']:>9}  " + (f"{spill} (spillback; a lane holds {a['lane_storage']})"
                                                 if spill else "0"))
    if fed:
        lines += ["    -: no vehicle entered the network there (arrived, running, waiting and mean delay count",
                  "       vehicles by the approach they entered on): its traffic comes from a neighbouring light"]
    return lines


#: The widest a name column grows. RESCO names lights by their SUMO cluster ids: cologne3's runs to 45 characters,
#: one of ingolstadt's to 166. Longer names are shortened in the middle; summary.json keeps them whole.
_NAME_COLUMN = 48


def _width(names: Iterable[str], least: int) -> int:
    return min(_NAME_COLUMN, max([least, *map(len, names)]))


def _fit(name: str, width: int) -> str:
    """``name`` in a column ``width`` wide: padded, or shortened in the middle (its start and end tell lights and
    approaches apart: ``cluster_3064…_306484190 north``)."""
    if len(name) <= width:
        return f"{name:<{width}}"
    tail = (width - 1) // 2
    return name[:width - 1 - tail] + "…" + name[-tail:]


def _refused(refusal: Mapping[str, Any]) -> str:
    return f"at {refusal['t']:.1f} s, action {refusal['action_id']}: {refusal['error']}: {refusal['message']}"


def _controls(summary: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    """Each controller's signal control in a summary, by how a message names it ('' for a run of one)."""
    if "intersections" in summary:
        return {f"{tls}: ": c for tls, c in summary["intersections"].items()}
    return {"": summary}


def warnings(summary: Mapping[str, Any]) -> list[str]:
    """What a reader must not miss: vehicles that could not enter, naming their approaches; an agent whose every
    action was refused, and why the first one was."""
    out = []
    for name, c in _controls(summary).items():
        if c["actions"] and c["actions_refused"] == c["actions"]:
            out.append(f"WARNING: {name}every action of the agent was refused ({c['actions']} of {c['actions']}): "
                       f"it never commanded the controller; the first was refused "
                       f"{_refused(c['first_refusal'])}")
    t = summary.get("traffic")
    if t and t["waiting_to_enter"]:
        blocked = [f"{name} {a['waiting_to_enter']}" for name, a in t["approaches"].items() if a["waiting_to_enter"]]
        out.append(f"WARNING: {t['waiting_to_enter']} vehicles could not enter the network by the end "
                   f"({', '.join(blocked)}): their approaches were not served enough; their delay so far is "
                   "in the mean delay")
    return out


def cleared(summary: Mapping[str, Any]) -> bool | None:
    """Whether every controller that was given calls had them cleared at the end (None: none was given any)."""
    placed = [c["calls_cleared"] for c in _controls(summary).values() if c["calls_cleared"] is not None]
    return all(placed) if placed else None


def lost(summary: Mapping[str, Any]) -> list[str]:
    """The controllers a run lost, each in a few words: ended in TIMEOUT, or calls it could not clear (empty when
    every controller was still under control at the end and cleared)."""
    out = []
    for name, c in _controls(summary).items():
        timeout = c["timeout_at_end"]
        if timeout:
            out.append(f"{name}ended in TIMEOUT since {timeout['t']:.1f} s ({timeout['reason']}: {timeout['detail']}), "
                       "not recovered")
        if c["calls_cleared"] is False:
            out.append(f"{name}calls NOT cleared ({c['clear_error'] or 'no answer in time'}): they stay on the "
                       "controller until its backup time")
    return out


def write(summary: Mapping[str, Any], path: Path) -> None:
    """summary.json, without NaN (see :mod:`hils.report.jsonout`)."""
    write_whole(path, jsonout.dumps(summary) + "\n")


def actuations_per_phase(records: Iterable[Mapping[str, Any]], config: IntersectionConfig) -> dict[int, int]:
    """How often each phase's detector went from idle to actuated over a run (its ``detectors`` records)."""
    counts = dict.fromkeys(config.detectors.values(), 0)
    before: set[int] = set()
    for r in records:
        if r["kind"] == Kind.DETECTORS:
            now = set(r["active"])
            for d in now - before:
                counts[config.detectors[d]] += 1
            before = now
    return counts
