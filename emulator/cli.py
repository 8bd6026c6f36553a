"""`hils emulator ...`: commands of the NTCIP 1202 controller emulator."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from emulator.agent.asclog import MAX_CONNECTIONS, WRITE_TIMEOUT
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import ASCLOG_PATH
from hils.protocol.ntcip import AUTH_KEY_ENV, PRIV_KEY_ENV, Version
from hils.protocol.scenario import SCENARIOS, load_scenario
from hils.protocol.usm import services_missing

if TYPE_CHECKING:
    from emulator.agent.serve import EmulatorServer
    from emulator.agent.snmp import V3User

#: ``--http`` without a port: each controller's event log on the TCP port numbered as its UDP port.
SAME_PORTS = -1


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("emulator", help="the NTCIP 1202 controller emulator",
                            description="The NTCIP 1202 controller emulator: a dual-ring NEMA controller model.")
    commands = parser.add_subparsers(dest="emulator_command", metavar="COMMAND", required=True)
    _register_demo(commands)
    _register_serve(commands)


def _register_demo(commands: argparse._SubParsersAction) -> None:
    demo = commands.add_parser(
        "demo", help="run the controller model in virtual time and print its interval timeline",
        description="Run the controller model for a minute of virtual time, place vehicle calls on "
                    "[3,7], [4,8], [1,5] and [1,6] and a pedestrian call on 4 (the throughs get a 4 s walk and "
                    "5 s pedestrian clearance unless the config gives them their own), and print every change "
                    "of the signal display, the pedestrian intervals and the committed next phases.")
    demo.add_argument("--config", metavar="FILE", help="intersection config (TOML); default: the shipped four-leg")
    demo.add_argument("--duration", type=float, default=60.0, metavar="S", help="virtual seconds to run (60)")
    demo.set_defaults(func=_demo)


def _demo(args: argparse.Namespace) -> int:
    from emulator import demo

    cfg = demo.with_pedestrians(config_mod.load(args.config))
    print(f"{cfg.name}: calls at " + ", ".join(f"{t:g} s {list(p)}" for t, p in demo.DEFAULT_CALLS)
          + "; pedestrian calls at " + ", ".join(f"{t:g} s {list(p)}" for t, p in demo.DEFAULT_PED_CALLS))
    print(demo.render(demo.run(cfg, duration=args.duration), cfg))
    return 0


def _register_serve(commands: argparse._SubParsersAction) -> None:
    serve = commands.add_parser(
        "serve", help="serve the controller model as an SNMP agent at wall-clock time",
        description="Run the controller model at wall-clock time (one tick per 0.1 s) behind an SNMPv1/v2c "
                    "(and, with --v3-user, SNMPv3) agent on UDP until Ctrl-C or SIGTERM. Every SET is logged; "
                    "on exit the counts of requests answered and datagrams dropped are printed. With --count or "
                    "--scenario, one process serves many controllers, each its own model and agent on its own "
                    "port, all ticked together.")
    which = serve.add_mutually_exclusive_group()
    which.add_argument("--config", metavar="FILE", help="intersection config (TOML); default: the shipped four-leg")
    which.add_argument("--scenario", metavar="NAME|FILE",
                       help=f"serve every intersection of a scenario ({', '.join(SCENARIOS)}, resco:NAME or a "
                            ".scenario.toml), each with its own config, on consecutive ports in the scenario's order")
    serve.add_argument("--count", type=int, metavar="N",
                       help="serve N controllers on ports PORT..PORT+N-1 (1, or the scenario's number of "
                            "intersections)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (127.0.0.1)")
    serve.add_argument("--port", type=int, default=1161,
                       help="UDP port (of the first controller); 0 picks a free one for each (1161)")
    serve.add_argument("--ro-community", default="public", metavar="NAME", help="read-only community (public)")
    serve.add_argument("--rw-community", default="private", metavar="NAME", help="read-write community (private)")
    serve.add_argument("--latency-ms", type=float, default=0.0, metavar="MS", help="mean response delay (0)")
    serve.add_argument("--jitter-ms", type=float, default=0.0, metavar="MS",
                       help="uniform jitter of the response delay, +/- MS (0)")
    serve.add_argument("--v3-user", metavar="NAME",
                       help="also accept SNMPv3 from this user (USM, HMAC-SHA-96; read-write); keys are pass "
                            "phrases of 8 characters or more")
    serve.add_argument("--v3-auth-key", metavar="KEY",
                       help=f"the user's authentication key (SHA); default: ${AUTH_KEY_ENV}")
    serve.add_argument("--v3-priv-key", metavar="KEY",
                       help=f"the user's privacy key (AES-128): requests must be authPriv; default: ${PRIV_KEY_ENV}, "
                            "and without either authNoPriv is enough")
    serve.add_argument("--trace", type=Path, metavar="FILE",
                       help="write every interval change as JSON Lines, stamped with the monotonic clock")
    serve.add_argument("--http", type=int, nargs="?", const=SAME_PORTS, metavar="PORT",
                       help="also serve each controller's hi-res event log as an Intelight MaxTime does "
                            f"(GET http://HOST:PORT{ASCLOG_PATH}[?since=MM-DD-YYYY HH:MM:SS.0], the Indiana "
                            "enumerations), on TCP ports PORT.. (0: free ones); without PORT on the same numbers as "
                            "the UDP ports, where Signal-Replay looks for a controller on this host. The controllers' "
                            "clocks are the host's local time. The log is streamed a few events at a time between "
                            f"ticks, so that no request delays one; at most {MAX_CONNECTIONS} connections at once "
                            f"(more are answered 503), and a client that takes nothing of its answer for "
                            f"{WRITE_TIMEOUT:g} s is dropped")
    serve.add_argument("--ntcip", choices=[v.value for v in Version],
                       help="the edition of NTCIP 1202 the objects follow: v02 (what an Econolite Cobalt speaks, as "
                            "in the paper's lab) answers noSuchObject for the objects v03 added, but the detector "
                            "inputs; v03 serves them with v03's access (patternSplitNumber read-only). Default: the "
                            "config's [emulator] ntcip, v02 unless it says otherwise")
    serve.add_argument("--spat", type=_address, metavar="HOST:PORT",
                       help="also send each controller's SPaT every tick (10 Hz) as an Econolite controller "
                            "broadcasts it, in the UDP layout V2X Hub's SpatPlugin and MMITSS parse (per phase the "
                            "min and max time to change, status bitmasks), to HOST:PORT, the next controllers to "
                            "PORT+1..; see docs/spat.md")
    serve.add_argument("--j2735", type=_address, metavar="HOST:PORT",
                       help="also send each controller's SPaT every tick (10 Hz) as SAE J2735 SPaT messages (UPER "
                            "MessageFrame, messageId 19; startTime, minEndTime, maxEndTime and likelyTime per signal "
                            "group: phase p is group p, overlap n group 16+n) to HOST:PORT, the next controllers to "
                            "PORT+1..; needs pycrate (pip install 'hils[j2735]'); see docs/spat.md")
    serve.add_argument("--log-events", type=int, default=100_000, metavar="N",
                       help="hi-res events each controller keeps, its last ones, as a controller's ring buffer "
                            "(100000; an Intelight MaxTime keeps about 10000)")
    serve.set_defaults(func=_serve)


def _address(text: str) -> tuple[str, int]:
    """HOST:PORT of ``--spat`` and ``--j2735``."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: HOST:PORT with PORT 1..65535, e.g. 127.0.0.1:6053")
    return host, int(port)


