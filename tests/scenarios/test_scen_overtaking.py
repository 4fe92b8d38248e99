"""``scenarios/overtaking.yaml`` end to end through the CLI: short batches, rows, safety, specs, a real pass.

Seeds 10 and 11 have oncoming traffic that the pass must respect (the gaps depend on the per-field draws;
the rows record them); the every-step comparison is marked slow.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from corridor.scenario import load
from corridor.stl import parse_formula
from tests.conftest import REPO, SCENARIOS

SCENARIO = SCENARIOS / "overtaking.yaml"


def run_cli(out: Path, *args: str) -> pd.DataFrame:
    cmd = [sys.executable, "-m", "corridor.cli", str(SCENARIO), "--workers", "1", "--out", str(out),
           "--no-report", "--quiet", *args]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return pd.read_parquet(out / "runs.parquet")


def test_scenario_loads_and_specs_parse() -> None:
    sc, _ = load(SCENARIO)
    assert {s.name for s in sc.specs} == {"safety", "completion"}
    for spec in sc.specs:
        assert parse_formula(spec.formula).signal_names() <= {
            "gap_lead", "ahead_lead", "lat_lead", "lat_onc", "gap_onc", "lane_offset", "clearance"}
    assert set(sc.sweep) == {"event", "every_step"}


@pytest.fixture(scope="module")
def event_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[pd.DataFrame, Path]:
    out = tmp_path_factory.mktemp("overtaking")
    # 20 s with the ego instead of 45 s: the passes of these seeds are complete by t = 70 s
    return run_cli(out, "--runs", "2", "--seed", "10", "--variant", "event", "--set", "duration=80"), out


def test_rows_ok_safe_and_specs_positive(event_runs: tuple[pd.DataFrame, Path]) -> None:
    df, _ = event_runs
    assert len(df) == 2
    assert (df["status"] == "ok").all(), df["error"].tolist()
    assert (df["collisions"] == 0).all()
    for col in ("spec.safety.satisfied", "spec.safety.space", "spec.safety.time",
                "spec.completion.satisfied", "spec.completion.space"):
        assert col in df.columns
    assert (df["spec.safety.space"] > 0).all()
    assert df["outcome"].isin(["passed", "aborted", "stayed"]).all()
    assert (df["replans"] > 0).all() and (df["replans"] < df["replans_every_step"]).all()


def test_ego_changes_lane_and_passes(event_runs: tuple[pd.DataFrame, Path]) -> None:
    df, out = event_runs
    passed = df[df["overtake_success"] == 1]
    assert len(passed) >= 1
    row = passed.iloc[0]
    assert row["spec.completion.satisfied"] and row["completion_time_s"] > 0
    sig = np.load(out / "signals" / f"{row['run_id']}.npz")
    assert sig["lane_offset"].max() > 2.0  # the body centre went well into the oncoming lane
    assert abs(sig["lane_offset"][-1]) < 0.5  # and came back
    assert sig["ahead_lead"][-1] > 5.0  # ahead of the car it overtook


@pytest.mark.slow
def test_event_triggered_saves_replans(tmp_path: Path) -> None:
    df = run_cli(tmp_path, "--runs", "1", "--seed", "12")
    by = df.set_index("variant")
    assert (df["collisions"] == 0).all() and (df["spec.safety.space"] > 0).all()
    assert by.loc["event", "replans"] < 0.5 * by.loc["every_step", "replans"]
    assert by.loc["every_step", "replans"] >= by.loc["every_step", "replans_every_step"]
