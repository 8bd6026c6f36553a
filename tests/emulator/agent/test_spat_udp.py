"""The 10 Hz UDP SPaT packet (`hils emulator serve --spat`), read by a decoder written here from the layout the
open V2X stacks parse, not from our encoder: MMITSS's ``Ntcip1202v2Blob.py`` reads each phase's min and max time
to change at fixed byte offsets ([3,4], [16,17], ... and [5,6], [18,19], ...) and the status groups' low bytes at
211 (reds), 213 (yellows), 215 (greens) as bit strings; V2X Hub's ``NTCIP1202.h`` reads the same times as
16-bit big-endian (``ntohs``) and the message counter and clock from the packed tail."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from emulator.agent.spat_udp import encode
from emulator.model.controller import Controller
from harness.bench.processes import start_emulator, tool
from hils.protocol.config import load
from hils.protocol.ntcip import SPAT_OPTIONS, ControlColumn, control_oid, oid_str
from hils.sim.network import data_path


@dataclass(frozen=True)
class Decoded:
    length: int
    veh_min: list[int]  # phases 1..8, tenths of a second from now
    veh_max: list[int]
    ovl_min: list[int]
    reds: set[int]
    yellows: set[int]
    greens: set[int]
    walks: set[int]
    sequence: int
    second: int


def decode(blob: bytes) -> Decoded:
    def u16(at: int) -> int:
        return blob[at] * 256 + blob[at + 1]

    def phases(at: int) -> set[int]:  # MMITSS: the low byte's bits, least significant first
        return {i + 1 for i, bit in enumerate(f"{blob[at]:08b}"[::-1]) if bit == "1"}

    min_at = [[3 + 13 * i, 4 + 13 * i] for i in range(8)]
    max_at = [[5 + 13 * i, 6 + 13 * i] for i in range(8)]
    assert min_at[7] == [94, 95] and max_at[7] == [96, 97]  # MMITSS's byte maps
    return Decoded(len(blob), [u16(a) for a, _ in min_at], [u16(a) for a, _ in max_at],
                   [u16(11 + 13 * i) for i in range(8)], phases(211), phases(213), phases(215), phases(221),
                   blob[235], blob[238])


def test_each_tick_the_packet_says_what_the_controller_announces() -> None:
    """Over a minute of the city four-leg (overlaps, a preempt) with calls, every packet's times and bitmasks are the
    model's announcement and status: 0 where nothing is announced."""
    c = Controller(load(data_path("four_leg_city.toml")))
    seen_yellow = 0
    for tick in range(600):
        if tick == 50:
            c.set_control(ControlColumn.VEH_CALL, {4, 8})
        if tick == 300:
            c.set_control(ControlColumn.VEH_CALL, {1, 5})
        c.step()
        d = decode(encode(c, tick))
        assert d.length == 245 and d.sequence == tick % 256
        spat = {(s.kind, s.number): s for s in c.spat()}
        for p in range(1, 9):
            s = spat["phase", p]
            assert (d.veh_min[p - 1], d.veh_max[p - 1]) == (s.earliest or 0, s.latest or 0), (tick, p)
            if ("overlap", p) in spat:
                assert d.ovl_min[p - 1] == spat["overlap", p].earliest
        assert (d.reds, d.yellows, d.greens, d.walks) == (set(c.reds), set(c.yellows), set(c.greens), set(c.walks))
        seen_yellow += bool(d.yellows)
    assert seen_yellow > 0


@pytest.mark.wallclock
def test_the_served_emulator_sends_it_at_10_hz_over_udp_and_a_call_shows_in_it(tmp_path: Path) -> None:
    """`hils emulator serve --spat` on loopback: consecutive counters at 10 Hz; 2+6 rest green with no latest end;
    once net-snmp's snmpset calls 4+8, 2+6 show yellow with its exact 3 s (min = max), then 4+8 green; with v03's
    spatOptions SET to 0 the packets stop."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(2.0)
        served = start_emulator(tmp_path / "serve.log", "--ntcip", "v03", "--spat",
                                f"127.0.0.1:{sock.getsockname()[1]}")
        try:
            first = [decode(sock.recv(1024)) for _ in range(20)]
            start = time.monotonic()
            more = [decode(sock.recv(1024)) for _ in range(20)]
            rate = 20 / (time.monotonic() - start)
            counters = [d.sequence for d in first + more]
            assert counters == [(counters[0] + i) % 256 for i in range(40)]
            assert 8 <= rate <= 12, rate
            rest = more[-1]
            assert rest.greens == {2, 6} and rest.veh_max[1] == 0 and rest.veh_min[3] > 0
            subprocess.run([tool("snmpset"), "-v2c", "-c", "private", "-On", f"127.0.0.1:{served.ports[0]}",
                            oid_str(control_oid(ControlColumn.VEH_CALL, 1)), "i", str(0b10001000)],
                           check=True, capture_output=True, timeout=10)
            yellows, greens = [], set()
            deadline = time.monotonic() + 10
            while greens != {4, 8}:
                assert time.monotonic() < deadline, "4+8 never turned green"
                d = decode(sock.recv(1024))
                greens = d.greens
                if 2 in d.yellows:
                    yellows.append(d)
            # spatOptions bit 0 clear ("Enabled SPAT" off): no packet once the SET is taken.
            subprocess.run([tool("snmpset"), "-v2c", "-c", "private", "-On", f"127.0.0.1:{served.ports[0]}",
                            oid_str(SPAT_OPTIONS.instance()), "i", "0"], check=True, capture_output=True, timeout=10)
            sock.settimeout(0.3)
            late = time.monotonic() + 1.0
            with contextlib.suppress(TimeoutError):
                while time.monotonic() < late:
                    sock.recv(1024)  # those sent before the SET was taken
            with pytest.raises(TimeoutError):
                sock.recv(1024)
        finally:
            code, out = served.stop()
    assert yellows and all(d.veh_min[1] == d.veh_max[1] for d in yellows)
    assert yellows[0].veh_min[1] in (29, 30) and yellows[-1].veh_min[1] <= 2
    assert code == 0 and "SPaT of" in out

