"""`hils bench ...`: benchmarks that print figures and write them as NAME.json.

Each writes to ``--out DIR`` or a new ``reports/runs/<time>-bench-NAME/``; ``--publish`` rebuilds the published
``reports/bench/NAME.json`` (:mod:`harness.published`). The folder is made before measuring: one that cannot be made
is said at once, not after an hour.

Figures are wall-clock measurements on a shared machine: each report states
the machine, and comparisons are made side by side within one run. Modules that
load libsumo or pysnmp are imported where they are used, so that `hils --help`
does not pay for them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from http import HTTPStatus
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import simpy

from harness import published
from harness.bench import corridor as bench_corridor
from harness.bench import floods, machine
from harness.bench import seeds as bench_seeds
from harness.bench.processes import in_fresh_process, snmpd, start_emulator
from harness.bench.seeds import Spread, seeds_text
from harness.bench.serve import resident_mb
from hils.control.actions import PAPER_ACTION_TYPES, ActionType
from hils.protocol import config as config_mod
from hils.protocol.ntcip import signal_oids
from hils.report import jsonout
from hils.report.latency import PAPER_LATENCY_MS, Stats, internal_latencies_ms
from hils.report.outfiles import write_whole
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind

if TYPE_CHECKING:
    from emulator.agent.serve import EmulatorServer, ServeSummary


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("bench", help="benchmarks (figures printed and written as JSON)",
                            description="Benchmarks: each prints its figures beside the machine it ran on and "
                                        "writes them to NAME.json in a new reports/runs/<time>-bench-NAME/ (or --out "
                                        "DIR); --publish rebuilds the published reports/bench/NAME.json.")
    commands = parser.add_subparsers(dest="bench_command", metavar="BENCH", required=True)
    lat = commands.add_parser("latency", help="middleware internal latency per action type (paper's Table)",
                              description="Middleware internal latency, as the paper defines it: from the agent's "
                                          "action reaching the middleware to the SET being dispatched, exclusive. "
                                          "Virtual time against the in-process emulator, event log written "
                                          "through to a file as in a real run.")
    lat.add_argument("--samples", type=int, default=1000, metavar="N", help="commands per action type (1000)")
    lat.add_argument("--seed", type=int, default=0)
    published.options(lat, "bench-latency", "bench")
    lat.set_defaults(func=_latency_command)
    over = commands.add_parser("overhead", help="wall time of the full loop over bare SUMO with the same traffic",
                               description="The cost of the HILS over bare SUMO: the wall time of the full loop "
                                           "(SUMO at 0.25 s steps, 10 Hz polling, middleware, emulator, max-pressure "
                                           "every 10 s) in virtual time, divided by the wall time of libsumo alone "
                                           "replaying, step for step, the signal states the loop showed (same "
                                           "seed: same vehicles; same_traffic checks equal departed and arrived "
                                           "counts). Each side once per seed, every run in a fresh process, "
                                           "alternately; the ratio is taken seed by seed and reported as its median "
                                           "and min-max, and the old baseline (libsumo running a fixed cycle at "
                                           "maximum green: other traffic) for the record.")
    over.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds (3600)")
    bench_seeds.seeds_option(over)
    over.add_argument("--instructions", action="store_true",
                      help="also count the instructions of each side under valgrind's callgrind (minutes; "
                           "exact and repeatable on a busy machine, where seconds are not)")
    published.options(over, "bench-overhead", "bench")
    over.set_defaults(func=_overhead_command)
    wire = commands.add_parser("wire", help="verification lag and GET round trip over UDP (wall-clock time)",
                               description="Against `hils emulator serve` in another process, over loopback UDP: "
                                           "(1) verification lag, from the moment the controller turned the "
                                           "commanded phases green (its trace, monotonic clock) to the manager's "
                                           "return to IDLE, at several polling rates; (2) the 3-varbind GET round "
                                           "trip (reds, yellows, greens) and the request rate, beside net-snmp's "
                                           "snmpd answering a comparable GET, with the client's and the agent's CPU "
                                           "per GET; (3) the emulator's tick lateness and memory under floods "
                                           "from another process: large datagrams with a wrong community, "
                                           "SNMPv3 requests without a user name (noAuthNoPriv, the agent's "
                                           "discovered engine ID), and requests for the controller's event log "
                                           "over HTTP (its last 100,000 events) from clients that read every "
                                           "answer whole, again and again, and from clients that never read one.")
    wire.add_argument("--duration", type=float, default=90.0, metavar="S",
                      help="wall-clock seconds of phase switching per polling rate (90)")
    wire.add_argument("--rates", default="10,50,100", metavar="HZ,...", help="polling rates (10,50,100)")
    wire.add_argument("--gets", type=int, default=2000, metavar="N", help="GETs per agent for the round trip (2000)")
    wire.add_argument("--flood", type=float, default=20.0, metavar="S",
                      help="seconds of the controller's tick measured without a flood and under each flood: 20 "
                           "datagrams of 60 KB a second with a wrong community, 3000 SNMPv3 GETs a second without "
                           "a user name, the event log asked by 6 clients reading it whole and 100 never reading "
                           "(20)")
    published.options(wire, "bench-wire", "bench")
    wire.set_defaults(func=_wire_command)
    env = commands.add_parser("env", help="the gymnasium environment's speed beside sumo-rl's (same network, demand)",
                              description="Environment steps per second and wall time per simulated hour of "
                                          "hils/Intersection-v1 beside sumo-rl's SumoEnvironment on the shipped "
                                          "four-leg network and demand: 0.25 s SUMO steps, a decision every 10 s, "
                                          "a seeded random policy; one episode of each side per seed, each in a "
                                          "fresh process, alternately; medians and min-max over the seeds, and "
                                          "hils' ratio to sumo-rl seed by seed (wall time, SUMO's part, own work). "
                                          "hils' controller enforces minimum green, yellow and red clearance; "
                                          "sumo-rl inserts its own yellow (the config's 3 s, and its 3 s minimum "
                                          "green, given in SUMO steps: sumo-rl counts them so) and no all-red, so "
                                          "the same demand makes different traffic (vehicles inserted and arrived "
                                          "are shown). Needs "
                                          "sumo-rl: pip install 'hils[bench]'.")
    env.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds per episode (3600)")
    bench_seeds.seeds_option(env, "0-7")
    published.options(env, "bench-env", "bench")
    env.set_defaults(func=_env_command)
    res = commands.add_parser("resco", help="hils' PettingZoo environment beside sumo-rl's on RESCO's networks",
                              description=(
                                          "Wall time per simulated hour of "
                                          "hils.envs.parallel_env(scenario='resco:NAME') (every light an emulated NEMA"
                                          " controller) beside sumo-rl's multi-agent SumoEnvironment on the same "
                                          "network and demand: 0.25 s SUMO steps, a decision every RESCO step length "
                                          "(10 s, 5 s on arterial4x4), sumo-rl given each light's yellow and minimum "
                                          "green in its unit (SUMO steps), a seeded random policy; one episode of each"
                                          " side per seed, each in a fresh process, alternately. Each side's time is "
                                          "split into SUMO's steps and its own work (also per controller-hour); "
                                          "vehicles inserted and arrived are shown. sumo-rl's PettingZoo wrapper does "
                                          "not start with pettingzoo 1.27 (agent_selector is now AgentSelector): its "
                                          "SumoEnvironment(single_agent=False) is stepped directly. Needs sumo-rl: pip"
                                          " install 'hils[bench]'."))
    res.add_argument("--scenarios", type=_resco_names, default="grid4x4,cologne8", metavar="NAME,...|all",
                     help="RESCO scenarios (grid4x4,cologne8; all: the eight)")
    res.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated seconds per episode (3600)")
    bench_seeds.seeds_option(res)
    published.options(res, "bench-resco", "bench")
    res.set_defaults(func=_resco_command)
    train = commands.add_parser("train", help="PPO training steps per second, hils beside sumo-rl (SB3, RLlib)",
                                description="Training throughput on PyTorch's CPU build, hils beside sumo-rl: "
                                            "(1) Stable-Baselines3 PPO on sumo-rl's single intersection, "
                                            "hils.sumo_rl.SumoEnvironment beside sumo-rl's SumoEnvironment (the same "
                                            "arguments: a decision every 5 s, yellow 3 s, min green 5 s; the same PPO "
                                            "settings), environment steps per second of learn(); (2) RLlib PPO on "
                                            "RESCO's grid4x4 as both give it (grid4x4(parallel=True): PettingZoo's "
                                            "parallel API, 16 lights, one shared policy), environment steps per second "
                                            "of its training iterations, sampled and learnt in one process. Each side "
                                            "once per seed, each run in a fresh process, alternately; medians and "
                                            "min-max over the seeds, hils' ratio to sumo-rl seed by seed (steps per "
                                            "second and per CPU second), each run's wall time split into SUMO, the "
                                            "environment's own work and the learner, its CPU time per step into the "
                                            "environment's and the learner's, and the machine's load. Needs the "
                                            "training libraries and sumo-rl: pip install 'hils[rl,bench]' (torch's "
                                            "CPU build first: docs/rl.md).")
    train.add_argument("--parts", type=_train_parts, default="sb3,rllib", metavar="sb3,rllib",
                       help="which trainings (sb3,rllib)")
    train.add_argument("--timesteps", type=_positive, default=2048, metavar="N",
                       help="Stable-Baselines3 PPO: environment steps learnt per run (2048: 8 rollouts of 256)")
    train.add_argument("--iterations", type=_positive, default=3, metavar="N",
                       help="RLlib PPO: training iterations per run (3)")
    train.add_argument("--batch", type=_positive, default=400, metavar="N",
                       help="RLlib PPO: environment steps per iteration (400)")
    train.add_argument("--torch-threads", type=_positive, default=1, metavar="N",
                       help="torch's threads in each run (1: small networks, a shared machine)")
    bench_seeds.seeds_option(train, "0-2")
    published.options(train, "bench-train", "bench")
    train.set_defaults(func=_train_command)
    spat = commands.add_parser("spat", help="share of indication changes inside the window the SPaT announced",
                               description="An hour of the four-leg with SUMO's traffic under the controller's "
                                           "actuated operation, the city's coordinated pattern and the max-pressure "
                                           "agent: the share of phase and overlap indication changes that came "
                                           "within the earliest and latest the controller's SPaT announced for them "
                                           "(goal 100 %), and the share that had a finite latest announced (so that "
                                           "the first is not hollow), per operation over several seeds. Virtual "
                                           "time, every tick stepped, each run in a fresh process.")
    spat.add_argument("--seconds", type=float, default=3600.0, metavar="S", help="simulated seconds per run (3600)")
    bench_seeds.seeds_option(spat, "0-2")
    spat.add_argument("--operation", action="append", choices=["actuated", "coordinated", "max-pressure"],
                      help="run only this operation (repeatable; default: all three)")
    published.options(spat, "bench-spat", "bench")
    spat.set_defaults(func=_spat_command)
    corridor = commands.add_parser("corridor", help="controllers one process drives at wall clock; virtual time and "
                                                    "memory per controller",
                                   description="(1) Wall clock: N controllers of one `hils emulator serve --count N` "
                                               "on loopback, driven by one middleware process at 10 Hz polling each "
                                               "(four-leg config, fixed-cycle agent, no SUMO), for N = 1, 4, 16, ... "
                                               "until a count fails: it passes without any TIMEOUT and with the "
                                               "driver's event lateness p99 under 20 ms (goal: 64 or more); the climb "
                                               "is made several times, and the count that passes is reported with "
                                               "its spread and what stopped each climb. (2) "
                                               "Virtual time: wall seconds per simulated controller-hour for 1, 4 "
                                               "and 16 controllers, with SUMO (four_leg, corridor, grid4x4) and "
                                               "without, one run per seed, alternately. (3) Resident memory of the "
                                               "middleware and of the serve process as N grows (goal: at most 10 MB "
                                               "per added controller). "
                                               "Every run in a fresh process.")
    corridor.add_argument("--counts", type=_counts, default=list(bench_corridor.WALL_COUNTS), metavar="N,...",
                          help="wall-clock controller counts, tried in order until one fails "
                               f"({','.join(map(str, bench_corridor.WALL_COUNTS))})")
    corridor.add_argument("--duration", type=float, default=30.0, metavar="S",
                          help="wall-clock seconds per count (30)")
    corridor.add_argument("--virtual-duration", type=float, default=600.0, metavar="S",
                          help="simulated seconds per virtual-time run (600)")
    corridor.add_argument("--climbs", type=_positive, default=3, metavar="N",
                          help="times the wall-clock counts are climbed, each until one fails (3)")
    bench_seeds.seeds_option(corridor)
    published.options(corridor, "bench-corridor", "bench")
    corridor.set_defaults(func=_corridor_command)


def measure_latency(samples: int, seed: int = 0) -> dict[str, Stats]:
    """Internal latency (ms) per action type over at least ``samples`` dispatched commands each."""
    cfg = config_mod.load()
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for action_type in PAPER_ACTION_TYPES:
            # Seconds of simulated time per dispatched command: random selection repeats the pair shown
            # about one decision in four; a duration command lasts its clearance plus a green of 3..20 s.
            per_command = {ActionType.SELECTION: 14.0, ActionType.SWITCH: 10.0, ActionType.DURATION: 18.0}
            duration = samples * per_command[action_type] * 1.15
            spec = RunSpec(cfg, action_type, duration=duration, seed=seed,
                           log_path=Path(tmp) / f"{action_type.value}.jsonl")
            result = run_spec(spec)
            values = internal_latencies_ms(result.records).get(action_type.value, [])
            out[action_type.value] = Stats.of(values[:samples])
    return out


def _latency_command(args: argparse.Namespace) -> int:
    folder = published.folder(args)
    info = machine.describe()
    stats = measure_latency(args.samples, args.seed)
    print(machine.header(info))
    print(f"{'action type':12} {'N':>6} {'mean us':>9} {'std us':>8} {'p50 us':>8} {'p99 us':>8}   "
          f"{'paper N':>7} {'mean us':>8} {'std us':>8}  {'paper/ours':>10}")
    rows: dict[str, Any] = {}
    for name, st in stats.items():
        pn, pmean, pstd = PAPER_LATENCY_MS[name]
        ratio = pmean / st.mean
        print(f"{name:12} {st.n:6d} {st.mean * 1e3:9.1f} {st.std * 1e3:8.1f} {st.p50 * 1e3:8.1f} {st.p99 * 1e3:8.1f}"
              f"   {pn:7d} {pmean * 1e3:8.1f} {pstd * 1e3:8.1f}  {ratio:9.1f}x")
        rows[name] = {"ours_ms": st.as_dict(), "paper_ms": {"n": pn, "mean": pmean, "std": pstd},
                      "paper_over_ours": ratio}
    print("target: mean < 50 us, p99 < 200 us")
    _write_figures(folder / "latency.json", {"machine": info, "latency": rows})
    return 0


def _spat_command(args: argparse.Namespace) -> int:
    from harness.bench import spat

    folder = published.folder(args)
    info = machine.describe()
    print(machine.header(info))
    shares = []
    for seed in args.seeds:
        for operation in args.operation or list(spat.OPERATIONS):
            print(f"{operation}, seed {seed}: {args.seconds:g} s ...", flush=True)
            shares.append(in_fresh_process(spat.measure, operation, args.seconds, seed))
    text, figures = spat.report(shares)
    print(text)
    _write_figures(folder / "spat.json", {"machine": info, **figures})
    return 0


def _write_figures(path: Path, figures: dict[str, Any]) -> None:
    """A benchmark's figures as JSON in ``path``, written whole, and the console told where."""
    write_whole(path, jsonout.dumps(figures) + "\n")
    print(f"written: {path}")


