"""`hils bench overhead`: the wall time of the full loop over bare SUMO stepping the very same traffic.

The full loop is the default run (four-leg, max-pressure every 10 s, SUMO at 0.25 s steps, 10 Hz polling, the
emulator, the event log written to a file) in virtual time. Its floor is libsumo alone showing, step for step,
the signal states the loop showed: the same seed gives the same vehicles, and equal departed and arrived counts
check that the traffic is the same. Seed by seed (:mod:`harness.bench.seeds`), every run in a fresh process, the
floor right after the loop it replays; the ratio is taken per seed and reported as its median and spread.
``--instructions`` counts both sides' instructions under valgrind's callgrind (:mod:`harness.bench.overhead_probe`),
which a busy machine does not change.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

from harness.bench.processes import in_fresh_process
from harness.bench.seeds import Spread, order, ratios
from hils.control.actions import ActionType
from hils.protocol import config as config_mod
from hils.run.testbed import RunSpec, run_spec


class _Recording:
    """A SUMO simulation of one intersection that notes, step by step, each change of the light's state string it
    was given.

    Only changes are noted (a few hundred per hour), so the recording costs the measured run nothing
    on the steps where the controller's indications stay as they are."""

    def __init__(self, sim: Any) -> None:
        self.sim = sim
        self.steps = 0
        self.changes: list[tuple[int, str]] = []
        self.lights = {name: _RecordedLight(light, self) for name, light in sim.lights.items()}

    def step(self) -> Any:
        self.steps += 1
        return self.sim.step()

    def advance(self, steps: int) -> None:
        self.steps += steps
        self.sim.advance(steps)


class _RecordedLight:
    """A light of a :class:`_Recording`: what it is given to show goes to the recording when it changes SUMO's."""

    def __init__(self, light: Any, recording: _Recording) -> None:
        self.light, self.recording = light, recording

    def apply(self, state: Any) -> None:
        if self.light.apply(state):
            self.recording.changes.append((self.recording.steps, self.light.indications()))

    def traffic_state(self) -> Any:
        return self.light.traffic_state()

    def queues(self) -> Any:
        return self.light.queues()


def _replay(cfg: Any, seed: int, duration: float, changes: list[tuple[int, str]]) -> tuple[float, Any]:
    """Bare libsumo stepping the same scenario and seed, showing the recorded state strings at the same
    steps: the same-traffic floor. Between two changes SUMO steps in one call (to the next change's
    time), as cheaply as libsumo allows. Returns the wall seconds of the stepping and SUMO's end figures."""
    from hils.sim.quiet_libsumo import libsumo
    from hils.sim.sumo import SumoSimulation, step_on

    sim = SumoSimulation(cfg, seed=seed, end=duration)
    with sim:
        steps = round(duration / sim.step_length)
        (tls,) = sim.lights
        show, length = libsumo.trafficlight.setRedYellowGreenState, sim.step_length
        shown = [(k, text) for k, text in changes if k < steps]
        begins = [0, *(k for k, _ in shown)]
        ends = [*begins[1:], steps]
        texts = [None, *(text for _, text in shown)]
        t0 = time.perf_counter()
        for text, begin, end in zip(texts, begins, ends, strict=True):
            if text is not None:
                show(tls, text)
            if end > begin:
                step_on(end - begin, length)
        wall = time.perf_counter() - t0
        return wall, sim.summary()


def record_full_loop(cfg: Any, seed: int, duration: float) -> tuple[float, list[tuple[int, str]], Any]:
    """The benchmark's full loop (four-leg, max-pressure, SUMO, event log to a file): its wall seconds, the
    signal states it showed step by step (for :func:`_replay`) and SUMO's end figures."""
    from hils.sim.sumo import SumoSimulation

    sim = SumoSimulation(cfg, seed=seed, end=duration)
    sim.start()
    recording = _Recording(sim)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            spec = RunSpec(cfg, ActionType.SELECTION, duration=duration, seed=seed, sumo=True,
                           log_path=Path(tmp) / "events.jsonl")
            wall = run_spec(spec, simulation=recording).wall_s
        return wall, recording.changes, sim.summary()
    finally:
        sim.close()


def full_loop_run(seed: int, *, duration: float) -> dict[str, Any]:
    """One side of a seed: the full loop (:func:`record_full_loop`), with the states it showed for the floor."""
    wall, changes, traffic = record_full_loop(config_mod.load(), seed, duration)
    return {"wall_s": wall, "changes": changes, "departed": traffic.departed, "arrived": traffic.arrived}


