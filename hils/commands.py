"""`hils run`: the main job.

Without --target it runs in virtual time against the in-process emulator, with
SUMO computing the traffic (unless --no-sumo). With --target snmp://HOST:PORT
the same agent and middleware run at wall-clock time against whatever answers
there: `hils emulator serve`, or a real controller.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from hils import config as config_mod
from hils import plots, record, summary
from hils.actions import ActionType
from hils.agents import controller_config, describe_plan
from hils.errors import UserError
from hils.events import Kind
from hils.junction import Junction
from hils.scenario import SCENARIOS, Scenario, load_scenario, load_targets
from hils.status import StatusLine
from hils.sumo_net import scenario_config
from hils.testbed import DEFAULT_AGENTS, VIRTUAL, AgentFailed, RunInterrupted, RunSpec, Testbed
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
                   help="built-in agent (random, fixed-cycle, max-pressure, queue-proportional, webster; actuated: "
                        "none, the controller runs on its detectors; coordinated: none, the controller runs its "
                        "config's timing plan on its detectors) or your own "
                        "package.module:Class; default: " + ", ".join(f"{k.value} -> {v}"
                                                                      for k, v in DEFAULT_AGENTS.items()))
    p.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds (3600)")
    p.add_argument("--seed", type=int, default=0, help="seed of SUMO, the emulator's latency model and random "
                                                       "agents; a virtual-time run is reproducible from it (0)")
    p.add_argument("--scenario", metavar="NAME|FILE",
                   help="a scenario of one or several signalised intersections, each controller with its own "
                        f"config and agent: {', '.join(SCENARIOS)} (corridor: four on an arterial; grid4x4: "
                        "sixteen), resco:NAME (RESCO's benchmark: grid4x4, arterial4x4, cologne1/3/8, "
                        "ingolstadt1/7/21; pip install 'hils[resco]') or your own .scenario.toml; default: the "
                        "shipped four-leg")
    p.add_argument("--target", metavar="URL|FILE", help="snmp://HOST:PORT?community=NAME&version=1|2c: run at "
                                                        "wall-clock time against a real controller or "
                                                        "`hils emulator serve`; for a scenario of several "
                                                        'controllers a TOML file of TLS = "snmp://..." lines; '
                                                        "default: in-process emulator, virtual time")
    p.add_argument("--log", metavar="FILE", type=Path, help="JSON Lines event log (default: RUN_DIR/events.jsonl)")
    p.add_argument("--out", metavar="RUN_DIR", type=Path,
                   help="run folder (default: reports/runs/<time>-<action type>)")
    p.add_argument("--net", metavar="FILE", help="your own SUMO network (.net.xml; with --routes): the phase of each "
                   "signal link is derived from it and the config's approach and turn of each phase")
    p.add_argument("--routes", metavar="FILE", help="the demand (.rou.xml) for --net")
    p.add_argument("--sumocfg", metavar="FILE", help="your own SUMO scenario (.sumocfg) instead of --net/--routes")
    p.add_argument("--no-sumo", action="store_true", help="middleware and controller only, no traffic simulation")
    p.add_argument("--poll-hz", type=float, metavar="HZ", help="signal-state polling rate (default: config, 10)")
    p.add_argument("--recover-after", type=float, default=5.0, metavar="S",
                   help="call recover() this long after a TIMEOUT (default 5; negative: never)")
    p.add_argument("--plot-window", default="0:180", metavar="START:END",
                   help="simulated seconds shown in the signal timeline (0:180)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--dashboard", type=int, metavar="PORT",
                   help="serve a live dashboard of the run on http://127.0.0.1:PORT/ (wall-clock runs; 0: any "
                        "free port); watch a finished or virtual-time run with `hils view RUN_DIR`")
    p.add_argument("--dashboard-control", action="store_true",
                   help="let the dashboard's page recover the manager from TIMEOUT (default: read-only); only the "
                        "page opened from the URL printed at start may: it carries the run's secret (?token=...)")
    p.add_argument("--asclog", metavar="http://HOST:PORT",
                   help="wall-clock runs of one controller: after the run, collect the controller's own hi-res log "
                        "from its MaxTime event-log endpoint (`hils emulator serve --http`, an Intelight MaxTime) "
                        "into the run folder, with its ATSPM measures; virtual-time runs keep the emulator's anyway")
    p.set_defaults(func=run_command)


def _window(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise UsageError(f"--plot-window must be START:END in seconds, got {text!r}") from None
    return a, b


def run_command(args: argparse.Namespace) -> int:
    cfg = config_mod.load(args.config)
    if args.poll_hz is not None:
        cfg = cfg.with_middleware(poll_hz=args.poll_hz)
    window = _window(args.plot_window)
    if not args.duration > 0:
        raise UsageError(f"--duration must be positive seconds, got {args.duration:g}")
    scenario = _scenario(args)
    dashboard = _dashboard(args)
    if args.asclog is not None and (not args.target or scenario is not None):
        raise UsageError("--asclog collects the log of the one controller a wall-clock run drives: use it with "
                         "--target snmp://... and without --scenario")
    out = _run_folder(args.out, args.action_type)
    log_path = args.log or out / "events.jsonl"
    sumo_config = scenario_config(sumocfg=args.sumocfg, net=args.net, routes=args.routes, directory=out)
    spec = RunSpec(cfg, ActionType(args.action_type), agent=args.agent, duration=args.duration, seed=args.seed,
                   log_path=log_path, recover_after=None if args.recover_after < 0 else args.recover_after,
                   sumo=not args.no_sumo)
    if spec.agent_spec == "webster":
        if sumo_config is not None or scenario is not None:
            raise UsageError("--agent webster plans from the shipped four-leg network and demand; it cannot "
                             "plan for --scenario/--net/--routes/--sumocfg yet: run it without them")
        print(webster_plan(cfg).describe())
    if spec.agent_spec == "coordinated":
        print(describe_plan(controller_config(spec.agent_spec, cfg)) if scenario is None else
              "\n".join(f"{tls}: {describe_plan(controller_config(spec.agent_spec, c))}"
                        for tls, c in scenario.intersections.items()))
    # A wall-clock run is never silent: a live status line (periodic log lines when not on a terminal).
    status = StatusLine() if args.target and not args.no_progress else None
    tb = Testbed(None if scenario else cfg, scenario=scenario, action_type=spec.action_type,
                 target=_targets(args.target, scenario), sumo=spec.sumo, seed=spec.seed, agent=spec.agent,
                 duration=spec.duration, log_path=log_path, recover_after=spec.recover_after,
                 on_reset=_hooks(status.start if status else None, dashboard.attach if dashboard else None),
                 sumo_config=sumo_config)
    error: BaseException | None = None
    started = datetime.now()  # the controller's clock is the host's when it is `hils emulator serve`
    with _terminate_as_interrupt(), tb, _served(dashboard):
        try:
            tb.reset()
            if tb.mode != VIRTUAL and args.asclog is None:
                tb.events.emit(Kind.NOTE, message=record.KEPT_BY_CONTROLLER)
            if tb.mode == VIRTUAL and not args.no_progress:
                with _progress(spec) as bar:
                    tb.run(progress=lambda t: bar.update(t - bar.n))
            else:
                tb.run()
        except (AgentFailed, RunInterrupted, KeyboardInterrupt) as exc:
            error = exc
        except UserError:
            raise
        except Exception as exc:  # an error inside the run: the run is finished, say so and keep what it logged
            if args.verbose:
                raise
            error = exc
        finally:
            if status is not None:
                status.close()
    outputs = [log_path.name if log_path.parent == out else str(log_path), "summary.json"]
    if tb.several:
        s = summary.summarize_network(tb.tally, {tls: (j.tally, j.config) for tls, j in tb.junctions.items()},
                                      traffic=tb.traffic, wall_s=tb.wall_s)
        outputs += _network_plots(tb, s, out, window)
    else:
        s = summary.summarize(tb.tally, tb.config, traffic=tb.traffic, wall_s=tb.wall_s)
        outputs += _plots(tb.junction, s, out, window)
    s["record"], kept = record.keep(tb.hires(), tb.configs, out, several=tb.several, asclog=args.asclog,
                                    since=started - timedelta(seconds=1))
    outputs += kept
    summary.write(s, out / "summary.json")
    print(summary.render_network(s) if tb.several else summary.render(s))
    print("\n".join(record.describe(s["record"])))
    for warning in summary.warnings(s):
        print(warning)
    print(f"Outputs in {out}/: {', '.join(outputs)}")
    return _ending(tb.end_reason, error)


def _plots(junction: Junction, s: dict[str, Any], folder: Path, window: tuple[float, float], *,
           prefix: str = "", name: str | None = None) -> list[str]:
    """One controller's signal timeline and queue plot in ``folder`` (``prefix``: what the network's summary puts
    before its approaches' names, as :attr:`hils.sumo.Light.prefix`; ``name``: the intersection's, default its
    config's); returns the names of the files written."""
    written = []
    name = name or junction.config.name
    if junction.tally.records:
        plots.signal_timeline(junction.tally.records, junction.config, folder / "signal_timeline.svg",
                              start=window[0], end=window[1], label=name)
        written.append("signal_timeline.svg")
    if junction.traffic_samples:
        approaches = s["traffic"]["approaches"] if s.get("traffic") else None
        spillback = None if approaches is None else {
            a: [60.0 * m for m in approaches[prefix + a]["spillback_minutes"]]
            for a in junction.traffic_samples[0][1] if prefix + a in approaches}
        plots.queues(junction.traffic_samples, folder / "queues.svg", title=f"Queues per approach, {name}",
                     spillback=spillback)
        written.append("queues.svg")
    return written


