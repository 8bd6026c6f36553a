"""The peer of `hils bench resco` and the RESCO study: sumo-rl's multi-agent environment on RESCO's networks, each of
its stages matched to the pair of phases hils' controller serves for it, given hils' yellow and minimum green in its
unit, decided by hils' own agents; and the bench's figures seed by seed."""

from __future__ import annotations

import json
import subprocess
import sys
from functools import partial
from pathlib import Path

import pytest

from harness.bench.processes import in_fresh_process
from harness.reference.sumo_rl_peer import Light, _AgentBridge, episode
from hils.agents.builtin import FixedCycleAgent, MaxPressureAgent
from hils.protocol import resco


def _stage_check(name: str) -> tuple[int, list[str]]:
    """In a fresh process: every light of the scenario, sumo-rl's green phases as its TrafficSignal builds them, each
    matched to its pair; the greens hils' phase map shows for that pair on the connected links must be the phase's."""
    import libsumo

    from harness.reference.sumo_rl_peer import _lights, sumo_rl
    from hils.protocol.ntcip import SignalState
    from hils.sim.network import derive_phase_map, read_net

    module = sumo_rl()
    scenario = resco.load(name)
    net_file = next(scenario.sumo_config.parent.glob("*.net.xml"))
    routes = next(scenario.sumo_config.parent.glob("*.rou.xml"))
    env = module.SumoEnvironment(net_file=str(net_file), route_file=str(routes), num_seconds=10, delta_time=10,
                                 begin_time=int(resco.MAPS[name].start), single_agent=False, sumo_seed=0,
                                 sumo_warnings=False)
    env.reset(seed=0)
    lights = _lights(env, scenario.intersections)
    net = read_net(str(net_file))
    checked, no_stage = 0, []
    for tls, light in lights.items():
        links = libsumo.trafficlight.getControlledLinks(tls)
        connected = [k for k, link in enumerate(links) if link]
        phase_map = derive_phase_map(light.config, net, links, tls, scenario.links.get(tls))
        for action, phase in enumerate(env.traffic_signals[tls].green_phases):
            pair = light.pair_of(action)
            if pair is None:
                no_stage.append(f"{tls} {phase.state}")
                continue
            shown = phase_map.state_string(SignalState(frozenset(light.config.phases) - set(pair), frozenset(),
                                                       frozenset(pair)))
            wanted = [phase.state[k] if phase.state[k] in "Gg" else "r" for k in connected]
            assert [shown[k] for k in connected] == wanted, (tls, action, pair)
            checked += 1
        # the yellow sumo-rl times is the light's (one for all its phases), in SUMO steps of 0.25 s
        (yellow,) = {phase.yellow for phase in light.config.phases.values()}
        assert env.traffic_signals[tls].yellow_time == round(yellow / 0.25)
    env.close()
    return checked, no_stage


@pytest.mark.parametrize("name", resco.NAMES)
def test_every_stage_sumo_rl_can_choose_shows_what_hils_controller_shows_for_its_pair(name: str) -> None:
    checked, no_stage = in_fresh_process(_stage_check, name)
    assert checked == sum(len(c.sequence) for c in resco.load(name).intersections.values())
    # the one program phase that is no stage: green only on links of no connection (module header)
    assert no_stage == (["cluster_1427494838_273472399 GGrrrrrrrr"] if name == "ingolstadt21" else [])


def _light(name: str, tls: str) -> Light:
    config = resco.load(name).intersections[tls]
    n = len(config.sequence)
    greens = ["".join("G" if k == i else "r" for k in range(n)) for i in range(n)]
    return Light.of(tls, config, greens, list(range(n)))


def test_the_minimum_green_given_is_the_longer_of_the_stage_pairs_phases_in_sumo_steps() -> None:
    light = _light("ingolstadt21", "1863241632")
    phases = light.config.phases
    for action, pair in zip(light.sequence, light.config.sequence, strict=True):
        assert light.min_green_steps(action) == max(phases[p].min_green for p in pair) * 4
    assert {light.min_green_steps(a) for a in light.sequence} == {28, 40}  # 7 s and 10 s stages
    assert light.yellow_steps == 20  # 5 s


