"""Fixtures and paths shared by the test suite: the repository, its scenarios, the tests' data.

A test function asks for them as fixtures (``def test_x(scenario_path): scenario_path("merging")``);
module-level code (a ``parametrize`` list, a constant of the module) imports the same paths:
``from tests.conftest import REPO, SCENARIOS, scenario_file``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]  # the repository (a clone of corridor)
SCENARIOS = REPO / "scenarios"  # the packaged YAML scenarios
TESTS = REPO / "tests"
TEST_DATA = TESTS / "data"  # data files of the tests (TPCAP cases, ...)


def scenario_file(name: str) -> Path:
    """The packaged scenario ``name`` (``"merging"`` -> ``scenarios/merging.yaml``); it must exist."""
    path = SCENARIOS / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in SCENARIOS.glob("*.yaml")))
        raise FileNotFoundError(f"no scenario {name!r} in {SCENARIOS} (known: {known})")
    return path


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository's root folder."""
    return REPO


@pytest.fixture(scope="session")
def scenarios_dir() -> Path:
    """The folder of the packaged scenarios."""
    return SCENARIOS


@pytest.fixture(scope="session")
def scenario_path() -> Callable[[str], Path]:
    """A function: scenario name -> its file (``scenario_path("merging")``)."""
    return scenario_file
