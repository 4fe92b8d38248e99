"""The merging sweep: the grid written from the flagship (tools/merging_sweep.py) and its heat-map cells
(``corridor.analysis.merge_sweep``): paired by seed against the cell's human baseline."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pandas as pd
import yaml

from corridor.analysis.merge_report import report_sections
from corridor.analysis.merge_sweep import NAME, sweep_cells
from tests.conftest import REPO


def _tool():  # tools/ is not a package
    spec = importlib.util.spec_from_file_location("merging_sweep", REPO / "tools" / "merging_sweep.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_grid_is_the_documented_one_on_the_flagship() -> None:
    tool = _tool()
    base = yaml.safe_load((REPO / "scenarios" / "merging.yaml").read_text())
    data = tool.sweep_data(base)
    assert len(data["sweep"]) == 5 * 3 * 3 and all(NAME.match(v) for v in data["sweep"])
    human, coop = data["sweep"]["p0_r800_L200"], data["sweep"]["p25_r1200_L50"]
    assert "controllers.merge" not in human and coop["controllers.merge"] == base["sweep"]["v2x_cps"]["controllers.merge"]
    assert coop["road.demand.flows.main_car.connected_share"] == 0.25
    assert coop["road.network.params.accel_lane_length_m"] == 50
    assert max(r for _, r in coop["road.demand.flows.ramp_car.profile"]) == 1200
    assert not any("connected_share" in k for k in data["randomize"])  # penetration is the grid's
    assert data["road"]["demand"]["vehicle_types"] == base["road"]["demand"]["vehicle_types"]  # the same humans


def test_the_committed_sweep_file_is_what_the_tool_writes(tmp_path: Path) -> None:
    tool = _tool()
    tool.write(tmp_path / "sweep.yaml")
    assert (tmp_path / "sweep.yaml").read_text() == (REPO / "scenarios" / "sweeps" / "merging_sweep.yaml").read_text()


def _rows() -> pd.DataFrame:
    rows = []
    for seed, human, coop in ((0, 20.0, 18.0), (1, 30.0, 27.0), (2, 25.0, 22.5)):
        rows.append({"variant": "p0_r800_L100", "seed": seed, "status": "ok", "delay_mean_s": human})
        rows.append({"variant": "p25_r800_L100", "seed": seed, "status": "ok", "delay_mean_s": coop})
        rows.append({"variant": "p25_r400_L100", "seed": seed, "status": "ok", "delay_mean_s": coop})  # no baseline
    return pd.DataFrame(rows)


def test_cells_are_paired_differences_to_their_own_baseline() -> None:
    [cell] = sweep_cells(_rows(), "delay_mean_s")  # p25_r400 has no p0_r400: left out
    assert (cell.penetration_pct, cell.ramp_vph, cell.lane_m, cell.pairs) == (25, 800, 100, 3)
    assert math.isclose(cell.mean, -2.5) and cell.hi < 0 and cell.significant  # -2, -3, -2.5


def test_two_equal_differences_are_not_significant() -> None:
    rows = _rows()
    rows.loc[(rows["variant"] == "p25_r800_L100") & (rows["seed"] == 1), "delay_mean_s"] = 28.0  # -2, -2, -2.5
    rows = rows[rows["seed"] < 2]  # -2, -2: zero spread
    [cell] = sweep_cells(rows, "delay_mean_s")
    assert cell.lo == cell.hi == -2.0 and not cell.significant


def test_the_report_draws_the_sweep_instead_of_per_variant_tables(tmp_path: Path) -> None:
    html = "".join(report_sections(tmp_path, _rows(), None))
    assert "Merging sweep" in html and html.count('class="plot sweep"') == 1  # delay only: no other metric
