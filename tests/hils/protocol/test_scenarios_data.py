"""The shipped scenarios of many signals (corridor, grid4x4) and the scenario files that name a config per light.

(The fault scenarios are in tests/harness/faults/test_fault_scenarios.py.) What a network should be is written down
here from the junction names alone, independently of the geometry the phase map is derived from.
"""

from __future__ import annotations

import fnmatch
import re
import subprocess
import tomllib
from collections.abc import Callable
from pathlib import Path

import libsumo
import pytest

from hils.protocol.config import ConfigError, IntersectionConfig
from hils.protocol.ntcip import SignalState
from hils.protocol.scenario import SCENARIOS, load_scenario
from hils.sim.network import NetworkError, check_scenario, data_path

ROOT = Path(__file__).resolve().parents[3]
CORRIDOR = ("J1", "J2", "J3", "J4")
GRID = tuple(f"{c}{r}" for r in "1234" for c in "ABCD")
#: The phase of each (approach side, SUMO direction) under the NEMA numbering of every shipped 8-phase config.
PHASE_OF = {("west", "l"): 1, ("west", "s"): 6, ("west", "r"): 6, ("east", "l"): 5, ("east", "s"): 2,
            ("east", "r"): 2, ("south", "l"): 3, ("south", "s"): 8, ("south", "r"): 8, ("north", "l"): 7,
            ("north", "s"): 4, ("north", "r"): 4}


def corridor_neighbours(tls: str) -> dict[str, str]:
    k = int(tls[1])
    return {"west": "W" if k == 1 else f"J{k - 1}", "east": "E" if k == 4 else f"J{k + 1}",
            "north": f"N{k}", "south": f"S{k}"}


def grid_neighbours(tls: str) -> dict[str, str]:
    col, row = "ABCD".index(tls[0]), int(tls[1])
    return {"west": f"w{row}" if col == 0 else f"{'ABCD'[col - 1]}{row}",
            "east": f"e{row}" if col == 3 else f"{'ABCD'[col + 1]}{row}",
            "north": f"n{tls[0]}" if row == 4 else f"{tls[0]}{row + 1}",
            "south": f"s{tls[0]}" if row == 1 else f"{tls[0]}{row - 1}"}


# --- the files ---------------------------------------------------------------------------------------------


