"""RESCO's eight scenarios from the installed sumo-rl: every light's derived NEMA controller serves exactly the
stages of its SUMO program, with the program's timing as its plan where that is a legal NEMA plan (and why not
where it is not), two are pinned as checked by hand, every scenario runs with max-pressure and with the actuated
baseline from its own begin time (and with fixed-time and coordinated where every light has a plan), and RESCO's
figures come from SUMO's tripinfo as its code defines them."""

from __future__ import annotations

import subprocess
import sys
from datetime import date, datetime, timedelta
from pathlib import Path
from types import SimpleNamespace

import pytest
import sumolib

from hils.agents.builtin import AgentError
from hils.protocol import resco
from hils.protocol.config import FREE, parse
from hils.protocol.ntcip import SignalState
from hils.protocol.scenario import SignalLink, load_scenario
from hils.report import summary
from hils.run.testbed import Testbed
from hils.sim.network import NetworkError, PhaseMap, check_scenario, derive_phase_map, sumocfg_net_file
from hils.sim.resco_metrics import TripinfoError, read_tripinfo


def program_stages(net, tls: str) -> list[str]:
    """RESCO's green phases of the light's first program, less those green only on unconnected indices."""
    light = net.getTLS(tls)
    connected = {i for *_, i in light.getConnections()}
    program = next(iter(light.getPrograms().values()))
    return [p.state for p in program.getPhases() if "y" not in p.state and "g" in p.state.lower()
            and any(p.state[i] in "Gg" for i in connected)]


@pytest.mark.parametrize("name", resco.NAMES)
def test_every_light_shows_exactly_its_programs_stages_when_its_pairs_are_green(name: str) -> None:
    scenario = load_scenario(f"resco:{name}")
    net = sumolib.net.readNet(str(sumocfg_net_file(scenario.sumo_config)), withPrograms=True)
    assert set(scenario.intersections) == {t.getID() for t in net.getTrafficLights()}
    maps = check_scenario(scenario)  # every light's links mapped onto the network by its binding
    for tls, config in scenario.intersections.items():
        stages = program_stages(net, tls)
        assert len(config.sequence) == len(stages) and list(config.pairs) == list(dict.fromkeys(config.sequence))
        connected = {i for *_, i in net.getTLS(tls).getConnections()}
        for (a, b), stage in zip(config.sequence, stages, strict=True):
            shown = maps[tls].state_string(SignalState(frozenset(config.phases) - {a, b}, frozenset(),
                                                       frozenset({a, b})))
            wanted = "".join(c if c in "Gg" else "r" for c in stage)
            assert [shown[i] for i in sorted(connected)] == [wanted[i] for i in sorted(connected)], (tls, a, b)
        for p, phase in config.phases.items():
            assert phase.yellow > 0 and phase.red_clear > 0 and phase.min_green <= phase.max_green, (tls, p)


GRID_A0 = """\
name = "A0, dual-ring from its SUMO program"

[phases]
1 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }
2 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false, startup = "green" }
3 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }
4 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }
5 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }
6 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false, startup = "green" }
7 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }
8 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, backup_prevent = false }

[structure]
rings = [[2, 1, 4, 3], [6, 5, 8, 7]]
barriers = [[1, 2, 5, 6], [3, 4, 7, 8]]
sequence = [[2, 6], [1, 5], [2, 5], [1, 6], [4, 8], [3, 7], [3, 8], [4, 7]]
pairs = [[2, 6], [1, 5], [2, 5], [1, 6], [4, 8], [3, 7], [3, 8], [4, 7]]

[middleware]
control_interval = 10
tau_trans = 14

[emulator]
start = 2024-01-01T00:00:00

[coordination]
pattern = "free"

[[coordination.patterns]]
number = 1
cycle = 104
offset = 0
coord_phases = [2, 6]
splits = { 1 = 26, 2 = 26, 3 = 26, 4 = 26, 5 = 26, 6 = 26, 7 = 26, 8 = 26 }"""

