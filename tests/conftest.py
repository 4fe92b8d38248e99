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

# --set lines for SUMO's Krauss drivers on scenarios/merging.yaml (its sumo_default variant): tests whose
# figures were measured with them (the scenario's base humans, EIDM since issue 27, never brake hard)
KRAUSS = [
    "road.demand.vehicle_types.car={car_following: Krauss, accel: 2.6, decel: 4.5, sigma: 0.5, tau: 1.0, "
    "length: 4.8, min_gap: 2.5, max_speed: 40, speed_dev: 0.1}",
    "road.demand.vehicle_types.truck={car_following: Krauss, accel: 1.2, decel: 4.0, sigma: 0.5, tau: 1.5, "
    "length: 12.0, width: 2.5, min_gap: 3.0, max_speed: 25, speed_dev: 0.05}",
]
