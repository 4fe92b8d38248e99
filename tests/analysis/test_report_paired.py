"""Report: paired differences between variants over common seeds, and sensitivity to the draws."""

from __future__ import annotations

import numpy as np
import pandas as pd

from corridor.analysis.report import draw_sensitivity, paired_differences, paired_table


def _batch(offset: float, seeds: int = 12, spread: float = 3.0) -> pd.DataFrame:
    rng = np.random.default_rng(5)
    demand = rng.uniform(0.9, 1.1, seeds)
    seed_effect = rng.normal(0.0, spread, seeds)  # large spread between seeds, shared by the variants
    rows = []
    for s in range(seeds):
        base = 10.0 + 20.0 * (demand[s] - 1.0) + seed_effect[s]
        for v, d in (("a", 0.0), ("b", offset), ("c", 0.0)):
            rows.append({"run_id": f"{v}-s{s}", "variant": v, "seed": s, "status": "ok",
                         "delay": base + d + rng.normal(0.0, 0.05), "draw.road.demand.scale": demand[s]})
    return pd.DataFrame(rows)


def test_paired_difference_resolves_a_shift_that_the_seed_spread_hides() -> None:
    df = _batch(offset=-0.5)
    d = paired_differences(df, "delay", "b", "a")
    assert len(d) == 12 and abs(d.mean() + 0.5) < 0.05
    # the unpaired means differ by 0.5 while each variant's spread is ~3: the per-variant CIs overlap
    assert df[df.variant == "a"]["delay"].std() > 2.0
    html = paired_table(df, ["delay"])
    cells = html.split("<td")
    assert "b − a" in html and "c − a" in html and "c − b" in html
    b_minus_a, c_minus_a, c_minus_b = [c for c in cells if "n=12" in c]
    assert b_minus_a.startswith(" class=res>-0.4")  # resolved: bold
    assert not c_minus_a.startswith(" class=res")  # c equals a up to noise: not resolved
    assert c_minus_b.startswith(" class=res>0.4")
    # the relative difference is taken against the second variant's mean over the same seeds
    pct = float(b_minus_a.split("(")[1].split(" %")[0])
    assert abs(pct - d.mean() / df[df.variant == "a"]["delay"].mean() * 100) < 0.06


def test_paired_difference_uses_only_seeds_both_variants_ran() -> None:
    df = _batch(offset=1.0)
    df = df[~((df.variant == "b") & (df.seed < 4))]
    assert len(paired_differences(df, "delay", "b", "a")) == 8


def test_sensitivity_reports_the_slope_over_the_draws() -> None:
    html = draw_sensitivity(_batch(offset=0.0, spread=0.2), "delay")
    assert "<svg" in html and "road.demand.scale" in html
    slopes = [float(r.split("<td>")[3].split(" ")[0]) for r in html.split("<tr>")[2:]]
    assert len(slopes) == 3 and all(abs(s - 20.0) < 4.0 for s in slopes)  # the built-in 20 per unit scale
    assert draw_sensitivity(_batch(0.0).drop(columns="draw.road.demand.scale"), "delay") == ""
