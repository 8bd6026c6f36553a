"""`hils run`: the main job.

Without --target it runs in virtual time against the in-process emulator, with
SUMO computing the traffic (unless --no-sumo). With --target snmp://HOST:PORT
the same agent and middleware run at wall-clock time against whatever answers
there: `hils emulator serve`, or a real controller.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from hils import config as config_mod
from hils import plots, summary
from hils.actions import ActionType
from hils.agents import AgentError
from hils.runner import DEFAULT_AGENTS, RunSpec, Simulation, run_virtual
from hils.webster import webster_plan

log = logging.getLogger(__name__)

RUN_HELP = """\
Run a control agent against a signal controller through the middleware.

Default (no arguments): the shipped four-leg intersection, the max-pressure agent
choosing phase pairs every 10 s, one simulated hour of SUMO traffic, and the
built-in NTCIP 1202 emulator in virtual time. Outputs go to a run folder under
reports/runs/: the JSON Lines event log, summary.json, a signal timeline and a
queue plot.

One flag to real hardware: --target snmp://HOST:PORT?community=NAME&version=1|2c
runs the same agent and middleware at wall-clock time against that controller
(or against `hils emulator serve`). For an Econolite Cobalt: version=1, port 501,
community = the controller's user name (default administrator).
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run an agent against a controller (the main job)", description=RUN_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="FILE", help="intersection config (TOML); default: the shipped four-leg")
    p.add_argument("--action-type", choices=[t.value for t in ActionType], default=ActionType.SELECTION.value,
                   help="action design: selection (pick a pair), switch (0 keep / 1 advance), duration "
                        "(green time of the next pair); default: selection")
    p.add_argument("--agent", metavar="NAME|MODULE:CLASS",
                   help="built-in agent (random, fixed-cycle, max-pressure, queue-proportional, webster) or your own "
                        "package.module:Class; default: " + ", ".join(f"{k.value} -> {v}"
                                                                      for k, v in DEFAULT_AGENTS.items()))
    p.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds (3600)")
    p.add_argument("--seed", type=int, default=0, help="seed of SUMO, the emulator's latency model and random "
                                                       "agents; a virtual-time run is reproducible from it (0)")
    p.add_argument("--target", metavar="URL", help="snmp://HOST:PORT?community=NAME&version=1|2c: run at "
                                                   "wall-clock time against a real controller or "
                                                   "`hils emulator serve`; default: in-process emulator, "
                                                   "virtual time")
    p.add_argument("--log", metavar="FILE", type=Path, help="JSON Lines event log (default: RUN_DIR/events.jsonl)")
    p.add_argument("--out", metavar="RUN_DIR", type=Path,
                   help="run folder (default: reports/runs/<time>-<action type>)")
    p.add_argument("--no-sumo", action="store_true", help="middleware and controller only, no traffic simulation")
    p.add_argument("--poll-hz", type=float, metavar="HZ", help="signal-state polling rate (default: config, 10)")
    p.add_argument("--recover-after", type=float, default=5.0, metavar="S",
                   help="call recover() this long after a TIMEOUT (default 5; negative: never)")
    p.add_argument("--plot-window", default="0:180", metavar="START:END",
                   help="simulated seconds shown in the signal timeline (0:180)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_command)


def _window(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise SystemExit(f"hils run: --plot-window must be START:END in seconds, got {text!r}") from None
    return a, b


def run_command(args: argparse.Namespace) -> int:
    cfg = config_mod.load(args.config)
    if args.poll_hz is not None:
        cfg = cfg.with_middleware(poll_hz=args.poll_hz)
    window = _window(args.plot_window)
    out = args.out or Path("reports/runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{args.action_type}"
    out.mkdir(parents=True, exist_ok=True)
    spec = RunSpec(cfg, ActionType(args.action_type), agent=args.agent, duration=args.duration, seed=args.seed,
                   log_path=args.log or out / "events.jsonl",
                   recover_after=None if args.recover_after < 0 else args.recover_after, sumo=not args.no_sumo)
    if spec.agent_spec == "webster":
        print(webster_plan(cfg).describe())
    simulation = None if args.no_sumo else _sumo(cfg, args)
    try:
        if args.target:
            from hils.wire import run_wire

            result = run_wire(spec, args.target, simulation=simulation)
        else:
            result = _run_with_progress(spec, simulation, args.no_progress)
    except AgentError as exc:
        print(f"hils run: {exc}")
        return 2
    finally:
        if simulation is not None:
            traffic = simulation.summary()
            simulation.close()
    records = result.records
    s = summary.summarize(records, cfg, traffic=None if simulation is None else traffic, wall_s=result.wall_s)
    summary.write(s, out / "summary.json")
    plots.signal_timeline(records, cfg, out / "signal_timeline.png", start=window[0], end=window[1])
    if result.run.traffic_samples:
        plots.queues(result.run.traffic_samples, out / "queues.png", title=f"Queues per approach, {cfg.name}",
                     spillback={a: [60.0 * m for m in v["spillback_minutes"]]
                                for a, v in s["traffic"]["approaches"].items()} if s.get("traffic") else None)
    print(summary.render(s))
    for warning in summary.warnings(s):
        print(warning)
    print(f"Outputs in {out}/: {spec.log_path.name if spec.log_path.parent == out else spec.log_path}, "
          "summary.json, signal_timeline.png" + (", queues.png" if result.run.traffic_samples else ""))
    return 0


def _sumo(cfg: config_mod.IntersectionConfig, args: argparse.Namespace) -> Simulation:
    from hils.sumo import SumoSimulation

    sim = SumoSimulation(cfg, seed=args.seed, end=args.duration)
    sim.start()
    return sim


def _run_with_progress(spec: RunSpec, simulation: Simulation | None, quiet: bool):
    from tqdm import tqdm

    with tqdm(total=spec.duration, unit="sim s", disable=quiet, desc=f"{spec.action_type.value}",
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]") as bar:
        return run_virtual(spec, simulation=simulation, progress=lambda t: bar.update(t - bar.n))
