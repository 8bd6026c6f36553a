"""What the controller's inputs ask of the rings: the control objects, the detectors and the pattern, as phase sets.

Rules of this file
------------------
- Nothing here keeps state or acts: :meth:`Reader.read` derives an :class:`Inputs` from the inputs as they are,
  and :func:`latched` and :func:`demand` compute the pedestrian calls and the demand of one tick from them. The
  controller (:mod:`emulator.model.controller`) keeps what they return.

Theory of operation
-------------------
*Demand* on a phase is a vehicle call, a latched pedestrian call, or a recall (min, max, ped; soft only while
no other phase has demand), never on an omitted phase. A vehicle call is a SET of phaseControlGroupVehCall or
an actuated detector of the phase (non-locking: the call goes when the vehicle does), never on a phase
PhaseOmit omits. While a pattern runs its coordinated phases and its split-mode recalls are demand too, and
its omitted splits are omitted.

A pedestrian call latches on a phase not showing green, from phaseControlGroupPedCall, pedestrian recall or
the pattern's pedestrian recall; a push button (a pedestrian detector, pedestrianDetectorControlGroupActuation)
latches its phase's call at once, during that phase's green too: the walk comes at the phase's next green; but not
while that phase times its walk, the walk serving the pedestrian who pushed: a button still held as the walk it
brought begins places no second call (the MaxTime of issue 35's 638572533917628534.xml: four pushes held into the
walk they brought, 0.1-0.7 s, no other push before the phase's next green, and no walk at that green, four of four),
while one still held after the walk (a stuck button) calls the next.
No call latches on an omitted or PedOmit phase. A call arriving later in the green waits for the next service
(no recycling).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from emulator.model.coordination import Coordinator, Plan
from hils.protocol.config import IntersectionConfig, Recall
from hils.protocol.ntcip import ControlColumn


@dataclass(frozen=True, slots=True)
class Inputs:
    """What the inputs ask of the rings: the control objects, the detectors and the running pattern, read as
    phase sets. A step reads them every tick but they change only with a write or a new pattern, so they are
    derived once per change (:attr:`emulator.model.controller.Controller.inputs`)."""

    plan: Plan | None  # the pattern they were derived under
    calls: frozenset[int]  # vehicle calls the controller acts on (phaseStatusGroupVehCalls)
    holds: frozenset[int]
    omits: frozenset[int]  # PhaseOmit and the pattern's omitted splits
    ped_omits: frozenset[int]  # omits and PedOmit: no pedestrian call latches
    peds: frozenset[int]  # pedestrian calls asked: PedCall, pedestrian recall, the pattern's pedestrian recall
    pushed: frozenset[int]  # phases of the push buttons actuated now
    recalled: frozenset[int]  # demand whatever the calls: min and max recall, the pattern's recalls (not omitted)
    soft: frozenset[int]  # soft recall (not omitted): demand only while no other phase has any
    extending: frozenset[int]  # phases a green extends on without a call: max recall, the pattern's max recall


class Reader:
    """Reads the inputs of one controller as phase sets, by its config's detectors and recalls."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.phases = frozenset(config.phases)
        self._recall = {rc: frozenset(p for p, ph in config.phases.items() if ph.recall is rc) for rc in Recall}
        self._detector_phase = config.detectors
        self._ped_detector_phase = config.ped_detectors

    def read(self, co: Coordinator, control: Mapping[ControlColumn, frozenset[int]], actuations: Iterable[int],
             ped_actuations: Iterable[int]) -> Inputs:
        phases = self.phases
        omits = control[ControlColumn.PHASE_OMIT] | co.omitted()
        # Vehicle calls: SET (VehCall) or from an actuated detector, configured and not omitted.
        detected = {self._detector_phase[d] for d in actuations if d in self._detector_phase}
        calls = (control[ControlColumn.VEH_CALL] | detected).intersection(phases) - control[ControlColumn.PHASE_OMIT]
        recall = self._recall
        return Inputs(
            plan=co.plan, calls=calls, holds=control[ControlColumn.HOLD], omits=omits,
            ped_omits=omits | control[ControlColumn.PED_OMIT],
            peds=control[ControlColumn.PED_CALL].intersection(phases) | recall[Recall.PED] | co.ped_recalled(),
            pushed=frozenset(self._ped_detector_phase[d] for d in ped_actuations if d in self._ped_detector_phase),
            recalled=(recall[Recall.MIN] | recall[Recall.MAX] | co.recalled()) - omits,
            soft=recall[Recall.SOFT] - omits,
            extending=recall[Recall.MAX] | co.max_recalled())


def latched(ped_calls: frozenset[int], greens: Iterable[int], inputs: Inputs,
            walking: frozenset[int] = frozenset()) -> frozenset[int]:
    """The pedestrian calls latched this tick: those asked on phases not showing green, and push buttons but on the
    phases ``walking`` (timing their walk)."""
    return (ped_calls | (inputs.peds - set(greens)) | (inputs.pushed - walking)) - inputs.ped_omits


def demand(inputs: Inputs, ped_calls: frozenset[int]) -> frozenset[int]:
    """Phases wanting service: calls, latched pedestrian calls and recalls (while a pattern runs its coordinated
    phases and its split-mode recalls too), soft recalls when nothing else is."""
    wanted = (inputs.calls - inputs.omits) | ped_calls | inputs.recalled
    soft = inputs.soft
    if soft and not wanted - soft:
        wanted |= soft
    return wanted
