"""The differential's judge can fail (issue 35, item 5): faults planted in our controller are reported as its own.

Each fault is planted from here, by a subclass of the controller that drives its public control objects
(NTCIP 1202's phaseControlGroup columns) behind the judge's back, never by editing the model: a controller that
never serves phase 8 skips it while it is called; one blind to the calls across the barrier for its first 25 s
backs into an earlier phase while one waits there; one that holds phase 2 green until 40 s keeps it past its
maximum. The judge sees only the calls of the sequence and the colours shown, as for the real model. The same
sequences given the real model have no model fault, so what is reported comes from the planted fault.
"""

from __future__ import annotations

import dataclasses

import pytest

from emulator.model.controller import Controller
from harness.reference.nema import EXAMPLES, CallSequence, Model, differential, seconds
from harness.reference.nema_rules import (
    BACKED_WITH_CALL_ACROSS,
    CONDITIONAL_SERVICE,
    HELD_PAST_MAXIMUM,
    SKIPPED,
    DifferenceClass,
    Side,
    Verdict,
)
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import ControlColumn


class NeverServes8(Controller):
    """Skips phase 8 whenever it is called (omits it for good)."""

    def __init__(self, config: IntersectionConfig) -> None:
        super().__init__(config)
        self.set_control(ControlColumn.PHASE_OMIT, {8})


class BlindAcrossTheBarrier(Controller):
    """Backs as Naztec's controllers do (``backup_prevent`` off) but does not see the calls on 3, 4, 7 and 8 for its
    first 25 s: it backs as if nothing waited across."""

    def __init__(self, config: IntersectionConfig) -> None:
        super().__init__(dataclasses.replace(config, phases={p: dataclasses.replace(ph, backup_prevent=False)
                                                             for p, ph in config.phases.items()}))
        self.set_control(ControlColumn.PHASE_OMIT, {3, 4, 7, 8})

    def step(self) -> None:
        if self.tick == 250:
            self.set_control(ControlColumn.PHASE_OMIT, ())
        super().step()


class Holds2(Controller):
    """Holds phase 2 green until 40 s, whatever waits."""

    def __init__(self, config: IntersectionConfig) -> None:
        super().__init__(config)
        self.set_control(ControlColumn.HOLD, {2})

    def step(self) -> None:
        if self.tick == 400:
            self.set_control(ControlColumn.HOLD, ())
        super().step()


MUTANTS: dict[str, tuple[Model, CallSequence, int, DifferenceClass]] = {
    # 3+7 green; 1, 5 and 8 called: 8 (after 7, before the barrier) is skipped. SUMO skips it too, so only the
    # audit of our own greens can see it
    "skipped phase": (NeverServes8, *EXAMPLES[SKIPPED][1:], SKIPPED),
    # 2+6 green; 6's call drops as 4 (across) and 5 are called: ring 2 backs from 6 into 5, which the model does
    # not do (the paper config does not set conditional service); SUMO backs there too (a setting it has)
    "backing": (BlindAcrossTheBarrier, *EXAMPLES[CONDITIONAL_SERVICE][1:], BACKED_WITH_CALL_ACROSS),
    # 2+6 green, 4 called from 10 s: both max out at 30 s; 2 is held to 40 s, 6 waits at the barrier for it
    "green past its maximum": (Holds2, seconds((0, [2, 6]), (10, [2, 4, 6]), (50, [])), 600, HELD_PAST_MAXIMUM),
}


@pytest.mark.parametrize("name", list(MUTANTS))
def test_a_fault_planted_in_the_model_is_the_models_fault(paper_config: IntersectionConfig, name: str) -> None:
    model, calls, ticks, kind = MUTANTS[name]
    assert not differential(paper_config, calls, ticks).model_faults  # the real model is not at fault here
    result = differential(paper_config, calls, ticks, model)
    faults = result.model_faults
    assert faults, f"{name}: the judge passed the planted fault\n{result.comparison.report(calls)}"
    assert any(f.kind is kind and f.breaker is Side.OURS for f in faults), [str(f) for f in faults]
    assert result.counts()[Verdict.MODEL] == len(faults)


def test_a_fault_sumo_shares_is_still_found_by_the_audit(paper_config: IntersectionConfig) -> None:
    """Where both skip phase 8 the timelines agree: no divergence names it, the audit of our greens does."""
    model, calls, ticks, _ = MUTANTS["skipped phase"]
    result = differential(paper_config, calls, ticks, model)
    assert not any(j.kind is SKIPPED for j in result.judgements)
    assert [(f.kind, f.phase) for f in result.audited] == [(SKIPPED, 7)]