COLOGNE1 = """\
name = "GS_cluster_357187_359543, dual-ring from its SUMO program"

[phases]
1 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }
2 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false, startup = "green" }
3 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }
4 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }
5 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }
6 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false, startup = "green" }
7 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }
8 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, backup_prevent = false }

[structure]
rings = [[2, 1, 4, 3], [6, 5, 8, 7]]
barriers = [[1, 2, 5, 6], [3, 4, 7, 8]]
sequence = [[2, 6], [1, 5], [4, 8], [3, 7]]
pairs = [[2, 6], [1, 5], [4, 8], [3, 7]]

[middleware]
control_interval = 10
tau_trans = 16

[emulator]
start = 2024-01-01T07:00:00

[coordination]
pattern = "free"

[[coordination.patterns]]
number = 1
cycle = 90
offset = 0
coord_phases = [2, 6]
splits = { 1 = 11, 2 = 34, 3 = 11, 4 = 34, 5 = 11, 6 = 34, 7 = 11, 8 = 34 }"""


@pytest.mark.parametrize(("name", "tls", "toml", "links"), [
    # Checked by hand against the program: stage 1 greens indices 0-5 (the straights and rights from A1) and 18-23
    # (from the opposite side): phases 2 and 6; the lefts of those sides (6-8, 24-26) are 5 and 1, and each
    # side alone is 2+5 and 1+6, the four pairs of the first barrier; the cross street's the same in 3, 4, 7, 8.
    # Static program: netconvert's 5 s and 50 s; yellow 3 s as the program's; no all-red in it.
    # Plan: eight stages of 10 s green + 3 s yellow, a cycle of 104 s; each phase green in two stages (2 in the 1st
    # and 3rd, 1 in the 2nd and 4th, 6 in the 1st and 4th, 5 in the 2nd and 3rd; the cross street alike), 26 s
    # each; every stage 10 s, so the first (2+6) is the coordinated pair, its green at 0 s of the program (offset 0).
    ("grid4x4", "A0", GRID_A0, "2 2 2 2 2 2 5 5 5 4 4 4 4 4 4 7 7 7 6 6 6 6 6 6 1 1 1 8 8 8 8 8 8 3 3 3"),
    # Stages: 5-7 and 15-17 (straights and rights) with their lefts and U-turns yielding (8-9, 18-19 'g'), then
    # those lefts and U-turns protected; the cross street likewise. A left and U-turn (U-turns run with the left
    # of their approach) are its protected phase, yielding beside their through (~). minDur 5/maxDur 50 and the
    # 5 s yellow are the program's. Plan: 29+5, 6+5, 29+5, 6+5 s, a cycle of 90 s: 2 and 6 34 s, 1 and 5 11 s, the
    # cross street alike; the longest stages (29 s) are the first and third, the first (2+6) coordinated, offset 0.
    # The controller's clock starts at the scenario's begin, 25200 s: 07:00.
    ("cologne1", "GS_cluster_357187_359543", COLOGNE1,
     "4 4 4 7~4 7~4 2 2 2 5~2 5~2 8 8 8 3~8 3~8 6 6 6 1~6 1~6"),
])
def test_the_derived_configs_of_grid4x4_and_cologne1_are_as_checked_by_hand(name: str, tls: str, toml: str,
                                                                            links: str) -> None:
    scenario = resco.load(name)
    assert resco.to_toml(scenario.intersections[tls]) == toml
    assert " ".join(resco.describe_link(link).replace(" ~", "~") for link in scenario.links[tls]) == links


#: Lights with a timing plan of the lights of each scenario (the rest are named, with why, in the refusals).
PLANNED = {"grid4x4": (16, 16), "arterial4x4": (16, 16), "cologne1": (1, 1), "cologne3": (3, 3), "cologne8": (8, 8),
           "ingolstadt1": (1, 1), "ingolstadt7": (6, 7), "ingolstadt21": (15, 21)}


@pytest.mark.parametrize("name", resco.NAMES)
def test_every_light_gets_its_programs_timing_as_a_plan_that_passes_the_config_checks_or_says_why_not(
        name: str) -> None:
    scenario = resco.load(name)
    net = sumolib.net.readNet(str(sumocfg_net_file(scenario.sumo_config)), withPrograms=True)
    planned = {tls: c for tls, c in scenario.intersections.items() if c.coordination.patterns}
    assert (len(planned), len(scenario.intersections)) == PLANNED[name]
    for tls, config in scenario.intersections.items():
        c = config.coordination
        assert c.pattern == FREE  # powers up free: the phase-commanding agents need it
        if tls not in planned:
            assert "is shorter than its minimum service" in c.unplanned, tls
            continue
        assert not c.unplanned and list(c.patterns) == [1]
        pattern = c.patterns[1]
        program = next(iter(net.getTLS(tls).getPrograms().values())).getPhases()
        assert pattern.cycle == round(sum(p.duration for p in program)), tls
        # the config checks again, on the plan as a config file writes it
        assert parse(resco.to_toml(config), f"{tls}.toml").coordination.patterns[1] == pattern
        assert set(pattern.coord_phases) in [set(pair) for pair in config.pairs]


