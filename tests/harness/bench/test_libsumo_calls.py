"""The count of what each side of the RESCO bench asks SUMO."""

from __future__ import annotations

from harness.bench.libsumo_calls import calls


def test_every_libsumo_call_of_an_episode_is_counted_on_both_sides() -> None:
    """A minute of grid4x4 at 0.25 s steps: sumo-rl steps SUMO once per step, 240 times; hils steps it in stretches
    (fewer calls, the same simulated minute) and shows its sixteen lights through setRedYellowGreenState."""
    sumo_rl = calls("sumo-rl", "grid4x4", 0, duration=60.0)
    hils = calls("hils", "grid4x4", 0, duration=60.0)
    assert sumo_rl["simulation_step"] == 240
    assert 0 < hils["simulation_step"] < 240
    assert hils["trafficlight_setRedYellowGreenState"] >= 16
    assert not any(name.endswith("swigregister") for name in (*hils, *sumo_rl))
