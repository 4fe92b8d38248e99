"""The HTML report of a batch: self-contained (plots embedded as PNG), read from the results table."""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from corridor.analysis.stats import clopper_pearson, mean_ci

CSS = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}.bad{color:#b00}.good{color:#070}
img{max-width:100%}code{background:#f3f3f3;padding:1px 3px}.res{font-weight:bold}"""

NON_METRICS = {"run_id", "scenario", "variant", "seed", "status", "error", "traceback"}


def _num(x: float, digits: int = 3) -> str:
    return "–" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}g}"


def metric_columns(df: pd.DataFrame) -> list[str]:
    cols = []
    for c in df.columns:
        if c in NON_METRICS or c.startswith("draw."):
            continue
        if pd.api.types.is_numeric_dtype(df[c]) or pd.api.types.is_bool_dtype(df[c]):
            cols.append(c)
    return cols


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return f'<img src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def distribution_plot(ok: pd.DataFrame, column: str, title: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    groups = [(v, pd.to_numeric(g[column], errors="coerce").dropna().to_numpy(dtype=float))
              for v, g in ok.groupby("variant", sort=False)]
    groups = [(v, x) for v, x in groups if len(x)]
    if not groups:
        plt.close(fig)
        return ""
    ax.boxplot([x for _, x in groups], vert=False, showmeans=True)
    for i, (_, x) in enumerate(groups, start=1):
        jitter = np.linspace(-0.15, 0.15, len(x)) if len(x) > 1 else np.zeros(1)
        ax.plot(x, i + jitter, ".", alpha=0.5, color="C0")
    ax.set_yticks(range(1, len(groups) + 1), [v for v, _ in groups])
    ax.set_title(title)
    ax.set_xlabel(column)
    ax.grid(alpha=0.3)
    return _png(fig)


def kpi_table(ok: pd.DataFrame, cols: list[str], baseline: str) -> str:
    variants = list(dict.fromkeys(ok["variant"]))
    head = "".join(f"<th>{html.escape(v)}</th>" for v in variants)
    rows = []
    base = ok[ok["variant"] == baseline]
    for c in cols:
        cells = []
        b = mean_ci(pd.to_numeric(base[c], errors="coerce").to_numpy(dtype=float))[0] if len(base) else math.nan
        for v in variants:
            x = pd.to_numeric(ok[ok["variant"] == v][c], errors="coerce").to_numpy(dtype=float)
            m, lo, hi = mean_ci(x)
            sd = np.nanstd(x, ddof=1) if np.isfinite(x).sum() > 1 else math.nan
            rel = ""
            if v != baseline and math.isfinite(m) and math.isfinite(b) and b != 0:
                rel = f" <small>({(m - b) / abs(b) * 100:+.1f} %)</small>"
            cells.append(f"<td title='95% CI [{_num(lo)}, {_num(hi)}]'>{_num(m)} ± {_num(sd, 2)}{rel}</td>")
        rows.append(f"<tr><td>{html.escape(c)}</td>{''.join(cells)}</tr>")
    return f"<table><tr><th>metric (mean ± sd; % vs {html.escape(baseline)})</th>{head}</tr>{''.join(rows)}</table>"