def test_every_shipped_data_file_is_package_data() -> None:
    """A `pip install` carries hils/data only as far as the package-data patterns reach."""
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["hils.data"]
    tracked = subprocess.run(["git", "ls-files", "hils/data"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    untracked = subprocess.run(["git", "ls-files", "--others", "--exclude-standard", "hils/data"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.split()
    files = [Path(f).name for f in (*tracked, *untracked) if not f.endswith(".py")]
    assert {f"{name}.scenario.toml" for name in SCENARIOS} <= set(files)
    assert [f for f in files if not any(fnmatch.fnmatch(f, p) for p in patterns)] == []


@pytest.mark.parametrize(("name", "lights"), [("four_leg", ("C",)), ("four_phase", ("C",)), ("corridor", CORRIDOR),
                                              ("grid4x4", GRID)])
def test_a_shipped_scenario_names_every_light_of_its_network_with_a_config(name: str, lights: tuple[str, ...]) -> None:
    scenario = load_scenario(name)
    assert scenario.tls_ids == lights
    assert scenario.sumo_config == data_path(f"{name}.sumocfg")
    assert set(check_scenario(scenario)) == set(lights)


@pytest.mark.parametrize(("name", "neighbours"), [("corridor", corridor_neighbours), ("grid4x4", grid_neighbours)])
def test_every_link_of_every_light_is_under_the_phase_of_its_movement(name: str, neighbours) -> None:
    maps = check_scenario(load_scenario(name))
    for tls, pm in maps.items():
        side_of = {f"{node}_{tls}": side for side, node in neighbours(tls).items()}
        assert len(pm.link_phases) == 16 and pm.phases == tuple(range(1, 9)), tls
        assert {side: len(lanes) for side, lanes in pm.approach_lanes.items()} == dict.fromkeys(side_of.values(), 3)
        for link in pm.links:
            edge, lane = link.from_lane.rsplit("_", 1)
            assert link.phase == PHASE_OF[side_of[edge], link.direction], (tls, link)
            # lane 0 right and through, 1 through, 2 the protected left
            assert link.direction in {"0": "rs", "1": "s", "2": "l"}[lane], (tls, link)


def test_the_corridor_times_its_arterial_longer_and_its_busy_crossroad_its_own_way() -> None:
    lights = load_scenario("corridor").intersections
    arterial, crossroad = lights["J1"], lights["J3"]
    # one file, loaded once; each light its own offset
    assert lights["J2"].phases is arterial.phases and lights["J4"].phases is arterial.phases
    for cfg in (arterial, crossroad):
        assert min(cfg.phases[p].max_green for p in (2, 6)) > max(cfg.phases[p].max_green for p in (3, 4, 7, 8))
    assert crossroad.phases[4].max_green > arterial.phases[4].max_green
    assert crossroad.phases[2].max_green < arterial.phases[2].max_green


def flows_per_hour(name: str) -> dict[str, float]:
    """veh/h entering at each edge, from the Poisson rates (veh/s) of the demand file."""
    text = data_path(f"{name}.rou.xml").read_text()
    out: dict[str, float] = {}
    for entry, rate in re.findall(r'<flow [^>]*from="([^"]+)"[^>]*period="exp\(([\d.]+)\)"', text):
        out[entry] = out.get(entry, 0.0) + float(rate) * 3600
    return out


def test_the_arterial_carries_far_more_than_the_cross_streets() -> None:
    entries = flows_per_hour("corridor")
    arterial = [entries.pop("W_J1"), entries.pop("E_J4")]
    assert len(entries) == 8 and all(100 < v < 400 for v in entries.values())
    assert min(arterial) > 2.5 * max(entries.values())
    assert 2000 < sum(arterial) + sum(entries.values()) < 4000


def test_the_grid_has_moderate_demand_on_every_boundary_entry() -> None:
    entries = flows_per_hour("grid4x4")
    assert len(entries) == 16 and all(150 < v < 300 for v in entries.values())


# --- refusals ----------------------------------------------------------------------------------------------


def scenario_file(tmp_path: Path, intersections: dict[str, str], sumocfg: str | None = None,
                  extra: str = "") -> Path:
    path = tmp_path / "mine.scenario.toml"
    lights = "".join(f'{tls} = "{cfg}"\n' for tls, cfg in intersections.items())
    path.write_text(f'sumocfg = "{sumocfg or data_path("corridor.sumocfg")}"\n{extra}\n[intersections]\n{lights}')
    return path


def arterial() -> dict[str, str]:
    """Every light of the corridor on the arterial config."""
    return dict.fromkeys(CORRIDOR, str(data_path("corridor_arterial.toml")))


@pytest.mark.parametrize(("make", "field", "allowed"), [
    (lambda tmp: "corridoor", "<scenario>", "allowed: a shipped scenario (four_leg, four_phase, corridor, grid4x4), "
                                            "resco:NAME (RESCO's benchmark) or a path to a .scenario.toml file"),
    (lambda tmp: tmp / "absent.scenario.toml", "<file>", "cannot be read (No such file or directory); allowed: a "
                                                         "shipped scenario"),
    (lambda tmp: scenario_file(tmp, arterial(), extra='target = "snmp://x"'), "target",
     "unknown field; allowed: name, sumocfg, intersections"),
    (lambda tmp: scenario_file(tmp, arterial(), sumocfg="nowhere.sumocfg"), "sumocfg",
     "nowhere.sumocfg does not exist; allowed: the path of a SUMO configuration (.sumocfg), relative to this file"),
    (lambda tmp: scenario_file(tmp, {"J1": "arterial.toml"}), "intersections.J1",
     "arterial.toml does not exist; allowed: the path of an intersection config (.toml)"),
    (lambda tmp: scenario_file(tmp, {}), "intersections", "is required: a table of traffic light id = intersection "
                                                          "config file"),
])
def test_a_scenario_that_cannot_be_loaded_is_refused_naming_file_field_and_what_is_allowed(
        tmp_path: Path, make, field: str, allowed: str) -> None:
    given = make(tmp_path)
    with pytest.raises(ConfigError) as caught:
        load_scenario(given)
    assert caught.value.source == str(given) and caught.value.field == field
    assert allowed in caught.value.message


def test_a_light_the_network_lacks_is_refused_with_the_lights_it_has(tmp_path: Path) -> None:
    path = scenario_file(tmp_path, arterial() | {"J5": str(data_path("corridor_arterial.toml"))})
    with pytest.raises(NetworkError, match=re.escape(f"{path}: intersections.J5: the network corridor.net.xml has no "
                                                     "traffic light 'J5'; allowed: J1, J2, J3, J4")):
        check_scenario(load_scenario(path))


def test_a_light_of_the_network_without_a_config_is_refused(tmp_path: Path) -> None:
    lights = arterial()
    del lights["J2"], lights["J4"]
    path = scenario_file(tmp_path, lights)
    with pytest.raises(NetworkError, match=re.escape(f"{path}: intersections: traffic light(s) J2, J4 of "
                                                     "corridor.net.xml have no controller config; allowed: a config "
                                                     "for every traffic light of the network (J1, J2, J3, J4)")):
        check_scenario(load_scenario(path))


def test_a_config_that_does_not_fit_its_light_is_refused_naming_the_light(tmp_path: Path) -> None:
    # Four phases without protected or permissive lefts: the left lanes of J3 would be served by no phase.
    no_lefts = tmp_path / "no_lefts.toml"
    no_lefts.write_text(data_path("four_phase.toml").read_text().replace(', permissive = ["left"]', ""))
    path = scenario_file(tmp_path, arterial() | {"J3": str(no_lefts)})
    with pytest.raises(NetworkError, match=r"traffic light J3: link .*no phase serves the left movement"):
        check_scenario(load_scenario(path))


# --- in SUMO -----------------------------------------------------------------------------------------------


def fixed_cycle(config: IntersectionConfig) -> Callable[[float], SignalState]:
    """Test scaffolding, not the controller: the state at each time of a fixed cycle through the config's
    sequence, each pair green for its phases' maximum green, then its yellow and red clearance."""
    every, none = frozenset(config.phases), frozenset[int]()
    intervals: list[tuple[float, SignalState]] = []
    for pair in config.sequence:
        on, phases = frozenset(pair), [config.phases[p] for p in pair]
        intervals += [(max(ph.max_green for ph in phases), SignalState(every - on, none, on)),
                      (max(ph.yellow for ph in phases), SignalState(every - on, on, none)),
                      (max(ph.red_clear for ph in phases), SignalState(every, none, none))]
    length = sum(duration for duration, _ in intervals)

    def state_at(t: float) -> SignalState:
        t %= length
        for duration, state in intervals:
            if t < duration:
                return state
            t -= duration
        return intervals[-1][1]  # float rounding at the very end of the cycle

    return state_at


WARM_UP = 300.0  # s: a crossing of the network takes one to three minutes


@pytest.mark.parametrize("name", ["corridor", "grid4x4"])
def test_traffic_flows_through_every_light_under_a_fixed_cycle(name: str) -> None:
    scenario = load_scenario(name)
    maps = check_scenario(scenario)
    libsumo.start(["sumo", "-c", str(scenario.sumo_config), "--seed", "1", "--no-step-log", "true",
                   "--no-warnings", "true"])
    try:
        assert set(libsumo.trafficlight.getIDList()) == set(maps)
        for tls, pm in maps.items():
            assert len(libsumo.trafficlight.getControlledLinks(tls)) == len(pm.link_phases)
        plans = {tls: fixed_cycle(cfg) for tls, cfg in scenario.intersections.items()}
        departed = arrived = teleported = departed_warm = arrived_warm = 0
        crossed: dict[str, set[str]] = {tls: set() for tls in maps}  # vehicles seen inside each junction
        while libsumo.simulation.getTime() < 2 * WARM_UP:
            now = libsumo.simulation.getTime()
            for tls, pm in maps.items():
                libsumo.trafficlight.setRedYellowGreenState(tls, pm.state_string(plans[tls](now)))
            libsumo.simulationStep()
            departed += libsumo.simulation.getDepartedNumber()
            arrived += libsumo.simulation.getArrivedNumber()
            teleported += libsumo.simulation.getStartingTeleportNumber()
            if now == WARM_UP:
                departed_warm, arrived_warm = departed, arrived
            if now % 10 == 0:
                for tls, pm in maps.items():
                    crossed[tls].update(v for link in pm.links for v in libsumo.lane.getLastStepVehicleIDs(link.via))
    finally:
        libsumo.close()
    assert teleported == 0
    # No gridlock: once the network has filled, vehicles leave about as fast as they come in.
    assert departed - departed_warm > 200
    assert arrived - arrived_warm > 0.8 * (departed - departed_warm), (arrived, departed, arrived_warm, departed_warm)
    assert all(crossed.values()), {tls: len(v) for tls, v in crossed.items()}


def test_the_corridor_plan_progresses_eastbound() -> None:
    """One cycle for the corridor; each junction's offset is the travel time from J1 at the arterial's speed
    (300 m apart, 13.89 m/s), to the nearest second."""
    lights = load_scenario("corridor").intersections
    assert {cfg.coordination.patterns[1].cycle for cfg in lights.values()} == {80}
    offsets = {tls: cfg.coordination.patterns[1].offset for tls, cfg in lights.items()}
    assert offsets == {tls: round(i * 300 / 13.89) for i, tls in enumerate(CORRIDOR)}
    assert all(cfg.coordination.pattern == 254 for cfg in lights.values())  # free unless --agent coordinated


@pytest.mark.parametrize(("offsets", "field", "allowed"), [
    ("J9 = 3", "offsets.J9", "unknown traffic light; allowed: J1, J2, J3, J4"),
    ("J2 = 300", "offsets.J2", "whole seconds 0-254"),
    ('J2 = "22"', "offsets.J2", "whole seconds 0-254"),
])
def test_a_bad_offset_is_refused(tmp_path: Path, offsets: str, field: str, allowed: str) -> None:
    path = scenario_file(tmp_path, arterial())
    path.write_text(path.read_text() + f"\n[offsets]\n{offsets}\n")
    with pytest.raises(ConfigError) as caught:
        load_scenario(path)
    assert caught.value.field == field and allowed in caught.value.message
