"""The end-of-run summary a traffic engineer reads, and the run folder's plots."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from hils.config import IntersectionConfig
from hils.events import Kind
from hils.latency import Stats, internal_latencies_ms, transition_holds


def summarize(records: Sequence[dict[str, Any]], config: IntersectionConfig, *,
              traffic: Any = None, wall_s: float | None = None) -> dict[str, Any]:
    kinds = Counter(r["kind"] for r in records)
    started = next((r for r in records if r["kind"] == Kind.RUN_STARTED), {})
    ended = [r for r in records if r["kind"] == Kind.RUN_ENDED]
    timeouts = Counter(r["reason"] for r in records if r["kind"] == Kind.TIMEOUT_ENTERED)
    holds = transition_holds(records)
    latency = {k: Stats.of(v).as_dict() for k, v in internal_latencies_ms(records).items()}
    out: dict[str, Any] = {
        "config": config.name,
        "mode": started.get("mode"),
        "action_type": started.get("action_type"),
        "agent": started.get("agent"),
        "seed": started.get("seed"),
        "sim_time_s": ended[-1]["t"] if ended else (records[-1]["t"] if records else 0.0),
        "wall_time_s": wall_s,
        "actions": kinds[Kind.ACTION_RECEIVED],
        "actions_refused": kinds[Kind.ACTION_REFUSED],
        "actions_dropped": kinds[Kind.ACTION_DROPPED],
        "commands_dispatched": kinds[Kind.COMMAND_DISPATCHED],
        "transitions_verified": kinds[Kind.TRANSITION_VERIFIED],
        "hold_s": Stats.of(holds).as_dict(),
        "timeouts": dict(timeouts),
        "recoveries": kinds[Kind.RECOVERED],
        "polls": kinds[Kind.POLL],
        "polls_failed": kinds[Kind.POLL_FAILED],
        "drifted_steps": kinds[Kind.DRIFT],
        "internal_latency_ms": latency,
    }
    if traffic is not None:
        out["traffic"] = asdict(traffic) if is_dataclass(traffic) else traffic
    return out


def render(summary: Mapping[str, Any]) -> str:
    s = summary
    lines = [f"Run summary: {s['config']} ({s['mode']}, {s['action_type']} by {s['agent']}, seed {s['seed']})",
             f"  simulated {s['sim_time_s']:.0f} s" + (f" in {s['wall_time_s']:.1f} s wall" if s.get("wall_time_s")
                                                     else "")]
    t = s.get("traffic")
    if t:
        delay = "n/a" if t["mean_time_loss"] is None else f"{t['mean_time_loss']:.1f} s"
        wait = "n/a" if t["mean_waiting_time"] is None else f"{t['mean_waiting_time']:.1f} s"
        lines += [
            "Traffic",
            f"  vehicles served      {t['arrived']} of {t['departed']} departed ({t['running']} still in the network)",
            f"  mean delay           {delay} (time loss per vehicle)",
            f"  mean waiting time    {wait}",
            "  max queue (veh)      " + ", ".join(f"{a} {q}" for a, q in sorted(t["max_queue"].items())),
        ]
    h = s["hold_s"]
    lines += [
        "Signal control",
        f"  actions              {s['actions']} ({s['actions_refused']} refused, {s['actions_dropped']} dropped)",
        f"  transitions          {s['transitions_verified']} verified of {s['commands_dispatched']} commanded",
    ]
    if h["n"]:
        lines.append(f"  hold per transition  mean {h['mean']:.3f} s, min {h['min']:.3f} s, max {h['max']:.3f} s")
    lines.append("  timeouts             " + (", ".join(f"{k} {v}" for k, v in s["timeouts"].items()) or "none")
                 + (f" ({s['recoveries']} recovered)" if s["timeouts"] else ""))
    lines.append(f"  polls                {s['polls']} ({s['polls_failed']} failed); "
                 f"drifted steps {s['drifted_steps']}")
    for action_type, st in s["internal_latency_ms"].items():
        lines.append(f"  internal latency     {action_type}: N {st['n']}, mean {st['mean'] * 1000:.1f} us, "
                     f"p99 {st['p99'] * 1000:.1f} us")
    return "\n".join(lines)


def write(summary: Mapping[str, Any], path: Path) -> None:
    path.write_text(json.dumps(summary, indent=2, default=str) + "\n", encoding="utf-8")
