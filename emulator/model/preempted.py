"""The preemptor's part in the rings: a preempt's entry, track clearance, dwell and exit driven through the rings.

Rules of this file
------------------
- The preemptor (:mod:`emulator.model.preemption`) keeps each preempt's state and timers; this unit drives the
  rings while it serves one, and hands it the events that depend on the rings (entry, track clearance and exit
  done). It ends a green and commits a ring's next phase only through the sequencer
  (:meth:`emulator.model.sequencer.Sequencer.commit`); a ring's clearance it may cut to a preempt's caps.
- Once per tick, in the controller's order: :meth:`Preempted.caps_now` after the preemptor stepped,
  :meth:`Preempted.entry` when a service started, :meth:`Preempted.drive` instead of the sequencer's decision,
  :meth:`Preempted.progress` after the rings started their phases. Time is integer ticks.

Theory of operation
-------------------
NTCIP 1202 v02's preempt node (A.6), as it acts on the rings:

- Entry (entryStarted). The phases not to be served end: "A preempt initiated transition shall not cause the
  termination of an existing Green prior to its display for lesser of the phase's Minimum Green time or this
  period" (preemptMinimumGreen), and likewise the Walk (preemptMinimumWalk), the pedestrian clearance
  (preemptEnterPedClear), the yellow (preemptEnterYellowChange) and the red clearance (preemptEnterRedClear):
  running clearances shorten to those caps at once, and each green's end (``cut``) is set to the lesser of its
  minimum green and the preempt's, its walk and pedestrian clearance likewise.
- Track clearance (trackService). preemptTrackPhase are green for preemptTrackGreen, then clear with "the
  lesser of the phase's Yellow Change time or" preemptTrackYellowChange (and Red Clear).
- Dwell. preemptDwellPhase are green. With preemptCyclingPhase, phases "allowed to cycle during the Preempt Dwell
  interval" ("The phase(s) defined in preemptCyclingPhase shall occur after those defined herein", says
  preemptDwellPhase): once the dwell phases show, the rings run as the sequencer runs them, on the demand of the
  cycling phases, the dwell phases recalled (the ring returns to them) and every other phase omitted
  (:meth:`Preempted.cycling`). The preemptor ends the dwell as without them; the exit then drives the rings.
- Exit (exitStarted). preemptExitPhase: the phases "that shall be active following Preempt"; once they show
  green the controller returns to its own operation. A ring without an exit phase keeps what it shows, unless
  that is a green across the barrier from the exit phases: it clears to red.

The preempt being served drives the rings to its phases: a green of another phase ends once it may (its entry
minimum, the end of the track green, else its minimum), a clearing or resting ring takes the preempt's phase as
its next, and the barrier group is the preempt's. A preempt overrides phase omits. The entry, track clearance
or exit is done when every ring shows its phase (or, without one, rests in red).

Deadlines. A green's entry minimum (``cut``) is a threshold of its ring (:meth:`Preempted.thresholds`); the
preemptor's own timers are its ``deadline``.
"""

from __future__ import annotations

from collections.abc import Sequence

from emulator.model.inputs import Inputs
from emulator.model.preemption import Event, Preemptor
from emulator.model.ring import CLEARANCE, DWELL, GREEN, RED_CLEAR, Ring, Timing
from emulator.model.sequencer import Sequencer
from hils.protocol.config import IntersectionConfig
from hils.protocol.ntcip import PreemptState