def _overhead_command(args: argparse.Namespace) -> int:
    from harness.bench.overhead import measure_instructions, measure_overhead

    folder = published.folder(args)
    info = machine.describe()
    f = measure_overhead(args.duration, args.seeds)
    print(machine.header(info))
    print(f"one simulated {f['duration_s']:g} s per run, seeds {seeds_text(f['seeds'])}, every run in a fresh process, "
          "alternately; median [min-max] over the seeds:")
    runs = f["runs"]
    for side, label in (("hils", "full HILS loop"), ("floor", "bare libsumo, same signal states"),
                        ("fixed_cycle", "bare libsumo, fixed cycle at max green")):
        per_seed = " ".join(f"{runs[side][s]['wall_s']:.2f}" for s in f["seeds"])
        print(f"  {label:40} {Spread(**f[f'{side}_s']).text()} s   per seed: {per_seed}")
    same = ", ".join(f"{s}: {runs['hils'][s]['departed']}/{runs['floor'][s]['departed']} departed, "
                     f"{runs['hils'][s]['arrived']}/{runs['floor'][s]['arrived']} arrived" for s in f["seeds"])
    print(f"    same traffic: {str(f['same_traffic']).lower()} (loop/floor by seed: {same})")
    print(f"  ratio to the same-traffic floor, per seed   {Spread(**f['ratio']).text()} (goal <= 1.15)")
    print(f"  for the record, ratio to the fixed cycle at maximum green (other traffic): "
          f"{Spread(**f['ratio_vs_fixed_cycle_at_max_green']).text()}")
    if args.instructions:
        ins = f["instructions"] = measure_instructions(args.duration)
        print(f"  instructions (callgrind, seed 0, start-up counted out): full loop "
              f"{ins['hils_instructions'] / 1e9:.2f} G, same-traffic floor {ins['floor_instructions'] / 1e9:.2f} G, "
              f"ratio {ins['ratio']:.2f}")
    _write_figures(folder / "overhead.json", {"machine": info, "overhead": f})
    return 0


