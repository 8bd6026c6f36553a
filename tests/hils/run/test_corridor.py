"""Corridors: many controllers in one run, one middleware each, one clock, one log.

A run of the corridor drives four controllers with their own agents; every record names its
intersection; a fault on one controller's link times that one out and leaves the others serving;
a refused action reaches no controller; the same run goes at the wall clock against four served
emulators through ``hils run --scenario corridor --target targets.toml``.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from collections import Counter
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from harness.bench.processes import start_emulator
from harness.faults.inject import DatagramLoss, FaultTarget, Window
from hils import Testbed
from hils.cli.main import main
from hils.control.actions import ConflictError
from hils.run.testbed import SeveralIntersections
from hils.shell.events import Kind, read
from hils.shell.targets import TargetError

LIGHTS = ["J1", "J2", "J3", "J4"]
RUN_WIDE = {Kind.RUN_STARTED, Kind.RUN_ENDED}


@pytest.fixture(scope="module")
def corridor_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("corridor") / "run"
    console = io.StringIO()
    with contextlib.redirect_stdout(console):
        code = main(["run", "--scenario", "corridor", "--duration", "300", "--no-progress", "--out", str(out)])
    assert code == 0
    return out, console.getvalue()


def test_hils_run_corridor_writes_a_summary_and_plots_per_intersection(corridor_run: tuple[Path, str]) -> None:
    out, _ = corridor_run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario"].startswith("corridor") and list(summary["intersections"]) == LIGHTS
    for tls, control in summary["intersections"].items():
        assert control["transitions_verified"] >= 10 and control["timeouts"] == {}, tls
        assert control["polls"]["polls"] == 3000 and control["polls"]["failed"] == 0, tls
        assert (out / tls / "signal_timeline.svg").stat().st_size > 0
        assert (out / tls / "queues.svg").stat().st_size > 0
    assert (out / "queues.svg").stat().st_size > 0
    # The console names what each intersection's folder holds once, not once per intersection.
    (listed,) = [line for line in corridor_run[1].splitlines() if line.startswith("Outputs in")]
    folders = re.search(r"J1/ \.\. J4/ \(([^)]*)\)", listed)
    assert folders is not None and listed.count("J2") == 0, listed
    assert set(folders[1].split(", ")) == {p.name for p in (out / "J2").iterdir()}
    traffic = summary["traffic"]
    assert traffic["arrived"] > 100 and traffic["waiting_to_enter"] == 0
    # Vehicles enter at the network's edges: the arterial's ends and every cross street, named by light.
    entered = {name for name, a in traffic["approaches"].items() if a["arrived"] + a["running"]}
    assert {"J1 west", "J4 east", "J1 north", "J3 south"} <= entered and "J2 west" not in entered


def test_every_record_of_the_corridor_names_its_intersection(corridor_run: tuple[Path, str]) -> None:
    out, _ = corridor_run
    records = list(read(out / "events.jsonl"))
    assert [r["seq"] for r in records] == list(range(len(records)))
    per_light = Counter(r.get("intersection") for r in records if r["kind"] not in RUN_WIDE)
    assert set(per_light) == set(LIGHTS)  # none without its intersection
    assert records[0]["intersections"] == LIGHTS and "intersection" not in records[0]
    dispatched = Counter(r["intersection"] for r in records if r["kind"] == Kind.COMMAND_DISPATCHED)
    assert all(dispatched[tls] >= 10 for tls in LIGHTS)  # each its own agent, deciding every 10 s


def test_a_lost_link_times_out_only_its_own_controller() -> None:
    """Every datagram to and from J2 is lost for 20 s: J2 enters TIMEOUT (communication) and recovers; the
    other three never leave normal operation and keep verifying transitions through the outage."""
    loss = DatagramLoss("j2-link", window=Window(100.0, 120.0))

    def j2(env: Any, config: Any, **run: Any) -> FaultTarget:
        return FaultTarget(env, config, **run, faults=[loss])

    def run(targets: dict[str, Any]) -> list[dict[str, Any]]:
        with Testbed(scenario="corridor", target=targets, seed=2, duration=240.0, agent="random") as tb:
            tb.reset_all()
            tb.run()
            return tb.records

    records = run({"J1": "virtual", "J2": j2, "J3": "virtual", "J4": "virtual"})
    undisturbed = run(dict.fromkeys(LIGHTS, "virtual"))
    timeouts = [r for r in records if r["kind"] == Kind.TIMEOUT_ENTERED]
    assert [(r["intersection"], r["reason"]) for r in timeouts] == [("J2", "communication")]
    assert [r["intersection"] for r in records if r["kind"] == Kind.RECOVERED] == ["J2"]
    during = Counter(r["intersection"] for r in records
                     if r["kind"] == Kind.TRANSITION_VERIFIED and 100.0 <= r["t"] <= 120.0)
    assert all(during[tls] >= 1 for tls in ("J1", "J3", "J4")) and during["J2"] == 0
    assert loss.fired > 0
    # Each controller keeps its own decision schedule: J2's TIMEOUT asks J2's agent, not the others'.
    for tls in ("J1", "J3", "J4"):
        assert [(r["t"], r["command"]) for r in records if r["kind"] == Kind.COMMAND_DISPATCHED
                and r["intersection"] == tls] == [(r["t"], r["command"]) for r in undisturbed
                                                  if r["kind"] == Kind.COMMAND_DISPATCHED and r["intersection"] == tls]


def test_a_refused_action_reaches_no_controller() -> None:
    with Testbed(scenario="corridor", seed=0, duration=60.0) as tb:
        tb.reset_all()
        sent = len(tb.events.of(Kind.SET_SENT))
        with pytest.raises(ConflictError):
            tb.step_all({"J1": (2, 6), "J2": (1, 2), "J3": (3, 7)})  # 1 and 2 share a ring
        assert len(tb.events.of(Kind.SET_SENT)) == sent and tb.now == pytest.approx(0.0, abs=0.2)
        refused = tb.events.of(Kind.ACTION_REFUSED)
        assert [r["intersection"] for r in refused] == ["J2"]
        observations, infos = tb.step_all({"J1": (2, 6), "J3": (3, 7)})
        assert set(observations) == set(LIGHTS) and infos["J3"]["acted"] and not infos["J2"]["acted"]
        with pytest.raises(SeveralIntersections, match=r"testbed\.intersections\[NAME\]"):
            tb.step((2, 6))


def test_targets_must_name_every_light_and_share_one_clock() -> None:
    with pytest.raises(TargetError, match="no target for J4"):
        Testbed(scenario="corridor", target={"J1": "virtual", "J2": "virtual", "J3": "virtual"})
    with pytest.raises(TargetError, match="one clock"):
        Testbed(scenario="corridor", target={"J1": "snmp://127.0.0.1:1161", "J2": "virtual", "J3": "virtual",
                                             "J4": "virtual"})
    with pytest.raises(TargetError, match="one target per intersection"):
        Testbed(scenario="corridor", target="snmp://127.0.0.1:1161")
    with pytest.raises(TargetError, match=r"^J3: target 'snmp://no-such-host\.invalid': cannot resolve"):
        Testbed(scenario="corridor", target={tls: "snmp://127.0.0.1:1161" for tls in ("J1", "J2", "J4")}
                | {"J3": "snmp://no-such-host.invalid"})
    v3 = "snmp://no-such-host.invalid?version=3&user=u&auth=SHA&auth_key=authsecret&priv=AES&priv_key=privsecret"
    with pytest.raises(TargetError, match="cannot resolve") as refused:
        Testbed(scenario="corridor", target={tls: "snmp://127.0.0.1:1161" for tls in ("J1", "J2", "J4")} | {"J3": v3})
    assert "secret" not in str(refused.value) and "auth_key=..." in str(refused.value)  # keys never printed


@pytest.mark.wallclock
def test_the_corridor_at_the_wall_clock_against_served_emulators(tmp_path: Path, capsys) -> None:
    served = start_emulator(tmp_path / "serve.log", "--scenario", "corridor", count=4)
    try:
        targets = tmp_path / "targets.toml"
        targets.write_text("".join(f'{tls} = "snmp://127.0.0.1:{port}?community=private&version=2c"\n'
                                   for tls, port in zip(LIGHTS, served.ports, strict=True)))
        out = tmp_path / "run"
        code = main(["run", "--scenario", "corridor", "--target", str(targets), "--duration", "12",
                     "--agent", "random", "--no-sumo", "--no-progress", "--out", str(out)])
    finally:
        served.stop()
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "wall-clock"
    for tls, control in summary["intersections"].items():
        assert control["timeouts"] == {} and control["polls"]["answered"] >= 100, tls
        assert control["commands_dispatched"] >= 1, tls
    assert "4 controllers, wall-clock" in capsys.readouterr().out


def test_the_controllers_of_a_corridor_start_spread_over_one_poll_period() -> None:
    """So that their polls, keepalives and read-backs do not all go out at one instant (a burst that makes a
    grid's last answers of each round late at the wall clock)."""
    with Testbed(scenario="corridor", duration=1.0) as tb:
        tb.reset_all()
        starts = {r["intersection"]: r["t"] for r in tb.records
                  if r["kind"] == Kind.SET_SENT and r["purpose"] == "startup"}
        polls = {tls: [r["t"] for r in tb.records if r["kind"] == Kind.POLL and r["intersection"] == tls]
                 for tls in starts}
    period = tb.intersections["J1"].config.middleware.poll_period
    assert list(starts) == ["J1", "J2", "J3", "J4"]
    gaps = [b - a for a, b in pairwise(starts.values())]
    assert gaps == pytest.approx([period / 4] * 3)
    assert len({round(ts[0] % period, 4) for ts in polls.values()}) == 4
