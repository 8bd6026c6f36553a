"""Fixtures of the served emulator's tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    """`hils emulator serve --http` in another process: one controller, its event log on a TCP port."""
    from harness.bench.processes import start_emulator

    server = start_emulator(tmp_path_factory.mktemp("serve") / "serve.log", http=True)
    try:
        yield server
    finally:
        server.stop()
