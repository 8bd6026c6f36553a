"""The lights of a sumo-rl network as hils derives them: sumo-rl's own names for each light (its green phases, lanes
and spaces, read against sumo-rl's TrafficSignal on the same network), the stage each green phase asks for, the timings
sumo-rl's options set, and what is refused."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from harness.reference.sumo_rl_peer import sumo_rl
from hils.envs.intersection import EnvOptionError
from hils.protocol import resco
from hils.protocol.errors import UserError
from hils.sim.network import scenario_config
from hils.sim.sumo import _console
from hils.sumo_rl import SumoEnvironment
from hils.sumo_rl.environment import register
from hils.sumo_rl.lights import Timings, derive, green_phases

NETS = resco.networks_dir().parent  # the installed sumo-rl's nets/
#: sumo-rl's networks with traffic lights, each with a demand of its folder, and RESCO's three largest
NETWORKS = {
    "single-intersection": ("single-intersection/single-intersection.net.xml",
                            "single-intersection/single-intersection.rou.xml"),
    "2way-single-intersection": ("2way-single-intersection/single-intersection.net.xml",
                                 "2way-single-intersection/single-intersection-vhvh.rou.xml"),
    "2x2grid": ("2x2grid/2x2.net.xml", "2x2grid/2x2.rou.xml"),
    "3x3grid": ("3x3grid/3x3Grid2lanes.net.xml", "3x3grid/routes14000.rou.xml"),
    "4x4-Lucas": ("4x4-Lucas/4x4.net.xml", "4x4-Lucas/4x4c1c2c1c2.rou.xml"),
    "4x4loop": ("4x4loop/4x4loop.net.xml", "4x4loop/4x4loop.rou.xml"),
    "Nguyen": ("Nguyen/nguyentl.net.xml", "Nguyen/flows/nguyen2lanes.rou.xml"),
    "double": ("double/network.net.xml", "double/flow.rou.xml"),
    "grid4x4": ("RESCO/grid4x4/grid4x4.net.xml", "RESCO/grid4x4/grid4x4_1.rou.xml"),
    "cologne8": ("RESCO/cologne8/cologne8.net.xml", "RESCO/cologne8/cologne8.rou.xml"),
    "ingolstadt21": ("RESCO/ingolstadt21/ingolstadt21.net.xml", "RESCO/ingolstadt21/ingolstadt21.rou.xml"),
}


def files(name: str) -> dict[str, str]:
    net, routes = NETWORKS[name]
    return {"net_file": str(NETS / net), "route_file": str(NETS / routes)}


@pytest.fixture
def sumo_rls_own() -> Iterator[Any]:
    """sumo-rl itself (through libsumo, as its peer runs), and gymnasium's ``sumo-rl-v0`` given back to hils after:
    importing sumo-rl registers its own environment under that id."""
    yield sumo_rl()
    register()


@pytest.mark.parametrize("name", NETWORKS)
def test_every_light_has_sumo_rls_green_phases_lanes_and_spaces(name: str, sumo_rls_own: Any) -> None:
    """sumo-rl's TrafficSignal on the same network (sumo-rl starts SUMO on it to read its lights) is the reference:
    the same lights in the same order, each with the same green phases, incoming lanes (in order), outgoing lanes (a
    set in sumo-rl), lane lengths and observation and action spaces."""
    with _console(quiet=True):
        theirs = sumo_rls_own.SumoEnvironment(**files(name), sumo_warnings=False)
    ours = SumoEnvironment(**files(name), sumo_warnings=False)
    try:
        assert ours.ts_ids == list(theirs.ts_ids)
        for ts in ours.ts_ids:
            a, b = theirs.traffic_signals[ts], ours.traffic_signals[ts]
            assert [p.state for p in b.green_phases] == [p.state for p in a.green_phases], ts
            assert b.lanes == a.lanes, ts
            assert set(b.out_lanes) == set(a.out_lanes) and len(b.out_lanes) == len(set(a.out_lanes)), ts
            assert b.lanes_length == a.lanes_length, ts
            assert b.observation_space == a.observation_space and b.action_space == a.action_space, ts
    finally:
        ours.close()
        theirs.close()


def test_each_green_phase_asks_for_the_stage_of_its_program_phase(tmp_path: Path) -> None:
    """On grid4x4 RESCO's stages are sumo-rl's green phases: green phase k asks for the pair of the controller's k-th
    stage, and every pair is some green phase's."""
    _, lights = derive_files("grid4x4", tmp_path)
    for light in lights.values():
        assert None not in light.stage_of
        assert [light.pair_of(g) for g in range(len(light.stage_of))] == list(light.config.sequence)
        assert {light.config.sequence[s] for s in light.stage_of} == set(light.config.pairs)


def test_a_green_phase_that_is_no_stage_asks_for_nothing(tmp_path: Path) -> None:
    """3x3grid's programs write their yellows 'Y', which sumo-rl takes for green phases (only 'y' is yellow to it): the
    derivation has no stage for them, and asking for one asks the controller for nothing."""
    _, lights = derive_files("3x3grid", tmp_path)
    light = lights["0"]
    assert light.green_states[1].startswith("YYYY")
    assert light.stage_of == (0, None, 1, None)
    assert light.pair_of(1) is None and light.pair_of(2) == light.config.sequence[1]


