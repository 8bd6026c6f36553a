"""Virtual time at the speed of SUMO changes no result: the fast path (the event-driven controller, polls and
read-backs that cannot see a change left out, SUMO in stretches) runs exactly the reference, ``fast_path=False``
(every tick stepped, every poll sent, every SUMO step taken alone).

The two runs share seed, agent and traffic; their event logs must be equal record for record, apart
from the wall-clock stamps and the per-poll bookkeeping (``poll`` records are compared on their own:
both log a record when the state seen changes, at the same poll), and their traffic figures equal.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Any

import pytest

from emulator.inprocess import VirtualTarget
from harness.faults.inject import DatagramLoss, FaultTarget, Window
from hils import Testbed
from hils.shell.events import Kind


def run(*, fast_path: bool, seconds: float, agent: str | None, action_type: str, seed: int, sumo: bool
        ) -> tuple[list[dict[str, Any]], Any, VirtualTarget]:
    with Testbed(action_type=action_type, sumo=sumo, seed=seed, duration=seconds, agent=agent,
                 fast_path=fast_path) as tb:
        tb.reset()
        tb.run()
        return tb.records, tb.traffic, tb.target


def comparable(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k not in ("wall_ns", "polls")} for r in records]


@pytest.mark.parametrize(("agent", "action_type", "seed"), [
    (None, "selection", 3),  # max-pressure
    ("fixed-cycle", "switch", 1),
    (None, "duration", 2),  # queue-proportional: holds of the served green
    ("actuated", "selection", 4),  # no commands: the controller on its detectors, SET every change
])
def test_the_elided_run_is_the_polled_run_with_sumo(agent: str | None, action_type: str, seed: int) -> None:
    reference, ref_traffic, _ = run(fast_path=False, seconds=400.0, agent=agent, action_type=action_type, seed=seed,
                                    sumo=True)
    fast, traffic, target = run(fast_path=True, seconds=400.0, agent=agent, action_type=action_type, seed=seed,
                                sumo=True)
    assert comparable(fast) == comparable(reference)
    assert traffic == ref_traffic
    polls, ref_polls = fast[-1]["polls"], reference[-1]["polls"]
    assert polls["polls"] == ref_polls["polls"] == 4000 and ref_polls["elided"] == 0
    assert polls["elided"] > 0.8 * polls["polls"], "most polls could not see a change"
    assert target.clock.steps < 0.3 * 4000, "most ticks were quiet"


def test_the_elided_run_is_the_polled_run_without_traffic() -> None:
    reference, _, _ = run(fast_path=False, seconds=300.0, agent="random", action_type="selection", seed=7, sumo=False)
    fast, _, _ = run(fast_path=True, seconds=300.0, agent="random", action_type="selection", seed=7, sumo=False)
    assert comparable(fast) == comparable(reference)
    # One poll record per change of what the polls saw, the first being the start-up read.
    changes = [r for r in fast if r["kind"] == Kind.POLL]
    assert changes[0]["poll_id"] == 0
    assert all((a["greens"], a["yellows"]) != (b["greens"], b["yellows"]) for a, b in pairwise(changes))


def test_faults_draw_on_every_poll_in_their_window() -> None:
    """A fault in the request path sees every poll while it may act: polls are left out only outside its window,
    and the run is the reference's record for record."""
    def target_with(loss: DatagramLoss) -> Any:
        def target(env: Any, config: Any, *, seed: int, fast_path: bool, hires: bool) -> FaultTarget:
            return FaultTarget(env, config, seed=seed, faults=[loss], fast_path=fast_path, hires=hires)
        return target

    runs = {}
    for fast_path in (True, False):
        loss = DatagramLoss("loss", probability=0.1, window=Window(50.0, 60.0), seed=1)
        with Testbed(target=target_with(loss), seed=1, duration=120.0, agent="random", fast_path=fast_path) as tb:
            tb.reset()
            tb.run()
            runs[fast_path] = (tb.records, loss.fired)
    (fast, fired), (reference, ref_fired) = runs[True], runs[False]
    assert comparable(fast) == comparable(reference) and fired == ref_fired > 0
    counts, ref_counts = fast[-1]["polls"], reference[-1]["polls"]
    assert counts["polls"] == ref_counts["polls"] == 1200 and counts["failed"] == ref_counts["failed"] > 0
    assert counts["elided"] > 900 and ref_counts["elided"] == 0
    in_window = [r for r in fast if r["kind"] == Kind.POLL_FAILED]
    assert in_window and all(50.0 <= r["t"] <= 60.0 + 1.0 for r in in_window)