# --- wire ------------------------------------------------------------------------------------------

#: Three INTEGER scalars snmpd answers, comparable to reds, yellows and greens of group 1.
SNMPD_OIDS = ((1, 3, 6, 1, 2, 1, 4, 1, 0), (1, 3, 6, 1, 2, 1, 4, 2, 0), (1, 3, 6, 1, 2, 1, 4, 13, 0))


def measure_get_rtt(url: str, oids: tuple, count: int) -> dict[str, float]:
    """Sequential GETs of ``oids`` in one PDU through the middleware's transport at wall-clock time:
    round trip per request (ms) and the request rate sustained."""
    from hils.shell.clock import WallClockDriver
    from hils.shell.snmp import SnmpTarget, SnmpTransport

    env = simpy.Environment()
    driver = WallClockDriver(env)
    transport = SnmpTransport(env, driver, SnmpTarget.parse(url), tau_udp=1.0)
    rtts: list[float] = []
    span: list[float] = []
    cpu: list[float] = []

    def client():
        yield transport.get(oids)  # warm-up: first-use costs are not round trips
        span.append(time.perf_counter())
        cpu.append(time.process_time())
        for _ in range(count):
            t0 = time.perf_counter()
            yield transport.get(oids)
            rtts.append((time.perf_counter() - t0) * 1e3)
        cpu.append(time.process_time())
        span.append(time.perf_counter())
        driver.stop()

    env.process(client())
    try:
        driver.run_sync(handle_signals=False)
    finally:
        transport.close()
        driver.close()
    stats = Stats.of(rtts)
    return {**stats.as_dict(), "rate_per_s": count / (span[1] - span[0]),
            "client_cpu_ms_per_get": (cpu[1] - cpu[0]) * 1e3 / count}


