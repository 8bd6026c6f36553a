"""The J2735 SPaT (:mod:`emulator.agent.j2735`), decoded by a second, independent decoder: asn1tools (its own UPER
codec) compiling the ASN.1 text of ISO TS 19091's SPAT and of ETSI's DSRC MessageFrame, written back from the types
pycrate compiled (tests/emulator/agent/asn1_text.py); the hand-written MessageFrame header is checked against
pycrate's own MessageFrame too. Then judged as USDOT's jpo-geojsonconverter judges CTI 4501 conformance
(:mod:`harness.reference.cti4501`), and received over real UDP from `hils emulator serve --j2735`."""

from __future__ import annotations

import socket
import subprocess
import time
from datetime import UTC, datetime, timedelta
from functools import cache
from pathlib import Path
from typing import Any

import asn1tools
import gymnasium
import pytest
from pycrate_asn1dir import ITS_IS, ITS_r1318

from emulator.agent import j2735
from emulator.model.controller import Controller
from emulator.model.spat import Indication
from harness.bench.processes import start_emulator, tool
from harness.reference import cti4501
from hils.envs import ENV_ID
from hils.envs.intersection import EnvOptionError, IntersectionEnv
from hils.protocol.config import load
from hils.protocol.ntcip import ControlColumn, control_oid, oid_str
from hils.run.testbed import Testbed
from hils.sim.network import TLS_ID, data_path
from tests.emulator.agent.asn1_text import module

STATES = {Indication.GREEN: "protected-Movement-Allowed", Indication.YELLOW: "protected-clearance",
          Indication.RED: "stop-And-Remain"}


@cache
def spec() -> Any:
    return asn1tools.compile_string(module("Check", {"MessageFrame": ITS_r1318.DSRC.MessageFrame,
                                                     "SPAT": ITS_IS.DSRC.SPAT}), "uper")


def decode(message: bytes) -> dict[str, Any]:
    """asn1tools' reading of a message: the frame, then the SPAT inside."""
    frame = spec().decode("MessageFrame", message)
    assert frame["messageId"] == 19
    return spec().decode("SPAT", frame["value"])


def clock(c: Controller) -> datetime:
    """The controller's clock now (its coordinator's: ticks since midnight of its first day), taken as UTC."""
    return (c.day0 + timedelta(seconds=c.coordinator.clock / 10)).replace(tzinfo=UTC)


def mark(c: Controller, ticks: int | None) -> int:
    """A time from now as a TimeMark of the controller's clock (tenths of a second past its hour)."""
    return 36001 if ticks is None else (c.coordinator.clock + ticks) % 36000


def run_city(ticks: int):
    """The city four-leg (overlaps, a preempt configured) with calls on 4+8, then 1+5: the controller after each
    tick."""
    c = Controller(load(data_path("four_leg_city.toml")))
    for tick in range(ticks):
        if tick == 50:
            c.set_control(ControlColumn.VEH_CALL, {4, 8})
        if tick == 300:
            c.set_control(ControlColumn.VEH_CALL, {1, 5})
        c.step()
        yield tick, c