def floor_run(seed: int, *, duration: float, changes: list[tuple[int, str]]) -> dict[str, Any]:
    """The same-traffic floor of a seed: bare libsumo replaying ``changes`` (:func:`_replay`)."""
    wall, traffic = _replay(config_mod.load(), seed, duration, [tuple(c) for c in changes])
    return {"wall_s": wall, "departed": traffic.departed, "arrived": traffic.arrived}


def fixed_cycle_run(seed: int, *, duration: float) -> dict[str, Any]:
    """For the record: libsumo running the config's fixed cycle at maximum green itself (other traffic)."""
    from hils.sim.sumo import time_bare_sumo

    return {"wall_s": time_bare_sumo(duration, seed=seed, config=config_mod.load())}


def measure_overhead(duration: float, seeds: Sequence[int], *, progress: bool = True,
                     fresh: Callable[..., Any] = in_fresh_process) -> dict[str, Any]:
    """Per seed, each in a fresh process: the full loop, then bare libsumo replaying the very signal states the loop
    showed (same vehicles, same traffic), and, for the record, libsumo running the config's fixed cycle at maximum
    green (other traffic: the comparison this benchmark used to make); the loop and its floor, and the fixed cycle,
    take turns to go first from seed to seed. Every run, medians and spread, and the ratios seed by seed."""
    from tqdm import tqdm

    runs: dict[str, dict[int, dict[str, Any]]] = {"hils": {}, "floor": {}, "fixed_cycle": {}}
    with tqdm(order(seeds, ["loop", "fixed_cycle"]), unit="run", disable=None if progress else True,
              file=sys.stderr, leave=False) as bar:
        for seed, side in bar:
            bar.set_description(f"{side}, seed {seed}")
            if side == "fixed_cycle":
                runs["fixed_cycle"][seed] = fresh(partial(fixed_cycle_run, duration=duration), seed)
                continue
            full = fresh(partial(full_loop_run, duration=duration), seed)
            changes = full.pop("changes")
            runs["floor"][seed] = fresh(partial(floor_run, duration=duration, changes=changes), seed)
            runs["hils"][seed] = {**full, "signal_changes": len(changes)}
    wall = {side: {seed: r["wall_s"] for seed, r in by_seed.items()} for side, by_seed in runs.items()}
    same = {seed: (runs["hils"][seed]["departed"], runs["hils"][seed]["arrived"])
            == (runs["floor"][seed]["departed"], runs["floor"][seed]["arrived"]) for seed in seeds}
    return {"duration_s": duration, "seeds": list(seeds), "runs": runs, "same_traffic": all(same.values()),
            "same_traffic_per_seed": same,
            **{f"{side}_s": Spread.of(list(w.values())).as_dict() for side, w in wall.items()},
            "ratio": ratios(wall["hils"], wall["floor"]).as_dict(),
            "ratio_vs_fixed_cycle_at_max_green": ratios(wall["hils"], wall["fixed_cycle"]).as_dict()}


def measure_instructions(duration: float, warm: float = 10.0) -> dict[str, Any]:
    """Instructions of the full loop and of its same-traffic floor per ``duration`` simulated seconds, each
    counted by callgrind in a process of its own, less the same process run for ``warm`` s (start-up out)."""
    counts: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        changes = Path(tmp) / "changes.json"
        for seconds in (duration, warm):
            for side in ("hils", "floor"):  # the floor replays what the loop just showed
                counts[f"{side}_{seconds:g}"] = _callgrind(["-m", "harness.bench.overhead_probe", side, str(seconds),
                                                            str(changes)])
    hils = counts[f"hils_{duration:g}"] - counts[f"hils_{warm:g}"]
    floor = counts[f"floor_{duration:g}"] - counts[f"floor_{warm:g}"]
    return {"duration_s": duration, "warm_s": warm, "counts": counts, "hils_instructions": hils,
            "floor_instructions": floor, "ratio": hils / floor}


def _callgrind(args: list[str]) -> float:
    """Instructions a Python process executes, as valgrind's callgrind counts them (its 'Collected' line)."""
    done = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable, *args],
                          capture_output=True, text=True, check=False)
    found = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        raise SystemExit(f"hils bench overhead --instructions: valgrind failed ({done.returncode}): "
                         f"{done.stderr.strip()[-300:]}")
    return float(found[1])
