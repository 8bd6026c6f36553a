"""The public Testbed: step semantics per action type, in virtual time and against `hils emulator serve`,
and every way a run can end (normal, agent error, Ctrl-C, SIGTERM) leaving the calls cleared and a summary."""

from __future__ import annotations

import io
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from harness.bench.processes import start_emulator, tool
from harness.faults.inject import DatagramLoss, FaultTarget, Window
from hils import ActionError, State, Testbed
from hils.cli.status import StatusLine
from hils.control.actions import ConflictError
from hils.protocol.config import DEFAULT_CONFIG_NAME, IntersectionConfig, load
from hils.protocol.ntcip import UNIT_CONTROL_STATUS, ControlColumn, control_oid, oid_str
from hils.shell.events import Kind, read

CFG = load()


def kinds(tb: Testbed, kind: Kind) -> list[dict[str, Any]]:
    return [r for r in tb.records if r["kind"] == kind]


def test_selection_step_runs_one_control_interval() -> None:
    with Testbed(CFG, action_type="selection", seed=0) as tb:
        obs = tb.reset()
        assert obs.signal is not None and obs.signal.greens == {2, 6}
        assert obs.state is State.IDLE
        t0 = obs.t
        obs, info = tb.step((3, 7))
        assert obs.t == pytest.approx(t0 + CFG.middleware.control_interval)
        assert info == {"t": obs.t, "action_id": 1, "acted": True, "dropped": False, "state": "idle",
                        "timeout": False, "timeout_reason": None, "refused": None, "ended": False, "due": True}
        assert obs.signal.greens == {3, 7}
        # A numpy pair, as a policy network hands it over, is the same action.
        obs, info = tb.step(np.array([4.0, 8.0], dtype=np.float32))
        assert not info["dropped"] and obs.signal.greens == {4, 8}


def test_switch_step_keep_and_advance() -> None:
    with Testbed(CFG, action_type="switch") as tb:
        tb.reset()
        obs, _ = tb.step(np.int64(0))
        assert obs.signal.greens == {2, 6} and not kinds(tb, Kind.COMMAND_DISPATCHED)
        obs, _ = tb.step(np.float32(1.0))
        assert obs.signal.greens == {3, 7} and obs.next_pair == (4, 8)


def test_duration_step_returns_when_the_green_has_been_served() -> None:
    with Testbed(CFG, action_type="duration") as tb:
        tb.reset()
        tb.run_for(5.0)
        obs, info = tb.step(np.array([0.5], dtype=np.float32))  # green 3 + 0.5 * 17 = 11.5 s
        (verified,) = kinds(tb, Kind.TRANSITION_VERIFIED)
        (released,) = kinds(tb, Kind.HOLD_RELEASED)
        assert released["reason"] == "served"
        assert obs.t == released["t"] == pytest.approx(verified["t"] + 11.5)
        assert info["state"] == "idle" and obs.signal.greens == {3, 7}


def test_a_refused_action_raises_sends_nothing_and_takes_no_time() -> None:
    with Testbed(CFG, action_type="selection") as tb:
        obs = tb.reset()
        with pytest.raises(ConflictError) as caught:
            tb.step((1, 2))
        assert isinstance(caught.value, ActionError)
        assert tb.now == obs.t
        assert [r["purpose"] for r in kinds(tb, Kind.SET_SENT)] == ["startup"]
        (refused,) = kinds(tb, Kind.ACTION_REFUSED)
        assert refused["reason"] == "conflict"
        _, info = tb.wait()
        assert info["acted"] is False and tb.now == pytest.approx(obs.t + CFG.middleware.control_interval)


def test_a_step_ends_early_when_the_manager_enters_timeout() -> None:
    def target(env: Any, config: IntersectionConfig, *, seed: int, fast_path: bool, hires: bool) -> FaultTarget:
        return FaultTarget(env, config, seed=seed, faults=[DatagramLoss("down", window=Window(2.0))],
                           fast_path=fast_path, hires=hires)

    with Testbed(CFG, action_type="selection", target=target, recover_after=None) as tb:
        tb.reset()
        obs, info = tb.step((3, 7))
        assert info["timeout"] and info["timeout_reason"] == "communication" and info["state"] == "timeout"
        assert obs.t < CFG.middleware.control_interval
        (entered,) = kinds(tb, Kind.TIMEOUT_ENTERED)
        assert obs.t == entered["t"]


