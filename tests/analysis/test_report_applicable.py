"""Report shows only what applies: no collision probability without vehicles, no sensitivity to a draw
that cannot affect a variant, and time-series / trajectory sections for merging and UAV runs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from corridor.analysis.report import (
    collisions_apply,
    draw_not_applicable,
    draw_sensitivity,
    not_applicable_draws,
    variant_scenarios,
    write_report,
)
from corridor.scenario import load
from tests.conftest import SCENARIOS


def _scenario(name: str, sets: list[str] | None = None):  # noqa: ANN202 - a corridor Scenario
    return load(SCENARIOS / f"{name}.yaml", sets or [])[0]


def _rows(variants: list[str], seeds: int, **cols_of_seed) -> pd.DataFrame:  # noqa: ANN003
    rows = []
    for s in range(seeds):
        for v in variants:
            rows.append({"run_id": f"{v}-s{s}", "variant": v, "seed": s, "status": "ok", "error": "",
                         "collisions": 0, **{k: f(s, v) for k, f in cols_of_seed.items()}})
    return pd.DataFrame(rows)


def test_metanet_report_has_no_collision_probability(tmp_path: Path) -> None:
    sc = _scenario("hegyi_benchmark")
    df = _rows(["none", "alinea", "mpc"], 3, tts_vh=lambda s, v: 1500.0 + s - 10 * len(v))
    assert not collisions_apply(df, sc)
    text = write_report(df, sc, tmp_path / "report.html").read_text()
    assert "<h2>Safety: collisions</h2>" not in text and "P(collision)" not in text
    assert "No collision probability" in text
    verdict = text.split("<h2>Verdict")[1].split("<h2>")[0]
    assert "collisions" not in verdict  # a count of 0 that means nothing is not a verdict
    # a road scenario keeps it, and so does any run that did report a collision
    merging = _scenario("merging")
    assert collisions_apply(_rows(["sumo_default"], 2), merging)
    hit = df.copy()
    hit.loc[0, "collisions"] = 1
    assert collisions_apply(hit, sc)
    assert not collisions_apply(df.drop(columns="collisions"), merging)  # rows without the column


def test_uav_scenario_keeps_collision_probability(tmp_path: Path) -> None:
    sc = _scenario("uav_encounter")
    df = _rows(["none", "potential_field", "control_tube"], 2, nmac=lambda s, v: 0)
    assert collisions_apply(df, sc)  # no road, but the air backend puts aircraft in the snapshot
    assert "<h2>Safety: collisions</h2>" in write_report(df, sc, tmp_path / "r.html").read_text()


def _merging_batch(seeds: int = 12) -> pd.DataFrame:
    rng = np.random.default_rng(3)
    loss, scale = rng.uniform(0.0, 0.3, seeds), rng.uniform(0.9, 1.1, seeds)
    return _rows(["sumo_default", "v2x_fifo", "v2x_cps"], seeds,
                 **{"draw.channels.v2x.loss.p": lambda s, v: loss[s], "draw.road.demand.scale": lambda s, v: scale[s],
                    "delay_mean_s": lambda s, v: 10.0 + 20.0 * (scale[s] - 1.0) + (5.0 * loss[s] if "v2x" in v else 0.0)})


def test_sensitivity_only_against_draws_the_variant_uses() -> None:
    sc = _scenario("merging")
    scen = variant_scenarios(sc)
    assert draw_not_applicable(scen["sumo_default"], "channels.v2x.loss.p") == "no component uses channel v2x"
    assert draw_not_applicable(scen["v2x_fifo"], "channels.v2x.loss.p") is None  # v2x_merging's channel default
    assert draw_not_applicable(scen["sumo_default"], "road.demand.scale") is None
    df = _merging_batch()
    skip = not_applicable_draws(df, sc)
    assert skip == {"sumo_default": {"draw.channels.v2x.loss.p": "no component uses channel v2x"}}
    html = draw_sensitivity(df, "delay_mean_s", skip)
    fitted = re.findall(r"<tr><td>(\w+)</td><td>([\w.]+)</td><td>", html)
    assert ("sumo_default", "road.demand.scale") in fitted
    assert ("v2x_fifo", "channels.v2x.loss.p") in fitted and ("v2x_cps", "channels.v2x.loss.p") in fitted
    assert ("sumo_default", "channels.v2x.loss.p") not in fitted
    assert "sumo_default &times; <code>channels.v2x.loss.p</code>: no component uses channel v2x" in html
    # without the scenario's knowledge every pair is fitted (the old behaviour)
    assert len(re.findall(r"<tr><td>\w+</td><td>[\w.]+</td><td>", draw_sensitivity(df, "delay_mean_s"))) == 6


def test_sensitivity_note_in_the_written_report(tmp_path: Path) -> None:
    text = write_report(_merging_batch(), _scenario("merging"), tmp_path / "r.html").read_text()
    assert "Sensitivity to the randomized fields" in text and "Not fitted" in text
    assert "no component uses channel v2x" in text


@pytest.mark.parametrize(("path", "none", "tube"), [
    ("controllers.avoid.params.control_tube.uav_accel_mps2", "configures another", None),
    ("controllers.avoid.params.no_such_gain", "has no parameter", "has no parameter"),
    ("controllers.missing.params.x", "no controller missing", "no controller missing"),
    ("channels.mavlink.loss.p", None, None),  # the MAVLink link backend uses it in every variant
    ("road.demand.scale", "no road", "no road"),
    ("backends.air.params.encounter.geometry", None, None),
])
def test_component_rules(path: str, none: str | None, tube: str | None) -> None:
    scen = variant_scenarios(_scenario("uav_swarm"))
    for variant, want in (("none", none), ("control_tube", tube)):
        got = draw_not_applicable(scen[variant], path)
        assert (got is None) if want is None else (got is not None and want in got), (variant, got)


def test_a_none_controller_uses_nothing() -> None:
    sc = _scenario("merging", ["sweep={plain: {controllers.merge: {type: none}}, coord: "
                               "{controllers.merge: {type: v2x_merging}}}"])
    scen = variant_scenarios(sc)
    assert draw_not_applicable(scen["plain"], "controllers.merge.params.policy") == "controller merge is of type none"
    assert draw_not_applicable(scen["plain"], "channels.v2x.loss.p") is not None
    assert draw_not_applicable(scen["coord"], "controllers.merge.params.policy") is None


# ---------------------------------------------------------------- merging and UAV time series
def _save(out: Path, run_id: str, signals: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    (out / "signals").mkdir(parents=True, exist_ok=True)
    arrays = {k: v for name, (t, x) in signals.items() for k, v in ((name, x), (f"{name}.t", t))}
    np.savez_compressed(out / "signals" / f"{run_id}.npz", **arrays)


def _svgs(text: str, cls: str) -> list[str]:
    return re.findall(rf'<figure class="plot {cls}">.*?</figure>', text, re.S)


def _ids(fig: str, kind: str) -> list[str]:
    return re.findall(rf'id="{kind}:([^"]*)"', fig)


def _merging_signals(out: Path, variants: list[str], seeds: range) -> None:
    t = np.arange(0.1, 600.05, 0.1)  # a 600 s run at 10 Hz: 6000 samples, drawn as <= 300 bins
    for s in seeds:
        for k, v in enumerate(variants):
            _save(out, f"{v}-s{s}", {"min_ttc": (t, np.where(t % 50 < 5, 1.0 + k, np.nan)),  # NaN: no closing pair
                                     "mean_speed": (t, np.full_like(t, 25.0 + k)),
                                     "vehicles": (t, np.minimum(t, 100.0))})


def test_merging_sections_from_signals(tmp_path: Path) -> None:
    from corridor.analysis.report_series import report_sections

    sc = _scenario("merging")
    variants = ["sumo_default", "v2x_fifo", "v2x_cps"]
    df = _merging_batch(3)
    df["merge_loss_ramp_s"], df["merge_loss_mainline_s"], df["merge_loss_mean_s"] = 6.0, 2.0, 3.0
    df.loc[df.run_id == "v2x_cps-s0", "status"] = "error"
    _merging_signals(tmp_path, variants, range(1, 3))
    _save(tmp_path, "sumo_default-s0", {"min_ttc": (np.array([0.0, 1.0]), np.array([5.0, 5.0]))})
    secs = report_sections(tmp_path, df, sc, SCENARIOS / "merging.yaml")
    titles = [re.search(r"<h2>(.*?)</h2>", s).group(1) for s in secs]
    assert titles == ["Minimum time-to-collision", "Mean speed", "Vehicles in the network", "Time lost around the merge"]
    ttc = secs[0]
    (chart,) = _svgs(ttc, "bands")
    assert _ids(chart, "series") == variants and _ids(chart, "band") == variants  # median and IQR per variant
    assert "sumo_default (median, n=3)" in chart and "v2x_cps (median, n=2)" in chart  # every ok run, not seed 0
    assert 'id="warmup"' in chart and "warm-up (120 s)" in chart
    assert _ids(chart, "ref") == ["TTC threshold 1.5 s"] and "min TTC [s]" in chart and "t [s]" in chart
    assert "nan" not in chart.lower().replace("nanosecond", "")
    assert "mean speed [m/s]" in secs[1]  # SI, as recorded
    (bars,) = _svgs(secs[3], "bars")
    assert _ids(bars, "bar") == [s for s in ("ramp vehicles", "mainline vehicles", "all vehicles") for _ in variants]
    text = write_report(df, sc, tmp_path / "report.html", secs).read_text()
    assert all(s in text for s in secs)


def test_overlay_band_is_the_median_and_quartiles_over_seeds(tmp_path: Path) -> None:
    from corridor.analysis.report_series import OVERLAYS, quartile_series

    t = np.arange(0.0, 100.0, 1.0)
    for s in range(5):
        _save(tmp_path, f"a-s{s}", {"mean_speed": (t, np.full_like(t, 20.0 + s))})
    files = sorted((tmp_path / "signals").glob("a-s*.npz"))
    ov = next(o for o in OVERLAYS if o.signal == "mean_speed")
    med, q25, q75, n = quartile_series(ov, files, np.linspace(0.0, 100.0, 11))
    assert int(n) == 5 and np.allclose(med, 22.0) and np.allclose(q25, 21.0) and np.allclose(q75, 23.0)


def test_binned_keeps_the_minimum() -> None:
    from corridor.analysis.report_series import binned, on_grid

    t = np.arange(0.0, 1000.0, 0.1)
    v = np.full_like(t, 9.0)
    v[4321] = 0.5
    tb, vb = binned(t, v, "min", max_bins=100)
    assert len(tb) == 100 and vb.min() == 0.5 and np.all(np.diff(tb) > 0)
    assert np.allclose(binned(t, t, "mean", max_bins=10)[1], binned(t, t, "mean", max_bins=10)[0], atol=0.06)
    grid = on_grid(t, v, np.linspace(0.0, 1000.0, 101), "min")
    assert grid[43] == 0.5 and np.nanmax(grid) == 9.0 and np.isfinite(grid).all()


def test_uav_sections_separation_and_tracks(tmp_path: Path) -> None:
    from corridor.analysis.report_series import report_sections

    sc = _scenario("uav_encounter")
    variants = ["none", "potential_field", "control_tube"]
    t = np.arange(0.1, 75.05, 0.1)
    for k, v in enumerate(variants):
        sep = np.abs(t - 25.0) * 6.0 + 20.0 * k
        sig = {"min_sep_h": (t, sep), "min_sep_3d": (t, sep + 1.0)}
        if v != "control_tube":  # positions recorded by these runs only
            for i, course in enumerate((0.0, np.pi)):
                sig[f"track_e_uav{i}"] = (t, 6.0 * (t - 25.0) * np.sin(course) + 5.0 * k * i)
                sig[f"track_n_uav{i}"] = (t, 6.0 * (t - 25.0) * np.cos(course))
                sig[f"track_u_uav{i}"] = (t, np.full_like(t, 100.0 + 10.0 * i))
            sig["track_e_c172x"] = (t, 50.0 * (t - 25.0))
            sig["track_n_c172x"] = (t, np.full_like(t, 2000.0))
        _save(tmp_path, f"{v}-s0", sig)
    df = _rows(variants, 1, nmac=lambda s, v: int(v == "none"))
    secs = report_sections(tmp_path, df, sc, None)
    titles = [re.search(r"<h2>(.*?)</h2>", s).group(1) for s in secs]
    assert titles == ["Minimum horizontal separation", "Minimum 3-D separation", "Trajectories"]
    (hchart,) = _svgs(secs[0], "bands")
    assert _ids(hchart, "series") == variants and _ids(hchart, "ref") == ["NMAC 30.5 m", "LoS (UAV-UAV) 61.0 m"]
    assert "min horizontal separation [m]" in hchart
    tracks = _svgs(secs[2], "tracks")
    assert len(tracks) == 2  # control_tube recorded no positions
    assert all(_ids(c, "track") == ["c172x", "uav0", "uav1"] and "east [m]" in c and "north [m]" in c for c in tracks)
    assert 'id="closest"' in tracks[0] and "closest approach 0.0 m" in tracks[0]  # uav0 and uav1 meet head-on
    assert all(f">{i}</text>" in tracks[0] for i in ("c172x", "uav0", "uav1"))  # the legend
    assert "closest approach 5.0 m" in tracks[1]  # 5 m apart east in potential_field
    alts = _svgs(secs[2], "altitude")
    assert len(alts) == 2 and _ids(alts[0], "series") == ["uav0", "uav1"]


def test_closest_approach_of_two_tracks() -> None:
    from corridor.analysis.report_series import closest_approach

    t = np.arange(0.0, 10.0, 0.5)
    a = ("a", t, 10.0 * t, np.zeros_like(t), None)
    b = ("b", t, 100.0 - 10.0 * t, np.full_like(t, 8.0), None)
    e, n, d = closest_approach([a, b])
    assert (e, n, d) == (50.0, 4.0, 8.0)  # they pass at t = 5 s, 8 m apart north


def test_real_short_merging_run_has_time_series(tmp_path: Path) -> None:
    from corridor import batch
    from corridor.analysis.report_series import report_sections
    from corridor.run import execute

    path = SCENARIOS / "merging.yaml"
    sc, raw = load(path, ["duration=20", "warmup=0"])
    specs = batch.expand(sc, raw, str(path), 1, out_dir=str(tmp_path), variants=["sumo_default"])
    df = pd.DataFrame([execute(s) for s in specs])
    assert df["status"].tolist() == ["ok"], df.get("error")
    secs = report_sections(tmp_path, df, sc, path)
    assert any("<h2>Minimum time-to-collision</h2>" in s and "<svg" in s for s in secs)
    assert any("<h2>Mean speed</h2>" in s for s in secs)
    (ts,) = [s for s in secs if "<h2>Time-space diagram</h2>" in s]  # the time_space monitor's samples
    assert len(_svgs(ts, "timespace")) == 1 and "<image" in ts and "speed [m/s]" in ts