def _network_plots(tb: Testbed, s: dict[str, Any], out: Path, window: tuple[float, float]) -> list[str]:
    """Per traffic light, a folder with its signal timeline and queues; and the network's queues, one line per
    light (the queues of its approaches summed)."""
    per_light: set[str] = set()
    for tls, j in tb.junctions.items():
        folder = out / tls
        folder.mkdir(exist_ok=True)
        per_light.update(_plots(j, s, folder, window, name=f"{tls} ({j.config.name})",
                                prefix=j.view.prefix if j.view is not None else ""))
    lights = list(tb.junctions)
    written = [f"{lights[0]}/ .. {lights[-1]}/ ({', '.join(sorted(per_light, reverse=True))})"] if per_light else []
    samples = [j.traffic_samples for j in tb.junctions.values()]
    if all(samples):
        network = [(at[0][0], {tls: sum(q.values()) for tls, (_, q) in zip(tb.junctions, at, strict=True)})
                   for at in zip(*samples, strict=False)]
        plots.queues(network, out / "queues.svg", title=f"Queues per intersection (approaches summed), "
                                                        f"{tb.scenario.name}", legend="intersection")
        written.append("queues.svg")
    return written


def _scenario(args: argparse.Namespace) -> Scenario | None:
    """The scenario asked for; refuses what cannot go with it."""
    if args.scenario is None:
        return None
    clash = [flag for flag, given in (("--config", args.config), ("--net", args.net), ("--routes", args.routes),
                                      ("--sumocfg", args.sumocfg)) if given]
    if clash:
        raise UsageError(f"--scenario brings its own network and configs: drop {', '.join(clash)}")
    return load_scenario(args.scenario)