def measure_agent_cost(count: int) -> float:
    """CPU time (ms) the emulator's agent spends answering one 3-varbind GET (reds, yellows, greens)."""
    from pyasn1.codec.ber import encoder
    from pysnmp.proto import api

    from emulator.agent.mib import MibView
    from emulator.agent.snmp import SnmpAgent
    from emulator.model.controller import Controller

    agent = SnmpAgent(MibView(Controller(config_mod.load())))
    message = api.v2c.Message()
    api.v2c.apiMessage.set_defaults(message)
    api.v2c.apiMessage.set_community(message, "public")
    pdu = api.v2c.GetRequestPDU()
    api.v2c.apiPDU.set_defaults(pdu)
    api.v2c.apiPDU.set_varbinds(pdu, [(oid, api.v2c.Null("")) for oid in signal_oids(1)])
    api.v2c.apiMessage.set_pdu(message, pdu)
    datagram = encoder.encode(message)
    if agent.respond(datagram) is None:
        raise RuntimeError("the agent did not answer the benchmark's GET")
    t0 = time.process_time()
    for _ in range(count):
        agent.respond(datagram)
    return (time.process_time() - t0) * 1e3 / count


@dataclass(frozen=True)
class Flood:
    """A stream of hostile datagrams against the served emulator's agent."""

    name: str
    make: floods.Datagram  # the datagram, made by the sending process from the agent's address
    per_second: int
    what: str  # for the console

    def settings(self) -> dict[str, Any]:
        return {"per_second": self.per_second, "what": self.what}

    def sending(self, server: EmulatorServer) -> contextlib.AbstractContextManager[None]:
        return floods.flooding(server.addresses[0], self.make, self.per_second)

    def counts(self, summary: ServeSummary) -> dict[str, int]:
        """What the server counted of this flood so far."""
        return {"dropped": summary.traffic.total_dropped}

    def describe(self, figures: dict[str, Any]) -> str:
        return f"dropped {figures['dropped']:6d}: {self.per_second}/s {self.what}"


