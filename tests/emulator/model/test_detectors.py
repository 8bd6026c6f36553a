"""The detector unit: a vehicle detector's delay, extension and carryover (NTCIP 1202 vehicleDetectorDelay and
vehicleDetectorExtend; the detector unit's output extension), in the config, in the model and over NTCIP."""

from __future__ import annotations

import pytest

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from hils.protocol.config import ConfigError, DetectorTiming, IntersectionConfig, load, parse
from hils.protocol.hires import EventCode as E
from hils.protocol.ntcip import (
    VEHICLE_DETECTOR_DELAY,
    VEHICLE_DETECTOR_EXTEND,
    VEHICLE_DETECTOR_OPTIONS,
    DetectorOption,
    ErrorStatus,
    SnmpError,
)
from hils.sim.network import data_path


def with_detector(paper_toml: str, entry: str) -> IntersectionConfig:
    """The paper's intersection, a detector per phase, and detector 9 on phase 4 as ``entry`` says."""
    table = "\n".join(f"{p} = {p}" for p in range(1, 9))
    return parse(f"{paper_toml}\n[detectors]\n{table}\n9 = {{ phase = 4, {entry} }}\n", "det.toml")


def steps(c: Controller, n: int) -> list[bool]:
    """Step ``n`` ticks: whether phase 4 is called after each."""
    out = []
    for _ in range(n):
        c.step()
        out.append(4 in c.calls)
    return out


def green_on_4(c: Controller) -> None:
    """Phase 4 green and resting (no other call): its own detector called it and went."""
    c.set_actuations({4})
    for _ in range(200):
        c.step()
        if 4 in c.greens:
            break
    c.set_actuations(set())
    c.step()
    assert 4 in c.greens and not c.calls


def test_a_delayed_detector_calls_its_red_phase_once_its_actuation_lasted_the_delay(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "delay = 3.0"))
    assert 4 not in c.greens
    c.set_actuations({9})
    called = steps(c, 40)
    # The actuation is seen on the first step; its call 3.0 s (30 ticks) later.
    assert called.index(True) == 30 and all(called[30:])


def test_an_actuation_shorter_than_the_delay_calls_nothing(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "delay = 3.0"))
    c.set_actuations({9})
    assert not any(steps(c, 29))
    c.set_actuations(set())  # the vehicle left before the delay ran: the delay timer resets
    assert not any(steps(c, 50))
    c.set_actuations({9})
    assert steps(c, 31)[-1]  # a new actuation times a whole delay again


def test_the_delay_does_not_act_while_the_phase_is_green(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "delay = 3.0"))
    green_on_4(c)
    c.set_actuations({9})
    assert steps(c, 1) == [True]


def test_a_detector_log_shows_the_delay_between_actuation_and_call(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "delay = 2.5"))
    log = DataLogger(c)
    c.set_actuations({9})
    steps(c, 40)
    events = log.events()
    on = next(e.time for e in events if e.code == E.DETECTOR_ON and e.parameter == 9)
    call = next(e.time for e in events if e.code == E.PHASE_CALL_REGISTERED and e.parameter == 4)
    assert (call - on).total_seconds() == pytest.approx(2.5)


def test_an_extending_detector_holds_its_green_phase_called_after_the_vehicle_left(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "extend = 2.0"))
    green_on_4(c)
    c.set_actuations({9})
    c.step()
    c.set_actuations(set())
    assert steps(c, 21) == [True] * 20 + [False]


def test_the_extension_does_not_act_while_the_phase_is_red(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "extend = 2.0"))
    c.set_actuations({9})
    assert steps(c, 1) == [True]
    c.set_actuations(set())
    assert steps(c, 1) == [False]


def test_carryover_holds_the_call_whatever_the_phase_shows(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "carryover = 1.5"))
    c.set_actuations({9})
    steps(c, 1)
    c.set_actuations(set())
    assert steps(c, 16) == [True] * 15 + [False]


def test_a_locking_detector_holds_its_call_off_green_until_its_phase_is_green(paper_toml: str) -> None:
    """vehicleDetectorOptions bit 2, "Yellow Lock Call - ... lock a call to the assigned phase if an actuation occurs
    while the phase is not timing Green": a vehicle passing detector 9 while 4 is red leaves 4 called until 4 is
    green, then the call goes (the 4895 Econolite's detector 17 and phase 3); unlocked, the call goes with it and 4
    is never served. Stepped tick by tick or skipped through quiet time, the same."""
    for locked in (True, False):
        logs = []
        for skipping in (False, True):
            c = Controller(with_detector(paper_toml, f"lock = {str(locked).lower()}"))
            logs.append(DataLogger(c))
            assert 4 not in c.greens
            c.set_actuations({9})
            c.step()
            c.set_actuations(set())
            if skipping:
                c.advance(600)
                continue
            seen = []
            for _ in range(600):
                c.step()
                seen.append((4 in c.calls, 4 in c.greens))
        assert logs[0].events() == logs[1].events()
        if not locked:
            assert not any(called or green for called, green in seen)
            continue
        green = next(k for k, (_, g) in enumerate(seen) if g)
        assert all(called for called, _ in seen[:green + 1]) and not any(called for called, _ in seen[green + 1:])


