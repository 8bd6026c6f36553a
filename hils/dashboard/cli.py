"""`hils view RUN_DIR`: replay a finished run in the dashboard's page, with a time slider."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path
from typing import TYPE_CHECKING

from hils import config as config_mod
from hils.config import IntersectionConfig
from hils.dashboard import DashboardError
from hils.scenario import Scenario, load_scenario

if TYPE_CHECKING:  # the dashboard's modules load when a page is served, not for `hils --help`
    from hils.dashboard.board import Panels

VIEW_HELP = """\
Replay a finished run (a run folder of `hils run`, or its events.jsonl) in the dashboard's page:
the ring-and-barrier diagram, the manager's state, the last commands, polls and queues at any
instant, with a time slider; a run of several controllers (a corridor, a grid) shows one panel per
intersection, laid out as on the network's map. --realtime FACTOR plays it at FACTOR times sim
speed (1 or 10 to watch a virtual-time run as it would have run at the wall clock). Stop with Ctrl-C.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="replay a finished run in the dashboard's page", description=VIEW_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="run folder (with events.jsonl) or an event log file")
    p.add_argument("--port", type=int, default=8014, help="TCP port on 127.0.0.1 (8014; 0: any free one)")
    p.add_argument("--realtime", type=float, default=1.0, metavar="FACTOR",
                   help="play back at FACTOR x sim speed when Play is pressed (1)")
    p.add_argument("--config", metavar="FILE", help="the run's intersection config, when the one the log names "
                                                    "cannot be found")
    p.add_argument("--scenario", metavar="NAME|FILE", help="a run of several controllers: its scenario, when the "
                                                           "one the log names cannot be found")
    p.set_defaults(func=view_command)


def view_command(args: argparse.Namespace) -> int:
    from hils.dashboard.board import Board, Replay
    from hils.dashboard.server import address, bind, create_app, server, url
    from hils.events import read

    if not args.realtime > 0:
        raise DashboardError(f"--realtime must be a positive factor (1 = sim speed), got {args.realtime:g}")
    log_path = args.run / "events.jsonl" if args.run.is_dir() else args.run
    if not log_path.is_file():
        raise DashboardError(f"{args.run}: no event log there; allowed: a run folder holding events.jsonl, "
                             "or an events.jsonl file")
    records = list(read(log_path))
    if not records or records[0].get("kind") != "run_started":
        raise DashboardError(f"{log_path}: first record: not run_started; allowed: an event log written by a run")
    started = records[0]
    if "intersections" in started:
        empty: Board | Panels = _panels(_scenario(started, args.scenario, log_path), started["intersections"], log_path)
    else:
        empty = Board(_config(started, args.config, log_path))
    replay = Replay(empty, records)
    sock = bind("127.0.0.1", args.port)
    print(f"dashboard: {url(sock)} (replay of {log_path}, {replay.end:.0f} sim s; Ctrl-C stops)", flush=True)
    try:
        app = create_app(replay, address(sock), realtime=args.realtime)
        asyncio.run(server(app, own_signals=True).serve(sockets=[sock]))
    finally:
        sock.close()
    return 0


def _config(started: dict, given: str | None, log_path: Path) -> IntersectionConfig:
    """The config the run used: the one given, or the file its run_started names, or the shipped one."""
    if given is not None:
        return config_mod.load(given)
    source = started.get("source")
    default = config_mod.load(None)
    if source in (None, default.source):
        return default
    if Path(source).is_file():
        return config_mod.load(source)
    raise DashboardError(f"{log_path}: run_started.source: {source} is not a file here; allowed: give the run's "
                         "config with --config FILE")


def _scenario(started: dict, given: str | None, log_path: Path) -> Scenario:
    """The scenario the run used: the one given, or the file its run_started names."""
    if given is not None:
        return load_scenario(given)
    source = started.get("source")
    if source is not None and Path(source).is_file():
        return load_scenario(source)
    raise DashboardError(f"{log_path}: run_started.source: {source} is not a file here; allowed: give the run's "
                         "scenario with --scenario NAME|FILE")


def _panels(scenario: Scenario, intersections: list[str], log_path: Path) -> Panels:
    """Empty panels of the scenario's intersections, placed as on its network's map."""
    from hils.dashboard.board import Panels
    from hils.sumo_net import light_positions

    if sorted(intersections) != sorted(scenario.intersections):
        raise DashboardError(f"{log_path}: the run's intersections {', '.join(intersections)} are not those of "
                             f"{scenario.source} ({', '.join(scenario.intersections)}); allowed: the run's own "
                             "scenario (--scenario NAME|FILE)")
    configs = {tls: scenario.intersections[tls] for tls in intersections}
    return Panels.of(configs, light_positions(scenario))
