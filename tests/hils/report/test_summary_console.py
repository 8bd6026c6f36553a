"""The run's console summary as a newcomer reads it."""

from __future__ import annotations

from hils.report import summary
from hils.run.testbed import Testbed


def test_an_approach_fed_by_a_neighbour_reads_no_vehicles_entered_not_zero_beside_its_queue() -> None:
    """Seen as a user: the corridor's rows read 0 vehicles arrived, running and waiting beside a max queue of 6: its
    figures count vehicles by the approach they entered the network on, and none enters between two lights."""
    with Testbed(scenario="corridor", sumo=True, duration=180.0, seed=0) as tb:
        tb.reset_all()
        tb.run()
        s = summary.summarize({i.label: (i.tally, i.config) for i in tb.intersections.values()}, traffic=tb.traffic)
    approaches = s["traffic"]["approaches"]
    fed = [name for name, a in approaches.items() if not a["departed"] and not a["waiting_to_enter"]]
    assert "J2 west" in fed and "J1 west" not in fed and any(approaches[name]["max_queue"] for name in fed)
    lines = summary.render(s).splitlines()
    for name, a in approaches.items():
        (row,) = [line for line in lines if line.startswith(f"    {name} ")]
        cells = row[len(f"    {name}"):].split()
        if name in fed:
            assert cells[:4] == ["-"] * 4 and cells[4] == str(a["max_queue"]), row
        else:
            assert cells[:3] == [str(a["arrived"]), str(a["running"]), str(a["waiting_to_enter"])], row
    assert "    -: no vehicle entered the network there (arrived, running, waiting and mean delay count" in lines
