"""Virtual time's fast path: what a run leaves out because nothing left out could change a result.

One switch, a flag of the run: ``Testbed(fast_path=True)``, the default. ``fast_path=False`` is the reference
every rule below is held to, record for record (``tests/hils/shell/test_poll_elision.py``,
``tests/hils/shell/test_fast_path.py``):
the controller stepped at every 0.1 s tick, every poll and every read-back sent, SUMO stepped one step at a
time through the run's step cost. Nothing else chooses the path: no part compares functions or guesses from
what it was handed, and wrapping a cost function or a transport in a fault leaves the path as the flag says
(the fault is seen wherever it may act, and the rest stays fast).

What is left out, and why the result is the same
------------------------------------------------
1. The controller's quiet ticks (``emulator/model/event_clock.py``): after each real step the controller says how
   many ticks ahead the next step that may change anything is, and only that step is scheduled; a write
   brings the counters up to the present first, so a SET lands on the tick it would have landed on.
   The emulator's target takes the flag (``VirtualTarget(fast_path=...)``): without it, every tick is stepped.
2. Polls that cannot see a change (:class:`QuietPolls`): an in-process controller is the transport's
   *change feed* (:class:`ChangeFeed`): its ``version`` moves whenever what a GET answers could change (a
   write, a change of status). A transport that knows its feed is its run's *foresight* (:class:`Foresight`);
   the :class:`hils.shell.transport.Transport` interface knows nothing of it, and a transport over the wire has
   none. A poll whose feed version is the one the newest answered poll read would get
   that same answer at the same latency: it is counted on the poll grid (its poll id used up) and not sent,
   and the poller sleeps until the feed moves. What the signal cache holds, and when the manager sees it, is
   what polling every period gives. A SET of ours moves the feed but changes no answer by itself: when the
   newest answer read again would only be counted (:meth:`hils.control.manager.Manager.counts_only`: no transition
   it verifies), the polls stay left out, and the one poll the SET would have sent (the first of the grid not before
   it) is counted as answered, as it was when a SET woke the poller: ``run_ended``'s counts are what they were.
3. Read-backs of the control objects that cannot see a change (:class:`QuietReadbacks`): only a write of a
   control object can give one phases (the controller itself only clears them); the feed's ``controls``
   moves on such a write, and a read-back that found the objects ours sleeps until someone else's moves it
   (the middleware's own SETs, whose values it knows, leave it asleep).
4. SUMO's steps one by one (:func:`steps_before`): while nothing else is due and the steps cost nothing, the
   step due and the quiet ones after it run in one libsumo call; nothing SUMO shows can change in between.

Where the fast path stops short, and who says so
------------------------------------------------
- A transport offers a change feed only while the answer to a GET, and its time, are known without sending
  it: :class:`hils.shell.transport.LocalTransport` without loss or jitter; the fault harness's transport only while
  no fault may act on a request (it wakes a sleeping poller when one may). Over the wire there is none: the run
  hands the middleware no foresight (:func:`hils.shell.targets.connect` says which transport has one).
- A step cost says until when steps are free (:meth:`StepCost.free_until`): the modeled cost of virtual time
  always; a slow-steps fault until its window opens and again once it is spent; the wall clock never. A cost
  that must see every step says so (:func:`every_step`).
- Detector feeds SET the controller at every step: a run with detectors steps SUMO one step at a time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

import simpy

from hils.protocol.timegrid import Grid

__all__ = ["ChangeFeed", "Foresight", "QuietPolls", "QuietReadbacks", "StepCost", "every_step", "modeled_cost",
           "steps_before"]


class ChangeFeed(Protocol):
    """What an in-process controller can tell its poller: when a GET could start answering differently.

    ``version`` moves whenever it could (a write, a change of the status the controller answers);
    ``changed()`` is an event that fires when it next moves. ``controls`` moves whenever a control
    object could have been given phases (a write of one), ``controls_changed()`` when it next moves."""

    version: int
    controls: int

    def changed(self) -> simpy.Event: ...

    def controls_changed(self) -> simpy.Event: ...

    def bump(self) -> None:
        """Something besides the controller changed what a GET may answer (a transport's loss, say)."""
        ...


class Foresight(Protocol):
    """A transport's knowledge of when its answer can change: its change feed while the answer to a GET, and its
    time, are known without sending it, and None while they are not (a loss or a fault that may act)."""

    @property
    def change_feed(self) -> ChangeFeed | None: ...


class StepCost(Protocol):
    """What a simulation step costs: run ``step`` and return the seconds it took (modeled, or measured)."""

    def __call__(self, step: Callable[[], Any]) -> float: ...

    def free_until(self, now: float) -> float:
        """The time before which every step costs nothing (``now`` or earlier: the step due now may cost)."""
        ...


class _Modeled:
    """Virtual time: a step costs no simulated time, ever."""

    def __call__(self, step: Callable[[], Any]) -> float:
        step()
        return 0.0

    def free_until(self, now: float) -> float:
        return math.inf


#: The step cost of virtual time.
modeled_cost: StepCost = _Modeled()


class _EveryStep:
    def __init__(self, cost: Callable[[Callable[[], Any]], float]) -> None:
        self.cost = cost

    def __call__(self, step: Callable[[], Any]) -> float:
        return self.cost(step)

    def free_until(self, now: float) -> float:
        return now


def every_step(cost: Callable[[Callable[[], Any]], float]) -> StepCost:
    """A cost function that must see every step (it may make any of them cost): SUMO is stepped one step at a
    time while it is the run's."""
    return _EveryStep(cost)


#: Steps run back to back at most when no other event is queued (one simulated hour at 0.25 s).
MAX_STRETCH = 14400


def steps_before(until: float, grid: Grid, k: int) -> int:
    """How many steps of the grid, from step k on, start before ``until``: those a stretch may run at once."""
    if math.isinf(until):
        return MAX_STRETCH  # nothing else will ever happen: step on, a stretch at a time
    return grid.first_at_or_after(until, k) - k


class QuietPolls:
    """Which polls of a poller need not be sent (rule 2): ``newest()`` is the newest poll answered and applied;
    ``counts_only()`` says whether an answer showing what it showed would only be counted (no transition verified by
    it, no state left)."""

    def __init__(self, foresight: Foresight, newest: Callable[[], int], counts_only: Callable[[], bool]) -> None:
        self.foresight = foresight
        self.newest = newest
        self.counts_only = counts_only
        self._sent = 0  # the newest poll sent
        self._seen: int | None = None  # the feed's version when the newest poll sent read the controller

    def leaves_out(self, poll_id: int) -> bool:
        """True when poll ``poll_id`` would get the newest answer again; otherwise it goes out, reading the
        feed's version of now."""
        if self._unchanged():
            return True
        feed = self.foresight.change_feed
        self._sent, self._seen = poll_id, feed.version if feed is not None else None
        return False

    def still(self) -> bool:
        """True while a poll would get the newest answer again (the feed moved by a SET of ours alone, say)."""
        return self._unchanged()

    def before_write(self) -> int | None:
        """A SET of ours is about to be sent: the feed's version while polls would be left out, else None."""
        return self.foresight.change_feed.version if self._unchanged() else None

    def written(self, before: int | None) -> bool:
        """The SET is sent: True when the polls left out before it stay left out. A write moves the feed's version
        once and changes no answer of a poll by itself (the controller's next step may, and moves it again); so when
        the feed moved by that one move alone and the newest answer would only be counted again, the next poll would
        read what the newest did, to no effect."""
        feed = self.foresight.change_feed
        if before is None or feed is None or feed.version != before + 1 or not self.counts_only():
            return False
        self._seen = feed.version
        return True

    def moved(self) -> simpy.Event:
        """After a poll left out: the event to sleep on, the feed's next move (every poll until then would be left
        out too)."""
        return self.foresight.change_feed.changed()

    def forget(self) -> None:
        """Polling halted: the first poll after it goes out."""
        self._seen = None

    def _unchanged(self) -> bool:
        feed = self.foresight.change_feed
        return feed is not None and self._seen == feed.version and self.newest() == self._sent


class QuietReadbacks:
    """Which read-backs of the control objects need not be sent (rule 3)."""

    def __init__(self, foresight: Foresight) -> None:
        self.foresight = foresight
        self._ours: int | None = None  # the feed's controls when a read-back last found the control objects ours

    def asleep(self) -> simpy.Event | None:
        """The event to sleep on while a read-back would find the control objects ours again (someone writing
        one), or None when it goes out."""
        feed = self.foresight.change_feed
        return feed.controls_changed() if feed is not None and feed.controls == self._ours else None

    def sent(self) -> int | None:
        """A read-back goes out: the feed's controls it reads."""
        feed = self.foresight.change_feed
        return feed.controls if feed is not None else None

    def writing(self) -> Callable[[], None]:
        """The middleware SETs control objects to values it knows: call the function returned once the SET is
        sent; a read-back asleep on objects found ours stays asleep (they are still ours)."""
        before = self.sent()

        def sent() -> None:
            if before is not None and before == self._ours:
                self._ours = self.sent()
        return sent

    def found(self, controls: int | None, ours: bool) -> None:
        """What the read-back sent at ``controls`` found: the objects ours (or not)."""
        self._ours = controls if ours else None