def _targets(target: str | None, scenario: Scenario | None) -> str | dict[str, str]:
    """--target: one URL, or (a scenario of several controllers) a TOML file of one URL per traffic light."""
    if target is None:
        return VIRTUAL
    if target.startswith("snmp://"):
        return target
    if scenario is None or len(scenario.intersections) == 1:
        raise UsageError(f"--target {target!r}: allowed: snmp://HOST:PORT?community=NAME&version=1|2c")
    return load_targets(target)


def _dashboard(args: argparse.Namespace) -> Any:
    """The live dashboard asked for (None without --dashboard)."""
    if args.dashboard is None:
        if args.dashboard_control:
            raise UsageError("--dashboard-control needs --dashboard PORT")
        return None
    if not args.target:
        raise UsageError("--dashboard serves wall-clock runs (--target snmp://...); watch a virtual-time run "
                         "afterwards with `hils view RUN_DIR --realtime 10`")
    if not 0 <= args.dashboard <= 65535:
        raise UsageError(f"--dashboard must be a TCP port from 0 to 65535, got {args.dashboard}")
    from hils.dashboard.live import LiveDashboard

    return LiveDashboard(args.dashboard, control=args.dashboard_control)


@contextlib.contextmanager
def _served(dashboard: Any) -> Iterator[None]:
    """Stop the dashboard's server when the run is over, before the Testbed closes its loop."""
    try:
        yield
    finally:
        if dashboard is not None:
            dashboard.stop()