def test_sumo_rls_green_phase_rule() -> None:
    """sumo-rl's rule (``_build_phases``): no 'y', not only 'r' and 's'."""
    assert green_phases(["GGrr", "yyrr", "rrrr", "rrGG", "ssrr", "rrGy", "YYrr", "rruu"]) == (0, 3, 6, 7)


def derive_files(name: str, directory: Path, **timings: Any) -> tuple[Any, Any]:
    net, routes = (NETS / f for f in NETWORKS[name])
    given = {"delta_time": 5.0, "yellow_time": 3.0, "min_green": 5, "max_green": 50, "begin_time": 0.0,
             "num_seconds": 100.0, "step_length": 1.0} | timings
    return derive(net, scenario_config(net=net, routes=routes, directory=directory), Timings(**given))


def test_yellow_min_green_and_max_green_are_every_phases(tmp_path: Path) -> None:
    """sumo-rl's timing options set every derived phase's yellow change, minimum and maximum green; the red clearance
    stays the program's (Nguyen's 1 s all-red phases), and delta_time is the control interval."""
    scenario, lights = derive_files("Nguyen", tmp_path, yellow_time=4.0, min_green=7, max_green=33, delta_time=10.0)
    reds = set()
    for config in scenario.intersections.values():
        assert config.middleware.control_interval == 10.0 and config.middleware.sumo_step == 1.0
        for phase in config.phases.values():
            assert (phase.yellow, phase.min_green, phase.max_green) == (4.0, 7, 33)
            reds.add(phase.red_clear)
    assert reds == {1.0}
    assert all(lights[tls].config is scenario.intersections[tls] for tls in lights)


REFUSED = [
    ({"yellow_time": 2}, "yellow_time 2: a NEMA controller's yellow change is NTCIP 1202's phaseYellowChange; allowed: "
                         "3-25.5 s"),
    ({"yellow_time": 3.25}, "yellow_time 3.25"),
    ({"min_green": 0}, "min_green 0: allowed: a positive number of seconds"),
    ({"min_green": 300}, "min_green 300: allowed: whole seconds, 1-255 (NTCIP 1202)"),
    ({"delta_time": "5"}, "delta_time '5': allowed: a positive number of seconds"),
    ({"min_green": 4.5}, "min_green 4.5: allowed: whole seconds"),
    ({"max_green": 5}, "max_green 5 s is not above min_green 5 s; allowed: max_green > min_green"),
    ({"delta_time": 3}, "delta_time 3 s: traffic light t clears for 3.1 s (yellow 3 s + the red clearance of its "
                        "program); allowed: delta_time > 3.1 s"),
    ({"delta_time": 0}, "delta_time 0: allowed: a positive number of seconds"),
    ({"render_mode": "human"}, "render_mode 'human': hils runs SUMO in process through libsumo, which has no GUI to "
                               "render; allowed: None"),
    ({"reward_fn": "wait"}, "reward_fn 'wait': allowed: diff-waiting-time, average-speed, queue, pressure"),
    ({"reward_fn": {"x": "queue"}}, "reward_fn: a dict with no reward for traffic light(s) t; allowed: one for every "
                                    "light (t)"),
    ({"additional_sumo_cmd": "--step-length fast"}, "additional_sumo_cmd: --step-length 'fast': allowed: seconds"),
    ({"additional_sumo_cmd": "--step-length 2", "delta_time": 5}, None),  # allowed: a longer SUMO step
    ({"fixed_ts": True, "min_green": 60, "max_green": 90},
     "the fixed-time agent runs each controller's timing plan, and 1 of the 1 lights of sumo-rl:single-intersection"
     ".net.xml has none: t: phase"),
]


@pytest.mark.parametrize(("options", "message"), REFUSED, ids=[str(o) for o, _ in REFUSED])
def test_what_the_controllers_cannot_honour_is_refused_saying_what_is_allowed(options: dict[str, Any],
                                                                              message: str | None) -> None:
    """sumo-rl's default yellow of 2 s, a delta_time within a light's clearance (3 s yellow + one 0.1 s tick of red
    clearance on single-intersection, whose program has no all-red), timings NTCIP cannot hold, a fixed-time run of a
    program whose splits are shorter than the minimum service: refused at construction, naming the option."""
    if message is None:
        SumoEnvironment(**files("single-intersection"), **options).close()
        return
    with pytest.raises(UserError) as refused:
        SumoEnvironment(**files("single-intersection"), **options)
    assert message in str(refused.value)


def test_a_network_without_lights_is_refused() -> None:
    with pytest.raises(EnvOptionError, match="has no traffic light; allowed: a network with at least one"):
        SumoEnvironment(net_file=str(NETS / "simple" / "simple.net.xml"),
                        route_file=str(NETS / "simple" / "simple.rou.xml"))
