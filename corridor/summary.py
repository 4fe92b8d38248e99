"""The summary table printed at the end of a batch: one line per variant, fitted to the terminal.

Columns: runs, errors, collisions and the collision probability with its exact 95 % interval (only
when the runs count collisions), then as many of the scenario's key metrics as fit the terminal width
(mean ± standard deviation over the variant's ``ok`` runs); the rest are named under the table and
shown in ``report.html``.

Under it, when the batch has more than one variant: the paired differences of the first key metric
to the first variant (the baseline), seed by seed (the variants of one seed share their random
draws), as the mean difference with its 95 % Student-t interval over the seeds both ran.
"""

from __future__ import annotations

import math
import shutil
import sys
from typing import TextIO

import numpy as np
import pandas as pd

from corridor.stats import clopper_pearson

NOTE = ("metrics: mean ± standard deviation over the variant's ok runs; (k/n): a value in only k of the n ok "
        "runs (e.g. min_ttc_s: no closing pair in the others)")
NOTE_COLLISIONS = "; P(collision): ok runs with a collision / ok runs [exact (Clopper-Pearson) 95 % interval]"


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    ax = abs(x)
    return f"{x:.3g}" if ax < 1000 else f"{x:.0f}"


def summary_rows(df: pd.DataFrame, key_metrics: list[str],
                 collisions: bool = True) -> tuple[list[str], list[list[str]]]:
    """Header and one row of strings per variant (collision columns only if ``collisions`` apply)."""
    metrics = [m for m in key_metrics if m in df.columns and m != "collisions"]
    counts_collisions = collisions and "collisions" in df.columns
    head = ["variant", "runs", "errors"]
    if counts_collisions:
        head += ["collisions", "P(collision)"]
    head += metrics
    lines = []
    for variant, g in df.groupby("variant", sort=False):
        ok = g[g["status"] == "ok"]
        row = [str(variant), str(len(g)), str(len(g) - len(ok))]
        if counts_collisions:
            coll = pd.to_numeric(ok["collisions"], errors="coerce").fillna(0).astype(int)
            k, n = int((coll > 0).sum()), len(ok)
            lo, hi = clopper_pearson(k, n)
            row += [str(int(coll.sum())), f"{k}/{n} [{_fmt(lo)}, {_fmt(hi)}]" if n else "-"]
        for m in metrics:
            v = pd.to_numeric(ok[m], errors="coerce").to_numpy(dtype=float)
            v = v[np.isfinite(v)]
            some = f" ({len(v)}/{len(ok)})" if len(v) < len(ok) else ""  # runs without a value, counted
            row.append((f"{_fmt(v.mean())} ± {_fmt(v.std(ddof=1))}" if len(v) > 1 else
                        (_fmt(v[0]) if len(v) else "-")) + some)
        lines.append(row)
    return head, lines


def paired_rows(df: pd.DataFrame, metric: str, confidence: float = 0.95) -> list[tuple[str, int, float, float, float]]:
    """Per variant after the first: (variant, pairs, mean difference, interval low, high) of ``metric``
    minus the first variant's, over the seeds where both have a finite value in an ``ok`` run."""
    if metric not in df.columns or "seed" not in df.columns:
        return []
    ok = df[df["status"] == "ok"]
    variants = list(dict.fromkeys(df["variant"]))
    if len(variants) < 2:
        return []

    def by_seed(v: str) -> pd.Series:
        g = ok[ok["variant"] == v]
        return pd.Series(pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float), index=g["seed"].to_numpy())

    base = by_seed(variants[0])
    rows = []
    for v in variants[1:]:
        both = pd.concat([by_seed(v), base], axis=1, join="inner").to_numpy(dtype=float)
        d = both[:, 0] - both[:, 1]
        d = d[np.isfinite(d)]
        rows.append((str(v), len(d), *_mean_interval(d, confidence)))
    return rows


def _mean_interval(d: np.ndarray, confidence: float) -> tuple[float, float, float]:
    """Mean and Student-t interval of the mean (nan where undefined)."""
    if len(d) == 0:
        return (math.nan, math.nan, math.nan)
    m = float(d.mean())
    if len(d) < 2:
        return (m, math.nan, math.nan)
    from scipy import stats  # here: scipy.stats costs ~0.4 s at import

    h = float(stats.t.ppf(0.5 + confidence / 2, len(d) - 1)) * float(d.std(ddof=1)) / math.sqrt(len(d))
    return (m, m - h, m + h)


def paired_lines(df: pd.DataFrame, key_metrics: list[str]) -> list[str]:
    """The paired-difference lines printed under the table (none for a single variant)."""
    metric = next((m for m in key_metrics if m in df.columns and m != "collisions"), None)
    rows = paired_rows(df, metric) if metric else []
    if not rows:
        return []
    base = str(next(iter(dict.fromkeys(df["variant"]))))
    out = [f"paired difference of {metric} to {base} (same seeds; mean [95 % t-interval], pairs):"]
    for v, n, m, lo, hi in rows:
        verdict = "" if not (math.isfinite(lo) and math.isfinite(hi)) else (
            "  (interval excludes 0)" if lo > 0 or hi < 0 else "  (interval includes 0)")
        out.append(f"  {v}: {_signed(m)} [{_signed(lo)}, {_signed(hi)}] ({n}){verdict}")
    return out


def _signed(x: float) -> str:
    return _fmt(x) if not math.isfinite(x) or x < 0 else "+" + _fmt(x)


def _fit(head: list[str], lines: list[list[str]], fixed: int, width: int) -> int:
    """How many columns fit ``width`` (the first ``fixed`` always stay); 3 characters per separator."""
    used = 0
    for i, h in enumerate(head):
        w = max(len(h) if i < fixed else min(len(h), 12), *(len(r[i]) for r in lines)) if lines else len(h)
        if i >= fixed and used + w + 3 > width:
            return i
        used += w + 3
    return len(head)


def summary_table(df: pd.DataFrame, key_metrics: list[str], width: int | None = None,
                  collisions: bool = True) -> str:
    """The table as text (for logs and tests); ``print_summary`` prints the same with colours."""
    from io import StringIO

    buf = StringIO()
    print_summary(df, key_metrics, file=buf, width=width or 100, collisions=collisions)
    return buf.getvalue()


def print_summary(df: pd.DataFrame, key_metrics: list[str], file: TextIO | None = None,
                  width: int | None = None, collisions: bool = True) -> None:
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    file = file or sys.stdout
    width = width or shutil.get_terminal_size((100, 24)).columns
    head, lines = summary_rows(df, key_metrics, collisions)
    fixed = 5 if "collisions" in head else 3
    n = _fit(head, lines, fixed, width - 4)
    table = Table(title="summary per variant", caption=Text(NOTE + (NOTE_COLLISIONS if fixed == 5 else "")),
                  caption_justify="left")
    for i, h in enumerate(head[:n]):
        w = max(len(h) if i < fixed else min(len(h), 12), *(len(r[i]) for r in lines)) if lines else len(h)
        table.add_column(h, justify="left" if i == 0 else "right", overflow="fold", min_width=w)
    for r in lines:
        table.add_row(*r[:n])
    console = Console(file=file, width=width, highlight=False, soft_wrap=False,
                      force_terminal=file.isatty() if hasattr(file, "isatty") else False)
    console.print(table)
    if n < len(head):
        console.print(f"more metrics in report.html and runs.parquet: {', '.join(head[n:])}", markup=False)
    for line in paired_lines(df, key_metrics):
        console.print(line, markup=False)
