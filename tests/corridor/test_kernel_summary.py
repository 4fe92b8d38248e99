"""The batch summary's paired differences to the first variant (``corridor.summary``)."""

from __future__ import annotations

import math

import pandas as pd

from corridor.summary import paired_rows, summary_table


def _rows() -> pd.DataFrame:
    rows = []
    for seed, base, coop in ((0, 10.0, 9.0), (1, 12.0, 11.0), (2, 14.0, 13.5), (3, 16.0, math.nan)):
        rows.append({"run_id": f"human-s{seed}", "variant": "human", "seed": seed, "status": "ok", "delay_mean_s": base})
        rows.append({"run_id": f"coop-s{seed}", "variant": "coop", "seed": seed, "status": "ok", "delay_mean_s": coop})
    rows.append({"run_id": "coop-s4", "variant": "coop", "seed": 4, "status": "error", "delay_mean_s": 0.0})
    return pd.DataFrame(rows)


def test_paired_differences_are_seed_by_seed_with_a_t_interval() -> None:
    # differences -1, -1, -0.5 (seed 3 has no value, seed 4 failed and has no baseline):
    # mean -0.8333, sd 0.2887, t(0.975, 2) = 4.3027 -> half-width 0.7172
    [(variant, n, m, lo, hi)] = paired_rows(_rows(), "delay_mean_s")
    assert (variant, n) == ("coop", 3)
    assert math.isclose(m, -0.8333333, abs_tol=1e-6)
    assert math.isclose(lo, -1.5505, abs_tol=1e-3) and math.isclose(hi, -0.1161, abs_tol=1e-3)


def test_the_console_summary_prints_them() -> None:
    text = summary_table(_rows(), ["delay_mean_s"], width=120, collisions=False)
    assert "paired difference of delay_mean_s to human" in text
    assert "coop: -0.833 [-1.55, -0.116] (3)  (interval excludes 0)" in text


def test_one_variant_prints_no_paired_line() -> None:
    df = _rows()
    assert "paired difference" not in summary_table(df[df["variant"] == "human"], ["delay_mean_s"], width=120)