def test_reset_restarts_and_a_seed_gives_the_same_trajectory() -> None:
    def trajectory(tb: Testbed, seed: int) -> list[tuple]:
        tb.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(12):
            tb.step(CFG.pairs[rng.integers(len(CFG.pairs))])
        return [(r["kind"], r["t"], r.get("poll_id"), r.get("phases")) for r in tb.records]

    with Testbed(CFG, action_type="selection") as tb:
        first = trajectory(tb, 3)
        again = trajectory(tb, 3)
        other = trajectory(tb, 4)
    assert first == again
    assert first != other


@pytest.mark.wallclock
def test_the_steps_at_wall_clock_against_the_served_emulator(tmp_path: Path) -> None:
    served = start_emulator(tmp_path / "serve.log")
    url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
    cfg = CFG.with_middleware(control_interval=2.0, poll_hz=20.0)
    try:
        with Testbed(cfg, action_type="selection", target=url) as tb:
            obs = tb.reset()
            assert tb.mode == "wall-clock" and obs.signal.greens == {2, 6}
            start = time.monotonic()
            obs, info = tb.step((3, 7))
            # The step lasted its control interval at the wall clock; the transition (at least the
            # 5 s clearance) is still under way, so the next action is dropped.
            assert time.monotonic() - start == pytest.approx(2.0, abs=0.3)
            assert info["state"] == "on_hold"
            _, info = tb.step((4, 8))
            assert info["dropped"]
            tb.run_for(5.0)
            assert tb.observe().signal.greens == {3, 7} and tb.state is State.IDLE
        assert veh_call(served.port) == 0, "close() clears the call it placed"
        assert tb.records[-1]["kind"] == Kind.RUN_ENDED and tb.records[-1]["reason"] == "closed"
    finally:
        served.stop()


# --- every way a run can end ------------------------------------------------------------------

CRASHING_AGENT = """
from hils import ActionType

class Crash:
    action_type = ActionType.SWITCH

    def __init__(self, config, action_type, seed):
        self.calls = 0

    def act(self, observation):
        self.calls += 1
        if self.calls > 2:
            raise RuntimeError("boom")
        return 1
"""


def veh_call(port: int) -> int:
    oid = oid_str(control_oid(ControlColumn.VEH_CALL, 1))
    done = subprocess.run([tool("snmpget"), "-v2c", "-c", "public", "-On", "-t", "1", "-r", "2",
                           f"127.0.0.1:{port}", oid], capture_output=True, text=True, timeout=20)
    assert done.returncode == 0, done.stderr
    return int(done.stdout.rsplit("INTEGER: ", 1)[1])


def hils_run(tmp_path: Path, *args: str) -> subprocess.Popen[str]:
    (tmp_path / "my_agents.py").write_text(CRASHING_AGENT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress",
                             "--out", str(tmp_path / "run"), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)


def wait_for_command(run_dir: Path, proc: subprocess.Popen[str], within: float = 30.0) -> None:
    deadline = time.monotonic() + within
    log = run_dir / "events.jsonl"
    while time.monotonic() < deadline and proc.poll() is None:
        if log.exists() and any(r["kind"] == "set_sent" and r["purpose"] == "command" for r in read(log)):
            return
        time.sleep(0.1)
    raise AssertionError(f"no command SET within {within} s; stderr: {proc.stderr.read() if proc.poll() else ''}")


def ended(run_dir: Path) -> tuple[str, list[dict[str, Any]]]:
    records = list(read(run_dir / "events.jsonl"))
    assert records[-1]["kind"] == "run_ended"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["sim_time_s"] == records[-1]["t"]
    assert (run_dir / "signal_timeline.svg").stat().st_size > 0
    return records[-1]["reason"], records


