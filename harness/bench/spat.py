"""`hils bench spat`: does every indication change come within the window the controller announced for it?

The controller's SPaT (:meth:`emulator.model.controller.Controller.spat`) gives per phase and overlap the earliest
and latest tick of its next change. Its property test holds it over random configs and inputs; this measures it
where a user meets it: an hour of the shipped four-leg with SUMO's traffic, under the controller's own actuated
operation, the city's coordinated pattern and the max-pressure agent's calls, over several seeds. A watcher reads
the controller half way between every two ticks (every tick is stepped: no fast path), as a connected vehicle
reads each SPaT, and at each change checks it against what was announced: no sooner than every earliest announced
since the signal's last change, no later than the latest announced the tick before (the one a vehicle holds when
the change comes; a latest holds while the inputs stand, and SUMO's detectors and the agent's calls change them
between two announcements, which the figure counts as any miss). The figures: the share of changes inside (goal
100 %) and the share that had a finite latest announced the tick before, so that the first is not hollow.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import simpy

from emulator.inprocess import VirtualTarget
from emulator.model.controller import TICK
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.sim.network import data_path

#: Each operation: the config it runs and the agent that drives it (``hils run --agent``).
OPERATIONS = {"actuated": ("four_leg_city.toml", "actuated"), "coordinated": ("four_leg_city.toml", "coordinated"),
              "max-pressure": ("four_leg.toml", "max-pressure")}


@dataclass(frozen=True, slots=True)
class Share:
    operation: str
    seconds: float
    seed: int
    changes: int  # indication changes of phases and overlaps
    inside: int  # of them, after every earliest since the signal's last change and by the latest of the tick before
    bounded: int  # of them, with a finite latest announced the tick before (the rest had only an earliest)
    first_outside: str | None  # the first change outside its window, said

    @property
    def percent(self) -> float:
        return 100.0 * self.inside / self.changes if self.changes else math.nan

    @property
    def bounded_percent(self) -> float:
        return 100.0 * self.bounded / self.changes if self.changes else math.nan


class _Watcher:
    """Checks one controller's changes against its announcements, half way between its ticks."""

    def __init__(self, target: VirtualTarget) -> None:
        self.c = target.controller
        # per signal: the latest earliest since its change, and the latest announced at the last look
        self.window: dict[tuple[str, int], tuple[float, float]] = {}
        self.before: dict[tuple[str, int], str] = {}
        self.changes = self.inside = self.bounded = 0
        self.first_outside: str | None = None
        target.env.process(self._watch(target.env, target.tick_phase + TICK / 2))

    def _watch(self, env: simpy.Environment, phase: float):
        yield env.timeout(phase)
        while True:
            self._look()
            yield env.timeout(TICK)

    def _look(self) -> None:
        c = self.c
        spat = c.spat()
        for s in spat:
            key = (s.kind, s.number)
            was = self.before.get(key)
            if was is not None and was != s.indication:
                soonest, latest = self.window.pop(key, (-math.inf, math.inf))
                self.changes += 1
                self.bounded += latest < math.inf
                if soonest <= c.tick <= latest:
                    self.inside += 1
                elif self.first_outside is None:
                    self.first_outside = (f"{s.kind} {s.number} {was} -> {s.indication} at tick {c.tick}, announced "
                                          f"[{soonest}, {latest}]")
            self.before[key] = s.indication
            soonest = math.inf if s.earliest is None else c.tick + s.earliest
            latest = math.inf if s.latest is None else c.tick + s.latest
            prior = self.window.get(key, (-math.inf, math.inf))
            self.window[key] = (max(prior[0], soonest), latest)


def measure(operation: str, seconds: float = 3600.0, seed: int = 0) -> Share:
    """One run of ``operation`` (:data:`OPERATIONS`) for ``seconds`` with SUMO, watched."""
    from hils.run.testbed import Testbed

    name, agent = OPERATIONS[operation]
    watchers: list[_Watcher] = []

    def factory(env: simpy.Environment, config: IntersectionConfig, *, seed: int, fast_path: bool,
                hires: bool) -> VirtualTarget:
        target = VirtualTarget(env, config, seed=seed, fast_path=False, hires=False)
        watchers.append(_Watcher(target))
        return target

    with Testbed(config_mod.load(data_path(name)), target=factory, sumo=True, seed=seed, agent=agent,
                 duration=seconds, measure=False) as tb:
        tb.reset(seed=seed)
        tb.run()
    (w,) = watchers
    return Share(operation, seconds, seed, w.changes, w.inside, w.bounded, w.first_outside)


def report(shares: list[Share]) -> tuple[str, dict[str, Any]]:
    """The console table and the figures of ``shares``: each run, then each operation over its seeds."""
    head = (f"{'operation':14} {'seed':>6} {'seconds':>8} {'changes':>8} {'inside':>8} {'inside %':>9} "
            f"{'with latest':>11} {'latest %':>9}")
    lines = [head]
    for s in shares:
        lines.append(f"{s.operation:14} {s.seed:6d} {s.seconds:8.0f} {s.changes:8d} {s.inside:8d} {s.percent:9.2f} "
                     f"{s.bounded:11d} {s.bounded_percent:9.2f}")
        if s.first_outside:
            lines.append(f"  first outside: {s.first_outside}")
    totals = {}
    for operation in dict.fromkeys(s.operation for s in shares):
        runs = [s for s in shares if s.operation == operation]
        changes = sum(s.changes for s in runs)
        inside, bounded = sum(s.inside for s in runs), sum(s.bounded for s in runs)
        totals[operation] = {"seeds": [s.seed for s in runs], "changes": changes, "inside": inside,
                             "inside_percent": 100.0 * inside / changes if changes else math.nan,
                             "bounded": bounded, "bounded_percent": 100.0 * bounded / changes if changes else math.nan}
        lines.append(f"{operation:14} {'all':>6} {sum(s.seconds for s in runs):8.0f} {changes:8d} {inside:8d} "
                     f"{totals[operation]['inside_percent']:9.2f} {bounded:11d} "
                     f"{totals[operation]['bounded_percent']:9.2f}")
    lines.append("goal: 100 % of indication changes inside the window announced for them (inside %), with a finite "
                 "latest announced for as many as the controller's timers bound (latest %)")
    runs = [asdict(s) | {"percent": s.percent, "bounded_percent": s.bounded_percent} for s in shares]
    return "\n".join(lines), {"spat": runs, "operations": totals}
