"""Bad input gets one clear line naming the file or option, the field and what is allowed: never a traceback.

Configs are fuzzed (any TOML value at any field of the shipped config, or the field removed); command-line
values are tried one by one through the command line, as a user types them.
"""

from __future__ import annotations

import copy
import datetime
import json
import tomllib
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import orjson
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from emulator.agent.mib import MibView
from emulator.model.controller import Controller
from emulator.model.delays import DelayedController
from hils.cli.main import main
from hils.dashboard.cli import load_replay
from hils.protocol import config
from hils.protocol.config import DEFAULT_CONFIG_NAME, ConfigError, IntersectionConfig
from hils.protocol.errors import UserError
from hils.protocol.ntcip import UNIT_FLASH_STATUS, UNIT_STARTUP_FLASH, UnitFlashStatus
from hils.run.testbed import Testbed
from hils.shell.events import BadLine, EventLogError, read

SHIPPED = tomllib.loads((resources.files("hils.data") / DEFAULT_CONFIG_NAME).read_text(encoding="utf-8"))
SOURCE = "lab/site.toml"

# Fields the shipped file leaves out, that a user may write.
OPTIONAL = [("phases", "2", name) for name in (*config._PHASE_OPTIONS, "startup", "approach", "turn", "permissive")] + [
    ("timing", name) for name in (*config._PHASE_OPTIONS, "startup_flash")] + [
    ("detectors", "1"), ("detectors", "1", "phase"), ("detectors", "1", "lane"),
    ("structure", "compatibility"), ("structure", "conflict")]


def _paths(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield (*prefix, key)
        yield from _paths(value, (*prefix, key))


PATHS = sorted({*_paths(SHIPPED), *OPTIONAL}, key=repr)

# Every kind of value TOML can hold, nested.
_SCALARS = (st.booleans() | st.integers() | st.integers(-3, 300) | st.floats(allow_nan=True, allow_infinity=True)
            | st.text(max_size=8) | st.sampled_from(["green", "off", "min", "north", "left", "E2C_0"])
            | st.datetimes(max_value=datetime.datetime(9999, 1, 1)) | st.dates() | st.times())
TOML_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=4), inner, max_size=3), max_leaves=8)


_GONE = object()  # a field left out


def _with(raw: dict, path: tuple, value: Any) -> dict:
    """A copy of ``raw`` with the field at ``path`` set to ``value`` (removed when ``value`` is ``_GONE``)."""
    out = copy.deepcopy(raw)
    node = out
    for key in path[:-1]:
        node = node.setdefault(key, {}) if isinstance(node, dict) else node[key]
    if not isinstance(node, (dict, list)):
        return out  # a field inside a value that is not a table: nothing to put there
    if value is _GONE:
        if isinstance(node, dict):
            node.pop(path[-1], None)
        else:
            del node[path[-1]]
    else:
        node[path[-1]] = value
    return out


@settings(max_examples=600, deadline=None)
@given(path=st.sampled_from(PATHS), value=TOML_VALUES | st.just(_GONE))
@example(path=("coordination", "patterns", 0, "coord_phases", 0), value=0)  # no such phase: it crashed once
def test_any_value_in_any_field_of_a_config_is_loaded_or_refused_with_file_and_field(path: tuple,
                                                                                   value: Any) -> None:
    raw = _with(SHIPPED, path, value)
    try:
        cfg = config.from_dict(raw, SOURCE)
    except ConfigError as err:
        assert str(err).startswith(f"{SOURCE}: {err.field}: ")
        assert err.field and err.message
    else:
        assert isinstance(cfg, IntersectionConfig)


@pytest.mark.parametrize(("phase_line", "field", "allowed"), [
    ('2 = { approach = "east", turn = "through", startup = ["green"] }', "phases.2.startup", "off, green"),
    ('2 = { approach = "east", turn = "through", startup = { on = "green" } }', "phases.2.startup", "off, green"),
])
@pytest.mark.parametrize("command", [["run", "--no-sumo", "--duration", "5", "--no-progress"],
                                     ["emulator", "serve", "--port", "0"]])
