"""Control agents behind one small protocol: observe, then return an action value.

An agent has an ``action_type`` (selection, switch, duration or control) and an
``act`` method that takes an :class:`Observation` and returns the action value
for its type: a pair of phases, 0 or 1, x in [0, 1], or a phase-control schedule
or step (:mod:`hils.control.phase_control`). A user's own agent class is loaded
with :func:`load_agent` from ``package.module:Class``.
"""

from __future__ import annotations

import importlib
import inspect
import random
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from hils.control.actions import ActionType
from hils.control.phase_control import Control, Schedule
from hils.protocol.config import IntersectionConfig, Pair
from hils.protocol.errors import STOPS, AgentFailed, UserError, described
from hils.protocol.ntcip import SignalState
from hils.sim.webster import webster_plan

__all__ = [
    "BUILTIN", "ActuatedAgent", "Agent", "AgentError", "CoordinatedAgent", "FixedCycleAgent", "FixedTimeAgent",
    "MaxPressureAgent", "Observation", "OmitHoldAgent",
    "QueueProportionalAgent", "RandomAgent", "ScheduleAgent", "WebsterAgent", "load_agent",
]


@dataclass(frozen=True, slots=True)
class Observation:
    """What an agent sees at a decision point."""

    t: float
    signal: SignalState | None
    traffic: Any = None  # the simulation's traffic state (hils.sim.sumo.TrafficState), when a simulation runs
    next_pair: Pair | None = None  # the pair a switch or duration action would serve next
    state: Any = None  # the manager's state (hils.control.manager.State): idle, on_hold or timeout


@runtime_checkable
class Agent(Protocol):
    action_type: ActionType

    def act(self, observation: Observation) -> Any: ...


class AgentError(UserError, TypeError):
    """A class that cannot serve as an agent, or an agent spec that does not load."""


def _issues_only(name: str, allowed: ActionType, action_type: ActionType | str) -> None:
    """Refuse a built-in agent an action type it does not issue, saying which it does."""
    if ActionType(action_type) is not allowed:
        raise AgentError(f"the {name} agent issues phase {allowed.value} actions only (--action-type "
                         f"{allowed.value}), not {ActionType(action_type).value}")


