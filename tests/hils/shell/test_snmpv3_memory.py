"""SNMPv3 messages the agent refuses keep nothing: measured in process (no UDP, no real seconds, so outside the
wall-clock tests of test_snmpv3.py)."""

from __future__ import annotations

import gc
import tracemalloc

from emulator.agent.mib import MibView
from emulator.agent.snmp import ReportBudget, SnmpAgent, V3User
from emulator.model.controller import Controller
from harness.bench.floods import AUTH, REPORTABLE, v3_get
from tests.hils.shell.test_snmpv3 import AUTH_KEY, PRIV_KEY, USER, engine_of


def test_hostile_v3_messages_leave_no_state_behind(paper_config) -> None:
    """Whatever pysnmp keeps of a message it refuses or answers with a Report is dropped with the datagram (the
    Report budget unbounded here, so that every one of them reaches pysnmp)."""
    agent = SnmpAgent(MibView(Controller(paper_config)), v3_user=V3User(USER, AUTH_KEY, PRIV_KEY),
                      reports=ReportBudget(per_second=1e9, burst=10**9))
    engine_id = engine_of(agent)
    hostile = {"no user": v3_get(engine_id), "foreign engine": v3_get(b"\x80\x00\x1f\x88\x04hils", b"someone"),
               "discovery": v3_get(b""), "unknown user": v3_get(engine_id, b"nobody"),
               "below the user's level": v3_get(engine_id, USER.encode()),
               "wrong digest": v3_get(engine_id, USER.encode(), REPORTABLE | AUTH, bytes(12), boots=1, engine_time=5)}
    for kind, datagram in hostile.items():
        for _ in range(20):  # pysnmp's first-use allocations are not what is measured
            agent.respond(datagram)
        gc.collect()
        tracemalloc.start()
        try:
            for _ in range(300):
                agent.respond(datagram)
            gc.collect()  # pyasn1's objects hold cycles: garbage is not what is kept
            kept = tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()
        assert kept < 64_000, f"{kind}: {kept} bytes kept after 300 messages"
    assert agent.stats.answered == 0