@pytest.mark.parametrize(("how", "code", "reason"), [
    (signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted"), (None, 1, "agent_error")])
@pytest.mark.wallclock
def test_a_wall_clock_run_ends_cleanly_whatever_ends_it(tmp_path: Path, how: signal.Signals | None, code: int,
                                                        reason: str) -> None:
    served = start_emulator(tmp_path / "serve.log")
    url = f"snmp://127.0.0.1:{served.port}?community=private&version=2c"
    agent = ["--agent", "my_agents:Crash"] if how is None else []
    try:
        proc = hils_run(tmp_path, "--target", url, "--action-type", "switch", "--duration", "120", *agent,
                        "--config", str(short_interval_config(tmp_path)))
        wait_for_command(tmp_path / "run", proc)
        if how is not None:
            proc.send_signal(how)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == code, err
        assert veh_call(served.port) == 0, "the run cleared its call"
    finally:
        served.stop()
    got, records = ended(tmp_path / "run")
    assert got == reason
    assert [r["phases"] for r in records if r["kind"] == "set_sent"][-1] == []
    assert "Traceback" not in err and "run ended early" in err
    assert "Run summary" in out


def test_a_virtual_run_ends_cleanly_on_sigterm_and_on_an_agent_error(tmp_path: Path) -> None:
    proc = hils_run(tmp_path, "--action-type", "switch", "--duration", "360000")
    wait_for_command(tmp_path / "run", proc)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    reason, records = ended(tmp_path / "run")
    assert reason == "terminated" and records[-1]["t"] < 360000
    assert [r["phases"] for r in records if r["kind"] == "set_sent"][-1] == []

    crash = tmp_path / "crash"
    crash.mkdir()
    proc = hils_run(crash, "--action-type", "switch", "--duration", "600", "--agent", "my_agents:Crash")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert "the agent failed" in err and "boom" in err and "Traceback" not in err
    assert ended(crash / "run")[0] == "agent_error"


def short_interval_config(tmp_path: Path) -> Path:
    """The shipped config with a decision every 2 s, so that a wall-clock run acts soon."""
    path = tmp_path / "short.toml"
    source = (resources.files("hils.data") / DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")
    path.write_text(source.replace("control_interval = 10.0", "control_interval = 2.0"), encoding="utf-8")
    return path


def test_an_error_inside_the_run_finishes_it_before_it_propagates() -> None:
    def broken(tb: Testbed) -> None:
        def fail_at_30():
            yield tb.env.timeout(30.0)
            raise RuntimeError("a part of the run broke")

        tb.env.process(fail_at_30())

    tb = Testbed(CFG, action_type="switch", agent="fixed-cycle", duration=600.0, on_reset=broken)
    with pytest.raises(RuntimeError, match="a part of the run broke"):
        tb.run()
    assert tb.records[-1]["kind"] == Kind.RUN_ENDED and tb.records[-1]["reason"] == "error"
    assert [r["phases"] for r in kinds(tb, Kind.SET_SENT)][-1] == frozenset()
    assert tb.target.unit.control[ControlColumn.VEH_CALL] == frozenset(), "the calls are cleared"
    tb.close()


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_status_line_on_a_terminal_and_as_log_lines(caplog: pytest.LogCaptureFixture) -> None:
    terminal = _Terminal()
    status = StatusLine(stream=terminal)
    with Testbed(CFG, action_type="switch", on_reset=status.start, seed=0) as tb:
        tb.reset()
        tb.step(1)
        tb.run_for(3.0)
    status.close()
    shown = terminal.getvalue()
    assert shown.count("\r") == int(tb.records[-1]["t"] / 0.5)
    assert "ON_HOLD" in shown and "IDLE" in shown and "yellow 2+6" in shown and "green 3+7" in shown
    assert "last hold 8.1" in shown and shown.endswith("\n")  # the start-up green first times its minimum
    with caplog.at_level(logging.INFO, logger="hils.cli.status"):
        status = StatusLine(stream=io.StringIO(), log_every=5.0)
        with Testbed(CFG, action_type="switch", on_reset=status.start) as tb:
            tb.reset()
            tb.run_for(21.0)
    lines = [r.getMessage() for r in caplog.records if r.name == "hils.cli.status"]
    assert len(lines) == 4 and "20.0 s  IDLE" in lines[-1] and "polls 200 answered, 0 failed" in lines[-1]


def test_a_run_that_does_not_measure_is_the_same_run_without_the_summary_samples() -> None:
    """measure=False (what environments use for speed) changes nothing of the run: the same commands at the same
    times and the same vehicle counts; only the per-vehicle and per-lane samples, and their figures, are gone."""
    runs = {}
    for measure in (True, False):
        with Testbed(sumo=True, seed=4, duration=300.0, agent="max-pressure", measure=measure) as tb:
            tb.reset()
            tb.run()
            runs[measure] = (tb.records, tb.traffic)
    (measured, traffic), (unmeasured, counts) = runs[True], runs[False]
    def comparable(records: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k not in ("wall_ns", "seq")} for r in records
                if r["kind"] != Kind.QUEUES]

    assert comparable(unmeasured) == comparable(measured)
    assert not any(r["kind"] == Kind.QUEUES for r in unmeasured) and any(r["kind"] == Kind.QUEUES for r in measured)
    assert (counts.departed, counts.arrived, counts.running) == (traffic.departed, traffic.arrived, traffic.running)
    assert traffic.mean_delay is not None and counts.mean_delay is None and counts.approaches == {}
    assert "not measured" in counts.notes[0]


def test_a_run_that_keeps_no_hi_res_record_runs_no_data_logger_and_takes_no_step_for_one(tmp_path: Path) -> None:
    """measure=False without a hi-res journal keeps no hi-res record: its controller runs no data logger, and takes
    the very steps a run with one takes (the logger logs a green's minimum at its tick without a step of its own).
    A run that writes the journal keeps the logger whatever it measures, and the very same record."""
    runs = {}
    for measure, journal in ((True, tmp_path / "measured.csv"), (False, tmp_path / "unmeasured.csv"), (False, None)):
        own = [0]  # the controller's own steps: those the logger did not ask for alone

        def count(tb: Testbed, own: list[int] = own) -> None:
            controller = tb.target.controller
            step = controller._step

            def counted() -> None:
                own[0] += 1
                step()
            controller._step = counted

        with Testbed(seed=1, duration=300.0, agent="random", measure=measure, hires_path=journal,
                     on_reset=count) as tb:
            tb.reset()
            tb.run()
            runs[measure, journal is not None] = (tb.target, tb.target.clock.steps, own[0], tb.hires())
    (logged, steps, own, hires), (kept, kept_steps, kept_own, kept_hires) = runs[True, True], runs[False, True]
    bare, bare_steps, bare_own, nothing = runs[False, False]
    assert logged.log is not None and kept.log is not None and kept_hires == hires and len(hires["C"]) > 100
    assert (tmp_path / "unmeasured.csv").read_bytes() == (tmp_path / "measured.csv").read_bytes()
    assert (kept_steps, kept_own) == (steps, own)
    assert bare.log is None and bare.controller.recorder is None and nothing == {}
    assert (bare_own, bare_steps) == (own, steps), "the logger takes no step of its own"
    with pytest.raises(RuntimeError, match="keeps no hi-res log"):
        bare.hires()


@settings(max_examples=300, deadline=None)
@given(start=st.floats(0.0, 5000.0), k=st.integers(0, 20000), step=st.sampled_from([0.1, 0.2, 0.25, 0.5, 1.0]),
       ahead=st.floats(0.0, 40.0), on_grid=st.booleans())
def test_a_stretch_is_the_steps_the_grid_starts_before_the_next_event(start, k, step, ahead, on_grid) -> None:
    """The steps run back to back are counted as the stepping loop counted them, one float comparison each
    (an event on a step's own start time stops the stretch before that step)."""
    from hils.protocol.timegrid import Grid
    from hils.shell.fastpath import steps_before

    until = start + (k + round(ahead / step)) * step if on_grid else start + k * step + ahead
    counted = 0
    while until > start + (k + counted) * step:
        counted += 1
    assert steps_before(until, Grid(start, step), k) == counted


@pytest.mark.parametrize("scenario", [None, "corridor"])
def test_each_action_is_converted_once_and_its_latency_counts_the_conversion(monkeypatch, scenario) -> None:
    """A step converts every action before it submits any (all or none), once; the action's receipt is stamped
    before that conversion, so the internal latency (received to dispatched) counts it, as the paper's does."""
    from hils.control.actions import ActionConverter

    converted: list[Any] = []
    convert = ActionConverter.convert

    def slow(self: ActionConverter, value: Any, position: int) -> Any:
        converted.append(value)
        time.sleep(0.003)
        return convert(self, value, position)

    monkeypatch.setattr(ActionConverter, "convert", slow)
    with Testbed(scenario=scenario, seed=0, duration=30.0) as tb:
        tb.reset_all()
        names = list(tb.intersections)
        tb.step_all(dict.fromkeys(names, (4, 8)))
        assert converted == [(4, 8)] * len(names)
        received = {r["action_id"] if scenario is None else r["intersection"]: r["wall_ns"]
                    for r in kinds(tb, Kind.ACTION_RECEIVED)}
        dispatched = {r["action_id"] if scenario is None else r["intersection"]: r["wall_ns"]
                      for r in kinds(tb, Kind.COMMAND_DISPATCHED)}
        assert received.keys() == dispatched.keys() and len(received) == len(names)
        assert all(dispatched[k] - received[k] >= 3_000_000 for k in received)


def test_the_single_view_refuses_a_run_of_several_before_anything_starts() -> None:
    from hils.run.testbed import SeveralIntersections

    tb = Testbed(scenario="corridor", duration=10.0)
    with pytest.raises(SeveralIntersections, match=r"4 intersections \(J1, J2, J3, J4\).*reset_all"):
        tb.reset()
    assert tb.env is None and tb.intersections == {}
    assert Testbed.__doc__ is not None and "reset_all" in Testbed.__doc__


class SlowOnce:
    """Switches every decision, and once (its second decision) blocks 16 s before it answers."""

    action_type = "switch"

    def __init__(self) -> None:
        self.calls = 0

    def act(self, obs: Any) -> int:
        self.calls += 1
        if self.calls == 2:
            time.sleep(16.0)
        return 1


@pytest.mark.wallclock
def test_an_agent_that_blocks_at_the_wall_clock_does_not_stop_the_middleware(tmp_path: Path) -> None:
    """The agent thinks in a thread of its own: while it blocks 16 s (the controller's backup time is 12 s, the
    control interval 4 s) polls and the keepalive go on, so net-snmp's snmpget sees unitControlStatus
    systemControl throughout; the run's log shows the late agent and the TIMEOUT of its own reason (the agent
    gave nothing within the control interval), recovered while the agent still thinks; its late answer is
    discarded and it is asked again."""
    config = tmp_path / "backup12.toml"
    text = (resources.files("hils.data") / "four_leg.toml").read_text(encoding="utf-8")
    text = text.replace("control_interval = 10.0", "control_interval = 4.0").replace("backup_time = 30",
                                                                                      "backup_time = 12")
    config.write_text(text)
    served = start_emulator(tmp_path / "serve.log", "--config", str(config))
    status = oid_str(UNIT_CONTROL_STATUS.instance())
    seen: list[str] = []
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            out = subprocess.run([tool("snmpget"), "-v2c", "-c", "public", "-On", "-t", "1", "-r", "0",
                                  f"127.0.0.1:{served.port}", status], capture_output=True, text=True)
            seen.append(out.stdout.strip().rsplit(" ", 1)[-1] if out.returncode == 0 else "no answer")
            time.sleep(0.5)

    watcher = threading.Thread(target=watch, daemon=True)
    try:
        agent = SlowOnce()
        with Testbed(load(config), action_type="switch", agent=agent, duration=30.0,
                     target=f"snmp://127.0.0.1:{served.port}?community=private&version=2c") as tb:
            tb.reset()
            tb.run_for(1.0)  # the controller's status image shows the start-up SET a few ticks later
            watcher.start()
            tb.run()
            records = tb.records
    finally:
        done.set()
        watcher.join(timeout=10)
        served.stop()
    assert len(seen) > 40 and set(seen) == {"2"}, f"unitControlStatus seen: {sorted(set(seen))}"
    (late,) = [r for r in records if r["kind"] == Kind.AGENT_LATE]
    assert late["took_s"] == pytest.approx(16.0, abs=1.0) and late["discarded"] is True
    (timeout,) = [r for r in records if r["kind"] == Kind.TIMEOUT_ENTERED]
    assert timeout["reason"] == "agent" and "within the control interval (4 s)" in timeout["detail"]
    assert timeout["t"] == pytest.approx(late["t"] - 12.0, abs=1.0), "TIMEOUT when the interval passed"
    assert [r for r in records if r["kind"] == Kind.RECOVERED and r["t"] < late["t"]], "recovered meanwhile"
    keepalives = [r["t"] for r in records if r["kind"] == Kind.SET_SENT and r["purpose"] == "keepalive"]
    assert any(timeout["t"] < t < late["t"] for t in keepalives), "the keepalive went on while the agent thought"
    assert agent.calls >= 4, "asked again after its late answer"
