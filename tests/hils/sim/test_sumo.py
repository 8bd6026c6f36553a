"""The SUMO side: the shipped network, the derived phase-to-link map and the libsumo wrapper."""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections.abc import Iterator
from pathlib import Path

import libsumo
import pytest

from hils.protocol.config import IntersectionConfig, from_dict, load
from hils.protocol.ntcip import SignalState
from hils.sim.network import (
    NETWORKS,
    TLS_ID,
    NetworkError,
    build_network,
    compass_side,
    controlled_links_from_net,
    data_path,
    derive_phase_map,
    read_net,
)
from hils.sim.sumo import LaneState, SumoError, SumoSimulation, time_bare_sumo
from hils.sim.webster import webster_plan

STEP = 0.25

# What the shipped network is, written down independently of the derivation: the phase of
# each (incoming edge, SUMO direction) of junction C under the NEMA numbering of four_leg.toml.
EXPECTED_PHASE = {
    ("W2C", "l"): 1, ("W2C", "s"): 6, ("W2C", "r"): 6,
    ("E2C", "l"): 5, ("E2C", "s"): 2, ("E2C", "r"): 2,
    ("S2C", "l"): 3, ("S2C", "s"): 8, ("S2C", "r"): 8,
    ("N2C", "l"): 7, ("N2C", "s"): 4, ("N2C", "r"): 4,
}
INCOMING_EDGES = ("N2C", "E2C", "S2C", "W2C")


@pytest.fixture(scope="module")
def config() -> IntersectionConfig:
    return load()


@pytest.fixture(scope="module")
def net():
    return read_net()


def edge_of(lane: str) -> str:
    return lane.rsplit("_", 1)[0]


def cycle(config: IntersectionConfig, green: float, yellow: float = 3.0,
          red_clear: float = 2.0) -> Iterator[SignalState]:
    """Test scaffolding, not the controller: the state of every SUMO step of a fixed cycle of pairs."""
    every = frozenset(config.phases)
    none: frozenset[int] = frozenset()
    while True:
        for pair in config.sequence:
            on = frozenset(pair)
            for duration, state in ((green, SignalState(every - on, none, on)),
                                    (yellow, SignalState(every - on, on, none)),
                                    (red_clear, SignalState(every, none, none))):
                for _ in range(round(duration / STEP)):
                    yield state


# --- the network and the derived map (no simulation) -----------------------------------------


def test_every_link_is_under_the_phase_of_its_movement(config, net) -> None:
    pm = derive_phase_map(config, net)
    assert len(pm.link_phases) == 16
    seen = set()
    for link in pm.links:
        key = (edge_of(link.from_lane), link.direction)
        assert pm.link_phases[link.index] == link.phase == EXPECTED_PHASE[key], link
        seen.add(key)
    assert seen == set(EXPECTED_PHASE)
    assert pm.phases == (1, 2, 3, 4, 5, 6, 7, 8)
    for phase in pm.phases:
        turn = config.phases[phase].turn
        links = pm.links_of(phase)
        assert links, f"phase {phase} has no link"
        # a left phase serves exactly the left lane; a through phase the through and right links
        assert {lk.direction for lk in links} == ({"l"} if turn == "left" else {"s", "r"})
        assert {lk.approach for lk in links} == {config.phases[phase].approach}


def test_right_turns_run_with_the_through_of_their_approach(config, net) -> None:
    pm = derive_phase_map(config, net)
    rights = [lk for lk in pm.links if lk.direction == "r"]
    assert len(rights) == 4
    for link in rights:
        assert config.phases[link.phase].turn == "through"
        assert config.phases[link.phase].approach == link.approach


def test_state_string_shows_green_yellow_and_red_by_phase(config, net) -> None:
    pm = derive_phase_map(config, net)
    state = SignalState(reds=frozenset({2, 3, 4, 6, 7, 8}), yellows=frozenset({5}), greens=frozenset({1}))
    text = pm.state_string(state)
    for link in pm.links:
        assert text[link.index] == {1: "G", 5: "y"}.get(link.phase, "r")


