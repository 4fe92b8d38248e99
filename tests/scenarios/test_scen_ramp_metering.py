"""scenarios/ramp_metering.yaml end to end, short: the CLI runs none / alinea / mpc on one seed, and
ALINEA in SUMO throttles a ramp when the measured occupancy is above its set point."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from corridor.run import simulate
from corridor.scenario import load
from tests.conftest import REPO, SCENARIOS

SCENARIO = SCENARIOS / "ramp_metering.yaml"


def test_cli_runs_the_three_variants(tmp_path: Path) -> None:
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "corridor.cli", str(SCENARIO), "--runs", "1", "--workers", "1", "--quiet",
           "--no-report", "--out", str(out), "--set", "duration=70"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    df = pd.read_parquet(out / "runs.parquet")
    assert sorted(df["variant"]) == ["alinea", "mpc", "none"]
    assert (df["status"] == "ok").all(), df[["variant", "error"]].to_string()
    assert (df["tts_vh"] > 0).all() and (df["vehicles_departed"] > 100).all()
    mpc = df[df["variant"] == "mpc"].iloc[0]
    assert mpc["mpc_solves"] == 2 and mpc["mpc_solve_p95_s"] > 0


def _min_rate(setpoint_pct: float) -> float:
    sc, _ = load(SCENARIO, [f"controllers.ramps={{type: ramp_alinea, params: {{alinea_setpoint_pct: {setpoint_pct}}}}}",
                            "duration=190"])
    _, ctx, _ = simulate(sc, seed=1)
    rates = [ctx.signals.get(n)[1] for n in ctx.signals.names() if n.startswith("rate_")]
    return float(np.min(np.concatenate(rates)))


def test_alinea_responds_to_occupancy() -> None:
    """Set point far below the loops' occupancy: meters throttle; far above it: meters stay open."""
    assert _min_rate(0.5) < 1800.0 - 70.0 * 2.0  # at least one step of >= 2 % over the set point
    assert _min_rate(90.0) == 1800.0