def test_the_detector_table_says_which_detector_locks(paper_toml: str) -> None:
    mib = MibView(Controller(with_detector(paper_toml, "lock = true")))
    options = mib.get_many([VEHICLE_DETECTOR_OPTIONS.instance(9), VEHICLE_DETECTOR_OPTIONS.instance(4)])
    assert [bool(o & DetectorOption.YELLOW_LOCK_CALL) for o in options] == [True, False]


def test_the_config_holds_each_detectors_timers(paper_toml: str) -> None:
    config = with_detector(paper_toml, "delay = 3.0, extend = 1.5, carryover = 0.5")
    assert config.detector_timing == {9: DetectorTiming(3.0, 1.5, 0.5)}
    assert config.detectors[9] == 4


@pytest.mark.parametrize(("entry", "field", "allowed"), [
    ("delay = 300", "detectors.9.delay", "<= 255.0"),
    ("extend = 30", "detectors.9.extend", "<= 25.5"),
    ("carryover = -1", "detectors.9.carryover", ">= 0"),
    ("delay = 1.25", "detectors.9.delay", "multiples of 0.1"),
    ("stretch = 2", "detectors.9.stretch", "allowed: phase, lane, delay, extend, carryover, lock"),
    ("lock = 1", "detectors.9.lock", "allowed: true"),
])
def test_a_bad_detector_timer_is_refused_naming_file_field_and_range(paper_toml: str, entry: str, field: str,
                                                                     allowed: str) -> None:
    with pytest.raises(ConfigError) as info:
        with_detector(paper_toml, entry)
    assert info.value.source == "det.toml" and info.value.field == field and allowed in info.value.message


def test_the_detector_table_serves_delay_and_extend_and_a_set_retimes_the_detector(paper_toml: str) -> None:
    c = Controller(with_detector(paper_toml, "delay = 3.0, extend = 1.5"))
    mib = MibView(c)
    assert mib.get_many([VEHICLE_DETECTOR_DELAY.instance(9), VEHICLE_DETECTOR_EXTEND.instance(9),
                         VEHICLE_DETECTOR_DELAY.instance(4)]) == (30, 15, 0)
    mib.set_many([(VEHICLE_DETECTOR_DELAY.instance(4), 10)])  # detector 4: 1.0 s of delay
    assert mib.get_many([VEHICLE_DETECTOR_DELAY.instance(4)]) == (10,)
    c.set_actuations({4})
    assert steps(c, 11) == [False] * 10 + [True]
    # "If a management station attempts to set a value between 2551 and 65535, inclusive, the parameter is undefined":
    # the emulator refuses it, and keeps its delay.
    with pytest.raises(SnmpError) as info:
        mib.set_many([(VEHICLE_DETECTOR_DELAY.instance(4), 2551)])
    assert info.value.status is ErrorStatus.WRONG_VALUE and mib.get(VEHICLE_DETECTOR_DELAY.instance(4)) == 10


def test_a_detector_retimed_over_ntcip_keeps_the_calls_its_inputs_place(paper_toml: str) -> None:
    """The first timer SET on a controller whose detectors had none: the call of an actuation already there stays."""
    c = Controller(parse(paper_toml, "plain.toml"))
    mib = MibView(c)
    c.set_actuations({4})
    c.step()
    assert 4 in c.calls
    mib.set_many([(VEHICLE_DETECTOR_EXTEND.instance(2), 20)])
    assert 4 in c.calls


def test_a_detector_wired_to_no_phase_retimed_over_ntcip_calls_nothing_and_the_controller_runs_on() -> None:
    """The shipped four-phase intersection wires detectors 2, 4, 6 and 8; detector 1's row exists (up to the highest)
    but calls no phase. A SET of its delay and extension while it is actuated times them and calls nothing. Before,
    the controller's next step raised KeyError and the served emulator died (net-snmp's next request got no
    answer: the MIB conformance check's edge SETs, now and then)."""
    c = Controller(load(data_path("four_phase.toml")))
    mib = MibView(c)
    c.set_actuations({1})
    mib.set_many([(VEHICLE_DETECTOR_DELAY.instance(1), 255), (VEHICLE_DETECTOR_EXTEND.instance(1), 255)])
    calls = set()
    for _ in range(600):
        c.step()
        calls |= set(c.calls)
    assert not calls
    assert mib.get_many([VEHICLE_DETECTOR_DELAY.instance(1), VEHICLE_DETECTOR_EXTEND.instance(1)]) == (255, 255)