def test_a_plan_takes_the_programs_offset_and_its_longest_stage_and_a_short_one_or_a_long_cycle_gets_none() -> None:
    # the triangle served split phase: stages of 20 s green + 3, 3 and 4 s of yellow; the second stage the longest
    light = fake_light([("GGr", 20), ("yyr", 3), ("rGG", 25), ("ryy", 3), ("GrG", 20), ("yry", 4)],
                       [("a", "s"), ("b", "s"), ("c", "s")], offset=10)
    config = resco.derive(light, resco.MAPS["grid4x4"], "test").config
    pattern = config.coordination.patterns[1]
    assert pattern.cycle == 75 and pattern.offset == 10 + 23 and set(pattern.coord_phases) == set(config.sequence[1])
    assert [pattern.splits[p] for p in config.sequence[1]] == [28, 28] and sorted(pattern.splits.values()) == [
        23, 23, 24, 24, 28, 28]
    short = fake_light([("Gr", 30), ("yr", 3), ("rG", 4), ("ry", 3)], [("a", "s"), ("b", "s")])
    c = resco.derive(short, resco.MAPS["grid4x4"], "test").config.coordination
    assert not c.patterns and c.unplanned.endswith("split of 7 s (program phase 2 with its yellow and all-red) is "
                                                   "shorter than its minimum service of 8.1 s (minimum green + "
                                                   "yellow + red clearance)")
    long = fake_light([("Gr", 200), ("yr", 3), ("rG", 60), ("ry", 3)], [("a", "s"), ("b", "s")])
    c = resco.derive(long, resco.MAPS["grid4x4"], "test").config.coordination
    assert not c.patterns and c.unplanned == "its program's cycle of 266 s is outside NTCIP's 30-255 s"


@pytest.mark.parametrize("agent", ["coordinated", "fixed-time"])
def test_an_agent_that_runs_the_plans_refuses_a_scenario_naming_every_light_without_one(agent: str) -> None:
    with pytest.raises(AgentError) as info:
        Testbed(scenario="resco:ingolstadt21", sumo=True, agent=agent, duration=10.0)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"the {agent} agent runs each controller's timing plan, and 6 "
                                                       "of the 21 lights of resco:ingolstadt21 have none: 1863241632: "
                                                       "phase 1's split of 11 s")
    assert all(tls in message for tls in ("2330725114", "243749571", "89173763", "gneJ208"))


def test_the_refusal_is_one_line_of_the_cli(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--scenario", "resco:ingolstadt7", "--agent",
                           "fixed-time"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert "1 of the 7 lights of resco:ingolstadt7 has none: cluster_306484187" in done.stderr


# The plans' agents where every light has a plan; coordinated (the same plan, on detectors) not on the two sixteen-light
# grids, to keep the tests' time.
SCENARIO_RUNS = [(name, agent) for name in resco.NAMES for agent in ("max-pressure", "actuated")] + [
    (name, agent) for name in resco.NAMES if PLANNED[name][0] == PLANNED[name][1]
    for agent in ("fixed-time", "coordinated")[:1 if name in ("grid4x4", "arterial4x4") else 2]]


@pytest.mark.parametrize(("name", "agent"), SCENARIO_RUNS, ids=[f"{n}-{a}" for n, a in SCENARIO_RUNS])
def test_every_scenario_runs_300_simulated_seconds_from_its_own_begin(name: str, agent: str) -> None:
    with Testbed(scenario=f"resco:{name}", sumo=True, agent=agent, duration=300.0, seed=0) as tb:
        tb.reset_all()
        tb.run()
    assert tb.end_reason == "duration"
    traffic = tb.traffic
    assert traffic.begin == resco.MAPS[name].start and traffic.sim_time == pytest.approx(300.0, abs=1.0)
    assert traffic.arrived > 0 and traffic.collisions == 0
    summaries = [i.tally for i in tb.intersections.values()]
    assert all(not t.kinds["timeout_entered"] for t in summaries)
    if agent == "max-pressure":  # the lights were commanded, and each showed every pair it was told (the last one
        # may still be in its transition when the run ends; one never shown would have timed out)
        assert sum(t.kinds["transition_verified"] for t in summaries) >= len(summaries)
        assert all(t.kinds["transition_verified"] >= t.kinds["command_dispatched"] - 1 for t in summaries)
    if agent in ("coordinated", "fixed-time"):  # the controllers ran their plans, the middleware commanded nothing
        assert all(t.kinds["command_dispatched"] == 0 for t in summaries)
        assert all(tb.configs[tls].coordination.pattern == 1 for tls in tb.configs)
        assert any(t.kinds["detectors"] for t in summaries) is (agent == "coordinated")  # pretimed: no detectors
        if agent == "fixed-time":  # pretimed: every phase green within the cycle, no call needed
            for tls, i in tb.intersections.items():
                cycle = tb.configs[tls].coordination.patterns[1].cycle
                shown = {p for r in i.tally.records if r["kind"] == "poll" and r["t"] >= 300.0 - cycle
                         for p in r["greens"]}
                assert shown == set(tb.configs[tls].phases), tls
    figures = traffic.resco
    assert figures.vehicles >= traffic.departed and figures.delay_s > 0 and figures.queue_steps == 300 // int(
        resco.MAPS[name].decision_interval)


