"""One signalised intersection as a gymnasium environment, built on :class:`hils.Testbed`.

The controller (the built-in emulator in virtual time, or a real one with ``target="snmp://..."``
at wall-clock time) enforces minimum green, yellow and red clearance itself: an action chooses
what to serve next, never a colour. ``step`` runs to the next decision point of the Testbed.

Observation (a ``Box`` of float32; ``n`` = number of phases, in phase-number order; a phase's
movement is the approach and turn(s) it serves):

=================  ==========  ==================================================================
slice              size        value
=================  ==========  ==================================================================
``[0, n)``         n           queue of each phase's movement: halting vehicles on its incoming lanes
``[n, 2n)``        n           pressure of each phase's movement: incoming minus outgoing halting
``[2n, 3n)``       n           signal of each phase: 0 red, 0.5 yellow, 1 green
``3n``             1           seconds since the signal last changed (time in the current interval)
``[3n+1, 3n+5)``   4           the manager's state, one-hot: idle, on_hold, timeout, preempted
``[3n+5, 4n+5)``   n           with ``spat=True``: seconds to the earliest change of each phase's signal the
                               controller announces (J2735's minEndTime; -1: none coming)
``[4n+5, 5n+5)``   n           with ``spat=True``: seconds to the latest (maxEndTime; -1: unknown), docs/spat.md
=================  ==========  ==================================================================

Actions: selection ``Discrete(len(pairs))``, switch ``Discrete(2)``, duration ``Box(0, 1, (1,))``; control
(phase control, docs/phase-control.md) ``MultiBinary((6, n))``, row k setting command type k of
:class:`hils.control.phase_control.Control` (hold, forceoff, omit_veh, omit_ped, call_veh, call_ped) on each phase,
from now until the next step (all zeros clears them); a schedule (MMITSS's JSON as a dict) is taken as it is.

Rewards (``reward=``): ``"queue"`` minus the total queue, ``"pressure"`` minus the summed pressure,
``"wait"`` the decrease of the waiting time accumulated by the vehicles on the signal's lanes, or
any callable ``(previous, current) -> float`` of two :class:`hils.Observation` s.

Rules
-----
- An episode is ``episode_length`` simulated seconds (one hour by default) and is *truncated* at its
  end; it is never *terminated*: a TIMEOUT of the manager is reported in ``info["timeout"]`` and the
  Testbed recovers from it (``recover_after``) while training goes on.
- An action the controller cannot take now is refused, nothing is sent, and the step runs to the next
  decision: ``info["refused"]`` says why (None when taken). While the controller serves a preempt
  (ambulance, train) every action is refused so; the observation's state says PREEMPTED.
- Seeding: ``reset(seed=s)`` seeds SUMO, the latency model and the agent-facing RNG; a reset without
  a seed draws the next seed from ``np_random``, so a seeded sequence of episodes is reproducible.
- What is said of one intersection here (spaces, conversions, rewards) lives in :class:`IntersectionAdapter`
  and the functions beside it, which the PettingZoo environment (:mod:`hils.envs.parallel`) uses per agent.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

from hils.agents.builtin import Observation
from hils.control.actions import ActionError, ActionType
from hils.control.manager import State
from hils.control.phase_control import Control, Schedule
from hils.protocol import config as config_mod
from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.spat import MovementTiming
from hils.run.testbed import Testbed
from hils.shell.poller import SignalCache, Snapshot
from hils.shell.targets import VIRTUAL
from hils.sim.network import TLS_ID, derive_phase_map, read_net, scenario_config

__all__ = [
    "REWARDS", "STATES", "EnvOptionError", "IntersectionAdapter", "IntersectionEnv", "Reward", "action_type_of",
    "episode_seed", "pressure_reward", "queue_reward", "reset_info", "reward_of", "wait_reward", "with_timing",
]

Reward = Callable[[Observation, Observation], float]
STATES = (State.IDLE, State.ON_HOLD, State.TIMEOUT, State.PREEMPTED)
#: The integer scalars a selection takes as they are: Python's and numpy's (not bool, which the general path refuses).
_INDICES = frozenset({int, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64})


class EnvOptionError(UserError, ValueError):
    """An option of the environment that cannot be used; names the option and what is allowed."""


def queue_reward(previous: Observation, current: Observation) -> float:
    """Minus the vehicles halting on the incoming lanes of every movement."""
    return -float(sum(m.upstream_queue for m in current.traffic.movements.values()))


def pressure_reward(previous: Observation, current: Observation) -> float:
    """Minus the summed pressure (incoming minus outgoing halting vehicles) of every movement."""
    return -float(sum(m.pressure for m in current.traffic.movements.values()))


def _waiting(obs: Observation) -> float:
    return sum(lane.waiting_time for lane in obs.traffic.lanes.values())


def wait_reward(previous: Observation, current: Observation) -> float:
    """The decrease of the waiting time accumulated by the vehicles on the signal's lanes."""
    return _waiting(previous) - _waiting(current)


