"""The controller as its NTCIP agent sees it: call-processing and status-update delays.

Rules of this file
------------------
- The controller model (:mod:`emulator.model.controller`) knows nothing of these
  delays: it is wrapped, never edited. Everything the MIB view reads or writes
  goes through :class:`DelayedController`, which has the controller's surface.
- Delays are whole controller ticks (0.1 s), counted with the controller's own
  integer tick counter; no float time is compared here.
- A SET is stored at once (a GET of a control object reads back what was SET,
  as a real controller's NTCIP database does); only its effect on the phase
  logic waits.

Theory of operation
-------------------
A real controller (Econolite Cobalt class) is a timing application and an
NTCIP agent sharing a database. Three things stand between a SET of
``phaseControlGroupVehCall`` and the new green showing in
``phaseStatusGroupGreens``, beside the yellow and red clearance themselves:

1. **The tick phase.** The application reads its inputs once per 0.1 s tick;
   a SET waits for the next tick. The tick grid has its own phase against the
   middleware's clock (drawn from the seed in :mod:`emulator.inprocess`), so
   this wait is anywhere in (0, 0.1] s.
2. **Call processing** (``call_processing_ticks``): the tick that reads a call
   decides on it and the outputs change at a later tick (inputs, logic and
   load-switch outputs are a pipeline). Here: a SET received before tick T
   reaches the phase logic at tick T + ``call_processing_ticks``.
3. **Status update** (``status_update_ticks``): the agent answers status GETs
   from an image the application publishes once per tick; the image lags the
   lamps by this many ticks. Here: a ring buffer of one status snapshot per
   tick, read ``status_update_ticks`` behind (without a lag, the live status).

Calibration. The paper measured holds of 5.18-5.20 s per transition against a
Cobalt at 10 Hz (nominal 5 s), its verification thread polling "every 0.1 s"
from the dispatch. It does not say how that loop was timed; our reading (an
inference, not the paper's words): it slept 0.1 s after each poll of three
GETs, so its polls came every ~0.1036-0.104 s and the verifying poll was the
50th (5.18-5.20 s), the green not yet visible at the 49th (~5.08-5.10 s).
With the tick wait in (0, 0.1] s that puts the controller's own extra latency
at about 0.08-0.1 s: one tick. The defaults (``[emulator]`` in the intersection config)
are therefore one tick of call processing and none of status update; only
their sum shows in a hold, and the split follows the pipeline in 2.

What a hold looks like here. The middleware polls on a fixed grid that does
not drift and that the agent's decisions share in virtual time, so a hold is
a whole number of poll periods plus the GET's response time: with the
defaults, 5.2 s + 2 ms at 10 Hz for every transition (0.1 s tick wait + 0.1 s
call processing + 5 s clearance, seen at the next poll). Per-transition jitter
inside the controller (where a SET lands in the tick, when the status scan
runs) cannot spread that: it only moves a hold by a whole poll period
(to 5.1 or 5.3 s), far outside the paper's 20 ms band, so none is drawn. By
the reading above, the paper's 20 ms spread came from its own poll loop's
drift, which a fixed grid does not have. At 50 and 100 Hz the tick phase does show: holds spread over
one poll period across seeds.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from emulator.model.controller import Controller
from hils.protocol.config import EmulatorParams
from hils.protocol.ntcip import ControlColumn

#: Controller attributes the NTCIP agent reads as status: published once per tick, late by the status delay.
STATUS_ATTRIBUTES = ("reds", "yellows", "greens", "phase_ons", "phase_nexts", "calls", "walks", "ped_clears",
                     "dont_walks", "ped_calls", "overlap_reds", "overlap_yellows", "overlap_greens")


@dataclass(frozen=True, slots=True)
class StatusImage:
    """What the agent answers for status objects: one snapshot of the controller after a tick."""

    version: int  # the controller's status_version when it was taken
    values: dict[str, frozenset[int]]

    @classmethod
    def of(cls, controller: Controller) -> StatusImage:
        return cls(controller.status_version, {name: getattr(controller, name) for name in STATUS_ATTRIBUTES})


@dataclass(frozen=True, slots=True)
class PendingSet:
    """A SET of one control object waiting for the tick that processes it."""

    due: int  # the controller applies it just before the step that starts at this tick count
    column: ControlColumn
    phases: frozenset[int]


class DelayedController:
    """A controller behind its call-processing and status-update delays, with the controller's surface.

    The MIB view, the in-process target and the served emulator use this object as they would the
    controller: :meth:`step` ticks, :meth:`set_control` takes SETs, the status attributes
    (:data:`STATUS_ATTRIBUTES`) answer from the published image, ``control`` reads back the NTCIP
    database (SETs not yet processed included), and every other attribute is the controller's own.
    """

    def __init__(self, controller: Controller, delays: EmulatorParams) -> None:
        self.controller = controller
        self.delays = delays
        self._pending: list[PendingSet] = []
        # The status of the last ``status_update_ticks`` ticks, oldest first (none without a lag).
        self._images: deque[StatusImage] = deque(maxlen=delays.status_update_ticks)
        self._fill_images()

    # The controller's own tick loop and its quiet-time stepping, driving this object's step and skip.
    process = Controller.process
    advance = Controller.advance

    @property
    def status(self) -> Controller | DelayedController:
        """Where status objects are read: the published image when it lags, else the controller itself
        (status is read at up to 100 Hz; the lookup through this wrapper is not free)."""
        return self if self._images.maxlen else self.controller

    def reset(self) -> None:
        """Power-up: the controller resets, SETs not yet processed are lost, the image starts afresh."""
        self.controller.reset()
        self._pending.clear()
        self._fill_images()

    def step(self) -> None:
        """One tick: process the SETs that are due, time the controller, publish its status."""
        due = [p for p in self._pending if p.due <= self.controller.tick]
        if due:
            self._pending = [p for p in self._pending if p.due > self.controller.tick]
            for p in due:
                self.controller.set_control(p.column, p.phases)
        if self._images.maxlen:
            self._images.append(StatusImage.of(self.controller))
        self.controller.step()

    @property
    def tick(self) -> int:
        """The controller's tick count (the event clock reads it at every step: not through ``__getattr__``)."""
        return self.controller.tick

    @property
    def status_version(self) -> int:
        """Counts changes of the status the agent answers (the image's, when it lags)."""
        return self._images[0].version if self._images.maxlen else self.controller.status_version

    def quiet_ticks(self) -> int | None:
        """The controller's quiet ticks, up to the step that hands it a waiting SET; every tick is stepped
        while the published image still shows older status."""
        if self._images.maxlen and self._images[0].version != self.controller.status_version:
            return 1
        quiet = self.controller.quiet_ticks()
        if self._pending:
            # A SET due at tick d is processed by the step that starts at tick d.
            due = max(1, min(p.due for p in self._pending) - self.controller.tick + 1)
            quiet = due if quiet is None else min(quiet, due)
        return quiet

    def skip(self, n: int) -> None:
        """Quiet ticks at once: no SET is due and every image is the current status, so nothing but the
        controller's counters moves."""
        self.controller.skip(n)

    def set_control(self, column: ControlColumn, phases: Iterable[int]) -> None:
        """A SET of one control object: stored now, processed ``call_processing_ticks`` ticks after the next tick."""
        self._pending.append(PendingSet(self.controller.tick + self.delays.call_processing_ticks, column,
                                        frozenset(phases)))

    @property
    def control(self) -> dict[ControlColumn, frozenset[int]]:
        """The control objects as the NTCIP database holds them: the latest SET of each, processed or not."""
        out = dict(self.controller.control)
        for p in self._pending:
            out[p.column] = p.phases
        return out

    # Writable objects of the unit go to the controller itself (the backup time through set_backup_time): an
    # attribute set on this wrapper would shadow the controller's and change nothing it does.
    @property
    def startup_flash(self) -> int:
        """unitStartUpFlash (s): the flash the controller shows when power is restored, from its next power-up."""
        return self.controller.startup_flash

    @startup_flash.setter
    def startup_flash(self, value: int) -> None:
        self.controller.startup_flash = value

    def __getattr__(self, name: str) -> Any:
        # Only reached for attributes not defined above: status from the image, the rest from the controller.
        if name.startswith("_"):
            raise AttributeError(name)  # own state not set up yet (copy, pickle): never the controller's
        if name in STATUS_ATTRIBUTES and self._images.maxlen:
            return self._images[0].values[name]
        return getattr(self.controller, name)

    def _fill_images(self) -> None:
        # At power-up the image shows the start-up state, however far behind it runs.
        image = StatusImage.of(self.controller)
        self._images.clear()
        self._images.extend([image] * self._images.maxlen)
