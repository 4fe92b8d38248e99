"""``scenarios/parking_lot.yaml``: a short batch through the CLI (rows, highway-env's success, no
collision, the modes in the event log), determinism (same seed, same rows) and re-planning around a
pedestrian-sized obstacle that appears in front of the goal bay."""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pytest

from corridor.run import build
from corridor.scenario import load
from tests.conftest import REPO, SCENARIOS

SCENARIO = SCENARIOS / "parking_lot.yaml"
SHORT = ["duration=35"]
SAME = ("he_success", "success", "collisions", "pos_err_m", "heading_err_rad", "min_clearance_m",
        "manoeuvre_time_s", "direction_changes", "final_mode", "planned_direction_changes", "slots_detected")


def run_once(seed: int, sets: list[str]) -> tuple[dict, list]:
    sc, _ = load(SCENARIO, [*SHORT, *sets])
    with tempfile.TemporaryDirectory() as tmp:
        sim = build(sc, seed, Path(tmp))
        metrics = sim.run()
    return metrics, sim.ctx.events.events


def test_cli_batch_parks_without_collision(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "corridor.cli", str(SCENARIO), "--runs", "2", "--workers", "2", "--out",
           str(tmp_path), "--no-report", "--quiet", *[a for s in SHORT for a in ("--set", s)]]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    df = pd.read_parquet(tmp_path / "runs.parquet")
    assert len(df) == 2 and (df["status"] == "ok").all(), df["error"].tolist()
    assert (df["collisions"] == 0).all() and (df["he_crashed"] == 0).all()
    assert (df["he_success"] == 1).all() and (df["final_mode"] == "parked").all()
    assert (df["pos_err_m"] < 0.3).all() and (df["min_clearance_m"] > 0.2).all()
    assert (df["plan_time_p50_s"] > 0).all() and (df["events_mode"] >= 4).all()


def test_same_seed_same_row_and_modes() -> None:
    a, ev_a = run_once(2, [])
    b, ev_b = run_once(2, [])
    for k in SAME:
        assert a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])), k
    modes = [(e.t, e.message) for e in ev_a if e.kind == "mode"]
    assert modes == [(e.t, e.message) for e in ev_b if e.kind == "mode"]
    assert modes[0][1].startswith("search -> slot_found") and modes[-1][1].endswith("-> parked: at the goal")


def test_obstacle_appearing_in_front_of_the_bay_triggers_a_replan() -> None:
    m, events = run_once(1, ["backends.lot.params.intruder_t_s=3.0", "backends.lot.params.intruder_offset_m=[0.0,1.5]",
                             "randomize={}"])
    kinds = [e.kind for e in events]
    assert "scene" in kinds
    assert m["replans"] >= 1 and "path blocked" in m["abort_reasons"]
    assert m["collisions"] == 0 and m["he_success"] == 1 and m["final_mode"] == "parked"


def test_rerun_recording_with_lot_outlines_plan_and_sensor_overlays(tmp_path: Path) -> None:
    """The recorder draws what the lot, the plan event and the controller offer (and never fails on it)."""
    sc, _ = load(SCENARIO, ["duration=3"])
    rrd = tmp_path / "lot.rrd"
    sim = build(sc, 0, tmp_path, rerun_path=str(rrd))
    sim.run()
    ctrl = sim.ctx.components["parking"]
    lot = sim.ctx.snapshot.road.tables.landmarks
    assert set(lot.outlines()) == {"bays", "goal_bay", "walls"} and len(lot.outlines()["bays"]) == 28
    kinds = dict(ctrl.overlays().values())
    assert len(kinds["lines"]) == 6 and kinds["points"].shape[1] == 2  # six beams, their echoes
    assert any(e.data.get("polyline") for e in sim.ctx.events.of_kind("plan"))
    assert rrd.stat().st_size > 10_000
    import json

    lot_doc = json.loads((tmp_path / "parking" / "lot-run.json").read_text())  # the report's lot figure
    assert len(lot_doc["outlines"]["bays"]) == 28 and len(lot_doc["plans"]) >= 1
    assert len(lot_doc["driven"]) == 30 and lot_doc["goal"] is not None  # 3 s at the monitor's 0.1 s


@pytest.mark.slow
def test_fifty_runs_all_park(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "corridor.cli", str(SCENARIO), "--runs", "50", "--workers", "2", "--out",
           str(tmp_path), "--no-report", "--quiet"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=3600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    df = pd.read_parquet(tmp_path / "runs.parquet")
    assert (df["collisions"] == 0).all() and df["he_success"].mean() >= 0.98
