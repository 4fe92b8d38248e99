"""``scenarios/parking.yaml`` (SUMO street): SUMO's parked cars stand in the bays the network's
landmarks declare; a short batch of both variants searches, finds a slot, parks without collision;
same seed, same row."""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from corridor.run import build
from corridor.scenario import load
from corridor.snapshot import Kind
from tests.conftest import REPO, SCENARIOS

SCENARIO = SCENARIOS / "parking.yaml"
PERPENDICULAR = ["road.network.params.layout=perpendicular", "road.network.params.bay_length_m=3.0",
                 "road.network.params.bay_depth_m=5.5"]


@pytest.mark.parametrize("sets", [[], PERPENDICULAR], ids=["parallel", "perpendicular"])
def test_sumo_parks_its_cars_in_the_declared_bays(sets: list[str]) -> None:
    sc, _ = load(SCENARIO, ["duration=20", "warmup=5", "randomize={}", "road.network.params.occupancy_seed=5", *sets])
    with tempfile.TemporaryDirectory() as tmp:
        sim = build(sc, 0, Path(tmp))
        sim.run()
        s = sim.ctx.snapshot
    marks = s.road.tables.landmarks
    parked = np.array([str(i).startswith("parked") for i in s.ids])
    assert parked.sum() == sum(marks.taken) > 0
    bays = np.column_stack([np.asarray(marks.bay_x)[list(marks.taken)], np.full(sum(marks.taken), marks.bay_y)])
    got = s.position[parked, :2][np.argsort(s.position[parked, 0])]
    assert np.allclose(got, bays, atol=1e-6)
    assert np.allclose(np.cos(s.heading[parked] - marks.parked_heading), 1.0)
    assert (s.kind[parked] == Kind.CAR).all() and (s.speed[parked] == 0).all()


def run_cli(out: Path, *args: str) -> pd.DataFrame:
    cmd = [sys.executable, "-m", "corridor.cli", str(SCENARIO), "--workers", "2", "--out", str(out),
           "--no-report", "--quiet", *args]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return pd.read_parquet(out / "runs.parquet")


def test_both_variants_find_a_slot_and_park(tmp_path: Path) -> None:
    df = run_cli(tmp_path, "--runs", "1", "--set", "duration=80")
    assert set(df["variant"]) == {"parallel", "perpendicular"}
    assert (df["status"] == "ok").all(), df["error"].tolist()
    assert (df["collisions"] == 0).all() and (df["final_mode"] == "parked").all() and (df["success"] == 1).all()
    assert (df["slots_detected"] >= 1).all() and (df["slot_precision"] == 1.0).all()
    assert (df["delay_mainline_mean_s"] >= 0).all() and (df["slot_found_s"] > 20).all()


@pytest.mark.slow
def test_same_seed_same_row(tmp_path: Path) -> None:
    a = run_cli(tmp_path / "a", "--runs", "1", "--variant", "parallel", "--seed", "3")
    b = run_cli(tmp_path / "b", "--runs", "1", "--variant", "parallel", "--seed", "3")
    for k in ("success", "collisions", "pos_err_m", "manoeuvre_time_s", "slot_found_s", "delay_mainline_mean_s"):
        va, vb = a[k].iloc[0], b[k].iloc[0]
        assert va == vb or (math.isnan(va) and math.isnan(vb)), k