class CountingSurface:
    """The emulator's surface, counting the GETs that read the control objects back."""

    def __init__(self, inner: Any, oid: Any) -> None:
        self.inner, self.oid, self.read_backs = inner, oid, 0

    def get_many(self, oids: Any) -> Any:
        self.read_backs += self.oid in oids
        return self.inner.get_many(oids)

    def set_many(self, varbinds: Any) -> None:
        self.inner.set_many(varbinds)


@pytest.mark.parametrize("fast_path", [False, True])
def test_read_backs_that_cannot_see_a_change_are_not_sent(fast_path: bool) -> None:
    """Only a write of a control object besides VehCall can give one phases: with a change feed the read-back
    sleeps from the first that finds them ours, commands and keepalives going on; every 2 s without one."""
    from hils.protocol.ntcip import ControlColumn, control_oid
    from hils.shell.middleware import READBACK_PERIOD

    hold = control_oid(ControlColumn.HOLD, 1)
    surfaces: list[CountingSurface] = []

    def target(env: Any, config: Any, *, seed: int, fast_path: bool, hires: bool) -> VirtualTarget:
        t = VirtualTarget(env, config, seed=seed, fast_path=fast_path, hires=hires)
        surfaces.append(CountingSurface(t.surface, hold))
        t.surface = surfaces[-1]
        return t

    with Testbed(target=target, seed=3, duration=300.0, agent="random", fast_path=fast_path) as tb:
        tb.reset()
        tb.run()
        assert len([r for r in tb.records if r["kind"] == Kind.SET_ANSWERED]) > 20
    # the start-up read, then the first read-back (finding them ours); without a feed every 2 s
    expected = 2 if fast_path else pytest.approx(1 + 300.0 / READBACK_PERIOD, abs=2)
    assert surfaces[0].read_backs == expected


def test_a_write_of_a_control_object_moves_the_controls_counter_and_the_controllers_steps_do_not() -> None:
    """What the read-back sleeps on: a SET of a control object (VehCall or any other) and a bump move
    ``controls``; the controller's own steps (serving the call, clearing a force-off) leave it alone."""
    import simpy

    from hils.protocol.config import load
    from hils.protocol.ntcip import ControlColumn, control_oid

    env = simpy.Environment()
    target = VirtualTarget(env, load(), seed=0)
    clock, surface = target.clock, target.surface
    controls, version = clock.controls, clock.version
    surface.set_many([(control_oid(ControlColumn.VEH_CALL, 1), 0b1000_1000)])
    assert clock.controls == controls + 1
    env.run(until=30.0)  # the call served: intervals change, the status moves
    assert clock.version > version and clock.controls == controls + 1
    surface.set_many([(control_oid(ControlColumn.HOLD, 1), 0b10)])
    assert clock.controls == controls + 2
    clock.bump()
    assert clock.controls == controls + 3


def test_someone_elses_call_is_seen_on_the_fast_path_as_on_the_reference() -> None:
    """A VehCall written by someone else (here: straight into the emulator) is a foreign_control TIMEOUT at the
    next read-back, on the fast path too: the read-back sleeps through the run's own SETs, not through that one."""
    from hils.protocol.ntcip import ControlColumn, control_oid

    runs = {}
    for fast_path in (True, False):
        def other_manager(tb: Testbed) -> None:
            def write() -> Any:
                yield tb.env.timeout(33.3)
                tb.target.surface.set_many([(control_oid(ControlColumn.VEH_CALL, 1), 0b0100_0100)])
            tb.env.process(write())

        with Testbed(seed=5, duration=60.0, agent="random", recover_after=None, fast_path=fast_path,
                     on_reset=other_manager) as tb:
            tb.reset()
            tb.run()
            runs[fast_path] = tb.records
    fast, reference = runs[True], runs[False]
    assert comparable(fast) == comparable(reference)
    (entered,) = [r for r in fast if r["kind"] == Kind.TIMEOUT_ENTERED]
    assert entered["reason"] == "foreign_control" and "phaseControlGroupVehCall on phases [3, 7]" in entered["detail"]
    assert 33.3 < entered["t"] <= 33.3 + 2.1


