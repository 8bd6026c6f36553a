"""The layers of the design hold by themselves: hils never imports emulator or harness; the emulator
imports nothing of hils but the shared layer (the NTCIP object model with its value types and latency
model, the intersection config, the scenario files that name the config of each intersection, the scenarios
derived from RESCO's networks, the user-error base class, SNMPv3's security failures and services), which
imports nothing else of hils."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = {"hils", "hils.ntcip", "hils.config", "hils.scenario", "hils.resco", "hils.errors", "hils.usm",
          "hils.timegrid", "hils.hires"}


def imports_of(path: Path) -> set[str]:
    """Every module a file imports, at any depth of the file (lazy imports inside functions too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names if node.module == "hils")
    return out


def ours(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("path", ours("hils"), ids=lambda p: p.name)
def test_hils_imports_neither_the_emulator_nor_the_harness(path: Path) -> None:
    bad = {m for m in imports_of(path) if m.split(".")[0] in ("emulator", "harness")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}: hils must run against real hardware alone"


@pytest.mark.parametrize("path", ours("emulator"), ids=lambda p: p.name)
def test_the_emulator_imports_only_the_shared_layer_of_hils(path: Path) -> None:
    bad = {m for m in imports_of(path) if m.split(".")[0] == "hils" and m not in SHARED}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}; allowed of hils: {sorted(SHARED)}"
    assert not {m for m in imports_of(path) if m.split(".")[0] == "harness"}


@pytest.mark.parametrize("module", sorted(SHARED - {"hils"}))
def test_the_shared_layer_imports_nothing_else_of_hils(module: str) -> None:
    path = ROOT / (module.replace(".", "/") + ".py")
    bad = {m for m in imports_of(path) if m.split(".")[0] == "hils" and m not in SHARED}
    assert not bad, f"{module} imports {sorted(bad)}"


def test_loading_the_emulator_loads_no_middleware() -> None:
    """At run time too: importing every emulator module pulls in only the shared layer of hils."""
    modules = [f"emulator.{p.stem}" for p in ours("emulator") if p.stem != "__init__"]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "print(' '.join(sorted(m for m in sys.modules if m == 'hils' or m.startswith('hils.'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded = set(done.stdout.split())
    assert loaded <= SHARED, f"the emulator loaded {sorted(loaded - SHARED)}"