def test_a_link_no_phase_serves_is_an_error(net) -> None:
    east_west_only = from_dict({
        "phases": {"1": {"approach": "west", "turn": "left"}, "2": {"approach": "east", "turn": "through"},
                   "5": {"approach": "east", "turn": "left"}, "6": {"approach": "west", "turn": "through"}},
        "timing": {"min_green": 3, "max_green": 20, "yellow": 3.0, "red_clear": 2.0},
        "structure": {"rings": [[1, 2], [5, 6]], "barriers": [[1, 2, 5, 6]],
                      "sequence": [[1, 5], [2, 6]], "pairs": [[1, 5], [2, 6]]},
    }, "ew.toml")
    with pytest.raises(NetworkError, match=r"no phase serves the (through|left) movement of the (north|south) "):
        derive_phase_map(east_west_only, net)


def test_a_phase_without_links_is_an_error(config, net) -> None:
    without_north = [t for t in controlled_links_from_net(net) if edge_of(t[0][0]) != "N2C"]
    with pytest.raises(NetworkError, match=r"phase\(s\) \[4, 7\] serve no link"):
        derive_phase_map(config, net, without_north)


def test_two_phases_for_one_movement_is_an_error(config, net) -> None:
    phases = dict(config.phases)
    phases[3] = dataclasses.replace(phases[3], approach="north")
    with pytest.raises(NetworkError, match="phases 3 and 7 both serve the left movement of the north approach"):
        derive_phase_map(dataclasses.replace(config, phases=phases), net)


def test_compass_side_of_an_approach() -> None:
    assert compass_side(0.0, 240.0, "x") == "north"
    assert compass_side(-240.0, 30.0, "x") == "west"
    assert compass_side(100.0, -20.0, "x") == "east"
    assert compass_side(5.0, -240.0, "x") == "south"
    with pytest.raises(NetworkError, match="diagonal"):
        compass_side(100.0, 95.0, "x")


@pytest.mark.parametrize("name", NETWORKS)
def test_shipped_network_is_what_netconvert_makes_of_the_sources(tmp_path: Path, name: str) -> None:
    def body(text: str) -> str:
        # the leading comment holds the generation date and the output path
        return re.sub(r"\A.*?-->", "", text, count=1, flags=re.S)

    rebuilt = build_network(tmp_path / "rebuilt.net.xml", name)
    assert body(rebuilt.read_text()) == body(data_path(f"{name}.net.xml").read_text())


# --- the simulation -----------------------------------------------------------------------------


def test_indications_follow_the_applied_state_and_nobody_crosses_on_red(config, net) -> None:
    with SumoSimulation(config, seed=3) as sim:
        pm = sim.lights[TLS_ID].phase_map
        # the link table SUMO runs with is the one the map was derived for
        assert [list(t) for t in libsumo.trafficlight.getControlledLinks("C")] == controlled_links_from_net(net)
        link_of = {(lk.from_lane, edge_of(lk.to_lane)): lk.index for lk in pm.links}
        incoming = [f"{e}_{i}" for e in INCOMING_EDGES for i in range(3)]
        last_lane: dict[str, str] = {}
        crossings = {"G": 0, "y": 0, "r": 0}
        phases_crossed = set()
        states = cycle(config, green=12.0)
        while sim.time < 400.0:
            state = next(states)
            sim.lights[TLS_ID].apply(state)
            expected = pm.state_string(state)
            sim.step()
            assert sim.lights[TLS_ID].indications() == expected, f"t={sim.time}"
            now = {vid: lane for lane in incoming for vid in libsumo.lane.getLastStepVehicleIDs(lane)}
            for vid, lane in last_lane.items():
                if vid in now:
                    continue
                # left its approach during this step: through the link of its lane and route
                index = link_of[(lane, libsumo.vehicle.getRoute(vid)[-1])]
                crossings[expected[index]] += 1
                phases_crossed.add(pm.link_phases[index])
            last_lane = now
    assert crossings["r"] == 0, crossings
    assert crossings["G"] > 200, crossings
    assert phases_crossed == set(config.phases)


