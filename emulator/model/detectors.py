"""The detector unit: which vehicle detector inputs the controller recognizes, by each detector's delay, extension
and carryover.

Rules of this file
------------------
- Time is integer ticks, as in the controller. :meth:`Detectors.step` is the only thing that moves the timers, once
  per controller tick before the inputs are read (:mod:`emulator.model.inputs` reads :attr:`Detectors.recognized`
  as the actuated detectors).
- A detector with no timer is its input: recognized on the tick its actuation comes, dropped on the tick it goes.
- :meth:`Detectors.deadline` says when a timer next changes what is recognized, so that quiet time
  (:mod:`emulator.model.quiet`) skips no tick that would.

Theory of operation
-------------------
NTCIP 1202 vehicleDetectorDelay: "The period a detector actuation (input recognition) shall be delayed when the
phase is not Green". An actuation present while its phase is not green is recognized once it has lasted the delay
without a break; one that ends before that is never recognized ("If vehicle detection is lost during the delay time
period the delay timer is reset to zero", RAE H2 loop detector manual, "Detect Output Delay"). An actuation while
its phase is green, or a delaying one whose phase turns green, is recognized at once.

vehicleDetectorExtend: "The period a vehicle detector actuation (input duration) shall be extended from the point
of termination, when the phase is Green"; carryover holds it so long after the vehicle leaves whatever the phase
shows (the detector unit's "Detect Output Extension": "the time following the loss of detection before the Detect
Output is dropped"). A recognized detector whose input goes is held while either runs; an actuation coming again
in that time keeps it recognized and restarts them when it goes ("a full extension time period follows the
departure of the last detected vehicle").

vehicleDetectorOptions bit 2, "Yellow Lock Call - if Enabled, the detector will lock a call to the assigned phase if
an actuation occurs while the phase is not timing Green": a locking detector recognized while its phase is not green
stays recognized, its input gone or not, until its phase shows green.

What the phases show is read from the tick before (the unit steps before the rings time): a detector's call goes
to its phase a tick after that phase's green ends, as a real controller's detector scan follows its outputs.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass

from hils.protocol.config import IntersectionConfig


@dataclass(slots=True)
class DetectorTimers:
    """A detector's timers in ticks; mutable so the detector table can be retimed over SNMP."""

    delay: int = 0
    extend: int = 0
    carryover: int = 0
    lock: bool = False  # yellow lock call: recognized off the phase's green, held until it is green

    def hold(self, green: bool) -> int:
        """Ticks a recognized actuation is held after its input goes: carryover, or the extension while green."""
        return max(self.carryover, self.extend if green else 0)



class Detectors:
    """The vehicle detectors' timers of one controller, and the detectors it recognizes as actuated."""

    def __init__(self, config: IntersectionConfig) -> None:
        #: Each wired detector's phase. A detector wired to none may still be given timers over NTCIP (its table row
        #: exists up to maxVehicleDetectors): they time, and its recognized actuation calls nothing.
        self.phase = config.detectors
        #: The detectors that have a timer (the others are their input).
        self.timers = {d: DetectorTimers(round(t.delay * 10), round(t.extend * 10), round(t.carryover * 10), t.lock)
                       for d, t in config.detector_timing.items() if d in self.phase}
        #: The locking detectors: from the config only (vehicleDetectorOptions is not writable here), so fixed.
        self.locking = frozenset(d for d, t in self.timers.items() if t.lock)
        self.reset()

    def reset(self) -> None:
        """Power-up: nothing actuated, no timer running."""
        self.recognized: frozenset[int] = frozenset()
        self.waited: dict[int, int] = {}  # a delaying detector: ticks its actuation has lasted
        self.held: dict[int, int] = {}  # a recognized detector whose input went: ticks since it did
        self.locked: set[int] = set()  # a locking detector recognized off its phase's green, until it is green

    def timer(self, d: int, name: str) -> int:
        """One timer of detector ``d``, in ticks (0 for a detector that has none)."""
        t = self.timers.get(d)
        return 0 if t is None else getattr(t, name)

    def retime(self, d: int, name: str, ticks: int, actuated: frozenset[int]) -> None:
        """A SET of the detector table: one timer of detector ``d``, acting from the controller's next tick. A unit
        that had no timer passed the inputs ``actuated`` now as they are: it recognizes them from here."""
        if not self.timers:
            self.recognized = actuated
        t = self.timers.setdefault(d, DetectorTimers())
        setattr(t, name, ticks)
        if not any(astuple(t)):
            del self.timers[d]
            self.waited.pop(d, None)
            self.held.pop(d, None)
            self.locked.discard(d)

    def step(self, actuated: frozenset[int], greens: frozenset[int]) -> bool:
        """One tick: what is recognized, from the inputs actuated now and the phases green (the tick before).
        True when that changed."""
        timers = self.timers
        recognized = set(actuated - timers.keys())
        waited, held = self.waited, self.held
        for d, t in timers.items():
            green = self.phase.get(d) in greens
            if d in actuated:
                held.pop(d, None)
                if d in self.recognized or green or t.delay == 0:
                    waited.pop(d, None)
                    recognized.add(d)
                else:
                    waited[d] = waited[d] + 1 if d in waited else 0
                    if waited[d] >= t.delay:
                        del waited[d]
                        recognized.add(d)
                continue
            waited.pop(d, None)
            if d in self.recognized:
                held[d] = held[d] + 1 if d in held else 0
                if held[d] < t.hold(green):
                    recognized.add(d)
                else:
                    del held[d]
        if self.locking:  # held off its phase's green, let go as it shows green
            self.locked = {d for d in self.locked | (recognized & self.locking) if self.phase.get(d) not in greens}
        recognized = frozenset(recognized | self.locked)
        changed = recognized != self.recognized
        self.recognized = recognized
        return changed

    # --- quiet time (see emulator/model/quiet.py) -------------------------------------------------

    def deadline(self, actuated: frozenset[int], greens: frozenset[int]) -> int | None:
        """Steps until a timer changes what is recognized (None: no timer runs); at least the next step. A delaying
        detector whose phase shows green is recognized at the next step; an input no step has read yet (``actuated``
        changed during the start-up flash, which reads no input) is read by the next step."""
        if (actuated ^ self.recognized) - self.waited.keys() - self.held.keys() - self.locked:
            return 1
        ahead = [1 if self.phase.get(d) in greens else self.timers[d].delay - w for d, w in self.waited.items()]
        ahead += [1 for d in self.locked if self.phase.get(d) in greens]
        ahead += [self.timers[d].hold(self.phase.get(d) in greens) - h for d, h in self.held.items()]
        return max(1, min(ahead)) if ahead else None

    def skip(self, n: int) -> None:
        for d in self.waited:
            self.waited[d] += n
        for d in self.held:
            self.held[d] += n

