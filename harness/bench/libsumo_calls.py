"""What each side of ``hils bench resco`` asks SUMO: libsumo's calls per simulated hour, hils beside sumo-rl.

``python -m harness.bench.libsumo_calls [--scenario grid4x4] [--seed 0]`` runs one episode of each side as the bench
runs it (:func:`harness.bench.resco.hils_episode`, :func:`harness.reference.sumo_rl_peer.episode`: one simulated hour,
a seeded random policy) under :mod:`cProfile`, which counts every call of libsumo's C functions (the SWIG module
``libsumo._libsumo`` that both sides' calls end in, through libsumo's Python wrappers or not), and prints how many
each side made of each, start-up and episode together. Fewer calls are less of SUMO's time spent answering; what a
``simulationStep`` costs depends on the traffic alone.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
from collections import Counter

SIDES = ("hils", "sumo-rl")


def calls(side: str, scenario: str, seed: int, duration: float = 3600.0) -> Counter[str]:
    """libsumo's C functions that one episode of ``side`` (``duration`` simulated seconds) called, and how often
    (SWIG's own registrations left out)."""
    from harness.bench.resco import hils_episode
    from harness.reference.sumo_rl_peer import episode

    profile = cProfile.Profile()
    profile.enable()
    if side == "hils":
        hils_episode(seed, scenario=scenario, duration=duration)
    else:
        episode(seed, scenario=scenario, duration=duration)
    profile.disable()
    counted: Counter[str] = Counter()
    for (_, _, name), (_, calls_, *_) in pstats.Stats(profile).stats.items():  # type: ignore[attr-defined]
        if "_libsumo." in name and not name.endswith("swigregister>") and "swiginit" not in name:
            counted[name.split("_libsumo.", 1)[1].rstrip(">}")] += calls_
    return counted


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.bench.libsumo_calls", description=__doc__.split("\n\n")[0])
    from hils.protocol.resco import MAPS

    parser.add_argument("--scenario", default="grid4x4", choices=list(MAPS), help="a RESCO scenario (grid4x4)")
    parser.add_argument("--seed", type=int, default=0, help="the episode's seed (0)")
    args = parser.parse_args(argv)
    counted = {side: calls(side, args.scenario, args.seed) for side in SIDES}
    names = sorted(set().union(*counted.values()), key=lambda n: -max(c[n] for c in counted.values()))
    print(f"libsumo calls in one simulated hour of RESCO {args.scenario}, seed {args.seed}")
    print(f"{'call':<40}" + "".join(f"{side:>12}" for side in SIDES))
    for name in names:
        print(f"{name:<40}" + "".join(f"{counted[side][name]:>12,}" for side in SIDES))
    print(f"{'all':<40}" + "".join(f"{sum(counted[side].values()):>12,}" for side in SIDES))
    return 0


if __name__ == "__main__":
    sys.exit(main())
