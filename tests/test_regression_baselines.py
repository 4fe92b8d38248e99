"""Every scenario has a recorded baseline; a short re-run must not collide more, nor lose STL
robustness below the recorded bound.  This also runs every scenario briefly in the default suite.
Re-record explicitly: python -m corridor.baseline record scenarios/<name>.yaml"""

from __future__ import annotations

from pathlib import Path

import pytest

from corridor.baseline import check
from tests.conftest import SCENARIOS as SCENARIO_DIR

SCENARIOS = sorted(SCENARIO_DIR.glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_scenario_keeps_its_baseline(path: Path):
    problems = check(path)
    assert not problems, "\n".join(problems)