class Preempted:
    """The rings under the preempt being served: its caps, each green's entry minimum, the driving."""

    def __init__(self, config: IntersectionConfig, preemptor: Preemptor, timing: dict[int, Timing]) -> None:
        self.config = config
        self.preemptor = preemptor
        self.timing = timing
        self._ring_of = {p: config.ring_of(p) for p in config.phases}
        self._phases = frozenset(config.phases)
        self._numbers = range(1, len(config.rings) + 1)
        self.reset()

    def reset(self) -> None:
        # The yellow and red clearance a preempt-initiated transition may shorten to, in ticks (None: no cap).
        self.caps: tuple[int, int] | None = None
        # Per ring: the ticks its green must show before a preempt's entry may end it (lesser of the minimum and the
        # preempt's entry minimums).
        self.cut = dict.fromkeys(self._numbers, 0)

    @property
    def serving(self) -> bool:
        """A preempt drives the rings (its entry, track clearance, dwell or exit)."""
        return self.preemptor.serving is not None

    def _targets(self) -> dict[int, int]:
        """Per ring, the phase the preempt being served wants green now (a ring without one rests in red; in
        the exit, it is left to itself)."""
        pe = self.preemptor
        n, state = pe.serving, pe.state
        p, tm = self.config.preempts[n], pe.timing[n]
        if state is PreemptState.ENTRY_STARTED:
            phases = p.track_phases if tm.track_green and p.track_phases else p.dwell_phases
        elif state is PreemptState.TRACK_SERVICE:
            phases = p.track_phases if pe.stage[n] < tm.track_green else p.dwell_phases
        elif state is PreemptState.DWELL:
            phases = p.dwell_phases
        else:
            phases = p.exit_phases
        return {self._ring_of[q]: q for q in phases}

    def cycling(self, demand: frozenset[int]) -> tuple[frozenset[int], frozenset[int]] | None:
        """In the dwell of a preempt with cycling phases: the demand the rings cycle on (the cycling phases' own, the
        dwell phases always) and the phases omitted (all others); None when the preempt drives the rings."""
        pe = self.preemptor
        if pe.serving is None or pe.state is not PreemptState.DWELL:
            return None
        p = self.config.preempts[pe.serving]
        if not p.cycling_phases:
            return None
        dwell, cycling = frozenset(p.dwell_phases), frozenset(p.cycling_phases)
        return (demand & cycling) | dwell, self._phases - dwell - cycling

    def caps_now(self) -> None:
        """The yellow and red clearance a preempt-initiated transition may shorten to now (entry, track), or None."""
        pe = self.preemptor
        if pe.serving is None:
            self.caps = None
        elif pe.state is PreemptState.ENTRY_STARTED:
            tm = pe.timing[pe.serving]
            self.caps = tm.enter_yellow, tm.enter_red
        elif pe.state is PreemptState.TRACK_SERVICE:
            tm = pe.timing[pe.serving]
            self.caps = tm.track_yellow, tm.track_red
        else:
            self.caps = None

    def entry(self, rings: Sequence[Ring]) -> None:
        """A preempt's entry starts: running clearances shorten to its caps, and each green's end is set to the
        lesser of its minimum green and the preempt's, its walk and pedestrian clearance likewise."""
        tm = self.preemptor.timing[self.preemptor.serving]
        for r in rings:
            if r.interval in CLEARANCE:
                r.length = min(r.length, self.caps[r.interval is RED_CLEAR])
            elif r.interval is GREEN:
                walked = r.walk > 0  # this green serves a walk (its walk may be cut to nothing below)
                if walked and r.ticks < r.walk:
                    r.walk = max(r.ticks, min(r.walk, r.walk_start + tm.min_walk))
                if walked and r.ticks < r.walk + r.ped_clear:
                    r.ped_clear = max(r.ticks - r.walk, min(r.ped_clear, tm.enter_ped_clear))
                self.cut[r.number] = max(min(self.timing[r.phase].min_green, tm.min_green), r.walk + r.ped_clear)

    def drive(self, sequencer: Sequencer, inputs: Inputs) -> None:
        """The preempt being served drives the rings to its phases: a green of another phase ends once it may
        (its entry minimum, the end of the track green, else its minimum), a clearing or resting ring takes the
        preempt's phase as its next. In the exit a ring without an exit phase keeps what it shows, unless that is
        a green across the barrier from the exit phases: it clears to red."""
        state = self.preemptor.state
        targets = self._targets()
        exit_group = next((sequencer.barrier_of(q) for q in targets.values()), None)
        for r in sequencer.rings:
            t = targets.get(r.number)
            if t is None and state is PreemptState.EXIT_STARTED and (
                    r.interval is not GREEN or exit_group in (None, sequencer.barrier_of(r.phase))):
                continue  # no exit phase of its own: left to itself, unless it holds the exit across a barrier
            if r.interval is GREEN:
                if r.phase == t:
                    continue
                limit = {PreemptState.ENTRY_STARTED: self.cut[r.number],
                         PreemptState.TRACK_SERVICE: 0}.get(state, r.minimum)
                if r.ticks >= limit:
                    sequencer.commit(r, t, inputs)
            else:
                r.target = t
            if t is not None:
                sequencer.group = sequencer.barrier_of(t)

    def progress(self, rings: Sequence[Ring]) -> None:
        """After the rings moved: the entry, track clearance or exit is done when every ring shows its phase (or,
        without one, rests in red)."""
        pe = self.preemptor
        n, state = pe.serving, pe.state
        targets = self._targets()

        if not all(self._there(r, targets, state) for r in rings):
            return
        if state is PreemptState.ENTRY_STARTED:
            track = pe.timing[n].track_green and self.config.preempts[n].track_phases
            pe.event(n, Event.CLEARED_TO_TRACK if track else Event.CLEARED)
        elif state is PreemptState.TRACK_SERVICE and pe.stage[n] >= pe.timing[n].track_green:
            pe.event(n, Event.TRACKED)
        elif state is PreemptState.EXIT_STARTED:
            pe.event(n, Event.EXITED)

    @staticmethod
    def _there(r: Ring, targets: dict[int, int], state: PreemptState) -> bool:
        """``r`` shows the phase the preempt wants of it (or, without one, rests in red)."""
        t = targets.get(r.number)
        if t is None:
            return state is PreemptState.EXIT_STARTED or (r.interval is DWELL and r.target is None)
        return r.interval is GREEN and r.phase == t

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def thresholds(self, r: Ring) -> list[int]:
        """Ticks from now to the entry minimum of ``r``'s green, if still ahead."""
        cut = self.cut[r.number]
        return [cut - r.ticks] if r.interval is GREEN and r.ticks < cut else []

    def deadline(self, sequencer: Sequencer) -> int | None:
        """1 when the next step's driving (:meth:`drive`) or progress (:meth:`progress`) acts on the rings or the
        preemptor, no ring moving otherwise; else None (the thresholds they compare are the rings' and the
        preemptor's)."""
        pe = self.preemptor
        if pe.serving is None:
            return None
        state, targets = pe.state, self._targets()
        exit_group = next((sequencer.barrier_of(q) for q in targets.values()), None)
        for r in sequencer.rings:
            t = targets.get(r.number)
            if t is None and state is PreemptState.EXIT_STARTED and (
                    r.interval is not GREEN or exit_group in (None, sequencer.barrier_of(r.phase))):
                continue
            if r.interval is GREEN:
                if r.phase == t:
                    continue
                limit = {PreemptState.ENTRY_STARTED: self.cut[r.number],
                         PreemptState.TRACK_SERVICE: 0}.get(state, r.minimum)
                if r.ticks + 1 >= limit:
                    return 1  # the green ends
            elif r.target != t:
                return 1  # the preempt's phase committed next
            if t is not None and sequencer.group != sequencer.barrier_of(t):
                return 1
        n = pe.serving
        if not all(self._there(r, targets, state) for r in sequencer.rings):
            return None
        if state is PreemptState.TRACK_SERVICE and pe.stage[n] + 1 < pe.timing[n].track_green:
            return None
        return 1 if state in (PreemptState.ENTRY_STARTED, PreemptState.TRACK_SERVICE,
                              PreemptState.EXIT_STARTED) else None
