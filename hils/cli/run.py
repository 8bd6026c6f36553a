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
import math
import os
import signal
import sys
import tempfile
import urllib.parse
from collections.abc import Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from hils.agents.builtin import (
    PLAN_AGENTS,
    ScheduleAgent,
    check_plans,
    controlled_by,
    controller_config,
    describe_plan,
)
from hils.cli.status import Notices, StatusLine
from hils.control import phase_control
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.protocol.config import ConfigError, IntersectionConfig
from hils.protocol.errors import AgentFailed, RunInterrupted, UserError
from hils.protocol.scenario import SCENARIOS, Scenario, load_scenario, load_targets
from hils.report import outfiles, plots, record, summary
from hils.report.outfiles import Outputs
from hils.run.intersection import Intersection
from hils.run.testbed import BLIND_AGENTS, DEFAULT_AGENTS, RunSpec, Testbed, reason_of
from hils.shell import hiresjournal
from hils.shell.asclog import Bounds
from hils.shell.events import Kind
from hils.shell.targets import VIRTUAL
from hils.sim.network import scenario_config
from hils.sim.webster import webster_plan

log = logging.getLogger(__name__)

RUN_HELP = """\
Run a control agent against a signal controller through the middleware.

Default (no arguments): the shipped four-leg intersection, the max-pressure agent
choosing phase pairs every 10 s, one simulated hour of SUMO traffic, and the
built-in NTCIP 1202 emulator in virtual time. With --schedule FILE the run
commands by phase control instead: the holds, force-offs, omits and calls of
MMITSS's schedule JSON, from the run's start, re-sent before the controller's
backup time runs out and cleared at its end (docs/phase-control.md).

Outputs go to a run folder under reports/runs/: the JSON Lines event log,
summary.json, a signal timeline and a queue plot, and the controller's hi-res
log (hires.parquet) with its ATSPM measures and charts. The event log and the hi-res log (hires.journal.csv until
the run ends) are written as the run goes: a run killed with SIGKILL keeps them.
At the end the small files come first (summary.json before the pictures, the
pictures before hires.parquet); a file that cannot be written is named with why
in summary.json, and the others are still written.

One flag to real hardware: --target snmp://HOST:PORT?community=NAME&version=1|2c
runs the same agent and middleware at wall-clock time against that controller
(or against `hils emulator serve`). For an Econolite Cobalt: version=1, port 501,
community = the controller's user name (default administrator).

A TIMEOUT is one console line when it happens, and its recovery another. Every
way the run ends clears the calls it placed first, and a last line says how it
ended. Exit status:
  0    the duration passed, every controller under control to the end
  1    an error: the agent failed, or the event log or the outputs could not be
       written (the calls are cleared all the same)
  2    bad input, refused before the run started
  3    a controller was lost: the run ended in an unrecovered TIMEOUT, or its
       calls could not be cleared (they stay until the controller's backup time)
  130  interrupted (Ctrl-C)
  143  terminated (SIGTERM)
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run an agent against a controller (the main job)", description=RUN_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="FILE", help="intersection config (TOML); default: the shipped four-leg")
    p.add_argument("--action-type", choices=[t.value for t in ActionType],
                   help="action design: selection (pick a pair), switch (0 keep / 1 advance), duration "
                        "(green time of the next pair), control (holds, force-offs, omits and calls per phase: "
                        "docs/phase-control.md); default: selection, control with --schedule")
    p.add_argument("--schedule", metavar="FILE", type=Path,
                   help="phase control by a schedule: MMITSS's JSON ({\"MsgType\": \"Schedule\", \"Schedule\": "
                        "[{\"commandPhase\": 2, \"commandType\": \"hold\", \"commandStartTime\": 0, "
                        "\"commandEndTime\": 24}, ...]} or its list of commands; types hold, forceoff, omit_veh, "
                        "omit_ped, call_veh, call_ped; times in seconds from the run's start), handed over at the "
                        "first decision; one intersection, no --agent")
    p.add_argument("--agent", metavar="NAME|MODULE:CLASS",
                   help="built-in agent (random, fixed-cycle, max-pressure, queue-proportional, webster; actuated: "
                        "none, the controller runs on its detectors; coordinated: none, the controller runs its "
                        "config's timing plan on its detectors; fixed-time: none, the controller runs that plan "
                        "pretimed, every phase on max recall, no detectors) or your own package.module:Class; default "
                        "per action type: " + ", ".join(f"{k.value} -> {v}" for k, v in DEFAULT_AGENTS.items())
                        + "; with --no-sumo (no traffic to observe): "
                        + ", ".join(f"{k.value} -> {v}" for k, v in BLIND_AGENTS.items()))
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
                   help="recover this long after a TIMEOUT (default 5; negative: never)")
    p.add_argument("--take-over", action="store_true",
                   help="take the controller at once when someone else's calls are found on it, and clear them "
                        "(default: watch them for two control intervals first; calls that change mean another "
                        "manager at work, and the run refuses to start)")
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
    bounds = Bounds()
    p.add_argument("--asclog-timeout", type=float, default=bounds.seconds, metavar="S",
                   help="--asclog: the most the collection may take, from connecting to the last byte "
                        f"({bounds.seconds:g}); each receive waits at most {bounds.read_timeout:g} s")
    p.add_argument("--asclog-max-mb", type=float, default=bounds.max_bytes / 2**20, metavar="MB",
                   help=f"--asclog: the largest log collected ({bounds.max_bytes / 2**20:g} MB; a day of the "
                        "shipped four-leg's actuated controller, 9,900 events an hour, is 19 MB)")
    p.set_defaults(func=run_command)


def _window(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        a = b = math.nan
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise UsageError(f"--plot-window is {text!r}; allowed: START:END in simulated seconds, 0 <= START < END")
    return a, b


#: The longest run: a year of simulated seconds (SUMO's clock and every event log stay exact far beyond it).
MAX_DURATION = 365 * 24 * 3600.0

#: The seeds a run takes: SUMO's are 32-bit signed integers, and gymnasium's are never negative.
MAX_SEED = 2**31 - 1


def _check_values(args: argparse.Namespace) -> None:
    """Refuse the numbers a run cannot take, naming the option and what it allows."""
    if not 0 < args.duration <= MAX_DURATION:
        raise UsageError(f"--duration is {args.duration:g}; allowed: simulated seconds > 0, at most "
                         f"{MAX_DURATION:g} (a year)")
    if math.isnan(args.recover_after):
        raise UsageError("--recover-after is nan; allowed: seconds >= 0, or negative for never")
    if not 0 <= args.seed <= MAX_SEED:
        raise UsageError(f"--seed is {args.seed}; allowed: 0 to {MAX_SEED}")
    for flag, value, least in (("--asclog-timeout", args.asclog_timeout, 0.001),
                               ("--asclog-max-mb", args.asclog_max_mb, 0.001)):
        if not (math.isfinite(value) and value >= least):
            raise UsageError(f"{flag} is {value:g}; allowed: a number >= {least:g}")
    if args.asclog is not None:
        url = urllib.parse.urlsplit(args.asclog)
        try:
            port = url.port
        except ValueError:
            port = -1
        if url.scheme != "http" or not url.hostname or port == -1 or url.path.strip("/") or url.query:
            raise UsageError(f"--asclog is {args.asclog!r}; allowed: http://HOST:PORT (the controller's event-log "
                             "endpoint, without a path)")


def _config(args: argparse.Namespace) -> IntersectionConfig:
    """The intersection config with the options that change it; a bad option value is blamed on the option."""
    cfg = config_mod.load(args.config)
    if args.poll_hz is None:
        return cfg
    try:
        return cfg.with_middleware(poll_hz=args.poll_hz)
    except ConfigError as exc:
        raise UsageError(f"--poll-hz {exc.message} (polls per second)") from None


def _schedule_agent(args: argparse.Namespace, cfg: IntersectionConfig,
                    scenario: Scenario | None) -> ScheduleAgent | None:
    """The agent that hands over ``--schedule``'s schedule, checked against the config (None without it); sets the
    action type it implies."""
    if args.schedule is None:
        args.action_type = args.action_type or ActionType.SELECTION.value
        return None
    if args.action_type not in (None, ActionType.CONTROL.value):
        raise UsageError(f"--schedule commands by phase control; --action-type is {args.action_type}: leave it out "
                         "or give control")
    if args.agent is not None or scenario is not None:
        raise UsageError("--schedule is the agent of one intersection: leave out --agent and --scenario")
    args.action_type = ActionType.CONTROL.value
    return ScheduleAgent(phase_control.load(args.schedule, cfg))


def run_command(args: argparse.Namespace) -> int:
    _check_values(args)
    cfg = _config(args)
    window = _window(args.plot_window)
    scenario = _scenario(args)
    schedule_agent = _schedule_agent(args, cfg, scenario)
    dashboard = _dashboard(args)
    if args.asclog is not None and (not args.target or scenario is not None):
        raise UsageError("--asclog collects the log of the one controller a wall-clock run drives: use it with "
                         "--target snmp://... and without --scenario")
    out = _run_folder(args.out, args.action_type)
    log_path = args.log or out / "events.jsonl"
    _check_room(out, log_path)
    sumo_config = scenario_config(sumocfg=args.sumocfg, net=args.net, routes=args.routes, directory=out)
    spec = RunSpec(cfg, ActionType(args.action_type), agent=args.agent, duration=args.duration, seed=args.seed,
                   log_path=log_path, recover_after=None if args.recover_after < 0 else args.recover_after,
                   sumo=not args.no_sumo)
    if spec.agent_spec == "webster":
        if sumo_config is not None or scenario is not None:
            raise UsageError("--agent webster plans from the shipped four-leg network and demand; it cannot "
                             "plan for --scenario/--net/--routes/--sumocfg yet: run it without them")
        print(webster_plan(cfg).describe())
    if spec.agent_spec in PLAN_AGENTS:
        if scenario is not None:
            check_plans(spec.agent_spec, scenario.name, scenario.intersections)
        print(describe_plan(controller_config(spec.agent_spec, cfg)) if scenario is None else
              "\n".join(f"{tls}: {describe_plan(controller_config(spec.agent_spec, c))}"
                        for tls, c in scenario.intersections.items()))
    # A wall-clock run is never silent: a live status line (periodic log lines when not on a terminal).
    status = StatusLine() if args.target and not args.no_progress else None
    tb = Testbed(None if scenario else cfg, scenario=scenario, action_type=spec.action_type,
                 target=_targets(args.target, scenario), sumo=spec.sumo, seed=spec.seed,
                 agent=schedule_agent or spec.agent,
                 duration=spec.duration, log_path=log_path, hires_path=out / hiresjournal.NAME,
                 recover_after=spec.recover_after,
                 on_reset=_hooks(status.start if status else None, dashboard.attach if dashboard else None),
                 sumo_config=sumo_config, take_over=args.take_over,
                 # a schedule drives an actuated controller (MMITSS's premise): SUMO's loops call its phases too
                 detectors=True if schedule_agent is not None else None)
    error: BaseException | None = None
    started = datetime.now()  # the controller's clock is the host's when it is `hils emulator serve`
    with _terminate_as_interrupt(), tb, _served(dashboard):
        try:
            with status.above() if status is not None else contextlib.nullcontext():
                tb.reset_all()
                # From here on: a controller refused at start-up is said once, by the refusal itself.
                tb.events.subscribe(Notices())
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
        if error is not None:
            tb.finish(reason_of(error))  # a run that failed as it started is finished too (nothing stays called)
    if not any(i.tally.kinds[Kind.RUN_STARTED] for i in tb.intersections.values()):
        return _ending(tb, error, None, None)  # it never started: nothing to summarise
    bounds = Bounds(seconds=args.asclog_timeout, max_bytes=round(args.asclog_max_mb * 2**20))
    s, files = _outputs(tb, out, log_path, window, asclog=args.asclog, since=started - timedelta(seconds=1),
                        bounds=bounds, verbose=args.verbose)
    print(summary.render(s, by=controlled_by(s["agent"], s["action_type"])))
    if "record" in s:
        print("\n".join(record.describe(s["record"])))
    for warning in summary.warnings(s):
        print(warning)
    print(f"Outputs in {out}/: {', '.join(_shown(files.written, tb)) or 'none'}")
    for line in files.lines():
        print(f"NOT WRITTEN: {line}")
    return _ending(tb, error, s, "; ".join(files.lines()) or None)


def _outputs(tb: Testbed, out: Path, log_path: Path, window: tuple[float, float], *, asclog: str | None,
             since: datetime, bounds: Bounds, verbose: bool) -> tuple[dict[str, Any], Outputs]:
    """The run's summary, and its files: the event log (written as the run went), then the small files before the
    large ones: summary.json, the plots, the controllers' record (collected first when it is at the controller),
    its measures and charts, and last the hi-res log. summary.json is written again at the end, naming what could
    not be written and why (it is written first so that a full disk or a kill while the rest is written leaves
    it, saying which files it was still writing)."""
    files = Outputs(out, raise_errors=verbose)
    if not tb.events.failure:
        files.written.append(log_path.name if log_path.parent == out else str(log_path))
    journal = tb.journal
    s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()}, traffic=tb.traffic,
                          wall_s=tb.wall_s)

    def write_summary() -> None:
        # Until the record is written, its journal is what holds it (its first events, if it stopped).
        held = [journal.path.name] if journal is not None and "record" not in s else []
        written = list(dict.fromkeys([*files.written, *held, "summary.json"]))
        summary.write({**s, "outputs": {"written": written, "failed": files.failed, "finished": "record" in s}},
                      out / "summary.json")

    files.write("summary.json", write_summary)
    _plots(tb, s, files, window)
    kept = record.gather(tb.hires(), tb.configs, tb.devices, asclog=asclog, since=since, bounds=bounds,
                         journal=journal)
    kept.write_small(files, several=len(tb.intersections) > 1)
    kept.write_log(files)
    if kept.journal_kept is not None:
        files.written.append(kept.journal_kept)  # the record's file could not be written: the journal stays
    s["record"] = kept.section
    files.write("summary.json", write_summary)
    kept.drop_journal()
    return s, files


def _shown(written: list[str], tb: Testbed) -> list[str]:
    """The files written as the console lists them: the intersections' folders of a run of several as one entry."""
    labels = [i.label for i in tb.intersections.values() if i.label]
    if not labels:
        return written
    inside = sorted({Path(name).name for name in written if Path(name).parts[0] in labels}, reverse=True)
    rest = [name for name in written if Path(name).parts[0] not in labels]
    return rest + ([f"{labels[0]}/ .. {labels[-1]}/ ({', '.join(inside)})"] if inside else [])


