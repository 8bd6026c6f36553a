"""RESCO's eight scenarios from the installed sumo-rl: every light's derived NEMA controller serves exactly the
stages of its SUMO program, two are pinned as checked by hand, every scenario runs with max-pressure and with the
actuated baseline from its own begin time, and RESCO's figures come from SUMO's tripinfo as its code defines them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import sumolib

from hils.protocol import resco
from hils.protocol.ntcip import SignalState
from hils.protocol.scenario import SignalLink, load_scenario
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
1 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }
2 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, startup = "green" }
3 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }
4 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }
5 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }
6 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1, startup = "green" }
7 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }
8 = { min_green = 5, max_green = 50, yellow = 3, red_clear = 0.1 }

[structure]
rings = [[2, 1, 4, 3], [6, 5, 8, 7]]
barriers = [[1, 2, 5, 6], [3, 4, 7, 8]]
sequence = [[2, 6], [1, 5], [2, 5], [1, 6], [4, 8], [3, 7], [3, 8], [4, 7]]
pairs = [[2, 6], [1, 5], [2, 5], [1, 6], [4, 8], [3, 7], [3, 8], [4, 7]]

[middleware]
control_interval = 10
tau_trans = 14"""

COLOGNE1 = """\
name = "GS_cluster_357187_359543, dual-ring from its SUMO program"

[phases]
1 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }
2 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, startup = "green" }
3 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }
4 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }
5 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }
6 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1, startup = "green" }
7 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }
8 = { min_green = 5, max_green = 50, yellow = 5, red_clear = 0.1 }

[structure]
rings = [[2, 1, 4, 3], [6, 5, 8, 7]]
barriers = [[1, 2, 5, 6], [3, 4, 7, 8]]
sequence = [[2, 6], [1, 5], [4, 8], [3, 7]]
pairs = [[2, 6], [1, 5], [4, 8], [3, 7]]

[middleware]
control_interval = 10
tau_trans = 16"""


@pytest.mark.parametrize(("name", "tls", "toml", "links"), [
    # Checked by hand against the program: stage 1 greens indices 0-5 (the straights and rights from A1) and 18-23
    # (from the opposite side): phases 2 and 6; the lefts of those sides (6-8, 24-26) are 5 and 1, and each
    # side alone is 2+5 and 1+6, the four pairs of the first barrier; the cross street's the same in 3, 4, 7, 8.
    # Static program: netconvert's 5 s and 50 s; yellow 3 s as the program's; no all-red in it.
    ("grid4x4", "A0", GRID_A0, "2 2 2 2 2 2 5 5 5 4 4 4 4 4 4 7 7 7 6 6 6 6 6 6 1 1 1 8 8 8 8 8 8 3 3 3"),
    # Stages: 5-7 and 15-17 (straights and rights) with their lefts and U-turns yielding (8-9, 18-19 'g'), then
    # those lefts and U-turns protected; the cross street likewise. A left and U-turn (U-turns run with the left
    # of their approach) are its protected phase, yielding beside their through (~). minDur 5/maxDur 50 and the
    # 5 s yellow are the program's.
    ("cologne1", "GS_cluster_357187_359543", COLOGNE1,
     "4 4 4 7~4 7~4 2 2 2 5~2 5~2 8 8 8 3~8 3~8 6 6 6 1~6 1~6"),
])
def test_the_derived_configs_of_grid4x4_and_cologne1_are_as_checked_by_hand(name: str, tls: str, toml: str,
                                                                            links: str) -> None:
    scenario = resco.load(name)
    assert resco.to_toml(scenario.intersections[tls]) == toml
    assert " ".join(resco.describe_link(link).replace(" ~", "~") for link in scenario.links[tls]) == links


SCENARIO_RUNS = [(name, agent) for name in resco.NAMES for agent in ("max-pressure", "actuated")]


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
    figures = traffic.resco
    assert figures.vehicles >= traffic.departed and figures.delay_s > 0 and figures.queue_steps == 300 // int(
        resco.MAPS[name].decision_interval)


def write_tripinfo(path: Path, rows: list[dict[str, float]]) -> None:
    body = "".join('    <tripinfo id="v{}" depart="{depart}" departDelay="{departDelay}" arrival="{arrival}" '
                   'duration="{duration}" waitingTime="{waitingTime}" timeLoss="{timeLoss}"/>\n'.format(i, **r)
                   for i, r in enumerate(rows))
    path.write_text(f'<?xml version="1.0"?>\n<tripinfos>\n{body}</tripinfos>\n', encoding="utf-8")


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


def fake_light(states: list[str], links: list[tuple[str, str]], foes: bool = True) -> SimpleNamespace:
    """A sumolib-like light: per index an (edge, direction), its program's phases, and a junction whose links are
    all foes of each other (or none)."""
    junction = SimpleNamespace(areFoes=lambda a, b: foes and a != b)
    conns = [_Conn(edge, d, junction, i) for i, (edge, d) in enumerate(links)]
    lanes = [SimpleNamespace(getConnection=lambda _out, c=c: c) for c in conns]
    phases = [SimpleNamespace(state=s, duration=d, minDur=-1, maxDur=-1) for s, d in states]
    return SimpleNamespace(getID=lambda: "X", getPrograms=lambda: {"0": SimpleNamespace(getPhases=lambda: phases)},
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