class RandomAgent:
    """Uniformly random actions of one type (a baseline, and a fuzzer of the middleware). Phase control: a step
    that calls a random pair of the config's and holds each of its phases or not, at random."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str, seed: int = 0) -> None:
        self.config = config
        self.action_type = ActionType(action_type)
        self.rng = random.Random(seed)

    def act(self, observation: Observation) -> Any:
        if self.action_type is ActionType.SELECTION:
            return self.rng.choice(self.config.pairs)
        if self.action_type is ActionType.SWITCH:
            return self.rng.randint(0, 1)
        if self.action_type is ActionType.CONTROL:
            pair = self.rng.choice(self.config.pairs)
            held = [p for p in pair if self.rng.random() < 0.5]
            return {Control.CALL_VEH.value: list(pair), Control.HOLD.value: held}
        return self.rng.random()


class FixedCycleAgent:
    """Advance at every decision (switch 1): a fixed-time cycle through the configured sequence."""

    action_type = ActionType.SWITCH

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.SWITCH,
                 seed: int = 0) -> None:
        _issues_only("fixed-cycle", ActionType.SWITCH, action_type)

    def act(self, observation: Observation) -> int:
        return 1


class MaxPressureAgent:
    """Max-pressure phase selection (Varaiya 2013): the compatible pair whose movements have the
    largest summed pressure, upstream queue minus downstream queue. Ties keep the pair shown, then
    go to the first pair in the configured order."""

    action_type = ActionType.SELECTION

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.SELECTION,
                 seed: int = 0) -> None:
        _issues_only("max-pressure", ActionType.SELECTION, action_type)
        self.pairs = config.pairs

    def act(self, observation: Observation) -> Pair:
        if observation.traffic is None:
            raise AgentError("the max-pressure agent needs the traffic state: run it with SUMO (without --no-sumo)")
        movements = observation.traffic.movements
        greens = observation.signal.greens if observation.signal else frozenset()

        def score(pair: Pair) -> tuple[int, bool]:
            return sum(movements[p].pressure for p in pair), set(pair) <= greens

        return max(self.pairs, key=score)


class QueueProportionalAgent:
    """Phase duration in proportion to the queue waiting for the next pair: x = queue / saturation,
    capped at 1 (saturation: the queue that deserves the maximum green)."""

    action_type = ActionType.DURATION

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.DURATION,
                 seed: int = 0, saturation: int = 20) -> None:
        _issues_only("queue-proportional", ActionType.DURATION, action_type)
        self.saturation = saturation

    def act(self, observation: Observation) -> float:
        if observation.traffic is None or observation.next_pair is None:
            raise AgentError("the queue-proportional agent needs the traffic state: run it with SUMO")
        queue = sum(observation.traffic.movements[p].upstream_queue for p in observation.next_pair)
        return min(1.0, queue / self.saturation)


class WebsterAgent:
    """The fixed-time baseline: Webster's plan for the shipped demand, run through phase durations.

    The plan (:func:`hils.sim.webster.webster_plan`) puts each route-file flow on the phase that
    serves it, takes flow ratios y = q / (lanes x 1800 veh/h), the larger y of each pair of the
    sequence as the stage's critical ratio (sum Y), the yellow plus red clearance of every stage
    as lost time L, the optimal cycle C0 = (1.5 L + 5) / (1 - Y), and splits C0 - L in proportion
    to the critical ratios, each green clipped to the pair's [min_green, max_green]. At each
    decision the agent asks for the next pair's planned green: x = (green - min) / (max - min),
    which the middleware turns back into exactly that green. The demand, not the traffic state,
    sets the plan, so the agent also runs without SUMO.
    """

    action_type = ActionType.DURATION

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.DURATION,
                 seed: int = 0) -> None:
        _issues_only("webster", ActionType.DURATION, action_type)
        self.config = config
        self.plan = webster_plan(config)

    def act(self, observation: Observation) -> float:
        if observation.next_pair is None:
            raise AgentError("the webster agent needs the pair a duration action serves next")
        pair = observation.next_pair
        g_min = max(self.config.phases[p].min_green for p in pair)
        g_max = max(g_min, min(self.config.phases[p].max_green for p in pair))
        if g_max == g_min:
            return 0.0
        return (self.plan.green_of(pair) - g_min) / (g_max - g_min)


class OmitHoldAgent:
    """Phase control step by step, as CARMA Streets commands a controller (``tsc_client_service``,
    ``control_tsc_state``): at each decision a target pair, every other phase omitted, the target called and held.

    The target is the max-pressure pair (Varaiya 2013, as :class:`MaxPressureAgent`) when the traffic is observed,
    else the next pair of the configured sequence. A target already green is held (a hold on a phase not green is
    armed: it keeps the target's green once it comes). The phases showing green outside the target are forced off, so
    that their green ends at its minimum for the target's call."""

    action_type = ActionType.CONTROL

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.CONTROL,
                 seed: int = 0) -> None:
        _issues_only("omit-hold", ActionType.CONTROL, action_type)
        self.config = config
        self.pressure = MaxPressureAgent(config)
        self._position = -1

    def act(self, observation: Observation) -> dict[str, list[int]]:
        if observation.traffic is not None:
            target = self.pressure.act(observation)
        else:
            self._position = (self._position + 1) % len(self.config.sequence)
            target = self.config.sequence[self._position]
        others = [p for p in self.config.phase_numbers if p not in target]
        greens = observation.signal.greens if observation.signal is not None else frozenset()
        return {Control.OMIT_VEH.value: others, Control.CALL_VEH.value: list(target), Control.HOLD.value: list(target),
                Control.FORCE_OFF.value: sorted(greens - set(target))}