def test_queues_build_on_red_and_discharge_on_green(config) -> None:
    every = frozenset(config.phases)
    with SumoSimulation(config, seed=5) as sim:
        all_red = SignalState(every, frozenset(), frozenset())
        assert sim.lights[TLS_ID].apply(all_red) is False  # the light starts all red
        while sim.time < 120.0:
            sim.step()
        red = sim.lights[TLS_ID].traffic_state()
        assert red.departed > 30 and red.arrived == 0
        assert sim.summary().mean_time_loss is None
        for phase in (2, 6):  # the major through movements
            assert red.movements[phase].upstream_queue >= 5
        assert all(m.downstream_queue == 0 for m in red.movements.values())
        assert red.lanes["W2C_1"].waiting_time > 0 and red.lanes["W2C_1"].vehicles >= red.lanes["W2C_1"].halting

        green = SignalState(every - {2, 6}, frozenset(), frozenset({2, 6}))
        assert sim.lights[TLS_ID].apply(green) is True
        assert sim.lights[TLS_ID].apply(SignalState(every - {2, 6}, frozenset(), frozenset({2, 6}))) is False
        while sim.time < 180.0:
            sim.step()
        after = sim.lights[TLS_ID].traffic_state()
        assert after.arrived > 10
        for phase in (2, 6):
            assert after.movements[phase].upstream_queue < red.movements[phase].upstream_queue
        for phase in (1, 3, 4, 5, 7, 8):
            assert after.movements[phase].upstream_queue >= red.movements[phase].upstream_queue
        summary = sim.summary()
    assert summary.arrived == after.arrived
    assert summary.mean_time_loss is not None and summary.mean_time_loss > 30  # they all waited a red
    assert summary.max_queue["west"] >= red.movements[6].upstream_queue
    assert summary.collisions == 0
    every_vehicle = summary.approaches.values()
    assert sum(a.arrived for a in every_vehicle) == summary.arrived
    assert sum(a.running for a in every_vehicle) == summary.running
    assert sum(a.waiting_to_enter for a in every_vehicle) == summary.waiting_to_enter
    # the north and south approaches saw red for three minutes: their delay so far is at least a minute
    assert summary.approaches["north"].mean_delay > 60 and summary.approaches["south"].mean_delay > 60
    assert summary.mean_delay > summary.mean_time_loss  # it counts those still waiting at the red


def test_the_traffic_state_is_what_libsumo_reads_lane_by_lane(config) -> None:
    """Every lane's state is SUMO's own three figures, an empty lane's too (whose halting number and waiting time
    are not asked for: SUMO's loop over its vehicles has none), and a movement's queues sum its lanes' halting."""
    every = frozenset(config.phases)
    lane = libsumo.lane
    with SumoSimulation(config, seed=5) as sim:
        light = sim.lights[TLS_ID]
        light.apply(SignalState(every - {2, 6}, frozenset(), frozenset({2, 6})))
        empty = busy = 0
        for _ in range(30):
            sim.advance(40)  # 10 s
            state = light.traffic_state()
            for name, read in state.lanes.items():
                assert read == LaneState(lane.getLastStepHaltingNumber(name), lane.getWaitingTime(name),
                                         lane.getLastStepVehicleNumber(name))
                assert type(read.waiting_time) is float and type(read.halting) is type(read.vehicles) is int
                empty += read.vehicles == 0
                busy += read.halting > 0 and read.waiting_time > 0
            for phase, movement in state.movements.items():
                pm = light.phase_map
                assert movement.upstream_queue == sum(map(lane.getLastStepHaltingNumber, pm.incoming_lanes(phase)))
                assert movement.downstream_queue == sum(map(lane.getLastStepHaltingNumber,
                                                            pm.outgoing_lanes(phase)))
    assert empty > 30 and busy > 30  # both kinds were read, many times


def test_same_seed_same_run_and_restart_in_one_process(config) -> None:
    def run() -> tuple:
        with SumoSimulation(config, seed=11) as sim:
            states = cycle(config, green=10.0)
            while sim.time < 150.0:
                sim.lights[TLS_ID].apply(next(states))
                sim.step()
            return sim.lights[TLS_ID].traffic_state(), sim.summary()

    first, second = run(), run()
    assert first == second
    assert first[1].arrived > 0


def test_one_simulation_per_process(config) -> None:
    with SumoSimulation(config) as sim:
        with pytest.raises(SumoError, match="already running"):
            SumoSimulation(config).start()
        assert sim.running
    assert not sim.running