class SignalGets:
    """The emulator's surface, noting when a GET of the signal state reached it."""

    def __init__(self, inner: Any, oids: Any) -> None:
        self.inner, self.oids, self.times = inner, tuple(oids), []
        self.env: Any = None

    def get_many(self, oids: Any) -> Any:
        if tuple(oids) == self.oids:
            self.times.append(self.env.now)
        return self.inner.get_many(oids)

    def set_many(self, varbinds: Any) -> None:
        self.inner.set_many(varbinds)


def test_a_set_of_ours_sends_no_poll_and_counts_it_answered(paper_config) -> None:
    """A SET changes no answer of a poll by itself (only the controller's next step may): a keepalive re-SETting the
    call of a resting controller sends no GET of the signal state at the poll after it (the controller's step that
    takes the SET in may send one later), and that poll is counted as answered, so that run_ended's counts are what
    they were."""
    from hils.protocol.ntcip import signal_oids

    cfg = paper_config.with_middleware(backup_time=15)  # a keepalive every 5 s
    surfaces: list[SignalGets] = []

    def target(env: Any, config: Any, *, seed: int, fast_path: bool, hires: bool) -> VirtualTarget:
        t = VirtualTarget(env, config, seed=seed, fast_path=fast_path, hires=hires)
        surfaces.append(SignalGets(t.surface, signal_oids(config.groups)))
        surfaces[-1].env = env
        t.surface = surfaces[-1]
        return t

    tb = Testbed(cfg, action_type="selection", sumo=False, target=target)
    tb.reset()
    tb.run_for(1.0)
    tb.middleware.submit((4, 8))
    tb.run_for(30.0)  # served, then resting in 4+8: nothing calls another phase
    (verified,) = tb.events.of(Kind.TRANSITION_VERIFIED)
    gets, before = len(surfaces[0].times), tb.middleware.poll_counts
    tb.run_for(60.0)
    keepalives = [r for r in tb.events.of(Kind.SET_SENT) if r["purpose"] == "keepalive" and r["t"] > tb.now - 60.0]
    after = tb.middleware.poll_counts
    tb.close()
    assert len(keepalives) >= 10 and verified["command"] == (4, 8)
    period = cfg.middleware.poll_period
    woken = [t for t in surfaces[0].times[gets:] if any(0 <= t - r["t"] < period for r in keepalives)]
    assert woken == [], "a keepalive SET sent the next poll"
    sent = len(surfaces[0].times) - gets
    assert after["answered"] - before["answered"] == sent + len(keepalives), "each counted as the poll it once sent"
    assert after["polls"] - before["polls"] == 600 == (after["answered"] - before["answered"]
                                                       + after["elided"] - before["elided"])


def test_a_command_a_poll_of_the_state_shown_verifies_still_sends_that_poll(paper_config) -> None:
    """The SET of a duration command for the pair already green is no reason to leave the next poll out: its answer
    verifies the command (:meth:`hils.control.manager.Manager.counts_only` is False), as on the reference."""
    holds = {}
    for fast_path in (True, False):
        tb = Testbed(paper_config, action_type="duration", sumo=False, fast_path=fast_path)
        tb.reset()
        tb.run_for(1.0)
        tb.middleware.manager.position = paper_config.sequence.index((1, 5))  # the next pair is 2+6, green now
        tb.middleware.submit(0.0)
        tb.run_for(10.0)
        holds[fast_path] = [(r["t"], r["hold_s"]) for r in tb.events.of(Kind.TRANSITION_VERIFIED)]
        tb.close()
    assert holds[True] == holds[False] and holds[True][0][1] <= 0.1 + 1e-9
