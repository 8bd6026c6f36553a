"""sumo-rl's own tests and experiment scripts (this folder: its ``tests/`` and ``experiments/``, each file as its
repository has it but the import of its environments) run where they expect to: in a folder holding ``sumo_rl/nets``
(a copy of the installed sumo-rl's networks, which a script may write a demand into), with ``SUMO_HOME`` set (the
scripts check it) and gymnasium's ``sumo-rl-v0`` hils' (sumo-rl, which other tests of the process import, registers
the same id)."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
import sumo

from hils.protocol.resco import networks_dir
from hils.sumo_rl.environment import register


@pytest.fixture(scope="session")
def sumo_rl_checkout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder laid out as sumo-rl's repository is where its files run: ``sumo_rl/nets``."""
    root = tmp_path_factory.mktemp("sumo-rl")
    shutil.copytree(networks_dir().parent, root / "sumo_rl" / "nets", ignore=shutil.ignore_patterns("__pycache__"))
    return root


@pytest.fixture(autouse=True)
def in_sumo_rl_checkout(sumo_rl_checkout: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.chdir(sumo_rl_checkout)
    monkeypatch.setenv("SUMO_HOME", sumo.SUMO_HOME)
    register()
    yield sumo_rl_checkout