REWARDS: dict[str, Reward] = {"queue": queue_reward, "pressure": pressure_reward, "wait": wait_reward}


# --- one intersection as an agent sees it: shared by this environment and the PettingZoo one ------------


def action_type_of(action_type: ActionType | str) -> ActionType:
    """The action type named, or an :class:`EnvOptionError` saying which are allowed."""
    try:
        return ActionType(action_type)
    except ValueError:
        raise EnvOptionError(f"action_type {action_type!r}: allowed: "
                             f"{', '.join(t.value for t in ActionType)}") from None


def reward_of(reward: str | Reward) -> Reward:
    """The reward function named in :data:`REWARDS`, or the callable given."""
    if isinstance(reward, str) and reward not in REWARDS:
        raise EnvOptionError(f"reward {reward!r}: allowed: {', '.join(REWARDS)} or a callable "
                             "(previous, current) -> float")
    if not callable(reward) and not isinstance(reward, str):
        raise EnvOptionError(f"reward {reward!r}: allowed: {', '.join(REWARDS)} or a callable")
    return REWARDS[reward] if isinstance(reward, str) else reward


def with_timing(config: IntersectionConfig, sumo_step: float | None, control_interval: float | None
                ) -> IntersectionConfig:
    """``config`` with the environment's ``sumo_step`` and ``control_interval`` options, where given."""
    changes = {k: v for k, v in (("sumo_step", sumo_step), ("control_interval", control_interval)) if v is not None}
    return config.with_middleware(**changes) if changes else config


def episode_seed(seed: int | None, rng: np.random.Generator) -> int:
    """The seed of an episode: the one given, else the next draw of the environment's RNG."""
    return seed if seed is not None else int(rng.integers(0, 2**31 - 1))


def reset_info(obs: Observation, seed: int) -> dict[str, Any]:
    """The info of an intersection's first observation."""
    return {"t": obs.t, "seed": seed, "state": obs.state.value}


