"""Report time-series sections and the fitted-diagram section, on small synthetic runs (no SUMO)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from corridor.analysis.report import write_report
from corridor.analysis.report_series import (
    calibration_path,
    contour_grid,
    diagram_section,
    item_order,
    ramp_storage_veh,
    report_sections,
    series_sections,
)
from corridor.engine import Signals
from corridor.scenario import load
from corridor.traffic.macro.calibrate import FdFit
from tests.conftest import SCENARIOS

RAMPS = ["ccw0", "ccw1", "ccw10", "cw0"]
LOOP_T = [60.0, 120.0, 180.0]  # [s] loop interval ends


def _save(out: Path, run_id: str, sig: Signals) -> None:
    (out / "signals").mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out / "signals" / f"{run_id}.npz", **sig.as_arrays())


def _ramp_signals(with_control: bool) -> Signals:
    sig = Signals()
    for k, key in enumerate(RAMPS):
        for t in np.arange(0.0, 181.0, 5.0):
            sig.record(f"queue_{key}", t, t / 10 + k)
        for t in LOOP_T:
            sig.record(f"speed_down_kmh_{key}", t, 100.0 - t / 4 - k)
        if with_control:
            for t in (0.0, 60.0, 120.0):
                sig.record(f"rate_{key}", t, 900.0 + t)
    if with_control:
        for k in range(3):
            for t in (0.0, 60.0, 120.0):
                sig.record(f"split_ccw_{k}", t, 0.5 + 0.1 * k)
    sig.record("min_ttc", 0.0, 3.0)
    return sig


@pytest.fixture
def ramp_batch(tmp_path: Path) -> pd.DataFrame:
    """Variant none (no meters) and mpc; mpc's first run failed, so its second is the representative."""
    _save(tmp_path, "none-s0", _ramp_signals(False))
    _save(tmp_path, "mpc-s1", _ramp_signals(True))
    return pd.DataFrame({"run_id": ["none-s0", "mpc-s0", "mpc-s1"], "variant": ["none", "mpc", "mpc"],
                         "seed": [0, 0, 1], "status": ["ok", "error", "ok"], "error": ["", "boom", ""],
                         "tts_vh": [10.0, np.nan, 8.0], "collisions": [0, 0, 0]})


def _svgs(text: str, cls: str) -> list[str]:
    """The report's figures of one kind (``corridor.analysis.plots``: ``<figure class="plot <cls>">``)."""
    return re.findall(rf'<figure class="plot {cls}">.*?</figure>', text, re.S)


def _ids(fig: str, kind: str) -> list[str]:
    """The labels of the data layers of one kind drawn in a figure (``id="<kind>:<label>"``)."""
    return re.findall(rf'id="{kind}:([^"]*)"', fig)


def test_sections_drawn_from_signals(tmp_path: Path, ramp_batch: pd.DataFrame) -> None:
    secs = series_sections(tmp_path, ramp_batch, storage_veh=160.0)
    titles = [re.search(r"<h2>(.*?)</h2>", s).group(1) for s in secs]
    assert titles == ["Mainline speed contour", "Ramp queues", "Meter rates", "Route split"]
    contour, queues, rates, split = secs
    assert "mpc-s1" in contour and "mpc-s0" not in contour  # the first ok run stands for its variant
    maps = _svgs(contour, "heatmap")
    assert len(maps) == 2  # one panel per variant
    assert all("<image" in m and "speed [m/s]" in m for m in maps)  # the cells, rasterized; SI units
    rows = re.findall(r'>(c+w\d+)</text>', maps[0])
    assert rows == ["ccw0", "ccw1", "ccw10", "cw0"]  # ordered around the ring, per carriageway
    qcharts = _svgs(queues, "lines")
    assert len(qcharts) == 2 and all(_ids(c, "series") == RAMPS for c in qcharts)
    assert all(_ids(c, "ref") == ["storage 160 veh"] for c in qcharts)
    assert len(_svgs(rates, "lines")) == 1 and "mpc: meter rates" in rates  # none recorded no rates
    assert len(_ids(_svgs(split, "lines")[0], "series")) == 3


