"""Safety and liveness of the controller model over random configs and random control SETs.

Every tick of every run is checked against what a conflict monitor and a
timing engineer would demand: no two conflicting phases shown together, every
green at least its minimum, every change to a conflicting green through the
full yellow and red clearance of the ending phase, and no flash. With calls
held constant and no holds, every called phase that is not omitted is served
within a bound derived from the timings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.controller import Controller, tenths
from hils.config import IntersectionConfig, from_dict
from hils.ntcip import ControlColumn, UnitFlashStatus

RING1, RING2 = (1, 2, 3, 4), (5, 6, 7, 8)
ALL_PHASES = frozenset(RING1 + RING2)
SETTINGS = settings(max_examples=60, deadline=None)


@st.composite
def timings(draw: st.DrawFn) -> dict[str, float]:
    min_green = draw(st.integers(1, 10))
    return {
        "min_green": min_green,
        "max_green": draw(st.integers(min_green, 30)),
        "yellow": draw(st.integers(30, 60)) / 10,
        "red_clear": draw(st.integers(5, 30)) / 10,
    }


@st.composite
def configs(draw: st.DrawFn) -> IntersectionConfig:
    """Dual-ring two-barrier eight-phase intersections with random barrier positions and timings."""
    k1, k2 = draw(st.integers(1, 3)), draw(st.integers(1, 3))
    barriers = [list(RING1[:k1] + RING2[:k2]), list(RING1[k1:] + RING2[k2:])]
    compatible = [[a, b] for group in barriers for a in RING1 for b in RING2 if a in group and b in group]
    if draw(st.booleans()):
        shared = draw(timings())
        phases = {str(p): dict(shared) for p in ALL_PHASES}
    else:
        phases = {str(p): draw(timings()) for p in ALL_PHASES}
    startup = draw(st.none() | st.sampled_from(compatible))
    for p in startup or ():
        phases[str(p)]["startup"] = "green"
    # The phase options, at random: passage (within the maximum), recalls, backup prevent, and at most
    # one dual-entry phase per ring and barrier group.
    for p in ALL_PHASES:
        ph = phases[str(p)] = dict(phases[str(p)])
        ph["passage"] = min(draw(st.sampled_from([0.0, 0.0, 0.5, 2.0])), ph["max_green"])
        ph["recall"] = draw(st.sampled_from(["none", "none", "none", "min", "max", "soft"]))
        ph["backup_prevent"] = draw(st.booleans())
    for ring in (RING1, RING2):
        for group in barriers:
            members = [p for p in ring if p in group]
            if members and draw(st.booleans()):
                phases[str(draw(st.sampled_from(members)))]["dual_entry"] = True
    raw = {
        "name": "random",
        "phases": phases,
        "structure": {
            "rings": [list(RING1), list(RING2)],
            "barriers": barriers,
            "sequence": [[RING1[0], RING2[0]], [RING1[-1], RING2[-1]]],
            "pairs": compatible,
        },
    }
    return from_dict(raw, "random.toml")


# Calls are listed twice: they are what the middleware SETs most, and what moves the controller.
SETTABLE = (ControlColumn.VEH_CALL, ControlColumn.VEH_CALL, ControlColumn.HOLD, ControlColumn.FORCE_OFF,
            ControlColumn.PHASE_OMIT)
phase_sets = st.frozensets(st.sampled_from(sorted(ALL_PHASES)))
operations = st.lists(
    st.one_of(st.tuples(st.just("tick"), st.integers(1, 400)),
              st.tuples(st.sampled_from(SETTABLE), phase_sets)),
    max_size=20,
)


@dataclass
class Monitor:
    """Checks every tick of a controller against the safety properties."""

    c: Controller
    green_since: dict[int, int] = field(default_factory=dict)
    yellow_since: dict[int, int] = field(default_factory=dict)
    clear_at: dict[int, int] = field(default_factory=dict)  # first tick a conflicting green may start
    shown: dict[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.shown = self._display()
        self.green_since = {p: 0 for p in self.c.greens}
        self.check_instant()

    def _display(self) -> dict[int, str]:
        c = self.c
        return {p: "G" if p in c.greens else "Y" if p in c.yellows else "r" for p in ALL_PHASES}

    def conflicting(self, a: int, b: int) -> bool:
        return a == b or not self.c.config.compatible(a, b)

    def check_instant(self) -> None:
        c = self.c
        assert c.flash_status is UnitFlashStatus.NOT_FLASH, f"flash at tick {c.tick}"
        assert c.greens | c.yellows | c.reds == ALL_PHASES
        assert not (c.greens & c.yellows or c.greens & c.reds or c.yellows & c.reds)
        lit = sorted(c.greens | c.yellows)
        for i, a in enumerate(lit):
            for b in lit[i + 1:]:
                assert not self.conflicting(a, b), f"phases {a} and {b} shown together at tick {c.tick}"

    def step(self, ticks: int = 1) -> None:
        for _ in range(ticks):
            self.c.step()
            self.observe()

    def observe(self) -> None:
        c, phases = self.c, self.c.config.phases
        now = self._display()
        t = c.tick
        self.check_instant()
        for p in ALL_PHASES:
            before, after = self.shown[p], now[p]
            if before == after:
                continue
            if before == "G":
                assert after == "Y", f"phase {p} went from green to {after} at tick {t}"
                self._check_crossing(p, t)
                served = t - self.green_since.pop(p)
                assert served >= tenths(phases[p].min_green), f"phase {p} green {served} ticks at tick {t}"
                self.yellow_since[p] = t
                self.clear_at[p] = t + tenths(phases[p].yellow) + tenths(phases[p].red_clear)
            elif before == "Y":
                assert after == "r", f"phase {p} went from yellow to {after} at tick {t}"
                timed = t - self.yellow_since.pop(p)
                assert timed >= tenths(phases[p].yellow), f"phase {p} yellow {timed} ticks at tick {t}"
                self.clear_at[p] = max(self.clear_at[p], t + tenths(phases[p].red_clear))
            else:
                assert after == "G", f"phase {p} went from red to {after} at tick {t}"
                for q, ready in self.clear_at.items():
                    if self.conflicting(p, q):
                        assert t >= ready, f"phase {p} green at tick {t} before {q} cleared at {ready}"
                self.green_since[p] = t
        self.shown = now

    def _check_crossing(self, p: int, t: int) -> None:
        """Both rings cross a barrier together: a green ending toward the other barrier group ends on the
        same tick as the other ring's green (a ring without a green, in red, does not hold it back)."""
        c = self.c
        ring = c.rings[c.config.ring_of(p) - 1]
        if ring.target is None or c.config.barrier_of(ring.target) == c.config.barrier_of(p):
            return
        for other in c.rings:
            if other is not ring:
                assert other.phase not in self.green_since or other.phase in c.yellows, (
                    f"phase {p} clears toward {ring.target} across the barrier at tick {t}, "
                    f"but {other.phase} stays green")

    def apply(self, operation: tuple[object, object]) -> None:
        kind, arg = operation
        if kind == "tick":
            self.step(arg)
        else:
            self.c.set_control(kind, arg)


