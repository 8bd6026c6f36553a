"""Bad input gets one clear line naming the file or option, the field and what is allowed: never a traceback.

Configs are fuzzed (any TOML value at any field of the shipped config, or the field removed); command-line
values are tried one by one through the command line, as a user types them.
"""

from __future__ import annotations

import copy
import datetime
import tomllib
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hils import config
from hils.cli import main
from hils.config import DEFAULT_CONFIG_NAME, ConfigError, IntersectionConfig

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