def test_start_failure_reports_sumo_message(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "broken.sumocfg"
    cfg.write_text('<sumoConfiguration><input><net-file value="missing.net.xml"/></input></sumoConfiguration>')
    with pytest.raises(SumoError, match=r"missing\.net\.xml"):
        SumoSimulation(sumo_config=cfg).start()
    assert "missing.net.xml" not in capfd.readouterr().out


def test_quiet_simulation_prints_nothing(config, capfd: pytest.CaptureFixture[str]) -> None:
    with SumoSimulation(config) as sim:
        sim.step()
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_fixed_time_baseline_runs_the_webster_cycle(config) -> None:
    every = frozenset(config.phases)
    green = webster_plan(config).green_of((1, 5))  # yellow 3 s and red clearance 2 s follow it
    with SumoSimulation(config) as sim:
        sim.run_fixed_time()
        pm = sim.lights[TLS_ID].phase_map
        checks = {green - 1.0: SignalState(every - {1, 5}, frozenset(), frozenset({1, 5})),
                  green + 1.5: SignalState(every - {1, 5}, frozenset({1, 5}), frozenset()),
                  green + 4.0: SignalState(every, frozenset(), frozenset()),
                  green + 6.0: SignalState(every - {2, 6}, frozenset(), frozenset({2, 6}))}
        for at, state in checks.items():
            while sim.time < at:
                sim.step()
            assert sim.lights[TLS_ID].indications() == pm.state_string(state), at
    wall = time_bare_sumo(60.0, config=config)
    assert 0.0 < wall < 10.0


def test_a_vehicle_standing_at_the_stop_bar_is_present_on_its_lane(config) -> None:
    with SumoSimulation(config, seed=2) as sim:
        pm = sim.lights[TLS_ID].phase_map
        phase_of_lane = {lane: p for p in pm.phases for lane in pm.incoming_lanes(p)}
        # all red: queues form
        sim.lights[TLS_ID].apply(SignalState(frozenset(config.phases), frozenset(), frozenset()))
        while sim.time < 60.0:
            sim.step()
        present = sim.lights[TLS_ID].present()
        # After a minute of red, a lane with a halted queue has its first vehicle at the stop bar: exactly those
        # lanes are present.
        queued = {lane for lane in phase_of_lane if libsumo.lane.getLastStepHaltingNumber(lane)}
        assert present == queued and len({phase_of_lane[lane] for lane in present}) >= 4
        assert sim.lights[TLS_ID].present(zone=0.5) <= present


@pytest.mark.parametrize("measure", [True, False])
def test_advancing_several_steps_at_once_is_stepping_them_one_by_one(config, measure: bool) -> None:
    """libsumo steps to a time in one call; the stretches the Testbed hands it (nothing shown changes within
    one) must give the very traffic, and the very per-second samples, of as many single steps."""
    states = list(itertools.islice(cycle(config, green=12.0), 1200))  # 300 s
    runs = [(state, len(list(group))) for state, group in itertools.groupby(states)]

    def run(stretched: bool) -> tuple:
        with SumoSimulation(config, seed=5, measure=measure) as sim:
            for state, n in runs:
                sim.lights[TLS_ID].apply(state)
                sim.step()
                left = n - 1
                while left:  # stretches of 1..7 steps: across the per-second samples and between them
                    if stretched:
                        m = min(left, 1 + left % 7)
                        sim.advance(m)
                    else:
                        m = 1
                        sim.step()
                    left -= m
            vehicles = {v: (libsumo.vehicle.getLanePosition(v), libsumo.vehicle.getSpeed(v))
                        for v in libsumo.vehicle.getIDList()}
            return sim.time, vehicles, sim.summary()

    single, stretched = run(False), run(True)
    assert stretched[0] == single[0] == 300.0
    assert stretched[1] == single[1] and len(single[1]) > 20
    assert stretched[2] == single[2]
    assert (single[2].mean_delay is not None) is measure


def test_a_movement_state_is_made_once_per_value_and_the_store_of_them_stays_bounded(monkeypatch) -> None:
    """Every light's traffic state at every decision takes its movement states from one store of values: the same
    fields give the same object, equal to one made anew; the store empties once it holds its bound."""
    from hils.sim import sumo as sumo_mod

    first, again = sumo_mod._movement(2, 3, 1), sumo_mod._movement(2, 3, 1)
    assert first is again and first == sumo_mod.MovementState(2, 3, 1) and first.pressure == 2
    assert sumo_mod._movement(2, 1, 3) != first
    monkeypatch.setattr(sumo_mod, "_MOVEMENTS_KEPT", len(sumo_mod._MOVEMENTS) + 1)
    sumo_mod._movement(16, 999, 998)  # the last one the bound lets in
    assert sumo_mod._movement(16, 999, 997) == sumo_mod.MovementState(16, 999, 997)
    assert len(sumo_mod._MOVEMENTS) == 1