def _plots(tb: Testbed, s: dict[str, Any], files: Outputs, window: tuple[float, float]) -> None:
    """Each intersection's signal timeline and queue plot, in the run folder (a run of one) or in a folder of its
    own named by its label; for several, the network's queues too (one line per intersection, the queues of its
    approaches summed)."""
    for i in tb.intersections.values():
        _intersection_plots(i, s, files, window)
    labels = [i.label for i in tb.intersections.values() if i.label]
    samples = [i.traffic_samples for i in tb.intersections.values()]
    if not labels or not all(samples):
        return
    network = [(at[0][0], {label: sum(q.values()) for label, (_, q) in zip(labels, at, strict=True)})
               for at in zip(*samples, strict=False)]
    files.write("queues.svg", lambda: plots.queues(network, files.folder / "queues.svg",
                                                   title=f"Queues per intersection (approaches summed), "
                                                         f"{tb.scenario.name}", legend="intersection"))


def _intersection_plots(i: Intersection, s: dict[str, Any], files: Outputs, window: tuple[float, float]) -> None:
    """One intersection's signal timeline and queue plot, in its folder."""
    folder = files.folder / i.label if i.label else files.folder
    prefix = f"{i.label}/" if i.label else ""
    name = plots.named(i.label, i.config)
    if i.tally.records:
        files.write(f"{prefix}signal_timeline.svg", lambda: plots.signal_timeline(
            i.tally.records, i.config, folder / "signal_timeline.svg", start=window[0], end=window[1], label=name,
            preemptions=i.tally.preemptions))
    if i.traffic_samples:
        approaches = s["traffic"]["approaches"] if s.get("traffic") else None
        signals = i.signals.prefix if i.signals is not None else ""  # how the summary names its approaches
        spillback = None if approaches is None else {
            a: [60.0 * m for m in approaches[signals + a]["spillback_minutes"]]
            for a in i.traffic_samples[0][1] if signals + a in approaches}
        files.write(f"{prefix}queues.svg", lambda: plots.queues(
            i.traffic_samples, folder / "queues.svg", title=f"Queues per approach, {name}", spillback=spillback))


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

    def on_reset(testbed: Testbed) -> None:
        for hook in given:
            hook(testbed)

    return on_reset