def write_tripinfo(path: Path, rows: list[dict[str, float]]) -> None:
    body = "".join('    <tripinfo id="v{}" depart="{depart}" departDelay="{departDelay}" arrival="{arrival}" '
                   'duration="{duration}" waitingTime="{waitingTime}" timeLoss="{timeLoss}"/>\n'.format(i, **r)
                   for i, r in enumerate(rows))
    path.write_text(f'<?xml version="1.0"?>\n<tripinfos>\n{body}</tripinfos>\n', encoding="utf-8")


@pytest.mark.parametrize(("name", "agent", "longest"), [("cologne3", "fixed-time", 45),
                                                        ("ingolstadt21", "max-pressure", 166)])
def test_the_console_summary_keeps_its_columns_under_a_light_named_by_a_long_cluster_id(name: str, agent: str,
                                                                                     longest: int) -> None:
    """cologne3's third light is ``GS_cluster_2415878664_254486231_359566_359576``, one of ingolstadt21's a cluster
    id of 166 characters: their rows had pushed every column of the plans, signal-control and per-approach tables
    out of line (and past any screen). A name longer than the column is shortened in the middle."""
    with Testbed(scenario=f"resco:{name}", sumo=True, agent=agent, duration=120.0, seed=0) as tb:
        tb.reset_all()
        tb.run()
        text = summary.render(summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()},
                                                traffic=tb.traffic))
        traffic = tb.traffic
    lines = text.splitlines()
    long = max(tb.intersections, key=len)
    assert len(long) == longest

    def table(title: str, rows: int) -> list[str]:
        at = next(i for i, line in enumerate(lines) if line.lstrip().startswith(title))
        return lines[at:at + 1 + rows]

    header, *rows = table("light ", len(tb.intersections))
    assert {row.index(" of ") - 5 for row in rows} == {header.index("transitions")}  # "{verified:>5} of {dispatched}"
    assert max(map(len, rows)) < 140
    if agent == "fixed-time":
        assert len({line.index("pattern 1") for line in table("Controller plans", len(tb.intersections))[1:]}) == 1
    header, *rows = table("per approach", len(traffic.approaches))
    arrived = header.index("arrived") + len("arrived")  # the column's right edge: numbers are right-aligned
    assert any(row.lstrip().startswith(long[:20]) and "…" in row for row in rows)  # "GS_cluster_2415878664_25…"
    assert all(row[arrived - 7:arrived].strip().isdigit() or row[arrived - 7:arrived].strip() == "-"
               for row in rows), rows  # "-": no vehicle entered the network on it
    assert all(row[arrived] == " " for row in rows), rows
    # A lane shorter than one vehicle cannot show a queue reaching back: ingolstadt21's made their approaches
    # report spillback in every minute, vehicles merely crossing them.
    assert all(a.lane_storage >= 1 for a in traffic.approaches.values() if a.spillback_minutes)


