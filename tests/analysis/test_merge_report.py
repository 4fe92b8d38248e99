"""Merge-bottleneck report sections: capacity-drop table with intervals, paired differences seed by seed,
loop charts and the time-space diagram from the runs' signals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from corridor.analysis.merge_report import report_sections


def _signals(path: Path, flow_down: float) -> None:
    t = np.array([60.0, 120.0, 180.0])
    np.savez(path, **{"loop_flow_vph_down": np.full(3, flow_down), "loop_flow_vph_down.t": t,
                      "loop_density_vpkm_down": np.array([20.0, 30.0, 40.0]), "loop_density_vpkm_down.t": t,
                      "ts_speed_kmh_00000": np.array([100.0, 20.0, 90.0]), "ts_speed_kmh_00000.t": t,
                      "ts_speed_kmh_00025": np.array([100.0, 100.0, 10.0]), "ts_speed_kmh_00025.t": t})


def test_sections_show_drop_intervals_and_paired_differences(tmp_path: Path) -> None:
    (tmp_path / "signals").mkdir()
    rows = []
    for v, speed in (("human", 20.0), ("merge0", 21.0)):
        for seed in range(3):
            rid = f"{v}-s{seed}"
            _signals(tmp_path / "signals" / f"{rid}.npz", 1800.0)
            rows.append({"run_id": rid, "variant": v, "seed": seed, "status": "ok", "breakdown": 1.0,
                         "breakdown_s": 600.0, "prebreakdown_flow_vph": 2000.0, "discharge_flow_vph": 1800.0,
                         "capacity_drop_pct": 10.0 + seed, "avg_speed_mps": speed + 0.1 * seed, "collisions": 0})
    html = "".join(report_sections(tmp_path, pd.DataFrame(rows), None))
    assert "<td>3/3</td>" in html and "11.0 [8.5, 13.5]" in html  # drops 10, 11, 12: t(2) interval
    assert "<td>merge0</td><td>3</td><td>1.00 [1.00, 1.00]</td>" in html  # every seed +1.00 m/s
    assert html.count('class="plot heatmap"') == 2 and html.count('class="plot fd"') == 2
    assert "x=25 m" in html


def test_scenarios_without_the_columns_get_nothing(tmp_path: Path) -> None:
    df = pd.DataFrame([{"run_id": "a-s0", "variant": "a", "seed": 0, "status": "ok", "delay_mean_s": 3.0}])
    assert report_sections(tmp_path, df, None) == []
