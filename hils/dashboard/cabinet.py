"""What the cabinet shows beyond the signal, read for the dashboard: walks, calls, PhaseNext and overlaps.

The middleware polls reds, yellows and greens only: that is what the manager verifies, ten times a
second. The page also shows each phase's pedestrian indication, its vehicle and pedestrian calls as the
controller holds them (from detectors and recalls too, not only the middleware's VehCall), the phase the
ring will serve next, and the overlaps' greens and yellows (overlapStatusGroup). A dashboard run reads
those at a low rate (:data:`PERIOD_S`) on the run's own SimPy environment, through the run's transport,
as one GET beside the polls. A change is logged as a ``cabinet`` record, so a replay of the run shows
what the live page showed. A read that fails is let go: the poller counts failures and the manager
decides what they mean.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import simpy

from hils.protocol.ntcip import (
    OVERLAP_STATUS_TABLE,
    OverlapStatusColumn,
    SnmpError,
    StatusColumn,
    groups_to_phases,
    status_oid,
)
from hils.shell.events import EventLog, Kind
from hils.shell.transport import Transport, TransportError

#: Seconds between two reads: a walk lasts seconds, and the strip is drawn at this resolution.
PERIOD_S = 1.0

#: The status columns read, in the order of the ``cabinet`` record's fields.
COLUMNS: dict[str, StatusColumn] = {
    "walks": StatusColumn.WALKS,
    "ped_clears": StatusColumn.PED_CLEARS,
    "veh_calls": StatusColumn.VEH_CALLS,
    "ped_calls": StatusColumn.PED_CALLS,
    "nexts": StatusColumn.PHASE_NEXTS,
}
#: The overlap status columns read (overlap numbers, 1 = A), after the phase columns; empty lists without overlaps.
OVERLAP_COLUMNS: dict[str, OverlapStatusColumn] = {
    "overlap_greens": OverlapStatusColumn.GREENS,
    "overlap_yellows": OverlapStatusColumn.YELLOWS,
}


def read_cabinet(env: simpy.Environment, transport: Transport, log: EventLog, groups: int,
                 period: float = PERIOD_S, *, overlap_groups: int = 0) -> Generator[simpy.Event, Any, None]:
    """A SimPy process: read the cabinet's status every ``period`` s, log a ``cabinet`` record on change."""
    oids = [status_oid(col, g) for col in COLUMNS.values() for g in range(1, groups + 1)]
    oids += [OVERLAP_STATUS_TABLE[col].instance(g) for col in OVERLAP_COLUMNS.values()
             for g in range(1, overlap_groups + 1)]
    last: dict[str, list[int]] | None = None
    while True:
        try:
            values = yield transport.get(oids)
        except (TransportError, SnmpError):
            values = None
        if values is not None:
            masks = [int(v) for v in values]
            shown = {name: sorted(groups_to_phases(masks[i * groups:(i + 1) * groups]))
                     for i, name in enumerate(COLUMNS)}
            rest = masks[len(COLUMNS) * groups:]
            shown |= {name: sorted(groups_to_phases(rest[i * overlap_groups:(i + 1) * overlap_groups]))
                      for i, name in enumerate(OVERLAP_COLUMNS)}
            if shown != last:
                log.emit(Kind.CABINET, **shown)
                last = shown
        yield env.timeout(period)
