"""The SUMO backend skips comparing the id lists on a quiet step (no departure, arrival, teleport or
off-lane vehicle): on every such step of a real run the ids must be those of the previous step."""

from __future__ import annotations

from pathlib import Path

import pytest

from corridor.run import build
from corridor.scenario import load
from corridor.traffic.sumo.backend import SumoBackend
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "merging.yaml"


def test_a_quiet_step_has_the_previous_steps_ids(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {"quiet": 0, "other": 0}
    same_rows = SumoBackend._same_rows

    def checked(self: SumoBackend, ids: list[str], quiet: bool = False):  # noqa: ANN202
        prev = self._rows.id_list
        if quiet and len(ids) == len(prev):
            assert ids == prev  # what the skipped comparison would have found
            seen["quiet"] += 1
        else:
            seen["other"] += 1
        return same_rows(self, ids, quiet)

    monkeypatch.setattr(SumoBackend, "_same_rows", checked)
    sc, _ = load(str(SCENARIO), ["duration=120", "warmup=0"])  # departures from the start, arrivals from ~80 s
    metrics = build(sc, 1, tmp_path).run()
    assert metrics["vehicles_arrived"] > 0 and seen["quiet"] > 100 and seen["other"] > 100
