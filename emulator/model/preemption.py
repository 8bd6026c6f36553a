"""Preemption: preempt inputs, their delay, memory and priority, and where each preempt's service is.

Rules of this file
------------------
- A preempt's state (NTCIP 1202 preemptState) changes only by ``_NEXT`` below, on the events named there.
- :meth:`Preemptor.step` runs once per controller tick before the rings time: it reads the inputs, times the
  delays and presences and picks the preempt to serve. The events that depend on the rings (entry, track
  clearance and exit done) come from the controller (:meth:`Preemptor.event`), which drives the rings.
- Time is integer ticks, like the controller's.

Theory of operation
-------------------
NTCIP 1202 v02's preempt node (A.6), quoted where it decides something:

- Input. preemptControlState "when set to ON (one) shall cause the associated preempt actions to occur ... The
  preempt shall remain active as long as this object is ON". The emulator's only preempt inputs are these
  objects: SUMO's detection zones SET them, as a central system calling a preempt would.
- Delay and memory. preemptDelay: "the time the preempt input shall be active prior to initiating any preempt
  sequence". preemptControl bit 0, Non-Locking Memory: "When set (1) a preempt sequence shall not occur if the
  preempt input terminates prior to expiration of the preemptDelay time"; without it the call is remembered.
- Priority. "Lowered numbered preempts override higher numbered preempts": a lower-numbered preempt whose delay
  has passed takes over from one being served, which goes back to waiting while its input is on.
- Entry (entryStarted). The phases not to be served end: "A preempt initiated transition shall not cause the
  termination of an existing Green prior to its display for lesser of the phase's Minimum Green time or this
  period" (preemptMinimumGreen), and likewise the Walk (preemptMinimumWalk), the pedestrian clearance
  (preemptEnterPedClear), the yellow (preemptEnterYellowChange) and the red clearance (preemptEnterRedClear).
- Track clearance (trackService). preemptTrackPhase are green for preemptTrackGreen ("If this value is zero,
  the track clearance movement is omitted"), then clear with "the lesser of the phase's Yellow Change time or"
  preemptTrackYellowChange (and Red Clear).
- Dwell. preemptDwellPhase are green: "The Dwell interval shall not terminate prior to the completion of
  preemptMinimumDuration, preemptDwellGreen (this object), and the call is no longer present";
  preemptMinimumDuration "begins timing at the end of Preempt Delay".
- Exit (exitStarted). preemptExitPhase: the phases "that shall be active following Preempt"; once they show
  green the controller returns to its own operation.
- Maximum presence. "When the preempt call has been active for this time period, the CU shall return to normal
  operation. This preempt call shall be considered invalid until such time as a change in state occurs".

Not modelled: preemptLink (linked preempts, read as 0), cycling phases and pedestrians during dwell, flash
dwell, and preemption during flash (the inputs are read only while the controller is not flashing).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from hils.protocol.config import IntersectionConfig, Preempt
from hils.protocol.ntcip import PreemptState

S = PreemptState


class Event(Enum):
    CALLED = "its input turned on"
    FORGOTTEN = "a non-locking call went before its delay passed"
    SERVED = "its delay passed and no lower-numbered preempt is called: entry starts"
    CLEARED = "the entry is done: the dwell phases show (or their rings rest in red)"
    CLEARED_TO_TRACK = "the entry is done: the track phases show"
    TRACKED = "the track phases have timed their green and cleared"
    DWELT = "minimum dwell and duration done, and the call is gone"
    EXITED = "the exit phases show: the controller's own operation resumes"
    OVERRIDDEN = "a lower-numbered preempt took over"
    TIMED_OUT = "the input has been on for the maximum presence"
    GONE = "the input turned off"


_SERVING = (S.ENTRY_STARTED, S.TRACK_SERVICE, S.DWELL)
_NEXT: dict[tuple[PreemptState, Event], PreemptState] = {
    (S.NOT_ACTIVE, Event.CALLED): S.NOT_ACTIVE_WITH_CALL,
    (S.NOT_ACTIVE_WITH_CALL, Event.FORGOTTEN): S.NOT_ACTIVE,
    (S.NOT_ACTIVE_WITH_CALL, Event.SERVED): S.ENTRY_STARTED,
    (S.NOT_ACTIVE_WITH_CALL, Event.TIMED_OUT): S.MAX_PRESENCE,
    (S.ENTRY_STARTED, Event.CLEARED): S.DWELL,
    (S.ENTRY_STARTED, Event.CLEARED_TO_TRACK): S.TRACK_SERVICE,
    (S.TRACK_SERVICE, Event.TRACKED): S.DWELL,
    (S.DWELL, Event.DWELT): S.EXIT_STARTED,
    (S.EXIT_STARTED, Event.EXITED): S.NOT_ACTIVE,
    **{(s, Event.OVERRIDDEN): S.NOT_ACTIVE_WITH_CALL for s in _SERVING},
    (S.EXIT_STARTED, Event.OVERRIDDEN): S.NOT_ACTIVE,
    **{(s, Event.TIMED_OUT): S.MAX_PRESENCE for s in _SERVING},
    (S.MAX_PRESENCE, Event.GONE): S.NOT_ACTIVE,
}
#: States in which a preempt drives the rings.
ACTIVE = frozenset({*_SERVING, S.EXIT_STARTED})


@dataclass(slots=True)
class PreemptTiming:
    """A preempt's times in ticks; mutable so the preempt table can be retimed over SNMP."""

    delay: int
    min_duration: int
    min_green: int
    min_walk: int
    enter_ped_clear: int
    enter_yellow: int
    enter_red: int
    track_green: int
    track_yellow: int
    track_red: int
    dwell_green: int
    max_presence: int

    @classmethod
    def of(cls, p: Preempt) -> PreemptTiming:
        seconds = (p.delay, p.min_duration, p.min_green, p.min_walk, p.enter_ped_clear)
        return cls(*(10 * s for s in seconds), round(p.enter_yellow * 10), round(p.enter_red * 10),
                   10 * p.track_green, round(p.track_yellow * 10), round(p.track_red * 10), 10 * p.dwell_green,
                   10 * p.max_presence)


