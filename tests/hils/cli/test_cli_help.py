"""`hils --help` and every command's --help explain themselves (and do not crash on their own text)."""

from __future__ import annotations

import pytest

from hils.cli.main import build_parser, main

COMMANDS = ["run", "sweep", "compare", "view", "bench", "bench env", "bench overhead", "bench wire", "bench latency",
            "bench resco", "bench corridor",
            "emulator", "emulator serve", "emulator demo", "faults", "faults run", "report", "report paper"]


def test_the_top_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    for command in ("run", "sweep", "compare", "view", "bench", "emulator", "faults", "report"):
        assert f"\n    {command} " in out, command


@pytest.mark.parametrize("command", COMMANDS)
def test_each_command_has_a_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        build_parser().parse_args([*command.split(), "--help"])
    assert done.value.code == 0
    assert "usage: hils " + command in capsys.readouterr().out
