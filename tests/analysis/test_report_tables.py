"""The report's tables and distributions: 95 % intervals printed (not only in tooltips), missing
values shown as "—" with the count of runs that have one (never "nan" or "– ± –"), box plots only
from 5 runs on (points below), the sensitivity table naming metric, unit and interval."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from corridor.analysis.report import distribution_plot, draw_sensitivity, kpi_table, write_report
from corridor.scenario import load
from tests.conftest import SCENARIOS


def _df(n: int, ttc: list[float] | None = None) -> pd.DataFrame:
    rng = np.random.default_rng(1)
    rows = []
    for v in ("sumo_default", "v2x_fifo"):
        for s in range(n):
            rows.append({"run_id": f"{v}-s{s}", "variant": v, "seed": s, "status": "ok", "error": "", "collisions": 0,
                         "delay_mean_s": 10.0 + s + (v == "v2x_fifo"), "draw.road.demand.scale": 0.9 + 0.05 * s,
                         "min_ttc_s": (ttc[s] if ttc else float(rng.uniform(1, 3))) if v == "sumo_default" else np.nan})
    return pd.DataFrame(rows)


def test_kpi_table_prints_the_interval_and_missing_values() -> None:
    df = _df(4, ttc=[1.0, np.nan, 2.0, 3.0])
    table = kpi_table(df, ["delay_mean_s", "min_ttc_s"], "sumo_default", {"delay_mean_s": "s", "min_ttc_s": "s"})
    delay = re.search(r"<tr><td>delay_mean_s \[s\]</td>(.*?)</tr>", table).group(1)
    assert re.search(r"<td[^>]*>11.5 <small>\[9.\d+, 13.\d+\]</small> <small>n=4</small></td>", delay)  # printed
    ttc = re.search(r"<tr><td>min_ttc_s \[s\]</td>(.*?)</tr>", table).group(1)
    assert "<small>n=3 of 4</small>" in ttc  # one run without a closing pair: counted, not averaged
    assert "— <small>(no value in 4 runs)</small>" in ttc  # v2x_fifo: none at all
    assert "nan" not in table.lower() and "– ± –" not in table and "± –" not in table


def test_few_runs_are_points_not_boxes() -> None:
    few = distribution_plot(_df(3), "delay_mean_s", "delay", "s")
    many = distribution_plot(_df(6), "delay_mean_s", "delay", "s")
    assert re.findall(r'id="points:([^"]*)"', few) == ["sumo_default", "v2x_fifo"]
    assert "boxplot" not in few and few.count("<path") < many.count("<path")
    assert "sumo_default (n=3)" in few and "delay_mean_s [s]" in few


def test_sensitivity_table_names_metric_unit_and_interval() -> None:
    text = draw_sensitivity(_df(6), "delay_mean_s", unit="s")
    assert "slope of delay_mean_s [s per unit of the field] [95 % CI]" in text
    assert "change of delay_mean_s over the drawn range [s] [95 % CI]" in text
    row = re.search(r"<tr><td>sumo_default</td><td>road.demand.scale</td>(.*?)</tr>", text).group(1)
    assert re.search(r"<td>20 <small>\[\S+, \S+\]</small></td>", row)  # 1 s per 0.05: slope 20 s


def test_written_report_has_no_nan(tmp_path: Path) -> None:
    sc = load(SCENARIOS / "merging.yaml", [])[0]
    text = write_report(_df(2, ttc=[np.nan, np.nan]), sc, tmp_path / "r.html").read_text()
    body = re.sub(r"<svg.*?</svg>", "", text, flags=re.S)
    assert not re.search(r"\bnan\b", body, re.I) and "– ± –" not in body
    assert "<h2>Metric glossary</h2>" in text and "<code>min_ttc_s</code>" in text


def test_values_print_as_plain_digits() -> None:
    from corridor.analysis.report import _num

    assert [_num(2321.5), _num(0.93612), _num(-8.05), _num(0.0), _num(float("nan")), _num(None)] == \
        ["2320", "0.936", "-8.05", "0", "—", "—"]
    assert _num(1.5e-5) == "1.5e-05" and _num(2.5e7) == "2.5e+07"  # far from 1: exponent kept