def test_fixed_time_advances_through_the_configs_sequence_as_sumo_rl_stages() -> None:
    light = _light("grid4x4", "A0")
    bridge = _AgentBridge(light, FixedCycleAgent(light.config), lanes={})
    shown = light.sequence[0]
    seen = []
    for t in range(10):
        shown = bridge.act(10.0 * t, shown)
        seen.append(shown)
    n = len(light.sequence)
    assert seen == [light.sequence[(k + 1) % n] for k in range(10)]


def test_max_pressure_on_sumo_rl_chooses_the_stage_of_the_pair_hils_agent_chooses(monkeypatch) -> None:
    import libsumo

    light = _light("grid4x4", "A0")
    lanes = {p: ((f"in{p}",), (f"out{p}",)) for p in light.config.phase_numbers}
    halting = {f"in{p}": 0 for p in light.config.phase_numbers} | {f"out{p}": 0 for p in light.config.phase_numbers}
    monkeypatch.setattr(libsumo.lane, "getLastStepHaltingNumber", halting.__getitem__)
    bridge = _AgentBridge(light, MaxPressureAgent(light.config), lanes)
    for pair in light.config.pairs:
        halting.update(dict.fromkeys(halting, 0))
        for p in pair:
            halting[f"in{p}"] = 5  # the pair's movements have the most vehicles waiting
        for p in light.config.phase_numbers:  # and a phase of another pair a long queue and a full exit
            if p not in pair:
                halting[f"in{p}"], halting[f"out{p}"] = 9, 8
                break
        action = bridge.act(0.0, light.sequence[0])
        assert light.pair_of(action) == pair and action == light.action_of_pair[pair]


def test_a_peer_episode_gives_rescos_figures_from_its_tripinfo(tmp_path: Path) -> None:
    run = in_fresh_process(partial(episode, scenario="cologne1", duration=120.0, agent="max-pressure",
                                   tripinfo=str(tmp_path / "tripinfo.xml")), 0)
    assert run["steps"] == 12 and run["inserted"] > 0 and 0 < run["sumo_s"] < run["wall_s"]
    m = run["resco"]
    assert m.queue_steps == 12 and m.vehicles >= run["inserted"] and m.delay_s > 0
    assert (tmp_path / "tripinfo.xml").is_file()


def test_the_resco_bench_compares_both_sides_seed_by_seed(tmp_path: Path) -> None:
    out = tmp_path / "figures"
    done = subprocess.run([sys.executable, "-m", "hils", "bench", "resco", "--scenarios", "cologne1", "--seeds",
                           "0,1", "--duration", "120", "--out", str(out)], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    doc = json.loads((out / "resco.json").read_text())
    f = doc["resco"]
    assert f["seeds"] == [0, 1] and doc["machine"]["cpu"] and "single_agent=False" in f["peer"]
    sc = f["scenarios"]["cologne1"]
    assert sc["controllers"] == 1 and set(sc["runs"]) == {"hils", "hils_worker", "sumo_rl"}
    per_seed = {s: sc["runs"]["hils"][s]["wall_s"] / sc["runs"]["sumo_rl"][s]["wall_s"] for s in ("0", "1")}
    assert sc["hils_to_sumo_rl"]["wall"]["min"] == pytest.approx(min(per_seed.values()))
    for side in ("hils", "hils_worker", "sumo_rl"):
        for run in sc["runs"][side].values():
            assert run["steps"] == 12 and 0 < run["sumo_s"] < run["wall_s"] and run["inserted"] >= run["arrived"]
    # the same demand on both sides
    assert sc["runs"]["hils"]["0"]["inserted"] == pytest.approx(sc["runs"]["sumo_rl"]["0"]["inserted"], abs=3)
    assert "the peer: sumo-rl's SumoEnvironment(single_agent=False)" in done.stdout