def test_a_run_of_a_scenarios_one_light_is_titled_by_the_scenario() -> None:
    """Seen as a user: `hils run --scenario resco:cologne1` was summed up as "GS_cluster_357187_359543, dual-ring
    from its SUMO program", the SUMO cluster id of its light."""
    with Testbed(scenario="resco:cologne1", sumo=True, duration=20.0, seed=0) as tb:
        tb.reset_all()
        tb.run()
        s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()}, traffic=tb.traffic)
    assert (s["scenario"], s["light"]) == ("resco:cologne1", "GS_cluster_357187_359543")
    assert s["config"] == "GS_cluster_357187_359543, dual-ring from its SUMO program"
    assert summary.render(s).splitlines()[0] == ("Run summary: resco:cologne1, light GS_cluster_357187_359543 "
                                                 "(virtual, selection by max-pressure, seed 0)")


def test_a_controllers_clock_and_hi_res_log_show_sumos_time_of_day() -> None:
    """cologne begins at 25200 s of SUMO's day: its controllers' logs start at 07:00, not at midnight."""
    with Testbed(scenario="resco:cologne1", sumo=True, agent="coordinated", duration=20.0, seed=0) as tb:
        tb.reset_all()
        tb.run()
        (events,) = tb.hires().values()
    assert events and all(e.time.date() == date(2024, 1, 1) for e in events)
    assert timedelta(hours=7) <= events[0].time - datetime(2024, 1, 1) < timedelta(hours=7, seconds=1)
    assert events[-1].time - events[0].time <= timedelta(seconds=20)


def test_resco_figures_from_a_tripinfo_computed_by_hand(tmp_path: Path) -> None:
    path = tmp_path / "tripinfo.xml"
    write_tripinfo(path, [
        # arrived: delay 20 + 2 = 22
        {"depart": 10, "departDelay": 2, "arrival": 90, "duration": 80, "waitingTime": 12, "timeLoss": 20},
        # still running at the end (write-unfinished): delay 30 + 0 = 30
        {"depart": 50, "departDelay": 0, "arrival": -1, "duration": 50, "waitingTime": 6, "timeLoss": 30},
        # never entered (write-undeparted): delay = end - depart = 40, no trip time nor waiting time
        {"depart": -1, "departDelay": 40, "arrival": -1, "duration": 0, "waitingTime": 0, "timeLoss": 0},
    ])
    trips = read_tripinfo(path)
    assert trips.delay_s == pytest.approx((22 + 30 + 40) / 3)
    assert trips.trip_time_s == pytest.approx((80 + 50) / 2) and trips.waiting_time_s == pytest.approx((12 + 6) / 2)
    assert (trips.vehicles, trips.arrived, trips.running, trips.never_entered) == (3, 1, 1, 1)


def test_an_unreadable_tripinfo_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "tripinfo.xml"
    path.write_text("<tripinfos><tripinfo id='x' depart='1'/>", encoding="utf-8")
    with pytest.raises(TripinfoError, match=r"tripinfo\.xml: cannot be read as SUMO tripinfo"):
        read_tripinfo(path)


def test_a_bound_link_shows_its_overlap_its_yield_and_their_clearance() -> None:
    links = (SignalLink(2), SignalLink(2, also=(3,)), SignalLink(1, yields_with=(2,)), SignalLink(2, yields=True),
             SignalLink(None))
    pm = PhaseMap("X", (), tuple(s.phase or 0 for s in links), tuple(s.yields for s in links),
                  tuple(s.also for s in links), tuple(s.yields_with for s in links))
    every = frozenset({1, 2, 3})

    def shown(greens: set[int], yellows: set[int] = frozenset()) -> str:
        return pm.state_string(SignalState(every - greens - yellows, frozenset(yellows), frozenset(greens)))

    assert shown({2}) == "GGgg" + "r"
    assert shown({3}) == "rGrr" + "r"      # the overlap follows its second parent
    assert shown({1}) == "rrGr" + "r"      # the protected left
    assert shown(set(), {2}) == "yyyy" + "r"  # a yielding left clears with its through
    assert pm.phases == (1, 2)