class Preemptor:
    """The preempts of one controller: inputs, states, timers, and the one being served."""

    def __init__(self, config: IntersectionConfig) -> None:
        self.preempts = config.preempts
        self.timing = {n: PreemptTiming.of(p) for n, p in config.preempts.items()}
        self.reset()

    def reset(self) -> None:
        """Power-up: no input, nothing called."""
        self.control: frozenset[int] = frozenset()  # preemptControlState ON
        self.states = dict.fromkeys(self.preempts, S.NOT_ACTIVE)
        self.presence = dict.fromkeys(self.preempts, 0)  # ticks the input has been on without a break
        self.waited = dict.fromkeys(self.preempts, 0)  # ticks since the call (the delay)
        self.since_entry = dict.fromkeys(self.preempts, 0)  # ticks since the entry started (minimum duration)
        self.stage = dict.fromkeys(self.preempts, 0)  # ticks in track service, or in dwell
        self.serving: int | None = None
        self.started = False  # the service of ``serving`` started this tick

    def set_control(self, numbers: frozenset[int]) -> None:
        """preemptControlState: the preempts whose object is ON."""
        self.control = numbers

    @property
    def state(self) -> PreemptState | None:
        """The state of the preempt being served, None when none is."""
        return None if self.serving is None else self.states[self.serving]

    def discrete(self) -> tuple:
        return self.control, self.serving, tuple(self.states.values())

    def event(self, n: int, event: Event) -> None:
        before = self.states[n]
        self.states[n] = _NEXT[before, event]
        if self.states[n] in (S.TRACK_SERVICE, S.DWELL) and before is not self.states[n]:
            self.stage[n] = 0
        if n == self.serving and self.states[n] not in ACTIVE:
            self.serving = None

    def step(self) -> None:
        """One tick of the inputs and timers; then the preempt to serve (the lowest-numbered ready one)."""
        self.started = False
        if not self.preempts:
            return
        for n in self.preempts:
            self._input(n)
        ready = [n for n, s in self.states.items()
                 if s in ACTIVE or (s is S.NOT_ACTIVE_WITH_CALL and self.waited[n] >= self.timing[n].delay)]
        top = min(ready, default=None)
        if self.serving is not None and top != self.serving:
            self.event(self.serving, Event.OVERRIDDEN)
        if top is not None and self.states[top] is S.NOT_ACTIVE_WITH_CALL:
            self.event(top, Event.SERVED)
            self.since_entry[top] = 0
            self.started = True
        self.serving = top
        n = self.serving
        if n is not None and self.states[n] is S.DWELL and self._dwelt(n):
            self.event(n, Event.DWELT)

    def _input(self, n: int) -> None:
        on, s, tm = n in self.control, self.states[n], self.timing[n]
        self.presence[n] = self.presence[n] + 1 if on else 0
        if s is S.MAX_PRESENCE:
            if not on:
                self.event(n, Event.GONE)
            return
        if s is S.NOT_ACTIVE:
            if on:
                self.event(n, Event.CALLED)
                self.waited[n] = 0
            return
        if tm.max_presence and self.presence[n] >= tm.max_presence and s is not S.EXIT_STARTED:
            self.event(n, Event.TIMED_OUT)
            return
        if s is S.NOT_ACTIVE_WITH_CALL:
            self.waited[n] += 1
            if not on and self.preempts[n].non_locking and self.waited[n] < tm.delay:
                self.event(n, Event.FORGOTTEN)
        elif s in _SERVING:
            self.since_entry[n] += 1
            self.stage[n] += 1

    def _dwelt(self, n: int) -> bool:
        tm = self.timing[n]
        return (self.stage[n] >= tm.dwell_green and self.since_entry[n] >= tm.min_duration
                and n not in self.control)

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def deadline(self) -> int | None:
        """Steps until the next one at which a preempt's state changes, the inputs as they are (None: none will):
        1 when the next step moves one (:meth:`_moves`), else when a delay, a maximum presence, a track green, a
        minimum dwell or duration runs out."""
        if not self.preempts:
            return None
        if self._moves():
            return 1
        ahead = []
        for n, s in self.states.items():
            tm = self.timing[n]
            if tm.max_presence and n in self.control and s not in (S.MAX_PRESENCE, S.EXIT_STARTED, S.NOT_ACTIVE):
                ahead.append(tm.max_presence - self.presence[n])
            if s is S.NOT_ACTIVE_WITH_CALL:
                ahead.append(tm.delay - self.waited[n])
            elif s is S.TRACK_SERVICE:
                ahead.append(tm.track_green - self.stage[n])
            elif s is S.DWELL:
                ahead += [tm.dwell_green - self.stage[n], tm.min_duration - self.since_entry[n]]
        # A threshold already passed changes nothing by itself (the dwell waits for its call to go, a delay
        # that ran out for a lower-numbered preempt to end): inputs and the rings move those on.
        return min((a for a in ahead if a > 0), default=None)

    def _moves(self) -> bool:
        """The next :meth:`step` changes a preempt's state or the one served (its own questions, asked with the
        timers as they will be then)."""
        ready = []
        for n, s in self.states.items():
            on, tm = n in self.control, self.timing[n]
            if s is S.MAX_PRESENCE or s is S.NOT_ACTIVE:
                if on is (s is S.NOT_ACTIVE):
                    return True  # called, or its input gone
                continue
            if on and tm.max_presence and self.presence[n] + 1 >= tm.max_presence and s is not S.EXIT_STARTED:
                return True  # timed out
            if s is S.NOT_ACTIVE_WITH_CALL:
                if not on and self.preempts[n].non_locking and self.waited[n] + 1 < tm.delay:
                    return True  # forgotten
                if self.waited[n] + 1 >= tm.delay:
                    ready.append(n)
            else:
                ready.append(n)
        top = min(ready, default=None)
        if top != self.serving or (top is not None and self.states[top] is S.NOT_ACTIVE_WITH_CALL):
            return True  # another preempt served, or this one's entry starts
        if top is None or self.states[top] is not S.DWELL:
            return False
        tm = self.timing[top]
        return (self.stage[top] + 1 >= tm.dwell_green and self.since_entry[top] + 1 >= tm.min_duration
                and top not in self.control)

    def skip(self, k: int) -> None:
        for n, s in self.states.items():
            if n in self.control:
                self.presence[n] += k
            if s is S.NOT_ACTIVE_WITH_CALL:
                self.waited[n] += k
            elif s in _SERVING:
                self.since_entry[n] += k
                self.stage[n] += k