@dataclass(frozen=True)
class LogFlood:
    """Requests for a served controller's event log over HTTP: clients that read each answer whole, again and
    again, and clients that never read one."""

    name: str
    whole: int
    never_read: int

    def settings(self) -> dict[str, Any]:
        return {"whole": self.whole, "never_read": self.never_read}

    def sending(self, server: EmulatorServer) -> contextlib.AbstractContextManager[None]:
        return floods.fetching_logs(server.http_addresses[0], self.whole, self.never_read)

    def counts(self, summary: ServeSummary) -> dict[str, int]:
        """What the server counted of this flood so far."""
        from emulator.agent.asclog import Dropped

        if summary.http is None:
            raise ValueError("the event-log flood needs the event log served (ServeOptions.http)")
        answered, dropped = summary.http.answered, summary.http.dropped
        return {"answered": answered[HTTPStatus.OK], "refused_busy": answered[HTTPStatus.SERVICE_UNAVAILABLE],
                "dropped_not_reading": dropped[Dropped.NOT_READING]}

    def describe(self, figures: dict[str, Any]) -> str:
        return (f"answered {figures['answered']}, refused {figures['refused_busy']} (busy), dropped "
                f"{figures['dropped_not_reading']} (not reading): {self.whole} clients reading the whole log again "
                f"and again, {self.never_read} never reading")


#: The floods the wire benchmark measures the controller's tick under, one after the other.
FLOODS = (Flood("wrong_community", floods.large_wrong_community, 20, "datagrams of 60 KB with a wrong community"),
          Flood("v3_no_user", floods.v3_without_user, 3000,
                "SNMPv3 GETs, noAuthNoPriv, no user name, the agent's engine ID"),
          LogFlood("event_log", whole=6, never_read=100))
#: The events in the served controller's log while the tick is measured: as many as it keeps (the default).
LOG_EVENTS = 100_000


def measure_tick_lateness_under_flood(seconds: float, of: Sequence[Flood | LogFlood] = FLOODS) -> dict[str, Any]:
    """The served controller's tick lateness (ms) during ``seconds`` of each flood, beside the same time without one:
    the emulator (with an SNMPv3 user, its event log served over HTTP and holding :data:`LOG_EVENTS` events) in
    this process on its own loop, each flood from another process. With each flood, what the server counted of it
    and how much this process's resident memory grew (MB)."""
    import asyncio
    import os

    from emulator.agent.serve import EmulatorServer, ServeOptions
    from emulator.agent.snmp import V3User
    from emulator.model.controller import TICK

    options = ServeOptions(port=0, http=0, log_events=LOG_EVENTS,
                           v3_user=V3User("hils", "auth-pass-phrase", "priv-pass-phrase"))

    def serve(flood: Flood | LogFlood | None) -> dict[str, Any]:
        lateness: list[float] = []

        async def session() -> dict[str, Any]:
            server = EmulatorServer([config_mod.load()], options)
            floods.fill_log(server.controllers[0], LOG_EVENTS)
            await server.start()
            # The ticks stepped to fill the log are caught up with first: they are not measured.
            await asyncio.sleep(2 * TICK)
            server.ticker.observe = lambda late: lateness.append(late * 1e3)
            if flood is None:
                await asyncio.sleep(seconds)
                await server.stop()
                return {}
            # The agent warns of what it drops (once per 10 s): here the figures say it.
            with flood.sending(server), _quiet("emulator.agent.snmp"):
                # From the flood's first datagram or request on (the sender takes a moment to start).
                while not any(flood.counts(server.summary()).values()):
                    await asyncio.sleep(0.01)
                lateness.clear()
                before, rss = flood.counts(server.summary()), resident_mb(os.getpid())
                await asyncio.sleep(seconds)
                after, rss = flood.counts(server.summary()), resident_mb(os.getpid()) - rss
            await server.stop()
            return {**{key: after[key] - before[key] for key in after}, "rss_growth_mb": rss}

        counted = asyncio.run(session())
        return {**Stats.of(lateness).as_dict(), **counted}

    return {"log_events": LOG_EVENTS, "quiet": serve(None),
            "floods": {f.name: {**f.settings(), **serve(f)} for f in of}}


