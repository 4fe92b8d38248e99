"""Parking sections of the HTML report (a ``corridor.report_sections`` entry point): success by
highway-env's criterion and by corridor's pose tolerance with exact 95 % intervals, how the runs
ended (final mode of the manoeuvre automaton and the abort reasons: failures explained by mode),
and the distributions of the final pose error and the manoeuvre time per variant (transition accuracy
and repeatability).  Scenarios without the ``parking`` monitor's columns get nothing."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from corridor.analysis.plots import histogram, lot_chart
from corridor.stats import clopper_pearson

HISTOGRAMS = (  # column, scale, label, bin width
    ("pos_err_m", 1.0, "final position error [m]", 0.02),
    ("heading_err_rad", 1.0, "final heading error [rad]", 0.005),
    ("manoeuvre_time_s", 1.0, "manoeuvre time [s]", 2.0),
)


def _rate(x: pd.Series) -> str:
    x = pd.to_numeric(x, errors="coerce").dropna()
    k, n = int(x.sum()), len(x)
    if not n:
        return "–"
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} = {100.0 * k / n:.1f} % [{100.0 * lo:.1f}, {100.0 * hi:.1f}]"


def _summary(ok: pd.DataFrame, variants: list[str]) -> str:
    rows = []
    for v in variants:
        d = ok[ok["variant"].astype(str) == v]
        modes = d["final_mode"].astype(str).value_counts().to_dict() if "final_mode" in d else {}
        reasons = d["abort_reasons"].astype(str).str.split("; ").explode() if "abort_reasons" in d else pd.Series()
        reasons = reasons[reasons.str.len() > 0].value_counts().to_dict()
        coll = int((pd.to_numeric(d.get("collisions", pd.Series(dtype=float)), errors="coerce") > 0).sum())
        cells = [v, _rate(d["he_success"]) if "he_success" in d else "–", _rate(d["success"]), str(coll),
                 ", ".join(f"{m}: {n}" for m, n in modes.items()), ", ".join(f"{r}: {n}" for r, n in reasons.items())]
        rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    head = ("<tr><th>variant</th><th>success (highway-env) [95 %]</th><th>success (pose) [95 %]</th>"
            "<th>runs with a collision</th><th>final mode</th><th>abort reasons</th></tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def _histogram(ok: pd.DataFrame, variants: list[str], col: str, scale: float, label: str, width: float) -> str:
    data = {v: scale * pd.to_numeric(ok[ok["variant"].astype(str) == v][col], errors="coerce").dropna().to_numpy()
            for v in variants}
    allv = np.concatenate([x for x in data.values()]) if data else np.zeros(0)
    if not len(allv):
        return ""
    hi = max(float(np.percentile(allv, 99)), width)
    edges = np.arange(0.0, hi + width, width)
    stats = "; ".join(f"{html.escape(v)}: p50 {np.median(x):.3g}, p95 {np.percentile(x, 95):.3g}, "
                      f"max {np.max(x):.3g} (n={len(x)})" for v, x in data.items() if len(x))
    return (f"<h3>{html.escape(label)}</h3><p>{stats}</p>"
            f"{histogram(data, edges, label, label + ' (the last bin holds everything above)')}")


def lot_section(out_dir: Path, ok: pd.DataFrame, variants: list[str]) -> str:
    """The lot seen from above with the planned and the driven path, for the first run of each
    variant that left ``parking/lot-<run_id>.json`` (the parking monitor writes it)."""
    charts = []
    for v in variants:
        for rid in ok[ok["variant"].astype(str) == v]["run_id"].astype(str):
            path = Path(out_dir) / "parking" / f"lot-{rid}.json"
            if path.is_file():
                charts.append(lot_chart(json.loads(path.read_text()), f"{v}: {rid}"))
                break
    if not charts:
        return ""
    return ("<h3>The lot, the plan and the path driven</h3><p>Bays and walls (grey), parked cars (dark), the "
            "goal bay (green), every plan the controller announced (its planner's reference point; dashed, the last one "
            "solid) and the path "
            "the ego's centre drove (blue), one run per variant.</p>" + "".join(charts))


def report_sections(out_dir: Path, df: pd.DataFrame, scenario: Any, scenario_path: Path | str | None) -> list[str]:
    if "pos_err_m" not in df or "success" not in df:
        return []
    ok = df[df["status"] == "ok"] if "status" in df else df
    if ok.empty:
        return []
    variants = list(dict.fromkeys(ok["variant"].astype(str)))
    parts = ["<h2>Parking</h2><p>Success by highway-env's own criterion (<code>ParkingEnv._is_success</code> "
             "at the end of the run) and by corridor's pose tolerance (the <code>parking</code> monitor), with "
             "exact (Clopper–Pearson) 95 % intervals; how the runs ended: the manoeuvre automaton's final mode "
             "and why it aborted.</p>", _summary(ok, variants)]
    parts.append(lot_section(out_dir, ok, variants))
    parts += [h for h in (_histogram(ok, variants, *spec) for spec in HISTOGRAMS if spec[0] in ok) if h]
    return ["".join(parts)]