def _paired(ok: pd.DataFrame, column: str, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
    """One metric of ``a`` and of ``b`` over the seeds both variants ran, aligned by seed."""
    x = ok[ok["variant"] == a].set_index("seed")[column]
    y = ok[ok["variant"] == b].set_index("seed")[column]
    both = x.index.intersection(y.index)
    return (pd.to_numeric(x.loc[both], errors="coerce").to_numpy(dtype=float),
            pd.to_numeric(y.loc[both], errors="coerce").to_numpy(dtype=float))


def paired_differences(ok: pd.DataFrame, column: str, a: str, b: str) -> np.ndarray:
    """``a − b`` of one metric over the seeds both variants ran (the same draws: common random numbers)."""
    x, y = _paired(ok, column, a, b)
    return x - y


def paired_table(ok: pd.DataFrame, cols: list[str]) -> str:
    """Every pair of variants, per key metric: the mean paired difference with its 95 % Student-t
    interval.  Each seed gives every variant the same demand and draws, so the per-seed difference
    cancels most of the run-to-run spread that the per-variant means carry; an interval that
    excludes 0 is a difference the batch resolves, one that contains 0 is not (yet)."""
    variants = list(dict.fromkeys(ok["variant"]))
    pairs = [(a, b) for i, b in enumerate(variants) for a in variants[i + 1:]]
    if not pairs:
        return ""
    head = "".join(f"<th>{html.escape(a)} − {html.escape(b)}</th>" for a, b in pairs)
    rows = []
    for c in cols:
        cells = []
        for a, b in pairs:
            x, y = _paired(ok, c, a, b)
            d = x - y
            m, lo, hi = mean_ci(d)
            n = int(np.isfinite(d).sum())
            cls = "" if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0 <= hi else " class=res"
            ref = float(np.mean(y[np.isfinite(d)])) if n else math.nan
            rel = f" ({m / abs(ref) * 100:+.1f} %)" if math.isfinite(m) and math.isfinite(ref) and ref != 0 else ""
            cells.append(f"<td{cls}>{_num(m)}{rel} <small>[{_num(lo)}, {_num(hi)}], n={n}</small></td>")
        rows.append(f"<tr><td>{html.escape(c)}</td>{''.join(cells)}</tr>")
    return ("<p>Mean paired difference per seed (in % of the second variant's mean over the same seeds),"
            " [95 % CI]; <b>bold</b>: the interval excludes 0.</p>"
            f"<table><tr><th>metric</th>{head}</tr>{''.join(rows)}</table>")


def draw_sensitivity(ok: pd.DataFrame, column: str) -> str:
    """The metric against each randomized field, per variant, with a least-squares line: how the
    result moves with demand, penetration, message loss ... over the batch's draws."""
    draws = [c for c in ok.columns if c.startswith("draw.") and pd.api.types.is_numeric_dtype(ok[c])]
    draws = [c for c in draws if ok[c].nunique() > 2]
    if not draws or column not in ok:
        return ""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(draws), figsize=(3.4 * len(draws), 3.0), squeeze=False, sharey=True)
    rows = []
    for ax, dc in zip(axes[0], draws, strict=True):
        for i, (v, g) in enumerate(ok.groupby("variant", sort=False)):
            x = g[dc].to_numpy(dtype=float)
            y = pd.to_numeric(g[column], errors="coerce").to_numpy(dtype=float)
            keep = np.isfinite(x) & np.isfinite(y)
            ax.plot(x[keep], y[keep], ".", color=f"C{i}", alpha=0.6, label=v)
            if keep.sum() >= 3 and np.ptp(x[keep]) > 0:
                slope, icpt = np.polyfit(x[keep], y[keep], 1)
                xs = np.array([x[keep].min(), x[keep].max()])
                ax.plot(xs, icpt + slope * xs, "-", color=f"C{i}", lw=1)
                rows.append(f"<tr><td>{html.escape(v)}</td><td>{html.escape(dc[5:])}</td>"
                            f"<td>{_num(slope)}</td><td>{_num(slope * np.ptp(x[keep]))}</td></tr>")
        ax.set_xlabel(dc[5:], fontsize=8)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(column)
    axes[0][0].legend(fontsize=7)
    table = ("<table><tr><th>variant</th><th>randomized field</th><th>slope</th>"
             "<th>change over the drawn range</th></tr>" + "".join(rows) + "</table>")
    return _png(fig) + table