def _hooks(*hooks: Any) -> Any:
    """One ``on_reset`` hook calling each of ``hooks`` that is given (None when none is)."""
    given = [h for h in hooks if h is not None]
    if not given:
        return None

    def on_reset(testbed: Testbed, target: Any) -> None:
        for hook in given:
            hook(testbed, target)

    return on_reset


class UsageError(UserError):
    """A command-line mistake: one line on stderr, exit status 2."""


#: Exit status per way a run ends (0 only for a normal end).
EXIT_STATUS = {"duration": 0, "interrupted": 130, "terminated": 143, "agent_error": 1, "error": 1}


def _ending(reason: str | None, error: BaseException | None) -> int:
    """Say how the run ended (one line, stderr for anything but a normal end) and return the exit status."""
    if reason == "duration" and error is None:
        print("Run ended: its duration passed.")
        return 0
    cause = error.__cause__ if isinstance(error, AgentFailed) and error.__cause__ else error
    how = {"interrupted": "interrupted (Ctrl-C)", "terminated": "terminated (SIGTERM)",
           "agent_error": f"the agent failed: {error}", }.get(reason or "error", f"error: {cause}")
    print(f"hils run: run ended early, {how}; calls cleared, outputs written (use -v for a traceback)",
          file=sys.stderr)
    if isinstance(error, AgentFailed) and cause is not error:
        log.debug("agent traceback", exc_info=cause)
    return EXIT_STATUS.get(reason or "error", 1)


def _run_folder(given: Path | None, action_type: str) -> Path:
    """The run's folder: the one given, or a new one under reports/runs/ that no other run uses."""
    if given is not None:
        try:
            given.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"cannot create the output folder {given}: {exc.strerror}") from None
        return given
    base = Path("reports/runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{action_type}"
    for n in range(1, 1000):
        candidate = base if n == 1 else base.with_name(f"{base.name}-{n}")
        try:
            candidate.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            continue  # another run started in the same second: take the next name
        except OSError as exc:
            raise UsageError(f"cannot create the output folder {candidate}: {exc.strerror}") from None
        return candidate
    raise UsageError(f"no free run folder name beside {base}")


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM ends a virtual-time run like Ctrl-C does (the wall-clock driver handles both itself)."""
    def handler(signum: int, frame: Any) -> None:
        raise RunInterrupted("terminated")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _progress(spec: RunSpec):
    from tqdm import tqdm

    return tqdm(total=spec.duration, unit="sim s", desc=f"{spec.action_type.value}",
                bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]")