class IntersectionAdapter:
    """One intersection as an agent sees it: its action and observation spaces, its actions converted for
    the Testbed and its observations as the vector of the module's layout.

    ``start`` it at every reset with the intersection's signal cache: the time in the current interval is
    counted from the signal's last change, which the cache reports."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType, spat: bool = False) -> None:
        self.config = config
        self.action_type = action_type
        self.spat = spat
        self.phases = config.phase_numbers
        n = len(self.phases)
        if action_type is ActionType.SELECTION:
            self.action_space: spaces.Space = spaces.Discrete(len(config.pairs))
        elif action_type is ActionType.SWITCH:
            self.action_space = spaces.Discrete(2)
        elif action_type is ActionType.CONTROL:  # a step: row k sets command type k (Control's order) on each phase
            self.action_space = spaces.MultiBinary((len(Control), n))
        else:
            self.action_space = spaces.Box(0.0, 1.0, (1,), np.float32)
        timing = 2 * n if spat else 0
        low = np.concatenate([np.zeros(n), np.full(n, -np.inf), np.zeros(n), [0.0], np.zeros(len(STATES)),
                              np.full(timing, -1.0)])
        high = np.concatenate([np.full(n, np.inf), np.full(n, np.inf), np.ones(n), [np.inf], np.ones(len(STATES)),
                               np.full(timing, np.inf)])
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self._changed_at = 0.0

    def start(self, cache: SignalCache, obs: Observation) -> None:
        """Follow the signal's changes from the first observation of an episode on."""
        self._changed_at = cache.snapshot.t if cache.snapshot is not None else obs.t
        cache.subscribe(self._on_signal_change)

    def action(self, action: Any) -> Any:
        """What the Testbed takes: a pair for selection, 0/1 for switch, x in [0, 1] for duration."""
        # What an action space's sample() gives (a numpy integer), taken without building an array
        pairs = self.config.pairs
        if self.action_type is ActionType.SELECTION and type(action) in _INDICES and 0 <= action < len(pairs):
            return pairs[action]
        value = np.asarray(action)
        if self.action_type is ActionType.SELECTION:
            if value.size != 1 or not np.issubdtype(value.dtype, np.integer) \
                    or not 0 <= int(value.reshape(())) < len(self.config.pairs):
                raise EnvOptionError(f"selection action {action!r}: allowed: an integer in "
                                     f"[0, {len(self.config.pairs)}) indexing {list(self.config.pairs)}")
            return self.config.pairs[int(value.reshape(()))]
        if self.action_type is ActionType.SWITCH:
            return int(value.reshape(())) if value.size == 1 else action
        if self.action_type is ActionType.CONTROL:
            return self._step(action, value)
        return float(np.clip(value.reshape(-1)[0], 0.0, 1.0)) if value.size == 1 else action

    def _step(self, action: Any, value: np.ndarray) -> Any:
        """A phase-control step from the action space's array (a schedule or a step mapping goes as it is)."""
        if isinstance(action, Mapping | str | Schedule):
            return action
        shape = (len(Control), len(self.phases))
        if value.shape != shape or not np.isin(value, (0, 1)).all():
            raise EnvOptionError(f"control action of shape {value.shape}: allowed: 0/1 of shape {shape}, row k "
                                 f"setting {', '.join(c.value for c in Control)}[k] on phases {list(self.phases)}, "
                                 "or a schedule (docs/phase-control.md)")
        return {c.value: [p for p, bit in zip(self.phases, value[k], strict=True) if bit]
                for k, c in enumerate(Control) if value[k].any()} or "clear"

    def vector(self, obs: Observation, spat: Sequence[MovementTiming] = ()) -> np.ndarray:
        """The observation as the module's layout says; ``spat``, the controller's announcement at ``obs.t``, fills
        the timing entries of an adapter built with ``spat=True``."""
        traffic, signal = obs.traffic, obs.signal
        queue = [traffic.movements[p].upstream_queue for p in self.phases]
        pressure = [traffic.movements[p].pressure for p in self.phases]
        lights = [0.0 if signal is None else 1.0 if p in signal.greens else 0.5 if p in signal.yellows else 0.0
                  for p in self.phases]
        state = [float(obs.state is s) for s in STATES]
        timing: list[float] = []
        if self.spat:
            of = {t.number: t for t in spat if t.kind == "phase"}

            def left(at: float | None) -> float:
                return -1.0 if at is None else max(0.0, at - obs.t)

            timing = [left(of[p].min_end) for p in self.phases] + [left(of[p].max_end) for p in self.phases]
        return np.array([*queue, *pressure, *lights, max(0.0, obs.t - self._changed_at), *state, *timing],
                        dtype=np.float32)

    def _on_signal_change(self, snapshot: Snapshot, changed: bool) -> None:
        self._changed_at = snapshot.t


