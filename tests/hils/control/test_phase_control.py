"""Phase-control schedules: MMITSS's own schedules read as MMITSS sends them, the rules a schedule is refused by (each
a typed error naming its rule), and the life cycle of an order (armed, acting, spent, lapsed)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hils.control.actions import ActionConverter, ActionError, ActionType, ActionTypeError, UnknownPhaseError
from hils.control.errors import (
    CallOmittedError,
    HoldForceOffError,
    HoldOmittedError,
    RingOmittedError,
    ScheduleTimeError,
)
from hils.control.phase_control import Control, OrderState, Running, Schedule, ScheduleFileError, load, parse
from hils.protocol.config import load as load_config
from hils.protocol.ntcip import ControlColumn

CONFIG = load_config()
MMITSS = Path(__file__).resolve().parents[3] / "examples" / "mmitss"


def command(kind: str, phase: int, start: float, end: float) -> dict[str, object]:
    return {"commandPhase": phase, "commandType": kind, "commandStartTime": start, "commandEndTime": end}


def message(*commands: dict[str, object]) -> dict[str, object]:
    return {"MsgType": "Schedule", "Schedule": list(commands)}


def test_mmitss_readme_schedule_is_read_as_mmitss_sends_it() -> None:
    s = load(MMITSS / "schedule_ev.json", CONFIG)
    # 22 commands, of which MMITSS itself drops the two that start and end at 0 (holds on 2 and 6).
    assert len(s.orders) == 20 and len(s.dropped) == 2 and all("starts and ends at once" in d for d in s.dropped)
    assert s.span == 133.5 and not s.open
    # commandEndTime 23.999767065048218 is rounded to the tenth, as MMITSS rounds it.
    assert {o.end for o in s.orders if o.control is Control.CALL_VEH} == {240}
    at_6 = s.at(60)
    assert at_6[ControlColumn.HOLD] == {4, 7} and at_6[ControlColumn.VEH_CALL] == {4, 7}
    assert at_6[ControlColumn.PHASE_OMIT] == {1, 3, 5, 8} and at_6[ControlColumn.FORCE_OFF] == frozenset()
    assert s.at(110)[ControlColumn.FORCE_OFF] == {2, 6} and s.at(120)[ControlColumn.FORCE_OFF] == frozenset()
    assert all(not phases for phases in s.at(1335).values()), "every order has ended at 133.5 s"


def test_overlapping_orders_of_one_type_on_one_phase_are_one() -> None:
    s = load(MMITSS / "schedule1.json", CONFIG)
    # MMITSS's schedule1 calls phase 2 from 0 to 68 s and from 0 to 168 s: the call stands to 168 s.
    assert 2 in s.at(1000)[ControlColumn.VEH_CALL] and 2 not in s.at(1680)[ControlColumn.VEH_CALL]


def test_the_clear_message_and_a_step() -> None:
    assert parse({"MsgType": "Schedule", "Schedule": "Clear"}, CONFIG) == Schedule()
    assert parse("clear", CONFIG) == Schedule()
    step = parse({"hold": [2, 6], "omit_veh": [3, 4, 7, 8], "call_veh": (2, 6)}, CONFIG)
    assert step.open and step.span is None and step.instants == (0,)
    assert step.at(10**6)[ControlColumn.HOLD] == {2, 6}
    assert parse([command("hold", 2, 0, 5)], CONFIG).orders[0].end == 50, "a bare list of MMITSS commands"


@pytest.mark.parametrize(("value", "error", "says"), [
    (message(command("hold", 2, 0, 20), command("forceoff", 2, 10, 11)), HoldForceOffError,
     "phase 2 is held and forced off at once (Schedule[0]: hold 2 (0 s to 20 s); Schedule[1]: forceoff 2 (10 s to "
     "11 s))"),
    (message(command("call_veh", 4, 0, 20), command("omit_veh", 4, 19.9, 30)), CallOmittedError,
     "phase 4 is called and omitted at once"),
    (message(command("call_ped", 4, 0, 20), command("omit_ped", 4, 5, 6)), CallOmittedError,
     "called for pedestrians and their walk omitted"),
    (message(command("hold", 6, 0, 20), command("omit_veh", 6, 0, 20)), HoldOmittedError, "held and omitted"),
    ({"omit_veh": [1, 2, 3, 4]}, RingOmittedError, "every phase of ring 1 (1, 2, 3, 4) is omitted at 0 s"),
    (message(*(command("omit_veh", p, 10 * (p == 8), 30) for p in (5, 6, 7, 8))), RingOmittedError,
     "every phase of ring 2 (5, 6, 7, 8) is omitted at 10 s (Schedule[0]: omit_veh 5"),
    (message(command("hold", 9, 0, 5)), UnknownPhaseError, "unknown phase 9 in Schedule[0]: hold 9 (0 s to 5 s)"),
    (message(command("hold", 2, 5, 4)), ScheduleTimeError, "ends at 4 s, before it starts at 5 s"),
    (message(command("hold", 2, -1, 4)), ScheduleTimeError, "seconds >= 0"),
    (message(command("hold", 2, 0, math.nan)), ScheduleTimeError, "a finite number"),
    (message(command("hold", 2, 0, "5")), ScheduleTimeError, "a finite number"),
    (message(command("holdd", 2, 0, 5)), ActionTypeError, "allowed: hold, forceoff, omit_veh, omit_ped, call_veh"),
    (message({"commandPhase": 2, "commandType": "hold"}), ActionTypeError, "has no commandStartTime, commandEndTime"),
    ({"MsgType": "Status"}, ActionTypeError, "allowed: 'Schedule'"),
    ({"hold": 2}, ActionTypeError, "a list of phase numbers"),
    ({"hold": [2.5]}, ActionTypeError, "a phase number"),
    (1.5, ActionTypeError, "phase control takes a schedule"),
    ("go", ActionTypeError, "phase control takes a schedule"),
])
def test_a_schedule_that_breaks_a_rule_is_refused_naming_it(value: object, error: type[ActionError],
                                                            says: str) -> None:
    converter = ActionConverter(CONFIG, ActionType.CONTROL)
    with pytest.raises(error) as refused:
        converter.convert(value)
    assert says in str(refused.value)
    assert refused.value.reason == error.reason and refused.value.reason != ActionError.reason


def test_orders_that_touch_do_not_conflict() -> None:
    # MMITSS's own schedule1: hold 1 from 111 to 131 s, force-off 1 from 131 to 132 s.
    parse(message(command("hold", 1, 111, 131), command("forceoff", 1, 131, 132)), CONFIG)
    parse(message(command("call_veh", 4, 0, 10), command("omit_veh", 4, 10, 20)), CONFIG)


def test_a_schedule_file_that_cannot_be_used_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "plan.json"
    bad.write_text(json.dumps(message(command("hold", 2, 0, 20), command("forceoff", 2, 0, 1))))
    with pytest.raises(ScheduleFileError, match=rf"schedule {bad}: phase 2 is held and forced off at once"):
        load(bad, CONFIG)
    bad.write_text("{not json")
    with pytest.raises(ScheduleFileError, match="is not JSON"):
        load(bad, CONFIG)
    with pytest.raises(ScheduleFileError, match="cannot be read"):
        load(tmp_path / "missing.json", CONFIG)


# --- the life of an order ----------------------------------------------------------------------------------------


def states(running: Running) -> dict[str, str]:
    return {str(o): s.value for o, s in zip(running.schedule.orders, running.states, strict=True)}


def test_a_hold_on_a_phase_not_green_is_armed_and_acts_when_its_phase_shows_green() -> None:
    running = Running(parse(message(command("hold", 4, 0, 20), command("call_veh", 4, 0, 20)), CONFIG), 0.0)
    changes = running.pass_instant(frozenset({2, 6}))
    assert [(c.order.control, c.after) for c in changes] == [(Control.HOLD, OrderState.ARMED),
                                                             (Control.CALL_VEH, OrderState.ACTING)]
    assert running.image()[ControlColumn.HOLD] == {4}, "an armed hold is set: it calls nothing, it waits"
    assert running.seen(frozenset({2, 6})) == []
    (green,) = running.seen(frozenset({4, 8}))
    assert (green.before, green.after) == (OrderState.ARMED, OrderState.ACTING)
    running.pass_instant(frozenset({4, 8}))
    assert running.over and set(states(running).values()) == {"ended"}


def test_a_force_off_whose_green_ends_is_spent_and_one_whose_green_rests_lapses() -> None:
    running = Running(parse(message(command("forceoff", 2, 0, 1), command("forceoff", 6, 0, 1)), CONFIG), 0.0)
    running.pass_instant(frozenset({2, 6}))
    (ended,) = running.seen(frozenset({6}))  # 2 ended its green (a conflicting call): the controller reset its bit
    assert (ended.order.phase, ended.after) == (2, OrderState.SPENT)
    assert running.image()[ControlColumn.FORCE_OFF] == {6}, "a spent force-off is not set again"
    running.pass_instant(frozenset({6}))
    assert states(running) == {"forceoff 2 (0 s to 1 s)": "ended", "forceoff 6 (0 s to 1 s)": "lapsed"}


def test_a_hold_whose_phase_never_shows_green_lapses_and_cancel_ends_every_order() -> None:
    running = Running(parse(message(command("hold", 3, 0, 1), command("omit_veh", 1, 0, 5)), CONFIG), 0.0)
    running.pass_instant(frozenset({2, 6}))
    running.pass_instant(frozenset({2, 6}))
    assert states(running)["hold 3 (0 s to 1 s)"] == "lapsed"
    assert [c.after for c in running.cancel()] == [OrderState.ENDED] and running.over