@contextlib.contextmanager
def _quiet(logger: str) -> Iterator[None]:
    """``logger``'s warnings kept off the console while the block runs."""
    log = logging.getLogger(logger)
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def measure_verification_lag(rate_hz: float, duration: float, workdir: Path) -> dict[str, Any]:
    """Phase switching at wall-clock time against a served emulator that traces its intervals:
    per command, the lag (ms) from the commanded phases turning green to the manager's IDLE."""

    # Short minimum greens and a decision every 6.5 s: more transitions per minute of wall clock.
    # The emulator and the middleware read the same config file.
    source = resources.files("hils.data").joinpath(config_mod.DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")
    variant = workdir / "short_min_green.toml"
    variant.write_text(source.replace("min_green = 3 ", "min_green = 1 "), encoding="utf-8")
    cfg = config_mod.load(variant).with_middleware(poll_hz=rate_hz, control_interval=6.5)
    trace = workdir / f"trace-{rate_hz:g}.jsonl"
    served = start_emulator(workdir / f"serve-{rate_hz:g}.log", "--config", str(variant), "--trace", str(trace))
    try:
        spec = RunSpec(cfg, ActionType.SWITCH, duration=duration, log_path=workdir / f"events-{rate_hz:g}.jsonl")
        records = run_spec(spec, target=f"snmp://127.0.0.1:{served.port}?community=private&version=2c").records
    finally:
        served.stop()
    greens = [json.loads(line) for line in trace.read_text().splitlines()]
    greens = [g for g in greens if g["interval"] == "green"]
    lags = []
    dispatched = {r["command_id"]: r for r in records if r["kind"] == Kind.COMMAND_DISPATCHED}
    for r in records:
        if r["kind"] == Kind.HOLD_RELEASED and r["reason"] == "verified":
            cmd = dispatched[r["command_id"]]
            onsets = [g["wall_ns"] for g in greens if g["phase"] in cmd["command"] and g["wall_ns"] > cmd["wall_ns"]]
            # Both rings turn green on the same tick; the later of the two stamps is the moment.
            onset = sorted(onsets)[1] if len(onsets) >= 2 else None
            if onset is not None:
                lags.append((r["wall_ns"] - onset) / 1e6)
    return Stats.of(lags).as_dict()


def _wire_command(args: argparse.Namespace) -> int:
    folder = published.folder(args)
    info = machine.describe()
    rates = [float(r) for r in args.rates.split(",")]
    out: dict[str, Any] = {"machine": info}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        lag = {}
        for rate in rates:
            print(f"phase switching for {args.duration:g} s at {rate:g} Hz polling ...", flush=True)
            lag[f"{rate:g}"] = measure_verification_lag(rate, args.duration, work)
        out["verification_lag_ms"] = lag
        served = start_emulator(work / "serve-get.log")
        try:
            ours = measure_get_rtt(f"snmp://127.0.0.1:{served.port}?community=public", signal_oids(1), args.gets)
        finally:
            served.stop()
        with snmpd(work) as port:
            theirs = measure_get_rtt(f"snmp://127.0.0.1:{port}?community=public", SNMPD_OIDS, args.gets)
    out["get_rtt_ms"] = {"hils_emulator": ours, "net_snmp_snmpd": theirs, "ratio_mean": ours["mean"] / theirs["mean"]}
    out["agent_cpu_ms_per_get"] = measure_agent_cost(args.gets)
    out["tick_lateness_ms"] = flood = measure_tick_lateness_under_flood(args.flood)
    print(machine.header(info))
    print("verification lag (controller green -> manager IDLE), ms:")
    for rate, st in lag.items():
        print(f"  {rate:>5} Hz  N {st['n']:3d}  mean {st['mean']:6.1f}  p50 {st['p50']:6.1f}  p99 {st['p99']:6.1f}"
              f"  max {st['max']:6.1f}")
    print("  target: p99 < 25 ms at 50 Hz or more (paper, 10 Hz: 180-200 ms over the 5 s clearance)")
    print("3-varbind GET round trip through the middleware's transport, ms:")
    for name, st in (("hils emulator serve", ours), ("net-snmp snmpd", theirs)):
        print(f"  {name:20} mean {st['mean']:.3f}  p50 {st['p50']:.3f}  p99 {st['p99']:.3f}  "
              f"rate {st['rate_per_s']:.0f}/s  client CPU {st['client_cpu_ms_per_get']:.3f} ms/GET")
    print(f"  ratio (ours / snmpd, mean): {out['get_rtt_ms']['ratio_mean']:.2f} (target <= 1.2)")
    print(f"  emulator agent CPU per GET: {out['agent_cpu_ms_per_get']:.3f} ms (target <= 0.2; client target <= 0.2)")
    print(f"emulator tick lateness, ms, {args.flood:g} s of each flood (from another process) and without one; the "
          f"controller's event log served over HTTP and holding {flood['log_events']} events:")
    print(f"  {'quiet':16} {_lateness(flood['quiet'])}")
    for f in FLOODS:
        st = flood["floods"][f.name]
        print(f"  {f.name:16} {_lateness(st)}  RSS {st['rss_growth_mb']:+6.1f} MB  {f.describe(st)}")
    print("  target: p99 < 5 ms with the wrong community, < 20 ms with the SNMPv3 flood and the event-log requests, "
          "no memory kept")
    _write_figures(folder / "wire.json", out)
    return 0


def _lateness(st: dict[str, Any]) -> str:
    return f"N {st['n']:4d}  p50 {st['p50']:6.2f}  p99 {st['p99']:6.2f}  max {st['max']:6.2f}"


# --- env -------------------------------------------------------------------------------------------


def _env_command(args: argparse.Namespace) -> int:
    from harness.bench.env import measure_env

    try:
        import sumo_rl  # noqa: F401
    except ImportError as exc:
        if "SUMO_HOME" not in str(exc):
            raise SystemExit("hils bench env compares with sumo-rl: pip install 'hils[bench]'") from None
    folder = published.folder(args)
    info = machine.describe()
    f = measure_env(args.seeds, args.duration)
    print(machine.header(info))
    print(f"one {f['episode_s']:g} s episode per side and seed (seeds {seeds_text(f['seeds'])}), each in a fresh "
          f"process, alternately; {f['sumo_step_s']} s SUMO steps, a decision every {f['decision_s']:g} s, random "
          "policy; median [min-max] over the seeds:")
    t, c = f["sumo_rl_timing_steps"], f["config_timing_s"]
    print(f"  sumo-rl counts its yellow and minimum green in SUMO steps: it is given the config's {c['yellow']:g} s "
          f"and {c['min_green']:g} s as {t['yellow']} and {t['min_green']} steps; 'unconverted' is the same numbers "
          f"as steps (a {c['yellow'] * f['sumo_step_s']:g} s yellow), as its own docs suggest writing them")
    labels = {"hils": "hils", "hils_worker": "hils, SUMO worker", "hils_no_all_red": "hils, no all-red",
              "sumo_rl": "sumo-rl", "sumo_rl_unconverted": "sumo-rl, unconverted"}
    for line in bench_seeds.episode_table({labels[side]: figures for side, figures in f["sides"].items()}):
        print(line)
    print(bench_seeds.ratio_line("hils / sumo-rl", f["hils_to_sumo_rl"])
          + " (goal: wall <= 1; hils' controller adds a 2 s all-red to every change and serves the config's pairs: "
            "other signals, other traffic, which SUMO steps at its own cost)")
    print(bench_seeds.ratio_line("hils, SUMO worker / sumo-rl", f["hils_worker_to_sumo_rl"]))
    print(bench_seeds.ratio_line("hils / sumo-rl unconverted", f["hils_to_sumo_rl_unconverted"])
          + " (shorter clearances, lighter traffic)")
    print(bench_seeds.ratio_line("hils, no all-red / sumo-rl", f["same_clearances"])
          + " (the same clearances: the config's red clearance set to 0 s, as sumo-rl has none; goal: wall <= 1)")
    print(_loads(f["runs"], info))
    _write_figures(folder / "env.json", {"machine": info, "env": f})
    return 0


def _loads(runs: dict[str, dict[int, dict[str, Any]]], info: dict[str, Any]) -> str:
    """The machine's load at the ends of the episodes: a busy machine moves wall time much more than CPU time."""
    loads = [run["load"] for by_seed in runs.values() for run in by_seed.values()]
    return f"  machine load (1 min) at the episodes' ends: {min(loads):.1f}-{max(loads):.1f} on {info['cores']} cores"


def _resco_command(args: argparse.Namespace) -> int:
    from harness.bench.resco import measure_resco

    folder = published.folder(args)
    info = machine.describe()
    f = measure_resco(args.scenarios, args.seeds, args.duration)
    print(machine.header(info))
    print(f"one {f['episode_s']:g} s episode per side, scenario and seed (seeds {seeds_text(f['seeds'])}), each in a "
          f"fresh process, alternately; {f['sumo_step_s']} s SUMO steps, random policy; median [min-max] over the "
          "seeds:")
    print(f"  the peer: {f['peer']}")
    for name, sc in f["scenarios"].items():
        print(f"resco:{name} ({sc['controllers']} lights, a decision every {sc['decision_s']:g} s):")
        sides = sc["sides"]
        for line in bench_seeds.episode_table({"hils": sides["hils"], "hils, SUMO worker": sides["hils_worker"],
                                               "sumo-rl": sides["sumo_rl"]}, per_controller=True):
            print(line)
        print(bench_seeds.ratio_line("hils / sumo-rl", sc["hils_to_sumo_rl"]) + " (goal: wall <= 1)")
        print(bench_seeds.ratio_line("hils, SUMO worker / sumo-rl", sc["hils_worker_to_sumo_rl"]))
        print(_loads(sc["runs"], info))
    _write_figures(folder / "resco.json", {"machine": info, "resco": f})
    return 0


def _train_command(args: argparse.Namespace) -> int:
    from harness.bench.train import LABELS, measure_train, missing_libraries, table

    missing = missing_libraries(args.parts)
    if missing:
        raise SystemExit(f"hils bench train needs {', '.join(missing)}: pip install 'hils[rl,bench]' (PyTorch's CPU "
                         "build first: docs/rl.md)")
    folder = published.folder(args)
    info = machine.describe()
    f = measure_train(args.seeds, timesteps=args.timesteps, iterations=args.iterations, batch=args.batch,
                      threads=args.torch_threads, parts=args.parts)
    print(machine.header(info))
    threads = f"{f['torch_threads']} thread{'s' * (f['torch_threads'] > 1)}"
    print(f"each side once per seed (seeds {seeds_text(f['seeds'])}), each run in a fresh process, alternately; torch "
          f"{f['versions']['torch']}, {threads} each; median [min-max] over the seeds; a run's "
          "training (not its imports and build) split by wall time into SUMO, the environment's own work and the "
          "learner, and its CPU time per environment step into the environment's (SUMO's included) and the learner's:")
    titles = {"sb3": f"Stable-Baselines3 {f['versions']['stable-baselines3']} PPO, {args.timesteps} steps of sumo-rl's "
                     "single intersection (a decision every 5 s):",
              "rllib": f"RLlib {f['versions']['ray']} PPO, {args.iterations} iteration(s) of {args.batch} environment "
                       "steps of grid4x4 (16 lights, each step 16 agents' steps; PettingZoo parallel, a decision every "
                       "5 s):"}
    for part in args.parts:
        p = f[part]
        print(titles[part])
        for line in table({LABELS[side]: figures for side, figures in p["sides"].items()}):
            print(line)
        ratio = {f: Spread(**r).text() for f, r in p["hils_to_sumo_rl"].items()}
        print(f"  hils / sumo-rl, per seed: steps per second {ratio['steps_per_s']}, steps per CPU second "
              f"{ratio['steps_per_cpu_s']}; CPU per step: the environment's {ratio['env_cpu_ms']}, the learner's "
              f"{ratio['learner_cpu_ms']}")
    _write_figures(folder / "train.json", {"machine": info, "train": f})
    return 0


def _train_parts(text: str) -> list[str]:
    """``--parts`` of the training bench: sb3, rllib or both, comma-separated."""
    parts = [p.strip() for p in text.split(",")]
    if not parts or not set(parts) <= {"sb3", "rllib"} or len(set(parts)) < len(parts):
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: sb3, rllib or sb3,rllib")
    return parts


def _resco_names(text: str) -> list[str]:
    """``--scenarios`` of the RESCO bench: names of RESCO's scenarios, comma-separated, or all."""
    from hils.protocol.resco import NAMES

    names = list(NAMES) if text == "all" else [n.strip().removeprefix("resco:") for n in text.split(",")]
    unknown = [n for n in names if n not in NAMES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: all, or some of {','.join(NAMES)}")
    return names


def _corridor_command(args: argparse.Namespace) -> int:
    folder = published.folder(args)
    info = machine.describe()
    print(machine.header(info))
    f = bench_corridor.measure_corridor(args.counts, args.duration, args.virtual_duration, args.seeds, args.climbs)
    w = f["wall_clock"]
    print(f"wall clock: one middleware process, 10 Hz polling each controller, {args.duration:g} s per count, "
          f"against one `hils emulator serve --count N` on loopback; {args.climbs} climbs of the counts, each "
          "until a count fails:")
    print(f"  {'climb':>5} {'N':>4} {'lateness p99 ms':>16} {'max ms':>8} {'TIMEOUTs':>9} {'polls answered':>15} "
          f"{'failed':>7} {'CPU hils':>9} {'CPU serve':>10} {'RSS hils MB':>12} {'RSS serve MB':>13}  passes")
    for climb, ladder in enumerate(w["climbs"], 1):
        for r in ladder:
            if not r["started"]:
                print(f"  {climb:>5} {r['controllers']:>4}  did not start: {r['refused']} controllers refused at "
                      f"start-up ({r['refusal']})")
                continue
            polls = r["polls"]
            print(f"  {climb:>5} {r['controllers']:>4} {r['lateness_p99_ms']:>16.2f} {r['lateness_max_ms']:>8.1f} "
                  f"{sum(r['timeouts'].values()):>9} {polls.get('answered', 0):>15} {polls.get('failed', 0):>7} "
                  f"{r['cpu_share']:>9.0%} {r['serve_cpu_share']:>10.0%} {r['rss_mb']:>12.1f} "
                  f"{r['serve_rss_mb']:>13.1f}  {'yes' if r['passes'] else 'no'}")
    print(f"  most controllers passing, per climb: {', '.join(map(str, w['most_controllers_passing']))}; median "
          f"{Spread(**w['most_controllers_passing_spread']).text(0)} (goal >= {w['goal_controllers']}: no TIMEOUT, "
          f"p99 < {w['goal_p99_ms']:g} ms)")
    for lim in w["limits"]:
        if not lim["started"]:
            print(f"  what stopped a climb at {lim['controllers']}: {lim['refused']} controllers unanswered at "
                  "start-up")
            continue
        reasons = ", ".join(f"{n} {reason}" for reason, n in lim["timeouts"].items()) or "none"
        print(f"  what stopped a climb at {lim['controllers']}: lateness p99 {lim['lateness_p99_ms']:.1f} ms, "
              f"TIMEOUTs {reasons}, {lim['polls_per_s']:.0f} polls/s ({lim['failed_polls']} failed); the "
              f"middleware's one thread busy {lim['cpu_share']:.0%}, the serve process {lim['serve_cpu_share']:.0%} "
              f"(on {info['cores']} cores)")
    print(f"virtual time, {args.virtual_duration:g} simulated s, seeds {seeds_text(f['seeds'])}, median [min-max]:")
    for key, label in (("with_sumo", "with SUMO"), ("controllers_only", "no SUMO")):
        for r in f["virtual"][key]:
            print(f"  {label:9} {r['controllers']:>3} controllers ({r['scenario']}): "
                  f"{Spread(**r['wall_s']).text()} s wall, {Spread(**r['wall_per_controller_hour_s']).text()} s per "
                  "controller-hour")
    m = f["memory"]
    for side in ("middleware", "serve"):
        per = m[side]["mb_per_controller"]
        print(f"memory, {side}: " + ("-" if per is None else f"{per:.2f} MB per added controller") +
              f" (goal <= {m['goal_mb_per_controller']:g})")
    _write_figures(folder / "corridor.json", {"machine": info, "corridor": f})
    return 0


def _positive(text: str) -> int:
    """A count of 1 or more."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: a whole number of 1 or more")
    return n


def _counts(text: str) -> list[int]:
    """``--counts``: a comma-separated list of controller counts."""
    try:
        counts = [int(n) for n in text.split(",")]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: counts of 1 or more, comma-separated (e.g. 1,4,16,64)")
    return counts