def _v3_user(args: argparse.Namespace) -> V3User | None:
    from emulator.agent.snmp import V3User

    auth_key = args.v3_auth_key or os.environ.get(AUTH_KEY_ENV, "")
    priv_key = args.v3_priv_key or os.environ.get(PRIV_KEY_ENV, "")
    if args.v3_user is None:
        if args.v3_auth_key or args.v3_priv_key:
            raise SystemExit("hils emulator serve: --v3-auth-key and --v3-priv-key need --v3-user")
        return None
    if not auth_key:
        raise SystemExit(f"hils emulator serve: --v3-user needs --v3-auth-key (or ${AUTH_KEY_ENV})")
    try:
        user = V3User(args.v3_user, auth_key, priv_key)
    except ValueError as exc:
        raise SystemExit(f"hils emulator serve: {exc}") from None
    missing = services_missing(privacy=bool(priv_key))
    if missing:
        raise SystemExit(f"hils emulator serve: --v3-user {args.v3_user}: {missing}")
    return user


def _controllers(args: argparse.Namespace) -> list[tuple[str | None, IntersectionConfig]]:
    """(tls id or None, config) of each controller to serve, in port order."""
    from emulator.agent.serve import ServeError

    if args.count is not None and args.count < 1:
        raise ServeError(f"--count {args.count}: no controller to serve; allowed: 1 or more")
    if args.scenario is None:
        return [(None, config_mod.load(args.config))] * (1 if args.count is None else args.count)
    scenario = load_scenario(args.scenario)
    lights = list(scenario.intersections.items())
    if args.count is not None and args.count != len(lights):
        raise ServeError(f"--count {args.count} with --scenario {args.scenario}, which has {len(lights)} "
                         f"intersections; allowed: --count {len(lights)}, or no --count")
    return lights


