"""Benchmarks over seeds: each side of a comparison once per seed, alternately, every run in a fresh process;
figures as medians with their spread.

Rules of this module
--------------------
- A benchmark that runs traffic measures several seeds (:data:`DEFAULT_SEEDS`, five), never one: the same
  demand under another seed is other traffic, which costs SUMO and the environment more or less to step (the
  single-intersection environment ran at parity with sumo-rl at seed 0 and took 1.28-1.33x its wall time at
  seeds 0-7).
- The sides of a seed run one after the other, in an order that turns from seed to seed (A B C, then B C A,
  ...: :func:`order`), so that a machine growing busier or quieter during a benchmark weighs on every side
  alike; each run is a fresh process (:func:`harness.bench.processes.in_fresh_process`: its own libsumo, imports and
  memory), as a user starts it.
- A side's figure is the median over the seeds with its spread (min-max and the interquartile range:
  :class:`Spread`). A comparison of two sides is their ratio per seed (the same seed, the same demand),
  summarised the same way: never the ratio of two medians.
- A report lists its seeds and the machine (:mod:`harness.bench.machine`) beside every run's own figures.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from harness.bench.processes import in_fresh_process

__all__ = [
    "DEFAULT_SEEDS", "Spread", "alternate", "compare_episodes", "episode_figures", "episode_table", "order",
    "ratio_line", "ratios", "seeds_option", "seeds_text", "time_sumo_steps",
]


#: The seeds a benchmark that runs traffic measures unless told otherwise.
DEFAULT_SEEDS = "0-4"

Run = Callable[[int], dict[str, Any]]


@dataclass(frozen=True, slots=True)
class Spread:
    """A figure over seeds: its median, min and max, and quartiles (``statistics.quantiles``, inclusive method)."""

    n: int
    median: float
    min: float
    max: float
    q1: float
    q3: float

    @classmethod
    def of(cls, values: Sequence[float]) -> Spread:
        if not values:
            raise ValueError("a spread over no values")
        ordered = sorted(values)
        q1, q3 = (ordered[0], ordered[0]) if len(ordered) == 1 else \
            statistics.quantiles(ordered, n=4, method="inclusive")[::2]
        return cls(len(ordered), statistics.median(ordered), ordered[0], ordered[-1], q1, q3)

    def text(self, digits: int = 2) -> str:
        """``median [min-max]``, as the consoles print a figure over seeds."""
        return f"{self.median:.{digits}f} [{self.min:.{digits}f}-{self.max:.{digits}f}]"

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def order(seeds: Sequence[int], sides: Sequence[str]) -> list[tuple[int, str]]:
    """Every (seed, side) once, seed after seed, the sides of each seed turned by one from the seed before."""
    n = len(sides)
    return [(seed, sides[(i + k) % n]) for i, seed in enumerate(seeds) for k in range(n)]


def alternate(seeds: Sequence[int], runs: Mapping[str, Run], *, progress: bool = True,
              fresh: Callable[..., Any] = in_fresh_process) -> dict[str, dict[int, dict[str, Any]]]:
    """Each side's ``run(seed)`` for every seed, in :func:`order`, each in a fresh process; per side, by seed, what
    it returned. A run must be picklable: a module's function, or a ``functools.partial`` of one with its other
    arguments given by keyword."""
    from tqdm import tqdm

    out: dict[str, dict[int, dict[str, Any]]] = {side: {} for side in runs}
    plan = order(seeds, list(runs))
    with tqdm(plan, unit="run", disable=None if progress else True, file=sys.stderr, leave=False) as bar:
        for seed, side in bar:
            bar.set_description(f"{side}, seed {seed}")
            out[side][seed] = fresh(runs[side], seed)
    return out


def ratios(numerator: Mapping[int, float], denominator: Mapping[int, float]) -> Spread:
    """The ratio of two sides seed by seed (the seeds both have), over the seeds."""
    common = [s for s in numerator if s in denominator]
    return Spread.of([numerator[s] / denominator[s] for s in common])


def episode_figures(runs: Mapping[int, Mapping[str, Any]], duration: float, controllers: int = 1) -> dict[str, Any]:
    """Figures of one side's episodes (each a mapping with ``wall_s``, ``sumo_s``, ``steps``, ``inserted`` and
    ``arrived``, and ``cpu_s`` when measured) of ``duration`` simulated seconds: per seed and over the seeds, wall
    seconds per simulated hour, of it SUMO's steps and the environment's own work (the rest), the CPU seconds the
    episode's process took per simulated hour beside them, own work per simulated controller-hour, steps per second,
    vehicles inserted and arrived."""
    hours = duration / 3600.0
    per_seed = {seed: {"wall_per_sim_hour_s": r["wall_s"] / hours,
                       **({"cpu_per_sim_hour_s": r["cpu_s"] / hours} if "cpu_s" in r else {}),
                       "sumo_per_sim_hour_s": r["sumo_s"] / hours,
                       "own_per_sim_hour_s": (r["wall_s"] - r["sumo_s"]) / hours,
                       "own_per_controller_hour_s": (r["wall_s"] - r["sumo_s"]) / (hours * controllers),
                       "steps_per_s": r["steps"] / r["wall_s"], "inserted": r["inserted"], "arrived": r["arrived"]}
                for seed, r in runs.items()}
    figures = next(iter(per_seed.values())).keys()
    return {"per_seed": per_seed,
            **{f: Spread.of([v[f] for v in per_seed.values()]).as_dict() for f in figures}}


def time_sumo_steps() -> list[float]:
    """From now on in this (fresh) process, the wall seconds libsumo's simulationStep takes are summed into the
    list returned: both environments step SUMO through it, so what is left of an episode's wall time is the
    environment's own work, whatever traffic its signals made."""
    from hils.sim.quiet_libsumo import libsumo

    total = [0.0]
    step = libsumo.simulationStep

    def timed(*args: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return step(*args)
        finally:
            total[0] += time.perf_counter() - t0

    # sumo-rl calls traci, which is libsumo itself (harness.reference.sumo_rl_peer.sumo_rl) or, where LIBSUMO_AS_TRACI
    # was set
    # before traci's first import, a module holding libsumo's functions as its own.
    for module in (libsumo, sys.modules.get("traci")):
        if module is not None and getattr(module, "simulationStep", None) is step:
            module.simulationStep = timed
    return total


def worker_usage(worker: Any) -> tuple[float, float]:
    """A hils environment's SUMO worker (:class:`hils.sim.worker.SumoProcess`, or None when SUMO steps in the
    environment's process): its CPU seconds so far and the seconds its SUMO steps took. An episode's CPU time is both
    processes', its SUMO part the worker's steps (:func:`time_sumo_steps` times those of this process)."""
    return worker.usage() if worker is not None else (0.0, 0.0)


#: What :func:`compare_episodes` compares, and the figure of :func:`episode_figures` each is the ratio of (the CPU
#: time where both sides measured it).
COMPARED = {"wall": "wall_per_sim_hour_s", "cpu": "cpu_per_sim_hour_s", "sumo": "sumo_per_sim_hour_s",
            "own": "own_per_sim_hour_s"}


def compare_episodes(numerator: Mapping[str, Any], denominator: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """Two sides' :func:`episode_figures` compared seed by seed: the ratio of their wall time, of SUMO's part and of
    their own work, over the seeds."""
    a, b = numerator["per_seed"], denominator["per_seed"]
    return {name: ratios({s: v[f] for s, v in a.items()}, {s: v[f] for s, v in b.items()}).as_dict()
            for name, f in COMPARED.items() if f in numerator and f in denominator}


def episode_table(sides: Mapping[str, Mapping[str, Any]], *, per_controller: bool = False) -> list[str]:
    """Console lines: per side (its label, its :func:`episode_figures`) median [min-max] over the seeds."""
    cpu = all("cpu_per_sim_hour_s" in f for f in sides.values())
    head = (f"  {'':22} {'steps/s':>17} {'wall s / sim h':>19}" + (f" {'CPU s / sim h':>19}" if cpu else "")
            + f" {'of it SUMO':>19} {'own work':>19}"
            + (f" {'own / controller-h':>19}" if per_controller else "") + f" {'inserted':>17} {'arrived':>17}")
    lines = [head]
    for label, f in sides.items():
        cells = [_spread(f["steps_per_s"], 1), *(_spread(f[k]) for k in (
            "wall_per_sim_hour_s", *(["cpu_per_sim_hour_s"] if cpu else []), "sumo_per_sim_hour_s",
            "own_per_sim_hour_s"))]
        if per_controller:
            cells.append(_spread(f["own_per_controller_hour_s"], 3))
        cells += [_spread(f["inserted"], 0), _spread(f["arrived"], 0)]
        widths = [17, 19, *([19] if cpu else []), 19, 19, *([19] if per_controller else []), 17, 17]
        lines.append(f"  {label:22} " + " ".join(f"{c:>{w}}" for c, w in zip(cells, widths, strict=True)))
    return lines


def ratio_line(label: str, compared: Mapping[str, Mapping[str, float]]) -> str:
    """One console line of :func:`compare_episodes`."""
    cpu = f"CPU {_spread(compared['cpu'])}, " if "cpu" in compared else ""
    return (f"  {label}, per seed: wall {_spread(compared['wall'])}, {cpu}SUMO {_spread(compared['sumo'])}, "
            f"own work {_spread(compared['own'])}")


def _spread(figure: Mapping[str, float], digits: int = 2) -> str:
    return Spread(**figure).text(digits)


def seeds_text(seeds: Sequence[int]) -> str:
    """Seeds as a command line takes them: ``0-7`` when consecutive, else ``0,3,7``."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


def seeds_option(parser: argparse.ArgumentParser, default: str = DEFAULT_SEEDS) -> None:
    """``--seeds`` of a benchmark: ranges and lists (``0-4``, ``0,3,7``)."""
    parser.add_argument("--seeds", type=_seeds, default=default, metavar="LIST",  # argparse converts the default
                        help=f"seeds, each side run once per seed, alternately, in fresh processes ({default}); "
                             "figures are medians with min-max over them")


def _seeds(text: str) -> list[int]:
    from hils.sweep.grid import SweepError, parse_seeds

    try:
        return parse_seeds(text)
    except SweepError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