class UsageError(UserError):
    """A command-line mistake: one line on stderr, exit status 2."""


#: Exit status per way a run ends (0 only for a normal end); see :data:`RUN_EPILOG`.
EXIT_STATUS = {"duration": 0, "interrupted": 130, "terminated": 143, "agent_error": 1, "error": 1}
#: A controller lost: the run ended in an unrecovered TIMEOUT, or its calls could not be cleared.
LOST = 3


def _ending(tb: Testbed, error: BaseException | None, s: dict[str, Any] | None, unwritten: str | None) -> int:
    """Say how the run ended (one line, on stderr for anything but a normal end) and return the exit status."""
    reason = tb.end_reason or "error"
    lost = summary.lost(s) if s is not None else []
    failure = tb.events.failure if tb.events is not None else None
    if reason == "duration" and error is None and not lost and unwritten is None and failure is None:
        print("Run ended: its duration passed.")
        return 0
    cause = error.__cause__ if isinstance(error, AgentFailed) and error.__cause__ else error
    if s is None:
        how = f"the run did not start: {error}"
    elif reason == "duration":
        how = "its duration passed" + (", but the controller was lost" if lost else "")
    else:
        how = "run ended early, " + {"interrupted": "interrupted (Ctrl-C)", "terminated": "terminated (SIGTERM)",
                                     "agent_error": f"the agent failed: {error}"}.get(reason, f"error: {cause}")
    parts = [how]
    if failure is not None and failure is not cause and str(failure) != str(cause):
        parts.append(f"error: {failure}")  # the log failed as the run was ending
    parts += lost
    if s is not None:
        calls = summary.cleared(s)
        if calls is not False:  # not cleared: a line of `lost` says so
            parts.append("calls cleared" if calls else "no call was placed")
        parts.append(f"not written: {unwritten}" if unwritten else "outputs written")
    if reason in ("agent_error", "error"):
        parts.append("use -v for a traceback")
    print(f"hils run: {'; '.join(parts)}", file=sys.stderr)
    if isinstance(error, AgentFailed) and cause is not error:
        log.debug("agent traceback", exc_info=cause)
    if reason in ("interrupted", "terminated"):
        return EXIT_STATUS[reason]
    if lost:
        return LOST
    return 1 if failure is not None or unwritten is not None else EXIT_STATUS.get(reason, 1)


def _check_room(out: Path, log_path: Path) -> None:
    """Refuse, before anything is sent to a controller, a run whose outputs cannot be written at all: a full disk,
    a file size limit that allows nothing, a folder that is not writable, a --log that is a folder."""
    if log_path.is_dir():
        raise UsageError(f"--log {log_path} is a folder; allowed: the path of a file")
    for folder in dict.fromkeys((out, log_path.parent)):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder) as probe:
                os.write(probe.fileno(), b"\n")
        except OSError as exc:
            raise UsageError(f"no room for the run's outputs in {folder}: {exc.strerror or exc}") from None


def _run_folder(given: Path | None, action_type: str) -> Path:
    """The run's folder: the one given, or a new one under reports/runs/ that no other run uses."""
    return outfiles.given_folder(given) if given is not None else outfiles.fresh_folder(action_type)


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


@contextlib.contextmanager
def _progress(spec: RunSpec) -> Iterator[Any]:
    """A progress bar of the simulated time, with the console's log lines written above it."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    with tqdm(total=spec.duration, unit="sim s", desc=f"{spec.action_type.value}",
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]") as bar, \
            logging_redirect_tqdm():
        yield bar