class IntersectionEnv(gymnasium.Env):
    """``gymnasium.make("hils/Intersection-v1", action_type="selection" | "switch" | "duration" | "control", ...)``.

    ``config``: an intersection config (object or TOML path; default: the shipped four-leg).
    ``net``/``routes`` or ``sumocfg``: your own SUMO scenario (default: the shipped one).
    ``target``: ``"virtual"`` or ``"snmp://HOST:PORT"`` (wall clock). ``sumo_step``,
    ``control_interval``: override the config's. ``episode_length``: simulated seconds.
    ``reward``: a name of :data:`REWARDS` or a callable. ``recover_after``: seconds in TIMEOUT
    before the Testbed recovers. ``log_path``: the event log of each episode (overwritten). ``measure``:
    True to have ``testbed.traffic`` carry the run summary's delays and queues at an episode's end, and
    ``testbed.hires()`` the controllers' hi-res logs (they cost per-vehicle samples every second and a data
    logger in every controller, which training does not need: off by default; the episode is the same).
    ``spat``: True to add the controller's announced earliest and latest change of each phase to the observation
    (the in-process emulator, ``target="virtual"``, only: NTCIP 1202 has no per-phase timing object to poll).
    ``j2735``: True to hand, in ``info["j2735"]`` of every reset and step, the controller's SPaT as SAE J2735 sends
    it (UPER MessageFrame bytes, :meth:`hils.Testbed.j2735`; virtual target only, like ``spat``).
    ``sumo_worker``: True steps SUMO in a worker process of its own beside the environment's work
    (:mod:`hils.sim.worker`: the same episodes, on two cores; virtual time only). Off by default: it gains only where
    a core is free for it (on a busy machine, or with an environment per core, it adds the cost of its pipe).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, action_type: ActionType | str = ActionType.SELECTION, *,
                 config: IntersectionConfig | str | Path | None = None, net: str | Path | None = None,
                 routes: str | Path | None = None, sumocfg: str | Path | None = None, target: str = VIRTUAL,
                 sumo_step: float | None = None, control_interval: float | None = None,
                 episode_length: float = 3600.0, reward: str | Reward = "queue", recover_after: float = 5.0,
                 log_path: str | Path | None = None, measure: bool = False, spat: bool = False,
                 j2735: bool = False, sumo_worker: bool = False) -> None:
        self.action_type = action_type_of(action_type)
        for option, on in (("spat", spat), ("j2735", j2735)):
            if on and target != VIRTUAL:
                raise EnvOptionError(f"{option}=True with target={target!r}: allowed: {option}=True with "
                                     f"target={VIRTUAL!r} (the in-process emulator announces its timing; NTCIP 1202 "
                                     "has no per-phase timing object to poll a controller for)")
        self.j2735 = j2735
        cfg = config if isinstance(config, IntersectionConfig) else config_mod.load(config)
        self.config = with_timing(cfg, sumo_step, control_interval)
        self.reward_fn = reward_of(reward)
        self._scenario_dir = tempfile.TemporaryDirectory(prefix="hils-env-") if net is not None else None
        self.sumo_config = scenario_config(sumocfg=sumocfg, net=net, routes=routes,
                                           directory=self._scenario_dir.name if self._scenario_dir else None)
        if net is not None:
            derive_phase_map(self.config, read_net(net), tls_id=TLS_ID)  # refuse an unmappable movement now
        self.adapter = IntersectionAdapter(self.config, self.action_type, spat)
        self.phases = self.adapter.phases
        self.action_space = self.adapter.action_space
        self.observation_space = self.adapter.observation_space
        self.testbed = Testbed(self.config, action_type=self.action_type, target=target, sumo=True,
                               duration=episode_length, recover_after=recover_after, log_path=log_path,
                               sumo_config=self.sumo_config, measure=measure,
                               sumo_worker=sumo_worker)
        self._last: Observation | None = None

    # --- gymnasium API ----------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        run_seed = episode_seed(seed, self.np_random)
        obs = self.testbed.reset(seed=run_seed)
        self.adapter.start(self.testbed.middleware.cache, obs)
        self._last = obs
        return self.adapter.vector(obs, self._spat()), self._with_j2735(reset_info(obs, run_seed))

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        tb = self.testbed
        try:
            obs, info = tb.step(self.adapter.action(action))
        except ActionError as exc:  # refused (preempted, or not servable now), nothing sent: on to the next decision
            obs, info = tb.wait()
            info["refused"] = str(exc)
        reward = float(self.reward_fn(self._last, obs))
        self._last = obs
        truncated = tb.done
        info = self._with_j2735(info)
        if truncated:
            tb.finish()
        return self.adapter.vector(obs, self._spat()), reward, False, truncated, info

    def _spat(self) -> tuple[MovementTiming, ...]:
        return next(iter(self.testbed.spat().values())) if self.adapter.spat else ()

    def _with_j2735(self, info: dict[str, Any]) -> dict[str, Any]:
        if self.j2735:
            info["j2735"] = next(iter(self.testbed.j2735().values()))
        return info

    def close(self) -> None:
        self.testbed.close()
        if self._scenario_dir is not None:
            self._scenario_dir.cleanup()
            self._scenario_dir = None
