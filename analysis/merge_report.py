"""Merge-bottleneck sections of the HTML report (a ``corridor.report_sections`` entry point).

* **Bottleneck**: per variant, the runs that broke down and the capacity drop (mean, Student-t 95 %
  interval over seeds) from the ``merge_loops`` columns; a flow-time chart of the loops (one
  representative run per variant) and a flow-density scatter of every loop interval of every run.
* **Paired differences**: each variant minus the baseline (the first variant), seed by seed (the same
  seed draws the same demand), mean and 95 % interval, for the merge benchmark's metrics.
* **Time-space diagram**: mean highway speed per cell and period (``network_metrics`` with ``cell_m``),
  one representative run per variant: waves show as red bands running upstream.

Scenarios without these columns or signals get nothing.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from corridor.analysis.merge_sweep import NAME, sweep_section
from corridor.analysis.plots import heatmap, line_chart, scatter_chart
from corridor.analysis.report_series import load_npz, representative_runs
from corridor.analysis.stats import mean_ci

PAIRED = (("avg_speed_mps", "average speed [m/s]"),
          ("avg_speed_all_mps", "average speed, vehicles waiting to enter at 0 [m/s]"), ("outflow_vph", "outflow [veh/h]"),
          ("delay_mean_s", "mean delay [s]"), ("hard_brakes", "hard brakes"), ("min_ttc_s", "min TTC [s]"),
          ("co2_g_per_km", "CO2 [g/km]"), ("fuel_g_per_km", "fuel [g/km]"), ("collisions", "collisions"),
          ("capacity_drop_pct", "capacity drop [%]"))


def _fmt_ci(x: np.ndarray, digits: int = 1) -> str:
    m, lo, hi = mean_ci(x)
    if not math.isfinite(m):
        return "–"
    if not math.isfinite(lo):
        return f"{m:.{digits}f}"
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _table(head: list[str], rows: list[list[str]]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _num(d: pd.DataFrame, col: str) -> np.ndarray:
    return pd.to_numeric(d[col], errors="coerce").to_numpy(dtype=float) if col in d else np.zeros(0)


def bottleneck_section(out_dir: Path, ok: pd.DataFrame, variants: list[str]) -> list[str]:
    if "capacity_drop_pct" not in ok:
        return []
    rows = []
    for v in variants:
        d = ok[ok["variant"].astype(str) == v]
        broke = _num(d, "breakdown")
        rows.append([v, f"{int(np.nansum(broke))}/{len(d)}", _fmt_ci(_num(d, "breakdown_s"), 0),
                     _fmt_ci(_num(d, "prebreakdown_flow_vph"), 0), _fmt_ci(_num(d, "discharge_flow_vph"), 0),
                     _fmt_ci(_num(d, "capacity_drop_pct"))])
    out = ["<h2>Bottleneck: breakdown and capacity drop (virtual loops)</h2>",
           "<p>Breakdown (HCM): the upstream loop's speed at least 25 % below the free-flow speed, sustained. "
           "Capacity drop = 1 − queue discharge flow / pre-breakdown maximum flow at the downstream loop "
           "(Cassidy &amp; Bertini 1999 measured about 10 % at Toronto bottlenecks). Mean [95 % interval] over seeds.</p>",
           _table(["variant", "breakdowns", "breakdown at [s]", "pre-breakdown max [veh/h]",
                   "queue discharge [veh/h]", "capacity drop [%]"], rows)]
    return out + _loop_charts(out_dir, ok, variants)


def _loop_charts(out_dir: Path, ok: pd.DataFrame, variants: list[str]) -> list[str]:
    charts = []
    runs = representative_runs(out_dir, ok)
    for v in variants:
        if v not in runs:
            continue
        rid, sig = runs[v]
        flows = sorted(n for n in sig if n.startswith("loop_flow_vph_"))
        if flows:
            series = [(n[len("loop_flow_vph_"):], *sig[n]) for n in flows]
            charts.append(line_chart(series, f"{v}: loop flows ({rid})", "t [s]", "flow [veh/h]"))
        k, q = _all_intervals(out_dir, ok[ok["variant"].astype(str) == v])
        if len(k):
            charts.append(scatter_chart(k, q, [], f"{v}: flow-density, every loop interval of every run",
                                        "density [veh/km]", "flow [veh/h]", "fd"))
    if not charts:
        return []
    return ["<h3>Flow-time and flow-density at the loops</h3>", *charts]


def _all_intervals(out_dir: Path, runs: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    ks, qs = [], []
    for rid in runs["run_id"].astype(str):
        path = Path(out_dir) / "signals" / f"{rid}.npz"
        if not path.is_file():
            continue
        sig = load_npz(path)
        for n in sig:
            if n.startswith("loop_density_vpkm_"):
                ks.append(sig[n][1])
                qs.append(sig["loop_flow_vph_" + n[len("loop_density_vpkm_"):]][1])
    if not ks:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(ks), np.concatenate(qs)


def paired_section(ok: pd.DataFrame, variants: list[str]) -> list[str]:
    cols = [(c, label) for c, label in PAIRED if c in ok and pd.to_numeric(ok[c], errors="coerce").notna().any()]
    if not ({"avg_speed_mps", "capacity_drop_pct"} & set(ok)) or len(variants) < 2 or not cols:
        return []
    base = variants[0]
    b = ok[ok["variant"].astype(str) == base].set_index("seed")
    rows = []
    for v in variants[1:]:
        d = ok[ok["variant"].astype(str) == v].set_index("seed")
        seeds = d.index.intersection(b.index)
        row = [v, str(len(seeds))]
        for c, _ in cols:
            diff = pd.to_numeric(d.loc[seeds, c], errors="coerce") - pd.to_numeric(b.loc[seeds, c], errors="coerce")
            row.append(_fmt_ci(diff.to_numpy(dtype=float), 2))
        rows.append(row)
    means = [[v, str(int((ok["variant"].astype(str) == v).sum()))]
             + [_fmt_ci(_num(ok[ok["variant"].astype(str) == v], c), 2) for c, _ in cols] for v in variants]
    return [f"<h2>Paired differences to <code>{html.escape(base)}</code></h2>",
            "<p>Each variant minus the baseline on the same seed (same demand draws), mean [95 % interval]. "
            "An interval that excludes 0 is a measured difference.</p>",
            _table(["variant", "seeds", *(label for _, label in cols)], rows),
            "<h3>Per-variant means [95 % interval]</h3>",
            _table(["variant", "runs", *(label for _, label in cols)], means)]


def space_time_section(out_dir: Path, ok: pd.DataFrame, variants: list[str]) -> list[str]:
    runs = representative_runs(out_dir, ok)
    charts = []
    for v in variants:
        if v not in runs:
            continue
        rid, sig = runs[v]
        cells = sorted((n for n in sig if n.startswith("ts_speed_kmh_")), reverse=True)  # downstream on top
        if not cells:
            continue
        t = sig[cells[0]][0]
        step = float(np.median(np.diff(t))) if len(t) > 1 else 5.0
        edges = np.concatenate([[t[0] - step], t])
        grid = np.vstack([sig[c][1] for c in cells])
        labels = [f"x={int(c[len('ts_speed_kmh_'):])} m" for c in cells]
        charts.append(heatmap(labels, edges, grid, f"{v}: highway speed ({rid})", "t [s]", "km/h", 110.0))
    if not charts:
        return []
    return ["<h2>Time-space diagram of speeds</h2>",
            "<p>Mean speed of the highway's vehicles per 25 m cell (rows, downstream at the top) and period; "
            "stop-and-go waves run upstream as red bands. One representative run per variant.</p>", *charts]


def report_sections(out_dir: Path, df: pd.DataFrame, scenario: Any, scenario_path: Any = None) -> list[str]:
    if df.empty or "status" not in df:
        return []
    ok = df[df["status"] == "ok"]
    variants = list(dict.fromkeys(ok["variant"].astype(str)))
    if any(NAME.match(v) for v in variants):  # the merging sweep: heat maps instead of per-variant tables
        return sweep_section(ok)
    return [*bottleneck_section(out_dir, ok, variants), *paired_section(ok, variants),
            *space_time_section(out_dir, ok, variants)]