class ScheduleAgent:
    """Phase control by a schedule given up front (MMITSS's JSON: :func:`hils.control.phase_control.load`): hands it
    over at the first decision, then nothing (the schedule runs on its own times; the controller runs as it asks,
    and as it is set up, after its end)."""

    action_type = ActionType.CONTROL

    def __init__(self, schedule: Schedule) -> None:
        self.schedule = schedule
        self._given = False

    def act(self, observation: Observation) -> Schedule | None:
        if self._given:
            return None
        self._given = True
        return self.schedule


class ActuatedAgent:
    """No agent: the controller runs fully actuated on its detectors (SUMO's stop-bar presence, see
    :mod:`hils.run.detectors`) with the config's recalls; the middleware only observes. Never acts."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.SELECTION,
                 seed: int = 0) -> None:
        self.action_type = ActionType(action_type)

    def act(self, observation: Observation) -> None:
        return None


class _PlanAgent(ActuatedAgent):
    """No agent: the controller runs the timing plan of its config; a config without one is refused."""

    name = ""

    def __init__(self, config: IntersectionConfig, action_type: ActionType | str = ActionType.SELECTION,
                 seed: int = 0) -> None:
        if not config.coordination.patterns:
            raise AgentError(f"the {self.name} agent runs the controller's timing plan, and {config.source} has none"
                             + (f": {config.coordination.unplanned}" if config.coordination.unplanned else
                                ": add [[coordination.patterns]] (the shipped four-leg and corridor configs have one)"))
        super().__init__(config, action_type, seed)


class CoordinatedAgent(_PlanAgent):
    """No agent: the controller runs the city's coordination plan of its config (cycle, offset, splits, the
    coordinated phases resting, force-offs) on its own detectors, as ``actuated`` does free; the middleware only
    observes. A config without a plan is refused."""

    name = "coordinated"


class FixedTimeAgent(_PlanAgent):
    """No agent: the controller runs the timing plan of its config pretimed (every phase on maximum recall through
    the split table's splitMode, no detectors: each phase its whole split, every cycle), RESCO's fixed-time baseline
    on the real controller; the middleware only observes. A config without a plan is refused.

    Unlike ``fixed-cycle`` and ``webster``, which command the controller phase by phase from the middleware in free
    mode, this is the controller's own operation: its coordinator times the cycle, the splits and the offset."""

    name = "fixed-time"


BUILTIN: dict[str, type] = {"random": RandomAgent, "fixed-cycle": FixedCycleAgent, "max-pressure": MaxPressureAgent,
                            "queue-proportional": QueueProportionalAgent, "webster": WebsterAgent,
                            "actuated": ActuatedAgent, "coordinated": CoordinatedAgent,
                            "fixed-time": FixedTimeAgent, "omit-hold": OmitHoldAgent}

#: Built-in agents that leave the controller to its own operation (the middleware observes), and the config each
#: makes the controller run: its plan from power-up for coordinated, pretimed for fixed-time, as given (free by
#: default) for actuated and every other agent.
_PLANS = {"coordinated": IntersectionConfig.planned, "fixed-time": IntersectionConfig.pretimed}
PLAN_AGENTS = frozenset(_PLANS)
#: What the controller runs under each of those, as the console says it (no agent acts: its action type is moot).
OWN_OPERATION = {"actuated": "actuated on its detectors", "coordinated": "its coordination plan on its detectors",
                 "fixed-time": "its coordination plan pretimed, no detectors"}
#: Of those, the ones whose controller runs on its detectors (fixed-time's pretimed plan needs none).
DETECTOR_AGENTS = frozenset({"actuated", "coordinated"})


def controlled_by(agent: str | None, action_type: str | None) -> str:
    """Who drove the signals, in a few words: ``selection by max-pressure``, or for an agent that leaves the
    controller to its own operation, what the controller ran (``coordinated: the controller's own operation, its
    coordination plan on its detectors``)."""
    own = OWN_OPERATION.get(agent or "")
    return f"{action_type} by {agent}" if own is None else f"{agent}: the controller's own operation, {own}"


def controller_config(agent: object, config: IntersectionConfig) -> IntersectionConfig:
    """The config the controller runs for ``agent``: its coordination plan from power-up for ``coordinated``, that
    plan pretimed for ``fixed-time``, as given (free by default, as the phase-commanding agents need) for every
    other."""
    plan = _PLANS.get(agent) if isinstance(agent, str) else None
    return plan(config) if plan else config


def check_plans(agent: object, scenario: str, configs: Mapping[str, IntersectionConfig]) -> None:
    """Refuse, in one line naming every light of ``scenario`` without one and why, an agent that runs the
    controllers' timing plans where some have none."""
    missing = {tls: c.coordination.unplanned or "no [[coordination.patterns]]"
               for tls, c in configs.items() if not c.coordination.patterns}
    if isinstance(agent, str) and agent in _PLANS and missing:
        raise AgentError(f"the {agent} agent runs each controller's timing plan, and {len(missing)} of the "
                         f"{len(configs)} lights of {scenario} {'has' if len(missing) == 1 else 'have'} none: "
                         + "; ".join(f"{tls}: {why}" for tls, why in missing.items()))


def describe_plan(config: IntersectionConfig) -> str:
    """One line on what the controller runs: its pattern (cycle, offset, coordinated phases) or free."""
    c = config.coordination
    p = c.patterns.get(c.pattern)
    if p is None:
        return "Controller plan: free (no coordination pattern)"
    return (f"Controller plan: pattern {p.number}{' pretimed (every phase on max recall)' if p.pretimed else ''}, "
            f"cycle {p.cycle} s, offset {p.offset} s, splits "
            f"{' '.join(f'{n}:{t}' for n, t in sorted(p.splits.items()))}, coordinated phases "
            f"{'+'.join(map(str, p.coord_phases))}, {c.force_off.value} force-offs, offset to the "
            f"{'start of their green' if c.offset_reference.value == 'lead_green' else 'start of their yellow'}"
            + (f"; {len(c.schedule)} time-of-day changes" if c.schedule else ""))


def load_agent(spec: str, config: IntersectionConfig, action_type: ActionType | str, seed: int = 0) -> Agent:
    """An agent from a built-in name or ``package.module:Class``; refused with a clear message if it
    does not fit the protocol."""
    if spec in BUILTIN:
        cls = BUILTIN[spec]
    else:
        module_name, sep, class_name = spec.partition(":")
        if not sep or not module_name or not class_name:
            raise AgentError(f"agent {spec!r}: expected a built-in agent ({', '.join(BUILTIN)}) "
                             "or package.module:Class")
        try:
            cls = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as exc:
            raise AgentError(f"agent {spec!r} cannot be loaded: {exc}") from None
    if not inspect.isclass(cls):
        raise AgentError(f"agent {spec!r} is not a class")
    if not callable(getattr(cls, "act", None)):
        raise AgentError(f"agent {spec!r} does not fit the agent protocol: it has no act(observation) method")
    try:
        inspect.signature(cls).bind(config, action_type, seed)
    except TypeError as exc:
        raise AgentError(f"agent {spec!r} does not fit the agent protocol: its constructor must take "
                         f"(config, action_type, seed): {exc}") from None
    except ValueError:
        pass  # a class whose signature Python cannot tell (written in C): its constructor answers for itself
    try:
        agent = cls(config, action_type, seed)
    except AgentError:
        raise  # the agent's own refusal (a built-in asked for an action type it does not issue)
    except STOPS:
        raise
    except BaseException as exc:
        raise AgentFailed(f"agent {spec!r} could not start: its constructor raised {described(exc)}") from exc
    declared = getattr(agent, "action_type", None)
    try:
        declared = ActionType(declared)
    except ValueError:
        raise AgentError(f"agent {spec!r} does not fit the agent protocol: action_type must be one of "
                         f"{[t.value for t in ActionType]}, got {declared!r}") from None
    if declared is not ActionType(action_type):
        raise AgentError(f"agent {spec!r} issues {declared.value} actions, but the run uses "
                         f"{ActionType(action_type).value}")
    return agent