def service_bound(config: IntersectionConfig) -> int:
    """Ticks within which any called, non-omitted phase must turn green when nothing is held.

    In one visit of a barrier group each ring serves each of its called phases at
    most once, each for at most its maximum green (timed from the conflicting
    demand) plus its clearance, and both rings leave the group together. A
    phase that just missed its turn waits for the rest of this visit and one
    visit of every group: at most one cycle of every phase at maximum, plus the
    green already running when the calls were placed.
    """
    per_phase = [tenths(ph.max_green) + tenths(ph.yellow) + tenths(ph.red_clear) for ph in config.phases.values()]
    return sum(per_phase) + max(per_phase) + 10


@SETTINGS
@given(config=configs(), ops=operations)
def test_safety_under_random_control(config: IntersectionConfig, ops: list[tuple[object, object]]) -> None:
    monitor = Monitor(Controller(config))
    for operation in ops:
        monitor.apply(operation)
    # Whatever the SETs left behind, the controller keeps obeying the rules for a cycle more.
    monitor.step(service_bound(config))


@SETTINGS
@given(config=configs(), prefix=operations, calls=phase_sets.filter(bool), omit=phase_sets,
       force_off=phase_sets)
def test_every_called_phase_is_served_within_the_bound(config: IntersectionConfig,
                                                       prefix: list[tuple[object, object]],
                                                       calls: frozenset[int], omit: frozenset[int],
                                                       force_off: frozenset[int]) -> None:
    c = Controller(config)
    monitor = Monitor(c)
    for operation in prefix:
        monitor.apply(operation)
    c.backup_time = 0
    c.set_control(ControlColumn.HOLD, ())
    c.set_control(ControlColumn.PHASE_OMIT, omit)
    c.set_control(ControlColumn.FORCE_OFF, force_off)
    c.set_control(ControlColumn.VEH_CALL, calls)
    waiting = set(calls - omit)
    bound = service_bound(config)
    # Two bounds: every called phase is served in the first, and no omitted one starts in either.
    for elapsed in range(1, 2 * bound + 1):
        before = c.greens
        monitor.step()
        assert not (c.greens - before) & omit, f"omitted phase started green at tick {c.tick}"
        waiting -= c.greens
        if elapsed == bound:
            assert not waiting, f"phases {sorted(waiting)} not served within {bound} ticks"


@SETTINGS
@given(config=configs(), calls=phase_sets.filter(bool))
def test_a_phase_with_hold_and_a_conflicting_call_never_ends(config: IntersectionConfig,
                                                             calls: frozenset[int]) -> None:
    c = Controller(config)
    monitor = Monitor(c)
    c.backup_time = 0
    c.set_control(ControlColumn.VEH_CALL, calls)
    monitor.step(service_bound(config))
    held = c.greens
    c.set_control(ControlColumn.HOLD, held)
    monitor.step(service_bound(config))
    assert held <= c.greens
