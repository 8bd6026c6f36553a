"""The layers of the design hold by themselves, and the folder names say what they are.

- ``hils`` never imports ``emulator`` or ``harness``: the middleware runs against real hardware alone.
- The emulator imports nothing of hils but the shared layer, ``hils.protocol`` (NTCIP objects and values, the
  intersection config, scenario files and RESCO's derived scenarios, SNMPv3's security services, the time grid,
  the user-error base), which imports nothing else of hils; importing the emulator loads no more of hils.
- Inside hils the data flow of DESIGN.md is the arrows between its subpackages (:data:`ALLOWED`): the manager
  (``control``) knows only the protocol; the I/O shell carries out its effects; a run assembles shell, SUMO
  (``sim``), agents and reports; the environments, the dashboard, sweeps and the command line sit on a run.
- The fault harness is a chain of jobs (:data:`FAULTS`), without a cycle: the faults, a scenario file's tables,
  the fault types, the file's reader, the judge, the runner, the command line.
- No module of hils imports, at run time or for its types alone, a module that imports it back: each has one job,
  and what two modules share lives in a third (the fast path's change feed in :mod:`hils.shell.fastpath`, which the
  transports import and which imports none of them).
"""

from __future__ import annotations

import ast
import graphlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Which subpackages of hils each subpackage may import (besides itself and the package ``hils``).
ALLOWED: dict[str, set[str]] = {
    "protocol": set(),
    "control": {"protocol"},
    "shell": {"protocol", "control"},
    "sim": {"protocol"},
    "agents": {"protocol", "control", "sim"},
    "report": {"protocol", "shell"},
    "run": {"protocol", "control", "shell", "sim", "agents", "report"},
    "envs": {"protocol", "control", "shell", "sim", "agents", "run"},
    # sumo-rl's API: its environments on the Testbed, beside hils' own
    "sumo_rl": {"protocol", "control", "shell", "sim", "agents", "run", "envs"},
    "dashboard": {"protocol", "shell", "sim", "run"},
    # a sweep's cell is one `hils run` (imported where a cell runs, so a Ray worker loads this module first)
    "sweep": {"protocol", "control", "agents", "report", "cli"},
    "cli": {"protocol", "control", "shell", "sim", "agents", "report", "run", "dashboard", "sweep"},
    "data": set(),
}

#: Which modules of harness.faults each module of it may import.
FAULTS: dict[str, set[str]] = {
    "inject": set(),
    "proxy": {"inject"},
    "table": set(),
    "registry": {"inject", "table"},
    "reader": {"inject", "table", "registry"},
    "judge": {"inject", "reader"},
    "runner": {"inject", "reader", "judge"},
    "cli": {"proxy", "reader", "judge", "runner"},
}


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


def module_imports(path: Path) -> set[str]:
    """The modules a file imports when it is loaded or type-checked: its top level, ``if TYPE_CHECKING:`` and
    ``try:`` blocks included, the lazy imports inside functions left out (they run after both modules are loaded)."""
    out: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Import):
                out.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                out.add(node.module)
                out.update(f"{node.module}.{alias.name}" for alias in node.names)
            elif isinstance(node, ast.If | ast.Try):
                visit(node.body)
                visit(node.orelse)

    visit(ast.parse(path.read_text(encoding="utf-8")).body)
    return out


def ours(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def module_of(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def layer(module: str) -> str | None:
    """The subpackage of hils a module belongs to (None for the package itself and its two top-level files)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in ALLOWED) else None


@pytest.mark.parametrize("path", ours("hils"), ids=lambda p: str(p.relative_to(ROOT)))
def test_hils_imports_neither_the_emulator_nor_the_harness(path: Path) -> None:
    bad = {m for m in imports_of(path) if m.split(".")[0] in ("emulator", "harness")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}: hils must run against real hardware alone"


@pytest.mark.parametrize("path", ours("hils"), ids=lambda p: str(p.relative_to(ROOT)))
def test_each_layer_of_hils_imports_only_the_layers_below_it(path: Path) -> None:
    own = layer(module_of(path))
    if own is None:
        return  # hils/__init__.py and __main__.py name the public API and the entry point
    assert own in ALLOWED, f"{path.relative_to(ROOT)}: subpackage {own!r} is not in ALLOWED: place it"
    imported = {layer(m) for m in imports_of(path) if m.split(".")[0] == "hils"} - {None, own}
    bad = imported - ALLOWED[own]
    assert not bad, f"{path.relative_to(ROOT)} ({own}) imports {sorted(bad)}; allowed: {sorted(ALLOWED[own])}"


@pytest.mark.parametrize("path", ours("emulator"), ids=lambda p: str(p.relative_to(ROOT)))
def test_the_emulator_imports_only_the_shared_layer_of_hils(path: Path) -> None:
    bad = {m for m in imports_of(path) if m.split(".")[0] == "hils" and m != "hils"
           and not m.startswith("hils.protocol")}
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}; allowed of hils: hils.protocol"
    assert not {m for m in imports_of(path) if m.split(".")[0] == "harness"}


def test_loading_the_emulator_loads_no_middleware() -> None:
    """At run time too: importing every emulator module pulls in only the shared layer of hils."""
    modules = [module_of(p) for p in ours("emulator")]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "print(' '.join(sorted(m for m in sys.modules if m == 'hils' or m.startswith('hils.'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded = set(done.stdout.split())
    assert loaded and all(m == "hils" or m.startswith("hils.protocol") for m in loaded), \
        f"the emulator loaded {sorted(m for m in loaded if m != 'hils' and not m.startswith('hils.protocol'))}"


#: Left out of the check for import circles: sumo-rl's API keeps sumo-rl's module layout, read side by side with
#: sumo-rl's own, in which the traffic signal and the environment name each other's types.
MIRRORED = ("hils.sumo_rl.",)


def test_no_module_of_hils_imports_a_module_that_imports_it_back() -> None:
    modules = {module_of(p): p for p in ours("hils") if not module_of(p).startswith(MIRRORED)}
    graph = {m: {i for i in module_imports(p) if i in modules and i != m} for m, p in modules.items()}
    graphlib.TopologicalSorter(graph).prepare()  # raises CycleError, naming the circle


def test_the_fault_harness_has_no_cycle() -> None:
    graphlib.TopologicalSorter(FAULTS).prepare()  # raises CycleError, naming the cycle


@pytest.mark.parametrize("path", [p for p in ours("harness/faults") if p.stem != "__init__"],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_each_module_of_the_fault_harness_imports_only_the_jobs_before_it(path: Path) -> None:
    own = path.stem
    assert own in FAULTS, f"{path.relative_to(ROOT)}: module {own!r} is not in FAULTS: place it"
    imported = {m.split(".")[2] for m in imports_of(path) if m.startswith("harness.faults.")}
    bad = imported - FAULTS[own]
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)} of harness.faults; allowed: {sorted(FAULTS[own])}"