class _Conn:
    def __init__(self, edge: str, direction: str, junction: object, index: int) -> None:
        self.edge, self.direction, self.junction, self.index = edge, direction, junction, index

    def getDirection(self) -> str:  # noqa: N802 - sumolib's names
        return self.direction

    def getFrom(self) -> SimpleNamespace:  # noqa: N802
        return SimpleNamespace(getID=lambda: self.edge)

    def getJunction(self) -> object:  # noqa: N802
        return self.junction

    def getJunctionIndex(self) -> int:  # noqa: N802
        return self.index


def fake_light(states: list[tuple[str, float]], links: list[tuple[str, str]], foes: bool = True,
               offset: float = 0) -> SimpleNamespace:
    """A sumolib-like light: per index an (edge, direction), its program's phases, and a junction whose links are
    all foes of each other (or none)."""
    junction = SimpleNamespace(areFoes=lambda a, b: foes and a != b)
    conns = [_Conn(edge, d, junction, i) for i, (edge, d) in enumerate(links)]
    lanes = [SimpleNamespace(getConnection=lambda _out, c=c: c) for c in conns]
    phases = [SimpleNamespace(state=s, duration=d, minDur=-1, maxDur=-1) for s, d in states]
    program = SimpleNamespace(getPhases=lambda: phases, getOffset=lambda: offset)
    return SimpleNamespace(getID=lambda: "X", getPrograms=lambda: {"0": program},
                           getConnections=lambda: [(lane, None, i) for i, lane in enumerate(lanes)])


def test_three_stages_no_dual_ring_fits_are_served_split_phase_with_an_overlap() -> None:
    # Three approaches, each one straight, shown two at a time round a triangle: no two-colouring of the rings.
    light = fake_light([("GGr", 20), ("yyr", 3), ("rGG", 20), ("ryy", 3), ("GrG", 20), ("yry", 4)],
                       [("a", "s"), ("b", "s"), ("c", "s")])
    derived = resco.derive(light, resco.MAPS["grid4x4"], "test")
    assert derived.structure == "split phase" and len(derived.config.barriers) == 3
    config = derived.config
    pm = PhaseMap("X", (), tuple(s.phase for s in derived.links), tuple(s.yields for s in derived.links),
                  tuple(s.also for s in derived.links), tuple(s.yields_with for s in derived.links))
    for (a, b), stage in zip(config.sequence, ("GGr", "rGG", "GrG"), strict=True):
        assert pm.state_string(SignalState(frozenset(config.phases) - {a, b}, frozenset(), frozenset({a, b}))) == stage
    assert max(p.yellow for p in config.phases.values()) == 4.0  # the program's longest yellow after its green


def test_a_light_no_structure_fits_is_refused_naming_it_and_why() -> None:
    never = fake_light([("Gr", 20), ("yr", 3)], [("a", "s"), ("b", "s")])
    with pytest.raises(resco.RescoError, match=r"traffic light X: link 1 \(b, s\) is green in no phase"):
        resco.derive(never, resco.MAPS["grid4x4"], "test")
    yielding = fake_light([("Gr", 20), ("yr", 3), ("rg", 20), ("ry", 3)], [("a", "s"), ("b", "s")])
    with pytest.raises(resco.RescoError, match=r"program phase 2 \(rg\) shows no protected"):
        resco.derive(yielding, resco.MAPS["grid4x4"], "test")


def test_without_sumo_rl_a_resco_scenario_is_refused_with_the_extra_to_install(monkeypatch) -> None:
    monkeypatch.setattr(resco.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(resco.RescoError, match=r"pip install 'hils\[resco\]'"):
        resco.sumo_config("cologne1")


def test_an_unknown_resco_scenario_is_a_one_line_usage_error(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "hils", "run", "--scenario", "resco:cologne2"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "resco:cologne2: no RESCO scenario of that name; allowed: resco:grid4x4" in done.stderr


def test_derive_phase_map_refuses_a_binding_that_does_not_fit_the_light() -> None:
    scenario = resco.load("cologne1")
    tls, config = next(iter(scenario.intersections.items()))
    net = sumolib.net.readNet(str(sumocfg_net_file(scenario.sumo_config)))
    with pytest.raises(NetworkError, match="signal links bound, but the light has"):
        derive_phase_map(config, net, tls_id=tls, bound=scenario.links[tls][:-1])
    wrong = (SignalLink(9), *scenario.links[tls][1:])
    with pytest.raises(NetworkError, match=r"link 0 is bound to phase\(s\) \[9\]"):
        derive_phase_map(config, net, tls_id=tls, bound=wrong)
