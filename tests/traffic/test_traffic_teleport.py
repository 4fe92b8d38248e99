"""Teleporting vehicles: SUMO keeps reporting a vehicle it has taken off the road (lane '', invalid
values) until it re-inserts it; the road frame leaves such rows out instead of failing the run."""

from __future__ import annotations

from corridor.api import run
from tests.conftest import SCENARIOS

RAMP = str(SCENARIOS / "ramp_metering.yaml")


def test_a_run_with_teleports_is_ok_and_counts_them(tmp_path):
    # unmetered beltway, jams at the merges; a 2 s teleport threshold makes SUMO teleport waiting vehicles
    res = run(RAMP, runs=1, variants=["none"], sets=["duration=300", "road.sumo.time_to_teleport=2"],
              out=tmp_path / "b", report=False, workers=1)
    row = res.rows.iloc[0]
    assert row["status"] == "ok", row.get("error")
    assert row["teleports"] > 0
