"""The closed loop: SUMO shows what the controller shows, never what the agent asked for.

A real HILS run (max-pressure selection, the middleware, the emulator, SUMO) with the simulation
watched step by step: the link indications SUMO shows equal the controller's signal state in the
signal cache mapped to links, and no vehicle leaves its approach on red.
"""

from __future__ import annotations

import libsumo

from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.protocol.ntcip import SignalState
from hils.run.testbed import RunSpec, run_spec
from hils.shell.events import Kind
from hils.sim.network import TLS_ID
from hils.sim.sumo import SumoSimulation

CFG = config_mod.load()


class Watched:
    """The SUMO simulation of the run (its one light), checked after every step."""

    def __init__(self, sim: SumoSimulation) -> None:
        self.sim = sim
        (self.light,) = sim.lights.values()
        self.lights = {TLS_ID: self}
        self.applied: SignalState | None = None
        self.mismatches: list[tuple[float, str, str]] = []
        self.steps = 0
        self.crossings = {"G": 0, "y": 0, "r": 0}
        self._last: dict[str, str] = {}
        pm = self.light.phase_map
        self._link_of = {(lk.from_lane, lk.to_lane.rsplit("_", 1)[0]): lk.index for lk in pm.links}
        self._incoming = sorted({lk.from_lane for lk in pm.links})

    def apply(self, state: SignalState) -> None:
        self.applied = state
        self.light.apply(state)

    def step(self) -> None:
        self.sim.step()
        self.steps += 1
        shown = self.light.indications()
        expected = self.light.phase_map.state_string(self.applied) if self.applied else shown
        if shown != expected:
            self.mismatches.append((self.sim.time, shown, expected))
        now = {v: lane for lane in self._incoming for v in libsumo.lane.getLastStepVehicleIDs(lane)}
        for vid, lane in self._last.items():
            if vid not in now:
                self.crossings[shown[self._link_of[(lane, libsumo.vehicle.getRoute(vid)[-1])]]] += 1
        self._last = now

    def advance(self, steps: int) -> None:
        for _ in range(steps):  # every step watched
            self.step()

    def traffic_state(self):
        return self.light.traffic_state()

    def queues(self):
        return self.light.queues()


def test_sumo_shows_the_controllers_state_and_nobody_crosses_on_red():
    sim = SumoSimulation(CFG, seed=5, end=400.0)
    sim.start()
    watched = Watched(sim)
    try:
        result = run_spec(RunSpec(CFG, ActionType.SELECTION, duration=400.0, seed=5, sumo=True),
                             simulation=watched)
    finally:
        sim.close()
    assert watched.steps == 400.0 / CFG.middleware.sumo_step
    assert watched.mismatches == []
    assert watched.crossings["r"] == 0, watched.crossings
    assert watched.crossings["G"] > 150, watched.crossings
    # The lights changed because the controller changed them, through several transitions.
    assert len([r for r in result.records if r["kind"] == Kind.TRANSITION_VERIFIED]) >= 10
