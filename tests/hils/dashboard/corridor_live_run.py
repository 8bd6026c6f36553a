"""A wall-clock corridor run with the live dashboard, for test_dashboard_browser.py.

``python tests/hils/dashboard/corridor_live_run.py RUN_DIR URL...``: one ``snmp://`` URL per traffic light of the
corridor,
in the scenario's order; prints the dashboard's URL, runs until SIGINT (or 600 s) with SUMO, the page's
Recover button enabled and no automatic recovery. The fixed-cycle agent advances every controller at
every decision (every 10 s, the first at once), so that every panel changes within seconds. It assembles
the run as ``hils run --scenario corridor --target ... --dashboard 0 --dashboard-control`` does: the
Testbed of the scenario, the dashboard's ``attach`` as the on_reset hook, the server stopped before the
Testbed closes its loop.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hils.dashboard.live import LiveDashboard
from hils.protocol.scenario import load_scenario
from hils.run.testbed import RunInterrupted, Testbed


def main(run_dir: str, *urls: str) -> None:
    lights = load_scenario("corridor").tls_ids
    dashboard = LiveDashboard(0, control=True)
    tb = Testbed(scenario="corridor", target=dict(zip(lights, urls, strict=True)), sumo=True, duration=600.0,
                 action_type="switch", agent="fixed-cycle", log_path=Path(run_dir) / "events.jsonl",
                 recover_after=None, on_reset=dashboard.attach)
    with tb:
        try:
            tb.reset_all()
            tb.run()
        except (RunInterrupted, KeyboardInterrupt):
            pass
        finally:
            dashboard.stop()


if __name__ == "__main__":
    main(*sys.argv[1:])