def test_each_message_decoded_independently_is_what_the_controller_announces() -> None:
    """Over a minute of the city four-leg, every tick's message as asn1tools decodes it: the frame opens 00 13 (no
    extension, messageId 19) as pycrate's own MessageFrame encodes it, and per phase and overlap its signal group,
    state and TimeMarks are the model's announcement on the controller's clock (36001 where nothing is
    announced)."""
    finite_max = 0
    for tick, c in run_city(600):
        message = j2735.encode(c, tick, intersection=7)
        spat = decode(message)
        frame = ITS_r1318.DSRC.MessageFrame
        inner = ITS_IS.DSRC.SPAT
        inner.from_uper(message[3:] if message[2] < 128 else message[4:])
        frame.set_val({"messageId": 19, "value": ("SPAT", inner.get_val())})
        assert message[:2] == b"\x00\x13" and frame.to_uper() == message
        x = spat["intersections"][0]
        now = clock(c)
        moy = (now.timetuple().tm_yday - 1) * 1440 + now.hour * 60 + now.minute
        assert (x["id"], x["revision"], x["moy"], spat["timeStamp"]) == ({"region": 0, "id": 7}, tick % 128, moy, moy)
        assert x["timeStamp"] == now.second * 1000 + now.microsecond // 1000
        decoded = {m["signalGroup"]: m["state-time-speed"][0] for m in x["states"]}
        for s in c.spat():
            event = decoded[s.number if s.kind == "phase" else 16 + s.number]
            flashing = s.kind == "overlap" and s.number in c.overlaps.flashing
            assert event["eventState"] == ("permissive-Movement-Allowed" if flashing else STATES[s.indication])
            timing = event["timing"]
            assert timing["minEndTime"] == mark(c, s.earliest), (tick, s)
            assert timing["maxEndTime"] == mark(c, s.latest), (tick, s)
            assert timing.get("likelyTime") == (None if s.likely is None else mark(c, s.likely))
            assert timing["startTime"] == mark(c, None if s.started is None else -s.started)
            assert timing["nextTime"] == 36001
            finite_max += timing["maxEndTime"] != 36001
    assert finite_max > 600  # the latest is announced, not only the earliest


def test_a_yellow_reads_its_exact_end_and_its_start_through_the_converter() -> None:
    """The converter's processed SPaT (jpo-geojsonconverter's own schema checks it) puts phase 2's yellow, once it
    shows, between its start and its end 3 s later, the min and max end equal; the message is CTI 4501
    conformant as the converter computes it."""
    for _, c in run_city(400):
        spat = {(s.kind, s.number): s for s in c.spat()}
        if spat["phase", 2].indication is Indication.YELLOW and spat["phase", 2].started == 0:
            break
    else:
        pytest.fail("2 never turned yellow")
    now = clock(c)
    judgement = cti4501.judge(decode(j2735.encode(c, 1)), now)
    assert judgement.conformant, judgement.messages
    assert judgement.processed["cti4501Conformant"] is True
    two = next(m for m in judgement.processed["states"] if m["signalGroup"] == 2)["stateTimeSpeed"][0]
    assert two["eventState"] == "PROTECTED_CLEARANCE"
    instant = {k: datetime.fromisoformat(v) for k, v in two["timing"].items()}
    assert instant["startTime"] == now
    assert instant["minEndTime"] == instant["maxEndTime"] == instant["likelyTime"] == now + timedelta(seconds=3)
    assert instant["nextTime"] == datetime(1970, 1, 1, tzinfo=UTC)  # unknown: the converter's epoch


def test_a_message_without_a_max_end_time_is_not_conformant() -> None:
    """The judge can fail: a SPaT leaving maxEndTime out (J2735 allows it; CTI 4501 does not) is refused, the
    converter's message naming the field."""
    value = {"timeStamp": 1000, "intersections": [{
        "id": {"region": 0, "id": 1}, "revision": 0, "status": (0, 16), "moy": 1000, "timeStamp": 0,
        "states": [{"signalGroup": 2, "state-time-speed": [{"eventState": "protected-Movement-Allowed", "timing": {
            "startTime": 10, "minEndTime": 40, "nextTime": 36001}}]}]}]}
    ITS_IS.DSRC.SPAT.set_val(value)
    message = j2735.frame(19, ITS_IS.DSRC.SPAT.to_uper())
    judgement = cti4501.judge(decode(message), datetime(2026, 1, 1, tzinfo=UTC))
    assert not judgement.conformant and judgement.processed["cti4501Conformant"] is False
    assert any("maxEndTime" in m for m in judgement.messages), judgement.messages


def test_a_long_message_takes_a_two_octet_length() -> None:
    """X.691's length determinant: one octet below 128, 10 and 14 bits below 16384, as asn1tools reads it."""
    for n, head in ((0, b"\x00\x13\x00"), (127, b"\x00\x13\x7f"), (128, b"\x00\x13\x80\x80"),
                    (300, b"\x00\x13\x81\x2c")):
        message = j2735.frame(19, b"x" * n)
        assert message.startswith(head)
        assert spec().decode("MessageFrame", message) == {"messageId": 19, "value": b"x" * n}


