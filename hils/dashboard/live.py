"""The live dashboard of a wall-clock run: a board fed by the run's event log, served on the run's loop.

:func:`attach` is given to :class:`hils.Testbed` as its ``on_reset`` hook: the run is then assembled
(its event log and its wall-clock driver exist) and nothing has started, so the board sees every
record from ``run_started`` on; the cabinet's walks, calls and PhaseNext are read from then on too
(:mod:`hils.dashboard.cabinet`), for every controller of the run. A run of several controllers (a
scenario) gets one panel per intersection (:class:`hils.dashboard.board.Panels`), placed as on the
network's map. The server is a task on ``driver.loop``; a recovery asked for from the page is delivered
to SimPy as an event through the driver, so it runs between two SimPy steps like every other completion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hils.dashboard import DashboardError
from hils.dashboard.board import Board, Panels
from hils.dashboard.cabinet import read_cabinet
from hils.dashboard.server import Live, LiveServer, bind

if TYPE_CHECKING:
    from hils.run.intersection import Intersection


@dataclass
class LiveDashboard:
    """``hils run --dashboard PORT``: where to listen and whether the page may recover the manager."""

    port: int
    control: bool = False
    host: str = "127.0.0.1"
    server: LiveServer | None = field(default=None, init=False)

    def attach(self, testbed: Any) -> None:
        """The Testbed's ``on_reset`` hook: start serving this run's board (one panel per controller)."""
        driver = testbed.driver
        if driver is None:
            raise DashboardError("--dashboard needs a wall-clock run (--target snmp://...); watch a virtual-time "
                                 "run afterwards with `hils view RUN_FOLDER --realtime 10`")
        if self.server is not None:
            self.stop()
        intersections = testbed.intersections
        first = next(iter(intersections.values()))
        if first.label is not None:
            from hils.sim.network import light_positions

            board: Board | Panels = Panels.of({name: i.config for name, i in intersections.items()},
                                              light_positions(testbed.scenario),
                                              {name: _counter(i) for name, i in intersections.items()})
        else:
            board = Board(first.config, counter=_counter(first))
        testbed.events.subscribe(board.feed)
        for i in intersections.values():
            testbed.env.process(read_cabinet(testbed.env, i.transport, i.events, i.config.groups,
                                             overlap_groups=i.config.overlap_groups))
        live = Live(board, recover=(lambda tls: _request_recovery(testbed, tls)) if self.control else None)
        self.server = LiveServer(live, bind(self.host, self.port), driver.loop)
        print(f"dashboard: {self.server.url}", flush=True)

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None


def _counter(intersection: Intersection) -> Callable[[], dict[str, int]]:
    """The intersection's poll counts, read at each snapshot."""
    return lambda: intersection.middleware.poll_counts


def _request_recovery(testbed: Any, tls: str | None) -> str:
    """Ask the manager (of traffic light ``tls`` in a run of several) to recover; runs as a SimPy event
    delivered at the wall-mapped present."""
    if testbed.ended or not testbed.intersections:
        return "the run has ended"
    mw = (testbed.intersections[tls] if tls is not None else testbed.intersection).middleware
    if not mw.timeout_flag:
        return f"nothing to recover: the manager is {mw.state.name}"
    event = testbed.env.event()
    event.callbacks.append(lambda _ev: mw.recover())
    testbed.driver.deliver(event)
    return "requested"