def test_no_sections_without_their_signals(tmp_path: Path) -> None:
    sig = Signals()
    for t in range(10):
        sig.record("min_ttc", float(t), 2.0)
    _save(tmp_path, "a-s0", sig)
    df = pd.DataFrame({"run_id": ["a-s0", "b-s0"], "variant": ["a", "b"], "status": ["ok", "ok"]})
    assert series_sections(tmp_path, df) == []
    assert series_sections(tmp_path / "nowhere", df) == []  # no signals kept at all


def test_contour_grid_places_samples_by_time() -> None:
    sig = {"s_a": (np.array([60.0, 120.0]), np.array([90.0, 30.0])), "s_b": (np.array([120.0]), np.array([50.0]))}
    edges, grid = contour_grid(sig, "s_", ["a", "b"])
    assert edges.tolist() == [0.0, 60.0, 120.0]
    assert grid[0].tolist() == [90.0, 30.0] and np.isnan(grid[1, 0]) and grid[1, 1] == 50.0


def test_item_order() -> None:
    assert sorted(["cw1", "ccw10", "ccw2", "cw0"], key=item_order) == ["ccw2", "ccw10", "cw0", "cw1"]


def _calibration(path: Path, n: int, with_flow: bool = True) -> Path:
    fit = FdFit(100.0, 35.0, 2.0, 0.0, 0.0, n)
    rho = np.linspace(1.0, 90.0, n)
    v = fit.speed(rho)
    pts = {"rho": rho.tolist(), "v_kmh": v.tolist(), **({"q": (rho * v).tolist()} if with_flow else {})}
    path.write_text(json.dumps({"v_free_kmh": 100.0, "rho_crit": 35.0, "a": 2.0, "capacity_vph_per_lane": 2123.0,
                                "rmse_kmh": 0.0, "n_points": n, "points": pts}))
    return path


def test_diagram_draws_every_detector_point(tmp_path: Path) -> None:
    sec = diagram_section(_calibration(tmp_path / "x.calibration.json", 37))
    assert "<h2>Calibrated fundamental diagram</h2>" in sec and "37 detector points" in sec
    speed, flow = _svgs(sec, "fd-speed"), _svgs(sec, "fd-flow")
    assert len(speed) == len(flow) == 1
    assert "detector points (n=37)" in speed[0] and "detector points (n=37)" in flow[0]
    assert "speed [m/s]" in speed[0] and "27.8 m/s" in sec  # SI: 100 km/h shown as 27.8 m/s
    assert _ids(speed[0], "series") == ["fit (all loops)"]  # the fitted curve
    only_speed = diagram_section(_calibration(tmp_path / "y.calibration.json", 12, with_flow=False))
    assert "detector points (n=12)" in _svgs(only_speed, "fd-speed")[0] and not _svgs(only_speed, "fd-flow")
    assert diagram_section(tmp_path / "missing.json") == "" and diagram_section(None) == ""


def test_report_of_ramp_scenario_has_sections(tmp_path: Path, ramp_batch: pd.DataFrame) -> None:
    scen = tmp_path / "ring.yaml"
    scen.write_text((SCENARIOS / "ramp_metering.yaml").read_text())
    sc, _ = load(scen, [])
    assert ramp_storage_veh(sc) == 160.0  # 1200 m ramps / 7.5 m per queued vehicle
    assert calibration_path(scen) is None
    _calibration(tmp_path / "ring.calibration.json", 20)
    assert calibration_path(scen) == tmp_path / "ring.calibration.json"
    out = write_report(ramp_batch, sc, tmp_path / "report.html", report_sections(tmp_path, ramp_batch, sc, scen))
    text = out.read_text()
    for title in ("Mainline speed contour", "Ramp queues", "Meter rates", "Route split",
                  "Calibrated fundamental diagram"):
        assert f"<h2>{title}</h2>" in text
    assert text.count("detector points (n=20)") == 2  # 20 points in each of the two diagrams


def test_other_scenarios_get_no_extra_sections(tmp_path: Path) -> None:
    sc, _ = load(SCENARIOS / "merging.yaml", [])
    sig = Signals()
    sig.record("min_ttc", 0.0, 4.0)
    _save(tmp_path, "sumo_default-s0", sig)
    df = pd.DataFrame({"run_id": ["sumo_default-s0"], "variant": ["sumo_default"], "status": ["ok"]})
    assert ramp_storage_veh(sc) is None
    assert report_sections(tmp_path, df, sc, SCENARIOS / "merging.yaml") == []