@pytest.mark.wallclock
def test_the_served_emulator_sends_it_at_10_hz_over_udp(tmp_path: Path) -> None:
    """`hils emulator serve --j2735` on loopback: messages asn1tools decodes, revisions consecutive, at 10 Hz; 2+6
    rest green with no latest end (maxEndTime unknown); once net-snmp's snmpset calls 4+8, 2 and 6 announce their
    maximum as their latest end."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(2.0)
        served = start_emulator(tmp_path / "serve.log", "--j2735", f"127.0.0.1:{sock.getsockname()[1]}")
        try:
            got = [decode(sock.recv(2048)) for _ in range(20)]  # the first, while the server settles
            start = time.monotonic()
            got += [decode(sock.recv(2048)) for _ in range(20)]
            rate = 20 / (time.monotonic() - start)
            revisions = [m["intersections"][0]["revision"] for m in got]
            assert revisions == [(revisions[0] + i) % 128 for i in range(40)]
            assert 8 <= rate <= 12, rate
            resting = {m["signalGroup"]: m["state-time-speed"][0] for m in got[-1]["intersections"][0]["states"]}
            assert resting[2]["eventState"] == "protected-Movement-Allowed"
            assert resting[2]["timing"]["maxEndTime"] == 36001
            subprocess.run([tool("snmpset"), "-v2c", "-c", "private", "-On", f"127.0.0.1:{served.ports[0]}",
                            oid_str(control_oid(ControlColumn.VEH_CALL, 1)), "i", str(0b10001000)],
                           check=True, capture_output=True, timeout=10)
            deadline = time.monotonic() + 5
            while True:
                assert time.monotonic() < deadline, "2 never announced a latest end"
                states = {m["signalGroup"]: m["state-time-speed"][0]
                          for m in decode(sock.recv(2048))["intersections"][0]["states"]}
                if states[2]["timing"]["maxEndTime"] != 36001:
                    break
        finally:
            code, out = served.stop()
    assert code == 0, out



def test_the_testbed_and_the_environment_hand_it_in_virtual_time() -> None:
    """`Testbed.j2735()` gives each controller's message: asn1tools reads per signal group the indications and
    the earliest ends `Testbed.spat()` gives in the run's seconds (a TimeMark is tenths of the hour: the same
    tenths from now); the environment's ``j2735=True`` hands it in ``info`` (virtual target only)."""
    with Testbed(action_type="selection", seed=3) as tb:
        tb.reset(seed=3)
        tb.run_for(7.0)
        tb.step((4, 8))
        timing = {m.number: m for m in tb.spat()[TLS_ID] if m.kind == "phase"}
        message = tb.j2735()[TLS_ID]
        c = tb.intersections[TLS_ID].target.controller
        x = decode(message)["intersections"][0]
        now = c.coordinator.clock % 36000
        for m in x["states"]:
            t, event = timing[m["signalGroup"]], m["state-time-speed"][0]
            assert event["eventState"] == STATES[Indication(t.indication)]
            ahead = (event["timing"]["minEndTime"] - now) % 36000
            assert ahead == pytest.approx((t.min_end - tb.now) * 10, abs=1.0)
    env = gymnasium.make(ENV_ID, action_type="selection", episode_length=30.0, j2735=True)
    try:
        _, info = env.reset(seed=2)
        assert decode(info["j2735"])["intersections"][0]["id"] == {"region": 0, "id": 1}
        *_, info = env.step(env.action_space.sample())
        assert len(decode(info["j2735"])["intersections"][0]["states"]) == 8
    finally:
        env.close()
    with pytest.raises(EnvOptionError, match="j2735=True with target="):
        IntersectionEnv(j2735=True, target="snmp://127.0.0.1:1161")
