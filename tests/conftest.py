"""Shared fixtures: the shipped paper intersection, the city's, and a fresh controller on the paper's."""

from __future__ import annotations

from importlib import resources

import pytest

from emulator.model.controller import Controller
from hils.protocol.config import DEFAULT_CONFIG_NAME, IntersectionConfig, load, parse


@pytest.fixture(scope="session")
def paper_config() -> IntersectionConfig:
    """The shipped four-leg intersection of the paper (immutable, so shared by the session)."""
    return load()


@pytest.fixture(scope="session")
def city_config() -> IntersectionConfig:
    """The shipped four-leg intersection as a city runs it: the paper's, with overlaps, a plan and a preempt."""
    return parse((resources.files("hils.data") / "four_leg_city.toml").read_text(encoding="utf-8"),
                 "hils/data/four_leg_city.toml")


@pytest.fixture(scope="session")
def paper_toml() -> str:
    """The text of the shipped config, to derive variants from."""
    return (resources.files("hils.data") / DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")


@pytest.fixture
def controller(paper_config: IntersectionConfig) -> Controller:
    """A freshly powered-up controller on the paper intersection."""
    return Controller(paper_config)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """`make test` runs two pytest-xdist workers (``--dist loadgroup``): every test that waits on real seconds or
    drives a browser goes to one of them, one after another as without xdist, so that no two share a clock's
    slack; the rest, which only compute, spread over both (the wall-clock tests leave most of a core idle)."""
    for item in items:
        if item.get_closest_marker("wallclock") or item.get_closest_marker("browser"):
            item.add_marker(pytest.mark.xdist_group("real-time"))
