"""The dashboard: see the signal while a run runs (``hils run --dashboard PORT``) or after (``hils view``).

- :mod:`hils.dashboard.board`: what the page shows, folded from the event log (live and replay alike);
- :mod:`hils.dashboard.server`: the Starlette app (page, snapshots, server-sent events, recover);
- :mod:`hils.dashboard.live`: serving a wall-clock run from its own asyncio loop;
- :mod:`hils.dashboard.cli`: ``hils view RUN_DIR``, the replay with a time slider;
- ``static/``: the page, its script and style, shipped with the package (no build step, nothing fetched).
"""

from hils.protocol.errors import UserError


class DashboardError(UserError):
    """The dashboard cannot start: its port is taken, a run folder without an event log, a run not at wall clock."""