def _port_range(ports: list[int]) -> str:
    return f"{ports[0]}..{ports[-1]}" if ports == list(range(ports[0], ports[-1] + 1)) else ",".join(map(str, ports))


def _serve(args: argparse.Namespace) -> int:
    import asyncio

    from emulator.agent.serve import ServeOptions, serve_until_signalled
    from hils.protocol.ntcip import Latency

    if args.ro_community == args.rw_community:
        raise SystemExit("hils emulator serve: --ro-community and --rw-community must differ")
    if not all(math.isfinite(ms) and ms >= 0 for ms in (args.latency_ms, args.jitter_ms)):
        raise SystemExit(f"hils emulator serve: --latency-ms {args.latency_ms:g} --jitter-ms {args.jitter_ms:g}; "
                         "allowed: finite milliseconds >= 0")
    if args.log_events < 1:
        raise SystemExit(f"hils emulator serve: --log-events {args.log_events}: allowed: 1 or more")
    if args.j2735 is not None:
        from emulator.agent import j2735

        try:
            j2735.require()
        except ImportError as exc:
            raise SystemExit(f"hils emulator serve: --j2735 needs pycrate ({exc}): pip install 'hils[j2735]'") from exc
    v3_user = _v3_user(args)
    controllers = _controllers(args)
    http = args.port if args.http == SAME_PORTS else args.http
    options = ServeOptions(host=args.host, port=args.port, ro_community=args.ro_community,
                           rw_community=args.rw_community, latency=Latency(args.latency_ms / 1e3, args.jitter_ms / 1e3),
                           trace=args.trace, v3_user=v3_user, http=http, log_events=args.log_events,
                           ntcip=Version(args.ntcip) if args.ntcip else None, spat=args.spat, j2735=args.j2735)

    def ready(server: EmulatorServer, addresses: list[tuple[str, int]]) -> None:
        # Scripts and tests wait for these lines: they are printed only once requests are answered.
        v3 = f" v3={v3_user.name}/{'authPriv' if v3_user.priv_key else 'authNoPriv'}" if v3_user else ""
        for (tls, cfg), (host, port) in zip(controllers, addresses, strict=True):
            label = f" [{tls}]" if tls is not None else ""
            print(f"serving {cfg.name}{label} on udp:{host}:{port} "
                  f"(ro={options.ro_community} rw={options.rw_community}{v3} "
                  f"ntcip={(options.ntcip or cfg.emulator.ntcip).value})")
        if len(addresses) > 1:
            print(f"serving {len(addresses)} controllers on udp:{addresses[0][0]}:"
                  f"{_port_range([port for _, port in addresses])}")
        for (tls, cfg), (host, port) in zip(controllers, server.http_addresses, strict=False):
            label = f" [{tls}]" if tls is not None else ""
            print(f"event log of {cfg.name}{label}: http://{host}:{port}{ASCLOG_PATH}")
        for (tls, cfg), sender in zip(controllers, server.spat, strict=False):
            label = f" [{tls}]" if tls is not None else ""
            print(f"SPaT of {cfg.name}{label} to udp:{sender.address[0]}:{sender.address[1]} (10 Hz)")
        for (tls, cfg), sender in zip(controllers, server.j2735, strict=False):
            label = f" [{tls}]" if tls is not None else ""
            print(f"J2735 SPaT of {cfg.name}{label} to udp:{sender.address[0]}:{sender.address[1]} (10 Hz)")
        sys.stdout.flush()

    try:
        summary = asyncio.run(serve_until_signalled([cfg for _, cfg in controllers], options, ready))
    except OSError as exc:  # binding a socket (BindError names the port) or opening the trace
        print(f"hils emulator serve: {exc}", file=sys.stderr)
        return 1
    print(summary.describe(), flush=True)
    return 0
