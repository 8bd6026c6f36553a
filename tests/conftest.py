"""Shared fixtures: the shipped paper intersection and a fresh controller on it."""

from __future__ import annotations

from importlib import resources

import pytest

from emulator.model.controller import Controller
from hils.protocol.config import DEFAULT_CONFIG_NAME, IntersectionConfig, load


@pytest.fixture(scope="session")
def paper_config() -> IntersectionConfig:
    """The shipped four-leg intersection of the paper (immutable, so shared by the session)."""
    return load()


@pytest.fixture(scope="session")
def paper_toml() -> str:
    """The text of the shipped config, to derive variants from."""
    return (resources.files("hils.data") / DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")


@pytest.fixture
def controller(paper_config: IntersectionConfig) -> Controller:
    """A freshly powered-up controller on the paper intersection."""
    return Controller(paper_config)