def collision_table(df: pd.DataFrame) -> str:
    rows = []
    for v, g in df.groupby("variant", sort=False):
        ok = g[g["status"] == "ok"]
        coll = ok["collisions"].fillna(0) if "collisions" in ok else pd.Series(dtype=float)
        k, n = int((coll > 0).sum()), len(ok)
        lo, hi = clopper_pearson(k, n)
        cls = "bad" if k else "good"
        rows.append(f"<tr><td>{html.escape(str(v))}</td><td>{len(g)}</td><td>{len(g) - n}</td>"
                    f"<td class={cls}>{int(coll.sum())}</td><td class={cls}>{k}/{n}</td>"
                    f"<td>[{_num(lo)}, {_num(hi)}]</td></tr>")
    return ("<table><tr><th>variant</th><th>runs</th><th>errors</th><th>collisions</th>"
            "<th>runs with a collision</th><th>P(collision) 95 % exact CI</th></tr>" + "".join(rows) + "</table>")


def problem_runs(df: pd.DataFrame) -> str:
    spec_cols = [c for c in df.columns if c.startswith("spec.") and c.endswith(".satisfied")]
    coll = df["collisions"].fillna(0) if "collisions" in df else pd.Series(0, index=df.index)
    bad = df[(df["status"] != "ok") | (coll > 0)]
    for c in spec_cols:
        bad = pd.concat([bad, df[df[c] == False]])  # noqa: E712 (pandas comparison)
    bad = bad.drop_duplicates("run_id")
    if bad.empty:
        return "<p class=good>No run collided, failed, or violated a specification.</p>"
    rows = []
    for _, r in bad.iterrows():
        violated = [c.split(".")[1] for c in spec_cols if r.get(c) is False or r.get(c) == 0]
        why = (r["error"] if r["status"] != "ok" else
               f"{int(r.get('collisions', 0) or 0)} collision(s)" + (f"; violates {', '.join(violated)}" if violated else ""))
        rows.append(f"<tr><td>{html.escape(r['run_id'])}</td><td>{html.escape(str(r['status']))}</td>"
                    f"<td style='text-align:left'>{html.escape(str(why))}</td></tr>")
    return "<table><tr><th>run</th><th>status</th><th>why</th></tr>" + "".join(rows) + "</table>"


def write_report(df: pd.DataFrame, scenario: Any, path: Path, extra_sections: list[str] | None = None) -> Path:
    """Write ``report.html``: per-variant KPIs, collision probability, distributions, problem runs."""
    ok = df[df["status"] == "ok"]
    variants = list(dict.fromkeys(df["variant"]))
    baseline = variants[0] if variants else ""
    cols = metric_columns(ok) if len(ok) else []
    key = [m for m in scenario.metrics if m in cols] or cols[:6]
    plots = "".join(distribution_plot(ok, c, c) for c in key if len(ok))
    spec_cols = [c for c in cols if c.startswith("spec.") and c.endswith(".space")]
    spec_plots = "".join(distribution_plot(ok, c, f"STL robustness {c}") for c in spec_cols)
    body = [
        f"<h1>{html.escape(scenario.name)}</h1><p>{html.escape(scenario.description)}</p>",
        f"<p>{len(df)} runs ({len(ok)} ok), variants: {', '.join(map(html.escape, variants))}; "
        f"{scenario.duration:g} s simulated per run, warm-up {scenario.warmup:g} s.</p>",
        "<h2>Safety: collisions</h2>", collision_table(df),
        "<h2>Key metrics per variant</h2>", kpi_table(ok, key, baseline) if len(ok) else "",
        *(["<h2>Paired differences between variants</h2>", paired_table(ok, key)]
          if len(ok) and ok["variant"].nunique() > 1 else []),
        "<h2>Distributions</h2>", plots, spec_plots,
        *(["<h2>Sensitivity to the randomized fields</h2>", sensitivity] if (sensitivity := (
            draw_sensitivity(ok, key[0]) if len(ok) and key else "")) else []),
        *(extra_sections or []),
        "<h2>Runs with collisions, errors or violated specifications</h2>", problem_runs(df),
        "<h2>All metrics</h2>", kpi_table(ok, cols, baseline) if len(ok) else "",
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"<!doctype html><html><head><meta charset=utf-8><title>{html.escape(scenario.name)}"
                    f"</title><style>{CSS}</style></head><body>{''.join(body)}</body></html>")
    return path
