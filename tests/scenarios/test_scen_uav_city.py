"""uav_city end to end (a small, dense city so that a short run has encounters): rows ok, the
encounters are real (``none`` has NMACs), the fleet-wide potential field removes most of them,
aircraft switch fidelity both ways, deliveries complete; same seed -> same rows."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pandas as pd

from corridor.run import simulate
from corridor.scenario import load
from tests.conftest import REPO, scenario_file

CITY = scenario_file("uav_city")
SMALL = ["backends.air.params.city.n=80", "backends.air.params.city.size_m=1200", "backends.air.params.city.vertiports=6",
         "backends.air.params.city.vertiport_spacing_m=200", "backends.air.params.city.start_spacing_m=60"]
MACHINE = {"wall_s", "rtf", "cpu_per_sim_s"}  # measurements of the machine, not of the scenario


def test_small_city_both_variants(tmp_path: Path) -> None:
    out = tmp_path / "city"
    sets = [a for s in [*SMALL, "duration=40"] for a in ("--set", s)]
    exe = [sys.executable, "-m", "corridor.cli", str(CITY), "--out", str(out), "--workers", "2", "--quiet",
           "--no-report", *sets]
    res = subprocess.run(exe, capture_output=True, text=True, cwd=REPO, timeout=1800)
    assert res.returncode == 0, res.stderr[-2000:]
    df = pd.read_parquet(out / "runs.parquet").set_index("variant")
    assert (df["status"] == "ok").all(), df["error"].tolist()
    none, pf = df.loc["none"], df.loc["potential_field"]
    assert none["nmac"] >= 5 and pf["nmac"] < none["nmac"] / 3
    assert pf["avoid_share"] > 0.0 and none["avoid_share"] == 0.0
    for row in (none, pf):
        assert 0.0 < row["six_dof_share"] < 1.0 and row["promotions"] >= 1 and row["demotions"] >= 1
        assert row["missions_done"] >= 1 and math.isfinite(row["mission_delay_mean_s"])
        assert row["los_per_fh"] == row["los"] / (80 * 40 / 3600.0)
        assert 0.95 < row["link_delivery_ratio"] < 1.0  # 2 % Bernoulli loss
        assert row["cpu_per_sim_s"] > 0.0


def test_same_seed_same_rows() -> None:
    sc, _ = load(CITY, [*SMALL, "duration=8", "backends.air.params.city.n=40"])
    a, b = simulate(sc, 3)[0], simulate(sc, 3)[0]
    keys = sorted(set(a) - MACHINE)
    assert [a[k] for k in keys] == [b[k] for k in keys]
    assert a["promotions"] >= 1