def test_an_unhashable_value_in_a_phase_is_one_line_for_run_and_serve(tmp_path: Path, capsys, phase_line: str,
                                                                      field: str, allowed: str,
                                                                      command: list[str]) -> None:
    text = (resources.files("hils.data") / DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")
    shipped_line = '2 = { approach = "east", turn = "through", startup = "green" }'
    assert shipped_line in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(shipped_line, phase_line), encoding="utf-8")
    code = main([*command, "--config", str(bad)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{bad}: {field}: " in err and allowed in err


def test_a_detector_calling_a_list_is_refused_naming_the_detector() -> None:
    raw = _with(SHIPPED, ("detectors", "3"), {"phase": [2]})
    with pytest.raises(ConfigError) as info:
        config.from_dict(raw, SOURCE)
    assert info.value.field == "detectors.3" and "allowed: the configured phases" in info.value.message


# --- event logs: hils.shell.events.read and `hils view` ------------------------------------------------------------


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> list[bytes]:
    """The lines of a real run's event log: two minutes, commands and polls."""
    path = tmp_path_factory.mktemp("run") / "events.jsonl"
    with Testbed(action_type="switch", agent="fixed-cycle", duration=120.0, log_path=path) as tb:
        tb.reset()
        tb.run()
    lines = path.read_bytes().splitlines(keepends=True)
    assert len(lines) > 40
    return lines


def _deep(depth: int) -> Any:
    value: Any = [2]
    for _ in range(depth):
        value = [value]
    return value


def _edit(field: str, value: Any, kind: str = "poll") -> Callable[[list[bytes]], list[bytes]]:
    """A crafter: the first record of ``kind`` with ``field`` set to ``value`` (removed when ``value`` is _GONE)."""
    def craft(lines: list[bytes]) -> list[bytes]:
        out, done = [], False
        for line in lines:
            record = orjson.loads(line)
            if not done and record["kind"] == kind:
                if value is _GONE:
                    record.pop(field, None)
                else:
                    record[field] = value
                line, done = orjson.dumps(record) + b"\n", True
            out.append(line)
        assert done, kind
        return out

    return craft


def _line(n: int, text: bytes) -> Callable[[list[bytes]], list[bytes]]:
    """A crafter: line ``n`` (1-based) replaced by ``text``."""
    return lambda lines: [*lines[:n - 1], text, *lines[n:]]


# Logs as a hostile or broken tool could hand them over: every one is replayed (its bad lines left out and
# named) or refused in one line; none gives a traceback.
CRAFTED: dict[str, Callable[[list[bytes]], list[bytes]]] = {
    "no kind": _edit("kind", _GONE),
    "no t": _edit("t", _GONE),
    "t a string": _edit("t", "12.5"),
    "t null": _edit("t", None),
    "t huge": _edit("t", 1e308),
    "no seq": _edit("seq", _GONE),
    "kind a number": _edit("kind", 7),
    "invalid UTF-8": _line(11, b'{"seq":10,"t":1.0,"kind":"note","message":"\xff\xfe"}\n'),
    "nested 100000 deep": _line(11, b"[" * 100_000 + b"\n"),
    "nested 40 deep": _edit("greens", _deep(40)),
    "a JSON array": _line(11, b"[1, 2, 3]\n"),
    "an empty line": _line(11, b"\n"),
    "NaN": _line(11, b'{"seq":10,"t":NaN,"kind":"note"}\n'),
    "poll without greens": _edit("greens", _GONE),
    "greens a string": _edit("greens", "2,6"),
    "poll_id a string": _edit("poll_id", "7"),
    "greens of lists": _edit("greens", [[2], [6]]),
    "state without to": _edit("to", _GONE, "state"),
    "command of strings": _edit("command", ["a", "b"], "command_dispatched"),
    "hold a string": _edit("hold_s", "5.2", "transition_verified"),
    "polls of run_ended": _edit("polls", {"polls": "many"}, "run_ended"),
    "reason of run_ended a list": _edit("reason", ["duration"], "run_ended"),
    "an unknown kind": _edit("kind", "from_the_future"),
    "intersections not a list": _edit("intersections", 5, "run_started"),
    "source a table": _edit("source", {"a": 1}, "run_started"),
    "torn last line": lambda lines: [*lines[:-1], lines[-1][:25]],
    "first line gone": lambda lines: lines[1:],
    "first line bad": _line(1, b"{not json\n"),
    "empty": lambda lines: [],
    "binary": lambda lines: [bytes(range(256)) * 4],
}


@pytest.mark.parametrize("name", list(CRAFTED))
def test_a_crafted_log_is_replayed_without_its_bad_lines_or_refused_in_one_line(tmp_path: Path, run_log: list[bytes],
                                                                                 name: str) -> None:
    path = tmp_path / "events.jsonl"
    path.write_bytes(b"".join(CRAFTED[name](run_log)))
    try:
        replay, _, skipped = load_replay(path)
    except UserError as err:
        assert "\n" not in str(err) and str(path) in str(err)
        return
    # What the page gets at any instant is JSON that every browser reads.
    for t in (0.0, replay.end / 2, replay.end):
        json.dumps(replay.at(t).snapshot(), allow_nan=False)
    # Records of a kind the board does not know (another version's) and a late t are records all the same.
    if name not in ("an unknown kind", "t huge"):
        assert skipped, "the bad line is named"


def test_a_bad_line_in_the_middle_is_named_and_the_rest_replays(tmp_path: Path, run_log: list[bytes]) -> None:
    """A log whose line 11 is bad: read() refuses it naming the line; the replay leaves it out and replays the
    whole run (it used to stop at line 11 and replay 0 s)."""
    path = tmp_path / "events.jsonl"
    path.write_bytes(b"".join(_line(11, b'{"seq":10,"t":1.0,"wall_ns":1}\n')(run_log)))
    with pytest.raises(EventLogError, match=rf"{path}: line 11: kind is missing"):
        list(read(path))
    bad: list[BadLine] = []
    records = list(read(path, on_bad=bad.append))
    assert [b.line for b in bad] == [11] and len(records) == len(run_log) - 1
    replay, _, skipped = load_replay(path)
    assert replay.end == orjson.loads(run_log[-1])["t"] > 100.0
    assert skipped == ["line 11: kind is missing; allowed: a string"]


@pytest.mark.parametrize(("args", "says"), [
    (["--realtime", "inf"], "--realtime is inf"),
    (["--realtime", "nan"], "--realtime is nan"),
    (["--port", "99999"], "--port is 99999"),
])
def test_hils_view_refuses_bad_options_in_one_line(tmp_path: Path, run_log: list[bytes], capsys, args: list[str],
                                                   says: str) -> None:
    (tmp_path / "events.jsonl").write_bytes(b"".join(run_log))
    assert main(["view", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1


# --- command-line values -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(("args", "says"), [
    (["--poll-hz", "0"], "--poll-hz is 0.0; allowed: > 0 and <= 1000"),
    (["--poll-hz", "nan"], "--poll-hz must be a finite number"),
    (["--duration", "inf"], "--duration is inf; allowed: simulated seconds > 0, at most 3.1536e+07 (a year)"),
    (["--duration", "1e308"], "--duration is 1e+308; allowed"),
    (["--duration", "nan"], "--duration is nan"),
    (["--duration", "0"], "--duration is 0"),
    (["--recover-after", "nan"], "--recover-after is nan"),
    (["--seed", "-1"], "--seed is -1; allowed: 0 to 2147483647"),
    (["--seed", "99999999999999999999"], "--seed is 99999999999999999999"),
    (["--plot-window", "0:0"], "--plot-window is '0:0'; allowed: START:END in simulated seconds, 0 <= START < END"),
    (["--plot-window", "nan:inf"], "--plot-window is 'nan:inf'"),
    (["--plot-window", "60"], "--plot-window is '60'"),
    (["--log", "."], "--log . is a folder; allowed: the path of a file"),
])
def test_a_bad_run_option_is_one_line_naming_the_option(tmp_path: Path, monkeypatch, capsys, args: list[str],
                                                        says: str) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--no-sumo", "--no-progress", "--duration", "5", "--out", "run", *args]) == 2
    err = capsys.readouterr().err
    assert err == f"hils: {err[6:]}" and err.count("\n") == 1 and says in err
    assert "four_leg.toml" not in err  # the option is to blame, not a file the user never gave


def test_a_route_file_sumo_cannot_read_is_named_with_sumos_reason(tmp_path: Path, capsys) -> None:
    from hils.sim.network import NET_FILE, data_path

    routes = tmp_path / "broken.rou.xml"
    routes.write_text("this is not XML\n")
    assert main(["run", "--duration", "5", "--no-progress", "--out", str(tmp_path / "run"),
                 "--net", str(data_path(NET_FILE)), "--routes", str(routes)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hils: SUMO did not start: ") and str(routes) in err and err.count("\n") == 1


# --- a SET the emulator accepts acts ---------------------------------------------------------------------------------


def test_a_set_of_unit_startup_flash_acts_at_the_next_power_up(paper_config: IntersectionConfig) -> None:
    """unitStartUpFlash is read-write in NTCIP 1202 (0..255 s): the Start-Up Flash the controller shows when power is
    restored. A SET reached the latency wrapper and changed nothing; it now goes to the controller, whose next
    power-up (a reboot) flashes that long, as unitFlashStatus startup(7) says, then starts its intervals."""
    unit = DelayedController(Controller(paper_config), paper_config.emulator)
    mib = MibView(unit)
    oid = UNIT_STARTUP_FLASH.instance()
    mib.set_many([(oid, 4)])
    assert mib.get_many([oid]) == (4,)
    unit.reset()  # power restored
    flash = UNIT_FLASH_STATUS.instance()
    assert mib.get_many([flash]) == (int(UnitFlashStatus.STARTUP),)
    for _ in range(39):
        unit.step()
    assert mib.get_many([flash]) == (int(UnitFlashStatus.STARTUP),) and not unit.greens
    unit.step()
    assert mib.get_many([flash]) == (int(UnitFlashStatus.NOT_FLASH),)
    assert unit.controller.greens == {2, 6}  # the start-up intervals of the config


@pytest.mark.parametrize("args", [["--latency-ms", "nan"], ["--jitter-ms", "inf"], ["--latency-ms", "-1"]])
def test_the_served_emulator_refuses_a_latency_that_is_not_finite_milliseconds(args: list[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["emulator", "serve", "--port", "0", *args])
    assert "allowed: finite milliseconds >= 0" in str(done.value.code)
