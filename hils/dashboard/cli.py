"""`hils view RUN_DIR`: replay a finished run in the dashboard's page, with a time slider."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hils.dashboard import DashboardError
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.resco import light_of
from hils.protocol.scenario import RESCO_PREFIX, Scenario, load_scenario

if TYPE_CHECKING:  # the dashboard's modules load when a page is served, not for `hils --help`
    from hils.dashboard.board import Panels, Replay
    from hils.shell.events import BadLine

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
    from hils.dashboard.server import address, bind, create_app, server, url

    if not (math.isfinite(args.realtime) and args.realtime > 0):
        raise DashboardError(f"--realtime is {args.realtime:g}; allowed: a positive factor (1 = sim speed)")
    if not 0 <= args.port <= 65535:
        raise DashboardError(f"--port is {args.port}; allowed: a TCP port from 0 to 65535 (0: any free one)")
    replay, log_path, skipped = load_replay(args.run, config=args.config, scenario=args.scenario)
    if skipped:
        print(f"hils view: left out {len(skipped)} line{'s' if len(skipped) > 1 else ''} of {log_path} that "
              f"{'are' if len(skipped) > 1 else 'is'} not a record of a run: {'; '.join(skipped[:3])}"
              f"{'; ...' if len(skipped) > 3 else ''}", file=sys.stderr)
    sock = bind("127.0.0.1", args.port)
    print(f"dashboard: {url(sock)} (replay of {log_path}, {replay.end:.0f} sim s; Ctrl-C stops)", flush=True)
    try:
        app = create_app(replay, address(sock), realtime=args.realtime)
        asyncio.run(server(app, own_signals=True).serve(sockets=[sock]))
    finally:
        sock.close()
    return 0


def load_replay(run: Path, *, config: str | None = None, scenario: str | None = None
                ) -> tuple[Replay, Path, list[str]]:
    """The replay of a run folder (or its event log), the log's path, and the lines left out of it, each named
    with why: a line that is not a record, or a record the board cannot fold. A log that cannot be replayed at
    all (none there, no run_started first, nothing but bad lines) is refused in one line."""
    from hils.dashboard.board import Board, Replay
    from hils.shell.events import read

    log_path = run / "events.jsonl" if run.is_dir() else run
    if not log_path.is_file():
        raise DashboardError(f"{run}: no event log there; allowed: a run folder holding events.jsonl, "
                             "or an events.jsonl file")
    bad: list[BadLine] = []
    try:
        records = list(read(log_path, on_bad=bad.append))
    except OSError as exc:
        raise DashboardError(f"{log_path}: cannot be read ({exc.strerror}); allowed: an event log") from None
    if not records or records[0]["kind"] != "run_started":
        first = f"line {bad[0].line}: {bad[0].why}" if bad and (not records or bad[0].line == 1) else \
            f"a {records[0]['kind']} record" if records else "empty"
        raise DashboardError(f"{log_path}: its first record is not run_started ({first}); allowed: an event log "
                             "written by a run")
    started = records[0]
    intersections = started.get("intersections")
    if intersections is not None:
        if not (isinstance(intersections, list) and intersections and all(isinstance(t, str) for t in intersections)):
            raise DashboardError(f"{log_path}: run_started.intersections is {repr(intersections)[:40]}; allowed: "
                                 "the traffic lights of the run, a list of names")
        empty: Board | Panels = _panels(_scenario(started, scenario, log_path), intersections, log_path)
    else:
        empty = Board(_config(started, config, log_path))
    replay = Replay(empty, records)
    skipped = [f"line {b.line}: {b.why}" for b in bad] + [f"record seq {seq}: {why}" for seq, why in replay.skipped]
    return replay, log_path, skipped


def _config(started: dict, given: str | None, log_path: Path) -> IntersectionConfig:
    """The config the run used: the one given, the file its run_started names, the shipped one, or a RESCO light's
    derived anew from the installed sumo-rl (its source names the scenario and the light)."""
    if given is not None:
        return config_mod.load(given)
    source = started.get("source")
    default = config_mod.load(None)
    if source in (None, default.source):
        return default
    if isinstance(source, str) and Path(source).is_file():
        return config_mod.load(source)
    light = light_of(source) if isinstance(source, str) else None
    if light is not None:
        derived = load_scenario(light[0]).intersections
        if light[1] in derived:
            return derived[light[1]]
    raise DashboardError(f"{log_path}: run_started.source: {source} is not a file here; allowed: give the run's "
                         "config with --config FILE")


def _scenario(started: dict, given: str | None, log_path: Path) -> Scenario:
    """The scenario the run used: the one given, the file its run_started names, or RESCO's of its name (read from
    the installed sumo-rl, as the run did)."""
    if given is not None:
        return load_scenario(given)
    source, name = started.get("source"), started.get("scenario")
    if isinstance(source, str) and Path(source).is_file():
        return load_scenario(source)
    if isinstance(name, str) and name.startswith(RESCO_PREFIX):
        return load_scenario(name)
    raise DashboardError(f"{log_path}: run_started.source: {source} is not a file here; allowed: give the run's "
                         "scenario with --scenario NAME|FILE")


def _panels(scenario: Scenario, intersections: list[str], log_path: Path) -> Panels:
    """Empty panels of the scenario's intersections, placed as on its network's map."""
    from hils.dashboard.board import Panels
    from hils.sim.network import light_positions

    if sorted(intersections) != sorted(scenario.intersections):
        raise DashboardError(f"{log_path}: the run's intersections {', '.join(intersections)} are not those of "
                             f"{scenario.source} ({', '.join(scenario.intersections)}); allowed: the run's own "
                             "scenario (--scenario NAME|FILE)")
    configs = {tls: scenario.intersections[tls] for tls in intersections}
    return Panels.of(configs, light_positions(scenario))
