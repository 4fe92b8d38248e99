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

REPO = Path(__file__).resolve().parents[2]


def _scenario(name: str, sets: list[str] | None = None):  # noqa: ANN202 - a corridor Scenario
    return load(REPO / "scenarios" / f"{name}.yaml", sets or [])[0]


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
    assert "Runs with errors or violated specifications" in text and "collided" not in text
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
